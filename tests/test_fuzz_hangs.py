"""In-process hangs: an input past its own time is ended, saved and replayed as a hang; an input the host only kept
waiting for a CPU is not one (host_tools/fuzz/hangs.py)."""
from __future__ import annotations

import inspect
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from host_tools.fuzz import planted
from host_tools.fuzz.hangs import Hang, HangWatch
from host_tools.worlds.child import run
from timebase import RealClock, SimClock

ASPOD = [sys.executable, "-m", "host_tools.cli.main"]
PLANTED_HANG = "host_tools.fuzz.planted:planted_hang_target"
REPO = Path(__file__).resolve().parents[1]


class Waited:
    """A CPU-wait counter the test sets."""

    def __init__(self, value) -> None:
        self.value = value

    def __call__(self):
        return self.value


def test_an_inputs_own_time_leaves_out_what_it_waited_for_a_cpu():
    clock, waited = SimClock(100.0), Waited(5.0)
    watch = HangWatch(10.0, clock, waited)
    assert watch.overdue() is None                        # no input running; the watch looks: 5.0 s waited so far
    with watch.input():                                   # the input's wait counts from that look
        clock.sleep_until(112.0)
        waited.value = 8.0                                # 12 s of wall time, 3 of them waiting for a CPU: 9 s
        assert watch.overdue() is None
        waited.value = 6.0                                # 1 s waiting: 11 s of its own
        why = watch.overdue()
        assert why is not None and "11.0 s of its own time" in why and "1.0 s of it waiting for a CPU" in why
    assert watch.overdue() is None                        # ended


def test_a_look_that_counted_a_wait_the_kernel_had_not_yet_added_does_not_leave_the_input_running_for_ever():
    clock, waited = SimClock(), Waited(0.0)
    watch = HangWatch(1.0, clock, waited)
    watch.overdue()
    with watch.input():
        clock.sleep_until(1.01)                # the watch looks while the main thread waits on a run queue, 20 ms so
        assert watch.look()                    # far, which the kernel adds only when the thread gets its CPU
        assert not watch.look()                # one interrupt at a time
        waited.value = 0.02                    # the main thread runs, interrupted: 0.99 s of its own, within its time
        watch.interrupt()
        clock.sleep_until(1.1)                 # the watch looks again, and this time the input is past its time
        assert watch.look()
        with pytest.raises(Hang, match="1.1 s of its own time"):
            watch.interrupt()
    assert not watch.look()                    # no input running


def test_where_the_kernel_does_not_say_the_wall_time_counts():
    clock = SimClock()
    watch = HangWatch(1.0, clock, Waited(None))
    with watch.input():
        clock.sleep_until(1.5)
        assert "1.5 s of its own time" in watch.overdue()


def test_the_kernel_counts_the_time_a_thread_waited_for_a_cpu():
    import threading
    first = RealClock.cpu_wait_s(threading.main_thread().native_id)
    if first is None:
        pytest.skip("this kernel keeps no schedstat")
    sum(range(200_000))
    assert 0.0 <= first <= RealClock.cpu_wait_s(threading.main_thread().native_id)


def test_a_planted_hang_is_ended_saved_with_its_place_and_replayed_as_a_hang(tmp_path):
    done = run([*ASPOD, "fuzz", PLANTED_HANG, "--runs", "100000", "--hang-s", "0.5", "--json", "--no-progress",
                "--corpus", "corpus", "--findings", "found"], cwd=tmp_path, text=True, timeout_s=120)
    assert done.returncode == 1, done.stderr
    job = json.loads(done.stdout)["jobs"][0]
    assert len(job["findings"]) == 1 and job["execs"] < 100000, job
    # the one file is the finding: libFuzzer's own copy of the input is not left beside it
    assert [p.name for p in (tmp_path / "found").iterdir()] == [Path(job["findings"][0]).name]
    finding = json.loads((tmp_path / job["findings"][0]).read_text())
    lines, first = inspect.getsourcelines(planted.planted_walk)
    loop = first + next(k for k, line in enumerate(lines) if line.strip().startswith("while"))
    stuck = {f"host_tools/fuzz/planted.py:{n}" for n in range(loop, first + len(lines))}
    assert finding["failure"]["kind"] == "hang"
    # the line of the loop it was stuck in, or (an instruction atheris added has no line) the function
    assert finding["failure"]["where"] in stuck | {"host_tools/fuzz/planted.py, in planted_walk()"}, finding
    assert "of its own time, past the 0.5 s of --hang-s" in finding["failure"]["error"]
    again = run([*ASPOD, "fuzz", "--replay", job["findings"][0], PLANTED_HANG, "--hang-s", "0.5"], cwd=tmp_path,
                text=True, timeout_s=60)
    assert again.returncode == 1 and "fails as found: hang" in again.stdout, again.stdout + again.stderr


STARVED = """
import json, time
from host_tools.fuzz.hangs import Hang, HangWatch
from timebase import RealClock
clock = RealClock()
with HangWatch(0.3) as watch:
    start, cpu = clock.now(), time.thread_time()
    try:
        with watch.input():
            # past the bound on the wall clock, on a CPU it shares at SCHED_IDLE, with at most half the bound's CPU
            # (a fixed 30 ms of CPU took 0.18 s under `nice -n 19 pytest`, the hog at nice 19 too: 3 weights in 18)
            while clock.now() - start < 0.45 and time.thread_time() - cpu < 0.15:
                pass
        hang = ""
    except Hang as exc:
        hang = str(exc)
print(json.dumps({"wall_s": clock.now() - start, "hang": hang}))
"""


def _idle() -> None:
    """This process is run only when nothing else wants its CPU (SCHED_IDLE): starved beside a busy loop whatever
    the nice value the test runs at (nice 19 was starved only beside a hog at nice 0: under `nice pytest` the
    hog had nice 10 too, the input took 0.1 s, and the premise failed)."""
    os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))


@pytest.mark.realtime
def test_an_input_the_host_starves_past_the_bound_is_not_a_hang():
    cpu = min(os.sched_getaffinity(0))
    pin = lambda: os.sched_setaffinity(0, {cpu})                          # noqa: E731
    hog = subprocess.Popen([sys.executable, "-c", "while True: pass"], preexec_fn=pin)
    try:
        done = run([sys.executable, "-c", STARVED], cwd=REPO, text=True, timeout_s=120,
                   preexec_fn=lambda: (pin(), _idle()), env={**os.environ, "PYTHONPATH": str(REPO)})
    finally:
        hog.kill()
        hog.wait()
    assert done.returncode == 0, done.stderr
    said = json.loads(done.stdout)
    assert said["wall_s"] > 0.3, f"the premise: the input took longer than the bound on the wall clock ({said})"
    assert said["hang"] == ""
