"""Minimum-cost planning by dynamic programming on the (s, s') grid (report, section 3).

The path is cut into N intervals; at every node s' takes one of M values. Between node k at s'_i and node k+1
at s'_j the pseudo-acceleration is constant, (s'_j^2 - s'_i^2) / (2 ds). The report checks the torques at node
k only; here a step is admissible only if they are within the limits at both of its nodes, so the plan keeps its
limits where the report's could exceed them at the far node. Bellman's principle, from the end
at rest back to the start at rest, gives the cheapest admissible profile.

The objectives (`OBJECTIVES`), each a sum over the joints, each joint's share times its weight (default 1):

(Each interval's cost is taken by the trapezoidal rule, from the torques at both its ends.)

- "electrical" (the default): the electrical energy the motors draw, sum of (u_i dq_i + c_i u_i^2 dt), their
  mechanical work plus their copper losses R i^2, with c_i = R_i / (k_t,i N_i eta_i)^2 from the joints' motors
  (motors.py: the problem's, or ASPOD's own J1 and J2 drives where it names none), and the drives' own draw
  while enabled times the time. Without regeneration (the
  default) a joint that is driven back (its power negative) draws nothing and gives nothing back; with it, that
  energy returns to the supply. It can choose: a slow crawl pays its copper losses for longer, a fast move pays
  the square of its torques.
- "energy": the report's index, sum of u^T dq. **It cannot choose a profile**: for a rigid, frictionless chain
  moving from rest to rest, u^T dq summed is the work done on the chain, which is the change of its kinetic
  energy (zero) plus the change of its potential energy, whatever the speed (`potential_rise`). With gravity off
  it is about 0 for every profile; on any path it is the same for every profile, up to the grid's rounding. The
  DP then returns whichever admissible profile rounding favours; the report's Figs. 15-16 show one such.
- "work": sum of |u_i dq_i|, the work the motors do without getting any back (no regeneration).
- "thermal": sum of c_i u_i^2 dt, the heat in the motors' windings.

Slow motions cost less heat and no more work, so the user gives a time bound: the DP minimises cost + mu * time,
and mu is found by bisection so that the time is within the bound.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

from host_tools.plan.errors import PlanError
from host_tools.plan.motors import Motors, aspod_drives
from host_tools.plan.phase import Problem, Terms
from host_tools.plan.profile import Profile, profile_from_speeds

OBJECTIVES = ("electrical", "energy", "work", "thermal")


@dataclass(frozen=True)
class DpGrid:
    """The report's grid: 101 nodes in s (100 intervals) and 201 speeds 0.005 apart (s' from 0 to 1)."""

    intervals: int = 100
    speeds: int = 201
    speed_step: float = 0.005

    def __post_init__(self) -> None:
        if not 2 <= self.intervals <= 5000 or not 3 <= self.speeds <= 2001:
            raise PlanError("grid", "use 2 to 5000 intervals in s and 3 to 2001 speeds")
        if not (self.speed_step > 0 and np.isfinite(self.speed_step)):
            raise PlanError("grid", "the speed step must be a positive number")


@dataclass(frozen=True)
class Pricing:
    """How a plan's cost is counted beside its objective: each joint's weight, its motor's copper coefficient
    (motors.py `Motors.copper`) and whether energy a joint gives back returns to the supply."""

    weights: np.ndarray
    copper: np.ndarray
    regen: bool = False
    drive_w: float = 0.0

    @classmethod
    def of(cls, problem: Problem, weights: Optional[Sequence[float]] = None, regen: bool = False) -> "Pricing":
        """For `problem`: `weights` (else the problem's, else 1 each), its motors' copper (else ASPOD's drives')."""
        joints = len(problem.limits.lower)
        given = weights if weights is not None else problem.weights
        w = np.ones(joints) if given is None else np.asarray(given, float)
        if w.shape != (joints,) or not np.all(np.isfinite(w)) or np.any(w < 0):
            raise PlanError("weights", f"one finite, non-negative weight per joint ({joints})")
        motors = motors_of(problem)
        copper = motors.copper()
        if copper.shape != (joints,):
            raise PlanError("motors", f"one motor per joint ({joints})")
        return cls(w, copper, regen, motors.drive_w)


def motors_of(problem: Problem) -> Motors:
    return problem.motors if problem.motors is not None else aspod_drives()


def costs_of(terms: Terms, sd: np.ndarray, pricing: Pricing) -> dict:
    """Each objective's value for the profile s' = sd at the nodes of `terms` (torques at each interval's start)."""
    x = sd * sd
    ds = np.diff(terms.s)
    sdd = (x[1:] - x[:-1]) / (2 * ds)
    u = terms.at(slice(0, -1)).torque(sd[:-1], sdd)
    far = terms.at(slice(1, None)).torque(sd[1:], sdd)
    dq = np.diff(terms.joints.q, axis=0)
    with np.errstate(divide="ignore"):
        dt = 2 * ds / (sd[:-1] + sd[1:])
    out = {name: float(np.sum(_step_cost(name, u, far, dq, dt, pricing))) for name in OBJECTIVES}
    return {**out, "time": float(dt.sum())}


def profile_costs(problem: Problem, profile: Profile, pricing: Optional[Pricing] = None) -> dict:
    """Each objective's value for a profile planned by any of the planners (s'' constant between its nodes), as
    `costs_of` counts them, and "drives", the drives' own draw over its time (part of "electrical"): what the
    objective predicts a plan as executed costs (`pricing`: default `Pricing.of(problem)`)."""
    w = Pricing.of(problem) if pricing is None else pricing
    costs = costs_of(problem.terms(profile.s), np.asarray(profile.sd, float), w)
    return {**costs, "drives": w.drive_w * costs["time"]}


def potential_rise(problem: Problem, nodes: int = 2000) -> float:
    """The change of the arms' and the object's potential energy from the path's start to its end (J): what the
    report's index equals for every rest-to-rest profile (the gravity torques' work along the path)."""
    terms = problem.terms(np.linspace(0.0, 1.0, nodes + 1))
    dq = np.diff(terms.joints.q, axis=0)
    return float(np.sum((terms.c[:-1] + terms.c[1:]) / 2 * dq))


@dataclass
class CostOptimal:
    objective: str
    grid: DpGrid
    profile: Profile
    costs: dict
    time_weight: float              # mu, the price of a second in the objective's units
    terms: Terms
    pricing: Pricing


def _step_cost(objective: str, u: np.ndarray, far: np.ndarray, dq: np.ndarray, dt, pricing: Pricing):
    """One interval's cost by the trapezoidal rule: torques `u` at its start and `far` at its end."""
    w = pricing.weights
    if objective == "energy":
        return ((u + far) * dq) @ w / 2
    if objective == "work":
        return (np.abs(u * dq) + np.abs(far * dq)) @ w / 2
    heat = (u * u + far * far) * pricing.copper * np.asarray(dt)[..., None] / 2
    if objective == "thermal":
        return heat @ w
    drawn = (u + far) * dq / 2 + heat                   # electrical: work plus copper loss, joint by joint
    return (drawn if pricing.regen else np.maximum(drawn, 0.0)) @ w + pricing.drive_w * np.asarray(dt)


def _within(effort: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    return ((effort >= lo) & (effort <= hi)).all(axis=-1)


class _Stages:
    """Every interval's admissible steps, their cost and their time, worked out once (float32: about 70 MB on
    the report's grid) so that the search for the time price mu only repeats Bellman's recursion."""

    def __init__(self, terms: Terms, problem: Problem, grid: DpGrid, objective: str, pricing: Pricing) -> None:
        self.v = v = np.arange(grid.speeds) * grid.speed_step
        x = v * v
        lo, hi = problem.limits.lo, problem.limits.hi
        q = terms.joints.q
        n = len(terms.s) - 1
        self.cost = np.empty((n, grid.speeds, grid.speeds), np.float32)
        self.time = np.empty_like(self.cost)
        for k in range(n):
            ds = terms.s[k + 1] - terms.s[k]
            sdd = (x[None, :] - x[:, None]) / (2 * ds)                     # (from i, to j)
            u = terms.a[k] * sdd[..., None] + terms.b[k] * x[:, None, None] + terms.c[k]
            far = terms.a[k + 1] * sdd[..., None] + terms.b[k + 1] * x[None, :, None] + terms.c[k + 1]
            ok = (_within(u + terms.d[k] * v[:, None, None], lo, hi)
                  & _within(far + terms.d[k + 1] * v[None, :, None], lo, hi))
            with np.errstate(divide="ignore"):
                dt = 2 * ds / (v[:, None] + v[None, :])
            ok &= np.isfinite(dt) & (v[:, None] <= problem.speed_cap) & (v[None, :] <= problem.speed_cap)
            dt = np.where(ok, dt, 0.0)
            self.cost[k] = np.where(ok, _step_cost(objective, u, far, q[k + 1] - q[k], dt, pricing), np.inf)
            self.time[k] = dt

    def solve(self, mu: float) -> Optional[np.ndarray]:
        """Bellman's recursion for cost + mu * time: s' at each node, or None if no admissible profile exists."""
        n, m = self.cost.shape[:2]
        cost_to_go = np.where(self.v == 0, 0.0, np.inf)
        choice = np.zeros((n, m), dtype=np.int32)
        for k in range(n - 1, -1, -1):
            total = self.cost[k] + np.float32(mu) * self.time[k] + cost_to_go[None, :]
            choice[k] = np.argmin(total, axis=1)
            cost_to_go = total[np.arange(m), choice[k]]
        if not np.isfinite(cost_to_go[0]):
            return None
        path = [0]
        for k in range(n):
            path.append(int(choice[k][path[-1]]))
        return self.v[np.asarray(path)]


def plan_cost_optimal(problem: Problem, objective: str = "electrical", grid: DpGrid = DpGrid(),
                      max_time: Optional[float] = None, pricing: Optional[Pricing] = None) -> CostOptimal:
    """The cheapest rest-to-rest profile by `objective` on `grid`, within `max_time` seconds if given (`pricing`:
    the weights, motors and regeneration; default `Pricing.of(problem)`)."""
    if objective not in OBJECTIVES:
        raise PlanError("objective", f"{objective!r}: one of {', '.join(OBJECTIVES)}")
    if max_time is not None and not (max_time > 0 and np.isfinite(max_time)):
        raise PlanError("time", "the time bound must be a positive number of seconds")
    terms = problem.terms(np.linspace(0.0, 1.0, grid.intervals + 1))
    w = Pricing.of(problem) if pricing is None else pricing

    stages = _Stages(terms, problem, grid, objective, w)

    def solve(mu):
        sd = stages.solve(mu)
        return sd, (None if sd is None else costs_of(terms, sd, w)["time"])

    sd, t = solve(0.0)
    if sd is None:
        raise PlanError("grid", f"no admissible profile on this grid ({grid.speeds} speeds {grid.speed_step:g} "
                                f"apart, {grid.intervals} intervals): the speeds step too far for the limits "
                                "between nodes; use a finer speed step or more intervals")
    mu = 0.0
    if max_time is not None and t > max_time:
        fastest, tf = solve(1e12)
        if tf > max_time:
            raise PlanError("time", f"no profile on this grid is within {max_time:g} s (the fastest takes "
                                    f"{tf:.4g} s; a finer grid or a larger speed range may reach it)")
        low, high = 1e-12, 1e12                   # mu is searched on a log scale: its units are the objective's
        sd, t = fastest, tf
        for _ in range(60):
            if t > 0.995 * max_time or high / low < 1.0001:
                break
            mid = np.sqrt(low * high)
            sd_mid, t_mid = solve(mid)
            if t_mid > max_time:
                low = mid
            else:
                high, sd, t = mid, sd_mid, t_mid
        mu = high
    profile = profile_from_speeds(terms, problem.limits, sd)
    return CostOptimal(objective, grid, profile, costs_of(terms, sd, w), mu, terms, w)
