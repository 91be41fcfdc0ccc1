"""`aspod demo`: the arm picks up debris and drops it in the bin, on the simulated clock (host_tools/apps/demo.py)."""
from __future__ import annotations



import argparse
from pathlib import Path
from host_tools.cli.options import add_seed_arg, baud_rate

# ---- the command line: its options, examples and run --------------------------------------------------------

EXAMPLES = [
    "aspod demo",
    "aspod demo --json --gravity orbit",
    "aspod demo --link",
]


def add_options(demo: argparse.ArgumentParser) -> None:
    from host_tools.worlds.settings import GRAVITY_MODES
    demo.add_argument("--json", action="store_true", help="print one JSON object (steps, errors, times)")
    demo.add_argument("--gravity", choices=GRAVITY_MODES, default="earth", help="the arm's gravity (default earth)")
    add_seed_arg(demo, "the plant's noise and the link's nonces")
    demo.add_argument("--link", action="store_true",
                      help="instead: start `aspod sim --pty` and run a scripted teleop session over the pty")
    demo.add_argument("--baud", type=baud_rate, default=115200, help="line rate for --link")
    demo.add_argument("--record", type=Path, metavar="FILE.pcapng",
                      help="capture the session (on the simulated clock: aspod replay re-runs it to the bit)")


def run(args: argparse.Namespace) -> int:
    from host_tools.cli import settings
    from host_tools.apps.demo import run_demo
    return run_demo(settings.demo_settings(args))
