"""The object's path: its centre w(s) for s in [0, 1], and the derivatives dw/ds, d2w/ds2 the dynamics need.

Two kinds, both exact in s (no numerical differentiation):

- `PolynomialPath`: each coordinate a polynomial in s (a straight line is the degree-one case);
- `PiecewisePath`: polynomial pieces joined end to end, each over its own part of [0, 1]. The joins must be
  continuous in w and in dw/ds (a corner would force the object to stop there); d2w/ds2 may jump, and those
  joins are the report's "discontinuity points" (section 2.1).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

from host_tools.plan.errors import PlanError, finite


@dataclass(frozen=True)
class PathPoints:
    """w, dw/ds and d2w/ds2 at an array of s, each of shape (len(s), 2)."""

    w: np.ndarray
    w_s: np.ndarray
    w_ss: np.ndarray


class PolynomialPath:
    """w(s) = (sum x_k s^k, sum y_k s^k): coefficients lowest power first."""

    def __init__(self, x: Sequence[float], y: Sequence[float]) -> None:
        self.x = np.polynomial.Polynomial(np.asarray(x, dtype=float))
        self.y = np.polynomial.Polynomial(np.asarray(y, dtype=float))
        if not (np.all(np.isfinite(self.x.coef)) and np.all(np.isfinite(self.y.coef))):
            raise PlanError("path", "the path's coefficients must be finite numbers")

    breaks: tuple[float, ...] = ()

    @classmethod
    def line(cls, start: Sequence[float], end: Sequence[float]) -> "PolynomialPath":
        (x0, y0), (x1, y1) = start, end
        return cls((x0, x1 - x0), (y0, y1 - y0))

    def __call__(self, s) -> PathPoints:
        s = np.asarray(s, dtype=float)
        dx, dy = self.x.deriv(), self.y.deriv()
        return PathPoints(np.stack([self.x(s), self.y(s)], -1), np.stack([dx(s), dy(s)], -1),
                          np.stack([dx.deriv()(s), dy.deriv()(s)], -1))

    def describe(self) -> dict:
        return {"kind": "polynomial", "x": self.x.coef.tolist(), "y": self.y.coef.tolist()}


class PiecewisePath:
    """Pieces (each a PolynomialPath in the global s) over [knots[i], knots[i+1]]; continuous in w and dw/ds."""

    TOLERANCE = 1e-9

    def __init__(self, knots: Sequence[float], pieces: Sequence[PolynomialPath]) -> None:
        knots = [float(k) for k in knots]
        if len(pieces) < 1 or len(knots) != len(pieces) + 1:
            raise PlanError("path", "a piecewise path needs one more knot than pieces")
        if knots[0] != 0.0 or knots[-1] != 1.0 or any(b <= a for a, b in zip(knots, knots[1:])):
            raise PlanError("path", "the knots must rise from 0 to 1")
        self.knots, self.pieces = np.asarray(knots), list(pieces)
        jumps = []
        for k, (left, right) in enumerate(zip(self.pieces, self.pieces[1:]), start=1):
            a, b = left(knots[k]), right(knots[k])
            if np.abs(a.w - b.w).max() > self.TOLERANCE:
                raise PlanError("path", f"the path jumps at s = {knots[k]:g}")
            if np.abs(a.w_s - b.w_s).max() > self.TOLERANCE * max(1.0, np.abs(a.w_s).max()):
                raise PlanError("path", f"the path has a corner at s = {knots[k]:g} (dw/ds jumps); the object "
                                        "would have to stop there: split it into two paths")
            if np.abs(a.w_ss - b.w_ss).max() > self.TOLERANCE:
                jumps.append(knots[k])
        self.breaks = tuple(jumps)

    def __call__(self, s) -> PathPoints:
        s = np.atleast_1d(np.asarray(s, dtype=float))
        piece = np.clip(np.searchsorted(self.knots, s, side="right") - 1, 0, len(self.pieces) - 1)
        w, w_s, w_ss = (np.empty(s.shape + (2,)) for _ in range(3))
        for k, p in enumerate(self.pieces):
            mask = piece == k
            if mask.any():
                pts = p(s[mask])
                w[mask], w_s[mask], w_ss[mask] = pts.w, pts.w_s, pts.w_ss
        return PathPoints(w, w_s, w_ss)

    def describe(self) -> dict:
        return {"kind": "piecewise", "knots": self.knots.tolist(), "pieces": [p.describe() for p in self.pieces]}


def _numbers(value, what: str, n: Optional[int] = None) -> list:
    """`value` as a list of finite floats (`n` of them if given): PlanError naming `what` else (a bool, text, an
    integer too large for a float, an infinity are not numbers here)."""
    if not isinstance(value, (list, tuple)) or (n is not None and len(value) != n) or not value:
        raise PlanError("path", f"{what} must be a list of {n or 'one or more'} finite numbers")
    out = [finite(v) for v in value]
    if None in out:
        v = value[out.index(None)]
        raise PlanError("path", f"{what} must hold finite numbers, not {type(v).__name__} {str(v)[:40]}")
    return out


def path_from_dict(spec: dict, piece: bool = False):
    """A path from its description (the `describe()` form; what `aspod plan --path FILE` reads)."""
    if not isinstance(spec, dict):
        raise PlanError("path", "a path is an object with a 'kind'")
    kind = spec.get("kind")
    try:
        if kind == "line":
            return PolynomialPath.line(_numbers(spec["start"], "path.start", 2), _numbers(spec["end"], "path.end", 2))
        if kind == "polynomial":
            return PolynomialPath(_numbers(spec["x"], "path.x"), _numbers(spec["y"], "path.y"))
        if kind == "piecewise" and not piece:
            pieces = spec["pieces"]
            if not isinstance(pieces, list):
                raise PlanError("path", "path.pieces must be a list of paths")
            return PiecewisePath(_numbers(spec["knots"], "path.knots"), [path_from_dict(p, True) for p in pieces])
    except PlanError:
        raise
    except (KeyError, TypeError, ValueError) as e:
        raise PlanError("path", f"a {kind} path needs {e}" if isinstance(e, KeyError) else f"{kind} path: {e}")
    if kind == "piecewise":
        raise PlanError("path", "a piece of a piecewise path is a line or a polynomial, not another piecewise path")
    raise PlanError("path", f"unknown path kind {str(kind)[:40]!r} (line, polynomial, piecewise)")
