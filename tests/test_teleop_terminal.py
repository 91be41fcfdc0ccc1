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


@pytest.mark.parametrize("columns,rows", SIZES)
def test_the_console_fits_the_terminal_and_pages_helps_watches_and_clears(start_sim, console, columns, rows):
    """Every line the console writes fits the terminal (tmux joins what it had to wrap: none may be wider); `help`
    is an index by job, paged; `help move` speaks in degrees; the key that ends `watch` begins the next line;
    `params` pages; `clear` clears; the bottom toolbar shows the link, the round trip and the time."""
    _sim, url = start_sim("--sun-start", "2026-03-20T06:50-07:00")
    term = console(url, columns, rows)
    term.shows(rf"^ link UP {url} \| round trip [\d.]+ ms \| time paced [\d.]+x real time$")
    term.type("help")
    term.shows(r"^commands by job .*^arm$.*-- \d+/\d+ lines: any key for more, q to stop --")
    term.key("q")
    term.until(lambda: "any key for more" not in term.screen())      # the pager's line gone: the prompt is back
    at = term.mark()
    term.type("help move")
    term.shows(r"^move AXIS TARGET \[SPEED\]$.*TARGET +a number of degrees, from -360 to 360.*aspod IDLE >", at)
    for line in ("telemetry 10", "clock now", "switch sensor on"):
        at = term.mark()
        term.type(line)
        term.shows(r"^ok   .*aspod IDLE >", at)
    at = term.mark()
    term.type("watch")
    term.shows(r"^axis +homed +position.*^mount .*\(any key ends watch\)", at)
    term.type("s", enter=False)                         # ends watch, and is the first letter of the next line
    term.shows(r"aspod IDLE > s$", at)
    term.type("tatus")
    term.shows(r"^ok   Status .*aspod IDLE >", at)
    at = term.mark()
    term.type("box")
    term.shows(r"^axis +mode +dir +speed +% +relay +brake +% +mV +V +deg +deg$\n^az .*^warnings: .*aspod IDLE >", at)
    at = term.mark()
    term.type("params")
    term.shows(r"^  name +value +unit +range +what it does$.*-- \d+/\d+ lines: any key for more, q to stop --", at)
    term.key("q")
    term.until(lambda: "any key for more" not in term.screen())
    term.shows(r"aspod IDLE > ?$", at)
    too_wide = [line for line in term.lines() if len(line) > columns]
    assert not too_wide, "\n".join(too_wide)
    term.type("clear")
    term.until(lambda: term.visible()[0].startswith("aspod IDLE >"))      # the screen begins at the prompt
    term.type("quit")
    assert term.wait_exit() == 0
    too_wide = [line for line in term.lines() if len(line) > columns]     # the exit summary too
    assert not too_wide and "commands: " in term.screen(), "\n".join(too_wide)
