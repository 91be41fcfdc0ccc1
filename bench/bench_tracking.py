"""Tracking: positioning error at the gripper after each move, and the settle time, per joint, Earth against orbit.

The goal: the positioning error at the gripper after each move and the settle time, per
joint, Earth against orbit. The report's specification: the gripper within 1 cm
(0.39 in) of where it was sent.

For each gravity (Earth 9.81 m/s^2, orbit 0), a fresh `host_tools.worlds.world.LockstepBench`
(plant, controller and host link on the simulated clock, seed 0) with the plant in that
gravity; for orbit the controller is told so too (ParamSet `gravity_m_s2` 0, as
`host_tools/apps/pick_place.py` does), so its gravity feed-forward is off. Everything goes
through the protocol: connect, Enable, Home all (axis ALL; every axis's MotionDone
awaited), then every joint to the middle pose, 0 deg: links II and III and the gripper
level and in line, the arm stretched out, where gravity's moment on J1-J3 is largest. Then,
one joint at a time (j1, j2, j3, j4, mount), Move to middle + 20 deg, middle - 10 deg and
back to the middle (--quick: + 5 deg and back), each at the axis's default speed (the
report's 1/2 RPM, 3 deg/s, at 3 deg/s^2), the other joints holding. For each move:

* joint error: the plant's true angle (`plant.arm.pos_rad[k]`) against the target, when
  the host has the MotionDone event;
* tip error: the true gripper tip (`plant.arm.gripper_position_m()`) against the tip of the
  target pose (`hil_sim.arm.gripper_position_m` of the true angles with joint k at its
  target): what the joint's error costs at the gripper, in millimetres (J4 rolls the
  gripper about its own axis and cannot move the tip);
* settle time: from the planned end of the trapezoid (the axis's own profile:
  `controller.arm.joints[name]._profile`, started at `_profile_t0`) to the MotionDone
  (the controller's `uptime_ms` in the event, 1 ms resolution). The controller reports
  DONE once within 0.2 mrad and 2 mrad/s of the target, NOT_SETTLED after 3 s;
* peak following error during the move: |setpoint - true angle| (`axis.pos_sp_rad` against
  `plant.arm.pos_rad[k]`), sampled every simulated millisecond. The controller faults above
  0.05 rad (2.9 deg).

Then (not with --quick) the pick-and-place (`host_tools.apps.pick_place.run`, Earth and orbit):
its per-step tip errors, as `aspod demo` reports them.

Every figure here is simulated, so a given seed gives the same figures on any machine; only
the pick-and-place's wall time (printed for information) moves.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from hil_sim.arm import gripper_position_m
from host_tools.apps import pick_place
from host_tools.worlds.world import LockstepBench
from protocol.messages import MESSAGES as M, started_motions
from host_tools.worlds.settings import PlantSettings
from protocol.reasons import Reason
from protocol.states import Axis, MotionOutcome

GRAVITIES = ("earth", "orbit")
JOINTS = ("j1", "j2", "j3", "j4", "mount")
MIDDLE_DEG = 0.0                      # every joint: the arm stretched out, level
OFFSETS_DEG = (20.0, -10.0, 0.0)      # targets, from the middle pose, in this order
QUICK_OFFSETS_DEG = (5.0, 0.0)
SPEC_M = pick_place.SPEC_M            # the report: within 1 cm at the gripper
SEED = 0
MOTION_TIMEOUT_S = 120.0              # simulated
UPTIME_RESOLUTION_S = 0.001           # MotionDone's uptime_ms
SETTLE_FLOOR_S = 0.01                 # settle times both below this: no Earth/orbit ratio (both "at the end")


class TrackingFailed(RuntimeError):
    """The world could not be set up, or a move could not be made: no figures from there on."""


@dataclass
class MoveResult:
    joint: str
    target_deg: float
    outcome: str = ""
    joint_error_rad: float = math.nan
    tip_error_m: float = math.nan
    settle_s: float = math.nan
    peak_following_rad: float = 0.0
    peak_following_at_s: float = math.nan   # when, from the start of the profile
    planned_s: float = math.nan        # the profile's duration


@dataclass
class JointSummary:
    joint: str
    moves: int = 0
    not_done: int = 0
    max_joint_error_rad: float = math.nan
    max_tip_error_m: float = math.nan
    max_settle_s: float = math.nan
    peak_following_rad: float = math.nan
    peak_following_at_s: float = math.nan


@dataclass
class GravityResult:
    gravity: str
    homing_s: float = math.nan
    in_position_rad: float = math.nan      # the controller reports DONE within this of the target
    moves: list[MoveResult] = field(default_factory=list)
    sim_s: float = 0.0
    error: str = ""

    def summary(self, joint: str) -> JointSummary:
        rows = [m for m in self.moves if m.joint == joint]
        s = JointSummary(joint, len(rows), sum(1 for m in rows if m.outcome != "DONE"))
        if rows:
            s.max_joint_error_rad = max(abs(m.joint_error_rad) for m in rows)
            s.max_tip_error_m = max(m.tip_error_m for m in rows)
            s.max_settle_s = max(m.settle_s for m in rows)
            worst = max(rows, key=lambda m: m.peak_following_rad)
            s.peak_following_rad, s.peak_following_at_s = worst.peak_following_rad, worst.peak_following_at_s
        return s

    @property
    def max_tip_error_m(self) -> float:
        return max((m.tip_error_m for m in self.moves), default=math.nan)


class Tracker:
    """One gravity's world, driven through the protocol, measured against the plant's truth."""

    def __init__(self, gravity: str, seed: int = SEED) -> None:
        self.gravity = gravity
        self.bench = LockstepBench(seed=seed, plant=PlantSettings(gravity=gravity))
        self.plant = self.bench.world.plant
        self.controller = self.bench.controller
        self._seen = 0
        self.done: dict[tuple[int, int], object] = {}     # (axis, motion_id) -> MotionDone

    def _scan(self) -> None:
        events = self.bench.events
        while self._seen < len(events):
            event = events[self._seen]
            self._seen += 1
            if event.spec.name == "MotionDone":
                self.done[(event.axis, event.motion_id)] = event

    def _call(self, msg, what: str):
        handle = self.bench.call(msg)
        if not handle.ok:
            raise TrackingFailed(f"{what}: {handle.describe()}")
        return handle.reply

    def _wait(self, started: dict[int, int], what: str, sample=None) -> dict[int, object]:
        """Run until every (axis -> motion_id) has its MotionDone; `sample()` runs every simulated ms."""
        sup = self.controller.supervisor

        def finished() -> bool:
            if sample is not None:
                sample()
            self._scan()
            return all((a, m) in self.done for a, m in started.items()) or sup.in_safe_state

        if not self.bench.wait_until(finished, MOTION_TIMEOUT_S):
            raise TrackingFailed(f"{what}: no MotionDone within {MOTION_TIMEOUT_S:g} simulated s")
        if sup.in_safe_state:
            raise TrackingFailed(f"{what}: the controller went to {sup.state.name} ({sup.safe_reason.name}, "
                                 f"faults {sup.faults!r})")
        return {a: self.done[(a, m)] for a, m in started.items()}

    def _check_done(self, events: dict[int, object], what: str) -> None:
        bad = {a: e for a, e in events.items() if e.outcome != MotionOutcome.DONE}
        if bad:
            raise TrackingFailed(f"{what}: " + ", ".join(
                f"{Axis(a).name.lower()} {MotionOutcome(e.outcome).name} ({Reason(e.reason).name})"
                for a, e in bad.items()))

    def prepare(self) -> float:
        """Connect, gravity, enable, home all, every joint to the middle pose; the homing's simulated time."""
        if not self.bench.connect():
            raise TrackingFailed("connect: no session")
        if self.gravity == "orbit":
            self._call(M["ParamSet"]("gravity_m_s2", 0.0), "set gravity_m_s2 0 (orbit)")
        self._call(M["Enable"](), "enable")
        start = self.bench.clock.now()
        started = started_motions(self._call(M["Home"](int(Axis.ALL)), "home all"))
        self._check_done(self._wait(started, "home all"), "home all")
        homing_s = self.bench.clock.now() - start
        started = {}
        for name in JOINTS:
            axis = Axis[name.upper()]
            started[int(axis)] = self._call(M["Move"](int(axis), MIDDLE_DEG, 0.0), f"{name} to the middle").motion_id
        self._check_done(self._wait(started, "to the middle pose"), "to the middle pose")
        return homing_s

    def move(self, joint: str, target_deg: float) -> MoveResult:
        axis_id = Axis[joint.upper()]
        k = int(axis_id)
        axis = self.controller.arm.joints[joint]
        arm = self.plant.arm
        out = MoveResult(joint, target_deg)
        reply = self._call(M["Move"](k, target_deg, 0.0), f"{joint} to {target_deg:g} deg")
        profile = getattr(axis, "_profile", None)
        planned_end_s = start_s = math.nan
        if profile is not None and axis.motion_id == reply.motion_id:
            out.planned_s = profile.duration_s
            start_s = axis._profile_t0
            planned_end_s = start_s + profile.duration_s
        clock = self.bench.clock
        peak = [0.0, math.nan]

        def sample() -> None:
            err = abs(axis.pos_sp_rad - arm.pos_rad[k])
            if err > peak[0]:
                peak[0], peak[1] = err, clock.now() - start_s
        event = self._wait({k: reply.motion_id}, f"{joint} to {target_deg:g} deg", sample)[k]
        out.peak_following_rad, out.peak_following_at_s = float(peak[0]), peak[1]
        out.outcome = MotionOutcome(event.outcome).name
        # uptime_ms is whole milliseconds, truncated: a MotionDone in the profile's last tick reads up to 1 ms early
        settle = self.controller.started_s + event.uptime_ms / 1000.0 - planned_end_s
        out.settle_s = 0.0 if -UPTIME_RESOLUTION_S <= settle < 0.0 else settle
        target_rad = math.radians(target_deg)
        true = arm.pos_rad.copy()
        out.joint_error_rad = float(true[k] - target_rad)
        wanted = true.copy()
        wanted[k] = target_rad
        out.tip_error_m = float(math.dist(arm.gripper_position_m(), gripper_position_m(wanted)))
        return out

    def close(self) -> None:
        self.bench.close()


def run_gravity(gravity: str, offsets_deg: tuple[float, ...], seed: int = SEED) -> GravityResult:
    result = GravityResult(gravity)
    tracker = Tracker(gravity, seed)
    try:
        result.in_position_rad = tracker.controller.arm.joints[JOINTS[0]].config.in_position_rad
        result.homing_s = tracker.prepare()
        for joint in JOINTS:
            for offset in offsets_deg:
                result.moves.append(tracker.move(joint, MIDDLE_DEG + offset))
    except TrackingFailed as exc:
        result.error = str(exc)
    finally:
        result.sim_s = tracker.bench.clock.now()
        tracker.close()
    return result


@dataclass
class TrackingResults:
    gravities: dict[str, GravityResult] = field(default_factory=dict)
    pick_place: dict[str, dict] = field(default_factory=dict)     # gravity -> pick_place.run's report
    offsets_deg: tuple[float, ...] = ()

    @property
    def error(self) -> str:
        errors = [f"{g}: {r.error}" for g, r in self.gravities.items() if r.error]
        errors += [f"pick-and-place {g}: {r['error']}" for g, r in self.pick_place.items() if r.get("error")]
        return "; ".join(errors)


def run(quick: bool = False) -> TrackingResults:
    offsets = QUICK_OFFSETS_DEG if quick else OFFSETS_DEG
    out = TrackingResults(offsets_deg=offsets)
    for gravity in GRAVITIES:
        out.gravities[gravity] = run_gravity(gravity, offsets)
    if not quick:
        for gravity in GRAVITIES:
            try:
                out.pick_place[gravity] = pick_place.run(gravity, SEED)
            except Exception as exc:   # reported in its row
                out.pick_place[gravity] = {"error": f"{type(exc).__name__}: {exc}", "steps": []}
    return out


# ---------------------------------------------------------------- report

def mdeg(x: float) -> str:
    return "-" if math.isnan(x) else f"{math.degrees(x) * 1e3:.1f}"


def mm(x: float) -> str:
    return "-" if math.isnan(x) else f"{x * 1e3:.3f}"


def ms(x: float) -> str:
    return "-" if math.isnan(x) else f"{x * 1e3:.0f}"


def ratio(a: float, b: float, floor: float = 0.0) -> str:
    """a / b, or '-' when either is missing or both are below `floor` (the measure's resolution)."""
    if math.isnan(a) or math.isnan(b) or b == 0 or (abs(a) <= floor and abs(b) <= floor):
        return "-"
    return f"{a / b:.2f}"


def report(res: TrackingResults) -> str:
    offsets = ", ".join(f"{o:+g}" for o in res.offsets_deg)
    in_position = next((r.in_position_rad for r in res.gravities.values()), math.nan)
    lines = [f"Tracking: error at the gripper after each move and settle time, per joint, Earth against orbit "
             f"(seed {SEED}, every figure simulated)",
             f"  each joint in turn from the middle pose ({MIDDLE_DEG:g} deg everywhere: the arm stretched out, "
             f"level) to middle {offsets} deg by Move at the default 3 deg/s, 3 deg/s^2, the others holding",
             "  joint err = |true angle - target| at MotionDone (the controller reports DONE within "
             f"{in_position * 1e3:g} mrad = {mdeg(in_position)} mdeg of the target); tip err = true tip against the "
             "tip of the target pose (J4 cannot move the tip)",
             "  settle = MotionDone - planned end of the profile (1 ms resolution); following = peak |setpoint - "
             "true angle| from the start of the move to MotionDone, and when (s after the profile's start)",
             f"  spec (the report): the tip within {SPEC_M * 1e3:g} mm (0.39 in)", ""]
    for gravity, r in res.gravities.items():
        lines.append(f"  {gravity}: homing {r.homing_s:.3f} s, {len(r.moves)} moves, {r.sim_s:.1f} simulated s; "
                     "worst of each joint's moves:")
        lines.append(f"    {'joint':<7}{'moves':>6}{'not done':>9}{'joint err mdeg':>15}{'tip err mm':>11}"
                     f"{'settle ms':>10}{'following mdeg':>15}{'at s':>6}")
        for joint in JOINTS:
            s = r.summary(joint)
            if not s.moves:
                continue
            lines.append(f"    {joint:<7}{s.moves:>6}{s.not_done:>9}{mdeg(s.max_joint_error_rad):>15}"
                         f"{mm(s.max_tip_error_m):>11}{ms(s.max_settle_s):>10}{mdeg(s.peak_following_rad):>15}"
                         f"{s.peak_following_at_s:>6.2f}")
        if r.moves:
            worst = r.max_tip_error_m
            lines.append(f"    worst tip error {mm(worst)} mm = {worst / SPEC_M:.1%} of the {SPEC_M * 1e3:g} mm spec  "
                         f"{'PASS' if worst <= SPEC_M and not r.error else 'FAIL'}")
        if r.error:
            lines.append(f"    FAILED: {r.error}")
        lines.append("")
    earth, orbit = res.gravities.get("earth"), res.gravities.get("orbit")
    if earth and orbit and earth.moves and orbit.moves:
        lines += ["  Earth against orbit (worst of each joint's moves; E/O = Earth's figure over orbit's):",
                  f"    {'':<7}{'joint err mdeg':^21}{'tip err mm':^24}{'settle ms':^21}{'following mdeg':^21}",
                  f"    {'joint':<7}" + f"{'earth':>8}{'orbit':>8}{'E/O':>6}" + f"{'earth':>9}{'orbit':>9}{'E/O':>6}"
                  + f"{'earth':>8}{'orbit':>8}{'E/O':>6}" + f"{'earth':>8}{'orbit':>8}{'E/O':>6}"]
        for joint in JOINTS:
            e, o = earth.summary(joint), orbit.summary(joint)
            if not (e.moves and o.moves):
                continue
            lines.append(
                f"    {joint:<7}"
                f"{mdeg(e.max_joint_error_rad):>8}{mdeg(o.max_joint_error_rad):>8}"
                f"{ratio(e.max_joint_error_rad, o.max_joint_error_rad):>6}"
                f"{mm(e.max_tip_error_m):>9}{mm(o.max_tip_error_m):>9}"
                f"{ratio(e.max_tip_error_m, o.max_tip_error_m, 1e-7):>6}"
                f"{ms(e.max_settle_s):>8}{ms(o.max_settle_s):>8}"
                f"{ratio(e.max_settle_s, o.max_settle_s, SETTLE_FLOOR_S):>6}"
                f"{mdeg(e.peak_following_rad):>8}{mdeg(o.peak_following_rad):>8}"
                f"{ratio(e.peak_following_rad, o.peak_following_rad):>6}")
        worst_e, worst_o = earth.max_tip_error_m, orbit.max_tip_error_m
        lines.append(f"    worst tip error: Earth {mm(worst_e)} mm, orbit {mm(worst_o)} mm, ratio "
                     f"{ratio(worst_e, worst_o)}; spec {SPEC_M * 1e3:g} mm")
        lines.append("")
    for gravity, r in res.gravities.items():
        for m in r.moves:
            if m.outcome != "DONE":
                lines.append(f"  NOTE {gravity} {m.joint} to {m.target_deg:+g} deg: {m.outcome}")
            if m.tip_error_m > SPEC_M:
                lines.append(f"  NOTE {gravity} {m.joint} to {m.target_deg:+g} deg: tip error {mm(m.tip_error_m)} mm, "
                             "above the spec")
    if res.pick_place:
        lines += pick_place_lines(res.pick_place)
    else:
        lines.append("  pick-and-place: skipped (--quick)")
    return "\n".join(lines).rstrip()


def pick_place_lines(reports: dict[str, dict]) -> list[str]:
    gravities = list(reports)
    names: list[str] = []
    for r in reports.values():
        for step in r.get("steps", []):
            if step["name"] not in names:
                names.append(step["name"])
    header = "".join(f"{g + ' mm':>12}" for g in gravities)
    lines = ["  pick-and-place (host_tools.apps.pick_place.run, as `aspod demo`): tip error after each step",
             f"    {'step':<34}{header}"]
    for name in names:
        cells = ""
        for g in gravities:
            step = next((s for s in reports[g].get("steps", []) if s["name"] == name), None)
            cells += f"{mm(step['position_error_m']) if step else '-':>12}"
        lines.append(f"    {name:<34}{cells}")
    cells = "".join(f"{mm(r['max_position_error_m']) if r.get('max_position_error_m') is not None else '-':>12}"
                    for r in reports.values())
    lines.append(f"    {'worst':<34}{cells}")
    verdict = "".join(f"{('PASS' if r.get('within_spec') else 'FAIL'):>12}" for r in reports.values())
    lines.append(f"    {f'within {SPEC_M * 1e3:g} mm':<34}{verdict}")
    for g, r in reports.items():
        if r.get("error"):
            lines.append(f"    {g}: FAILED: {r['error']}")
        elif r.get("sim_time_s") is not None:
            lines.append(f"    {g}: {r['sim_time_s']:.1f} simulated s in {r['wall_time_s']:.1f} wall s "
                         f"({r['speed_x_real_time']}x real time, for information)")
    return lines


def main(quick: bool = False) -> TrackingResults:
    results = run(quick)
    print(report(results), flush=True)
    return results


if __name__ == "__main__":
    import sys
    main(quick="--quick" in sys.argv[1:])
