"""The interactive console (host_tools/teleop/console.py) on prompt_toolkit's pipe input and a vt100 output to a
buffer: completion, events printed above the prompt without losing what is typed, link loss said at once,
the prompt's state, history that never fails, output wrapped to the terminal."""
from __future__ import annotations

import io
import os
import re
import subprocess
import sys
import threading
from contextlib import contextmanager
from types import SimpleNamespace

import pytest

from prompt_toolkit.application import get_app_session
from prompt_toolkit.data_structures import Size
from prompt_toolkit.document import Document
from prompt_toolkit.history import InMemoryHistory
from prompt_toolkit.input import create_pipe_input
from prompt_toolkit.output.vt100 import Vt100_Output

from protocol.link import LinkState
from protocol.messages import SCHEMA
from protocol.reasons import Reason
from protocol.states import ControllerState
from timebase import RealClock

from host_tools.teleop import format as teleop_format
from host_tools.teleop import words as teleop_words
from host_tools.teleop.console import (TeleopCompleter, TeleopConsole, fit, follow_width,
                                       history_path, open_history, prompt_text)
from host_tools.teleop.watch import TelemetryCache

PARAMS = ["j1_max_deg", "j1_min_deg", "j1_speed_dps", "trk_dial_low_pct"]


class FakeClient:
    """What the console and Session use of a HostClient: listeners, the link's state and statistics, call()."""

    def __init__(self) -> None:
        self.clock = RealClock()
        self.url = "/dev/pts/test"
        self.io_error = None
        self.telemetry_listeners, self.event_listeners = [], []
        stats = SimpleNamespace(crc_errors=0, auth_errors=0)
        self.link = SimpleNamespace(state=LinkState.UP, stats=stats, event_from_earlier_session=False)

    def call(self, msg, timeout_s: float = 30.0):
        if msg.spec.name == "ParamList":
            reply = SCHEMA["ParamValue"].type(0, PARAMS[msg.index], 1.0, 0.0, 2.0, msg.index, len(PARAMS), "", "")
            return SimpleNamespace(ok=True, reply=reply, latency_s=0.001)
        raise AssertionError(f"unexpected {msg.spec.name}")

    def event(self, msg) -> None:
        for listener in list(self.event_listeners):
            listener(msg, self.clock.now())


def test_completion_offers_parameters_switch_positions_and_only_the_axes_a_motion_takes():
    c = TeleopCompleter(lambda: PARAMS)
    assert c.options("mo") == ["move", "moveby"]
    assert c.options("move ") == ["j1", "j2", "j3", "j4", "mount"]        # the controller refuses all, gripper
    assert c.options("jog ") == ["j1", "j2", "j3", "j4", "mount"]
    assert c.options("home ") == ["j1", "j2", "j3", "j4", "gripper", "mount", "all"]
    assert c.options("set j1_m") == ["j1_max_deg", "j1_min_deg"]
    assert c.options("get ") == sorted(PARAMS)
    assert c.options("switch main ") == ["off", "on"]
    assert c.options("switch mode ") == ["manual", "sensor"]
    assert c.options("switch direction c") == ["cw", "ccw"]
    assert c.options("switch speed ") == ["brake", "on"]
    assert c.options("switch main on ") == ["both"]
    assert c.options("switch speed on ") == ["az", "el", "both"]
    assert c.options("expect DIAL_NOT_LOW switch mode ") == ["manual", "sensor"]
    done = list(c.get_completions(Document("switch sensor o"), None))
    assert [(x.text, x.start_position) for x in done] == [("off", -1), ("on", -1)]
    described = TeleopCompleter(lambda: PARAMS, lambda name: "deg  upper soft limit" if name == "j1_max_deg" else "")
    menu = {x.text: x.display_meta_text for x in described.get_completions(Document("set j1_m"), None)}
    assert menu == {"j1_max_deg": "deg  upper soft limit", "j1_min_deg": ""}


def test_history_is_per_user_and_never_fails(tmp_path):
    assert str(history_path({"XDG_STATE_HOME": "/s", "HOME": "/h"})) == "/s/aspod/teleop_history"
    assert str(history_path({"HOME": "/h"})) == "/h/.local/state/aspod/teleop_history"
    history = open_history(tmp_path / "a" / "teleop_history")
    history.store_string("status")
    assert list(open_history(tmp_path / "a" / "teleop_history").load_history_strings()) == ["status"]
    blocker = tmp_path / "file"
    blocker.write_text("")
    assert isinstance(open_history(blocker / "x" / "teleop_history"), InMemoryHistory)     # cannot be made: in memory


def _msg(name: str, **values):
    spec = SCHEMA[name]
    return spec.type(**{f.name: values.get(f.name, 0) for f in spec.fields})


def test_prompt_shows_the_state_faults_and_moving_axes():
    client, cache = FakeClient(), TelemetryCache()
    assert prompt_text(client, cache) == "aspod ? > "
    cache.on_telemetry(_msg("TelemetryStatus", state=int(ControllerState.FAULT), faults=1), 0.0)
    assert prompt_text(client, cache).startswith("aspod FAULT ")
    cache.on_telemetry(_msg("TelemetryStatus", state=int(ControllerState.ENABLED)), 0.0)
    cache.on_telemetry(_msg("TelemetryJoints", j1_pos=3.04, j1_vel=3.0), 0.0)
    assert prompt_text(client, cache) == "aspod ENABLED j1 3.0° > "
    client.link.state = LinkState.SUSPENDED
    assert prompt_text(client, cache).startswith("aspod LINK ")


@pytest.fixture(autouse=True)
def _widths_restored():
    """The console sets teleop's output widths for the process (follow_width); other tests' scripts expect 96."""
    widths = teleop_format.WIDTH, teleop_words.HELP_WIDTH
    yield
    teleop_format.WIDTH, teleop_words.HELP_WIDTH = widths


def test_output_follows_the_terminal_width():
    assert follow_width(80) == 79 and teleop_format.WIDTH == 79 and teleop_words.HELP_WIDTH == 79
    assert max(map(len, teleop_words.help_text().split("\n"))) <= 79
    assert follow_width(200) == 96
    long = "ok   motion all started: one end per axis follows (j1, j2, j3, j4, gripper, mount) (15.8 ms)"
    lines = fit(long, 80)
    assert all(len(x) <= 79 for x in lines) and lines[1].startswith("     ")
    assert fit("short", 80) == ["short"]


def test_params_show_unit_range_and_description_wrapped_in_their_column_when_the_terminal_is_narrow():
    plain = SCHEMA["ParamValue"].type(0, "j1_speed_dps", 3.0, 0.1, 10.0, 0, 1, "", "")
    assert teleop_format.param_lines(plain) == ["  j1_speed_dps                3            [0.1 .. 10]"]
    described = SCHEMA["ParamValue"].type(0, "j1_speed_dps", 3.0, 0.1, 10.0, 0, 1, "deg/s",
                                          "the joint's default cruise speed, used when a move names none")
    assert teleop_format.param_lines(described) == [        # a script's: one line each, as they come
        "  j1_speed_dps                3 deg/s      [0.1 .. 10]  the joint's default cruise speed, used when a move "
        "names none"]
    wide = teleop_format.params_table([plain, described], 120)
    assert wide[0].split() == ["name", "value", "unit", "range", "what", "it", "does"]
    assert wide[2].split() == ["j1_speed_dps", "3", "deg/s", "0.1", "..", "10", "the", "joint's", "default",
                               "cruise", "speed,", "used", "when", "a", "move", "names", "none"]
    narrow = teleop_format.params_table([plain, described], 60)
    assert max(map(len, narrow)) <= 60 and len(narrow) > 3
    column = wide[0].index("what")                      # the description wraps under its own heading
    assert narrow[3].startswith(" " * column) and narrow[3].strip() in described.description
    assert " ".join(line[column:].strip() for line in narrow[2:]) == described.description


SHOWN_S = 60.0      # a step's effect on the screen: milliseconds on a quiet machine; this bound only ends a hang


@contextmanager
def _terminal(pipe, output):
    """The app session every thread sees, reading `pipe` and writing `output`, as a terminal is for `aspod teleop`.

    Not `create_app_session`: it sets a context variable, which the thread that writes the console's StdoutProxy does
    not see (a thread starts in a context of its own), so an event went to the screen without `run_in_terminal`:
    written after what was typed, and the prompt never drawn again under it, unlike in a terminal."""
    session = get_app_session()
    kept = session._input, session._output
    session._input, session._output = pipe, output
    try:
        yield
    finally:
        session._input, session._output = kept


def _run_console(client, steps):
    """Run the console on a pipe and a 80x24 vt100 output to a buffer, feeding it `steps` from another thread: each
    a text typed or a callable given the console, and a pattern of what the screen shows once it has taken effect
    (None: no wait), which the next step waits for. Returns (status, screen text).

    Each step waits for the console's own progress, its screen: with fixed pauses of the wall clock (0.5 s, then 0.4 s
    a step) a busy machine let an event be printed before the console had echoed what was typed before it."""
    buffer = io.StringIO()
    output = Vt100_Output(buffer, lambda: Size(rows=24, columns=80), term="xterm")
    clock = RealClock()
    with create_pipe_input() as pipe, _terminal(pipe, output):
        console = TeleopConsole(client, history=InMemoryHistory())

        missed: list[str] = []

        def shows(pattern: str, after: int) -> None:
            end = clock.now() + SHOWN_S
            while not re.search(pattern, buffer.getvalue()[after:], re.S):
                if clock.now() > end:
                    missed.append(pattern)
                    return
                clock.sleep(0.01)

        def feed() -> None:
            shows(PROMPT, 0)                         # the prompt is up
            for step, shown in steps:
                after = len(buffer.getvalue())
                if callable(step):
                    step(console)
                else:
                    pipe.send_text(step)
                if shown is not None:
                    shows(shown, after)
        thread = threading.Thread(target=feed, daemon=True)
        thread.start()
        status, session = console.run()
        thread.join()
    assert not missed, f"the screen never showed {missed}: {buffer.getvalue()!r}"
    return status, buffer.getvalue()


PROMPT = re.escape("aspod ? >")        # (its last space is drawn as a move of the cursor)


def test_an_event_prints_above_the_prompt_and_what_is_typed_stays():
    client = FakeClient()
    event = SCHEMA["StateChanged"].type(int(ControllerState.ENABLED), int(ControllerState.IDLE),
                                         int(Reason.HOST_REQUEST), 0, 1234)
    status, screen = _run_console(client, [("stat", "stat"),
                                           (lambda c: client.event(event), "! StateChanged.*" + PROMPT + " stat"),
                                           ("\x15quit\r", None)])
    assert status == 0
    at = screen.index("! StateChanged state=ENABLED")
    assert "stat" in screen[:at]                     # typed before the event came
    assert "aspod ? > stat" in screen[at:]           # and drawn again under it, still there


def test_losing_the_link_is_said_when_it_happens():
    client = FakeClient()

    def lose(_console) -> None:
        client.io_error = "device disconnected"
        client.link.state = LinkState.SUSPENDED
    status, screen = _run_console(client, [("ping", "ping"), (lose, "! LINK LOST.*aspod LINK LOST >"),
                                           ("\x15quit\r", None)])
    assert "! LINK LOST: /dev/pts/test: device disconnected" in screen
    assert "aspod LINK LOST > " in screen


def test_a_pty_read_that_finds_nothing_names_a_second_reader_while_the_simulator_runs(tmp_path):
    """pyserial's "returned no data" is the far end gone, or another program that read the bytes first: a simulator
    that no longer runs tells which; one whose process is still there (running, or stopping) leaves both said."""
    from host_tools.teleop.session import closed_text
    error = ("device reports readiness to read but returned no data (device disconnected or multiple access on "
             "port?)")
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)

    def client(pid: int):
        return SimpleNamespace(url="/dev/pts/9", io_error=error,
                               control=SimpleNamespace(path=tmp_path / f"sim-{pid}.sock"))
    assert closed_text(client(os.getpid())) == (                 # still running, or on its way out: either
        "the simulator closed its end of /dev/pts/9 (it stopped?), or another program reads it too and took what was "
        "meant for this one (multiple access on port?)")
    assert closed_text(client(int(dead.stdout))) == "the simulator closed its end of /dev/pts/9 (it stopped?)"
    gone = SimpleNamespace(url="/dev/pts/9", io_error="[Errno 5] Input/output error",
                           control=SimpleNamespace(path=tmp_path / f"sim-{os.getpid()}.sock"))
    assert closed_text(gone) == "the simulator closed its end of /dev/pts/9 (it stopped?)"
