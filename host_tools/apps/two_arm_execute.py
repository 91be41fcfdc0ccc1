"""A two-arm plan carried out on two live controllers: `aspod plan --execute LINK1,LINK2` (docs/two_arms.md).

Each arm's knots come from the plan as `aspod plan --output` writes them (two_arm_plan.py `controller_knots`).
Before anything moves, each controller's own limits are read over its link and the plan is checked against them
(`check_arm`): each joint's soft limits and speed parameter against the curve through its knots, its current limit
against the torque the plan asks of it, and the supply the controller measures against the voltage its motor needs
at the plan's speed and torque (back EMF plus the armature's drop), and the controller's gravity against the
plan's. A plan that would pass one is refused, naming the arm, the joint and the limit: nothing has moved.

Then each arm is made ready as its bench is (bench/bench_two_arms.py): enabled, homed unless it is, its jaws open,
its shoulder and elbow moved to the plan's start, its jaws closed on the object; both trajectories are uploaded and
started on one plant tick (two_arm_plan.py `start_together`). It is watched to its end: each arm's shoulder and
elbow in telemetry against its knots' curve, and, when the simulator serves a control endpoint, the object's true
pose and squeeze (its `state`). Waits are judged on the controllers' own clocks (their telemetry's uptime), so a
slow host or a paced world never looks like a stuck arm; a link silent for `SILENCE_S` of wall time ends it.
"""
from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np

from firmware_py.arm_config import ArmDescription, highest_speed_dps
from firmware_py.hermite import HermiteProfile
from host_tools.apps.arm_plan import ARM_JOINTS
from host_tools.apps.two_arm_figure import CarryTrace, carry_trace
from host_tools.apps.two_arm_plan import ELBOW, SHOULDER, curve_bounds_deg, start_together
from host_tools.client.live import HostClient
from host_tools.client.trajectory import Knot
from host_tools.plan.errors import PlanError
from host_tools.plan.phase import Problem
from host_tools.plan.profile import Profile
from protocol.messages import MESSAGES as M, SCHEMA, TRAJECTORY_JOINTS, started_motions
from protocol.states import Axis, ControllerState, GripAction, MotionOutcome

SILENCE_S = 5.0               # wall time without telemetry from a controller: its link is gone
READY_TIMEOUT_S = 120.0       # controller seconds for homing, a move to the start, a grip
RUN_SPARE_S = 10.0            # ... and for the trajectory, past the plan's duration
WATCH_PERIOD_S = 0.01         # how often the object is read from the control endpoint (wall time)
AFTER_S = 0.5                 # the figure goes on this long past the plan's end
GRAVITY_TOLERANCE = 0.05      # m/s^2: the controller's gravity parameter against the plan's
MOVE_DPS = 30.0               # the moves to the plan's start, at most (within each joint's speed parameter)
PLANNED_JOINTS = (SHOULDER, ELBOW)
ALL_HOMED = sum(1 << int(a) for a in Axis if a is not Axis.ALL)     # TelemetryJoints' homed bits, every axis


class ExecuteError(RuntimeError):
    """The run could not go on; the message says which arm and why (what moved by then is said too)."""


@dataclass(frozen=True)
class ArmLimits:
    """What one controller allows, read over its link: per joint its soft limits and speed (deg, deg/s) and
    current limit (A); its gravity parameter (m/s^2) and the supply it measures (V)."""

    soft_deg: dict[str, tuple[float, float]]
    speed_dps: dict[str, float]
    current_a: dict[str, float]
    gravity_m_s2: float
    supply_v: float


def planned_torques(problem: Problem, profile: Profile) -> np.ndarray:
    """The joints' torques (N m, one column per joint of the problem) at the profile's nodes: the planner's
    a s'' + b s'^2 + c, with the s'' of the interval each node starts (the last node its own)."""
    terms = problem.terms(profile.s)
    sdd = np.append(profile.sdd, profile.sdd[-1] if len(profile.sdd) else 0.0)
    return terms.a * sdd[:, None] + terms.b * (profile.sd ** 2)[:, None] + terms.c


def read_limits(client: HostClient) -> ArmLimits:
    """The controller's limits, asked over its link (ParamGet, GetStatus); ExecuteError if it does not answer."""
    values: dict[str, float] = {}
    names = [f"{j}_{what}" for j in ARM_JOINTS for what in ("min_deg", "max_deg", "speed_dps", "i_lim_a")]
    for name in names + ["gravity_m_s2"]:
        handle = client.call(M["ParamGet"](name))
        if not handle.ok:
            raise ExecuteError(f"{client.url}: ParamGet {name}: {handle.describe()}")
        values[name] = float(handle.reply.value)
    status = client.call(SCHEMA["GetStatus"].type())
    if not status.ok:
        raise ExecuteError(f"{client.url}: GetStatus: {status.describe()}")
    return ArmLimits(soft_deg={j: (values[f"{j}_min_deg"], values[f"{j}_max_deg"]) for j in ARM_JOINTS},
                     speed_dps={j: values[f"{j}_speed_dps"] for j in ARM_JOINTS},
                     current_a={j: values[f"{j}_i_lim_a"] for j in ARM_JOINTS},
                     gravity_m_s2=values["gravity_m_s2"], supply_v=float(status.reply.supply_v))


@dataclass(frozen=True)
class Refusal:
    """A limit the plan would pass, said naming the arm, the joint and the limit; for a speed parameter under the
    plan's need (and that need within the parameter's range), the value to raise it to (`--set-speeds`)."""

    text: str
    arm: int
    raise_to: Optional[tuple[str, float]] = None


def check_arm(number: int, knots: Sequence[Knot], torques_nm: np.ndarray, speeds_rad_s: np.ndarray,
              limits: ArmLimits, description: ArmDescription, gravity_m_s2: float) -> list[Refusal]:
    """What arm `number`'s controller would not allow of the plan ([] if nothing): its knots' curve against each
    joint's soft limits and speed parameter; the plan's torque (the arm's shoulder and elbow columns of
    `torques_nm`, at the plan's joint speeds `speeds_rad_s`) against the current limit, and the voltage it needs
    against the supply measured; its gravity parameter against the plan's."""
    problems: list[Refusal] = []
    if abs(limits.gravity_m_s2 - gravity_m_s2) > GRAVITY_TOLERANCE:
        problems.append(Refusal(f"arm {number}: the controller's gravity_m_s2 is {limits.gravity_m_s2:g}, the "
                                f"plan's {gravity_m_s2:g} m/s^2 (plan with --gravity for a simulator in Earth gravity, "
                                "without it for --gravity orbit)", number))
    for j, name in enumerate(ARM_JOINTS):
        lowest, highest, top = curve_bounds_deg(knots, j)
        low, high = limits.soft_deg[name]
        if lowest < low:
            problems.append(Refusal(f"arm {number} {name} reaches {lowest:.2f} deg, below {name}_min_deg {low:g}",
                                    number))
        if highest > high:
            problems.append(Refusal(f"arm {number} {name} reaches {highest:.2f} deg, above {name}_max_deg {high:g}",
                                    number))
        if top > limits.speed_dps[name] + 1e-6:
            need = math.ceil(top * 10) / 10
            within = need <= highest_speed_dps(description.drive(name))
            problems.append(Refusal(f"arm {number} {name} reaches {top:.1f} deg/s, above {name}_speed_dps "
                                    f"{limits.speed_dps[name]:g} (" + ("--set-speeds raises it to "
                                                                      f"{need:g}; or plan --slower)" if within else
                                                                      "its most; plan --slower)"),
                                    number, (f"{name}_speed_dps", need) if within else None))
    for column, j in enumerate(PLANNED_JOINTS):
        name, drive = ARM_JOINTS[j], description.drive(ARM_JOINTS[j])
        per_amp = drive.kt_nm_a * drive.ratio * drive.efficiency
        current = np.abs(torques_nm[:, column]) / per_amp
        volts = drive.kt_nm_a * drive.ratio * np.abs(speeds_rad_s[:, column]) + drive.r_ohm * current
        if float(current.max()) > limits.current_a[name]:
            problems.append(Refusal(f"arm {number} {name} needs {float(current.max()):.2f} A, above {name}_i_lim_a "
                                    f"{limits.current_a[name]:g}", number))
        worst = int(np.argmax(volts))
        if float(volts[worst]) > limits.supply_v:
            problems.append(Refusal(f"arm {number} {name} needs {float(volts[worst]):.1f} V (back EMF and its "
                                    f"armature's drop at the plan's speed and torque), above the supply's "
                                    f"{limits.supply_v:.1f} V", number))
    return problems


ALIGN_SPAN_MS = 200           # the trajectory's start is found within this of the TrajRun reply's telemetry


@dataclass
class ArmWatch:
    """One arm's telemetry, kept from the pump's thread: its latest uptime and state and, while `recording`, its
    shoulder's and elbow's angles (uptime ms, j1 deg, j2 deg)."""

    uptime_ms: int = 0
    state: int = int(ControllerState.BOOT)
    heard_wall_s: float = 0.0
    recording: bool = False
    samples: list = field(default_factory=list)
    homed: Optional[int] = None        # the latest TelemetryJoints' homed bits

    def telemetry(self, msg, now: float) -> None:
        self.heard_wall_s = now
        self.uptime_ms = max(self.uptime_ms, int(msg.uptime_ms))
        if msg.spec.name == "TelemetryStatus":
            self.state = int(msg.state)
        elif msg.spec.name == "TelemetryJoints":
            self.homed = int(msg.homed)
            if self.recording:
                self.samples.append((int(msg.uptime_ms), float(msg.j1_pos), float(msg.j2_pos)))


def tracking_error_deg(samples: Sequence[tuple[int, float, float]], knots: Sequence[Knot], near_ms: int
                       ) -> tuple[float, int]:
    """The shoulder's and elbow's worst distance (deg) from their knots' curve, and the start (uptime ms) it is
    measured from. The link does not say on which tick a trajectory started (only the two controllers know: docs/
    two_arms.md), so the start is the one within ALIGN_SPAN_MS of `near_ms` that fits the telemetry best (worst
    error least), at 1 ms steps."""
    curves = [HermiteProfile([k.t_s for k in knots], [math.radians(k.q_deg[j]) for k in knots],
                             [math.radians(k.qd_deg_s[j]) for k in knots]) for j in PLANNED_JOINTS]
    duration = knots[-1].t_s
    times = np.array([u for u, _, _ in samples], dtype=float)
    angles = np.array([(a, b) for _, a, b in samples])
    planned_at = {}

    def worst(start_ms: int) -> float:
        t = np.clip((times - start_ms) / 1000.0, 0.0, duration)
        inside = (times >= start_ms) & (times <= start_ms + 1000.0 * duration + 500.0)
        if not inside.any():
            return math.inf
        key = tuple(np.round(t[inside], 6))
        if key not in planned_at:
            planned_at[key] = np.array([[math.degrees(c.sample(x)[0]) for c in curves] for x in t[inside]])
        return float(np.abs(angles[inside] - planned_at[key]).max())
    best = min(range(near_ms - ALIGN_SPAN_MS, near_ms + ALIGN_SPAN_MS + 1), key=worst)
    return worst(best), best


def path_error_m(problem: Problem, points: Sequence[tuple[float, float]], resolution: int = 4001) -> float:
    """The worst distance (m) of the object's centre at `points` from its path (the nearest of `resolution`
    points along w(s))."""
    w = problem.path(np.linspace(0.0, 1.0, resolution)).w
    return max((float(np.min(np.hypot(w[:, 0] - x, w[:, 1] - z))) for x, z in points), default=math.nan)


@dataclass(frozen=True)
class Executed:
    """What a run measured: per arm its tracking error (deg, telemetry against its knots' curve, from the start
    that fits best) and how its joints' motions ended; the plan's time and the time until every joint's motion had
    ended (controller time); from the simulator's control endpoint, if there is one: the object's worst distance
    from its path, its largest squeeze and its grasps' states, and how many readings of it (None without)."""

    tracking_deg: tuple[float, float]
    outcomes: tuple[dict[str, str], dict[str, str]]
    plan_s: float
    ended_s: float
    path_error_m: Optional[float]
    squeeze_n: Optional[float]
    grasps: Optional[list[str]]
    object_readings: int = 0
    trace: Optional[CarryTrace] = None     # plan against execution, from the control endpoint's readings


class TwoArmRun:
    """Carry out a two-arm plan on two controllers (`clients`: the leader's, arm 1, then arm 2's)."""

    def __init__(self, clients: tuple[HostClient, HostClient], knots: tuple[Sequence[Knot], Sequence[Knot]],
                 log=lambda text: None) -> None:
        self.clients, self.knots, self.log = clients, knots, log
        self.watches = (ArmWatch(), ArmWatch())
        for client, watch in zip(clients, self.watches):
            client.telemetry_listeners.append(watch.telemetry)

    # ---- waiting, on the controllers' clocks ----
    def _wait(self, arm: int, predicate, timeout_s: float, what: str) -> None:
        client, watch = self.clients[arm], self.watches[arm]
        start_ms = watch.uptime_ms
        while not predicate():
            if client.wait_for(predicate, 0.05):
                return
            if client.io_error is not None:
                raise ExecuteError(f"arm {arm + 1}: {what}: the link failed: {client.io_error}")
            if (watch.uptime_ms - start_ms) / 1000.0 > timeout_s:
                raise ExecuteError(f"arm {arm + 1}: {what}: not done in {timeout_s:g} s of the controller's time")
            if client.clock.now() - watch.heard_wall_s > SILENCE_S:
                raise ExecuteError(f"arm {arm + 1}: {what}: no telemetry for {SILENCE_S:g} s (wall clock)")
            if watch.state in (int(ControllerState.FAULT), int(ControllerState.ESTOP)):
                raise ExecuteError(f"arm {arm + 1}: {what}: the controller went to "
                                   f"{ControllerState(watch.state).name}")

    def _done(self, arm: int, motions: dict[int, int]) -> dict[int, object]:
        """The MotionDone of each of `motions` (axis: motion id) that has ended."""
        ended = {}
        for e in list(self.clients[arm].events):
            if e.spec.name == "MotionDone" and motions.get(int(e.axis)) == e.motion_id:
                ended[int(e.axis)] = e
        return ended

    def _motions(self, messages: Sequence[Sequence], what: str, timeout_s: float = READY_TIMEOUT_S) -> None:
        """Each arm's motion commands (`messages[arm]`, perhaps none), all sent, then all waited for; ExecuteError
        naming the arm if one is refused or does not end DONE."""
        started: list[dict[int, int]] = [{}, {}]
        for arm, commands in enumerate(messages):
            for msg in commands:
                handle = self.clients[arm].call(msg)
                if not handle.ok:
                    raise ExecuteError(f"arm {arm + 1}: {what}: {handle.describe()}")
                started[arm].update(started_motions(handle.reply))
        for arm, motions in enumerate(started):
            self._wait(arm, lambda arm=arm, motions=motions: len(self._done(arm, motions)) == len(motions),
                       timeout_s, what)
            bad = {Axis(a).name.lower(): MotionOutcome(e.outcome).name for a, e in self._done(arm, motions).items()
                   if e.outcome != MotionOutcome.DONE}
            if bad:
                raise ExecuteError(f"arm {arm + 1}: {what}: " + ", ".join(f"{k} {v}" for k, v in bad.items()))

    # ---- the run ----
    def ready(self, start_deg: tuple[tuple[float, float], tuple[float, float]], speed_dps: tuple[float, float]
              ) -> None:
        """Both arms enabled, homed (those joints that are not), their jaws open, their shoulders and elbows at the
        plan's start, then their jaws closed on the object: each step sent to both, then waited for."""
        for arm, client in enumerate(self.clients):
            status = client.call(SCHEMA["GetStatus"].type())
            if not status.ok:
                raise ExecuteError(f"arm {arm + 1}: GetStatus: {status.describe()}")
            if status.reply.state == ControllerState.IDLE:
                enable = client.call(M["Enable"]())
                if not enable.ok:
                    raise ExecuteError(f"arm {arm + 1}: Enable: {enable.describe()}")
            elif status.reply.state != ControllerState.ENABLED:
                raise ExecuteError(f"arm {arm + 1}: the controller is {ControllerState(status.reply.state).name}: "
                                   "reset it first")
        for arm in range(2):
            self._wait(arm, lambda arm=arm: self.watches[arm].homed is not None, 5.0, "the first TelemetryJoints")
        self.log("both arms: homing what is not homed, opening the jaws, to the plan's start")
        self._motions([[] if self.watches[arm].homed == ALL_HOMED else [M["Home"](int(Axis.ALL))]
                       for arm in range(2)], "home all")
        self._motions([[M["Grip"](int(GripAction.OPEN))]] * 2, "open the jaws")
        self._motions([[M["Move"](int(axis), start_deg[arm][j], speed_dps[arm])
                        for j, axis in enumerate((Axis.J1, Axis.J2))] for arm in range(2)],
                      "move the shoulder and elbow to the start")
        self._motions([[M["Grip"](int(GripAction.CLOSE))]] * 2, "close the jaws on the object")

    def run(self, problem: Problem, profile: Profile, control=None) -> Executed:
        """Both trajectories started on one tick and watched to their end; the object read from `control` (the
        simulator's endpoint) meanwhile, if given."""
        objects: list = []
        stop = threading.Event()
        reader = None
        if control is not None:
            reader = threading.Thread(target=_read_object, args=(control, objects, stop), daemon=True)
            reader.start()
        plan_s = profile.duration
        for watch in self.watches:
            watch.recording = True
        try:
            ids = start_together(self.clients[0], self.clients[1], self.knots)
            near = [watch.uptime_ms for watch in self.watches]
            wanted = [{int(a): i for a, i in zip(TRAJECTORY_JOINTS, motions)} for motions in ids]
            for arm in range(2):
                self._wait(arm, lambda arm=arm: len(self._done(arm, wanted[arm])) == len(wanted[arm]),
                           plan_s + RUN_SPARE_S, "the trajectory")
        finally:
            stop.set()
            for watch in self.watches:
                watch.recording = False
            if reader is not None:
                reader.join(timeout=1.0)
        fits = [tracking_error_deg(w.samples, k, n) for w, k, n in zip(self.watches, self.knots, near)]
        ended = [self._done(arm, wanted[arm]) for arm in range(2)]
        outcomes = tuple({Axis(a).name.lower(): MotionOutcome(e.outcome).name for a, e in done.items()}
                         for done in ended)
        ended_s = max((int(e.uptime_ms) - fits[arm][1]) / 1000.0 for arm in range(2) for e in ended[arm].values())
        held = [state for _, state in objects if state and state.get("held")]
        start_s = fits[0][1] / 1000.0          # the controllers' uptime counts the world's time from its start
        during = [(t - start_s, state) for t, state in objects if state and "x_m" in state
                  and 0.0 <= t - start_s <= plan_s + AFTER_S]
        trace = None if not during else carry_trace(
            problem, profile, [t for t, _ in during], [(s["x_m"], s["z_m"]) for _, s in during],
            [s["squeeze_n"] for _, s in during],
            [[math.radians(a) for arm in s["shoulder_elbow_deg"] for a in arm] for _, s in during])
        return Executed(tracking_deg=(fits[0][0], fits[1][0]), outcomes=outcomes, plan_s=plan_s, ended_s=ended_s,
                        path_error_m=path_error_m(problem, [(s["x_m"], s["z_m"]) for s in held]) if held else None,
                        squeeze_n=max((abs(s["squeeze_n"]) for s in held), default=None),
                        grasps=sorted({g["state"] for s in held for g in s["grasps"]}) if held else None,
                        object_readings=len(held), trace=trace)


def _read_object(control, objects: list, stop: threading.Event) -> None:
    """The object, as the control endpoint's `state` says it, every WATCH_PERIOD_S until `stop`."""
    while not stop.wait(WATCH_PERIOD_S):
        try:
            reply = control.request({"op": "state"})
        except Exception:            # the endpoint went away: the run goes on without the object's truth
            return
        if reply.get("ok"):
            objects.append((reply["time_s"], reply["state"].get("object")))


def execute(problem: Problem, profile: Profile, knots: tuple[Sequence[Knot], Sequence[Knot]], settings,
            keys: tuple[bytes, bytes], log=lambda text: None) -> tuple[dict, Optional[CarryTrace]]:
    """`aspod plan --execute`: connect to both controllers (`settings.execute`, arm 1's first, with `keys`), check the plan against what each allows (PlanError naming every limit it would pass,
    before anything moves; with `settings.set_speeds`, a speed parameter under the plan's is raised to it, within
    its range, and said), make both arms ready, carry the object, and say what was measured (JSON values), with the
    trace of plan against execution when the simulator's endpoint gave the object (None without)."""
    from firmware_py.arm_config import EXAMPLE_ARM
    from host_tools.client.control import open_control
    torques = planned_torques(problem, profile)
    path = problem.system.joint_path(problem.path, profile.s)
    speeds = path.q_s * profile.sd[:, None]
    clients: list[HostClient] = []
    control = None
    try:
        for url, key in zip(settings.execute, keys):
            clients.append(HostClient(url, key))
            clients[-1].connect()
        control = open_control(settings.execute[0])
        gravity = float(problem.system.gravity)
        limits = [read_limits(c) for c in clients]
        problems = [p for arm in range(2) for p in check_arm(arm + 1, knots[arm], torques[:, 2 * arm:2 * arm + 2],
                                                             speeds[:, 2 * arm:2 * arm + 2], limits[arm], EXAMPLE_ARM,
                                                             gravity)]
        raised = [p for p in problems if settings.set_speeds and p.raise_to is not None]
        refused = [p.text for p in problems if p not in raised]
        if refused:
            raise PlanError("limits", "the controllers would not allow this plan, nothing moved: " + "; ".join(refused))
        speeds_dps = [dict(arm.speed_dps) for arm in limits]
        for p in raised:
            name, value = p.raise_to
            reply = clients[p.arm - 1].call(M["ParamSet"](name, value))
            if not reply.ok or reply.reply.result != 0:
                raise PlanError("limits", f"arm {p.arm}: ParamSet {name} {value:g}: {reply.describe()}; nothing moved")
            speeds_dps[p.arm - 1][name.split("_")[0]] = value
            log(f"arm {p.arm}: {name} raised to {value:g} (--set-speeds)")
        run = TwoArmRun((clients[0], clients[1]), knots, log)
        run.ready(tuple((k[0].q_deg[0], k[0].q_deg[1]) for k in knots),
                  tuple(min(MOVE_DPS, s["j1"], s["j2"]) for s in speeds_dps))
        if control is not None:
            held = control.request({"op": "state"}).get("state", {}).get("object")
            if held is not None and not held.get("held"):
                raise ExecuteError("both jaws closed at the plan's start, but the object is not between them (the "
                                   "simulator's control endpoint says so): its hands are not at its grasps")
        log(f"both arms at the plan's start, the object held; running the plan ({profile.duration:.3f} s)")
        done = run.run(problem, profile, control)
    finally:
        for client in clients:
            client.close()
        if control is not None:
            control.close()
    return {"links": list(settings.execute), "plan_s": round(done.plan_s, 6), "ended_s": round(done.ended_s, 3),
            "tracking_deg": [round(x, 3) for x in done.tracking_deg], "outcomes": list(done.outcomes),
            "object": None if done.path_error_m is None else {
                "path_error_mm": round(done.path_error_m * 1e3, 3), "squeeze_n": round(done.squeeze_n, 3),
                "grasps": done.grasps, "readings": done.object_readings}}, done.trace
