"""A teleop script's run as data: each line a step with its outcome and what it printed, each motion with its end.

`run_script(..., record=ScriptRecord())` fills one; `as_dict` is what `aspod teleop --script F --json` and
`aspod bench SCRIPT --json` print, one JSON object:

    {"status": 0, "ok": true, "steps": [{"line": 3, "text": "moveby j1 5", "ok": true, "start_s": 1.204,
      "duration_s": 0.031, "output": ["ok   j1#2 started ..."]}, ...],
     "motions": [{"axis": "j1", "motion_id": 2, "kind": "MoveBy", "line": 3, "started_s": 1.23,
      "ended_s": 3.91, "outcome": "DONE", "ok": true, "position": 5.01}, ...],
     "commands": {"sent": 7, "ok": 7, "failed": 0}, "round_trip_ms": {"p50": 9.1, "p99": 14.0}, ...}

Times are the client's clock: simulated seconds on a lock-step bench, the host's monotonic clock live.
"""
from __future__ import annotations

import statistics
from dataclasses import asdict, dataclass, field
from typing import Any, Optional, TextIO

from protocol.states import MotionOutcome

from host_tools.teleop.motion import axis_word


@dataclass
class StepRecord:
    line: int
    text: str
    ok: bool = False
    start_s: float = 0.0
    duration_s: float = 0.0
    output: list[str] = field(default_factory=list)


class ScriptRecord:
    """Collects steps as `run_script` runs them; it is also the stream the session prints to (`tee`)."""

    MAX_OUTPUT_LINES = 200        # per step: a `watch` or a long `help` is cut, and says so

    def __init__(self, echo: Optional[TextIO] = None) -> None:
        self.echo = echo          # where the printed lines go too (None: nowhere, as for --json)
        self.steps: list[StepRecord] = []
        self._current: Optional[StepRecord] = None
        self._partial = ""

    # ---- the session's output stream ----
    def write(self, text: str) -> int:
        if self.echo is not None:
            self.echo.write(text)
        self._partial += text
        *whole, self._partial = self._partial.split("\n")
        if self._current is not None:
            room = self.MAX_OUTPUT_LINES - len(self._current.output)
            if room > 0:
                self._current.output += whole[:room]
            if len(whole) > room >= 0 and self._current.output[-1:] != ["(more output left out)"]:
                self._current.output.append("(more output left out)")
        return len(text)

    def flush(self) -> None:
        if self.echo is not None:
            self.echo.flush()

    def isatty(self) -> bool:
        return False

    # ---- steps ----
    def begin(self, line: int, text: str, now: float) -> None:
        self._current = StepRecord(line, text, start_s=now)
        self.steps.append(self._current)

    def end(self, ok: bool, now: float) -> None:
        if self._current is not None:
            self._current.ok = ok
            self._current.duration_s = now - self._current.start_s
            self._current = None

    def as_dict(self, session, status: int, **extra: Any) -> dict:
        motions = []
        for m in session.tracker.motions:
            end = m.end
            motions.append({"axis": axis_word(m.axis), "motion_id": m.motion_id, "kind": m.kind, "line": m.line_no,
                            "started_s": m.started_s, "ended_s": m.ended_s,
                            "outcome": None if end is None else MotionOutcome(end.outcome).name,
                            "ok": m.ok, "replaced_by": m.replaced_by,
                            "position": None if end is None else end.position})
        latencies = sorted(x * 1000 for x in session.latencies_s)
        round_trip = None if not latencies else {
            "p50": statistics.median(latencies), "p99": latencies[min(len(latencies) - 1,
                                                                      int(round(0.99 * (len(latencies) - 1))))],
            "max": latencies[-1]}
        return {"status": status, "ok": status == 0, "steps": [asdict(s) for s in self.steps], "motions": motions,
                "motion_counts": session.tracker.counts(),
                "commands": {"sent": session.sent, "ok": session.sent - session.failed, "failed": session.failed},
                "round_trip_ms": round_trip, **extra}
