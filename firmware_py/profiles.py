"""Motion profiles: piecewise constant-acceleration setpoints within speed and acceleration limits.

A profile is a short list of segments, each starting at a time with a position, a velocity and
a constant acceleration. `sample(t_s)` gives `(pos_rad, vel_rad_s, acc_rad_s2)` at `t_s` seconds
after the profile's start; before 0 it gives the start, at and after `duration_s` the exact end
(the end position is stored, not integrated, so endpoints are exact).

* `trapezoid(...)`: a move to a target from any present state (position, velocity): accelerate,
  cruise at the speed limit, decelerate; triangular when the move is too short to reach the
  speed limit. If the present velocity points away from the target, or is too high to stop in
  time, it first stops at the acceleration limit and then moves back (so a new command during a
  move blends from the present setpoint without a jump). `relative` moves are the caller's sum.
* `jog(...)`: ramp to a constant velocity and hold it forever (`duration_s` is infinite) until
  replaced by `stop(...)`.
* `stop(...)`: decelerate to rest at the acceleration limit.

A trajectory's setpoint, a cubic through given positions and velocities, is `hermite.HermiteProfile`
(the same interface). S-curves (jerk-limited) are not implemented: at the report's joint speeds (1/2 RPM) the
trapezoid's acceleration steps are far below anything that excites the links, and the
velocity loop smooths them further.
"""
from __future__ import annotations

import math
from typing import NamedTuple

from firmware_py.joints_tick import sample_profile, stopping_distance

# The report (DEFLECTION AND MOMENT ANALYSIS, Figure 7 and APPENDIX B, ACCELERATION ANALYSIS)
# keeps joint speed at or below 1/2 RPM so torques stay static, and the inertial term of the Lagrangian
# stays orders of magnitude below the gravity term on Earth. (Its "30 seconds" for a half turn does not fit
# 1/2 RPM, which takes 60 s: docs/fidelity.md, S2.)
REPORT_JOINT_SPEED_RAD_S = 0.5 * 2.0 * math.pi / 60.0   # 1/2 RPM = pi/60 rad/s

# Reaches the report's speed in about a second. The inertial torque it asks for stays in the
# report's "static" regime: even the shoulder's whole arm (a few kg m^2 about J1) needs well
# under 1 N m at 0.05 rad/s^2, against tens of N m of gravity torque on Earth.
DEFAULT_JOINT_ACC_RAD_S2 = 0.05

INFINITY = math.inf


class Segment(NamedTuple):
    t0_s: float
    pos_rad: float
    vel_rad_s: float
    acc_rad_s2: float


class Profile:
    """A sequence of constant-acceleration segments ending at rest at `end_pos_rad`
    (or, for a jog, cruising forever)."""

    constant_acceleration = True      # the joints' compiled tick evaluates it (firmware_py/joints_tick.py)
    __slots__ = ("segments", "duration_s", "end_pos_rad", "end_vel_rad_s", "_row")

    def __init__(self, segments: list[Segment], duration_s: float, end_pos_rad: float,
                 end_vel_rad_s: float = 0.0) -> None:
        if not segments:
            segments = [Segment(0.0, end_pos_rad, end_vel_rad_s, 0.0)]
        self.segments = segments
        self.duration_s = duration_s
        self.end_pos_rad = end_pos_rad
        self.end_vel_rad_s = end_vel_rad_s
        # the joints' tick's profile row (firmware_py/joints_tick.py: the end, then the segments), which `sample`
        # evaluates as the tick does
        self._row = [duration_s, end_pos_rad, end_vel_rad_s, *(x for segment in segments for x in segment)]

    @property
    def start(self) -> Segment:
        return self.segments[0]

    def sample(self, t_s: float) -> tuple[float, float, float]:
        """(pos_rad, vel_rad_s, acc_rad_s2) at `t_s` seconds after the start (`joints_tick.sample_profile`, as the
        joints' tick samples it)."""
        return sample_profile(self._row, len(self.segments), t_s)

    def max_abs(self) -> tuple[float, float]:
        """Largest |velocity| and |acceleration| over the profile (at segment ends, where they peak)."""
        vmax = abs(self.end_vel_rad_s)
        amax = 0.0
        bounds = [s.t0_s for s in self.segments[1:]] + [self.duration_s]
        for seg, t1 in zip(self.segments, bounds):
            amax = max(amax, abs(seg.acc_rad_s2))
            vmax = max(vmax, abs(seg.vel_rad_s))
            if math.isfinite(t1):
                vmax = max(vmax, abs(seg.vel_rad_s + seg.acc_rad_s2 * (t1 - seg.t0_s)))
        return vmax, amax


def _check_limits(vel_max_rad_s: float, acc_max_rad_s2: float) -> None:
    if not (math.isfinite(vel_max_rad_s) and vel_max_rad_s > 0):
        raise ValueError(f"speed limit must be finite and > 0, not {vel_max_rad_s}")
    if not (math.isfinite(acc_max_rad_s2) and acc_max_rad_s2 > 0):
        raise ValueError(f"acceleration limit must be finite and > 0, not {acc_max_rad_s2}")


class _Builder:
    """Appends constant-acceleration segments, tracking time, position and velocity."""

    def __init__(self, pos_rad: float, vel_rad_s: float) -> None:
        self.t = 0.0
        self.p = float(pos_rad)
        self.v = float(vel_rad_s)
        self.segments: list[Segment] = []

    def add(self, acc: float, duration_s: float) -> None:
        if duration_s <= 0.0:
            return
        self.segments.append(Segment(self.t, self.p, self.v, acc))
        self.p += duration_s * (self.v + 0.5 * acc * duration_s)
        self.v += acc * duration_s
        self.t += duration_s

    def add_ramp_to(self, vel_rad_s: float, acc_max: float) -> None:
        """Change velocity to `vel_rad_s` at the acceleration limit."""
        dv = vel_rad_s - self.v
        if dv:
            self.add(math.copysign(acc_max, dv), abs(dv) / acc_max)
        self.v = vel_rad_s   # exact, not accumulated


def trapezoid(pos_rad: float, target_rad: float, vel_max_rad_s: float = REPORT_JOINT_SPEED_RAD_S,
              acc_max_rad_s2: float = DEFAULT_JOINT_ACC_RAD_S2, vel_rad_s: float = 0.0) -> Profile:
    """Move from (`pos_rad`, `vel_rad_s`) to rest at `target_rad` within the limits."""
    _check_limits(vel_max_rad_s, acc_max_rad_s2)
    for name, value in (("pos_rad", pos_rad), ("target_rad", target_rad), ("vel_rad_s", vel_rad_s)):
        if not math.isfinite(value):
            raise ValueError(f"{name} must be finite, not {value}")
    a = acc_max_rad_s2
    b = _Builder(pos_rad, vel_rad_s)
    distance = target_rad - pos_rad
    direction = 1.0 if distance > 0 else -1.0
    stop_distance = vel_rad_s * abs(vel_rad_s) / (2 * a)     # signed
    if vel_rad_s * direction < 0 or abs(stop_distance) > abs(distance) or distance == 0.0:
        b.add_ramp_to(0.0, a)                                 # stop first, then move from rest
        distance = target_rad - b.p
        direction = 1.0 if distance > 0 else -1.0
    remaining = abs(distance)
    if remaining > 0.0:
        u0 = abs(b.v)   # toward the target, and stoppable in time
        peak = math.sqrt((2 * a * remaining + u0 * u0) / 2)
        if peak <= vel_max_rad_s and u0 <= vel_max_rad_s:
            b.add_ramp_to(direction * peak, a)                # triangular
        else:
            b.add_ramp_to(direction * vel_max_rad_s, a)
            cruise_rad = direction * (target_rad - b.p) - vel_max_rad_s ** 2 / (2 * a)
            b.add(0.0, max(0.0, cruise_rad / vel_max_rad_s))
        b.add_ramp_to(0.0, a)
    return Profile(b.segments, b.t, target_rad)


def jog(pos_rad: float, vel_target_rad_s: float, acc_max_rad_s2: float, vel_rad_s: float = 0.0) -> Profile:
    """Ramp from (`pos_rad`, `vel_rad_s`) to `vel_target_rad_s` and keep going (infinite duration)."""
    _check_limits(abs(vel_target_rad_s) or 1.0, acc_max_rad_s2)
    b = _Builder(pos_rad, vel_rad_s)
    b.add_ramp_to(vel_target_rad_s, acc_max_rad_s2)
    b.segments.append(Segment(b.t, b.p, b.v, 0.0))
    return Profile(b.segments, INFINITY, math.nan, vel_target_rad_s)


def stop(pos_rad: float, vel_rad_s: float, acc_max_rad_s2: float) -> Profile:
    """Decelerate from (`pos_rad`, `vel_rad_s`) to rest at the acceleration limit."""
    _check_limits(1.0, acc_max_rad_s2)
    b = _Builder(pos_rad, vel_rad_s)
    b.add_ramp_to(0.0, acc_max_rad_s2)
    return Profile(b.segments, b.t, b.p)


__all__ = ["DEFAULT_JOINT_ACC_RAD_S2", "INFINITY", "Profile", "REPORT_JOINT_SPEED_RAD_S", "Segment", "jog", "stop",
           "stopping_distance", "trapezoid"]
