"""A piecewise cubic Hermite setpoint: the profile an axis follows through a trajectory's knots.

Between two knots (t0, p0, v0) and (t1, p1, v1) the position is the one cubic that passes through
both positions with both velocities (the cubic Hermite interpolant), written about the segment's
start, tau = t - t0, h = t1 - t0:

    pos(tau) = p0 + v0 tau + c tau^2 + d tau^3,   c = (3 (p1 - p0) / h - 2 v0 - v1) / h,
                                                   d = (2 (p0 - p1) / h + v0 + v1) / h^2
    vel(tau) = v0 + 2 c tau + 3 d tau^2,          acc(tau) = 2 c + 6 d tau

so position and velocity are continuous at every knot and the acceleration is piecewise linear
(it may step at a knot). `HermiteProfile` has the interface of `profiles.Profile` that an axis
uses: `sample(t_s) -> (pos_rad, vel_rad_s, acc_rad_s2)` (before 0 the start; at and after
`duration_s` the exact last knot), `duration_s`, `end_pos_rad`, `end_vel_rad_s`. The joints'
tick evaluates constant-acceleration segments only (`constant_acceleration` False here): it
hands each tick of a joint following this profile to the joint's facade to sample
(firmware_py/joints_tick.py).

`bounds()` gives the lowest and highest position and the highest speed anywhere on the curve, not
only at the knots: a cubic may overshoot between two knots.
"""
from __future__ import annotations

import math
from typing import Sequence


class HermiteProfile:
    """The cubic Hermite curve through knots at `times_s` (the first 0, strictly increasing) with positions
    `pos_rad` and velocities `vel_rad_s`; ValueError for fewer than two knots, lengths that differ, a value
    that is not finite or times out of order."""

    constant_acceleration = False
    __slots__ = ("times_s", "coefficients", "duration_s", "end_pos_rad", "end_vel_rad_s", "_start")

    def __init__(self, times_s: Sequence[float], pos_rad: Sequence[float], vel_rad_s: Sequence[float]) -> None:
        n = len(times_s)
        if n < 2 or len(pos_rad) != n or len(vel_rad_s) != n:
            raise ValueError(f"a Hermite profile needs at least two knots, as many positions and velocities as "
                             f"times: {n} times, {len(pos_rad)} positions, {len(vel_rad_s)} velocities")
        if not all(math.isfinite(x) for x in (*times_s, *pos_rad, *vel_rad_s)):
            raise ValueError("a Hermite profile's times, positions and velocities must be finite")
        if times_s[0] != 0.0 or any(b <= a for a, b in zip(times_s, times_s[1:])):
            raise ValueError("a Hermite profile's knot times start at 0 and increase strictly")
        self.times_s = tuple(float(t) for t in times_s)
        self.coefficients = tuple(_cubic(t1 - t0, p0, v0, p1, v1) for t0, t1, p0, v0, p1, v1 in zip(
            times_s, times_s[1:], pos_rad, vel_rad_s, pos_rad[1:], vel_rad_s[1:]))
        self.duration_s = self.times_s[-1]
        self.end_pos_rad = float(pos_rad[-1])
        self.end_vel_rad_s = float(vel_rad_s[-1])
        self._start = (float(pos_rad[0]), float(vel_rad_s[0]), 2.0 * self.coefficients[0][2])

    def sample(self, t_s: float) -> tuple[float, float, float]:
        """(pos_rad, vel_rad_s, acc_rad_s2) at `t_s` seconds after the start (`hermite_sample`)."""
        start_pos, start_vel, start_acc = self._start
        return hermite_sample(self.times_s, self.coefficients, len(self.times_s), t_s, self.end_pos_rad,
                              self.end_vel_rad_s, start_pos, start_vel, start_acc)

    def bounds(self) -> tuple[float, float, float]:
        """(lowest position, highest position, highest |velocity|) over the whole curve."""
        lo = hi = self._start[0]
        top_speed = 0.0
        for (a, b, c, d), t0, t1 in zip(self.coefficients, self.times_s, self.times_s[1:]):
            h = t1 - t0
            # position: at both ends and where the velocity is 0 inside; speed: at both ends and at the
            # velocity's own extremum (where the acceleration is 0) inside
            for tau in (h, *_roots_within(3.0 * d, 2.0 * c, b, h)):
                p = a + tau * (b + tau * (c + tau * d))
                lo, hi = min(lo, p), max(hi, p)
            candidates = [0.0, h] + ([-c / (3.0 * d)] if d != 0.0 and 0.0 < -c / (3.0 * d) < h else [])
            top_speed = max(top_speed, *(abs(b + tau * (2.0 * c + 3.0 * d * tau)) for tau in candidates))
        return lo, hi, top_speed


class SlowedProfile:
    """A trajectory's curve (`profile`) slowed to rest along itself: from its time `from_s` (at this profile's 0) its
    clock runs slower at a constant rate, tau(t) = from_s + t - t^2 / (2 stop_s), until it stands still at
    from_s + stop_s / 2 after `stop_s`. Two arms whose trajectories are slowed alike from the same time stay on their
    plan's path together (the path is the plan's, only its timing changes), where each joint stopping at its own
    acceleration limit would not. Past the curve's end it holds there, at rest."""

    constant_acceleration = False
    __slots__ = ("profile", "from_s", "duration_s", "end_pos_rad", "end_vel_rad_s")

    def __init__(self, profile: HermiteProfile, from_s: float, stop_s: float) -> None:
        if not (math.isfinite(from_s) and stop_s > 0.0):
            raise ValueError(f"a slowed profile starts at a finite time and stops in more than 0 s, got {from_s!r}, "
                             f"{stop_s!r}")
        self.profile, self.from_s, self.duration_s = profile, float(from_s), float(stop_s)
        self.end_pos_rad = profile.sample(self.from_s + self.duration_s / 2.0)[0]
        self.end_vel_rad_s = 0.0

    def sample(self, t_s: float) -> tuple[float, float, float]:
        """(pos_rad, vel_rad_s, acc_rad_s2) at `t_s` seconds after the slowing began: the curve at tau(t), its
        velocity times tau' and its acceleration times tau'^2 plus its velocity times tau''."""
        stop_s = self.duration_s
        t = 0.0 if t_s < 0.0 else stop_s if t_s > stop_s else t_s
        rate = 1.0 - t / stop_s
        p, v, a = self.profile.sample(self.from_s + t - t * t / (2.0 * stop_s))
        if t_s >= stop_s:
            return p, 0.0, 0.0
        return p, v * rate, a * rate * rate - v / stop_s


def hermite_sample(times_s, coefficients, knots: int, t_s: float, end_pos_rad: float, end_vel_rad_s: float,
                   start_pos_rad: float, start_vel_rad_s: float, start_acc_rad_s2: float) -> tuple[float, float, float]:
    """A Hermite curve's (pos_rad, vel_rad_s, acc_rad_s2) at `t_s`, the one implementation (`HermiteProfile.sample`,
    and the world's fast loop, host_tools/worlds/fast_loop.py, compiled by numba): the first `knots` of `times_s`,
    each segment's (a, b, c, d) in `coefficients`; at and after the last knot its end, before 0 its start."""
    if t_s >= times_s[knots - 1]:
        return end_pos_rad, end_vel_rad_s, 0.0
    if t_s <= 0.0:
        return start_pos_rad, start_vel_rad_s, start_acc_rad_s2
    lo, hi = 0, knots                       # the segment: the last knot at or before t_s (bisect_right - 1)
    while lo < hi:
        mid = (lo + hi) // 2
        if t_s < times_s[mid]:
            hi = mid
        else:
            lo = mid + 1
    i = lo - 1
    row = coefficients[i]
    a, b, c, d = row[0], row[1], row[2], row[3]
    tau = t_s - times_s[i]
    return a + tau * (b + tau * (c + tau * d)), b + tau * (2.0 * c + 3.0 * d * tau), 2.0 * c + 6.0 * d * tau


def _cubic(h: float, p0: float, v0: float, p1: float, v1: float) -> tuple[float, float, float, float]:
    """(a, b, c, d) of pos(tau) = a + b tau + c tau^2 + d tau^3 through (0, p0, v0) and (h, p1, v1)."""
    slope = (p1 - p0) / h
    return p0, v0, (3.0 * slope - 2.0 * v0 - v1) / h, (v0 + v1 - 2.0 * slope) / (h * h)


def _roots_within(qa: float, qb: float, qc: float, h: float) -> list[float]:
    """The real roots of qa x^2 + qb x + qc strictly inside (0, h)."""
    if qa == 0.0:
        roots = [] if qb == 0.0 else [-qc / qb]
    else:
        disc = qb * qb - 4.0 * qa * qc
        if disc < 0.0:
            return []
        root = math.sqrt(disc)
        roots = [(-qb - root) / (2.0 * qa), (-qb + root) / (2.0 * qa)]
    return [x for x in roots if 0.0 < x < h]
