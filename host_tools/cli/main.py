"""`aspod`: one command line, thin subcommands on shared argument helpers.

    aspod sim [--pty | --tcp PORT | --port DEVICE] [--baud N] [--key-file PATH] [--hal INTERFACE] ...
              [--sun-start now|ISO] [--clouds SPEC] [--no-tracker]
    aspod plant --interface X --channel Y [--bitrate N] [--seed N] [--gravity earth|orbit] [--payload-kg M]
              [--sun-start now|ISO] [--clouds SPEC] [--no-tracker]
    aspod firmware --interface X --channel Y [--pty | --tcp PORT | --port DEVICE] [--baud N] ...
    aspod teleop URL [--script FILE] [--key-file PATH] ...
    aspod demo [--json] [--gravity earth|orbit]
    aspod tracker-day [--mode relay|feedforward] [--dial X] [--date YYYY-MM-DD] [--clouds SPEC] [--json] [--plot F]

    aspod completion bash|zsh
    aspod --version;  -v / -q / --log-file PATH before or after the command

Each command turns its Namespace, once, into frozen settings (host_tools/cli/settings.py); nothing
below cli/ sees argparse. Only the command being run gets its options (`COMMANDS`, `build_parser`), and
each command imports its own module when it runs: `aspod --version` and `--help` import neither numpy
nor the plant (docs/Code_Overview.md, "Starting light"). Diagnostics go through the `aspod` logger (stderr, bare messages at INFO);
results and ready lines go to stdout.

Exit status: 0 ok, 1 a command failed, 2 bad usage or input, 3 link refused, unreachable or lost.
"""
from __future__ import annotations

import argparse
import math
import os
import signal
import sys
from pathlib import Path
from typing import Collection, Optional, Sequence

from firmware_py.uart import BAUD_RATES
from protocol.errors import KeyFileError, LinkError, shown

from host_tools.exit_codes import EXIT_FAILED, EXIT_LINK, EXIT_OK, EXIT_USAGE


_KIND_NAMES = {int: "whole number", float: "number"}


def _baud(text: str) -> int:
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


def controller_id(text: str) -> bytes:
    """An argparse type: a controller's identity, 16 hex digits (8 bytes)."""
    try:
        value = bytes.fromhex(text)
    except ValueError:
        value = b""
    if len(value) != 8:
        raise argparse.ArgumentTypeError(f"{shown(text)} is not 16 hex digits (8 bytes), e.g. 00000000000000a1")
    return value


def _squeeze(text: str) -> float:
    """`free` (unbounded) or a bound in newtons, 0 to 1e6."""
    return float("inf") if text.strip().lower() == "free" else bounded(float, 0.0, 1e6)(text)


def _speed(text: str) -> float:
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
    parser.add_argument("--speed", type=_speed, default=1.0, metavar="X|max",
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
    parser.add_argument("--baud", type=_baud, default=115200,
                        help="line rate in baud, 8N1 (default 115200; one of " + ", ".join(map(str, BAUD_RATES)) + ")")


def _interface(text: str) -> str:
    from host_tools.worlds import nodes   # imported when used: it loads the controller and the plant
    try:
        return nodes.check_interface(text, between_processes=True)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_bus_args(parser: argparse.ArgumentParser) -> None:
    """The HAL bus: a python-can interface and channel, opened for CAN FD."""
    parser.add_argument("--interface", type=_interface, required=True,
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


def _sun_start(text: str):
    """`now` (resolved when the plant is built: cli/plant.py `resolve_sun`), else POSIX seconds."""
    from host_tools.datetimes import NOW, parse_when
    try:
        seconds = parse_when(text, "sun start", posix=False)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return NOW if seconds is None else seconds


def _clouds(text: str) -> str:
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


def add_tracker_args(parser: argparse.ArgumentParser) -> None:
    """The plant's solar tracker: the sun's date-time at start, clouds, or no tracker at all."""
    parser.add_argument("--sun-start", type=_sun_start, default=None, metavar="now|ISO",
                        help="the simulated sun's date-time at start: `now` (the default: the real sun at Tucson, "
                             "so that `clock now` at teleop matches it) or ISO 8601 with its offset, e.g. "
                             "2026-03-20T06:50-07:00 (MST; Z for UTC); 2000-2099")
    parser.add_argument("--clouds", type=_clouds, default=None, metavar="SPEC",
                        help="cloud passages TIME+DURATION@ATTENUATION, comma-separated, local standard time on the "
                             "start's date: '12:00+300s@0.9,14:30+10m@0.5'")
    parser.add_argument("--no-tracker", action="store_true",
                        help="a plant without the solar tracker (the arm, mount and gripper only)")


EXIT_CODES_TEXT = (f"exit status: {EXIT_OK} ok, {EXIT_FAILED} a command failed, {EXIT_USAGE} bad usage or input, "
                   f"{EXIT_LINK} link refused, unreachable or lost, 130 interrupted")
EXAMPLES = {
    None: ["aspod sim --pty", "aspod teleop /dev/pts/5 --script benches/tracker_procedure.aspod", "aspod demo",
           "aspod completion bash > ~/.local/share/bash-completion/completions/aspod"],
    "sim": ["aspod sim --pty", "aspod sim --tcp 0 --sun-start 2026-03-20T06:50-07:00 --clouds '12:00+300s@0.9'",
            "aspod sim --hal udp_multicast --pty"],
    "plant": ["aspod plant --interface udp_multicast --channel 239.74.163.2 --gravity orbit"],
    "firmware": ["aspod firmware --interface udp_multicast --channel 239.74.163.2 --pty"],
    "teleop": ["aspod teleop /dev/pts/5", "aspod teleop socket://127.0.0.1:5555 --script session.txt --summary"],
    "bench": ["aspod bench benches/tracker_procedure.aspod --sun-start 2026-03-20T06:50-07:00",
              "aspod bench session.txt --json > result.json", "aspod bench session.txt --record s.pcapng"],
    "campaign": ["aspod campaign benches/test_pick_and_place.py --seeds 1000 --draw payload_kg=0..2.5 "
                 "--draw fault=none,jam:j2,open_circuit:j1,encoder_dropout:j3 --draw fault_at_s=1..20 "
                 "--group-by fault --plot m.worst_error_mm:payload_kg",
                 "aspod campaign benches/campaigns/tracker_dial.txt --vary sun_start=2026-01-15T10:00-07:00..2026-12-15T10:00-07:00/12 "
                 "--vary dial=5,10,20 --scheduler tcp://10.0.0.5:8786"],
    "demo": ["aspod demo", "aspod demo --json --gravity orbit", "aspod demo --link"],
    "tracker-day": ["aspod tracker-day --mode feedforward --date 2026-12-21 --plot day.png"],
    "log": ["aspod log session.pcapng", "aspod log session.pcapng --class command --class event",
            "aspod log session.pcapng --stats", "aspod log session.pcapng --message TelemetryJoints --csv joints.csv",
            "aspod log session.pcapng --plot session.png --key-file link.key"],
    "fuzz": ["aspod fuzz controller-link --time 60", "aspod fuzz frames codec teleop --runs 10000000 --jobs 8 --coverage",
             "aspod fuzz --target-cmd 'aspod sim --pty --no-pacing' --time 60",
             "aspod fuzz --url /dev/pts/5 --key-file link.key --only BoxDial --time 600",
             "aspod fuzz --replay fuzz-findings/crash-codec-0123456789ab.json"],
    "plan": ["aspod plan", "aspod plan --json --plot figures", "aspod plan --objective thermal --max-time 2",
             "aspod plan --problem my_path.json --objective time --integrator ab2",
             "aspod plan --method reach --nodes 99 --squeeze free --objective time",
             "aspod plan --method reach --order 2 --nodes 99 --objective time"],
    "proxy": ["aspod proxy --controller /dev/pts/5", "aspod proxy --controller socket://127.0.0.1:5000 --host tcp:6000 "
              "--impair 'radio,seed=7' --record radio.pcapng"],
    "replay": ["aspod demo --record demo.pcapng && aspod replay demo.pcapng",
               "aspod replay sim.pcapng --param j1_kp=40 --output replayed.pcapng"],
    "wireshark": ["aspod wireshark -o aspod.lua && tshark -X lua_script:aspod.lua -r session.pcapng"],
    "completion": ["aspod completion bash > ~/.local/share/bash-completion/completions/aspod",
                   "aspod completion zsh > ~/.zfunc/_aspod"],
}
SHELLS = ("bash", "zsh")


def _epilog(command: Optional[str]) -> str:
    lines = "\n".join(f"  {example}" for example in EXAMPLES[command])
    return f"examples:\n{lines}\n\n{EXIT_CODES_TEXT}"


def installed_version(distribution: str = "aspod") -> str:
    """The version in the installed distribution's metadata: the `Version:` line of the first
    `NAME-*.dist-info/METADATA` on sys.path, where importlib.metadata finds it too (tests/test_cli_start.py
    compares them), read without importlib.metadata's imports (email, zipfile, csv), which cost as much as
    Python's own start."""
    prefix = distribution + "-"
    for entry in sys.path:
        try:
            names = sorted(os.listdir(entry or "."))
        except OSError:                 # a zip, a folder gone: importlib.metadata skips it too
            continue
        for name in names:
            if name.startswith(prefix) and name.endswith(".dist-info"):
                try:
                    with open(os.path.join(entry or ".", name, "METADATA"), encoding="utf-8") as metadata:
                        for line in metadata:
                            if line.startswith("Version:"):
                                return line.split(":", 1)[1].strip()
                            if not line.strip():        # the headers end at the first blank line
                                break
                except OSError:
                    continue
    return "unknown (not installed)"    # run from a source tree that was never installed


class _VersionAction(argparse.Action):
    """--version: the installed package's version, from its metadata, read only when asked."""

    def __init__(self, option_strings: Sequence[str], dest: str = argparse.SUPPRESS, **kwargs) -> None:
        super().__init__(option_strings, dest=dest, default=argparse.SUPPRESS, nargs=0,
                         help="show the program's version and exit")

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        print(f"{parser.prog} {installed_version()}")
        parser.exit()


def add_logging_args(parser: argparse.ArgumentParser) -> None:
    """-v, -q, --log-file and --force: before the command or after it (`aspod -v sim`, `aspod sim -v`)."""
    group = parser.add_argument_group("logging")
    group.add_argument("-v", "--verbose", action="count", default=argparse.SUPPRESS,
                       help="more diagnostics on stderr (repeatable: -vv for debug)")
    group.add_argument("-q", "--quiet", action="count", default=argparse.SUPPRESS,
                       help="fewer diagnostics on stderr: -q warnings and errors only, -qq errors only")
    group.add_argument("--log-file", type=Path, default=argparse.SUPPRESS, metavar="PATH",
                       help="also write the diagnostics, time-stamped, to PATH (appended)")
    outputs = parser.add_argument_group("output files")
    outputs.add_argument("--force", action="store_true", default=argparse.SUPPRESS,
                         help="write an output over an existing file that is not of its kind (a capture over a text "
                              "file, say); an output never replaces an input of the same run (docs/sessions.md)")


def setup_logging(verbose: int = 0, quiet: int = 0, log_file: Optional[Path] = None) -> None:
    """The `aspod` logger: diagnostics on stderr as bare messages (INFO by default, so the lines that scripts
    and tests read stay as they were), and to `log_file` with time and level."""
    import logging                      # here, not at the top: `aspod --version` and `--help` need none of it
    level = min(max(logging.INFO - 10 * verbose + 10 * quiet, logging.DEBUG), logging.CRITICAL)
    log = logging.getLogger("aspod")
    for handler in list(log.handlers):
        log.removeHandler(handler)
        handler.close()
    log.setLevel(level)
    log.propagate = False
    stderr = logging.StreamHandler(sys.stderr)
    stderr.setFormatter(logging.Formatter("%(message)s"))
    log.addHandler(stderr)
    if log_file is not None:
        to_file = logging.FileHandler(log_file, encoding="utf-8")
        to_file.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(message)s"))
        log.addHandler(to_file)


def _sim_options(sim: argparse.ArgumentParser) -> None:
    add_controller_args(sim)
    add_seed_arg(sim, "the plant's noise")
    sim.add_argument("--hal", type=_interface, metavar="INTERFACE",
                     help="run the plant as a separate process (`aspod plant`), meeting it on this python-can "
                          "interface, e.g. udp_multicast (default: one process, a private virtual bus)")
    sim.add_argument("--hal-channel", metavar="CH",
                     help="channel for --hal (udp_multicast: a multicast group; default: a fresh group and "
                          "port for this run)")
    sim.add_argument("--hal-arg", action="append", metavar="KEY=VALUE",
                     help="further keyword for the --hal bus, repeatable (udp_multicast: port=N)")
    add_speed_arg(sim, "the world (one process; with --hal, the plant process, in lock-step with the controller) "
                       "runs")
    add_arm_args(sim)
    add_tracker_args(sim)
    sim.add_argument("--record", type=Path, metavar="FILE.pcapng",
                     help="capture every frame on the controller's line, both ways, stamped with the world's time "
                          "(aspod log, Wireshark with aspod wireshark's dissector, aspod replay)")
    sim.add_argument("--can-log", type=Path, metavar="FILE",
                     help="write every HAL bus frame through python-can's Logger (.blf, .asc, .log, .csv, .trc, "
                          ".txt), for cantools decode, can.viewer, cantools plot")
    control = sim.add_mutually_exclusive_group()
    control.add_argument("--control", type=Path, metavar="PATH",
                         help="serve the control endpoint (faults, gravity, payload, clouds, pause and step, the "
                              "plant's true state: docs/benches.md; the link's key for host tools) on this Unix "
                              "socket; by default it is served at a per-user path, said in an ASPOD-CONTROL line "
                              "(with --hal it reaches no plant and says only the link and its key)")
    control.add_argument("--no-control", action="store_true",
                         help="serve no control endpoint (host tools then need --key-file)")


def _plant_options(plant: argparse.ArgumentParser) -> None:
    add_bus_args(plant)
    add_seed_arg(plant, "the plant's noise")
    add_arm_args(plant)
    add_tracker_args(plant)
    plant.add_argument("--stop-on-stdin-eof", action="store_true",
                       help="also stop when standard input closes (for a parent process that started it)")
    add_timing_arg(plant, "lockstep", "lockstep: integrate each tick only once the controller (aspod firmware "
                                      "--timing lockstep) has answered the last one, so neither side sees the "
                                      "other's stalls; realtime: tick on the wall clock, whoever listens (to close "
                                      "the loop around a controller that does not speak lock-step)")
    add_speed_arg(plant, "the plant")


def _firmware_options(firmware: argparse.ArgumentParser) -> None:
    add_bus_args(firmware)
    add_controller_args(firmware)
    firmware.add_argument("--boot-timeout", type=bounded(float, 0.01, 3600), default=None, metavar="S",
                          help="HAL inputs must arrive this soon after start, else HAL_STALE (default 1 s)")
    add_timing_arg(firmware, "lockstep", "lockstep: the controller's time follows the plant's PLANT_SYNC ticks "
                                         "(aspod plant --timing lockstep); realtime: the wall clock, as on real "
                                         "hardware, with the staleness limits and loop deadlines as parameters")
    firmware.add_argument("--plant-pid", type=bounded(int, 1, 2**22), default=None, metavar="PID",
                          help="lock-step: the plant's process on this machine (its ASPOD-PLANT line says pid=N); "
                               "the wait for its tick is then judged on its own time, so a busy machine is not "
                               "taken for a plant gone (default: the wall clock, less this process's own waits "
                               "for a CPU)")


def _teleop_options(teleop: argparse.ArgumentParser) -> None:
    teleop.add_argument("url", help="pyserial URL or device: /dev/pts/N, socket://HOST:PORT, ...")
    add_link_args(teleop)
    teleop.add_argument("--script", type=Path, metavar="FILE", help="run the commands in FILE and exit")
    teleop.add_argument("--keep-going", action="store_true", help="in a script, go on after a failed command")
    teleop.add_argument("--connect-timeout", type=bounded(float, 0.1, 600), default=10.0, metavar="S")
    teleop.add_argument("--summary", action="store_true", help="print link figures at the end")
    teleop.add_argument("--json", action="store_true",
                        help="with a script: print one JSON object (each line's outcome and output, the motions, "
                             "the round trips) instead of the session's text")
    teleop.add_argument("--record", type=Path, metavar="FILE.pcapng",
                        help="capture every frame both ways, as this host sent and received them (aspod log)")
    teleop.add_argument("--control", type=Path, metavar="PATH",
                        help="the simulator's control endpoint, for `sim` lines (default: the one of the aspod sim "
                             "that serves URL, if any)")


def _bench_options(bench: argparse.ArgumentParser) -> None:
    bench.add_argument("script", type=Path, metavar="SCRIPT", help="a teleop script (one command a line)")
    add_seed_arg(bench, "the plant's noise and the link's nonces")
    add_arm_args(bench)
    add_tracker_args(bench)
    add_bench_world_args(bench)
    bench.add_argument("--keep-going", action="store_true", help="go on after a failed command")
    bench.add_argument("--json", action="store_true", help="print one JSON object: steps, motions, the plant's state")
    bench.add_argument("--record", type=Path, metavar="FILE.pcapng",
                       help="capture the session on the simulated clock (aspod replay re-runs it to the bit)")


def _campaign_options(campaign: argparse.ArgumentParser) -> None:
    campaign.add_argument("bench", metavar="BENCH", help="a teleop script, or a pytest file or node "
                                                         "(path.py, path.py::test_name)")
    campaign.add_argument("--vary", action="append", default=[], metavar="NAME=VALUES",
                          help="a grid axis: NAME=A,B,C (impairment, clouds: A|B|C) or NAME=LO..HI/N (numbers or ISO date-times); every "
                               "combination runs. NAME: gravity, payload_kg, sun_start, clouds, fault, fault_at_s, "
                               "fault_until_s, impairment, param.NAME, or a bench variable (a script's ${NAME})")
    campaign.add_argument("--draw", action="append", default=[], metavar="NAME=VALUES",
                          help="drawn for each run from its seed: NAME=A,B,C (one of) or NAME=LO..HI (uniform); "
                               "impairment and clouds values are separated by | instead")
    campaign.add_argument("--seeds", default="1", metavar="N|FIRST..LAST",
                          help="each grid point runs with these seeds (default 1: seed 0)")
    campaign.add_argument("--workers", type=bounded(int, 1, 1024), default=None, metavar="N",
                          help="local Dask workers (default: one per core)")
    campaign.add_argument("--scheduler", default=None, metavar="tcp://HOST:8786",
                          help="a running Dask scheduler instead of a local cluster (docs/campaigns.md)")
    campaign.add_argument("--serial", action="store_true", help="no Dask: every run in this process, in order")
    campaign.add_argument("--out", type=Path, default=None, metavar="DIR",
                          help="where the rows, campaign.json and plots go (default campaign-<UTC time>; "
                               "a folder that already holds a campaign is refused)")
    campaign.add_argument("--format", choices=("csv", "parquet"), default="csv", help="the rows' file (default csv)")
    campaign.add_argument("--group-by", default=None, metavar="COLUMN",
                          help="the summary per value of this column (default: fault, when it varies)")
    campaign.add_argument("--summarize", action="append", default=[], metavar="COLUMN",
                          help="a figure for the summary (default: the bench's measurements, the time to the "
                               "safe state)")
    campaign.add_argument("--plot", action="append", default=[], metavar="Y:X", help="a scatter plot of Y against X")
    campaign.add_argument("--hist", action="append", default=[], metavar="COLUMN", help="a histogram")
    campaign.add_argument("--keep-going", action="store_true", help="a script goes on after a failed line")
    campaign.add_argument("--no-progress", action="store_true", help="no progress bar")


def _fuzz_options(fuzz: argparse.ArgumentParser) -> None:
    fuzz.add_argument("targets", nargs="*", metavar="TARGET",
                      help="in-process targets (--list names them), or module:factory for your own")
    fuzz.add_argument("--list", action="store_true", help="list the in-process targets and what each covers")
    fuzz.add_argument("--url", default=None, help="black-box: the link of a running target (pty, socket://, device)")
    fuzz.add_argument("--target-cmd", default=None, metavar="COMMAND",
                      help="black-box: start the target with COMMAND (it prints ASPOD-LINK URL, as aspod sim does); "
                           "it is restarted after a crash, and findings are shrunk on fresh targets")
    fuzz.add_argument("--key-file", type=Path, default=None,
                      help="the link's key (default: with --url, that of the local simulator serving it; with "
                           "--target-cmd, each target's own, from its ASPOD-KEY line)")
    fuzz.add_argument("--baud", type=_baud, default=115200, help="black-box: the line's rate (default 115200)")
    fuzz.add_argument("--replay", type=Path, default=None, metavar="FILE", help="run one finding again, alone")
    fuzz.add_argument("--time", type=bounded(float, 0.001, 30 * 86400), default=None, metavar="S",
                      help="seconds per job (in process) or in all (black-box); default 60 unless --runs/--cases")
    fuzz.add_argument("--runs", type=bounded(int, 1, 10**12), default=None, metavar="N",
                      help="in process: executions per job")
    fuzz.add_argument("--cases", type=bounded(int, 1, 10**9), default=None, metavar="N", help="black-box: cases")
    fuzz.add_argument("--hang-s", type=bounded(float, 0.01, 86400), default=None, metavar="S",
                      help="in process and --replay: an input past S seconds of its own time (the time the host kept "
                           "it waiting for a CPU does not count) is a hang (default 10)")
    fuzz.add_argument("--max-findings", type=bounded(int, 1, 10**6), default=None, metavar="N",
                      help="black-box: stop after N findings (default: go on to --time or --cases)")
    fuzz.add_argument("--jobs", type=bounded(int, 1, 10000), default=1, metavar="N",
                      help="in process: jobs per target, each with its own seed, sharing the target's corpus")
    fuzz.add_argument("--seed", type=bounded(int, 1, 2**31 - 1), default=1, help="the first job's seed (default 1)")
    fuzz.add_argument("--corpus", type=Path, default=Path("fuzz-corpus"), metavar="DIR",
                      help="corpus folders, one per target, kept between runs (default fuzz-corpus)")
    fuzz.add_argument("--findings", type=Path, default=Path("fuzz-findings"), metavar="DIR",
                      help="where findings are written (default fuzz-findings)")
    fuzz.add_argument("--only", action="append", default=[], metavar="MESSAGE",
                      help="black-box: send only this command in sequence (repeatable)")
    fuzz.add_argument("--skip", action="append", default=None, metavar="MESSAGE",
                      help="black-box: never send this command (repeatable; default ParamSave)")
    fuzz.add_argument("--workers", type=bounded(int, 1, 1024), default=None, metavar="N",
                      help="in process: local Dask workers (default one per core)")
    fuzz.add_argument("--scheduler", default=None, metavar="tcp://HOST:8786", help="a running Dask scheduler")
    fuzz.add_argument("--serial", action="store_true", help="no Dask: the jobs one after the other, here")
    fuzz.add_argument("--coverage", action="store_true",
                      help="in process: afterwards, the line coverage each target's corpus reaches (coverage.py)")
    fuzz.add_argument("--json", action="store_true", help="print one JSON object at the end")
    fuzz.add_argument("--no-progress", action="store_true", help="no progress bar")


def _plan_options(plan: argparse.ArgumentParser) -> None:
    plan.add_argument("--problem", type=Path, default=None, metavar="FILE",
                      help="a path, arms, object and limits from a JSON file (default: the report's example)")
    plan.add_argument("--objective", choices=("time", "energy", "work", "thermal"), default="energy",
                      help="time: the minimum-time plan alone; otherwise also the dynamic-programming plan "
                           "minimising this (default energy, the report's index)")
    plan.add_argument("--max-time", type=bounded(float, 1e-6, 1e6), default=None, metavar="S",
                      help="the minimum-cost plan's time bound in seconds")
    plan.add_argument("--method", choices=("phase", "reach"), default="phase",
                      help="minimum time: phase, the report's switching points on the phase plane (default); reach, "
                           "reachability (TOPP-RA), every torque within its limits between grid points too")
    plan.add_argument("--squeeze", type=_squeeze, default=None, metavar="N|free",
                      help="--method reach: the squeeze force between the grasps a free variable, |squeeze| <= N "
                           "newtons, or unbounded (free); default none, the load shared without squeeze")
    plan.add_argument("--order", type=int, choices=(1, 2), default=1,
                      help="--method reach: 1, s'' constant between grid points (default; takes --squeeze); 2, s'' "
                           "linear, on grid points placed where time is lost (within 0.1 %% of a dense plan at 100)")
    plan.add_argument("--integrator", choices=("ab2", "rk4"), default="rk4",
                      help="limit curves by the report's 2nd-order Adams-Bashforth, or 4th-order Runge-Kutta "
                           "(default)")
    # at most plan.reach.MAX_GRIDPOINTS - 1 (a reach plan takes nodes + 1 points; not imported: the CLI starts light)
    plan.add_argument("--nodes", type=bounded(int, 10, 199_999), default=2000,
                      help="intervals in s for the minimum-time plan (default 2000)")
    plan.add_argument("--dp-intervals", type=bounded(int, 2, 5000), default=100,
                      help="dynamic programming: intervals in s (default 100, the report's)")
    plan.add_argument("--dp-speeds", type=bounded(int, 3, 2001), default=201,
                      help="dynamic programming: speeds per node (default 201, the report's)")
    plan.add_argument("--dp-speed-step", type=bounded(float, 1e-6, 100.0), default=0.005, metavar="STEP",
                      help="dynamic programming: the step between speeds, 1/s (default 0.005, the report's)")
    plan.add_argument("--gravity", action="store_true",
                      help="the example with gravity on (the report's points are matched with it off)")
    plan.add_argument("--links", choices=("point", "rod"), default="point",
                      help="the example's links: point masses at their far ends (default), or uniform rods")
    plan.add_argument("--json", action="store_true", help="print one JSON object")
    plan.add_argument("--plot", type=Path, default=None, metavar="DIR", help="draw the report's Figs. 11-17 into DIR")


def _demo_options(demo: argparse.ArgumentParser) -> None:
    from host_tools.worlds.settings import GRAVITY_MODES
    demo.add_argument("--json", action="store_true", help="print one JSON object (steps, errors, times)")
    demo.add_argument("--gravity", choices=GRAVITY_MODES, default="earth", help="the arm's gravity (default earth)")
    add_seed_arg(demo, "the plant's noise and the link's nonces")
    demo.add_argument("--link", action="store_true",
                      help="instead: start `aspod sim --pty` and run a scripted teleop session over the pty")
    demo.add_argument("--baud", type=_baud, default=115200, help="line rate for --link")
    demo.add_argument("--record", type=Path, metavar="FILE.pcapng",
                      help="capture the session (on the simulated clock: aspod replay re-runs it to the bit)")


def _tracker_day_options(day: argparse.ArgumentParser) -> None:
    day.add_argument("--mode", choices=("relay", "feedforward"), default="relay",
                     help="relay: the report's relay logic (default); feedforward: the sun-rate feed-forward")
    day.add_argument("--dial", default="50", metavar="X",
                     help="speed dial, percent, for both axes (50, the default) or az,el (40,20); in feedforward "
                          "mode it caps the speed")
    day.add_argument("--date", default="2026-06-21", metavar="YYYY-MM-DD",
                     help="the day (default 2026-06-21, the June solstice: the sun's fastest azimuth)")
    day.add_argument("--clouds", default=None, metavar="SPEC",
                     help="cloud passages TIME+DURATION@ATTENUATION, comma-separated, local standard time: "
                          "'12:00+300s@0.9,14:30+10m@0.5'")
    day.add_argument("--from", dest="start", default=None, metavar="HH:MM",
                     help="start (local standard time; default: when the sun climbs above 5 deg)")
    day.add_argument("--to", dest="end", default=None, metavar="HH:MM",
                     help="end (default: when the sun sinks below 5 deg)")
    day.add_argument("--param", action="append", metavar="NAME=VALUE",
                     help="a tracker parameter of the firmware, repeatable (e.g. trk_deadband_mv=1.5)")
    add_seed_arg(day, "the photocells' and sensors' noise")
    day.add_argument("--json", action="store_true", help="print one JSON object")
    day.add_argument("--plot", type=Path, default=None, metavar="FILE.png",
                     help="write the pointing error and the lag over the day to this PNG")


def _log_options(log_cmd: argparse.ArgumentParser) -> None:
    log_cmd.add_argument("capture", type=Path, metavar="FILE", help="a capture written by --record or aspod proxy")
    log_cmd.add_argument("--class", dest="cls", action="append", metavar="CLASS",
                         help="only frames of this class (link, command, urgent, telemetry, event); repeatable")
    log_cmd.add_argument("--message", action="append", metavar="NAME",
                         help="only this message (e.g. TelemetryJoints); repeatable")
    log_cmd.add_argument("--link", action="append", metavar="NAME", help="only frames of this link; repeatable")
    log_cmd.add_argument("--errors", action="store_true", help="only frames that failed to decode or verify")
    log_cmd.add_argument("--stats", action="store_true",
                         help="counts instead: frames, errors, round trips, retransmissions, losses per class")
    log_cmd.add_argument("--csv", type=Path, metavar="FILE.csv", help="write the decoded messages as CSV (- for stdout)")
    log_cmd.add_argument("--plot", type=Path, metavar="FILE.png",
                         help="plot joint positions and currents, the tracker's pointing error and link health")
    log_cmd.add_argument("--key-file", type=Path, default=None,
                         help="pre-shared key file (hex): verify every frame's MAC (without it MACs are not checked)")


def _proxy_options(proxy: argparse.ArgumentParser) -> None:
    proxy.add_argument("--host", default="pty", metavar="ENDPOINT",
                       help="where the host connects: pty (a new pseudo-terminal, the default), tcp:PORT (tcp:0 picks "
                            "one), or a device or pyserial URL")
    proxy.add_argument("--controller", required=True, metavar="ENDPOINT",
                       help="the controller: the port aspod sim announced (/dev/pts/N, socket://127.0.0.1:PORT), a "
                            "device, a pyserial URL, or pty / tcp:PORT for a controller that connects itself")
    proxy.add_argument("--impair", default="clean", metavar="SPEC",
                       help="the link: a preset (clean, radio, optical) and/or key=value pairs: baud, latency_ms, "
                            "jitter_ms, ber, drop, dup, fade_every_s, fade_s, block_every_s, block_s, fade=START+S, "
                            "block=START+S, seed (e.g. 'radio,fade=60+30')")
    proxy.add_argument("--seed", type=int, default=None, help="the impairment's seed (overrides seed= in --impair)")
    proxy.add_argument("--baud", type=_baud, default=115200, help="line rate of a device endpoint (default 115200)")
    proxy.add_argument("--record", type=Path, metavar="FILE.pcapng",
                       help="capture every frame both ways as sent, each lost or damaged one with a comment")
    proxy.add_argument("--key-file", type=Path, default=None,
                       help="verify MACs in the live view with this key (default: that of the local simulator "
                            "serving --controller, if it is one)")
    proxy.add_argument("--no-view", action="store_true", help="no live view (the summary at the end only)")


def _replay_options(replay_cmd: argparse.ArgumentParser) -> None:
    replay_cmd.add_argument("capture", type=Path, metavar="FILE", help="a capture from aspod sim or aspod demo --record")
    replay_cmd.add_argument("--param", action="append", metavar="NAME=VALUE",
                            help="change a controller parameter for the replay (repeatable): what would differ?")
    replay_cmd.add_argument("--key-file", type=Path, default=None,
                            help="the recording's pre-shared key: verify its MACs, and with it a simulated-clock "
                                 "replay is compared byte for byte too")
    replay_cmd.add_argument("--json", action="store_true", help="print one JSON object")
    replay_cmd.add_argument("--output", type=Path, default=None, metavar="FILE.pcapng",
                            help="also write the replay's own capture")


def _wireshark_options(wireshark: argparse.ArgumentParser) -> None:
    wireshark.add_argument("--output", "-o", type=Path, default=None, metavar="FILE.lua",
                           help="where to write it (default: standard output)")


def _completion_options(completion: argparse.ArgumentParser) -> None:
    completion.add_argument("shell", choices=SHELLS)


# The commands in the order `aspod --help` lists them: name, the keywords of its parser (help, description), and
# the function that adds its options, called only for the command being run (`build_parser`).
COMMANDS = (
    ("sim", dict(help="run the controller and its plant; prints ASPOD-LINK, ASPOD-KEY and ASPOD-CONTROL "
                      "lines"), _sim_options),
    ("plant", dict(help="run only the plant, in real time, on a python-can interface; "
                        "prints an ASPOD-PLANT ready line"), _plant_options),
    ("firmware", dict(help="run only the controller, its HAL on a python-can interface; "
                           "prints ASPOD-LINK and ASPOD-KEY lines"), _firmware_options),
    ("teleop", dict(help="console to a controller: interactive, or a script"), _teleop_options),
    ("bench", dict(help="run a teleop script against the whole world on the simulated clock "
                        "(deterministic, fast); the plant's true state at the end"), _bench_options),
    ("campaign", dict(help="run a bench over a matrix of settings, one row per run, on Dask "
                           "(a local cluster on every core, or --scheduler)"), _campaign_options),
    ("fuzz", dict(help="fuzz the protocol: in process, coverage-guided (atheris), on a target of the "
                       "emulator's; or black-box against a live link; or replay a finding"), _fuzz_options),
    ("plan", dict(help="the report's trajectory planning for two arms carrying one object: time-optimal "
                       "on the phase plane, minimum cost by dynamic programming (docs/planning.md)"), _plan_options),
    ("demo", dict(help="the arm picks up debris and drops it in the bin, on the simulated clock; "
                       "reports the positioning error of each step"), _demo_options),
    ("tracker-day", dict(help="the solar tracker through a simulated day at Tucson, on the "
                              "simulated clock; pointing error, lag and relay switchings"), _tracker_day_options),
    ("log", dict(help="decode a session capture (pcapng): every frame, counts, a table or a plot"), _log_options),
    ("proxy", dict(help="a man in the middle between host and controller: impairs, shows and records "
                        "the link; prints ASPOD-LINK for the host"), _proxy_options),
    ("replay", dict(help="re-simulate a recorded session (aspod sim/demo --record) and report "
                         "the first divergence"), _replay_options),
    ("wireshark", dict(help="write the Wireshark Lua dissector for this protocol's captures"), _wireshark_options),
    ("completion", dict(help="print a shell completion script (bash or zsh)",
                        description="print a completion script for aspod: bash (source it, or put it in "
                                    "~/.local/share/bash-completion/completions/aspod) or zsh (put it as "
                                    "_aspod in a folder on $fpath)"), _completion_options),
)


def build_parser(only: Optional[Collection[str]] = None) -> argparse.ArgumentParser:
    """The `aspod` parser, with the options of the commands `only` names (None: every command's).

    The others are there by name and help, which is all `aspod --help`, `aspod --version` and argparse's
    choice of a command need: so a command imports only what its own options need, and `aspod --version`
    loads neither numpy nor the plant (bench/bench_start.py).
    """
    formatter = argparse.RawDescriptionHelpFormatter
    parser = argparse.ArgumentParser(prog="aspod", description="ASPOD controller emulator", epilog=_epilog(None),
                                     formatter_class=formatter)
    parser.add_argument("--version", action=_VersionAction)
    add_logging_args(parser)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, keywords, add_options in COMMANDS:
        command_parser = sub.add_parser(name, epilog=_epilog(name), formatter_class=formatter, **keywords)
        if only is None or name in only:
            add_logging_args(command_parser)
            add_options(command_parser)
    return parser


def default_params_path() -> Path:
    """The per-user parameter file: `$XDG_CONFIG_HOME/aspod/params.json` (default `~/.config`)."""
    base = os.environ.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
    return Path(base) / "aspod" / "params.json"


def host_key(path: Optional[Path], url: str) -> bytes:
    """The key a host tool uses for the link `url`: --key-file, else the key of this user's simulator serving
    `url` (host_tools/client/control.py `simulator_key`)."""
    if path is not None:
        from protocol import auth
        return auth.load_key(path, "--key-file")
    from host_tools.client.control import simulator_key
    return simulator_key(url)


def run_command(args: argparse.Namespace) -> int:
    """Turn the Namespace into the command's settings (host_tools/cli/settings.py), then run the command."""
    from host_tools.cli import settings
    if args.command == "sim":
        from host_tools.cli.sim import run_sim
        return run_sim(settings.sim_settings(args))
    if args.command == "plant":
        from host_tools.cli.plant import run_plant
        return run_plant(settings.plant_run_settings(args))
    if args.command == "firmware":
        from host_tools.cli.firmware import run_firmware
        return run_firmware(settings.firmware_settings(args))
    if args.command == "teleop":
        from host_tools.cli.teleop import run_teleop
        return run_teleop(settings.teleop_settings(args))
    if args.command == "campaign":
        from host_tools.cli.campaign import run_campaign
        return run_campaign(settings.campaign_settings(args))
    if args.command == "fuzz":
        from host_tools.cli.fuzz import run_fuzz
        return run_fuzz(settings.fuzz_settings(args))
    if args.command == "plan":
        from host_tools.cli.plan import run_plan
        return run_plan(settings.plan_settings(args))
    if args.command == "bench":
        from host_tools.cli.bench import run_bench
        return run_bench(settings.bench_settings(args))
    if args.command == "demo":
        from host_tools.apps.demo import run_demo
        return run_demo(settings.demo_settings(args))
    if args.command == "tracker-day":
        from host_tools.apps.tracker_day import run_tracker_day
        return run_tracker_day(settings.day_settings(args), as_json=args.json, plot=settings.day_plot(args))
    if args.command == "log":
        from host_tools.cli.log import run_log
        return run_log(settings.log_settings(args))
    if args.command == "proxy":
        from host_tools.cli.proxy import run_proxy
        return run_proxy(settings.proxy_settings(args))
    if args.command == "replay":
        from host_tools.cli.replay import run_replay
        return run_replay(settings.replay_settings(args))
    if args.command == "wireshark":
        from host_tools.cli.wireshark import run_wireshark
        return run_wireshark(settings.wireshark_output(args))
    if args.command == "completion":
        import shtab
        print(shtab.complete(build_parser(), shell=args.shell))
        return EXIT_OK
    return EXIT_USAGE


def with_script_directive(args: argparse.Namespace, argv: Sequence[str]) -> argparse.Namespace:
    """`aspod bench SCRIPT`: the options of the script's first line (`#! aspod bench --sun-start ...`) come first,
    the command line's after them (so they win), as the pytest plugin and `aspod campaign` read a script. A
    script that cannot be read is left for the command to refuse; a first line that gives more than the world
    (words.py `script_directive`) is refused here: TeleopError (a ValueError)."""
    from host_tools.teleop.words import TeleopError, read_script, script_directive
    try:
        first = read_script(args.script, option="script")[:1]
    except (OSError, TeleopError):
        return args
    directive = script_directive(first)
    if not directive:
        return args
    at = list(argv).index("bench") + 1
    return build_parser(["bench"]).parse_args([*argv[:at], *directive, *argv[at:]])


def _terminated(signum, frame) -> None:
    raise SystemExit(128 + signum)


def command_word(argv: Sequence[str]) -> Optional[str]:
    """The command `argv` names: its first word that is not an option nor --log-file's path; None if there is none,
    or that word is no command (argparse then says so)."""
    value_next = False
    for word in argv:
        if value_next:
            value_next = False
        elif word.startswith("--") and "=" not in word and len(word) > 3 and "--log-file".startswith(word):
            value_next = True               # --log-file PATH (argparse takes any unambiguous prefix: --log PATH)
        elif not word.startswith("-"):
            return word if any(word == name for name, _, _ in COMMANDS) else None
    return None


def main(argv: Optional[Sequence[str]] = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    word = command_word(argv)
    args = build_parser(only=() if word is None else (word,)).parse_args(argv)
    if args.command == "bench":
        try:
            args = with_script_directive(args, argv)
        except ValueError as exc:               # logging is not set up yet: the script's line is refused plainly
            print(f"aspod bench: {args.script}: {exc}", file=sys.stderr)
            return EXIT_USAGE
    args.argv = tuple(argv)            # the command line as given (a campaign keeps it in its record)
    from host_tools.cli.settings import claims
    try:
        claims(args)                            # --log-file: not an input, a folder, a file of another kind, ...
        setup_logging(getattr(args, "verbose", 0), getattr(args, "quiet", 0), getattr(args, "log_file", None))
    except ValueError as exc:
        print(f"aspod: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except OSError as exc:                      # (claimed, then taken away)
        print(f"aspod: --log-file: cannot write {exc.filename}: {exc.strerror}", file=sys.stderr)
        return EXIT_USAGE
    # SIGTERM ends a command as an error would, through every `finally`: a live capture is put in place whole, an
    # output half written is removed (host_tools/outputs.py). Commands that run until stopped set their own.
    before = signal.signal(signal.SIGTERM, _terminated)
    try:
        return _run(args)
    finally:
        signal.signal(signal.SIGTERM, before)


def _run(args: argparse.Namespace) -> int:
    import logging
    log = logging.getLogger("aspod")
    try:
        return run_command(args)
    except BrokenPipeError:                     # `aspod log ... | head`: the reader has all it wanted
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())   # no second complaint at exit
        return 128 + signal.SIGPIPE
    except (KeyFileError, ValueError) as exc:   # bad key file, or settings out of their bounds
        log.error(f"aspod: {exc}")
        return EXIT_USAGE
    except OSError as exc:                      # a port that cannot be opened or bound
        log.error(f"aspod: {exc}")
        return EXIT_LINK
    except LinkError as exc:
        log.error(f"aspod: link: {exc}")
        return EXIT_LINK
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
