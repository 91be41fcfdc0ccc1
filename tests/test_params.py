"""Parameters: range-checked, set over the link, saved atomically, loaded at boot."""
from __future__ import annotations

import json
import os

import pytest

from firmware_py.controller import ControllerConfig
from firmware_py.params import ParamSpec, ParamStore
from host_tools.worlds.world import LockstepBench
from protocol.messages import MESSAGES as M
from protocol.reasons import Reason
from protocol.states import ControllerState, Fault

SPECS = [ParamSpec("gain", 1.0, 0.0, 10.0, "", "a gain"), ParamSpec("limit_v", 22.0, 0.0, 60.0, "V", "a limit")]


def test_set_refuses_unknown_and_out_of_range_and_changes_nothing(tmp_path):
    store = ParamStore(SPECS, tmp_path / "p.json")
    assert store.set("gain", 11.0)[0] is Reason.OUT_OF_RANGE
    assert store.set("gain", float("nan"))[0] is Reason.OUT_OF_RANGE
    assert store.set("nope", 1.0)[0] is Reason.UNKNOWN_PARAM
    assert store["gain"] == 1.0
    assert store.set("gain", 2.5) == (Reason.OK, "")
    assert store["gain"] == 2.5


def test_save_then_load_restores_the_set(tmp_path):
    path = tmp_path / "sub" / "p.json"
    store = ParamStore(SPECS, path)
    store.set("gain", 3.0)
    assert store.save() == (Reason.OK, "")
    again = ParamStore(SPECS, path)
    assert again.load() == [] and again["gain"] == 3.0 and again["limit_v"] == 22.0


def test_a_crash_in_the_middle_of_a_save_keeps_the_previous_set(tmp_path, monkeypatch):
    path = tmp_path / "p.json"
    store = ParamStore(SPECS, path)
    store.set("gain", 4.0)
    store.save()
    before = path.read_bytes()
    store.set("gain", 9.0)

    def crash(*args):
        raise OSError("power lost")
    monkeypatch.setattr(os, "replace", crash)    # dies after writing the temporary file, before the rename
    reason, detail = store.save()
    assert reason is Reason.SAVE_FAILED and "power lost" in detail
    assert path.read_bytes() == before
    monkeypatch.undo()
    reloaded = ParamStore(SPECS, path)
    reloaded.load()
    assert reloaded["gain"] == 4.0                # the leftover temporary file is ignored


@pytest.mark.parametrize("content, problem", [
    ("{not json", "keep their defaults"),
    (json.dumps({"version": 99, "params": {}}), "not a version-1"),
    (json.dumps({"version": 1, "params": {"gain": 50}}), "outside"),
    (json.dumps({"version": 1, "params": {"gain": "high"}}), "not a number"),
    (json.dumps({"version": 1, "params": {"ghost": 1}}), "no parameter 'ghost'"),
])
def test_a_bad_file_is_reported_and_defaults_stay(tmp_path, content, problem):
    path = tmp_path / "p.json"
    path.write_text(content)
    store = ParamStore(SPECS, path)
    problems = store.load()
    assert len(problems) == 1 and problem in problems[0]
    assert store["gain"] == 1.0


def test_save_without_a_file_is_refused_with_a_reason():
    assert ParamStore(SPECS).save()[0] is Reason.SAVE_FAILED


def param(bench, name):
    handle = bench.call(M["ParamGet"](name))
    return handle


def test_parameters_over_the_link_and_across_a_reboot(tmp_path):
    path = tmp_path / "params.json"
    bench = LockstepBench(seed=1, controller_config=ControllerConfig(params_path=path))
    try:
        assert bench.connect()
        got = param(bench, "supply_min_v")
        assert got.ok and got.reply.value == 22.0 and (got.reply.min, got.reply.max) == (0.0, 60.0)
        refused = bench.call(M["ParamSet"]("supply_min_v", 75.0))
        assert refused.reason is Reason.OUT_OF_RANGE and refused.reply.value == 22.0
        assert param(bench, "warp_factor").reason is Reason.UNKNOWN_PARAM
        listed = [bench.call(M["ParamList"](i)).reply.name for i in range(bench.call(M["ParamList"](0)).reply.count)]
        assert "link_timeout_s" in listed and "temp_max_c" in listed
        assert bench.call(M["ParamList"](len(listed))).reason is Reason.OUT_OF_RANGE
        # a parameter takes effect: raising the supply limit above the supply faults the controller
        assert bench.call(M["ParamSet"]("supply_min_v", 30.0)).ok
        assert bench.wait_until(lambda: bench.controller.supervisor.faults & Fault.SUPPLY_LOW, 0.1)
        assert bench.call(M["ParamSet"]("supply_min_v", 20.0)).ok
        assert bench.call(M["Reset"]()).ok
        assert bench.call(M["ParamSet"]("telemetry_hz", 4)).ok
        assert bench.call(M["ParamSave"]()).ok
    finally:
        bench.close()
    saved = json.loads(path.read_text())["params"]
    assert saved["supply_min_v"] == 20.0 and saved["telemetry_hz"] == 4
    rebooted = LockstepBench(seed=2, controller_config=ControllerConfig(params_path=path))
    try:
        assert rebooted.connect()
        assert param(rebooted, "supply_min_v").reply.value == 20.0
        assert rebooted.controller.telemetry_hz == 4
        assert rebooted.controller.supervisor.state is ControllerState.IDLE
    finally:
        rebooted.close()


def test_a_range_end_that_the_link_carries_as_an_f32_is_that_end(bench):
    """ParamSet's value is an f32: 0.01 arrives as 0.0099999998, below a minimum of 0.01, and the end a parameter's
    own description gives was refused (still_deg, still_current_a, hal_stale_s 0.005; the review of 2026-11-25;
    hal_stale_s's minimum is 0.02 since 2026-11-27, two of ANALOG_IN's periods).
    A value that misses an end only by that rounding is the end; one below it, by more, is still refused."""
    for name, end in (("still_deg", 0.01), ("still_current_a", 0.01), ("hal_stale_s", 0.02), ("still_deg", 30.0)):
        done = bench.call(M["ParamSet"](name, end))
        assert done.ok, (name, end, done.reason)
        assert bench.controller.params[name] == end                         # the end itself, not its f32
    assert bench.call(M["ParamSet"]("still_deg", 0.0099)).reason is Reason.OUT_OF_RANGE
    store = ParamStore([ParamSpec("x", 1.0, 0.01, 2.0, "", "a test")])
    assert store.set("x", 0.009999999776482582)[0] is Reason.OK and store["x"] == 0.01
    assert store.set("x", 0.00999)[0] is Reason.OUT_OF_RANGE and store["x"] == 0.01


def test_link_timeout_parameter_applies_to_the_watchdog(tmp_path):
    bench = LockstepBench(seed=3, controller_config=ControllerConfig(params_path=tmp_path / "p.json"))
    try:
        assert bench.connect()
        assert bench.call(M["ParamSet"]("link_timeout_s", 10.0)).ok
        bench.host_alive = False
        bench.run_for(5.0)
        assert bench.controller.supervisor.state is ControllerState.IDLE     # 3 s would have tripped
        bench.run_for(6.0)
        assert bench.controller.supervisor.faults & Fault.LINK_LOST
    finally:
        bench.close()


@pytest.mark.parametrize("kind, problem", [
    ("fifo", "a FIFO (named pipe), not a regular file"),     # nobody writes to it: a plain open would hang
    ("device", "a character device, not a regular file"),   # /dev/zero: a plain read would never end
    ("large", "larger than 256 KiB"),
])
def test_a_path_that_is_no_parameter_file_is_not_read_and_defaults_stay(tmp_path, kind, problem):
    from firmware_py.params import PARAMS_FILE_LIMIT
    path = tmp_path / "p.json"
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "device":
        path = "/dev/zero"
    else:
        path.write_text(json.dumps({"version": 1, "params": {"gain": 4.0}}) + " " * PARAMS_FILE_LIMIT)
    store = ParamStore(SPECS, path)
    problems = store.load()
    assert len(problems) == 1 and problem in problems[0] and "keep their defaults" in problems[0]
    assert store["gain"] == 1.0


def test_a_missing_file_means_defaults_without_a_problem(tmp_path):
    store = ParamStore(SPECS, tmp_path / "absent.json")
    assert store.load() == [] and store["gain"] == 1.0


def test_every_parameter_at_either_end_of_its_range_is_taken_or_refused_and_the_controller_runs_on(bench):
    """A ParamSet in range must never crash the controller. The fuzz campaign's controller-link target (its
    grammar naming real parameters since 8fd1c39) found `j1_kv 0`: the anti-windup time constant kv/ki became
    0 and the axis' reconfigure divided by it (ZeroDivisionError, the whole firmware down, from one command).
    Each parameter is set to each end of its declared range over the link with the outputs enabled, the loops run
    on with it, and it is set back (a fault that the value itself implies, a current limit of 0.1 A say, is reset)."""
    params = bench.controller.params
    defaults = params.values()
    assert bench.call(M["Enable"]()).ok
    for name in params.order:
        spec = params.specs[name]
        for end in (spec.lo, spec.hi):
            done = bench.call(M["ParamSet"](name, end))
            assert done.outcome is not None and done.reason in (Reason.OK, Reason.OUT_OF_RANGE), (name, end, done)
            bench.run_for(0.05)
            assert bench.call(M["ParamSet"](name, defaults[name])).ok, (name, "set back")
            if bench.controller.supervisor.state is not ControllerState.ENABLED:
                bench.run_for(0.5)
                assert bench.call(M["Reset"]()).ok and bench.call(M["Enable"]()).ok, (name, end)
    assert bench.call(M["Ping"](7)).reply.token == 7


def test_a_joint_with_no_velocity_gain_moves_without_dividing_by_zero(bench):
    """kv = 0 (in range: an integral-only velocity loop) leaves the anti-windup a time constant of one tick."""
    assert bench.call(M["ParamSet"]("j2_kv", 0.0)).ok
    joint = bench.controller.arm.joints["j2"]
    assert joint.config.tracking_s == joint.config.estimator.dt_s
    assert bench.call(M["Enable"]()).ok
    start = joint.pos_rad
    assert bench.call(M["MoveBy"](1, 1.0, 0.0)).ok           # axis 1: j2
    bench.run_for(1.5)
    assert bench.call(M["Ping"](8)).reply.token == 8
    assert abs(joint.pos_rad - start) > 0.01 and joint.mode.name == "HOLDING"
    assert bench.controller.supervisor.state is ControllerState.ENABLED


def test_a_saved_consistent_set_comes_back_whole_after_a_reboot(tmp_path):
    """The file is loaded in passes: a value the veto refuses against its partner's default (a deadband below the
    default hysteresis, a minimum above the default maximum) is taken once the file's own partner is in. One pass in
    table order kept the defaults for them, and said so only in load_problems (an attack on 2026-11-27)."""
    path = tmp_path / "params.json"
    chosen = (("trk_hyst_mv", 0.5), ("trk_deadband_mv", 1.0), ("j1_max_deg", 200.0), ("j1_min_deg", 150.0))
    first = LockstepBench(seed=1, controller_config=ControllerConfig(params_path=path))
    try:
        assert first.connect()
        for name, value in chosen:
            assert first.call(M["ParamSet"](name, value)).ok, name
        assert first.call(M["ParamSave"]()).ok
    finally:
        first.close()
    rebooted = LockstepBench(seed=1, controller_config=ControllerConfig(params_path=path))
    try:
        params = rebooted.controller.params
        assert params.load_problems == []
        assert {name: params[name] for name, _ in chosen} == dict(chosen)
    finally:
        rebooted.close()


def test_pairs_that_would_switch_a_fault_off_or_latch_one_for_good_are_refused(bench):
    """A lateness warning at or past its fault's level (the fault was never reached), a minimum temperature above
    the maximum (OVER_TEMPERATURE for good), a fractional telemetry rate (cut to 0 Hz at boot): refused, and
    nothing changes."""
    for name, value in (("loop_late_warn_s", 0.1), ("loop_late_max_s", 0.01), ("temp_min_c", 45.0),
                        ("temp_max_c", -10.0), ("telemetry_hz", 0.5)):
        before = bench.controller.params.values()
        done = bench.call(M["ParamSet"](name, value))
        assert done.reason is Reason.OUT_OF_RANGE, (name, value, done.reason)
        assert bench.controller.params.values() == before
    assert bench.call(M["ParamSet"]("loop_late_warn_s", 0.05)).ok
    assert bench.call(M["ParamSet"]("telemetry_hz", 20.0)).ok


def test_a_joints_speed_and_acceleration_do_not_change_under_a_motion_planned_with_them(bench):
    """A running profile keeps the limits it was planned with: a lower speed set mid-move let the loop's clamp
    hold the joint back until FOLLOWING_ERROR, and a lower acceleration made a jog's stop at the soft limit take
    minutes, past the limit into the hard stop (an attack on 2026-11-27). Refused BUSY while the joint moves (its
    gains and the other joints' limits are not), taken once it holds."""
    assert bench.call(M["Enable"]()).ok
    assert bench.call(M["MoveBy"](0, 5.0, 0.0)).ok
    bench.run_for(0.3)
    for name in ("j1_speed_dps", "j1_acc_dps2"):
        done = bench.call(M["ParamSet"](name, 0.5))
        assert done.reason is Reason.BUSY, (name, done.reason)
        assert bench.controller.params[name] != 0.5
    assert bench.call(M["ParamSet"]("j2_speed_dps", 2.0)).ok
    assert bench.call(M["ParamSet"]("j1_kp", bench.controller.params["j1_kp"])).ok
    bench.run_for(3.0)
    assert bench.controller.supervisor.state is ControllerState.ENABLED
    assert bench.controller.arm.joints["j1"].mode.name == "HOLDING"
    assert bench.call(M["ParamSet"]("j1_speed_dps", 0.5)).ok


def test_a_number_too_large_for_a_float_is_refused_not_raised(tmp_path):
    """JSON has integers of any size: one of 400 digits raised OverflowError out of a load that never raises (the
    review of 2026-11-27); now it is out of range, like any other, and the default stays."""
    path = tmp_path / "p.json"
    path.write_text('{"version": 1, "params": {"gain": 1' + "0" * 400 + ', "limit_v": 30}}')
    store = ParamStore(SPECS, path)
    problems = store.load()
    assert len(problems) == 1 and "gain: a whole number of 401 digits, outside 0.0..10.0" in problems[0], problems
    assert store["gain"] == 1.0 and store["limit_v"] == 30.0
    assert store.set("gain", 10**400)[0] is Reason.OUT_OF_RANGE
