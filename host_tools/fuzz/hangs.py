"""When an in-process input is a hang: its own time, not the host's.

libFuzzer's `-timeout` counts wall time. A job the host starves (the campaign runs at nice 19 beside other work;
under load 12 one input of controller-link took over 10 s of wall time, its world build being 15 ms of CPU) would
report an input as hung that only waited for a CPU: the host's slowness taken for the target's fault. So
`HangWatch` counts an input's own time: the wall time since it started, less the time its thread was runnable but
waiting on a run queue for a CPU (Linux's schedstat `run_delay`; where the kernel does not say, the whole wall
time counts). Past `hang_s` of its own time, the input is interrupted on the main thread with `Hang`, and the
finding holds the inputs that led there and where it was stuck. A hang that blocks in a call without waiting for a
CPU (a lock, a read) still counts, since blocked time is the input's own.

Reading the kernel's count costs 13 µs, 6 % of a codec execution, so an input's start notes only the time and
the count the watch read at its latest look (every `POLL_S`, and once as it starts). The wait between that look
and the input's start is then left out of the input's time too: a hang is found a little late, by at most that,
never early, however long the host keeps the watch itself from looking.

The watch's look is only a trigger; the interrupt, on the main thread, judges again, and that judgement decides. The
two can differ: the kernel adds a wait to run_delay only when the waiting thread gets its CPU, so a look taken while
the main thread sits on a run queue counts that wait as the input's own (up to 20 ms under load, measured). When the
interrupt finds the input within its time after all, the watch is armed again and looks on; otherwise the input
would never be interrupted, and a replayed hang would hang the replay.

libFuzzer's own timeout stays as the backstop, at `backstop_s(hang_s)` of wall time, for a hang the interrupt
cannot reach (a loop in C that never returns to Python).
"""
from __future__ import annotations

import signal
import threading
from contextlib import contextmanager
from typing import Callable, Iterator, Optional

from timebase import Clock, RealClock

HANG_S = 10.0                 # an input's own time past which it is a hang (`aspod fuzz --hang-s`)
POLL_S = 0.1                  # how often the watch looks
_SIGNAL = signal.SIGRTMIN + 2  # libFuzzer keeps SIGALRM (its timeout), SIGUSR1 and SIGUSR2 (its exits) for itself


def backstop_s(hang_s: float) -> int:
    """libFuzzer's wall-clock `-timeout` behind the watch: 30 times the bound, at least 5 minutes."""
    return max(300, int(30 * hang_s) + 1)


class Hang(BaseException):
    """An input ran past its time. A BaseException, as KeyboardInterrupt is, so that a target's own
    `except Exception` cannot swallow it."""


class HangWatch:
    """Interrupts the main thread's input once its own time passes `hang_s` (use `with watch:` around the run, and
    `with watch.input():` around each input). `waited_s` says how long the main thread has waited for a CPU so far
    (None: not known); the default reads the kernel's count."""

    def __init__(self, hang_s: float = HANG_S, clock: Optional[Clock] = None,
                 waited_s: Optional[Callable[[], Optional[float]]] = None) -> None:
        self.hang_s = hang_s
        self.clock = clock or RealClock()
        main_id = threading.main_thread().native_id
        self._waited_s = waited_s or (lambda: RealClock.cpu_wait_s(main_id))
        self._started: Optional[tuple[float, Optional[float]]] = None   # the running input's start, the wait then
        self._looked: Optional[float] = None       # the main thread's CPU wait at the latest look
        self._fired_for: Optional[tuple[float, Optional[float]]] = None   # the input the watch interrupted
        self._stop = threading.Event()
        self._thread: Optional[threading.Thread] = None
        self._previous = None

    # ---- the judgement (no thread, no signal: tests drive it with a SimClock) ----
    def overdue(self) -> Optional[str]:
        """Why the running input is a hang, or None (none running, or still within its time). Each call is a look:
        it reads the main thread's CPU wait, from which the next input counts."""
        started = self._started
        self._looked = waited_now = self._waited_s()
        if started is None:
            return None
        wall = self.clock.now() - started[0]
        waited_then = started[1]
        waited = 0.0 if waited_now is None or waited_then is None else max(0.0, waited_now - waited_then)
        own = wall - waited
        if own <= self.hang_s:
            return None
        return (f"one input ran {own:.1f} s of its own time, past the {self.hang_s:g} s of --hang-s "
                f"({wall:.1f} s of wall time, {waited:.1f} s of it waiting for a CPU)")

    @contextmanager
    def input(self) -> Iterator[None]:
        """Around one input: its time starts now and ends with the block."""
        self._started = (self.clock.now(), self._looked)
        try:
            yield
        finally:
            self._started = None

    # ---- the watch ----
    def __enter__(self) -> "HangWatch":
        self.overdue()           # the first look: the CPU wait the first input counts from
        if threading.current_thread() is not threading.main_thread():
            return self          # a signal reaches only the main thread: no watch (in a fuzzing child, libFuzzer's
                                 # wall-clock backstop is still there)
        self._previous = signal.signal(_SIGNAL, self._interrupt)
        self._stop.clear()
        self._thread = threading.Thread(target=self._watch, name="aspod-hang-watch", daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        if self._thread is None:
            return
        self._stop.set()
        self._thread.join()
        self._thread = None
        signal.signal(_SIGNAL, self._previous)

    def _watch(self) -> None:
        while not self._stop.wait(POLL_S):
            if self.look():
                signal.pthread_kill(threading.main_thread().ident, _SIGNAL)

    def look(self) -> bool:
        """One look of the watch: whether to interrupt the main thread now (once per input, until the interrupt
        finds it within its time after all)."""
        started, why = self._started, self.overdue()      # every look reads the CPU wait the next input counts from
        if started is None or why is None or started is self._fired_for:
            return False
        self._fired_for = started
        return True

    def interrupt(self) -> None:
        """On the main thread, interrupted by the watch: raise `Hang` if the running input is past its time, judged
        again now (it may have ended since the watch looked, or been within its time: see the module's docstring);
        else arm the watch again."""
        why = self.overdue()
        if why is None:
            self._fired_for = None
            return
        raise Hang(why)

    def _interrupt(self, signum, frame) -> None:
        self.interrupt()
