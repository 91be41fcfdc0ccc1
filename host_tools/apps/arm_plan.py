"""Time-optimal joint moves for ASPOD's own arm, under its motors' voltage and current limits (issue 16, item 6).

The path is a straight line in joint space, q(s) = q0 + s (q1 - q0), for the joints that move (J1..J4 and the
mount). The model
is the firmware's description of ASPOD's arm (firmware_py/arm_config.py `ASPOD_ARM`), as ground software would have
it, not the plant's truth (it holds for ASPOD's arm alone, whose rotors outweigh their loads; not for the example
arm's, whose loads are up to 35 times their rotors: its moves are the two-arm planner's, host_tools/plan):

* each joint is its own axis: inertia J = the rotor reflected through the train plus the output's own, plus the
  drive's typical (outstretched) arm load, so the mass matrix is diagonal and constant (the plant neglects the
  coupling too: every joint sees its rotor through 300:1 to 1600:1);
* gravity is the mass model's holding torques (`MassModel.holding_torques_nm`, with the payload); J4 (a roll
  about the gripper's axis) and the mount (about a vertical shaft) hold none;
* viscous friction at the joint.

Joint torque u = J q'' + v q' + g(q). The motor, with efficiency eta through a train of ratio N, draws
i = u / (eta k N) and needs V = R i + k N q'. Both are limited, so each joint gives two bounded quantities of the
planner's one form a s'' + b s'^2 + d s' + c (host_tools/plan/bounds.py):

    current:  |u| <= eta k N i_max                          (d: the friction alone)
    voltage:  |u + (eta k^2 N^2 / R) q'| <= eta k N V / R   (d: friction plus back-emf)

with i_max and V shares of the current limit parameter and the 28 V supply (`ArmPlanSettings`): the rest is the
loops' authority to correct what the model does not know. Each joint's speed limit (the controller refuses a
trajectory faster than `jN_speed_dps`) caps s' at min over the joints of v_max / |q1 - q0|. The profile comes
from the report's phase-plane planner (host_tools/plan/timeopt.py), and `knots` turns it into the trajectory the controller follows.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable
import numpy as np

from firmware_py.arm_config import ASPOD_ARM, SUPPLY_NOMINAL_V, ArmDescription, Drive, axis_config
from firmware_py.hermite import HermiteProfile
from firmware_py.trajectory import TRAJECTORY_KNOTS
from host_tools.client.trajectory import Knot
from host_tools.plan.bounds import Limits
from host_tools.plan.errors import PlanError
from host_tools.plan.model import Coefficients, JointPath
from host_tools.plan.phase import Problem
from host_tools.plan.timeopt import TimeOptimal, plan_time_optimal
from protocol.messages import TRAJECTORY_JOINTS

ARM_JOINTS = tuple(a.name.lower() for a in TRAJECTORY_JOINTS)       # j1..j4 and the mount
HELD = ("j1", "j2", "j3")                                             # the joints that hold against gravity
MOVE_EPS_RAD = 1e-6          # a joint that moves less than this is not part of the path
SPEED_SHARE = 0.98           # of each joint's speed limit: the knots' cubics may overshoot a knot's speed a little


@dataclass(frozen=True)
class ArmPlanSettings:
    voltage_share: float = 0.7       # of the nominal supply the plan may use
    current_share: float = 0.9       # of each joint's current limit (J1 holds the arm stretched out at 72 %)
    nodes: int = 200                 # phase-plane intervals
    knots: int = 41                  # trajectory knots sent to the controller (the profile resampled in time)

    def __post_init__(self) -> None:
        for name in ("voltage_share", "current_share"):
            if not 0.05 <= getattr(self, name) <= 1.0:
                raise PlanError("bounds", f"{name} {getattr(self, name)}: between 0.05 and 1")
        if not 20 <= self.nodes <= 20000:
            raise PlanError("grid", f"nodes {self.nodes}: between 20 and 20000")
        if not 2 <= self.knots <= TRAJECTORY_KNOTS:
            raise PlanError("grid", f"knots {self.knots}: between 2 and {TRAJECTORY_KNOTS} (the controller's buffer)")


@dataclass(frozen=True)
class JointLine:
    """The straight joint-space path from q0 to q1 (rad, one per moving joint)."""

    q0: np.ndarray
    q1: np.ndarray

    def q(self, s) -> np.ndarray:
        s = np.atleast_1d(np.asarray(s, float))[:, None]
        return self.q0 + s * (self.q1 - self.q0)


def _torque_per_amp(d: Drive) -> float:
    return d.efficiency * d.kt_nm_a * d.ratio


@dataclass(frozen=True)
class ArmJoints:
    """The moving joints' model, as `Problem.system`: every joint appears twice, its current then its voltage."""

    names: tuple[str, ...]
    gravity_m_s2: float
    payload_kg: float
    fixed_rad: tuple[float, float, float]      # J1..J3 as they stand, for the gravity of joints that do not move

    @property
    def drives(self) -> list[Drive]:
        return [ASPOD_ARM.drive(n) for n in self.names]

    def gravity_nm(self, q: np.ndarray) -> np.ndarray:
        """(N, joints): the holding torque of each moving joint along q (N, joints)."""
        full = np.tile(np.asarray(self.fixed_rad, float), (len(q), 1))
        for k, name in enumerate(self.names):
            if name in HELD:
                full[:, HELD.index(name)] = q[:, k]
        torques = np.array([ASPOD_ARM.masses.holding_torques_nm(*row, self.gravity_m_s2, self.payload_kg)
                            for row in full])
        return np.stack([torques[:, HELD.index(n)] if n in HELD else np.zeros(len(q)) for n in self.names], axis=1)

    def coefficients(self, path: JointLine, s) -> Coefficients:
        s = np.atleast_1d(np.asarray(s, float))
        q = path.q(s)
        q_s = np.tile(path.q1 - path.q0, (len(s), 1))
        inertia = np.array([d.inertia_kg_m2 + d.load_inertia_kg_m2 for d in self.drives])
        a = inertia * q_s
        c = self.gravity_nm(q)
        twice = lambda m: np.concatenate([m, m], axis=1)      # noqa: E731 (current rows, then voltage rows)
        zero2 = np.zeros((len(s), 2))
        joints = JointPath(s, twice(q), twice(q_s), np.zeros_like(twice(q)), zero2, zero2, zero2)
        return Coefficients(s, twice(a), np.zeros_like(twice(a)), twice(c), np.zeros_like(twice(a)), joints)

    def limits(self, settings: ArmPlanSettings, current_limits_a: dict[str, float]) -> Limits:
        """Current rows: |u| <= eta k N i; voltage rows: |u + K q'| <= eta k N V / R (K: friction + back-emf)."""
        volts = SUPPLY_NOMINAL_V * settings.voltage_share
        current = [_torque_per_amp(d) * current_limits_a[d.name] * settings.current_share for d in self.drives]
        voltage = [_torque_per_amp(d) * volts / d.r_ohm for d in self.drives]
        k_current = [d.viscous_nm_s_rad for d in self.drives]
        k_voltage = [d.viscous_nm_s_rad + d.efficiency * (d.kt_nm_a * d.ratio) ** 2 / d.r_ohm for d in self.drives]
        return Limits.symmetric(current + voltage, k_current + k_voltage)


@dataclass(frozen=True)
class PlannedMove:
    names: tuple[str, ...]
    start_rad: dict[str, float]           # every joint of the trajectory (ARM_JOINTS)
    path: JointLine
    plan: TimeOptimal

    @property
    def duration_s(self) -> float:
        return self.plan.duration

    def knots(self, count: int) -> list[Knot]:
        """`count` knots evenly spaced in time along the profile (each joint's angle and speed there)."""
        prof = self.plan.profile
        times = np.linspace(0.0, prof.duration, count)
        s = np.interp(times, prof.t, prof.s)
        sd = np.interp(times, prof.t, prof.sd)
        s[-1], sd[0], sd[-1] = 1.0, 0.0, 0.0
        q = self.path.q(s)
        qd = sd[:, None] * (self.path.q1 - self.path.q0)
        out = []
        for k, t in enumerate(times):
            angles = dict(self.start_rad)
            speeds = {n: 0.0 for n in ARM_JOINTS}
            for j, name in enumerate(self.names):
                angles[name], speeds[name] = q[k, j], qd[k, j]
            out.append(Knot(float(t), tuple(math.degrees(angles[n]) for n in ARM_JOINTS),
                            tuple(math.degrees(speeds[n]) for n in ARM_JOINTS)))
        return out


def knots_within_speed(knots_of: Callable[[int], list[Knot]], speed_limits_rad_s: dict[str, float],
                       fewest: int) -> list[Knot]:
    """A plan's knots (`knots_of(count)`: a move's, `PlannedMove.knots`, an arm's of two, two_arm_plan.py),
    `fewest` of them or more (doubled up to the controller's buffer) until the Hermite curve through them stays
    within each joint's speed limit as the controller judges it (`HermiteProfile.bounds`): the profile's speed is
    within its limit at every knot, but a cubic between two knots overshoots it where the acceleration switches (an
    11-degree move's 41 knots passed j1's 3 deg/s by 16 %). PlanError if none do."""
    count = fewest
    while True:
        knots = knots_of(count)
        times = [k.t_s for k in knots]
        over = [name for j, name in enumerate(ARM_JOINTS) if HermiteProfile(
            times, [math.radians(k.q_deg[j]) for k in knots],
            [math.radians(k.qd_deg_s[j]) for k in knots]).bounds()[2] > speed_limits_rad_s[name]]
        if not over:
            return knots
        if count >= TRAJECTORY_KNOTS:
            raise PlanError("grid", f"the curve through {count} knots passes the speed limit of {', '.join(over)}")
        count = min(2 * count, TRAJECTORY_KNOTS)


def homed_pose_rad(arm: ArmDescription = ASPOD_ARM) -> dict[str, float]:
    """Where each joint of the trajectory holds after `home all` with the controller of `arm` in its default
    configuration: its home angle, backed off its switch (firmware_py/homing.py)."""
    config = {p.name: p.default for p in arm.parameter_table()}
    axes = {d.name: axis_config(d, config, 0.001) for d in arm.drives}
    return {n: axes[n].home_pos_rad - axes[n].home_dir * axes[n].home_backoff_rad for n in ARM_JOINTS}


def plan_move(start_rad: dict[str, float], targets_rad: dict[str, float], gravity_m_s2: float, payload_kg: float,
              current_limits_a: dict[str, float], speed_limits_rad_s: dict[str, float],
              settings: ArmPlanSettings = ArmPlanSettings()) -> PlannedMove:
    """The minimum-time move of the arm's joints from `start_rad` (every one of ARM_JOINTS) to `targets_rad` (those
    that move), within each joint's current limit and speed limit (the controller's parameters) and the supply."""
    missing = [n for n in ARM_JOINTS if n not in start_rad]
    if missing:
        raise PlanError("path", f"the start pose has no angle for {', '.join(missing)}")
    unknown = [n for n in targets_rad if n not in ARM_JOINTS]
    if unknown:
        raise PlanError("path", f"{', '.join(unknown)}: not an arm joint (the trajectory moves {ARM_JOINTS})")
    names = tuple(n for n in ARM_JOINTS if n in targets_rad and abs(targets_rad[n] - start_rad[n]) > MOVE_EPS_RAD)
    if not names:
        raise PlanError("path", "no joint moves")
    fixed = tuple(float(start_rad[n]) for n in HELD)
    system = ArmJoints(names, gravity_m_s2, payload_kg, fixed)
    path = JointLine(np.array([start_rad[n] for n in names], float), np.array([targets_rad[n] for n in names], float))
    cap = min(speed_limits_rad_s[n] * SPEED_SHARE / abs(targets_rad[n] - start_rad[n]) for n in names)
    problem = Problem(system, path, system.limits(settings, current_limits_a), speed_cap=cap)
    return PlannedMove(names, dict(start_rad), path, plan_time_optimal(problem, settings.nodes))

