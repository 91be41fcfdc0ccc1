"""A two-arm plan as the two controllers' trajectories (issue 39, docs/two_arms.md).

The planner (host_tools/plan) plans the object's progress s(t) along its path w(s); each arm's shoulder and elbow
follow q(s) (the planner's inverse kinematics, `TwoArms.joint_path`) at speeds q_s s'. Each arm's controller follows
knots of j1..j4 and the mount (firmware_py/trajectory.py): its shoulder is j1 and its elbow j2, as the example arm
is built (hil_sim/arm_params.py `EXAMPLE_ARM_PLANT`: both angles as the planner measures them), and j3, j4 and the
mount hold where they are (`held_deg`). Knots are evenly spaced in time on the exact profile (s'' constant
between its nodes), as `PlannedMove.knots` places a move's. `start_together` uploads both and starts them on one
plant tick: the second arm's controller armed first, then the first's, which leads (firmware_py/trajectory_sync.py).
"""
from __future__ import annotations

import dataclasses
import math
from typing import Sequence

import numpy as np

from host_tools.client.trajectory import Caller, Knot, run_trajectory, upload_trajectory
from host_tools.plan.phase import Problem
from host_tools.plan.profile import Profile
from protocol.messages import TRAJECTORY_JOINTS

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


def start_together(leader: Caller, follower: Caller, knots: tuple[Sequence[Knot], Sequence[Knot]]
                   ) -> tuple[list[int], list[int]]:
    """Upload each arm's knots to its controller (`leader`: the first arm's), arm the follower's, start the
    leader's: both start on the tick the leader names. Each arm's motion ids (j1..j4 and the mount); ValueError
    or TrajectoryRefused (nothing started) as `send_trajectory`."""
    upload_trajectory(leader, knots[0])
    upload_trajectory(follower, knots[1])
    followed = run_trajectory(follower, len(knots[1]))
    return run_trajectory(leader, len(knots[0])), followed
