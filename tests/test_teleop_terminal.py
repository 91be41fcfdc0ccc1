"""`aspod teleop`'s console as a user meets it (issue 36): a real `aspod sim --pty`, the console in a real tmux at
80x24 and 120x40. Every step waits for what the screen shows (tests/tmux_console.py), never a fixed time."""
from __future__ import annotations

import os
import signal

import pytest

from tests.tmux_console import TmuxConsole

pytestmark = pytest.mark.pty

SIZES = [(80, 24), (120, 40)]


@pytest.fixture
def env(tmp_path):
    """A runtime folder of the test's own (the simulators of other tests are not seen), and a private history."""
    (tmp_path / "run").mkdir(mode=0o700)
    (tmp_path / "tmp").mkdir()
    return {**os.environ, "XDG_CONFIG_HOME": str(tmp_path / "config"), "XDG_RUNTIME_DIR": str(tmp_path / "run"),
            "TMPDIR": str(tmp_path / "tmp"), "XDG_STATE_HOME": str(tmp_path / "state")}


@pytest.fixture
def console(tmp_path, env):
    terms = []

    def start(url: str, columns: int = 80, rows: int = 24) -> TmuxConsole:
        terms.append(TmuxConsole(tmp_path, ["teleop", url], env, columns, rows))
        terms[-1].shows(r"aspod IDLE >")
        return terms[-1]
    yield start
    for term in terms:
        term.close()


def test_connect_after_the_simulator_stopped_stays_in_the_console_and_takes_a_new_url(start_sim, console):
    first, url = start_sim()
    term = console(url)
    first.stop(signal.SIGTERM, timeout_s=30)
    term.shows(r"! LINK LOST: the simulator closed its end of \S+ \(it stopped\?\).*aspod LINK LOST >")
    at = term.mark()
    term.type("connect")                                  # nothing serves the old link: said, and the console stays
    term.shows(r"FAIL connect \S+: no simulator of yours serves.*aspod LINK LOST >", at)
    second, url2 = start_sim()
    at = term.mark()
    term.type(f"connect {url2}")
    term.shows(rf"ok   link up: {url2}, a new session.*aspod IDLE >", at)
    at = term.mark()
    term.type("ping")
    term.shows(r"ok   Pong .*aspod IDLE >", at)
    at = term.mark()
    term.type("connect no-such-scheme://x")               # a bad URL is refused before anything is opened
    term.shows(r"error: connect: .*no-such-scheme.*aspod IDLE >", at)   # no `line N:` at the prompt
    term.type("quit")
    term.wait_exit()
    screen = term.screen()
    assert "Errno" not in screen and "Traceback" not in screen, screen
    assert "commands: 1 sent, 1 ok" in screen                # the summary is of the session, on the new link
