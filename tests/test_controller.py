"""The controller skeleton in a lock-step world: supervisor, safe state, faults, telemetry."""
from __future__ import annotations

from dataclasses import replace

import pytest

from firmware_py.controller import ControllerConfig
from hil_sim.plant import PlantParams
from host_tools.teleop.format import describe_report
from host_tools.worlds.world import LockstepBench
from protocol.line import TELEMETRY_LINE_SHARE, max_telemetry_hz, telemetry_bytes_per_s
from protocol.link import LinkConfig
from protocol.messages import MESSAGES as M, SCHEMA
from protocol.reasons import Reason
from protocol.states import ControllerState, Fault, FaultCause, Switch, SwitchPosition, TrackerAxis


def status(bench):
    handle = bench.call(M["GetStatus"]())
    assert handle.ok, handle.describe()
    return handle.reply


def test_boots_to_idle_and_enables(bench):
    assert status(bench).state == ControllerState.IDLE
    assert bench.call(M["Enable"]()).ok
    assert status(bench).state == ControllerState.ENABLED
    assert bench.wait_until(lambda: bench.world.plant.outputs_enabled, 0.1)   # the plant sees it over CAN
    assert bench.call(M["Disable"]()).ok
    assert bench.wait_until(lambda: not bench.world.plant.outputs_enabled, 0.1)


def test_estop_takes_the_one_path_to_the_safe_state_and_latches_until_reset(bench):
    assert bench.call(M["Enable"]()).ok
    assert bench.wait_until(lambda: bench.world.plant.outputs_enabled, 0.1)
    assert bench.call(M["EStop"]()).ok
    assert not bench.world.plant.outputs_enabled and bench.world.plant.brake
    reply = status(bench)
    assert reply.state == ControllerState.ESTOP and reply.faults & Fault.ESTOP
    refused = bench.call(M["Enable"]())
    assert refused.reason is Reason.ESTOP            # refused with a reason, nothing changed
    bench.run_for(1.0)
    assert not bench.world.plant.outputs_enabled
    assert bench.call(M["Reset"]()).ok
    assert status(bench).state == ControllerState.IDLE
    names = [ControllerState(e.state).name for e in bench.events]
    assert names[-2:] == ["ESTOP", "IDLE"]


def test_link_loss_reaches_the_safe_state_within_the_timeout():
    config = ControllerConfig(link=LinkConfig(link_timeout_s=0.5, heartbeat_s=0.1))
    bench = LockstepBench(seed=2, controller_config=config)
    try:
        assert bench.connect()
        assert bench.call(M["Enable"]()).ok
        lost_at = bench.clock.now()
        bench.host_alive = False
        assert bench.wait_until(lambda: bench.controller.supervisor.state is ControllerState.FAULT, 0.6)
        faulted_at = bench.clock.now()
        last_frame_at = bench.controller.link.last_valid_rx_s
        assert last_frame_at <= lost_at
        assert 0.5 <= faulted_at - last_frame_at <= 0.52     # the timeout counts from the last valid frame
        assert faulted_at - lost_at <= 0.52
        assert bench.controller.supervisor.faults & Fault.LINK_LOST
        assert bench.wait_until(lambda: not bench.world.plant.outputs_enabled, 0.01)
        bench.run_for(5.0)                             # stays there: latched, no telemetry into the void
        assert bench.controller.supervisor.state is ControllerState.FAULT
        bench.host_alive = True
        bench.host.connect(bench.clock.now())          # the host comes back, the fault is still latched
        assert bench.wait_until(lambda: bench.host.state.value == "up", 5.0)
        assert status(bench).faults & Fault.LINK_LOST
        assert bench.call(M["Reset"]()).ok
        assert status(bench).state == ControllerState.IDLE
        # the fault event of the lost session is delivered in the new one
        assert any(e.spec.name == "StateChanged" and e.reason == Reason.LINK_TIMEOUT for e in bench.events)
        # ... with what was measured: the silence, against the link timeout
        report = next(e for e in bench.events if e.spec.name == "FaultReport")
        assert (report.fault, report.reason, report.cause) == (Fault.LINK_LOST, Reason.LINK_TIMEOUT,
                                                               FaultCause.LINK_SILENCE)
        assert report.limit_ms == 500.0 and 500.0 < report.value_ms <= 520.0
        assert "no valid frame from the host" in describe_report(report)
    finally:
        bench.close()


def test_supply_sag_faults_and_reset_is_refused_while_it_lasts(bench):
    bench.world.plant.inject("supply_sag")
    assert bench.wait_until(lambda: bench.controller.supervisor.state is ControllerState.FAULT, 0.1)
    assert bench.controller.supervisor.faults & Fault.SUPPLY_LOW
    assert bench.call(M["Reset"]()).reason is Reason.SUPPLY_LOW
    bench.world.plant.clear("supply_sag")
    bench.run_for(0.05)
    assert bench.call(M["Reset"]()).ok


def test_over_temperature_reaches_the_safe_state():
    # The default box (time constant 300 s) would cross 45 C about 242 s after the fault; this one
    # has a tenth of its thermal capacity (30 s, everything else the same), so it heats ten times
    # faster and the bound is a tenth of 400 s.
    scale = 10.0
    default = PlantParams()
    bench = LockstepBench(seed=4, plant_params=replace(
        default, thermal_capacity_j_per_c=default.thermal_capacity_j_per_c / scale))
    try:
        assert bench.connect()
        bench.call(M["SetTelemetryRate"](1))
        bench.world.plant.inject("over_temperature")
        assert bench.wait_until(lambda: bench.controller.supervisor.state is ControllerState.FAULT, 400 / scale)
        assert bench.controller.supervisor.faults & Fault.OVER_TEMPERATURE
        assert bench.world.plant.temp_c > 44.5
    finally:
        bench.close()


def test_hal_silence_is_a_fault(bench):
    bench.world.scheduler.remove("plant")   # the plant stops talking on the bus
    assert bench.wait_until(lambda: bench.controller.supervisor.state is ControllerState.FAULT, 0.5)
    assert bench.controller.supervisor.faults & Fault.HAL_STALE


def test_telemetry_rate_is_set_over_the_link(bench):
    def count(name):
        return sum(1 for m in bench.telemetry if m.spec.name == name)
    # 30 Hz, the most a 115200-baud line carries (protocol/line.py): TelemetryStatus (96 B on the wire) and
    # TelemetryJoints (154 B) take 7.5 kB/s, with TelemetryTracker's 10 Hz (158 B) 9.08 kB/s, within the 80 % of the
    # line's 11.52 kB/s telemetry may take
    assert bench.call(M["SetTelemetryRate"](30)).ok
    start, start_joints = count("TelemetryStatus"), count("TelemetryJoints")
    bench.run_for(1.0)
    assert 27 <= count("TelemetryStatus") - start <= 31
    assert 27 <= count("TelemetryJoints") - start_joints <= 31   # the arm's, at the same rate
    assert bench.call(M["SetTelemetryRate"](0)).ok
    start = len(bench.telemetry)
    bench.run_for(1.0)
    assert len(bench.telemetry) - start <= 2
    refused = bench.call(M["SetTelemetryRate"](201))
    assert refused.reason is Reason.OUT_OF_RANGE and "rate_hz=201" in refused.detail   # refused by the host


@pytest.mark.parametrize("baud, most", [(9600, 1), (115200, 30), (460800, 141)])
def test_a_telemetry_rate_the_line_cannot_carry_is_refused(baud, most):
    """docs/protocol.md, "Line timing": rate_hz counts each kind of telemetry message; a rate whose frames need more
    than TELEMETRY_LINE_SHARE of the line at the controller's baud is refused OUT_OF_RANGE, the rate unchanged."""
    assert max_telemetry_hz(baud) == most
    assert telemetry_bytes_per_s(most) <= baud / 10 * TELEMETRY_LINE_SHARE < telemetry_bytes_per_s(most + 1)
    bench = LockstepBench(seed=5, baud=baud)
    try:
        assert bench.connect()
        assert bench.controller.max_telemetry_hz == most
        refused = bench.call(M["SetTelemetryRate"](most + 1))
        assert refused.reason is Reason.OUT_OF_RANGE and refused.reply.spec.name == "Result"
        assert bench.controller.telemetry_hz == int(bench.controller.params["telemetry_hz"])
        assert bench.call(M["SetTelemetryRate"](most)).ok and bench.controller.telemetry_hz == most
    finally:
        bench.close()


def test_an_unpaced_line_has_no_telemetry_limit():
    bench = LockstepBench(seed=5, paced=False)
    try:
        assert bench.connect()
        assert bench.controller.max_telemetry_hz is None
        assert bench.call(M["SetTelemetryRate"](200)).ok and bench.controller.telemetry_hz == 200
    finally:
        bench.close()


def test_the_controller_refuses_out_of_range_values_that_reach_the_wire(bench):
    # a host that skips the range check (here: the sender's raw submit) gets a reason, and nothing changes
    from protocol.host_link import CommandHandle
    handle = CommandHandle(M["SetTelemetryRate"](10), bench.clock.now())
    bench.host._commands.submit(SCHEMA["SetTelemetryRate"].id, (500).to_bytes(2, "little"), handle)
    bench.wait_until(lambda: handle.done, 1.0)
    assert handle.reason is Reason.OUT_OF_RANGE
    assert bench.controller.telemetry_hz == 10
    assert bench.call(M["Ping"](1)).ok       # and the channel goes on


def test_same_seed_same_bytes():
    def run(seed):
        b = LockstepBench(seed=seed)
        captured = bytearray()
        feed = b.host.feed
        b.host.feed = lambda data, now: (captured.extend(data), feed(data, now))
        b.connect()
        b.call(M["Enable"]())
        b.world.plant.inject("supply_sag")
        b.run_for(2.0)
        b.close()
        return bytes(captured)
    assert run(7) == run(7)
    assert run(7) != run(8)


def _next_telemetry(bench, name: str, timeout_s: float = 1.0):
    """The next frame of telemetry `name` the host receives from now."""
    seen = len(bench.telemetry)
    assert bench.wait_until(lambda: any(m.spec.name == name for m in bench.telemetry[seen:]), timeout_s)
    return next(m for m in bench.telemetry[seen:] if m.spec.name == name)


def test_telemetry_values_are_each_in_their_field_and_a_change_is_in_the_next_frame(bench):
    """The telemetry messages are built from their values in the message's order (no dict of names: issue 35), and
    nothing is kept from one run to the next: each value read by its field's name is the controller's own, and a
    change between two frames (a tracker's switch, a supply sag, a task added to the scheduler that overruns) is in
    the next one."""
    from firmware_py.arm import GRIPPER_INDEX
    ctrl = bench.controller
    main_on, sensor_on = (M["BoxSwitch"](int(which), int(SwitchPosition.ON), int(TrackerAxis.BOTH))
                          for which in (Switch.MAIN, Switch.SENSOR))
    for msg in (main_on, M["SetTelemetryRate"](20), M["Enable"]()):      # main power on: the box is in use
        assert bench.call(msg).ok
    bench.run_for(0.3)
    now = bench.clock.now()
    status, joints, tracker = ctrl.telemetry(now), ctrl.joint_telemetry(now), ctrl.tracker_telemetry(now)
    sup, inputs, arm, box, axes = ctrl.supervisor, ctrl.hal.inputs, ctrl.arm, ctrl.tracker.box, ctrl.tracker.axes
    assert (status.state, status.faults, status.supply_v, status.temp_c, status.frames_rx, status.commands_executed) \
        == (sup.state, sup.faults, inputs.supply_v, inputs.temp_c, ctrl.link.stats.frames_rx,
            ctrl.link.commands_executed)
    assert status.overruns == sum(t.stats.overruns for t in ctrl.scheduler.tasks.values())
    assert status.timing == 0 and status.uptime_ms == ctrl.uptime_ms(now)        # a simulated clock
    assert (joints.homed, joints.j3_mode, joints.gripper_mode, joints.arm_period_us) == (
        arm.homed_bits(), int(arm.channels[2].mode), int(arm.channels[GRIPPER_INDEX].mode), 1000)
    assert (joints.j1_pos, joints.j2_vel, joints.mount_current) == (
        arm.position(0), arm.velocity(1), inputs.currents_a[-1])
    assert (tracker.main, tracker.sensor, tracker.dial_el, tracker.angle_az, tracker.angle_el) == (
        int(box.main), int(box.sensor), box.dial_pct(1), inputs.tracker_angles_deg[0], inputs.tracker_angles_deg[1])
    assert (tracker.brake_el, tracker.duty_az, tracker.switchings_el, tracker.reversals_az) == (
        axes[1].brake, axes[0].duty, axes[1].switchings, axes[0].reversals)
    # a change between two frames is in the next one
    assert _next_telemetry(bench, "TelemetryTracker").sensor == 0
    assert bench.call(sensor_on).ok
    assert _next_telemetry(bench, "TelemetryTracker").sensor == 1
    before = _next_telemetry(bench, "TelemetryStatus")
    late = bench.world.scheduler.add("late", lambda now: now + 0.001, bench.clock.now() - 1.0, tolerance_s=0.0)
    bench.world.plant.inject("supply_sag")
    after = _next_telemetry(bench, "TelemetryStatus", 0.2)
    assert late.stats.overruns >= 1 and after.overruns - before.overruns >= late.stats.overruns
    assert after.supply_v < before.supply_v
