"""`aspod teleop`'s interactive console, on prompt_toolkit (scripts never come here: session.run_script).

* Events (motion ends, faults, timing warnings) and the loss of the link are printed above the prompt
  as they happen, from the link's pump thread, and never overwrite what is being typed: every line of
  the session goes through one `StdoutProxy` (prompt_toolkit's `run_in_terminal` while a prompt runs).
* The prompt shows the controller as it is now, refreshed twice a second from the latest telemetry:
  `aspod ENABLED j1 3.0° >`, `aspod FAULT STALL >`, `aspod LINK DOWN >`.
* History is kept between sessions in `$XDG_STATE_HOME/aspod/teleop_history` (else
  `~/.local/state/aspod/teleop_history`); a history that cannot be written is kept in memory only.
* The loss of the link says what happened (the simulator closed its end, no answer for N s, another program on
  the line); `connect` opens a new session on the same link, `connect URL` (or `connect` once the port is gone)
  on a new one, with the key and control endpoint of the simulator serving it (`Session.connect`, through the
  `opener` cli/teleop.py gives); a failure says why and the console stays.
* Tab completes command words, parameter names after `get`/`set` (read from the controller with
  ParamList in the background), the positions the named switch has after `switch SWITCH`, and for the
  motions only the axes the controller takes (`move` neither `all` nor `gripper`).
* Output follows the terminal's width (tables: teleop/tables.py); `watch` redraws in place until a key is pressed
  (or its seconds, if given, run out), and that key begins the next line; a long `help` and `params` are shown a
  screenful at a time; `clear` clears the screen and the scrollback.
* A bottom toolbar: the link's state, the smoothed round trip, the controller's real-time factor (`toolbar_text`).
* `wait` fails when a motion it waited for ended other than as asked (FAULT, DISABLED, ...).
* `params` shows each parameter's unit and description when the controller sends them.
"""
from __future__ import annotations

import os
import textwrap
import threading
from pathlib import Path
from typing import Callable, Iterable, Optional, Sequence

from prompt_toolkit import PromptSession
from prompt_toolkit.application import Application
from prompt_toolkit.completion import Completer, Completion
from prompt_toolkit.document import Document
from prompt_toolkit.history import FileHistory, History, InMemoryHistory
from prompt_toolkit.key_binding import KeyBindings
from prompt_toolkit.layout import Layout, Window
from prompt_toolkit.layout.controls import FormattedTextControl
from prompt_toolkit.patch_stdout import StdoutProxy
from prompt_toolkit.shortcuts import clear

from protocol.host_link import CommandHandle
from protocol.link import LinkState
from protocol.states import SWITCH_POSITIONS, ControllerState, MotionOutcome, Switch, TimingMode

from host_tools.client.params import ParamTable, read_param_table
from host_tools.exit_codes import EXIT_FAILED, EXIT_LINK, EXIT_OK
from host_tools.teleop import format as teleop_format
from host_tools.teleop import words as teleop_words
from host_tools.teleop.box import box_block
from host_tools.teleop.format import INDENT, MIN_WIDTH, Console, enum_word, fit, format_faults, format_outcome
from host_tools.teleop.motion import axis_word, position_text
from host_tools.teleop.session import Session
from host_tools.teleop.watch import TELEMETRY_AXES, TelemetryCache, arm_block
from host_tools.teleop.words import REFUSED_AXES, TeleopError, completions, parse_line

PROMPT_REFRESH_S = 0.5
PROMPT_AXES = 2            # the prompt names at most this many moving axes, then says how many more move
WATCH_REFRESH_S = 0.1
LINK_CHECK_S = 0.25        # how often the link's state is looked at, to say at once that it is lost
MAX_WIDTH = 96             # the scripts' width: wider terminals keep it, narrower ones wrap to theirs
MAX_WATCH_S = 3600.0
# Switches that take no axis but `both` (protocol/messages.py BoxSwitch: "main and sensor: both only").
BOTH_ONLY = ("main", "sensor")
_STATE_NAMES = {int(s): s.name for s in ControllerState}


def history_path(environ: Optional[dict] = None) -> Path:
    """$XDG_STATE_HOME/aspod/teleop_history, else ~/.local/state/aspod/teleop_history."""
    environ = os.environ if environ is None else environ
    base = environ.get("XDG_STATE_HOME") or os.path.join(environ.get("HOME") or os.path.expanduser("~"),
                                                         ".local", "state")
    return Path(base) / "aspod" / "teleop_history"


class SafeFileHistory(FileHistory):
    """FileHistory that never fails: a file that cannot be read or written leaves the history in memory."""

    def load_history_strings(self) -> Iterable[str]:
        try:
            return list(super().load_history_strings())
        except OSError:
            return []

    def store_string(self, string: str) -> None:
        try:
            super().store_string(string)
        except OSError:
            pass


def open_history(path: Optional[Path] = None) -> History:
    path = history_path() if path is None else path
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(path, "ab"):
            pass
    except OSError:
        return InMemoryHistory()
    return SafeFileHistory(str(path))


class ParamNames:
    """The controller's parameter names (and ParamValue replies), read once with ParamList in the background."""

    def __init__(self, client) -> None:
        self.client = client
        self.table = ParamTable()           # empty until the whole table is read
        self._thread: Optional[threading.Thread] = None

    @property
    def replies(self) -> list:
        return self.table.replies

    @property
    def names(self) -> tuple[str, ...]:
        return self.table.names

    def meta(self, name: str) -> str:
        """`unit  description` of a parameter, "" for another word or before the list has come."""
        for reply in self.replies:
            if reply.name == name:
                return f"{reply.unit}  {reply.description}".strip()
        return ""

    def start(self) -> None:
        if self._thread is None:
            self._thread = threading.Thread(target=self.read, name="aspod-param-names", daemon=True)
            self._thread.start()

    def read(self) -> Optional[CommandHandle]:
        """Read the table; None, or the ParamList that failed (the names stay as they were)."""
        table = read_param_table(self.client, 5.0)
        if table.failed is None:
            self.table = table
        return table.failed


class TeleopCompleter(Completer):
    """words.completions, with what the console knows besides: parameter names, each switch's own positions,
    and no axis a motion command is refused for."""

    def __init__(self, param_names: Callable[[], Sequence[str]] = lambda: (),
                 param_meta: Callable[[str], str] = lambda name: "") -> None:
        self.param_names = param_names
        self.param_meta = param_meta      # a parameter's unit and description, shown beside it in the menu

    def options(self, line: str) -> list[str]:
        begin = len(line) - len(line.split(" ")[-1])
        text = line[begin:]
        before = line[:begin].split()
        if before and before[0].lower() == "expect":
            before = before[2:]
        spec = teleop_words.commands().get(before[0].lower()) if before else None
        position = len(before) - 1
        if spec is not None and spec.name in ("ParamGet", "ParamSet") and position == 0:
            return sorted(n for n in self.param_names() if n.startswith(text))
        found = completions(line, begin, text)
        if spec is None:
            return found
        if spec.name in REFUSED_AXES and position == 0:
            return [w for w in found if w not in REFUSED_AXES[spec.name]]
        if spec.name == "BoxSwitch" and position >= 1:
            switch = before[1].lower()
            if switch.upper() not in Switch.__members__:
                return found
            if position == 1:
                allowed = [p.name.lower() for p in SWITCH_POSITIONS[Switch[switch.upper()]]]
                return [w for w in allowed if w in found]      # in the switch's own order (off, on)
            if position == 2 and switch in BOTH_ONLY:
                return [w for w in found if w == "both"]
        return found

    def get_completions(self, document: Document, complete_event):
        line = document.text_before_cursor
        text = line[len(line) - len(line.split(" ")[-1]):]
        for option in self.options(line):
            yield Completion(option, start_position=-len(text), display_meta=self.param_meta(option))


def prompt_text(client, cache: TelemetryCache, running: Callable[[], list] = lambda: []) -> str:
    """`aspod ENABLED j1 3.0° >`: the link if it is not up, the state, the faults, the axes in motion and where
    they are now (from the latest telemetry)."""
    if client.io_error is not None or client.link.state is not LinkState.UP:
        return f"aspod LINK {client.link.state.value.upper() if client.io_error is None else 'LOST'} > "
    status, joints = cache.status, cache.joints
    if status is None:
        return "aspod ? > "
    parts = [_STATE_NAMES.get(status.state, str(status.state))]
    if status.faults:
        parts.append(format_faults(status.faults))
    if joints is not None:
        moving = {axis_word(m.axis) for m in running()}
        axes = [a for a in TELEMETRY_AXES if a in moving or abs(getattr(joints, f"{a}_vel")) > 0.05]
        for n, axis in enumerate(axes):
            if n == PROMPT_AXES and len(axes) > n + 1:
                parts.append(f"+{len(axes) - n} moving")
                break
            unit = "°" if axis != "gripper" else " mm"
            parts.append(f"{axis} {getattr(joints, f'{axis}_pos'):.1f}{unit}")
    return "aspod " + " ".join(parts) + " > "


def toolbar_text(client, cache: TelemetryCache, columns: int) -> str:
    """The bottom line: the link's state, the smoothed round trip, and how the controller's time keeps up
    (`link UP /dev/pts/3 | round trip 2.1 ms | time paced 1.00x real time`), cut to the terminal's width."""
    link = client.link
    state = "LOST" if client.io_error is not None else link.state.value.upper()
    parts = [f"link {state} {getattr(client, 'url', '')}".rstrip()]
    srtt = link.srtt_s
    parts.append(f"round trip {srtt * 1000:.1f} ms" if srtt is not None else "round trip -")
    status = cache.status
    if status is not None:
        mode = enum_word(TimingMode, status.timing)
        measured = status.timing not in (TimingMode.SIMULATED, TimingMode.REALTIME)
        parts.append(f"time {mode}" + (f" {status.rtf_recent:.2f}x real time" if measured else ""))
    text = " " + " | ".join(parts)
    return text if len(text) < columns else text[:max(1, columns - 2)] + "…"


def follow_width(columns: int) -> int:
    """Wrap the console's output to the terminal: at most the scripts' 96 columns, fewer on a narrower one."""
    width = max(MIN_WIDTH, min(MAX_WIDTH, columns - 1))
    teleop_format.WIDTH = width
    teleop_words.HELP_WIDTH = width
    return width


def _key_bindings(on_key: Callable[[object], None], on_ctrl_c: Optional[Callable[[object], None]] = None
                  ) -> KeyBindings:
    keys = KeyBindings()

    @keys.add("<any>")
    def _(event) -> None:
        on_key(event)

    @keys.add("c-c")
    def _(event) -> None:
        if on_ctrl_c is not None:
            on_ctrl_c(event)
        else:
            event.app.exit(result=False)

    return keys


def wait_key(text: str) -> bool:
    """Show `text` until a key is pressed: False for q, Escape or Ctrl-C, True for any other."""
    def on_key(event) -> None:
        event.app.exit(result=event.key_sequence[0].key not in ("q", "Q", "escape"))
    app = Application(layout=Layout(Window(FormattedTextControl(text), height=1)),
                      key_bindings=_key_bindings(on_key), erase_when_done=True)
    return bool(app.run())


def page(console: Console, text: str, rows: int) -> None:
    """`text` a screenful at a time (space or Enter: the next, q: the rest unseen)."""
    lines = text.split("\n")
    step = max(1, rows - 2)
    for start in range(0, len(lines), step):
        console.lines(lines[start:start + step])
        if start + step < len(lines):
            console.out.flush()
            shown = min(start + step, len(lines))
            if not wait_key(f"-- {shown}/{len(lines)} lines: any key for more, q to stop --"):
                break


def live_block(cache: TelemetryCache, block: Callable[[TelemetryCache], list[str]],
               seconds: Optional[float]) -> str:
    """Draw `block` in place, refreshed from telemetry, until a key is pressed or `seconds` are up; the character
    typed to end it ("" for Enter, q, Escape, Ctrl-C or a key that types nothing), for the prompt to begin with."""
    done = []
    hint = f"(any key ends watch{f'; it ends by itself after {seconds:g} s' if seconds is not None else ''})"

    def text() -> str:
        lines = block(cache) if cache.latest else ["(no telemetry: is the rate 0? `telemetry 10` starts it)"]
        return "\n".join(lines + ([] if done else [hint]))

    def end(event=None) -> None:
        if app.is_running and not done:
            done.append(True)
            typed = event.key_sequence[0].data if event is not None else ""
            app.exit(result=typed if len(typed) == 1 and typed.isprintable() and typed not in "qQ" else "")

    app: Application = Application(layout=Layout(Window(FormattedTextControl(text), wrap_lines=True)),
                                   key_bindings=_key_bindings(end, lambda _event: end()),
                                   refresh_interval=WATCH_REFRESH_S)

    def pre_run() -> None:
        if seconds is not None:
            app.loop.call_later(seconds, end)
    return app.run(pre_run=pre_run) or ""


class WrappingConsole(Console):
    """Whole lines, as Console, each wrapped to the terminal's width (`columns()`) at spaces, continuation lines
    indented under the text; the link's pump thread and the main thread both print through it."""

    def __init__(self, out, columns: Callable[[], int]) -> None:
        super().__init__(out)
        self.columns = columns

    def line(self, text: str = "") -> None:
        super().line("\n".join(fit(text, self.columns())))


class TeleopConsole:
    """One interactive session: the prompt, the completer, the history; `run()` returns (status, session)."""

    def __init__(self, client, history: Optional[History] = None,
                 opener: Optional[Callable[[str], object]] = None) -> None:
        self.proxy = StdoutProxy(sleep_between_writes=0.05, raw=True)
        self.params = ParamNames(client)
        self.prompt: PromptSession = PromptSession(
            history=history if history is not None else open_history(),
            completer=TeleopCompleter(lambda: self.params.names, lambda name: self.params.meta(name)),
            complete_while_typing=False,
            bottom_toolbar=lambda: toolbar_text(self.session.client, self.session.telemetry, self.columns()),
            refresh_interval=PROMPT_REFRESH_S)
        self.session = Session(client, self.proxy, all_events=True)
        self.session.opener = opener             # `connect URL`, `connect` after the port is gone
        self.session.event_prefix = ""          # prompt_toolkit prints above the prompt: no need to step off it
        self.console = self.session.console = WrappingConsole(self.proxy, self.columns)
        self.typed_ahead = ""                   # the key that ended `watch`: the next line begins with it
        self._stop = threading.Event()
        self._monitor = threading.Thread(target=self._watch_link, name="aspod-link-watch", daemon=True)

    # ---- the link, watched from its own thread ----
    def _watch_link(self) -> None:
        announced = False
        while not self._stop.wait(LINK_CHECK_S):
            trouble = self.session.link_trouble()
            if trouble is not None and not announced:
                self.console.lines(textwrap.wrap(f"! LINK LOST: {trouble}; nothing can be sent until `connect` "
                                                 "(or `connect URL`) opens a new session", teleop_format.WIDTH,
                                                 subsequent_indent="  "))
            announced = trouble is not None

    def columns(self) -> int:
        return self._size()[1]

    def rows(self) -> int:
        return self._size()[0]

    def _size(self) -> tuple[int, int]:
        """The terminal's (rows, columns); 24 x 80 if it cannot say (never raises: the pump thread asks too)."""
        try:
            size = self.prompt.output.get_size()
            return size.rows or 24, size.columns or 80
        except Exception:
            return 24, 80

    def run(self) -> tuple[int, Session]:
        status = EXIT_OK
        number = 0
        self.params.start()
        self._monitor.start()
        self.console.line("type `help` for the commands, Tab completes, `quit` leaves")
        try:
            while True:
                follow_width(self.columns())
                try:
                    text = self.prompt.prompt(lambda: prompt_text(self.session.client, self.session.telemetry,
                                                                  self.session.tracker.running),
                                              default=self.typed_ahead)
                except KeyboardInterrupt:
                    continue             # Ctrl-C clears the line, as in a shell
                except EOFError:
                    break
                finally:
                    self.typed_ahead = ""
                number += 1
                try:
                    step = parse_line(text, number)
                except TeleopError as exc:        # its `line N: ` is for a script's lines, not the prompt's
                    self.console.line(f"error: {str(exc).removeprefix(f'line {number}: ')}")
                    continue
                if step is None:
                    continue
                if step.word == "quit":
                    break
                try:
                    ok = self.run_step(step)
                except KeyboardInterrupt:
                    self.console.line("(interrupted)")
                    ok = True
                if not ok or self.session.motion_failures():
                    status = max(status, EXIT_LINK if self.session.link_trouble() is not None else EXIT_FAILED)
        finally:
            self._stop.set()
            self._monitor.join()
            self.session.close()
            self.proxy.close()
        return status, self.session

    def run_step(self, step) -> bool:
        word = step.word
        if word == "help":
            page(self.console, teleop_words.help_text(step.args[0] if step.args else None), self.rows())
            return True
        if word == "watch":
            seconds = step.seconds if step.args and step.args[-1].lower() != "box" else None
            block = (lambda cache: box_block(cache.latest)) if step.view == "box" else arm_block
            self.proxy.flush()
            self.typed_ahead = live_block(self.session.telemetry, block, seconds)
            return True
        if word == "params":
            failed = self.params.read()
            if failed is not None:
                self.console.line(format_outcome(failed))
                return False
            page(self.console, "\n".join(teleop_format.params_table(self.params.replies, teleop_format.WIDTH)),
                 self.rows())
            return True
        if word == "clear":              # as the shell's `clear`: the screen, and the terminal's scrollback (E3)
            self.proxy.flush()
            clear()
            self.prompt.output.write_raw("\033[3J")
            self.prompt.output.flush()
            return True
        if step.waits_for_motion:
            return self.wait_motions(step)
        client = self.session.client
        ok = self.session.run_step(step)
        if self.session.client is not client:          # `connect URL`: the parameters are the new controller's
            self.params = ParamNames(self.session.client)
            self.params.start()
        return ok

    def wait_motions(self, step) -> bool:
        """`wait [AXIS]`, which here also fails when a motion it waited for ended other than as asked (FAULT,
        DISABLED, ...): its `ok` line is then replaced by a FAIL naming them."""
        waited = self.session.tracker.running(step.axis)
        said = _Lines(self.console)
        self.session.console = said
        try:
            ok = self.session.run_step(step)
        finally:
            self.session.console = self.console
        bad = [m for m in waited if m.end is not None and not m.ok]
        lines = said.texts
        if bad:
            ok = False
            lines = [f"FAIL wait {axis_word(step.axis)}: {len(bad)} motion(s) did not end as asked"]
            for m in bad:
                outcome = enum_word(MotionOutcome, m.end.outcome).upper()
                lines.append(f"{INDENT}{m.label} ended {outcome} at {position_text(m.axis, m.end.position)} "
                             f"(line {m.line_no}: {m.text})")
        if lines:
            self.console.lines(lines)
        return ok


class _Lines(Console):
    """Holds back the `ok   wait` line (whose verdict the console may still change); every other line, the
    pump thread's events and the wait's own notes, goes on to `forward` as it comes."""

    def __init__(self, forward: Console) -> None:
        super().__init__(None)
        self.forward = forward
        self.owner = threading.current_thread()      # the main thread, running the wait
        self.texts: list[str] = []

    def line(self, text: str = "") -> None:
        if threading.current_thread() is self.owner and text.startswith("ok   wait"):
            self.texts.extend(text.split("\n"))
        else:
            self.forward.line(text)


def interactive_console(client, history: Optional[History] = None,
                        opener: Optional[Callable[[str], object]] = None) -> tuple[int, Session]:
    """`aspod teleop` on a terminal: see the module doc. `opener(url)`: a new, unconnected client for `connect URL`."""
    return TeleopConsole(client, history, opener).run()
