"""`aspod fuzz`: protocol fuzzing (docs/fuzzing.md).

    aspod fuzz controller-link --time 60                  one in-process target, coverage-guided (atheris)
    aspod fuzz frames codec --runs 10000000 --jobs 8      a campaign: jobs split by seed, on Dask
    aspod fuzz --target-cmd 'aspod sim --pty --no-pacing' black-box against a target it starts (and restarts)
    aspod fuzz --url /dev/pts/5                           black-box against a running target (its key: found, or
                                                          --key-file)
    aspod fuzz --replay FINDING.json [--url ...]          one finding again, alone

In process (and replaying what it found) needs the `fuzz` extra (atheris; coverage for --coverage, Dask for jobs on
it); listing and black-box fuzzing need none: a missing extra is named, exit 2 (kernels/extras.py).

Exit status: 0 nothing found, 1 findings (or a replayed finding still fails), 2 bad usage or input.
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path
from typing import Optional

from host_tools.cli.options import baud_rate, bounded
from host_tools.cli.main import host_key
from host_tools.cli.settings import FuzzSettings
from host_tools.exit_codes import EXIT_FAILED, EXIT_LINK, EXIT_OK, EXIT_USAGE
from kernels.extras import require

log = logging.getLogger("aspod")


def run_fuzz(settings: FuzzSettings) -> int:
    if settings.mode == "list":
        from host_tools.fuzz.targets import builtin_targets
        for name, target in builtin_targets().items():
            print(f"{name:17} {target.about}")
        return EXIT_OK
    if settings.mode == "replay":
        return _replay(settings)
    if settings.mode == "blackbox":
        return _blackbox(settings)
    if settings.mode == "hostile":
        return _hostile(settings)
    return _inprocess(settings)


def _progress_bar(settings: FuzzSettings, total, unit: str):
    from host_tools.progress import on_terminal
    if not settings.progress or settings.as_json or not on_terminal(sys.stderr):     # a pipe or a log: none of it
        return None
    from tqdm import tqdm
    return tqdm(total=total, unit=unit, unit_scale=True, file=sys.stderr, dynamic_ncols=True)


def _inprocess(settings: FuzzSettings) -> int:
    from host_tools.fuzz.campaign import run_campaign, summarize
    from host_tools.fuzz.targets import load_target
    plan = settings.plan
    jobs = plan.jobs()
    engine = settings.engine
    on_dask = not (engine.serial or (len(jobs) == 1 and engine.scheduler is None))    # as run_campaign decides
    require("fuzz", "atheris", *(("coverage",) if settings.coverage else ()),
            *(("dask", "distributed") if on_dask else ()), what="fuzz")
    for name in plan.targets:
        load_target(name).close()            # an unknown target: refused before anything starts
    total = sum(j.runs for j in jobs) if plan.runs is not None else None
    bar = _progress_bar(settings, total, "exec")
    seen: dict[tuple, int] = {}

    def advance(target: str, seed: int, execs: int, said: str) -> None:
        if bar is not None:
            bar.update(max(0, execs - seen.get((target, seed), 0)))
            seen[(target, seed)] = execs
            bar.set_postfix_str(f"{target} {said}")

    def progress(p) -> None:
        advance(p.target, p.seed, p.execs, f"{p.execs / p.wall_s if p.wall_s else 0:,.0f} exec/s cov {p.cov}")

    def done(r) -> None:
        advance(r.target, r.seed, r.execs, f"done: {r.execs_per_s:,.0f} exec/s cov {r.cov}")
        for path in r.findings:
            log.error(f"aspod fuzz: {r.target}: finding {path}")
        if r.error:
            log.error(f"aspod fuzz: {r.target} (seed {r.seed}): {r.error}")

    results = run_campaign(plan, settings.engine, done, progress)
    if bar is not None:
        bar.close()
    summary = summarize(results)
    coverage = {}
    if settings.coverage:
        from host_tools.fuzz.coverage_report import line_coverage
        for s in summary:
            target = load_target(s.target)
            coverage[s.target] = line_coverage(s.target, plan.corpus(s.target),
                                               tuple(getattr(target, "covers", ())))
            target.close()
    if settings.as_json:
        print(json.dumps({"targets": [s.as_dict() for s in summary], "jobs": [r.as_dict() for r in results],
                          "coverage": coverage}, indent=1))
    else:
        print(f"{'target':17} {'jobs':>4} {'executions':>12} {'exec/s/core':>11} {'cov':>5} {'corpus':>6} findings")
        for s in summary:
            print(f"{s.target:17} {s.jobs:4} {s.execs:12,} {s.execs_per_core_s:11,.0f} {s.cov:5} {s.corpus:6} "
                  f"{s.findings}" + (f"  ({s.errors} jobs could not run)" if s.errors else ""))
            for name, figures in coverage.get(s.target, {}).items():
                print(f"    {name:36} {figures['percent']:5.1f} % of {figures['statements']} lines")
    if any(r.error for r in results) and not any(r.findings for r in results):
        return EXIT_USAGE if all(r.error for r in results) else EXIT_FAILED
    return EXIT_FAILED if any(r.findings for r in results) else EXIT_OK


def blackbox_key(settings: FuzzSettings) -> Optional[bytes]:
    """--key-file; else, against --url, the key of the local simulator serving it; with --target-cmd, None: each
    target started says its own (its ASPOD-KEY line)."""
    bb = settings.blackbox
    if settings.key_file is None and bb.command:
        return None
    return host_key(settings.key_file, bb.url)


def _blackbox(settings: FuzzSettings) -> int:
    from host_tools.fuzz.blackbox import BlackBoxFuzzer, TargetGone
    bb = settings.blackbox
    bar = _progress_bar(settings, bb.cases, "case")
    state = {"cases": 0}

    def on_case(r) -> None:
        if bar is not None:
            bar.update(r.cases - state["cases"])
            state["cases"] = r.cases
            bar.set_postfix_str(f"{r.cases_per_s:,.1f} cases/s, {len(r.findings)} findings")

    try:
        result = BlackBoxFuzzer(bb, blackbox_key(settings)).run(on_case)
    except TargetGone as exc:
        log.error(f"aspod fuzz: {exc}")
        return EXIT_LINK
    finally:
        if bar is not None:
            bar.close()
    for path in result.findings:
        log.error(f"aspod fuzz: finding {path}")
    figures = {"cases": result.cases, "steps": result.steps, "wall_s": round(result.wall_s, 2),
               "cases_per_s": round(result.cases_per_s, 2), "restarts": result.restarts, "findings": result.findings,
               "unsaved": len(result.unsaved), "params_put_back": result.params_put_back, "checks": result.checks,
               "repeats": result.repeats, "pinning_s": round(result.pinning_s, 2),
               "fuzzing_cases_per_s": round(result.fuzzing_cases_per_s, 2)}
    if settings.as_json:
        print(json.dumps(figures, indent=1))
    else:
        print(f"black-box: {result.cases} cases ({result.steps} steps) in {result.wall_s:.1f} s, "
              f"{result.cases_per_s:.1f} cases/s, {result.checks} health checks, {len(result.findings)} findings"
              + (f" ({result.repeats} found again, counted in their files)" if result.repeats else "")
              + (f", {len(result.unsaved)} not saved (on stderr)" if result.unsaved else "")
              + (f"; {result.params_put_back} parameters set back after the case that changed them"
                 if result.params_put_back else ""))
    return EXIT_FAILED if result.findings or result.unsaved else EXIT_OK


def _hostile(settings: FuzzSettings) -> int:
    """--as-controller: serve the line, attack the host (host_tools/fuzz/hostile.py)."""
    from host_tools.fuzz.hostile import fuzz_as_controller
    bar = _progress_bar(settings, settings.hostile.cases, "case")

    def on_case(r) -> None:
        if bar is not None:
            bar.update(r.cases - bar.n)
            bar.set_postfix_str(f"{r.cases_per_s:,.1f} cases/s, {r.sessions} sessions, {len(r.findings)} findings")

    try:
        result = fuzz_as_controller(settings.hostile, settings.key_file, on_case)
    finally:
        if bar is not None:
            bar.close()
    for path in result.findings:
        log.error(f"aspod fuzz: finding {path}")
    print(json.dumps(result.figures(), indent=1) if settings.as_json else result.describe())
    return EXIT_FAILED if result.findings or result.unsaved else EXIT_OK


def _replay(settings: FuzzSettings) -> int:
    from host_tools.fuzz import findings
    finding = findings.load(settings.replay)
    if (finding.target == "hostile") != (settings.hostile is not None):
        raise ValueError(f"{settings.replay} is a finding of " + ("a host attacked by --as-controller: replay it with "
                         "--as-controller --host-cmd ..." if finding.target == "hostile" else
                         f"{finding.target}, not of a host: replay it without --as-controller"))
    if finding.target == "hostile":
        from host_tools.fuzz.hostile import replay_as_controller
        failure = replay_as_controller(settings.hostile, settings.key_file, finding)
    elif finding.target == "blackbox":
        if settings.blackbox is None:
            raise ValueError(f"{settings.replay} is a black-box finding (against {finding.url}): "
                             "give --url or --target-cmd to replay it against")
        from host_tools.fuzz.blackbox import BlackBoxFuzzer
        failure = BlackBoxFuzzer(settings.blackbox, blackbox_key(settings)).replay(finding)
    else:
        require("fuzz", "atheris", what=f"fuzz --replay (an in-process finding, of {finding.target})")
        from host_tools.fuzz.targets import builtin_targets, load_target
        if finding.target not in builtin_targets() and finding.target != settings.replay_target:
            raise ValueError(f"{settings.replay} names the target {finding.target}, which a replay would import and "
                             f"run: name it after the file to say you trust it "
                             f"(aspod fuzz --replay {settings.replay} {finding.target})")
        failure = findings.replay(finding, lambda: load_target(finding.target), settings.hang_s)
    said = finding.failure.describe()
    if failure is None:
        print(f"{settings.replay}: no longer fails (it was: {said})")
        return EXIT_OK
    same = failure.signature == finding.failure.signature if finding.target not in ("blackbox", "hostile") else (
        failure.kind == finding.failure.kind)
    print(f"{settings.replay}: fails {'as found' if same else 'differently'}: {failure.describe()}")
    if failure.trace:
        print(failure.trace, file=sys.stderr)
    return EXIT_FAILED


# ---- the command line: its options, examples and run --------------------------------------------------------

EXAMPLES = [
    "aspod fuzz controller-link --time 60",
    "aspod fuzz frames codec teleop --runs 10000000 --jobs 8 --coverage",
    "aspod fuzz --target-cmd 'aspod sim --pty --no-pacing' --time 60",
    "aspod fuzz --url /dev/pts/5 --key-file link.key --only BoxDial --time 600",
    "aspod fuzz --replay fuzz-findings/crash-codec-0123456789ab.json",
    "aspod fuzz --as-controller --host-cmd 'aspod teleop {url} --key-file {key} --script s.txt' --time 60",
]


def add_options(fuzz: argparse.ArgumentParser) -> None:
    fuzz.add_argument("targets", nargs="*", metavar="TARGET",
                      help="in-process targets (--list names them), or module:factory for your own")
    fuzz.add_argument("--list", action="store_true", help="list the in-process targets and what each covers")
    fuzz.add_argument("--url", default=None, help="black-box: the link of a running target (pty, socket://, device)")
    fuzz.add_argument("--target-cmd", default=None, metavar="COMMAND",
                      help="black-box: start the target with COMMAND (it prints ASPOD-LINK URL, as aspod sim does); "
                           "it is restarted after a crash, and findings are shrunk on fresh targets")
    fuzz.add_argument("--key-file", type=Path, default=None,
                      help="the link's key (default: with --url, that of the local simulator serving it; with "
                           "--target-cmd, each target's own, from its ASPOD-KEY line)")
    fuzz.add_argument("--baud", type=baud_rate, default=115200, help="black-box: the line's rate (default 115200)")
    fuzz.add_argument("--replay", type=Path, default=None, metavar="FILE", help="run one finding again, alone")
    fuzz.add_argument("--time", type=bounded(float, 0.001, 30 * 86400), default=None, metavar="S",
                      help="seconds per job (in process) or in all (black-box); default 60 unless --runs/--cases")
    fuzz.add_argument("--runs", type=bounded(int, 1, 10**12), default=None, metavar="N",
                      help="in process: executions per job")
    fuzz.add_argument("--cases", type=bounded(int, 1, 10**9), default=None, metavar="N", help="black-box: cases")
    fuzz.add_argument("--hang-s", type=bounded(float, 0.01, 86400), default=None, metavar="S",
                      help="in process and --replay: an input past S seconds of its own time (the time the host kept "
                           "it waiting for a CPU does not count) is a hang (default 10); --as-controller: a host "
                           "silent on the link, or a probe unanswered, for S seconds of its own time")
    fuzz.add_argument("--check-every", type=bounded(int, 1, 1000), default=None, metavar="N",
                      help="black-box: a health check every N cases, sooner when the target's behaviour changes "
                           "(default 16 with --target-cmd, whose failures are pinned to their case on a fresh target; "
                           "1 with --url)")
    fuzz.add_argument("--max-findings", type=bounded(int, 1, 10**6), default=None, metavar="N",
                      help="black-box: stop after N findings (default: go on to --time or --cases)")
    fuzz.add_argument("--jobs", type=bounded(int, 1, 10000), default=1, metavar="N",
                      help="in process: jobs per target, each with its own seed, sharing the target's corpus")
    fuzz.add_argument("--seed", type=bounded(int, 1, 2**31 - 1), default=1, help="the first job's seed (default 1)")
    fuzz.add_argument("--corpus", type=Path, default=Path("fuzz-corpus"), metavar="DIR",
                      help="corpus folders, one per target, kept between runs (default fuzz-corpus)")
    fuzz.add_argument("--findings", type=Path, default=Path("fuzz-findings"), metavar="DIR",
                      help="where findings are written (default fuzz-findings)")
    fuzz.add_argument("--only", action="append", default=[], metavar="MESSAGE",
                      help="black-box: send only this command in sequence (repeatable)")
    fuzz.add_argument("--skip", action="append", default=None, metavar="MESSAGE",
                      help="black-box: never send this command (repeatable; default ParamSave)")
    fuzz.add_argument("--workers", type=bounded(int, 1, 1024), default=None, metavar="N",
                      help="in process: local Dask workers (default one per core)")
    fuzz.add_argument("--scheduler", default=None, metavar="tcp://HOST:8786", help="a running Dask scheduler")
    fuzz.add_argument("--serial", action="store_true", help="no Dask: the jobs one after the other, here")
    fuzz.add_argument("--coverage", action="store_true",
                      help="in process: afterwards, the line coverage each target's corpus reaches (coverage.py)")
    hostile = fuzz.add_argument_group("a ground tool attacked by a hostile controller (docs/fuzzing.md)")
    hostile.add_argument("--as-controller", action="store_true",
                         help="play a controller for a host to connect to (prints ASPOD-LINK and ASPOD-KEY as aspod "
                              "sim does) and answer it with mutated replies, telemetry, events, NAKs, stalls, floods")
    hostile.add_argument("--serve", default="pty", metavar="pty|tcp:PORT|DEVICE",
                         help="the line served: a new pty (default), a TCP port (tcp:0 picks one) or a serial device")
    hostile.add_argument("--host-cmd", default=None, metavar="COMMAND",
                         help="start the host with COMMAND, once per session ({url} and {key} put in); it fails if "
                              "it dies (a signal, a traceback, an exit status not --host-exit-ok) or goes silent")
    hostile.add_argument("--probe", default=None, metavar="COMMAND",
                         help="after each case run COMMAND ({url} and {key} put in): the host is healthy if it exits 0 "
                              "within --hang-s of its own time")
    hostile.add_argument("--host-exit-ok", action="append", type=bounded(int, 0, 255), default=None, metavar="N",
                         help="an exit status of the host that is not a crash (repeatable; default 0, 1, 3: aspod's "
                              "done, a command failed, the link failed)")
    fuzz.add_argument("--json", action="store_true", help="print one JSON object at the end")
    fuzz.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from host_tools.cli import settings
    return run_fuzz(settings.fuzz_settings(args))
