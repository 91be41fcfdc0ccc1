"""A real-time teleop session of arm moves on a machine the test keeps busy: every motion ends DONE.

The test starts CPU hogs of its own (one per core, so that every core of the machine is kept
busy whatever else runs), then runs `aspod sim` and a scripted `aspod teleop` over a
real pty, in one process and with the plant as a separate process in lock-step over udp_multicast.
Under such load the world runs slower than real time (it says so: TimingWarning), but it never
faults for it. Bounds are about behaviour, and the time limits are generous (the lock-step pair
runs at a fraction of real time on a machine this busy).
"""
from __future__ import annotations

import os
import re
import signal
import subprocess
import sys

import pytest

from host_tools.worlds.child import Child, run

pytestmark = [pytest.mark.pty, pytest.mark.cpu_hog]   # never beside another real-time test (conftest)
ASPOD = [sys.executable, "-m", "host_tools.cli.main"]
# Relative moves (no homing needed), three joints at once, out and back: 6 motion ends in all. Short
# moves (about 1.5 s each): the load is what is tested, not the distance.
SCRIPT = """\
enable
moveby j1 2
moveby j2 -2
moveby mount 1
wait all 600
moveby j1 -2
moveby j2 2
moveby mount -1
wait all 600
status
"""
MOTIONS = 6


@pytest.fixture
def hogs():
    """CPU hogs started and stopped by the test: one per core."""
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(os.cpu_count() or 2)]
    yield procs
    for proc in procs:
        proc.kill()
        proc.wait()


@pytest.mark.parametrize("mode", [(), ("--hal", "udp_multicast")], ids=["one-process", "lockstep-processes"])
def test_a_session_of_arm_moves_on_a_busy_machine_ends_every_motion_done_without_a_fault(mode, hogs, tmp_path):
    env = {**os.environ, "XDG_CONFIG_HOME": str(tmp_path / "config")}
    sim = Child(["sim", "--pty", "--params", str(tmp_path / "params.json"), *mode], env=env)
    try:
        link = sim.ready("ASPOD-LINK ", timeout_s=120.0)
        url = link.split(" ", 1)[1]
        # the connect may take teleop's longest: a 60 s connect timeout once ended first, the sim at 0.085x real time
        # beside a second test run and two more CPU hogs; the run is bounded by its own time
        done = run(ASPOD + ["teleop", url, "--connect-timeout", "600"], input=SCRIPT.encode(), env=env,
                   timeout_s=900, peers=(sim.pid,))
    finally:
        _, err = sim.stop(signal.SIGTERM, timeout_s=60)
    out = done.stdout.decode()
    assert done.returncode == 0, out + done.stderr.decode() + err
    ends = re.findall(r"! (\w+)#\d+ (\w+) at ", out)
    assert len(ends) == MOTIONS and {outcome for _, outcome in ends} == {"DONE"}, out
    assert "state=ENABLED faults=none" in out and "FAULT" not in out, out
    assert "-> FAULT" not in err and "HAL_STALE" not in err, err
