"""Teleop's words: a line of text -> a checked message (or a local word), and the help that goes with it.

The command words, their arguments (names, enum values, defaults, units, ranges), help and
completion all come from the protocol declaration (`teleop=` in protocol/messages.py). The
few local words act on the console itself; `wait` names its axes from the declared Axis enum.
Every check runs before anything is sent, so a bad line changes nothing.

Besides the declared commands: `box` and `watch box` (the solar tracker's control box,
teleop/box.py), `wait aligned [az|el] DEG [TIMEOUT]` (until the tracker points at the sun),
`expect REASON COMMAND` (a script line that passes only if COMMAND is refused with exactly
REASON) and `clock now` / `clock YYYY-MM-DDTHH:MM[:SS]+HH:MM` besides POSIX seconds; `sim ...`
(the simulated plant, outside the link: teleop/sim_words.py).
"""
from __future__ import annotations

import difflib
import re
import shlex
import textwrap
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, Optional, Sequence

from protocol import files
from protocol.errors import EncodeError, shown
from protocol.messages import SCHEMA
from protocol.reasons import Reason
from protocol.schema import Field, Message, MessageSpec

from host_tools.datetimes import FORMAT as CLOCK_FORMAT
from host_tools.datetimes import parse_when, split_seconds
from host_tools.teleop import sim_words
from host_tools.worlds.ports import check_url

# The axes `wait` takes: the declared enum of the motion commands' `axis` field (Home's includes `all`).
AXIS_ENUM = next(f.enum for f in SCHEMA["Home"].fields if f.name == "axis")
AXIS_ALL = next(a for a in AXIS_ENUM if a.name == "ALL")
AXES = tuple(a for a in AXIS_ENUM if a is not AXIS_ALL)          # every channel, in declared order
AXIS_WORDS = tuple(a.name.lower() for a in AXIS_ENUM)           # j1 ... mount, all

WAIT_TIMEOUT_S = 120.0         # default for `wait [AXIS|all]`: a 330 deg mount move at 3 deg/s takes 110 s
ALIGNED_TIMEOUT_S = 300.0      # default for `wait aligned`: 150 deg of azimuth at the full dial's 35 deg/min
MAX_WAIT_S = 3600.0
WATCH_S = 5.0
HELP_WIDTH = 96
TRACKER_AXES = ("az", "el")
WATCH_VIEWS = ("box",)          # `watch box`; plain `watch` is the arm
EXPECTABLE = tuple(r.name for r in Reason if r is not Reason.OK)
SCRIPT_LIMIT = 4 * files.MIB    # a script of ~100,000 lines; checked whole before it runs
MAX_INTEGER_TEXT = 80           # u64 in binary with its 0b and a sign is 67 characters
MAX_PROBLEMS = 50               # a script's problems listed before its check stops
MAX_LINE_CHARS = 1024           # a command line (its comment aside): the longest real ones are under 100

LOCAL_COMMANDS = {
    "help": "help [WORD]: list the commands, or describe one",
    "watch": f"watch [box] [seconds]: live arm and controller telemetry, or with `box` the solar tracker's "
             f"control box (default {WATCH_S:g} s; Ctrl-C ends it early); on a pipe, the last reading once",
    "box": "box: the solar tracker's control box as a person at it sees it, from the latest TelemetryTracker: "
           "switches, dials, relays (CW, CCW, open), brakes, duties, photocell difference and sum, angles, the "
           "sun and the pointing error, counters, warnings with their meaning, the box's temperature",
    "expect": "expect REASON COMMAND...: COMMAND must be refused with exactly REASON (e.g. `expect DIAL_NOT_LOW "
              "switch mode sensor`); the line fails if COMMAND is accepted or refused for another reason. "
              "REASON is a reason code's name; checked with the rest of a script before anything is sent",
    "link": "link: this end's and the controller's link statistics",
    "params": "params: every parameter with its value and range (get NAME / set NAME VALUE / save)",
    "wait": f"wait [AXIS|all] [TIMEOUT]: wait until the motions started here on AXIS (default all: every "
            f"axis) have ended (default timeout {WAIT_TIMEOUT_S:g} s; a timeout fails the line); "
            "wait SECONDS: pause (timeouts and pauses count the controller's seconds where its time is simulated). "
            "AXIS: " + ", ".join(AXIS_WORDS[:-1]) + ". "
            "wait aligned [az|el] DEG [TIMEOUT]: until the solar tracker points at the sun within DEG degrees in "
            "three TelemetryTracker in a row (the angle between the focal axis and the ephemeris sun; with az or el, "
            "that axis's error alone); it needs the controller's clock (`clock now`) and the box in use (main or "
            f"sensor power on); default timeout {ALIGNED_TIMEOUT_S:g} s; a timeout fails the line",
    "connect": "connect [URL]: a new session: a handshake again on this link, or, once the link is lost (the "
               "simulator stopped, say) or with URL, on the link at URL (`connect /dev/pts/7`: the key is the "
               "simulator's own, as at the start)",
    "sim": sim_words.summary(),
    "traj": "traj load FILE [arm 1|2]|run|clear: load FILE uploads a planned trajectory (a file of `aspod plan "
            "--arm-to ... --output FILE`) to the controller, replacing the knots it holds; a two-arm file (`aspod "
            "plan --output FILE`) needs `arm 1` or `arm 2`, the knots of that arm's controller; traj run: start it "
            "(j1..j4 and the mount, from where they stand at rest; `wait` waits for it); traj clear: drop the knots. "
            "A script checks the file before anything is sent",
    "clear": "clear: clear the screen (Ctrl-L does too); nothing in a script",
    "quit": "quit: leave",
}
# Axes the controller refuses for these motions (firmware_py/arm_commands.py `_joint_motion`: `all` is OUT_OF_RANGE;
# firmware_py/arm.py `move`, `jog`: the gripper opens and closes with `grip`): help and Tab leave them out.
REFUSED_AXES = {"Move": ("all", "gripper"), "MoveBy": ("all", "gripper"), "Jog": ("all", "gripper")}

# `help`: every word once, by the job it is for, with what it does in a line.
INDEX = (
    ("arm", (("enable", "IDLE to ENABLED: the motors may be driven"),
             ("disable", "ENABLED to IDLE: outputs off"),
             ("home", "find an axis's home switch and zero it there"),
             ("move", "move an axis to an angle"),
             ("moveby", "move an axis by an angle"),
             ("jog", "turn an axis at a speed until `stop`"),
             ("grip", "open or close the gripper"),
             ("stop", "stop every motion"),
             ("traj", "a planned trajectory: load a file, run it, clear it"),
             ("wait", "until the motions end; or a pause"),
             ("watch", "the arm live (`watch box`: the tracker's box)"))),
    ("tracker", (("switch", "set a switch of the solar tracker's control box"),
                 ("dial", "turn the speed dial"),
                 ("box", "the control box as a person at it sees it"),
                 ("boxstate", "read the box's switches and dials"),
                 ("clock", "set the controller's clock (`clock now`)"))),
    ("controller", (("status", "its state, faults and sensors"),
                    ("reset", "clear latched faults, back to IDLE"),
                    ("estop", "emergency stop, latched until `reset`"),
                    ("params", "every parameter, its value and range"),
                    ("get", "read a parameter"),
                    ("set", "change a parameter (checked against its range)"),
                    ("save", "keep the parameters in the controller's file"),
                    ("telemetry", "how often telemetry comes"))),
    ("link", (("connect", "a new session; `connect URL`: a new link"),
              ("ping", "a round trip through the command channel"),
              ("link", "both ends' link statistics"))),
    ("simulator", (("sim", "the simulated plant: loads, faults, clouds"),)),
    ("console", (("help", "this list; `help WORD`: one command"),
                 ("expect", "a script's line: COMMAND refused with REASON"),
                 ("clear", "clear the screen"),
                 ("quit", "leave"))),
)
# A field's type and unit in words, for `help WORD`.
TYPE_WORDS = {"f32": "a number", "bool": "on or off"}
UNIT_WORDS = {"deg": "degrees", "deg/s": "degrees a second", "mm": "millimetres", "mm/s": "millimetres a second",
              "s": "seconds", "ms": "milliseconds", "Hz": "times a second", "%": "percent", "V": "volts",
              "A": "amperes"}
TRAJ_ACTIONS = ("load", "run", "clear")

SCRIPT_RULES = ("in a script (--script FILE, or a pipe), a motion that ends other than DONE counts as a failed "
                "command (a jog's STOPPED by `stop` is its normal end): the script stops there, or goes on "
                "with --keep-going, and exits 1")


class TeleopError(ValueError):
    """A line that cannot be turned into a command."""


@dataclass
class Step:
    word: str
    args: list[str]
    line_no: int
    text: str
    message: Optional[Message] = None
    seconds: Optional[float] = None       # watch, and wait as a pause
    axis: Optional[int] = None            # wait for motions: an AXIS value (AXIS_ALL: every axis)
    view: str = "arm"                     # watch: "arm" or "box"
    aligned_deg: Optional[float] = None   # wait aligned: the pointing error to wait for ...
    aligned_axis: Optional[str] = None    # ... of one axis (az, el), or None: the angle to the sun
    expect: Optional[Reason] = None       # expect REASON COMMAND: the refusal that passes
    clock_now: bool = False               # clock now: SetClock built from the host's UTC when it runs
    control: Optional[dict] = None        # sim ...: the control endpoint's request
    knots: Optional[list] = None          # traj load FILE: the trajectory's knots, read and checked

    @property
    def waits_for_motion(self) -> bool:
        return self.word == "wait" and self.axis is not None

    @property
    def waits_for_alignment(self) -> bool:
        return self.word == "wait" and self.aligned_deg is not None

    @property
    def sends(self) -> bool:
        """A command for the controller (built now, or for `clock now` when it runs)."""
        return self.message is not None or self.clock_now

    def build(self, wall_time) -> Message:
        """The message to send; `wall_time()` (POSIX seconds) is read for `clock now`."""
        if self.clock_now:
            return SCHEMA["SetClock"].type(*split_seconds(wall_time()))
        return self.message


_COMMANDS = SCHEMA.teleop_commands()                             # the declaration does not change: once
_ALL_WORDS = tuple(sorted(list(_COMMANDS) + list(LOCAL_COMMANDS)))


def commands() -> dict[str, MessageSpec]:
    return dict(_COMMANDS)


def all_words() -> list[str]:
    return list(_ALL_WORDS)


def enum_words(fld: Field) -> list[str]:
    return [m.name.lower() for m in fld.enum] if fld.enum is not None else []


def parse_value(fld: Field, text: str):
    try:
        if fld.enum is not None and not text.lstrip("-").isdigit():
            return int(fld.enum[text.upper()])
        if fld.type == "f32":
            return float(text)
        if fld.type == "bool":
            lowered = text.lower()
            if lowered in ("1", "true", "on", "yes"):
                return True
            if lowered in ("0", "false", "off", "no"):
                return False
            raise ValueError(text)
        if fld.type.startswith("bytes"):
            return bytes.fromhex(text)
        if fld.type.startswith("str"):
            if fld.check(text):
                raise ValueError(text)
            return text
        if len(text) > MAX_INTEGER_TEXT:     # no integer of ours is this long, and a huge one costs time to convert
            raise ValueError(text)
        return int(text, 0)
    except (ValueError, KeyError):
        kind = f"one of {', '.join(enum_words(fld))}" if fld.enum else fld.type
        raise TeleopError(f"{fld.name}: {shown(text)} is not a valid {kind}") from None


def build_message(spec: MessageSpec, args: list[str]) -> Message:
    """A message from `name=value` or positional arguments, range-checked as on the wire."""
    values: dict[str, object] = {}
    names = [f.name for f in spec.fields]
    for index, arg in enumerate(args):
        key, sep, text = arg.partition("=")
        if not sep:
            if index >= len(names):
                raise TeleopError(f"{spec.teleop} takes {len(names)} argument(s): {usage(spec)}")
            key, text = names[index], arg
        fld = next((f for f in spec.fields if f.name == key), None)
        if fld is None:
            raise TeleopError(f"{spec.teleop} has no argument {shown(key)}: {usage(spec)}")
        values[key] = parse_value(fld, text)
    for fld in spec.fields:
        if fld.name not in values and fld.default is not None:
            values[fld.name] = fld.default
    missing = [n for n in names if n not in values]
    if missing:
        raise TeleopError(f"{spec.teleop} needs {', '.join(missing)}: {usage(spec)}")
    msg = spec.type(**values)
    for fld, value in zip(spec.fields, msg):
        problem = fld.check(value) if fld.limits is None or fld.range is not None else _type_range(fld, value)
        if problem:
            raise TeleopError(problem)
    try:
        spec.encode(msg)             # what the link will do with it: refused here, before anything is sent
    except EncodeError as exc:
        raise TeleopError(str(exc)) from None
    return msg


def _type_range(fld: Field, value) -> Optional[str]:
    lo, hi = fld.limits
    if not lo <= value <= hi:
        return f"{fld.name}={value} does not fit in {fld.type} ({lo}..{hi})"
    return fld.check(value)


def usage(spec: MessageSpec, units: bool = True) -> str:
    def arg(f: Field) -> str:
        name = "|".join(enum_words(f)) if f.enum is not None and len(f.enum) <= 3 else f.name.upper()
        name += f"({f.unit})" if f.unit and units else ""
        return f"[{name}]" if f.default is not None else name
    return " ".join([spec.teleop] + [arg(f) for f in spec.fields])


def _seconds(text: str, what: str, line_no: int) -> float:
    try:
        seconds = float(text)
    except ValueError:
        raise TeleopError(f"line {line_no}: {what}: {shown(text)} is not a number of seconds") from None
    if not 0 <= seconds <= MAX_WAIT_S:
        raise TeleopError(f"line {line_no}: {what}: {seconds:g} s is outside 0..{MAX_WAIT_S:g}")
    return seconds


def _parse_aligned(step: Step) -> None:
    """`wait aligned [az|el] DEG [TIMEOUT]`."""
    args, n = step.args[1:], step.line_no
    if args and args[0].lower() in TRACKER_AXES:
        step.aligned_axis, args = args[0].lower(), args[1:]
    if not 1 <= len(args) <= 2:
        raise TeleopError(f"line {n}: wait aligned [az|el] DEG [TIMEOUT]: a pointing error in degrees, then "
                          "optionally a timeout in seconds")
    try:
        deg = float(args[0])
    except ValueError:
        raise TeleopError(f"line {n}: wait aligned: {shown(args[0])} is not a number of degrees") from None
    if not 0 < deg <= 180:
        raise TeleopError(f"line {n}: wait aligned: {deg:g} deg is outside (0, 180]")
    step.aligned_deg = deg
    step.seconds = _seconds(args[1], "wait aligned: timeout", n) if len(args) == 2 else ALIGNED_TIMEOUT_S


def _parse_wait(step: Step) -> None:
    """`wait` / `wait AXIS|all [TIMEOUT]`: wait for motions; `wait SECONDS`: pause; `wait aligned ...`."""
    args, n = step.args, step.line_no
    if args and args[0].lower() == "aligned":
        _parse_aligned(step)
        return
    if len(args) > 2:
        raise TeleopError(f"line {n}: wait takes at most an axis and a timeout: wait [AXIS|all] [TIMEOUT]")
    if not args:
        step.axis, step.seconds = int(AXIS_ALL), WAIT_TIMEOUT_S
        return
    word = args[0].lower()
    if word in AXIS_WORDS:
        step.axis = int(AXIS_ENUM[word.upper()])
        step.seconds = _seconds(args[1], f"wait {word}: timeout", n) if len(args) == 2 else WAIT_TIMEOUT_S
        return
    if len(args) == 2:
        raise TeleopError(f"line {n}: wait: {shown(args[0])} is not an axis ({', '.join(AXIS_WORDS)}) nor `aligned`")
    try:
        float(word)
    except ValueError:
        raise TeleopError(f"line {n}: wait: {shown(args[0])} is not a number of seconds nor an axis "
                          f"({', '.join(AXIS_WORDS)})") from None
    step.seconds = _seconds(word, "wait", n)


_QUOTING = re.compile(r"""['"\\]""")      # a line without these splits as str.split does: no need for shlex


def did_you_mean(word: str, choices: Sequence[str]) -> str:
    """` (did you mean `x`?)` for the choices close to `word`, else "". A word far longer than every choice
    cannot be close to one, and is not compared (difflib's cost grows with the product of the lengths)."""
    if not word or len(word) > 2 * max(map(len, choices), default=0):
        return ""
    close = difflib.get_close_matches(word, choices, n=3, cutoff=0.6)
    return f" (did you mean {' or '.join(f'`{c}`' for c in close)}?)" if close else ""


def parse_line(text: str, line_no: int) -> Optional[Step]:
    """A step for one line; None for blank lines and comments; raises TeleopError."""
    stripped = text.split("#", 1)[0].strip()
    if not stripped:
        return None
    if len(stripped) > MAX_LINE_CHARS:     # refused before it is split into words (shlex: quadratic in a word)
        raise TeleopError(f"line {line_no}: {shown(stripped)} is longer than any command: at most "
                          f"{MAX_LINE_CHARS} characters before a comment")
    try:
        words = shlex.split(stripped) if _QUOTING.search(stripped) else stripped.split()
    except ValueError as exc:
        raise TeleopError(f"line {line_no}: {exc}") from None
    word, args = words[0].lower(), words[1:]
    if word in ("exit",):
        word = "quit"
    step = Step(word, args, line_no, stripped)
    if word == "expect":
        return _parse_expect(step)
    if word in LOCAL_COMMANDS:
        if word == "wait":
            _parse_wait(step)
        elif word == "watch":
            if args and args[0].lower() in WATCH_VIEWS:
                step.view, args = args[0].lower(), args[1:]
            if len(args) > 1:
                raise TeleopError(f"line {line_no}: watch takes `box` and at most a number of seconds")
            step.seconds = _seconds(args[0], "watch", line_no) if args else WATCH_S
        elif word == "sim":
            try:
                step.control = sim_words.parse(args)
            except sim_words.SimWordError as exc:
                raise TeleopError(f"line {line_no}: {exc}") from None
        elif word == "traj":
            _parse_traj(step)
        elif word == "connect" and args:
            if len(args) > 1:
                raise TeleopError(f"line {line_no}: connect takes at most one URL: connect [URL]")
            try:
                check_url(args[0])
            except ValueError as exc:
                raise TeleopError(f"line {line_no}: connect: {exc}") from None
        elif word == "help" and len(args) > 1:
            raise TeleopError(f"line {line_no}: help takes at most one command word")
        elif word == "help" and args and args[0].lower() not in _ALL_WORDS:
            raise TeleopError(f"line {line_no}: help: no command {shown(args[0])}"
                              f"{did_you_mean(args[0].lower(), _ALL_WORDS)}; `help` lists them all")
        elif word not in ("help", "connect", "traj") and args:
            raise TeleopError(f"line {line_no}: {word} takes no arguments")
        return step
    spec = _COMMANDS.get(word)
    if spec is None:
        raise TeleopError(f"line {line_no}: unknown command {shown(word)}{did_you_mean(word, _ALL_WORDS)} "
                          f"(known: {', '.join(_ALL_WORDS)})")
    try:
        if spec.name == "SetClock" and args and _is_date_time(args[0]):
            _parse_clock(step, spec)
        else:
            step.message = build_message(spec, args)
    except TeleopError as exc:
        raise TeleopError(f"line {line_no}: {exc}") from None
    return step


def _parse_traj(step: Step) -> None:
    """traj load FILE [arm N] (the file read and checked now: a script refuses a bad one before sending anything),
    run, clear."""
    args, line_no = step.args, step.line_no
    action = args[0].lower() if args else ""
    if action not in TRAJ_ACTIONS or len(args) not in ((2, 4) if action == "load" else (1,)):
        raise TeleopError(f"line {line_no}: traj load FILE [arm 1|2] | traj run | traj clear")
    if action == "load":
        from host_tools.client.trajectory import load_trajectory
        arm = None
        if len(args) == 4:
            if args[2].lower() != "arm" or args[3] not in ("1", "2"):
                raise TeleopError(f"line {line_no}: traj load FILE arm 1 | traj load FILE arm 2, not "
                                  f"`{' '.join(args[2:])}`")
            arm = int(args[3])
        try:
            step.knots = load_trajectory(args[1], arm)
        except (ValueError, OSError) as exc:       # files.InputFileError is an OSError: unreadable, too big
            raise TeleopError(f"line {line_no}: traj load: {exc}") from None


def _is_date_time(text: str) -> bool:
    """`now`, or a date-time rather than a number (or name=value) for SetClock's fields."""
    return text.lower() == "now" or ("-" in text[1:] and "=" not in text)


def _parse_clock(step: Step, spec: MessageSpec) -> None:
    """`clock now` (read when it runs) or `clock YYYY-MM-DDTHH:MM[:SS]+HH:MM`."""
    if len(step.args) != 1:
        raise TeleopError(f"{spec.teleop} now, or {spec.teleop} {CLOCK_FORMAT}, takes nothing after it")
    try:
        seconds = parse_when(step.args[0], "clock")
    except ValueError as exc:
        raise TeleopError(str(exc)) from None
    if seconds is None:
        step.clock_now = True
    else:
        step.message = spec.type(*split_seconds(seconds))


def _parse_expect(step: Step) -> Step:
    """`expect REASON COMMAND...`: COMMAND's step, which passes only if refused with exactly REASON."""
    n, args = step.line_no, step.args
    if not args:
        raise TeleopError(f"line {n}: expect REASON COMMAND: e.g. `expect DIAL_NOT_LOW switch mode sensor`")
    name = args[0].upper()
    if name == "OK":
        raise TeleopError(f"line {n}: expect OK: write the command alone; a script fails when a command is refused")
    if name not in EXPECTABLE:
        raise TeleopError(f"line {n}: expect: {shown(args[0])} is not a reason code (e.g. DIAL_NOT_LOW, "
                          "SWITCH_POSITION, SOFT_LIMIT; `help expect`)")
    if len(args) > 1 and args[1].lower() == "expect":
        raise TeleopError(f"line {n}: expect {name}: one command follows the reason, not another `expect`")
    rest = " ".join(shlex.quote(a) for a in args[1:])
    inner = parse_line(rest, n) if rest else None
    if inner is None or not inner.sends:
        what = f"{inner.word!r} is a local word" if inner is not None else "nothing follows the reason"
        raise TeleopError(f"line {n}: expect {name}: {what}; it takes a command for the controller "
                          f"(e.g. `expect {name} switch speed on`)")
    inner.expect, inner.text = Reason[name], step.text
    return inner


def read_script(path: Optional[Path], stdin: Optional[BinaryIO] = None, option: str = "--script") -> list[str]:
    """The lines of a script: the regular file `path` (named by `option`), or else all of `stdin` (a pipe, say);
    at most SCRIPT_LIMIT bytes of UTF-8 text. TeleopError naming the option and the file, else."""
    source = f"{option} {path}" if path is not None else "standard input"
    try:
        if path is not None:
            raw = files.read_bounded(path, SCRIPT_LIMIT)
        else:
            raw = files.read_stream_bounded(stdin, SCRIPT_LIMIT, "standard input")
        return raw.decode("utf-8").splitlines()
    except files.InputFileError as exc:
        raise TeleopError(f"{option} {exc}" if path is not None else str(exc)) from None
    except UnicodeDecodeError as exc:
        raise TeleopError(f"{source}: not UTF-8 text (byte {exc.start}: {exc.reason})") from None


DIRECTIVE = re.compile(r"#!\s*aspod\s+bench\b(.*)")
MAX_DIRECTIVE_CHARS = 4 * files.KIB   # the longest real directive is under 200 characters
# The options a script's first line may give: those of the world it runs in (`aspod bench`'s seed, arm, tracker
# and bench-world options; host_tools/cli/main.py), each with whether it takes a value. Nothing else: a script is
# input, and must not choose where the tool writes (--record, --log-file) or how it reports.
WORLD_OPTIONS = {"--seed": True, "--gravity": True, "--payload-kg": True, "--sun-start": True, "--clouds": True,
                 "--no-tracker": False, "--fault": True, "--impairment": True, "--param": True, "--var": True,
                 "--arms": True}


def script_directive(lines: list[str]) -> tuple[str, ...]:
    """The `aspod bench` options a script's first line asks for (`#! aspod bench --seed 3 ...`); none: ().
    TeleopError if the line is longer than MAX_DIRECTIVE_CHARS, cannot be split as a shell would, or gives
    anything but WORLD_OPTIONS."""
    found = DIRECTIVE.match(lines[0]) if lines else None
    if not found:
        return ()
    if len(lines[0]) > MAX_DIRECTIVE_CHARS:
        raise TeleopError(f"line 1: its `aspod bench` options are {len(lines[0])} characters, more than "
                          f"{MAX_DIRECTIVE_CHARS}, the most a script's first line may give")
    try:
        words = tuple(shlex.split(found.group(1)))
    except ValueError as exc:
        raise TeleopError(f"line 1: its `aspod bench` options: {exc}") from None
    value_next = False
    for word in words:
        if value_next:
            value_next = False
            continue
        name, eq, _ = word.partition("=")
        if name not in WORLD_OPTIONS:
            raise TeleopError(f"line 1: {shown(word)} is not an option a script may give: its first line "
                              f"gives only the world it runs in ({', '.join(WORLD_OPTIONS)}); where the run is "
                              "recorded or logged is for the command line")
        value_next = WORLD_OPTIONS[name] and not eq
    return words


VARIABLE = re.compile(r"\$\{([A-Za-z_][A-Za-z0-9_]*)\}")


def substitute(lines: list[str], values: dict[str, str], all_used: bool = True) -> list[str]:
    """A script's `${name}` written as `values[name]` (how `aspod bench --var` and a campaign's axes reach a
    script). TeleopError naming the line of a variable with no value, or (`all_used`) a value the script
    never uses."""
    used: set[str] = set()
    out = []
    for number, text in enumerate(lines, 1):
        def value(found: re.Match) -> str:
            name = found.group(1)
            if name not in values:
                raise TeleopError(f"line {number}: no value for ${{{name}}} (give one: --var {name}=VALUE)")
            used.add(name)
            return str(values[name])
        out.append(VARIABLE.sub(value, text))
    unused = sorted(set(values) - used)
    if unused and all_used:
        raise TeleopError(f"the script uses no {', '.join('${' + name + '}' for name in unused)}")
    return out


def check_script(lines: list[str]) -> tuple[list[Step], list[str]]:
    """Every line parsed: the steps, and a message for each line that is not a command (the first
    MAX_PROBLEMS of them: past that, checking stops, and a last message says so; nothing will be sent)."""
    steps, problems = [], []
    for number, text in enumerate(lines, 1):
        try:
            step = parse_line(text, number)
        except TeleopError as exc:
            problems.append(str(exc))
            if len(problems) == MAX_PROBLEMS and number < len(lines):
                problems.append(f"checking stopped at line {number} of {len(lines)} after {MAX_PROBLEMS} problems")
                break
            continue
        if step is not None:
            steps.append(step)
    return steps, problems


def help_text(word: Optional[str] = None) -> str:
    """`help`: the index by job; `help WORD`: one command, its arguments in words."""
    if word is None:
        return "\n".join(help_index())
    word = word.lower()
    if word == "sim":
        rows = [line for left, text in sim_words.help_lines() for line in _row(left, text, 26)]
        return "\n".join(rows + _wrap(sim_words.HELP_NOTE, "  "))
    if word in LOCAL_COMMANDS:
        return "\n".join(_wrap(LOCAL_COMMANDS[word], "") + (_wrap(SCRIPT_RULES, "  ") if word == "wait" else []))
    spec = commands().get(word)
    if spec is None:
        return f"unknown command {word!r}"
    lines = [usage(spec, units=False)] + _paragraph(spec.doc)
    column = max(len(f.name) for f in spec.fields) + 2 if spec.fields else 0
    for f in spec.fields:
        lines += _row(f.name.upper(), argument_words(spec, f), column)
    if spec.reply == "MotionAccepted":
        lines += _paragraph("It prints the motion id (axis#id); its end (MotionDone) is printed when it comes; "
                            "`wait` waits for it.")
    lines += [line for note in NOTES.get(word, ()) for line in _paragraph(note)]
    return "\n".join(lines)


def _paragraph(text: str) -> list[str]:
    return textwrap.wrap(text, HELP_WIDTH, initial_indent="  ", subsequent_indent="  ")


def help_index() -> list[str]:
    lines = ["commands by job (`help WORD` for one; Tab completes):"]
    for job, words in INDEX:
        lines.append(job)
        for word, what in words:
            lines += _row(index_usage(word), what, 27)
    return lines + _wrap(SCRIPT_RULES, "")


def index_usage(word: str) -> str:
    spec = _COMMANDS.get(word)
    return usage(spec, units=False) if spec is not None else LOCAL_COMMANDS[word].split(": ", 1)[0]


def argument_words(spec: MessageSpec, f: Field) -> str:
    """One argument as a user reads it: `a number of degrees, from -360 to 360: target angle; if left out, 0`;
    an enum as the one list of the words this command takes."""
    if f.enum is not None:
        allowed = [w for w in enum_words(f) if w not in REFUSED_AXES.get(spec.name, ())]
        kind = ", ".join(allowed[:-1]) + f" or {allowed[-1]}" if len(allowed) > 1 else allowed[0]
        doc = "" if allowed[0] in f.doc else f.doc
    else:
        kind = TYPE_WORDS.get(f.type) or ("a name" if f.type.startswith("str") else
                                          "bytes in hex" if f.type.startswith("bytes") else "a whole number")
        if f.unit:
            kind += f" of {UNIT_WORDS.get(f.unit, f.unit)}"
        if f.range:
            kind += f", from {f.range[0]:g} to {f.range[1]:g}"
        doc = f.doc
    default = f"; if left out, {_default_word(f)}" if f.default is not None else ""
    return f"{kind}{': ' + doc if doc else ''}{default}"


# Conveniences teleop adds to a declared command, shown in its help.
NOTES = {
    "clock": (f"Also: `clock now` (the host's UTC when the line runs) and `clock {CLOCK_FORMAT}`, e.g. "
              "`clock 2026-03-20T06:50-07:00` (MST, Tucson); the simulator prints its sun's start "
              "(`aspod sim --sun-start`)",),
    "switch": ("A refusal (DIAL_NOT_LOW, SWITCH_POSITION) prints the reason's meaning and remedy and the box as it "
               "still stands; `box` shows the whole box; in a script `expect DIAL_NOT_LOW switch ...` checks that "
               "an interlock refuses",),
}


def _row(left: str, text: str, width: int = 34) -> list[str]:
    """`  usage   doc` with the doc wrapped in its column (on its own lines when the usage is long)."""
    pad = " " * (width + 3)
    body = textwrap.wrap(text, HELP_WIDTH - len(pad)) or [""]
    if len(left) > width:
        return [f"  {left}"] + [pad + b for b in body]
    return [f"  {left:<{width}} {body[0]}"] + [pad + b for b in body[1:]]


def _wrap(text: str, indent: str) -> list[str]:
    return textwrap.wrap(text, HELP_WIDTH, initial_indent=indent, subsequent_indent=indent + "    ")


def _default_word(f: Field) -> str:
    if f.enum is not None:
        try:
            return f.enum(f.default).name.lower()
        except ValueError:
            pass
    return str(f.default)


def completions(line: str, begin: int, text: str) -> list[str]:
    """Tab completion: the word, then the declared enum values of the argument at that position."""
    before = line[:begin].split()
    if not before:
        return [w for w in all_words() if w.startswith(text)]
    word, position = before[0].lower(), len(before) - 1
    if word == "help":
        options = all_words() if position == 0 else []
    elif word == "wait":
        options = (list(AXIS_WORDS) + ["aligned"] if position == 0 else
                   list(TRACKER_AXES) if position == 1 and before[1].lower() == "aligned" else [])
    elif word == "watch":
        options = list(WATCH_VIEWS) if position == 0 else []
    elif word == "expect":
        if position == 0:
            return [r for r in EXPECTABLE if r.lower().startswith(text.lower())]
        if position == 1:
            return [w for w in sorted(commands()) if w.startswith(text.lower())]
        rest = line[:begin].split(None, 2)[2]
        return completions(rest, len(rest), text)
    elif word == "clock":
        options = ["now"] if position == 0 else []
    elif word == "traj":
        load = len(before) > 1 and before[1].lower() == "load"
        options = {0: list(TRAJ_ACTIONS), 2: ["arm"] if load else [], 3: ["1", "2"] if load else []}.get(position, [])
    elif word == "sim":
        options = sim_words.completions(position, before[1:])
    else:
        spec = commands().get(word)
        fields = spec.fields if spec is not None else ()
        options = enum_words(fields[position]) if position < len(fields) else []
    return [o for o in options if o.startswith(text.lower())]
