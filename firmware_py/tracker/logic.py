"""The solar tracker's per-axis logic: the photocell filter, the report's relay logic, the sun-rate
feed-forward, and the relays (dwell, counters); the drive model the feed-forward inverts.

Design: docs/tracker.md#modes
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

from protocol.states import AZ, EL
from protocol.units import DEG

FF_CLOSE_DEG_S = 0.02 / 60.0     # feed-forward: a relay closes above this commanded rate
FF_OPEN_DEG_S = 0.007 / 60.0     # ... and opens below this one
FF_ERROR_FILTER = 1.0 / 30.0     # feed-forward: the photocell error is low-passed at this x trk_ff_tau_s
COS_EL_FLOOR = 0.1               # azimuth error = cross-beam error / max(cos(elevation), this)


@dataclass(frozen=True)
class TrackerDrive:
    """One axis's drive as the firmware knows it: a 90 VDC PM motor on a 20,000:1 train.

    The report gives the 90 V only; the rest is ASSUMED, the catalogue figures of the 1/8 hp,
    1750 rpm, 90 VDC motor class such a speed controller drives and its gear train (the numbers
    hil_sim/tracker.py documents for the plant; tests/test_tracker_control.py checks the two
    agree, as a controller's configuration must match the build it drives).
    """

    supply_v: float = 90.0
    r_ohm: float = 8.0
    k_v_s_rad: float = 0.43            # Kt = Ke
    coulomb_nm: float = 0.06           # friction at the motor shaft
    viscous_nm_s_rad: float = 2e-4
    gear_ratio: float = 20_000.0

    def speed_deg_s(self, duty: float, bus_v: Optional[float] = None) -> float:
        """Steady axis speed at `duty` (friction dead band included) [deg/s]."""
        k, r = self.k_v_s_rad, self.r_ohm
        v = duty * (bus_v if bus_v else self.supply_v) - r * self.coulomb_nm / k
        return max(0.0, v / (k + r * self.viscous_nm_s_rad / k)) / self.gear_ratio / DEG

    def duty_for(self, speed_deg_s: float, bus_v: Optional[float] = None) -> float:
        """The duty that gives |speed_deg_s| in steady state (the inverse of `speed_deg_s`), unclipped."""
        k, r = self.k_v_s_rad, self.r_ohm
        w = abs(speed_deg_s) * DEG * self.gear_ratio
        return (w * (k + r * self.viscous_nm_s_rad / k) + r * self.coulomb_nm / k) / (bus_v if bus_v else self.supply_v)

    @property
    def top_speed_deg_s(self) -> float:
        return self.speed_deg_s(1.0)


DRIVE = TrackerDrive()


@dataclass
class AxisState:
    """One axis: its relay (-1 CCW, 0 open, +1 CW), the logic's wish, filters, counters."""

    relay: int = 0
    want: int = 0                      # the relay logic's (or feed-forward's) hysteresis state
    changed_s: Optional[float] = None  # `now` of the last relay change
    opened_s: Optional[float] = None   # `now` of the last opening
    last_closed: int = 0               # direction of the last closing
    duty: float = 0.0                  # as sent
    brake: bool = True                 # as sent
    diff_v: float = math.nan           # filtered photocell difference a - b
    sum_v: float = math.nan            # filtered a + b
    rate_cmd_dps: float = 0.0          # feed-forward: the commanded rate
    error_deg: float = math.nan        # feed-forward: the photocells' pointing error, low-passed
    error_s: Optional[float] = None    # `now` of its last update
    switchings: int = 0
    chatter: int = 0
    reversals: int = 0


class RelayLogic:
    """Each axis's decision and its relay, for `TrackerController` (needs `axes`, `box`, `params`, `hal`,
    `drive`, `sun_rates`)."""

    def _filter(self, sense_s: Optional[float], cells: list, stale_s: float) -> None:
        """Low-pass each pair's difference and sum, once per new TRACKER_SENSE."""
        if sense_s is None or sense_s == self._sense_seen:
            return
        previous, self._sense_seen = self._sense_seen, sense_s
        tau = self.params["trk_filter_s"]
        dt = None if previous is None else sense_s - previous
        alpha = 1.0 if dt is None or dt > stale_s or tau <= 0.0 else -math.expm1(-dt / tau)
        for k, ax in enumerate(self.axes):
            a, b = cells[2 * k], cells[2 * k + 1]
            if not math.isfinite(ax.diff_v) or alpha >= 1.0:
                ax.diff_v, ax.sum_v = a - b, a + b
            else:
                ax.diff_v += alpha * (a - b - ax.diff_v)
                ax.sum_v += alpha * (a + b - ax.sum_v)

    def _relay_logic(self, k: int, ax: AxisState, sun_min: float) -> tuple[int, float]:
        """The report's sensor mode: the photocell difference picks the relay, with deadband and hysteresis."""
        if not ax.sum_v >= sun_min:
            ax.want = 0
            return 0, 0.0
        p = self.params
        d = ax.diff_v * 1000.0
        close = p["trk_deadband_mv"]
        hold = close - p["trk_hyst_mv"]
        w = ax.want
        if w == 0:
            w = 1 if d > close else -1 if d < -close else 0
        elif w > 0:
            w = -1 if d < -close else 0 if d < hold else 1
        else:
            w = 1 if d > close else 0 if d > -hold else -1
        ax.want = w
        return w, self.box.dial_duty(k)

    def _feedforward(self, k: int, ax: AxisState, sun_min: float, now: float) -> tuple[int, float]:
        """Sun rate + photocell correction; the relays follow its sign, the duty its size (capped by the dial)."""
        rate = self.sun_rates()[k]
        tau = self.params["trk_ff_tau_s"]
        correction = 0.0
        if ax.sum_v >= sun_min and ax.sum_v > 0.0:
            error = math.atan(ax.diff_v / ax.sum_v) / DEG
            if k == AZ:
                el = self.hal.inputs.tracker_angles_deg[EL]
                error /= max(math.cos(el * DEG), COS_EL_FLOOR) if math.isfinite(el) else 1.0
            if ax.error_s is None or not math.isfinite(ax.error_deg):
                ax.error_deg = error
            else:
                ax.error_deg += -math.expm1(-(now - ax.error_s) / (FF_ERROR_FILTER * tau)) * (error - ax.error_deg)
            ax.error_s = now
            correction = ax.error_deg / tau
        else:
            ax.error_deg, ax.error_s = math.nan, None
        cmd = rate + correction
        ax.rate_cmd_dps = cmd
        size, sign = abs(cmd), (1 if cmd > 0 else -1)
        w = ax.want
        if w == 0:
            w = sign if size > FF_CLOSE_DEG_S else 0
        elif w != sign or size < FF_OPEN_DEG_S:
            w = 0
        ax.want = w
        bus_v = self.hal.inputs.motor_supply_v
        bus_v = bus_v if math.isfinite(bus_v) and bus_v > 0.5 * self.drive.supply_v else None
        return w, min(self.drive.duty_for(size, bus_v), self.box.dial_duty(k))

    def _apply(self, ax: AxisState, target: int, now: float, dwell_s: float, chatter_s: float) -> None:
        """Move the relay towards `target` (not where it is): open at once; close only after the dwell;
        reverse through open."""
        if ax.relay != 0:
            self._set_relay(ax, 0, now)
            return
        if ax.changed_s is not None and now - ax.changed_s < dwell_s - 1e-9:
            return
        if ax.opened_s is not None and now - ax.opened_s < chatter_s:
            ax.chatter += 1
        if ax.last_closed and target != ax.last_closed:
            ax.reversals += 1
        ax.last_closed = target
        self._set_relay(ax, target, now)

    def _set_relay(self, ax: AxisState, relay: int, now: float) -> None:
        if relay == 0:
            ax.opened_s = now
        ax.relay = relay
        ax.changed_s = now
        ax.switchings += 1
