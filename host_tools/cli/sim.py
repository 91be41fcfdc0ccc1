"""`aspod sim`: the controller and its plant in one process, on a real port.

Plant and controller share one simulated time paced to the wall clock (`timebase.PacedClock`
at --speed, 1 by default): when the process falls behind, the world slows down instead of
jumping, so the host's stalls never look like hardware faults; the link to the host stays on
the wall clock (docs/realtime.md). The real-time factor and the lag are in telemetry and
`status`; falling below real time is said on stderr and in a TimingWarning event.

Prints `ASPOD-LINK <url>` as its first line on stdout and `ASPOD-KEY <path>` as its
second, then runs until SIGINT or SIGTERM. Without --key-file it uses (creating it
if needed) the per-user development key that the host tools also default to.

The plant carries the solar tracker unless --no-tracker; its sun starts at --sun-start
(`now` by default: the real sun at Tucson, which `clock now` at teleop matches) with
--clouds; where it starts is said on stderr (host_tools/cli/plant.py `tracker_options`).

With --hal INTERFACE the plant runs as a separate process (`aspod plant`) and the two
meet on that python-can interface: see host_tools/cli/firmware.py and
docs/separate_processes.md.
"""
from __future__ import annotations

import argparse
import signal
import sys

from timebase import PacedClock, RealClock

from host_tools.cli.firmware import (apply_command_line, controller_config, log_states, open_port,
                                    run_sim_over_hal)
from host_tools.cli.plant import sun_from_now, sun_line, tracker_options
from host_tools.worlds.world import World


def run_sim(args: argparse.Namespace) -> int:
    if getattr(args, "hal", None) is not None:   # plant in a process of its own, on a real python-can interface
        return run_sim_over_hal(args)
    psk, key_path, params_path, config = controller_config(args)
    sun = tracker_options(args)
    port = open_port(args, "aspod sim")
    wall = RealClock()
    world = World(PacedClock(wall, args.speed), port, psk, seed=args.seed, baud=args.baud, paced=not args.no_pacing,
                  controller_config=config, gravity=args.gravity, payload_kg=args.payload_kg, link_clock=wall, **sun)
    params = world.controller.params
    apply_command_line(world.controller, args, "aspod sim")
    log_states(world.controller, "aspod sim")
    print(f"ASPOD-LINK {port.url}", flush=True)
    print(f"ASPOD-KEY {key_path}", flush=True)
    print(f"aspod sim: controller up at {args.baud} baud{' (unpaced)' if args.no_pacing else ''}, "
          f"link timeout {params['link_timeout_s']} s, parameters in {params_path}; Ctrl-C stops",
          file=sys.stderr, flush=True)
    print(sun_line("aspod sim", sun, world.plant.tracker, from_now=sun_from_now(args)), file=sys.stderr, flush=True)
    stopping = []

    def stop(signum, frame):
        stopping.append(signum)

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    try:
        world.run(lambda: bool(stopping))
    finally:
        world.close()
    return 0
