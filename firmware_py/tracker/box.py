"""The solar tracker's control box: its switches and dial, the interlocks on them, the temperature watch.

Design: docs/tracker.md#the-control-box
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from protocol.reasons import Reason
from protocol.states import (AZ, EL, SWITCH_POSITIONS, TRACKER_AXES, Switch, SwitchPosition, TempSide, TrackerAxis,
                             TrackerWarning)

ADC_COUNTS = 1023                # the dial's 10-bit ADC: 0..1023
TEMP_WARN_HYST_C = 0.5           # a temperature warning clears this far back inside its band

_TEMP_LOW, _TEMP_HIGH = int(TrackerWarning.TEMP_LOW), int(TrackerWarning.TEMP_HIGH)

ON, OFF, BRAKE = SwitchPosition.ON, SwitchPosition.OFF, SwitchPosition.BRAKE
MANUAL, SENSOR, CW, CCW = SwitchPosition.MANUAL, SwitchPosition.SENSOR, SwitchPosition.CW, SwitchPosition.CCW


def quantize_dial(pct: float) -> int:
    """ADC counts (0..1023) of a dial setting in percent (0..100), as the box's 10-bit ADC reads it."""
    return max(0, min(ADC_COUNTS, round(pct / 100.0 * ADC_COUNTS)))


@dataclass
class Box:
    """The control box's switches and dials (per axis where it has one per axis)."""

    main: SwitchPosition = OFF
    sensor: SwitchPosition = OFF
    mode: list = field(default_factory=lambda: [MANUAL, MANUAL])
    direction: list = field(default_factory=lambda: [CW, CW])
    speed: list = field(default_factory=lambda: [BRAKE, BRAKE])
    dial_counts: list = field(default_factory=lambda: [0, 0])

    def dial_pct(self, k: int) -> float:
        return self.dial_counts[k] * 100.0 / ADC_COUNTS

    def dial_duty(self, k: int) -> float:
        return self.dial_counts[k] / ADC_COUNTS


class TempWatch:
    """Warnings near the edges of the control box's allowed temperature range, once per crossing."""

    def __init__(self) -> None:
        self.active = {TempSide.COLD: False, TempSide.HOT: False}
        self._judged: tuple = ()      # the last reading and limits judged: the same again has no crossing

    @property
    def flags(self) -> TrackerWarning:
        return TrackerWarning(self.bits)

    @property
    def bits(self) -> int:
        """`flags` as a plain int."""
        return (_TEMP_LOW if self.active[TempSide.COLD] else 0) | (_TEMP_HIGH if self.active[TempSide.HOT] else 0)

    def update(self, temp_c: float, min_c: float, max_c: float, margin_c: float
               ) -> list[tuple[TempSide, bool, float]]:
        """The crossings at this reading: (side, now active, the fault limit it is about). NaN: none.

        The health task asks at every run (100 Hz) and the reading comes every 10 ms, mostly the same: the same
        reading and limits as the last time cannot cross again (that call left each side as they say), so they
        are not judged again."""
        if not math.isfinite(temp_c):
            return []
        judged = (temp_c, min_c, max_c, margin_c)
        if judged == self._judged:
            return []
        self._judged = judged
        crossings = []
        for side, limit, near, back in (
                (TempSide.COLD, min_c, temp_c <= min_c + margin_c, temp_c > min_c + margin_c + TEMP_WARN_HYST_C),
                (TempSide.HOT, max_c, temp_c >= max_c - margin_c, temp_c < max_c - margin_c - TEMP_WARN_HYST_C)):
            if not self.active[side] and near:
                self.active[side] = True
                crossings.append((side, True, limit))
            elif self.active[side] and back:
                self.active[side] = False
                crossings.append((side, False, limit))
        return crossings


class BoxCommands:
    """The box's commands and interlocks, for `TrackerController` (needs `box`, `params`, `refusals`)."""

    def _dial_low(self, k: int) -> bool:
        return self.box.dial_pct(k) <= self.params["trk_dial_low_pct"] + 1e-9

    def _refuse_high(self, ks: list[int], what: str) -> tuple[Reason, str]:
        self.refusals += 1
        dials = ", ".join(f"{TRACKER_AXES[k]} {self.box.dial_pct(k):.1f} %" for k in ks)
        return Reason.DIAL_NOT_LOW, (f"{what} needs the dial low (<= {self.params['trk_dial_low_pct']:g} %): "
                                     f"dial {dials}")

    def switch(self, switch: int, position: int, axis: int = TrackerAxis.BOTH) -> tuple[Reason, str]:
        """Set one of the box's switches; refused (nothing changes) by the interlocks or a bad position."""
        try:
            sw, pos, axis = Switch(switch), SwitchPosition(position), TrackerAxis(axis)
        except ValueError:
            return Reason.OUT_OF_RANGE, f"no switch {switch}, position {position} or axis {axis}"
        if pos not in SWITCH_POSITIONS[sw]:
            allowed = " or ".join(p.name.lower() for p in SWITCH_POSITIONS[sw])
            return Reason.SWITCH_POSITION, f"the {sw.name.lower()} switch is {allowed}, not {pos.name.lower()}"
        box = self.box
        if sw in (Switch.MAIN, Switch.SENSOR):
            if axis is not TrackerAxis.BOTH:
                return Reason.OUT_OF_RANGE, f"{sw.name.lower()} power is one switch for both axes"
            if sw is Switch.MAIN:
                if pos is ON and box.main is not ON:
                    high = [k for k in (AZ, EL) if box.speed[k] is ON and not self._dial_low(k)]
                    if high:
                        return self._refuse_high(high, "main power on with the speed switch on")
                box.main = pos
            else:
                box.sensor = pos
            return Reason.OK, ""
        ks = [AZ, EL] if axis is TrackerAxis.BOTH else [int(axis)]
        setting = {Switch.MODE: box.mode, Switch.DIRECTION: box.direction, Switch.SPEED: box.speed}[sw]
        changing = [k for k in ks if setting[k] is not pos]
        if sw is not Switch.SPEED or pos is ON:          # speed to brake is always allowed
            high = [k for k in changing if not self._dial_low(k)]
            if high:
                what = {Switch.MODE: "changing mode", Switch.DIRECTION: "changing direction",
                        Switch.SPEED: "starting (speed switch on)"}[sw]
                return self._refuse_high(high, what)
        for k in ks:
            setting[k] = pos
        return Reason.OK, ""

    def dial(self, pct: float, axis: int = TrackerAxis.BOTH) -> tuple[Reason, str]:
        """Turn the speed dial (0..100 %); read as a 10-bit ADC would read it. Never interlocked."""
        if not (isinstance(pct, (int, float)) and math.isfinite(pct) and 0.0 <= pct <= 100.0):
            return Reason.OUT_OF_RANGE, f"dial {pct!r} outside 0..100 %"
        try:
            axis = TrackerAxis(axis)
        except ValueError:
            return Reason.OUT_OF_RANGE, f"no axis {axis}"
        counts = quantize_dial(pct)
        for k in ([AZ, EL] if axis is TrackerAxis.BOTH else [int(axis)]):
            self.box.dial_counts[k] = counts
        return Reason.OK, ""
