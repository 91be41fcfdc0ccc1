"""The object two hands carry: a planar rigid body held at two grasps, each a spring-damper to its hand.

The report (issue 39, docs/two_arms.md "The shared object") closes the two arms' chain through the forces on a
common object, F = M_l w'' + G_l, but says nothing of how the object is held (docs/second_arm_sources.md 1.2).
Here, in the arm's vertical plane (x horizontal, z up, as `hil_sim.arm`):

* **The body.** Three degrees of freedom, the centre's x and z and the angle from the x axis, with the object's
  mass, its moment of inertia about its centre and gravity along -z (0 in orbit). Nothing pins its angle: it
  keeps its orientation only as far as the two grasp forces hold it.
* **The grasps.** Each hand is a point. A grasp is a spring-damper between the hand and the object's grasp point
  (fixed in the object's frame), with a stiffness and a damping along x and along z. The grasp passes a force and
  no moment (the planner's pin, `host_tools/plan/model.py`), so with two grasps the object's weight, its
  acceleration and its turning are carried by four force components: three balance it, the fourth is the internal
  (squeeze) force along the line between the grasps.
* **Stiffness and damping, chosen.** The report gives neither. A 1 cm error at a grasp is 50 N (5000 N/m): the
  report's 1 cm positioning specification (`POSITIONING_SPEC_M`) against a force well within the grip's limit
  (friction 0.5 x the jaws' 118 N at hold duty 0.3: 59 N). The damping, 35 N s/m, gives the example's object
  (0.25 kg) a damping ratio of 0.70 on its two grasps: it settles within a few of its 31 ms periods and
  overshoots by under 5 %; its turning on the grasps is then overdamped (1.13).
* **Slip and drop.** A grasp holds while the force across it (its magnitude, spring and damper together) is
  within friction x its jaws' force. Past that limit it slips, Coulomb-like: the grasp point slides in the
  object's frame, along the force, until the spring sheds the excess, so the force stays at the limit; where the
  slip leaves it, the grasp holds again. Past twice the limit in one step, with the jaws open (their force below
  `open_jaw_n`), or once the grasp point has slid off the object, the grasp lets go (the example's grasps are at
  the object's very ends: pulled apart past the limit, it slides out of the jaws). With neither grasp holding the object is a free body: it falls in gravity, drifts
  in orbit.

**The step** (every 1 ms plant step, so pure Python floats). Positions advance with the last acceleration
(x1 = x + h v + h^2/2 a, velocity Verlet), the grasp forces are taken at the new pose against the hands where they
are now, and the velocities follow by the trapezoidal rule, the dampers' part of it implicit (a 3 x 3 solve):
M v1 = M v + h/2 (M a + Q(x1, v1)). The springs and gravity are then integrated as velocity Verlet (second order,
symplectic; stable while every mode's omega dt < 2), and the dampers unconditionally: no damping ratio narrows the
bound, as it would if they were explicit. The example's stiffest mode is the object turning on its grasps:
omega = sqrt(2 k r^2 / I) = 322 rad/s, a 19.5 ms period against dt = 1 ms (omega dt = 0.32, 6.2 times inside
the bound of 2; `ObjectParams.stiffest_period_s`). A slip or a drop found in a step is applied to that same step
(its force capped or removed, the velocities solved again).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from protocol.states import GraspState
from protocol.units import G_EARTH_M_S2


class GraspRefused(ValueError):
    """`HeldObject.grasp` would not take the object: the hands are not the grasps' distance apart."""


@dataclass(frozen=True)
class ObjectParams:
    """The object and its two grasps. Defaults: the report's example object (section 4: 0.25 kg, 0.25 m x 0.1 m),
    held at its two ends as the planner holds it (`host_tools.plan.model.Held`); the rest chosen here
    (docs/fidelity.md, "The shared object")."""

    mass_kg: float = 0.25
    size_m: tuple[float, float] = (0.25, 0.1)                     # along its x axis, along its z axis
    inertia_kg_m2: Optional[float] = None                         # about its centre; None: a uniform block
    grasps_m: tuple[tuple[float, float], tuple[float, float]] = ((-0.125, 0.0), (0.125, 0.0))   # object frame
    stiffness_n_m: tuple[float, float] = (5000.0, 5000.0)         # per grasp, along x and z: 1 cm is 50 N
    damping_n_s_m: tuple[float, float] = (35.0, 35.0)             # per grasp, along x and z: 0.70 of critical
    friction: float = 0.5                                         # ASSUMED: the report gives no grip friction
    gravity_m_s2: float = G_EARTH_M_S2                            # along -z; 0 in orbit
    open_jaw_n: float = 1.0                                       # a jaw force below this is open jaws
    grasp_tolerance_m: float = 0.005                              # `grasp`: hands' distance against the grasps'

    def __post_init__(self) -> None:
        def numbers(name, values, least, strict):
            for v in values:
                if not (isinstance(v, (int, float)) and math.isfinite(v) and (v > least if strict else v >= least)):
                    raise ValueError(f"ObjectParams.{name} must be finite and {'>' if strict else '>='} {least}, "
                                     f"got {getattr(self, name)!r}")
        numbers("mass_kg", (self.mass_kg,), 0.0, True)
        numbers("size_m", self.size_m, 0.0, True)
        if len(self.size_m) != 2 or len(self.stiffness_n_m) != 2 or len(self.damping_n_s_m) != 2:
            raise ValueError("ObjectParams: size_m, stiffness_n_m and damping_n_s_m are (x, z) pairs")
        if self.inertia_kg_m2 is None:
            w, t = self.size_m
            object.__setattr__(self, "inertia_kg_m2", self.mass_kg * (w * w + t * t) / 12.0)
        numbers("inertia_kg_m2", (self.inertia_kg_m2,), 0.0, True)
        numbers("stiffness_n_m", self.stiffness_n_m, 0.0, True)
        numbers("damping_n_s_m", self.damping_n_s_m, 0.0, False)
        numbers("friction", (self.friction,), 0.0, True)
        numbers("gravity_m_s2", (self.gravity_m_s2,), 0.0, False)
        numbers("open_jaw_n", (self.open_jaw_n,), 0.0, False)
        numbers("grasp_tolerance_m", (self.grasp_tolerance_m,), 0.0, True)
        if len(self.grasps_m) != 2 or any(len(g) != 2 for g in self.grasps_m):
            raise ValueError(f"ObjectParams.grasps_m: two (x, z) points, got {self.grasps_m!r}")
        for g in self.grasps_m:
            numbers("grasps_m", g, -math.inf, True)
            if abs(g[0]) > self.size_m[0] / 2 or abs(g[1]) > self.size_m[1] / 2:
                raise ValueError(f"ObjectParams.grasps_m: {g} lies outside the object ({self.size_m} m)")
        if self.grasp_span_m <= 0.0:
            raise ValueError(f"ObjectParams.grasps_m: the two grasps must be apart, got {self.grasps_m!r}")

    @property
    def grasp_span_m(self) -> float:
        """The distance between the two grasp points."""
        (x0, z0), (x1, z1) = self.grasps_m
        return math.hypot(x1 - x0, z1 - z0)

    def damping_ratio(self, axis: int) -> float:
        """The damping ratio of the object's translation along `axis` (0: x, 1: z) on its two grasps."""
        return self.damping_n_s_m[axis] / math.sqrt(2.0 * self.stiffness_n_m[axis] * self.mass_kg)

    def stiffest_period_s(self) -> float:
        """The period of the object's fastest undamped mode on its two grasps (at rest, angle 0). The step is
        stable while it exceeds pi dt (omega dt < 2)."""
        kx, kz = self.stiffness_n_m
        k = np.zeros((3, 3))
        for gx, gz in self.grasps_m:       # sum of G^T K G, G = [[1, 0, -gz], [0, 1, gx]]
            g = np.array([[1.0, 0.0, -gz], [0.0, 1.0, gx]])
            k += g.T @ np.diag([kx, kz]) @ g
        m = np.diag([self.mass_kg, self.mass_kg, self.inertia_kg_m2])
        omega = math.sqrt(max(np.linalg.eigvals(np.linalg.solve(m, k)).real))
        return 2.0 * math.pi / omega


@dataclass(frozen=True)
class GraspEvent:
    """A grasp changed state: which (0 or 1, the index into `hands`), to what, the force across it and its limit
    (N) then, the object's own time, and why."""

    t_s: float
    grasp: int
    state: GraspState
    force_n: float
    limit_n: float
    reason: str


@dataclass(slots=True)
class _Grasp:
    """One grasp's live state: where it holds the object (object frame, m) and how."""

    anchor_x: float
    anchor_z: float
    state: GraspState = GraspState.FREE
    holding: bool = False                   # HELD or SLIPPING: the spring acts
    # this step's spring: the grasp point's offset from the centre (world), spring + hand-damper force, the force
    rx: float = 0.0
    rz: float = 0.0
    sx: float = 0.0
    sz: float = 0.0
    fx: float = 0.0
    fz: float = 0.0
    fixed: bool = False                     # this step: slipping at the limit, its force (fx, fz) fixed


class HeldObject:
    """The object between two hands (module docstring). `grasp(hands)` takes it; `step(...)` advances it.

    After each step: `pose` (x, z, angle), `velocity`, `hand_forces` (the force each grasp puts on its hand: the
    reaction an arm's joints feel as J^T F), `squeeze_n` (the internal force along the line between the grasps,
    positive pushing them together: compression; 0 unless both grasps hold), `carried_n` (the force across each
    grasp), `limits_n` (friction x each jaw force), `states` (a `GraspState` per grasp), `last_event` and
    `event_count` (each change of a grasp's state is one event)."""

    __slots__ = ("params", "_x", "_z", "_th", "_vx", "_vz", "_w", "_acc", "_grasps", "_constants", "t_s",
                 "hand_forces", "squeeze_n", "carried_n", "limits_n", "last_event", "event_count")

    def __init__(self, params: ObjectParams = ObjectParams(), pose: tuple[float, float, float] = (0.0, 0.0, 0.0)):
        if len(pose) != 3 or not all(math.isfinite(v) for v in pose):
            raise ValueError(f"pose must be three finite numbers (x m, z m, angle rad), got {pose!r}")
        self.params = params
        self._x, self._z, self._th = (float(v) for v in pose)
        self._vx = self._vz = self._w = 0.0
        self._grasps = [_Grasp(*g) for g in params.grasps_m]
        # the settings the step reads, unpacked once
        self._constants = (params.mass_kg, params.inertia_kg_m2, *params.stiffness_n_m, *params.damping_n_s_m,
                           params.gravity_m_s2, params.friction)
        self._acc = (0.0, -params.gravity_m_s2, 0.0)
        self.t_s = 0.0
        self.hand_forces: tuple[tuple[float, float], tuple[float, float]] = ((0.0, 0.0), (0.0, 0.0))
        self.squeeze_n = 0.0
        self.carried_n = (0.0, 0.0)
        self.limits_n = (0.0, 0.0)
        self.last_event: Optional[GraspEvent] = None
        self.event_count = 0

    # -- readings --
    @property
    def pose(self) -> tuple[float, float, float]:
        return (self._x, self._z, self._th)

    @property
    def velocity(self) -> tuple[float, float, float]:
        return (self._vx, self._vz, self._w)

    @property
    def states(self) -> tuple[GraspState, GraspState]:
        return (self._grasps[0].state, self._grasps[1].state)

    @property
    def grasp_points_m(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """Where each grasp holds the object now, in the plane (moves with the object and with a slip)."""
        c, s = math.cos(self._th), math.sin(self._th)
        return tuple((self._x + c * g.anchor_x - s * g.anchor_z, self._z + s * g.anchor_x + c * g.anchor_z)
                     for g in self._grasps)

    # -- taking it --
    def grasp(self, hands) -> None:
        """Place the object at rest with its grasp points on the two hands (grasp 0 at hands[0]) and hold it with
        both; the grasp points go back to `params.grasps_m`. Refused (`GraspRefused`, nothing changed) unless the
        hands are the grasps' distance apart within `grasp_tolerance_m`; a mismatch within it is shared between
        the two springs."""
        (h0x, h0z), (h1x, h1z) = _pairs(hands, "hands")
        p = self.params
        apart, span = math.hypot(h1x - h0x, h1z - h0z), p.grasp_span_m
        if abs(apart - span) > p.grasp_tolerance_m:
            raise GraspRefused(f"the hands are {apart:.4f} m apart and the grasps {span:.4f} m: more than "
                               f"{p.grasp_tolerance_m} m off, the object cannot be placed between them")
        (a0x, a0z), (a1x, a1z) = p.grasps_m
        th = math.atan2(h1z - h0z, h1x - h0x) - math.atan2(a1z - a0z, a1x - a0x)
        th = math.atan2(math.sin(th), math.cos(th))
        c, s = math.cos(th), math.sin(th)
        self._th = th
        self._x = 0.5 * ((h0x - c * a0x + s * a0z) + (h1x - c * a1x + s * a1z))
        self._z = 0.5 * ((h0z - s * a0x - c * a0z) + (h1z - s * a1x - c * a1z))
        self._vx = self._vz = self._w = 0.0
        for i, g in enumerate(self._grasps):
            g.anchor_x, g.anchor_z = p.grasps_m[i]
            self._event(i, GraspState.HELD, 0.0, 0.0, f"grasp {i} takes the object: the hands {apart:.4f} m apart, "
                                                        f"the grasps {span:.4f} m")
        self._grasp_forces(((h0x, h0z), (h1x, h1z)), ((0.0, 0.0), (0.0, 0.0)), 0.0, (0.0,) * 6)
        self._readings(None)

    # -- the step --
    def step(self, dt_s: float, hands, hand_velocities, jaw_forces_n) -> None:
        """Advance `dt_s` seconds with the hands at `hands` ((x, z), (x, z), m) moving at `hand_velocities`
        (m/s), each jaw closed with `jaw_forces_n` (N). Bad input raises ValueError and changes nothing."""
        try:
            (h0x, h0z), (h1x, h1z) = hands
            (u0x, u0z), (u1x, u1z) = hand_velocities
            n0, n1 = jaw_forces_n
            total = dt_s + h0x + h0z + h1x + h1z + u0x + u0z + u1x + u1z + n0 + n1
        except (TypeError, ValueError):
            raise ValueError(f"step takes dt_s, hands and hand_velocities as two (x, z) pairs each and two jaw "
                             f"forces, got {dt_s!r}, {hands!r}, {hand_velocities!r}, {jaw_forces_n!r}") from None
        if not math.isfinite(total):
            for name, values in (("dt_s", (dt_s,)), ("hands", (h0x, h0z, h1x, h1z)),
                                 ("hand_velocities", (u0x, u0z, u1x, u1z)), ("jaw_forces_n", (n0, n1))):
                if not all(math.isfinite(v) for v in values):
                    raise ValueError(f"{name} must be finite, got {values!r}")
            raise ValueError("the inputs are finite but too large to add up: not a plausible plant step")
        if dt_s < 0.0 or n0 < 0.0 or n1 < 0.0:
            raise ValueError(f"dt_s and the jaw forces must be >= 0, got dt_s {dt_s!r}, jaws ({n0!r}, {n1!r})")
        if dt_s == 0.0:
            return
        h = dt_s
        ax, az, aw = self._acc
        start = (self._vx, self._vz, self._w, ax, az, aw)
        self._x += h * (self._vx + 0.5 * h * ax)
        self._z += h * (self._vz + 0.5 * h * az)
        self._th += h * (self._w + 0.5 * h * aw)
        self.t_s += h
        hands, velocities = ((h0x, h0z), (h1x, h1z)), ((u0x, u0z), (u1x, u1z))
        self._grasp_forces(hands, velocities, h, start)
        fric = self._constants[-1]
        limits = (fric * n0, fric * n1)
        if self._judge((n0, n1), limits):
            self._grasp_forces(hands, velocities, h, start, again=True)
        self._readings(limits)

    # -- inside the step --
    def _grasp_forces(self, hands, hand_velocities, h: float, start: tuple, again: bool = False) -> None:
        """Solve this step's velocities from the velocities and accelerations at its `start` (trapezoidal, the
        dampers implicit) with the holding grasps' springs at the pose now; set each grasp's force on the object
        (fx, fz) and the acceleration they and gravity give. `again`: the slipping grasps keep the capped force
        `_judge` gave them."""
        m, inertia, kx, kz, cx, cz, gravity, _ = self._constants
        c, s = math.cos(self._th), math.sin(self._th)
        hh = 0.5 * h
        vx, vz, w, ax, az, aw = start
        # M v1 + hh D v1 = M v + hh (M a + gravity + sum G^T (spring + damper of the hand's velocity))
        b1 = m * (vx + hh * ax)
        b2 = m * (vz + hh * (az - gravity))
        b3 = inertia * (w + hh * aw)
        d11 = d22 = d13 = d23 = d33 = 0.0
        for g, (hx, hz), (ux, uz) in zip(self._grasps, hands, hand_velocities):
            if not g.holding:
                continue
            if again and g.fixed:
                fx, fz = g.fx, g.fz
                rx, rz = g.rx, g.rz
            else:
                g.fixed = False
                rx = c * g.anchor_x - s * g.anchor_z
                rz = s * g.anchor_x + c * g.anchor_z
                g.rx, g.rz = rx, rz
                g.sx = kx * (hx - self._x - rx)
                g.sz = kz * (hz - self._z - rz)
                fx, fz = g.sx + cx * ux, g.sz + cz * uz
                d11 += cx
                d22 += cz
                d13 -= cx * rz
                d23 += cz * rx
                d33 += cx * rz * rz + cz * rx * rx
            b1 += hh * fx
            b2 += hh * fz
            b3 += hh * (rx * fz - rz * fx)
        a11, a22, a13, a23, a33 = m + hh * d11, m + hh * d22, hh * d13, hh * d23, inertia + hh * d33
        w = (b3 - a13 * b1 / a11 - a23 * b2 / a22) / (a33 - a13 * a13 / a11 - a23 * a23 / a22)
        vx = (b1 - a13 * w) / a11
        vz = (b2 - a23 * w) / a22
        self._vx, self._vz, self._w = vx, vz, w
        qx, qz, qw = 0.0, -m * gravity, 0.0
        for g, (ux, uz) in zip(self._grasps, hand_velocities):
            if not g.holding:
                g.fx = g.fz = 0.0
                continue
            if not (again and g.fixed):
                g.fx = g.sx + cx * (ux - vx + w * g.rz)
                g.fz = g.sz + cz * (uz - vz - w * g.rx)
            qx += g.fx
            qz += g.fz
            qw += g.rx * g.fz - g.rz * g.fx
        self._acc = (qx / m, qz / m, qw / inertia)

    def _judge(self, jaws, limits) -> bool:
        """Each holding grasp against its limit: holds, slips (its force capped at the limit along itself, its
        grasp point slid along it so that the spring sheds the excess), or lets go. True if any force changed."""
        p = self.params
        kx, kz = p.stiffness_n_m
        half_w, half_t = p.size_m[0] / 2, p.size_m[1] / 2
        changed = False
        for i, (g, jaw, limit) in enumerate(zip(self._grasps, jaws, limits)):
            if not g.holding:
                continue
            force = math.hypot(g.fx, g.fz)
            if jaw < p.open_jaw_n:
                changed = self._let_go(i, force, limit, f"grasp {i} lets go: its jaws are open ({jaw:.2f} N, "
                                                        f"below {p.open_jaw_n} N)")
            elif force > 2.0 * limit:
                changed = self._let_go(i, force, limit, f"grasp {i} lets go: {force:.1f} N across it at once, past "
                                                        f"twice its limit {limit:.1f} N (friction {p.friction} x "
                                                        f"jaws {jaw:.1f} N)")
            elif force > limit:
                # the grasp point slides towards the hand until the spring sheds the excess over the limit
                excess = 1.0 - limit / force
                g.rx += excess * g.fx / kx
                g.rz += excess * g.fz / kz
                g.fx, g.fz, g.fixed = g.fx - excess * g.fx, g.fz - excess * g.fz, True
                c, s = math.cos(self._th), math.sin(self._th)
                g.anchor_x, g.anchor_z = c * g.rx + s * g.rz, -s * g.rx + c * g.rz
                changed = True
                if abs(g.anchor_x) > half_w or abs(g.anchor_z) > half_t:
                    self._let_go(i, force, limit, f"grasp {i} lets go: it slid off the object (at "
                                                  f"({g.anchor_x:.4f}, {g.anchor_z:.4f}) m, the object "
                                                  f"{p.size_m[0]} x {p.size_m[1]} m)")
                elif g.state is GraspState.HELD:
                    self._event(i, GraspState.SLIPPING, force, limit,
                                f"grasp {i} slips: {force:.1f} N across it, past its limit {limit:.1f} N (friction "
                                f"{p.friction} x jaws {jaw:.1f} N); held at the limit")
            elif g.state is GraspState.SLIPPING:
                self._event(i, GraspState.HELD, force, limit,
                            f"grasp {i} holds again: {force:.1f} N across it, within its limit {limit:.1f} N")
        return changed

    def _let_go(self, i: int, force: float, limit: float, reason: str) -> bool:
        g = self._grasps[i]
        g.fixed = False
        self._event(i, GraspState.DROPPED, force, limit, reason)
        return True

    def _event(self, i: int, state: GraspState, force: float, limit: float, reason: str) -> None:
        g = self._grasps[i]
        g.state, g.holding = state, state in (GraspState.HELD, GraspState.SLIPPING)
        self.last_event = GraspEvent(self.t_s, i, state, force, limit, reason)
        self.event_count += 1

    def _readings(self, limits: Optional[tuple[float, float]]) -> None:
        g0, g1 = self._grasps
        self.hand_forces = ((-g0.fx, -g0.fz), (-g1.fx, -g1.fz))
        self.carried_n = (math.hypot(g0.fx, g0.fz), math.hypot(g1.fx, g1.fz))
        if limits is not None:
            self.limits_n = limits
        if g0.holding and g1.holding:
            ex, ez = g1.rx - g0.rx, g1.rz - g0.rz        # grasp 0 towards grasp 1
            span = math.hypot(ex, ez)         # 0 only if slips brought the two grasp points together
            self.squeeze_n = ((g0.fx - g1.fx) * ex + (g0.fz - g1.fz) * ez) / (2.0 * span) if span > 0.0 else 0.0
        else:
            self.squeeze_n = 0.0


def _pairs(values, name: str) -> tuple[tuple[float, float], tuple[float, float]]:
    """Two finite (x, z) pairs, or ValueError naming `name`."""
    try:
        (a, b), (c, d) = values
        ok = all(math.isfinite(v) for v in (a, b, c, d))
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ValueError(f"{name} must be two finite (x, z) pairs in metres, got {values!r}")
    return (float(a), float(b)), (float(c), float(d))


__all__ = ["GraspEvent", "GraspRefused", "HeldObject", "ObjectParams"]
