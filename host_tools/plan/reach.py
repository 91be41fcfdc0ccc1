"""Time-optimal planning by reachability (TOPP-RA: Pham and Pham, 2018), with no torque excess between grid
points and, as an option, the squeeze force as a free variable. Beyond the report: docs/planning.md says how.

**The profile.** On a grid s_0 < ... < s_N (uniform, plus the path's breaks) the pseudo-acceleration s'' = u_i
is constant on each interval, so x = s'^2 = x_i + 2 u_i (s - s_i) is linear in s there, and every joint's torque
tau(s) = a(s) u_i + b(s) x(s) + c(s) (+ n(s) lambda_i, the squeeze, also constant on the interval) is linear in
the interval's variables (x_i, u_i, lambda_i) at every s. This is the profile `bench.toppra_peer` checks.

**The curvature guard.** Each interval is judged at three points, its ends and its midpoint, each of them a
linear function of the variables. Between two of them (h/2 apart) a smooth function leaves its chord by at
most (h/2)^2 max|tau''| / 8, and D = tau(s_i) - 2 tau(mid) + tau(s_{i+1}) = (h/2)^2 tau'' (exactly, for a
quadratic), so that excess is |D| / 8. Each of the three points is required to keep tau +/- GUARD * D within the
limits. GUARD = 1/4 is twice the quadratic's need: the other half covers the cubic and higher terms the three
points do not see. D is linear in the variables too, so every constraint stays a half-plane.

**The passes.** With the squeeze eliminated first (Fourier-Motzkin: every pair of constraints that bound it from
opposite sides gives one constraint without it), each interval is a set of half-planes in (x_i, u_i).
Eliminating u the same way gives each interval's x-range on its own, once, for the whole grid (numpy, no loop).
Backwards from rest at the end, the controllable set K_i (the x_i from which some admissible u_i reaches
K_{i+1}) is an interval: the only new pairs are each constraint with the coupling x_i + 2 h u_i in K_{i+1},
five numpy operations per grid point. Forwards from rest at the start, each interval takes the largest u_i
keeping x_{i+1} in K_{i+1}: that greedy pass is time-optimal for this discretization (Pham and Pham, 2018).
The squeeze then is, on each interval, the admissible value nearest 0 (the least squeeze that does).

**Order 2** (`order=2`, `reach2`): s'' linear in s on each interval, the state (x_i, u_i) at each grid point,
controllable sets convex polygons (compiled by numba where installed). Every torque along an interval is kept
within its limits by the Bernstein coefficients of its polynomial in the interval's variables (`_rows_order2`),
not by sampled points and a guard. Second order in h; on grid points placed where order-1 plans lose time
(`placed_grid`, `placed=True`) within 0.1 % of the reference at 100 points on the bench's paths, where order 1
needs 200-3200. No squeeze with it (`PlanError` "squeeze"). Order 1 stays the default: it takes the squeeze,
and needs no compiler to be fast.

**Back-emf limits** (DC motors, order 1 only): the bounded quantity a u + b x + d sqrt(x) + c is not linear in x.
sqrt is concave, so on each interval `_emf_linear` puts in its place, for each bounded quantity and side, the
line that makes the constraint stricter: its tangent (above sqrt everywhere) where d sqrt(x) must be over-estimated
(an upper limit with d >= 0, a lower one with d < 0), its chord over a bracket [lo^2, hi^2] (below sqrt there)
where it must be under-estimated, with lo^2 <= x <= hi^2 added at both ends of the interval as half-planes. Every
plan so made keeps the true limits (`sampled_torques` adds d s'). `_linearized` plans first around the maximum
velocity curve, then around each plan's own speeds (tangent at their mean, the bracket +/- 25 % of them, halved each
time down to 1 %) until the time changes by less than 0.01 % (3 to 5 plans on the report's path and ASPOD's arm),
and keeps the fastest. A speed cap is x <= cap^2 at the grid points (x is linear between them). Order 2 and the
squeeze with back-emf limits are refused (`PlanError`), and order 2 with a speed cap.
"""
from __future__ import annotations

import operator
from dataclasses import dataclass
from math import comb
from typing import Optional, Union

import numpy as np

from host_tools.plan.bounds import Limits
from host_tools.plan.errors import PlanError
from host_tools.plan.phase import SPEED_CAP, Problem, Terms, admissible_speeds
from host_tools.plan import reach2
from host_tools.plan.profile import Profile, profile_from_speeds
from timebase.clock import RealClock

MAX_GRIDPOINTS = 200_000        # the most grid points a plan takes (uniform or placed)
GUARD = 0.25                    # the curvature guard's factor on D (1/8 covers a quadratic exactly)
UNIFORM_SHARE = 0.3            # placed grids: the share of the points spread evenly, the rest where time is lost
FRACTIONS2 = np.linspace(0.0, 1.0, 5)   # order 2: where a, b, c are sampled in each interval (a quartic through them)
_DEGREE2 = 6                            # order 2: a torque along an interval is a polynomial of this degree in sigma
_TO_POWER = np.linalg.inv(np.vander(FRACTIONS2, increasing=True))     # values at FRACTIONS2 -> power coefficients
_TO_BERNSTEIN = np.array([[comb(k, j) / comb(_DEGREE2, j) if j <= k else 0.0 for j in range(_DEGREE2 + 1)]
                          for k in range(_DEGREE2 + 1)])               # power -> Bernstein coefficients, degree 6
_END_SHARE = 0.25               # order 2: the last interval's x_{N-1} + h u_{N-1} >= this share of x_{N-1}, so
                                # u_N <= -_END_SHARE x_{N-1} / h (u_N = 0 reaches rest only after infinite time)
FREE = float("inf")             # squeeze=FREE: the squeeze is unbounded
Squeeze = Union[None, float, tuple]
_TINY = 1e-12                   # a normalized coefficient below this does not bound the variable it multiplies
EMF_ITERATIONS = 9              # back-emf limits: the most plans (the first guess and 8 re-linearizations)
EMF_SETTLED = 1e-4              # ... done when the time changes by less than this share
EMF_WIDTH = 0.25                # ... the first bracket around a plan's speeds: +/- this share of them
EMF_WIDTH_MIN = 0.01            # ... halved each time down to this


@dataclass(frozen=True)
class ReachPlan:
    """The plan: x = s'^2 at the grid points, u = s'' and the squeeze (N) on each interval, the controllable
    sets (N+1, 2), how long the planning took, and the profile (torques at the nodes
    with each interval's u and squeeze)."""

    s: np.ndarray
    x: np.ndarray
    u: np.ndarray
    squeeze: np.ndarray
    controllable: np.ndarray
    setup_time_s: float             # the grid (placed: the two order-1 plans) and the model's coefficients on it
    solve_time_s: float             # all of it: coefficients, constraints, both passes
    profile: Profile
    order: int = 1                  # 2: u is s'' at the grid points (N + 1), linear in s between them
    iterations: int = 0             # back-emf limits: how many linearized plans were made (0: none needed)

    @property
    def duration(self) -> float:
        return self.profile.duration

    @property
    def gridpoints(self) -> int:
        return len(self.s)


def _grid(problem: Problem, gridpoints) -> np.ndarray:
    """`gridpoints` evenly spaced, or the grid itself (rising from 0 to 1); with the path's breaks added."""
    if np.ndim(gridpoints) == 0:
        if not 3 <= gridpoints <= MAX_GRIDPOINTS:
            raise PlanError("grid", f"{gridpoints} grid points: use 3 to {MAX_GRIDPOINTS}")
        gridpoints = np.linspace(0.0, 1.0, int(gridpoints))
    grid = np.asarray(gridpoints, float)
    if len(grid) < 3 or grid[0] != 0.0 or grid[-1] != 1.0 or np.any(np.diff(grid) <= 0):
        raise PlanError("grid", "a grid rises from 0 to 1 through at least 3 points")
    breaks = [b for b in getattr(problem.path, "breaks", ()) if 0.0 < b < 1.0]
    return np.unique(np.concatenate([grid, breaks]))


def _squeeze_range(squeeze: Squeeze) -> Optional[tuple[float, float]]:
    """None (the fixed split) or the squeeze's range [lo, hi] in newtons."""
    if squeeze is None:
        return None
    lo, hi = (-float(squeeze), float(squeeze)) if np.ndim(squeeze) == 0 else (float(squeeze[0]), float(squeeze[1]))
    if np.isnan(lo) or np.isnan(hi) or lo > hi:
        raise PlanError("squeeze", "give a bound lambda_max >= 0, a range (lo, hi) with lo <= hi, or FREE")
    return lo, hi


def _point_terms(problem: Problem, s: np.ndarray, fractions=(0.0, 0.5, 1.0)) -> tuple[Terms, ...]:
    """The terms at each of `fractions` (rising from 0 to 1) of every interval, from one evaluation of the model:
    by default its start, midpoint and end. An interval that ends on a break of the path is judged by its own
    piece: its end's terms are taken just before the break."""
    fractions = np.asarray(fractions, float)
    width = len(fractions) - 1
    points = np.append((s[:-1, None] + fractions[None, :-1] * np.diff(s)[:, None]).ravel(), s[-1])
    t = problem.terms(points)
    # the ends by an index array: a copy (a slice would be a view sharing each end with the next interval's start,
    # and replacing an end at a break below would give the interval after it the piece before it)
    end = t.at(np.arange(width, len(points), width))
    found = [t.at(slice(k, -1, width)) for k in range(width)] + [end]
    breaks = np.isin(s[1:], getattr(problem.path, "breaks", ()))
    if breaks.any():
        left = problem.terms(np.nextafter(s[1:][breaks], 0.0))
        for name in ("a", "b", "c", "d", "n"):
            getattr(end, name)[breaks] = getattr(left, name)
    return tuple(found)


def _rows(limits: Limits, s: np.ndarray, terms: tuple, guard: float, squeeze: Optional[tuple[float, float]],
          emf: Optional[tuple] = None) -> tuple:
    """Every interval's constraints as rows  alpha x + beta u (+ mu lambda) <= gamma: the tuple (alpha, beta,
    [mu,] gamma) of (N, M) arrays, each row scaled so that its largest coefficient is 1. `terms`: the terms at
    each interval's start, midpoint and end. The first PAIRED rows bound the torques from above, the next PAIRED
    the same from below (their coefficients negated), then x_i >= 0 and x_{i+1} >= 0 (and the squeeze's bounds).
    `emf`: each interval's (v0, lo, hi) for a back-emf term d s' (`_emf_linear`), then the bracket's rows last."""
    h = np.diff(s)[:, None]
    n = len(h)
    one, zero = np.ones((n, 1)), np.zeros((n, 1))
    extra = [(-one, zero, zero, zero), (-one, -2 * h, zero, zero)]     # x_i >= 0, x_{i+1} >= 0
    if squeeze is not None:
        extra += [(zero, zero, one, squeeze[1] * one), (zero, zero, -one, -squeeze[0] * one)]
    sides = [terms, terms]
    if emf is not None:
        sides = _emf_linear(terms, *emf)
        lo2, hi2 = emf[1][:, None] ** 2, emf[2][:, None] ** 2        # the bracket lo^2 <= x <= hi^2, at both ends
        extra += [(-one, zero, zero, -lo2), (one, zero, zero, hi2), (-one, -2 * h, zero, -lo2), (one, 2 * h, zero, hi2)]
    # each point's torque as coefficients of x_i, u_i, lambda_i and 1: x there is x_i + 2 u_i (offset)
    upper, lower = ([(t.b, t.a + 2 * off * t.b, t.n, t.c) for t, off in zip(side, (0.0, h / 2, h))] for side in sides)
    rows = _guarded_rows(limits, upper, guard, extra, lower)
    if squeeze is None:
        del rows[2]
    return _normalized(_finite(rows))


def _emf_linear(terms: tuple, v0: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> list:
    """The terms at each interval's points with the back-emf term d s' = d sqrt(x) made linear in x, for the
    upper limits and for the lower ones: each a tuple of `Terms` with b + d k1 for b and c + d k0 for c.

    sqrt is concave: its tangent at v0 (sqrt(x) <= v0 / 2 + x / (2 v0), for every x) lies above it, its chord
    over the bracket [lo^2, hi^2] (sqrt(x) >= lo hi / (lo + hi) + x / (lo + hi), for x in the bracket) below it.
    An upper limit needs d sqrt(x) over-estimated: the tangent where d >= 0, the chord where d < 0; a lower limit
    the other way round. With the same line all along an interval (d keeps its sign), the linearized quantity
    is a smooth function of s above (below) the true one everywhere in it, and the curvature guard keeps it within
    its limits as it keeps a torque; where d changes sign the line is chosen point by point, and d is near 0."""
    v0 = np.maximum(v0, 1e-9)[:, None]
    width = np.maximum(lo + hi, 1e-9)[:, None]
    tangent, chord = (v0 / 2, 1 / (2 * v0)), (lo[:, None] * hi[:, None] / width, 1 / width)
    out = []
    for over in (True, False):          # upper limits: over-estimate d sqrt(x); lower limits: under-estimate it
        side = []
        for t in terms:
            k0, k1 = (np.where((t.d >= 0) == over, a, b) for a, b in zip(tangent, chord))
            side.append(Terms(t.s, t.a, t.b + t.d * k1, t.c + t.d * k0, t.d, t.n, t.joints))
        out.append(tuple(side))
    return out


def _rows_order2(limits: Limits, s: np.ndarray, terms: tuple) -> tuple:
    """The second-order profile's constraints as rows  alpha x_i + beta u_i + delta u_{i+1} <= gamma (as `_rows`),
    every torque within its limits all along each interval by its Bernstein coefficients.

    At sigma in [0, 1] across an interval of width h, s'' = u_i (1 - sigma) + u_{i+1} sigma and x = x_i +
    2 h u_i sigma + h (u_{i+1} - u_i) sigma^2. With a, b, c replaced by their quartics through the interval's
    `FRACTIONS2` (`terms`), each torque a s'' + b x + c is a polynomial of degree 6 in sigma whose coefficients
    are linear in (x_i, u_i, u_{i+1}); it lies within the hull of its 7 Bernstein coefficients, so those within
    the limits keep it there everywhere in the interval (not only where it was sampled). What the quartics leave
    out of a, b, c is of order h^5. x >= 0 all along, by x's own Bernstein coefficients x_i, x_i + h u_i, x_{i+1};
    on the last interval the middle one at least `_END_SHARE` x_{N-1}, so that x meets 0 with s'' < 0 (with s'' = 0
    there x has a double root at the end, and rest takes forever: the greedy forward pass rode to that vertex)."""
    n = len(s) - 1
    h = np.diff(s)[:, None, None]
    power = {name: np.einsum("jk,nkd->njd", _TO_POWER, np.stack([getattr(t, name) for t in terms], axis=1))
             for name in "abc"}
    a, b, c = (np.pad(power[name], ((0, 0), (0, _DEGREE2 - 4), (0, 0))) for name in "abc")
    times_sigma = lambda p, k: np.roll(p, k, axis=1)           # degree 4 times sigma^k, k <= 2: nothing wraps
    columns = (b,                                                                        # x_i
               a - times_sigma(a, 1) + 2 * h * times_sigma(b, 1) - h * times_sigma(b, 2),   # u_i
               times_sigma(a, 1) + h * times_sigma(b, 2),                                   # u_{i+1}
               c)
    alpha, beta, delta, const = (np.einsum("kj,njd->nkd", _TO_BERNSTEIN, p).reshape(n, -1) for p in columns)
    hi, lo = np.tile(limits.hi, _DEGREE2 + 1), np.tile(limits.lo, _DEGREE2 + 1)
    h = h[:, :, 0]
    one, nil = np.ones((n, 1)), np.zeros((n, 1))
    middle = -one.copy()                        # x's middle coefficient x_i + h u_i >= 0; at the end >= a share
    middle[-1] = -(1.0 - _END_SHARE)            # of x_{N-1}: rest is reached with s'' < 0, in finite time
    rows = [np.concatenate(parts, axis=1) for parts in (
        (alpha, -alpha, -one, middle, -one), (beta, -beta, nil, -h, -h), (delta, -delta, nil, nil, -h),
        (hi - const, const - lo, nil, nil, nil))]
    return _normalized(rows)


def _guarded_rows(limits: Limits, points: list, guard: float, extra: list, lower_points: Optional[list] = None) -> list:
    """Each point's torque (coefficients of the variables, then the constant) kept within the limits with the
    curvature guard's +/- guard D; the torques' upper rows first, then their lower rows, then `extra`. A list of
    (N, M) arrays, one per variable and the right-hand side last. `lower_points`: the lower rows' own points
    (back-emf made linear the other way), `points` if None."""
    lo, hi = limits.lo, limits.hi
    width = len(points[0]) - 1
    upper: list[list] = [[] for _ in range(width + 1)]
    lower: list[list] = [[] for _ in range(width + 1)]
    for side, pts in ((upper, points), (lower, points if lower_points is None else lower_points)):
        curvature = [p0 - 2 * p1 + p2 for p0, p1, p2 in zip(*pts)]
        flip = 1.0 if side is upper else -1.0
        for p in pts:
            for sign in (guard, -guard):
                g = [v + sign * d for v, d in zip(p, curvature)]
                for k in range(width):
                    side[k].append(flip * g[k])                    # tau <= upper; tau >= lower, the row negated
                side[width].append(hi - g[width] if side is upper else g[width] - lo)
    cols = [u + lw for u, lw in zip(upper, lower)]
    for row in extra:
        for k in range(width + 1):
            cols[k].append(row[k])
    return [np.concatenate(c, axis=1) for c in cols]


def _finite(rows: list) -> list:
    """An infinite bound (an unbounded squeeze) is no constraint: made the trivial row 0 <= 1."""
    inf = ~np.isfinite(rows[-1])
    return [np.where(inf, 0.0, r) for r in rows[:-1]] + [np.where(inf, 1.0, rows[-1])]


def _normalized(rows: list) -> tuple:
    scale = np.abs(rows[0])
    for r in rows[1:-1]:
        scale = np.maximum(scale, np.abs(r))
    scale = np.where(scale > 0, scale, 1.0)
    return tuple(r / scale for r in rows)


def _blocks(rows: tuple, var: int) -> tuple[tuple, tuple, tuple]:
    """The rows whose coefficient of `var` is negative, positive and zero, each padded (per interval) with the
    trivial row 0 <= 1 to the largest count over the intervals."""
    coef = rows[var]
    order = np.argsort(coef, axis=1, kind="stable")             # negative first, positive last
    out = []
    for mask, take in ((coef < 0, slice(None)), (coef > 0, slice(None, None, -1)), (coef == 0, None)):
        width = max(1, int(mask.sum(axis=1).max()))
        index = order[:, take][:, :width] if take is not None else np.argsort(~mask, axis=1, kind="stable")[:, :width]
        keep = np.take_along_axis(mask, index, axis=1)
        block = [np.where(keep, np.take_along_axis(r, index, axis=1), 0.0) for r in rows[:-1]]
        block.append(np.where(keep, np.take_along_axis(rows[-1], index, axis=1), 1.0))
        out.append(tuple(block))
    return out[0], out[1], out[2]


def _paired_blocks(rows: tuple, paired: int) -> tuple[tuple, tuple, tuple]:
    """`_blocks(rows, 1)` for the rows `_rows` makes without the squeeze, without sorting: of each upper and
    lower row of one torque (coefficients negated) one bounds u from above and the other from below (a row with
    no u in it does no harm in either block: paired with a row that has u, it comes back as itself times a
    positive weight). The two last rows are x_i >= 0 (no u) and x_{i+1} >= 0 (a negative u coefficient)."""
    up = rows[1][:, :paired] < 0
    neg, pos = [], []
    for r in rows:
        first, second = r[:, :paired], r[:, paired:2 * paired]
        neg.append(np.concatenate([np.where(up, first, second), r[:, -1:]], axis=1))
        pos.append(np.where(up, second, first))
    return tuple(neg), tuple(pos), tuple(r[:, -2:-1] for r in rows)


def _eliminate(rows: tuple, var: int) -> tuple:
    """Fourier-Motzkin: the rows without variable `var` that hold exactly where some value of it satisfies all
    of `rows` (M rows -> M' rows, one fewer variable). Each (negative, positive) pair is combined with
    non-negative weights that cancel `var`, so no coefficient is divided by."""
    neg, pos, zero = _blocks(rows, var)
    wn, wp = -neg[var][:, :, None], pos[var][:, None, :]
    out = []
    for k in range(len(rows)):
        if k == var:
            continue
        pair = wp * neg[k][:, :, None] + wn * pos[k][:, None, :]
        out.append(np.concatenate([pair.reshape(len(pair), -1), zero[k]], axis=1))
    return _normalized(out)


def _x_range(blocks: tuple, pairs: int = 40_000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """From rows alpha x + beta u <= gamma, split by the sign of beta (`_blocks`): each interval's [lower, upper]
    for x where some u satisfies them all, and where none does. Fourier-Motzkin on u (as `_eliminate`), each
    pair's bound on x taken at once, a chunk of intervals at a time (about `pairs` pairs, to stay in the cache)."""
    neg, pos, zero = blocks
    n = len(neg[0])
    chunk = max(1, pairs // (neg[0].shape[1] * pos[0].shape[1]))
    lower, upper, empty = np.empty(n), np.empty(n), np.zeros(n, bool)
    with np.errstate(divide="ignore", invalid="ignore"):
        for k in range(0, n, chunk):
            part = slice(k, k + chunk)
            wn, wp = -neg[1][part, :, None], pos[1][part, None, :]
            alpha = wp * neg[0][part, :, None]
            alpha += wn * pos[0][part, None, :]
            gamma = wp * neg[2][part, :, None]
            gamma += wn * pos[2][part, None, :]
            alpha, gamma = alpha.reshape(len(alpha), -1), gamma.reshape(len(gamma), -1)
            empty[part] = ((alpha == 0) & (gamma < -1e-9)).any(axis=1)
            bound = gamma / alpha
            upper[part] = np.where(alpha > 0, bound, np.inf).min(axis=1)
            lower[part] = np.where(alpha < 0, bound, -np.inf).max(axis=1)
        alpha, gamma = zero[0], zero[2]                         # rows without u bound x alone
        bound = gamma / alpha
    upper = np.minimum(upper, np.min(bound, axis=1, where=alpha > 0, initial=np.inf))
    lower = np.maximum(lower, np.max(bound, axis=1, where=alpha < 0, initial=-np.inf))
    return lower, upper, empty | ((alpha == 0) & (gamma < -1e-9)).any(axis=1)


def _coupling(rows: tuple, h: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For the backward pass: each row (alpha, beta, gamma) in (x, u) paired with the coupling
    L <= x + 2 h u <= U gives (2 h alpha - beta) x <= 2 h gamma - beta (L if beta > 0 else U). Returned as
    A0 - L A1 - U A2 per row, scaled so that the first half of the rows (c > 0) give upper bounds on x and the
    second half (c < 0) minus lower bounds: min over each half is all the step needs."""
    alpha, beta, gamma = rows
    hh = 2 * h[:, None]
    c = hh * alpha - beta
    a1, a2 = np.where(beta > 0, beta, 0.0), np.where(beta < 0, beta, 0.0)
    halves = []
    for side in (c > 0, c < 0):
        w = np.where(side & (beta != 0), 1.0 / np.where(c != 0, np.abs(c), 1.0), 0.0)
        halves.append((np.where(w > 0, hh * gamma * w, np.inf), a1 * w, a2 * w))
    return tuple(np.ascontiguousarray(np.concatenate(pair, axis=1)) for pair in zip(*halves))


def _forward_bounds(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """u <= Q0 - x Q1 from every row with a positive coefficient of u (padded with +inf)."""
    alpha, beta, gamma = rows
    up = beta > _TINY
    safe = np.where(up, beta, 1.0)
    return np.where(up, gamma / safe, np.inf), np.where(up, alpha / safe, 0.0)


def _refuse(problem: Problem, s: float, why: str) -> PlanError:
    """Names the joint that needs the most of its limit to hold the object still at s."""
    c = problem.terms([s]).c[0]
    lo, hi = problem.limits.lo, problem.limits.hi
    need = np.maximum(c / hi, c / lo)
    j = int(np.argmax(need))
    return PlanError("bounds", f"{why} at s = {s:.4g} (holding the object still there, joint {j + 1} needs "
                               f"{c[j]:.4g} N m against its limits [{lo[j]:g}, {hi[j]:g}])")


def placed_grid(problem: Problem, gridpoints: int, uniform_share: float = UNIFORM_SHARE) -> np.ndarray:
    """`gridpoints` grid points placed where a plan loses time. Two order-1 plans, on half as many points and on
    the same with every interval halved, say how much time each coarse interval loses to its width (the
    difference of its time and its halves' times, d): order 1's loss stands in for order 2's. Order 2's error in
    an interval of width h is of order h^3 (C h^3), so the total is least with h proportional to C^(-1/3): the
    density of points follows d^(1/3) (the coarse intervals are all as wide), mixed with a uniform density
    (`uniform_share` of it) so that no stretch is left bare."""
    try:
        count = operator.index(gridpoints)          # an integer (a float, a string or a grid is refused)
    except TypeError:
        count = None
    if count is None or not 5 <= count <= MAX_GRIDPOINTS:
        raise PlanError("grid", f"placed grid points: give their number, 5 to {MAX_GRIDPOINTS} (got {gridpoints!r})")
    if not 0.0 <= uniform_share <= 1.0:
        raise PlanError("grid", f"placed grid points: the share spread evenly is 0 to 1 (got {uniform_share!r})")
    coarse = np.linspace(0.0, 1.0, max(3, count // 2))
    halved = np.sort(np.concatenate([coarse, (coarse[:-1] + coarse[1:]) / 2]))
    # breaks of the path split intervals: sum each plan's times per coarse interval
    per = [np.bincount(np.searchsorted(coarse, plan.s[:-1], side="right") - 1, np.diff(plan.profile.t),
                       len(coarse) - 1) for plan in (plan_reach(problem, grid) for grid in (coarse, halved))]
    h = np.diff(coarse)
    density = np.cbrt(np.abs(per[0] - per[1]) / h ** 3)
    weight = float(np.sum(density * h))
    density = uniform_share + (1.0 - uniform_share) * (density / weight if weight > 0 else 1.0)
    cumulative = np.concatenate([[0.0], np.cumsum(density * h)])
    grid = np.interp(np.linspace(0.0, cumulative[-1], count), cumulative, coarse)
    grid[0], grid[-1] = 0.0, 1.0
    return grid


def plan_reach(problem: Problem, gridpoints: int = 100, squeeze: Squeeze = None, guard: float = GUARD,
               clock=None, order: int = 1, placed: bool = False) -> ReachPlan:
    """The time-optimal rest-to-rest profile on `gridpoints` grid points (plus the path's breaks), every torque
    within its limits between grid points too. `squeeze`: None keeps the load shared with no squeeze (the
    model's split); a number bounds |lambda| (N); a pair (lo, hi) bounds lambda; FREE leaves it unbounded.
    `order`: 1, s'' constant on each interval (its torques kept by three points and the curvature `guard`);
    2, s'' linear in s on each interval (without the squeeze; its torques kept by Bernstein coefficients).
    `placed`: the points where the plan loses time (`placed_grid`, its time included), not evenly spaced."""
    clock = clock or RealClock()
    started = clock.precise_now()
    span = _squeeze_range(squeeze)
    if order not in (1, 2):
        raise PlanError("order", f"order {order!r}: 1 (s'' constant per interval) or 2 (s'' linear)")
    if order == 2 and span is not None:
        raise PlanError("squeeze", "order 2 plans with the load shared, without the squeeze: use order 1 for a "
                                   "squeeze (eliminating it too would make each interval's rows 3-D polytopes)")
    if order == 2 and np.isfinite(problem.speed_cap):
        raise PlanError("bounds", "order 2 takes no speed cap (s' <= a ceiling: x is quadratic between grid points): "
                                  "plan it with order 1 or the phase-plane method (--method phase)")
    emf = problem.limits.state_dependent
    if emf and order == 2:
        raise PlanError("bounds", "order 2 takes constant torque limits only (a back-emf term d s' is not linear in "
                                  "x = s'^2, and order 1 alone makes it so): plan DC motors' limits with order 1")
    if emf and span is not None:
        raise PlanError("squeeze", "the squeeze with back-emf limits is not built: plan DC motors' limits without "
                                   "the squeeze (order 1), or constant torque limits with it")
    s = _grid(problem, placed_grid(problem, gridpoints) if placed else gridpoints)     # refused input first
    terms = _point_terms(problem, s, FRACTIONS2 if order == 2 else (0.0, 0.5, 1.0))
    setup = clock.precise_now() - started
    if order == 2:
        return _plan_order2(problem, s, terms, clock, started, setup)
    iterations = 0
    if emf:
        x, sets, iterations = _linearized(problem, s, terms, guard)
    else:
        rows3 = _rows(problem.limits, s, terms, guard, span)
        if span is not None:
            rows2 = _eliminate(rows3, 2)
            x, sets = _passes(problem, s, rows2, _blocks(rows2, 1))
        else:
            rows2 = rows3
            x, sets = _passes(problem, s, rows2, _paired_blocks(rows2, 6 * len(problem.limits.lo)))
    u = (x[1:] - x[:-1]) / (2 * np.diff(s))
    lam = np.clip(_squeeze_values(rows3, x, u), *span) if span is not None else np.zeros(len(u))
    solve = clock.precise_now() - started
    terms = problem.terms(s)
    profile = profile_from_speeds(terms, problem.limits, np.sqrt(x), getattr(problem.path, "breaks", ()),
                                  squeeze=lam)
    return ReachPlan(s, x, u, lam, sets, setup, solve, profile, iterations=iterations)


def _passes(problem: Problem, s: np.ndarray, rows2: tuple, blocks: tuple) -> tuple[np.ndarray, np.ndarray]:
    """Order 1's passes on rows in (x_i, u_i) (`blocks`: the same split by the sign of u's coefficient): each
    interval's own x-range (under the speed cap), the controllable sets backwards, the greedy pass forwards.
    Returns x at the grid points and the sets (N+1, 2); PlanError where the limits leave no way to the end."""
    h = np.diff(s)
    static_lo, static_hi, empty = _x_range(blocks)
    static_hi = np.minimum(static_hi, problem.speed_cap ** 2)     # s' <= cap at both ends, so all along (x linear)
    if np.isinf(static_hi).any():
        raise PlanError("bounds", "the limits do not bound the speed along this path")
    backward = np.stack(_coupling(rows2, h), axis=1) * np.array([1.0, -1.0, -1.0])[:, None]    # (N, 3, M)
    forward = np.stack(_forward_bounds(rows2), axis=1) * np.array([1.0, -1.0])[:, None]         # (N, 2, M)
    n, half = len(h), backward.shape[2] // 2
    s_lo, s_hi, hh = static_lo.tolist(), static_hi.tolist(), (2 * h).tolist()
    sets = np.zeros((n + 1, 2))
    step = np.array([1.0, 0.0, 0.0])                              # (1, L, U): K_N is rest at the end
    for i in range(n - 1, -1, -1):
        hi_i, neg_lo = (step @ backward[i]).reshape(2, half).min(axis=1).tolist()
        hi_i, lo_i = min(s_hi[i], hi_i), max(s_lo[i], -neg_lo, 0.0)
        if lo_i > hi_i + 1e-9 * max(1.0, hi_i):
            raise _refuse(problem, float(s[i]), "no admissible speed reaches the end at rest from here")
        step[1], step[2] = sets[i] = min(lo_i, hi_i), hi_i
    if empty.any():
        raise _refuse(problem, float(s[np.argmax(empty)]), "no admissible speed")
    if sets[0, 0] > 1e-9 * max(1.0, sets[0, 1]):
        raise _refuse(problem, 0.0, "the start at rest is not controllable: no admissible profile reaches the end")
    x = [0.0] * (n + 1)
    ends = sets.tolist()
    state = np.array([1.0, 0.0])                                  # (1, x_i)
    for i in range(n):
        lower, upper = ends[i + 1]
        xi = x[i]
        state[1] = xi
        u = min(float((state @ forward[i]).min()), (upper - xi) / hh[i])
        x[i + 1] = min(max(xi + hh[i] * u, lower), upper)
    return np.array(x), sets


def _linearized(problem: Problem, s: np.ndarray, terms: tuple, guard: float) -> tuple[np.ndarray, np.ndarray, int]:
    """Order 1 with back-emf limits: the passes on constraints made linear (`_emf_linear`) around a guess of the
    speeds, then around each plan's own, until the time settles. Every iterate is safe (the linear bounds are
    conservative within the bracket its x is held to), and the fastest is kept. Returns x, the sets and the
    number of plans made.

    The first guess: the maximum velocity curve (`phase.admissible_speeds`, back-emf included) at each
    interval's points, the bracket [0, its highest there], the tangent at half of that. Then, around a plan's
    speeds v at an interval's ends: the bracket [min v (1 - w), max v (1 + w)], the tangent at their mean, w
    halving from `EMF_WIDTH` to `EMF_WIDTH_MIN` (room to gain speed where the last plan was held back, and a
    chord close to the curve), until the time changes by less than `EMF_SETTLED` or `EMF_ITERATIONS` plans."""
    mvc = np.minimum(np.max([admissible_speeds(t, problem.limits).mvc for t in terms], axis=0), problem.speed_cap)
    if (mvc >= SPEED_CAP).any():
        raise PlanError("bounds", "the limits do not bound the speed along this path")
    h = np.diff(s)
    lo, hi, v0 = np.zeros_like(mvc), mvc, mvc / 2
    best, width, duration = None, EMF_WIDTH, np.inf
    for k in range(1, EMF_ITERATIONS + 1):
        rows = _rows(problem.limits, s, terms, guard, None, (v0, lo, hi))
        try:
            x, sets = _passes(problem, s, rows, _blocks(rows, 1))
        except PlanError:
            if best is None and k < EMF_ITERATIONS and v0.max() > 1e-3 * mvc.max():
                v0 = v0 / 2                 # the first guess's tangent too high at rest (d v0 / 2 there): lower it
                continue
            if best is None:
                raise
            break                           # the bracket left no way to the end: keep the last plan
        v = np.sqrt(x)
        previous, duration = duration, float(np.sum(2 * h / (v[:-1] + v[1:])))
        if best is None or duration < best[0]:
            best = (duration, x, sets, k)
        if abs(previous - duration) < EMF_SETTLED * duration:
            break
        low, high = np.minimum(v[:-1], v[1:]), np.maximum(v[:-1], v[1:])
        lo, hi, v0 = low * (1 - width), high * (1 + width), (low + high) / 2
        width = max(width / 2, EMF_WIDTH_MIN)
    return best[1], best[2], k


def _plan_order2(problem: Problem, s: np.ndarray, terms: tuple, clock, started: float, setup: float) -> ReachPlan:
    """`plan_reach` with s'' linear on each interval: the passes of `reach2`. ReachPlan.u holds s'' at the grid
    points (N + 1) and `controllable` each K_i's x-range at its vertices."""
    h = np.diff(s)
    limits = problem.limits
    rows = _rows_order2(limits, s, terms)
    start = terms[0]
    node = (np.concatenate([start.b, -start.b], axis=1), np.concatenate([start.a, -start.a], axis=1),
            np.concatenate([limits.hi - start.c, start.c - limits.lo], axis=1))
    _, x_max, empty = _x_range(_blocks(_normalized(list(node)), 1))
    if np.isinf(x_max).any():
        raise PlanError("bounds", "the limits do not bound the speed along this path")
    if empty.any():
        raise _refuse(problem, float(s[np.argmax(empty)]), "no admissible speed")
    sets, spans, failed = reach2.backward(rows, h, x_max)
    if sets is None:
        raise _refuse(problem, float(s[failed]), "no admissible speed reaches the end at rest from here")
    e, f, g = sets[0]
    if np.max(g[f < 0] / f[f < 0], initial=-np.inf) > np.min(g[f > 0] / f[f > 0]) + 1e-9 or (g[f == 0] < -1e-9).any():
        raise _refuse(problem, 0.0, "the start at rest is not controllable: no admissible profile reaches the end")
    x, u = reach2.forward(rows, h, sets)
    solve = clock.precise_now() - started
    node_terms = problem.terms(s)
    t = np.concatenate([[0.0], np.cumsum(reach2.interval_times(x, u, h))])
    profile = _profile_order2(node_terms, limits, x, u, t)
    return ReachPlan(s, x, u, np.zeros(len(h)), spans, setup, solve, profile, order=2)


def _profile_order2(terms: Terms, limits: Limits, x: np.ndarray, u: np.ndarray, t: np.ndarray) -> Profile:
    """The order-2 plan as a `Profile`: s' and s'' at the nodes, sdd per interval the mean of its ends'."""
    sd = np.sqrt(np.maximum(x, 0.0))
    effort, torque = terms.effort(sd, u), terms.torque(sd, u)
    lo, hi = limits.lo, limits.hi
    half, mid = (hi - lo) / 2, (hi + lo) / 2
    excess = float(np.max(np.maximum(0.0, np.abs(effort - mid) - half) / half))
    near = (np.abs(effort[:-1] - mid) / half).max(axis=1) >= 0.99
    dt = np.diff(t)
    return Profile(terms.s, sd, (u[:-1] + u[1:]) / 2, t, torque, effort, excess, float((dt * near).sum() / dt.sum()))


def _squeeze_values(rows: np.ndarray, x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """On each interval, the admissible squeeze nearest 0 for the chosen (x_i, u_i)."""
    alpha, beta, mu, gamma = rows
    rest = gamma - alpha * x[:-1, None] - beta * u[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        bound = rest / mu
    hi = np.where(mu > _TINY, bound, np.inf).min(axis=1)
    lo = np.where(mu < -_TINY, bound, -np.inf).max(axis=1)
    return np.where(lo <= hi, np.clip(0.0, lo, hi), (lo + hi) / 2)


REFINE_ROUNDS = 8              # plan_reach_checked: the most times the failing intervals are halved
REFINE_PER_INTERVAL = 20       # ... the points checked inside every interval
REFINE_SLACK = 1e-9            # ... an excess of this share of a limit is rounding


def plan_reach_checked(problem: Problem, gridpoints, squeeze: Squeeze = None, order: int = 1,
                       placed: bool = False) -> tuple[ReachPlan, float, int]:
    """`plan_reach`, its bounded quantities then checked straight from the model (`sampled_torques`) at
    REFINE_PER_INTERVAL points inside every interval; each interval where one passes its limit is halved and the
    plan made again, at most REFINE_ROUNDS times. Returns the plan, its worst excess (a share of the limit; at most
    REFINE_SLACK, rounding, unless the rounds ran out) and how many rounds it took.

    The curvature guard judges an interval at three points, and a bounded quantity that bends sharply inside it
    (near a singularity: d = K q_s rose from 15.8 to 788 inside one interval of 8; a path near a straight elbow
    at 50 grid points) can peak past its limit between them: 96 % and 119 % over, found by the review of
    2026-11-24. Halving the interval brings the three points close enough."""
    grid, rounds = gridpoints, 0
    while True:    # the first plan places its own points (placed: their time in its setup and solve times)
        plan = plan_reach(problem, grid, squeeze, order=order, placed=placed and rounds == 0)
        _, tau = sampled_torques(problem, plan, REFINE_PER_INTERVAL)
        lo, hi = problem.limits.lo, problem.limits.hi
        over = np.maximum((tau - hi) / np.abs(hi), (lo - tau) / np.abs(lo)).max(axis=1)
        per_interval = over.reshape(len(plan.s) - 1, -1).max(axis=1)
        bad = np.nonzero(per_interval > REFINE_SLACK)[0]
        if not len(bad) or rounds == REFINE_ROUNDS or len(plan.s) + len(bad) > MAX_GRIDPOINTS:
            return plan, float(max(0.0, per_interval.max())), rounds
        grid = np.union1d(plan.s, (plan.s[bad] + plan.s[bad + 1]) / 2)
        rounds += 1


def _samples(plan: ReachPlan, per_interval: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """s, x, u and the squeeze at both ends of every interval and `per_interval` points inside (an interval's end
    seen from inside it), with that interval's u (order 2: s'' linear between the grid points' u, x quadratic)."""
    frac = np.linspace(0.0, 1.0, per_interval + 2)
    s0, s1 = plan.s[:-1, None], plan.s[1:, None]
    s = s0 + frac * (s1 - s0)
    s[:, -1] = np.nextafter(s1[:, 0], s0[:, 0])                  # an interval's end, seen from inside it
    if plan.order == 2:
        bend = (plan.u[1:, None] - plan.u[:-1, None]) / (s1 - s0)
        x = np.clip(plan.x[:-1, None] + 2 * plan.u[:-1, None] * (s - s0) + bend * (s - s0) ** 2, 0.0, None).ravel()
        u = (plan.u[:-1, None] + bend * (s - s0)).ravel()
    else:
        x = np.clip(plan.x[:-1, None] + 2 * plan.u[:, None] * (s - s0), 0.0, None).ravel()
        u = np.repeat(plan.u, frac.size)
    return s.ravel(), x, u, np.repeat(plan.squeeze, frac.size)


def sampled_torques(problem: Problem, plan: ReachPlan, per_interval: int = 50) -> tuple[np.ndarray, np.ndarray]:
    """The bounded quantities along the planned motion, straight from the model's inverse dynamics and squeeze
    direction (not from a, b, c), plus the back-emf term d s' of DC motors' limits (0 for constant torque
    limits): at `_samples`' points, each with its interval's u and squeeze. Returns (s (M,), tau (M, dof))."""
    s, x, u, lam = _samples(plan, per_interval)
    system = problem.system
    jp = system.joint_path(problem.path, s)
    sd = np.sqrt(x)[:, None]
    tau = system.inverse_dynamics(jp.q, jp.q_s * sd, jp.q_s * u[:, None] + jp.q_ss * x[:, None])
    return s, tau + lam[:, None] * system.squeeze_direction(jp.q) + problem.limits.d(jp.q_s) * sd


def sampled_efforts(problem: Problem, plan: ReachPlan, per_interval: int = 50) -> tuple[np.ndarray, np.ndarray]:
    """The same from the model's coefficients, a s'' + b s'^2 + d s' + c + lambda n at `_samples`' points, for a
    model without inverse dynamics (ASPOD's arm, `host_tools/apps/arm_plan.py`). Returns (s (M,), effort (M, dof))."""
    s, x, u, lam = _samples(plan, per_interval)
    t = problem.terms(s)
    return s, t.effort(np.sqrt(x), u) + lam[:, None] * t.n
