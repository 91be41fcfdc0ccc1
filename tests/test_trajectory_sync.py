"""Two arms, two controllers, one start: the first arm's controller leads (its TrajRun starts its trajectory a few plant
ticks ahead and says on which, TRAJ_START), the second's follows (its TrajRun arms the trajectory; it starts on the
leader's tick), relayed between their buses by the plant, on the simulated clock (firmware_py/trajectory_sync.py,
host_tools/worlds/second_arm.py)."""
from __future__ import annotations

import math

import can
import pytest

from firmware_py.trajectory_sync import ARMED_S, LEAD_TICKS, SyncRole
from host_tools.apps.two_arm_plan import start_together
from host_tools.client.bench import BenchClient
from host_tools.client.trajectory import TrajectoryRefused, upload_trajectory
from host_tools.worlds.world import LockstepBench
from host_tools.worlds.local_bus import LocalBus
from protocol.hal import BusView, HalCodec, HalEndpoint
from protocol.messages import MESSAGES as M, TRAJECTORY_JOINTS
from protocol.reasons import Reason
from protocol.states import Axis, ControllerState, Fault, MotionOutcome
from tests.test_realtime_faults import LoseFrames
from tests.test_trajectory import smooth_knots

J1 = int(Axis.J1)


def homed(call, events: list, wait_until) -> None:
    assert call(M["Enable"]()).ok
    reply = call(M["Home"](int(Axis.ALL))).reply
    started = {int(a): getattr(reply, f"{a.name.lower()}_motion_id") for a in Axis if a is not Axis.ALL}
    assert wait_until(lambda: all(any(e.spec.name == "MotionDone" and e.axis == a and e.motion_id == i for e in events)
                                  for a, i in started.items()), 60.0)


@pytest.fixture
def bench():
    bench = LockstepBench(seed=5, arms=2)
    assert bench.connect() and bench.arm2.connect(bench.world.arm2.controller)
    homed(bench.call, bench.events, bench.wait_until)
    homed(bench.arm2.call, bench.arm2.events, bench.wait_until)
    yield bench
    bench.close()


def moved(channel, held_rad: float) -> bool:
    """Off the first knot by more than a rounding: the two controllers reckon the start tick's time along two sums of
    floats, which may differ in the last bit (a setpoint a hair past its start, 1e-30 rad along)."""
    return abs(channel.pos_sp_rad - held_rad) > 1e-12


def test_the_two_arms_start_their_trajectories_on_one_tick(bench):
    first, second = bench.controller, bench.world.arm2.controller
    assert (first.trajectory_sync.role, second.trajectory_sync.role) == (SyncRole.LEADER, SyncRole.FOLLOWER)
    knots_1, knots_2 = smooth_knots(holding_deg_of(first)), smooth_knots(holding_deg_of(second))
    upload_trajectory(bench, knots_1)
    upload_trajectory(bench.arm2, knots_2)
    armed = bench.arm2.call(M["TrajRun"](len(knots_2)))
    assert armed.ok and second.trajectory_sync.armed is not None
    bench.run_for(0.01)
    held_2 = second.arm.channels[J1].pos_sp_rad          # the first knot (as the wire carried it), at rest
    bench.run_for(0.5)                                   # armed, holding: nothing moves
    assert not moved(second.arm.channels[J1], held_2)
    led = bench.call(M["TrajRun"](len(knots_1)))
    assert led.ok
    tick = first.trajectory_sync.last_start_tick
    assert first.hal.inputs.tick < tick
    held_1 = first.arm.channels[J1].pos_sp_rad           # its first knot, until the tick
    # each controller's setpoint leaves its first knot on the same plant tick, the one TRAJ_START named
    left = {}
    while len(left) < 2:
        bench.run_for(0.001)
        for name, controller, held in (("first", first, held_1), ("second", second, held_2)):
            if name not in left and moved(controller.arm.channels[J1], held):
                left[name] = controller.hal.inputs.tick
        assert first.hal.inputs.tick - tick < 50, f"no start near tick {tick}: {left}"
    assert left["first"] == left["second"] and 0 <= left["first"] - tick <= 1
    assert second.trajectory_sync.last_start_tick == tick and second.trajectory_sync.starts == 1
    assert tick - LEAD_TICKS <= first.hal.inputs.tick
    # a peer's TRAJ_START is no foreign frame: neither controller took it for another node driving its motors
    assert first.hal.foreign_frames() == 0 == second.hal.foreign_frames()
    assert first.supervisor.state is second.supervisor.state is ControllerState.ENABLED


def holding_deg_of(controller) -> list[float]:
    return [math.degrees(controller.arm.channels[int(a)].pos_sp_rad) for a in TRAJECTORY_JOINTS]


def test_a_follower_the_leader_never_starts_stops_where_it_holds(bench):
    second = bench.world.arm2.controller
    knots = smooth_knots(holding_deg_of(second))
    upload_trajectory(bench.arm2, knots)
    reply = bench.arm2.call(M["TrajRun"](len(knots))).reply
    ids = {int(a): getattr(reply, f"{a.name.lower()}_motion_id") for a in TRAJECTORY_JOINTS}
    assert reply.result == Reason.OK
    bench.wait_until(lambda: second.trajectory_sync.armed is None, ARMED_S + 1.0)
    assert bench.wait_until(lambda: all(any(e.spec.name == "MotionDone" and e.axis == a and e.motion_id == i
                                            for e in bench.arm2.events) for a, i in ids.items()), 5.0)
    ends = [e for e in bench.arm2.events if e.spec.name == "MotionDone" and (e.axis, e.motion_id) in ids.items()]
    assert {MotionOutcome(e.outcome) for e in ends} == {MotionOutcome.STOPPED}
    assert abs(second.arm.channels[J1].pos_sp_rad - math.radians(knots[0].q_deg[0])) < 1e-6   # never left knot 0


def test_a_single_arm_world_has_no_coordination_and_sends_no_new_frame():
    bench = LockstepBench(seed=5)
    try:
        assert bench.controller.trajectory_sync is None and bench.world.arm2 is None
        assert "TRAJ_START" not in bench.world.plant_node.sent_by_name
    finally:
        bench.close()


def armed_follower(bench) -> tuple:
    """The second controller's trajectory armed: (its controller, its knots, its motion ids by axis)."""
    second = bench.world.arm2.controller
    knots = smooth_knots(holding_deg_of(second))
    upload_trajectory(bench.arm2, knots)
    reply = bench.arm2.call(M["TrajRun"](len(knots))).reply
    assert reply.result == Reason.OK and second.trajectory_sync.armed is not None
    return second, knots, {int(a): getattr(reply, f"{a.name.lower()}_motion_id") for a in TRAJECTORY_JOINTS}


def stopped_at_knot_0(bench, second, knots, ids: dict) -> None:
    """Every joint the armed trajectory still ran there stopped (MotionDone STOPPED), J1 never off its first knot,
    and it stays there past the time the armed trajectory was parked at (2 ARMED_S)."""
    bench.run_for(2 * ARMED_S + 1.0)
    off_deg = math.degrees(second.arm.channels[J1].pos_sp_rad) - knots[0].q_deg[0]
    assert abs(off_deg) < 1e-4, f"J1 moved {off_deg:.3f} deg alone"
    ends = {(e.axis, e.motion_id): MotionOutcome(e.outcome) for e in bench.arm2.events if e.spec.name == "MotionDone"}
    assert ends.get((J1, ids[J1])) is MotionOutcome.STOPPED, ends
    assert not second.arm.trajectory_running()


def test_a_start_the_follower_cannot_follow_on_every_joint_stops_the_rest(bench):
    """One joint of the armed trajectory moved on (a Move of J4 in place): the leader's start cannot start them
    all, and the others must not start alone 2 ARMED_S after arming (where the armed trajectory was parked)."""
    second, knots, ids = armed_follower(bench)
    j4 = int(Axis.J4)
    assert bench.arm2.call(M["Move"](j4, knots[0].q_deg[j4], 1.0)).ok      # J4's motion replaced
    first = bench.controller
    leader_knots = smooth_knots(holding_deg_of(first))
    upload_trajectory(bench, leader_knots)
    assert bench.call(M["TrajRun"](len(leader_knots))).ok
    bench.run_for(0.1)
    assert second.trajectory_sync.armed is None and second.trajectory_sync.starts == 0
    assert second.trajectory_sync.unmatched == 1
    stopped_at_knot_0(bench, second, knots, ids)



def test_a_start_named_past_the_followers_wait_is_not_followed(bench):
    """A TRAJ_START (here from a third node on the follower's bus) naming a tick beyond the armed wait: the follower
    does not park its trajectory that long (ARMED_S's stop undone); it stops where it holds."""
    second, knots, ids = armed_follower(bench)
    plant = bench.world.arm2.plant_node
    far = (second.hal.inputs.tick + round(3 * ARMED_S / 0.001)) % (1 << 32)
    plant.send_frame(plant.codec.layout("TRAJ_START"), [far, len(knots)])
    bench.run_for(0.01)
    assert second.trajectory_sync.armed is None and second.trajectory_sync.starts == 0
    assert second.trajectory_sync.unmatched == 1
    stopped_at_knot_0(bench, second, knots, ids)


def test_a_leader_that_refuses_leaves_no_follower_armed(bench):
    """start_together: the leader's TrajRun refused (knots that start 5 deg off where it holds), nothing started;
    the follower's armed trajectory is stopped with it, so both may be started again at once (an armed follower's
    joints are busy and its buffer locked for ARMED_S)."""
    first, second = bench.controller, bench.world.arm2.controller
    off = [q + 5.0 for q in holding_deg_of(first)]
    with pytest.raises(TrajectoryRefused) as refused:
        start_together(BenchClient(bench), bench.arm2, (smooth_knots(off), smooth_knots(holding_deg_of(second))))
    assert refused.value.reason is Reason.TRAJ_ENDPOINTS and refused.value.command == "TrajRun"
    bench.run_for(0.05)
    assert not second.arm.trajectory_running()
    start_together(BenchClient(bench), bench.arm2, (smooth_knots(holding_deg_of(first)),
                                                   smooth_knots(holding_deg_of(second))))
    bench.run_for(0.1)
    assert first.trajectory_sync.starts == 1 == second.trajectory_sync.starts


def test_a_leader_whose_last_plant_tick_is_old_still_starts_with_its_follower(bench):
    """The leader's PLANT_SYNCs lost for 50 ms (its ANALOG_IN still fresh): its TrajRun names a tick counted on from
    the last one it heard by the time since, not one already past (it would start 40 ms into its trajectory, and
    the follower, seeing a tick gone, would stop: the leader alone moving)."""
    first, second = bench.controller, bench.world.arm2.controller
    knots_1, knots_2 = smooth_knots(holding_deg_of(first)), smooth_knots(holding_deg_of(second))
    upload_trajectory(bench, knots_1)
    upload_trajectory(bench.arm2, knots_2)
    assert bench.arm2.call(M["TrajRun"](len(knots_2))).ok
    bench.run_for(0.01)
    held_2 = second.arm.channels[J1].pos_sp_rad
    lossy = first.hal.bus = LoseFrames(first.hal.bus, "PLANT_SYNC")
    lossy.lost = True
    bench.run_for(0.05)
    assert first.hal.inputs.tick + 40 < second.hal.inputs.tick            # the leader's last tick is old
    assert bench.call(M["TrajRun"](len(knots_1))).ok
    lossy.lost = False
    held_1 = first.arm.channels[J1].pos_sp_rad           # its first knot, until the tick
    left = {}
    for _ in range(100):
        bench.run_for(0.001)
        for name, controller, held in (("first", first, held_1), ("second", second, held_2)):
            if name not in left and moved(controller.arm.channels[J1], held):
                left[name] = second.hal.inputs.tick
    assert len(left) == 2 and left["first"] == left["second"], left
    assert second.trajectory_sync.starts == 1 and second.trajectory_sync.unmatched == 0


class RefusingStarts(BusView):
    """A bus that refuses to send TRAJ_START (a bus error: python-can raises CanOperationError)."""

    def send(self, msg, timeout=None):
        if msg.arbitration_id == HalCodec().frame_id("TRAJ_START"):
            raise can.CanOperationError("bus off")
        self.bus.send(msg, timeout)


def test_a_leader_whose_start_cannot_be_sent_does_not_start_alone(bench):
    """The leader's TRAJ_START refused by its bus: its follower cannot hear the start, so the leader's own trajectory
    stops where it holds (MotionDone STOPPED, nothing moved), as the follower's does when no start comes."""
    first = bench.controller
    knots = smooth_knots(holding_deg_of(first))
    upload_trajectory(bench, knots)
    first.hal.bus = RefusingStarts(first.hal.bus)
    reply = bench.call(M["TrajRun"](len(knots))).reply
    ids = {int(a): getattr(reply, f"{a.name.lower()}_motion_id") for a in TRAJECTORY_JOINTS}
    bench.run_for(0.5)
    off_deg = math.degrees(first.arm.channels[J1].pos_sp_rad) - knots[0].q_deg[0]
    assert abs(off_deg) < 1e-4, f"J1 moved {off_deg:.3f} deg alone"
    assert first.hal.bus_errors == 1 and first.trajectory_sync.starts == 0
    ends = {(e.axis, e.motion_id): MotionOutcome(e.outcome) for e in bench.events if e.spec.name == "MotionDone"}
    assert all(ends.get((a, i)) is MotionOutcome.STOPPED for a, i in ids.items()), ends


def listening_on_both_buses(bench, frame: str) -> list:
    """A node on each arm's bus (the first arm's, then the second's), each with the values of every `frame` it hears."""
    heard = []
    for bus in (bench.world.controller_bus, bench.world.arm2.controller_bus):
        node, got = HalEndpoint(LocalBus(bus.local_channel, carries_values=bus.carries_values)), []
        node.on_frame(frame, lambda values, now, got=got: got.append(values))
        heard.append((node, got))
    return heard


def test_the_plant_relays_the_leaders_starts_alone():
    """TRAJ_START goes from the leader's bus to the follower's, not back: relayed both ways, on buses that give each
    node its own frames back (udp_multicast, across processes), every relayed start came back to be relayed again,
    one start circling for ever (one a tick on each bus), and a later start's armed follower stopped by the old one
    (a tick past)."""
    bench = LockstepBench(seed=5, arms=2)
    heard = listening_on_both_buses(bench, "TRAJ_START")
    try:
        (on_first, got_first), (on_second, got_second) = heard
        layout = HalCodec().layout("TRAJ_START")
        on_first.send_frame(layout, [6, 20])
        on_second.send_frame(layout, [5, 20])
        bench.run_for(0.01)
        on_first.poll(bench.clock.now())
        on_second.poll(bench.clock.now())
        assert got_second == [[6, 20]] and got_first == []
    finally:
        for node, _ in heard:
            node.bus.shutdown()
        bench.close()


def started_together(bench) -> tuple[dict, dict]:
    """Both arms' trajectories (8 s each) started on one tick: each arm's trajectory motions by axis."""
    first, second = bench.controller, bench.world.arm2.controller
    knots = (smooth_knots(holding_deg_of(first)), smooth_knots(holding_deg_of(second)))
    ids = start_together(BenchClient(bench), bench.arm2, knots)
    return tuple({int(a): i for a, i in zip(TRAJECTORY_JOINTS, motions)} for motions in ids)


def ends(events: list, ids: dict) -> dict:
    """How each of the motions `ids` (axis -> motion id) ended, by axis (MotionDone), so far."""
    return {e.axis: MotionOutcome(e.outcome) for e in events
            if e.spec.name == "MotionDone" and ids.get(e.axis) == e.motion_id}


def ticks_until(bench, predicate, limit: int) -> int:
    """Plant ticks run, one at a time, until `predicate()` holds (at most `limit`)."""
    for ticks in range(limit + 1):
        if predicate():
            return ticks
        bench.run_for(0.001)
    raise AssertionError(f"not within {limit} ticks")


def test_a_leader_stopped_mid_trajectory_stops_its_follower_within_two_ticks(bench):
    """Stop to the leader 2 s into the coordinated trajectory: its TRAJ_STOP, relayed by the plant, stops the follower's
    trajectory within 2 plant ticks of the leader's stop: both slow to rest along their curves (MotionDone STOPPED on
    every joint of both). The follower sends no stop back."""
    first, second = bench.controller, bench.world.arm2.controller
    ids_1, ids_2 = started_together(bench)
    bench.run_for(2.0)
    assert first.arm.trajectory_running() and second.arm.trajectory_running()
    bench.host.submit(M["Stop"](), bench.link_clock.now())
    ticks_until(bench, lambda: first.trajectory_sync.stops_sent == 1, 100)
    assert ticks_until(bench, lambda: second.trajectory_sync.stopped_by_peer == 1, 5) <= 2
    assert bench.wait_until(lambda: len(ends(bench.arm2.events, ids_2)) == len(ids_2) == len(ends(bench.events, ids_1)),
                            10.0)
    assert set(ends(bench.events, ids_1).values()) == set(ends(bench.arm2.events, ids_2).values()) \
        == {MotionOutcome.STOPPED}
    assert second.trajectory_sync.stops_sent == 0 and first.trajectory_sync.stopped_by_peer == 0
    assert first.supervisor.state is second.supervisor.state is ControllerState.ENABLED


def test_a_follower_that_faults_mid_trajectory_stops_the_leader(bench):
    """An encoder glitch on the follower's shoulder (a plant fault) 2 s into the trajectory: the follower faults
    (ENCODER) and its safe state's TRAJ_STOP stops the leader's trajectory (MotionDone STOPPED), which would otherwise
    drag the object alone; the leader stays ENABLED."""
    first, second = bench.controller, bench.world.arm2.controller
    ids_1, _ = started_together(bench)
    bench.run_for(2.0)
    bench.world.arm2.plant.inject("encoder_glitch", "j1")
    ticks_until(bench, lambda: second.supervisor.state is ControllerState.FAULT, 100)
    assert second.supervisor.faults & Fault.ENCODER and second.trajectory_sync.stops_sent == 1
    assert ticks_until(bench, lambda: first.trajectory_sync.stopped_by_peer == 1, 5) <= 2
    assert bench.wait_until(lambda: len(ends(bench.events, ids_1)) == len(ids_1), 10.0)
    assert set(ends(bench.events, ids_1).values()) == {MotionOutcome.STOPPED}
    assert first.supervisor.state is ControllerState.ENABLED and not first.arm.trajectory_running()


def test_a_leader_stopped_inside_its_lead_leaves_the_follower_where_it_was(bench):
    """Stop (an urgent request, ahead of any queued command) to the leader as soon as its TrajRun has run: it comes
    within the 10-tick lead, before the tick its TRAJ_START named. The follower, started for that tick, is stopped
    before it: no joint of either arm leaves its first knot, and every motion of both ends STOPPED."""
    first, second = bench.controller, bench.world.arm2.controller
    knots_1, knots_2 = smooth_knots(holding_deg_of(first)), smooth_knots(holding_deg_of(second))
    upload_trajectory(bench, knots_1)
    upload_trajectory(bench.arm2, knots_2)
    reply = bench.arm2.call(M["TrajRun"](len(knots_2))).reply
    ids_2 = {int(a): getattr(reply, f"{a.name.lower()}_motion_id") for a in TRAJECTORY_JOINTS}
    bench.run_for(0.01)
    run = bench.host.submit(M["TrajRun"](len(knots_1)), bench.link_clock.now())
    ticks_until(bench, lambda: first.trajectory_sync.starts == 1, 1000)
    tick = first.trajectory_sync.last_start_tick
    held = (first.arm.channels[J1].pos_sp_rad, second.arm.channels[J1].pos_sp_rad)      # each one's first knot
    bench.host.submit(M["Stop"](), bench.link_clock.now())
    ticks_until(bench, lambda: first.trajectory_sync.stops_sent == 1, LEAD_TICKS)
    assert first.hal.inputs.tick < tick                     # inside the lead
    ticks_until(bench, lambda: second.trajectory_sync.stopped_by_peer == 1, 2)
    assert second.trajectory_sync.starts == 1 and second.hal.inputs.tick < tick     # the follower's start was set
    bench.run_for(1.0)
    assert run.done and run.reply.result == Reason.OK
    for controller, knot_0 in zip((first, second), held):        # within a rounding of the stop's profile
        assert abs(math.degrees(controller.arm.channels[J1].pos_sp_rad - knot_0)) < 1e-4
    ids_1 = {int(a): getattr(run.reply, f"{a.name.lower()}_motion_id") for a in TRAJECTORY_JOINTS}
    assert set(ends(bench.events, ids_1).values()) == set(ends(bench.arm2.events, ids_2).values()) \
        == {MotionOutcome.STOPPED}


def test_the_plant_relays_trajectory_stops_both_ways_and_never_back():
    """A controller's TRAJ_STOP (relayed 0) on either arm's bus reaches the other's marked relayed (1); a relayed one is
    not relayed again (on a bus that gives each node its own frames back, it would circle for ever)."""
    bench = LockstepBench(seed=5, arms=2)
    heard = listening_on_both_buses(bench, "TRAJ_STOP")
    try:
        (on_first, got_first), (on_second, got_second) = heard
        layout = HalCodec().layout("TRAJ_STOP")
        on_first.send_frame(layout, [7, 0])        # stop_tick, relayed
        on_second.send_frame(layout, [8, 1])       # as if relayed already: goes no further
        bench.run_for(0.01)
        on_second.send_frame(layout, [9, 0])
        bench.run_for(0.01)
        on_first.poll(bench.clock.now())
        on_second.poll(bench.clock.now())
        assert got_second == [[7, 1]] and got_first == [[9, 1]]
    finally:
        for node, _ in heard:
            node.bus.shutdown()
        bench.close()
