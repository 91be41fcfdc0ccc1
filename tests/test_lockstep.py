"""Lock-step over the HAL bus (protocol/lockstep.py): plant and controller share one time, tick by tick.

Here both run in one thread on an in-process bus pair, each on its own scheduler and lock-step
clock as in their own processes (`aspod plant`, `aspod firmware`), stepped in turn and never
blocking; the wall clock is a `SimClock` moved by hand. The same clocks between real processes
over udp_multicast are tested in tests/test_separate_processes.py.
"""
from __future__ import annotations

import math

import can
import pytest

from firmware_py.controller import ControllerConfig
from timebase.scheduler import Scheduler
from firmware_py.uart import PacedUart
from host_tools.worlds.ports import BufferPort
from host_tools.worlds.settings import PlantSettings
from host_tools.worlds.local_bus import LocalBus, open_local_pair
from host_tools.worlds.nodes import build_controller, build_plant_node
from protocol.hal import BusView, HalCodec
from protocol.lockstep import (MAX_SYNC_GAP_TICKS, REOFFER_S, BurstWatch, ControllersWatch, LockstepFollower,
                               LockstepLeader, PlantsWatch)
from protocol.messages import MESSAGES as M
from protocol.reasons import Reason
from protocol.states import Axis, ControllerState, Fault, FaultCause, MotionOutcome
from timebase import PacedClock, SimClock

KEY = b"lockstep-test-key-0123456789"
CTRL_SYNC_ID = HalCodec().frame_id("CTRL_SYNC")


class DropFrames(BusView):
    """Loses the next `count` frames with id `frame_id` that this end sends."""

    def __init__(self, bus, frame_id: int) -> None:
        super().__init__(bus)
        self.frame_id, self.count, self.dropped = frame_id, 0, 0

    def send(self, msg: can.Message, timeout=None) -> None:
        if msg.arbitration_id == self.frame_id and self.count:
            self.count -= 1
            self.dropped += 1
            return
        self.bus.send(msg, timeout)


_open_pairs: list["Pair"] = []


@pytest.fixture(autouse=True)
def _close_pairs():
    """Every Pair a test made has its bus shut down after it."""
    yield
    while _open_pairs:
        _open_pairs.pop().close()


class Pair:
    """A lock-step plant (as fast as it goes) and controller, stepped in turn in one thread."""

    def __init__(self, seed: int = 1, controller: bool = True, first_tick: int = 0, speed: float = math.inf,
                 judge=None) -> None:
        self.wall = SimClock(1000.0)
        self.speed = speed
        self.plant_bus, self._controller_end = open_local_pair()
        _open_pairs.append(self)
        self.start_plant(seed, first_tick)
        self.control = None
        self.judge = judge
        if controller:
            self.start_controller()

    def start_controller(self) -> None:
        self.controller_bus = DropFrames(self._controller_end, CTRL_SYNC_ID)
        self.follower = LockstepFollower(self.controller_bus, self.wall, speed=self.speed, judge=self.judge)
        self.controller = build_controller(KEY, PacedUart(BufferPort(notifies=False)), self.follower.tap,
                                           ControllerConfig())
        self.control = Scheduler(self.follower, stopwatch=self.follower.now)
        self.link = Scheduler(self.wall)
        self.controller.attach(self.control, self.link)

    def start_plant(self, seed: int, first_tick: int = 0) -> None:
        """A plant on the bus (a new one, counting its ticks from `first_tick`, if there was one already)."""
        self.leader = LockstepLeader(self.plant_bus, PacedClock(self.wall, self.speed, start_s=first_tick * 0.001),
                                     0.001, reoffer=lambda: self.node.resend_sync())
        self.leader.controller_tick = first_tick      # its first tick is free, as tick 0 is
        self.node = build_plant_node(self.leader.tap, seed, settings=PlantSettings(tracker=False), lockstep=True)
        self.node.tick = first_tick
        self.plant = Scheduler(self.leader, stopwatch=self.leader.now)
        self.plant.add("plant", self.node.step, period_s=self.node.period_s)

    def turn(self, plant: bool = True) -> None:
        """One pass of each process's loop (`run_live`), returning at once where it would wait."""
        sides = ([(self.plant, None)] if plant else []) + ([(self.control, self.link)] if self.control else [])
        for scheduler, link in sides:
            if link is not None:
                link.run_due()
            scheduler.run_due()
            scheduler.clock.advance(scheduler.next_wake_s(), self.wall.now())

    def run_until(self, predicate, turns: int = 100_000) -> bool:
        for _ in range(turns):
            if predicate():
                return True
            self.turn()
        return predicate()

    def execute(self, msg):
        return self.controller._execute(msg, False, self.wall.now())

    def close(self) -> None:
        self.plant_bus.shutdown()
        self._controller_end.shutdown()


def test_the_controller_runs_each_tick_on_the_plant_tick_before_it_and_nothing_runs_ahead():
    pair = Pair()
    assert pair.follower.now() == 0.0 and pair.node.tick == 0
    pair.turn()
    assert pair.node.tick == 1                        # tick 0 needs no answer ...
    for _ in range(5):
        pair.turn(plant=True)
    assert pair.run_until(lambda: pair.node.tick >= 2000)
    # ... every later tick waited for the controller: one motor loop per plant tick, in step
    arm_runs = pair.control.tasks["arm"].stats.runs
    assert pair.node.tick - 1 <= arm_runs <= pair.node.tick
    assert pair.follower.now() == pytest.approx((pair.node.tick - 1) * 0.001, abs=0.0015)
    assert pair.controller.supervisor.state is ControllerState.IDLE and not pair.controller.supervisor.faults
    assert pair.follower.timing().mode == "lockstep" and pair.leader.timing().mode == "lockstep"


def test_a_plant_paced_at_the_slow_speed_asked_is_neither_slow_nor_lagging_to_its_controller():
    """`aspod sim --hal ... --speed 0.01`: the controller knows the pace asked (LockstepFollower's speed)."""
    pair = Pair(speed=0.01)
    reports = []
    pair.controller.report_listeners.append(reports.append)
    for _ in range(2000):                    # 20 wall seconds, 10 ms a turn: 0.2 simulated
        pair.wall.advance_by(0.01)
        pair.turn()
    timing = pair.follower.timing()
    assert timing.speed == 0.01 and timing.rtf_recent == pytest.approx(0.01, rel=0.1) and timing.lag_s < 0.1
    assert not [r for r in reports if r.spec.name == "TimingWarning"], reports


def test_a_move_in_lock_step_ends_done_and_is_the_same_to_the_bit_whatever_the_wall_clock_does():
    def move(stall_every: int) -> tuple:
        pair = Pair(seed=3)
        assert pair.run_until(lambda: pair.controller.supervisor.state is ControllerState.IDLE)
        assert pair.execute(M["Enable"]()).result == Reason.OK
        accepted = pair.execute(M["MoveBy"](int(Axis.J1), 5.0, 0))
        assert accepted.result == Reason.OK
        axis = pair.controller.arm.channels[int(Axis.J1)]
        turns = 0

        def done() -> bool:
            nonlocal turns
            turns += 1
            if stall_every and turns % stall_every == 0:
                pair.wall.advance_by(0.25)           # a process descheduled for a quarter of a second
            return axis.outcome is not MotionOutcome.RUNNING
        assert pair.run_until(done, 200_000)
        assert axis.outcome is MotionOutcome.DONE and not pair.controller.supervisor.faults
        return pair.node.tick, tuple(pair.node.plant.arm.pos_rad)
    assert move(stall_every=0) == move(stall_every=997)


def test_a_lost_ctrl_sync_costs_a_re_offer_not_the_run():
    pair = Pair()
    assert pair.run_until(lambda: pair.node.tick >= 50)
    pair.controller_bus.count = 1                   # the controller's next CTRL_SYNC is lost
    for _ in range(20):
        pair.turn()
    stuck = pair.node.tick
    assert pair.controller_bus.dropped == 1 and pair.leader.stalled_s() == 0.0
    for _ in range(20):
        pair.turn()
    assert pair.node.tick == stuck                  # the plant waits: it never runs ahead
    pair.wall.advance_by(REOFFER_S)                 # ... and after 0.1 s (wall) offers its tick again
    assert pair.run_until(lambda: pair.node.tick >= stuck + 100)
    assert pair.node.sync_resends >= 1 and pair.follower.syncs_sent > stuck


def test_a_controller_started_after_the_plant_picks_it_up_at_once():
    pair = Pair(controller=False)
    for _ in range(30):                             # the plant alone: tick 0, then it waits, offering it again
        pair.wall.advance_by(0.05)
        pair.turn()
    assert pair.node.tick == 1 and pair.node.sync_resends >= 5
    pair.start_controller()                         # its CTRL_SYNC(0) makes the plant offer its tick at once:
    assert pair.run_until(lambda: pair.node.tick >= 100, 1000)   # no wall time passes here
    assert pair.follower.plant_lockstep is True


def test_a_new_plant_counting_from_zero_is_followed_and_time_goes_on():
    pair = Pair()
    assert pair.run_until(lambda: pair.node.tick >= 300)
    before = pair.follower.now()
    pair.start_plant(seed=2)                        # a new plant process on the same bus: ticks from 0 again
    assert pair.run_until(lambda: pair.node.tick >= 100)
    assert pair.follower.resyncs == 1 and pair.follower.now() > before
    assert not pair.controller.supervisor.faults


def test_a_silent_plant_is_hal_stale_after_lockstep_wait_s_on_the_wall_clock_and_says_so():
    pair = Pair()
    reports = []
    pair.controller.report_listeners.append(reports.append)
    assert pair.run_until(lambda: pair.controller.supervisor.state is ControllerState.IDLE)
    frozen = pair.follower.now()
    limit = pair.controller.params["lockstep_wait_s"]
    for _ in range(int(limit / 0.05) + 2):           # the plant is gone: only the wall clock moves
        pair.wall.advance_by(0.05)
        pair.turn(plant=False)
    assert pair.follower.now() == frozen             # its time stands still without the plant ...
    sup = pair.controller.supervisor
    assert sup.state is ControllerState.FAULT and sup.faults & Fault.HAL_STALE   # ... and the wall clock says why
    report = [r for r in reports if r.spec.name == "FaultReport"][-1]
    assert report.cause == FaultCause.PLANT_SILENT and report.value_ms >= limit * 1000 and \
        report.limit_ms == pytest.approx(limit * 1000)
    assert pair.execute(M["Reset"]()).result == Reason.HAL_STALE    # refused while the plant stays away
    pair.start_plant(seed=1)
    assert pair.run_until(lambda: pair.execute(M["Reset"]()).result == Reason.OK, 2000)


def test_the_controllers_own_start_up_is_not_the_plants_silence():
    """The wait for the plant began when the follower was built, before the controller was: at load 45-49 building it
    took seconds of wall time, and the first look of the watch found the plant silent for them (HAL_STALE at boot),
    its first PLANT_SYNC unread in the bus. The wait begins when the controller first waits for a tick."""
    pair = Pair(controller=False)
    for _ in range(5):
        pair.turn()                                   # the plant alone: tick 0, offered and offered again
    pair.start_controller()
    pair.wall.advance_by(5.0)                         # the rest of the controller's start-up, on a busy machine
    assert pair.follower.stalled_s() == 0.0
    assert pair.run_until(lambda: pair.controller.supervisor.state is ControllerState.IDLE)
    assert not pair.controller.supervisor.faults


def test_a_tick_the_bus_holds_is_not_the_plants_silence_however_late_the_controller_looks():
    """CI, beside a busy core: the plant sent its tick, but the controller, busy elsewhere or blocked, had not read it
    when its watch looked, and faulted the plant HAL_STALE for a silence that was its own. The watch first reads
    what the bus holds."""
    pair = Pair()
    assert pair.run_until(lambda: pair.controller.supervisor.state is ControllerState.IDLE)
    waits, tick = pair.follower.waits, pair.node.tick     # the controller has answered, and waits for the next tick
    for _ in range(2):                                # the plant's turn: its next tick is on the bus ...
        pair.plant.run_due()
        pair.plant.clock.advance(pair.plant.next_wake_s(), pair.wall.now())
    assert pair.node.tick == tick + 1
    pair.wall.advance_by(3 * pair.controller.params["lockstep_wait_s"])   # ... unread for three limits
    pair.link.run_due()                               # the watch looks before the controller's loop reads it
    assert not pair.controller.supervisor.faults
    assert pair.follower.stalled_s() == 0.0 and pair.follower.waits == waits


class KeptFromRunning:
    """A WaitJudge for a plant process that waits on a run queue for `kept_s` of every wait, or has gone."""

    def __init__(self) -> None:
        self.kept_s, self.gone, self.begun = 0.0, False, 0

    def begin(self) -> None:
        self.begun += 1

    def own_s(self, waited_s: float) -> float:
        return waited_s if self.gone else max(0.0, waited_s - self.kept_s)


def test_a_plant_kept_from_running_is_not_silent_and_one_gone_is_after_lockstep_wait_s():
    """At load 45-49 a live plant waited on a run queue for over 2 s and was taken for gone (HAL_STALE): the wait is
    judged on what the judge says the plant had of it, and a plant gone on the wall clock."""
    judge = KeptFromRunning()
    pair = Pair(judge=judge)
    assert pair.run_until(lambda: pair.controller.supervisor.state is ControllerState.IDLE)
    assert judge.begun > 5                            # a wait begins at every tick
    limit = pair.controller.params["lockstep_wait_s"]
    judge.kept_s = 3 * limit
    for _ in range(int(2.5 * limit / 0.05)):          # 2.5 limits of wall time, all of it on a run queue
        pair.wall.advance_by(0.05)
        pair.turn(plant=False)
    assert pair.follower.stalled_s() == 0.0 and not pair.controller.supervisor.faults
    assert pair.execute(M["Reset"]()).result == Reason.OK      # and not silent to the fault check either
    assert pair.run_until(lambda: pair.follower.longest_wait_s >= 2.5 * limit - 0.05, 10)   # the plant is back
    judge.gone = True                                 # the process ended, or is stopped: its silence counts whole
    for _ in range(int(limit / 0.05) + 2):
        pair.wall.advance_by(0.05)
        pair.turn(plant=False)
    assert pair.controller.supervisor.faults & Fault.HAL_STALE


def test_the_followers_grant_is_counted_from_its_first_tick_never_summed():
    """100,000 ticks granted one by one end exactly 100,000 periods after the first (summing the
    period would be 0.1 ns off by then, and half a tick off after 53 simulated hours)."""
    plant_end, controller_end = open_local_pair()
    follower = LockstepFollower(controller_end, SimClock(1000.0))
    layout = HalCodec().layout("PLANT_SYNC", ("tick", "lockstep", "period_us"))
    try:
        for tick in range(100_001):
            plant_end.send(layout.message((tick, 1, 1000)))
            follower.tap.recv(timeout=0)
        assert follower._granted_s == -0.001 + 100_001 * 0.001
        assert abs(follower._granted_s - 100.0) < 1e-12
    finally:
        plant_end.shutdown()
        controller_end.shutdown()


def test_lock_step_goes_on_through_the_32_bit_wrap_of_the_tick():
    """PLANT_SYNC and CTRL_SYNC carry the tick modulo 2**32 (49.7 days at 1 kHz): across the wrap
    the controller answers CTRL_SYNC(0) to PLANT_SYNC(2**32 - 1), and the plant takes it as tick 2**32."""
    wrap = 2 ** 32
    pair = Pair(first_tick=wrap - 50)
    assert pair.run_until(lambda: pair.node.tick >= wrap + 50, 20_000)
    assert pair.leader.controller_tick >= wrap + 49 and pair.leader.ignored == 0
    assert pair.follower.resyncs == 0 and pair.follower.plant_tick == (pair.node.tick - 1) % wrap
    assert pair.control.tasks["arm"].stats.runs >= 99
    assert not pair.controller.supervisor.faults


class FailingReads(BusView):
    """Its next `count` reads made within the lock-step wait (`armed`) raise what udp_multicast raises for a
    datagram that is not a frame."""

    def __init__(self, bus) -> None:
        super().__init__(bus)
        self.count = 0
        self.armed = False

    def recv(self, timeout=None):
        if self.count and self.armed:
            self.count -= 1
            raise can.CanOperationError("could not unpack received message")
        return self.bus.recv(timeout)


@pytest.mark.parametrize("side", ["plant", "controller"])
def test_a_read_error_met_while_waiting_for_the_sync_is_a_bus_error_not_a_crash(side):
    """A junk datagram on a udp_multicast port makes python-can's recv raise CanOperationError; met in the
    lock-step wait (not the node's poll) it ended `aspod plant` / `aspod firmware` with a traceback."""
    pair = Pair()
    assert pair.run_until(lambda: pair.node.tick >= 50)
    tap = pair.leader.tap if side == "plant" else pair.follower.tap
    node = pair.node if side == "plant" else pair.controller.hal
    tap.bus = failing = FailingReads(tap.bus)
    wait = tap.wait

    def armed_wait(timeout_s):
        failing.armed = True
        try:
            return wait(timeout_s)
        finally:
            failing.armed = False
    tap.wait = armed_wait
    for _ in range(3):
        failing.count = 2
        pair.run_until(lambda: failing.count == 0, 1000)
        for _ in range(5):
            pair.turn()
    tick = pair.node.tick
    assert pair.run_until(lambda: pair.node.tick >= tick + 200)
    assert node.bus_errors == 6 and isinstance(node.last_bus_error, can.CanOperationError)
    assert not pair.controller.supervisor.faults


SYNC_LAYOUT = HalCodec().layout("PLANT_SYNC", ("tick", "lockstep", "period_us"))


def test_a_plant_sync_replayed_from_just_behind_grants_no_time():
    """A PLANT_SYNC a few ticks behind the last (replayed, or overtaken on the bus) was taken as a new plant:
    it granted a tick, and the plant's re-offer that its answer drew one more. 25 of them put the controller
    50 ms ahead of the plant's feedback: HAL_STALE (ENCODER_STALE) with a healthy plant."""
    pair = Pair()
    assert pair.run_until(lambda: pair.node.tick >= 200)
    for back in [1] * 30 + [2, 5, 100]:
        pair.plant_bus.send(SYNC_LAYOUT.message(((pair.node.tick - 1 - back) % 2 ** 32, 1, 1000)))
        for _ in range(3):
            pair.turn()
    tick = pair.node.tick
    assert pair.run_until(lambda: pair.node.tick >= tick + 300)
    assert pair.follower.now() == pytest.approx((pair.node.tick - 1) * 0.001, abs=0.0015)
    assert not pair.controller.supervisor.faults
    assert pair.follower.old_syncs == 33 and pair.follower.resyncs == 0


def test_a_plant_sync_with_another_period_does_not_rescale_the_ticks_already_granted():
    """`granted = base + ticks * period` took the period of the last frame for every tick since the first: one
    PLANT_SYNC saying 65535 us at tick 7000 granted 458 s at once (and 1 us took the grant back to 7 ms)."""
    plant_end, controller_end = open_local_pair()
    follower = LockstepFollower(controller_end, SimClock(1000.0))
    try:
        for tick, period_us in [*((t, 1000) for t in range(7001)), (7001, 65535), (7002, 1000), (7003, 1)]:
            plant_end.send(SYNC_LAYOUT.message((tick, 1, period_us)))
            follower.tap.recv(timeout=0)
        assert follower._granted_s == pytest.approx(7.000 + 0.065535 + 0.001 + 0.000001, abs=1e-9)
    finally:
        plant_end.shutdown()
        controller_end.shutdown()


# --- a second node on the bus: said on the log (PlantsWatch on the controller, ControllersWatch on the plant) ---

def _interleaved(ahead: int, behind: int, count: int, start_s: float = 0.0, step_s: float = 0.001):
    """(tick, wall time) of two plants' PLANT_SYNCs as a controller following both sees them."""
    for i in range(count):
        yield ahead + i, start_s + 2 * i * step_s
        yield behind + i, start_s + (2 * i + 1) * step_s


def test_plants_watch_says_two_plants_once_by_their_ticks_and_again_only_after_they_stopped_and_came_back():
    watch = PlantsWatch()
    lines = [(now, line) for tick, now in _interleaved(5000, 100, 500) if (line := watch.seen(tick, now))]
    assert len(lines) == 1 and lines[0][0] < 0.1                  # said at once, and once only
    assert "two plants (ticks near 50" in lines[0][1] and "and near 1" in lines[0][1]
    assert "another aspod plant" in lines[0][1] and "--channel" in lines[0][1]
    # they stop (one plant alone for 10 s), then come back: said again, but never within BURST_REPEAT_S of the last
    alone = [watch.seen(5500 + i, 1.0 + i * 0.001) for i in range(10_000)]
    again = [now for tick, now in _interleaved(16_000, 200, 500, start_s=12.0) if watch.seen(tick, now)]
    assert not any(alone) and again == []                          # 12 s after the first: too soon
    later = [now for tick, now in _interleaved(40_000, 300, 500, start_s=40.0) if watch.seen(tick, now)]
    assert len(later) == 1 and watch.burst.said == 2


def test_plants_watch_is_silent_for_what_one_plant_does_restarts_lost_frames_replays_and_the_wrap():
    watch = PlantsWatch()
    ticks: list[int] = []
    ticks += range(0, 5000)                          # a plant ...
    ticks += range(0, 5000)                          # ... restarted (a resync)
    ticks += range(0, 50)                            # ... and again within its first ticks
    ticks += [t for t in range(0, 3000) if t % 7]    # frames lost: gaps below MAX_SYNC_GAP_TICKS ...
    ticks += range(3000 + MAX_SYNC_GAP_TICKS * 5, 4000 + MAX_SYNC_GAP_TICKS * 5)   # ... and beyond: a resync
    ticks += [4500, 4500, 4500, 4499, 4501]          # re-offers of a tick, and one replayed from just behind
    ticks += [(2 ** 32 - 300 + t) % 2 ** 32 for t in range(600)]   # 32-bit wrap (after a jump back: a resync)
    lines = [watch.seen(tick, i * 0.0001) for i, tick in enumerate(ticks)]   # all within 2.5 s of wall time
    assert not any(lines) and watch.steps_back == 5


def test_controllers_watch_says_two_controllers_or_another_plant_and_nothing_for_one_controller():
    one = ControllersWatch()
    offered = 0
    for i in range(20_000):                          # one controller: every PLANT_SYNC answered once ...
        offered += 1
        if i % 500 == 0:                             # ... a re-offer now and then, answered too ...
            offered += 1
            assert one.answer(i * 0.001, offered) is None
        if i % 300 != 0:                             # ... and answers lost
            assert one.answer(i * 0.001, offered) is None
    for _ in range(100_000):                         # a plant alone for long: its re-offers are never answered ...
        offered += 1
    assert one.answer(30.0, offered) is None and one.answer(30.0, offered) is None   # ... then a new controller
    assert one.unasked == 0
    two = ControllersWatch()
    offered, lines = 0, []
    for i in range(1000):                            # two controllers: every PLANT_SYNC answered twice
        offered += 1
        lines += [line for _ in range(2) if (line := two.answer(i * 0.001, offered))]
    assert len(lines) == 1 and "two controllers" in lines[0] and "another aspod firmware" in lines[0]
    assert two.unasked >= 900
    other = ControllersWatch()
    lines = [line for i in range(1000)
             if (line := other.answer(i * 0.001, i // 2, others=i // 3))]   # another plant's ticks answered too
    assert len(lines) == 1 and "another aspod plant" in lines[0]


def test_controllers_watch_credit_is_bounded_so_a_long_wait_alone_hides_no_second_controller():
    watch = ControllersWatch()
    offered = 100_000                                # the plant waited alone, re-offering, for hours
    lines = []
    for i in range(200):
        offered += 1
        lines += [line for _ in range(2) if (line := watch.answer(i * 0.001, offered))]
    assert len(lines) == 1 and watch.unasked < 200


def test_burst_watch_needs_count_within_window_and_goes_quiet_before_it_says_again():
    burst = BurstWatch(count=3, window_s=1.0, quiet_s=5.0, repeat_s=30.0)
    assert [burst.note(t) for t in (0.0, 1.5, 3.0, 4.5)] == [False] * 4     # never 3 within 1 s
    assert [burst.note(t) for t in (10.0, 10.2, 10.4, 10.6)] == [False, False, True, False]
    assert [burst.note(t) for t in (13.0, 13.1, 13.2)] == [False] * 3       # goes on: not again
    assert [burst.note(t) for t in (20.0, 20.1, 20.2)] == [False] * 3       # stopped 6.8 s, back: too soon
    assert [burst.note(t) for t in (41.0, 41.1, 41.2)] == [False, False, True]   # stopped, back, 30 s later
    with pytest.raises(ValueError):
        BurstWatch(count=0)


def test_a_second_plant_on_the_bus_is_said_by_the_controller_a_plant_restart_is_not():
    pair = Pair()
    watch = PlantsWatch()
    lines: list[str] = []
    pair.follower.on_tick = lambda tick: lines.extend(filter(None, [watch.seen(tick, pair.wall.now())]))
    assert pair.run_until(lambda: pair.node.tick >= 300)
    pair.start_plant(seed=2)                         # a new plant process on the same bus: one resync
    assert pair.run_until(lambda: pair.node.tick >= 300)
    assert pair.follower.resyncs == 1 and lines == []
    other = LocalBus(pair.plant_bus.local_channel)   # a second plant, its ticks far ahead of this one's
    try:
        for i in range(30):                          # the controller answers its ticks: this plant waits, re-offers
            other.send(SYNC_LAYOUT.message((9000 + i, 1, 1000)))
            pair.wall.advance_by(REOFFER_S)
            for _ in range(3):
                pair.turn()
    finally:
        other.shutdown()
    assert len(lines) == 1 and "ticks near 90" in lines[0]
    assert pair.follower.resyncs > 1              # what the follower grants is its own business: unchanged


def test_a_second_controller_on_the_bus_is_said_by_the_plant_one_controller_is_not():
    pair = Pair()
    watch = ControllersWatch()
    lines: list[str] = []
    pair.leader.on_answer = lambda tick: lines.extend(filter(None, [watch.answer(
        pair.wall.now(), pair.node.tick + pair.node.sync_resends)]))
    assert pair.run_until(lambda: pair.node.tick >= 300)
    pair.controller_bus.count = 1                   # a lost CTRL_SYNC: the plant re-offers its tick
    for _ in range(5):
        pair.turn()
    pair.wall.advance_by(REOFFER_S)
    assert pair.run_until(lambda: pair.node.tick >= 600)
    assert lines == [] and watch.unasked == 0 and pair.node.sync_resends >= 1
    second = LockstepFollower(LocalBus(pair.plant_bus.local_channel), pair.wall)   # a second controller
    try:
        for _ in range(200):
            pair.turn()
            second.advance(math.inf, pair.wall.now())   # it answers every tick it sees
    finally:
        second.tap.shutdown()
    assert len(lines) == 1 and "two controllers" in lines[0]
