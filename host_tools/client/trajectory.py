"""Sending a planned trajectory to the controller: clear its buffer, upload every knot, run it.

`send_trajectory(client, knots)` works with any client that has `call(msg) -> CommandHandle` (`HostClient`
live, `BenchClient` on the simulated clock, a `LockstepBench` itself). Knots are checked here first (four
joints, finite values, the first at t = 0, times increasing, within the message's declared ranges), so a
bad trajectory is refused before anything is sent; what the controller refuses raises `TrajectoryRefused`
with its reason, the command and, for a knot, its index. The motions end with one MotionDone per joint,
carrying the ids returned.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, Sequence

from protocol.host_link import CommandHandle
from protocol.messages import MESSAGES as M, SCHEMA, TRAJECTORY_JOINTS
from protocol.reasons import Reason
from protocol.schema import Message

JOINTS = len(TRAJECTORY_JOINTS)     # j1..j4 and the mount


class Caller(Protocol):
    def call(self, msg: Message, timeout_s: float = 30.0) -> CommandHandle: ...


@dataclass(frozen=True)
class Knot:
    """One knot: its time from the start [s], and j1..j4's and the mount's positions [deg] and
    velocities [deg/s]."""

    t_s: float
    q_deg: tuple[float, ...]
    qd_deg_s: tuple[float, ...]

    def __post_init__(self) -> None:
        if len(self.q_deg) != JOINTS or len(self.qd_deg_s) != JOINTS:
            raise ValueError(f"a knot has {JOINTS} positions and {JOINTS} velocities (j1..j4, mount), not "
                             f"{len(self.q_deg)} and {len(self.qd_deg_s)}")
        if not all(math.isfinite(v) for v in (self.t_s, *self.q_deg, *self.qd_deg_s)):
            raise ValueError(f"a knot's time, positions and velocities must be finite: {self}")


class TrajectoryRefused(Exception):
    """The controller refused a trajectory command: `reason` its code, `command` which, `index` the knot (or None)."""

    def __init__(self, reason: Reason, command: str, detail: str, index: int | None = None) -> None:
        where = f"{command} {index}" if index is not None else command
        super().__init__(f"{where}: {detail}")
        self.reason, self.command, self.index = reason, command, index


def point_message(index: int, knot: Knot) -> Message:
    """The TrajPoint carrying `knot` as knot `index` (ValueError for a value its fields cannot carry)."""
    values = [v for j in range(JOINTS) for v in (knot.q_deg[j], knot.qd_deg_s[j])]
    msg = M["TrajPoint"](index, knot.t_s, *values)
    for fld, value in zip(SCHEMA["TrajPoint"].fields, msg):
        problem = fld.check(value)
        if problem is not None:
            raise ValueError(f"knot {index}: {problem}")
    return msg


def send_trajectory(client: Caller, knots: Sequence[Knot]) -> list[int]:
    """Clear the controller's buffer, upload `knots`, run them: j1..j4's and the mount's motion ids (MotionDone
    carries them).
    ValueError for knots that cannot be a trajectory (nothing sent); TrajectoryRefused for the controller's no."""
    if len(knots) < 2:
        raise ValueError(f"a trajectory needs at least 2 knots, not {len(knots)}")
    if knots[0].t_s != 0.0 or any(b.t_s <= a.t_s for a, b in zip(knots, knots[1:])):
        raise ValueError("a trajectory's knots start at t = 0 s and their times increase strictly")
    messages = [point_message(index, knot) for index, knot in enumerate(knots)]
    _ok(client.call(M["TrajClear"]()), "TrajClear")
    for index, msg in enumerate(messages):
        _ok(client.call(msg), "TrajPoint", index)
    reply = _ok(client.call(M["TrajRun"](len(knots))), "TrajRun")
    return [getattr(reply, f"{a.name.lower()}_motion_id") for a in TRAJECTORY_JOINTS]


def _ok(handle: CommandHandle, command: str, index: int | None = None) -> Message:
    if not handle.ok:
        detail, reply = handle.describe(), handle.reply
        if reply is not None and getattr(reply, "limit", ""):
            detail += f" (limit {reply.limit} = {reply.limit_value:g}, asked {reply.asked:g})"
        raise TrajectoryRefused(Reason(handle.reason), command, detail, index)
    return handle.reply
