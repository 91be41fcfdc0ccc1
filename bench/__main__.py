"""`python -m bench` (`make bench`): codec, round trip, real-time loop, lock-step speed, tracking, the solar tracker's day, live sessions under load, sessions (proxy, capture decoding, two links), campaigns (Dask throughput and overhead, lock-step against live), fuzzing (in process, black-box, beside boofuzz; and planted bugs found or missed), time-optimal planning (beside toppra), two arms carrying the report's object, and the start (the command line, aspod sim, children's memory, numba's cache), in that order.

    python -m bench [--quick] [--only codec|rtt|realtime|lockstep|tracking|tracker|live|handshake|sessions|campaign|fuzz|fuzz-plants|plan|two-arms|start]

These print figures and ratios beside a peer measured in the same run; they are not
pass/fail tests. The exit status is 0 when every benchmark produced its figures
(whether or not a goal was met), 1 when one could not run.
"""
from __future__ import annotations

import argparse
import sys
from typing import Optional, Sequence


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m bench", description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true",
                        help="fewer frames and pings, 5 s loops instead of 60 s, 5 simulated s of lock-step "
                             "instead of 20, shorter tracking moves and no pick-and-place: a smoke run")
    parser.add_argument("--only", choices=("codec", "rtt", "realtime", "lockstep", "tracking", "tracker", "live",
                                                  "handshake", "sessions", "campaign", "fuzz", "fuzz-plants", "plan",
                                                  "two-arms", "start"),
                        help="run one benchmark only (fuzz: its speed and then the planted bugs; fuzz-plants: only the "
                             "planted bugs)")
    return parser


def show_lines_as_printed() -> None:
    """Line-buffer stdout: piped (`make bench | tee`), Python would hold a benchmark's lines in a block buffer, and a
    long run would show nothing for minutes."""
    sys.stdout.reconfigure(line_buffering=True)


def main(argv: Optional[Sequence[str]] = None) -> int:
    args = build_parser().parse_args(argv)
    show_lines_as_printed()
    status = 0
    if args.only in (None, "codec"):
        from bench import bench_codec
        try:
            bench_codec.main(quick=args.quick)
        except bench_codec.BenchError as exc:
            print(f"bench codec: {exc}", file=sys.stderr)
            status = 1
        if args.only is None:
            print()
    if args.only in (None, "rtt"):
        from bench import bench_rtt
        results = bench_rtt.main(quick=args.quick)
        if any(r.error for r in results):
            status = 1
        if args.only is None:
            print()
    if args.only in (None, "realtime"):
        from bench import bench_realtime
        if bench_realtime.main(quick=args.quick).error:
            status = 1
        if args.only is None:
            print()
    if args.only in (None, "lockstep"):
        from bench import bench_lockstep
        if bench_lockstep.main(quick=args.quick).error:
            status = 1
        if args.only is None:
            print()
    if args.only in (None, "tracking"):
        from bench import bench_tracking
        if bench_tracking.main(quick=args.quick).error:
            status = 1
        if args.only is None:
            print()
    if args.only in (None, "tracker"):
        from bench import bench_tracker
        if bench_tracker.main(quick=args.quick).error:
            status = 1
        if args.only is None:
            print()
    if args.only in (None, "live"):
        from bench import bench_live
        if bench_live.main(quick=args.quick).error:
            status = 1
        if args.only is None:
            print()
    if args.only in (None, "handshake"):
        from bench import bench_handshake
        if bench_handshake.main(quick=args.quick).error:
            status = 1
        if args.only is None:
            print()
    if args.only in (None, "sessions"):
        from bench import bench_sessions
        if bench_sessions.main(quick=args.quick).error:
            status = 1
        if args.only is None:
            print()
    if args.only in (None, "campaign"):
        from bench import bench_campaign
        if bench_campaign.main(quick=args.quick).error:
            status = 1
        if args.only is None:
            print()
    if args.only in (None, "fuzz"):
        from bench import bench_fuzz
        if bench_fuzz.main(quick=args.quick).error:
            status = 1
        print()
    if args.only in (None, "fuzz", "fuzz-plants"):
        from bench import bench_fuzz_plants
        if bench_fuzz_plants.main(quick=args.quick).error:
            status = 1
        if args.only is None:
            print()
    if args.only in (None, "plan"):
        from bench import bench_arm_moves, bench_plan
        if bench_plan.main(quick=args.quick).error:
            status = 1
        print()
        if bench_arm_moves.main(quick=args.quick).error:
            status = 1
        if args.only is None:
            print()
    if args.only in (None, "two-arms"):
        from bench import bench_two_arms
        if bench_two_arms.main(quick=args.quick).error:
            status = 1
        if args.only is None:
            print()
    if args.only in (None, "start"):
        from bench import bench_start
        if bench_start.main(quick=args.quick).error:
            status = 1
    return status


if __name__ == "__main__":
    sys.exit(main())
