"""`aspod sim`: the controller and its plant in one process, on a real port.

Plant and controller share one simulated time paced to the wall clock (`timebase.PacedClock`
at --speed, 1 by default): when the process falls behind, the world slows down instead of
jumping, so the host's stalls never look like hardware faults; the link to the host stays on
the wall clock (docs/realtime.md). The real-time factor and the lag are in telemetry and
`status`; falling behind the speed asked is said on stderr and in a TimingWarning event.

Prints `ASPOD-LINK <url>` as its first line on stdout and `ASPOD-KEY <path>` as its
second, then runs until SIGINT or SIGTERM. Without --key-file it makes a fresh key of its
own, in this user's private runtime folder, removed when it stops (host_tools/worlds/
runtime_folder.py): no two simulators share a key unless given the same --key-file.

Beside the link it serves the control endpoint (unless --no-control): a local Unix socket that
faults, loads, clouds, pauses and steps the plant, and reads its true state, for teleop's `sim`
words and the pytest plugin (host_tools/worlds/control_server.py, plant_control.py), and says
the link's key file to a host tool given only the link's address (`info`). Its path is the third
ready line, `ASPOD-CONTROL <path>`; each change it makes is said on stderr.

The plant carries the solar tracker unless --no-tracker; its sun starts at --sun-start
(`now` by default: the real sun at Tucson, which `clock now` at teleop matches) with
--clouds; where it starts is said on stderr (host_tools/cli/plant.py `resolve_sun`, `sun_line`).

With --hal INTERFACE the plant runs as a separate process (`aspod plant`) and the two
meet on that python-can interface: see host_tools/cli/firmware.py and
docs/separate_processes.md.
"""
from __future__ import annotations

import argparse
import dataclasses
import logging
import os
import signal
from pathlib import Path
from typing import Optional

from firmware_py.arm_config import EXAMPLE_ARM
from firmware_py.controller import ControllerConfig

from timebase import PacedClock, RealClock

from host_tools.cli.options import (above_zero, bounded, add_arm_args, add_controller_args, add_seed_arg, add_speed_arg,
                                      add_tracker_args, can_interface)
from host_tools.cli.firmware import (apply_command_line, check_params_file, controller_config, controller_key,
                                     log_states, open_port, run_sim_over_hal, runtime_folder, serve_endpoint)
from host_tools.cli.plant import resolve_sun, sun_line
from host_tools.cli.settings import SimSettings
from host_tools.sessions.capture import CaptureWriter, SessionInfo
from host_tools.sessions.foxglove import DEFAULT_PORT as FOXGLOVE_PORT
from host_tools.worlds.control_server import ControlServer
from host_tools.worlds.runtime_folder import RuntimeFolder
from host_tools.worlds.plant_control import PlantControl
from host_tools.worlds.second_arm import SecondArm
from host_tools.worlds.settings import PlantSettings
from host_tools.worlds.world import World

log = logging.getLogger("aspod")


def session_info(settings: SimSettings, plant: PlantSettings, world: World) -> SessionInfo:
    """What `aspod replay` needs to build this world again: the plant, every parameter's value, the seed."""
    return SessionInfo(clock="paced", tool="aspod sim", seed=settings.seed, settings={
        "plant": plant.to_dict(), "params": world.controller.params.values(), "speed": settings.speed,
        "baud": settings.port.baud, "paced": settings.port.paced})


def run_sim(settings: SimSettings) -> int:
    if settings.hal is not None:   # plant in a process of its own, on a real python-can interface
        return run_sim_over_hal(settings)
    params_path, config = controller_config(settings.controller)
    stopping: list[int] = []

    def stop(signum, frame):
        stopping.append(signum)

    # From here on a stop is a request the run answers by closing everything (the control socket's file and the
    # key's too), whenever it comes: a parent may stop the simulator as soon as it has read the ready lines.
    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    folder = runtime_folder(settings.controller, settings.control and settings.control_path is None, "aspod sim")
    try:
        return _run_sim(settings, params_path, config, folder, stopping)
    finally:
        if folder is not None:
            folder.close()


def _run_sim(settings: SimSettings, params_path: Path, config: ControllerConfig, folder: Optional[RuntimeFolder],
             stopping: list[int]) -> int:
    psk, key_path = controller_key(settings.controller, folder)
    from_now = settings.plant.tracker and settings.plant.start is None
    plant = resolve_sun(settings.plant)
    port = open_port(settings.port, "aspod sim")
    wall = RealClock()
    baud, paced = settings.port.baud, settings.port.paced
    second = None
    try:
        if settings.arms == 2:
            config, second = two_arms(settings, config, params_path)
        world = World(PacedClock(wall, settings.speed), port, psk, seed=settings.seed, baud=baud, paced=paced,
                      controller_config=config, plant=plant, link_clock=wall, second_arm=second,
                      arm_params=None if second is None else second.arm_params)
    except BaseException:
        port.close()
        if second is not None:
            second.port.close()
        raise
    params = world.controller.params
    controllers = [world.controller] + ([world.arm2.controller] if world.arm2 is not None else [])
    for number, controller in enumerate(controllers, 1):
        prog = "aspod sim" if len(controllers) == 1 else f"aspod sim (arm {number})"
        apply_command_line(controller, settings.controller, prog)
        log_states(controller, prog)
    control = None
    try:
        link2 = None if second is None else second.port.url
        control_path = settings.control_path or (folder.control_path() if folder is not None else None)
        if settings.control and control_path is not None:
            control = serve_control(control_path, plant, world, port.url, key_path, link2)
        record_outputs(settings, plant, world)
        print(f"ASPOD-LINK {port.url}", flush=True)
        print(f"ASPOD-KEY {key_path}", flush=True)
        if link2 is not None:
            print(f"ASPOD-LINK2 {link2}", flush=True)
        if control is not None:
            print(f"ASPOD-CONTROL {control.path}", flush=True)
        if settings.foxglove is not None:
            print(f"ASPOD-FOXGLOVE {serve_foxglove(settings.foxglove, world)}", flush=True)
        log.info(f"aspod sim: controller up at {baud} baud{'' if paced else ' (unpaced)'}, "
                 f"link timeout {params['link_timeout_s']} s, parameters in {world.controller.config.params_path}; Ctrl-C stops")
        if second is not None:
            world.arm2.on_object_event = lambda text: log.info(f"aspod sim: {text}")
            log.info(f"aspod sim: two {EXAMPLE_ARM.name} arms {second.bases_m[1][0] - second.bases_m[0][0]:g} m "
                     f"apart, arm 1's controller at {port.url} leading, arm 2's at {link2} (parameters in "
                     f"{world.arm2.controller.config.params_path}); the object waits at x {second.waits_at_m[0]:g}, "
                     f"z {second.waits_at_m[1]:g} m for both hands to close on it (docs/two_arms.md)")
        else:
            log.info(sun_line("aspod sim", plant, world.plant.tracker, from_now=from_now))
        world.run(lambda: bool(stopping))
    finally:
        if control is not None:
            control.close()
        world.close()
    return 0


def two_arms(settings: SimSettings, config: ControllerConfig, params_path: Path) -> tuple[ControllerConfig, SecondArm]:
    """`--arms 2`: the report's coordinated system as its example plans it (docs/two_arms.md), two example arms
    with the example's object waiting at its path's start; the first arm's controller settings and the second
    arm. Each controller keeps its parameters in a file of its own beside `params_path` (a one-arm simulator's set is
    ASPOD's arm's: its gains would not suit an example arm), and the second's id is the first's, plus one."""
    from hil_sim.arm_params import EXAMPLE_ARM_PLANT
    from hil_sim.held_object import ObjectParams
    from host_tools.plan.example import PATH
    paths = [params_path.with_name(f"{params_path.stem}-arm{k}{params_path.suffix}") for k in (1, 2)]
    for path in paths:
        check_params_file(path)
    first = dataclasses.replace(config, arm=EXAMPLE_ARM, params_path=paths[0])
    ident = config.controller_id
    second_id = None if ident is None else ident[:-1] + bytes([(ident[-1] + 1) % 256])
    port2 = open_port(dataclasses.replace(settings.port, tcp=None if settings.port.tcp is None else
                                          (0 if settings.port.tcp == 0 else settings.port.tcp + 1)), "aspod sim")
    second = SecondArm(port2, dataclasses.replace(first, params_path=paths[1], controller_id=second_id),
                       arm_params=EXAMPLE_ARM_PLANT, held_object=ObjectParams(), waits_at_m=PATH[0])
    return first, second


def record_outputs(settings: SimSettings, plant: PlantSettings, world: World) -> None:
    """--record and --can-log, begun when nothing before the run can fail any more (a run that never started leaves
    them as they were); each is written to a temporary file and put in place when the world closes, a stop by
    SIGINT or SIGTERM included (host_tools/outputs.py)."""
    if settings.record is not None:
        world.record_link(CaptureWriter.create(settings.record, session_info(settings, plant, world)))
        log.info(f"aspod sim: recording the link to {settings.record} (aspod log {settings.record})")
    if settings.can_log is not None:
        world.log_hal_bus(settings.can_log, settings.can_ids, settings.can_rotate_bytes)
        parts = ""
        if settings.can_rotate_bytes is not None:
            from host_tools.worlds.can_log import MEGABYTE, part_path
            first, second = (part_path(settings.can_log.destination, n).name for n in (0, 1))
            parts = (f", in parts of {settings.can_rotate_bytes / MEGABYTE:g} MB: {first}, {second}, ... and the "
                     "newest frames in it")
        log.info(f"aspod sim: logging the HAL bus to {settings.can_log}{parts} (cantools decode protocol/hal.dbc)")


def serve_foxglove(port: int, world: World) -> str:
    """The controller's telemetry and events, as it writes them, on Foxglove's WebSocket protocol at 127.0.0.1:`port`
    (0: a free port), the topics of `aspod log --mcap` (host_tools/sessions/foxglove.py); returns its URL. The
    server stops when the world closes."""
    import math
    from host_tools.sessions.foxglove import FoxgloveTap, serve
    from host_tools.worlds.ports import RecordedPort
    topics, server = serve(port)
    tap = FoxgloveTap(topics, math.floor(RealClock.wall_time()), on_close=server.stop)
    world.uart.port = RecordedPort(world.uart.port, tap, world.clock)
    url = f"ws://127.0.0.1:{server.port}"
    log.info(f"aspod sim: serving the telemetry to Foxglove at {url} (Foxglove: Open connection, Foxglove WebSocket)")
    return url


def serve_control(path: Path, plant: PlantSettings, world: World, link_url: str, key_path: Path,
                  link2: Optional[str] = None) -> ControlServer:
    """The plant's control endpoint at `path`, served by a task on the link's (wall-clock) scheduler; with two arms
    it names the second arm's link too (`link2`), and its `state` carries the object."""
    about = {"link": link_url, "pid": os.getpid(), "key": str(key_path)}
    if link2 is not None:
        about["link2"] = link2
    control = PlantControl(world.plant, world.clock, tracker=plant.tracker, about=about,
                           log=lambda text: log.info(f"aspod sim: {text}"),
                           held_object=None if world.arm2 is None else world.arm2.object_state)
    return serve_endpoint(path, control, world.link_scheduler, "aspod sim")


# ---- the command line: its options, examples and run --------------------------------------------------------

EXAMPLES = [
    "aspod sim --pty",
    "aspod sim --tcp 0 --sun-start 2026-03-20T06:50-07:00 --clouds '12:00+300s@0.9'",
    "aspod sim --hal udp_multicast --pty",
    "aspod sim --pty --foxglove",
    "aspod sim --arms 2 --tcp 0 --no-tracker",
]


def add_options(sim: argparse.ArgumentParser) -> None:
    add_controller_args(sim)
    add_seed_arg(sim, "the plant's noise")
    sim.add_argument("--hal", type=can_interface, metavar="INTERFACE",
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
    sim.add_argument("--arms", type=int, choices=(1, 2), default=1,
                     help="2: the report's coordinated system, two example arms 2 m apart (1 m rod links), each "
                          "with its own controller and link (an ASPOD-LINK2 line names the second's; with --tcp "
                          "PORT it is PORT + 1), the example's object waiting at its path's start for both hands; "
                          "aspod plan --links rod --execute LINK,LINK2 carries it (docs/two_arms.md)")
    add_tracker_args(sim)
    sim.add_argument("--record", type=Path, metavar="FILE.pcapng",
                     help="capture every frame on the controller's line, both ways, stamped with the world's time "
                          "(aspod log, Wireshark with aspod wireshark's dissector, aspod replay)")
    sim.add_argument("--can-log", type=Path, metavar="FILE",
                     help="write every HAL bus frame through python-can's Logger (.blf, .asc, .log, .csv, .trc, "
                          ".txt), for cantools decode, can.viewer, cantools plot; .blf is compressed (a tenth of "
                          "a .log's size)")
    sim.add_argument("--can-only", action="append", default=[], metavar="NAME[,NAME]",
                     help="with --can-log: only these messages of protocol/hal.dbc (repeatable), e.g. "
                          "ANALOG_IN,DIGITAL_IN")
    sim.add_argument("--can-skip", action="append", default=[], metavar="NAME[,NAME]",
                     help="with --can-log: not these messages (repeatable), e.g. MOTOR_CMD,MOTOR_FB,PLANT_SYNC, "
                          "the 1 kHz ones")
    sim.add_argument("--can-rotate-mb", type=above_zero, metavar="MB",
                     help="with --can-log FILE (.blf, .asc, .log, .csv, .txt): cut it into parts of MB megabytes "
                          "(10^6 bytes; each at most a frame more) through python-can's SizedRotatingLogger: hal.log "
                          "is written as hal_#000.log, hal_#001.log, ... (python-can's names, less their wall time), "
                          "each put in place when full, and the newest frames in hal.log; refused if a file of those "
                          "names is there already (docs/sessions.md)")
    sim.add_argument("--foxglove", type=bounded(int, 0, 65535), nargs="?", const=FOXGLOVE_PORT, metavar="PORT",
                     help="serve the telemetry live over Foxglove's WebSocket protocol on 127.0.0.1:PORT (default "
                          f"{FOXGLOVE_PORT}; 0: a free port), said in an ASPOD-FOXGLOVE line: the topics of "
                          "aspod log --mcap (the foxglove extra; docs/sessions.md)")
    control = sim.add_mutually_exclusive_group()
    control.add_argument("--control", type=Path, metavar="PATH",
                         help="serve the control endpoint (faults, gravity, payload, clouds, pause and step, the "
                              "plant's true state: docs/benches.md; the link's key for host tools) on this Unix "
                              "socket; by default it is served at a per-user path, said in an ASPOD-CONTROL line "
                              "(with --hal it reaches no plant and says only the link and its key)")
    control.add_argument("--no-control", action="store_true",
                         help="serve no control endpoint (host tools then need --key-file)")


def run(args: argparse.Namespace) -> int:
    from host_tools.cli import settings
    return run_sim(settings.sim_settings(args))
