"""Sending a planned trajectory to the controller: clear its buffer, upload every knot, run it.

`send_trajectory(client, knots)` works with any client that has `call(msg) -> CommandHandle` (`HostClient`
live, `BenchClient` on the simulated clock, a `LockstepBench` itself). Knots are checked here first (four
joints, finite values, the first at t = 0, times increasing, within the message's declared ranges), so a
bad trajectory is refused before anything is sent; what the controller refuses raises `TrajectoryRefused`
with its reason, the command and, for a knot, its index. The motions end with one MotionDone per joint,
carrying the ids returned.

A trajectory file (`aspod plan --arm-to ... --output FILE`, teleop's `traj load FILE`) is JSON: `format`
"aspod-trajectory", `version` 1, `joints` (j1..j4, mount), `units`, what made it (`about`), and `knots`, each
`{"t": s, "q": [deg...], "qd": [deg/s...]}`. `load_trajectory` reads it bounded and checks it as
`send_trajectory` would, saying what is wrong and where.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, Sequence

from firmware_py.trajectory import TRAJECTORY_KNOTS
from host_tools.outputs import Kind, begins
from protocol import files
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
    upload_trajectory(client, knots)
    return run_trajectory(client, len(knots))


def run_trajectory(client: Caller, count: int) -> list[int]:
    """TrajRun of the `count` knots uploaded: j1..j4's and the mount's motion ids; TrajectoryRefused for the
    controller's no. A controller that follows another's start (two arms) arms them here: they start on its
    leader's tick (firmware_py/trajectory_sync.py)."""
    reply = _ok(client.call(M["TrajRun"](count)), "TrajRun")
    return [getattr(reply, f"{a.name.lower()}_motion_id") for a in TRAJECTORY_JOINTS]


def upload_trajectory(client: Caller, knots: Sequence[Knot]) -> None:
    """Clear the controller's buffer and upload `knots` (TrajRun with their count starts them); ValueError for a
    knot a TrajPoint cannot carry (nothing sent), TrajectoryRefused for the controller's no."""
    messages = [point_message(index, knot) for index, knot in enumerate(knots)]
    _ok(client.call(M["TrajClear"]()), "TrajClear")
    for index, msg in enumerate(messages):
        _ok(client.call(msg), "TrajPoint", index)


def _ok(handle: CommandHandle, command: str, index: int | None = None) -> Message:
    if not handle.ok:
        detail, reply = handle.describe(), handle.reply
        if reply is not None and getattr(reply, "limit", ""):
            detail += f" (limit {reply.limit} = {reply.limit_value:g}, asked {reply.asked:g})"
        raise TrajectoryRefused(Reason(handle.reason), command, detail, index)
    return handle.reply


FILE_FORMAT = "aspod-trajectory"
FILE_VERSION = 1
TRAJECTORY_FILE = Kind("a trajectory file of aspod plan's (it begins `{\"format\": \"aspod-trajectory\"`)",
                       begins(b'{"format": "aspod-trajectory"'))
FILE_LIMIT = 1 * files.MIB            # a full buffer of knots is tens of KiB


def trajectory_json(knots: Sequence[Knot], about: dict[str, Any]) -> str:
    """The file's text: its kind first (an existing file is known as one by how it begins), then the knots."""
    names = [a.name.lower() for a in TRAJECTORY_JOINTS]
    head = {"format": FILE_FORMAT, "version": FILE_VERSION, "joints": names,
            "units": {"t": "s", "q": "deg", "qd": "deg/s"}, "about": about}
    rows = ",\n".join("    " + json.dumps({"t": k.t_s, "q": list(k.q_deg), "qd": list(k.qd_deg_s)}) for k in knots)
    return json.dumps(head)[:-1] + ', "knots": [\n' + rows + "\n]}\n"


def load_trajectory(path: Path | str) -> list[Knot]:
    """The knots of a trajectory file; ValueError (files.InputFileError for an unreadable file) saying what is
    wrong: not one of ours, another version, a knot that is not one (which, and why), times not increasing."""
    data = files.read_bounded(path, FILE_LIMIT)
    try:
        doc = json.loads(data)
    except (UnicodeDecodeError, ValueError) as exc:
        raise ValueError(f"{path}: not a trajectory file: not JSON ({exc})") from None
    if not isinstance(doc, dict) or doc.get("format") != FILE_FORMAT:
        raise ValueError(f"{path}: not a trajectory file (its format is not {FILE_FORMAT!r}; aspod plan --arm-to "
                         "... --output writes one)")
    if doc.get("version") != FILE_VERSION:
        raise ValueError(f"{path}: trajectory file version {doc.get('version')!r}; this aspod reads {FILE_VERSION}")
    names = [a.name.lower() for a in TRAJECTORY_JOINTS]
    if doc.get("joints") != names:
        raise ValueError(f"{path}: its joints are {doc.get('joints')!r}; a trajectory moves {names}")
    rows = doc.get("knots")
    if not isinstance(rows, list) or not 2 <= len(rows) <= TRAJECTORY_KNOTS:
        raise ValueError(f"{path}: `knots` must be a list of 2 to {TRAJECTORY_KNOTS} knots")
    knots = []
    for index, row in enumerate(rows):
        try:
            if not isinstance(row, dict) or set(row) != {"t", "q", "qd"}:
                raise ValueError("a knot is {\"t\": s, \"q\": [deg x5], \"qd\": [deg/s x5]}")
            values = [row["t"], *row["q"], *row["qd"]]
            if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values):
                raise ValueError("its values must be numbers")
            knot = Knot(float(row["t"]), tuple(map(float, row["q"])), tuple(map(float, row["qd"])))
            point_message(index, knot)                 # within the message's declared ranges
        except (ValueError, TypeError) as exc:
            raise ValueError(f"{path}: knot {index}: {exc}") from None
        knots.append(knot)
    if knots[0].t_s != 0.0 or any(b.t_s <= a.t_s for a, b in zip(knots, knots[1:])):
        raise ValueError(f"{path}: a trajectory's knots start at t = 0 s and their times increase strictly")
    return knots
