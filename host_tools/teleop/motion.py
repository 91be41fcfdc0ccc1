"""The motions a teleop session started, matched with their MotionDone events.

A motion command (move, moveby, jog, home, grip) answers MotionAccepted with the id of every
motion it started, by axis (`home all`: one per axis); each ends later with a MotionDone event
with the same axis and id. A motion that a newer command replaces on the same axis ends
SUPERSEDED: when the newer one is accepted (or ends) the older is marked replaced, and its
SUPERSEDED, whenever it comes, is the end expected of it, not a failure: the new motion's end
decides.

The tracker is fed from the link's pump thread (`on_done`) and read from the main thread;
it has its own lock. Events may arrive before the reply that names their motion, so every
end is kept for a while and looked up when a motion is registered.
"""
from __future__ import annotations

import threading
from collections import deque
from dataclasses import dataclass
from typing import Optional

from protocol.messages import SCHEMA, started_motions
from protocol.reasons import Reason, reason_name
from protocol.schema import Message
from protocol.states import MotionOutcome

from host_tools.teleop.format import enum_word, reason_lines, wrap
from host_tools.teleop.words import AXES, AXIS_ALL, Step

_KEPT_ENDS = 512
_JOINTS = SCHEMA["TelemetryJoints"]
# unit of each axis's position (deg, gripper mm), from the telemetry declaration
POSITION_UNIT = {int(a): next((f.unit for f in _JOINTS.fields if f.name == f"{a.name.lower()}_pos"), "")
                 for a in AXES}


def axis_word(axis: int) -> str:
    return enum_word(type(AXIS_ALL), axis)


@dataclass(eq=False)
class Motion:
    """One accepted motion command on one axis, until its end."""

    axis: int
    motion_id: int
    kind: str                      # the request's message name: Move, MoveBy, Jog, Home, Grip
    line_no: int
    text: str
    started_s: float
    end: Optional[Message] = None  # its MotionDone
    ended_s: Optional[float] = None
    replaced_by: Optional[str] = None    # what replaced it: it ends SUPERSEDED, as expected
    accounted: bool = False        # a failure already counted

    @property
    def label(self) -> str:
        return f"{axis_word(self.axis)}#{self.motion_id}"

    @property
    def running(self) -> bool:
        return self.end is None and self.replaced_by is None

    @property
    def superseded(self) -> bool:
        """Replaced by a newer motion of ours on its axis: its SUPERSEDED end (come or still to come) is expected."""
        return self.replaced_by is not None and (self.end is None or self.end.outcome == MotionOutcome.SUPERSEDED)

    @property
    def ok(self) -> bool:
        """Ended as asked: DONE (a jog: STOPPED on request, its only normal end), or replaced by a newer one."""
        if self.superseded:
            return True
        if self.end is None:
            return False
        outcome = self.end.outcome
        return outcome == MotionOutcome.DONE or (self.kind == "Jog" and outcome == MotionOutcome.STOPPED
                                                 and self.end.reason == Reason.HOST_REQUEST)

    def matches(self, end: Message) -> bool:
        return end.axis == self.axis and self.end is None and end.motion_id == self.motion_id


class MotionTracker:
    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.motions: list[Motion] = []
        self._ends: deque[tuple[Message, float]] = deque(maxlen=_KEPT_ENDS)
        self._in_flight = 0                       # motion commands sent and not yet answered
        self._held: list[tuple[Message, float]] = []   # unmatched ends that one of those may claim

    # ---- pump thread ----
    def on_done(self, end: Message, now: float) -> tuple[Optional[Motion], list[Motion], bool]:
        """Record a MotionDone: (the motion of ours it ends or None, older ones of ours it shows were replaced,
        whether to print it now: an end no motion of ours claims is held while a motion command is
        unanswered, since its reply may name it)."""
        with self._lock:
            self._ends.append((end, now))
            mine = next((m for m in self.motions if m.matches(end)), None)
            if mine is not None:
                self._finish(mine, end, now)
            replaced = self._replace_older(end.axis, end.motion_id, f"{axis_word(end.axis)}#{end.motion_id}")
            if mine is None and self._in_flight:
                self._held.append((end, now))
                return None, replaced, False
            return mine, replaced, True

    # ---- main thread ----
    def sending(self) -> None:
        """Call before sending a motion command (ends that come before its reply are held); `started` or
        `refused` must follow."""
        with self._lock:
            self._in_flight += 1

    def refused(self) -> list[tuple[Message, Optional[Motion]]]:
        """The motion command was not accepted; returns the held ends to print now."""
        with self._lock:
            self._in_flight -= 1
            return self._release([])

    def started(self, step: Step, reply: Message, now: float
                ) -> tuple[list[Motion], list[Motion], list[tuple[Message, Optional[Motion]]]]:
        """Register the motions an accepted command started, as its MotionAccepted names them: (them, older
        motions of ours they replaced, held ends to print now, with the motion each ends)."""
        kind = step.message.spec.name
        with self._lock:
            self._in_flight -= 1
            new = [Motion(axis, motion_id, kind, step.line_no, step.text, now)
                   for axis, motion_id in started_motions(reply).items()]
            replaced = []
            for motion in new:
                replaced += self._replace_older(motion.axis, motion.motion_id, "this " + step.text)
            self.motions += new
            for end, at in self._ends:        # ends that came before the reply
                for motion in new:
                    if motion.matches(end):
                        self._finish(motion, end, at)
            return new, replaced, self._release(new)

    def running(self, axis: int = int(AXIS_ALL)) -> list[Motion]:
        with self._lock:
            return [m for m in self.motions if m.running and axis in (m.axis, int(AXIS_ALL))]

    def take_failures(self) -> list[Motion]:
        """Motions that ended other than asked and have not been counted yet (counts them now)."""
        with self._lock:
            failed = [m for m in self.motions if m.end is not None and not m.ok and not m.accounted]
            for motion in failed:
                motion.accounted = True
            return failed

    def counts(self) -> dict[str, int]:
        with self._lock:
            ended = [m for m in self.motions if m.end is not None]
            return {"started": len(self.motions), "done": sum(m.ok and not m.superseded for m in ended),
                    "failed": sum(not m.ok for m in ended),
                    "replaced": sum(m.superseded for m in self.motions),
                    "running": sum(m.running for m in self.motions)}

    # ---- helpers (lock held) ----
    def _release(self, new: list[Motion]) -> list[tuple[Message, Optional[Motion]]]:
        """Held ends: those `new` motions claimed, and (no command left unanswered) the rest."""
        out, keep = [], []
        for end, at in self._held:
            mine = next((m for m in new if m.end is end), None)
            if mine is not None or not self._in_flight:
                out.append((end, mine))
            else:
                keep.append((end, at))
        self._held = keep
        return out

    def _finish(self, motion: Motion, end: Message, now: float) -> None:
        """`end` ends `motion`. A SUPERSEDED that comes before the reply naming its replacement (a motion command
        is unanswered) is taken as replaced by that command; with none in flight, another host replaced it."""
        motion.end, motion.ended_s = end, now
        if end.outcome != MotionOutcome.SUPERSEDED:
            motion.replaced_by = None
        elif motion.replaced_by is None and self._in_flight:
            motion.replaced_by = "a newer motion command"

    def _replace_older(self, axis: int, newer_id: int, by: str) -> list[Motion]:
        """Our running motions on `axis` older than `newer_id` were replaced."""
        older = [m for m in self.motions if m.running and m.axis == axis and m.motion_id < newer_id]
        for motion in older:
            motion.replaced_by = by
        return older


# ---- text ----
def position_text(axis: int, position: float) -> str:
    return f"{position:.3f} {POSITION_UNIT.get(axis, '')}".rstrip()


def started_text(motions: list[Motion]) -> str:
    if len(motions) == 1:
        return f"motion {motions[0].label} started"
    return f"motion {axis_word(int(AXIS_ALL))} started, one end each: {' '.join(m.label for m in motions)}"


def end_lines(end: Message, motion: Optional[Motion]) -> list[str]:
    """`! j1#2 DONE at 3.005 deg (line 5: move j1 3, 2.1 s)`, with the reason's doc and remedy if not OK."""
    label = f"{axis_word(end.axis)}#{end.motion_id}"
    outcome = enum_word(MotionOutcome, end.outcome).upper()
    if motion is None:
        origin = "not started by this session"
    else:
        took = f", {motion.ended_s - motion.started_s:.1f} s" if motion.ended_s is not None else ""
        origin = f"line {motion.line_no}: {motion.text}{took}"
    head = f"! {label} {outcome} at {position_text(end.axis, end.position)} ({origin})"
    if end.reason == Reason.OK:
        return [head]
    head += f": {reason_name(end.reason)} ({end.reason})"
    if end.reason == Reason.HOST_REQUEST:     # stopped on request: nothing to explain or remedy
        return [head]
    return [head] + reason_lines(end.reason, "!     ")


def replaced_lines(replaced: list[Motion]) -> list[str]:
    return [f"! {m.label} (line {m.line_no}: {m.text}) was replaced by {m.replaced_by}; it ends SUPERSEDED, "
            "as expected, and the newer motion's end decides" for m in replaced]


def limit_text(request: Message, refusal: Message) -> str:
    """The limit a motion command was refused for, from its MotionAccepted: SOFT_LIMIT names a soft limit (deg),
    OUT_OF_RANGE the axis's speed (deg/s), each with the parameter that sets it."""
    limit, value, asked = refusal.limit, refusal.limit_value, refusal.asked
    if not hasattr(request, "axis"):             # a trajectory: the limit's parameter names the joint
        what = "a soft limit" if refusal.result == Reason.SOFT_LIMIT else "a speed limit"
        return f"the trajectory passes {what}: {asked:g} against {limit} = {value:g}"
    axis = axis_word(request.axis)
    if refusal.result == Reason.SOFT_LIMIT and request.spec.name == "Jog":
        return f"{axis}: at {asked:g} deg, against {limit} = {value:g} deg; jog the other way"
    if refusal.result == Reason.SOFT_LIMIT:
        return (f"{axis}: target {asked:g} deg is beyond {limit} = {value:g} deg "
                f"(soft limits {axis}_min_deg .. {axis}_max_deg)")
    return f"{axis}: speed {asked:g} deg/s is above its highest, {limit} = {value:g} deg/s"


def failure_text(motion: Motion) -> str:
    end = motion.end
    outcome = enum_word(MotionOutcome, end.outcome).upper()
    return (f"line {motion.line_no}: {motion.text!r}: motion {motion.label} ended {outcome} "
            f"({reason_name(end.reason)}) at {position_text(motion.axis, end.position)}")


def still_running_lines(motions: list[Motion], indent: str = "", lead: str = "") -> list[str]:
    return wrap(lead + "still running: " + ", ".join(f"{m.label} (line {m.line_no}: {m.text})" for m in motions),
                indent)
