"""`aspod ARGS` as a child of a test, with a private per-user config.

The config lives beside `cwd` (not in it: some tests check that nothing was written there), so the user's own
parameter file is neither read nor written.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ASPOD = [sys.executable, "-m", "host_tools.cli.main"]


def aspod(*args: str, cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess:
    config = cwd.parent / f"{cwd.name}-config"
    return subprocess.run([*ASPOD, *args], cwd=cwd, capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, "XDG_CONFIG_HOME": str(config)})
