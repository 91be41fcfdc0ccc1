"""The one-process world's nodes hand each other values: every handler gets what packed frames give it.

`FrameLayout.roundtrip` is `unpack(pack(values))` without the bytes, to the bit and the type, or
None (the sender then packs the frame); a world on the direct carrier and one on packed frames,
same seed, same session, have every handler of both nodes receive the very same values at the
very same `now`, and count the same.
"""
from __future__ import annotations

import struct

import can
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from host_tools.worlds.local_bus import open_local_pair
from host_tools.worlds.settings import PlantSettings
from host_tools.worlds.world import LockstepBench
from protocol import hal
from protocol.hal import HalEncodeError, HalEndpoint, default_codec
from protocol.value_frame import ValueFrame
from test_same_bytes_as_before import run_session

CODEC = default_codec()
LAYOUTS = {name: CODEC.layout(name) for name in CODEC.names}


def exactly(values) -> list:
    """Each value as its type and its exact value (a float by its bits), for comparing to the bit."""
    return [(type(v).__name__, v.hex() if isinstance(v, float) else v) for v in values]


# --- the roundtrip ---------------------------------------------------------------------------------

def signal_value(signal) -> st.SearchStrategy:
    """Values of every kind a sender might hand a layout: in range and out, ints, bools, floats, numpy."""
    lo, hi = round(signal.minimum / signal.scale), round(signal.maximum / signal.scale)
    raws = st.integers(lo - 2, hi + 2)
    physical = raws.map(lambda r: r * signal.scale) if signal.scale != 1 else raws
    near = st.floats(signal.minimum - 2 * signal.scale, signal.maximum + 2 * signal.scale)
    return st.one_of(physical, physical, near, st.booleans(), st.floats(), st.none(),
                     physical.map(np.float64), near.map(np.float32), raws.map(np.int64), st.booleans().map(np.bool_))


def pack_then_unpack(layout, values):
    try:
        return layout.unpack(layout.pack(values))
    except (ValueError, TypeError, ArithmeticError, struct.error):    # refused, as the bytes would be
        return None


@settings(max_examples=200, deadline=None)
@given(name=st.sampled_from(sorted(LAYOUTS)), data=st.data())
def test_a_roundtrip_gives_what_the_bytes_give_to_the_bit_and_the_type_or_declines(name, data):
    layout = LAYOUTS[name]
    signals = {s.name: s for s in CODEC.database.get_message_by_name(name).signals}
    values = [data.draw(signal_value(signals[n]), label=n) for n in layout.order]
    got = layout.roundtrip(values)
    if got is not None:
        expected = pack_then_unpack(layout, values)
        assert expected is not None and exactly(got) == exactly(expected)


@settings(max_examples=200, deadline=None)
@given(name=st.sampled_from(sorted(LAYOUTS)), data=st.data())
def test_what_the_nodes_send_never_takes_the_bytes(name, data):
    """Python ints (bools for bits) and floats inside the declared ranges: the roundtrip always answers."""
    layout = LAYOUTS[name]
    values = []
    for n in layout.order:
        s = CODEC.database.get_message_by_name(name).get_signal_by_name(n)
        if s.scale == 1:
            kind = st.booleans() if s.length == 1 else st.integers(round(s.minimum), round(s.maximum))
        else:
            kind = st.floats(s.minimum, s.maximum)
        values.append(data.draw(kind, label=n))
    got = layout.roundtrip(values)
    assert got is not None and exactly(got) == exactly(layout.unpack(layout.pack(values)))


def test_a_receiver_with_its_own_order_unpacks_the_bytes_of_a_value_frame():
    plant_end, controller_end = open_local_pair(carries_values=True)
    sender, receiver = HalEndpoint(plant_end), HalEndpoint(controller_end)
    got = []
    order = tuple(reversed(LAYOUTS["ANALOG_IN"].order))
    receiver.on_frame("ANALOG_IN", lambda values, now: got.append(values), order)
    try:
        assert sender.carries_values and sender.send_frame(LAYOUTS["ANALOG_IN"], (24.0004, -3.25))
        assert receiver.poll(0.0) == 1
        assert exactly(got[0]) == exactly(CODEC.layout("ANALOG_IN", order).unpack(CODEC.encode(
            "ANALOG_IN", supply_v=24.0004, controller_temp_c=-3.25).data))
    finally:
        plant_end.shutdown()
        controller_end.shutdown()


# --- a world both ways -----------------------------------------------------------------------------

def record_handlers(endpoint: HalEndpoint, node: str, log: list) -> None:
    """Every value the endpoint's handlers receive goes to `log` as (node, frame, values, now), exactly."""
    for layout, handler in list(endpoint._listeners.values()):
        def recorded(values, now, name=layout.name, handler=handler):
            log.append((node, name, exactly(values), now.hex()))
            handler(values, now)
        endpoint.on_frame(layout.name, recorded, layout.order)


def session(direct_values: bool, monkeypatch) -> tuple:
    """The session of tests/test_same_bytes_as_before.py (homing, every joint jogged, the gripper closed
    and opened, the tracker's box turned), what the handlers of both nodes received, the nodes' counters,
    and which frames were packed."""
    packed, log, counters = [], [], {}
    message = hal.FrameLayout.message

    def counting_message(layout, values):
        packed.append(layout.name)
        return message(layout, values)

    def watch(world) -> None:
        record_handlers(world.plant_node, "plant", log)
        record_handlers(world.controller.hal, "controller", log)
        counters.update(plant=world.plant_node, controller=world.controller.hal)
    with monkeypatch.context() as patched:
        patched.setattr(hal.FrameLayout, "message", counting_message)
        result = run_session(direct_values, watch, fast_loop=False)     # every handler call, none handed over
    counted = {node: (e.frames_sent, e.sent_by_name, e.frames_received, e.bad_frames, e.bus_errors)
               for node, e in counters.items()}
    return log, counted, result, packed


def test_the_direct_carrier_hands_every_handler_what_packed_frames_give_it(monkeypatch):
    direct, direct_counters, direct_result, packed_in_direct = session(True, monkeypatch)
    frames, frame_counters, frame_result, packed = session(False, monkeypatch)
    assert packed_in_direct == []                                   # the direct world packed not one frame
    # the other, every kind one arm sends (the two-arm frames but)
    assert set(packed) == LAYOUTS.keys() - {"CTRL_SYNC", "TRAJ_START", "TRAJ_STOP", "GRASP_FORCE"}
    assert len(direct) == len(frames) > 10_000
    for k, (a, b) in enumerate(zip(direct, frames)):
        assert a == b, f"handler call {k} differs: direct {a} against packed {b}"
    assert direct_counters == frame_counters
    assert direct_result == frame_result


def test_raw_frames_sent_onto_the_direct_carrier_arrive_and_are_counted_as_before():
    bench = LockstepBench(seed=1, plant=PlantSettings(tracker=False))
    world = bench.world
    try:
        bench.run_for(0.05)
        world.controller_bus.send(can.Message(arbitration_id=CODEC.frame_id("CTRL_OUTPUTS"), data=bytes(2),
                                              is_extended_id=False))          # too short
        world.plant_bus.send(can.Message(arbitration_id=0x7F0, data=bytes(8), is_extended_id=False))  # not ours
        world.plant_bus.send(CODEC.encode("ANALOG_IN", supply_v=12.5, controller_temp_c=-7.0))   # a good one
        received = world.controller.hal.frames_received
        world.controller.hal.poll(bench.clock.now())
        assert world.controller.hal.frames_received == received + 2 and world.controller.hal.bad_frames == 1
        assert world.controller.hal.inputs.supply_v == 12.5 and world.controller.hal.inputs.temp_c == -7.0
        bench.run_for(0.002)
        assert world.plant_node.bad_frames == 1
    finally:
        bench.close()


def test_a_value_frame_passes_the_bus_as_a_frame_would_and_what_it_cannot_carry_is_packed():
    plant_end, controller_end = open_local_pair(carries_values=True)
    try:
        node = HalEndpoint(plant_end)
        layout = LAYOUTS["PLANT_SYNC"]
        assert node.send_frame(layout, (7, True, 1000))
        frame = controller_end.recv(0)
        assert isinstance(frame, ValueFrame) and frame.arbitration_id == layout.frame_id
        assert exactly(frame.values) == exactly([7, 1, 1000]) and bytes(frame.data) == layout.pack((7, 1, 1000))
        assert CODEC.decode(frame) == ("PLANT_SYNC", {"tick": 7, "lockstep": 1, "period_us": 1000})
        assert node.send_frame(layout, (7.0, 1, 1000))          # a float for an integer: packed (pack rounds it)
        packed = controller_end.recv(0)
        assert isinstance(packed, can.Message) and layout.unpack(packed.data) == [7, 1, 1000]
        with pytest.raises(HalEncodeError, match="lockstep"):   # refused by the sender, as with bytes
            node.send_frame(layout, (7, 2, 1000))
        assert node.frames_sent == 2 and node.sent_by_name == {"PLANT_SYNC": 2}
    finally:
        plant_end.shutdown()
        controller_end.shutdown()
