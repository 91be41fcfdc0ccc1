"""Inverse kinematics of the ASPOD arm and the pick-and-place demo scene, as plain data.

The frame and the forward kinematics are `hil_sim.arm.gripper_position_m`'s: origin on
the central shaft's axis at the foot of link I, z up, x toward the mount's zero. The
manipulator works in the vertical plane through the shaft at the mount angle phi; in that
plane J1's axis sits at the track radius r0 from the shaft and link1_m above the origin,
and links II, III and the gripper make a planar chain with absolute angles a1 = q1,
a2 = q1 + q2, a3 = q1 + q2 + q3 (positive = raising). A tip at arm-plane offset (tx, tz)
from J1 lands at radius r0 + reach_sign * tx from the shaft, height link1_m + tz.

`inverse` turns a tip position and a gripper pitch (a3, e.g. -pi/2 = pointing straight
down) into J1, J2, J3 and the mount: the mount faces the target's azimuth, the wrist
point (J3's axis) lies tip_m back along the pitch, and links II and III reach it as a
two-link arm, elbow above ('up') or below ('down') the line from J1 to the wrist.
J4 (roll) and the gripper do not move the tip and are not solved for.

`DEMO_SCENE` and `steps` describe the demo: pick a piece of debris off the work surface
at one mount angle and drop it in the storage bin at another. Another module sends the
moves; this one only says where to go and where the tip should end up.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

from hil_sim.arm import chain_points_m as arm_chain_points_m, gripper_position_m
from hil_sim.arm_params import (AL_6061_DENSITY_LB_IN3, ARM_PLANT_PARAMS, CHANNEL_PARAMS, ArmGeometry, ArmPlantParams,
                                MountParams)
from protocol.states import ARM_CHANNELS
from protocol.units import DEG, IN_TO_M, LB_TO_KG

ELBOWS = ("up", "down")
_LIMITS = {c.drive.name: (c.limit_lo_rad, c.limit_hi_rad) for c in CHANNEL_PARAMS}
# Law of cosines round-off: a wrist point this far (relative) beyond full stretch or full
# fold still counts as reachable (clamped), so targets exactly at the boundary solve.
_CLAMP_EPS = 1e-12
# A channel whose target differs from its present angle by less than this does not "move".
_MOVE_EPS_RAD = 1e-9


class Unreachable(ValueError):
    """The arm cannot put its tip there: out of reach, or only past a limit switch."""


@dataclass(frozen=True)
class JointPose:
    """Angles [rad] of the channels that place the tip: J1, J2, J3 and the mount."""

    q1: float
    q2: float
    q3: float
    mount: float

    def as_targets(self) -> dict[str, float]:
        """Channel name -> angle for J1, J2, J3 and the mount."""
        return {"j1": self.q1, "j2": self.q2, "j3": self.q3, "mount": self.mount}

    def positions(self, j4_rad: float = 0.0, gripper_rad: float = 0.0) -> list[float]:
        """All six channel angles in `ARM_CHANNELS` order (J4 and gripper as given)."""
        values = {**self.as_targets(), "j4": j4_rad, "gripper": gripper_rad}
        return [values[name] for name in ARM_CHANNELS]


def forward(pose: JointPose, geometry: ArmGeometry = ARM_PLANT_PARAMS.geometry,
            mount: MountParams = ARM_PLANT_PARAMS.mount) -> np.ndarray:
    """Gripper tip [x, y, z] in metres: `hil_sim.arm.gripper_position_m` of the pose."""
    return gripper_position_m(pose.positions(), geometry, mount)


def chain_points_m(pose: JointPose, geometry: ArmGeometry = ARM_PLANT_PARAMS.geometry,
                   mount: MountParams = ARM_PLANT_PARAMS.mount) -> dict[str, np.ndarray]:
    """World positions of J1's axis, the elbow (J2), the wrist (J3) and the tip.

    For clearance checks: the links are the straight segments between them (`hil_sim.arm.chain_points_m`).
    """
    return arm_chain_points_m(pose.q1, pose.q2, pose.q3, pose.mount, geometry, mount)


def _finite_xyz(value: Sequence[float], what: str) -> tuple[float, float, float]:
    try:
        xyz = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be three numbers [x, y, z] in metres, got {value!r}") from None
    if len(xyz) != 3 or not all(math.isfinite(v) for v in xyz):
        raise ValueError(f"{what} must be three finite numbers [x, y, z] in metres, got {value!r}")
    return xyz


def _fmt_angle(rad: float) -> str:
    return f"{rad:.4f} rad ({rad / DEG:.1f} deg)"


def check_limits(pose: JointPose, margin_rad: float = 0.0, what: str = "pose") -> None:
    """Raise `Unreachable` if a channel of `pose` is not strictly inside its limit switches.

    The switches are active at and beyond `limit_lo_rad`/`limit_hi_rad` (`CHANNEL_PARAMS`);
    `margin_rad` narrows the allowed range on both sides.
    """
    if not (math.isfinite(margin_rad) and margin_rad >= 0):
        raise ValueError(f"margin_rad must be finite and >= 0, got {margin_rad}")
    for name, angle in pose.as_targets().items():
        lo, hi = _LIMITS[name]
        if not (lo + margin_rad < angle < hi - margin_rad):
            extra = f" with a margin of {margin_rad / DEG:.1f} deg" if margin_rad else ""
            raise Unreachable(f"{what}: {name} would be at {_fmt_angle(angle)}, outside its limit switches "
                              f"({lo / DEG:.1f} .. {hi / DEG:.1f} deg){extra}")


def inverse(target_xyz_m: Sequence[float], pitch_rad: float,
            geometry: ArmGeometry = ARM_PLANT_PARAMS.geometry,
            mount: MountParams = ARM_PLANT_PARAMS.mount, elbow: str = "up",
            margin_rad: float = 0.0) -> JointPose:
    """The joint angles that put the tip at `target_xyz_m` with the gripper at `pitch_rad`.

    `pitch_rad` is the gripper's absolute angle a3 in the arm plane (0 = horizontal,
    pointing away from the shaft; -pi/2 = straight down). `elbow` picks the branch: 'up'
    puts the elbow above the line from J1 to the wrist (J2 <= 0), 'down' below (J2 >= 0).
    The mount angle is the target's azimuth about the shaft, in (-pi, pi]; the arm does not
    reach over the shaft from the far side. J3 is wrapped into [-pi, pi], J1 likewise.

    Raises `Unreachable` (a ValueError) when the target is on the shaft's axis, too far,
    too close, or the solution puts a channel at or past a limit switch (less `margin_rad`),
    and ValueError for malformed input.
    """
    x, y, z = _finite_xyz(target_xyz_m, "target_xyz_m")
    if not math.isfinite(pitch_rad):
        raise ValueError(f"pitch_rad must be finite, got {pitch_rad}")
    if elbow not in ELBOWS:
        raise ValueError(f"elbow must be one of {ELBOWS}, got {elbow!r}")
    l2, l3, tip = geometry.link2_m, geometry.link3_m, geometry.tip_m
    if not (l2 > 0 and l3 > 0):
        raise ValueError(f"geometry needs link2_m and link3_m > 0, got {l2} and {l3}")
    if mount.reach_sign == 0 or not math.isfinite(mount.reach_sign):
        raise ValueError(f"mount.reach_sign must be finite and nonzero, got {mount.reach_sign}")
    where = f"target ({x:.4f}, {y:.4f}, {z:.4f}) m"

    rho = math.hypot(x, y)
    if rho < 1e-9:
        raise Unreachable(f"{where} is on the central shaft's axis: no mount angle faces it")
    phi = math.atan2(y, x)
    # Tip in the arm plane, relative to J1; then the wrist point, tip_m back along the gripper.
    tx = (rho - mount.base_radius_m) / mount.reach_sign
    tz = z - geometry.link1_m
    wx, wz = tx - tip * math.cos(pitch_rad), tz - tip * math.sin(pitch_rad)
    r = math.hypot(wx, wz)
    cos_q2 = (r * r - l2 * l2 - l3 * l3) / (2.0 * l2 * l3)
    if cos_q2 > 1.0 + _CLAMP_EPS:
        raise Unreachable(f"{where} out of reach at pitch {_fmt_angle(pitch_rad)}: the wrist point is "
                          f"{r:.4f} m from J1, links II and III reach at most {l2 + l3:.4f} m")
    if cos_q2 < -1.0 - _CLAMP_EPS:
        raise Unreachable(f"{where} too close at pitch {_fmt_angle(pitch_rad)}: the wrist point is "
                          f"{r:.4f} m from J1, links II and III fold to no less than {abs(l2 - l3):.4f} m")
    cos_q2 = min(1.0, max(-1.0, cos_q2))
    sin_q2 = math.sqrt(1.0 - cos_q2 * cos_q2) * (-1.0 if elbow == "up" else 1.0)
    q2 = math.atan2(sin_q2, cos_q2)
    q1 = math.remainder(math.atan2(wz, wx) - math.atan2(l3 * sin_q2, l2 + l3 * cos_q2), 2.0 * math.pi)
    q3 = math.remainder(pitch_rad - q1 - q2, 2.0 * math.pi)
    pose = JointPose(q1=q1, q2=q2, q3=q3, mount=phi)
    check_limits(pose, margin_rad, f"{where}, pitch {_fmt_angle(pitch_rad)}, elbow {elbow}")
    return pose


# ---- the demo scene -----------------------------------------------------------------------------
# Where the numbers come from (report = shared/seed/000_54a4d1d9271955c2.txt):
# - Reach: J1 sits link I (12 in, Table 2) above the mount's arm at the track radius
#   (5 ft track, "TRACK and TRACK MOUNTS": r0 = 0.762 m); links II and III are 24 and 12 in
#   (Table 2) and the tip 8 in past J3 (ArmGeometry, ASSUMED), so the tip reaches 1.118 m
#   from J1. With the gripper pointing down the wrist is 0.20 m above the tip.
# - ASSUMED: the work surface is the z = 0 plane, level with the foot of link I (the report
#   gives no height of the platform around the track relative to the mobile arm).
# - Debris and bin both 1.30 m from the shaft (0.538 m out from J1): near enough that J2
#   stays 17 deg inside its -135 deg limit with the tip on the surface (closer in, the
#   elbow folds past it), far enough in that J1, which the report sizes with a safety
#   factor of only 1.4, holds the loaded arm at about 72 % of its rating (further out the
#   outstretched arm's weight takes over; stretched flat it needs 99 %).
# - The debris: a 3 x 1.5 x 1.5 in block of 6061 cut from a larger piece (the report's
#   concept: the solar cutter cuts debris into shapes the arms can handle), lying flat,
#   gripped across its 1.5 in width: 38 mm in a 2 in (50.8 mm) stroke (GripperParams,
#   ASSUMED), 6 mm clearance per jaw when open. Its mass from Table 1's density:
#   6.75 in^3 * 0.098 lb/in^3 = 0.66 lb = 0.300 kg. The report designed for a 1 oz load
#   (Appendix A); 0.3 kg at the tip adds 0.6 N m at J3 with the gripper horizontal
#   (J3 then at 37 % of its 4.1 N m rating, against the report's 4.7 safety factor
#   unloaded) and about 0 with it pointing down, as in every pose here.
# - Mount: debris at -45 deg, bin at +45 deg: the carry turns the mount 90 deg, the mount's
#   home (0) lies between them, all well inside the +-170 deg limit switches.
# - Storage bin ("stow unusable pieces in the storage bin", report): ASSUMED an open box
#   0.10 m (4 in) deep; the jaws release the block 3 cm above its rim.
# - Approach heights: 0.25 m above the debris and 0.12 m above the release point, both
#   putting the tip 0.269 m above the surface, so the carry is a pure mount turn with the
#   block's bottom 0.25 m above the surface and 0.15 m above the bin's rim.
# - Home/carry pose: J1 60, J2 -110, J3 -40 deg (gripper down) at mount 0: the arm folded
#   up, tip 0.40 m above the surface, every joint 25 deg or more inside its limits.
DEMO_RADIUS_M = 1.30
DEBRIS_LENGTH_M = 3.0 * IN_TO_M
DEBRIS_WIDTH_M = 1.5 * IN_TO_M
DEBRIS_HEIGHT_M = 1.5 * IN_TO_M
DEBRIS_MASS_KG = (3.0 * 1.5 * 1.5) * AL_6061_DENSITY_LB_IN3 * LB_TO_KG
BIN_RIM_Z_M = 0.10
DEBRIS_MOUNT_RAD = -45.0 * DEG
BIN_MOUNT_RAD = 45.0 * DEG


def _on_circle(radius_m: float, azimuth_rad: float, z_m: float) -> tuple[float, float, float]:
    return (radius_m * math.cos(azimuth_rad), radius_m * math.sin(azimuth_rad), z_m)


@dataclass(frozen=True)
class Scene:
    """A pick-and-place task. Positions are world [x, y, z] in metres (`hil_sim.arm` frame).

    `debris_xyz_m` is the centre of the piece (where the tip grips it), resting on the work
    surface at `surface_z_m`; `bin_xyz_m` is the centre of the bin's opening, at its rim.
    The tip releases the piece `release_clearance_m` above the rim (its bottom, that is),
    and approaches each place from `approach_height_m` / `bin_approach_height_m` above the
    grip / release point with the gripper at `pitch_rad`. `home` is the start, carry and
    end pose.
    """

    debris_xyz_m: tuple[float, float, float] = _on_circle(DEMO_RADIUS_M, DEBRIS_MOUNT_RAD, DEBRIS_HEIGHT_M / 2)
    debris_width_m: float = DEBRIS_WIDTH_M
    debris_height_m: float = DEBRIS_HEIGHT_M
    debris_mass_kg: float = DEBRIS_MASS_KG
    bin_xyz_m: tuple[float, float, float] = _on_circle(DEMO_RADIUS_M, BIN_MOUNT_RAD, BIN_RIM_Z_M)
    release_clearance_m: float = 0.03
    approach_height_m: float = 0.25
    bin_approach_height_m: float = 0.12
    surface_z_m: float = 0.0
    pitch_rad: float = -math.pi / 2
    home: JointPose = JointPose(60.0 * DEG, -110.0 * DEG, -40.0 * DEG, 0.0)

    def __post_init__(self) -> None:
        _finite_xyz(self.debris_xyz_m, "Scene.debris_xyz_m")
        _finite_xyz(self.bin_xyz_m, "Scene.bin_xyz_m")
        for name in ("debris_width_m", "debris_height_m", "debris_mass_kg", "approach_height_m",
                     "bin_approach_height_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"Scene.{name} must be finite and > 0, got {value}")
        for name in ("release_clearance_m", "surface_z_m", "pitch_rad"):
            value = getattr(self, name)
            if not math.isfinite(value) or (name == "release_clearance_m" and value < 0):
                raise ValueError(f"Scene.{name} must be finite{' and >= 0' if name.startswith('rel') else ''}, "
                                 f"got {value}")
        bottom = self.debris_xyz_m[2] - self.debris_height_m / 2
        if bottom < self.surface_z_m - 1e-9:
            raise ValueError(f"Scene: the debris' bottom ({bottom:.4f} m) is below the work surface "
                             f"({self.surface_z_m:.4f} m)")
        if self.bin_xyz_m[2] < self.surface_z_m:
            raise ValueError(f"Scene: the bin's rim ({self.bin_xyz_m[2]:.4f} m) is below the work surface")

    @property
    def release_xyz_m(self) -> tuple[float, float, float]:
        """Tip position where the jaws open over the bin."""
        x, y, z = self.bin_xyz_m
        return (x, y, z + self.release_clearance_m + self.debris_height_m / 2)

    @property
    def debris_approach_xyz_m(self) -> tuple[float, float, float]:
        x, y, z = self.debris_xyz_m
        return (x, y, z + self.approach_height_m)

    @property
    def bin_approach_xyz_m(self) -> tuple[float, float, float]:
        x, y, z = self.release_xyz_m
        return (x, y, z + self.bin_approach_height_m)


DEMO_SCENE = Scene()


@dataclass(frozen=True)
class Step:
    """One demo step.

    `targets`: channel name -> angle [rad] for the channels this step moves (empty for a
    gripper step; the first step, from wherever the arm is, lists J1-J3 and the mount). `action`: "open" or "close" for a gripper step, else None. `pose`: the
    full J1-J3/mount pose once the step is done, `tip_xyz_m` the tip position expected
    there (for the position-error check), `held_kg` the mass in the jaws once it is done.
    """

    name: str
    targets: dict[str, float]
    action: Optional[str]
    pose: JointPose
    tip_xyz_m: tuple[float, float, float]
    held_kg: float


def steps(scene: Scene = DEMO_SCENE, params: ArmPlantParams = ARM_PLANT_PARAMS) -> list[Step]:
    """The demo's ordered steps: home, open, approach, descend, close, lift, carry, lower,
    release, retreat, home.

    Raises `Unreachable` if a pose is out of reach or past a limit switch, ValueError if
    the debris does not fit between the open jaws.
    """
    grip = params.gripper
    if not scene.debris_width_m < grip.open_switch_m:
        raise ValueError(f"debris {scene.debris_width_m * 1000:.1f} mm wide does not fit the jaws, which "
                         f"open to {grip.open_switch_m * 1000:.1f} mm")
    geo, mnt = params.geometry, params.mount
    check_limits(scene.home, what="home pose")

    def solve(xyz):
        return inverse(xyz, scene.pitch_rad, geo, mnt, elbow="up")

    out: list[Step] = []
    pose: Optional[JointPose] = None
    held = 0.0

    def move(name: str, new: JointPose) -> None:
        nonlocal pose
        before = pose.as_targets() if pose is not None else {}
        targets = {ch: a for ch, a in new.as_targets().items()
                   if ch not in before or abs(a - before[ch]) > _MOVE_EPS_RAD}
        pose = new
        out.append(Step(name, targets, None, new, _tuple(forward(new, geo, mnt)), held))

    def gripper(name: str, action: str, now_held: float) -> None:
        nonlocal held
        held = now_held
        out.append(Step(name, {}, action, pose, out[-1].tip_xyz_m, held))

    above_debris = solve(scene.debris_approach_xyz_m)
    above_bin = solve(scene.bin_approach_xyz_m)
    move("home", scene.home)
    gripper("open gripper", "open", 0.0)
    move("approach debris", above_debris)
    move("descend", solve(scene.debris_xyz_m))
    gripper("close gripper", "close", scene.debris_mass_kg)
    move("lift", above_debris)
    move("carry to bin", above_bin)
    move("lower", solve(scene.release_xyz_m))
    gripper("release", "open", 0.0)
    move("retreat", above_bin)
    move("return home", scene.home)
    return out


def _tuple(xyz) -> tuple[float, float, float]:
    return (float(xyz[0]), float(xyz[1]), float(xyz[2]))


__all__ = ["DEMO_SCENE", "JointPose", "Scene", "Step", "Unreachable", "chain_points_m", "check_limits",
           "forward", "inverse", "steps"]
