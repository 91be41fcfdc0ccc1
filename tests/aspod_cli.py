"""`aspod ARGS` as a child of a test, with a private per-user config.

The config lives beside `cwd` (not in it: some tests check that nothing was written there), so the user's own
parameter file is neither read nor written.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from host_tools.worlds.child import run

ASPOD = [sys.executable, "-m", "host_tools.cli.main"]


def aspod(*args: str, cwd: Path, timeout_s: float = 300) -> subprocess.CompletedProcess:
    """Its run, bounded by `timeout_s` of its own time (the wall time less its waits for a CPU: child.run)."""
    config = cwd.parent / f"{cwd.name}-config"
    return run([*ASPOD, *args], cwd=cwd, text=True, timeout_s=timeout_s,
               env={**os.environ, "XDG_CONFIG_HOME": str(config)})
