"""Homing one axis on its switch: seek the switch at `home_vel_rad_s`, call that angle `home_pos_rad`,
back off `home_backoff_rad` and hold; an axis that starts on its switch leaves it first. No switch within
`home_max_travel_rad` of the start: HOMING_FAILED. Used by `firmware_py/axis.py`'s `Axis`.

Design: docs/arm.md#motion-commands
"""
from __future__ import annotations

import math
from typing import Optional

from firmware_py import profiles
from firmware_py.joints_tick import (HOME_BACKOFF, HOME_CLEAR, HOME_SEEK, HOME_START, HOMING_BACKED_OFF,
                                     HOMING_FAILED, HOMING_FOUND, HOMING_OFF_SWITCH, HOMING_ON_SWITCH)
from protocol.states import AxisMode, MotionOutcome

# homing phases: first tick (is the switch already closed?), leave the switch, seek it, back off
START, CLEAR, SEEK, BACKOFF = HOME_START, HOME_CLEAR, HOME_SEEK, HOME_BACKOFF
# the tick's decisions while homing: firmware_py/joints_tick.py's MOTION values HOMING_*


class Homing:
    """One axis's homing phases. `begin` starts the seek; `act` acts on the tick's decision at a phase's end."""

    def __init__(self, axis) -> None:
        self.axis = axis
        self.phase = SEEK
        self.start_rad = 0.0

    def begin(self, now: float) -> None:
        """Remember where homing starts (for `home_max_travel_rad`) and seek the switch."""
        self.start_rad = self.axis.estimator.pos_rad
        self.phase = START
        self.seek(now, self.axis.config.home_dir)

    def act(self, motion: int, now: float, pos_sp: float, vel_sp: float,
            acc_sp: float) -> Optional[tuple[float, float, float]]:
        """The tick's decision `motion` while the axis is HOMING (the phase's checks are the tick's:
        firmware_py/joints_tick.py): the setpoint to follow; None when the switch has not come within
        `home_max_travel_rad` (the axis faults HOMING_FAILED)."""
        axis = self.axis
        c = axis.config
        if motion == HOMING_BACKED_OFF:
            axis._hold(axis._profile.end_pos_rad)
            axis.outcome = MotionOutcome.DONE
        elif motion == HOMING_FAILED:
            return None
        elif motion == HOMING_ON_SWITCH:   # already on the switch: move off it first, then come back to it
            self.phase = CLEAR
            self.seek(now, -c.home_dir, pos_sp, vel_sp)
            return axis._profile.sample(0.0)
        elif motion == HOMING_OFF_SWITCH:
            self.seek(now, c.home_dir, pos_sp, vel_sp)
            self.phase = SEEK
            return axis._profile.sample(0.0)
        elif motion == HOMING_FOUND:       # found it: this is home_pos_rad; stop and back off from the switch
            shift = axis._rezero(c.home_pos_rad)
            axis.homed = True
            back = c.home_pos_rad - c.home_dir * c.home_backoff_rad
            axis._profile = profiles.trapezoid(pos_sp + shift, back, c.vel_limit_rad_s, c.acc_limit_rad_s2, vel_sp)
            axis._profile_t0 = now
            axis.target_rad = back
            self.phase = BACKOFF
            return axis._profile.sample(0.0)
        return pos_sp, vel_sp, acc_sp

    def seek(self, now: float, direction: int, pos_sp: Optional[float] = None,
             vel_sp: float = 0.0) -> None:
        """Jog towards the switch (`direction` = home_dir) or off it, from `pos_sp` (None: the present setpoint)."""
        axis = self.axis
        if pos_sp is None:
            pos_sp, vel_sp, _ = axis._setpoint(now)
        axis._profile = profiles.jog(pos_sp, direction * axis.config.home_vel_rad_s, axis.config.acc_limit_rad_s2,
                                     vel_sp)
        axis._profile_t0 = now
        axis.mode = AxisMode.HOMING
        axis.target_rad = math.nan
