"""On the wall clock (real hardware) the controller judges real time: stale inputs by their parameters,
a late loop by name (SCHEDULER_OVERRUN, HOST_OVERLOADED), never as a hardware fault.

The world runs on a simulated clock that says it is the wall clock (`WallLike`), so that a stall
of the host is a jump of it the tests make on purpose: everything else is the real controller.
"""
from __future__ import annotations

import pytest

from firmware_py.axis import AxisError
from firmware_py.estimator import EstimatorConfig, SteadyStateEstimator
from host_tools.worlds.world import LockstepBench
from host_tools.worlds.settings import PlantSettings
from protocol.hal import BusView, HalCodec
from protocol.messages import MESSAGES as M
from protocol.reasons import Reason
from protocol.states import Axis, ControllerState, Fault, FaultCause, TimingIssue
from timebase import SimClock, TimingReport


class WallLike(SimClock):
    """A simulated clock that reports itself as the wall clock: the controller judges lateness on it."""

    def timing(self) -> TimingReport:
        return TimingReport("realtime", 1.0, 1.0)


def stalled_bench(stall_s: float, at_s: float) -> LockstepBench:
    """A bench whose controller stalls once for `stall_s` at `at_s`, as a descheduled process would.

    The plant is real hardware here: it goes on ticking during the stall (its frames wait in the
    bus's queue for the controller), so the time passes one plant tick at a time.
    """
    clock = WallLike()
    bench = LockstepBench(clock=clock, plant=PlantSettings(tracker=False))
    plant = bench.world.plant_node
    stalls = [at_s]

    def hog(now: float):
        if stalls and now >= stalls[0]:
            stalls.clear()
            for _ in range(round(stall_s / plant.period_s)):
                clock.advance_by(plant.period_s)
                plant.step(clock.now())
        return now + 0.001
    bench.world.scheduler.add("hog", hog, priority=20)
    assert bench.connect()
    return bench


def reports(bench, name: str) -> list:
    return [e for e in bench.events if e.spec.name == name]


def test_a_loop_late_beyond_loop_late_max_s_while_enabled_is_scheduler_overrun_by_name():
    bench = stalled_bench(0.3, at_s=1.0)
    assert bench.call(M["Enable"]()).ok
    assert bench.wait_until(lambda: bench.controller.supervisor.state is ControllerState.FAULT, 3.0)
    sup = bench.controller.supervisor
    assert sup.faults == Fault.SCHEDULER_OVERRUN and sup.safe_reason is Reason.HOST_OVERLOADED
    bench.run_for(0.2)
    report = reports(bench, "FaultReport")[0]
    assert report.cause == FaultCause.LOOP_LATE and report.reason == Reason.HOST_OVERLOADED
    assert report.value_ms == pytest.approx(300.0, abs=2.0) and report.limit_ms == pytest.approx(100.0)
    assert "overloaded" in Reason.HOST_OVERLOADED.doc and "encoder" not in Reason.HOST_OVERLOADED.remedy
    assert bench.call(M["Reset"]()).ok         # nothing is still present: the host is fine again


@pytest.mark.parametrize("stall_s", [0.15, 0.3])
def test_a_loop_too_late_while_moving_latches_scheduler_overrun_and_nothing_else(stall_s):
    """The arm moved on during the stall; the estimators are told even when the late tick faults,
    so the next count is not taken for an encoder glitch (an ENCODER fault beside the overrun)."""
    bench = stalled_bench(stall_s, at_s=1.0)
    assert bench.call(M["Enable"]()).ok
    assert bench.call(M["MoveBy"](int(Axis.J1), 30.0, 0)).ok
    assert bench.wait_until(lambda: bench.controller.supervisor.state is ControllerState.FAULT, 3.0)
    bench.run_for(0.5)
    sup = bench.controller.supervisor
    assert sup.faults == Fault.SCHEDULER_OVERRUN, repr(Fault(sup.faults))
    assert [r.reason for r in reports(bench, "FaultReport")] == [Reason.HOST_OVERLOADED]


def test_a_late_loop_while_idle_or_below_the_limit_warns_and_faults_nothing():
    bench = stalled_bench(0.3, at_s=1.0)       # idle: nothing is driven, so a late loop harms nothing
    bench.run_for(2.0)
    assert bench.controller.supervisor.state is ControllerState.IDLE and not bench.controller.supervisor.faults
    warning = reports(bench, "TimingWarning")[0]
    assert warning.issue == TimingIssue.LOOP_LATE and warning.value == pytest.approx(0.3, abs=0.002)
    bench = stalled_bench(0.03, at_s=1.0)      # enabled and moving, 30 ms late: a warning only
    assert bench.call(M["Enable"]()).ok
    motion = bench.call(M["MoveBy"](int(Axis.J1), 2.0, 0)).reply.motion_id
    done = lambda: [e for e in reports(bench, "MotionDone") if e.motion_id == motion]  # noqa: E731
    assert bench.wait_until(lambda: bool(done()), 10.0)
    assert done()[0].reason == Reason.OK and not bench.controller.supervisor.faults
    assert [w.issue for w in reports(bench, "TimingWarning")] == [TimingIssue.LOOP_LATE]


def test_a_simulated_world_never_judges_lateness():
    bench = LockstepBench(plant=PlantSettings(tracker=False))
    assert not bench.controller.arm.judge_lateness
    bench = stalled_bench(0.01, at_s=0.5)
    assert bench.controller.arm.judge_lateness


class LoseFrames(BusView):
    """The controller's end of the bus, losing every frame `name` (MOTOR_FB) once `lost` is set (a broken bus,
    say)."""

    def __init__(self, bus, name: str = "MOTOR_FB") -> None:
        super().__init__(bus)
        self.lost = False
        self.frame_id = HalCodec().frame_id(name)

    def recv(self, timeout=None):
        while True:
            msg = self.bus.recv(timeout)
            if msg is None or not (self.lost and msg.arbitration_id == self.frame_id):
                return msg


def test_stale_encoder_counts_fault_by_their_own_parameter_and_say_how_old():
    bench = LockstepBench(plant=PlantSettings(tracker=False))
    hal = bench.controller.hal
    hal.bus = LoseFrames(hal.bus)
    assert bench.connect() and bench.call(M["Enable"]()).ok
    assert bench.call(M["ParamSet"]("encoder_stale_s", 0.02)).ok
    hal.bus.lost = True
    assert bench.wait_until(lambda: bench.controller.supervisor.state is ControllerState.FAULT, 1.0)
    assert bench.controller.supervisor.safe_reason is Reason.ENCODER_STALE
    bench.run_for(0.1)
    report = reports(bench, "FaultReport")[0]
    assert (report.cause, report.axis, report.reason) == (FaultCause.ENCODER_AGE, int(Axis.J1), Reason.ENCODER_STALE)
    assert report.fault == Fault.HAL_STALE
    assert report.limit_ms == pytest.approx(20.0) and 20.0 <= report.value_ms <= 22.0
    assert "encoder_stale_s" in Reason.ENCODER_STALE.remedy


def test_ticks_the_loop_missed_widen_the_glitch_check_instead_of_faulting():
    config = EstimatorConfig(rad_per_count=1e-4, dt_s=0.001, max_vel_rad_s=1.0, max_acc_rad_s2=2.0)
    moving = SteadyStateEstimator(config)
    moving.update(0)
    # 30 ms of motion at 0.8 rad/s is 240 counts: a glitch for one tick (at most 10 + margin) ...
    glitchy = SteadyStateEstimator(config)
    glitchy.update(0)
    assert glitchy.update(240) & 2
    # ... but not once the estimator knows that 29 ticks went by unseen
    moving.skip(29)
    assert moving.update(240) == 0 and AxisError.ENCODER_GLITCH


def test_stale_currents_fault_by_current_stale_s_when_it_is_the_tighter_limit():
    bench = LockstepBench(plant=PlantSettings(tracker=False))
    hal = bench.controller.hal
    hal.bus = LoseFrames(hal.bus)
    assert bench.connect() and bench.call(M["Enable"]()).ok
    assert bench.call(M["ParamSet"]("encoder_stale_s", 0.5)).ok and bench.call(M["ParamSet"]("current_stale_s", 0.03)).ok
    hal.bus.lost = True
    assert bench.wait_until(lambda: bench.controller.supervisor.state is ControllerState.FAULT, 1.0)
    assert bench.controller.supervisor.safe_reason is Reason.CURRENT_STALE
    bench.run_for(0.1)
    report = reports(bench, "FaultReport")[0]
    assert (report.cause, report.reason, report.fault) == (FaultCause.CURRENT_AGE, Reason.CURRENT_STALE, Fault.HAL_STALE)
    assert report.limit_ms == pytest.approx(30.0) and 30.0 <= report.value_ms <= 32.0
