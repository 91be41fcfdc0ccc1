"""A teleop script against a whole world on the simulated clock (`BenchClient` on a `LockstepBench`).

    python -m host_tools.cli.bench_script benches/tracker_procedure.txt --sun-start 2026-03-20T06:50-07:00

The plant's state at the end is printed after the session's summary.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Optional, Sequence

from host_tools.cli.main import add_seed_arg
from host_tools.client.bench import BenchClient
from host_tools.datetimes import parse_when
from host_tools.exit_codes import EXIT_USAGE
from host_tools.teleop.session import run_script
from host_tools.teleop.words import read_script
from host_tools.worlds.settings import PlantSettings
from host_tools.worlds.world import LockstepBench


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m host_tools.cli.bench_script",
                                     description="run a teleop script against a whole world on the simulated clock")
    parser.add_argument("script", type=Path)
    parser.add_argument("--sun-start", default="2026-03-20T06:50-07:00", metavar="ISO",
                        help="the plant's sun at start (default 2026-03-20T06:50-07:00, the March equinox at sunrise)")
    parser.add_argument("--clouds", default=None, metavar="SPEC", help="cloud passages, as `aspod sim --clouds`")
    add_seed_arg(parser, "the plant's noise and the link's nonces")
    parser.add_argument("--keep-going", action="store_true")
    args = parser.parse_args(argv)
    try:
        lines = read_script(args.script, option="script")
        start = parse_when(args.sun_start, "--sun-start", posix=False)
        if start is None:
            raise ValueError("--sun-start: a simulated run needs a date-time, not `now`")
        bench = LockstepBench(seed=args.seed, plant=PlantSettings(start=start, clouds=args.clouds))
    except (OSError, ValueError) as exc:     # TeleopError included
        print(f"bench_script: {exc}", file=sys.stderr)
        return EXIT_USAGE
    try:
        client = BenchClient(bench)
        client.connect()
        status, session = run_script(client, lines, sys.stdout, keep_going=args.keep_going,
                                     wall_time=client.wall_time)
        tracker = bench.world.plant.tracker
        el, az, _dni, _dhi = tracker.sun()
        print(session.summary())
        print(f"plant after {bench.clock.now():.1f} simulated s: tracker az {tracker.angle_deg[0]:.3f} el "
              f"{tracker.angle_deg[1]:.3f} deg, sun az {az:.3f} el {el:.3f} deg, off the sun by "
              f"{tracker.angular_error_deg():.3f} deg; relay closings az {tracker.relay_closures[0]} el "
              f"{tracker.relay_closures[1]}, starts at a high duty {tracker.high_duty_starts}")
        return status
    finally:
        bench.close()


if __name__ == "__main__":
    sys.exit(main())
