"""Sending a planned trajectory to the controller: clear its buffer, upload every knot, run it.

`send_trajectory(client, knots)` works with any client that has `call(msg) -> CommandHandle` (`HostClient`
live, `BenchClient` on the simulated clock, a `LockstepBench` itself). Knots are checked here first (four
joints, finite values, the first at t = 0, times increasing, within the message's declared ranges), so a
bad trajectory is refused before anything is sent; what the controller refuses raises `TrajectoryRefused`
with its reason, the command and, for a knot, its index. The motions end with one MotionDone per joint,
carrying the ids returned.

A trajectory file (`aspod plan ... --output FILE`, teleop's `traj load FILE`) is JSON: `format`
"aspod-trajectory", `version`, `joints` (j1..j4, mount), `units`, what made it (`about`), and the knots, each
`{"t": s, "q": [deg...], "qd": [deg/s...]}`: version 1 (one arm, `aspod plan --arm-to`) has them in `knots`; version 2
(two arms, the two-arm plan) in `arms`, `[{"knots": [...]}, {"knots": [...]}]`, arm 1's first, and an older aspod
refuses it by its version. `load_trajectory(path, arm)` reads one arm's, bounded, and checks them (and the other
arm's) as `send_trajectory` would, saying what is wrong and where.
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
    """The controller refused a trajectory command: `reason` its code, `command` which, `index` the knot (or None);
    `answered`: the controller's own reply said so (False: the link failed, and the command may have run)."""

    def __init__(self, reason: Reason, command: str, detail: str, index: int | None = None,
                 answered: bool = True) -> None:
        where = f"{command} {index}" if index is not None else command
        super().__init__(f"{where}: {detail}")
        self.reason, self.command, self.index, self.answered = reason, command, index, answered


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
        raise TrajectoryRefused(Reason(handle.reason), command, detail, index, answered=reply is not None)
    return handle.reply


FILE_FORMAT = "aspod-trajectory"
ONE_ARM_VERSION = 1                   # `knots`
TWO_ARM_VERSION = 2                   # `arms`: each arm's `knots`
FILE_ARMS = 2                         # arms in a version-2 file
TRAJECTORY_FILE = Kind("a trajectory file of aspod plan's (it begins `{\"format\": \"aspod-trajectory\"`)",
                       begins(b'{"format": "aspod-trajectory"'))
FILE_LIMIT = 1 * files.MIB            # a full buffer of knots is tens of KiB


def trajectory_json(arms: Sequence[Sequence[Knot]], about: dict[str, Any]) -> str:
    """The file's text for one arm's knots (version 1) or two arms' (version 2): its kind first (an existing file is
    known as one by how it begins), then the knots, a line each."""
    if len(arms) not in (1, FILE_ARMS):
        raise ValueError(f"a trajectory file holds 1 or {FILE_ARMS} arms' knots, not {len(arms)}")
    names = [a.name.lower() for a in TRAJECTORY_JOINTS]
    head = {"format": FILE_FORMAT, "version": ONE_ARM_VERSION if len(arms) == 1 else TWO_ARM_VERSION,
            "joints": names, "units": {"t": "s", "q": "deg", "qd": "deg/s"}, "about": about}

    def rows(knots: Sequence[Knot], indent: str) -> str:
        return ",\n".join(indent + json.dumps({"t": k.t_s, "q": list(k.q_deg), "qd": list(k.qd_deg_s)})
                          for k in knots)
    if len(arms) == 1:
        return json.dumps(head)[:-1] + ', "knots": [\n' + rows(arms[0], "    ") + "\n]}\n"
    return (json.dumps(head)[:-1] + ', "arms": [\n'
            + ",\n".join('  {"knots": [\n' + rows(knots, "    ") + "\n  ]}" for knots in arms) + "\n]}\n")


def load_trajectory(path: Path | str, arm: int | None = None) -> list[Knot]:
    """The knots of arm `arm` (1 or 2; None for a one-arm file) in a trajectory file; ValueError
    (files.InputFileError for an unreadable file) saying what is wrong: not one of ours, another version, a two-arm
    file without `arm` or an arm it does not have, a knot that is not one (which, and why), times not increasing."""
    data = files.read_bounded(path, FILE_LIMIT)
    try:
        doc = json.loads(data)
    except (UnicodeDecodeError, ValueError) as exc:
        raise ValueError(f"{path}: not a trajectory file: not JSON ({exc})") from None
    if not isinstance(doc, dict) or doc.get("format") != FILE_FORMAT:
        raise ValueError(f"{path}: not a trajectory file (its format is not {FILE_FORMAT!r}; aspod plan ... --output "
                         "writes one)")
    version = doc.get("version")
    if version not in (ONE_ARM_VERSION, TWO_ARM_VERSION):
        raise ValueError(f"{path}: trajectory file version {version!r}; this aspod reads {ONE_ARM_VERSION} (one arm) "
                         f"and {TWO_ARM_VERSION} (two arms)")
    names = [a.name.lower() for a in TRAJECTORY_JOINTS]
    if doc.get("joints") != names:
        raise ValueError(f"{path}: its joints are {doc.get('joints')!r}; a trajectory moves {names}")
    if version == ONE_ARM_VERSION:
        if arm not in (None, 1):
            raise ValueError(f"{path}: a one-arm trajectory file (aspod plan --arm-to): it has no arm {arm}")
        return _knots(path, doc.get("knots"), "")
    arms = doc.get("arms")
    if not isinstance(arms, list) or len(arms) != FILE_ARMS or not all(
            isinstance(a, dict) and set(a) == {"knots"} for a in arms):
        raise ValueError(f'{path}: `arms` must be a list of {FILE_ARMS} arms, each {{"knots": [...]}}')
    each = [_knots(path, a["knots"], f"arm {number}: ") for number, a in enumerate(arms, 1)]
    if arm is None:
        raise ValueError(f"{path}: a two-arm trajectory file: say which arm's knots (arm 1 or arm 2)")
    if arm not in range(1, FILE_ARMS + 1):
        raise ValueError(f"{path}: a two-arm trajectory file has arms 1 and 2, not arm {arm}")
    return each[arm - 1]


def _knots(path: Path | str, rows: Any, where: str) -> list[Knot]:
    """One arm's knots from the file's `rows`, checked; `where` names the arm in what is wrong ("arm 2: ")."""
    if not isinstance(rows, list) or not 2 <= len(rows) <= TRAJECTORY_KNOTS:
        raise ValueError(f"{path}: {where}`knots` must be a list of 2 to {TRAJECTORY_KNOTS} knots")
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
            raise ValueError(f"{path}: {where}knot {index}: {exc}") from None
        knots.append(knot)
    if knots[0].t_s != 0.0 or any(b.t_s <= a.t_s for a, b in zip(knots, knots[1:])):
        raise ValueError(f"{path}: {where}a trajectory's knots start at t = 0 s and their times increase strictly")
    return knots
