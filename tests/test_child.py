"""`host_tools.worlds.child.Child`: ready line, bounded waits, SIGINT then SIGTERM then SIGKILL."""
from __future__ import annotations

import signal
import sys

import pytest

from host_tools.worlds.child import Child, ChildError, describe_exit

PY = (sys.executable, "-c")
# a child that says it is ready, then ignores SIGINT (and, if asked, SIGTERM) until killed
STUBBORN = """
import signal, sys
signal.signal(signal.SIGINT, signal.SIG_IGN)
if sys.argv[1] == "term":
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
print("READY now", flush=True)
print("a note", file=sys.stderr, flush=True)
while True:
    signal.pause()
"""


def test_ready_line_then_sigint_stops_a_well_behaved_child():
    # its stderr line before its ready line: a SIGINT right after the ready line must not beat it
    # (it takes SIGINT itself: started from a background job, a process inherits SIGINT ignored)
    child = Child(["import sys, signal; signal.signal(signal.SIGINT, signal.default_int_handler); "
                   "print('bye', file=sys.stderr, flush=True); print('READY x', flush=True); signal.pause()"],
                  command=PY)
    assert child.ready("READY") == "READY x"
    status, err = child.stop(timeout_s=60)
    assert status == -signal.SIGINT or status == 1       # KeyboardInterrupt: a traceback, exit 1
    assert "bye" in err


@pytest.mark.parametrize("mode, expected", [("int", -signal.SIGTERM), ("term", -signal.SIGKILL)])
def test_a_child_that_ignores_the_first_signals_gets_the_next(mode, expected):
    child = Child([STUBBORN, mode], command=PY)
    child.ready("READY")
    assert child.wait_stderr("a (no)te").group(1) == "no"
    status, _ = child.stop(timeout_s=0.5)      # short on purpose: the child ignores what it is sent
    assert status == expected
    assert child.stop() == (expected, "")      # stopping again is harmless


def test_a_child_that_ends_before_its_line_or_says_something_else_is_an_error():
    child = Child(["import sys; print('oops', file=sys.stderr); sys.exit(4)"], command=PY)
    with pytest.raises(ChildError, match=r"exit status 4.*stderr so far \['oops'\]"):   # its reason, quoted
        child.ready("READY", timeout_s=60)
    assert child.stop() == (4, "")
    other = Child(["print('hello', flush=True)"], command=PY)
    with pytest.raises(ChildError, match="said 'hello'"):
        other.ready("READY", timeout_s=60)
    other.stop()


def test_describe_exit():
    assert describe_exit(0) == "exit status 0" and describe_exit(-9) == "killed by SIGKILL"


def test_follow_stderr_hands_each_line_over_as_it_comes_and_stop_still_ends_the_child():
    got: list[str] = []
    child = Child(["import sys, signal\nfor k in range(3): print(f'line {k}', file=sys.stderr, flush=True)\n"
                   "print('READY', flush=True)\nsignal.pause()"], command=PY)
    child.follow_stderr(got.append)
    child.ready("READY")
    status, rest = child.stop(signal.SIGTERM, timeout_s=60)
    assert status == -signal.SIGTERM and rest == ""
    assert got == ["line 0", "line 1", "line 2"]
