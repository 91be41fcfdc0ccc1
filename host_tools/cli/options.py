"""The options commands share: argument types that say their bounds, and groups of options (the link, the
controller's port, the HAL bus, the arm, the tracker, a bench's world). Each command's own options are in its
module (`add_options`: host_tools/cli/<command>.py); nothing here imports numpy or the plant until an option's
value is checked."""
from __future__ import annotations

import argparse
import math
import os
from pathlib import Path

from firmware_py.uart import BAUD_RATES
from protocol.errors import shown


_KIND_NAMES = {int: "whole number", float: "number"}


def baud_rate(text: str) -> int:
    rates = ", ".join(map(str, BAUD_RATES))
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{shown(text)} is not a whole number; one of {rates}") from None
    if value not in BAUD_RATES:
        raise argparse.ArgumentTypeError(f"{value} is not one of {rates}")
    return value


def bounded(kind, lo: float, hi: float):
    """An argparse type: a `kind` (int or float) within lo..hi; the error says the bounds (argparse names the
    option: `argument --seed: -1 is outside 0..4294967295`)."""
    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{shown(text)} is not a {_KIND_NAMES[kind]} in {lo}..{hi}") from None
        if not lo <= value <= hi:       # NaN too: it compares false
            raise argparse.ArgumentTypeError(f"{value} is outside {lo}..{hi}")
        return value
    return parse


def above_zero(text: str) -> float:
    """An argparse type: a finite number above 0 (a size, with no upper bound of its own)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{shown(text)} is not a number above 0") from None
    if not 0 < value < math.inf:        # NaN too: it compares false
        raise argparse.ArgumentTypeError(f"{value} is not a finite number above 0")
    return value


def controller_id(text: str) -> bytes:
    """An argparse type: a controller's identity, 16 hex digits (8 bytes)."""
    try:
        value = bytes.fromhex(text)
    except ValueError:
        value = b""
    if len(value) != 8:
        raise argparse.ArgumentTypeError(f"{shown(text)} is not 16 hex digits (8 bytes), e.g. 00000000000000a1")
    return value


def squeeze_force(text: str) -> float:
    """`free` (unbounded) or a bound in newtons, 0 to 1e6."""
    return float("inf") if text.strip().lower() == "free" else bounded(float, 0.0, 1e6)(text)


def weights_list(text: str) -> tuple[float, ...]:
    """Weights, one a joint, comma-separated: each a number 0..1e6."""
    parts = text.split(",")
    one = bounded(float, 0.0, 1e6)
    try:
        return tuple(one(part) for part in parts)
    except argparse.ArgumentTypeError as exc:
        raise argparse.ArgumentTypeError(f"{shown(text)}: each weight {exc}") from None


def speed_factor(text: str) -> float:
    if text.strip().lower() == "max":
        return math.inf
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{shown(text)} is not a number in 0.01..1000 or `max`") from None
    if not 0.01 <= value <= 1000:       # NaN too: it compares false
        raise argparse.ArgumentTypeError(f"{value} is outside 0.01..1000 (or `max`)")
    return value


def add_speed_arg(parser: argparse.ArgumentParser, what: str) -> None:
    parser.add_argument("--speed", type=speed_factor, default=1.0, metavar="X|max",
                        help=f"{what} simulated time at X times real time at most (default 1), or `max`: as fast "
                             "as the work allows; late, it slows down rather than jumps (docs/realtime.md)")


def add_timing_arg(parser: argparse.ArgumentParser, default: str, what: str) -> None:
    from host_tools.worlds.settings import TIMINGS
    parser.add_argument("--timing", choices=TIMINGS, default=default,
                        help=f"{what} (default {default}; docs/realtime.md)")


def add_seed_arg(parser: argparse.ArgumentParser, what: str) -> None:
    from host_tools.sessions.capture import SEED_MAX
    parser.add_argument("--seed", type=bounded(int, 0, SEED_MAX), default=0, metavar="N",
                        help=f"seed of {what}, 0..{SEED_MAX} (default 0)")


def add_link_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--key-file", type=Path, default=None,
                        help="pre-shared key file (hex); default: a simulator makes a key of its own, which a host "
                             "tool finds from the link's address (docs/protocol_security.md)")
    parser.add_argument("--baud", type=baud_rate, default=115200,
                        help="line rate in baud, 8N1 (default 115200; one of " + ", ".join(map(str, BAUD_RATES)) + ")")


def can_interface(text: str) -> str:
    from host_tools.worlds import nodes   # imported when used: it loads the controller and the plant
    try:
        return nodes.check_interface(text, between_processes=True)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_bus_args(parser: argparse.ArgumentParser) -> None:
    """The HAL bus: a python-can interface and channel, opened for CAN FD."""
    parser.add_argument("--interface", type=can_interface, required=True,
                        help="python-can interface: udp_multicast (between processes, no hardware), socketcan, "
                             "pcan, ... (not virtual: it joins only buses in one process)")
    parser.add_argument("--channel", required=True,
                        help="python-can channel: udp_multicast a multicast group (e.g. 239.74.163.2), "
                             "socketcan an interface (can0), ...")
    parser.add_argument("--bitrate", type=bounded(int, 1, 10_000_000), default=None, metavar="BIT/S",
                        help="nominal (arbitration) bit rate, for interfaces that set one")
    parser.add_argument("--data-bitrate", type=bounded(int, 1, 20_000_000), default=None, metavar="BIT/S",
                        help="CAN FD data-phase bit rate, for interfaces that set one")
    parser.add_argument("--bus-arg", action="append", metavar="KEY=VALUE",
                        help="further keyword for the python-can bus, repeatable (udp_multicast: port=N, "
                             "default 43113; socketcand: host=H port=N)")


def add_controller_args(parser: argparse.ArgumentParser) -> None:
    """The controller's UART and settings, shared by `aspod sim` and `aspod firmware`."""
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--pty", action="store_true", help="serve a new pseudo-terminal (the default)")
    where.add_argument("--tcp", type=bounded(int, 0, 65535), metavar="PORT",
                       help="serve TCP on 127.0.0.1:PORT (0 picks a free port)")
    where.add_argument("--port", metavar="DEVICE", help="use a real serial device (or any pyserial URL)")
    where.add_argument("--link", action="append", metavar="NAME=ENDPOINT",
                       help="one of several redundant links (repeatable): ENDPOINT is pty, tcp:PORT or a device; "
                            "every frame goes out on each, the first copy in is kept (docs/sessions.md), e.g. "
                            "--link radio=pty --link optical=tcp:0")
    add_link_args(parser)
    parser.add_argument("--no-pacing", action="store_true", help="do not emulate wire time (as fast as the port goes)")
    parser.add_argument("--loop-hz", type=bounded(float, 50.0, 5000.0), default=1000.0, metavar="HZ",
                        help="rate of the arm's motor loops (default 1000)")
    parser.add_argument("--link-timeout", type=bounded(float, 0.05, 3600), default=None, metavar="S",
                        help="safe state after this long without a valid frame (default: saved, else 3 s)")
    parser.add_argument("--controller-id", type=controller_id, default=None, metavar="HEX",
                        help="this controller's identity, 16 hex digits, named in HelloReply and binding its "
                             "handshake NAKs (default: new at each start); the same across restarts, a host "
                             "recognises a restart at once; a fleet sharing one key gives each its own "
                             "(docs/protocol_security.md)")
    parser.add_argument("--telemetry-hz", type=bounded(int, 0, 200), default=None, metavar="HZ",
                        help="telemetry rate at start (default: saved, else 10)")
    parser.add_argument("--params", type=Path, default=None, metavar="FILE",
                        help="parameter file, loaded at boot and written by `save` "
                             f"(default {default_params_path()})")


def add_arm_args(parser: argparse.ArgumentParser) -> None:
    """The plant's arm: gravity and payload."""
    from host_tools.worlds.settings import GRAVITY_MODES, PAYLOAD_MAX_KG
    parser.add_argument("--gravity", choices=GRAVITY_MODES, default="earth",
                        help="the arm's gravity (default earth)")
    parser.add_argument("--payload-kg", type=bounded(float, 0.0, PAYLOAD_MAX_KG), default=0.0, metavar="M",
                        help="mass carried at the gripper tip, kg (default 0)")


def sun_start(text: str):
    """`now` (resolved when the plant is built: cli/plant.py `resolve_sun`), else POSIX seconds."""
    from host_tools.datetimes import NOW, parse_when
    try:
        seconds = parse_when(text, "sun start", posix=False)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return NOW if seconds is None else seconds


def cloud_spec(text: str) -> str:
    from datetime import date

    from hil_sim.sun import parse_clouds
    try:
        parse_clouds(text, date(2026, 1, 1), -7.0)     # the form only; the day is the start's (PlantSettings)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def add_bench_world_args(parser: argparse.ArgumentParser) -> None:
    """What else a lock-step bench's world may be given: faults at their times, the link's impairment,
    controller parameters, the script's variables (host_tools/worlds/bench_world.py)."""
    parser.add_argument("--fault", action="append", default=[], metavar="NAME[:CH]@T[-T2]",
                        help="inject a plant fault at simulated time T (s), cleared at T2 if given (repeatable): "
                             "jam:j2@3.5, supply_sag@10-12 (the faults: hil_sim/faults.py)")
    parser.add_argument("--impairment", default=None, metavar="SPEC",
                        help="impair the link as `aspod proxy` does: radio, optical, ber=1e-5,drop=0.01, ...")
    parser.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                        help="set a controller parameter before the run (repeatable)")
    parser.add_argument("--var", action="append", default=[], metavar="NAME=VALUE",
                        help="the script's ${NAME} is VALUE (repeatable)")
    parser.add_argument("--arms", type=int, choices=(1, 2), default=1,
                        help="2: the report's two example arms, each with its own controller, the example's object "
                             "waiting between them, as aspod sim --arms 2 (the script drives arm 1; the pytest "
                             "plugin's aspod_target.arm2 the other; --param sets both)")


def add_tracker_args(parser: argparse.ArgumentParser) -> None:
    """The plant's solar tracker: the sun's date-time at start, clouds, or no tracker at all."""
    parser.add_argument("--sun-start", type=sun_start, default=None, metavar="now|ISO",
                        help="the simulated sun's date-time at start: `now` (the default: the real sun at Tucson, "
                             "so that `clock now` at teleop matches it) or ISO 8601 with its offset, e.g. "
                             "2026-03-20T06:50-07:00 (MST; Z for UTC); 2000-2099")
    parser.add_argument("--clouds", type=cloud_spec, default=None, metavar="SPEC",
                        help="cloud passages TIME+DURATION@ATTENUATION, comma-separated, local standard time on the "
                             "start's date: '12:00+300s@0.9,14:30+10m@0.5'")
    parser.add_argument("--no-tracker", action="store_true",
                        help="a plant without the solar tracker (the arm, mount and gripper only)")


def default_params_path() -> Path:
    """The per-user parameter file: `$XDG_CONFIG_HOME/aspod/params.json` (default `~/.config`)."""
    base = os.environ.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
    return Path(base) / "aspod" / "params.json"
