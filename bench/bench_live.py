"""Real time that holds under load: live sessions on a busy machine, lock-step speed, a killed host.

Three measurements, each of real `aspod` subprocesses on real ptys (docs/realtime.md):

1. **A busy machine.** CPU hogs of the benchmark's own keep every core busy (one per core) while
   `aspod sim` runs and a scripted teleop session drives the demo's pick-and-place moves (the
   steps of `host_tools.apps.kinematics.steps`, coordinated as `aspod demo` does them), cycle after
   cycle, for the whole duration (10 minutes by default): in one process, then with the plant as
   a separate process in lock-step over udp_multicast (`--hal udp_multicast`). Figures: faults
   (the goal is 0), motions started and ended DONE, and the real-time factor: since start at the
   end (the mean) and the lowest one-second factor seen (`status` after every step).
2. **Lock-step speed.** The moving world (the arm jogging on two axes, the solar tracker's box
   on) at `--speed max` for the same wall time, in one process and as two processes in lock-step:
   simulated seconds per wall second of each, and their ratio.
3. **A killed host.** A teleop session enables the arm, pings, and is killed with SIGKILL; the
   time from the kill to the controller's latched safe state (its stderr line `-> FAULT
   (LINK_TIMEOUT)`), ten trials, against the 3 s link timeout; and, on the controller's clock,
   from the host's last Pong to the fault.
"""
from __future__ import annotations

import math
import os
import re
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

from host_tools.apps.kinematics import DEMO_SCENE, steps
from host_tools.worlds.child import Child, ChildError, run
from timebase import RealClock

ASPOD = [sys.executable, "-m", "host_tools.cli.main"]
REPO_ROOT = Path(__file__).resolve().parent.parent
START_TIMEOUT_S = 120.0
JOINT_SPEED_DPS = 3.0          # the report's 1/2 RPM, every joint's default speed limit
ARM_AXES = 6                   # `home all` starts one motion per axis (j1-j4, gripper, mount)


class LiveError(RuntimeError):
    """A process could not be started or reached: no figures."""


class Sim:
    """`aspod sim` as a child process (`Child`); its stderr lines kept with the wall time they were read."""

    def __init__(self, *args: str, home: Path) -> None:
        self.env = {**os.environ, "XDG_CONFIG_HOME": str(home / "config")}
        self.clock = RealClock()
        self.lines: list[tuple[float, str]] = []
        self._seen = threading.Condition()
        self.child = Child(["sim", "--pty", "--params", str(home / "params.json"), *args], env=self.env)
        self.child.follow_stderr(self._stderr_line)
        try:
            self.url = self.child.ready("ASPOD-LINK ", timeout_s=120.0).split(" ", 1)[1]
            self.child.ready("ASPOD-KEY ")
        except ChildError as exc:
            self.close()
            raise LiveError(f"{exc}; stderr: {self.stderr()}") from None

    def _stderr_line(self, text: str) -> None:
        with self._seen:
            self.lines.append((self.clock.now(), text))
            self._seen.notify_all()

    def stderr(self) -> str:
        return "\n".join(text for _, text in self.lines)

    def wait_line(self, pattern: str, after: int, timeout_s: float) -> Optional[tuple[float, re.Match]]:
        """The first stderr line from index `after` on matching `pattern`, with the wall time it was read."""
        deadline = self.clock.now() + timeout_s
        with self._seen:
            while True:
                for when, text in self.lines[after:]:
                    found = re.search(pattern, text)
                    if found:
                        return when, found
                left = deadline - self.clock.now()
                if left <= 0:
                    return None
                self._seen.wait(min(left, 0.5))

    def teleop(self, script: str, timeout_s: float = 3600.0) -> subprocess.CompletedProcess:
        return run(ASPOD + ["teleop", self.url, "--connect-timeout", "60", "--keep-going"], input=script.encode(),
                   env=self.env, timeout_s=timeout_s, cwd=REPO_ROOT, peers=(self.child.pid,))

    def close(self) -> None:
        self.child.stop(signal.SIGTERM, timeout_s=30.0)


class Hogs:
    """One busy-looping process per core, for as long as the `with` lasts."""

    def __enter__(self) -> "Hogs":
        self.procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(os.cpu_count() or 2)]
        return self

    def __exit__(self, *exc: object) -> None:
        for proc in self.procs:
            proc.kill()
            proc.wait()


# ---------------------------------------------------------------- 1. a busy machine

def demo_steps() -> list[str]:
    """The demo's steps as teleop scripts, one per step: coordinated joint moves (all end together) or a grip,
    then `wait all` and `status` (whose real-time factor is a sample)."""
    scripts = []
    cycle = steps(DEMO_SCENE)
    pose = {name: math.degrees(rad) for name, rad in cycle[-1].targets.items()}   # a cycle ends where it began
    for step in cycle:
        lines = []
        if step.action is not None:
            lines.append(f"grip {step.action}")
        else:
            targets = {name: math.degrees(rad) for name, rad in step.targets.items()}
            distances = {name: abs(deg - pose.get(name, 0.0)) for name, deg in targets.items()}
            longest = max(distances.values(), default=0.0)
            for name, deg in targets.items():
                speed = JOINT_SPEED_DPS * distances[name] / longest if longest > 0 else 0.0
                lines.append(f"move {name} {deg:.3f} {max(0.1, speed):.3f}" if speed > 0 else f"move {name} {deg:.3f}")
            pose.update(targets)
        scripts.append("\n".join(lines + ["wait all 600", "status"]) + "\n")
    return scripts


@dataclass
class BusyResult:
    mode: str
    duration_s: float = 0.0
    steps: int = 0
    started: int = 0
    done: int = 0
    not_done: list[str] = field(default_factory=list)
    faults: list[str] = field(default_factory=list)
    rtf_samples: list[float] = field(default_factory=list)
    rtf_total: float = math.nan
    failed_commands: int = 0
    error: str = ""


def busy_session(mode: str, sim_args: tuple[str, ...], duration_s: float) -> BusyResult:
    result = BusyResult(mode)
    clock = RealClock()
    with tempfile.TemporaryDirectory() as home, Hogs():
        try:
            sim = Sim(*sim_args, home=Path(home))
        except LiveError as exc:
            result.error = str(exc)
            return result
        try:
            start = clock.now()
            first = sim.teleop("enable\nhome all\nwait all 600\nstatus\n")
            outputs = [first.stdout.decode()]
            scripts = demo_steps()
            while clock.now() - start < duration_s:       # step by step, cycle after cycle, until the time is up
                done = sim.teleop(scripts[result.steps % len(scripts)])
                outputs.append(done.stdout.decode())
                result.steps += 1
            result.duration_s = clock.now() - start
            for out in outputs:
                result.started += len(re.findall(r"^ok   motion \w+#\d+ started", out, re.M))
                result.started += ARM_AXES * len(re.findall(r"^ok   motion all started", out, re.M))
                ends = re.findall(r"^! (\w+#\d+) (\w+) at ", out, re.M)
                result.done += sum(1 for _, outcome in ends if outcome == "DONE")
                result.not_done += [f"{label} {outcome}" for label, outcome in ends if outcome != "DONE"]
                result.failed_commands += len(re.findall(r"^FAIL ", out, re.M))
                result.rtf_samples += [float(v) for v in re.findall(r"rtf_recent=([\d.]+)", out)]
                totals = re.findall(r"rtf_total=([\d.]+)", out)
                if totals:
                    result.rtf_total = float(totals[-1])
        finally:
            sim.close()
        result.faults = [text for _, text in sim.lines if "-> FAULT" in text or "FAULT " in text]
    return result


# ---------------------------------------------------------------- 2. lock-step speed

@dataclass
class SpeedResult:
    mode: str
    rtf: float = math.nan
    error: str = ""


def world_speed(mode: str, sim_args: tuple[str, ...], run_s: float) -> SpeedResult:
    result = SpeedResult(mode)
    with tempfile.TemporaryDirectory() as home:
        try:
            sim = Sim("--speed", "max", *sim_args, home=Path(home))
        except LiveError as exc:
            result.error = str(exc)
            return result
        try:
            samples = 4
            moving = ("enable\njog j1 1\njog mount -1\nswitch main on\nswitch speed on\ndial 50\nwait 2\n"
                      + f"wait {run_s / samples:g}\nstatus\n" * samples)
            out = sim.teleop(moving).stdout.decode()
            found = [float(v) for v in re.findall(r"rtf_recent=([\d.]+)", out)]
            if len(found) == samples:
                result.rtf = statistics.fmean(found)
            else:
                result.error = f"{len(found)} of {samples} status replies: {out[-500:]}"
        finally:
            sim.close()
    return result


# ---------------------------------------------------------------- 3. a killed host

@dataclass
class KillResult:
    wall_s: list[float] = field(default_factory=list)          # kill -> the FAULT line read
    controller_s: list[float] = field(default_factory=list)    # last Pong -> FAULT, controller time
    link_timeout_s: float = 3.0
    error: str = ""


def killed_host(trials: int) -> KillResult:
    result = KillResult()
    clock = RealClock()
    with tempfile.TemporaryDirectory() as home:
        try:
            sim = Sim(home=Path(home))
        except LiveError as exc:
            result.error = str(exc)
            return result
        try:
            for _ in range(trials):
                host = subprocess.Popen(ASPOD + ["teleop", sim.url], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                        stderr=subprocess.DEVNULL, env=sim.env, cwd=REPO_ROOT)
                host.stdin.write(b"reset\nenable\nping\nwait 600\n")
                host.stdin.close()                               # a script is read whole before it runs
                pong = None
                for raw in host.stdout:
                    pong = re.search(rb"Pong token=0 uptime_ms=(\d+)", raw)
                    if pong:
                        break
                if pong is None:
                    host.kill()
                    result.error = "no Pong from the host"
                    return result
                mark = len(sim.lines)
                killed = clock.now()
                host.kill()
                host.wait()
                seen = sim.wait_line(r"uptime (\d+) ms: ENABLED -> FAULT \(LINK_TIMEOUT\)", mark, 30.0)
                if seen is None:
                    result.error = "no LINK_TIMEOUT within 30 s of the kill"
                    return result
                result.wall_s.append(seen[0] - killed)
                result.controller_s.append((int(seen[1].group(1)) - int(pong.group(1))) / 1000.0)
        finally:
            sim.close()
    return result


# ---------------------------------------------------------------- report

@dataclass
class LiveResults:
    busy: list[BusyResult] = field(default_factory=list)
    speed: list[SpeedResult] = field(default_factory=list)
    kill: Optional[KillResult] = None
    error: str = ""


def _print_busy(results: list[BusyResult], duration_s: float) -> None:
    print(f"busy machine: the demo's moves over a pty for {duration_s:g} s, with {os.cpu_count() or 2} CPU hogs "
          f"(one per core)")
    print(f"  {'mode':<26} {'steps':>6} {'motions':>8} {'DONE':>6} {'faults':>7} {'failed':>7} "
          f"{'RTF mean':>9} {'RTF min':>8}")
    for r in results:
        if r.error:
            print(f"  {r.mode:<26} ERROR: {r.error}")
            continue
        low = min(r.rtf_samples) if r.rtf_samples else math.nan
        print(f"  {r.mode:<26} {r.steps:>6} {r.started:>8} {r.done:>6} {len(r.faults):>7} {r.failed_commands:>7} "
              f"{r.rtf_total:>9.2f} {low:>8.2f}")
        for line in r.faults[:5] + r.not_done[:5]:
            print(f"    {line}")
    met = all(not r.error and not r.faults and r.done == r.started and not r.failed_commands for r in results)
    print(f"  goal: no fault, every motion DONE: {'met' if met else 'NOT met'}")


def _print_speed(results: list[SpeedResult], run_s: float) -> None:
    print(f"lock-step speed: the moving world at --speed max for {run_s:g} s (simulated s per wall s, mean of four "
          "one-second factors)")
    for r in results:
        print(f"  {r.mode:<34} {'ERROR: ' + r.error if r.error else f'{r.rtf:.2f}x real time'}")
    if len(results) == 2 and not any(r.error for r in results) and results[0].rtf > 0:
        print(f"  ratio, lock-step processes / one process: {results[1].rtf / results[0].rtf:.2f}")


def _print_kill(r: KillResult) -> None:
    print(f"killed host: SIGKILL to the latched safe state (LINK_TIMEOUT), {len(r.wall_s)} trials, link timeout "
          f"{r.link_timeout_s:g} s")
    if r.error:
        print(f"  ERROR: {r.error}")
    if r.wall_s:
        print(f"  from the kill (wall):              min {min(r.wall_s):.2f}  median {statistics.median(r.wall_s):.2f}"
              f"  max {max(r.wall_s):.2f} s")
        print(f"  from its last Pong (controller):   min {min(r.controller_s):.2f}  median "
              f"{statistics.median(r.controller_s):.2f}  max {max(r.controller_s):.2f} s")


def main(quick: bool = False, duration_s: Optional[float] = None) -> LiveResults:
    duration_s = duration_s if duration_s is not None else (60.0 if quick else 600.0)
    run_s = 5.0 if quick else 20.0
    out = LiveResults()
    out.busy = [busy_session("one process", (), duration_s),
                busy_session("lock-step, udp_multicast", ("--hal", "udp_multicast"), duration_s)]
    _print_busy(out.busy, duration_s)
    print()
    out.speed = [world_speed("one process", (), run_s),
                 world_speed("two processes in lock-step", ("--hal", "udp_multicast"), run_s)]
    _print_speed(out.speed, run_s)
    print()
    out.kill = killed_host(3 if quick else 10)
    _print_kill(out.kill)
    errors = [r.error for r in out.busy + out.speed if r.error] + ([out.kill.error] if out.kill.error else [])
    out.error = "; ".join(errors)
    return out


if __name__ == "__main__":
    sys.exit(1 if main(quick="--quick" in sys.argv).error else 0)
