"""Typed settings at the edge: each command turns its argparse.Namespace, once, into frozen values.

Nothing below `cli/` sees a Namespace. The types the worlds and apps use live with them
(`host_tools.worlds.settings.PlantSettings`, `host_tools.apps.demo.DemoSettings`,
`host_tools.apps.tracker_day.DaySettings`); the ones only commands use live here.
"""
from __future__ import annotations

import argparse
import math
import shlex
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Optional

from hil_sim.sun import TUCSON, as_clouds, to_utc
from timebase import RealClock

from host_tools.fuzz.hangs import HANG_S
from host_tools.outputs import PNG, Claims, Output
from host_tools.worlds import nodes
from host_tools.worlds.settings import PlantSettings, TIMINGS
from kernels.extras import require

if TYPE_CHECKING:
    from host_tools.apps.demo import DemoSettings
    from host_tools.campaign.engine import EngineSettings
    from host_tools.campaign.matrix import Matrix
    from host_tools.fuzz.blackbox import BlackBoxSettings
    from host_tools.fuzz.campaign import CampaignPlan
    from host_tools.fuzz.hostile import HostileSettings
    from host_tools.worlds.bench_world import WorldSettings
    from host_tools.sessions.impairment import Impairment
    from host_tools.apps.tracker_day import DaySettings


def _speed_argv(speed: float) -> str:
    return "max" if speed == math.inf else repr(speed)


@dataclass(frozen=True)
class BusSettings:
    """A python-can bus: interface, channel and further keywords (bitrate, data_bitrate, port, ...)."""
    interface: str
    channel: str
    options: tuple[tuple[str, Any], ...] = ()

    def __post_init__(self) -> None:
        nodes.check_interface(self.interface, between_processes=True)
        object.__setattr__(self, "options", tuple(sorted(dict(self.options).items())))

    @property
    def kwargs(self) -> dict[str, Any]:
        return dict(self.options)

    def describe(self) -> str:
        return nodes.describe_bus(self.interface, self.channel, self.kwargs)

    def to_argv(self) -> list[str]:
        argv = ["--interface", self.interface, "--channel", self.channel]
        for key, value in self.options:
            if key in ("bitrate", "data_bitrate"):
                argv += [f"--{key.replace('_', '-')}", str(value)]
            else:
                argv += ["--bus-arg", f"{key}={value}"]
        return argv


@dataclass(frozen=True)
class PortSettings:
    """The controller's end of the serial line: a pty (the default), a TCP port or a device; baud, pacing."""
    tcp: Optional[int] = None
    device: Optional[str] = None
    baud: int = 115200
    paced: bool = True
    links: tuple[tuple[str, str], ...] = ()     # (name, endpoint): several redundant links instead of one line

    def __post_init__(self) -> None:
        if self.tcp is not None and self.device is not None:
            raise ValueError("--tcp and --port: one line only")
        names = [name for name, _ in self.links]
        if len(set(names)) != len(names):
            raise ValueError(f"--link: each link needs a name of its own, got {', '.join(names)}")
        from host_tools.worlds.ports import check_endpoint, check_url
        if self.device is not None:
            try:
                check_url(self.device)
            except ValueError as exc:
                raise ValueError(f"--port: {exc}") from None
        for name, endpoint in self.links:
            try:
                check_endpoint(endpoint)
            except ValueError as exc:
                raise ValueError(f"--link {name}: {exc}") from None


@dataclass(frozen=True)
class ControllerSettings:
    """The controller's key, parameter file and the settings the command line gives it (None: saved/default)."""
    key_file: Optional[Path] = None
    params: Optional[Path] = None
    link_timeout_s: Optional[float] = None
    telemetry_hz: Optional[int] = None
    loop_hz: Optional[float] = None
    boot_timeout_s: Optional[float] = None
    gravity_m_s2: Optional[float] = None     # `--gravity orbit` (aspod sim): the feed-forward goes to 0
    controller_id: Optional[bytes] = None    # 8 bytes (--controller-id); None: new at each start


@dataclass(frozen=True)
class TeleopSettings:
    """`aspod teleop`: where, at what rate, and a script (None: standard input or the console)."""
    url: str
    baud: int = 115200
    script: Optional[Path] = None
    keep_going: bool = False
    connect_timeout_s: float = 10.0
    summary: bool = False
    record: Optional[Output] = None      # a session capture (pcapng) of every frame both ways
    json: bool = False                   # a script's run as one JSON object (host_tools/teleop/record.py)
    control: Optional[Path] = None       # the simulator's control endpoint (None: found from the URL, if any)
    key_file: Optional[Path] = None      # None: the key of the local simulator serving the URL, found


@dataclass(frozen=True)
class LogSettings:
    """`aspod log`: which capture, which frames, and what to make of them."""
    capture: Path
    classes: tuple[str, ...] = ()        # MsgClass names; empty: every class
    messages: tuple[str, ...] = ()       # message names; empty: every message
    links: tuple[str, ...] = ()          # link names; empty: every link
    errors_only: bool = False
    stats: bool = False
    csv: Optional[Output] = None
    plot: Optional[Output] = None
    key_file: Optional[Path] = None
    csv_to_stdout: bool = False          # `--csv -`
    si: bool = False                     # the CSV's angles in radians and lengths in metres, not as the console
    mcap: Optional[Output] = None        # the session as MCAP, on Foxglove's topics (host_tools/sessions/foxglove.py)


@dataclass(frozen=True)
class BenchSettings:
    """`aspod bench SCRIPT`: the script and its variables, the world it runs in, and what to print or keep."""
    script: Path
    world: "WorldSettings"
    variables: tuple[tuple[str, str], ...] = ()
    keep_going: bool = False
    json: bool = False
    record: Optional[Output] = None


@dataclass(frozen=True)
class ProxySettings:
    """`aspod proxy`: its two endpoints, the link's impairment, the capture and the live view."""
    host: str
    controller: str
    impairment: "Impairment"
    baud: int = 115200
    record: Optional[Output] = None
    key_file: Optional[Path] = None
    view: bool = True


@dataclass(frozen=True)
class ReplaySettings:
    """`aspod replay`: the capture, parameters changed for the replay, and what to write."""
    capture: Path
    params: tuple[tuple[str, float], ...] = ()
    key_file: Optional[Path] = None
    json: bool = False
    output: Optional[Output] = None


@dataclass(frozen=True)
class SimSettings:
    """`aspod sim`: one process, or with `hal` the plant as a child `aspod plant`."""
    port: PortSettings
    controller: ControllerSettings
    plant: PlantSettings
    seed: int = 0
    speed: float = 1.0
    hal: Optional[str] = None
    hal_channel: Optional[str] = None
    hal_options: tuple[tuple[str, Any], ...] = ()
    record: Optional[Output] = None      # a session capture (pcapng) of the controller's line
    can_log: Optional[Output] = None     # the HAL bus through python-can's Logger (.blf, .asc, .log, ...)
    can_ids: Optional[frozenset[int]] = None     # ... of these frames only (--can-only, --can-skip; None: all)
    can_rotate_bytes: Optional[int] = None       # ... in parts of this size (--can-rotate-mb; None: one file)
    control: bool = False                # serve the endpoint (aspod sim: unless --no-control; with --hal: info) ...
    control_path: Optional[Path] = None  # ... on this socket (None: the per-user default; worlds/runtime_folder.py)
    foxglove: Optional[int] = None       # serve the telemetry over Foxglove's WebSocket on this port (0: any free one)
    arms: int = 1                        # 2: the report's two example arms and their object (docs/two_arms.md)

    def __post_init__(self) -> None:
        if self.arms not in (1, 2):
            raise ValueError(f"--arms is 1 or 2, not {self.arms}")
        if self.arms == 2:
            for given, name in ((self.hal, "--hal"), (self.port.device, "--port"), (self.port.links, "--link")):
                if given:
                    raise ValueError(f"--arms 2 with {name} is not built: two arms run in one process, each "
                                     "controller on a pty or a TCP port of its own (--pty, --tcp)")


@dataclass(frozen=True)
class FirmwareSettings:
    """`aspod firmware`: the controller alone, its HAL on `bus`; in lock-step, its plant's process `plant_pid` on this
    machine, if known (its silence is judged on it: docs/separate_processes.md)."""
    bus: BusSettings
    port: PortSettings
    controller: ControllerSettings
    timing: str = "lockstep"
    plant_pid: Optional[int] = None

    def __post_init__(self) -> None:
        if self.plant_pid is not None:
            if self.timing != "lockstep":
                raise ValueError("--plant-pid judges the wait for the plant's tick in lock-step: it takes "
                                 "--timing lockstep")
            if not Path(f"/proc/{self.plant_pid}/stat").exists():
                raise ValueError(f"--plant-pid {self.plant_pid}: no such process on this machine")


@dataclass(frozen=True)
class PlantRunSettings:
    """`aspod plant`: the plant alone on `bus`."""
    bus: BusSettings
    plant: PlantSettings = field(default_factory=PlantSettings)
    seed: int = 0
    timing: str = "lockstep"
    speed: float = 1.0
    stop_on_stdin_eof: bool = False
    verbosity: int = 0          # -v counts +1, -q -1: a child plant logs as its parent does

    def __post_init__(self) -> None:
        if self.timing not in TIMINGS:
            raise ValueError(f"timing {self.timing!r} is not one of {', '.join(TIMINGS)}")

    def to_argv(self) -> list[str]:
        """The `aspod plant` command line for these settings (a child plant: `aspod sim --hal`)."""
        loudness = ["-v"] * self.verbosity if self.verbosity > 0 else ["-q"] * -self.verbosity
        return [*self.bus.to_argv(), "--seed", str(self.seed), *self.plant.to_argv(), "--timing", self.timing,
                "--speed", _speed_argv(self.speed), *(["--stop-on-stdin-eof"] if self.stop_on_stdin_eof else []),
                *loudness]


# ---- from the Namespace ----

def plant_settings(args: argparse.Namespace) -> PlantSettings:
    """--gravity, --payload-kg, --no-tracker, --sun-start (parsed by its argparse type: None for `now`), --clouds.

    With `now`, the clouds are checked against today's date (the start is resolved when the plant is built).
    """
    if args.no_tracker:
        given = [name for name, value in (("--sun-start", args.sun_start), ("--clouds", args.clouds))
                 if value is not None]
        if given:
            raise ValueError(f"{' and '.join(given)} set the solar tracker's sun, but --no-tracker leaves the "
                             "tracker out: drop one or the other")
        return PlantSettings(gravity=args.gravity, payload_kg=args.payload_kg, tracker=False)
    start = None if args.sun_start in (None, "now") else to_utc(args.sun_start)
    if start is None:
        as_clouds(args.clouds, to_utc(RealClock.wall_time()), TUCSON)
    return PlantSettings(gravity=args.gravity, payload_kg=args.payload_kg, start=start, clouds=args.clouds)


def port_settings(args: argparse.Namespace) -> PortSettings:
    links = []
    for item in getattr(args, "link", None) or ():
        name, sep, endpoint = item.partition("=")
        if not sep or not name or not endpoint or not name.isidentifier():
            raise ValueError(f"--link {item}: write NAME=ENDPOINT, e.g. radio=pty or optical=tcp:0")
        links.append((name, endpoint))
    return PortSettings(tcp=args.tcp, device=args.port, baud=args.baud, paced=not args.no_pacing, links=tuple(links))


def controller_settings(args: argparse.Namespace) -> ControllerSettings:
    gravity = getattr(args, "gravity", "earth")      # aspod sim has --gravity, aspod firmware has not
    return ControllerSettings(key_file=args.key_file, params=args.params, link_timeout_s=args.link_timeout,
                              telemetry_hz=args.telemetry_hz, loop_hz=args.loop_hz,
                              boot_timeout_s=getattr(args, "boot_timeout", None),
                              gravity_m_s2=0.0 if gravity == "orbit" else None, controller_id=args.controller_id)


def bus_settings(args: argparse.Namespace) -> BusSettings:
    """--interface, --channel, --bitrate, --data-bitrate, --bus-arg."""
    options = nodes.parse_bus_args(args.bus_arg or (), args.interface)
    if args.bitrate is not None:
        options["bitrate"] = args.bitrate
    if args.data_bitrate is not None:
        options["data_bitrate"] = args.data_bitrate
    return BusSettings(args.interface, args.channel, tuple(options.items()))


def sim_settings(args: argparse.Namespace) -> SimSettings:
    hal_options: dict[str, Any] = {}
    if args.hal is not None and args.can_log is not None:
        raise ValueError(f"--can-log with --hal: the HAL bus is a real python-can bus then; log it with python-can "
                         f"itself: python -m can.logger -i {args.hal} -c CHANNEL -f {args.can_log}")
    if args.hal is not None and args.record is not None:
        raise ValueError("--record with --hal is not built yet: record in the one-process world (without --hal), "
                         "or with aspod teleop --record")
    if args.hal is None and (args.hal_channel is not None or args.hal_arg):
        given = " and ".join(name for name, value in (("--hal-channel", args.hal_channel), ("--hal-arg", args.hal_arg))
                             if value)
        raise ValueError(f"{given} without --hal: they set the bus of a plant in a process of its own "
                         "(--hal INTERFACE); without --hal the plant runs in this process on a private bus")
    if args.hal is not None:
        hal_options = nodes.parse_bus_args(args.hal_arg or (), args.hal, "--hal-arg")
    foxglove = getattr(args, "foxglove", None)
    if foxglove is not None:
        if args.hal is not None:
            raise ValueError("--foxglove with --hal is not built yet: serve it from the one-process world (without "
                             "--hal)")
        from host_tools.sessions.foxglove import require_foxglove
        require_foxglove("sim --foxglove")
    outputs = claims(args)
    return SimSettings(port=port_settings(args), controller=controller_settings(args), plant=plant_settings(args),
                       seed=args.seed, speed=args.speed, hal=args.hal, hal_channel=args.hal_channel,
                       hal_options=tuple(hal_options.items()), record=capture_output(outputs, args.record),
                       can_log=can_log_output(outputs, args.can_log, args.can_rotate_mb), can_ids=can_log_ids(args),
                       can_rotate_bytes=can_rotate_bytes(args.can_rotate_mb),
                       control=not args.no_control, control_path=args.control, foxglove=foxglove,
                       arms=args.arms)


def firmware_settings(args: argparse.Namespace) -> FirmwareSettings:
    return FirmwareSettings(bus=bus_settings(args), port=port_settings(args), controller=controller_settings(args),
                            timing=args.timing, plant_pid=args.plant_pid)


def plant_run_settings(args: argparse.Namespace) -> PlantRunSettings:
    return PlantRunSettings(bus=bus_settings(args), plant=plant_settings(args), seed=args.seed, timing=args.timing,
                            speed=args.speed, stop_on_stdin_eof=args.stop_on_stdin_eof,
                            verbosity=getattr(args, "verbose", 0) - getattr(args, "quiet", 0))


def teleop_settings(args: argparse.Namespace) -> TeleopSettings:
    from host_tools.client.lines import parse_links
    url = args.url if args.url is not None else the_one_simulator()
    parse_links(url)                 # a link address pyserial cannot take is bad input, refused before any is opened
    return TeleopSettings(url=url, baud=args.baud, script=args.script, keep_going=args.keep_going,
                          connect_timeout_s=args.connect_timeout, summary=args.summary,
                          record=capture_output(claims(args), args.record), json=args.json,
                          control=args.control, key_file=args.key_file)


def the_one_simulator() -> str:
    """The link of this user's one running simulator, for a host tool given no URL; ValueError (exit 2) listing them
    when there are several, or saying so when there is none."""
    from host_tools.client.control import running_simulators
    found = running_simulators()
    if len(found) == 1:
        return str(found[0].info.get("link"))
    if not found:
        raise ValueError("no URL given, and no simulator of yours is running: start one (aspod sim --pty) or give "
                         "the controller's port (aspod ports lists the serial ports)")
    links = "; ".join(f"{one.info.get('link')} (pid {one.info.get('pid')})" for one in found)
    raise ValueError(f"no URL given, and {len(found)} simulators of yours are running: give one of {links}")


def demo_settings(args: argparse.Namespace) -> "DemoSettings":
    from host_tools.apps.demo import DemoSettings
    if args.link and args.record is not None:
        raise ValueError("--record with --link: record with the teleop session instead (aspod teleop --record)")
    return DemoSettings(gravity=args.gravity, seed=args.seed, json=args.json, link=args.link, baud=args.baud,
                        record=capture_output(claims(args), args.record))


def day_settings(args: argparse.Namespace) -> "DaySettings":
    """DaySettings from `aspod tracker-day`'s arguments; ValueError with the reason for anything wrong."""
    from firmware_py.tracker.task import check_param, parameter_table

    from host_tools.apps.tracker_day import DaySettings, parse_clock, parse_date, parse_dial, parse_param
    settings = DaySettings(mode=args.mode, dial_pct=parse_dial(args.dial), day=parse_date(args.date),
                           clouds=args.clouds, seed=args.seed,
                           start=parse_clock(args.start) if args.start else None,
                           end=parse_clock(args.end) if args.end else None,
                           params=tuple(parse_param(p) for p in args.param or ()))
    check_params(settings.params, parameter_table(), "the tracker", check_param)    # before the day's sun is computed
    return settings


def plot_needs_its_extra(args: argparse.Namespace) -> None:
    """`--plot` draws with matplotlib, the `plot` extra: without it, MissingExtra (exit 2) before anything runs."""
    if args.plot is not None:
        require("plot", "matplotlib", what=f"{args.command} --plot")


def day_plot(args: argparse.Namespace) -> Optional[Output]:
    """`aspod tracker-day --plot`."""
    plot_needs_its_extra(args)
    return claims(args).file(args.plot, "--plot", PNG)


INPUTS = {             # the Namespace's file inputs, and what they are to the run
    "key_file": "the key file (--key-file)", "params": "the parameter file (--params)", "script": "the script",
    "capture": "the capture", "problem": "the problem file (--problem)", "replay": "the finding (--replay)",
    "bench": "the bench", "control": "the control endpoint's socket (--control)"}


def run_inputs(args: argparse.Namespace) -> list[tuple[str, Path]]:
    """Every file the run reads, which no output of it may replace: those named for it, and the parameter file
    that commands fall back to (in the per-user config folder). A simulator's own key is made in its runtime
    folder, where no output is named."""
    from host_tools.cli.options import default_params_path
    named = [(what, Path(str(getattr(args, name)).split("::")[0])) for name, what in INPUTS.items()
             if getattr(args, name, None) is not None]
    return named + [("the parameter file", default_params_path())]


def claims(args: argparse.Namespace) -> Claims:
    """The run's outputs are claimed here (host_tools/outputs.py): against its inputs, each other and, first, the
    --log-file (appended to: claimed before logging starts, host_tools/cli/main.py)."""
    from host_tools.outputs import LOG_FILE
    outputs = Claims(run_inputs(args), force=getattr(args, "force", False))
    outputs.file(getattr(args, "log_file", None), "--log-file", LOG_FILE)
    return outputs


def capture_output(outputs: Claims, path: Optional[Path], option: str = "--record") -> Optional[Output]:
    from host_tools.sessions.capture import CAPTURE
    return outputs.file(path, option, CAPTURE)


def can_log_ids(args: argparse.Namespace) -> Optional[frozenset[int]]:
    """--can-only and --can-skip (comma-separated, repeatable) as the frame ids kept; only with --can-log."""
    only = [n for text in args.can_only for n in text.split(",")]
    skip = [n for text in args.can_skip for n in text.split(",")]
    if (only or skip) and args.can_log is None:
        raise ValueError("--can-only, --can-skip: only with --can-log (which frames of the HAL bus it writes)")
    from host_tools.worlds.can_log import message_ids
    return message_ids(only, skip)


def can_log_output(outputs: Claims, path: Optional[Path], rotate_mb: Optional[float] = None) -> Optional[Output]:
    """A python-can log file: a suffix its `Logger` writes (which says the kind of file it is); with --can-rotate-mb
    one its `SizedRotatingLogger` writes, and the names of the parts claimed too (host_tools/worlds/can_log.py)."""
    if path is None:
        if rotate_mb is not None:
            raise ValueError("--can-rotate-mb: only with --can-log (the size of each file the HAL bus log is cut into)")
        return None
    from host_tools.worlds.can_log import KINDS, ROTATED, part_names
    path = Path(path)
    if path.suffix.lower() not in KINDS:
        raise ValueError(f"--can-log {path}: python-can writes {', '.join(KINDS)}; name the file so")
    if rotate_mb is not None and path.suffix.lower() not in ROTATED:
        raise ValueError(f"--can-log {path} with --can-rotate-mb: python-can rotates {', '.join(ROTATED)} only; "
                         "name the file so")
    output = outputs.file(path, "--can-log", KINDS[path.suffix.lower()])
    if rotate_mb is not None:
        named = output.destination
        outputs.series(output, part_names(named), f"{named.stem}_#NNN{named.suffix}")
    return output


def can_rotate_bytes(rotate_mb: Optional[float]) -> Optional[int]:
    """--can-rotate-mb in bytes (1 at least: python-can takes 0 as no rotation)."""
    from host_tools.worlds.can_log import MEGABYTE
    return None if rotate_mb is None else max(1, round(rotate_mb * MEGABYTE))


def log_settings(args: argparse.Namespace) -> LogSettings:
    from protocol.messages import SCHEMA
    from protocol.schema import MsgClass
    classes = tuple(c.upper() for c in args.cls or ())
    for name in classes:
        if name not in MsgClass.__members__:
            raise ValueError(f"--class {name.lower()}: not a message class; one of "
                             f"{', '.join(m.lower() for m in MsgClass.__members__)}")
    by_lower = {name.lower(): name for name in SCHEMA.by_name}
    messages = []
    for name in args.message or ():
        if name.lower() not in by_lower:
            raise ValueError(f"--message {name}: no such message (see docs/protocol.md)")
        messages.append(by_lower[name.lower()])
    from host_tools.sessions.export import CSV
    plot_needs_its_extra(args)
    outputs = claims(args)
    plot = outputs.file(args.plot, "--plot", PNG)
    to_stdout = args.csv is not None and str(args.csv) == "-"
    csv = None if to_stdout else outputs.file(args.csv, "--csv", CSV)
    mcap = None
    if args.mcap is not None:
        from host_tools.sessions.foxglove import MCAP, require_foxglove
        require_foxglove("log --mcap")
        mcap = outputs.file(args.mcap, "--mcap", MCAP)
    if args.si and args.csv is None:
        raise ValueError("--si: only with --csv (the units of the table)")
    return LogSettings(args.capture, classes, tuple(messages), tuple(args.link or ()), args.errors, args.stats,
                       csv, plot, args.key_file, to_stdout, args.si, mcap)


def replay_settings(args: argparse.Namespace) -> ReplaySettings:
    output = capture_output(claims(args), args.output, "--output")
    return ReplaySettings(args.capture, tuple(dict(pairs(args.param or [], "--param")).items()), args.key_file,
                          args.json, output)


def wireshark_output(args: argparse.Namespace) -> Optional[Output]:
    """`aspod wireshark --output` (None: standard output), or with `--install` aspod.lua in this user's personal Lua
    plugins folder (made if it is not there), where Wireshark and tshark load it at start."""
    from host_tools.sessions.wireshark import DISSECTOR, personal_lua_folder
    if args.install:
        folder = personal_lua_folder()
        folder.mkdir(parents=True, exist_ok=True)
        return claims(args).file(folder / "aspod.lua", "--install", DISSECTOR)
    return claims(args).file(args.output, "--output", DISSECTOR)


def schema_output(args: argparse.Namespace) -> Optional[Output]:
    """`aspod schema --json --output` (None: standard output); --output is for the JSON only."""
    if args.output is not None and not args.json:
        raise ValueError("--output writes the JSON declaration: say --json too")
    from host_tools.cli.schema import DECLARATION
    return claims(args).file(args.output, "--output", DECLARATION)


def proxy_settings(args: argparse.Namespace) -> ProxySettings:
    from host_tools.sessions.impairment import Impairment
    impairment = Impairment.parse(args.impair)
    if args.seed is not None:
        impairment = impairment.with_seed(args.seed)
    from host_tools.worlds.ports import check_endpoint
    for option, endpoint in (("--host", args.host), ("--controller", args.controller)):
        try:
            check_endpoint(endpoint)
        except ValueError as exc:
            raise ValueError(f"{option}: {exc}") from None
    if args.host == args.controller and args.host not in ("pty", "tcp:0"):     # (each of those is a new one)
        raise ValueError(f"--host and --controller are both {args.host}: the two sides must differ")
    return ProxySettings(args.host, args.controller, impairment, args.baud, capture_output(claims(args), args.record),
                         args.key_file, not args.no_view)


def bench_settings(args: argparse.Namespace) -> BenchSettings:
    """The plant as `aspod sim` takes it, but on the simulated clock the sun starts where PlantSettings starts it
    unless told (a bench must run the same every time); `--sun-start now` is the real sun, asked for."""
    plant = plant_settings(args)
    if plant.tracker and plant.start is None:
        default = PlantSettings().start if args.sun_start is None else to_utc(RealClock.wall_time())
        plant = plant.with_start(default)
    return BenchSettings(args.script, bench_world(args, plant), pairs(args.var, "--var", str), args.keep_going,
                         args.json, capture_output(claims(args), args.record))


def check_params(params, table, whose: str, check) -> None:
    """ValueError for the first `--param` (name, value) that `table` has no parameter of, whose value is outside
    its declared range, or that `check(store, name, value)` (the firmware's own veto, given the others, set in
    passes as the firmware sets them) refuses, before anything is built."""
    from firmware_py.params import ParamStore
    names = {spec.name for spec in table}
    store = ParamStore(table, check=lambda name, value: check(store, name, value))
    for name, _value in params:
        if name not in names:
            known = f"it has {', '.join(sorted(names))}" if len(names) <= 20 else "teleop's `params` lists its own"
            raise ValueError(f"--param {name}: {whose} has no such parameter; {known}")
    refused = store.set_all(params)
    if refused:
        raise ValueError(f"--param {next(iter(refused.values()))}")


def pairs(texts: list[str], option: str, kind=float) -> tuple[tuple[str, Any], ...]:
    """`NAME=VALUE` options as (name, value) pairs, the value a `kind`; ValueError naming a malformed one."""
    out = []
    for text in texts:
        name, sep, value = text.partition("=")
        try:
            if not sep or not name.strip():
                raise ValueError
            out.append((name.strip(), kind(value)))
        except ValueError:
            raise ValueError(f"{option} {text}: write NAME=VALUE"
                             + (" with a number" if kind is float else "")) from None
    return tuple(out)


def bench_world(args: argparse.Namespace, plant: PlantSettings) -> "WorldSettings":
    """The lock-step world of `aspod bench` (and of the plugin's options): seed, plant, timed faults,
    impairment, parameters. ValueError naming what is wrong."""
    from firmware_py.controller import ControllerConfig, check_param, parameter_table
    from host_tools.worlds.bench_world import TimedFault, WorldSettings
    params = pairs(args.param, "--param")
    arms = getattr(args, "arms", 1)
    if arms == 2:
        from firmware_py.arm_config import EXAMPLE_ARM
        config = ControllerConfig(arm=EXAMPLE_ARM)
    else:
        config = ControllerConfig()
    check_params(params, parameter_table(config), "the controller",
                 lambda store, name, value: check_param(store, config, name, value))
    return WorldSettings(args.seed, plant, tuple(TimedFault.parse(f) for f in args.fault), args.impairment, params,
                         arms)


@dataclass(frozen=True)
class CampaignSettings:
    """`aspod campaign`: the bench, its matrix, where it runs, and what to write and show."""
    bench: str
    matrix: "Matrix"
    engine: "EngineSettings"
    out: Path
    fmt: str = "csv"
    group_by: Optional[str] = None
    figures: tuple[str, ...] = ()
    plots: tuple[tuple[str, str], ...] = ()
    hists: tuple[str, ...] = ()
    keep_going: bool = False
    progress: bool = True
    command: str = ""                    # the command line that asked for it, for its record
    resume: bool = False                 # `out` holds this campaign begun: run only the runs its journal lacks


def campaign_settings(args: argparse.Namespace) -> CampaignSettings:
    from host_tools.campaign.engine import EngineSettings
    from host_tools.campaign.matrix import DrawnAxis, GridAxis, Matrix, parse_seeds
    matrix = Matrix(tuple(GridAxis.parse(t) for t in args.vary), tuple(DrawnAxis.parse(t) for t in args.draw),
                    parse_seeds(args.seeds))
    plots = []
    for text in args.plot:
        y, sep, x = text.rpartition(":")
        if not sep or not y or not x:
            raise ValueError(f"--plot {text}: write Y:X, two columns (e.g. m.worst_error_mm:payload_kg)")
        plots.append((y, x))
    out = args.out
    if out is None:
        from datetime import datetime, timezone
        out = Path(f"campaign-{datetime.fromtimestamp(RealClock.wall_time(), timezone.utc):%Y%m%d-%H%M%S}")
    claims(args).folder(out, "--out")
    resuming = getattr(args, "resuming", False)      # `--resume DIR`: this folder's campaign, the rest of its runs
    if not resuming and out.exists() and (any(out.glob("rows.*")) or (out / "campaign.json").exists()
                                          or (out / "runs.jsonl").exists()):
        raise ValueError(f"--out {out}: it already holds a campaign; give another (or --resume {out})")
    group_by = args.group_by
    if group_by is None and "fault" in matrix.axes:
        group_by = "fault"
    return CampaignSettings(args.bench, matrix, EngineSettings(args.workers, args.scheduler, args.serial), out,
                            args.format, group_by, tuple(args.summarize), tuple(plots), tuple(args.hist),
                            args.keep_going, not args.no_progress,
                            shlex.join(["aspod", *getattr(args, "argv", ("campaign", args.bench))]), resuming)


@dataclass(frozen=True)
class FuzzSettings:
    """`aspod fuzz`: one of three jobs (`mode`: list, inprocess, blackbox, replay) and what it needs."""
    mode: str
    plan: Optional["CampaignPlan"] = None
    engine: Optional["EngineSettings"] = None
    blackbox: Optional["BlackBoxSettings"] = None
    replay: Optional[Path] = None
    replay_target: Optional[str] = None   # `--replay FILE MODULE:FACTORY`: the user's own target, named to trust it
    key_file: Optional[Path] = None
    coverage: bool = False
    as_json: bool = False
    progress: bool = True
    hang_s: float = HANG_S             # in process and in-process replay: an input's own time past which it hangs
    hostile: Optional["HostileSettings"] = None   # --as-controller: the ground tool attacked (and its replay)


def _target_command(text: str, option: str = "--target-cmd") -> tuple[str, ...]:
    """`option`'s words, as a shell would split them; `aspod` is the aspod of this Python, wherever the shell's
    PATH points. ValueError naming a line that does not split or a program that is not there."""
    import shutil
    from host_tools.worlds.child import ASPOD
    try:
        command = tuple(shlex.split(text))
    except ValueError as exc:
        raise ValueError(f"{option} {text}: {exc} (it is split as a shell would)") from None
    if command and command[0] == "aspod":
        return ASPOD + command[1:]
    if command and shutil.which(command[0]) is None:
        raise ValueError(f"{option} {text}: no program {command[0]} (not a file that can be run, nor on PATH)")
    return command


def fuzz_settings(args: argparse.Namespace) -> FuzzSettings:
    from host_tools.campaign.engine import EngineSettings
    from host_tools.fuzz.blackbox import BlackBoxSettings
    from host_tools.fuzz.campaign import CampaignPlan
    common = dict(key_file=args.key_file, coverage=args.coverage, as_json=args.json, progress=not args.no_progress,
                  hang_s=HANG_S if args.hang_s is None else args.hang_s)
    live = args.url is not None or args.target_cmd is not None
    if args.as_controller:
        return _hostile_settings(args, common)
    if args.list:
        if args.targets or live or args.replay is not None:
            raise ValueError("--list names the in-process targets and runs nothing: give it alone")
        return FuzzSettings("list", **common)
    if args.targets and (live or (args.replay is not None and len(args.targets) > 1)):
        raise ValueError("in-process TARGETs, or --url/--target-cmd (black-box), or --replay FILE [MODULE:FACTORY]: "
                         "one at a time")
    if live or (args.replay is not None and not args.targets):
        command = _target_command(args.target_cmd) if args.target_cmd else ()
        if live:
            if args.runs is not None or args.jobs != 1 or args.coverage or (args.hang_s is not None and
                                                                             args.replay is None):
                raise ValueError("--runs, --jobs, --coverage and --hang-s are for in-process targets; black-box takes "
                                 "--cases")
            if args.url is not None:
                from host_tools.worlds.ports import check_url
                check_url(args.url)
            seconds = args.time if args.time is not None else (None if args.cases else 60.0)
            claims(args).folder(args.findings, "--findings")     # a finding made and then not saved would be lost
            blackbox = BlackBoxSettings(args.url or "", command, args.baud, seconds, args.cases, args.seed,
                                        args.findings, skip=tuple(args.skip) if args.skip is not None
                                        else ("ParamSave",), only=tuple(args.only),
                                        max_findings=args.max_findings, check_every=args.check_every)
            return FuzzSettings("replay" if args.replay is not None else "blackbox", blackbox=blackbox,
                                replay=args.replay, **common)
        return FuzzSettings("replay", replay=args.replay, **common)
    if args.replay is not None:
        return FuzzSettings("replay", replay=args.replay, replay_target=args.targets[0], **common)
    if len(set(args.targets)) != len(args.targets):
        raise ValueError(f"a TARGET named twice ({' '.join(args.targets)}): --jobs N runs one several times")
    if not args.targets:
        raise ValueError("name an in-process TARGET (aspod fuzz --list), or --url/--target-cmd, or --replay FILE")
    if (args.cases is not None or args.only or args.skip is not None or args.max_findings is not None
            or args.check_every is not None):
        raise ValueError("--cases, --only, --skip, --check-every and --max-findings are for black-box fuzzing "
                         "(--url or --target-cmd)")
    seconds = args.time if args.time is not None else (None if args.runs else 60.0)
    plan = CampaignPlan(tuple(args.targets), args.jobs, args.corpus, args.findings, seconds, args.runs, args.seed,
                        common["hang_s"])
    outputs = claims(args)
    outputs.folder(plan.findings, "--findings")
    for name in plan.targets:
        outputs.folder(plan.corpus(name), "--corpus")        # libFuzzer would only skip what it cannot keep
    return FuzzSettings("inprocess", plan=plan, engine=EngineSettings(args.workers, args.scheduler, args.serial),
                        **common)


def _hostile_settings(args: argparse.Namespace, common: dict) -> FuzzSettings:
    """`--as-controller`: this process serves the line as a controller and attacks the host (host_tools/fuzz/
    hostile.py); with --replay, one such finding again."""
    from host_tools.fuzz.hostile import EXIT_OK, HostileSettings
    from host_tools.worlds.ports import check_endpoint
    if args.targets or args.list or args.url is not None or args.target_cmd is not None:
        raise ValueError("--as-controller serves a line for a host to connect to: give no TARGET, --list, --url or "
                         "--target-cmd (--serve, --host-cmd and --probe say where and whom)")
    if args.runs is not None or args.jobs != 1 or args.coverage or args.only or args.skip is not None:
        raise ValueError("--runs, --jobs, --coverage, --only and --skip are not for --as-controller")
    check_endpoint(args.serve)
    host_cmd = _target_command(args.host_cmd, "--host-cmd") if args.host_cmd else ()
    probe = _target_command(args.probe, "--probe") if args.probe else ()
    if args.replay is not None and not host_cmd:
        raise ValueError(f"--replay {args.replay} --as-controller needs --host-cmd: the host to replay it against")
    seconds = args.time if args.time is not None else (None if args.cases else 60.0)
    claims(args).folder(args.findings, "--findings")     # a finding made and then not saved would be lost
    hostile = HostileSettings(args.serve, host_cmd, probe, seconds, args.cases, args.seed, args.findings, args.baud,
                              HANG_S if args.hang_s is None else args.hang_s,
                              tuple(args.host_exit_ok) if args.host_exit_ok else EXIT_OK,
                              max_findings=args.max_findings)
    return FuzzSettings("replay" if args.replay is not None else "hostile", hostile=hostile, replay=args.replay,
                        **common)


@dataclass(frozen=True)
class ArmMoveSettings:
    """`aspod plan --arm-to`: a minimum-time move of ASPOD's own arm (host_tools/apps/arm_plan.py), for a trajectory
    file teleop's `traj load` takes."""
    start_deg: tuple[tuple[str, float], ...]     # every joint of the trajectory (j1..j4, mount)
    target_deg: tuple[tuple[str, float], ...]    # those that move
    gravity: str = "earth"
    payload_kg: float = 0.0
    knots: int = 41
    output: Optional[Output] = None


@dataclass(frozen=True)
class TwoArmSettings:
    """`aspod plan` without --arm-to, given --output FILE or --execute LINK,LINK: the two-arm plan as each example
    arm's knots (host_tools/apps/two_arm_plan.py), the minimum-time plan within `torque_share` of the torque limits,
    run `slower` times slower, at least `knots` knots per arm (by default as bench/bench_two_arms.py runs it); written
    to `output`, carried out on the controllers at `execute` (arm 1's, the leader's, first: host_tools/apps/
    two_arm_execute.py) with `key_file` (None: each simulator's own), raising their speed parameters to the plan's
    with `set_speeds`."""
    output: Optional[Output] = None
    torque_share: float = 0.8
    slower: float = 2.0
    knots: int = 60
    execute: tuple[str, ...] = ()
    key_file: Optional[Path] = None
    set_speeds: bool = False


@dataclass(frozen=True)
class PlanSettings:
    """`aspod plan`: which problem (a file, or the report's example with its model options) and how to plan it."""
    problem: Optional[Path]
    gravity: bool
    links: str
    objective: str
    integrator: str
    nodes: int
    dp_intervals: int
    dp_speeds: int
    dp_speed_step: Optional[float]           # None: the speeds span the minimum-time plan's
    max_time: Optional[float]
    as_json: bool
    plot: Optional[Path]
    method: str = "phase"
    squeeze: Optional[float] = None          # --method reach: the bound on |squeeze| (N), inf for free
    order: int = 1                           # --method reach: 2, s'' linear on placed grid points
    arm: Optional[ArmMoveSettings] = None    # --arm-to: ASPOD's own arm instead of the report's two
    weights: Optional[tuple[float, ...]] = None   # each joint's weight in the minimum-cost plan (None: the file's)
    regen: bool = False                      # electrical: energy given back returns to the supply
    two_arms: Optional[TwoArmSettings] = None    # --output or --execute without --arm-to: the two arms' knots


def plan_settings(args: argparse.Namespace) -> PlanSettings:
    if args.problem is not None and (args.gravity or args.links != "point"):
        raise ValueError("--gravity and --links shape the report's example; a --problem file says its own")
    if args.max_time is not None and args.objective == "time":
        raise ValueError("--max-time bounds a minimum-cost plan: give --objective electrical, energy, work or thermal")
    if args.weights is not None and args.objective == "time":
        raise ValueError("--weights price a minimum-cost plan: give --objective electrical, energy, work or thermal")
    if args.regen and args.objective != "electrical":
        raise ValueError("--regen counts energy given back in --objective electrical")
    if args.method == "reach" and args.plot is not None:
        raise ValueError("--plot draws the phase-plane planner's figures: give --method phase")
    if args.squeeze is not None and args.method != "reach":
        raise ValueError("--squeeze frees the squeeze force in the reachability planner: give --method reach")
    if args.order != 1 and args.method != "reach":
        raise ValueError("--order is the reachability planner's: give --method reach")
    if args.order == 2 and args.squeeze is not None:
        raise ValueError("--order 2 plans with the load shared, without the squeeze: give --order 1 for --squeeze")
    outputs = claims(args)
    arm = arm_move_settings(args, outputs)
    two_arms = None if arm is not None else two_arm_settings(args, outputs)
    plot_needs_its_extra(args)
    outputs.folder(args.plot, "--plot")
    return PlanSettings(args.problem, args.gravity, args.links, args.objective, args.integrator, args.nodes,
                        args.dp_intervals, args.dp_speeds, args.dp_speed_step, args.max_time, args.json, args.plot,
                        args.method, args.squeeze, args.order, arm, args.weights, args.regen, two_arms)


def two_arm_settings(args: argparse.Namespace, outputs: Claims) -> Optional[TwoArmSettings]:
    """--output or --execute without --arm-to, and what goes with them; None without either (ValueError for --knots,
    --torque-share, --slower, --key-file or --set-speeds without them, or an output that may not be written)."""
    given = [name for name, value in (("--knots", args.knots), ("--torque-share", args.torque_share),
                                      ("--slower", args.slower)) if value is not None]
    execute_only = [name for name, value in (("--key-file", args.key_file), ("--set-speeds", args.set_speeds))
                    if value]
    if args.execute is None and execute_only:
        raise ValueError(f"{execute_only[0]}: only with --execute")
    if args.output is None and args.execute is None:
        if given:
            raise ValueError(f"{given[0]}: only with --output (the two arms' trajectory file), --execute or --arm-to "
                             "(ASPOD's own arm's)")
        return None
    values = {name: value for name, value in (("torque_share", args.torque_share), ("slower", args.slower),
                                              ("knots", args.knots)) if value is not None}
    output = None
    if args.output is not None:
        from host_tools.client.trajectory import TRAJECTORY_FILE
        output = outputs.file(args.output, "--output", TRAJECTORY_FILE)
    execute: tuple[str, ...] = ()
    if args.execute is not None:
        execute = tuple(url.strip() for url in args.execute.split(","))
        if len(execute) != 2 or not all(execute) or execute[0] == execute[1]:
            raise ValueError(f"--execute {args.execute}: give the two arms' links, arm 1's (it leads) first: "
                             "LINK,LINK2 as aspod sim --arms 2 says them (its ASPOD-LINK and ASPOD-LINK2 lines)")
        if args.problem is None and args.links != "rod":
            raise ValueError("--execute: the example arms' links are 1 m, 1 kg rods; plan them with --links rod")
    return TwoArmSettings(output=output, execute=execute, key_file=args.key_file, set_speeds=args.set_speeds,
                          **values)


def arm_move_settings(args: argparse.Namespace, outputs: Claims) -> Optional[ArmMoveSettings]:
    """--arm-to and what goes with it; None without it (ValueError for an arm option without --arm-to, a joint that
    is not one of the trajectory's, or a report-example option beside it)."""
    arm_options = {"--arm-from": args.arm_from, "--arm-gravity": args.arm_gravity, "--payload-kg": args.payload_kg}
    if not args.arm_to:
        given = [name for name, value in arm_options.items() if value is not None]
        if given:
            raise ValueError(f"{given[0]}: only with --arm-to (a move of ASPOD's own arm)")
        return None
    if args.problem is not None or args.gravity or args.plot is not None or args.method != "phase":
        raise ValueError("--arm-to plans ASPOD's own arm (the phase-plane planner): without --problem, --gravity, "
                         "--plot or --method")
    if args.torque_share is not None or args.slower is not None or args.execute is not None:
        raise ValueError("--torque-share, --slower and --execute are the two arms' plan's; --arm-to plans ASPOD's own "
                         "arm within its controller's limits, for teleop's `traj load`")
    from host_tools.apps.arm_plan import ARM_JOINTS, homed_pose_rad
    start = {name: math.degrees(q) for name, q in homed_pose_rad().items()}
    for option, texts, into in (("--arm-from", args.arm_from or [], start), ("--arm-to", args.arm_to, None)):
        for name, value in pairs([t for text in texts for t in text.split(",")], option):
            if name not in ARM_JOINTS:
                raise ValueError(f"{option} {name}: not a joint of the trajectory; one of {', '.join(ARM_JOINTS)}")
            if into is not None:
                into[name] = value
    target = dict(pairs([t for text in args.arm_to for t in text.split(",")], "--arm-to"))
    for name, value in (*start.items(), *target.items()):
        if not -360.0 <= value <= 360.0:          # NaN too: it compares false
            raise ValueError(f"--arm-from/--arm-to {name}={value}: an angle in degrees, -360..360")
    from host_tools.client.trajectory import TRAJECTORY_FILE
    return ArmMoveSettings(tuple(start.items()), tuple(target.items()), args.arm_gravity or "earth",
                           0.0 if args.payload_kg is None else args.payload_kg, args.knots or 41,
                           outputs.file(args.output, "--output", TRAJECTORY_FILE))
