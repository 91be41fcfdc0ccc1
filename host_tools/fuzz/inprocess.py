"""In-process fuzzing jobs: atheris in a child process (host_tools/fuzz/child.py), watched from here.

A job is one target, one seed, a budget of seconds or executions, a corpus folder it reads and adds to, and a
findings folder. `run_job` starts the child, turns its lines into `Progress`, and at the end minimizes what it
found (host_tools/fuzz/findings.py) and says what it ran: executions, executions per second, coverage (libFuzzer's
count of edges, `cov`, and features, `ft`), corpus size, findings.

A hang is an input past `hang_s` of its own time (host_tools/fuzz/hangs.py: the time the host kept it waiting
for a CPU does not count); the child interrupts it and saves it as any other finding, but it is not minimized
(every try would take `hang_s`). Running out of memory, or a hang past libFuzzer's wall-clock backstop, ends the
child without our harness seeing it; its artifact (the one input) becomes the finding, and for a stateful target
the file says that the inputs before it are not known.
"""
from __future__ import annotations

import os
import re
import subprocess
import sys

from timebase import RealClock

from collections import deque
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable, Optional

from host_tools.fuzz import findings as findings_mod
from host_tools.fuzz.hangs import HANG_S, backstop_s
from host_tools.fuzz.targets import load_target

_CLOCK = RealClock()           # the wall clock (timebase: the one module that reads it)

MAX_LEN = 4096                 # bytes of one fuzz input
RSS_LIMIT_MB = 2048
_STATUS = re.compile(r"^#(\d+)\s+\w+\s+cov: (\d+) ft: (\d+) corp: (\d+)/")
_ARTIFACT = re.compile(r"Test unit written to (\S+)")


@dataclass(frozen=True)
class JobSettings:
    target: str
    corpus: Path
    findings: Path
    seconds: Optional[float] = 60.0        # None: until `runs`
    runs: Optional[int] = None             # executions (None: until `seconds`)
    seed: int = 1
    minimize_s: float = 60.0
    hang_s: float = HANG_S                 # an input's own time past which it is a hang

    def __post_init__(self) -> None:
        if not 0 < self.hang_s <= 86400:
            raise ValueError(f"--hang-s {self.hang_s}: between 0 and a day of seconds")
        if self.seconds is None and self.runs is None:
            raise ValueError("a fuzzing job needs a time (--time) or a number of executions (--runs)")
        if self.seconds is not None and not 0 < self.seconds <= 30 * 86400:
            raise ValueError(f"--time {self.seconds}: between 0 and 30 days of seconds")
        if self.runs is not None and not 1 <= self.runs <= 10**12:
            raise ValueError(f"--runs {self.runs}: between 1 and 10^12")
        if not 1 <= self.seed < 2**31:
            raise ValueError(f"seed {self.seed}: between 1 and 2^31 - 1 (libFuzzer takes 0 as 'pick one')")


@dataclass
class Progress:
    target: str
    seed: int
    execs: int = 0
    cov: int = 0
    ft: int = 0
    corpus: int = 0
    wall_s: float = 0.0


@dataclass
class JobResult:
    target: str
    seed: int
    execs: int
    wall_s: float
    execs_per_s: float
    cov: int
    ft: int
    corpus: int
    findings: list[str] = field(default_factory=list)
    error: str = ""                      # the job could not run as asked (not a finding)

    def as_dict(self) -> dict:
        return asdict(self)


def child_command(settings: JobSettings) -> list[str]:
    settings.corpus.mkdir(parents=True, exist_ok=True)
    settings.findings.mkdir(parents=True, exist_ok=True)
    backstop = backstop_s(settings.hang_s)     # libFuzzer's wall-clock timeout, behind the child's own watch
    args = [sys.executable, "-m", "host_tools.fuzz.child", settings.target, str(settings.findings),
            repr(settings.hang_s), f"-seed={settings.seed}", f"-max_len={MAX_LEN}", f"-timeout={backstop}",
            f"-report_slow_units={backstop}", f"-rss_limit_mb={RSS_LIMIT_MB}", "-print_final_stats=1",
            f"-artifact_prefix={settings.findings}{os.sep}"]
    if settings.seconds is not None:
        args.append(f"-max_total_time={max(1, int(round(settings.seconds)))}")
    if settings.runs is not None:
        args.append(f"-runs={settings.runs}")
    return args + [str(settings.corpus)]


def run_job(settings: JobSettings, on_progress: Callable[[Progress], None] = lambda p: None) -> JobResult:
    """Run one job to its end; its findings minimized and saved."""
    load_target(settings.target).close()          # a bad target name fails here, with its reason
    start = _CLOCK.now()
    progress = Progress(settings.target, settings.seed)
    tail: deque[str] = deque(maxlen=40)
    found: list[Path] = []
    artifacts: list[tuple[str, Path]] = []
    copies: list[tuple[str, Path]] = []          # libFuzzer's crash-* file of an input the harness saved itself
    stats: dict[str, str] = {}
    kind = ""
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    with subprocess.Popen(child_command(settings), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                          errors="replace", env=env) as child:
        for line in child.stderr:
            line = line.rstrip("\n")
            tail.append(line)
            if line.startswith("ASPOD-PROGRESS "):
                progress.execs = int(line.split()[1])
            elif line.startswith("ASPOD-FINDING "):
                found.append(Path(line.split(" ", 1)[1]))
            elif (match := _STATUS.match(line)) is not None:
                progress.execs, progress.cov, progress.ft, progress.corpus = (int(g) for g in match.groups())
            elif line.startswith("stat::"):
                key, _, value = line.partition(":")[2].partition(":")
                stats[key.strip()] = value.strip()
            elif "ERROR: libFuzzer: timeout" in line:
                kind = "hang"
            elif "ERROR: libFuzzer: out-of-memory" in line:
                kind = "out-of-memory"
            elif (match := _ARTIFACT.search(line)) is not None:
                (artifacts if kind else copies).append((kind, Path(match.group(1))))
            else:
                continue
            progress.wall_s = _CLOCK.now() - start
            on_progress(progress)
    wall = _CLOCK.now() - start
    execs = int(stats.get("number_of_executed_units", progress.execs) or 0)
    result = JobResult(settings.target, settings.seed, execs, wall, execs / wall if wall > 0 else 0.0,
                       progress.cov, progress.ft, progress.corpus)
    if child.returncode != 0 and not found and not artifacts:
        result.error = f"the fuzzing child exited with status {child.returncode}: " + " | ".join(list(tail)[-6:])
    for path in found:
        result.findings.append(str(_minimized(path, settings)))
    for _, copy in copies if found else ():
        copy.unlink(missing_ok=True)             # its input is the finding's last, with those before it
    for what, path in artifacts:
        result.findings.append(str(_artifact_finding(what, path, settings, execs)))
    return result


def _minimized(path: Path, settings: JobSettings) -> Path:
    """The child's finding minimized and saved, or, if its bug is in the folder already (its signature), counted
    in that file and this one removed."""
    finding = findings_mod.load(path)
    known = findings_mod.Known(settings.findings, leave_out=path)
    if (counted := known.count(finding)) is not None:
        path.unlink(missing_ok=True)
        return counted
    if finding.failure.kind == "hang":
        return path                  # each try would run until the bound: kept as found
    smaller = findings_mod.minimize(finding, lambda: load_target(settings.target), settings.minimize_s)
    if smaller is finding:
        return path
    new_path = smaller.save(settings.findings)
    if new_path != path:
        path.unlink(missing_ok=True)
    return new_path


def _artifact_finding(kind: str, artifact: Path, settings: JobSettings, execs: int) -> Path:
    data = artifact.read_bytes() if artifact.is_file() else b""
    note = (f"one input ran longer than {backstop_s(settings.hang_s)} s of wall time (libFuzzer's backstop)"
            if kind == "hang" else f"past {RSS_LIMIT_MB} MB")
    if getattr(load_target(settings.target), "stateful", False):
        note += "; the target keeps a world between inputs, and the inputs before this one are not known"
    finding = findings_mod.Finding(settings.target, findings_mod.Failure(kind, note), [data], execs=execs)
    path = finding.save(settings.findings)
    artifact.unlink(missing_ok=True)
    return path
