"""`aspod tracker-day`: the solar tracker through a simulated day at Tucson (host_tools/apps/tracker_day.py)."""
from __future__ import annotations



import argparse
from pathlib import Path
from host_tools.cli.options import add_seed_arg

# ---- the command line: its options, examples and run --------------------------------------------------------

EXAMPLES = [
    "aspod tracker-day --mode feedforward --date 2026-12-21 --plot day.png",
]


def add_options(day: argparse.ArgumentParser) -> None:
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


def run(args: argparse.Namespace) -> int:
    from host_tools.cli import settings
    from host_tools.apps.tracker_day import run_tracker_day
    return run_tracker_day(settings.day_settings(args), as_json=args.json, plot=settings.day_plot(args))
