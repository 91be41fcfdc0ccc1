"""The firmware's description of the arm agrees with the plant it drives, and with the protocol."""
from __future__ import annotations

import math

import pytest

from firmware_py.arm_config import ASPOD_ARM, SUPPLY_NOMINAL_V, default_gains
from hil_sim.arm import static_torques_nm
from hil_sim.arm_params import ARM_PLANT_PARAMS, CHANNEL_PARAMS
from protocol.hal import HalCodec
from protocol.states import ARM_CHANNELS

PLANT = {c.drive.name: c for c in CHANNEL_PARAMS}


def test_the_dbc_lists_the_arm_channels_in_their_declared_order():
    """`ARM_CHANNELS` (protocol/states.py) is the one declaration; the DBC's per-channel signals follow it."""
    database = HalCodec().database
    for name, prefixes in (("MOTOR_CMD", ("duty", "enable", "brake")), ("MOTOR_FB", ("count", "current")),
                           ("DIGITAL_IN", ("home", "limit_lo", "limit_hi"))):
        signals = sorted(database.get_message_by_name(name).signals, key=lambda s: s.start)
        for prefix in prefixes:
            in_frame = tuple(s.name[len(prefix) + 1:] for s in signals
                             if s.name.startswith(prefix + "_") and s.name[len(prefix) + 1:] in ARM_CHANNELS)
            assert in_frame == ARM_CHANNELS, (name, prefix)
    assert tuple(c.drive.name for c in CHANNEL_PARAMS) == ARM_CHANNELS


@pytest.mark.parametrize("drive", ASPOD_ARM.drives, ids=lambda d: d.name)
def test_drive_constants_match_the_plant(drive):
    plant = PLANT[drive.name]
    d = plant.drive
    assert drive.ratio == pytest.approx(d.ratio)
    assert drive.kt_nm_a == pytest.approx(d.motor.kt_nm_a)
    assert drive.r_ohm == pytest.approx(d.motor.r_ohm)
    assert drive.efficiency == pytest.approx(d.efficiency, abs=2e-3)
    assert drive.inertia_kg_m2 == pytest.approx(d.inertia_kg_m2, rel=1e-3)
    assert drive.rad_per_count == pytest.approx(2 * math.pi / plant.counts_per_output_rev)
    # soft limits lie inside the limit switches
    assert plant.limit_lo_rad < math.radians(drive.soft_min_deg) < math.radians(drive.soft_max_deg) < plant.limit_hi_rad


@pytest.mark.parametrize("drive", ASPOD_ARM.drives, ids=lambda d: d.name)
def test_feed_forwards_are_the_plants_motor_equations(drive):
    """Turning at w takes duty kt N w / V against the back-EMF, the motor's own (no gear train's
    efficiency in it); holding torque tau at the joint takes tau R / (eta kt N V). (The back-EMF's once
    had the efficiency in it: 0.71 of the duty, and the velocity integrators carried the rest, which
    outlived every stop.)"""
    d = PLANT[drive.name].drive
    gains = default_gains(drive)
    v = SUPPLY_NOMINAL_V
    torque_per_duty_nm = d.efficiency * d.motor.kt_nm_a * d.ratio * v / d.motor.r_ohm
    assert gains["ff_torque_duty_nm"] == pytest.approx(1.0 / torque_per_duty_nm, rel=3e-3)
    back_emf_duty_s_rad = gains["ff_vel_duty_s_rad"] - drive.viscous_nm_s_rad * gains["ff_torque_duty_nm"]
    assert back_emf_duty_s_rad == pytest.approx(d.motor.kt_nm_a * d.ratio / v, rel=1e-6)


def test_gripper_constants_match_the_plant():
    g = ARM_PLANT_PARAMS.gripper
    assert ASPOD_ARM.gripper.lead_m_per_rad == pytest.approx(g.lead_m_per_rad)
    assert ASPOD_ARM.gripper.open_switch_m == pytest.approx(g.open_switch_m)
    assert ASPOD_ARM.gripper.ratio == pytest.approx(PLANT["gripper"].drive.ratio)


@pytest.mark.parametrize("pose", [(0.0, 0.0, 0.0), (0.5, -1.2, 0.3), (1.2, -2.0, -0.6), (-0.8, 1.0, 1.5)])
@pytest.mark.parametrize("payload_kg", [0.0, 0.3])
def test_gravity_model_matches_the_plant(pose, payload_kg):
    plant = static_torques_nm(*pose, ARM_PLANT_PARAMS.geometry, 9.80665, payload_kg)
    firmware = ASPOD_ARM.masses.holding_torques_nm(*pose, 9.80665, payload_kg)
    assert firmware == pytest.approx(plant, rel=1e-6, abs=1e-9)
