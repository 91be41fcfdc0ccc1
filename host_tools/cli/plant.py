"""`aspod plant`: the plant alone, on a python-can interface.

It closes the loop around a controller in another process (`aspod firmware`, or
`aspod sim --hal`, which starts this as its child) or on other hardware. Its time is
simulated time paced to the wall clock at --speed (`timebase.PacedClock`: late, it slows
down instead of jumping). With --timing lockstep (the default) it is also gated by the
controller: tick N is integrated only once the controller has answered tick N - 1 with
CTRL_SYNC (`protocol.lockstep.LockstepLeader`), so neither process ever sees the other's
stalls; --timing realtime ticks whoever listens (a controller that does not speak lock-step).
It prints

    ASPOD-PLANT ready interface=<interface> channel=<channel> [key=value ...] pid=<pid>

on stdout once its bus is open and its first tick is due (and, on stderr, where the simulated
sun starts: `resolve_sun`, `sun_line`), runs until SIGINT or SIGTERM
(or, with --stop-on-stdin-eof, until its standard input closes: the parent that
started it has gone), shuts the bus down and prints its counters on stderr:

    aspod plant: counters ticks=... frames_sent=... frames_received=... own_echoes=... bad_frames=... bus_errors=...

`frames_received` counts what other nodes sent: on udp_multicast the plant's own
frames come back to it and are dropped (`own_echoes`) before they are counted.

`PlantProcess` is the parent's side: start `aspod plant` as a child, wait for its
readiness line, notice if it dies, stop it.
"""
from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import os
import select
import signal
import sys
from typing import Callable, Optional

from timebase.scheduler import Scheduler, run_live
from hil_sim.sun import TUCSON, SunTable
from protocol.lockstep import ControllersWatch, LockstepLeader
from timebase import PacedClock, RealClock

from host_tools.cli.options import add_arm_args, add_bus_args, add_seed_arg, add_speed_arg, add_timing_arg, add_tracker_args
from host_tools.cli.settings import PlantRunSettings
from host_tools.worlds import nodes
from host_tools.worlds.child import PIPE, Child, ChildError
from host_tools.worlds.settings import PlantSettings

log = logging.getLogger("aspod")

READY = "ASPOD-PLANT ready"
STDIN_CHECK_S = 0.1
WAITING_NOTE_S = 5.0     # lock-step: say so on stderr when the controller has not answered for this long


def resolve_sun(plant: PlantSettings, *, warm: bool = True) -> PlantSettings:
    """`plant` with its sun's start resolved: `now` (start None) is read from the one wall clock
    (`RealClock.wall_time()`) after the day's sun has been computed (a day's table takes about 70 ms,
    `warm`), so that the plant's sun is the real sun at Tucson when the run starts."""
    if not plant.tracker or plant.start is not None:
        return plant
    if warm:
        SunTable(TUCSON).preload(RealClock.wall_time())  # the table, cached for the plant
    return plant.with_start(RealClock.wall_time())


def sun_line(prog: str, plant: PlantSettings, tracker=None, *, from_now: bool = False) -> str:
    """Where the plant's sun starts (and where it stands then, given the plant's `tracker`), for stderr."""
    if not plant.tracker:
        return f"{prog}: no solar tracker (--no-tracker)"
    start = plant.plant_start()
    local = start.astimezone(TUCSON.local_tz).isoformat(timespec="seconds")
    where = ""
    if tracker is not None:
        el, az, dni, _dhi = tracker.sun()
        if math.isfinite(el):
            where = f", azimuth {az:.2f} deg, elevation {el:.2f} deg, clear-sky beam {dni:.0f} W/m^2"
    passages = ", ".join(f"{p.start.astimezone(TUCSON.local_tz):%H:%M:%S}+{p.duration_s:g}s@{p.attenuation:g}"
                         for p in plant.passages()) or "none"
    clock = "clock now" if from_now else f"clock {local}"
    return (f"{prog}: the sun starts at {local} ({start:%Y-%m-%dT%H:%M:%S}Z{', now' if from_now else ''}) at "
            f"Tucson{where}; clouds {passages}; at teleop `{clock}` sets the controller's clock to it")


def run_plant(settings: PlantRunSettings) -> int:
    stopping: list[int] = []
    signal.signal(signal.SIGTERM, lambda signum, frame: stopping.append(signum))
    signal.signal(signal.SIGINT, lambda signum, frame: stopping.append(signum))
    bus_settings = settings.bus
    from_now = settings.plant.tracker and settings.plant.start is None
    plant = resolve_sun(settings.plant)
    bus = nodes.open_bus(bus_settings.interface, bus_settings.channel, node=nodes.PLANT, **bus_settings.kwargs)
    wall = RealClock()
    pace = PacedClock(wall, settings.speed)
    lockstep = settings.timing == "lockstep"
    node = None
    leader: Optional[LockstepLeader] = None
    controllers = ControllersWatch()
    started_s = wall.now()
    try:
        if lockstep:
            leader = LockstepLeader(bus, pace, nodes.PLANT_PERIOD_S, reoffer=lambda: node.resend_sync())
            # a second controller (or plant) on this bus: said on stderr
            leader.on_answer = lambda tick: _warn(controllers.answer(
                wall.now(), node.tick + node.sync_resends, node.foreign_frames()))
        node = nodes.build_plant_node(leader.tap if leader else bus, settings.seed, None, plant, lockstep=lockstep)
        scheduler = Scheduler(leader or pace)
        scheduler.add("plant", node.step, period_s=node.period_s)
        link = Scheduler(wall)              # the wall clock's own tasks: the parent, the waiting note
        if settings.stop_on_stdin_eof:
            link.add("stdin", _stdin_watch(stopping), tolerance_s=1.0)
        if leader is not None:
            link.add("waiting", _waiting_note(leader, node), wall.now() + 1.0, tolerance_s=1.0)
        speed = "max" if settings.speed == math.inf else f"{settings.speed:g}x"
        print(f"{READY} {bus_settings.describe()} pid={os.getpid()}", flush=True)
        log.info(f"aspod plant: running on {bus_settings.interface} {bus_settings.channel}, seed {settings.seed}, "
                 f"gravity {plant.gravity}, payload {plant.payload_kg} kg, timing {settings.timing} at speed {speed}; "
                 "Ctrl-C stops")
        log.info(sun_line("aspod plant", plant, node.plant.tracker, from_now=from_now))
        started_s = wall.now()
        pace.start()
        run_live(scheduler, link, lambda: bool(stopping))
    finally:
        bus.shutdown()
        if node is not None:
            timing = (leader or pace).timing()
            counters = {"ticks": node.tick, **nodes.hal_counters(node), "dt_clamps": node.dt_clamps,
                        "output_expiries": node.plant.commanded.expiries,
                        "rtf": f"{timing.rtf_total:.2f}", "slipped_s": f"{timing.slipped_s:.3f}"}
            if leader is not None:
                counters.update(sync_resends=node.sync_resends, held_dropped=leader.tap.dropped,
                                unasked_syncs=controllers.unasked)
            log.info(f"aspod plant: stopped after {wall.now() - started_s:.1f} s; counters "
                     f"{nodes.format_counters(counters)}")
            if node.last_bus_error is not None:
                log.warning(f"aspod plant: last bus error: {node.last_bus_error}")
    return 0


def _warn(line: Optional[str]) -> None:
    if line:
        log.warning(f"aspod plant: {line}")


def _waiting_note(leader: LockstepLeader, node) -> Callable[[float], Optional[float]]:
    """A wall-clock task: in lock-step, say on stderr when the controller has not answered for a while."""
    said = [0.0]

    def step(now: float) -> float:
        stalled = leader.stalled_s()
        if stalled >= WAITING_NOTE_S and stalled - said[0] >= WAITING_NOTE_S:
            said[0] = stalled
            log.warning(f"aspod plant: lock-step: waiting {stalled:.0f} s for the controller's CTRL_SYNC for tick "
                        f"{node.tick} (is `aspod firmware --timing lockstep` running on this bus?)")
        elif stalled < WAITING_NOTE_S:
            said[0] = 0.0
        return now + 1.0
    return step


def _stdin_watch(stopping: list[int]):
    """A task that stops the plant when standard input reaches end of file (its parent is gone)."""
    fd = sys.stdin.fileno()

    def step(now: float) -> Optional[float]:
        readable, _, _ = select.select([fd], [], [], 0)
        if readable:
            try:
                data = os.read(fd, 4096)
            except OSError:
                data = b""
            if not data:
                log.info("aspod plant: standard input closed (the parent is gone); stopping")
                stopping.append(0)
                return None
        return now + STDIN_CHECK_S
    return step


class PlantProcess(Child):
    """`aspod plant` as a child process of this one, ready once it has said so (`READY`).

    Its stdin is a pipe this process holds, so the child stops by itself if this
    process dies without stopping it; its stderr (messages, counters at exit) is this
    process's stderr; it runs in a session of its own, so a Ctrl-C at the terminal
    reaches only this process, which then stops the child (`stop`).
    """

    def __init__(self, settings: PlantRunSettings, *, start_timeout_s: float = 30.0) -> None:
        settings = dataclasses.replace(settings, stop_on_stdin_eof=True)
        super().__init__(["plant", *settings.to_argv()], stdin=PIPE, stderr=None, new_session=True)
        self.reported = False      # its unexpected end was reported
        try:
            self.ready_line = self.ready(READY, start_timeout_s)
        except ChildError as exc:
            self.stop()
            raise ChildError(f"the plant process did not start: {exc}; its messages are above") from None
        except BaseException:
            self.stop()
            raise


# ---- the command line: its options, examples and run --------------------------------------------------------

EXAMPLES = [
    "aspod plant --interface udp_multicast --channel 239.74.163.2 --gravity orbit",
]


def add_options(plant: argparse.ArgumentParser) -> None:
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


def run(args: argparse.Namespace) -> int:
    from host_tools.cli import settings
    return run_plant(settings.plant_run_settings(args))
