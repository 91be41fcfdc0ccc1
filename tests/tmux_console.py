"""`aspod teleop`'s console in a real terminal: tmux, on a server of the test's own, at a size the test gives.

    with TmuxConsole(tmp_path, ["teleop", url], env, columns=80, rows=24) as term:
        term.shows(r"aspod IDLE > $")
        term.type("status")
        ...

A step waits for what the screen shows (`shows`: a pattern of the pane's text, its history included), looking
again every `LOOK_S`, with a generous bound that only ends a hang; it never sleeps a fixed time. The pane stays
after the program ends (remain-on-exit), so its last screen and its exit status can be read.
"""
from __future__ import annotations

import os
import re
import shlex
import signal
import subprocess
from pathlib import Path
from typing import Mapping, Optional, Sequence

from timebase import RealClock

from tests.aspod_cli import ASPOD

SHOWN_S = 120.0       # a step's effect on the screen: well under a second on a quiet machine; this ends a hang
LOOK_S = 0.02
EXITED = "aspod-exited"
TOOLBAR = " link "             # how the console's bottom toolbar begins (host_tools/teleop/console.py toolbar_text)        # the line the pane's shell prints with the exit status: `aspod-exited N`


class TmuxConsole:
    def __init__(self, folder: Path, args: Sequence[str], env: Mapping[str, str], columns: int = 80,
                 rows: int = 24) -> None:
        self.socket = folder / f"tmux-{columns}x{rows}.sock"
        config = folder / "tmux.conf"
        config.write_text("set -g remain-on-exit on\nset -g history-limit 10000\nset -g status off\n")
        command = " ".join(shlex.quote(a) for a in ["env", *(f"{k}={v}" for k, v in env.items()
                                                              if k.startswith(("XDG_", "TMPDIR", "HOME"))),
                                                    "PYTHONFAULTHANDLER=1",
                                                    *ASPOD, *args])
        # the exit status said on the screen by the shell that ran it: tmux marks a pane dead when its pty closes and
        # knows the status only once it has reaped the process, which it once had not 120 s later (a zombie)
        command += f"; echo {EXITED} $?"
        self.columns, self.rows = columns, rows
        self.clock = RealClock()
        self._tmux("-f", str(config), "new-session", "-d", "-x", str(columns), "-y", str(rows), "-s", "t",
                   "-c", str(Path.cwd()), command)

    def _tmux(self, *args: str) -> str:
        done = subprocess.run(["tmux", "-S", str(self.socket), *args], capture_output=True, text=True, timeout=60)
        assert done.returncode == 0, f"tmux {' '.join(args)}: {done.stderr}"
        return done.stdout

    def screen(self) -> str:
        """The pane's text, its history first: each line as the terminal shows it, wrapped as it wrapped."""
        return self._tmux("capture-pane", "-p", "-S", "-", "-t", "t")

    def lines(self) -> list[str]:
        """The pane's lines as the program wrote them: a line the terminal wrapped is joined again (tmux -J)."""
        return [line.rstrip() for line in self._tmux("capture-pane", "-p", "-J", "-S", "-", "-t", "t").split("\n")]

    def visible(self) -> list[str]:
        return self._tmux("capture-pane", "-p", "-t", "t").split("\n")[:self.rows]

    def type(self, text: str, enter: bool = True) -> None:
        if text:
            self._tmux("send-keys", "-t", "t", "-l", text)
        if enter:
            self._tmux("send-keys", "-t", "t", "Enter")

    def key(self, name: str) -> None:
        self._tmux("send-keys", "-t", "t", name)

    def shows(self, pattern: str, after: int = 0, bound_s: float = SHOWN_S) -> re.Match:
        """Wait until the screen's text from `after` on matches `pattern` (re.M | re.S)."""
        end = self.clock.now() + bound_s
        while True:
            text = self.screen()
            found = re.search(pattern, text[after:], re.M | re.S)
            if found:
                return found
            assert self.clock.now() < end, f"the screen never showed {pattern!r}:\n{text}"
            self.clock.sleep(LOOK_S)

    def until(self, condition, bound_s: float = SHOWN_S) -> None:
        """Wait until `condition()` is true (of the screen, say)."""
        end = self.clock.now() + bound_s
        while not condition():
            assert self.clock.now() < end, f"the screen never came to the condition:\n{self.screen()}"
            self.clock.sleep(LOOK_S)

    def mark(self) -> int:
        """Where the screen's text ends now (the bottom toolbar, ` link ...`, aside): `shows(..., after=mark)` looks
        only at what comes next."""
        text = self.screen().rstrip("\n")
        last = text.rfind("\n") + 1
        if text[last:].startswith(TOOLBAR):
            text = text[:last].rstrip("\n")
        return len(text)

    def exit_status(self) -> Optional[int]:
        """None while the program runs; its exit status once it has ended, as the shell that ran it said it."""
        said = re.findall(rf"^{re.escape(EXITED)} (\d+)$", self.screen(), flags=re.M)
        return int(said[-1]) if said else None

    def wait_exit(self, bound_s: float = SHOWN_S) -> int:
        end = self.clock.now() + bound_s
        while (status := self.exit_status()) is None:
            if self.clock.now() > end:          # where it hangs: PYTHONFAULTHANDLER prints each thread on SIGABRT
                pane = int(self._tmux("display-message", "-p", "-t", "t", "#{pane_pid}"))
                for pid in [pane, *_descendants(pane)]:        # the pane's shell may not have exec'd Python
                    try:
                        os.kill(pid, signal.SIGABRT)
                    except ProcessLookupError:
                        pass
                state = self._tmux("display-message", "-p", "-t", "t",
                                   "dead=#{pane_dead} status=#{pane_dead_status} signal=#{pane_dead_signal}")
                tree = subprocess.run(["ps", "-o", "pid,stat,wchan:20,cmd", "--ppid", str(pane), "-p", str(pane)],
                                      capture_output=True, text=True).stdout
                raise AssertionError(f"the console never ended ({state.strip()}):\n{tree}\n{self.screen()}")
            self.clock.sleep(LOOK_S)
        return status

    def close(self) -> None:
        subprocess.run(["tmux", "-S", str(self.socket), "kill-server"], capture_output=True, timeout=60)

    def __enter__(self) -> "TmuxConsole":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _descendants(pid: int) -> list[int]:
    """The processes below `pid` (from /proc), deepest last."""
    children = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            children += [int(c) for c in (task / "children").read_text().split()]
        except OSError:
            continue
    return [d for c in children for d in (c, *_descendants(c))]
