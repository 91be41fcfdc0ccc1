"""The arm plant on the HAL bus: MOTOR_CMD in; PLANT_SYNC, MOTOR_FB, DIGITAL_IN, ANALOG_IN out; faults.

A `PlantNode` runs on a private python-can virtual channel in lock-step with a stand-in
controller task on a `SimClock` and the firmware's `Scheduler`. The stand-in speaks only
the bus: it encodes MOTOR_CMD and CTRL_OUTPUTS with `HalCodec` and decodes what the plant
sends. Nothing sleeps on wall time.
"""
from __future__ import annotations

import math
from typing import Optional

import can
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from timebase.scheduler import Scheduler
from hil_sim.arm_params import J1, J2, J4, MOUNT
from hil_sim.faults import CHANNEL_FAULTS, FAULT_NAMES, FAULT_TABLE, PLANT_FAULTS, describe
from hil_sim.hal_node import PlantNode
from protocol.hal import FrameLayout, HalFrame
from hil_sim.commands import ExpiringMotorCommands
from hil_sim.plant import Plant, PlantParams
from protocol.hal import HalCodec, HalDecodeError, HalEncodeError
from protocol.states import ARM_CHANNELS
from timebase import SimClock

CODEC = HalCodec()
CMD_ID = CODEC.frame_id("MOTOR_CMD")
N = len(ARM_CHANNELS)


class Rig:
    """A plant node and a stand-in controller, both at 1 ms, on one scheduler.

    Each millisecond the plant steps first (reading what the controller sent the tick
    before), then the controller reads the plant's frames and sends MOTOR_CMD (every
    tick, while `sending_cmd`) and CTRL_OUTPUTS (every 10th tick, while `sending_outputs`).
    `frames` records every frame the controller received: (now, name, values, bytes).
    `truth` records the plant's own state after every step: (tick, switches, true counts).
    """

    def __init__(self, open_bus, params: PlantParams = PlantParams(), seed: int = 1,
                 gravity: str = "earth") -> None:
        self.clock = SimClock()
        self.sched = Scheduler(self.clock, stopwatch=self.clock.now)
        self.plant = Plant(params, np.random.default_rng(seed), gravity=gravity)
        self.node = PlantNode(open_bus(), self.plant, codec=CODEC)
        self.bus = open_bus()
        self.duty = [0.0] * N
        self.enable = [False] * N
        self.brake = [True] * N
        self.outputs_enabled = False
        self.brake_all = True
        self.sending_cmd = True
        self.sending_outputs = True
        self.freeze_alive = False
        self.cmd_alive = 0
        self.out_alive = 0
        self.ctrl_ticks = 0
        self.last_cmd_s: Optional[float] = None
        self.frames: list[tuple[float, str, dict, bytes]] = []
        self.truth: list[tuple[int, tuple, list[int]]] = []
        self.sched.add("plant", self._plant_task)
        self.sched.add("controller", self._controller_task)

    def _plant_task(self, now: float) -> float:
        wake = self.node.step(now)
        self.truth.append((self.node.tick - 1, self.plant.switches(), self.plant.arm.encoder_counts.tolist()))
        return wake

    def _controller_task(self, now: float) -> float:
        while (msg := self.bus.recv(timeout=0)) is not None:
            name, values = CODEC.decode(msg)
            self.frames.append((now, name, values, bytes(msg.data)))
        if self.sending_cmd:
            self.bus.send(CODEC.encode(
                "MOTOR_CMD", alive=self.cmd_alive,
                **{f"duty_{ch}": d for ch, d in zip(ARM_CHANNELS, self.duty)},
                **{f"enable_{ch}": int(e) for ch, e in zip(ARM_CHANNELS, self.enable)},
                **{f"brake_{ch}": int(b) for ch, b in zip(ARM_CHANNELS, self.brake)}))
            if not self.freeze_alive:
                self.cmd_alive = (self.cmd_alive + 1) % 256
            self.last_cmd_s = now
        if self.sending_outputs and self.ctrl_ticks % 10 == 0:
            self.bus.send(CODEC.encode("CTRL_OUTPUTS", outputs_enabled=int(self.outputs_enabled),
                                       brake_all=int(self.brake_all), alive=self.out_alive))
            self.out_alive = (self.out_alive + 1) % 256
        self.ctrl_ticks += 1
        return now + 0.001

    # -- commands --
    def drive(self, channel: int, duty: float) -> None:
        """Enable outputs globally and drive one channel, brake released."""
        self.outputs_enabled, self.brake_all = True, False
        self.duty[channel], self.enable[channel], self.brake[channel] = duty, True, False

    def run_for(self, duration_s: float) -> None:
        self.sched.run_until(self.clock.now() + duration_s)

    # -- what the controller saw --
    def seen(self, name: str, since_s: float = -1.0) -> list[tuple[float, dict]]:
        return [(t, v) for t, n, v, _ in self.frames if n == name and t >= since_s]

    def fb(self, since_s: float = -1.0) -> list[dict]:
        return [v for _, v in self.seen("MOTOR_FB", since_s)]

    def counts(self, channel: int, since_s: float = -1.0) -> list[int]:
        return [v[f"count_{ARM_CHANNELS[channel]}"] for v in self.fb(since_s)]

    def currents(self, channel: int, since_s: float = -1.0) -> list[float]:
        return [v[f"current_{ARM_CHANNELS[channel]}"] for v in self.fb(since_s)]

    def last_count(self, channel: int) -> int:
        return self.fb()[-1][f"count_{ARM_CHANNELS[channel]}"]


def wrap32(count: int) -> int:
    return (count + 2**31) % 2**32 - 2**31


# --- commands in, feedback out -------------------------------------------------------------------

def test_positive_duty_turns_the_channel_and_its_counts_rise(virtual_can):
    rig = Rig(virtual_can())
    rig.run_for(0.05)
    still = {channel: rig.last_count(channel) for channel in (J1, J4)}
    rig.drive(J1, 0.5)       # the shoulder, raising against gravity
    rig.drive(J4, 0.5)       # the wrist roll, no gravity
    start = rig.clock.now()
    rig.run_for(0.3)
    for channel in (J1, J4):
        counts = rig.counts(channel, since_s=start)
        assert counts[-1] > still[channel] + 1000
        assert all(b >= a for a, b in zip(counts, counts[1:]))      # never backwards
        assert np.mean(rig.currents(channel, since_s=start + 0.1)) > 0.1
    # The other channels are braked (no fresh enable) and stay put.
    for channel in (J2, MOUNT):
        assert set(rig.counts(channel)) == {0}
        assert set(rig.currents(channel)) == {0.0}
    # MOTOR_FB every tick with its tick, PLANT_SYNC last in the tick (1 ms, not in lock-step); counts are the arm's.
    syncs = [v["tick"] for _, v in rig.seen("PLANT_SYNC")]
    fbs = rig.fb()
    assert syncs == [v["tick"] for v in fbs] == list(range(len(syncs)))
    assert len(syncs) == rig.node.tick == rig.node.sent_by_name["MOTOR_FB"]
    order = [n for _, n, v, _ in rig.frames if v.get("tick") == 20]
    assert order == ["MOTOR_FB", "DIGITAL_IN", "PLANT_SYNC"]
    assert {(v["lockstep"], v["period_us"]) for _, v in rig.seen("PLANT_SYNC")} == {(0, 1000)}
    last_tick, _, true_counts = rig.truth[-1]
    assert fbs[-1]["tick"] == last_tick
    assert [fbs[-1][f"count_{ch}"] for ch in ARM_CHANNELS] == [wrap32(c) for c in true_counts]
    assert rig.node.bad_frames == 0 and rig.node.bus_errors == 0


@pytest.mark.parametrize("glitch, duty", [(2**31 - 300, 0.5), (-2**31 + 300, -0.5)])
def test_counts_wrap_at_32_bits(virtual_can, glitch, duty):
    # A glitch of nearly 2**31 counts puts the count next to the wrap; the shaft then crosses it.
    rig = Rig(virtual_can(), PlantParams(encoder_glitch_counts=glitch))
    rig.plant.inject("encoder_glitch", "j4")
    rig.drive(J4, duty)
    rig.run_for(0.2)
    counts = rig.counts(J4)
    true_counts = [c[J4] for _, _, c in rig.truth[:len(counts)]]
    assert counts == [wrap32(c + glitch) for c in true_counts]
    steps = [b - a for a, b in zip(counts, counts[1:])]
    jumps = [s for s in steps if abs(s) > 2**31]
    assert len(jumps) == 1 and abs(jumps[0]) > 2**32 - 1000       # it wrapped, once
    # Differences modulo 2**32 (how a controller unwraps) give the true motion.
    unwrapped = [wrap32(s) for s in steps]
    assert sum(unwrapped) == true_counts[-1] - true_counts[0]
    assert all(math.copysign(1, duty) * s >= 0 for s in unwrapped)


def test_current_saturates_at_the_declared_range(virtual_can):
    rig = Rig(virtual_can())
    # Set before the first step, which integrates nothing (dt 0): the currents stand as set.
    rig.plant.arm.motors.set_state(i_a=[40.0, -40.0, 1.25, 0.0, 0.0, 0.0])
    rig.run_for(0.0)
    first = rig.fb()[0]
    assert (first["current_j1"], first["current_j2"], first["current_j3"]) == (32.767, -32.768, 1.25)


def test_motor_command_expires_to_braked_within_its_timeout(virtual_can):
    rig = Rig(virtual_can())
    rig.drive(J1, 0.5)
    rig.run_for(0.2)
    assert rig.plant.channel_driven[J1] and not rig.plant.channel_braked[J1]
    rig.sending_cmd = False                   # the controller stops, CTRL_OUTPUTS still flows
    rig.run_for(0.002)
    last_s = rig.last_cmd_s
    timeout_s = rig.plant.params.motor_cmd_timeout_s
    assert timeout_s == 0.02
    rig.sched.run_until(last_s + timeout_s - 0.002)
    assert rig.plant.channel_driven[J1]
    rig.sched.run_until(last_s + timeout_s + 0.003)    # one tick's latency + one tick
    assert not rig.plant.channel_driven[J1] and rig.plant.channel_braked[J1]
    assert rig.plant.motor_commands.expiries == 1
    assert rig.plant.outputs_enabled               # only the motor command expired
    rig.run_for(0.05)                              # the brake stops the joint (about 35 ms)
    held_from = rig.clock.now()
    rig.run_for(0.1)
    assert len(set(rig.counts(J1, since_s=held_from))) == 1
    assert set(rig.currents(J1, since_s=held_from)) == {0.0}
    # Expiry does not latch: fresh commands drive again.
    rig.sending_cmd = True
    before = rig.last_count(J1)
    rig.run_for(0.1)
    assert rig.plant.channel_driven[J1] and rig.last_count(J1) > before + 100


def test_a_repeated_motor_cmd_alive_is_not_a_refresh(virtual_can):
    rig = Rig(virtual_can())
    rig.drive(J4, 0.5)
    rig.freeze_alive = True
    rig.run_for(0.2)
    assert rig.plant.motor_commands.alive_repeats > 150
    # The first frame counts (its alive is new), the repeats do not: 20 ms of drive, then braked.
    assert rig.plant.motor_commands.expiries == 1 and not rig.plant.channel_driven[J4]
    assert len(set(rig.counts(J4, since_s=0.1))) == 1
    rig.freeze_alive = False
    rig.run_for(0.05)
    assert rig.plant.channel_driven[J4] and rig.last_count(J4) > 0


def test_no_motion_without_the_global_enable(virtual_can):
    rig = Rig(virtual_can())
    for channel in range(N):
        rig.duty[channel], rig.enable[channel], rig.brake[channel] = 0.8, True, False
    rig.outputs_enabled, rig.brake_all = False, False      # every channel asks, the global says no
    rig.run_for(0.2)
    assert rig.plant.channel_duty == pytest.approx([0.8] * N, abs=1e-4)
    assert rig.plant.channel_driven == [False] * N
    # Nothing drives; J1-J3 carry gravity with their brakes released, and must not be driven down
    # by a motor: no current anywhere.
    assert all(v[f"current_{ch}"] == 0.0 for v in rig.fb() for ch in ARM_CHANNELS)
    for channel in (J4, MOUNT):
        assert set(rig.counts(channel)) == {0}
    # With the global brake on as well, nothing moves at all.
    rig2 = Rig(virtual_can())
    for channel in range(N):
        rig2.duty[channel], rig2.enable[channel], rig2.brake[channel] = 0.8, True, False
    rig2.outputs_enabled, rig2.brake_all = False, True
    rig2.run_for(0.2)
    assert all(set(rig2.counts(channel)) == {0} for channel in range(N))
    assert rig2.plant.channel_braked == [True] * N
    # And without any CTRL_OUTPUTS (expired from the start): the same.
    rig3 = Rig(virtual_can())
    rig3.sending_outputs = False
    rig3.drive(J4, 0.8)
    rig3.run_for(0.2)
    assert set(rig3.counts(J4)) == {0} and not rig3.plant.channel_driven[J4]


def test_a_disabled_channel_does_not_move_while_another_drives(virtual_can):
    rig = Rig(virtual_can())
    rig.drive(J4, 0.5)
    rig.duty[MOUNT], rig.enable[MOUNT], rig.brake[MOUNT] = 0.8, False, False
    rig.run_for(0.2)
    assert rig.last_count(J4) > 1000
    assert set(rig.counts(MOUNT)) == {0}


def test_digital_in_on_a_switch_change_within_one_tick_and_every_10_ms(virtual_can):
    rig = Rig(virtual_can())
    rig.run_for(0.05)
    rig.drive(J4, 0.3)                          # J4 starts 0.1 rad below its home flag
    rig.run_for(0.3)
    digital = {v["tick"]: v for _, v in rig.seen("DIGITAL_IN")}
    ticks = sorted(digital)
    assert ticks[0] == 0
    assert max(b - a for a, b in zip(ticks, ticks[1:])) <= 10          # at least every 10 ms
    changes = [tick for (tick, sw, _), (_, prev, _) in zip(rig.truth[1:], rig.truth) if sw != prev]
    assert changes, "J4 should have crossed its home flag"
    for (tick, switches, _) in rig.truth[:-1]:
        if tick in changes:
            sent = digital[tick]                                          # sent in the same tick
            home, lo, hi = switches
            assert [sent[f"home_{ch}"] for ch in ARM_CHANNELS] == [int(s) for s in home]
            assert [sent[f"limit_lo_{ch}"] for ch in ARM_CHANNELS] == [int(s) for s in lo]
            assert [sent[f"limit_hi_{ch}"] for ch in ARM_CHANNELS] == [int(s) for s in hi]
    assert digital[changes[0]]["home_j4"] == 1                         # the home flag, reached
    # Periodic only when idle: 10 ms apart exactly.
    idle = [t for t in ticks if t < 50]
    assert idle == list(range(0, 50, 10))


def test_analog_in_every_10_ms(virtual_can):
    rig = Rig(virtual_can())
    rig.run_for(0.1)
    assert [rig.node.sent_by_name[n] for n in ("PLANT_SYNC", "MOTOR_FB", "ANALOG_IN")] == \
        [rig.node.tick, rig.node.tick, math.ceil(rig.node.tick / 10)]


# --- faults, as the controller sees them ------------------------------------------------------------

def test_encoder_dropout_freezes_the_count_while_the_shaft_moves(virtual_can):
    rig = Rig(virtual_can())
    rig.drive(J4, 0.5)
    rig.run_for(0.1)
    rig.plant.inject("encoder_dropout", "j4")
    frozen_at = rig.plant.encoder_counts[J4]
    start = rig.clock.now()
    rig.run_for(0.2)
    counts = rig.counts(J4, since_s=start + 0.002)
    assert set(counts) == {frozen_at}
    true_now = rig.plant.arm.encoder_counts[J4]
    assert true_now > frozen_at + 1000                                   # the shaft kept turning
    assert min(rig.currents(J4, since_s=start)) > 0.05                   # and the motor drawing current
    assert rig.plant.faults == {"encoder_dropout:j4"}
    # Cleared: counting resumes from the true position, a jump.
    rig.plant.clear("encoder_dropout", "j4")
    rig.run_for(0.003)
    assert rig.last_count(J4) == wrap32(int(rig.plant.arm.encoder_counts[J4]))
    assert rig.last_count(J4) > frozen_at + 1000


def test_encoder_glitch_jumps_once_then_counts_on(virtual_can):
    rig = Rig(virtual_can())
    rig.drive(J4, 0.5)
    rig.run_for(0.1)
    start = rig.clock.now()
    rig.plant.inject("encoder_glitch", "j4")
    rig.plant.inject("encoder_glitch", "j4")             # already active: no second jump
    rig.run_for(0.1)
    glitch = rig.plant.params.encoder_glitch_counts
    assert glitch == 20000
    counts = rig.counts(J4, since_s=start - 0.01)
    steps = [b - a for a, b in zip(counts, counts[1:])]
    big = [s for s in steps if abs(s) > 1000]
    assert len(big) == 1 and glitch < big[0] < glitch + 1000              # one jump of +20000 (plus motion)
    assert all(0 <= s < 1000 for s in steps if s not in big)              # and normal counting after
    assert rig.last_count(J4) == rig.plant.arm.encoder_counts[J4] + glitch
    rig.plant.clear("encoder_glitch:j4")
    rig.run_for(0.003)
    assert rig.last_count(J4) == rig.plant.arm.encoder_counts[J4]        # jumps back


def test_open_circuit_gives_no_current_and_the_joint_falls_with_its_brake_released(virtual_can):
    rig = Rig(virtual_can())
    rig.drive(J4, 0.5)
    rig.drive(J2, 0.3)
    rig.run_for(0.2)
    assert rig.currents(J4)[-1] > 0.05
    rig.plant.inject("open_circuit", "j4")
    rig.plant.inject("open_circuit", J2)
    start = rig.clock.now()
    rig.run_for(0.3)
    after = rig.fb(since_s=start + 0.002)
    assert {v["current_j4"] for v in after} == {0.0} and {v["current_j2"] for v in after} == {0.0}
    assert rig.plant.channel_driven[J2] is False and rig.plant.channel_braked[J2] is False
    j2 = rig.counts(J2, since_s=start + 0.002)
    assert j2[-1] < j2[0] - 1000                                          # gravity pulls the elbow down
    rig.plant.clear("open_circuit", J2)
    rig.plant.clear("open_circuit", J4)
    rig.run_for(0.1)
    assert rig.currents(J4)[-1] > 0.05 and rig.plant.channel_driven[J2]


def test_open_circuit_in_orbit_coasts(virtual_can):
    rig = Rig(virtual_can(), gravity="orbit")
    rig.drive(J4, 1.0)
    rig.run_for(0.2)
    rig.plant.inject("open_circuit", "j4")
    start = rig.clock.now()
    rig.run_for(0.004)
    coasting = rig.counts(J4, since_s=start)
    assert coasting[-1] > coasting[0]                                     # still turning, no drive
    assert set(rig.currents(J4, since_s=start + 0.002)) == {0.0}


def test_jam_holds_the_angle_with_a_high_current(virtual_can):
    rig = Rig(virtual_can())
    stops = rig.plant.arm.motors.stops_rad(J1)
    rig.drive(J1, 0.5)
    rig.run_for(0.2)
    free_current_a = rig.currents(J1)[-1]
    rig.plant.inject("jam", "j1")
    start = rig.clock.now()
    rig.run_for(0.2)
    counts = rig.counts(J1, since_s=start + 0.002)
    assert len(set(counts)) == 1
    stall_a = rig.plant.supply_true_v * 0.5 / rig.plant.arm.params.channels[J1].drive.motor.r_ohm
    assert rig.currents(J1)[-1] == pytest.approx(stall_a, rel=0.01)
    assert rig.currents(J1)[-1] > 1.3 * free_current_a
    rig.plant.clear("jam", "j1")
    assert rig.plant.arm.motors.stops_rad(J1) == stops                    # the original hard stops
    rig.run_for(0.1)
    assert rig.last_count(J1) > counts[-1] + 100


def test_stuck_brake_keeps_the_joint_still(virtual_can):
    rig = Rig(virtual_can())
    rig.plant.inject("stuck_brake", "j1")
    rig.drive(J1, 0.5)                                    # commands the brake released
    rig.run_for(0.3)
    assert rig.plant.channel_braked[J1] and rig.plant.channel_driven[J1]
    assert set(rig.counts(J1)) == {0}
    assert rig.currents(J1)[-1] > 2.0                     # stalled against the brake
    rig.plant.clear("stuck_brake", "j1")
    rig.run_for(0.1)
    assert rig.last_count(J1) > 100


def test_bad_fault_names_and_channels_raise_and_change_nothing():
    plant = Plant(PlantParams(), np.random.default_rng(0))
    plant.inject("jam", "j2")
    stops = [plant.arm.motors.stops_rad(k) for k in range(N)]
    cases = [
        (("meteor",), "known faults: supply_sag, over_temperature, encoder_dropout"),
        (("jam",), "needs a channel: one of j1, j2, j3, j4, gripper, mount"),
        (("jam", "j7"), "unknown channel 'j7'; channels: j1, j2, j3, j4, gripper, mount"),
        (("jam", 6), "index 0-5"),
        (("jam", -1), "unknown channel"),
        (("jam", True), "unknown channel"),
        (("jam", 1.0), "unknown channel"),
        (("supply_sag", "j1"), "takes no channel"),
        (("jam:j2", "j2"), "already names its channel"),
        (("jam:elbow",), "unknown channel 'elbow'"),
        ((None,), "unknown fault"),
    ]
    for args, message in cases:
        for action in (plant.inject, plant.clear):
            with pytest.raises(ValueError, match=message):
                action(*args)
            assert plant.faults == {"jam:j2"}
            assert [plant.arm.motors.stops_rad(k) for k in range(N)] == stops


def test_faults_are_listed_by_name_and_channel():
    plant = Plant(PlantParams(), np.random.default_rng(0))
    plant.inject("jam", "j2")
    plant.inject("jam", 1)                    # the same channel by index: no change
    plant.inject("stuck_brake", np.int64(5))
    plant.inject("supply_sag")
    assert plant.faults == {"jam:j2", "stuck_brake:mount", "supply_sag"}
    for fault in sorted(plant.faults):
        plant.clear(fault)
    assert plant.faults == frozenset()
    plant.clear("jam", "j2")                  # not active: nothing to do
    # Every fault in the table can be injected and cleared on every channel it applies to.
    for spec in FAULT_TABLE:
        for channel in (range(N) if spec.per_channel else [None]):
            plant.inject(spec.name, channel)
    assert len(plant.faults) == len(PLANT_FAULTS) + N * len(CHANNEL_FAULTS)
    for fault in list(plant.faults):
        plant.clear(fault)
    assert plant.faults == frozenset()
    assert [plant.arm.motors.stops_rad(k) for k in range(N)] == \
        [(d.drive.stop_lo_rad, d.drive.stop_hi_rad) for d in plant.arm.params.channels]
    assert FAULT_NAMES[:2] == ("supply_sag", "over_temperature")
    text = describe()
    assert all(f.name in text and f.effect in text and f.controller_sees in text for f in FAULT_TABLE)


# --- supply and box ---------------------------------------------------------------------------------

def test_supply_sags_under_motor_load(virtual_can):
    rig = Rig(virtual_can())
    p = rig.plant.params
    rig.outputs_enabled, rig.brake_all = True, False
    rig.run_for(0.3)
    idle = [v["supply_v"] for t, v in rig.seen("ANALOG_IN", since_s=0.1)]
    idle_v = float(np.mean(idle))
    assert idle_v == pytest.approx(p.supply_nominal_v - (p.idle_current_a + p.enabled_current_a)
                                   * p.supply_source_ohm, abs=0.01)
    # Two stalled motors at full duty: J1 (6 ohm) and the mount (4 ohm) jammed.
    rig.plant.inject("jam", "j1")
    rig.plant.inject("jam", "mount")
    rig.drive(J1, 1.0)
    rig.drive(MOUNT, 1.0)
    rig.run_for(0.3)
    start = rig.clock.now()
    rig.run_for(0.3)
    loaded_v = float(np.mean([v["supply_v"] for t, v in rig.seen("ANALOG_IN", since_s=start)]))
    fb = rig.fb(since_s=start)[-1]
    motor_a = fb["current_j1"] + fb["current_mount"]                     # duty 1: bridge current = motor current
    assert motor_a > 9.0
    assert loaded_v == pytest.approx(
        p.supply_nominal_v - (p.idle_current_a + p.enabled_current_a + motor_a) * p.supply_source_ohm, abs=0.02)
    assert idle_v - loaded_v > 2.0
    # Stall current follows the sagged bus, not the nominal one.
    r_j1 = rig.plant.arm.params.channels[J1].drive.motor.r_ohm
    assert fb["current_j1"] == pytest.approx(loaded_v / r_j1, rel=0.01)


def test_drive_losses_heat_the_box_motor_losses_do_not():
    params = PlantParams(thermal_capacity_j_per_c=1.0)            # time constant 0.5 s
    plant = Plant(params, np.random.default_rng(0))
    plant.inject("jam", "mount")
    duty, enable, brake = [0.0] * N, [False] * N, [False] * N
    duty[MOUNT], enable[MOUNT] = 1.0, True
    for _ in range(5000):
        plant.step(0.001, True, False, duty, enable, brake)
    i = plant.currents_a[MOUNT]
    electronics_a = params.idle_current_a + params.enabled_current_a
    heat_w = plant.supply_true_v * electronics_a + params.drive_on_resistance_ohm * i * i
    assert i > 6.0
    assert plant.temp_true_c == pytest.approx(params.ambient_c + heat_w * params.thermal_resistance_c_per_w,
                                              abs=0.01)
    # Far below what the motor itself dissipates (i^2 * 4 ohm, about 190 W): that stays in the arm.
    assert heat_w < 0.2 * i * i * 4.0


# --- determinism ------------------------------------------------------------------------------------

def test_same_seed_same_commands_same_motor_fb_bytes(virtual_can):
    def run(seed: int) -> tuple[list[bytes], list[bytes]]:
        rig = Rig(virtual_can(), seed=seed)
        rig.drive(J1, 0.6)
        rig.drive(J4, -0.4)
        rig.drive(MOUNT, 0.3)
        rig.run_for(0.15)
        rig.plant.inject("encoder_glitch", "mount")
        rig.plant.inject("supply_sag")
        rig.run_for(0.1)
        rig.duty[J1] = -0.2
        rig.run_for(0.1)
        fb = [b for _, n, _, b in rig.frames if n == "MOTOR_FB"]
        analog = [b for _, n, _, b in rig.frames if n == "ANALOG_IN"]
        return fb, analog

    fb, analog = run(seed=7)
    assert len(fb) >= 349 and len(set(fb)) > 300        # one per tick, and they change
    assert run(seed=7) == (fb, analog)
    other_fb, other_analog = run(seed=8)
    assert other_analog != analog                       # the seed drives the measurement noise


# --- the node's hand-packed frames match the codec --------------------------------------------------

def _layouts() -> dict[str, FrameLayout]:
    return {m.name: FrameLayout(CODEC, m.name, tuple(s.name for s in m.signals)) for m in CODEC.database.messages}


LAYOUTS = _layouts()


@settings(max_examples=300, deadline=None)
@given(data=st.data())
def test_frame_layout_packs_what_the_codec_encodes(data):
    name = data.draw(st.sampled_from(sorted(LAYOUTS)))
    message = CODEC.database.get_message_by_name(name)
    values = {}
    for s in message.signals:
        raw = data.draw(st.integers(round(s.minimum / s.scale), round(s.maximum / s.scale)))
        values[s.name] = raw if s.scale == 1 else raw * s.scale
    layout = LAYOUTS[name]
    packed = layout.pack([values[n] for n in layout.order])
    assert packed == bytes(CODEC.encode(name, **values).data)
    assert layout.unpack(packed) == [CODEC.decode(CODEC.encode(name, **values))[1][n] for n in layout.order]


@settings(max_examples=300, deadline=None)
@given(name=st.sampled_from(sorted(LAYOUTS)), data=st.data())
def test_frame_layout_unpacks_any_bytes_as_the_codec_decodes(name, data):
    layout = LAYOUTS[name]
    length = data.draw(st.sampled_from([layout.length, layout.length, layout.length - 1, 3]))
    payload = data.draw(st.binary(min_size=length, max_size=length))
    msg = can.Message(arbitration_id=layout.frame_id, data=payload, is_extended_id=False, is_fd=layout.is_fd)
    try:
        expected = CODEC.decode(msg)[1]
    except HalDecodeError:
        with pytest.raises(HalDecodeError):
            layout.unpack(payload)
    else:
        assert layout.unpack(payload) == [expected[n] for n in layout.order]


def test_frame_layout_refuses_values_outside_the_declared_range():
    fb = LAYOUTS["MOTOR_FB"]
    good = [0] * len(fb.order)
    fb.pack(good)
    for signal, bad in (("current_j1", 32.8), ("count_j3", 2**31), ("tick", -1), ("current_j2", math.nan)):
        values = list(good)
        values[fb.order.index(signal)] = bad
        with pytest.raises(HalEncodeError, match=signal):
            fb.pack(values)
    with pytest.raises(HalEncodeError, match="12 values for 13 signals"):
        fb.pack(good[:-1])
    with pytest.raises(ValueError, match="does not list the declared signals"):
        FrameLayout(CODEC, "MOTOR_FB", ("tick",))


def test_frame_layout_refuses_bits_and_duties_outside_their_range():
    layout = LAYOUTS["MOTOR_CMD"]
    good = [0] * len(layout.order)
    assert layout.pack(good) == bytes(16)
    for signal, bad in (("enable_j2", 2), ("brake_mount", -1), ("duty_j1", 1.5), ("alive", 256)):
        values = list(good)
        values[layout.order.index(signal)] = bad
        with pytest.raises(HalEncodeError, match=signal):
            layout.pack(values)


@settings(max_examples=100, deadline=None)
@given(name=st.sampled_from(sorted(LAYOUTS)), data=st.data())
def test_a_layout_in_any_order_takes_its_fast_paths_and_gives_the_same_bytes(name, data):
    declared = LAYOUTS[name]
    order = data.draw(st.permutations(declared.order))
    layout = FrameLayout(CODEC, name, order)
    message = CODEC.database.get_message_by_name(name)
    values = {}
    for s in message.signals:
        raw = data.draw(st.integers(round(s.minimum / s.scale), round(s.maximum / s.scale)))
        values[s.name] = raw if s.scale == 1 else raw * s.scale
    packed = layout._fast_pack([values[n] for n in order])          # in range: never declined
    assert packed == declared.pack([values[n] for n in declared.order])
    assert layout._fast_unpack(packed) == [dict(zip(declared.order, declared.unpack(packed)))[n] for n in order]
    assert "for " not in layout.pack_source + layout.unpack_source  # straight-line code


def test_a_hal_frame_built_quickly_is_the_message_the_constructor_builds():
    fast = HalFrame.data_frame(0x200, b"\x01\x02\x03", True)
    slow = can.Message(arbitration_id=0x200, data=b"\x01\x02\x03", is_extended_id=False, is_fd=True)
    assert isinstance(fast, can.Message)
    assert {n: getattr(fast, n) for n in can.Message.__slots__ if n != "__weakref__"} == \
        {n: getattr(slow, n) for n in can.Message.__slots__ if n != "__weakref__"}


def test_bad_motor_cmd_frames_are_counted_and_not_applied(virtual_can):
    rig = Rig(virtual_can())
    intruder = rig.bus
    rig.sending_cmd = False
    rig.outputs_enabled, rig.brake_all = True, False
    rig.run_for(0.02)
    layout = LAYOUTS["MOTOR_CMD"]
    values = dict.fromkeys(layout.order, 0)
    values.update(duty_j4=0.5, enable_j4=1, alive=1)
    good = bytearray(layout.pack([values[n] for n in layout.order]))
    too_fast = bytearray(good)
    too_fast[6:8] = (0x7FFF).to_bytes(2, "little")            # duty_j4 = 3.2767: outside -1..1
    for data in (bytes(good[:8]), bytes(too_fast)):
        intruder.send(can.Message(arbitration_id=CMD_ID, data=data, is_extended_id=False, is_fd=True))
    rig.run_for(0.02)
    assert rig.node.bad_frames == 2
    assert rig.plant.motor_commands.expired and not rig.plant.channel_driven[J4]
    intruder.send(can.Message(arbitration_id=CMD_ID, data=bytes(good), is_extended_id=False, is_fd=True))
    rig.run_for(0.002)
    assert rig.plant.channel_driven[J4]


def test_motor_commands_reject_bad_input_and_keep_the_last():
    commands = ExpiringMotorCommands(0.02)
    assert commands.command([0.5] * N, [True] * N, [False] * N, alive=1, now=0.0)
    for duty in ([0.5] * (N - 1), [1.5] + [0.0] * (N - 1), [math.nan] * N):
        with pytest.raises(ValueError):
            commands.command(duty, [True] * len(duty), [False] * len(duty), alive=2, now=0.001)
    assert commands.current(0.001) == ([0.5] * N, [True] * N, [False] * N)
    assert commands.current(0.021) == commands.safe
    with pytest.raises(ValueError, match="timeout_s"):
        ExpiringMotorCommands(0.0)


def test_plant_with_the_arm_by_default_and_its_options():
    plant = Plant(PlantParams(), np.random.default_rng(0))
    assert plant.arm.gravity == "earth" and plant.arm.payload_kg == 0.0
    orbit = Plant(PlantParams(), np.random.default_rng(0), gravity="orbit", payload_kg=2.0)
    assert orbit.arm.gravity == "orbit" and orbit.arm.payload_kg == 2.0
    with pytest.raises(ValueError, match="gravity"):
        Plant(PlantParams(), np.random.default_rng(0), gravity="moon")
    with pytest.raises(ValueError, match="together"):
        plant.step(0.001, True, False, duty=[0.0] * N)
    with pytest.raises(ValueError, match="6 entries"):
        plant.step(0.001, True, False, [0.0] * 5, [True] * 5, [False] * 5)
    with pytest.raises(ValueError, match="encoder_glitch_counts"):
        PlantParams(encoder_glitch_counts=0)
    with pytest.raises(ValueError, match="motor_cmd_timeout_s"):
        PlantParams(motor_cmd_timeout_s=0.0)


def test_float_noise_in_now_does_not_change_the_integration(virtual_can):
    # A scheduler's `now` accumulates float error (0.0010000000000000009 s steps); the plant must
    # integrate exactly as with clean 1 ms steps, for the same result and the same cost.
    open_bus = virtual_can()
    node = PlantNode(open_bus(), Plant(PlantParams(), np.random.default_rng(2)), codec=CODEC)
    twin = Plant(PlantParams(), np.random.default_rng(2))
    duty, enable, brake = [0.4, -0.3, 0.2, 0.5, 0.3, 0.6], [True] * N, [False] * N
    now = 0.1
    for k in range(300):
        for plant in (node.plant, twin):
            plant.commanded.command(True, False, alive=k % 256, now=now)
            plant.motor_commands.command(duty, enable, brake, alive=k % 256, now=now)
        node.step(now)
        twin.step(0.0 if k == 0 else 0.001, True, False, duty, enable, brake)
        now += 0.001
    assert node.plant.arm.pos_rad.tolist() == twin.arm.pos_rad.tolist()
    assert node.plant.encoder_counts == twin.encoder_counts and node.plant.supply_v == twin.supply_v
