"""The phase plane (s, s'): the bounds on the pseudo-acceleration, the maximum velocity curve, and the two
integrators that draw curves on it (report, sections 1.1-1.2 and 2).

Everything is bounded in the one form  lower <= a s'' + b s'^2 + d s' + c <= upper  (d = 0 for constant
torques). At a given (s, s') each joint with a != 0 bounds s'' from both sides; the report's alpha is the
largest lower bound, beta the smallest upper one. A joint with a = 0 (a zero-inertia point) bounds s' alone.

The maximum velocity curve (MVC) is where alpha = beta. It is found exactly, not by bisection: every pair of
joints (i, j) asks beta_j - alpha_i >= 0, a quadratic in s' (linear in s'^2 when d = 0); the admissible speeds
at s are where all of them hold. Above the first inadmissible speed there may be admissible ones again: the
gap between is an "island" (report, Fig. 6), which only state-dependent bounds make. The MVC here is the top of
the admissible speeds reachable from rest: a trajectory is kept under islands (see docs/planning.md).

Curves are integrated in s with x = s'^2 as the state, dx/ds = 2 s'' (exact for the phase plane; a curve's time
comes afterwards from t = integral ds/s'). The report's integrator is the second-order Adams-Bashforth
method ("ab2"); "rk4", the classical fourth-order Runge-Kutta, is the more accurate one on the same grid.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from host_tools.plan.bounds import Limits
from host_tools.plan.errors import PlanError
from host_tools.plan.model import JointPath, TwoArms
from host_tools.plan.motors import Motors

INTEGRATORS = ("ab2", "rk4")
SPEED_CAP = 1e3            # s' never considered above this (1/s): a path the limits do not bound is refused


@dataclass(frozen=True)
class Problem:
    """What is planned: the arms, the object's path, the limits."""

    system: TwoArms
    path: object
    limits: Limits
    speed_cap: float = float("inf")      # s' never above this (a joint speed limit on a straight joint-space path);
    #                                      the phase plane, the DP and the reachability planner (order 1) honour it
    motors: Optional[Motors] = None       # the joints' motors (motors.py), for the electrical and heat objectives;
    #                                      None: ASPOD's own drives (`energy.motors_of`)
    weights: Optional[tuple[float, ...]] = None    # each joint's weight in a minimum-cost plan (default 1 each)

    def terms(self, s) -> "Terms":
        """The coefficients at `s`; PlanError "bounds" where they overflow a float (computed without numpy's
        warnings, then checked: numbers too extreme to plan with are refused, never planned with NaNs)."""
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            co = self.system.coefficients(self.path, s)
            d = self.limits.d(co.joints.q_s)
        if co.a.shape[1] != len(self.limits.lower):
            raise PlanError("bounds", f"{co.a.shape[1]} joints but {len(self.limits.lower)} limits")
        finite = np.isfinite(co.a).all(axis=1) & np.isfinite(co.b).all(axis=1) & np.isfinite(co.c).all(axis=1) \
            & np.isfinite(d).all(axis=1) & np.isfinite(co.n).all(axis=1)
        if not finite.all():
            raise PlanError("bounds", f"the joints' torques at s = {float(np.asarray(co.s)[np.argmin(finite)]):.4g} "
                                      "overflow a float: the arms' masses, lengths or path are too extreme to plan")
        return Terms(co.s, co.a, co.b, co.c, d, co.n, co.joints)


@dataclass(frozen=True)
class Terms:
    """The bounded quantity's coefficients at each s: a s'' + b s'^2 + d s' + c (+ lambda n), each (N, dof)."""

    s: np.ndarray
    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: np.ndarray
    n: np.ndarray
    joints: JointPath

    def at(self, index) -> "Terms":
        j = self.joints
        return Terms(self.s[index], self.a[index], self.b[index], self.c[index], self.d[index], self.n[index],
                     JointPath(j.s[index], j.q[index], j.q_s[index], j.q_ss[index], j.w[index], j.w_s[index],
                               j.w_ss[index]))

    def effort(self, sd, sdd) -> np.ndarray:
        """The bounded quantity (torque, or scaled voltage) at s' = sd, s'' = sdd; (N, dof)."""
        sd, sdd = np.asarray(sd, float)[..., None], np.asarray(sdd, float)[..., None]
        return self.a * sdd + self.b * sd * sd + self.d * sd + self.c

    def torque(self, sd, sdd) -> np.ndarray:
        """The joint torques themselves (without the back-emf term)."""
        sd, sdd = np.asarray(sd, float)[..., None], np.asarray(sdd, float)[..., None]
        return self.a * sdd + self.b * sd * sd + self.c


def zero_inertia(a: np.ndarray) -> np.ndarray:
    """Where a joint's inertia term vanishes (relative to the largest at that s)."""
    return np.abs(a) <= 1e-9 * (1.0 + np.abs(a).max(axis=-1, keepdims=True))


def accel_bounds(t: Terms, limits: Limits, sd) -> tuple[np.ndarray, np.ndarray]:
    """(alpha, beta) at each of t's points for s' = sd; alpha > beta where no s'' is admissible (a zero-inertia
    joint whose speed bound is broken gives alpha = +inf, beta = -inf)."""
    return _accel_bounds(t.a, t.b, t.c, t.d, limits.lo, limits.hi, np.asarray(sd, float))


def _accel_bounds(a, b, c, d, lo, hi, sd) -> tuple[np.ndarray, np.ndarray]:
    rest = b * (sd * sd)[..., None] + d * sd[..., None] + c
    zero = zero_inertia(a)
    a = np.where(zero, 1.0, a)
    to_lo, to_hi = (lo - rest) / a, (hi - rest) / a
    alpha_i = np.where(zero, -np.inf, np.where(a > 0, to_lo, to_hi))
    beta_i = np.where(zero, np.inf, np.where(a > 0, to_hi, to_lo))
    alpha, beta = alpha_i.max(axis=-1), beta_i.min(axis=-1)
    slack = 1e-9 * (hi - lo)
    broken = (zero & ((rest < lo - slack) | (rest > hi + slack))).any(axis=-1)
    return np.where(broken, np.inf, alpha), np.where(broken, -np.inf, beta)


def _conditions(t: Terms, limits: Limits) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(P, Q, R), each (N, C): the speeds s' admissible at each s are those with P + Q s' + R s'^2 >= 0 for all C."""
    lo, hi = limits.lo, limits.hi
    zero = zero_inertia(t.a)
    a = np.where(zero, 1.0, t.a)
    u_alpha, u_beta = np.where(a > 0, lo, hi), np.where(a > 0, hi, lo)
    rows = []
    n = a.shape[1]
    for i in range(n):                      # beta_j - alpha_i >= 0 for every pair
        for j in range(n):
            if i == j:
                continue
            p = (u_beta[:, j] - t.c[:, j]) / a[:, j] - (u_alpha[:, i] - t.c[:, i]) / a[:, i]
            q = t.d[:, i] / a[:, i] - t.d[:, j] / a[:, j]
            r = t.b[:, i] / a[:, i] - t.b[:, j] / a[:, j]
            off = zero[:, i] | zero[:, j]
            rows.append((np.where(off, 1.0, p), np.where(off, 0.0, q), np.where(off, 0.0, r)))
    for i in range(n):                      # a zero-inertia joint bounds the speed itself
        z = zero[:, i]
        rows.append((np.where(z, hi[i] - t.c[:, i], 1.0), np.where(z, -t.d[:, i], 0.0), np.where(z, -t.b[:, i], 0.0)))
        rows.append((np.where(z, t.c[:, i] - lo[i], 1.0), np.where(z, t.d[:, i], 0.0), np.where(z, t.b[:, i], 0.0)))
    p, q, r = (np.stack(col, axis=1) for col in zip(*rows))
    return p, q, r


def _roots(p, q, r) -> np.ndarray:
    """Both real roots of p + q v + r v^2 (NaN where there is none), (N, C, 2)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        disc = q * q - 4 * r * p
        sq = np.sqrt(np.where(disc >= 0, disc, np.nan))
        quad = np.stack([(-q - sq) / (2 * r), (-q + sq) / (2 * r)], axis=-1)
        lin = np.stack([-p / q, np.full_like(p, np.nan)], axis=-1)
    small = np.abs(r) <= 1e-12 * (np.abs(q) + np.abs(p) + 1e-300)
    return np.where(small[..., None], np.where((q != 0)[..., None], lin, np.nan), quad)


@dataclass(frozen=True)
class Speeds:
    """At each s: the MVC (top of the admissible speeds reachable from rest) and the islands above it."""

    mvc: np.ndarray                         # (N,) s'
    islands: list                           # (s, bottom, top) of each inadmissible gap below more admissible speeds
    static_ok: np.ndarray                   # (N,) rest is admissible at s


def admissible_speeds(t: Terms, limits: Limits) -> Speeds:
    p, q, r = _conditions(t, limits)
    roots = _roots(p, q, r).reshape(len(t.s), -1)
    roots = np.where((roots > 0) & (roots < SPEED_CAP), roots, np.nan)
    cuts = np.sort(np.concatenate([np.zeros((len(t.s), 1)), roots, np.full((len(t.s), 1), SPEED_CAP)], axis=1), axis=1)
    cuts = np.where(np.isnan(cuts), SPEED_CAP, cuts)
    mids = np.concatenate([cuts[:, :1], (cuts[:, :-1] + cuts[:, 1:]) / 2], axis=1)       # rest, then each segment
    tol = 1e-9 * (limits.hi - limits.lo).max()
    ok = ((p[:, None, :] + q[:, None, :] * mids[..., None] + r[:, None, :] * mids[..., None] ** 2) >= -tol).all(-1)
    static_ok = (p >= -tol).all(-1)            # rest, s' = 0: P alone (Q 0 and R 0 would be NaN times an overflow)
    seg_ok = ok[:, 1:]
    first_bad = np.where(seg_ok.all(axis=1), seg_ok.shape[1], np.argmin(seg_ok, axis=1))
    mvc = np.where(static_ok, cuts[np.arange(len(t.s)), np.minimum(first_bad, cuts.shape[1] - 1)], 0.0)
    mvc = np.where(static_ok & seg_ok.all(axis=1), SPEED_CAP, mvc)
    islands = []
    for k in np.nonzero(static_ok & (first_bad < seg_ok.shape[1]))[0]:
        later = np.nonzero(seg_ok[k, first_bad[k]:])[0]
        if later.size:
            islands.append((float(t.s[k]), float(mvc[k]), float(cuts[k, first_bad[k] + later[0]])))
    return Speeds(mvc, islands, static_ok)


@dataclass
class Curve:
    """A curve integrated on the phase plane: nodes `index` (grid node numbers), x = s'^2 there, and why it
    stopped ("mvc": it reached the maximum velocity curve, where no s'' is admissible beyond; "rest": s'
    reached 0; "end": s reached 0 or 1)."""

    label: str
    direction: int
    index: np.ndarray
    x: np.ndarray
    stop: str


class PhaseGrid:
    """The problem evaluated on a uniform grid of `nodes` intervals in s, with midpoints for rk4."""

    def __init__(self, problem: Problem, nodes: int) -> None:
        if not 10 <= nodes <= 200_000:
            raise PlanError("grid", f"{nodes} grid intervals: use 10 to 200000")
        self.problem, self.nodes = problem, nodes
        self.h = 1.0 / nodes
        self.fine = problem.terms(np.linspace(0.0, 1.0, 2 * nodes + 1))      # even: nodes, odd: midpoints
        self.t = self.fine.at(slice(0, None, 2))
        self.s = self.t.s
        lo, hi = problem.limits.lo, problem.limits.hi
        held = ((self.fine.c >= lo) & (self.fine.c <= hi)).all(axis=1)     # still, s' = s'' = 0
        if not held.all():          # checked first: the speeds' arithmetic is bounded by the limits only past it
            k = int(np.argmin(held))
            u = self.fine.c[k]
            worst = int(np.argmax(np.maximum(u - hi, lo - u)))              # a joint outside its limits, by most
            raise PlanError("bounds", f"too weak to hold the object still at s = {self.fine.s[k]:.4g}: joint "
                                      f"{worst + 1} needs {u[worst]:.4g} N m against its limits "
                                      f"[{lo[worst]:g}, {hi[worst]:g}]")
        self.speeds = admissible_speeds(self.fine, problem.limits)
        if not self.speeds.static_ok.all():
            raise PlanError("bounds", "the bounds on s'' overflow a float at s = "
                                      f"{self.fine.s[int(np.argmin(self.speeds.static_ok))]:.4g}, where every joint "
                                      "holds the object still within its limits: the problem is too extreme to plan")
        self.mvc_fine = np.minimum(self.speeds.mvc, problem.speed_cap)
        self.mvc = self.mvc_fine[::2]
        if (self.mvc >= SPEED_CAP).any():
            raise PlanError("bounds", "the limits do not bound the speed along this path (the maximum velocity "
                                      f"curve passes {SPEED_CAP:g} /s)")

    def slope(self, fine_index: int, x: float, direction: int) -> float:
        """dx/ds = 2 s'' at the extreme admissible s'' (beta forwards, alpha backwards); NaN if none."""
        f, k, limits = self.fine, slice(fine_index, fine_index + 1), self.problem.limits
        alpha, beta = _accel_bounds(f.a[k], f.b[k], f.c[k], f.d[k], limits.lo, limits.hi,
                                    np.array([np.sqrt(max(x, 0.0))]))
        if alpha[0] > beta[0] + 1e-9 * max(1.0, abs(beta[0])):
            return float("nan")
        return 2.0 * float(beta[0] if direction > 0 else alpha[0])

    def integrate(self, node: int, x0: float, direction: int, integrator: str, label: str) -> Curve:
        """From node `node` at x = x0, forwards at beta (direction +1) or backwards at alpha (-1)."""
        if integrator not in INTEGRATORS:
            raise PlanError("integrator", f"{integrator!r}: one of {', '.join(INTEGRATORS)}")
        h = self.h * direction
        index, xs = [node], [x0]
        previous: Optional[float] = None
        stop = "end"
        k, x = node, x0
        while 0 <= k + direction <= self.nodes:
            f0 = self.slope(2 * k, x, direction)
            if np.isnan(f0):
                stop = "mvc"
                break
            if integrator == "ab2":
                nxt = x + h * (f0 if previous is None else 1.5 * f0 - 0.5 * previous)
            else:
                mid = 2 * k + direction
                f1 = self.slope(mid, x + h / 2 * f0, direction)
                f2 = self.slope(mid, x + h / 2 * f1, direction)
                f3 = self.slope(2 * (k + direction), x + h * f2, direction)
                if np.isnan(f1 + f2 + f3):          # the stage left the admissible region: the MVC is here
                    stop = "mvc"
                    break
                nxt = x + h / 6 * (f0 + 2 * f1 + 2 * f2 + f3)
            previous, k = f0, k + direction
            if nxt <= 0.0:
                index.append(k)
                xs.append(0.0)
                stop = "rest"
                break
            limit = self.mvc[k] ** 2
            if nxt > limit * (1 + 1e-9):
                index.append(k)
                xs.append(limit)
                stop = "mvc"
                break
            x = nxt
            index.append(k)
            xs.append(x)
        order = np.argsort(index)
        return Curve(label, direction, np.asarray(index)[order], np.asarray(xs)[order], stop)
