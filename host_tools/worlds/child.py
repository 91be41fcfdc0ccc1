"""`aspod ...` as a child process: start it, read its lines (its ready line first), stop it cleanly.

One helper for every parent: `aspod sim --hal` (its `aspod plant`), `aspod demo --link` (its
`aspod sim`), the end-to-end tests and the live benches.

    child = Child(["sim", "--pty"], env=env)
    url = child.ready("ASPOD-LINK ").split(" ", 1)[1]
    ...
    status, stderr = child.stop()      # SIGINT, then SIGTERM, then SIGKILL, each after a timeout

Its stdout (and stderr, unless inherited or discarded) is an unbuffered pipe read a byte at a
time behind a selector, so a line is waited for with a bound and no byte is left in a buffer
that the selector cannot see. Lines read from stderr are kept in `seen`; `stop` returns the rest.
A wait that runs out, or a child that ends before its line, raises `ChildError` (an OSError).

Every bound is on the child's own time, not the wall clock alone (host_tools/worlds/own_time.py): the
wall time less the longest wait for a CPU of the child, the processes it starts, and its `peers` (the
processes it waits on in turn: a teleop's sim). At load 45-49 on 2 CPUs `aspod sim` took over 30 s of
wall time to print its first line, its own time a few seconds; a child stuck, stopped or looping still
runs out of its own time as on a quiet machine. A bound of wall time stays behind it, `WALL_FACTOR`
times as long, for a child never given a CPU at all. `run` is `subprocess.run` with the same bound.
"""
from __future__ import annotations

import collections
import re
import selectors
import signal
import subprocess
import sys
import threading
from typing import IO, Any, Callable, Mapping, Optional, Sequence

from timebase import RealClock

from host_tools.worlds.own_time import Look, OwnTime

ASPOD = (sys.executable, "-m", "host_tools.cli.main")
PIPE, DEVNULL = subprocess.PIPE, subprocess.DEVNULL
LINE_TIMEOUT_S = 30.0        # of the child's own time, for each byte of a line
STOP_TIMEOUT_S = 10.0        # of its own time, for each signal of `stop`
EOF_EXIT_WAIT_S = 5.0
WALL_FACTOR = 20             # a bound of own time is also one of this many times as much wall time
LOOK_S = 1.0                 # how often a wait that has not ended looks at the child's own time
STDERR_TAIL_BYTES = 4096     # of an ended child's stderr, quoted in the ChildError
STDERR_TAIL_WAIT_S = 1.0     # for each read of it
STDERR_TAIL_LINES = 12       # of a child read as it goes (`keep_reading`), kept for `stop`


class ChildError(OSError):
    """The child said nothing in time, said something else, or ended before it said it."""


def describe_exit(status: int) -> str:
    """`exit status N`, or `killed by SIGNAME` for a negative status."""
    if status < 0:
        try:
            name = signal.Signals(-status).name
        except ValueError:
            name = str(-status)
        return f"killed by {name}"
    return f"exit status {status}"


class Child:
    """`aspod <args>` as a subprocess, stdout a pipe.

    `stdin`: DEVNULL (default), PIPE (the child can watch it for end of file: its parent is gone)
    or a file. `stderr`: PIPE (default: read it with `line(stream="stderr")`, `wait_stderr`, or at
    `stop`), None (this process's stderr) or DEVNULL. `new_session`: a Ctrl-C at the terminal
    reaches only the parent, which then stops the child. `command` replaces `aspod` (ASPOD) as the
    program and its first arguments. `peers`: processes the child waits on, whose waits for a CPU
    excuse it too (the module's doc).
    """

    def __init__(self, args: Sequence[str], *, env: Optional[Mapping[str, str]] = None, stdin=DEVNULL,
                 stderr=PIPE, new_session: bool = False, command: Sequence[str] = ASPOD,
                 peers: Sequence[int] = ()) -> None:
        self.peers = tuple(peers)
        self.args = list(args)
        self.argv = [*command, *self.args]
        self.name = f"aspod {self.args[0]}" if command == ASPOD and self.args else str(self.argv[0])
        self.proc = subprocess.Popen(self.argv, stdin=stdin, stdout=PIPE, stderr=stderr, env=env, bufsize=0,
                                     start_new_session=new_session)
        self.pid = self.proc.pid
        self.seen: list[str] = []       # stderr lines read so far
        self.stopped = False            # the parent asked it to stop
        self._follower: Optional[threading.Thread] = None
        self._drainer: Optional[threading.Thread] = None     # reads its stdout as it goes (`keep_reading`)
        self._tail: Optional[collections.deque] = None      # its last stderr lines, if read as it goes

    def _stream(self, stream) -> IO[bytes]:
        if stream is None or stream == "stdout":
            return self.proc.stdout
        if stream == "stderr":
            if self.proc.stderr is None:
                raise ValueError(f"{self.name}: its stderr is not a pipe")
            return self.proc.stderr
        return stream

    def own_time(self) -> OwnTime:
        """The child's own time from now on (its tree's, and its peers'), for a wait on it."""
        return OwnTime(self.pid, RealClock(), tree=True, fresh_s=LOOK_S, peers=self.peers)

    def line(self, timeout_s: float = LINE_TIMEOUT_S, stream=None) -> str:
        """The next line of stdout (or `stream="stderr"`), waiting at most `timeout_s` of the child's own time (and
        `WALL_FACTOR` times that of wall time) for each byte."""
        pipe = self._stream(stream)
        data = bytearray()
        own = self.own_time()
        with selectors.DefaultSelector() as sel:
            sel.register(pipe, selectors.EVENT_READ)
            while not data.endswith(b"\n"):
                if not sel.select(min(LOOK_S, timeout_s)):
                    look = own.look()
                    if not out_of_time(look, timeout_s) or sel.select(0):
                        continue
                    raise ChildError(f"{self.name} (pid {self.pid}): nothing for {look.describe()}, past "
                                     f"{timeout_s:g} s of its own time (so far {bytes(data)!r}; stderr so far "
                                     f"{self.seen})")
                own.begin()
                byte = pipe.read(1)
                if not byte:
                    try:
                        status = self.proc.wait(timeout=EOF_EXIT_WAIT_S)   # its output closes as it exits
                    except subprocess.TimeoutExpired:
                        status = None
                    ended = f"ended ({describe_exit(status)})" if status is not None else "closed its output"
                    if status is not None:
                        self.seen.extend(self._stderr_left())
                    raise ChildError(f"{self.name} (pid {self.pid}) {ended} (so far {bytes(data)!r}; "
                                     f"stderr so far {self.seen})")
                data += byte
        return data.decode(errors="replace").rstrip("\n")

    def _stderr_left(self, limit: int = STDERR_TAIL_BYTES) -> list[str]:
        """The lines an ended child left on its stderr pipe (the reason it gives for ending), at most the last
        `limit` bytes; [] if stderr is not ours to read. Bounded in time too: a grandchild may hold the pipe."""
        pipe = self.proc.stderr
        if pipe is None or self._follower is not None:
            return []
        data = bytearray()
        with selectors.DefaultSelector() as sel:
            sel.register(pipe, selectors.EVENT_READ)
            while sel.select(STDERR_TAIL_WAIT_S):
                chunk = pipe.read(4096)
                if not chunk:
                    break
                data += chunk
                del data[:-limit]
        return data.decode(errors="replace").splitlines()

    def ready(self, prefix: str, timeout_s: float = LINE_TIMEOUT_S) -> str:
        """The next stdout line, which must start with `prefix` (its ready line); ChildError else."""
        text = self.line(timeout_s)
        if not text.startswith(prefix):
            raise ChildError(f"{self.name} (pid {self.pid}) said {text!r}, not {prefix!r}...")
        return text

    def wait_stderr(self, pattern: str, timeout_s: float = LINE_TIMEOUT_S) -> re.Match:
        """Read stderr until a line matches `pattern` (every line read is kept in `seen`)."""
        for old in self.seen:
            found = re.search(pattern, old)
            if found:
                return found
        while True:
            text = self.line(timeout_s, "stderr")
            self.seen.append(text)
            found = re.search(pattern, text)
            if found:
                return found

    def follow_stderr(self, on_line: Callable[[str], None]) -> None:
        """From now on hand every stderr line to `on_line` as it is written, from a thread of its own (a
        parent that watches a long run's stderr as it goes); `stop` then returns "" for the rest, which
        `on_line` has had."""
        if self.proc.stderr is None:
            raise ValueError(f"{self.name}: its stderr is not a pipe")
        stderr = self.proc.stderr

        def follow() -> None:
            for raw in iter(stderr.readline, b""):
                on_line(raw.decode(errors="replace").rstrip("\n"))
        self._follower = threading.Thread(target=follow, name=f"{self.name} stderr", daemon=True)
        self._follower.start()

    def keep_reading(self, tail: int = STDERR_TAIL_LINES) -> None:
        """From now on read all it writes as it writes it: stdout dropped, stderr's last `tail` lines kept for
        `stop`. For a parent that reads nothing more of a long-running child: a pipe no one reads holds 64 KiB, and
        then stops the child in its next write (an `aspod sim` logging every state change stopped so after about
        10,000 cases of the black-box fuzzer, which took it for a hung target; 2026-11-29)."""
        self._tail = collections.deque(maxlen=tail)
        self.follow_stderr(self._tail.append)
        stdout = self.proc.stdout

        def drain() -> None:
            while stdout.read(65536):
                pass
        self._drainer = threading.Thread(target=drain, name=f"{self.name} stdout", daemon=True)
        self._drainer.start()

    def wait_for(self, held: Callable[[float], bool], timeout_s: float) -> bool:
        """Until `held(seconds)` is True: a wait of at most that many seconds for something this child is to do
        (`lambda s: client.wait_for(predicate, s)`), asked again until the child has had `timeout_s` of its own time
        (or `WALL_FACTOR` times that of wall time); then its last answer."""
        own = self.own_time()
        while not held(min(LOOK_S, timeout_s)):
            if out_of_time(own.look(), timeout_s):
                return held(0.0)
        return True

    def wait_exit(self, timeout_s: float) -> int:
        """Its exit status once it ends by itself, waiting at most `timeout_s` of its own time (and `WALL_FACTOR`
        times that of wall time); ChildError past it (it is left running)."""
        try:
            return _wait(lambda wait_s: self.proc.wait(timeout=wait_s), self.own_time(), timeout_s)
        except subprocess.TimeoutExpired:
            raise ChildError(f"{self.name} (pid {self.pid}) has not ended after {timeout_s:g} s of its own "
                             "time") from None

    def exit_status(self) -> Optional[int]:
        """None while it runs; its exit status (negative: killed by that signal) once it has ended."""
        return self.proc.poll()

    def stop(self, first: int = signal.SIGINT, timeout_s: float = STOP_TIMEOUT_S) -> tuple[int, str]:
        """`first` (SIGINT), then SIGTERM, then SIGKILL, each after `timeout_s` of the child's own time (and
        `WALL_FACTOR` times that of wall time) without an end; returns (exit status, the rest of its stderr if that
        is a pipe, else "")."""
        if self.stopped and self.proc.returncode is not None:
            return self.proc.returncode, ""      # stopped before
        self.stopped = True
        steps = list(dict.fromkeys((first, signal.SIGTERM, signal.SIGKILL)))
        steps = steps[:steps.index(signal.SIGKILL) + 1]
        err = b""
        own = self.own_time()
        for sig in steps:
            if self.proc.poll() is None:
                self.proc.send_signal(sig)
            own.begin()
            try:
                if self._follower is not None:          # its stderr is the follower's to read
                    _wait(lambda wait_s: self.proc.wait(timeout=wait_s), own, timeout_s)
                else:
                    _, err = _wait(lambda wait_s: self.proc.communicate(timeout=wait_s), own, timeout_s)
                break
            except subprocess.TimeoutExpired as exc:    # (after SIGKILL: a grandchild still holds the pipe)
                err = exc.stderr or err
        self.proc.wait()
        for reader in (self._follower, self._drainer):
            if reader is not None:
                reader.join(EOF_EXIT_WAIT_S)
        for stream in (self.proc.stdin, self.proc.stdout, self.proc.stderr):
            if stream is not None and not stream.closed:
                stream.close()
        if self._tail is not None:
            return self.proc.returncode, "\n".join(self._tail)
        return self.proc.returncode, (err or b"").decode(errors="replace")


def out_of_time(look: Look, timeout_s: float) -> bool:
    """A wait for a child has run out: past `timeout_s` of its own time, or `WALL_FACTOR` times that of wall time."""
    return look.own_s > timeout_s or look.wall_s > WALL_FACTOR * timeout_s


def _wait(step: Callable[[float], Any], own: OwnTime, timeout_s: float) -> Any:
    """`step(seconds)` (a Popen's `wait` or `communicate`, which raise subprocess.TimeoutExpired and lose nothing
    when called again) until it returns, or until the child is out of its own time: then its last TimeoutExpired."""
    while True:
        try:
            return step(min(LOOK_S, timeout_s))
        except subprocess.TimeoutExpired:
            if out_of_time(own.look(), timeout_s):
                raise


def run(argv: Sequence[str], *, timeout_s: float, input: Any = None, peers: Sequence[int] = (),
        **popen: Any) -> subprocess.CompletedProcess:
    """`subprocess.run(argv, capture_output=True, input=input, **popen)` with its bound, `timeout_s`, on the child's
    own time (its tree's, and its `peers`': the module's doc) and `WALL_FACTOR` times that of wall time: past it the
    child is killed and subprocess.TimeoutExpired raised, holding what it wrote.

    Its input is written, and its output read, by threads of their own: `Popen.communicate` called again after a
    timeout goes on reading but never writes the rest of the input (CPython 3.11), so a child given more than a pipe
    holds would wait for it for ever."""
    if input is not None:
        popen["stdin"] = PIPE
    with subprocess.Popen(argv, stdout=PIPE, stderr=PIPE, **popen) as proc:
        own = OwnTime(proc.pid, RealClock(), tree=True, fresh_s=LOOK_S, peers=tuple(peers))
        got: dict[str, Any] = {}

        def read(name: str, pipe) -> None:
            got[name] = pipe.read()

        def write() -> None:
            try:
                proc.stdin.write(input)
                proc.stdin.close()
            except (BrokenPipeError, ValueError):     # it ended, or stopped reading: what it read is its input
                pass
        threads = [threading.Thread(target=read, args=("out", proc.stdout), daemon=True),
                   threading.Thread(target=read, args=("err", proc.stderr), daemon=True)]
        if input is not None:
            threads.append(threading.Thread(target=write, daemon=True))
        for thread in threads:
            thread.start()
        try:
            _wait(lambda wait_s: proc.wait(timeout=wait_s), own, timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            raise subprocess.TimeoutExpired(proc.args, timeout_s, *_joined(threads, got)) from None
        out, err = _joined(threads, got)
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


def _joined(threads: list[threading.Thread], got: dict[str, Any]) -> tuple[Any, Any]:
    """What the child wrote on stdout and stderr, once the threads reading them are done (bounded: a grandchild may
    hold a pipe open)."""
    for thread in threads:
        thread.join(EOF_EXIT_WAIT_S)
    return got.get("out"), got.get("err")
