"""The second-order reachability passes (`plan_reach(..., order=2)`): s'' linear in s on each interval, so the
state at a grid point is (x_i, u_i) = (s'^2, s'') and the controllable sets are convex polygons.

Each interval's constraints are rows  alpha x_i + beta u_i + delta u_{i+1} <= gamma (`reach._rows_order2`), and
x_{i+1} = x_i + h (u_i + u_{i+1}) exactly. A polygon is a set of rows  e x + f u <= g.

**Backwards.** K_N is rest: x = 0 (two rows). K_i: the (x_i, u_i) from which some u_{i+1} satisfies the interval's
rows with (x_i + h (u_i + u_{i+1}), u_{i+1}) in K_{i+1}. K_{i+1}'s rows are substituted, u_{i+1} is eliminated by
Fourier-Motzkin (every pair of the interval's and K_{i+1}'s rows that bound it from opposite sides), and the
hundreds of rows that gives are cut down to the polygon's edges by clipping (Sutherland-Hodgman): from a box,
each row in turn cuts the polygon, unless it is violated at no vertex by more than its tolerance. The edges
left are K_i's rows (3 to 18 on the bench's paths, now and then up to 100; and the box's four).

**Forwards.** From rest with the u_0 that lets x_1 be the largest (`_start`: the largest u_0 in K_0 can force u_1
far below it), each step takes the largest u_{i+1} the interval's rows and
K_{i+1} allow (a one-variable LP): the greedy pass, which also makes x_{i+1} the largest. It rides K's boundary,
where forwards is the unstable direction (as integrating a deceleration curve forwards is): rounding outside K_i
by 1e-11 would grow step by step until no u_{i+1} is admissible. So K_i is computed as what reaches K_{i+1}
shrunk by a relative 1e-8 (`_MARGIN`), and the pass takes u_{i+1} in K_{i+1} itself: each step's rounding is
absorbed by the next step's margin instead of growing.

**Compiled.** Both passes are plain loops over numbers (`_backward_pass`, `_forward_pass` and the functions they
call), compiled by numba (`kernels.compile_kernel`: `njit(cache=True)`, no fastmath) whenever numba is
installed: a planner is not held to the bit as the firmware is, so no switch asks for it (compiled and plain
agree to the bit all the same: tests/test_plan_reach2_kernel.py). Without numba the same functions run as plain
Python: correct, but some 200 times slower (9-14 ms per grid point; the numpy code they replaced took 0.8-1.2).
Measured at 100 grid points on the bench's example and four random paths (seed 16), on a loaded 2-core
machine (its load moves these by up to 2x): all of the planning (`ReachPlan.solve_time_s`) 62-68 us per grid
point, of which the model's coefficients 26-28, the backward pass 19-27 and the forward pass under 1; before,
820-1,180 us (toppra: 650-1,460). Compiling takes some 7 s, once (numba's cache, beside this file); a
process's first order-2 plan then pays numba's import and start-up, about 1 s.
"""
from __future__ import annotations

import functools
import importlib.util
from dataclasses import dataclass
from typing import Callable, NamedTuple

import numpy as np

from kernels import compile_kernel

_BOX_U = 1e6                    # |s''| never considered above this: the box the clipping starts from
_MARGIN = 1e-8                  # K_i is what reaches K_{i+1} shrunk by this (relative): rounding cannot push out
_CANDIDATES = 64                # u_0 is searched among this many values, twice (`_start`)


@dataclass(frozen=True)
class Polygons:
    """K_0 .. K_N: K_i's rows (e, f, g) are rows[first[i]: first[i] + count[i]] ((R, 3), the box's four among them)."""

    rows: np.ndarray
    first: np.ndarray
    count: np.ndarray

    def __getitem__(self, i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """K_i's rows as (e, f, g)."""
        part = _polygon_rows(self.rows, self.first, self.count, i)
        return part[:, 0], part[:, 1], part[:, 2]

    def __len__(self) -> int:
        return len(self.first)


def backward(rows: tuple, h: np.ndarray, x_max: np.ndarray) -> tuple:
    """The controllable polygons K_0 .. K_N (`Polygons`), from rest at the end, and each one's x-range (its
    vertices' least and most x, (N + 1, 2)), and -1; or (None, spans, i) if K_i is empty. `rows`: (alpha, beta,
    delta, gamma), each (N, M); `x_max`: each grid point's x bound (N + 1,)."""
    kept, first, count, spans, failed = _passes().backward(*_arrays(*rows, h, x_max))
    if failed >= 0:
        return None, spans, int(failed)
    return Polygons(kept, first, count), spans, -1


def forward(rows: tuple, h: np.ndarray, sets: Polygons) -> tuple[np.ndarray, np.ndarray]:
    """From rest at the start (`_start`'s u_0), at each step the largest u_{i+1}: x and u at the grid points
    (N + 1,)."""
    return _passes().forward(*_arrays(*rows, h), sets.rows, sets.first, sets.count)


def _arrays(*values) -> list[np.ndarray]:
    """Each as a C-ordered float array (what the compiled passes are compiled for: no copy if it is one)."""
    return [np.ascontiguousarray(v, dtype=float) for v in values]


class _Passes(NamedTuple):
    backward: Callable
    forward: Callable


@functools.lru_cache(maxsize=1)
def _passes() -> _Passes:
    """The passes as they run: compiled when numba is installed, else the plain functions."""
    if importlib.util.find_spec("numba") is None:
        return _Passes(_backward_pass, _forward_pass)
    return _Passes(compile_kernel(_backward_pass, "order-2 backward pass", helpers=(
                       _substituted, _eliminated, _normalized_into, polygon, _worst, _clip, _edges_and_box, _kept,
                       _copied_into)),
                   compile_kernel(_forward_pass, "order-2 forward pass",
                                  helpers=(_polygon_rows, _start, _step_bounds, _bounded)))


# ---- the backward pass -------------------------------------------------------------------------------------------

def _backward_pass(alpha, beta, delta, gamma, h, x_max):
    """`backward` over arrays: K_0 .. K_N's rows kept one after another (kept (R, 3), first, count: as
    `Polygons`), the spans, and the grid point whose K is empty (-1: none)."""
    n = len(h)
    spans = np.zeros((n + 1, 2))
    first, count = np.zeros(n + 1, np.int64), np.zeros(n + 1, np.int64)
    k_rows = np.zeros((2, 3))
    k_rows[0, 0], k_rows[1, 0] = 1.0, -1.0                               # K_N: x = 0
    kept, used = _kept(np.empty((16 * (n + 1), 3)), 0, k_rows)
    count[n] = len(k_rows)
    for i in range(n - 1, -1, -1):
        margin = _MARGIN if i + 1 < n else 0.0                           # rest at the end: x = 0 itself
        rows, feasible = _eliminated(_substituted(alpha[i], beta[i], delta[i], gamma[i], k_rows, h[i], margin))
        if not feasible:
            return kept, first, count, spans, i
        vertices, labels = polygon(rows, x_max[i])
        if len(labels) == 0:
            return kept, first, count, spans, i
        spans[i, 0], spans[i, 1] = np.inf, -np.inf
        for k in range(len(vertices)):
            spans[i, 0], spans[i, 1] = min(spans[i, 0], vertices[k, 0]), max(spans[i, 1], vertices[k, 0])
        k_rows = _edges_and_box(rows, labels, x_max[i])
        first[i], count[i] = used, len(k_rows)
        kept, used = _kept(kept, used, k_rows)
    return kept, first, count, spans, -1


def _substituted(alpha, beta, delta, gamma, k_rows, h, margin):
    """The interval's rows and K_{i+1}'s, both as rows (a, b, d, g) in (x_i, u_i, u_{i+1}) ((M + K, 4)): K_{i+1}'s
    rows e x_{i+1} + f u_{i+1} <= g with x_{i+1} = x_i + h (u_i + u_{i+1}), g shrunk by `margin` (relative)."""
    m, k = len(alpha), len(k_rows)
    out = np.empty((m + k, 4))
    for j in range(m):
        out[j, 0], out[j, 1], out[j, 2], out[j, 3] = alpha[j], beta[j], delta[j], gamma[j]
    for j in range(k):
        e, f, g = k_rows[j, 0], k_rows[j, 1], k_rows[j, 2]
        out[m + j, 0], out[m + j, 1], out[m + j, 2] = e, e * h, e * h + f
        out[m + j, 3] = g - margin * (1.0 + abs(g))
    return out


def _eliminated(rows):
    """Fourier-Motzkin on u_{i+1} (rows' third column): every pair bounding it from opposite sides, combined
    with non-negative weights that cancel it, and the rows without it; as rows (e, f, g) (R, 3) meaning
    e x + f u <= g, each scaled so that max(|e|, |f|) = 1 (`_normalized_into`), and whether all can hold."""
    d = rows[:, 2]
    neg, pos, zero = np.flatnonzero(d < 0), np.flatnonzero(d > 0), np.flatnonzero(d == 0)
    out = np.empty((len(neg) * len(pos) + len(zero), 3))
    used = 0
    for j in neg:
        for k in pos:
            wp, wn = d[k], -d[j]
            used = _normalized_into(out, used, wp * rows[j, 0] + wn * rows[k, 0], wp * rows[j, 1] + wn * rows[k, 1],
                                    wp * rows[j, 3] + wn * rows[k, 3])
            if used < 0:
                return out[:0], False
    for j in zero:
        used = _normalized_into(out, used, rows[j, 0], rows[j, 1], rows[j, 3])
        if used < 0:
            return out[:0], False
    return out[:used], True


def _normalized_into(out, used, e, f, g):
    """The row e x + f u <= g scaled to max(|e|, |f|) = 1 into out[used]; the new count of rows. A row with
    neither x nor u in it is left out, or makes the count -1 if it cannot hold (0 <= g < 0)."""
    scale = max(abs(e), abs(f))
    if scale <= 1e-14 * (abs(g) + 1.0):
        return -1 if g < -1e-9 else used
    out[used, 0], out[used, 1], out[used, 2] = e / scale, f / scale, g / scale
    return used + 1


def polygon(rows, x_max):
    """The polygon of rows (e, f, g) (R, 3), e x + f u <= g, within 0 <= x <= x_max, |u| <= _BOX_U: its vertices
    (K, 2) and its edges' row numbers (K,), edge k from vertex k to vertex k + 1 (-1: the box's); K = 0 if
    empty. The box is clipped by each row in turn (exact for a convex polygon), except a row violated at no
    vertex by more than 1e-12 of its size; fewer than 3 vertices left is empty."""
    vertices, labels = np.empty((4 + len(rows), 2)), np.full(4 + len(rows), -1)
    spare_vertices, spare_labels = np.empty_like(vertices), np.empty_like(labels)
    box_x, box_u = (0.0, x_max, x_max, 0.0), (-_BOX_U, -_BOX_U, _BOX_U, _BOX_U)
    for k in range(4):
        vertices[k, 0], vertices[k, 1] = box_x[k], box_u[k]
    corners = 4
    for r in range(len(rows)):
        e, f, g = rows[r, 0], rows[r, 1], rows[r, 2]
        if _worst(vertices, corners, e, f, g) <= 1e-12 * (abs(g) + abs(e) * x_max + abs(f)) + 1e-15:
            continue
        cut, cut_labels, corners = _clip(vertices, labels, corners, e, f, g, r, spare_vertices, spare_labels)
        spare_vertices, spare_labels, vertices, labels = vertices, labels, cut, cut_labels
        if corners < 3:
            return vertices[:0], labels[:0]
    return vertices[:corners], labels[:corners]


def _worst(vertices, corners, e, f, g):
    """The most e x + f u - g at the polygon's vertices."""
    worst = -np.inf
    for k in range(corners):
        worst = max(worst, e * vertices[k, 0] + f * vertices[k, 1] - g)
    return worst


def _clip(vertices, labels, corners, e, f, g, row, out, out_labels):
    """The convex polygon vertices[:corners] (edge k on row labels[k]) cut by the row e x + f u <= g numbered
    `row`: into out, out_labels (or larger arrays if they could be too small), returned with the new count."""
    if len(out) < 2 * corners:                                    # each vertex gives at most two
        out, out_labels = np.empty((2 * corners, 2)), np.empty(2 * corners, np.int64)
    made = 0
    for k in range(corners):
        n = k + 1 if k + 1 < corners else 0
        px, pu, qx, qu = vertices[k, 0], vertices[k, 1], vertices[n, 0], vertices[n, 1]
        dp, dq = e * px + f * pu - g, e * qx + f * qu - g
        if dp <= 0:
            out[made, 0], out[made, 1], out_labels[made] = px, pu, labels[k]
            made += 1
        if (dp <= 0) != (dq <= 0):
            t = dp / (dp - dq)
            out[made, 0], out[made, 1] = px + t * (qx - px), pu + t * (qu - pu)
            out_labels[made] = row if dp <= 0 else labels[k]
            made += 1
    return out, out_labels, made


def _edges_and_box(rows, labels, x_max):
    """K_i's rows (K, 3): the rows of the polygon's edges, each once, then the box's four."""
    out = np.empty((len(labels) + 4, 3))
    taken = np.zeros(len(rows), np.bool_)
    used = 0
    for r in labels:
        if r >= 0 and not taken[r]:
            taken[r] = True
            out[used, 0], out[used, 1], out[used, 2] = rows[r, 0], rows[r, 1], rows[r, 2]
            used += 1
    box = (-1.0, 0.0, 0.0, 1.0, 0.0, x_max, 0.0, 1.0, _BOX_U, 0.0, -1.0, _BOX_U)    # x >= 0, x <= x_max, |u| <= box
    for j in range(4):
        out[used + j, 0], out[used + j, 1], out[used + j, 2] = box[3 * j], box[3 * j + 1], box[3 * j + 2]
    return out[:used + 4]


def _kept(kept, used, rows):
    """`rows` appended to kept[:used] (made twice as large when full): the array and its new count."""
    if used + len(rows) > len(kept):
        kept = _copied_into(np.empty((2 * (used + len(rows)), 3)), 0, kept[:used])
    return _copied_into(kept, used, rows), used + len(rows)


def _copied_into(out, at, rows):
    """out with rows (R, 3) copied into out[at: at + R]."""
    for j in range(len(rows)):
        out[at + j, 0], out[at + j, 1], out[at + j, 2] = rows[j, 0], rows[j, 1], rows[j, 2]
    return out


# ---- the forward pass --------------------------------------------------------------------------------------------

def _forward_pass(alpha, beta, delta, gamma, h, kept, first, count):
    """`forward` over arrays (the polygons as `Polygons`' arrays)."""
    n = len(h)
    x, u = np.zeros(n + 1), np.zeros(n + 1)
    u[0] = _start(alpha[0], beta[0], delta[0], gamma[0], h[0], _polygon_rows(kept, first, count, 0),
                  _polygon_rows(kept, first, count, 1))
    for i in range(n):
        lo, hi = _step_bounds(alpha[i], beta[i], delta[i], gamma[i], h[i], _polygon_rows(kept, first, count, i + 1),
                              x[i], u[i])
        v = hi if hi >= lo else (lo + hi) / 2
        u[i + 1] = v
        x[i + 1] = max(x[i] + h[i] * (u[i] + v), 0.0)
    x[n] = 0.0
    u[n] = -x[n - 1] / h[n - 1] - u[n - 1]
    return x, u


def _polygon_rows(kept, first, count, i):
    """K_i's rows (e, f, g) (K, 3)."""
    return kept[first[i]:first[i] + count[i]]


def _step_bounds(alpha, beta, delta, gamma, h, k_next, x, u):
    """For the state (x, u) at the start of an interval, the range (lo, hi) of u_{i+1} its rows and K_{i+1}'s
    (`k_next` (K, 3)) allow; lo > hi if none."""
    lo, hi = -np.inf, np.inf
    for j in range(len(alpha)):
        lo, hi = _bounded(lo, hi, delta[j], gamma[j] - alpha[j] * x - beta[j] * u, 1e-14)
    for j in range(len(k_next)):
        e, f, g = k_next[j, 0], k_next[j, 1], k_next[j, 2]
        lo, hi = _bounded(lo, hi, e * h + f, g - e * (x + h * u), 1e-14)
    return lo, hi


def _bounded(lo, hi, coef, rest, tiny):
    """The range [lo, hi] of a variable v narrowed by the row coef v <= rest (no bound if |coef| <= tiny)."""
    if coef > tiny:
        return lo, min(hi, rest / coef)
    if coef < -tiny:
        return max(lo, rest / coef), hi
    return lo, hi


def _start(alpha, beta, delta, gamma, h, k_first, k_next):
    """u_0 at rest: not simply the largest in K_0 (the next u_1 may then have to drop far below it), but the one
    that lets x_1 = h (u_0 + u_1) be the largest, searched on K_0's range of u at x = 0 (`_CANDIDATES` values
    evenly spaced), refined once about the best. `k_first`, `k_next`: K_0's and K_1's rows."""
    lo, hi = -np.inf, np.inf
    for j in range(len(k_first)):
        lo, hi = _bounded(lo, hi, k_first[j, 1], k_first[j, 2], 0.0)
    best = hi
    for _ in range(2):
        step = (hi - lo) / (_CANDIDATES - 1)
        top, pick = -np.inf, hi
        for c in range(_CANDIDATES):
            u = c * step + lo if c < _CANDIDATES - 1 else hi
            v_lo, v_hi = _step_bounds(alpha, beta, delta, gamma, h, k_next, 0.0, u)
            gain = u + v_hi if v_hi >= v_lo else -np.inf
            if gain > top:
                top, pick = gain, u
        if not np.isfinite(top):
            return best
        best = pick
        lo, hi = max(lo, best - step), min(hi, best + step)
    return best


def interval_times(x: np.ndarray, u: np.ndarray, h: np.ndarray) -> np.ndarray:
    """The time to cross each interval where x = x_i + 2 u_i sigma + C sigma^2, C = (u_{i+1} - u_i) / h: the
    integral of d sigma / sqrt(x), in closed form (arctangent for C < 0, logarithm for C > 0, the chord's
    2 h / (v_i + v_{i+1}) where C hardly bends x)."""
    x0, x1, u0, u1 = x[:-1], x[1:], u[:-1], u[1:]
    v0, v1 = np.sqrt(np.maximum(x0, 0.0)), np.sqrt(np.maximum(x1, 0.0))
    c = (u1 - u0) / h
    k = np.sqrt(np.abs(c))
    with np.errstate(divide="ignore", invalid="ignore"):
        chord = 2 * h / (v0 + v1)
        bent = np.arctan2(k * (u0 * v1 - u1 * v0), u0 * u1 + k * k * v0 * v1) / k
        x_start = np.where(u0 >= 0, k * v0 + u0, (k * k * x0 - u0 * u0) / (k * v0 - u0))
        log = np.log1p((k * h * (u0 + u1) / (v0 + v1) + c * h) / x_start) / k
    straight = np.abs(c) * h * h <= 1e-9 * (x0 + x1)
    return np.where(straight, chord, np.where(c < 0, bent, log))
