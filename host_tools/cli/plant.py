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
sun starts: `tracker_options`, `sun_line`), runs until SIGINT or SIGTERM
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
import math
import os
import select
import selectors
import signal
import subprocess
import sys
from typing import Any, Callable, Optional, Sequence

from timebase.scheduler import Scheduler, run_live
from hil_sim.sun import TUCSON, SunTable, as_clouds, to_utc
from protocol.lockstep import LockstepLeader
from timebase import PacedClock, RealClock

from host_tools.worlds import nodes
from host_tools.datetimes import NOW, parse_when

READY = "ASPOD-PLANT ready"
STDIN_CHECK_S = 0.1
WAITING_NOTE_S = 5.0     # lock-step: say so on stderr when the controller has not answered for this long


def bus_options(args: argparse.Namespace) -> dict[str, Any]:
    """Keywords for `nodes.open_bus` from --bitrate, --data-bitrate and --bus-arg."""
    options = nodes.parse_bus_args(args.bus_arg or (), args.interface)
    if args.bitrate is not None:
        options["bitrate"] = args.bitrate
    if args.data_bitrate is not None:
        options["data_bitrate"] = args.data_bitrate
    return options


def tracker_options(args: argparse.Namespace, *, warm: bool = True) -> dict[str, Any]:
    """`tracker`, `start` and `clouds` for `World` / `build_plant_node` from --no-tracker, --sun-start, --clouds.

    `now` (the default) is read from the one wall clock (`RealClock.wall_time()`) after the day's
    sun has been computed (pvlib's import and a day's table take about a second), so that the
    plant's sun is the real sun at Tucson when the run starts. ValueError with the reason for
    options that contradict each other or clouds that do not fit the start's day. `warm` False:
    only check them (a parent whose child process builds the plant).
    """
    text, clouds = getattr(args, "sun_start", None), getattr(args, "clouds", None)
    if getattr(args, "no_tracker", False):
        given = [name for name, value in (("--sun-start", text), ("--clouds", clouds)) if value is not None]
        if given:
            raise ValueError(f"{' and '.join(given)} set the solar tracker's sun, but --no-tracker leaves the "
                             "tracker out: drop one or the other")
        return {"tracker": False}
    seconds = parse_when(text or NOW, "--sun-start", posix=False)
    if seconds is None:
        if warm:
            SunTable(TUCSON).preload(RealClock.wall_time())  # the table, cached for the plant
        seconds = RealClock.wall_time()
    start = to_utc(seconds)
    return {"tracker": True, "start": start, "clouds": as_clouds(clouds, start, TUCSON)}


def sun_line(prog: str, options: dict[str, Any], tracker=None, *, from_now: bool = False) -> str:
    """Where the plant's sun starts (and where it stands then, given the plant's `tracker`), for stderr."""
    if not options.get("tracker"):
        return f"{prog}: no solar tracker (--no-tracker)"
    start = options["start"]
    local = start.astimezone(TUCSON.local_tz).isoformat(timespec="seconds")
    where = ""
    if tracker is not None:
        el, az, dni, _dhi = tracker.sun()
        if math.isfinite(el):
            where = f", azimuth {az:.2f} deg, elevation {el:.2f} deg, clear-sky beam {dni:.0f} W/m^2"
    passages = ", ".join(f"{p.start.astimezone(TUCSON.local_tz):%H:%M:%S}+{p.duration_s:g}s@{p.attenuation:g}"
                         for p in options["clouds"]) or "none"
    clock = "clock now" if from_now else f"clock {local}"
    return (f"{prog}: the sun starts at {local} ({start:%Y-%m-%dT%H:%M:%S}Z{', now' if from_now else ''}) at "
            f"Tucson{where}; clouds {passages}; at teleop `{clock}` sets the controller's clock to it")


def sun_from_now(args: argparse.Namespace) -> bool:
    return (getattr(args, "sun_start", None) or NOW).lower() == NOW


def tracker_child_args(args: argparse.Namespace) -> list[str]:
    """The tracker options as `aspod plant` takes them, for a child plant process (`aspod sim --hal`)."""
    out = []
    for flag, value in (("--sun-start", getattr(args, "sun_start", None)), ("--clouds", getattr(args, "clouds", None))):
        if value is not None:
            out += [flag, value]
    return out + (["--no-tracker"] if getattr(args, "no_tracker", False) else [])


def run_plant(args: argparse.Namespace) -> int:
    stopping: list[int] = []
    signal.signal(signal.SIGTERM, lambda signum, frame: stopping.append(signum))
    signal.signal(signal.SIGINT, lambda signum, frame: stopping.append(signum))
    options = bus_options(args)
    nodes.check_arm_settings(args.gravity, args.payload_kg)
    sun = tracker_options(args)
    bus = nodes.open_bus(args.interface, args.channel, node=nodes.PLANT, **options)
    wall = RealClock()
    pace = PacedClock(wall, args.speed)
    lockstep = args.timing == "lockstep"
    node = None
    leader: Optional[LockstepLeader] = None
    started_s = wall.now()
    try:
        if lockstep:
            leader = LockstepLeader(bus, pace, nodes.PLANT_PERIOD_S, reoffer=lambda: node.resend_sync())
        node = nodes.build_plant_node(leader.tap if leader else bus, args.seed, gravity=args.gravity,
                                      payload_kg=args.payload_kg, lockstep=lockstep, **sun)
        scheduler = Scheduler(leader or pace)
        scheduler.add("plant", node.step, period_s=node.period_s)
        link = Scheduler(wall)              # the wall clock's own tasks: the parent, the waiting note
        if args.stop_on_stdin_eof:
            link.add("stdin", _stdin_watch(stopping), tolerance_s=1.0)
        if leader is not None:
            link.add("waiting", _waiting_note(leader, node), wall.now() + 1.0, tolerance_s=1.0)
        speed = "max" if args.speed == math.inf else f"{args.speed:g}x"
        print(f"{READY} {nodes.describe_bus(args.interface, args.channel, options)} pid={os.getpid()}", flush=True)
        print(f"aspod plant: running on {args.interface} {args.channel}, seed {args.seed}, gravity {args.gravity}, "
              f"payload {args.payload_kg} kg, timing {args.timing} at speed {speed}; Ctrl-C stops",
              file=sys.stderr, flush=True)
        print(sun_line("aspod plant", sun, node.plant.tracker, from_now=sun_from_now(args)), file=sys.stderr,
              flush=True)
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
                counters.update(sync_resends=node.sync_resends, held_dropped=leader.tap.dropped)
            print(f"aspod plant: stopped after {wall.now() - started_s:.1f} s; counters "
                  f"{nodes.format_counters(counters)}", file=sys.stderr, flush=True)
            if node.last_bus_error is not None:
                print(f"aspod plant: last bus error: {node.last_bus_error}", file=sys.stderr, flush=True)
    return 0


def _waiting_note(leader: LockstepLeader, node) -> Callable[[float], Optional[float]]:
    """A wall-clock task: in lock-step, say on stderr when the controller has not answered for a while."""
    said = [0.0]

    def step(now: float) -> float:
        stalled = leader.stalled_s()
        if stalled >= WAITING_NOTE_S and stalled - said[0] >= WAITING_NOTE_S:
            said[0] = stalled
            print(f"aspod plant: lock-step: waiting {stalled:.0f} s for the controller's CTRL_SYNC for tick "
                  f"{node.tick} (is `aspod firmware --timing lockstep` running on this bus?)", file=sys.stderr,
                  flush=True)
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
                print("aspod plant: standard input closed (the parent is gone); stopping",
                      file=sys.stderr, flush=True)
                stopping.append(0)
                return None
        return now + STDIN_CHECK_S
    return step


class PlantProcess:
    """`aspod plant` as a child process of this one.

    Its stdin is a pipe this process holds, so the child stops by itself if this
    process dies without stopping it; its stderr (messages, counters at exit) is this
    process's stderr; it runs in a session of its own, so a Ctrl-C at the terminal
    reaches only this process, which then stops the child.
    """

    def __init__(self, interface: str, channel: str, options: dict[str, Any], *, seed: int = 0,
                 extra_args: Sequence[str] = (), start_timeout_s: float = 30.0) -> None:
        argv = [sys.executable, "-m", "host_tools.cli.main", "plant", "--interface", interface, "--channel", channel,
                "--seed", str(seed), "--stop-on-stdin-eof", *extra_args]
        for key, value in options.items():
            if key == "bitrate":
                argv += ["--bitrate", str(value)]
            elif key == "data_bitrate":
                argv += ["--data-bitrate", str(value)]
            else:
                argv += ["--bus-arg", f"{key}={value}"]
        self.argv = argv
        self.proc = subprocess.Popen(argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, bufsize=0,
                                     start_new_session=True)
        self.pid = self.proc.pid
        self.stopped = False       # we asked it to stop
        self.reported = False      # its unexpected end was reported
        try:
            self.ready_line = self._read_ready(start_timeout_s)
        except BaseException:
            self.stop()
            raise

    def _read_ready(self, timeout_s: float) -> str:
        line = bytearray()
        with selectors.DefaultSelector() as sel:
            sel.register(self.proc.stdout, selectors.EVENT_READ)
            while not line.endswith(b"\n"):
                if not sel.select(timeout_s):
                    raise OSError(f"the plant process (pid {self.pid}) did not say it was ready "
                                  f"within {timeout_s:g} s")
                byte = self.proc.stdout.read(1)
                if not byte:
                    status = self.proc.wait()
                    raise OSError(f"the plant process (pid {self.pid}) exited ({describe_exit(status)}) "
                                  "before it was ready; its messages are above")
                line += byte
        text = line.decode(errors="replace").rstrip("\n")
        if not text.startswith(READY):
            raise OSError(f"the plant process (pid {self.pid}) said {text!r}, not {READY!r}")
        return text

    def exit_status(self) -> Optional[int]:
        """None while it runs; its exit status (negative: killed by that signal) once it has ended."""
        return self.proc.poll()

    def stop(self, timeout_s: float = 10.0) -> Optional[int]:
        """SIGTERM, then SIGKILL if it has not gone within `timeout_s`; returns its exit status."""
        self.stopped = True
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        for stream in (self.proc.stdin, self.proc.stdout):
            if stream is not None:
                stream.close()
        return self.proc.returncode


def describe_exit(status: int) -> str:
    if status < 0:
        try:
            name = signal.Signals(-status).name
        except ValueError:
            name = str(-status)
        return f"killed by {name}"
    return f"exit status {status}"
