"""The arm's physical plant: loads on the six motor channels, gripper, encoders, switches.

Geometry (parameters in `hil_sim.arm_params`). The manipulator works in a vertical plane
that contains the mount's central shaft. In that plane, x is horizontal (away from the
shaft at J1 = 0), z is up, the origin is J1's axis. Link II (J1 to J2), link III (J2 to
J3) and the gripper (J3 to the tip) make a planar chain with absolute angles
a1 = q1, a2 = q1 + q2, a3 = q1 + q2 + q3. Link I stands vertical under J1 on the mobile
mount's arm, at the track radius from the shaft. J4 rolls the gripper about its own axis
and moves neither the tip nor the centre of gravity. The mount turns the whole plane
about the shaft.

Lumped mass model: links II and III are uniform rods; the elbow hardware sits at J2; the
wrist is split into a part fixed at the J3 axis and a part J3 turns (centre of gravity
on the gripper axis); a payload is a point at the tip. From it, each step:

* gravity: the static torque each joint must hold, tau_k = g * sum over the masses
  outboard of joint k of m_i * (x_i - x_k); none on J4 (cg on the roll axis), the
  gripper's travel, or the mount (level platform). Orbit mode sets g = 0.
* inertia: the diagonal of the arm's mass matrix, i.e. everything outboard of a joint
  about that joint with the other joints frozen. The off-diagonal (coupling) and the
  velocity terms are neglected: every joint sees its rotor through a 300:1 to 1600:1
  train (J1: 1.5e-5 kg m^2 * 1600^2 = 38 kg m^2 against at most 4 kg m^2 of arm), and
  the report keeps joints at or below 1/2 RPM. Not so for the example arm's 50:1 drives
  (`EXAMPLE_ARM_PLANT`): along the example's plan what this leaves out peaks at 20 N m at a
  shoulder and 18 N m at an elbow (docs/plant.md). The mount sees the whole arm (and its own
  mobile arm and guide wheels) about the shaft.
* an external force at the tip (`ArmPlant.set_hand_force`, the held object's): its torques
  J^T F on J1-J3, as gravity's on a mass there; none on J4, the gripper or the mount.

The gripper is the push/pull motor on a lead screw: opening = screw angle * lead. Hard
stops at closed and at the full stroke; an object of a given width puts a stop at that
opening, and the torque the stop absorbs gives the grip force.
"""
from __future__ import annotations

import math
from typing import Optional, Sequence

import numpy as np

from hil_sim.arm_params import (ARM_PLANT_PARAMS, GRAVITY_M_S2, GRIPPER, J1, J2, J3, J4,
                                MOUNT, ArmGeometry, ArmPlantParams, MountParams)
from hil_sim.arm_tick import ArmTick, GripperCut, LoadConstants, Sensors, gravity_and_inertia
from hil_sim.motor import TWO_PI, DcMotorBank
from kernels import compiled_by_default
from protocol.states import ARM_CHANNELS as _CHANNELS


# ---- the lumped mass model ------------------------------------------------------------------
class LoadModel:
    """Gravity torques and inertias of the lumped mass model, its constants resolved once.

    The formulas live once, in the plant's tick (`hil_sim.arm_tick.gravity_and_inertia`, run
    after every substep): this class works out, at construction, everything that does not
    depend on the pose (`tick_constants`, the tick's constants), and `loads` runs the tick's
    formulas for one pose, for the pure functions below, which build a model for one question.
    """

    def __init__(self, geometry: ArmGeometry, mount: MountParams = ARM_PLANT_PARAMS.mount, payload_kg: float = 0.0,
                 g_m_s2: float = 0.0) -> None:
        a, m, p, g = geometry, mount, payload_kg, g_m_s2
        self.geometry, self.mount, self.payload_kg, self.g_m_s2 = a, m, p, g
        self._l2, self._l3, self._cg, self._tip = a.link2_m, a.link3_m, a.wrist_turned_cg_m, a.tip_m
        # torques: t3 = g K3 c3, t2 = g K2 c2 + t3, t1 = g K1 c1 + t2
        beyond_j3 = a.wrist_fixed_kg + a.wrist_turned_kg + p
        beyond_j2 = a.elbow_hw_kg + a.link3_kg + beyond_j3
        self._k3 = a.wrist_turned_kg * a.wrist_turned_cg_m + p * a.tip_m
        self._k2 = a.link3_kg * a.link3_m / 2.0 + beyond_j3 * a.link3_m
        self._k1 = a.link2_kg * a.link2_m / 2.0 + beyond_j2 * a.link2_m
        # inertias: the rods about their centres, the turned part about its own cg, what J3 and J4 turn
        self._rod2 = a.link2_kg * a.link2_m ** 2 / 12.0
        self._rod3 = a.link3_kg * a.link3_m ** 2 / 12.0
        self._turned = a.wrist_turned_inertia_kg_m2
        self._i3 = self._turned + a.wrist_turned_kg * a.wrist_turned_cg_m ** 2 + p * a.tip_m ** 2
        self._i4 = a.roll_inertia_kg_m2 + p * a.payload_gyration_m ** 2
        self._masses = (a.link2_kg, a.elbow_hw_kg, a.link3_kg, a.wrist_fixed_kg, a.wrist_turned_kg, p)
        # the mount: the parts at the base radius, and the mobile arm and guide wheels
        r0, self._reach = m.base_radius_m, m.reach_sign
        self._r0 = r0
        self._link1_kg, self._shoulder_kg = a.link1_kg, a.shoulder_hw_kg
        self._at_base = 0.0 + a.link1_kg * r0 * r0 + a.shoulder_hw_kg * r0 * r0
        self._base = m.mobile_arm_kg * r0 * r0 / 3.0
        self._wheels = m.guide_wheels_kg * r0 * r0
        # The same constants, flat, for the fused tick (hil_sim.arm_tick.gravity_and_inertia).
        self.tick_constants = LoadConstants(self._l2, self._l3, self._cg, self._tip, g, self._k1, self._k2, self._k3,
                                            self._rod2, self._rod3, self._turned, self._i3, self._i4, *self._masses,
                                            r0, self._reach, self._at_base, self._base, self._wheels)

    def pose(self, q1: float, q2: float, q3: float):
        """Arm-plane points (x, z) from J1: elbow, wrist, turned-part cg, tip; and cos a1..a3."""
        c1, s1 = math.cos(q1), math.sin(q1)
        a2 = q1 + q2
        c2, s2 = math.cos(a2), math.sin(a2)
        c3, s3 = math.cos(a2 + q3), math.sin(a2 + q3)
        ex, ez = self._l2 * c1, self._l2 * s1
        wx, wz = ex + self._l3 * c2, ez + self._l3 * s2
        rx, rz = wx + self._cg * c3, wz + self._cg * s3
        tx, tz = wx + self._tip * c3, wz + self._tip * s3
        return (ex, ez), (wx, wz), (rx, rz), (tx, tz), (c1, c2, c3)

    def loads(self, q1: float, q2: float, q3: float,
              hand_force_n: tuple[float, float] = (0.0, 0.0)) -> tuple[list[float], list[float]]:
        """Gravity torques (and `hand_force_n`'s at the tip, x and z in the arm plane) and inertias per channel at
        joint angles q1..q3, as the plant's tick computes them (`hil_sim.arm_tick.gravity_and_inertia`, the
        model's one implementation): (load_nm, inertia)."""
        load, inertia = [0.0] * len(_CHANNELS), [0.0] * len(_CHANNELS)
        gravity_and_inertia(q1, q2, q3, (*self.tick_constants, -math.inf, math.inf, *hand_force_n), load, inertia)
        return load, inertia

    def _outer_radii(self, pose) -> tuple[float, ...]:
        """Distances from the shaft axis of the parts J1 carries, in the order of `_masses`."""
        (ex, _), (wx, _), (rx, _), (tx, _), _ = pose
        r0, k = self._r0, self._reach
        return (r0 + k * ex / 2.0, r0 + k * ex, r0 + k * (ex + wx) / 2.0, r0 + k * wx, r0 + k * rx, r0 + k * tx)

    def radial_masses(self, pose):
        """(mass kg, distance from the shaft axis m) of every lumped part of the manipulator."""
        r0 = self._r0
        return ((self._link1_kg, r0), (self._shoulder_kg, r0), *zip(self._masses, self._outer_radii(pose)))


def static_torques_nm(q1_rad: float, q2_rad: float, q3_rad: float, geometry: ArmGeometry,
                      g_m_s2: float, payload_kg: float = 0.0) -> tuple[float, float, float]:
    """Torque J1, J2, J3 must each supply to hold the pose still (positive = raising)."""
    load = LoadModel(geometry, payload_kg=payload_kg, g_m_s2=g_m_s2).loads(q1_rad, q2_rad, q3_rad)[0]
    return load[J1], load[J2], load[J3]


def joint_inertias_kg_m2(q1_rad: float, q2_rad: float, q3_rad: float, geometry: ArmGeometry,
                         payload_kg: float = 0.0) -> tuple[float, float, float, float]:
    """What J1, J2, J3, J4 each turn, about their own axis, the other joints frozen."""
    inertia = LoadModel(geometry, payload_kg=payload_kg).loads(q1_rad, q2_rad, q3_rad)[1]
    return inertia[J1], inertia[J2], inertia[J3], inertia[J4]


def mount_inertia_kg_m2(q1_rad: float, q2_rad: float, q3_rad: float, geometry: ArmGeometry,
                        mount: MountParams, payload_kg: float = 0.0) -> float:
    """The mobile arm, guide wheels and manipulator about the central shaft."""
    return LoadModel(geometry, mount, payload_kg).loads(q1_rad, q2_rad, q3_rad)[1][MOUNT]


def mount_static_moment_nm(q1_rad: float, q2_rad: float, q3_rad: float, geometry: ArmGeometry,
                           mount: MountParams, g_m_s2: float, payload_kg: float = 0.0) -> float:
    """Bending moment of the manipulator's weight about the shaft (Table 4's "mobile mount").

    It loads the shaft and the mobile arm, not the mount's drive (the platform is level).
    """
    model = LoadModel(geometry, mount, payload_kg)
    return g_m_s2 * sum(mass * r for mass, r in model.radial_masses(model.pose(q1_rad, q2_rad, q3_rad)))


def gripper_position_m(pos_rad: Sequence[float], geometry: ArmGeometry = ARM_PLANT_PARAMS.geometry,
                       mount: MountParams = ARM_PLANT_PARAMS.mount) -> np.ndarray:
    """Gripper tip [x, y, z] in metres from per-channel angles (indexed as `ARM_CHANNELS`).

    Frame: origin on the central shaft's axis at the foot of link I, z up, x toward the
    mount's zero. Uses J1, J2, J3 and the mount; J4 and the gripper do not move the tip.
    """
    q1, q2, q3 = float(pos_rad[J1]), float(pos_rad[J2]), float(pos_rad[J3])
    tx, tz = LoadModel(geometry, mount).pose(q1, q2, q3)[3]
    rho = mount.base_radius_m + mount.reach_sign * tx
    phi = float(pos_rad[MOUNT])
    return np.array([rho * math.cos(phi), rho * math.sin(phi), geometry.link1_m + tz])


def chain_points_m(q1: float, q2: float, q3: float, mount_rad: float,
                   geometry: ArmGeometry = ARM_PLANT_PARAMS.geometry,
                   mount: MountParams = ARM_PLANT_PARAMS.mount) -> dict[str, np.ndarray]:
    """World positions of J1's axis, the elbow (J2), the wrist (J3) and the tip, in `gripper_position_m`'s frame."""
    (ex, ez), (wx, wz), _, (tx, tz), _ = LoadModel(geometry, mount).pose(q1, q2, q3)
    c, s = math.cos(mount_rad), math.sin(mount_rad)
    out = {}
    for name, (px, pz) in (("j1", (0.0, 0.0)), ("elbow", (ex, ez)), ("wrist", (wx, wz)), ("tip", (tx, tz))):
        rho = mount.base_radius_m + mount.reach_sign * px
        out[name] = np.array([rho * c, rho * s, geometry.link1_m + pz])
    return out


# ---- the plant -------------------------------------------------------------------------------
class ArmPlant:
    """The six channels J1, J2, J3, J4, gripper, mount with their loads; no bus, no clock.

    `step(dt_s, duty, enable, brake, supply_v)` takes per-channel arrays (order `ARM_CHANNELS`)
    and integrates; read `i_a` (current sense), `encoder_counts`, the switch arrays and
    the gripper's `grip_force_n` afterwards. `set_hand_force` puts a force at the hand for the
    steps that follow (the held object's: `hil_sim.two_arms`).

    Every step is the plant's one tick (`tick`, a `hil_sim.arm_tick.ArmTick`: `arm_plant_tick`
    over flat rows of numbers, compiled by numba with `compiled`, None: as `ASPOD_COMPILED` says;
    MissingExtra without numba). The motor bank (`motors`) and the mass model (`LoadModel`)
    hold the state and the constants it steps; this class keeps the commands, the configuration
    and the readings.
    """

    def __init__(self, params: ArmPlantParams = ARM_PLANT_PARAMS, gravity: str = "earth",
                 payload_kg: float = 0.0, compiled: Optional[bool] = None) -> None:
        self.params = params
        ch = params.channels
        self.motors = DcMotorBank([c.drive for c in ch])
        self.motors.set_state(pos_rad=[c.start_pos_rad for c in ch])
        grip = params.gripper
        self._lead = grip.lead_m_per_rad
        self._closed_switch_rad = grip.closed_switch_m / grip.lead_m_per_rad
        self._open_switch_rad = grip.open_switch_m / grip.lead_m_per_rad
        self._gripper_stops_rad = self.motors.stops_rad(GRIPPER)
        self.object_width_m: Optional[float] = None
        self._load_nm = [0.0] * len(ch)
        self._inertia = [0.0] * len(ch)
        self.hand_force_n = (0.0, 0.0)
        self.payload_kg = 0.0
        self.g_m_s2 = GRAVITY_M_S2["earth"]
        self._loads = LoadModel(params.geometry, params.mount, self.payload_kg, self.g_m_s2)
        self.set_gravity(gravity)
        self.set_payload(payload_kg)
        sensors = Sensors([c.start_pos_rad for c in ch], [c.counts_per_output_rev / TWO_PI for c in ch],
                          [c.home_rad for c in ch], [c.limit_lo_rad for c in ch], [c.limit_hi_rad for c in ch])
        self.tick = ArmTick(self, sensors, compiled=compiled_by_default() if compiled is None else bool(compiled))

    # -- configuration --
    def set_gravity(self, mode: str) -> None:
        """'earth' (9.80665 m/s^2) or 'orbit' (0)."""
        if mode not in GRAVITY_M_S2:
            raise ValueError(f"unknown gravity mode {mode!r}; known: {', '.join(GRAVITY_M_S2)}")
        self.gravity = mode
        self.g_m_s2 = GRAVITY_M_S2[mode]
        self._update_loads()

    def set_payload(self, payload_kg: float) -> None:
        """Mass carried at the gripper tip (0 for none)."""
        if not (math.isfinite(payload_kg) and payload_kg >= 0):
            raise ValueError(f"payload_kg must be finite and >= 0, got {payload_kg}")
        self.payload_kg = float(payload_kg)
        self._update_loads()

    def set_object(self, width_m: Optional[float]) -> None:
        """Put an object of `width_m` between the jaws (None: take it away).

        The jaws must be open at least that wide. Closing then stops on it.
        """
        if width_m is None:
            self.object_width_m = None
            self.motors.set_stops(GRIPPER, *self._gripper_stops_rad)
            return
        if not (math.isfinite(width_m) and 0 < width_m <= self.params.gripper.stroke_m):
            raise ValueError(f"object width must be in (0, stroke], got {width_m}")
        if self.gripper_opening_m < width_m:
            raise ValueError(f"jaws open {self.gripper_opening_m:.4f} m, narrower than the object")
        self.object_width_m = float(width_m)
        self.motors.set_stops(GRIPPER, width_m / self._lead, self._gripper_stops_rad[1])

    def set_hand_force(self, fx_n: float, fz_n: float) -> None:
        """An external force at the hand [N], in the arm plane (x, z as the geometry's), from now on: the
        joints carry it as J^T F (`hil_sim.arm_tick.gravity_and_inertia`), held over every step until set again.
        0 (the default): none, and the plant is to the bit what it was without. The hand is the gripper's tip
        (`ArmGeometry.tip_m` along the gripper from J3). The force is taken in the arm plane whatever the
        mount's angle: a force in that plane puts no torque on the mount's vertical shaft, and whoever applies
        it (`hil_sim.two_arms`) keeps the mount at home, where that plane is the object's."""
        fx_n, fz_n = float(fx_n), float(fz_n)
        if not (math.isfinite(fx_n) and math.isfinite(fz_n)):
            raise ValueError(f"the hand force must be finite (N), got ({fx_n!r}, {fz_n!r})")
        self.hand_force_n = (fx_n, fz_n)
        self.tick.set_hand_force(fx_n, fz_n)
        self._update_loads()

    def set_joint_state(self, channel: int, pos_rad: float, vel_rad_s: float = 0.0) -> None:
        """Move one channel's output shaft by hand (tests, scenarios); its encoder counts the move."""
        pos = self.motors.pos_rad
        vel = self.motors.vel_rad_s
        pos[channel], vel[channel] = pos_rad, vel_rad_s
        self.motors.set_state(pos_rad=pos, vel_rad_s=vel)
        self._update_loads()

    # -- integration --
    def step(self, dt_s: float, duty, enable, brake, supply_v: float) -> None:
        """Advance `dt_s` seconds (split into substeps of at most `max_substep_s`): the plant's tick with these
        channels driven (`enable`) and braked (`brake`)."""
        if not (dt_s >= 0 and math.isfinite(dt_s)):
            raise ValueError(f"dt_s must be finite and >= 0, got {dt_s}")
        self.tick.step(dt_s, True, False, [*_as_list(duty), *_as_list(enable), *_as_list(brake)], supply_v)

    def load_lists(self) -> tuple[list[float], list[float]]:
        """The live rows of gravity torques and load inertias per channel (changed in place, never replaced)."""
        return self._load_nm, self._inertia

    def keep_loads_in(self, load_nm: np.ndarray, inertia: np.ndarray) -> None:
        """Keep the gravity torques and load inertias from now on in these float64 rows (a compiled tick's)."""
        load_nm[:], inertia[:] = self._load_nm, self._inertia
        self._load_nm, self._inertia = load_nm, inertia

    def gripper_cut(self) -> GripperCut:
        """Whether the gripper's end switches cut its motor, and where they trip (screw angle, rad)."""
        return GripperCut(self.params.gripper.switches_cut_power, self._closed_switch_rad, self._open_switch_rad)

    def load_model(self) -> LoadModel:
        """The mass model for the present payload and gravity (built again when either has changed)."""
        model = self._loads
        if model.payload_kg != self.payload_kg or model.g_m_s2 != self.g_m_s2:
            model = self._loads = LoadModel(self.params.geometry, self.params.mount, self.payload_kg, self.g_m_s2)
        return model

    def _update_loads(self) -> None:
        q = self.motors.positions()
        load, inertia = self.load_model().loads(q[0], q[1], q[2], self.hand_force_n)
        self._load_nm[:], self._inertia[:] = load, inertia

    # -- measured and true values --
    @property
    def pos_rad(self) -> np.ndarray:
        return self.motors.pos_rad

    @property
    def vel_rad_s(self) -> np.ndarray:
        return self.motors.vel_rad_s

    @property
    def i_a(self) -> np.ndarray:
        """Armature currents (signed): what a current-sense amplifier measures."""
        return self.motors.i_a

    @property
    def encoder_counts(self) -> np.ndarray:
        """Quadrature counts since power-on (x4 decoding, floor quantisation), int64: the true counts, as the tick
        counts them with no encoder fault (`ArmTick.true_counts`)."""
        return np.array(self.tick.true_counts(), dtype=np.int64)

    @property
    def home_switch(self) -> np.ndarray:
        return np.array(self.tick.switches()[0])

    @property
    def limit_lo_switch(self) -> np.ndarray:
        """Lower limit switches; the gripper's is its closed end switch."""
        return np.array(self.tick.switches()[1])

    @property
    def limit_hi_switch(self) -> np.ndarray:
        """Upper limit switches; the gripper's is its open end switch."""
        return np.array(self.tick.switches()[2])

    @property
    def gripper_opening_m(self) -> float:
        return float(self.motors.pos_rad[GRIPPER]) * self._lead

    @property
    def grip_force_n(self) -> float:
        """Force the jaws press on an object with; 0 without an object or not closed on it."""
        if self.object_width_m is None:
            return 0.0
        return max(0.0, -float(self.motors.stop_torque_nm[GRIPPER])) / self._lead

    def gripper_position_m(self) -> np.ndarray:
        return gripper_position_m(self.motors.pos_rad, self.params.geometry, self.params.mount)

    def static_torques_nm(self) -> tuple[float, float, float]:
        """Holding torques at J1, J2, J3 in the present pose and mode: gravity's and the hand force's."""
        return tuple([float(t) for t in self._load_nm[:3]])

    @property
    def load_inertia_kg_m2(self) -> np.ndarray:
        """The pose-dependent inertia each channel sees (its own drive's not included)."""
        return np.array(self._inertia)

    def kinetic_energy_j(self) -> float:
        m = self.motors
        return 0.5 * float(np.dot(m.inertia_kg_m2 + self._inertia, m.vel_rad_s ** 2))

    def supply_current_a(self) -> float:
        """Current the motor bridges draw from the supply at the last step (A, < 0 regenerates)."""
        return self.tick.bridges_a


def _as_list(values) -> list:
    return values.tolist() if isinstance(values, np.ndarray) else list(values)


__all__ = ["ArmPlant", "chain_points_m", "gripper_position_m", "joint_inertias_kg_m2", "mount_inertia_kg_m2",
           "mount_static_moment_nm", "static_torques_nm"]
