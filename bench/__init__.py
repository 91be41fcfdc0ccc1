"""Benchmarks: the codec beside pymavlink, command round trips over a real pty, real time, lock-step speed, tracking,
the tracker's day, live sessions, sessions tools and campaigns (`python -m bench`)."""
from __future__ import annotations

import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable, Sequence, TypeVar

from host_tools.worlds.child import Child, out_of_time

T = TypeVar("T")

Part = Callable[[Path, bool], Iterable[str]]   # a list, or a generator whose lines are printed as they come


@dataclass
class PartsResult:
    """A benchmark made of parts: every line it printed, and the first part's error ("" when all ran)."""
    lines: list[str] = field(default_factory=list)
    error: str = ""


def run_parts(title: str, parts: Sequence[Part], quick: bool, prefix: str) -> PartsResult:
    """Print `title`, then run each part in one scratch folder, printing its lines as they come (a part that is a
    generator shows its progress on a long run). A part that cannot run, or stops half way, says which and why; the
    others still run."""
    print(title, flush=True)
    lines_all, error = [], ""
    with tempfile.TemporaryDirectory(prefix=prefix) as tmp:
        for part in parts:
            try:
                for line in part(Path(tmp), quick):
                    print(line, flush=True)
                    lines_all.append(line)
            except Exception as exc:
                error = error or f"{part.__name__}: {type(exc).__name__}: {exc}"
                line = f"{part.__name__}: could not run: {type(exc).__name__}: {exc}"
                print(line, flush=True)
                lines_all.append(line)
    return PartsResult(lines_all, error)


class OwnTimeOut(TimeoutError):
    """A child had its own time for something and did not do it (`retry_on_own_time`)."""


def retry_on_own_time(child: Child, attempt: Callable[[], T], timeout_s: float,
                      again: Callable[[Exception], bool]) -> T:
    """`attempt()` (a handshake with `child`, bounded on the wall clock as on a real line), called again after a
    failure `again` accepts, until it succeeds or `child` has had `timeout_s` of its own time since the first
    (host_tools/worlds/own_time.py: the wall time less its waits for a CPU). A busy machine that kept the child from
    its CPU through one attempt is not taken for a dead child; a child that ended, or a failure `again` refuses (a
    refusal, a wrong key), ends it at once. Out of its own time: `OwnTimeOut`, saying how much it had."""
    own = child.own_time()
    while True:
        try:
            return attempt()
        except Exception as exc:
            if not again(exc) or child.exit_status() is not None:
                raise
            look = own.look()
            if out_of_time(look, timeout_s):
                raise OwnTimeOut(f"{exc}; {child.name} (pid {child.pid}) had {look.describe()}") from None
