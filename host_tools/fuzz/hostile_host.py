"""The host under test of the hostile controller (host_tools/fuzz/hostile.py): its process, started per session,
its output read as it comes, its own time; and what makes two of its failures the same bug.
"""
from __future__ import annotations

import os
import re
import signal
import subprocess
import threading
from collections import deque
from typing import Optional

from timebase import RealClock

from host_tools.fuzz import findings as findings_mod
from host_tools.worlds.child import out_of_time
from host_tools.worlds.own_time import OwnTime

_CLOCK = RealClock()           # the wall clock (timebase: the one module that reads it)
THREADS_LOOK_S = 0.5           # a host's threads, and its own time's readings of /proc, at most this often
STOP_WAIT_S = 2.0              # of its own time, for a host to end after SIGTERM (then SIGKILL)
TAIL_LINES = 40                # of the host's stderr, kept for a finding
TRACEBACK = "Traceback (most recent call last):"
EXCEPTION_LINE = re.compile(r"^[A-Za-z_][\w.]*(Error|Exception|Interrupt|Exit)\b")    # a traceback's last line
EXIT_OK = (0, 1, 3)            # aspod's own: done, a command failed, the link failed (host_tools/exit_codes.py)


def signature(failure: findings_mod.Failure) -> tuple:
    """What makes two failures of a host the same bug: the kind and oracle, and the exception a traceback ends with
    (its type and the place it was raised), else the error with its numbers taken out (a probe's exit status, a
    silence's seconds)."""
    lines = failure.trace.splitlines()
    ends = [i for i, line in enumerate(lines) if EXCEPTION_LINE.match(line)]
    if ends:
        places = [line.strip() for line in lines[:ends[-1]] if line.strip().startswith("File ")]
        return (failure.kind, failure.oracle, lines[ends[-1]].split(":", 1)[0], places[-1] if places else "")
    return (failure.kind, failure.oracle, re.sub(r"[\d.]+", "N", failure.error))


def with_values(words: tuple[str, ...], url: str, key: str) -> list[str]:
    """A command's words with `{url}` and `{key}` put in."""
    return [w.replace("{url}", url).replace("{key}", key) for w in words]


class Host:
    """The host's process, started by the fuzzer: its stdout and stderr read as it writes them (a full pipe would
    stop it: a false hang), a traceback on stderr noted, its own time for the judging of its silence."""

    def __init__(self, argv: list[str]) -> None:
        self.argv = argv
        self.proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, start_new_session=True)
        self.err: deque[str] = deque(maxlen=TAIL_LINES)
        self.traceback = False
        self.in_session = False          # it has opened a session with the fuzzer
        self.threads: tuple[int, ...] = ()
        self.own = self._own_time()
        self._threads_s = _CLOCK.now()
        self._readers = [threading.Thread(target=self._read, args=(pipe, keep), daemon=True)
                         for pipe, keep in ((self.proc.stdout, False), (self.proc.stderr, True))]
        for reader in self._readers:
            reader.start()

    def _read(self, pipe, keep: bool) -> None:
        for raw in iter(pipe.readline, b""):
            if keep:
                line = raw.decode(errors="replace").rstrip("\n")
                self.err.append(line)
                self.traceback = self.traceback or TRACEBACK in line

    def _own_time(self) -> OwnTime:
        """Its own time from now on: its process tree's, and its threads' (a client's pump thread kept from running
        while the main thread sleeps on a call is a host kept from running, not a hung one: /proc/PID/schedstat is
        the main thread's alone)."""
        return OwnTime(self.proc.pid, RealClock(), tree=True, fresh_s=THREADS_LOOK_S, peers=self.threads)

    def heard(self) -> None:
        """It said something on the link: its silence, if any, begins now (its threads looked at again now and
        then, for the threads it has started since)."""
        now = _CLOCK.now()
        if now - self._threads_s < THREADS_LOOK_S:
            self.own.begin()
            return
        self._threads_s = now
        try:
            tasks = os.listdir(f"/proc/{self.proc.pid}/task")
            threads = tuple(sorted(int(t) for t in tasks if int(t) != self.proc.pid))
        except (OSError, ValueError):
            threads = self.threads
        if threads != self.threads:
            self.threads = threads
            self.own = self._own_time()
        else:
            self.own.begin()

    def status(self) -> Optional[int]:
        return self.proc.poll()

    def stderr(self) -> str:
        for reader in self._readers:
            if self.proc.poll() is not None:
                reader.join(0.5)         # its last lines, the traceback among them
        return "\n".join(self.err)

    def stop(self) -> None:
        """SIGTERM to its process group, SIGKILL after `STOP_WAIT_S` of its own time."""
        for sig in (signal.SIGTERM, signal.SIGKILL):
            if self.proc.poll() is not None:
                break
            try:
                os.killpg(self.proc.pid, sig)
            except ProcessLookupError:
                break
            own = OwnTime(self.proc.pid, RealClock(), tree=True)
            while self.proc.poll() is None and not out_of_time(own.look(), STOP_WAIT_S):
                _CLOCK.sleep(0.01)
        self.proc.wait()
        for reader in self._readers:
            reader.join(1.0)
