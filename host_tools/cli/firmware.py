"""`aspod firmware`: the controller alone, its HAL on a python-can interface.

This is the half that would run against real CAN hardware: the plant is whatever
answers on the bus (`aspod plant` in another process, or a real I/O board). With
--timing lockstep (the default) its time follows the plant's PLANT_SYNC ticks
(`protocol.lockstep.LockstepFollower`; the plant runs `--timing lockstep` too); with
--timing realtime it runs on the wall clock, as against real hardware, where the
staleness limits and the motor loop's deadline are parameters (docs/realtime.md). Either
way the link to the host runs on the wall clock. The
UART side is `aspod sim`'s: a pty (default), a TCP port or a serial device, and the
same first two lines on stdout:

    ASPOD-LINK <url>
    ASPOD-KEY <path>

Without --key-file the key is a fresh one of this process's own (host_tools/worlds/runtime_folder.py), removed
when it stops. Beside the link it serves an endpoint that answers only `info` (`LinkInfo`: the link, the key's
file), so that a host tool given the link's address finds the key (host_tools/client/control.py); the plant's
control endpoint is `aspod sim`'s alone, as the plant is not here. `aspod sim --hal --no-control` serves none.

State changes are logged on stderr; at exit, the HAL counters:

    aspod firmware: HAL counters frames_sent=... frames_received=... own_echoes=... bad_frames=... bus_errors=...

`aspod sim --hal INTERFACE` is this with `aspod plant` started as a child process
(`run_sim_over_hal`), both in lock-step: the child is ready before the controller boots, is
watched while the controller runs (if it dies, that is said on stderr and the controller's
lock-step watch takes it to the safe state) and is stopped when the controller stops.

In lock-step the controller's wait for the plant's tick is judged on the plant's own time, not the wall
clock alone (`own_time.LockstepWait`): the time the plant's process (the child, or `--plant-pid`) and this
one waited for a CPU is excused; a plant process that ended or is stopped is excused nothing
(docs/separate_processes.md, "A plant gone, or a busy machine").
"""
from __future__ import annotations

import argparse
import logging
import math
import os
import signal
from pathlib import Path
from typing import Any, Callable, Optional

from firmware_py.controller import Controller, ControllerConfig
from firmware_py.params import PARAMS_FILE_LIMIT
from timebase.scheduler import Scheduler, run_live
from firmware_py.uart import PacedUart, Port
from host_tools.worlds.ports import DevicePort, PtyPort, RedundantPort, TcpServerPort, open_endpoint
from protocol import auth, files
from protocol.link import LinkConfig
from protocol.lockstep import LockstepFollower, PlantsWatch
from protocol.reasons import Reason
from protocol.states import Fault, FaultCause
from timebase import RealClock

from host_tools.worlds import nodes
from host_tools.cli.options import add_bus_args, add_controller_args, add_timing_arg, bounded, default_params_path
from host_tools.cli.plant import PlantProcess
from host_tools.cli.settings import (BusSettings, ControllerSettings, FirmwareSettings, PlantRunSettings, PortSettings,
                                     SimSettings)
from host_tools.worlds.child import describe_exit
from host_tools.worlds.control_server import ControlServer, Handler, LinkInfo
from host_tools.worlds.runtime_folder import RuntimeFolder
from host_tools.worlds.own_time import LockstepWait
from host_tools.teleop.format import describe_report

PLANT_WATCH_S = 0.1
KEPT_LOOK_S = 0.1            # how often a lock-step controller looks whether its wait outlasts lockstep_wait_s
KEPT_NOTE_EVERY_S = 30.0     # ... and says so at most this often
log = logging.getLogger("aspod")


def open_port(settings: PortSettings, prog: str) -> Port:
    """The controller's side of the line; a TCP port says on stderr when it refuses a newcomer. With several
    links, all of them as one redundant line (`RedundantPort`)."""
    if settings.links:
        ports = {}
        try:
            for name, endpoint in settings.links:
                ports[name] = open_endpoint(endpoint, settings.baud)
        except BaseException:
            for port in ports.values():
                port.close()
            raise
        return RedundantPort(ports, RealClock())
    if settings.tcp is not None:
        port = TcpServerPort(settings.tcp)
        port.on_refused = lambda peer: log.warning(f"{prog}: refused a TCP connection from {peer}: a live "
                                                   "authenticated session holds the line")
        return port
    if settings.device is not None:
        return DevicePort(settings.device, settings.baud)
    return PtyPort()


def controller_key(settings: ControllerSettings, folder: Optional[RuntimeFolder]) -> tuple[bytes, Path]:
    """(key, its file): --key-file, else a fresh key of this simulator's own in its runtime folder (removed when it
    stops; a host tool given the link's address finds it through the endpoint). `runtime_folder` gives a folder
    whenever there is no --key-file."""
    if settings.key_file is not None:
        return auth.load_key(settings.key_file, "--key-file"), settings.key_file.absolute()
    assert folder is not None
    return folder.new_key()


def controller_config(settings: ControllerSettings):
    """(params path, ControllerConfig) from the controller's settings."""
    params_path = settings.params if settings.params is not None else default_params_path()
    check_params_file(params_path)
    timeout_s = settings.link_timeout_s if settings.link_timeout_s is not None else LinkConfig.link_timeout_s
    link = LinkConfig(link_timeout_s=timeout_s, heartbeat_s=min(LinkConfig.heartbeat_s, timeout_s / 3))
    extra: dict[str, Any] = {}
    if settings.boot_timeout_s is not None:
        extra["boot_timeout_s"] = settings.boot_timeout_s
    if settings.loop_hz is not None:
        extra["arm_period_s"] = 1.0 / settings.loop_hz
    return params_path, ControllerConfig(link=link, params_path=params_path, controller_id=settings.controller_id,
                                         **extra)


def check_params_file(path) -> None:
    """ValueError (exit 2) naming --params if `path` is there but cannot be a parameter file (a FIFO, a device, a
    directory, a file larger than PARAMS_FILE_LIMIT); a missing file means the defaults, a damaged one is
    reported at boot (`apply_command_line`) and the defaults stay."""
    try:
        files.check_input(path, PARAMS_FILE_LIMIT)
    except files.InputFileError as exc:
        if exc.refused:
            raise ValueError(f"--params {exc}") from None


def apply_command_line(controller: Controller, settings: ControllerSettings, prog: str) -> None:
    """Report parameter-file problems; what the command line says wins over the saved set.

    `--gravity orbit` (aspod sim) also tells the controller: its gravity feed-forward goes to 0.
    """
    params = controller.params
    for problem in params.load_problems:
        log.warning(f"{prog}: parameters: {problem}")
    for name, value in (("link_timeout_s", settings.link_timeout_s), ("telemetry_hz", settings.telemetry_hz),
                        ("gravity_m_s2", settings.gravity_m_s2)):
        if value is not None:
            reason, detail = params.set(name, value)
            if reason is not Reason.OK:
                raise ValueError(f"--{name}: {detail}")
    controller.telemetry_hz = int(params["telemetry_hz"])


def runtime_folder(settings: ControllerSettings, endpoint: bool, prog: str) -> Optional[RuntimeFolder]:
    """The private folder a simulator needs for its own key (no --key-file) or its endpoint's socket (`endpoint`:
    at the default path); None if it needs neither. Without it the endpoint is left out, and said; the key
    cannot be: OSError."""
    if settings.key_file is None or endpoint:
        try:
            return RuntimeFolder.open(log=lambda text: log.warning(f"{prog}: {text}"))
        except OSError as exc:
            if settings.key_file is None:
                raise OSError(f"{exc}; or give --key-file") from None
            log.warning(f"{prog}: {exc}: running without the control endpoint (a host needs --key-file then)")
    return None


def serve_endpoint(path: Path, handler: Handler, link_scheduler: Scheduler, prog: str) -> ControlServer:
    """The endpoint at `path`, served by a task on the link's (wall-clock) scheduler."""
    server = ControlServer(path, handler, log=lambda text: log.info(f"{prog}: {text}"))
    link_scheduler.add("control", server.poll, tolerance_s=1.0)
    return server


def run_controller(port_settings: PortSettings, settings: ControllerSettings, prog: str, bus_settings: BusSettings,
                   plant: Optional[PlantProcess] = None, timing: str = "lockstep", speed: float = 1.0,
                   control: bool = True, control_path: Optional[Path] = None, plant_pid: Optional[int] = None) -> int:
    """Open the bus and the port, run the controller until SIGINT/SIGTERM, then close everything.

    `timing` "lockstep": the controller's time follows the plant's ticks; "realtime": the wall clock. `speed`:
    the plant's --speed, where known (aspod sim --hal): the pace the world's real-time factor is judged against.
    `control`: serve the endpoint that says the link's key (`LinkInfo`), at `control_path` or by default in the
    runtime folder. The plant's process, where it is known (`plant`, this process's child, or `plant_pid`), is
    what its silence is judged on.
    """
    stopping: list[int] = []
    signal.signal(signal.SIGTERM, lambda signum, frame: stopping.append(signum))
    signal.signal(signal.SIGINT, lambda signum, frame: stopping.append(signum))
    params_path, config = controller_config(settings)
    folder = runtime_folder(settings, control and control_path is None, prog)
    try:
        return _run_controller(port_settings, settings, prog, bus_settings, plant, timing, speed, stopping,
                               params_path, config, folder, control_path if control else None, plant_pid)
    finally:
        if folder is not None:
            folder.close()


def _run_controller(port_settings: PortSettings, settings: ControllerSettings, prog: str, bus_settings: BusSettings,
                    plant: Optional[PlantProcess], timing: str, speed: float, stopping: list[int], params_path: Path,
                    config: ControllerConfig, folder: Optional[RuntimeFolder], control_path: Optional[Path],
                    plant_pid: Optional[int]) -> int:
    psk, key_path = controller_key(settings, folder)
    if control_path is None and folder is not None:
        control_path = folder.control_path()
    bus = nodes.open_bus(bus_settings.interface, bus_settings.channel, node=nodes.CONTROLLER, **bus_settings.kwargs)
    wall = RealClock()
    if plant is not None:
        plant_pid = plant.pid
    judge = LockstepWait(wall, plant_pid)
    follower = LockstepFollower(bus, wall, speed=speed, judge=judge) if timing == "lockstep" else None
    kept = KeptWaits(follower, prog)
    plants = PlantsWatch()
    if follower is not None:                # a second plant on this bus: said on stderr (not a fault)
        follower.on_tick = lambda tick: warn(prog, plants.seen(tick, wall.now()))
    uart = None
    controller: Optional[Controller] = None
    endpoint: Optional[ControlServer] = None
    baud, paced = port_settings.baud, port_settings.paced
    try:
        port = open_port(port_settings, prog)
        uart = PacedUart(port, baud, paced)
        controller = nodes.build_controller(psk, uart, follower.tap if follower else bus, config)
        kept.params = controller.params
        params = controller.params
        apply_command_line(controller, settings, prog)
        scheduler = Scheduler(follower or wall)
        link_scheduler = Scheduler(wall)
        controller.attach(scheduler, link_scheduler)
        log_states(controller, prog)
        if follower is not None:
            controller.report_listeners.append(lambda msg: warn(prog, why_silent(msg, judge, plant_pid)))
            link_scheduler.add("kept-note", kept.step, tolerance_s=1.0)
        if plant is not None:
            link_scheduler.add("plant-watch", _plant_watch(plant, prog, stopping), tolerance_s=1.0)
        if control_path is not None:
            where = (f"in its own process, aspod plant (pid {plant.pid})" if plant is not None else
                     f"whatever answers on the HAL bus ({bus_settings.describe()}): aspod plant, or real hardware")
            about = {"link": port.url, "pid": os.getpid(), "key": str(key_path)}
            endpoint = serve_endpoint(control_path, LinkInfo(about, where), link_scheduler, prog)
        print(f"ASPOD-LINK {port.url}", flush=True)
        print(f"ASPOD-KEY {key_path}", flush=True)
        if endpoint is not None:        # `info` only: the link and its key (no plant here to act on)
            print(f"ASPOD-CONTROL {endpoint.path}", flush=True)
        log.info(f"{prog}: controller up at {baud} baud{'' if paced else ' (unpaced)'}, "
                 f"link timeout {params['link_timeout_s']} s, parameters in {params_path}; "
                 f"HAL on {bus_settings.describe()}, timing {timing}; Ctrl-C stops")
        run_live(scheduler, link_scheduler, lambda: bool(stopping))
    finally:
        if endpoint is not None:
            endpoint.close()
        if plant is not None:
            status, _ = plant.stop()
            if not plant.reported and status not in (0, -signal.SIGINT, -signal.SIGTERM):
                log.warning(f"{prog}: the plant process (pid {plant.pid}) ended: {describe_exit(status)}")
        bus.shutdown()
        if uart is not None:
            uart.close()
        if controller is not None:
            counters = nodes.hal_counters(controller.hal)
            if follower is not None:
                counters.update(ctrl_syncs=follower.syncs_sent, resyncs=follower.resyncs, old_syncs=follower.old_syncs,
                                sync_steps_back=plants.steps_back, rtf=f"{follower.timing().rtf_total:.2f}",
                                longest_wait_s=f"{follower.longest_wait_s:.3f}", kept_waits=kept.count)
            log.info(f"{prog}: HAL counters {nodes.format_counters(counters)}")
    return 0


def warn(prog: str, line: Optional[str]) -> None:
    """`line`, if there is one, as a warning of `prog` on stderr."""
    if line:
        log.warning(f"{prog}: {line}")


class KeptWaits:
    """Lock-step: the waits for a tick that outlast `lockstep_wait_s` of wall time while the plant has not had it of its
    own (the machine keeps the pair from running; the wall clock alone faulted them HAL_STALE), counted (`count`)
    and said on stderr, at most every `KEPT_NOTE_EVERY_S`. `step` is a wall-clock task."""

    def __init__(self, follower: Optional[LockstepFollower], prog: str) -> None:
        self.follower, self.prog = follower, prog
        self.params = None             # the controller's, once it is built
        self.count = 0
        self._counted = 0              # the wait counted last (follower.waits)
        self._said_s = -math.inf

    def step(self, now: float) -> float:
        follower = self.follower
        limit = self.params["lockstep_wait_s"]
        waited = follower.waited_s()
        if waited > limit and follower.waits != self._counted:
            own = follower.stalled_s()
            if own <= limit:
                self._counted = follower.waits
                self.count += 1
                if now - self._said_s >= KEPT_NOTE_EVERY_S:
                    self._said_s = now
                    log.warning(f"{self.prog}: lock-step: no tick from the plant for {waited:.2f} s of wall time, "
                                f"{own:.2f} s of its own: the machine keeps the pair from running (not a fault: "
                                f"lockstep_wait_s {limit:g} s judges the plant's own time; kept_waits in the counters "
                                "at exit)")
        return now + KEPT_LOOK_S


def why_silent(msg, judge: LockstepWait, plant_pid: Optional[int]) -> Optional[str]:
    """For a FaultReport PLANT_SILENT: what the plant's process was at the watch's latest look (None otherwise)."""
    if msg.spec.name != "FaultReport" or msg.cause != FaultCause.PLANT_SILENT:
        return None
    if plant_pid is None:
        return ("lock-step: the plant's process is not known here (--plant-pid names it), so its silence was judged "
                "on the wall clock, less this process's own waits for a CPU")
    look = judge.last
    if look is None:
        return None
    if look.gone is not None:
        return f"lock-step: the plant process (pid {plant_pid}): {look.gone}"
    return f"lock-step: the plant process (pid {plant_pid}) runs but sent no tick in {look.describe()}"


def log_states(controller: Controller, prog: str) -> None:
    """State changes, fault reports and timing warnings on stderr, as they happen."""
    def log_state(new, old, reason, now) -> None:
        log.info(f"{prog}: uptime {controller.uptime_ms(now)} ms: {old.name} -> {new.name} ({reason.name}), "
                 f"faults {Fault(controller.supervisor.faults).name or 'none'}")
        if reason is Reason.LINK_TIMEOUT:
            log.info(f"{prog}: the link until then: {describe_link(controller)}")
        if reason is Reason.UNCOMMANDED_MOTION and controller.uncommanded is not None:
            seen = controller.uncommanded
            log.info(f"{prog}: {seen.channel} {seen.detail}")

    def log_report(msg) -> None:
        # a fault, and a host too slow for the speed asked, are warnings (-q still shows them); a warning's end is not
        level = logging.INFO if msg.spec.name == "TimingWarning" and not msg.active else logging.WARNING
        log.log(level, f"{prog}: uptime {msg.uptime_ms} ms: {describe_report(msg)}")
    controller.state_listeners.append(log_state)
    controller.report_listeners.append(log_report)


def describe_link(controller: Controller) -> str:
    """What the controller's end of the link has counted, and its own stalls: what a link timeout is read against."""
    stats, comms = controller.link.stats, controller.comms
    return (f"{stats.frames_rx} frames ({stats.bytes_rx} B) in, {stats.frames_tx} out; {stats.crc_errors} CRC errors, "
            f"{stats.auth_errors} authentication errors ({stats.replays} replays), {stats.rejected} refused; "
            f"own stalls excused since the start {comms.stalls_excused_s:.3f} s; "
            f"{comms.uart.discarded_rx_bytes} B of a former client discarded")


def _plant_watch(plant: PlantProcess, prog: str, stopping: list[int]) -> Callable[[float], Optional[float]]:
    """A task that says so, once, if the plant process ends while the controller runs."""
    def step(now: float) -> Optional[float]:
        status = plant.exit_status()
        if status is None:
            return now + PLANT_WATCH_S
        if not stopping and not plant.stopped:
            plant.reported = True
            log.warning(f"{prog}: the plant process (pid {plant.pid}) ended: {describe_exit(status)}; the HAL has "
                        "gone quiet, the controller's lock-step watch takes it to the safe state")
        return None
    return step


def run_firmware(settings: FirmwareSettings) -> int:
    """`aspod firmware --interface X --channel Y ...`."""
    return run_controller(settings.port, settings.controller, "aspod firmware", settings.bus, timing=settings.timing,
                          plant_pid=settings.plant_pid)


def run_sim_over_hal(settings: SimSettings) -> int:
    """`aspod sim --hal INTERFACE [--hal-channel CH]`: `aspod plant` as a child, the controller here."""
    interface = nodes.check_interface(settings.hal, between_processes=True)
    options = dict(settings.hal_options)
    channel = settings.hal_channel
    if channel is None:
        if interface != "udp_multicast":
            raise ValueError(f"--hal {interface} needs --hal-channel (the {interface} channel to use)")
        channel, port = nodes.fresh_udp_multicast()   # private to this run
        options.setdefault("port", port)
    bus = BusSettings(interface, channel, tuple(options.items()))
    nodes.open_bus(interface, channel, **options).shutdown()   # fail here, before a child is started
    verbosity = (logging.INFO - log.getEffectiveLevel()) // 10       # the child logs as this process does
    plant = PlantProcess(PlantRunSettings(bus=bus, plant=settings.plant, seed=settings.seed, timing="lockstep",
                                          speed=settings.speed, verbosity=verbosity))
    log.info(f"aspod sim: plant process {plant.pid} ready on {bus.describe()}")
    try:
        return run_controller(settings.port, settings.controller, "aspod sim", bus, plant, timing="lockstep",
                              speed=settings.speed, control=settings.control, control_path=settings.control_path)
    finally:
        plant.stop()


# ---- the command line: its options, examples and run --------------------------------------------------------

EXAMPLES = [
    "aspod firmware --interface udp_multicast --channel 239.74.163.2 --pty",
]


def add_options(firmware: argparse.ArgumentParser) -> None:
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


def run(args: argparse.Namespace) -> int:
    from host_tools.cli import settings
    return run_firmware(settings.firmware_settings(args))
