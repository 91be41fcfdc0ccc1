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
  line, 115200 baud paced, every loop at 1 kHz, the scheduler's deterministic stopwatch),
  connected, telemetry at 10 Hz, enabled; every 2.5 simulated seconds the host sends, through
  the protocol, a Jog to each of J1-J4 and the mount (signed speeds within the 3 deg/s limit,
  the sign flipping each time) and a Grip (close, then open); the tracker's control box is in
  manual mode with both dials at 50 %, and at each segment the host turns the dials low, flips
  the direction switch and turns them up again (changing direction needs the dial low): all
  eight channels driven.
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
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional

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
GOAL_X = 20.0                  # the goal: at least 20x real time
PX4_X = (6.0, 10.0)            # PX4 lock-step SITL on desktops
ARDUPILOT_X = 8.0              # ArduPilot autotest's default speed-up
ARM_CHANNELS = 6               # J1-J4, gripper, mount: 1 kHz
TRACKER_CHANNELS = 2           # the solar tracker's azimuth and elevation motors: 100 Hz
TRACKER_DIAL_PCT = 50.0        # the moving world's dials (manual mode: about 17 deg/min)
# Jog speeds [deg/s], inside the joints' 3 deg/s limit; different so no two joints move alike.
JOG_DPS = {Axis.J1: 1.0, Axis.J2: 2.0, Axis.J3: 2.5, Axis.J4: 3.0, Axis.MOUNT: 1.5}
DRIVE_DUTY = 0.3               # the driven plant row: this duty on every channel, open loop,
DRIVE_FLIP_S = 0.5             # its sign flipping this often


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

    def __init__(self, label: str, moving: bool, timed_tasks: bool, seed: int = SEED) -> None:
        self.label = label
        self.moving = moving
        self.bench = LockstepBench(seed=seed)
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


class PlantRow(Row):
    """PlantNode + Plant at 1 kHz on an in-process bus nobody else joins; optionally its arm channels driven."""

    IDLE_LABEL = "plant alone (PlantNode + Plant, own bus)"
    DRIVEN_LABEL = "plant alone, its 6 arm channels driven open loop"

    def __init__(self, driven: bool = False, seed: int = SEED) -> None:
        self.label = self.DRIVEN_LABEL if driven else self.IDLE_LABEL
        self.clock = SimClock()
        self.bus = LocalBus(LocalChannel(), carries_values=True)   # the world's kind of bus, with nobody else on it
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
    duration_s: float = 0.0
    rounds: int = 0

    @property
    def main(self) -> RowResult:
        return self.rows[0]

    @property
    def error(self) -> str:
        return "; ".join(f"{r.label}: {r.error}" for r in self.rows if r.error)


def run(quick: bool = False, duration_s: Optional[float] = None, rounds: Optional[int] = None) -> LockstepResults:
    duration = duration_s if duration_s is not None else (QUICK_S if quick else FULL_S)
    rounds = rounds or (QUICK_ROUNDS if quick else FULL_ROUNDS)
    share = duration / rounds
    out = LockstepResults(duration_s=duration, rounds=rounds)
    clock = RealClock()
    builders = [
        ("world, all 8 channels moving, telemetry 10 Hz", lambda: WorldRow(
            "world, all 8 channels moving, telemetry 10 Hz", moving=True, timed_tasks=False)),
        ("world, enabled, holding, telemetry 10 Hz", lambda: WorldRow(
            "world, enabled, holding, telemetry 10 Hz", moving=False, timed_tasks=False)),
        ("world, all moving, timed per task", lambda: WorldRow(
            "world, all moving, timed per task", moving=True, timed_tasks=True)),
        (PlantRow.IDLE_LABEL, PlantRow),
        (PlantRow.DRIVEN_LABEL, lambda: PlantRow(driven=True)),
        (BareRow.label, BareRow),
    ]
    rows: list[Optional[Row]] = []
    meters: list[CpuMeter] = []
    for label, build in builders:
        result = RowResult(label)
        out.rows.append(result)
        meters.append(CpuMeter(clock))
        try:
            rows.append(build())
        except Exception as exc:   # reported in its row
            result.error = f"{type(exc).__name__}: {exc}"
            rows.append(None)
    try:
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
        main, timed = rows[0], rows[2]
        if isinstance(timed, WorldRow) and not out.rows[2].error:
            out.split = timed.task_split()
            out.split_row = out.rows[2]
        if isinstance(main, WorldRow):
            out.telemetry_frames = main.telemetry_frames()
            if isinstance(timed, WorldRow):
                ours, theirs = main.bench.world.plant.arm.pos_rad, timed.bench.world.plant.arm.pos_rad
                out.same_motion = bool((ours == theirs).all())
    finally:
        for row in rows:
            if row is not None:
                row.close()
    return out


# ---------------------------------------------------------------- report

def report(res: LockstepResults) -> str:
    main = res.main
    lines = [f"Lock-step speed: simulated seconds per wall second, every loop at 1 kHz on the simulated clock; "
             f"{res.duration_s:g} simulated s per row, rows taking turns in {res.rounds} round"
             f"{'s' if res.rounds > 1 else ''}",
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
        idle, driven = res.rows[3], res.rows[4]
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


def main(quick: bool = False) -> LockstepResults:
    results = run(quick)
    print(report(results), flush=True)
    return results


if __name__ == "__main__":
    import sys
    main(quick="--quick" in sys.argv[1:])
