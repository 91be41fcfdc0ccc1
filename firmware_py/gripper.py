"""The gripper: a push/pull motor on a lead screw, opened and closed against switches and current.

Unlike a joint it has no position loop: the report's gripper is a 27.5 VDC push/pull motor
(Key to Figure 9, part 64) that runs until something stops it. So:

* `open`: drive at `grip_duty` toward open until the open end switch closes. The switch is
  also the gripper's home: the opening is known from then on (`homed`).
* `close`: drive toward closed until the closed end switch closes (nothing between the jaws)
  or until the current reaches `grip_current_a` with the jaws still for `grip_confirm_s`
  (they close on an object): then hold at `grip_hold_duty`, which sets the grip force.
* Either taking longer than `grip_timeout_s` latches the GRIPPER fault bit.

Duty is positive toward open. `update` runs one tick and returns the duty, like `BankedAxis.update`.
"""
from __future__ import annotations

from typing import Callable, Optional

from firmware_py.arm_config import GripperModel
from firmware_py.axis import Refusal
from protocol.states import AxisMode, MotionOutcome
from firmware_py.estimator import unwrap_delta
from firmware_py.gripper_tick import (AT_CLOSED_SWITCH, AT_OPEN_SWITCH, CLOSE, GRIPPED, NO_COUNT, NONE, OPEN,
                                      TIMED_OUT, moving_tick, track)

GRIPPER_TIMEOUT = 1 << 0          # the gripper's one fault bit (mapped to Fault.GRIPPER)


class Gripper:
    def __init__(self, model: GripperModel, on_fault: Callable[[int, float], None] = lambda bits, now: None) -> None:
        self.model = model
        self._m_per_count = model.m_per_count     # the model's, computed once (the tick reads it twice)
        self._on_fault = on_fault
        self.mode = AxisMode.IDLE
        self.duty = 0.0
        self.brake = True              # "not driven" on the bus (the gripper has no brake; its screw holds)
        self.homed = False
        self.gripped = False
        self.motion_id = 0
        self.outcome = MotionOutcome.NONE
        self.faults = 0
        self.grip_duty = 0.8
        self.hold_duty = 0.3
        self.grip_current_a = 0.6
        self.timeout_s = 5.0
        self._direction = 0
        self._started_s = 0.0
        self._still_since = NONE         # the jaws still at grip current since (NONE: not)
        self._last_count = NO_COUNT      # the count at the last tick of a move
        self._ref_count = 0            # count at which the opening was `_ref_m`
        self._ref_m = 0.0
        self.opening_m = 0.0
        self.vel_m_s = 0.0
        self._vel_count: Optional[int] = None
        self._vel_s = 0.0

    # ---- commands ----
    def enable(self, now: float) -> tuple[Refusal, str]:
        if self.mode is AxisMode.FAULT:
            return Refusal.FAULT, "gripper: fault latched; reset first"
        if self.mode is AxisMode.IDLE:
            self.mode = AxisMode.HOLDING
            self.brake = False
        return Refusal.OK, ""

    def open(self, now: float) -> tuple[Refusal, str]:
        return self._start(OPEN, now)

    def close(self, now: float) -> tuple[Refusal, str]:
        return self._start(CLOSE, now)

    def stop(self, now: float) -> None:
        if self.mode is AxisMode.MOVING:
            self._finish(MotionOutcome.STOPPED)

    def safe(self) -> None:
        self.duty = 0.0
        self.brake = True
        self._direction = 0
        if self.outcome is MotionOutcome.RUNNING:
            self.outcome = MotionOutcome.FAULT if self.faults else MotionOutcome.DISABLED
        if self.mode is not AxisMode.FAULT:
            self.mode = AxisMode.IDLE

    def disable(self, now: float) -> None:
        self.safe()

    def reset_errors(self, now: float) -> None:
        self.faults = 0
        if self.mode is AxisMode.FAULT:
            self.mode = AxisMode.IDLE

    # ---- the tick ----
    def may_fault(self, now: float) -> bool:
        """Whether this tick's `update` could latch the timeout (the one way it reaches the other channels)."""
        return self.mode is AxisMode.MOVING and now - self._started_s > self.timeout_s

    def update(self, now: float, count: int, i_a: float, closed_switch: bool, open_switch: bool) -> float:
        self._track(now, count)
        if self.mode is AxisMode.HOLDING:
            self.duty = -self.hold_duty if self.gripped else 0.0
            return self.duty
        if self.mode is not AxisMode.MOVING:
            self.duty = 0.0
            return 0.0
        ended, self._still_since, self._last_count, duty = moving_tick(
            now, count, i_a, closed_switch, open_switch, self._direction, self._started_s, self._still_since,
            self._last_count, self.grip_current_a, self.grip_duty, self.timeout_s)
        if ended == AT_OPEN_SWITCH:
            self._ref_count, self._ref_m = count, self.model.open_switch_m
            self.opening_m = self._ref_m
            self.homed = True
            self._finish(MotionOutcome.DONE)
            return 0.0
        if ended == AT_CLOSED_SWITCH:
            self._finish(MotionOutcome.DONE)
            return 0.0
        if ended == GRIPPED:
            self.gripped = True
            self._finish(MotionOutcome.DONE)
            return self.duty
        if ended == TIMED_OUT:
            self.faults |= GRIPPER_TIMEOUT
            self.outcome = MotionOutcome.FAULT
            self.mode = AxisMode.FAULT
            self.safe()
            self._on_fault(GRIPPER_TIMEOUT, now)
            return 0.0
        self.duty = duty
        return duty

    # ---- helpers ----
    def _start(self, direction: int, now: float) -> tuple[Refusal, str]:
        if self.mode is AxisMode.FAULT:
            return Refusal.FAULT, "gripper: fault latched; reset first"
        if self.mode is AxisMode.IDLE:
            return Refusal.NOT_ENABLED, "gripper: not enabled"
        self.mode = AxisMode.MOVING
        self._direction = direction
        self._started_s = now
        self._still_since = NONE
        self._last_count = NO_COUNT
        self.gripped = False
        self.motion_id += 1
        self.outcome = MotionOutcome.RUNNING
        return Refusal.OK, ""

    def _finish(self, outcome: MotionOutcome) -> None:
        self.mode = AxisMode.HOLDING
        self._direction = 0
        self.outcome = outcome
        self.duty = -self.hold_duty if self.gripped else 0.0

    def _track(self, now: float, count: int) -> None:
        """Opening from counts (relative to the last open-switch reference), velocity over 20 ms (`track`)."""
        if self._vel_count is None:
            self.opening_m = self._ref_m + unwrap_delta(count, self._ref_count) * self._m_per_count
            self._vel_count, self._vel_s = count, now
            return
        self.opening_m, self.vel_m_s, self._vel_count, self._vel_s = track(
            now, count, self._ref_count, self._ref_m, self._m_per_count, self.vel_m_s, self._vel_count, self._vel_s)

