"""A process's own time (host_tools/worlds/own_time.py): a wait judged on what the process had of the machine.

On a /proc written by the test (each process's stat, schedstat and children, as Linux writes them) and a SimClock,
then once on this machine's own /proc with a real child process."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from host_tools.worlds.own_time import LockstepWait, OwnTime, children, sample
from timebase import RealClock, SimClock


class FakeProc:
    """A /proc of a few processes: state letter, CPU and run-queue wait in seconds, start tick, children."""

    def __init__(self, root: Path) -> None:
        self.root = root

    def set(self, pid: int, state: str = "S", cpu_s: float = 0.0, waited_s: float = 0.0, started: int = 100,
            kids: tuple[int, ...] = (), name: str = "python") -> None:
        folder = self.root / str(pid)
        (folder / "task" / str(pid)).mkdir(parents=True, exist_ok=True)
        fields = [state, *["0"] * 18, str(started), "0", "0"]     # field 22 of stat, the start: 20th after the name
        (folder / "stat").write_text(f"{pid} ({name}) {' '.join(fields)}\n")
        (folder / "schedstat").write_text(f"{int(cpu_s * 1e9)} {int(waited_s * 1e9)} 7\n")
        (folder / "task" / str(pid) / "children").write_text("".join(f"{k} " for k in kids))

    def remove(self, pid: int) -> None:
        for path in sorted((self.root / str(pid)).rglob("*"), reverse=True):
            path.unlink() if path.is_file() else path.rmdir()
        (self.root / str(pid)).rmdir()


@pytest.fixture
def proc(tmp_path) -> FakeProc:
    return FakeProc(tmp_path)


def test_a_sample_reads_state_cpu_wait_and_start_even_with_a_strange_name(proc):
    proc.set(7, "R", cpu_s=1.5, waited_s=0.25, started=4242, name="a) b (c")
    seen = sample(7, proc.root)
    assert (seen.state, seen.cpu_s, seen.waited_s, seen.started) == ("R", 1.5, 0.25, 4242)
    assert sample(8, proc.root) is None


def test_a_sleeping_process_is_excused_only_its_waits_for_a_cpu(proc):
    clock = SimClock(10.0)
    proc.set(7, "S", cpu_s=1.0, waited_s=2.0)
    own = OwnTime(7, clock, proc=proc.root)
    clock.advance_by(5.0)
    proc.set(7, "S", cpu_s=1.2, waited_s=5.5)          # 3.5 s of the 5 s on a run queue
    look = own.look()
    assert (look.wall_s, look.own_s, look.gone) == (5.0, pytest.approx(1.5), None)


def test_a_runnable_or_uninterruptible_process_is_excused_all_but_its_cpu_time(proc):
    """Runnable, its wait may not be counted yet; in state D it waits on the machine (a page from disk)."""
    clock = SimClock()
    proc.set(7, "S", cpu_s=1.0, waited_s=2.0)
    own = OwnTime(7, clock, proc=proc.root)
    clock.advance_by(4.0)
    proc.set(7, "R", cpu_s=1.1, waited_s=2.0)          # run_delay adds a wait only once the CPU is had
    assert own.look().own_s == pytest.approx(0.1)
    proc.set(7, "R", cpu_s=4.5, waited_s=2.0)          # busy, not kept from running: a loop that never ends
    assert own.look().own_s == pytest.approx(3.5)
    proc.set(7, "D", cpu_s=1.1, waited_s=2.0)          # in the kernel's uninterruptible sleep (a page from disk)
    assert own.look().own_s == pytest.approx(0.1)


def test_a_stopped_ended_or_replaced_process_is_excused_nothing(proc):
    clock = SimClock()
    proc.set(7, "S")
    own = OwnTime(7, clock, proc=proc.root)
    clock.advance_by(3.0)
    proc.set(7, "T", waited_s=2.0)
    assert own.look().gone == "stopped (SIGSTOP)" and own.look().own_s == 3.0
    proc.set(7, "Z")
    assert own.look().gone == "ended (a zombie)"
    proc.remove(7)
    assert own.look().gone == "ended"
    proc.set(7, "R", started=999)                      # the pid taken by another process
    assert own.look().gone == "ended"


def test_a_new_wait_counts_from_its_own_start(proc):
    clock = SimClock()
    proc.set(7, "S", waited_s=1.0)
    own = OwnTime(7, clock, proc=proc.root)
    clock.advance_by(2.0)
    proc.set(7, "S", waited_s=2.5)
    assert own.look().own_s == pytest.approx(0.5)
    own.begin()
    clock.advance_by(1.0)
    assert own.look().own_s == pytest.approx(1.0)      # the earlier wait for a CPU excuses nothing now


def test_begin_reads_again_only_once_its_latest_reading_is_older_than_fresh_s(proc):
    clock = SimClock()
    proc.set(7, "S", waited_s=1.0)
    own = OwnTime(7, clock, fresh_s=0.05, proc=proc.root)
    proc.set(7, "S", waited_s=1.02)
    clock.advance_by(0.01)
    own.begin()                                        # 10 ms after the last reading: its counters serve
    clock.advance_by(0.1)
    assert own.look().own_s == pytest.approx(0.1 - 0.02)    # the wait before begin() excused too: late, never early
    clock.advance_by(0.06)
    own.begin()                                        # the look 60 ms ago is not fresh: read again
    clock.advance_by(0.1)
    proc.set(7, "S", waited_s=1.05)
    assert own.look().own_s == pytest.approx(0.07)


def test_a_tree_is_excused_the_longest_wait_of_its_processes_those_born_in_the_wait_counted_whole(proc):
    clock = SimClock()
    proc.set(7, "S", waited_s=1.0, kids=(8,))
    proc.set(8, "S", waited_s=0.0)
    own = OwnTime(7, clock, tree=True, proc=proc.root)
    assert children(7, proc.root) == [8]
    clock.advance_by(10.0)
    proc.set(7, "S", waited_s=2.0, kids=(8, 9))        # the parent waits on its child, which starts another
    proc.set(8, "S", waited_s=3.0)
    proc.set(9, "S", waited_s=6.0)
    assert own.look().own_s == pytest.approx(4.0)
    proc.remove(9)                                     # ended: its excuse stays
    proc.set(7, "S", waited_s=2.0, kids=(8,))
    assert own.look().own_s == pytest.approx(4.0)


def test_a_peer_waited_on_excuses_its_waits_and_its_end_is_not_the_processs(proc):
    clock = SimClock()
    proc.set(7, "S")                                   # a teleop, waiting on its sim
    proc.set(9, "S", waited_s=1.0)
    own = OwnTime(7, clock, peers=(9,), proc=proc.root)
    clock.advance_by(10.0)
    proc.set(9, "S", waited_s=9.0)                     # the sim waited 8 s for a CPU
    assert own.look().own_s == pytest.approx(2.0)
    proc.remove(9)
    look = own.look()
    assert look.gone is None and look.own_s == pytest.approx(2.0)


def test_on_this_machine_a_stopped_child_is_said_and_a_sleeping_one_has_the_wall_time_as_its_own():
    child = subprocess.Popen([sys.executable, "-c", "import sys; sys.stdin.read()"], stdin=subprocess.PIPE)
    try:
        clock = RealClock()
        own = OwnTime(child.pid, clock)
        clock.sleep(0.2)
        look = own.look()
        assert look.gone is None and 0.0 < look.own_s <= look.wall_s
        os.kill(child.pid, signal.SIGSTOP)
        assert _within(lambda: own.look().gone == "stopped (SIGSTOP)", clock)
        os.kill(child.pid, signal.SIGCONT)
        child.stdin.close()
        child.wait(60)
        assert own.look().gone == "ended"
    finally:
        child.kill()
        child.wait()


def test_the_lockstep_wait_excuses_nothing_for_a_plant_gone_and_reads_this_threads_wait():
    clock = RealClock()
    alone = LockstepWait(clock)                        # no plant process known: the wall clock, less own waits
    assert 0.0 <= alone.own_s(1.0) <= 1.0 and alone.last is None
    child = subprocess.Popen([sys.executable, "-c", "import sys; sys.stdin.read()"], stdin=subprocess.PIPE)
    try:
        judge = LockstepWait(clock, child.pid)
        os.kill(child.pid, signal.SIGSTOP)
        assert _within(lambda: judge.own_s(5.0) == 5.0 and judge.last.gone == "stopped (SIGSTOP)", clock)
    finally:
        child.kill()
        child.wait()


def _within(predicate, clock, limit_s: float = 60.0) -> bool:
    """`predicate` comes true, looked at every 10 ms (a signal's delivery on a busy machine), at most `limit_s`."""
    end = clock.now() + limit_s
    while not predicate():
        if clock.now() > end:
            return False
        clock.sleep(0.01)
    return True
