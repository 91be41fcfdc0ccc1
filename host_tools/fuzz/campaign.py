"""A fuzzing campaign: several targets, each split into jobs by seed, spread over cores and machines through the
campaign engine (host_tools/campaign/engine.py: Dask's scheduler, or this process alone).

Every job of a target shares the target's corpus folder (libFuzzer adds what is new; the next job starts from
all of it) and the campaign's findings folder. On other machines both must be on a shared file system, as a
pytest bench's files must (docs/campaigns.md). One job running alone, or `--serial`, runs here with live
progress; on Dask, progress comes as each job ends.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional

from host_tools.campaign.engine import EngineSettings, map_on_dask
from host_tools.fuzz.hangs import HANG_S
from host_tools.fuzz.inprocess import JobResult, JobSettings, Progress, run_job


@dataclass(frozen=True)
class CampaignPlan:
    targets: tuple[str, ...]
    jobs_per_target: int
    corpus_root: Path
    findings: Path
    seconds: Optional[float]          # per job
    runs: Optional[int]               # per job
    seed: int = 1
    hang_s: float = HANG_S            # an input's own time past which it is a hang

    def jobs(self) -> list[JobSettings]:
        if not 1 <= self.jobs_per_target <= 10000:
            raise ValueError(f"--jobs {self.jobs_per_target}: between 1 and 10000")
        return [JobSettings(target, self.corpus(target), self.findings, self.seconds, self.runs, self.seed + k,
                            hang_s=self.hang_s)
                for target in self.targets for k in range(self.jobs_per_target)]

    def corpus(self, target: str) -> Path:
        """The corpus folder of `target`, shared by its jobs."""
        return self.corpus_root / target.replace(":", "_").replace("/", "_")


def _job_task(_shared, job: JobSettings) -> JobResult:
    return run_job(job)


def _error_result(job: JobSettings, why: str) -> JobResult:
    return JobResult(job.target, job.seed, 0, 0.0, 0.0, 0, 0, 0, [], why)


def run_campaign(plan: CampaignPlan, engine: EngineSettings, on_done: Callable[[JobResult], None],
                 on_progress: Callable[[Progress], None] = lambda p: None,
                 on_started: Callable[[str], None] = lambda where: None) -> list[JobResult]:
    jobs = plan.jobs()
    if engine.serial or (len(jobs) == 1 and engine.scheduler is None):
        on_started("in this process" if engine.serial else "one job, in a child process")
        results = []
        for job in jobs:
            try:
                result = run_job(job, on_progress)
            except ValueError:
                raise
            except Exception as exc:          # noqa: BLE001 (the job's own failure is its row)
                result = _error_result(job, f"{type(exc).__name__}: {exc}")
            results.append(result)
            on_done(result)
        return results
    return map_on_dask(_job_task, jobs, engine, lambda index, result: on_done(result), _error_result,
                       on_started=on_started)


@dataclass
class TargetSummary:
    target: str
    jobs: int = 0
    execs: int = 0
    job_s: float = 0.0               # the jobs' wall times added up (core-seconds)
    cov: int = 0
    ft: int = 0
    corpus: int = 0
    findings: int = 0
    errors: int = 0

    @property
    def execs_per_core_s(self) -> float:
        return self.execs / self.job_s if self.job_s > 0 else 0.0

    def as_dict(self) -> dict:
        return {**dataclasses.asdict(self), "execs_per_core_s": round(self.execs_per_core_s, 1)}


def summarize(results: list[JobResult]) -> list[TargetSummary]:
    by_target: dict[str, TargetSummary] = {}
    for r in results:
        s = by_target.setdefault(r.target, TargetSummary(r.target))
        s.jobs += 1
        s.execs += r.execs
        s.job_s += r.wall_s
        s.cov, s.ft, s.corpus = max(s.cov, r.cov), max(s.ft, r.ft), max(s.corpus, r.corpus)
        s.findings += len(r.findings)
        s.errors += bool(r.error)
    return list(by_target.values())
