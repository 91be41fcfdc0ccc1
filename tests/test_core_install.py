"""`pip install aspod` without extras, for real: a clean venv, pip from the package index, the core commands run
and the commands whose extra is missing say which to install and exit 2 (kernels/extras.py; README, "Set-up").

One venv for every check, in a temporary folder, in one test; pip's own cache is reused between runs. The
package is built from a copy of its sources, so that pip's build leaves nothing in the checkout. Without the
package index the test is skipped, saying so. It takes a minute or two (most of it pip), hence `long`; `realtime` keeps it apart
from the CPU hogs.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import venv
from pathlib import Path

import pytest

from host_tools.exit_codes import EXIT_OK, EXIT_USAGE

ROOT = Path(__file__).resolve().parent.parent
SOURCES = ["pyproject.toml", "README.md", "kernels", "timebase", "firmware_py", "protocol", "hil_sim", "host_tools"]
EXTRAS_MODULES = ["matplotlib", "atheris", "coverage", "dask", "distributed", "pyarrow", "numba", "pvlib", "filterpy",
                  "pandas", "pytest"]
CORE_GOAL_MB = 300            # the goal for the core venv (README, "Set-up")
PIP_S = 1800                  # pip's install: generous, it downloads some 60 MB the first time
COMMAND_S = 300               # one aspod command: generous on a busy 2-core machine

pytestmark = [pytest.mark.long, pytest.mark.realtime]


def _run(argv, cwd: Path, timeout: float, env=None) -> subprocess.CompletedProcess:
    return subprocess.run([str(a) for a in argv], cwd=cwd, capture_output=True, text=True, timeout=timeout,
                          env=env, stdin=subprocess.DEVNULL)


def _clean_env() -> dict:
    """This environment, less what would point the venv's Python at the test's own packages or switches."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV", "ASPOD_COMPILED")}
    env.pop("PYTHONHOME", None)
    return env


def _core_venv(top: Path) -> tuple[Path, Path, dict]:
    """(the venv's bin folder, a work folder, the environment): `aspod` installed without extras; skipped if the
    package index cannot be reached."""
    source, home, work = top / "source", top / "venv", top / "work"
    source.mkdir()
    work.mkdir()
    for name in SOURCES:
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, source / name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
        else:
            shutil.copy2(ROOT / name, source / name)
    venv.EnvBuilder(with_pip=True).create(home)
    python = home / "bin" / "python"
    env = _clean_env()
    probe = _run([python, "-m", "pip", "index", "versions", "cobs", "--timeout", "20"], work, 300, env)
    if probe.returncode != 0:
        said = (probe.stderr.strip().splitlines() or ["no answer"])[-1]
        pytest.skip(f"the package index cannot be reached (pip index versions cobs: {said})")
    installed = _run([python, "-m", "pip", "install", "--disable-pip-version-check", str(source)], work, PIP_S, env)
    assert installed.returncode == 0, installed.stdout[-3000:] + installed.stderr[-3000:]
    return home / "bin", work, env


REFUSED = [     # a command whose extra is missing: its words, and what it says
    (["fuzz", "codec", "--runs", "10"], "aspod: fuzz: needs the fuzz extra (atheris is not installed): "
                                        "pip install 'aspod[fuzz]'"),
    (["campaign", "s.txt", "--seeds", "2"], "aspod: campaign: needs the campaign extra (dask, distributed, pyarrow, "
                                            "matplotlib, pytest are not installed): pip install 'aspod[campaign]'"),
    (["tracker-day", "--plot", "day.png"], "aspod: tracker-day --plot: needs the plot extra (matplotlib is not "
                                           "installed): pip install 'aspod[plot]'"),
    (["plan", "--plot", "figures"], "aspod: plan --plot: needs the plot extra (matplotlib is not installed): "
                                    "pip install 'aspod[plot]'"),
    (["log", "s.pcapng", "--mcap", "s.mcap"], "aspod: log --mcap: needs the foxglove extra (foxglove is not "
                                              "installed): pip install 'aspod[foxglove]'"),
]


def test_the_core_installs_alone_runs_and_names_the_extra_a_command_needs(tmp_path):
    """One venv for every check (one test, so that pytest-xdist never builds it twice)."""
    bin_dir, work, env = _core_venv(tmp_path)
    aspod = bin_dir / "aspod"

    # nothing of the extras came with the core, and the core is small
    found = _run([bin_dir / "python", "-c", "import importlib.util, json, sys; "
                  "print(json.dumps([m for m in sys.argv[1:] if importlib.util.find_spec(m)]))", *EXTRAS_MODULES],
                 work, COMMAND_S, env)
    assert found.returncode == 0, found.stderr
    assert json.loads(found.stdout) == [], "the core installed modules of the extras"
    mb = int(_run(["du", "-sk", bin_dir.parent], work, COMMAND_S).stdout.split()[0]) / 1024
    assert mb <= CORE_GOAL_MB, f"the core venv takes {mb:.0f} MB (goal {CORE_GOAL_MB} MB)"

    # the core commands run: the version, a short bench on the simulated clock, the fuzz targets' list
    version = _run([aspod, "--version"], work, COMMAND_S, env)
    assert (version.returncode, version.stdout.split()[:1]) == (EXIT_OK, ["aspod"]), version.stderr
    script = work / "s.txt"
    script.write_text("enable\nmoveby j1 2 2\nwait\nstatus\n")
    bench = _run([aspod, "bench", script, "--json"], work, COMMAND_S, env)
    assert bench.returncode == EXIT_OK, bench.stderr[-3000:]
    doc = json.loads(bench.stdout)
    assert doc["ok"] and [m["outcome"] for m in doc["motions"]] == ["DONE"]
    listed = _run([aspod, "fuzz", "--list"], work, COMMAND_S, env)
    assert listed.returncode == EXIT_OK and "codec" in listed.stdout, listed.stderr

    # a command whose extra is missing: one line naming it, exit 2, nothing written
    for argv, said in REFUSED:
        done = _run([aspod, *argv], work, COMMAND_S, env)
        assert (done.returncode, done.stderr.strip()) == (EXIT_USAGE, said), argv
    assert not (work / "day.png").exists() and not (work / "figures").exists()

    # the compiled kernels asked for without numba
    done = _run([aspod, "bench", script], work, COMMAND_S, {**env, "ASPOD_COMPILED": "1"})
    assert done.returncode == EXIT_USAGE, done.stderr[-3000:]
    assert ("aspod: the compiled arm plant (ASPOD_COMPILED=1): needs the compiled extra (numba is not installed): "
            "pip install 'aspod[compiled]'") in done.stderr
