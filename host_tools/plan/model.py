"""Two planar two-link arms holding one object: kinematics, dynamics, and the report's parameterized dynamics.

The report (section 1) writes the closed chain as u = D(q) q'' + H(q, q') + G(q) + J(q)^T F, with F the forces
the arms apply to the object, F = M_l w'' + B + G_l. Here:

- Each arm is a planar two-link arm on its own base, joints q = (shoulder, elbow), the shoulder angle from the
  x axis and the elbow relative to the upper link. Joint order in u and q: arm 1 shoulder, arm 1 elbow, arm 2
  shoulder, arm 2 elbow (the report's u1..u4).
- A link is a uniform rod (centre of mass mid-link, inertia m l^2 / 12) or, as an option, a point mass at its
  far end ("point"): the report does not say which it used.
- The object keeps its orientation (the report's example does), so each arm holds it at one grasp point by a
  pin: three of the four grasp force components balance the object (x, y and moment) and one is free, the
  squeeze along the line between the grasps. **The load is shared by the smallest grasp forces that balance the
  object** (the pseudo-inverse of the grasp matrix). With grasps symmetric about the object's centre, as in the
  example, that is an equal split with no squeeze. The squeeze's direction in joint torques is `n(s)`, so a
  planner may use it as a free variable: u = a s'' + b s'^2 + c + lambda n.
- The path w(s) fixes q(s) by inverse kinematics; dq/ds = J^-1 dw/ds and d2q/ds2 = J^-1 (d2w/ds2 - J'(q, dq/ds)
  dq/ds) exactly, so
      a(s) = D f_s + J^T share(m w_s),   b(s) = D f_ss + H(f, f_s) + J^T share(m w_ss),
      c(s) = G(f) + J^T share(m g).
  They are computed as the report defines them: one inverse dynamics, evaluated three ways.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from host_tools.plan.errors import PlanError

GRAVITY = 9.81          # m/s^2, along -y


@dataclass(frozen=True)
class Arm:
    """One planar two-link arm: base position, link lengths and masses, and which elbow it uses (+1 or -1: the
    sign of the elbow angle)."""

    base: tuple[float, float]
    lengths: tuple[float, float] = (1.0, 1.0)
    masses: tuple[float, float] = (1.0, 1.0)
    elbow: int = 1
    links: str = "rod"                 # "rod" (uniform) or "point" (mass at the far end)

    def __post_init__(self) -> None:
        if self.elbow not in (1, -1):
            raise PlanError("arms", "elbow must be +1 or -1 (the sign of the elbow angle)")
        if self.links not in ("rod", "point"):
            raise PlanError("arms", "links are 'rod' (uniform) or 'point' (mass at the far end)")
        if min(self.lengths) <= 0 or min(self.masses) < 0:
            raise PlanError("arms", "link lengths must be positive and masses not negative")

    @property
    def centres(self) -> tuple[float, float]:
        """Distance of each link's centre of mass from its joint."""
        return tuple(l / 2 for l in self.lengths) if self.links == "rod" else self.lengths

    @property
    def inertias(self) -> tuple[float, float]:
        """Each link's moment of inertia about its centre of mass."""
        if self.links == "point":
            return (0.0, 0.0)
        return tuple(m * l * l / 12 for m, l in zip(self.masses, self.lengths))

    # ---- kinematics, vectorized over the leading axis ----
    def inverse(self, p: np.ndarray) -> np.ndarray:
        """Joint angles (N, 2) that put the hand at p (N, 2); NaN where p is out of reach."""
        l1, l2 = self.lengths
        x, y = p[:, 0] - self.base[0], p[:, 1] - self.base[1]
        c2 = (x * x + y * y - l1 * l1 - l2 * l2) / (2 * l1 * l2)
        with np.errstate(invalid="ignore"):
            q2 = self.elbow * np.arccos(np.where(np.abs(c2) <= 1.0, c2, np.nan))
        q1 = np.arctan2(y, x) - np.arctan2(l2 * np.sin(q2), l1 + l2 * np.cos(q2))
        return np.stack([q1, q2], -1)

    def forward(self, q: np.ndarray) -> np.ndarray:
        l1, l2 = self.lengths
        q1, q12 = q[:, 0], q[:, 0] + q[:, 1]
        return np.stack([self.base[0] + l1 * np.cos(q1) + l2 * np.cos(q12),
                         self.base[1] + l1 * np.sin(q1) + l2 * np.sin(q12)], -1)

    def jacobian(self, q: np.ndarray) -> np.ndarray:
        """(N, 2, 2): d(hand)/dq."""
        l1, l2 = self.lengths
        q1, q12 = q[:, 0], q[:, 0] + q[:, 1]
        j = np.empty(q.shape[:1] + (2, 2))
        j[:, 0, 0] = -l1 * np.sin(q1) - l2 * np.sin(q12)
        j[:, 0, 1] = -l2 * np.sin(q12)
        j[:, 1, 0] = l1 * np.cos(q1) + l2 * np.cos(q12)
        j[:, 1, 1] = l2 * np.cos(q12)
        return j

    def hand_bias(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """J'(q, qd) qd: the hand's acceleration when qdd = 0."""
        l1, l2 = self.lengths
        q1, q12 = q[:, 0], q[:, 0] + q[:, 1]
        w1, w12 = qd[:, 0], qd[:, 0] + qd[:, 1]
        return -np.stack([l1 * np.cos(q1) * w1 ** 2 + l2 * np.cos(q12) * w12 ** 2,
                          l1 * np.sin(q1) * w1 ** 2 + l2 * np.sin(q12) * w12 ** 2], -1)

    # ---- dynamics ----
    def torques(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, gravity: float) -> np.ndarray:
        """The arm's own inverse dynamics D qdd + H(q, qd) + G(q), (N, 2)."""
        (m1, m2), (l1, _), (r1, r2), (i1, i2) = self.masses, self.lengths, self.centres, self.inertias
        c2, s2 = np.cos(q[:, 1]), np.sin(q[:, 1])
        d11 = m1 * r1 ** 2 + i1 + m2 * (l1 ** 2 + r2 ** 2 + 2 * l1 * r2 * c2) + i2
        d12 = m2 * (r2 ** 2 + l1 * r2 * c2) + i2
        d22 = m2 * r2 ** 2 + i2
        h = -m2 * l1 * r2 * s2
        g1 = (m1 * r1 + m2 * l1) * gravity * np.cos(q[:, 0]) + m2 * r2 * gravity * np.cos(q[:, 0] + q[:, 1])
        g2 = m2 * r2 * gravity * np.cos(q[:, 0] + q[:, 1])
        w1, w2 = qd[:, 0], qd[:, 1]
        return np.stack([d11 * qdd[:, 0] + d12 * qdd[:, 1] + h * (2 * w1 * w2 + w2 * w2) + g1,
                         d12 * qdd[:, 0] + d22 * qdd[:, 1] - h * w1 * w1 + g2], -1)


@dataclass(frozen=True)
class Held:
    """The object: its mass, size (for drawing), and the grasp points relative to its centre."""

    mass: float = 0.25
    size: tuple[float, float] = (0.25, 0.1)
    grasps: tuple[tuple[float, float], tuple[float, float]] = ((-0.125, 0.0), (0.125, 0.0))


@dataclass(frozen=True)
class JointPath:
    """q(s), dq/ds, d2q/ds2 (each (N, 4)) and the object's w(s) and derivatives, at an array of s."""

    s: np.ndarray
    q: np.ndarray
    q_s: np.ndarray
    q_ss: np.ndarray
    w: np.ndarray
    w_s: np.ndarray
    w_ss: np.ndarray


@dataclass(frozen=True)
class Coefficients:
    """The parameterized dynamics u = a s'' + b s'^2 + c (+ lambda n, the squeeze), each (N, 4), at s (N,)."""

    s: np.ndarray
    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    n: np.ndarray
    joints: JointPath


@dataclass(frozen=True)
class TwoArms:
    """The closed chain: two arms, the object they hold, and gravity (m/s^2 along -y; 0 for orbit)."""

    arms: tuple[Arm, Arm]
    held: Held = field(default_factory=Held)
    gravity: float = GRAVITY
    singular_margin: float = 1e-3           # |sin(elbow)| below this is a kinematic singularity

    @property
    def dof(self) -> int:
        return 4

    def _share(self) -> tuple[np.ndarray, np.ndarray]:
        """The grasp matrix' pseudo-inverse (4, 3) and the squeeze direction (4,) in grasp forces."""
        (x1, y1), (x2, y2) = self.held.grasps
        grasp = np.array([[1.0, 0, 1, 0], [0, 1, 0, 1], [-y1, x1, -y2, x2]])
        e = np.array([x2 - x1, y2 - y1]) / np.hypot(x2 - x1, y2 - y1)
        return np.linalg.pinv(grasp), np.concatenate([e, -e])

    def joint_path(self, path, s) -> JointPath:
        """Inverse kinematics along the path; refuses (PlanError "reach") a point out of reach or singular."""
        s = np.atleast_1d(np.asarray(s, dtype=float))
        pts = path(s)
        parts = []
        for arm, grasp in zip(self.arms, self.held.grasps):
            p = pts.w + np.asarray(grasp)
            q = arm.inverse(p)
            bad = np.isnan(q).any(axis=1)
            if bad.any():
                raise PlanError("reach", f"the path leaves arm {len(parts) + 1}'s reach at s = {s[bad][0]:.4g} "
                                         f"(hand at {p[bad][0].round(4).tolist()} m)")
            near = np.abs(np.sin(q[:, 1])) < self.singular_margin
            if near.any():
                raise PlanError("reach", f"arm {len(parts) + 1} is at a kinematic singularity (elbow straight or "
                                         f"folded) at s = {s[near][0]:.4g}")
            j = arm.jacobian(q)
            q_s = np.linalg.solve(j, pts.w_s[..., None])[..., 0]
            q_ss = np.linalg.solve(j, (pts.w_ss - arm.hand_bias(q, q_s))[..., None])[..., 0]
            parts.append((q, q_s, q_ss))
        return JointPath(s, *(np.concatenate([a, b], axis=1) for a, b in zip(*parts)), pts.w, pts.w_s, pts.w_ss)

    def inverse_dynamics(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, gravity=None) -> np.ndarray:
        """Joint torques (N, 4) of the closed chain moving as (q, qd, qdd), the load shared as above. The object's
        acceleration is arm 1's hand's (its orientation is fixed)."""
        gravity = self.gravity if gravity is None else gravity
        arm1 = self.arms[0]
        w_dd = np.einsum("nij,nj->ni", arm1.jacobian(q[:, :2]), qdd[:, :2]) + arm1.hand_bias(q[:, :2], qd[:, :2])
        grasp = self.grasp_forces(w_dd, gravity)
        u = []
        for k, arm in enumerate(self.arms):
            sl = slice(2 * k, 2 * k + 2)
            own = arm.torques(q[:, sl], qd[:, sl], qdd[:, sl], gravity)
            u.append(own + np.einsum("nji,nj->ni", arm.jacobian(q[:, sl]), grasp[:, sl]))
        return np.concatenate(u, axis=1)

    def grasp_forces(self, w_dd: np.ndarray, gravity=None) -> np.ndarray:
        """(N, 4): F1x F1y F2x F2y, the force each hand puts on the object accelerating at `w_dd` ((N, 2), m/s^2)
        against gravity: m (w'' + g), shared as above (no squeeze)."""
        gravity = self.gravity if gravity is None else gravity
        share, _ = self._share()
        force = self.held.mass * (w_dd + np.array([0.0, gravity]))
        return np.concatenate([force, np.zeros((len(w_dd), 1))], axis=1) @ share.T

    def squeeze_direction(self, q: np.ndarray) -> np.ndarray:
        """(N, 4): the joint torques per newton of squeeze (the free grasp force, positive pressing inwards)."""
        _, squeeze = self._share()
        return np.concatenate([np.einsum("nji,j->ni", arm.jacobian(q[:, 2 * k:2 * k + 2]), squeeze[2 * k:2 * k + 2])
                               for k, arm in enumerate(self.arms)], axis=1)

    def coefficients(self, path, s) -> Coefficients:
        jp = self.joint_path(path, s)
        zero = np.zeros_like(jp.q)
        a = self.inverse_dynamics(jp.q, zero, jp.q_s, gravity=0.0)
        b = self.inverse_dynamics(jp.q, jp.q_s, jp.q_ss, gravity=0.0)
        c = self.inverse_dynamics(jp.q, zero, zero)
        return Coefficients(jp.s, a, b, c, self.squeeze_direction(jp.q), jp)

    def hands(self, q: np.ndarray) -> np.ndarray:
        """(N, 2, 2): both hands' positions, for drawing and checking closure."""
        return np.stack([arm.forward(q[:, 2 * k:2 * k + 2]) for k, arm in enumerate(self.arms)], axis=1)


def two_arms(separation: float = 2.0, lengths: Sequence[float] = (1.0, 1.0), masses: Sequence[float] = (1.0, 1.0),
             elbows: tuple[int, int] = (-1, 1), links: str = "rod", held: Held = Held(),
             gravity: float = GRAVITY) -> TwoArms:
    """Arm 1 at the origin, arm 2 `separation` metres along x, both alike: the report's configuration (Fig. 8).
    Default elbows (-1, +1): both elbows above the line from shoulder to hand, the arms mirror images."""
    return TwoArms((Arm((0.0, 0.0), tuple(lengths), tuple(masses), elbows[0], links),
                    Arm((separation, 0.0), tuple(lengths), tuple(masses), elbows[1], links)), held, gravity)
