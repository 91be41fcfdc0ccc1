"""The arm's trajectory buffer: knots uploaded one at a time (TrajPoint), run on j1..j4 and the mount at once
(TrajRun).

A knot is a time from the trajectory's start and, for each of the four arm joints, a position and a
velocity, in the protocol's units (s, deg, deg/s). The buffer takes them strictly in order (index 0 at
t = 0, then the next index at a later time) up to `TRAJECTORY_KNOTS`; a refused knot changes nothing.
`profiles()` turns the knots into each joint's cubic Hermite setpoint (firmware_py/hermite.py), in
radians; the arm checks those against each joint's limits and starts them (`ArmController.run_trajectory`).

The knots are the controller's memory only: uploading needs no particular controller state, and they
stay after a run (and after a fault) until TrajClear.
"""
from __future__ import annotations

import math
from typing import NamedTuple

from protocol.messages import TRAJECTORY_JOINTS
from protocol.reasons import Reason

from firmware_py.hermite import HermiteProfile

TRAJECTORY_KNOTS = 256            # the buffer's size: a 46-byte payload a knot, 11.8 KB uploaded at most
START_TOLERANCE_DEG = 0.1         # a trajectory's first knot must be this near where each joint holds ...
REST_TOLERANCE_DPS = 0.01         # ... and its first and last knots this near rest (TRAJ_ENDPOINTS)
JOINT_NAMES = tuple(a.name.lower() for a in TRAJECTORY_JOINTS)


class Knot(NamedTuple):
    """One knot as uploaded: its time [s] and each joint's position [deg] and velocity [deg/s] (j1..j4, mount)."""

    t_s: float
    pos_deg: tuple[float, ...]
    vel_deg_s: tuple[float, ...]


def knot_of(msg) -> Knot:
    """The knot a TrajPoint message carries."""
    return Knot(msg.t, tuple(getattr(msg, f"{j}_pos") for j in JOINT_NAMES),
                tuple(getattr(msg, f"{j}_vel") for j in JOINT_NAMES))


class TrajectoryBuffer:
    """At most `capacity` knots, in order; `append` and `clear` are the only ways to change them."""

    def __init__(self, capacity: int = TRAJECTORY_KNOTS) -> None:
        self.capacity = capacity
        self.knots: list[Knot] = []

    @property
    def t_last_s(self) -> float:
        return self.knots[-1].t_s if self.knots else 0.0

    def clear(self) -> None:
        self.knots.clear()

    def append(self, index: int, knot: Knot) -> tuple[Reason, str]:
        """Take `knot` as knot `index`, or refuse (nothing changes): TRAJ_FULL, TRAJ_ORDER, OUT_OF_RANGE."""
        held = len(self.knots)
        if index == held and held >= self.capacity:
            return Reason.TRAJ_FULL, f"the buffer holds {self.capacity} knots, its most"
        if index != held:
            return Reason.TRAJ_ORDER, f"knot {index} sent; the next is {held}"
        values = (knot.t_s, *knot.pos_deg, *knot.vel_deg_s)
        if len(knot.pos_deg) != len(JOINT_NAMES) or len(knot.vel_deg_s) != len(JOINT_NAMES) or not all(
                math.isfinite(v) for v in values):
            return Reason.OUT_OF_RANGE, f"knot {index}: a finite position and velocity of each of j1..j4 and the mount"
        if held == 0 and knot.t_s != 0.0:
            return Reason.TRAJ_ORDER, f"the first knot is at t = 0, not {knot.t_s} s"
        if held and not knot.t_s > self.knots[-1].t_s:
            return Reason.TRAJ_ORDER, f"knot {index} at {knot.t_s} s is not after knot {held - 1} at " \
                                      f"{self.knots[-1].t_s} s"
        self.knots.append(knot)
        return Reason.OK, ""

    def check_count(self, count: int) -> tuple[Reason, str]:
        """TRAJ_COUNT unless the host's `count` is the number of knots held, and at least two."""
        held = len(self.knots)
        if count != held or held < 2:
            return Reason.TRAJ_COUNT, f"TrajRun counts {count} knots; the buffer holds {held} (at least 2 to run)"
        return Reason.OK, ""

    def profiles(self) -> list[HermiteProfile]:
        """Each joint's setpoint through the knots, in radians (j1..j4 and the mount)."""
        times = [k.t_s for k in self.knots]
        return [HermiteProfile(times, [math.radians(k.pos_deg[j]) for k in self.knots],
                               [math.radians(k.vel_deg_s[j]) for k in self.knots]) for j in range(len(JOINT_NAMES))]
