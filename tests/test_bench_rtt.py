"""bench/bench_rtt.py waits for its sim on the sim's own time (issue 35: under load it gave up on wall-clock limits)."""
from __future__ import annotations

import secrets
import sys

import pytest

from bench import OwnTimeOut, bench_rtt
from host_tools.client.live import HostClient
from host_tools.worlds.child import Child
from protocol import auth

pytestmark = pytest.mark.pty

# A "sim" that says its link and then answers nothing: asleep, so every second of the wait is its own.
SILENT = ("import os, time; m, s = os.openpty(); print('ASPOD-LINK ' + os.ttyname(s), flush=True); "
          "time.sleep(600)")


def test_a_sim_that_never_answers_is_given_up_on_its_own_time_and_the_error_says_how_much_it_had():
    child = Child(["-c", SILENT], command=[sys.executable])
    try:
        url = child.ready("ASPOD-LINK ").split(" ", 1)[1]
        client = HostClient(url, secrets.token_bytes(auth.KEY_BYTES))
        try:
            with pytest.raises(OwnTimeOut, match=r"had \d+\.\d s of its own time"):
                bench_rtt.connect(client, child, timeout_s=1.0)
        finally:
            client.close()
        assert child.exit_status() is None          # not ended: given up on for its silence, not for an exit
    finally:
        child.stop()


def test_a_case_starts_its_sim_connects_and_times_its_pings(tmp_path):
    key, key_path = secrets.token_bytes(auth.KEY_BYTES), tmp_path / "bench.key"
    auth.write_key(key_path, key)
    result = bench_rtt.run_case(bench_rtt.Case(115200, 0, 3, 1, paced=False), key, key_path)
    assert result.error == "" and len(result.latencies_s) == 3
