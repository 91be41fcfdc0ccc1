"""Coordinated arms: two controllers start their trajectories on one plant tick (docs/two_arms.md).

Each arm has its own controller, and both follow the plant's ticks (PLANT_SYNC), the one clock they share. A
controller set to lead (`SyncRole.LEADER`) starts its trajectory on TrajRun `LEAD_TICKS` ticks ahead and says on
which tick (TRAJ_START on the HAL bus). A controller set to follow (`SyncRole.FOLLOWER`) takes TrajRun as the arming
of its trajectory: checked as TrajRun checks it and answered with its motions, each joint holding the first knot (a
Hermite curve before its start is its start, at rest); it starts on the tick the leader's TRAJ_START names. If none
comes within `ARMED_S`, or one names a tick already past, a tick past that wait (more than `LEAD_TICKS` beyond it)
or another knot count, or a joint of it no longer runs it (a Move of that joint meanwhile), its joints stop where
they hold (MotionDone STOPPED) and nothing has moved; so do a leader's when its bus refuses its TRAJ_START. A host
arms the followers first, then runs the leader.

Stopped together. While a coordinated trajectory is armed or runs, a Stop of either controller, its safe state
(EStop, a fault, Disable, the session's close) or a follower's start it cannot follow ends it on both arms: the
controller says so in a TRAJ_STOP (`stop`), which the plant relays to the other arm's bus, and both slow their
coordinated trajectories to rest along their curves from the tick it names (`SlowedProfile`: the hands stay on the
plan's path together; MotionDone STOPPED; a follower stopped within the leader's lead never starts), the other
sending none back. A controller takes only a relayed TRAJ_STOP (`relayed` 1), the plant relays only one
a controller sent (`relayed` 0): no stop circles, and a bus that gives a controller its own stop back does not stop a
later trajectory of its own.

With no role (the default) TrajRun starts at once, as a lone controller's does, and nothing here is built: the bus
carries no new frame.
"""
from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Optional, Sequence

from firmware_py.arm import ArmController, MotionStart
from firmware_py.hal import ControllerHal
from firmware_py.hermite import HermiteProfile
from protocol.reasons import Reason

LEAD_TICKS = 10          # the leader starts this many plant ticks after its TrajRun: its TRAJ_START's margin
ARMED_S = 10.0           # a follower's armed trajectory waits this long for the leader's start, then stops
STOP_S = 0.5             # a coordinated trajectory stopped slows to rest along its curve over this long (its clock)
TICK_MOD = 1 << 32       # PLANT_SYNC's tick wraps at 2**32


class SyncRole(enum.Enum):
    LEADER = "leader"
    FOLLOWER = "follower"


@dataclass
class _Armed:
    knots: int
    started: dict[int, int]          # channel -> the motion id the armed trajectory runs there
    deadline_s: float


class TrajectorySync:
    """One controller's part in a coordinated start: `run` in place of the arm's own start, `check` from a periodic
    task (a follower's wait ends)."""

    def __init__(self, role: SyncRole, hal: ControllerHal, arm: ArmController) -> None:
        self.role, self.hal, self.arm = role, hal, arm
        self.armed: Optional[_Armed] = None
        self.starts = 0              # trajectories started on a coordinated tick (led, or followed)
        self.unmatched = 0           # TRAJ_STARTs a follower could not follow (none armed, another count, too late or
                                     # too far ahead, a joint no longer running it)
        self.last_start_tick: Optional[int] = None
        self.coordinated: dict[int, int] = {}   # channel -> motion id of the coordinated trajectory armed or running
        self.stops_sent = 0          # TRAJ_STOPs sent: this arm's coordinated trajectory stopped, so the other's
        self.stopped_by_peer = 0     # coordinated trajectories stopped by the other arm's relayed TRAJ_STOP
        self._layout = hal.codec.layout("TRAJ_START", ("start_tick", "knots"))
        self._stop_layout = hal.on_frame("TRAJ_STOP", self._on_stop, ("stop_tick", "relayed"))
        if role is SyncRole.FOLLOWER:
            hal.on_frame("TRAJ_START", self._on_start, ("start_tick", "knots"))

    def run(self, profiles: Sequence[HermiteProfile], knots: int, now: float) -> tuple[Optional[int], MotionStart]:
        """TrajRun's start for this role: (the channel that refused, or None; the motions started)."""
        if self.hal.inputs.tick_s is None:
            return None, MotionStart(Reason.NOT_ALLOWED_IN_STATE, "no plant tick seen yet: nothing to start on")
        if self.role is SyncRole.LEADER:
            # counted on from the last PLANT_SYNC heard by the ticks gone since (frames lost, a late loop): a tick
            # already past would start the leader part-way along its trajectory, and its follower not at all
            tick = (self._tick_now(now) + LEAD_TICKS) % TICK_MOD
            axis, start = self.arm.run_trajectory(profiles, self._time_of(tick))
            if start.reason is not Reason.OK:
                return axis, start
            if not self.hal.send_frame(self._layout, [tick, knots]):
                # the bus refused it (counted in `bus_errors`): no follower hears the start, so none is made here
                # either; its joints stop where they hold, as a follower's do when no start comes
                self.arm.stop_trajectory(start.started, now)
                return axis, start
            self.starts += 1
            self.last_start_tick = tick
            self.coordinated = dict(start.started)
            return axis, start
        axis, start = self.arm.run_trajectory(profiles, now + 2 * ARMED_S)       # held at its start meanwhile
        if start.reason is Reason.OK:
            self.armed = _Armed(knots, dict(start.started), now + ARMED_S)
            self.coordinated = dict(start.started)
        return axis, start

    def stop(self, now: float) -> None:
        """This arm's coordinated trajectory, if one is armed or runs, is being stopped (Stop, the safe state): it
        slows to rest along its curve from this tick (a Stop's other joints then stop as they do; the safe state cuts
        them all), and the other arm's from the same tick (TRAJ_STOP). Called before the arm's own stop, while its
        joints still run it."""
        if self.arm.still_running(self.coordinated):
            tick = self._tick_now(now)
            if self.hal.send_frame(self._stop_layout, [tick, 0]):
                self.stops_sent += 1
            self.arm.slow_trajectory(self.coordinated, self._time_of(tick), STOP_S, now)
        self.coordinated = {}
        self.armed = None

    def _on_stop(self, values: list, now: float) -> None:
        """The other arm's coordinated trajectory stopped (relayed by the plant): this arm's slows to rest along its
        curve from the tick the other's did (`stop_tick`: at most a few ticks back, a jump of (ticks)^2 / (2 STOP_S)
        of its clock), MotionDone STOPPED as a Stop's."""
        tick, relayed = values
        if not relayed:
            return                   # not relayed: this controller's own, given back by its bus
        if self.arm.still_running(self.coordinated):
            from_s = self._time_of(int(tick)) if self.hal.inputs.tick_s is not None else now
            self.arm.slow_trajectory(self.coordinated, min(from_s, now), STOP_S, now)
            self.stopped_by_peer += 1
        self.coordinated = {}
        self.armed = None

    def _tick_now(self, now: float) -> int:
        """The plant tick of `now`: the last PLANT_SYNC's, counted on by the ticks gone since (as a leader's start)."""
        inputs = self.hal.inputs
        if inputs.tick_s is None:
            return inputs.tick
        return (inputs.tick + max(0, math.floor((now - inputs.tick_s) / inputs.tick_period_s))) % TICK_MOD

    def check(self, now: float) -> None:
        """A follower's armed trajectory that waited `ARMED_S` in vain stops."""
        if self.armed is not None and now >= self.armed.deadline_s:
            self._disarm(now)

    def _time_of(self, tick: int) -> float:
        """The controller's time of plant tick `tick`, from the last PLANT_SYNC (ticks apart, wrapping)."""
        inputs = self.hal.inputs
        ahead = (tick - inputs.tick) % TICK_MOD
        if ahead >= TICK_MOD // 2:
            ahead -= TICK_MOD
        return inputs.tick_s + ahead * inputs.tick_period_s

    def _on_start(self, values: list, now: float) -> None:
        armed, (tick, knots) = self.armed, values
        start_s = self._time_of(int(tick)) if self.hal.inputs.tick_s is not None else now - 1.0
        if (armed is None or knots != armed.knots or start_s < now or start_s > self._latest_start_s(armed)
                or not self.arm.retime_trajectory(armed.started, start_s)):
            # another trajectory's start, too late to start together, later than the wait allows, or a joint of it
            # moved on (a Move of one joint): none of it starts, not the rest alone where it was parked
            self.unmatched += 1
            self._disarm(now)
            return
        self.starts += 1
        self.last_start_tick = int(tick)
        self.armed = None

    def _latest_start_s(self, armed: _Armed) -> float:
        """The latest start a follower takes: a leader's TRAJ_START heard by the end of the wait names a tick at most
        `LEAD_TICKS` later; one further off would keep the joints armed past `ARMED_S` (a third node's, say)."""
        return armed.deadline_s + LEAD_TICKS * self.hal.inputs.tick_period_s

    def _disarm(self, now: float) -> None:
        """The armed trajectory stops where it holds, and the leader's, if it started one this arm cannot follow."""
        if self.armed is not None:
            started = self.armed.started
            self.stop(now)
            self.arm.stop_trajectory(started, now)
