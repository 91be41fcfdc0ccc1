"""The one-process world as `aspod sim` runs it, on a host that stalls: slower, never faulty.

Plant and controller on a `PacedClock`, the link and a host on the wall clock (`World(link_clock=)`,
`run_live`), exactly as in `aspod sim`; only the wall clock is a `SimClock` here, so that the tests
can stall the process on purpose (a task on the wall clock that moves it on, as a descheduled
process finds it moved on) and nothing waits on real time.
"""
from __future__ import annotations

import random

import pytest

from timebase.scheduler import run_live
from host_tools.worlds.plant_control import PlantControl
from host_tools.worlds.ports import BufferPort, exchange
from host_tools.worlds.settings import PlantSettings
from host_tools.worlds.world import World
from protocol.host_link import HostLink
from protocol.link import LinkState
from protocol.messages import MESSAGES as M
from protocol.reasons import Reason
from protocol.states import Axis, ControllerState, Fault, TimingIssue, TimingMode
from timebase import PacedClock, SimClock

KEY = b"paced-world-key-0123456789abcdef"


class LiveRig:
    """`aspod sim`'s world with a host in the same thread, on a wall clock the test moves."""

    def __init__(self, speed: float = 1.0) -> None:
        self.wall = SimClock(50.0)
        self.port = BufferPort(notifies=False)
        self.world = World(PacedClock(self.wall, speed), self.port, KEY, link_clock=self.wall, deterministic=True,
                           plant=PlantSettings(tracker=False))
        self.events: list = []
        rng = random.Random(7)
        self.host = HostLink(KEY, nonce_source=lambda: rng.randbytes(16),
                             on_event=lambda msg, now: self.events.append(msg))
        self.world.link_scheduler.add("host", self._host_step)
        self.stalls: list[tuple[float, float]] = []      # (every_s, stall_s): the process loses stall_s each every_s
        self.world.clock.start()

    def _host_step(self, now: float) -> float:
        exchange(self.port, self.host, now)
        return now + 0.001

    def cost(self, wall_per_tick_s: float) -> None:
        """From now on each simulated millisecond of the world takes `wall_per_tick_s` of the host's time."""
        def work(now: float) -> float:
            self.wall.advance_by(wall_per_tick_s)
            return now + 0.001
        self.world.scheduler.add("work", work, period_s=0.001, priority=99)

    def stall(self, every_s: float, stall_s: float) -> None:
        """From now on the process is descheduled for `stall_s` every `every_s` of wall time."""
        def hog(now: float) -> float:
            self.wall.advance_by(stall_s)
            return self.wall.now() + every_s
        self.world.link_scheduler.add(f"stall-{len(self.stalls)}", hog, self.wall.now() + every_s)
        self.stalls.append((every_s, stall_s))

    def run_until(self, predicate, wall_s: float) -> bool:
        end = self.wall.now() + wall_s
        run_live(self.world.scheduler, self.world.link_scheduler, lambda: predicate() or self.wall.now() >= end)
        return predicate()

    def call(self, msg, wall_s: float = 10.0):
        handle = self.host.submit(msg, self.wall.now())
        assert self.run_until(lambda: handle.done, wall_s), f"{msg.spec.name}: no outcome"
        return handle

    @property
    def controller(self):
        return self.world.controller


def test_a_host_too_slow_for_real_time_slows_the_world_down_and_faults_nothing():
    rig = LiveRig()
    rig.host.connect(rig.wall.now())
    assert rig.run_until(lambda: rig.host.state is LinkState.UP, 5.0)
    assert rig.call(M["Enable"]()).ok
    rig.cost(0.003)                                    # each simulated ms takes 3 ms of the host ...
    rig.stall(every_s=0.005, stall_s=0.020)            # ... which also loses 20 ms in every 25: a very busy machine
    accepted = rig.call(M["MoveBy"](int(Axis.J1), 3.0, 0)).reply
    assert rig.run_until(lambda: any(e.spec.name == "MotionDone" and e.motion_id == accepted.motion_id
                                     for e in rig.events), 120.0)
    done = [e for e in rig.events if e.spec.name == "MotionDone"][-1]
    assert done.reason == Reason.OK and done.position == pytest.approx(3.0, abs=0.05)
    sup = rig.controller.supervisor
    assert sup.state is ControllerState.ENABLED and not sup.faults
    # the plant integrated every millisecond the controller lived through, and no other
    node, clock = rig.world.plant_node, rig.world.clock
    assert node.dt_clamps == 0 and abs(node.tick - clock.now() / node.period_s) <= 1
    # ... and the slowness is said by name, with the factor
    warnings = [e for e in rig.events if e.spec.name == "TimingWarning"]
    assert warnings and warnings[0].issue == TimingIssue.BELOW_REAL_TIME and warnings[0].value < 0.5
    status = rig.call(M["GetStatus"](), 30.0).reply
    assert status.timing == TimingMode.PACED and 0.05 < status.rtf_recent < 0.5


def test_a_slow_speed_asked_for_is_not_a_slow_host_but_falling_behind_it_is():
    """`aspod sim --speed 0.01` once warned at once that the world ran below real time: 0.01x is what was asked."""
    rig = LiveRig(speed=0.01)
    rig.host.connect(rig.wall.now())
    assert rig.run_until(lambda: rig.host.state is LinkState.UP, 5.0)
    rig.run_until(lambda: False, 30.0)                # 30 wall seconds: 0.3 simulated, 30 health checks
    status = rig.call(M["GetStatus"]()).reply
    assert status.rtf_recent == pytest.approx(0.01, rel=0.1)
    assert not [e for e in rig.events if e.spec.name == "TimingWarning"]
    rig.cost(0.25)                                    # each simulated ms now takes 250 ms: 0.004x, short of 0.01x
    rig.run_until(lambda: any(e.spec.name == "TimingWarning" for e in rig.events), 30.0)
    warning = next(e for e in rig.events if e.spec.name == "TimingWarning")
    assert warning.issue == TimingIssue.BELOW_REAL_TIME and warning.active
    assert warning.value == pytest.approx(0.004, rel=0.1) and warning.limit == pytest.approx(0.009, rel=1e-6)


def test_a_stall_longer_than_the_link_timeout_is_not_the_hosts_silence():
    rig = LiveRig()
    rig.host.connect(rig.wall.now())
    assert rig.run_until(lambda: rig.host.state is LinkState.UP, 5.0)
    assert rig.call(M["Enable"]()).ok
    rig.run_until(lambda: False, 0.5)
    rig.wall.advance_by(4.0)                           # the whole process stopped for 4 s (link timeout 3 s)
    rig.run_until(lambda: False, 1.0)
    sup = rig.controller.supervisor
    assert sup.state is ControllerState.ENABLED and not sup.faults, [e for e in rig.events]
    assert 0 < rig.controller.comms.stalls_excused_s < 4.0     # no more than it took to hear the host out
    assert rig.world.clock.slips == 1                  # too far behind to catch up: the world was re-anchored
    assert rig.call(M["Ping"](3)).ok


@pytest.mark.parametrize("every_s,stall_s", [(0.05, 0.2), (0.001, 0.06)], ids=["throttled", "late-every-run"])
def test_a_controller_stopped_again_and_again_still_finds_its_host_dead_one_link_timeout_later(every_s, stall_s):
    """The stall excuse hears the host out after each stall; it never adds the stalls themselves to the link
    timeout: not for a throttled controller (stopped 200 ms in every 250 ms), which would give a dead host 5 link
    timeouts instead of one, nor for one late at every run (60 ms late at every 1 ms asked, an overloaded host),
    which renewed the excuse at every run and found a dead host at 4.6 s (firmware_py/comms.py)."""
    rig = LiveRig()
    rig.host.connect(rig.wall.now())
    assert rig.run_until(lambda: rig.host.state is LinkState.UP, 5.0)
    assert rig.call(M["Enable"]()).ok
    rig.world.link_scheduler.remove("host")             # the host process dies
    last_heard = rig.controller.link.last_valid_rx_s
    rig.stall(every_s=every_s, stall_s=stall_s)
    sup = rig.controller.supervisor
    assert rig.run_until(lambda: Fault.LINK_LOST in sup.faults, 30.0)
    found_after = rig.wall.now() - last_heard
    assert 3.0 < found_after < 3.0 + 0.5, found_after    # timeout 3 s; a few ms per stall, one stall late at most
    assert sup.state is ControllerState.FAULT


def test_paused_the_world_stands_still_its_link_stays_up_and_nothing_is_said_to_be_slow():
    """The control endpoint's pause (host_tools/worlds/plant_control.py) on `aspod sim`'s world: simulated time, the
    plant and the motion stand still for 10 wall seconds (three link timeouts) while the host's heartbeats and
    commands go on; resumed, the motion ends DONE, and neither the pause nor the step is taken for a slow host."""
    rig = LiveRig()
    control = PlantControl(rig.world.plant, rig.world.clock)
    rig.host.connect(rig.wall.now())
    assert rig.run_until(lambda: rig.host.state is LinkState.UP, 5.0)
    assert rig.call(M["Enable"]()).ok
    accepted = rig.call(M["MoveBy"](int(Axis.J1), 2.0, 0)).reply
    rig.run_until(lambda: False, 0.5)
    assert control.request({"op": "pause"})["paused"]
    pongs = [rig.call(M["Ping"](k)).reply.uptime_ms for k in range(3)]     # (the tasks due at the held moment run)
    held_s, tick, j1 = rig.world.clock.now(), rig.world.plant_node.tick, rig.world.plant.arm.pos_rad[0]
    rig.run_until(lambda: False, 10.0)
    pongs += [rig.call(M["Ping"](k)).reply.uptime_ms for k in range(3)]
    assert len(set(pongs)) == 1 and rig.host.state is LinkState.UP          # the controller's time stood still
    assert (rig.world.clock.now(), rig.world.plant_node.tick, rig.world.plant.arm.pos_rad[0]) == (held_s, tick, j1)
    reply = control.handle({"op": "step", "seconds": 0.25})
    assert rig.run_until(lambda: reply.poll() is not None, 5.0) and reply.poll()["time_s"] == pytest.approx(held_s + 0.25)
    assert control.request({"op": "resume"})["paused"] is False
    assert rig.run_until(lambda: any(e.spec.name == "MotionDone" and e.motion_id == accepted.motion_id
                                     for e in rig.events), 30.0)
    rig.run_until(lambda: False, 3.0)
    done = [e for e in rig.events if e.spec.name == "MotionDone"][-1]
    assert done.reason == Reason.OK and done.position == pytest.approx(2.0, abs=0.05)
    sup = rig.controller.supervisor
    assert sup.state is ControllerState.ENABLED and not sup.faults
    assert [e for e in rig.events if e.spec.name == "TimingWarning"] == []
    status = rig.call(M["GetStatus"]()).reply
    assert status.rtf_recent == pytest.approx(1.0, abs=0.1) and rig.world.clock.slips == 0
