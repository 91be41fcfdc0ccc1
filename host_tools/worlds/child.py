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
"""
from __future__ import annotations

import re
import selectors
import signal
import subprocess
import sys
import threading
from typing import IO, Callable, Mapping, Optional, Sequence

ASPOD = (sys.executable, "-m", "host_tools.cli.main")
PIPE, DEVNULL = subprocess.PIPE, subprocess.DEVNULL
LINE_TIMEOUT_S = 30.0
STOP_TIMEOUT_S = 10.0
EOF_EXIT_WAIT_S = 5.0
STDERR_TAIL_BYTES = 4096     # of an ended child's stderr, quoted in the ChildError
STDERR_TAIL_WAIT_S = 1.0     # for each read of it


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
    program and its first arguments.
    """

    def __init__(self, args: Sequence[str], *, env: Optional[Mapping[str, str]] = None, stdin=DEVNULL,
                 stderr=PIPE, new_session: bool = False, command: Sequence[str] = ASPOD) -> None:
        self.args = list(args)
        self.argv = [*command, *self.args]
        self.name = f"aspod {self.args[0]}" if command == ASPOD and self.args else str(self.argv[0])
        self.proc = subprocess.Popen(self.argv, stdin=stdin, stdout=PIPE, stderr=stderr, env=env, bufsize=0,
                                     start_new_session=new_session)
        self.pid = self.proc.pid
        self.seen: list[str] = []       # stderr lines read so far
        self.stopped = False            # the parent asked it to stop
        self._follower: Optional[threading.Thread] = None

    def _stream(self, stream) -> IO[bytes]:
        if stream is None or stream == "stdout":
            return self.proc.stdout
        if stream == "stderr":
            if self.proc.stderr is None:
                raise ValueError(f"{self.name}: its stderr is not a pipe")
            return self.proc.stderr
        return stream

    def line(self, timeout_s: float = LINE_TIMEOUT_S, stream=None) -> str:
        """The next line of stdout (or `stream="stderr"`), waiting at most `timeout_s` for each byte."""
        pipe = self._stream(stream)
        data = bytearray()
        with selectors.DefaultSelector() as sel:
            sel.register(pipe, selectors.EVENT_READ)
            while not data.endswith(b"\n"):
                if not sel.select(timeout_s):
                    raise ChildError(f"{self.name} (pid {self.pid}): nothing for {timeout_s:g} s "
                                     f"(so far {bytes(data)!r}; stderr so far {self.seen})")
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

    def exit_status(self) -> Optional[int]:
        """None while it runs; its exit status (negative: killed by that signal) once it has ended."""
        return self.proc.poll()

    def stop(self, first: int = signal.SIGINT, timeout_s: float = STOP_TIMEOUT_S) -> tuple[int, str]:
        """`first` (SIGINT), then SIGTERM, then SIGKILL, each after `timeout_s` without an end; returns
        (exit status, the rest of its stderr if that is a pipe, else "")."""
        if self.stopped and self.proc.returncode is not None:
            return self.proc.returncode, ""      # stopped before
        self.stopped = True
        steps = list(dict.fromkeys((first, signal.SIGTERM, signal.SIGKILL)))
        steps = steps[:steps.index(signal.SIGKILL) + 1]
        err = b""
        for sig in steps:
            if self.proc.poll() is None:
                self.proc.send_signal(sig)
            try:
                if self._follower is not None:          # its stderr is the follower's to read
                    self.proc.wait(timeout=timeout_s)
                else:
                    _, err = self.proc.communicate(timeout=timeout_s)
                break
            except subprocess.TimeoutExpired as exc:    # (after SIGKILL: a grandchild still holds the pipe)
                err = exc.stderr or err
        self.proc.wait()
        if self._follower is not None:
            self._follower.join(EOF_EXIT_WAIT_S)
        for stream in (self.proc.stdin, self.proc.stdout, self.proc.stderr):
            if stream is not None and not stream.closed:
                stream.close()
        return self.proc.returncode, (err or b"").decode(errors="replace")
