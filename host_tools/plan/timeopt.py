"""Time-optimal planning the report's way (section 2, after Slotine and Yang): candidate switching points found
by a search over s alone, limit curves integrated from each, and the profile from the start and end states.

1. Candidates of the three kinds:
   - zero-inertia: a joint's a_i(s) = 0 (a root of a_i, refined by Brent's method), at the MVC's speed there;
   - discontinuity: where the path's d2w/ds2 jumps (the path says where), at the lower of the MVC's two sides;
   - tangent: where a trajectory at the extreme deceleration meets the MVC tangentially, i.e. where
     phi(s) = alpha(s, mvc)/mvc - d(mvc)/ds crosses zero (the same condition as the report's
     dV_k/dt = 0 for the pair of joints saturated there, evaluated numerically along the MVC; with
     state-dependent bounds the MVC includes the lower edges of islands, so their tangent points are found
     the same way).
2. From each candidate, alpha backwards and beta forwards until the MVC, s = 0 or 1, or rest; a candidate
   whose curves cannot leave it without crossing the MVC is discarded (the report's step 2). Only a zero of
   phi crossed from above can be kept (alpha/s' >= d(mvc)/ds before it, <= after); one crossed from below,
   a peak of the MVC, is a candidate the integration discards.
3. From the start at rest forwards at beta, from the end at rest backwards at alpha. The profile is the lowest of
   all these curves and the MVC at every s; its torques saturate at least one joint everywhere.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import brentq

from host_tools.plan.errors import PlanError
from host_tools.plan.phase import Curve, PhaseGrid, Problem, accel_bounds, admissible_speeds, zero_inertia
from host_tools.plan.profile import Profile, profile_from_speeds

KINDS = ("zero-inertia", "discontinuity", "tangent")


@dataclass(frozen=True)
class SwitchingPoint:
    kind: str
    s: float
    sd: float
    joint: int = 0                  # zero-inertia: the joint (1-based); otherwise 0
    kept: bool = True
    why: str = ""                   # why a candidate was discarded

    def describe(self) -> dict:
        return {"kind": self.kind, "s": round(self.s, 6), "sd": round(self.sd, 6), "joint": self.joint or None,
                "kept": self.kept, "why": self.why or None}


@dataclass
class TimeOptimal:
    grid: PhaseGrid
    integrator: str
    profile: Profile
    switching_points: list[SwitchingPoint]
    curves: list[Curve] = field(default_factory=list)      # the limit curves, and the start and end legs

    @property
    def duration(self) -> float:
        return self.profile.duration


def _mvc_at(problem: Problem, s: float) -> float:
    return min(float(admissible_speeds(problem.terms([s]), problem.limits).mvc[0]), problem.speed_cap)


def zero_inertia_points(grid: PhaseGrid) -> list[SwitchingPoint]:
    problem, fine = grid.problem, grid.fine
    found = []
    for joint in range(fine.a.shape[1]):
        a = fine.a[:, joint]
        for k in np.nonzero(np.sign(a[:-1]) * np.sign(a[1:]) < 0)[0]:
            def a_of(s, joint=joint):
                return float(problem.terms([s]).a[0, joint])
            s = brentq(a_of, fine.s[k], fine.s[k + 1], xtol=1e-12)
            found.append(SwitchingPoint("zero-inertia", s, _mvc_at(problem, s), joint + 1))
        for k in np.nonzero(zero_inertia(fine.a)[:, joint])[0]:          # exactly zero on a grid point
            found.append(SwitchingPoint("zero-inertia", float(fine.s[k]), float(grid.mvc_fine[k]), joint + 1))
    return found


def discontinuity_points(grid: PhaseGrid) -> list[SwitchingPoint]:
    problem = grid.problem
    found = []
    for s in getattr(problem.path, "breaks", ()):
        sides = [_mvc_at(problem, min(1.0, max(0.0, s + e))) for e in (-1e-9, 1e-9)]
        found.append(SwitchingPoint("discontinuity", float(s), min(sides)))
    return found


def tangent_points(grid: PhaseGrid, avoid: list[float]) -> list[SwitchingPoint]:
    mvc = grid.mvc
    alpha, _ = accel_bounds(grid.t, grid.problem.limits, mvc * (1 - 1e-9))
    with np.errstate(invalid="ignore", divide="ignore"):
        phi = alpha / mvc - np.gradient(mvc, grid.h)
    found = []
    for k in np.nonzero(np.sign(phi[:-1]) * np.sign(phi[1:]) < 0)[0]:
        s = grid.s[k] + grid.h * phi[k] / (phi[k] - phi[k + 1])
        if any(abs(s - a) < 3 * grid.h for a in avoid) or not 0 < k < grid.nodes - 1:
            continue
        found.append(SwitchingPoint("tangent", float(s), float(np.interp(s, grid.s, mvc))))
    return found


def _limit_curves(grid: PhaseGrid, point: SwitchingPoint, integrator: str, label: str):
    """The two halves of the limit curve through `point`, or the reason it is discarded."""
    left = min(grid.nodes - 1, int(np.floor(point.s / grid.h)))
    right = left + 1
    x_left = min(grid.mvc[left] ** 2, point.sd ** 2) * (1 - 1e-6)
    x_right = min(grid.mvc[right] ** 2, point.sd ** 2) * (1 - 1e-6)
    back = grid.integrate(left, x_left, -1, integrator, f"{label} (alpha, backwards)")
    forth = grid.integrate(right, x_right, +1, integrator, f"{label} (beta, forwards)")
    for half, name in ((back, "backwards"), (forth, "forwards")):
        if half.stop == "mvc" and len(half.index) <= 3:
            return None, f"integrating {name} leaves the admissible region at once"
    return (back, forth), ""


MVC_FOLLOWED = 1e-7     # a node this close below the maximum velocity curve is on it
MVC_SLOPE_SLACK = 1e-3  # how far (relative) an interval along it may ask beyond [alpha, beta]: rounding only


def _check_no_mvc_followed(grid: PhaseGrid, x: np.ndarray) -> None:
    """PlanError where the lowest of the curves leaves the profile on the maximum velocity curve for an interval
    whose s'' (the curve's own slope) no admissible s'' is: a switching point the candidates above miss.

    Every candidate in such a stretch was discarded, and no limit curve passes below the MVC there, so the
    "lowest of all curves and the MVC" is the MVC itself, which a torque-limited MVC only admits at isolated
    points (seen: a back-and-forth path with gravity and DC motors, from s = 0.549 to 0.737, the MVC rising at
    s'' = +164 where only -216..-215 is admissible, 517 % over a limit). Refused, not planned past the limits."""
    on = x >= grid.mvc ** 2 * (1 - MVC_FOLLOWED)
    along = np.nonzero(on[:-1] & on[1:])[0]
    if not len(along):
        return
    sdd = (x[along + 1] - x[along]) / (2 * grid.h)
    alpha, beta = accel_bounds(grid.t.at(along), grid.problem.limits, grid.mvc[along])
    scale = np.maximum(1.0, np.maximum(np.abs(alpha), np.abs(beta)))
    bad = along[(np.maximum(alpha - sdd, sdd - beta) > MVC_SLOPE_SLACK * scale)]
    if len(bad):
        raise PlanError("switching", f"the profile would follow the maximum velocity curve from s = "
                                     f"{grid.s[bad[0]]:.4g} to {grid.s[bad[-1] + 1]:.4g}, where the curve cannot "
                                     "be followed within the limits: a switching point this planner's search does "
                                     "not find there; plan it by reachability (--method reach)")


def plan_time_optimal(problem: Problem, nodes: int = 1000, integrator: str = "rk4") -> TimeOptimal:
    """The minimum-time rest-to-rest profile along the path."""
    grid = PhaseGrid(problem, nodes)
    candidates = zero_inertia_points(grid) + discontinuity_points(grid)
    candidates += tangent_points(grid, [c.s for c in candidates])
    candidates.sort(key=lambda c: c.s)
    x = grid.mvc ** 2
    curves = []
    points = []
    for n, point in enumerate(candidates, start=1):
        pair, why = _limit_curves(grid, point, integrator, f"switching point {n}")
        if pair is None:
            points.append(SwitchingPoint(point.kind, point.s, point.sd, point.joint, False, why))
            continue
        points.append(point)
        curves += pair
    curves.append(grid.integrate(0, 0.0, +1, integrator, "start (beta, forwards)"))
    curves.append(grid.integrate(grid.nodes, 0.0, -1, integrator, "end (alpha, backwards)"))
    for curve in curves:
        x[curve.index] = np.minimum(x[curve.index], curve.x)
    _check_no_mvc_followed(grid, x)
    profile = profile_from_speeds(grid.t, problem.limits, np.sqrt(np.maximum(x, 0.0)),
                                  getattr(problem.path, "breaks", ()))
    return TimeOptimal(grid, integrator, profile, points, curves)
