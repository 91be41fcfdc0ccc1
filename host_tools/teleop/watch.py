"""`watch`: the arm and the controller, live, as one compact block fitted to the terminal (40-96 columns).

    ENABLED  faults none  supply 27.99 V  temp 25.0 C  up 14.2 s  cmds 9  homed 6/6
    axis    homed   position      velocity current mode    errors
    j1      yes    3.005 deg   0.000 deg/s   1.048 A HOLDING -
    ...
    gripper yes    50.790 mm    0.000 mm/s   0.000 A HOLDING -
    mount   yes   -1.143 deg   0.000 deg/s   0.156 A HOLDING -
    arm loop 1000 us: exec max 838 / p99 512 us, late max 8067 us, overruns 61
    all tasks: exec max 920 / p99 530 us, overruns 70; link rx/tx 120/355, errors 0, backlog 0 B
    time paced: 1.00x real time over the last second, lag 0.1 ms

Axes, units and modes come from the TelemetryJoints declaration; the state and faults from
TelemetryStatus. On a terminal the block is redrawn in place at up to 10 Hz; on a pipe or a
file the last reading is printed once at the end. `watch box` shows the solar tracker's control
box the same way (teleop/box.py).
"""
from __future__ import annotations

from typing import Callable, Optional

from protocol.messages import SCHEMA
from protocol.schema import Message

from host_tools.teleop import format as teleop_format
from host_tools.teleop.format import Console, enum_word, fit_parts, format_faults, format_value, time_summary
from host_tools.teleop.tables import Column, table_lines
from host_tools.teleop.words import AXIS_ENUM

REFRESH_S = 0.1
_JOINTS = SCHEMA["TelemetryJoints"]
_STATUS = SCHEMA["TelemetryStatus"]
_FIELD = {f.name: f for f in _JOINTS.fields}
# the axes in telemetry order: every `<axis>_pos` field, with its bit in `homed` (the axis's value)
TELEMETRY_AXES = tuple(f.name[:-4] for f in _JOINTS.fields if f.name.endswith("_pos"))


class TelemetryCache:
    """The latest message of each telemetry kind (written by the pump thread)."""

    def __init__(self) -> None:
        self.latest: dict[str, Message] = {}
        self.received = 0

    def on_telemetry(self, msg: Message, now: float) -> None:
        self.latest[msg.spec.name] = msg
        self.received += 1

    @property
    def status(self) -> Optional[Message]:
        return self.latest.get("TelemetryStatus")

    @property
    def joints(self) -> Optional[Message]:
        return self.latest.get("TelemetryJoints")


def _num(value: float, digits: int = 3) -> str:
    return f"{0.0 if abs(value) < 0.5 * 10 ** -digits else value:.{digits}f}"


_error_decoders = None


def error_names(axis: str, bits: int) -> str:
    """Axis error bits by name. They are the firmware's (firmware_py/axis.py, gripper.py), imported when first
    needed: the protocol declares only a u16 (see TelemetryJoints)."""
    global _error_decoders
    if not bits:
        return "-"
    if _error_decoders is None:
        from firmware_py.axis import AxisError
        from firmware_py.gripper import GRIPPER_TIMEOUT
        _error_decoders = ({int(e): e.name for e in AxisError if e}, {GRIPPER_TIMEOUT: "TIMEOUT"})
    table = _error_decoders[1] if axis == "gripper" else _error_decoders[0]
    names = [name for bit, name in table.items() if bits & bit]
    rest = bits & ~sum(table)
    return ",".join(names + ([f"0x{rest:x}"] if rest else []))


def status_parts(status: Optional[Message], joints: Optional[Message]) -> list[str]:
    parts = []
    if status is not None:
        state = format_value(_STATUS.fields[1], status.state)
        why = f" ({format_value(_STATUS.fields[2], status.safe_reason)})" if status.safe_reason else ""
        parts += [f"{state}{why}", f"faults {format_faults(status.faults)}", f"supply {status.supply_v:.2f} V",
                  f"temp {status.temp_c:.1f} C", f"up {status.uptime_ms / 1000:.1f} s",
                  f"cmds {status.commands_executed}"]
    else:
        parts.append("(no TelemetryStatus yet)")
    if joints is not None:
        homed = sum(bool(joints.homed >> int(AXIS_ENUM[a.upper()]) & 1) for a in TELEMETRY_AXES)
        parts.append(f"homed {homed}/{len(TELEMETRY_AXES)}")
    return parts


def axis_rows(joints: Message) -> list[list[str]]:
    rows = []
    for axis in TELEMETRY_AXES:
        get = lambda what: getattr(joints, f"{axis}_{what}")   # noqa: E731
        homed = "yes" if joints.homed >> int(AXIS_ENUM[axis.upper()]) & 1 else "no"
        pos_unit, vel_unit = _FIELD[f"{axis}_pos"].unit, _FIELD[f"{axis}_vel"].unit
        mode = enum_word(_FIELD[f"{axis}_mode"].enum, get("mode")).upper()
        rows.append([axis, homed, f"{_num(get('pos'))} {pos_unit}", f"{_num(get('vel'))} {vel_unit}",
                     f"{_num(get('current'))} A", mode, error_names(axis, get("errors"))])
    return rows


AXIS_COLUMNS = (Column("axis"), Column("homed"), Column("position", right=True), Column("velocity", right=True),
                Column("current", right=True), Column("mode"), Column("errors", wrap=True))


def timing_parts(status: Optional[Message], joints: Optional[Message]) -> list[list[str]]:
    """The loops' timing and the link's counters, each a list of parts (a line where the terminal is wide)."""
    lines = []
    if joints is not None:
        lines.append([f"arm loop {joints.arm_period_us} us:", f"exec max {joints.arm_exec_max_us} /",
                      f"p99 {joints.arm_exec_p99_us} us,", f"late max {joints.arm_late_max_us} us,",
                      f"overruns {joints.arm_overruns}"])
    if status is not None:
        lines.append(["all tasks:", f"exec max {status.loop_max_us} /", f"p99 {status.loop_p99_us} us,",
                      f"overruns {status.overruns};", f"link rx/tx {status.frames_rx}/{status.frames_tx},", f"errors {status.link_errors},",
                      f"backlog {status.tx_backlog_bytes} B"])
        lines.append([time_summary(status.timing, status.rtf_recent, status.lag_ms)])
    return lines


def arm_block(cache: TelemetryCache) -> list[str]:
    """The whole `watch` block, fitted to the console's width (teleop_format.WIDTH)."""
    status, joints = cache.status, cache.joints
    lines = fit_parts(status_parts(status, joints))
    if joints is not None:
        lines += table_lines(AXIS_COLUMNS, axis_rows(joints), teleop_format.WIDTH)
    for parts in timing_parts(status, joints):
        lines += fit_parts(parts, sep=" ")
    return lines


def watch(client, cache: TelemetryCache, seconds: float, console: Console,
          block: Callable[[TelemetryCache], list[str]] = arm_block) -> None:
    """Show `block` (the arm's; `watch box`: the control box's) for `seconds` (Ctrl-C ends it early)."""
    clock = client.clock
    deadline = clock.now() + seconds
    at_start = cache.received
    if console.live and cache.latest:
        console.block(block(cache))
    try:
        while True:
            left = deadline - clock.now()
            if left <= 0:
                break
            if not console.live:
                clock.sleep(left)
                continue
            seen = cache.received
            if client.wait_for(lambda: cache.received != seen, left) and cache.latest:
                console.block(block(cache))
                clock.sleep(min(REFRESH_S, max(0.0, deadline - clock.now())))
    except KeyboardInterrupt:
        pass
    if not cache.latest:
        console.line("(no telemetry: is the rate 0? `telemetry 10` starts it)")
    elif not console.live:
        stale = "" if cache.received != at_start else ["(no new telemetry while watching; the last reading)"]
        console.lines(list(stale) + block(cache))
