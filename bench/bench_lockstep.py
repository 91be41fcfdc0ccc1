"""Lock-step speed: simulated seconds per wall second of the whole world at 1 kHz, beside its parts.

The goal: simulated seconds per wall second with every motor channel and the loops at 1 kHz,
at least 20x real time on a 2-core machine (PX4's lock-step SITL reaches 6-10x on desktops;
ArduPilot's autotest runs at 8x by default). The world has eight motor
channels: the arm's six at 1 kHz (J1-J4, gripper, mount) and the solar tracker's two 90 VDC
motors (azimuth, elevation), whose relay logic runs at 100 Hz (the DBC's 10 ms cycle).

Rows, all in this process, each on its own `SimClock` (a simulated hour costs only the work
done in it):

* **world, all moving** (the figure the goal is about): a `host_tools.worlds.world.LockstepBench`
  as tests and `aspod demo` build it (plant, controller and a `HostLink` over the in-memory
  line, 115200 baud paced, every loop at 1 kHz, no stopwatch on the simulated clock),
  connected, telemetry at 10 Hz, enabled; every 2.5 simulated seconds the host sends, through
  the protocol, a Jog to each of J1-J4 and the mount (signed speeds within the 3 deg/s limit,
  the sign flipping each time) and a Grip (close, then open); the tracker's control box is in
  manual mode with both dials at 50 %, and at each segment the host turns the dials low, flips
  the direction switch and turns them up again (changing direction needs the dial low): all
  eight channels driven.
* **the same world, code before issue 12**: the first row as the code of commit 2d3728d runs it
  (packed CAN frames between the in-process nodes, the arm plant as per-concept classes, a
  stopwatch read around every task on the simulated clock), in a child process built from that
  commit's tree (`git archive` from this clone's history; bench/world_child.py drives it), so
  the old and the new code meet the same machine in the same run. Its final joint angles are
  compared with the first row's, to the bit.
* **the same world, kernels as plain Python**: the first row runs the compiled kernels
  (kernels/__init__.py: the joints' tick and the arm plant's tick compiled by numba) when numba is
  installed; this one runs the same functions as plain Python. Its final joint angles are
  compared with the first row's, to the bit. (Without numba there is no such row: the first row is
  plain Python, and the report says so.)
* **the same world, compiled, tick by tick**: the first row without the fast loop
  (host_tools/worlds/fast_loop.py): its three 1 kHz tasks run a tick at a time, as the plain world's
  do. Its final joint angles are compared with the first row's, to the bit.
* **world, holding**: the same world, connected and enabled, no motion commands (the loops
  hold every joint where it is; the control box stays off).
* **world, all moving, timed per task**: the first row again, with the scheduler's stopwatch
  replaced by `RealClock.precise_now` after set-up, so the scheduler's own statistics
  (`TaskStats.exec_total_s`) give the wall time of each task: the per-task split below. The
  stopwatch adds two clock reads per task run; its figure beside the first row's shows that cost.
* **plant alone**: `hil_sim.hal_node.PlantNode` with its `Plant` stepping at 1 kHz (the
  tracker's part at 100 Hz) on the world's kind of in-process python-can bus that nobody else joins (no controller: its channels are not driven).
* **plant alone, driven**: the same, with a second 1 kHz task that writes a command into the
  plant's command holders before each step (duty 0.3 on the arm's six channels, open loop, its
  sign flipping every 0.5 s): the plant's physics with every motor driven, still without a
  controller or a second bus end.
* **bare scheduler**: the same `Scheduler` with one empty 1 kHz task: its own overhead.

The rows take turns (4 rounds of 5 simulated seconds each, 1 round with --quick), so load
from the rest of the machine falls on them alike; the CPU that other processes used during
each row is printed beside it (`bench.bench_realtime.CpuMeter`). Wall time is
`RealClock.precise_now()` around each row's turn; the simulated time is exact. Given the
seed, every row simulates exactly the same thing on every run; only the wall times move.

Then the first two rows again with one process spinning on a core the whole time (the issue's
"another process using a core"), and the moving world in one and in two child processes at once:
the simulated seconds per wall second summed over them, a campaign's throughput.
"""
from __future__ import annotations

import importlib.util
import io
import json
import math
import os
import subprocess
import sys
import tarfile
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Optional

import numpy as np

import kernels
from bench.bench_realtime import CpuMeter
from timebase.scheduler import Scheduler
from host_tools.worlds.local_bus import LocalBus, LocalChannel
from host_tools.worlds.nodes import build_plant_node
from host_tools.worlds.world import LockstepBench
from protocol.messages import MESSAGES as M
from protocol.states import Axis, ControllerState, GripAction, Switch, SwitchPosition, TrackerAxis
from timebase import RealClock, SimClock


FULL_S = 20.0                  # simulated seconds per row
QUICK_S = 5.0
FULL_ROUNDS = 4                # rows take turns this many times
QUICK_ROUNDS = 1
SEGMENT_S = 2.5                # the host sends a new set of motion commands this often (simulated)
TELEMETRY_HZ = 10
SEED = 0
PERIOD_S = 0.001               # every loop of the world: 1 kHz
GOAL_X = 100.0                 # issue 35's goal: the moving world compiled at least 100x real time (a quiet machine)
PX4_X = (6.0, 10.0)            # PX4 lock-step SITL on desktops
ARDUPILOT_X = 8.0              # ArduPilot autotest's default speed-up
ARM_CHANNELS = 6               # J1-J4, gripper, mount: 1 kHz
TRACKER_CHANNELS = 2           # the solar tracker's azimuth and elevation motors: 100 Hz
TRACKER_DIAL_PCT = 50.0        # the moving world's dials (manual mode: about 17 deg/min)
# Jog speeds [deg/s], inside the joints' 3 deg/s limit; different so no two joints move alike.
JOG_DPS = {Axis.J1: 1.0, Axis.J2: 2.0, Axis.J3: 2.5, Axis.J4: 3.0, Axis.MOUNT: 1.5}
DRIVE_DUTY = 0.3               # the driven plant row: this duty on every channel, open loop,
DRIVE_FLIP_S = 0.5             # its sign flipping this often


# The tick path before issue 12 made it faster (packed CAN frames between the in-process nodes,
# the arm plant as per-concept classes, the scheduler's stopwatch on the simulated clock): measured
# in the same run, from its own tree (`git archive`), in a child process.
BEFORE_COMMIT = "2d3728d"
# The code before issue 35 (the joints' and the plant's ticks written twice, the world tick by tick), compiled as the
# first row is.
BEFORE_35_COMMIT = "8e4c122"
BEFORE_35_LABEL = f"the same world, code before issue 35 ({BEFORE_35_COMMIT})"
REPO = Path(__file__).resolve().parent.parent
CHILD_SCRIPT = Path(__file__).resolve().parent / "world_child.py"


class BenchSetupError(RuntimeError):
    """A row could not be built or did not do what it should: no figures for it."""


# ---------------------------------------------------------------- the rows

class Row:
    """One contender: `advance(duration_s)` runs it that long in simulated time (timed by the caller)."""

    label = ""

    def advance(self, duration_s: float) -> None:
        raise NotImplementedError

    def check(self) -> str:
        """After the run: '' if the row did what it should, else what went wrong."""
        return ""

    def close(self) -> None:
        pass


class WorldRow(Row):
    """A LockstepBench, connected, telemetry at 10 Hz, enabled; moving or holding."""

    def __init__(self, label: str, moving: bool, timed_tasks: bool, seed: int = SEED,
                 compiled: Optional[bool] = None, fast_loop: bool = True) -> None:
        self.label = label
        self.moving = moving
        with kernels.switched(compiled):      # None: as the environment says (a child world's parent sets it)
            self.bench = LockstepBench(seed=seed, fast_loop=fast_loop)
        self.handles: list = []
        self.segments = 0
        self.not_driven: list[str] = []      # segment ends at which some channel was not driven
        self._sign = 1
        b = self.bench
        if not b.connect():
            raise BenchSetupError(f"{label}: the host did not connect")
        for msg in (M["SetTelemetryRate"](TELEMETRY_HZ), M["Enable"]()):
            handle = b.call(msg)
            if not handle.ok:
                raise BenchSetupError(f"{label}: {msg.spec.name}: {handle.describe()}")
        self.scheduler = b.world.scheduler
        if timed_tasks:
            # the lock-step world times tasks with the simulated clock (deterministic bytes); time them for real
            self.scheduler._stopwatch = RealClock.precise_now
        if moving:
            for msg in self._box_setup():
                handle = b.call(msg)
                if not handle.ok:
                    raise BenchSetupError(f"{label}: {msg.spec.name}: {handle.describe()}")
        self.stats_before = self._stats()
        self.telemetry_before = len(b.telemetry)

    @staticmethod
    def _box_setup() -> list:
        """The control box as the operating instructions start it: dials low, manual, CW, main on, speed on, dials up."""
        both = int(TrackerAxis.BOTH)
        switch = M["BoxSwitch"]
        return [M["BoxDial"](0.0, both), switch(int(Switch.MODE), int(SwitchPosition.MANUAL), both),
                switch(int(Switch.DIRECTION), int(SwitchPosition.CW), both),
                switch(int(Switch.MAIN), int(SwitchPosition.ON), both),
                switch(int(Switch.SPEED), int(SwitchPosition.ON), both), M["BoxDial"](TRACKER_DIAL_PCT, both)]

    def _box_reverse(self) -> list:
        """Dials low, the direction switch flipped, dials up again (changing direction needs the dial low)."""
        both = int(TrackerAxis.BOTH)
        direction = SwitchPosition.CW if self._sign > 0 else SwitchPosition.CCW
        return [M["BoxDial"](0.0, both), M["BoxSwitch"](int(Switch.DIRECTION), int(direction), both),
                M["BoxDial"](TRACKER_DIAL_PCT, both)]

    def _stats(self) -> dict[str, tuple[int, float]]:
        return {n: (t.stats.runs, t.stats.exec_total_s) for n, t in self.scheduler.tasks.items()}

    def advance(self, duration_s: float) -> None:
        b = self.bench
        if not self.moving:
            b.run_for(duration_s)
            return
        for _ in range(max(1, round(duration_s / SEGMENT_S))):
            now = b.clock.now()
            for axis, dps in JOG_DPS.items():
                self.handles.append(b.host.submit(M["Jog"](int(axis), self._sign * dps), now))
            action = GripAction.CLOSE if self._sign > 0 else GripAction.OPEN
            self.handles.append(b.host.submit(M["Grip"](int(action)), now))
            for msg in self._box_reverse():
                self.handles.append(b.host.submit(msg, now))
            self._sign = -self._sign
            b.run_for(SEGMENT_S)
            self.segments += 1
            plant = b.world.plant
            driven = list(plant.channel_driven) + [any(pair) for pair in plant.tracker.relay_closed]
            if not all(driven):
                self.not_driven.append(f"t={b.clock.now():.1f} s: {driven}")

    def check(self) -> str:
        b = self.bench
        sup = b.controller.supervisor
        problems = []
        if sup.state is not ControllerState.ENABLED:
            problems.append(f"controller {sup.state.name} ({sup.safe_reason.name}, faults {sup.faults!r})")
        bad = [h.describe() for h in self.handles if not (h.done and h.ok)]
        if bad:
            problems.append(f"{len(bad)} of {len(self.handles)} commands not ok: {bad[0]}")
        if self.not_driven:
            problems.append(f"not every channel driven at {len(self.not_driven)} of {self.segments} segment ends: "
                            f"{self.not_driven[0]}")
        return "; ".join(problems)

    def task_split(self) -> dict[str, tuple[int, float]]:
        """Runs and execution seconds per task since set-up."""
        after = self._stats()
        return {n: (runs - self.stats_before.get(n, (0, 0.0))[0], total - self.stats_before.get(n, (0, 0.0))[1])
                for n, (runs, total) in after.items()}

    def telemetry_frames(self) -> int:
        return len(self.bench.telemetry) - self.telemetry_before

    def close(self) -> None:
        self.bench.close()


def tree_of_commit(commit: str, into: Path) -> Path:
    """This project's files at `commit`, written under `into` (from this clone's history)."""
    done = subprocess.run(["git", "-C", str(REPO), "archive", "--format=tar", commit], capture_output=True)
    if done.returncode != 0:
        raise BenchSetupError(f"commit {commit} is not in this clone's history: "
                              f"{done.stderr.decode(errors='replace').strip()}")
    with tarfile.open(fileobj=io.BytesIO(done.stdout)) as tar:
        tar.extractall(into, filter="data")
    return into


class ChildWorld:
    """The moving world in a process of its own (bench/world_child.py), built from the tree `tree`."""

    def __init__(self, tree: Path, seed: int = SEED, compiled: bool = False) -> None:
        env = {**os.environ, "PYTHONPATH": str(tree), kernels.ENVIRONMENT_SWITCH: "1" if compiled else "0"}
        self.proc = subprocess.Popen([sys.executable, str(CHILD_SCRIPT), str(seed)], cwd=tree, env=env,
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        if self._line() != "ready":
            raise BenchSetupError(f"the world in a child process did not start (exit {self.proc.wait()})")

    def _line(self) -> str:
        assert self.proc.stdout is not None
        return self.proc.stdout.readline().strip()

    def advance(self, duration_s: float) -> float:
        """Run `duration_s` simulated seconds there; the wall seconds it took, as the child measured them."""
        assert self.proc.stdin is not None
        self.proc.stdin.write(f"{duration_s!r}\n")
        self.proc.stdin.flush()
        answer = self._line()
        try:
            return float(answer)
        except ValueError:
            raise BenchSetupError(f"the world in a child process stopped (exit {self.proc.wait()})") from None

    def finish(self) -> dict:
        """End the child: its check ('' if the world did what it should) and the arm's final angles."""
        try:
            out, _ = self.proc.communicate("end\n", timeout=60)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
            return {"error": "the world in a child process did not end", "pos_rad": []}
        try:
            return json.loads(out.strip().splitlines()[-1])
        except (ValueError, IndexError):
            return {"error": f"the world in a child process ended without its result (exit {self.proc.returncode})",
                    "pos_rad": []}

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


class LimitRow(Row):
    """The limit: the moving world's two kernels and nothing else, all ticks in one call (bench/limit_kernel.py).

    Built as the first row's world (connected, enabled, the control box on), given one segment's jogs and run a
    tenth of a simulated second so every joint moves; then the joints' and the plant's rows of that world are
    stepped by `limit_ticks`, a row's whole turn in one call, plain or compiled as the world's kernels are."""

    def __init__(self, label: str, compiled: bool, seed: int = SEED) -> None:
        self.label = label
        self.world = WorldRow(label, moving=True, timed_tasks=False, seed=seed, compiled=compiled)
        b = self.world.bench
        now = b.clock.now()
        for axis, dps in JOG_DPS.items():
            b.host.submit(M["Jog"](int(axis), dps), now)
        b.run_for(0.1)
        self.bank = bank = b.controller.arm.bank
        tick = b.world.plant.arm.tick
        counts, currents, switches = tick.readouts()
        if compiled:
            from bench.limit_kernel import compiled_limit_ticks
            self.kernel = compiled_limit_ticks()
            inputs = (np.array(counts, dtype=np.int64), np.array(currents), np.array(switches[0]))
        else:
            from bench.limit_kernel import limit_ticks
            self.kernel = limit_ticks
            inputs = (list(counts), list(currents), list(switches[0]))
        params = b.controller.params
        h_s, substeps = tick.step_split
        self.now = b.clock.now()
        self.args = (PERIOD_S, bank.size, float(params["gravity_m_s2"]), float(params["payload_kg"]), bank.masses,
                     *inputs, bank.gravity_nm, bank.duties, bank.state, bank.int_state, bank.config, bank.int_config,
                     bank.profile, h_s, substeps, b.world.plant.supply_true_v, tick.command, tick.state, tick.table,
                     tick.flags, tick.counts, tick.constants)
        self.step(1)                         # compiled: numba compiles it here, not in a timed turn

    def step(self, ticks: int) -> None:
        done = self.kernel(ticks, self.now, *self.args)
        self.now += done * PERIOD_S
        if done < ticks:
            raise BenchSetupError(f"a joint handed an event to its facade after {done} of {ticks} ticks")

    def advance(self, duration_s: float) -> None:
        self.step(round(duration_s / PERIOD_S))

    def close(self) -> None:
        self.world.close()


class BeforeRow(Row):
    """The moving world as the code of `commit` runs it, in a child process (timed by the caller)."""

    label = f"the same world, code before issue 12 ({BEFORE_COMMIT})"

    def __init__(self, seed: int = SEED, commit: str = BEFORE_COMMIT, label: str = "", compiled: bool = False) -> None:
        self.label = label or self.label
        self._tmp = tempfile.TemporaryDirectory(prefix="aspod-before-")
        try:
            self.child = ChildWorld(tree_of_commit(commit, Path(self._tmp.name)), seed, compiled)
        except BaseException:
            self._tmp.cleanup()
            raise
        self.pid = self.child.proc.pid
        self.result: Optional[dict] = None

    def advance(self, duration_s: float) -> None:
        self.child.advance(duration_s)

    def check(self) -> str:
        self.result = self.child.finish()
        return self.result["error"]

    def close(self) -> None:
        self.child.close()
        self._tmp.cleanup()


class PlantRow(Row):
    """PlantNode + Plant at 1 kHz on an in-process bus nobody else joins; optionally its arm channels driven."""

    IDLE_LABEL = "plant alone (PlantNode + Plant, own bus)"
    DRIVEN_LABEL = "plant alone, its 6 arm channels driven open loop"

    def __init__(self, driven: bool = False, seed: int = SEED, compiled: Optional[bool] = None) -> None:
        self.label = self.DRIVEN_LABEL if driven else self.IDLE_LABEL
        self.clock = SimClock()
        self.bus = LocalBus(LocalChannel(), carries_values=True)   # the world's kind of bus, with nobody else on it
        with kernels.switched(compiled):
            self.node = build_plant_node(self.bus, seed)
        self.scheduler = Scheduler(self.clock, stopwatch=None)
        self.scheduler.add("plant", self.node.step, period_s=self.node.period_s)
        if driven:
            # No controller: the commands go straight into the plant's command holders, as the node's
            # MOTOR_CMD and CTRL_OUTPUTS handlers would put them, before each plant step.
            self._alive = 0
            self.scheduler.add("drive", self._drive, period_s=PERIOD_S, priority=-1)

    def _drive(self, now: float) -> float:
        plant = self.node.plant
        self._alive = alive = (self._alive + 1) & 0xFF
        sign = 1.0 if int(now / DRIVE_FLIP_S) % 2 == 0 else -1.0
        plant.commanded.command(True, False, alive, now)
        plant.motor_commands.command([sign * DRIVE_DUTY] * ARM_CHANNELS, [True] * ARM_CHANNELS,
                                     [False] * ARM_CHANNELS, alive, now)
        return now

    def check(self) -> str:
        plant = self.node.plant
        if self.label == self.DRIVEN_LABEL and not all(plant.channel_driven):
            return f"not every channel driven at the end: {plant.channel_driven}"
        return ""

    def advance(self, duration_s: float) -> None:
        self.scheduler.run_until(self.clock.now() + duration_s)

    def close(self) -> None:
        self.bus.shutdown()


class BareRow(Row):
    """The scheduler with one empty 1 kHz task."""

    label = "bare scheduler, one empty 1 kHz task"

    def __init__(self) -> None:
        self.clock = SimClock()
        self.scheduler = Scheduler(self.clock, stopwatch=None)
        self.scheduler.add("empty", lambda now: now, period_s=PERIOD_S)

    def advance(self, duration_s: float) -> None:
        self.scheduler.run_until(self.clock.now() + duration_s)


# ---------------------------------------------------------------- results

@dataclass
class RowResult:
    label: str
    sim_s: float = 0.0
    wall_s: float = 0.0
    cpu_others: float = 0.0
    error: str = ""
    detail: str = ""

    @property
    def x_real_time(self) -> float:
        return self.sim_s / self.wall_s if self.wall_s > 0 else math.nan

    @property
    def us_per_sim_ms(self) -> float:
        return self.wall_s / self.sim_s * 1e3 if self.sim_s > 0 else math.nan


@dataclass
class LockstepResults:
    rows: list[RowResult] = field(default_factory=list)
    split: dict[str, tuple[int, float]] = field(default_factory=dict)   # task -> (runs, exec seconds)
    split_row: Optional[RowResult] = None
    telemetry_frames: int = 0
    same_motion: Optional[bool] = None     # the timed world moved exactly as the main one
    same_as_before_35: Optional[bool] = None   # the main world ended exactly where the code before issue 35 did
    same_as_plain: Optional[bool] = None   # the compiled kernels' world ended exactly where the plain one did
    same_as_tick_by_tick: Optional[bool] = None   # ... and where the compiled one without the fast loop did
    duration_s: float = 0.0
    rounds: int = 0
    hogs: int = 0                          # processes spinning on a core each during the run

    @property
    def main(self) -> RowResult:
        """The moving world's row (the first if it is not there)."""
        return next((r for r in self.rows if r.label == MAIN_LABEL), self.rows[0])

    def row(self, label: str) -> RowResult:
        return next(r for r in self.rows if r.label == label)

    @property
    def error(self) -> str:
        return "; ".join(f"{r.label}: {r.error}" for r in self.rows if r.error)


# The compiled kernels (kernels/__init__.py) when numba is installed: the world as fast as it goes.
COMPILED = importlib.util.find_spec("numba") is not None
MAIN_LABEL = "world, all 8 channels moving, telemetry 10 Hz"
PLAIN_LABEL = "the same world, kernels as plain Python"
TICK_BY_TICK_LABEL = "the same world, compiled, tick by tick (no fast loop)"
LIMIT_LABEL = "limit: the 2 kernels, all ticks in 1 call"
PLAIN_LIMIT_LABEL = "limit, the kernels as plain Python"


def all_rows() -> list[tuple[str, type | object]]:
    """(label, builder) of every row: the limit (plain too, with numba), the main world, the code before issue 35 and
    before issue 12, the rest."""
    rows = [
        (MAIN_LABEL, lambda: WorldRow(MAIN_LABEL, moving=True, timed_tasks=False, compiled=COMPILED)),
        (BEFORE_35_LABEL, lambda: BeforeRow(commit=BEFORE_35_COMMIT, label=BEFORE_35_LABEL, compiled=COMPILED)),
        (BeforeRow.label, BeforeRow),
        ("world, enabled, holding, telemetry 10 Hz", lambda: WorldRow(
            "world, enabled, holding, telemetry 10 Hz", moving=False, timed_tasks=False, compiled=COMPILED)),
        ("world, all moving, timed per task", lambda: WorldRow(
            "world, all moving, timed per task", moving=True, timed_tasks=True, compiled=COMPILED)),
        (PlantRow.IDLE_LABEL, lambda: PlantRow(compiled=COMPILED)),
        (PlantRow.DRIVEN_LABEL, lambda: PlantRow(driven=True, compiled=COMPILED)),
        (BareRow.label, BareRow),
    ]
    if COMPILED:       # what the kernels buy: the main world with them as plain Python, and without the fast loop
        rows.insert(2, (PLAIN_LABEL, lambda: WorldRow(PLAIN_LABEL, moving=True, timed_tasks=False, compiled=False)))
        rows.insert(3, (TICK_BY_TICK_LABEL, lambda: WorldRow(TICK_BY_TICK_LABEL, moving=True, timed_tasks=False,
                                                             compiled=True, fast_loop=False)))
    rows.insert(0, (LIMIT_LABEL, lambda: LimitRow(LIMIT_LABEL, compiled=COMPILED)))
    if COMPILED:
        rows.insert(1, (PLAIN_LIMIT_LABEL, lambda: LimitRow(PLAIN_LIMIT_LABEL, compiled=False)))
    return rows


def run(quick: bool = False, duration_s: Optional[float] = None, rounds: Optional[int] = None,
        builders: Optional[list] = None, hogs: int = 0) -> LockstepResults:
    """Build the rows, let them take turns for `rounds` rounds, check them. With `hogs`, that many
    processes spin on a core each for the whole run (the machine made busy on purpose)."""
    duration = duration_s if duration_s is not None else (QUICK_S if quick else FULL_S)
    rounds = rounds or (QUICK_ROUNDS if quick else FULL_ROUNDS)
    share = duration / rounds
    out = LockstepResults(duration_s=duration, rounds=rounds, hogs=hogs)
    clock = RealClock()
    rows: list[Optional[Row]] = []
    meters: list[CpuMeter] = []
    spinners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(hogs)]
    try:
        for label, build in builders if builders is not None else all_rows():
            result = RowResult(label)
            out.rows.append(result)
            meter = CpuMeter(clock)
            meters.append(meter)
            try:
                row = build()
            except Exception as exc:   # reported in its row
                result.error = f"{type(exc).__name__}: {exc}"
                row = None
            if isinstance(row, BeforeRow):
                meter.child_pids = (row.pid,)         # its CPU is the row's own, not another process's
            rows.append(row)
        for _ in range(rounds):
            for row, result, meter in zip(rows, out.rows, meters):
                if row is None or result.error:
                    continue
                meter.resume()
                t0 = RealClock.precise_now()
                try:
                    row.advance(share)
                except Exception as exc:
                    result.error = f"{type(exc).__name__}: {exc}"
                finally:
                    result.wall_s += RealClock.precise_now() - t0
                    meter.stop()
                result.sim_s += share
        for row, result, meter in zip(rows, out.rows, meters):
            result.cpu_others = meter.others()
            if row is not None and not result.error:
                result.error = row.check()
        by_label = {r.label: row for r, row in zip(out.rows, rows)}
        main, timed = by_label.get(MAIN_LABEL), by_label.get("world, all moving, timed per task")
        plain = by_label.get(PLAIN_LABEL)
        tick_by_tick = by_label.get(TICK_BY_TICK_LABEL)
        before_35 = by_label.get(BEFORE_35_LABEL)
        if isinstance(timed, WorldRow) and not out.row(timed.label).error:
            out.split = timed.task_split()
            out.split_row = out.row(timed.label)
        if isinstance(main, WorldRow):
            out.telemetry_frames = main.telemetry_frames()
            angles = [float(x).hex() for x in main.bench.world.plant.arm.pos_rad]
            if isinstance(timed, WorldRow):
                out.same_motion = angles == [float(x).hex() for x in timed.bench.world.plant.arm.pos_rad]
            if isinstance(plain, WorldRow):
                out.same_as_plain = angles == [float(x).hex() for x in plain.bench.world.plant.arm.pos_rad]
            if isinstance(tick_by_tick, WorldRow):
                out.same_as_tick_by_tick = angles == [float(x).hex()
                                                      for x in tick_by_tick.bench.world.plant.arm.pos_rad]
            if isinstance(before_35, BeforeRow) and before_35.result is not None and before_35.result["pos_rad"]:
                out.same_as_before_35 = angles == before_35.result["pos_rad"]
    finally:
        for row in rows:
            if row is not None:
                row.close()
        for spinner in spinners:
            spinner.kill()
            spinner.wait()
    return out


def parallel_worlds(workers: int, duration_s: float, seed: int = SEED) -> tuple[float, str]:
    """Simulated seconds per wall second summed over `workers` worlds, each in its own process,
    running `duration_s` at the same time (a campaign's throughput); and an error, '' if none."""
    worlds: list[ChildWorld] = []
    try:
        worlds = [ChildWorld(REPO, seed + k, COMPILED) for k in range(workers)]
        for world in worlds:                   # all start together: each is told before any answers
            assert world.proc.stdin is not None
            world.proc.stdin.write(f"{duration_s!r}\n")
            world.proc.stdin.flush()
        t0 = RealClock.precise_now()
        answers = [world._line() for world in worlds]
        wall_s = RealClock.precise_now() - t0
        errors = [world.finish()["error"] for world in worlds]
        if not all(_is_number(a) for a in answers):
            return math.nan, "a world in a child process stopped"
        return workers * duration_s / wall_s, "; ".join(e for e in errors if e)
    except BenchSetupError as exc:
        return math.nan, str(exc)
    finally:
        for world in worlds:
            world.close()


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


# ---------------------------------------------------------------- report

def _beside(row: RowResult, same: Optional[bool], whose: str, speed: Callable[[RowResult], str]) -> list[str]:
    """The main world beside another row: `speed(row)` if the row ran, and whether it ended at `whose` angles."""
    lines = [speed(row)] if row.wall_s > 0 and not row.error else []
    if same is not None:
        lines.append(f"  and the same simulation to the bit: final joint angles identical to {whose}" if same else
                     f"  NOTE: the world ended with other joint angles than {whose} (it should not)")
    return lines


def report(res: LockstepResults) -> str:
    main = res.main
    load = (f"; {res.hogs} other process{'es' if res.hogs > 1 else ''} spinning on a core" if res.hogs else
            "; the machine as it is")
    lines = [f"Lock-step speed: simulated seconds per wall second, every loop at 1 kHz on the simulated clock; "
             f"{res.duration_s:g} simulated s per row, rows taking turns in {res.rounds} round"
             f"{'s' if res.rounds > 1 else ''}{load}",
             f"  motor channels: {ARM_CHANNELS + TRACKER_CHANNELS}: the arm's {ARM_CHANNELS} (J1-J4, gripper, mount) "
             f"at 1 kHz and the solar tracker's {TRACKER_CHANNELS} (relay logic at 100 Hz, the DBC's 10 ms cycle)",
             "",
             f"  {'row':<50}{'sim s':>7}{'wall s':>8}{'x real':>8}{'us/sim ms':>10}{'of main':>9}{'others':>8}"]
    for r in res.rows:
        if r.error and not r.wall_s:
            lines.append(f"  {r.label:<50}FAILED: {r.error}")
            continue
        share = r.us_per_sim_ms / main.us_per_sim_ms if main.wall_s > 0 else math.nan
        lines.append(f"  {r.label:<50}{r.sim_s:>7.1f}{r.wall_s:>8.2f}{r.x_real_time:>8.1f}{r.us_per_sim_ms:>10.1f}"
                     f"{share:>8.0%} {r.cpu_others:>7.2f}")
    lines.append("  x real = simulated s per wall s; us/sim ms = wall time per simulated millisecond (one tick of "
                 "every 1 kHz loop); of main = that cost against the first row's; others = CPU other processes "
                 "used meanwhile, in cores")
    for r in res.rows:
        if r.error and r.wall_s:
            lines.append(f"  NOTE {r.label}: {r.error}")
    lines.append("")
    if main.wall_s > 0 and not main.error:
        x = main.x_real_time
        ok = x >= GOAL_X
        lines += [f"  world, all moving: {x:.1f}x real time; goal >= {GOAL_X:g}x: ratio {x / GOAL_X:.2f}  "
                  f"{'PASS' if ok else 'FAIL'}",
                  f"  beside PX4 lock-step SITL {PX4_X[0]:g}-{PX4_X[1]:g}x (ratio "
                  f"{x / PX4_X[1]:.2f}-{x / PX4_X[0]:.2f}), ArduPilot autotest {ARDUPILOT_X:g}x (ratio "
                  f"{x / ARDUPILOT_X:.2f})",
                  f"  budget at {GOAL_X:g}x: {1e3 / GOAL_X:.0f} us of wall time per simulated ms; this world takes "
                  f"{main.us_per_sim_ms:.0f} us",
                  f"  goal {'met' if ok else 'NOT met'}"]
        labels = {r.label for r in res.rows}
        for label in (LIMIT_LABEL, PLAIN_LIMIT_LABEL):
            if label in labels and res.row(label).wall_s > 0 and not res.row(label).error:
                limit = res.row(label)
                lines.append(f"  {label}: {limit.x_real_time:.0f}x real time ({limit.us_per_sim_ms:.1f} us per "
                             f"simulated ms); the world runs at {x / limit.x_real_time:.1%} of it")
        if BEFORE_35_LABEL in labels:
            lines += _beside(res.row(BEFORE_35_LABEL), res.same_as_before_35, "the code before issue 35's",
                             lambda before: (f"  against the code before issue 35 ({BEFORE_35_COMMIT}), the same world "
                                             f"in the same run: {before.x_real_time:.1f}x, so "
                                             f"{x / before.x_real_time:.2f} times as fast"))
        if BeforeRow.label in labels:
            # Issue 34's handshake moved every command 14 ms later (tests/test_same_bytes_as_before.py): since then the
            # world simulates other motion than the code before issue 12 did, so its angles are not compared.
            lines += _beside(res.row(BeforeRow.label), None, "", lambda before: (
                f"  against the code before issue 12 ({BEFORE_COMMIT}), the same script in the same run: "
                f"{before.x_real_time:.1f}x, so {x / before.x_real_time:.2f} times as fast (its motion differs since "
                f"issue 34's handshake moved every command 14 ms later)"))
        if PLAIN_LABEL in labels:
            lines += _beside(res.row(PLAIN_LABEL), res.same_as_plain, "the plain kernels'", lambda plain: (
                f"  the compiled kernels (numba): {x / plain.x_real_time:.2f} times the world with them as "
                f"plain Python ({plain.x_real_time:.1f}x)"))
        elif not COMPILED:
            lines.append("  numba is not installed: the kernels ran as plain Python (pip install 'aspod[compiled]')")
        if TICK_BY_TICK_LABEL in labels:
            lines += _beside(res.row(TICK_BY_TICK_LABEL), res.same_as_tick_by_tick, "the tick-by-tick world's",
                             lambda tick: (f"  the fast loop (1 kHz tasks many ticks a call): {x / tick.x_real_time:.2f} "
                                           f"times the compiled world run tick by tick ({tick.x_real_time:.1f}x)"))
        if PlantRow.IDLE_LABEL in labels and PlantRow.DRIVEN_LABEL in labels:
            idle, driven = res.row(PlantRow.IDLE_LABEL), res.row(PlantRow.DRIVEN_LABEL)
        else:
            idle = driven = RowResult("")
        if driven.wall_s > 0 and not driven.error and idle.wall_s > 0 and not idle.error:
            lines.append(f"  the plant alone runs at {idle.x_real_time:.1f}x idle and {driven.x_real_time:.1f}x with "
                         f"its channels driven ({idle.us_per_sim_ms:.0f} and {driven.us_per_sim_ms:.0f} us per "
                         "simulated ms): no world with this plant runs faster than that")
        if res.telemetry_frames:
            lines.append(f"  the host received {res.telemetry_frames} telemetry frames in {res.duration_s:g} simulated "
                         f"s (TelemetryStatus + TelemetryJoints at {TELEMETRY_HZ} Hz)")
    if res.split and res.split_row is not None:
        sim_ms = res.split_row.sim_s * 1e3
        total = sum(e for _, e in res.split.values())
        lines += ["",
                  f"  where the time goes (the scheduler's own TaskStats in the timed world, {res.split_row.sim_s:g} "
                  f"simulated s; {res.split_row.x_real_time:.1f}x with the stopwatch on):",
                  f"    {'task':<34}{'runs/sim s':>11}{'us/run':>9}{'us/sim ms':>11}{'share':>8}"]
        for name, (runs, exec_s) in sorted(res.split.items(), key=lambda kv: -kv[1][1]):
            lines.append(f"    {name:<34}{runs / res.split_row.sim_s:>11.0f}{exec_s / runs * 1e6 if runs else 0:>9.1f}"
                         f"{exec_s / sim_ms * 1e6:>11.1f}{exec_s / res.split_row.wall_s:>8.0%}")
        rest = res.split_row.wall_s - total
        lines.append(f"    {'scheduler, stopwatch, run_until loop':<34}{'':>11}{'':>9}{rest / sim_ms * 1e6:>11.1f}"
                     f"{rest / res.split_row.wall_s:>8.0%}")
        lines.append(f"    {'all':<34}{'':>11}{'':>9}{res.split_row.us_per_sim_ms:>11.1f}{1:>8.0%}")
        lines.append("    plant = PlantNode.step (read MOTOR_CMD, integrate, send PLANT_SYNC, MOTOR_FB, DIGITAL_IN, "
                     "ANALOG_IN; at 100 Hz the tracker's step, TRACKER_SENSE, TRACKER_POS); arm = the controller's "
                     "motor loops (poll the HAL, six channels, MOTOR_CMD); tracker = the control box and the relay "
                     "logic (TRACKER_CMD); hal = "
                     "the controller's HAL inputs (it polls right after the plant's step, so it decodes most of the "
                     "plant's frames) and CTRL_OUTPUTS; comms = the controller's UART and link; host = the host link "
                     "and the in-memory line")
        if res.same_motion is not None:
            lines.append("    the real stopwatch changed nothing simulated: final joint angles identical to the first "
                         "row's" if res.same_motion else
                         "    NOTE: the timed world ended with other joint angles than the first row (the stopwatch "
                         "should not change the simulation)")
    return "\n".join(lines)


BUSY_GOAL_X = 60.0             # issue 35: compiled, beside a process spinning on a core
IDLE_GOAL_X = GOAL_X           # compiled, on a quiet machine
PLAIN_GOAL_X = 25.0            # the kernels as plain Python (no numba)
PARALLEL_GOAL = 1.8            # two worlds in two processes: at least this many times one's throughput


def main(quick: bool = False) -> LockstepResults:
    """Every row on the machine as it is; then the main world and the old code's with one process
    spinning on a core; then worlds in parallel processes (a campaign's throughput)."""
    results = run(quick)
    print(report(results), flush=True)
    pair = [(label, build) for label, build in all_rows() if label in (LIMIT_LABEL, MAIN_LABEL, BEFORE_35_LABEL,
                                                                         PLAIN_LABEL)]
    busy = run(quick, builders=pair, hogs=1)
    print()
    print(report(busy), flush=True)
    quiet, loaded = results.main, busy.main
    print()
    print(f"  goals: {quiet.x_real_time:.1f}x with {quiet.cpu_others:.2f} cores used by other processes "
          f"(goal >= {IDLE_GOAL_X:g}x on an idle machine: ratio {quiet.x_real_time / IDLE_GOAL_X:.2f}); "
          f"{loaded.x_real_time:.1f}x beside a process spinning on a core (others {loaded.cpu_others:.2f} cores; "
          f"goal >= {BUSY_GOAL_X:g}x: ratio {loaded.x_real_time / BUSY_GOAL_X:.2f})")
    if PLAIN_LABEL in {r.label for r in results.rows}:
        plain = results.row(PLAIN_LABEL)
        print(f"  plain Python kernels: {plain.x_real_time:.1f}x (goal >= {PLAIN_GOAL_X:g}x: ratio "
              f"{plain.x_real_time / PLAIN_GOAL_X:.2f})")
    duration = QUICK_S if quick else FULL_S
    one, err_one = parallel_worlds(1, duration)
    two, err_two = parallel_worlds(2, duration)
    print(f"  campaign throughput, the moving world in child processes, {duration:g} simulated s each: "
          f"1 process {one:.1f} simulated s per wall s, 2 processes {two:.1f} together: "
          f"{two / one:.2f}x one (goal >= {PARALLEL_GOAL:g}x)")
    for err in (err_one, err_two):
        if err:
            print(f"  NOTE parallel worlds: {err}")
    if busy.error or err_one or err_two:
        results.rows.append(RowResult("busy or parallel runs", error=busy.error or err_one or err_two))
    return results


if __name__ == "__main__":
    main(quick="--quick" in sys.argv[1:])
