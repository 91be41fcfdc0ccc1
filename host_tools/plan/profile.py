"""A speed profile along the path, whoever planned it: s' at grid nodes, and what follows from it (time, the
pseudo-acceleration per interval, torques, how close each joint runs to its limit)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from host_tools.plan.errors import PlanError
from host_tools.plan.phase import Terms
from host_tools.plan.bounds import Limits


@dataclass(frozen=True)
class Profile:
    """s' at the nodes s (uniform), s'' constant over each interval (x = s'^2 linear in s), and the torques."""

    s: np.ndarray
    sd: np.ndarray
    sdd: np.ndarray           # per interval (len(s) - 1)
    t: np.ndarray             # time at each node, from 0
    torque: np.ndarray        # (N, dof) at each node, with the s'' of the interval it starts (the last: its own)
    effort: np.ndarray        # (N, dof) the bounded quantity (torque, or scaled voltage)
    worst_violation: float    # largest excess over a limit at the nodes, as a fraction of (upper - lower) / 2
    saturated_time: float     # fraction of the time at least one joint is within 1 % of a limit

    @property
    def duration(self) -> float:
        return float(self.t[-1])


def profile_from_speeds(terms: Terms, limits: Limits, sd: np.ndarray, breaks=(), squeeze=None) -> Profile:
    """Everything that follows from s' at the nodes of `terms`. At a node on one of the path's `breaks` the
    torques jump with d2w/ds2, so the interval ending there is not judged by the next piece's terms.
    `squeeze`: the squeeze force on each interval (N), added to its torques along n(s); None: no squeeze."""
    s = terms.s
    sd = np.asarray(sd, float)
    x = sd * sd
    h = np.diff(s)
    sdd = (x[1:] - x[:-1]) / (2 * h)
    moving = sd[:-1] + sd[1:]
    if (moving <= 0).any():
        k = int(np.argmin(moving))
        raise PlanError("path", f"the object cannot move past s = {s[k]:.4g} (s' is 0 on both sides)")
    t = np.concatenate([[0.0], np.cumsum(2 * h / moving)])
    node_sdd = np.concatenate([sdd, sdd[-1:]])
    effort = terms.effort(sd, node_sdd)
    torque = terms.torque(sd, node_sdd)
    end_effort = terms.at(slice(1, None)).effort(sd[1:], sdd)     # each interval's s'' at its far node as well
    if squeeze is not None:
        lam = np.asarray(squeeze, float)[:, None]
        node_lam = np.concatenate([lam, lam[-1:]])
        effort, torque = effort + node_lam * terms.n, torque + node_lam * terms.n
        end_effort = end_effort + lam * terms.n[1:]
    lo, hi = limits.lo, limits.hi
    half, mid = (hi - lo) / 2, (hi + lo) / 2
    on_break = np.isin(s[1:], np.asarray(breaks, float))
    end_effort = np.where(on_break[:, None], mid, end_effort)
    excess = np.maximum(0.0, np.concatenate([np.abs(effort - mid), np.abs(end_effort - mid)]) - half) / half
    near = (np.abs(effort[:-1] - mid) / half).max(axis=1) >= 0.99
    dt = np.diff(t)
    return Profile(s, sd, sdd, t, torque, effort, float(excess.max()), float((dt * near).sum() / dt.sum()))
