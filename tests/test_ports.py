"""`aspod ports` and `aspod teleop` without a URL (issue 36): a new user finds where to connect.

Real `aspod sim` processes over real ptys, in a runtime folder of the test's own (XDG_RUNTIME_DIR, TMPDIR), so
the simulators of other tests running beside are not seen. Waits are on the sims' own time (Child)."""
from __future__ import annotations

import json
import os

import pytest

from host_tools.worlds.child import run
from tests.aspod_cli import ASPOD

pytestmark = pytest.mark.pty


@pytest.fixture
def env(tmp_path):
    (tmp_path / "run").mkdir(mode=0o700)
    (tmp_path / "tmp").mkdir()
    return {**os.environ, "XDG_CONFIG_HOME": str(tmp_path / "config"), "XDG_RUNTIME_DIR": str(tmp_path / "run"),
            "TMPDIR": str(tmp_path / "tmp")}


def aspod(env, *args: str, stdin: str = "", peers=()):
    return run([*ASPOD, *args], input=stdin, text=True, env=env, timeout_s=120, peers=peers)


def test_ports_lists_the_serial_ports_and_the_running_simulators(env, start_sim):
    none = aspod(env, "ports")
    assert none.returncode == 0 and "simulators (yours, running):\n  none" in none.stdout, none.stdout
    sim, url = start_sim()
    shown = aspod(env, "ports", peers=(sim.pid,))
    assert shown.returncode == 0 and f"  {url}  pid {sim.pid}, aspod sim" in shown.stdout, shown.stdout
    assert all(len(line) <= 80 for line in shown.stdout.splitlines() if "control" not in line)
    data = json.loads(aspod(env, "ports", "--json", peers=(sim.pid,)).stdout)
    assert [(s["link"], s["pid"], s["plant"]) for s in data["simulators"]] == [(url, sim.pid, True)]
    assert isinstance(data["serial"], list)


def test_teleop_without_a_url_attaches_to_the_one_simulator_and_lists_several(env, start_sim):
    alone = aspod(env, "teleop", stdin="ping\nquit\n")
    assert alone.returncode == 2 and "no simulator of yours is running" in alone.stderr, alone.stderr
    first, url = start_sim()
    done = aspod(env, "teleop", stdin="ping\nstatus\nquit\n", peers=(first.pid,))
    assert done.returncode == 0 and "ok   Pong" in done.stdout, done.stderr + done.stdout
    second, url2 = start_sim()
    several = aspod(env, "teleop", stdin="ping\nquit\n", peers=(first.pid, second.pid))
    assert several.returncode == 2 and "2 simulators of yours are running" in several.stderr
    assert url in several.stderr and url2 in several.stderr and "Pong" not in several.stdout


def test_the_sockets_of_killed_simulators_never_hide_a_live_one(env, start_sim, tmp_path):
    """A simulator killed outright leaves its socket; 55 of them once kept a live one out of the 64 scanned."""
    import socket
    from pathlib import Path
    folder = Path(env["XDG_RUNTIME_DIR"]) / "aspod"
    folder.mkdir(mode=0o700, exist_ok=True)
    beyond = 10 ** (len(Path("/proc/sys/kernel/pid_max").read_text().strip()) + 1)   # no process has such a pid,
    for k in range(80):
        stale = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        stale.bind(str(folder / f"sim-{beyond + k}.sock"))        # and its name sorts before any live one
        stale.close()                                               # the file stays, as a killed sim leaves it
    sim, url = start_sim()                                          # its folder sweeps them as it opens
    data = json.loads(aspod(env, "ports", "--json", peers=(sim.pid,)).stdout)
    assert [s["link"] for s in data["simulators"]] == [url]
    assert sorted(p.name for p in folder.glob("sim-*.sock")) == [f"sim-{sim.pid}.sock"]
