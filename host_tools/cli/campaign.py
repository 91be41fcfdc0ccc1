"""`aspod campaign BENCH`: a bench (a teleop script, or a pytest file or node) over a matrix of settings, one
row per run, on Dask's distributed scheduler; the rows, a summary, plots, and for each failed run the one
command that reproduces it alone. See docs/campaigns.md.

    aspod campaign benches/test_pick_and_place.py --seeds 1000 --draw payload_kg=0..2.5 \\
        --draw fault=none,jam:j2,open_circuit:j1 --draw fault_at_s=1..20 --plot m.worst_error_mm:payload_kg

It needs the `campaign` extra (Dask, pyarrow, matplotlib, pytest): without it, it says so and exits 2.
"""
from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from timebase import RealClock

from host_tools.campaign import results
from host_tools.campaign.engine import run_runs
from host_tools.campaign.runs import SCRIPT, BenchSpec, RunResult
from host_tools.cli.options import bounded
from host_tools.cli.main import build_parser
from host_tools.cli.settings import CampaignSettings, bench_settings
from host_tools.exit_codes import EXIT_FAILED, EXIT_OK, EXIT_USAGE
from host_tools.teleop.words import TeleopError, script_directive
from host_tools.worlds.bench_world import WorldSettings
from kernels.extras import require

log = logging.getLogger("aspod")
SHOWN_FAILURES = 10


def bench_spec(settings: CampaignSettings) -> BenchSpec:
    """The bench, read here; a script's `#! aspod bench ...` line gives its base world. ValueError if unreadable."""
    cwd = Path.cwd()
    try:
        spec = BenchSpec.of(settings.bench, WorldSettings(), cwd, settings.keep_going)
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"bench {settings.bench}: {exc}") from None
    if spec.kind != SCRIPT:
        return spec
    try:
        directive = script_directive(spec.text.splitlines())
    except TeleopError as exc:
        raise ValueError(f"bench {settings.bench}: {exc}") from None
    if not directive:
        return spec
    try:
        world = bench_settings(build_parser(["bench"]).parse_args(["bench", settings.bench, *directive])).world
    except SystemExit:
        raise ValueError(f"bench {settings.bench}: its first line's `aspod bench` options do not parse") from None
    return BenchSpec(spec.kind, spec.target, world, spec.text, spec.cwd, spec.keep_going)


def run_campaign(settings: CampaignSettings) -> int:
    require("campaign", "dask", "distributed", "pyarrow", "matplotlib", "pytest", what="campaign")
    try:
        bench = bench_spec(settings)
    except ValueError as exc:
        log.error(f"aspod campaign: {exc}")
        return EXIT_USAGE
    runs = settings.matrix.runs()
    settings.out.mkdir(parents=True, exist_ok=True)
    from tqdm import tqdm
    bar = tqdm(total=len(runs), unit="run", desc="campaign", file=sys.stderr, disable=not settings.progress,
               dynamic_ncols=True)
    failed = [0]

    def done(result: RunResult) -> None:
        failed[0] += not result.row.get("ok")
        bar.update(1)
        bar.set_postfix(failed=failed[0], refresh=False)

    wall0 = RealClock.precise_now()
    try:
        rows_results = run_runs(bench, runs, settings.engine, done,
                                lambda where: log.info(f"aspod campaign: {len(runs)} runs of {settings.bench} "
                                                       f"on {where}"))
    finally:
        bar.close()
    wall = RealClock.precise_now() - wall0
    rows = [r.row for r in rows_results]
    rows_path = settings.out / f"rows.{settings.fmt}"
    results.write_rows(rows, rows_path, settings.fmt)
    figures = settings.figures or tuple(results.default_figures(rows))
    table = results.summary(rows, settings.group_by, figures)
    sim_s = sum(float(r.get("sim_s") or 0.0) for r in rows)
    description = {
        "command": settings.command,
        "bench": settings.bench, "axes": settings.matrix.axes, "runs": len(rows),
        "seeds": [settings.matrix.seeds[0], settings.matrix.seeds[-1]], "engine": settings.engine.describe(),
        "timing": {"wall_s": wall, "sim_s": sim_s, "sim_s_per_wall_s": sim_s / wall if wall > 0 else None,
                   "run_wall_s": [r.wall_s for r in rows_results]}}
    results.write_json(settings.out / "campaign.json", description, table, rows)
    print(results.format_summary(table, settings.group_by))
    try:
        written = results.plot(rows, settings.out, settings.plots, settings.hists)
    except ValueError as exc:
        log.error(f"aspod campaign: {exc} (the rows are written)")
        written = []
    print(f"{len(rows)} runs in {wall:.1f} s ({sim_s:.0f} simulated s, {sim_s / max(wall, 1e-9):.1f} simulated s per "
          f"wall s) on {settings.engine.describe()}; rows in {rows_path}, all in {settings.out / 'campaign.json'}"
          + "".join(f", {p}" for p in written))
    bad = [r for r in rows if not r.get("ok")]
    for row in bad[:SHOWN_FAILURES]:
        command = row.get("reproduce") or "(no command: its settings do not fit)"
        print(f"run {row['run']} {row['outcome']}: {row.get('error', '')}\n    {command}")
    if len(bad) > SHOWN_FAILURES:
        print(f"... and {len(bad) - SHOWN_FAILURES} more: the rows' `reproduce` column")
    return EXIT_FAILED if bad else EXIT_OK


# ---- the command line: its options, examples and run --------------------------------------------------------

EXAMPLES = [
    "aspod campaign benches/test_pick_and_place.py --seeds 1000 --draw payload_kg=0..2.5 --draw fault=none,jam:j2,open_circuit:j1,encoder_dropout:j3 --draw fault_at_s=1..20 --group-by fault --plot m.worst_error_mm:payload_kg",
    "aspod campaign benches/campaigns/tracker_dial.txt --vary sun_start=2026-01-15T10:00-07:00..2026-12-15T10:00-07:00/12 --vary dial=5,10,20 --scheduler tcp://10.0.0.5:8786",
]


def add_options(campaign: argparse.ArgumentParser) -> None:
    campaign.add_argument("bench", metavar="BENCH", help="a teleop script, or a pytest file or node "
                                                         "(path.py, path.py::test_name)")
    campaign.add_argument("--vary", action="append", default=[], metavar="NAME=VALUES",
                          help="a grid axis: NAME=A,B,C (impairment, clouds: A|B|C) or NAME=LO..HI/N (numbers or ISO date-times); every "
                               "combination runs. NAME: gravity, payload_kg, sun_start, clouds, fault, fault_at_s, "
                               "fault_until_s, impairment, param.NAME, or a bench variable (a script's ${NAME})")
    campaign.add_argument("--draw", action="append", default=[], metavar="NAME=VALUES",
                          help="drawn for each run from its seed: NAME=A,B,C (one of) or NAME=LO..HI (uniform); "
                               "impairment and clouds values are separated by | instead")
    campaign.add_argument("--seeds", default="1", metavar="N|FIRST..LAST",
                          help="each grid point runs with these seeds (default 1: seed 0)")
    campaign.add_argument("--workers", type=bounded(int, 1, 1024), default=None, metavar="N",
                          help="local Dask workers (default: one per core)")
    campaign.add_argument("--scheduler", default=None, metavar="tcp://HOST:8786",
                          help="a running Dask scheduler instead of a local cluster (docs/campaigns.md)")
    campaign.add_argument("--serial", action="store_true", help="no Dask: every run in this process, in order")
    campaign.add_argument("--out", type=Path, default=None, metavar="DIR",
                          help="where the rows, campaign.json and plots go (default campaign-<UTC time>; "
                               "a folder that already holds a campaign is refused)")
    campaign.add_argument("--format", choices=("csv", "parquet"), default="csv", help="the rows' file (default csv)")
    campaign.add_argument("--group-by", default=None, metavar="COLUMN",
                          help="the summary per value of this column (default: fault, when it varies)")
    campaign.add_argument("--summarize", action="append", default=[], metavar="COLUMN",
                          help="a figure for the summary (default: the bench's measurements, the time to the "
                               "safe state)")
    campaign.add_argument("--plot", action="append", default=[], metavar="Y:X", help="a scatter plot of Y against X")
    campaign.add_argument("--hist", action="append", default=[], metavar="COLUMN", help="a histogram")
    campaign.add_argument("--keep-going", action="store_true", help="a script goes on after a failed line")
    campaign.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from host_tools.cli import settings
    return run_campaign(settings.campaign_settings(args))
