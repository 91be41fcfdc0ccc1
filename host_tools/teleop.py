"""`aspod teleop URL`: a person's (or a script's) console to the controller.

The command words, their arguments, help and tab completion all come from the
protocol declaration (`teleop=` in protocol/messages.py); a few local words
(`help`, `watch`, `link`, `wait`, `connect`, `quit`) act on the console itself.
With `--script FILE`, or when stdin is not a terminal, every line is checked
before any is sent (an unknown word fails the run with its line number and
sends nothing), then run in order; the exit status is non-zero if any failed.
"""
from __future__ import annotations

import shlex
import statistics
import sys
from dataclasses import dataclass, field
from typing import Optional, TextIO

from protocol.host_link import CommandHandle
from protocol.messages import SCHEMA
from protocol.reasons import Reason, reason_name
from protocol.schema import Field, Message, MessageSpec
from protocol.states import Fault

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_LINK = 0, 1, 2, 3

LOCAL_COMMANDS = {
    "help": "help [command]: list the commands, or describe one",
    "watch": "watch [seconds]: show live telemetry (default 5 s; Ctrl-C ends it early)",
    "link": "link: this end's and the controller's link statistics",
    "params": "params: every parameter with its value and range (get NAME / set NAME VALUE / save)",
    "wait": "wait SECONDS: pause (for scripts)",
    "connect": "connect: handshake again (a new session)",
    "quit": "quit: leave",
}


class TeleopError(ValueError):
    """A line that cannot be turned into a command."""


@dataclass
class Step:
    word: str
    args: list[str]
    line_no: int
    text: str
    message: Optional[Message] = None


def commands() -> dict[str, MessageSpec]:
    return SCHEMA.teleop_commands()


def all_words() -> list[str]:
    return sorted(list(commands()) + list(LOCAL_COMMANDS))


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
        return int(text, 0)
    except (ValueError, KeyError):
        kind = f"one of {', '.join(m.name.lower() for m in fld.enum)}" if fld.enum else fld.type
        raise TeleopError(f"{fld.name}: {text!r} is not a valid {kind}") from None


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
            raise TeleopError(f"{spec.teleop} has no argument {key!r}: {usage(spec)}")
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
    return msg


def _type_range(fld: Field, value) -> Optional[str]:
    lo, hi = fld.limits
    if not lo <= value <= hi:
        return f"{fld.name}={value} does not fit in {fld.type} ({lo}..{hi})"
    return fld.check(value)


def usage(spec: MessageSpec) -> str:
    parts = [spec.teleop] + [(f"[{f.name}]" if f.default is not None else f.name) + (f"({f.unit})" if f.unit else "")
                             for f in spec.fields]
    return " ".join(parts)


def parse_line(text: str, line_no: int) -> Optional[Step]:
    """A step for one line; None for blank lines and comments; raises TeleopError."""
    stripped = text.split("#", 1)[0].strip()
    if not stripped:
        return None
    try:
        words = shlex.split(stripped)
    except ValueError as exc:
        raise TeleopError(f"line {line_no}: {exc}") from None
    word, args = words[0].lower(), words[1:]
    if word in ("exit",):
        word = "quit"
    step = Step(word, args, line_no, stripped)
    if word in LOCAL_COMMANDS:
        if word == "wait":
            if len(args) != 1:
                raise TeleopError(f"line {line_no}: wait takes one number of seconds")
            try:
                seconds = float(args[0])
            except ValueError:
                raise TeleopError(f"line {line_no}: wait: {args[0]!r} is not a number of seconds") from None
            if not 0 <= seconds <= 3600:
                raise TeleopError(f"line {line_no}: wait: {seconds} s is outside 0..3600")
        return step
    spec = commands().get(word)
    if spec is None:
        raise TeleopError(f"line {line_no}: unknown command {word!r} (known: {', '.join(all_words())})")
    try:
        step.message = build_message(spec, args)
    except TeleopError as exc:
        raise TeleopError(f"line {line_no}: {exc}") from None
    return step


def format_value(fld: Field, value) -> str:
    if fld.enum is Reason or fld.name in ("reason", "result", "safe_reason"):
        return reason_name(value)
    if fld.enum is not None:
        try:
            return fld.enum(value).name
        except ValueError:
            return str(value)
    if fld.name == "faults":
        return Fault(value).name or "none" if value else "none"
    if isinstance(value, float):
        return f"{value:.2f}"
    if isinstance(value, bytes):
        return value.hex()
    return str(value)


def format_message(msg: Message, skip: tuple[str, ...] = ("result",)) -> str:
    parts = []
    for fld, value in zip(msg.spec.fields, msg):
        if fld.name in skip:
            continue
        unit = f" {fld.unit}" if fld.unit and not isinstance(value, bytes) else ""
        parts.append(f"{fld.name}={format_value(fld, value)}{unit}")
    return f"{msg.spec.name} " + " ".join(parts) if parts else msg.spec.name


def format_outcome(handle: CommandHandle) -> str:
    latency = f" ({handle.latency_s * 1000:.1f} ms)" if handle.latency_s is not None else ""
    if handle.ok:
        body = format_message(handle.reply) if handle.reply is not None else ""
        return f"ok   {body}{latency}"
    return f"FAIL {handle.describe()}{latency}"


@dataclass
class Session:
    """Runs steps against a connected client and keeps the figures for the summary."""

    client: object
    out: TextIO = sys.stdout
    latencies_s: list[float] = field(default_factory=list)
    sent: int = 0
    failed: int = 0

    def run_step(self, step: Step) -> bool:
        if step.message is not None:
            self.sent += 1
            handle = self.client.call(step.message)
            print(format_outcome(handle), file=self.out, flush=True)
            if handle.latency_s is not None and handle.ok:
                self.latencies_s.append(handle.latency_s)
            if not handle.ok:
                self.failed += 1
            return handle.ok
        return self.run_local(step)

    def run_local(self, step: Step) -> bool:
        word, args, out = step.word, step.args, self.out
        if word == "help":
            print(help_text(args[0] if args else None), file=out)
        elif word == "link":
            print(link_report(self.client), file=out)
        elif word == "params":
            return list_params(self.client, out)
        elif word == "wait":
            self.client.clock.sleep(float(args[0]))
        elif word == "connect":
            self.client.connect()
            print("link up", file=out)
        elif word == "watch":
            seconds = float(args[0]) if args else 5.0
            watch(self.client, seconds, out)
        return True

    def summary(self) -> str:
        link = self.client.link
        stats = link.stats
        lines = [f"commands: {self.sent} sent, {self.sent - self.failed} ok, {self.failed} failed"]
        if self.latencies_s:
            ms = sorted(x * 1000 for x in self.latencies_s)
            p99 = ms[min(len(ms) - 1, int(round(0.99 * (len(ms) - 1))))]
            lines.append(f"round trip: p50 {statistics.median(ms):.1f} ms, p99 {p99:.1f} ms, max {ms[-1]:.1f} ms")
        lines.append(f"host link: frames {stats.frames_tx} out / {stats.frames_rx} in, bytes {stats.bytes_tx} / "
                     f"{stats.bytes_rx}, crc {stats.crc_errors}, auth {stats.auth_errors}, "
                     f"retransmits {stats.retransmits}, telemetry lost {stats.telemetry_lost}")
        peer = link.peer_stats
        if peer is not None:
            lines.append(f"controller link (heartbeat {peer_age(self.client)}): frames {peer.frames_rx} in / "
                         f"{peer.frames_tx} out, bytes in {peer.bytes_rx}, crc {peer.crc_errors}, "
                         f"auth {peer.auth_errors}, rejected {peer.rejected}, naks {peer.naks_tx}")
        return "\n".join(lines)


def help_text(word: Optional[str] = None) -> str:
    cmds = commands()
    if word is None:
        rows = [f"  {usage(s):<28} {s.doc}" for _, s in sorted(cmds.items())]
        rows += [f"  {text}" for text in LOCAL_COMMANDS.values()]
        return "commands:\n" + "\n".join(rows)
    if word in LOCAL_COMMANDS:
        return LOCAL_COMMANDS[word]
    spec = cmds.get(word)
    if spec is None:
        return f"unknown command {word!r}"
    lines = [usage(spec), f"  {spec.doc}"]
    for f in spec.fields:
        rng = f" range {f.range[0]}..{f.range[1]}" if f.range else ""
        lines.append(f"  {f.name}: {f.type}{' [' + f.unit + ']' if f.unit else ''}{rng}: {f.doc}")
    return "\n".join(lines)


def list_params(client, out: TextIO) -> bool:
    """Every parameter, read one by one with ParamList."""
    index, count = 0, 1
    while index < count:
        handle = client.call(SCHEMA["ParamList"].type(index))
        if not handle.ok:
            print(format_outcome(handle), file=out)
            return False
        reply = handle.reply
        count = reply.count
        print(f"  {reply.name:<16} {reply.value:>12.6g}   [{reply.min:g} .. {reply.max:g}]", file=out)
        index += 1
    return True


def link_report(client) -> str:
    link = client.link
    s = link.stats
    srtt = f"{link.srtt_s * 1000:.1f} ms" if link.srtt_s is not None else "n/a"
    lines = [f"link {link.state.value}, srtt {srtt}",
             f"  this end: frames {s.frames_tx} out / {s.frames_rx} in, crc errors {s.crc_errors}, "
             f"auth errors {s.auth_errors} (replays {s.replays}), rejected {s.rejected}, naks {s.naks_tx}/{s.naks_rx}, "
             f"retransmits {s.retransmits}, telemetry lost {s.telemetry_lost}"]
    if link.peer_stats is not None:
        lines.append(f"  controller (its heartbeat {peer_age(client)}): " + format_message(link.peer_stats))
    return "\n".join(lines)


def peer_age(client) -> str:
    return f"{client.clock.now() - client.link.peer_stats_s:.1f} s ago"


def telemetry_line(msg: Message) -> str:
    return (f"{format_value(msg.spec.fields[1], msg.state):<8} faults={format_value(msg.spec.fields[3], msg.faults)} "
            f"supply={msg.supply_v:.2f} V temp={msg.temp_c:.1f} C cmds={msg.commands_executed} "
            f"rx/tx={msg.frames_rx}/{msg.frames_tx} link_err={msg.link_errors} "
            f"loop max/p99={msg.loop_max_us}/{msg.loop_p99_us} us overruns={msg.overruns}")


def watch(client, seconds: float, out: TextIO) -> None:
    """Live telemetry on one refreshed line; on a pipe or file, the last reading once at the end."""
    shown = [None]
    live = out.isatty()

    def show(msg: Message, now: float) -> None:
        shown[0] = msg
        if live:
            print("\r" + telemetry_line(msg), end="", file=out, flush=True)

    client.telemetry_listeners.append(show)
    try:
        client.clock.sleep(seconds)
    except KeyboardInterrupt:
        pass
    finally:
        client.telemetry_listeners.remove(show)
        if shown[0] is None:
            print("(no telemetry: is the rate 0?)", file=out, flush=True)
        else:
            print("" if live else telemetry_line(shown[0]), file=out, flush=True)


def check_script(lines: list[str]) -> tuple[list[Step], list[str]]:
    """Every line parsed: the steps, and a message for each line that is not a command."""
    steps, problems = [], []
    for number, text in enumerate(lines, 1):
        try:
            step = parse_line(text, number)
        except TeleopError as exc:
            problems.append(str(exc))
            continue
        if step is not None:
            steps.append(step)
    return steps, problems


def run_script(client, lines: list[str], out: TextIO, keep_going: bool = False,
               err: TextIO = sys.stderr) -> tuple[int, Session]:
    """Check every line, then run them; returns (exit status, session)."""
    session = Session(client, out)
    steps, problems = check_script(lines)
    if problems:
        for problem in problems:
            print(f"error: {problem}", file=err)
        print("error: script not run: nothing was sent", file=err)
        return EXIT_USAGE, session
    status = EXIT_OK
    for step in steps:
        print(f"> {step.text}", file=out, flush=True)
        if step.word == "quit":
            break
        if not session.run_step(step):
            status = EXIT_FAILED
            if not keep_going:
                print(f"error: line {step.line_no}: {step.text!r} failed; stopping (use --keep-going to go on)",
                      file=err)
                break
    return status, session


def interactive(client, out: TextIO = sys.stdout) -> tuple[int, Session]:
    session = Session(client, out)
    try:
        import readline
    except ImportError:   # not on every platform
        readline = None
    if readline is not None:
        words = all_words()

        def complete(text: str, state: int) -> Optional[str]:
            matches = [w + " " for w in words if w.startswith(text)]
            return matches[state] if state < len(matches) else None
        readline.set_completer(complete)
        readline.parse_and_bind("tab: complete")
    client.event_listeners.append(lambda msg, now: print(f"\n! {format_message(msg)}", file=out, flush=True))
    print("type `help` for the commands, Tab completes, `quit` leaves", file=out)
    number = 0
    status = EXIT_OK
    while True:
        link = client.link
        state = link.last_telemetry.state if link.last_telemetry is not None else None
        state_name = format_value(SCHEMA["TelemetryStatus"].fields[1], state) if state is not None else "?"
        try:
            text = input(f"aspod [{link.state.value} {state_name}]> ")
        except (EOFError, KeyboardInterrupt):
            print(file=out)
            break
        number += 1
        try:
            step = parse_line(text, number)
        except TeleopError as exc:
            print(f"error: {exc}", file=out)
            continue
        if step is None:
            continue
        if step.word == "quit":
            break
        if not session.run_step(step):
            status = EXIT_FAILED
    return status, session
