"""The lock-step world's in-process bus: a `can.BusABC` that delivers in order, once, to every other member."""
from __future__ import annotations

import can
import pytest

from firmware_py.hal import ControllerHal
from host_tools.worlds.local_bus import LocalBus, LocalChannel, open_local_pair
from protocol.hal import HalCodec, HalEndpoint

CODEC = HalCodec()


def frame(arbitration_id: int, data: bytes = b"\x01\x02") -> can.Message:
    return can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False)


def test_frames_arrive_in_order_once_at_the_other_end_and_never_back_at_the_sender():
    a, b = open_local_pair()
    try:
        assert isinstance(a, can.BusABC)
        for k in range(3):
            a.send(frame(0x100 + k))
        b.send(frame(0x200))
        assert [b.recv(0).arbitration_id for _ in range(3)] == [0x100, 0x101, 0x102]
        assert b.recv(0) is None and b.recv(timeout=5.0) is None      # never waits: one thread runs the world
        assert a.recv(0).arbitration_id == 0x200 and a.recv(0) is None
    finally:
        a.shutdown()
        b.shutdown()


def test_with_more_receivers_each_gets_its_own_copy_and_own_messages_on_request():
    channel = LocalChannel()
    a, b, c = LocalBus(channel), LocalBus(channel), LocalBus(channel, receive_own_messages=True)
    try:
        sent = frame(0x123, b"\x05\x06\x07")
        a.send(sent)
        got_b, got_c = b.recv(0), c.recv(0)
        assert got_b is not got_c and got_b is not sent
        got_b.data[0] = 0xFF
        assert bytes(got_c.data) == b"\x05\x06\x07" and bytes(sent.data) == b"\x05\x06\x07"
        c.send(frame(0x7))
        assert c.recv(0).arbitration_id == 0x7 and a.recv(0).arbitration_id == 0x7 and b.recv(0).arbitration_id == 0x7
    finally:
        for bus in (a, b, c):
            bus.shutdown()


def test_filters_and_a_closed_bus_behave_as_python_can_declares():
    a, b = open_local_pair()
    b.set_filters([{"can_id": 0x200, "can_mask": 0x700, "extended": False}])
    for arbitration_id in (0x100, 0x210, 0x300, 0x220):
        a.send(frame(arbitration_id))
    assert [b.recv(0).arbitration_id, b.recv(0).arbitration_id, b.recv(0)] == [0x210, 0x220, None]
    b.shutdown()
    with pytest.raises(can.CanOperationError):
        b.recv(0)
    with pytest.raises(can.CanOperationError):
        b.send(frame(0x1))
    a.send(frame(0x1))         # nobody left to hear it: gone, as on a real bus
    assert a.pending == 0
    a.shutdown()
    a.shutdown()               # twice is fine


def test_a_hal_node_reads_the_declared_frames_through_it():
    plant_end, controller_end = open_local_pair()
    hal = ControllerHal(controller_end)
    try:
        plant_end.send(CODEC.encode("PLANT_SYNC", tick=41, lockstep=0, period_us=1000))
        plant_end.send(CODEC.encode("ANALOG_IN", supply_v=27.5, controller_temp_c=31.0))
        assert hal.poll(now=1.0) == 2
        assert hal.inputs.tick == 41 and hal.inputs.supply_v == pytest.approx(27.5)
        hal.send_outputs(enabled=True, brake=False)
        name, values = CODEC.decode(plant_end.recv(0))
        assert name == "CTRL_OUTPUTS" and values["outputs_enabled"] == 1
    finally:
        plant_end.shutdown()
        controller_end.shutdown()


def test_value_frames_pass_filters_by_id_and_each_receiver_gets_its_own_values():
    channel = LocalChannel()
    a, b, c = (LocalBus(channel, carries_values=True) for _ in range(3))
    c.set_filters([{"can_id": CODEC.frame_id("ANALOG_IN"), "can_mask": 0x7FF, "extended": False}])
    try:
        sender = HalEndpoint(a)
        assert sender.send_frame(CODEC.layout("PLANT_SYNC"), (1, 0, 1000))
        assert sender.send_frame(CODEC.layout("ANALOG_IN"), (27.5, 31.0))
        got_b = [b.recv(0), b.recv(0)]
        got_c = c.recv(0)
        assert [f.layout.name for f in got_b] == ["PLANT_SYNC", "ANALOG_IN"] and got_c.layout.name == "ANALOG_IN"
        assert got_c is not got_b[1] and got_c.values == got_b[1].values and got_c.values is not got_b[1].values
        assert b.recv(0) is None and c.recv(0) is None
    finally:
        for bus in (a, b, c):
            bus.shutdown()
