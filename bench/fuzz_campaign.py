"""The long in-process fuzzing campaign (issue 15: at least 10^7 executions per target), run in chunks that
survive being stopped.

    python -m bench.fuzz_campaign DIR [--goal 10000000] [--chunk 1000000] [--jobs 2] [--targets a,b]
                                      [--ledger FILE] [--first-seed N] [--since REV]
    python -m bench.fuzz_campaign DIR --report [--since REV] [--targets a,b]   # the totals, each line coverage

Each chunk is one `aspod fuzz TARGET --runs CHUNK/JOBS --jobs JOBS` with seeds of its own; its jobs are
appended to DIR/ledger.jsonl when it ends, with the commit they ran. A chunk stopped half-way counts for
nothing, and the next start goes on from the ledger. The ledger defaults to DIR/ledger.jsonl; the campaign of
record keeps it in the repository (`--ledger bench/fuzz_campaign_ledger.jsonl`), since a machine's folders do
not outlive it. The targets share DIR/corpus (one folder each) and
DIR/findings, so the campaign's coverage grows across chunks as a single run's would. The children run at
the lowest priority (nice 19): the campaign uses what the machine does not. `--since REV` counts (and reports)
only the chunks that ran at REV or a commit after it: a harness mended at REV starts its targets' count afresh
(02afed8: controller-link, host-link and hal had run with their code under test uninstrumented).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from dataclasses import fields
from pathlib import Path
from typing import Optional

from host_tools.fuzz.campaign import summarize
from host_tools.fuzz.inprocess import JobResult

ROOT = Path(__file__).resolve().parents[1]
TARGETS = ("codec", "frames", "hal", "teleop", "key-file", "controller-link", "params-file", "host-link")


def _commit() -> str:
    out = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    return out.stdout.strip() or "unknown"


def read_ledger(path: Path) -> list[JobResult]:
    """The jobs of every chunk that ended (each row a `JobResult` and the commit it ran)."""
    if not path.exists():
        return []
    names = {f.name for f in fields(JobResult)}
    return [JobResult(**{k: v for k, v in json.loads(line).items() if k in names})
            for line in path.read_text().splitlines() if line.strip()]


def since(jobs: list[JobResult], commits: list[str], rev: str) -> list[JobResult]:
    """The jobs whose commit (`commits`, row by row) is `rev` or comes after it (git: `rev` is its ancestor)."""
    def after(commit: str) -> bool:
        return subprocess.run(["git", "-C", str(ROOT), "merge-base", "--is-ancestor", rev, commit],
                              capture_output=True).returncode == 0
    verdicts = {c: after(c) for c in set(commits)}
    return [job for job, commit in zip(jobs, commits) if verdicts[commit]]


def ledger_commits(path: Path) -> list[str]:
    """The commit of each row of the ledger, in order."""
    if not path.exists():
        return []
    return [json.loads(line).get("commit", "unknown") for line in path.read_text().splitlines() if line.strip()]


def next_seed(jobs: list[JobResult], target: str, first: int = 1) -> int:
    """A seed no job of `target` in the ledger has used, and at least `first` (a ledger begun anew after one
    was lost starts past the old one's seeds, so it does not rerun their inputs)."""
    return max([first - 1] + [j.seed for j in jobs if j.target == target]) + 1


def run_chunk(target: str, runs_per_job: int, jobs: int, seed: int, out: Path) -> list[dict]:
    """One chunk: `aspod fuzz` as a child at nice 19; its jobs' rows, or none if it did not finish."""
    cmd = [sys.executable, "-m", "host_tools.cli.main", "fuzz", target, "--runs", str(runs_per_job),
           "--jobs", str(jobs), "--workers", str(jobs), "--seed", str(seed), "--json", "--no-progress",
           "--corpus", str(out / "corpus"), "--findings", str(out / "findings")]
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, preexec_fn=lambda: os.nice(19),
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    if done.returncode not in (0, 1):           # 1: findings (they are in the rows); anything else: no chunk
        print(f"{target} seed {seed}: exit {done.returncode}: {done.stderr.strip()[-400:]}", file=sys.stderr)
        return []
    return json.loads(done.stdout)["jobs"]


def counted(ledger: Path, rev: Optional[str]) -> list[JobResult]:
    """The ledger's jobs that count: all of them, or those at `rev` and after."""
    jobs = read_ledger(ledger)
    return jobs if rev is None else since(jobs, ledger_commits(ledger), rev)


def report(out: Path, ledger: Path, rev: Optional[str], targets: list[str]) -> None:
    from host_tools.fuzz.coverage_report import line_coverage
    from host_tools.fuzz.targets import builtin_targets
    print(f"{'target':16} {'executions':>12} {'core-h':>7} {'exec/core-s':>11} {'findings':>8} {'errors':>6}  coverage")
    for t in summarize(counted(ledger, rev)):
        if t.target not in targets:
            continue
        corpus = out / "corpus" / t.target
        if corpus.is_dir():
            cov = line_coverage(t.target, corpus, builtin_targets()[t.target].covers)
            said = ", ".join(f"{file} {c['percent']}%" for file, c in cov.items())
        else:       # the ledger is the repository's; the corpus is the folder's, and may not be on this machine
            said = f"not measured: no corpus at {corpus}"
        print(f"{t.target:16} {t.execs:>12,} {t.job_s / 3600:>7.2f} {t.execs_per_core_s:>11,.0f} "
              f"{t.findings:>8} {t.errors:>6}  {said}")


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.fuzz_campaign", description=__doc__.split("\n\n")[0])
    ap.add_argument("dir", type=Path)
    ap.add_argument("--goal", type=int, default=10_000_000, help="executions per target")
    ap.add_argument("--chunk", type=int, default=1_000_000, help="executions per chunk (all its jobs)")
    ap.add_argument("--jobs", type=int, default=2, help="jobs per chunk, one per core")
    ap.add_argument("--targets", default=",".join(TARGETS))
    ap.add_argument("--ledger", type=Path, help="the ledger file (default DIR/ledger.jsonl)")
    ap.add_argument("--first-seed", type=int, default=1, help="the lowest seed a new chunk may take")
    ap.add_argument("--since", metavar="REV", help="count only the chunks run at REV or after it")
    ap.add_argument("--report", action="store_true", help="print the totals and coverage (of --targets), run nothing")
    args = ap.parse_args(argv)
    ledger = args.ledger or args.dir / "ledger.jsonl"
    if args.since is not None:
        known = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--verify", "--quiet", args.since + "^{commit}"],
                               capture_output=True)
        if known.returncode != 0:
            ap.error(f"--since {args.since}: not a commit of this repository")
    targets = args.targets.split(",")
    unknown = [t for t in targets if t not in TARGETS]
    if unknown:
        ap.error(f"--targets: no target named {', '.join(unknown)}; the targets are {', '.join(TARGETS)}")
    args.dir.mkdir(parents=True, exist_ok=True)
    if args.report:
        report(args.dir, ledger, args.since, targets)
        return 0
    commit = _commit()
    for target in targets:
        while True:
            jobs = read_ledger(ledger)
            done = sum(j.execs for j in counted(ledger, args.since) if j.target == target)
            if done >= args.goal:
                break
            rows = run_chunk(target, args.chunk // args.jobs, args.jobs, next_seed(jobs, target, args.first_seed), args.dir)
            if not rows:
                return 1
            with ledger.open("a") as f:
                for row in rows:
                    f.write(json.dumps({**row, "commit": commit}) + "\n")
            print(f"{target}: {done + sum(r['execs'] for r in rows):,} executions", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
