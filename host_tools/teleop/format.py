"""Teleop's output: one console shared by two threads, and how values, replies and reasons read.

The link's pump thread prints events (motion ends) as they arrive while the main thread prints
replies and the live `watch` block, so every line goes out whole, under one lock (`Console`).
Names, units and reason texts all come from the declarations (protocol/messages.py,
protocol/reasons.py, protocol/states.py).
"""
from __future__ import annotations

import shutil
import textwrap
import threading
from typing import Optional, TextIO

from protocol.host_link import CommandHandle
from protocol.reasons import Reason, reason_name
from protocol.schema import Field, Message
from protocol.states import FAULT_CAUSE_DOCS, Axis, CloseWhy, ControllerState, Fault, FaultCause, TimingIssue, TimingMode

from host_tools.teleop.tables import Column, table_lines

WIDTH = 96          # wrap long docs to fit a 100-column terminal
MIN_WIDTH = 40      # the narrowest a line is wrapped to
INDENT = "     "    # continuation lines line up under the text after "ok   " / "FAIL "


class Console:
    """Whole lines to one stream from several threads; on a terminal, a block redrawn in place."""

    def __init__(self, out: TextIO) -> None:
        self.out = out
        self.live = is_terminal(out)
        self._lock = threading.Lock()
        self._block_lines = 0      # lines of the live block just above the cursor (0: none)

    def line(self, text: str = "") -> None:
        with self._lock:
            self.out.write(text + "\n")
            self.out.flush()
            self._block_lines = 0  # anything printed below the block: redraw it afresh below that

    def lines(self, texts: list[str]) -> None:
        self.line("\n".join(texts))

    def block(self, texts: list[str]) -> None:
        """Draw `texts` over the previous block (terminal only: cursor up, rewrite, clear to the end)."""
        with self._lock:
            up = f"\033[{self._block_lines}F" if self._block_lines else ""
            self.out.write(up + "".join(t + "\033[K\n" for t in texts))
            self.out.flush()
            self._block_lines = len(texts)


def is_terminal(out: TextIO) -> bool:
    try:
        return out.isatty()
    except (AttributeError, ValueError):
        return False


def fit(text: str, columns: int) -> list[str]:
    """`text`'s lines, each longer than `columns` - 1 wrapped at spaces (a word longer than that is broken)."""
    width = max(MIN_WIDTH, columns - 1)
    out = []
    for line in text.split("\n"):
        if len(line) <= width:
            out.append(line)
            continue
        lead = line[:len(line) - len(line.lstrip())]
        indent = lead + ("     " if line.lstrip()[:5] in ("ok   ", "FAIL ") else "  ")
        out += textwrap.wrap(line, width, initial_indent="", subsequent_indent=indent[:width // 2], break_on_hyphens=False,
                             drop_whitespace=True) or [line[:width]]
    return out


def for_terminal(text: str, out: TextIO) -> str:
    """`text` wrapped at spaces to the terminal `out` is (the banner, the exit summary); as it is on a pipe."""
    if not is_terminal(out):
        return text
    return "\n".join(fit(text, shutil.get_terminal_size().columns))


def param_lines(reply: Message) -> list[str]:
    """A ParamValue as a script's `params` lists it, as it comes: name, value, unit, range and what it does."""
    head = f"  {reply.name:<16} {reply.value:>12.6g} {reply.unit:<10} [{reply.min:g} .. {reply.max:g}]"
    return [f"{head}  {reply.description}".rstrip()]


PARAM_COLUMNS = (Column("name"), Column("value", right=True), Column("unit"), Column("range"),
                 Column("what it does", wrap=True))


def params_table(replies: list[Message], width: int) -> list[str]:
    """The console's `params`: every ParamValue in a table of `width`, descriptions wrapped in their column."""
    return table_lines(PARAM_COLUMNS, [[r.name, f"{r.value:.6g}", r.unit, f"{r.min:g} .. {r.max:g}", r.description]
                                       for r in replies], width, indent=2)


def wrap(text: str, indent: str = INDENT) -> list[str]:
    return textwrap.wrap(text, WIDTH, initial_indent=indent, subsequent_indent=indent + "  ") or [indent]


def enum_word(enum_type, value: int) -> str:
    """A wire value as teleop spells it (`j1`, `all`, `close`), or the number if unknown."""
    try:
        return enum_type(value).name.lower()
    except ValueError:
        return str(value)


def format_faults(value: int) -> str:
    if not value:
        return "none"
    known = Fault(value & sum(int(f) for f in Fault))
    names = [f.name for f in Fault if f and known & f]
    unknown = value & ~int(known)
    return ",".join(names + ([f"0x{unknown:x}"] if unknown else []))


def format_value(fld: Field, value) -> str:
    if fld.enum is Reason or fld.name in ("reason", "result", "safe_reason"):
        return reason_name(value)
    if fld.enum is not None:
        try:
            return fld.enum(value).name
        except ValueError:
            return str(value)
    if fld.name == "faults":
        return format_faults(value)
    if isinstance(value, float):
        return f"{value:.2f}"
    if isinstance(value, bytes):
        return value.hex()
    return str(value)


def message_parts(msg: Message, skip: tuple[str, ...] = ("result",)) -> list[str]:
    """`Name`, then `field=value unit` for each field."""
    parts = [msg.spec.name]
    for fld, value in zip(msg.spec.fields, msg):
        if fld.name in skip:
            continue
        unit = f" {fld.unit}" if fld.unit and not isinstance(value, bytes) else ""
        parts.append(f"{fld.name}={format_value(fld, value)}{unit}")
    return parts


def format_message(msg: Message, skip: tuple[str, ...] = ("result",)) -> str:
    return " ".join(message_parts(msg, skip))


def pack(parts: list[str], first: str, indent: str = INDENT) -> str:
    """Parts joined by spaces into lines of at most WIDTH, never splitting a part."""
    lines, line, placed = [], first, 0
    for part in filter(None, parts):
        sep = "" if line.endswith(" ") else " "
        if placed and len(line) + len(sep) + len(part) > WIDTH:
            lines.append(line)
            line, sep, placed = indent, "", 0
        line += sep + part
        placed += 1
    return "\n".join(lines + [line])


def fit_parts(parts: list[str], sep: str = "  ", indent: str = "  ") -> list[str]:
    """Parts joined by `sep` into lines of at most WIDTH, never splitting a part; a part that does not fit goes on
    a new line under `indent` ("" parts are left out)."""
    lines, line = [], ""
    for part in filter(None, parts):
        if line and len(line) + len(sep) + len(part) > WIDTH:
            lines.append(line)
            line = indent + part
        else:
            line = f"{line}{sep}{part}" if line else part
    return lines + [line] if line else lines


def reason_lines(reason: int, indent: str = INDENT) -> list[str]:
    """What a reason means and what to do, from protocol/reasons.py (nothing for OK)."""
    try:
        known = Reason(reason)
    except ValueError:
        return wrap(f"reason {reason} is not known to this build: check the schema hash", indent)
    if known is Reason.OK:
        return []
    return wrap(known.doc, indent) + wrap(f"remedy: {known.remedy}", indent)


def latency(handle: CommandHandle) -> str:
    return f" ({handle.latency_s * 1000:.1f} ms)" if handle.latency_s is not None else ""


def format_outcome(handle: CommandHandle) -> str:
    """`ok   Reply fields (ms)`, or `FAIL Name: rejected: REASON (n) (ms)` with the reason's doc and remedy."""
    if handle.ok:
        parts = message_parts(handle.reply) if handle.reply is not None else []
        return pack(parts + [latency(handle).strip()], "ok   ")
    return "\n".join(failure_lines(handle))


def failure_lines(handle: CommandHandle, extra: Optional[list[str]] = None) -> list[str]:
    reason = int(handle.reason)
    detail = handle.detail or getattr(handle.reply, "detail", "")    # the link's, or the reply's own (ParamSaved)
    detail = f" ({detail})" if detail else ""
    head = f"FAIL {handle.msg.spec.name}: {handle.outcome.value}: {reason_name(reason)} ({reason}){detail}"
    return [head + latency(handle)] + reason_lines(reason) + (extra or [])


def time_summary(timing: int, rtf_recent: float, lag_ms: float) -> str:
    """How the controller's time keeps up with the wall clock (Status, TelemetryStatus)."""
    mode = enum_word(TimingMode, timing)
    if timing in (TimingMode.SIMULATED, TimingMode.REALTIME):
        return f"time {mode}"
    return f"time {mode}: {rtf_recent:.2f}x real time over the last second, lag {lag_ms:.1f} ms"


def report_lines(msg: Message, prefix: str = "") -> list[str]:
    """A FaultReport or TimingWarning as teleop prints it: `! ...`, wrapped to the console's width."""
    return textwrap.wrap(describe_report(msg), WIDTH, initial_indent=prefix + "! ", subsequent_indent="  ")


def describe_report(msg: Message) -> str:
    """A FaultReport or TimingWarning in words: what was measured, against which limit (its parameter)."""
    if msg.spec.name == "FaultReport":
        try:
            cause = FaultCause(msg.cause)
            what, param = FAULT_CAUSE_DOCS[cause]
        except ValueError:
            what, param = f"cause {msg.cause}", "?"
        axis = "" if msg.axis == Axis.ALL else f"{enum_word(Axis, msg.axis)}: "
        return (f"FAULT {format_faults(msg.fault)} ({reason_name(msg.reason)}): {axis}{what}: "
                f"{msg.value_ms:.1f} ms against a limit of {msg.limit_ms:.1f} ms (parameter {param})")
    if msg.spec.name == "TimingWarning":
        if msg.issue == TimingIssue.LOOP_LATE:
            return (f"TIMING the host is overloaded: the motor loop started {msg.value * 1000:.1f} ms late "
                    f"(warns past loop_late_warn_s = {msg.limit * 1000:.0f} ms; faults SCHEDULER_OVERRUN past "
                    "loop_late_max_s while enabled)")
        if msg.issue == TimingIssue.BELOW_REAL_TIME:
            if not msg.active:
                return f"TIMING back to {msg.value:.3g}x real time"
            return (f"TIMING slow: the world ran at {msg.value:.3g}x real time over the last second, below "
                    f"{msg.limit:.3g}x (rtf_warn of the speed asked): the host is too slow, so simulated time slows "
                    "down with it; nothing is faulted")
    if msg.spec.name == "SessionClosed":
        return (f"the host closed its session ({enum_word(CloseWhy, msg.why)}): every motion stopped, outputs off, "
                f"brakes on; {enum_word(ControllerState, msg.state).upper()}, faults {format_faults(msg.faults)}")
    return format_message(msg)


def link_down_lines(handle: CommandHandle, cause: str) -> list[str]:
    """A command that never got its answer because the link went down: the link's trouble, not the retry limit."""
    return ([f"FAIL {handle.msg.spec.name}: no answer, the link is down: {cause}"]
            + wrap("its outcome is unknown: once the line is sound, `connect` again and read `status` before "
                   "sending it again"))
