"""toppra as the peer of the time-optimal path-parameterization planner: one instance, given in a neutral form.

`toppra_solve(path_q, inverse_dynamics, lower, upper, gridpoints, discretization)` runs toppra's TOPP-RA
(`toppra.algorithm.TOPPRA`, solver wrapper "seidel") rest to rest on a joint path q(s), s in [0, 1], under constant
torque bounds lower <= inverse_dynamics(q, qd, qdd) <= upper, with `gridpoints` evenly spaced grid points and
toppra's "collocation" or "interpolation" discretization. It returns a `PeerResult` and never raises for toppra's
own failures (a result with `ok` False says why).

`worst_violation(grid_s, x, ...)` is the checker the bench applies to every planner, toppra included, and does not
use toppra: the profile between grid points as TOPP-RA-like methods imply it (x = sd^2 linear in s on each interval,
so the pseudo-acceleration u = sdd is constant there, u_i = (x_{i+1} - x_i) / (2 (s_{i+1} - s_i))), the torques
evaluated inside every interval, the largest excess over a bound as a fraction of that bound.
`traversal_time(grid_s, x)` is the time of that same profile.

What the bench must know about toppra 0.6.10 (see also `PeerResult.u_solver`):

- toppra has no `__version__`; the version comes from the installed distribution's metadata.
- `SecondOrderConstraint` defaults to Interpolation (its `discretization_scheme=1`), `JointTorqueConstraint` to
  Collocation: "toppra's default" depends on the class. Here the scheme is always set explicitly.
- The forward pass lowers each next x by 1e-8 (0.01 % below x = 1e-4) and clips it into the controllable set, so
  the x it returns are not exactly x_i + 2 delta_i u_i with its own u (`sdd_vec`; the gap is about 1e-8 / (2 delta),
  tiny). The x are what the time and toppra's `ParametrizeConstAccel` use, so the profile here is the one implied
  by x; toppra's u is kept as `u_solver`.
- `compute_trajectory` would use `ParametrizeSpline` by default, a cubic spline through (t, q) that is not the
  constant-u profile and adds its own overshoot (toppra issue #150); this adapter does not call it.
- Importing toppra imports matplotlib.pyplot (`toppra.algorithm.algorithm`).
"""
from __future__ import annotations

import importlib.metadata
from dataclasses import dataclass, field
from typing import Callable, Protocol

import numpy as np

from timebase.clock import RealClock

DISCRETIZATIONS = ("collocation", "interpolation")
SOLVER_WRAPPER = "seidel"       # toppra's own 1-D LP solver, compiled; no external solver needed

InverseDynamics = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]


class JointPath(Protocol):
    """q(s) and its derivatives for s in [0, 1]: `path(s, order)` has shape (len(s), dof) for an array `s`."""

    def __call__(self, s: np.ndarray, order: int = 0) -> np.ndarray: ...


def _empty() -> np.ndarray:
    return np.empty(0)


@dataclass
class PeerResult:
    """toppra's answer on one instance.

    `grid_s` (N+1,), `x` (N+1,) the pseudo-velocity squared sd^2 at the grid points, `u` (N,) the pseudo-acceleration
    per interval implied by `x` (what `traversal_time` and `worst_violation` assume), `u_solver` (N,) the one toppra
    reported (larger by about 1e-8 / (2 delta); see the module's notes). `solve_time_s`: wall time of building the TOPPRA instance
    (toppra evaluates the dynamics on the grid then: `setup_time_s`) and of the parameterization itself.
    When `ok` is False, `reason` says why and the arrays are whatever toppra left (possibly empty).
    """

    ok: bool
    reason: str
    gridpoints: int
    discretization: str
    toppra_version: str
    traversal_time_s: float = float("nan")
    grid_s: np.ndarray = field(default_factory=_empty)
    x: np.ndarray = field(default_factory=_empty)
    u: np.ndarray = field(default_factory=_empty)
    u_solver: np.ndarray = field(default_factory=_empty)
    setup_time_s: float = float("nan")
    solve_time_s: float = float("nan")

    @property
    def solve_time_per_gridpoint_s(self) -> float:
        return self.solve_time_s / self.gridpoints


def toppra_version() -> str:
    """The installed toppra's version, or "" when it is not installed."""
    try:
        return importlib.metadata.version("toppra")
    except importlib.metadata.PackageNotFoundError:
        return ""


# ---- the profile between grid points, independent of toppra ----------------------------------------------------

def implied_u(grid_s: np.ndarray, x: np.ndarray) -> np.ndarray:
    """The constant pseudo-acceleration on each interval that makes x = sd^2 linear in s between grid points."""
    grid_s, x = np.asarray(grid_s, float), np.asarray(x, float)
    return np.diff(x) / (2.0 * np.diff(grid_s))


def traversal_time(grid_s: np.ndarray, x: np.ndarray) -> float:
    """Time along the path for x linear in s on every interval: sum of 2 ds / (sd_i + sd_{i+1}); inf if the profile
    stops (both ends of an interval at rest)."""
    sd = np.sqrt(np.clip(np.asarray(x, float), 0.0, None))
    ends = sd[:-1] + sd[1:]
    if np.any(ends <= 0.0):
        return float("inf")
    return float(np.sum(2.0 * np.diff(np.asarray(grid_s, float)) / ends))


def implied_torques(grid_s, x, path_q: JointPath, inverse_dynamics: InverseDynamics, per_interval: int = 20):
    """The torques of the implied profile: on every interval its two ends and `per_interval` evenly spaced points
    inside, each with that interval's u (u jumps at grid points, so each grid point is seen from both sides).

    Returns (s, tau): s (M,), tau (M, dof), intervals one after the other.
    """
    grid_s, x = np.asarray(grid_s, float), np.asarray(x, float)
    u = implied_u(grid_s, x)
    frac = np.linspace(0.0, 1.0, per_interval + 2)
    s = (grid_s[:-1, None] + frac[None, :] * np.diff(grid_s)[:, None]).ravel()
    xs = np.clip((x[:-1, None] + frac[None, :] * np.diff(x)[:, None]).ravel(), 0.0, None)
    us = np.repeat(u, frac.size)
    q, dq, ddq = (np.asarray(path_q(s, order), float) for order in (0, 1, 2))
    qd = dq * np.sqrt(xs)[:, None]
    qdd = dq * us[:, None] + ddq * xs[:, None]
    tau = np.array([inverse_dynamics(q[k], qd[k], qdd[k]) for k in range(s.size)], dtype=float)
    return s, tau


def _bound_scale(bound: np.ndarray, half_range: np.ndarray) -> np.ndarray:
    """What a violation of `bound` is a fraction of: |bound|, or the half-width of [lower, upper] for a zero bound."""
    return np.where(np.abs(bound) > 0.0, np.abs(bound), np.maximum(half_range, 1e-12))


def worst_violation(grid_s, x, path_q: JointPath, inverse_dynamics: InverseDynamics, lower, upper,
                    per_interval: int = 20) -> float:
    """The largest torque excess over its bound, as a fraction of that bound (0.05: 5 % past it), over the profile
    x linear in s between grid points (see `implied_torques`); 0.0 when no bound is exceeded."""
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    _, tau = implied_torques(grid_s, x, path_q, inverse_dynamics, per_interval)
    half_range = (upper - lower) / 2.0
    over = (tau - upper) / _bound_scale(upper, half_range)
    under = (lower - tau) / _bound_scale(lower, half_range)
    return float(max(0.0, over.max(), under.max()))


# ---- toppra ---------------------------------------------------------------------------------------------------

def _path_for_toppra(path_q: JointPath, dof: int):
    """`path_q` as a `toppra.interpolator.AbstractGeometricPath` on [0, 1] (built here so that this module imports
    without toppra)."""
    from toppra.interpolator import AbstractGeometricPath

    class NeutralPath(AbstractGeometricPath):
        def __call__(self, path_positions, order=0):
            s = np.atleast_1d(np.asarray(path_positions, float))
            values = np.asarray(path_q(s, order), float).reshape(s.size, dof)
            return values[0] if np.ndim(path_positions) == 0 else values

        @property
        def dof(self):
            return dof

        @property
        def path_interval(self):
            return np.array([0.0, 1.0])

    return NeutralPath()


def _torque_constraint(inverse_dynamics: InverseDynamics, lower: np.ndarray, upper: np.ndarray, scheme):
    """lower <= inverse_dynamics(q, qd, qdd) <= upper as toppra's SecondOrderConstraint: F w <= g with F = [I; -I],
    g = [upper; -lower]. (`JointTorqueConstraint` would do too, but adds a friction term evaluated per grid point.)"""
    from toppra.constraint import SecondOrderConstraint

    dof = lower.size
    f = np.vstack((np.eye(dof), -np.eye(dof)))
    g = np.concatenate((upper, -lower))
    return SecondOrderConstraint(inverse_dynamics, lambda _q: f, lambda _q: g, dof, discretization_scheme=scheme)


def toppra_solve(path_q: JointPath, inverse_dynamics: InverseDynamics, lower, upper, gridpoints: int,
                 discretization: str = "collocation") -> PeerResult:
    """Time-optimal rest-to-rest parameterization of `path_q` by toppra, on `gridpoints` evenly spaced points.

    Raises ValueError only for the caller's mistakes (unknown `discretization`, fewer than 2 grid points, bounds not
    of the path's dof); anything toppra does wrong (not installed, raising, failing) comes back as `ok` False.
    """
    if discretization not in DISCRETIZATIONS:
        raise ValueError(f"discretization must be one of {DISCRETIZATIONS}, not {discretization!r}")
    if gridpoints < 2:
        raise ValueError(f"need at least 2 grid points, not {gridpoints}")
    lower, upper = np.asarray(lower, float).ravel(), np.asarray(upper, float).ravel()
    dof = np.asarray(path_q(np.zeros(1), 0)).shape[-1]
    if lower.size != dof or upper.size != dof:
        raise ValueError(f"bounds of size {lower.size} and {upper.size} for a path of dof {dof}")

    version = toppra_version()
    result = PeerResult(ok=False, reason="", gridpoints=gridpoints, discretization=discretization,
                        toppra_version=version)
    try:
        import toppra.algorithm
        from toppra.constraint import DiscretizationType
    except ImportError as exc:
        result.reason = f"toppra is not importable: {exc}"
        return result

    scheme = (DiscretizationType.Collocation if discretization == "collocation"
              else DiscretizationType.Interpolation)
    grid = np.linspace(0.0, 1.0, gridpoints)
    clock = RealClock()
    try:
        t0 = clock.precise_now()
        constraint = _torque_constraint(inverse_dynamics, lower, upper, scheme)
        instance = toppra.algorithm.TOPPRA([constraint], _path_for_toppra(path_q, dof), gridpoints=grid,
                                           solver_wrapper=SOLVER_WRAPPER)
        t1 = clock.precise_now()
        sdd, sd, _ = instance.compute_parameterization(0.0, 0.0)
        t2 = clock.precise_now()
    except Exception as exc:        # toppra's failures are results here, whatever they are
        result.reason = f"toppra raised {type(exc).__name__}: {exc}"
        return result

    result.setup_time_s, result.solve_time_s = t1 - t0, t2 - t0
    result.grid_s = grid
    code = instance.problem_data.return_code
    if sd is None or np.isnan(sd).any():
        result.reason = f"toppra failed: {code.value}"
        return result
    result.x = np.asarray(sd, float) ** 2
    result.u = implied_u(grid, result.x)
    result.u_solver = np.asarray(sdd, float)
    result.traversal_time_s = traversal_time(grid, result.x)
    result.ok = True
    return result
