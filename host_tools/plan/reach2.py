"""The second-order reachability passes (`plan_reach(..., order=2)`): s'' linear in s on each interval, so the
state at a grid point is (x_i, u_i) = (s'^2, s'') and the controllable sets are convex polygons.

Each interval's constraints are rows  alpha x_i + beta u_i + delta u_{i+1} <= gamma (`reach._rows_order2`), and
x_{i+1} = x_i + h (u_i + u_{i+1}) exactly. A polygon is a set of rows  e x + f u <= g.

**Backwards.** K_N is rest: x = 0 (two rows). K_i: the (x_i, u_i) from which some u_{i+1} satisfies the interval's
rows with (x_i + h (u_i + u_{i+1}), u_{i+1}) in K_{i+1}. K_{i+1}'s rows are substituted, u_{i+1} is eliminated by
Fourier-Motzkin (the interval's own pairs once for all intervals, in numpy; each step pairs only K_{i+1}'s few
rows with the interval's), and the hundreds of rows that gives are cut down to the polygon's edges by clipping:
from a box, the row most violated at each vertex cuts the polygon, until no row is violated at any vertex. The
edges left are K_i's rows (a handful).

**Forwards.** From rest with the largest u_0 in K_0, each step takes the largest u_{i+1} the interval's rows and
K_{i+1} allow (a one-variable LP): the greedy pass, which also makes x_{i+1} the largest. It rides K's boundary,
where forwards is the unstable direction (as integrating a deceleration curve forwards is): rounding outside K_i
by 1e-11 would grow step by step until no u_{i+1} is admissible. So K_i is computed as what reaches K_{i+1}
shrunk by a relative 1e-8 (`_MARGIN`), and the pass takes u_{i+1} in K_{i+1} itself: each step's rounding is
absorbed by the next step's margin instead of growing.
"""
from __future__ import annotations

from typing import Optional

import numpy as np

_BOX_U = 1e6                    # |s''| never considered above this: the box the clipping starts from
_MARGIN = 1e-8                  # K_i is what reaches K_{i+1} shrunk by this (relative): rounding cannot push out


def _pairs(neg: tuple, pos: tuple) -> tuple:
    """Fourier-Motzkin on the last variable of rows (e, f, d, g) split into d < 0 and d > 0: every pair, combined with
    non-negative weights that cancel d, as rows (e, f, g); the leading axes are kept, the pairs flattened."""
    wn, wp = -neg[2][..., :, None], pos[2][..., None, :]
    out = []
    for k in (0, 1, 3):
        pair = wp * neg[k][..., :, None] + wn * pos[k][..., None, :]
        out.append(pair.reshape(pair.shape[:-2] + (-1,)))
    return tuple(out)


def _split(rows: tuple) -> tuple[tuple, tuple, tuple]:
    """Rows (e, f, d, g) of one interval split by the sign of d."""
    d = rows[2]
    return tuple(tuple(r[m] for r in rows) for m in (d < 0, d > 0, d == 0))


def _clip(vertices: list, labels: list, side: np.ndarray, row: int) -> tuple[list, list]:
    """The convex polygon `vertices` (edge k from vertex k to k + 1 lies on row labels[k]) cut by one row whose
    value e x + f u - g at each vertex is `side` (<= 0 inside)."""
    out_v, out_l = [], []
    n = len(vertices)
    for k in range(n):
        p, q = vertices[k], vertices[(k + 1) % n]
        dp, dq = side[k], side[(k + 1) % n]
        if dp <= 0:
            out_v.append(p)
            out_l.append(labels[k])
        if (dp <= 0) != (dq <= 0):
            t = dp / (dp - dq)
            out_v.append((p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])))
            out_l.append(row if dp <= 0 else labels[k])
    return out_v, out_l


def polygon(e: np.ndarray, f: np.ndarray, g: np.ndarray, x_max: float) -> Optional[tuple[np.ndarray, np.ndarray]]:
    """The polygon of rows e x + f u <= g within 0 <= x <= x_max, |u| <= _BOX_U: its edges' row numbers (-1 for the
    box's) and its vertices (K, 2); None if empty."""
    vertices = [(0.0, -_BOX_U), (x_max, -_BOX_U), (x_max, _BOX_U), (0.0, _BOX_U)]
    labels = [-1, -1, -1, -1]
    tol = 1e-12 * (np.abs(g) + np.abs(e) * x_max + np.abs(f)) + 1e-15
    for _ in range(200):
        v = np.array(vertices)
        side = (e[:, None] * v[None, :, 0] + f[:, None] * v[None, :, 1] - g[:, None]) - tol[:, None]
        worst = side.argmax(axis=0)
        cut = [int(r) for r in np.unique(worst[side[worst, np.arange(len(v))] > 0])]
        if not cut:
            return np.array(labels), v
        for r in cut:
            values = e[r] * np.array(vertices)[:, 0] + f[r] * np.array(vertices)[:, 1] - g[r]
            vertices, labels = _clip(vertices, labels, values, r)
            if len(vertices) < 3:
                return None
    return None


def backward(rows: tuple, h: np.ndarray, x_max: np.ndarray) -> tuple[Optional[list], np.ndarray, int]:
    """The controllable polygons K_0 .. K_N as rows (e, f, g), from rest at the end, and each one's x-range (its
    vertices' least and most x, (N + 1, 2)); or (None, spans, i) if K_i is empty. `rows`: (alpha, beta, delta,
    gamma), each (N, M); `x_max`: each grid point's x bound (N + 1,)."""
    n = len(h)
    spans = np.zeros((n + 1, 2))
    neg, pos, zero = _blocks_of(rows)
    static = _pairs(neg, pos)                                  # the interval's own pairs, all intervals at once
    sets: list = [None] * (n + 1)
    sets[n] = (np.array([1.0, -1.0]), np.array([0.0, 0.0]), np.array([0.0, 0.0]))     # x = 0
    for i in range(n - 1, -1, -1):
        e, f, g = sets[i + 1]
        if i + 1 < n:
            g = g - _MARGIN * (1.0 + np.abs(g))                # reach K_{i+1}'s inside (rest at the end: x = 0)
        sub = (e, e * h[i], e * h[i] + f, g)                   # K_{i+1} with x_{i+1} = x_i + h (u_i + u_{i+1})
        k_neg, k_pos, k_zero = _split(sub)
        mine_neg = tuple(r[i] for r in neg)
        mine_pos = tuple(r[i] for r in pos)
        parts = [tuple(r[i] for r in static), _pairs(k_neg, mine_pos), _pairs(mine_neg, k_pos), _pairs(k_neg, k_pos),
                 (zero[0][i], zero[1][i], zero[3][i]), (k_zero[0], k_zero[1], k_zero[3])]
        e, f, g = (np.concatenate(c) for c in zip(*parts))
        scale = np.maximum(np.abs(e), np.abs(f))
        flat = scale <= 1e-14 * (np.abs(g) + 1.0)
        if (flat & (g < -1e-9)).any():
            return None, spans, i
        keep = ~flat
        e, f, g = e[keep] / scale[keep], f[keep] / scale[keep], g[keep] / scale[keep]
        found = polygon(e, f, g, float(x_max[i]))
        if found is None:
            return None, spans, i
        labels, vertices = found
        spans[i] = vertices[:, 0].min(), vertices[:, 0].max()
        edges = np.unique(labels[labels >= 0])
        box = np.array([[-1.0, 0.0, 0.0], [1.0, 0.0, x_max[i]], [0.0, 1.0, _BOX_U], [0.0, -1.0, _BOX_U]])
        sets[i] = (np.concatenate([e[edges], box[:, 0]]), np.concatenate([f[edges], box[:, 1]]),
                   np.concatenate([g[edges], box[:, 2]]))
    return sets, spans, -1


def _blocks_of(rows: tuple) -> tuple[tuple, tuple, tuple]:
    """The interval rows split by the sign of delta (u_{i+1}'s coefficient), each padded per interval with the
    trivial row 0 <= 1 (delta 0 in the zero block; in the others a row 0 x + 0 u +/- 0 u_{i+1} <= 1, harmless)."""
    d = rows[2]
    out = []
    for mask in (d < 0, d > 0, d == 0):
        width = max(1, int(mask.sum(axis=1).max()))
        index = np.argsort(~mask, axis=1, kind="stable")[:, :width]
        keep = np.take_along_axis(mask, index, axis=1)
        block = [np.where(keep, np.take_along_axis(r, index, axis=1), 0.0) for r in rows[:-1]]
        block.append(np.where(keep, np.take_along_axis(rows[-1], index, axis=1), 1.0))
        out.append(tuple(block))
    return out[0], out[1], out[2]


def _step_bounds(rows: tuple, h: float, k_next: tuple, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For states (x, u) at the start of an interval (arrays), the range [lo, hi] of u_{i+1} its rows and K_{i+1}
    allow."""
    alpha, beta, delta, gamma = rows
    e, f, g = k_next
    coef = np.concatenate([delta, e * h + f])
    rest = np.concatenate([gamma[None] - alpha[None] * x[:, None] - beta[None] * u[:, None],
                           g[None] - e[None] * (x + h * u)[:, None]], axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        bound = rest / coef
    hi = np.min(bound, axis=1, where=coef > 1e-14, initial=np.inf)
    lo = np.max(bound, axis=1, where=coef < -1e-14, initial=-np.inf)
    return lo, hi


def _start(rows: tuple, h: float, sets: list, candidates: int = 64) -> float:
    """u_0 at rest: not simply the largest in K_0 (the next u_1 may then have to drop far below it), but the one
    that lets x_1 = h (u_0 + u_1) be the largest, searched on K_0's range of u at x = 0, refined once."""
    e, f, g = sets[0]
    lo = float(np.max(g[f < 0] / f[f < 0], initial=-np.inf))
    hi = float(np.min(g[f > 0] / f[f > 0]))
    best = hi
    for _ in range(2):
        u = np.linspace(lo, hi, candidates)
        v_lo, v_hi = _step_bounds(tuple(r[0] for r in rows), h, sets[1], np.zeros(candidates), u)
        gain = np.where(v_hi >= v_lo, u + v_hi, -np.inf)
        k = int(np.argmax(gain))
        if not np.isfinite(gain[k]):
            return best
        best = float(u[k])
        step = (hi - lo) / (candidates - 1)
        lo, hi = max(lo, best - step), min(hi, best + step)
    return best


def forward(rows: tuple, h: np.ndarray, sets: list) -> tuple[np.ndarray, np.ndarray]:
    """From rest at the start (`_start`'s u_0), at each step the largest u_{i+1}: x and u at the grid points
    (N + 1,)."""
    n = len(h)
    x, u = np.zeros(n + 1), np.zeros(n + 1)
    u[0] = _start(rows, float(h[0]), sets)
    for i in range(n):
        xi, ui = x[i], u[i]
        lo, hi = _step_bounds(tuple(r[i] for r in rows), float(h[i]), sets[i + 1], np.array([xi]), np.array([ui]))
        v = float(hi[0]) if hi[0] >= lo[0] else float(lo[0] + hi[0]) / 2
        u[i + 1] = v
        x[i + 1] = max(xi + h[i] * (ui + v), 0.0)
    x[n] = 0.0
    u[n] = -x[n - 1] / h[n - 1] - u[n - 1]
    return x, u


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
