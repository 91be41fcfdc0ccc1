"""The arm plant's tick (hil_sim/arm_tick.py, the plant's one implementation of it) through its switches, stops
and faults, plain Python and compiled by numba; compiled, the same to the bit as plain.

Every test runs a plant stepping the plain tick, and (numba installed) one stepping the compiled
tick beside a plain one with the same seed, given the same commands. After every step, every
readout the plant's node sends and the arm's internal state must be equal: floats compared as
`float.hex`, the rest by `repr` (a bool is not an int, a numpy scalar is not a Python number),
never approximately; and what the plant hands out must be Python numbers.
"""
from __future__ import annotations

import importlib.util
import math
import struct
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil_sim.arm_params import EXAMPLE_ARM_PLANT, GRIPPER, J1, MOUNT
from hil_sim.arm_tick_compiled import compiled_arm_plant_tick
from hil_sim.commands import N_CHANNELS
from hil_sim.faults import CHANNEL_FAULTS, FAULTS_BY_NAME
from hil_sim.plant import Plant, PlantParams
from kernels import ENVIRONMENT_SWITCH
from kernels.extras import MissingExtra

N = N_CHANNELS
DT = 0.001
SEED = 3
ALL_ON = [True] * N
ALL_OFF = [False] * N
HAVE_NUMBA = importlib.util.find_spec("numba") is not None
# The twins' `compiled`: the plain tick alone, and the compiled tick beside a plain one.
COMPILED = [False, pytest.param(True, marks=pytest.mark.skipif(not HAVE_NUMBA, reason="numba is not installed "
                                                                "(the compiled arm plant is optional)"))]
both_ways = pytest.mark.parametrize("compiled", COMPILED)


def hexes(values) -> list[str]:
    return [float(v).hex() for v in values]


def snapshot(plant: Plant) -> dict:
    """Everything the plant's node reads, and the state behind it; floats as their bits (`bits`)."""
    arm = plant.arm
    motors = arm.motors
    stops = [motors.stops_rad(k) for k in range(N)]
    # What the plant and its arm hand out: Python floats (never numpy's).
    values = [*plant.currents_a, *plant.channel_duty, *motors.positions(), *motors.currents(), *arm.static_torques_nm(),
              *(x for pair in stops for x in pair), arm.supply_current_a(), arm.grip_force_n, plant.current_a,
              plant.supply_v, plant.temp_c, plant.supply_true_v, plant.temp_true_c]
    return {
        "readouts": repr((plant.encoder_counts, plant.switches(), plant.channel_driven, plant.channel_braked)),
        "kinds": set(map(type, values)),
        "values": bits(values),
        "state": bits([x for row in (*motors.state_lists(), *arm.load_lists()) for x in row]),
    }


def bits(values) -> bytes:
    """The floats' bits, all of them (as `float.hex` shows them, and a NaN's payload too), at one go."""
    return struct.pack(f"{len(values)}d", *values)


def readable(snap: dict) -> dict:
    """A snapshot with its floats as `float.hex`, for an assertion's message."""
    return {key: hexes(struct.unpack(f"{len(value) // 8}d", value)) if isinstance(value, bytes) else value
            for key, value in snap.items()}


class Twins:
    """A plant (`compiled`: its tick compiled) and, compiled, a plain one beside it, stepped alike and compared after
    every step."""

    def __init__(self, compiled: bool, **options) -> None:
        self.plant = Plant(PlantParams(), np.random.default_rng(SEED), compiled_arm_tick=compiled, **options)
        self.plain = Plant(PlantParams(), np.random.default_rng(SEED), compiled_arm_tick=False,
                           **options) if compiled else None
        self.steps = 0
        self.check()

    @property
    def both(self) -> tuple[Plant, ...]:
        return (self.plant,) if self.plain is None else (self.plant, self.plain)

    def check(self) -> None:
        snap = snapshot(self.plant)
        assert snap["kinds"] <= {float}, f"after {self.steps} steps: {snap['kinds']}"
        if self.plain is None:
            return
        plain = snapshot(self.plain)
        if snap != plain:
            assert readable(snap) == readable(plain), f"after {self.steps} steps"
            assert snap == plain, f"after {self.steps} steps: a NaN's payload differs"

    def step(self, dt_s: float, enabled: bool, brake_all: bool, duty=None, enable=None, brake=None, n: int = 1) -> None:
        for _ in range(n):
            for plant in self.both:   # each its own copies: nothing shared between the two
                if duty is None:
                    plant.step(dt_s, enabled, brake_all)
                else:
                    plant.step(dt_s, enabled, brake_all, list(duty), list(enable), list(brake))
            self.steps += 1
            self.check()

    def drive(self, duty: list, n: int, brake=ALL_OFF) -> None:
        """Every channel enabled at `duty`, outputs on, brakes as given, `n` steps of 1 ms."""
        self.step(DT, True, False, duty, ALL_ON, brake, n=n)

    def fault(self, name: str, channel, on: bool) -> None:
        for plant in self.both:
            (plant.inject if on else plant.clear)(name, channel)
        self.check()

    def hand_force(self, fx_n: float, fz_n: float) -> None:
        for plant in self.both:
            plant.arm.set_hand_force(fx_n, fz_n)
        self.check()

    def move_by_hand(self, channel: int, pos_rad: float) -> None:
        for plant in self.both:
            plant.arm.set_joint_state(channel, pos_rad)
        self.check()


def only(channel: int, value, rest=0.0) -> list:
    out = [rest] * N
    out[channel] = value
    return out


@both_ways
def test_the_plant_steps_its_arm_with_the_tick_compiled_as_asked(compiled):
    twins = Twins(compiled)
    assert twins.plant.compiled_arm_tick is compiled and twins.plant.arm.tick.compiled is compiled


# ---- any commands, faults and step lengths -------------------------------------------------------
DUTY = st.one_of(st.floats(-1.5, 1.5), st.sampled_from([0.0, -0.0, 1.0, -1.0, math.nan, math.inf, -math.inf]))
CHANNEL_BOOLS = st.lists(st.sampled_from([False, True, 0, 1]), min_size=N, max_size=N)   # as a decoder may give them
COMMAND = st.tuples(
    st.sampled_from([DT, DT, DT, 0.0, 0.0025, 0.0004]),    # 2.5 ms: three substeps; 0: no motion
    st.booleans(), st.booleans(),                           # outputs enabled, brake all
    st.one_of(st.none(), st.tuples(st.lists(DUTY, min_size=N, max_size=N), CHANNEL_BOOLS, CHANNEL_BOOLS)))
FAULT_CHANGE = st.tuples(st.sampled_from(sorted(FAULTS_BY_NAME)), st.integers(0, N - 1), st.booleans())
HAND_FORCE = st.one_of(st.just((0.0, 0.0)), st.tuples(st.floats(-200.0, 200.0), st.floats(-200.0, 200.0)))
SEGMENT = st.tuples(COMMAND, st.integers(1, 120), st.lists(FAULT_CHANGE, max_size=2), HAND_FORCE)


@both_ways
@settings(max_examples=30, deadline=None)
@given(gravity=st.sampled_from(["earth", "orbit"]), payload_kg=st.sampled_from([0.0, 0.3, 2.0]),
       segments=st.lists(SEGMENT, min_size=1, max_size=10))
def test_any_commands_faults_and_step_lengths(compiled, gravity, payload_kg,
                                                                         segments):
    """Duties of both signs, out of range and NaN; enable and brake per channel and global; the
    safe command (no per-channel one); faults injected and cleared and a force at the hand (none, or up to
    200 N along x and z) set before each segment."""
    twins = Twins(compiled, gravity=gravity, payload_kg=payload_kg)
    for (dt_s, enabled, brake_all, per_channel), steps, faults, hand_force in segments:
        for name, channel, on in faults:
            twins.fault(name, channel if FAULTS_BY_NAME[name].per_channel else None, on)
        twins.hand_force(*hand_force)
        duty, enable, brake = per_channel or (None, None, None)
        twins.step(dt_s, enabled, brake_all, duty, enable, brake, n=steps)


@both_ways
def test_step_lengths_split_into_substeps_alike(compiled):
    twins = Twins(compiled)
    duty = [0.9, -0.7, 0.5, -1.0, -0.6, 1.0]
    # 0.1 + 0.2 s: 300.00000000000006 steps of 1 ms, split into 300 (a step length's float noise is no substep)
    for dt_s in (DT, 0.0025, 0.0, 0.1, 0.0007, DT, 0.0, 0.1 + 0.2, DT):
        twins.step(dt_s, True, False, duty, ALL_ON, ALL_OFF, n=5)


# ---- the joints into their switches and stops ---------------------------------------------------
@both_ways
def test_from_power_on_every_channel_through_its_home_flag(compiled):
    twins = Twins(compiled)
    twins.drive([1.0] * N, n=1600)                       # the gripper's home is its open switch, 25 mm away
    assert all(twins.plant.switches()[0])


@both_ways
@pytest.mark.parametrize("gravity, payload_kg", [("earth", 0.0), ("earth", 2.0), ("orbit", 1.0)])
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_every_joint_through_its_limit_switch_into_its_hard_stop_and_stalled_there(compiled, gravity, payload_kg,
                                                                                     sign):
    twins = Twins(compiled, gravity=gravity, payload_kg=payload_kg)
    lead = twins.plant.arm.params.gripper.lead_m_per_rad
    for k, channel in enumerate(twins.plant.arm.params.channels):
        if k == GRIPPER:                     # its switches cut its motor: 1 mm short of the one ahead
            start = channel.limit_hi_rad - 0.001 / lead if sign > 0 else channel.limit_lo_rad + 0.001 / lead
        else:                                # 0.03 rad short of the limit switch ahead
            start = channel.limit_hi_rad - 0.03 if sign > 0 else channel.limit_lo_rad + 0.03
        twins.move_by_hand(k, start)
    twins.drive([sign] * N, n=700)
    motors = twins.plant.arm.motors
    for k, x in enumerate(motors.positions()):
        if k != GRIPPER:                     # the gripper stops at its switch, short of its stop
            assert x == motors.stops_rad(k)[1 if sign > 0 else 0]
    twins.drive([-0.005 * sign] * N, n=50)   # pulled back too weakly to break away: friction holds
    twins.drive([-0.5 * sign] * N, n=300)    # and back out, brakes released
    twins.drive([0.0] * N, n=100, brake=ALL_ON)


@both_ways
@pytest.mark.parametrize("switch", ["home_rad", "limit_lo_rad", "limit_hi_rad"])
def test_every_channel_exactly_on_a_switch_edge_and_driven_across_it(compiled, switch):
    """A switch closes at its edge (>= or <=): placed there exactly, then driven both ways."""
    twins = Twins(compiled, gravity="orbit")
    for k, channel in enumerate(twins.plant.arm.params.channels):
        twins.move_by_hand(k, getattr(channel, switch))
    twins.step(DT, True, False, [0.0] * N, ALL_ON, ALL_OFF)
    for duty in (0.3, -0.3):
        for k, channel in enumerate(twins.plant.arm.params.channels):
            twins.move_by_hand(k, getattr(channel, switch))
        twins.drive([duty] * N, n=30)


@both_ways
def test_the_gripper_closes_on_an_object_grips_it_and_opens_to_its_switch(compiled):
    twins = Twins(compiled)
    for plant in twins.both:
        plant.arm.set_object(0.02)
    close = only(GRIPPER, -1.0)
    twins.drive(close, n=600)                            # 25.4 mm to 20 mm at about 16 mm/s, then it grips
    assert twins.plant.arm.grip_force_n > 0.0
    twins.drive(only(GRIPPER, -0.3), n=200)              # hold at a lower duty
    twins.drive(only(GRIPPER, 1.0), n=2000)              # open to the open switch, which cuts the motor
    assert twins.plant.switches()[2][GRIPPER]
    for plant in twins.both:
        plant.arm.set_object(None)
    twins.drive(close, n=3300)                           # to the closed switch
    assert twins.plant.switches()[1][GRIPPER]
    # Not driven and braked: the gripper has no brake, so its armature is shorted (dynamic braking).
    twins.drive(only(GRIPPER, 1.0), n=100)
    twins.step(DT, True, False, only(GRIPPER, 1.0), only(GRIPPER, False, True), ALL_ON, n=50)


# ---- faults ---------------------------------------------------------------------------------------
@both_ways
@pytest.mark.parametrize("fault", CHANNEL_FAULTS)
def test_each_channel_fault_on_each_channel_alike(compiled, fault):
    twins = Twins(compiled, payload_kg=1.0)
    for k in range(N):
        duty = only(k, 0.8, rest=0.2)
        twins.drive(duty, n=60)
        twins.fault(fault, k, True)
        twins.drive(duty, n=60)
        twins.drive([-d for d in duty], n=60)
        twins.step(DT, True, False, duty, ALL_OFF, ALL_OFF, n=30)     # not driven, brakes released
        twins.fault(fault, k, False)
        twins.drive(duty, n=40)


@both_ways
@pytest.mark.parametrize("fault", ["supply_sag", "over_temperature"])
def test_the_plant_wide_faults_alike_under_full_load(compiled, fault):
    twins = Twins(compiled)
    twins.drive([1.0, -1.0, 1.0, -1.0, -1.0, 1.0], n=100)
    twins.fault(fault, None, True)
    twins.drive([1.0, -1.0, 1.0, -1.0, -1.0, 1.0], n=200)
    twins.fault(fault, None, False)
    twins.drive([1.0, -1.0, 1.0, -1.0, -1.0, 1.0], n=100)


@both_ways
def test_a_move_by_hand_or_an_encoder_fault_shows_at_once_without_a_step(compiled):
    """The tick samples counts and switches at its end: a move by hand or an encoder fault shows at once."""
    twins = Twins(compiled)
    twins.drive([0.5] * N, n=50)
    twins.move_by_hand(J1, 0.2)                          # across the home flag
    twins.fault("encoder_glitch", MOUNT, True)
    twins.fault("encoder_dropout", MOUNT, True)
    twins.move_by_hand(MOUNT, 0.3)                       # a dropped-out encoder does not count it
    twins.fault("encoder_glitch", MOUNT, False)
    twins.fault("encoder_dropout", MOUNT, False)
    twins.drive([0.5] * N, n=10)


# ---- configuration between steps ------------------------------------------------------------------
@both_ways
def test_payload_gravity_and_the_safe_command_changed_between_steps(compiled):
    twins = Twins(compiled)
    duty = [0.4, 0.4, -0.4, 0.4, -0.4, 0.4]
    twins.drive(duty, n=100)
    for change in (lambda arm: arm.set_payload(1.5), lambda arm: arm.set_gravity("orbit"),
                   lambda arm: arm.set_payload(0.0), lambda arm: arm.set_gravity("earth")):
        for plant in twins.both:
            change(plant.arm)
        twins.check()
        twins.drive(duty, n=100)
        twins.step(DT, True, False, n=50)               # the safe command: every channel off and braked
        twins.step(DT, False, False, duty, ALL_ON, ALL_OFF, n=50)   # outputs disabled


# ---- a force at the hand, on the example arm ------------------------------------------------------------
@both_ways
@pytest.mark.parametrize("gravity", ["earth", "orbit"])
def test_a_hand_force_changed_every_step_on_the_example_arm_alike(compiled, gravity):
    """The example arm (`EXAMPLE_ARM_PLANT`: its 50:1 drives, its hand on the J3 axis) driven with its brakes
    released, a force at the hand set anew every step as the held object sets it (`hil_sim.two_arms`), split
    into substeps too; then braked under it, then the force gone."""
    twins = Twins(compiled, gravity=gravity, arm_params=EXAMPLE_ARM_PLANT)
    duty = [0.2, -0.3, 0.1, 0.0, -0.3, 0.0]
    for k in range(400):
        twins.hand_force(30.0 * math.sin(k / 17.0), -2.0 + 20.0 * math.cos(k / 23.0))
        twins.step(DT if k % 50 else 0.0025, True, False, duty, ALL_ON, ALL_OFF)
    twins.drive([0.0] * N, n=100, brake=ALL_ON)
    twins.hand_force(0.0, 0.0)
    twins.drive(duty, n=100)


# ---- the switch: compiled by default with ASPOD_COMPILED=1, and not without numba ----------------------
@pytest.mark.skipif(not HAVE_NUMBA, reason="numba is not installed (the compiled arm plant is optional)")
def test_the_compiled_arm_tick_is_asked_for_by_the_environment(monkeypatch):
    monkeypatch.delenv(ENVIRONMENT_SWITCH, raising=False)
    assert not Plant(PlantParams(), np.random.default_rng(0)).compiled_arm_tick
    monkeypatch.setenv(ENVIRONMENT_SWITCH, "1")
    assert Plant(PlantParams(), np.random.default_rng(0)).compiled_arm_tick
    assert not Plant(PlantParams(), np.random.default_rng(0), compiled_arm_tick=False).compiled_arm_tick


def test_the_compiled_arm_tick_needs_numba(monkeypatch):
    monkeypatch.setitem(sys.modules, "numba", None)              # as if it were not installed
    compiled_arm_plant_tick.cache_clear()
    try:
        with pytest.raises(MissingExtra, match=r"the compiled arm plant .*: needs the compiled extra \(numba is not installed\): pip install 'aspod\[compiled\]'"):
            Plant(PlantParams(), np.random.default_rng(0), compiled_arm_tick=True)
        monkeypatch.setenv(ENVIRONMENT_SWITCH, "1")
        with pytest.raises(MissingExtra, match="needs the compiled extra"):
            Plant(PlantParams(), np.random.default_rng(0))         # asked for by the environment
        Plant(PlantParams(), np.random.default_rng(0), compiled_arm_tick=False)   # the plain tick needs nothing
    finally:
        compiled_arm_plant_tick.cache_clear()
