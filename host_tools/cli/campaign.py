"""`aspod campaign BENCH`: a bench (a teleop script, or a pytest file or node) over a matrix of settings, one
row per run, on Dask's distributed scheduler; the rows, a summary, plots, and for each failed run the one
command that reproduces it alone. See docs/campaigns.md.

    aspod campaign benches/test_pick_and_place.py --seeds 1000 --draw payload_kg=0..2.5 \\
        --draw fault=none,jam:j2,open_circuit:j1 --draw fault_at_s=1..20 --plot m.worst_error_mm:payload_kg

It needs the `campaign` extra (Dask, pyarrow, matplotlib, pytest): without it, it says so and exits 2.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import logging
import shlex
import signal
from pathlib import Path

from timebase import RealClock

from host_tools.campaign import results
from host_tools.campaign.engine import run_runs
from host_tools.campaign.runs import SCRIPT, BenchSpec, RunResult, known_columns
from host_tools.cli.options import bounded
from host_tools.cli.main import build_parser
from host_tools.cli.settings import CampaignSettings, bench_settings
from host_tools.exit_codes import EXIT_FAILED, EXIT_OK, EXIT_USAGE
from host_tools.progress import Progress, on_terminal
from host_tools.teleop.words import TeleopError, script_directive
from host_tools.worlds.bench_world import WorldSettings
from kernels.extras import require

log = logging.getLogger("aspod")
SHOWN_FAILURES = 10
EXIT_INTERRUPTED = 130               # Ctrl-C, as every aspod command (cli/main.py)


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


def bench_digest(bench: BenchSpec) -> str:
    """SHA-256 of the bench's file (a pytest node's file), as a resumed campaign must find it."""
    path = Path(bench.cwd) / bench.target.split("::", 1)[0]
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError as exc:
        raise ValueError(f"bench {bench.target}: {exc}") from None


def changed_bench(folder: Path, digest: str) -> str:
    """Why the campaign begun in `folder` cannot go on with this bench ("" if it can): its file has changed since,
    so the rows kept and the rows to come would be of two benches. A campaign begun before the digest was kept
    goes on."""
    try:
        began = json.loads((folder / "campaign.json").read_text(encoding="utf-8")).get("bench_sha256")
    except (OSError, ValueError, AttributeError):
        return ""
    if began is None or began == digest:
        return ""
    return (f"the bench file has changed since the campaign began there (SHA-256 {began[:12]}... then, "
            f"{digest[:12]}... now): its rows and the rest would be of two benches; put the file back as it was, "
            "or begin a new campaign in another folder")


def unknown_columns(settings: CampaignSettings, bench: BenchSpec) -> list[str]:
    """What the summary and plots are asked for that no row will have (before any run): a message each, naming the
    column and the columns there are."""
    names, open_prefixes = known_columns(bench, settings.matrix.axes)
    asked = [("--group-by", c) for c in ([settings.group_by] if settings.group_by is not None else [])]
    asked += [("--summarize", c) for c in settings.figures]
    asked += [("--plot", c) for pair in settings.plots for c in pair[::-1]]
    asked += [("--hist", c) for c in settings.hists]
    there = ", ".join(names) + "".join(f", {p}NAME" for p in open_prefixes)
    return [f"{option} {column}: no column {column!r}; the rows' columns: {there}"
            for option, column in dict.fromkeys(asked) if column not in names and not column.startswith(open_prefixes)]


def run_campaign(settings: CampaignSettings) -> int:
    require("campaign", "dask", "distributed", "pyarrow", "matplotlib", "pytest", what="campaign")
    try:
        bench = bench_spec(settings)
        digest = bench_digest(bench)
        wrong = unknown_columns(settings, bench)
    except ValueError as exc:
        log.error(f"aspod campaign: {exc}")
        return EXIT_USAGE
    if settings.resume and (why := changed_bench(settings.out, digest)):
        log.error(f"aspod campaign: --resume {settings.out}: {why}")
        return EXIT_USAGE
    for message in wrong:
        log.error(f"aspod campaign: {message}")
    if wrong:
        return EXIT_USAGE
    runs = settings.matrix.runs()
    journal_path = settings.out / results.JOURNAL
    try:
        done = results.read_journal(journal_path) if settings.resume else {}
    except (OSError, ValueError) as exc:
        log.error(f"aspod campaign: --resume {settings.out}: {exc}")
        return EXIT_USAGE
    kept = {r.index: RunResult(r.index, *done[r.index]) for r in runs if r.index in done}
    todo = [r for r in runs if r.index not in kept]
    settings.out.mkdir(parents=True, exist_ok=True)
    description = {"command": settings.command, "bench": settings.bench, "bench_sha256": digest,
                   "axes": settings.matrix.axes,
                   "runs": len(runs), "seeds": [settings.matrix.seeds[0], settings.matrix.seeds[-1]],
                   "engine": settings.engine.describe()}
    results.write_json(settings.out / "campaign.json", {**description, "state": "running"}, [], [])
    if settings.resume:
        print(f"resuming {settings.out}: {len(kept)} of {len(runs)} runs done, {len(todo)} to run", flush=True)
    failed = [sum(1 for r in kept.values() if not r.row.get("ok"))]
    stopping = [False]

    def on_sigint(signum, frame) -> None:
        stopping[0] = True           # a run that was under way (a script's wait takes Ctrl-C as its own) is not kept
        raise KeyboardInterrupt

    wall0 = RealClock.precise_now()
    previous = signal.signal(signal.SIGINT, on_sigint)
    try:
        with journal_path.open("a", encoding="utf-8") as journal, \
                Progress("campaign", len(runs), unit="run", enabled=settings.progress and on_terminal()) as shown:
            shown.update(len(kept))

            def ended(result: RunResult) -> None:
                if stopping[0]:
                    raise KeyboardInterrupt
                results.journal(journal_path, result.index, result.row, result.wall_s, journal)
                kept[result.index] = result
                failed[0] += not result.row.get("ok")
                shown.note(failed=failed[0])
                shown.update(1)

            run_runs(bench, todo, settings.engine, ended,
                     lambda where: log.info(f"aspod campaign: {len(todo)} runs of {settings.bench} on {where}"))
    except KeyboardInterrupt:
        signal.signal(signal.SIGINT, previous)
        rows = [kept[r.index].row for r in runs if r.index in kept]
        results.write_json(settings.out / "campaign.json", {**description, "state": "interrupted"}, [], rows)
        log.error(f"aspod campaign: interrupted: {len(kept)} of {len(runs)} runs done, their rows kept in "
                  f"{journal_path}; the rest: aspod campaign --resume {shlex.quote(str(settings.out))}")
        return EXIT_INTERRUPTED
    finally:
        if signal.getsignal(signal.SIGINT) is on_sigint:
            signal.signal(signal.SIGINT, previous)
    wall = RealClock.precise_now() - wall0
    rows_results = [kept[r.index] for r in runs]
    rows = [r.row for r in rows_results]
    rows_path = settings.out / f"rows.{settings.fmt}"
    results.write_rows(rows, rows_path, settings.fmt)
    figures = settings.figures or tuple(results.default_figures(rows))
    table = results.summary(rows, settings.group_by, figures)
    sim_s = sum(float(kept[r.index].row.get("sim_s") or 0.0) for r in todo)      # run now (not resumed ones)
    description["timing"] = {"wall_s": wall, "sim_s": sim_s, "sim_s_per_wall_s": sim_s / wall if wall > 0 else None,
                             "run_wall_s": [r.wall_s for r in rows_results]}
    results.write_json(settings.out / "campaign.json", {**description, "state": "done"}, table, rows)
    print(results.format_summary(table, settings.group_by))
    try:
        written = results.plot(rows, settings.out, settings.plots, settings.hists)
    except ValueError as exc:
        log.error(f"aspod campaign: {exc} (the rows are written)")
        written = []
    print(f"{len(todo)} runs in {wall:.1f} s ({sim_s:.0f} simulated s, {sim_s / max(wall, 1e-9):.1f} simulated s per "
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
    campaign.add_argument("bench", metavar="BENCH", nargs="?", help="a teleop script, or a pytest file or node "
                                                                    "(path.py, path.py::test_name)")
    campaign.add_argument("--resume", type=Path, default=None, metavar="DIR",
                          help="the campaign begun in DIR (stopped by Ctrl-C, say): run only the runs it lacks, with "
                               "its own command line (no other option with it)")
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


def resumed_args(folder: Path) -> argparse.Namespace:
    """The options of the campaign begun in `folder` (its campaign.json's command), to run the rest of it there.
    ValueError if the folder holds no campaign."""
    try:
        record = json.loads((folder / "campaign.json").read_text(encoding="utf-8"))
        argv = shlex.split(record["command"])[1:]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"--resume {folder}: no campaign begun there ({exc})") from None
    try:
        args = build_parser(["campaign"]).parse_args(argv)
    except SystemExit:
        raise ValueError(f"--resume {folder}: its campaign.json's command does not parse: {record['command']}") \
            from None
    args.out, args.argv, args.resuming = folder, tuple(argv), True
    return args


def run(args: argparse.Namespace) -> int:
    from host_tools.cli import settings
    if args.resume is not None:
        given = list(getattr(args, "argv", ()))
        given = given[given.index("campaign") + 1:] if "campaign" in given else []
        others = [a for a in given if a.startswith("-") and a != "--resume" and not a.startswith("--resume=")]
        if args.bench is not None or others:
            log.error("aspod campaign: --resume DIR runs the rest of the campaign begun there, with its own options: "
                      "nothing else with it")
            return EXIT_USAGE
        try:
            args = resumed_args(args.resume)
        except ValueError as exc:
            log.error(f"aspod campaign: {exc}")
            return EXIT_USAGE
    elif args.bench is None:
        log.error("aspod campaign: give a BENCH (a script or a pytest file or node), or --resume DIR")
        return EXIT_USAGE
    return run_campaign(settings.campaign_settings(args))
