"""The fuzzing benchmark's planted bugs are real (bench/fuzz_plants.py): each planted copy misbehaves on an input
made by hand to trigger it, where the real code does not; the slow path is slow but right.

Each test runs the same input on the real code and on the planted copy, in lock-step worlds on the simulated
clock (a planted handler in a world built after the plant: a controller takes its handlers when it is built,
firmware_py/handlers.py), and puts the real code back at its end."""
from __future__ import annotations

import struct
from contextlib import contextmanager

import pytest

from bench import fuzz_plants
from firmware_py.controller import ControllerConfig
from host_tools.teleop import format as teleop_format
from host_tools.worlds.world import LockstepBench
from protocol.errors import ParseError
from protocol.messages import SCHEMA
from protocol.reasons import Reason
from protocol.states import Axis, ControllerState, Fault, TimingIssue
from timebase import SimClock

M = SCHEMA.by_name


@pytest.fixture
def world(tmp_path):
    """A connected lock-step world; every plant installed during the test is taken out at its end."""
    bench = LockstepBench(seed=0, controller_config=ControllerConfig(params_path=tmp_path / "params.json"))
    assert bench.connect(timeout_s=10.0)
    yield bench
    bench.close()
    fuzz_plants.uninstall_all()


@contextmanager
def planted_world(tmp_path, name: str):
    """A connected lock-step world built after plant `name` is installed (taken out by `world` at the test's end)."""
    fuzz_plants.install(name)
    bench = LockstepBench(seed=0, controller_config=ControllerConfig(params_path=tmp_path / "planted.json"))
    try:
        assert bench.connect(timeout_s=10.0)
        yield bench
    finally:
        bench.close()


def reply(bench, msg):
    handle = bench.call(msg)
    assert handle.done
    return handle.reply


def reply_to_payload(bench, spec, payload: bytes):
    """The reply to command `spec` with `payload` as given (not through the encoder, which checks ranges)."""
    handle = bench.host.submit_payload(spec, payload, bench.link_clock.now())
    bench.wait_until(lambda: handle.done, 30.0, between_loops=True)
    return handle.reply


def next_f32_up(x: float) -> float:
    return struct.unpack("<f", struct.pack("<I", struct.unpack("<I", struct.pack("<f", x))[0] + 1))[0]


def test_param_index_raises_at_the_count_only_when_planted(tmp_path, world):
    count = len(world.controller.params.order)
    assert reply(world, M["ParamList"].type(count)).result == Reason.OUT_OF_RANGE
    with planted_world(tmp_path, "param-index") as planted:
        assert reply(planted, M["ParamList"].type(count - 1)).result == Reason.OK
        with pytest.raises(IndexError):
            planted.call(M["ParamList"].type(count))


def test_jog_range_accepts_one_f32_past_the_declared_maximum(world):
    spec = M["Jog"]
    past = next_f32_up(360.0)
    payload = struct.pack("<Bf", int(Axis.J1), past)
    with pytest.raises(ParseError):
        spec.decode(payload)
    before = world.controller.link.commands_executed
    refused = reply_to_payload(world, spec, payload)
    assert (refused.spec.name, refused.result) == ("Result", Reason.OUT_OF_RANGE)
    assert world.controller.link.commands_executed == before
    fuzz_plants.install("jog-range")
    assert spec.decode(payload).speed == past
    with pytest.raises(ParseError):
        spec.decode(struct.pack("<Bf", int(Axis.J1), next_f32_up(past)))          # one step only
    assert reply_to_payload(world, spec, payload).spec.name == "MotionAccepted"    # run: no crash
    assert world.controller.link.commands_executed == before + 1


def test_move_park_raises_at_the_interior_value_only(tmp_path, world):
    move = M["Move"].type
    assert reply(world, move(int(Axis.J1), fuzz_plants.PARK_DEG, 0.0)).spec.name == "MotionAccepted"
    with planted_world(tmp_path, "move-park") as planted:
        assert reply(planted, move(int(Axis.J1), 122.99999237060547, 0.0)).spec.name == "MotionAccepted"
        with pytest.raises(KeyError):
            planted.call(move(int(Axis.J1), fuzz_plants.PARK_DEG, 0.0))


def _estop_disable_enable(bench) -> tuple:
    assert reply(bench, M["EStop"].type()).result == Reason.OK
    reply(bench, M["Disable"].type())
    enabled = reply(bench, M["Enable"].type()).result
    sup = bench.controller.supervisor
    return enabled, sup.state, sup.faults


def test_disable_estop_leaves_estop_without_reset(tmp_path, world):
    assert _estop_disable_enable(world) == (Reason.ESTOP, ControllerState.ESTOP, Fault.ESTOP)
    with planted_world(tmp_path, "disable-estop") as planted:
        enabled, state, faults = _estop_disable_enable(planted)
        assert (enabled, state) == (Reason.OK, ControllerState.ENABLED) and faults & Fault.ESTOP


def test_hello_table_grows_each_handshake_until_the_controller_fails(tmp_path, world):
    fuzz_plants.install("hello-table")
    fresh = LockstepBench(seed=1, controller_config=ControllerConfig(params_path=tmp_path / "one.json"))
    try:
        assert fresh.connect(timeout_s=10.0)        # a Hello, its cookie, the Hello again
        assert fuzz_plants._hellos[0] == 2
    finally:
        fresh.close()
    fuzz_plants._hellos[0] = fuzz_plants.HELLO_TABLE_SIZE - 1     # as after 127 more sessions
    full = LockstepBench(seed=2, controller_config=ControllerConfig(params_path=tmp_path / "two.json"))
    try:
        with pytest.raises(IndexError):
            full.connect(timeout_s=10.0)
    finally:
        full.close()


def _knot(index: int, t: float):
    return M["TrajPoint"].type(index, t, *[0.0] * 10)


def _traj_sequence(bench, clear: bool):
    if clear:
        assert reply(bench, M["TrajClear"].type()).result == Reason.OK
    assert reply(bench, _knot(0, 0.0)).result == Reason.OK
    assert reply(bench, _knot(1, 1.0)).result == Reason.OK
    return bench.call(M["TrajRun"].type(2))


def test_traj_two_raises_only_after_the_sequence(tmp_path, world):
    assert _traj_sequence(world, clear=True).reply.result == Reason.NOT_ALLOWED_IN_STATE
    with planted_world(tmp_path, "traj-two") as planted:
        assert _traj_sequence(planted, clear=False).reply.result == Reason.NOT_ALLOWED_IN_STATE   # no TrajClear
        reply(planted, M["TrajClear"].type())
        with pytest.raises(IndexError):
            _traj_sequence(planted, clear=True)


def test_host_event_crashes_the_host_on_a_zero_limit():
    warning = M["TimingWarning"].type(int(TimingIssue.BELOW_REAL_TIME), 1, 0.5, 0.0, 1234)
    usual = M["TimingWarning"].type(int(TimingIssue.BELOW_REAL_TIME), 1, 0.5, 0.9, 1234)
    assert teleop_format.report_lines(warning)
    fuzz_plants.install("host-event")
    try:
        assert teleop_format.report_lines(usual)
        with pytest.raises(ZeroDivisionError):
            teleop_format.report_lines(warning)
    finally:
        fuzz_plants.uninstall_all()


def test_slow_param_is_slow_and_right(tmp_path, world, monkeypatch):
    clock = SimClock()
    monkeypatch.setattr(fuzz_plants, "WALL", clock)
    real = reply(world, M["ParamSet"].type("trk_dwell_s", 2.0))
    assert clock.now() == 0.0
    with planted_world(tmp_path, "slow-param") as planted:
        slow = reply(planted, M["ParamSet"].type("trk_dwell_s", 2.0))
        assert slow == real and slow.result == Reason.OK
        assert clock.now() == fuzz_plants.SLOW_S
        assert reply(planted, M["ParamSet"].type("temp_warn_c", 6.0)).result == Reason.OK
        assert clock.now() == fuzz_plants.SLOW_S          # only the trk_* parameters are slow


def test_every_plant_has_its_targets():
    from host_tools.fuzz.targets import load_target
    try:
        for name, plant in fuzz_plants.PLANTS.items():
            target = load_target(fuzz_plants.target_factory(name))
            assert target.name == f"planted-{name}" and callable(target.one_input)
            assert plant.black_box in ("sim", "teleop")
    finally:
        fuzz_plants.uninstall_all()
