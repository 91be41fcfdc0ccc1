"""HAL bus: codec, controller side, plant side, run in lock-step on real python-can virtual buses.

Every test opens its buses on a channel name of its own (python-can's virtual channels are
shared process-wide by name) and closes them at teardown. Time is a `SimClock`; nothing
sleeps on wall time.
"""
from __future__ import annotations

import math
import statistics
from dataclasses import replace
from pathlib import Path

import can
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from firmware_py.hal import ControllerHal
from timebase.scheduler import Scheduler
from hil_sim.hal_node import PlantNode
from hil_sim.plant import FAULTS, Plant, PlantParams
from protocol.hal import HalCodec, HalDecodeError, HalEncodeError
from protocol.states import ARM_CHANNELS
from timebase import SimClock

CODEC = HalCodec()
SYNC_ID = CODEC.frame_id("PLANT_SYNC")
OUTPUTS_ID = CODEC.frame_id("CTRL_OUTPUTS")
ANALOG_ID = CODEC.frame_id("ANALOG_IN")


def drain(bus: can.BusABC) -> list[can.Message]:
    frames = []
    while (msg := bus.recv(timeout=0)) is not None:
        frames.append(msg)
    return frames


class Rig:
    """A controller and a plant in lock-step on one virtual channel.

    The controller task polls the HAL, records what it sees, and (while `sending`)
    sends `enabled`/`brake` every `ctrl_period_s`.
    """

    def __init__(self, open_bus, params: PlantParams = PlantParams(), seed: int = 1,
                 plant_period_s: float = 0.001, ctrl_period_s: float = 0.01) -> None:
        self.clock = SimClock()
        self.sched = Scheduler(self.clock, stopwatch=self.clock.now)
        self.plant = Plant(params, np.random.default_rng(seed))
        self.node = PlantNode(open_bus(), self.plant, period_s=plant_period_s, codec=CODEC)
        self.hal = ControllerHal(open_bus(), CODEC)
        self.ctrl_period_s = ctrl_period_s
        self.enabled = False
        self.brake = True
        self.sending = True
        self.freeze_alive = False   # make the controller repeat one alive value (a stuck sender)
        self.plant_running = True
        self.last_sent_s: float | None = None
        self.seen: list[tuple[float, float, float]] = []  # (now, supply_v, temp_c) when fresh
        self._last_updated_s: float | None = None
        self.sched.add("plant", self._plant_task)
        self.sched.add("controller", self._controller_task)

    def _plant_task(self, now: float):
        return self.node.step(now) if self.plant_running else None

    def _controller_task(self, now: float) -> float:
        self.hal.poll(now)
        inputs = self.hal.inputs
        if inputs.updated_s is not None and inputs.updated_s != self._last_updated_s:
            self._last_updated_s = inputs.updated_s
            self.seen.append((now, inputs.supply_v, inputs.temp_c))
        if self.sending:
            if self.freeze_alive:
                self.hal.alive = 7
            self.hal.send_outputs(self.enabled, self.brake)
            self.last_sent_s = now
        return now + self.ctrl_period_s

    def run_for(self, duration_s: float) -> None:
        self.sched.run_until(self.clock.now() + duration_s)

    def seen_between(self, start_s: float, end_s: float) -> list[tuple[float, float, float]]:
        return [s for s in self.seen if start_s <= s[0] < end_s]


def mean_supply(samples) -> float:
    return statistics.fmean(s[1] for s in samples)


# --- codec -----------------------------------------------------------------------------------

def test_dbc_declares_the_bus():
    assert CODEC.names == ("PLANT_SYNC", "CTRL_SYNC", "TRAJ_START", "TRAJ_STOP", "CTRL_OUTPUTS", "TRACKER_CMD",
                           "MOTOR_CMD", "DIGITAL_IN", "MOTOR_FB", "ANALOG_IN", "TRACKER_SENSE", "TRACKER_POS",
                           "GRASP_FORCE")
    assert (SYNC_ID, CODEC.frame_id("CTRL_SYNC"), OUTPUTS_ID, ANALOG_ID) == (0x010, 0x011, 0x020, 0x280)
    senders = {m.name: m.senders for m in CODEC.database.messages}
    assert senders == {"PLANT_SYNC": ["PLANT"], "CTRL_SYNC": ["CONTROLLER"], "TRAJ_START": ["CONTROLLER"],
                       "TRAJ_STOP": ["CONTROLLER"], "GRASP_FORCE": ["PLANT"], "CTRL_OUTPUTS": ["CONTROLLER"],
                       "MOTOR_CMD": ["CONTROLLER"],
                       "DIGITAL_IN": ["PLANT"], "MOTOR_FB": ["PLANT"], "ANALOG_IN": ["PLANT"],
                       "TRACKER_CMD": ["CONTROLLER"], "TRACKER_SENSE": ["PLANT"], "TRACKER_POS": ["PLANT"]}
    assert CODEC.cycle_time_s("ANALOG_IN") == pytest.approx(0.01)
    # the per-tick motor frames carry every arm channel in one CAN FD frame each way
    assert CODEC.is_fd("MOTOR_CMD") and CODEC.is_fd("MOTOR_FB") and not CODEC.is_fd("DIGITAL_IN")
    for name, prefixes in (("MOTOR_CMD", ("duty", "enable", "brake")), ("MOTOR_FB", ("count", "current")),
                           ("DIGITAL_IN", ("home", "limit_lo", "limit_hi"))):
        signals = {s.name for s in CODEC.database.get_message_by_name(name).signals}
        assert {f"{p}_{ch}" for p in prefixes for ch in ARM_CHANNELS} <= signals


def test_fd_frames_round_trip_and_are_sent_as_fd():
    values = {f"duty_{ch}": (k - 2.5) / 3 for k, ch in enumerate(ARM_CHANNELS)}
    values.update({f"enable_{ch}": k % 2 for k, ch in enumerate(ARM_CHANNELS)})
    values.update({f"brake_{ch}": 1 - k % 2 for k, ch in enumerate(ARM_CHANNELS)})
    msg = CODEC.encode("MOTOR_CMD", alive=7, **values)
    assert msg.is_fd and len(msg.data) == 16
    name, decoded = CODEC.decode(msg)
    assert name == "MOTOR_CMD" and decoded["alive"] == 7
    for key, value in values.items():
        assert decoded[key] == pytest.approx(value, abs=1e-4)
    fb = CODEC.encode("MOTOR_FB", tick=3, **{f"count_{ch}": -2**31 + k for k, ch in enumerate(ARM_CHANNELS)},
                      **{f"current_{ch}": -1.5 * k for k, ch in enumerate(ARM_CHANNELS)})
    assert fb.is_fd and len(fb.data) == 48
    assert CODEC.decode(fb)[1]["count_gripper"] == -2**31 + 4


def test_docs_list_every_declared_frame():
    doc = (Path(__file__).parent.parent / "docs" / "hal_bus.md").read_text()
    for message in CODEC.database.messages:
        row = f"| 0x{message.frame_id:03X} | `{message.name}` | {message.senders[0]} |"
        assert row in doc, f"docs/hal_bus.md has no frame-table row for {message.name}"
        for signal in message.signals:
            # per-channel signals are documented once, as `duty_<ch>`
            name = signal.name
            for ch in ARM_CHANNELS:
                if name.endswith("_" + ch):
                    name = name[: -len(ch)] + "<ch>"
            for ax in ("az", "el"):      # tracker signals: `relay_cw_<ax>`, `cell_<ax>_a`
                name = name.replace(f"_{ax}_", "_<ax>_") if f"_{ax}_" in name else (
                    name[: -len(ax)] + "<ax>" if name.endswith("_" + ax) else name)
            assert f"`{name}`" in doc, f"docs/hal_bus.md does not mention {name}"


@settings(max_examples=200, deadline=None)
@given(tick=st.integers(0, 2**32 - 1), lockstep=st.integers(0, 1), period_us=st.integers(0, 65535))
def test_plant_sync_round_trip(tick, lockstep, period_us):
    msg = CODEC.encode("PLANT_SYNC", tick=tick, lockstep=lockstep, period_us=period_us)
    assert (msg.arbitration_id, msg.is_extended_id, msg.dlc, len(msg.data)) == (SYNC_ID, False, 8, 8)
    assert CODEC.decode(msg) == ("PLANT_SYNC", {"tick": tick, "lockstep": lockstep, "period_us": period_us})


@settings(max_examples=200, deadline=None)
@given(enabled=st.booleans(), brake=st.booleans(), alive=st.integers(0, 255))
def test_ctrl_outputs_round_trip(enabled, brake, alive):
    msg = CODEC.encode("CTRL_OUTPUTS", outputs_enabled=enabled, brake_all=brake, alive=alive)
    assert (msg.arbitration_id, msg.is_extended_id, len(msg.data)) == (OUTPUTS_ID, False, 8)
    assert CODEC.decode(msg) == ("CTRL_OUTPUTS", {"outputs_enabled": int(enabled),
                                                   "brake_all": int(brake), "alive": alive})


@settings(max_examples=200, deadline=None)
@given(supply_v=st.floats(0.0, 60.0), temp_c=st.floats(-40.0, 125.0))
def test_analog_in_round_trip_within_resolution(supply_v, temp_c):
    msg = CODEC.encode("ANALOG_IN", supply_v=supply_v, controller_temp_c=temp_c)
    assert (msg.arbitration_id, msg.is_extended_id, len(msg.data)) == (ANALOG_ID, False, 8)
    name, values = CODEC.decode(msg)
    assert name == "ANALOG_IN"
    assert values["supply_v"] == pytest.approx(supply_v, abs=0.0005 + 1e-9)   # 1 mV per count
    assert values["controller_temp_c"] == pytest.approx(temp_c, abs=0.05 + 1e-9)  # 0.1 C per count


def test_encode_rejects_what_the_dbc_does_not_declare():
    with pytest.raises(HalEncodeError, match="declared: PLANT_SYNC, CTRL_SYNC, TRAJ_START, TRAJ_STOP, CTRL_OUTPUTS, TRACKER_CMD"):
        CODEC.encode("MOTOR_CMD_0", duty=0.5)
    with pytest.raises(HalEncodeError, match="controller_temp_c"):
        CODEC.encode("ANALOG_IN", supply_v=28.0)
    with pytest.raises(HalEncodeError, match="supply_v"):
        CODEC.encode("ANALOG_IN", supply_v=61.0, controller_temp_c=20.0)


def test_decode_ignores_undeclared_frames_and_rejects_bad_data():
    assert CODEC.decode(can.Message(arbitration_id=0x7F0, data=bytes(8), is_extended_id=False)) is None
    # Same number as PLANT_SYNC, but a 29-bit ID: a different frame.
    assert CODEC.decode(can.Message(arbitration_id=SYNC_ID, data=bytes(8), is_extended_id=True)) is None
    assert CODEC.decode(can.Message(arbitration_id=SYNC_ID, is_remote_frame=True,
                                    is_extended_id=False)) is None
    with pytest.raises(HalDecodeError, match="ANALOG_IN.*4 data bytes"):
        CODEC.decode(can.Message(arbitration_id=ANALOG_ID, data=bytes(4), is_extended_id=False))
    # 0x7FFF in the temperature field is 3276.7 C: outside the declared -40..125 C.
    too_hot = bytes([0x60, 0x6D, 0xFF, 0x7F, 0, 0, 0, 0])
    with pytest.raises(HalDecodeError, match="controller_temp_c"):
        CODEC.decode(can.Message(arbitration_id=ANALOG_ID, data=too_hot, is_extended_id=False))
    assert issubclass(HalDecodeError, ValueError) and issubclass(HalEncodeError, ValueError)


@settings(max_examples=300, deadline=None)
@given(frame_id=st.integers(0, 0x7FF), data=st.binary(max_size=64), fd=st.booleans())
def test_decode_of_any_frame_returns_or_raises_hal_decode_error(frame_id, data, fd):
    msg = can.Message(arbitration_id=frame_id, data=data, is_extended_id=False, is_fd=fd)
    try:
        result = CODEC.decode(msg)
    except HalDecodeError:
        assert frame_id in {m.frame_id for m in CODEC.database.messages}
    else:
        assert result is None or result[0] in CODEC.names


# --- controller and plant on the bus -------------------------------------------------------------

def test_controller_sees_supply_temperature_and_tick(virtual_can):
    rig = Rig(virtual_can())
    assert rig.hal.is_stale(0.0, max_age_s=1.0)   # nothing received yet
    assert math.isnan(rig.hal.inputs.supply_v)
    rig.run_for(0.5)
    p = rig.plant.params
    idle_supply_v = p.supply_nominal_v - p.idle_current_a * p.supply_source_ohm
    inputs = rig.hal.inputs
    assert mean_supply(rig.seen) == pytest.approx(idle_supply_v, abs=0.01)
    assert inputs.temp_c == pytest.approx(p.ambient_c, abs=0.5)
    rig.hal.poll(rig.clock.now())
    assert inputs.tick == rig.node.tick - 1        # the last step's tick
    assert not rig.hal.is_stale(rig.clock.now(), max_age_s=0.011)
    assert rig.hal.bad_frames == 0 and rig.node.bad_frames == 0
    # PLANT_SYNC and MOTOR_FB every 1 ms step, ANALOG_IN and DIGITAL_IN every 10th step, starting with the first.
    assert rig.node.analog_every_n == 10
    n = rig.node.tick
    assert rig.node.sent_by_name == {"PLANT_SYNC": n, "MOTOR_FB": n, "DIGITAL_IN": math.ceil(n / 10),
                                     "ANALOG_IN": math.ceil(n / 10)}
    assert rig.node.frames_sent == 2 * n + 2 * math.ceil(n / 10)


def test_controller_detects_a_silent_plant(virtual_can):
    rig = Rig(virtual_can())
    rig.run_for(0.2)
    rig.plant_running = False
    rig.run_for(0.2)
    now = rig.clock.now()
    assert rig.hal.is_stale(now, max_age_s=0.05)
    assert now - rig.hal.inputs.updated_s == pytest.approx(0.2, abs=0.011)


def test_unknown_and_bad_frames_are_counted_never_raised(virtual_can):
    open_bus = virtual_can()
    rig = Rig(open_bus)
    intruder = open_bus()
    rig.run_for(0.05)
    junk = [
        can.Message(arbitration_id=0x7F0, data=bytes(8), is_extended_id=False),      # undeclared
        can.Message(arbitration_id=ANALOG_ID, data=bytes(8), is_extended_id=True),   # 29-bit
        can.Message(arbitration_id=ANALOG_ID, data=bytes(3), is_extended_id=False),  # short
        can.Message(arbitration_id=OUTPUTS_ID, data=bytes(2), is_extended_id=False),  # short
        can.Message(is_error_frame=True),
    ]
    for msg in junk:
        intruder.send(msg)
    before = rig.hal.inputs.supply_v
    assert rig.hal.poll(rig.clock.now()) == len(junk)  # read, all bad, nothing raised
    assert rig.hal.bad_frames == len(junk)
    assert rig.hal.inputs.supply_v == before
    rig.run_for(0.05)                                  # the plant drains the same junk
    assert rig.node.bad_frames == len(junk)
    assert rig.hal.bad_frames == len(junk)             # and good frames keep flowing
    assert not rig.hal.is_stale(rig.clock.now(), max_age_s=0.011)


def test_temperature_rises_while_enabled_and_relaxes_after(virtual_can):
    # A light box (time constant 10 s) so that three time constants take 30 simulated seconds.
    params = PlantParams(thermal_capacity_j_per_c=20.0)
    assert params.thermal_time_constant_s == pytest.approx(10.0)
    rig = Rig(virtual_can(), params, plant_period_s=0.01)
    rig.run_for(1.0)
    start_c = statistics.fmean(s[2] for s in rig.seen)
    rig.enabled, rig.brake = True, False
    rig.run_for(30.0)
    hot = rig.seen_between(30.0, 31.0)
    hot_c = statistics.fmean(s[2] for s in hot)
    current_a = params.idle_current_a + params.enabled_current_a
    enabled_target_c = params.ambient_c + (
        params.supply_nominal_v - current_a * params.supply_source_ohm
    ) * current_a * params.thermal_resistance_c_per_w
    assert hot_c > start_c + 10.0
    assert hot_c == pytest.approx(enabled_target_c, abs=1.2)   # 95 % of the way after 3 tau
    rig.enabled, rig.brake = False, True
    rig.run_for(30.0)
    cool = rig.seen_between(60.0, 61.0)
    cool_c = statistics.fmean(s[2] for s in cool)
    idle_target_c = params.ambient_c + (
        params.supply_nominal_v - params.idle_current_a * params.supply_source_ohm
    ) * params.idle_current_a * params.thermal_resistance_c_per_w
    assert cool_c < hot_c - 8.0
    assert cool_c == pytest.approx(idle_target_c, abs=1.2)


def test_supply_sags_under_load_and_under_the_fault(virtual_can):
    rig = Rig(virtual_can())
    p = rig.plant.params
    rig.run_for(1.0)
    idle_v = mean_supply(rig.seen_between(0.1, 1.0))
    rig.enabled, rig.brake = True, False
    rig.run_for(1.0)
    loaded_v = mean_supply(rig.seen_between(1.1, 2.0))
    assert idle_v - loaded_v == pytest.approx(p.enabled_current_a * p.supply_source_ohm, abs=0.01)
    rig.plant.inject("supply_sag")
    rig.run_for(1.0)
    sagged_v = mean_supply(rig.seen_between(2.1, 3.0))
    current_a = p.idle_current_a + p.enabled_current_a
    assert sagged_v == pytest.approx(p.supply_sag_v - current_a * p.supply_source_ohm, abs=0.01)
    rig.plant.clear("supply_sag")
    rig.run_for(1.0)
    assert mean_supply(rig.seen_between(3.1, 4.0)) == pytest.approx(loaded_v, abs=0.01)


def test_over_temperature_fault_passes_45_c_within_300_s(virtual_can):
    # Default box (time constant 300 s) starting at 22 C; the fault puts ambient at 60 C.
    # First-order prediction of the crossing: about 242 s. The controller must see > 45 C
    # within 300 simulated seconds, and not implausibly early (the box has thermal mass).
    # A first-order lag's crossing time is proportional to its time constant, so the plant
    # simulated is the default box with a tenth of its thermal capacity (time constant 30 s,
    # everything else the same), run for 30 s, and its times are scaled back by 10.
    p = PlantParams()
    scale = 10.0
    fast = replace(p, thermal_capacity_j_per_c=p.thermal_capacity_j_per_c / scale)
    assert fast.thermal_time_constant_s * scale == p.thermal_time_constant_s
    rig = Rig(virtual_can(), fast, plant_period_s=0.02, ctrl_period_s=0.05)
    rig.plant.inject("over_temperature")
    rig.run_for(300.0 / scale)
    crossing_s = scale * next(now for now, _, temp_c in rig.seen if temp_c > 45.0)
    heat_w = (p.supply_nominal_v - p.idle_current_a * p.supply_source_ohm) * p.idle_current_a
    target_c = p.over_temperature_ambient_c + heat_w * p.thermal_resistance_c_per_w
    predicted_s = -p.thermal_time_constant_s * math.log((target_c - 45.0) / (target_c - p.ambient_c))
    assert crossing_s < 300.0
    assert crossing_s == pytest.approx(predicted_s, rel=0.05)
    rig.plant.clear("over_temperature")
    assert rig.plant.ambient_c == p.ambient_c


def test_outputs_expire_at_the_plant_when_the_controller_stops_sending(virtual_can):
    rig = Rig(virtual_can())
    rig.enabled, rig.brake = True, False
    rig.run_for(1.0)
    assert (rig.plant.outputs_enabled, rig.plant.brake) == (True, False)
    rig.sending = False
    rig.run_for(0.05)
    last_s = rig.last_sent_s
    timeout_s = rig.plant.params.output_timeout_s
    rig.sched.run_until(last_s + timeout_s - 0.005)
    assert (rig.plant.outputs_enabled, rig.plant.brake) == (True, False)
    rig.sched.run_until(last_s + timeout_s + 0.005)   # one frame's plant latency + one tick
    assert (rig.plant.outputs_enabled, rig.plant.brake) == (False, True)
    assert rig.plant.commanded.expiries == 1
    # The controller sees its outputs die: the supply recovers to the idle level.
    rig.run_for(0.1)
    p = rig.plant.params
    idle_v = p.supply_nominal_v - p.idle_current_a * p.supply_source_ohm
    assert rig.hal.inputs.supply_v == pytest.approx(idle_v, abs=0.1)
    # Expiry does not latch at the plant: a fresh command applies again.
    rig.sending = True
    rig.run_for(0.05)
    assert (rig.plant.outputs_enabled, rig.plant.brake) == (True, False)


def test_a_repeated_alive_counter_is_not_a_refresh(virtual_can):
    rig = Rig(virtual_can())
    rig.enabled, rig.brake = True, False
    rig.freeze_alive = True            # the same frame, over and over
    rig.run_for(0.5)
    assert (rig.plant.outputs_enabled, rig.plant.brake) == (False, True)
    assert rig.plant.commanded.alive_repeats > 40
    rig.freeze_alive = False
    rig.run_for(0.05)
    assert (rig.plant.outputs_enabled, rig.plant.brake) == (True, False)


def test_plant_integrates_at_most_max_dt_after_a_stall(virtual_can):
    open_bus = virtual_can()
    params = PlantParams(thermal_capacity_j_per_c=2.0)
    node = PlantNode(open_bus(), Plant(params, np.random.default_rng(3)), codec=CODEC)
    twin = Plant(params, np.random.default_rng(3))
    twin.inject("over_temperature")
    node.plant.inject("over_temperature")
    node.step(10.0)
    twin.step(0.0, False, True)
    node.step(15.0)                      # a 5 s stall
    twin.step(node.max_dt_s, False, True)
    assert node.dt_clamps == 1
    assert node.plant.temp_true_c == twin.temp_true_c
    assert node.plant.temp_c == twin.temp_c


def test_same_seed_same_analog_bytes(virtual_can):
    def analog_payloads(seed: int) -> list[bytes]:
        open_bus = virtual_can()
        rig = Rig(open_bus, seed=seed)
        sniffer = open_bus()
        rig.enabled, rig.brake = True, False
        rig.run_for(0.3)
        rig.plant.inject("supply_sag")
        rig.run_for(0.2)
        return [bytes(m.data) for m in drain(sniffer) if m.arbitration_id == ANALOG_ID]

    first = analog_payloads(seed=7)
    assert len(first) >= 49                          # ANALOG_IN at 100 Hz for 0.5 s
    assert analog_payloads(seed=7) == first
    assert analog_payloads(seed=8) != first


# --- plant on its own -------------------------------------------------------------------------

def test_unknown_fault_names_the_known_ones():
    plant = Plant(PlantParams(), np.random.default_rng(0))
    with pytest.raises(ValueError, match="known faults: supply_sag, over_temperature"):
        plant.inject("meteor")
    with pytest.raises(ValueError, match="known faults"):
        plant.clear("meteor")
    for fault in FAULTS:
        plant.inject(fault)
    assert plant.faults == frozenset(FAULTS)


def test_params_are_checked_when_built():
    with pytest.raises(ValueError, match="thermal_capacity_j_per_c"):
        PlantParams(thermal_capacity_j_per_c=0.0)
    with pytest.raises(ValueError, match="supply_source_ohm"):
        PlantParams(supply_source_ohm=-1.0)
    assert PlantParams().thermal_time_constant_s == pytest.approx(300.0)


def test_motor_command_values_are_what_its_bytes_give_for_every_duty_step():
    """ControllerHal.send_motor_command hands a value-carrying bus its values as they are (no round trip through the
    layout): for every duty step of the range, duties between steps, beyond -1..1, the receiver gets what the
    frame's bytes give it, to the bit and the type."""
    from host_tools.worlds.local_bus import open_local_pair
    from firmware_py.hal import _CMD_ORDER
    from protocol.hal import HalEndpoint

    def received(carries_values: bool, commands: list) -> list:
        controller_end, plant_end = open_local_pair(carries_values=carries_values)
        hal, plant = ControllerHal(controller_end, CODEC), HalEndpoint(plant_end, CODEC)
        got: list = []
        plant.on_frame("MOTOR_CMD", lambda values, now: got.append(values), _CMD_ORDER)
        try:
            for duty, enable, brake in commands:
                hal.send_motor_command(duty, enable, brake)
                plant.poll(0.0)
        finally:
            controller_end.shutdown()
            plant_end.shutdown()
        return [[(type(v).__name__, v.hex() if isinstance(v, float) else v) for v in values] for values in got]

    n = len(ARM_CHANNELS)
    step = ControllerHal(open_local_pair()[0], CODEC).duty_step
    duties = [r * step for r in range(-10_000, 10_001)] + [r * step + step / 2 for r in range(-10_000, 10_000)]
    duties += [-1.5, 1.5, -1.0000000001, 1.0000000001, -0.0, 0.0, 0.123456789, -0.98765]
    commands = [(duties[k:k + n], [k % 2 == 0] * n, [k % 3 == 0] * n) for k in range(0, len(duties) - n, n)]
    carried = received(True, commands)
    assert len(carried) == len(commands)
    assert carried == received(False, commands)
