"""`aspod bench SCRIPT`: a teleop script against a whole world on the simulated clock (`BenchClient` on a
`LockstepBench`): deterministic, as fast as the machine goes, with the plant's true state at the end.

    aspod bench benches/tracker_procedure.aspod --sun-start 2026-03-20T06:50-07:00
    aspod bench session.txt --json > result.json
    aspod bench session.txt --record session.pcapng && aspod replay session.pcapng
    aspod bench drill.aspod --fault jam:j2@3.5 --impairment radio --param j2_kp=40 --var speed=2
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

from host_tools.apps.script_bench import run_script_bench, script_sim_s
from host_tools.cli.options import add_arm_args, add_bench_world_args, add_seed_arg, add_tracker_args
from host_tools.cli.settings import BenchSettings
from host_tools.exit_codes import EXIT_USAGE
from host_tools.progress import Progress
from host_tools.teleop.sim_words import state_lines
from host_tools.teleop.words import read_script, substitute

log = logging.getLogger("aspod")


def run_bench(settings: BenchSettings) -> int:
    try:
        lines = substitute(read_script(settings.script, option="script"), dict(settings.variables))
    except (OSError, ValueError) as exc:
        log.error(f"aspod bench: {exc}")
        return EXIT_USAGE
    with Progress("bench", script_sim_s(lines)) as shown:
        run = run_script_bench(settings.world, lines, keep_going=settings.keep_going, err=sys.stderr,
                               out=None if settings.json else sys.stdout, capture=settings.record,
                               script=str(settings.script), shown=shown)
    if settings.json:
        print(json.dumps(run.record, indent=1))
        return run.status
    print(run.summary)
    print(f"plant after {run.record['sim_time_s']:.1f} simulated s:")
    print("\n".join("  " + line for line in state_lines(run.record["plant"])))
    for fault in run.record["faults"]:
        after = fault["safe_after_s"]
        print(f"fault {fault['fault']} at {fault['at_s']:g} s: "
              + ("no safe state" if after is None else f"safe state after {after:.3f} s ({fault['fault_bits']})")
              + ("" if fault["stated_s"] is None else f", stated {fault['stated_s']:g} s"))
    return run.status


# ---- the command line: its options, examples and run --------------------------------------------------------

EXAMPLES = [
    "aspod bench benches/tracker_procedure.aspod --sun-start 2026-03-20T06:50-07:00",
    "aspod bench session.txt --json > result.json",
    "aspod bench session.txt --record s.pcapng",
]


def add_options(bench: argparse.ArgumentParser) -> None:
    bench.add_argument("script", type=Path, metavar="SCRIPT", help="a teleop script (one command a line)")
    add_seed_arg(bench, "the plant's noise and the link's nonces")
    add_arm_args(bench)
    add_tracker_args(bench)
    add_bench_world_args(bench)
    bench.add_argument("--keep-going", action="store_true", help="go on after a failed command")
    bench.add_argument("--json", action="store_true", help="print one JSON object: steps, motions, the plant's state")
    bench.add_argument("--record", type=Path, metavar="FILE.pcapng",
                       help="capture the session on the simulated clock (aspod replay re-runs it to the bit)")


def run(args: argparse.Namespace) -> int:
    from host_tools.cli import settings
    return run_bench(settings.bench_settings(args))
