"""Benchmarks: the codec beside pymavlink, command round trips over a real pty, real time, lock-step speed, tracking,
the tracker's day, live sessions, sessions tools and campaigns (`python -m bench`)."""
from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Callable, Sequence

Part = Callable[[Path, bool], list[str]]


def run_parts(parts: Sequence[Part], quick: bool, prefix: str) -> tuple[list[str], str]:
    """Run each part in one scratch folder, printing its lines as they come: (all the lines, the first part's
    error or ""). A part that cannot run says which and why; the others still run."""
    lines_all, error = [], ""
    with tempfile.TemporaryDirectory(prefix=prefix) as tmp:
        for part in parts:
            try:
                lines = part(Path(tmp), quick)
            except Exception as exc:
                error = error or f"{part.__name__}: {type(exc).__name__}: {exc}"
                lines = [f"{part.__name__}: could not run: {type(exc).__name__}: {exc}"]
            for line in lines:
                print(line, flush=True)
            lines_all += lines
    return lines_all, error
