"""A two-arm plan as the two controllers' trajectories (issue 39, docs/two_arms.md).

The planner (host_tools/plan) plans the object's progress s(t) along its path w(s); each arm's shoulder and elbow
follow q(s) (the planner's inverse kinematics, `TwoArms.joint_path`) at speeds q_s s'. Each arm's controller follows
knots of j1..j4 and the mount (firmware_py/trajectory.py): its shoulder is j1 and its elbow j2, as the example arm
is built (hil_sim/arm_params.py `EXAMPLE_ARM_PLANT`: both angles as the planner measures them), and j3, j4 and the
mount hold where they are (`held_deg`). Knots are evenly spaced in time on the exact profile (s'' constant
between its nodes), as `PlannedMove.knots` places a move's. `start_together` uploads both and starts them on one
plant tick: the second arm's controller armed first, then the first's, which leads (firmware_py/trajectory_sync.py).

`executable_plan` makes the plan they can follow (the minimum-time plan within a share of the torque limits, run
slower), and `controller_knots` each arm's knots for its controller, refused (PlanError) if the curve through them
would pass a joint's soft limit or speed limit, or a hand's force the grip's limit (`within_grip`): what `aspod plan
--output FILE` writes (host_tools/client/trajectory.py's two-arm file).
"""
from __future__ import annotations

import dataclasses
import math
from typing import Sequence

import numpy as np

from firmware_py.arm_config import ArmDescription, highest_speed_dps
from firmware_py.hermite import HermiteProfile
from firmware_py.trajectory import TRAJECTORY_KNOTS
from hil_sim.arm_params import EXAMPLE_ARM_PLANT, ArmPlantParams
from hil_sim.held_object import ObjectParams
from hil_sim.plant import PlantParams
from host_tools.apps.arm_plan import ARM_JOINTS, homed_pose_rad, knots_within_speed
from host_tools.client.trajectory import (Caller, Knot, TrajectoryRefused, point_message, run_trajectory,
                                         upload_trajectory)
from host_tools.plan.errors import PlanError
from host_tools.plan.phase import Problem
from host_tools.plan.profile import Profile
from host_tools.plan.reach import plan_reach_checked
from protocol.messages import MESSAGES as M, SCHEMA, TRAJECTORY_JOINTS

ARMS = 2
SHOULDER, ELBOW = 0, 1           # their places among the trajectory's joints (j1, j2)


def profile_at(profile: Profile, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """s and s' at `times` (seconds from the start), exactly: s'' is constant between the profile's nodes."""
    i = np.clip(np.searchsorted(profile.t, times, side="right") - 1, 0, len(profile.sdd) - 1)
    tau = times - profile.t[i]
    s = profile.s[i] + profile.sd[i] * tau + profile.sdd[i] * tau * tau / 2.0
    sd = profile.sd[i] + profile.sdd[i] * tau
    end = times >= profile.duration
    s[end], sd[end] = profile.s[-1], 0.0
    return s, sd


def arm_knots(problem: Problem, profile: Profile, count: int, arm: int, held_deg: Sequence[float]) -> list[Knot]:
    """Arm `arm`'s (0 or 1) `count` knots along `profile`: its shoulder and elbow as the plan moves them, the other
    joints of its trajectory at `held_deg` (j1..j4 and the mount, degrees; its shoulder's and elbow's are ignored)."""
    if arm not in range(ARMS):
        raise ValueError(f"arm is 0 or 1, not {arm}")
    if len(held_deg) != len(TRAJECTORY_JOINTS):
        raise ValueError(f"held_deg: {len(TRAJECTORY_JOINTS)} angles (j1..j4 and the mount), not {len(held_deg)}")
    times = np.linspace(0.0, profile.duration, count)
    s, sd = profile_at(profile, times)
    s[0], sd[0] = profile.s[0], 0.0
    path = problem.system.joint_path(problem.path, s)
    q, qd = path.q[:, 2 * arm:2 * arm + 2], path.q_s[:, 2 * arm:2 * arm + 2] * sd[:, None]
    knots = []
    for k, t in enumerate(times):
        angles, speeds = list(held_deg), [0.0] * len(TRAJECTORY_JOINTS)
        for j in (SHOULDER, ELBOW):
            angles[j], speeds[j] = math.degrees(q[k, j]), math.degrees(qd[k, j])
        knots.append(Knot(float(t), tuple(angles), tuple(speeds)))
    return knots


def start_pose_deg(problem: Problem) -> tuple[tuple[float, float], tuple[float, float]]:
    """Each arm's shoulder and elbow (degrees) where the plan starts: where the arms go before they take the
    object."""
    q = problem.system.joint_path(problem.path, np.array([0.0])).q[0]
    return (math.degrees(q[0]), math.degrees(q[1])), (math.degrees(q[2]), math.degrees(q[3]))


def slowed(profile: Profile, factor: float) -> Profile:
    """`profile` run `factor` times slower: the same path, s' / factor and s'' / factor^2 (the torques' dynamic
    part falls by factor^2; gravity's stays)."""
    if not (math.isfinite(factor) and factor >= 1.0):
        raise ValueError(f"a plan is slowed by a factor of 1 or more, not {factor!r}")
    return dataclasses.replace(profile, t=profile.t * factor, sd=profile.sd / factor,
                               sdd=profile.sdd / factor ** 2)


def executable_plan(problem: Problem, torque_share: float, slower: float, gridpoints: int) -> tuple[Problem, Profile]:
    """The minimum-time plan within `torque_share` of the problem's limits (each joint's range shrunk about its
    middle: -30..30 N m to -24..24 at 0.8; the rest is the loops' to follow it with), run `slower` times slower (the
    loops lag the fastest accelerations: docs/planning.md), and the problem so limited. Planned by reachability,
    order 1, on `gridpoints` points: every limit kept between them too, and s'' constant between them, as
    `profile_at` takes it."""
    if not (math.isfinite(torque_share) and 0.05 <= torque_share <= 1.0):
        raise PlanError("bounds", f"a plan uses a share of the torque limits between 0.05 and 1, not {torque_share!r}")
    lo, hi = problem.limits.lo, problem.limits.hi
    middle, half = (hi + lo) / 2, torque_share * (hi - lo) / 2
    limits = dataclasses.replace(problem.limits, lower=tuple(map(float, middle - half)),
                                 upper=tuple(map(float, middle + half)))
    limited = dataclasses.replace(problem, limits=limits)
    plan, _, _ = plan_reach_checked(limited, gridpoints)
    return limited, slowed(plan.profile, slower)


GRIP_SAMPLES = 8         # the hands' forces are judged at this many times on each of the plan's intervals, its ends too


def hand_forces_n(problem: Problem, profile: Profile, per_interval: int = GRIP_SAMPLES
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The times (K,) and the force [N] across each hand's grasp there (K, 2) along `profile`: the object's mass
    times its acceleration less gravity, shared between the hands as the plan shares it (`TwoArms.grasp_forces`:
    no squeeze). Judged at `per_interval` times on each interval of constant s'', its two ends with its own s''
    (where s'' jumps the force does too)."""
    tau = np.linspace(0.0, 1.0, per_interval)[None, :] * np.diff(profile.t)[:, None]      # (intervals, k)
    sdd = np.repeat(profile.sdd[:, None], per_interval, axis=1)
    sd = profile.sd[:-1, None] + sdd * tau
    s = np.clip(profile.s[:-1, None] + profile.sd[:-1, None] * tau + sdd * tau * tau / 2.0, profile.s[0], profile.s[-1])
    points = problem.path(s.ravel())
    w_dd = points.w_s * sdd.ravel()[:, None] + points.w_ss * (sd.ravel() ** 2)[:, None]
    grasp = problem.system.grasp_forces(w_dd)
    forces = np.stack([np.hypot(grasp[:, 0], grasp[:, 1]), np.hypot(grasp[:, 2], grasp[:, 3])], axis=1)
    return (profile.t[:-1, None] + tau).ravel(), forces


def grip_limit_n(description: ArmDescription, held: ObjectParams = ObjectParams(),
                 plant: ArmPlantParams = EXAMPLE_ARM_PLANT) -> tuple[float, str]:
    """The grip's limit [N] of an arm of `description` holding `held` (the plant's object: its friction) and what
    sets it: friction times the jaws' force, the plant's gripper holding at the controller's default
    `grip_hold_duty` from the nominal supply (`ArmPlantParams.jaw_force_n`; hil_sim/held_object.py)."""
    duty = next(spec.default for spec in description.parameter_table() if spec.name == "grip_hold_duty")
    supply_v = PlantParams().supply_nominal_v
    jaws_n = plant.jaw_force_n(duty, supply_v)
    return held.friction * jaws_n, (f"friction {held.friction:g} x the jaws' {jaws_n:.1f} N at grip_hold_duty "
                                    f"{duty:g} and {supply_v:g} V")


def within_grip(problem: Problem, profile: Profile, limit_n: float, why: str) -> None:
    """PlanError naming the arm, the force and when, if a hand's force (`hand_forces_n`) would pass the grip's
    limit `limit_n` (`why`: what sets it) anywhere along `profile`: the object would slip in that hand."""
    times, forces = hand_forces_n(problem, profile)
    k, arm = np.unravel_index(int(np.argmax(forces)), forces.shape)
    if forces[k, arm] > limit_n:
        raise PlanError("bounds", f"arm {arm + 1}'s grasp carries {forces[k, arm]:.1f} N at t = {times[k]:.3f} s, "
                                  f"above the grip's limit {limit_n:.1f} N ({why}): the object would slip; the plan "
                                  "must be gentler or the object lighter")


def speed_limits_dps(description: ArmDescription) -> dict[str, tuple[float, str]]:
    """Each joint's fastest trajectory speed [deg/s] for a controller of `description`, and what sets it: its speed
    cap (the most its `<joint>_speed_dps` may be), or the TrajPoint's declared range of a knot's velocity."""
    fields = {f.name: f for f in SCHEMA["TrajPoint"].fields}
    limits = {}
    for name in ARM_JOINTS:
        knot_dps, cap_dps = fields[f"{name}_vel"].range[1], highest_speed_dps(description.drive(name))
        limits[name] = ((knot_dps, "the TrajPoint's range of a knot's velocity") if knot_dps <= cap_dps else
                        (cap_dps, f"its speed cap, the most {name}_speed_dps may be"))
    return limits


def curve_bounds_deg(knots: Sequence[Knot], joint: int) -> tuple[float, float, float]:
    """The lowest and highest angle [deg] and the highest speed [deg/s] of joint `joint` (its place among j1..j4 and
    the mount) on the curve through `knots`, as the controller judges a trajectory (`HermiteProfile.bounds`)."""
    lowest, highest, top = HermiteProfile([k.t_s for k in knots], [math.radians(k.q_deg[joint]) for k in knots],
                                          [math.radians(k.qd_deg_s[joint]) for k in knots]).bounds()
    return math.degrees(lowest), math.degrees(highest), math.degrees(top)


def controller_knots(problem: Problem, profile: Profile, fewest: int, description: ArmDescription,
                     held_object: ObjectParams = ObjectParams()) -> tuple[list[Knot], list[Knot]]:
    """Each arm's knots along `profile` for its controller (both arms' `description`): its shoulder and elbow as the
    plan moves them, the other joints where `home all` leaves them; `fewest` knots or more, until the curve through
    them stays within each joint's speed limit (`knots_within_speed`). PlanError naming the arm and the force if a
    hand would carry more than the grip holds (`within_grip`, `held_object`'s friction: the plant's object), or
    naming the arm, the joint and the limit if the curve would pass its soft limit or its speed limit
    (`speed_limits_dps`) anywhere, as TrajRun would refuse it, or a knot the TrajPoint cannot carry."""
    within_grip(problem, profile, *grip_limit_n(description, held_object))
    held = [math.degrees(q) for q in homed_pose_rad(description).values()]
    limits = speed_limits_dps(description)
    speeds = {name: math.radians(dps) for name, (dps, _) in limits.items()}
    arms = []
    for arm in range(ARMS):
        def knots_of(count: int, arm: int = arm) -> list[Knot]:
            return arm_knots(problem, profile, count, arm, held)
        try:
            knots = knots_within_speed(knots_of, speeds, fewest)
        except PlanError:
            knots = knots_of(TRAJECTORY_KNOTS)        # the most the controller takes: what it passes is said below
        for j, name in enumerate(ARM_JOINTS):
            drive = description.drive(name)
            lowest, highest, top = curve_bounds_deg(knots, j)
            speed_dps, why = limits[name]
            for passed, detail in (
                    (lowest < drive.soft_min_deg, f"reaches {lowest:.2f} deg, below its soft limit "
                                                  f"{drive.soft_min_deg:g} deg ({name}_min_deg)"),
                    (highest > drive.soft_max_deg, f"reaches {highest:.2f} deg, above its soft limit "
                                                   f"{drive.soft_max_deg:g} deg ({name}_max_deg)"),
                    (top > speed_dps, f"reaches {top:.1f} deg/s, above {speed_dps:g} deg/s ({why}): the plan must "
                                      "be slower")):
                if passed:
                    raise PlanError("bounds", f"arm {arm + 1} ({description.name} arm) {name} {detail}")
        for index, knot in enumerate(knots):
            try:
                point_message(index, knot)             # its time too: at most the TrajPoint's 3600 s
            except ValueError as exc:
                raise PlanError("bounds", f"arm {arm + 1}: {exc}") from None
        arms.append(knots)
    return arms[0], arms[1]


def start_together(leader: Caller, follower: Caller, knots: tuple[Sequence[Knot], Sequence[Knot]]
                   ) -> tuple[list[int], list[int]]:
    """Upload each arm's knots to its controller (`leader`: the first arm's), arm the follower's, start the
    leader's: both start on the tick the leader names. Each arm's motion ids (j1..j4 and the mount); ValueError
    or TrajectoryRefused (nothing started) as `send_trajectory`: the leader's refusal stops the follower's armed
    trajectory (Stop: all its motion), which would otherwise keep its joints busy and its buffer locked for 10 s
    (firmware_py/trajectory_sync.py ARMED_S)."""
    upload_trajectory(leader, knots[0])
    upload_trajectory(follower, knots[1])
    followed = run_trajectory(follower, len(knots[1]))
    try:
        return run_trajectory(leader, len(knots[0])), followed
    except TrajectoryRefused as refused:
        if refused.answered:        # the leader started nothing (a lost reply: it may have, and the follower with it)
            follower.call(M["Stop"]())
        raise
