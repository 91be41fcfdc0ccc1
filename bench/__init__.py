"""Benchmarks: the codec beside pymavlink, command round trips over a real pty, real time, lock-step speed, tracking,
the tracker's day, live sessions, sessions tools and campaigns (`python -m bench`)."""
from __future__ import annotations

import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable, Sequence

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
