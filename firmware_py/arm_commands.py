"""The arm's commands: motions (Move, MoveBy, Jog, Home, Grip, Stop) and trajectories (TrajClear, TrajPoint,
TrajRun), beside the trajectory buffer they fill.

Every motion but Stop is refused unless the controller is ENABLED (`state` says which state it is in); an accepted
one is answered by MotionAccepted with the motions it started, and its end by a MotionDone event (the arm's
`on_motion_done`). Stop is accepted in any state. With a coordinated start (`sync`), TrajRun leads or arms the
start of another arm's controller too (firmware_py/trajectory_sync.py).
"""
from __future__ import annotations

import math
from typing import Callable, Optional

from protocol.messages import MESSAGES as M
from protocol.reasons import Reason
from protocol.schema import Message
from protocol.states import ARM_AXES, Axis, ControllerState, GripAction

from firmware_py.arm import ArmController, MotionStart
from firmware_py.handlers import CommandOwner, handles
from firmware_py.trajectory import TrajectoryBuffer, knot_of
from firmware_py.trajectory_sync import TrajectorySync


class ArmCommands(CommandOwner):
    """The commands of one arm (`arm`) and its trajectory buffer; `state()` is the controller's state now."""

    def __init__(self, arm: ArmController, state: Callable[[], ControllerState],
                 sync: Optional[TrajectorySync] = None) -> None:
        self.arm = arm
        self.trajectory = TrajectoryBuffer()
        self._state = state
        self.sync = sync             # a coordinated start with another arm's controller; None: TrajRun starts at once

    # ---- motion: refused unless ENABLED; MotionDone events report the end ----
    def _motion_refusal(self) -> Optional[Reason]:
        state = self._state()
        if state is ControllerState.ENABLED:
            return None
        return {ControllerState.ESTOP: Reason.ESTOP, ControllerState.FAULT: Reason.FAULT_LATCHED}.get(
            state, Reason.NOT_ALLOWED_IN_STATE)

    def _accepted(self, axis: int, start: MotionStart) -> Message:
        """MotionAccepted for `start`: every motion it started (by axis), or the refusal and the limit it broke."""
        reply = M["MotionAccepted"]
        ids = [start.started.get(int(a), 0) & 0xFFFFFFFF for a in ARM_AXES]
        motion_id = start.started.get(axis, 0) & 0xFFFFFFFF
        return reply(int(start.reason), axis, motion_id, *ids, start.limit, _finite(start.limit_value),
                     _finite(start.asked))

    def _joint_motion(self, msg: Message, start: Callable[[], MotionStart]) -> Message:
        refusal = self._motion_refusal()
        if refusal is not None or msg.axis == Axis.ALL:
            return self._accepted(msg.axis, MotionStart(refusal or Reason.OUT_OF_RANGE))
        return self._accepted(msg.axis, start())

    @handles("Move")
    def _move(self, msg: Message, now: float) -> Message:
        return self._joint_motion(msg, lambda: self.arm.move(msg.axis, msg.target, msg.speed, False, now))

    @handles("MoveBy")
    def _move_by(self, msg: Message, now: float) -> Message:
        return self._joint_motion(msg, lambda: self.arm.move(msg.axis, msg.distance, msg.speed, True, now))

    @handles("Jog")
    def _jog(self, msg: Message, now: float) -> Message:
        return self._joint_motion(msg, lambda: self.arm.jog(msg.axis, msg.speed, now))

    @handles("Home")
    def _home(self, msg: Message, now: float) -> Message:
        refusal = self._motion_refusal()
        if refusal is not None:
            return self._accepted(msg.axis, MotionStart(refusal))
        if msg.axis == Axis.ALL:
            return self._accepted(msg.axis, self.arm.home_all(now))
        return self._accepted(msg.axis, self.arm.home(msg.axis, now))

    @handles("Grip")
    def _grip(self, msg: Message, now: float) -> Message:
        refusal = self._motion_refusal()
        if refusal is not None:
            return self._accepted(int(Axis.GRIPPER), MotionStart(refusal))
        return self._accepted(int(Axis.GRIPPER), self.arm.grip(msg.action == GripAction.CLOSE, now))

    @handles("Stop")
    def _stop(self, msg: Message, now: float) -> Message:
        """Every axis decelerates at its limit and holds; accepted in any state. A coordinated trajectory stops on
        the other arm too (`TrajectorySync.stop`)."""
        if self.sync is not None:
            self.sync.stop(now)
        self.arm.stop_all(now)
        return M["Result"](int(Reason.OK))

    # ---- trajectories: knots into the buffer, then j1..j4 and the mount along them at once ----
    def _traj_state(self, reason: Reason) -> Message:
        buffer = self.trajectory
        return M["TrajState"](int(reason), len(buffer.knots), buffer.capacity, buffer.t_last_s,
                              self.arm.trajectory_running())

    @handles("TrajClear")
    def _traj_clear(self, msg: Message, now: float) -> Message:
        if self.arm.trajectory_running():
            return self._traj_state(Reason.BUSY)
        self.trajectory.clear()
        return self._traj_state(Reason.OK)

    @handles("TrajPoint")
    def _traj_point(self, msg: Message, now: float) -> Message:
        if self.arm.trajectory_running():
            return self._traj_state(Reason.BUSY)
        reason, _detail = self.trajectory.append(msg.index, knot_of(msg))
        return self._traj_state(reason)

    @handles("TrajRun")
    def _traj_run(self, msg: Message, now: float) -> Message:
        everyone = int(Axis.ALL)
        refusal = self._motion_refusal()
        if refusal is None:
            refusal = self.trajectory.check_count(msg.count)[0]
        if refusal is not Reason.OK:
            return self._accepted(everyone, MotionStart(refusal))
        profiles = self.trajectory.profiles()
        axis, start = (self.arm.run_trajectory(profiles, now) if self.sync is None
                       else self.sync.run(profiles, msg.count, now))
        return self._accepted(everyone if axis is None else axis, start)


def _finite(value: float) -> float:
    return value if math.isfinite(value) else 0.0
