"""A session's clean end: the host's authenticated, exactly-once Close (protocol/host_link.py `close`,
protocol/controller_link.py `close_session`, firmware_py/controller.py `_close`; docs/protocol.md "Closing a
session").

Before it, every session ended in a fault: a host that quit went silent, the controller latched LINK_LOST 3 s
later, and the next host opened on FAULT with the stale events of the last one, its `enable` refused until a
`reset`. Link loss without a Close still latches the fault.
"""
from __future__ import annotations

from protocol.link import LinkState
from protocol.messages import MESSAGES as M
from protocol.reasons import Reason
from protocol.states import Axis, CloseWhy, ControllerState, Fault



def events_named(bench, name: str) -> list:
    return [e for e in bench.events if e.spec.name == name]


def moving(bench) -> None:
    """ENABLED, every axis homed, j1 and the mount moving."""
    assert bench.call(M["Enable"]()).ok
    home = bench.call(M["Home"](int(Axis.ALL)))
    assert home.ok, home.describe()
    assert bench.wait_until(lambda: len(events_named(bench, "MotionDone")) >= 6, 120.0)
    assert bench.call(M["MoveBy"](int(Axis.J1), 20.0, 0)).ok
    assert bench.call(M["MoveBy"](int(Axis.MOUNT), 30.0, 0)).ok
    bench.run_for(0.5)


def test_a_closed_session_stops_every_motion_and_leaves_the_controller_idle_without_a_fault(bench):
    moving(bench)
    controller, plant = bench.controller, bench.world.plant
    before = len(bench.events)
    assert bench.close_session()
    assert bench.host.state is LinkState.CLOSED and bench.host.closed.state == ControllerState.IDLE
    assert controller.supervisor.state is ControllerState.IDLE and controller.supervisor.faults == Fault.NONE
    ends = bench.events[before:]
    names = [e.spec.name for e in ends]
    assert names[-1] == "SessionClosed" and ends[-1].why == CloseWhy.DONE
    assert names.count("MotionDone") == 2 and "StateChanged" in names       # the two moves ended, in the session
    changed = next(e for e in ends if e.spec.name == "StateChanged")
    assert changed.state == ControllerState.IDLE and changed.reason == Reason.SESSION_CLOSED
    assert bench.wait_until(lambda: controller.link.session is None, 0.5)   # forgotten once all is acknowledged
    bench.run_for(2.0)
    assert all(plant.arm.vel_rad_s[k] == 0.0 for k in range(len(plant.arm.vel_rad_s)))   # held by the brakes
    assert controller.supervisor.state is ControllerState.IDLE and controller.supervisor.faults == Fault.NONE


def test_the_next_session_opens_on_idle_with_no_fault_and_no_stale_event(bench):
    moving(bench)
    assert bench.close_session()
    bench.run_for(5.0)                                  # past the link timeout: silence after a Close is no loss
    assert bench.controller.supervisor.faults == Fault.NONE
    before = len(bench.events)
    assert bench.connect()
    status = bench.call(M["GetStatus"]()).reply
    assert status.state == ControllerState.IDLE and status.faults == 0
    assert bench.call(M["Enable"]()).ok                  # no `reset` needed
    bench.run_for(0.5)
    assert [e.spec.name for e in bench.events[before:]] == ["StateChanged"]    # its own enable, nothing older


def test_silence_without_a_close_still_latches_link_lost(bench):
    assert bench.call(M["Enable"]()).ok
    bench.host.abandon(bench.clock.now(), "the host is gone")     # no Close: the host just stops talking
    bench.run_for(bench.controller.link.config.link_timeout_s + 0.5)
    assert bench.controller.supervisor.state is ControllerState.FAULT
    assert bench.controller.supervisor.faults & Fault.LINK_LOST


def test_a_close_keeps_a_latched_fault(bench):
    assert bench.call(M["EStop"]()).ok
    assert bench.close_session()
    assert bench.host.closed.state == ControllerState.ESTOP and bench.host.closed.faults == int(Fault.ESTOP)
    assert bench.connect()
    assert bench.call(M["Enable"]()).reason is Reason.ESTOP       # a close is no reset


def test_commands_after_the_close_are_refused_and_a_repeated_close_is_answered_from_the_cache():
    from protocol.framing import FrameReceiver
    from test_auth_replay import Wire
    wire = Wire()
    wire.connect()
    wire.controller.send_event(M["StateChanged"](1, 1, 0, 0, 0))   # an event the host will not acknowledge
    wire.host.close(wire.now)
    wire.host.state = LinkState.UP               # a host that talks on after its Close (a bug of its own)
    wire.host.submit(M["Ping"](2), wire.now)
    wire.controller.feed(wire.host.take_all(wire.now), wire.now)   # the Close, then the Ping, in one read
    assert [m.spec.name for m in wire.executed] == ["Close"]
    assert wire.controller.stats.reasons[Reason.SESSION_CLOSED] == 1
    wire.controller.take_all(wire.now)           # its answers are lost: the event is not acknowledged, so the
    assert wire.controller.state is LinkState.CLOSING      # session lingers
    wire.host.state = LinkState.CLOSING
    wire.now += 2.5                              # past the host's retransmission timer
    wire.host.poll(wire.now)
    wire.controller.feed(wire.host.take_all(wire.now), wire.now)   # the Close (and the Ping) sent again
    answers = [f for f in FrameReceiver().feed(wire.controller.take_all(wire.now)) if not isinstance(f, Exception)]
    assert M["Closed"].spec.id in {f.msg_id for f in answers}      # from the reply cache
    assert [m.spec.name for m in wire.executed] == ["Close"]       # run once, the Ping never


def test_a_clean_close_draws_no_nak():
    """The host acknowledges each event as it comes and sends no Ack of its own when the close ends: one more would
    reach a controller that forgot the session and draw a Nak(NO_SESSION) (the vectors' capture showed one)."""
    from test_auth_replay import Wire
    wire = Wire()
    wire.connect()
    wire.controller.send_event(M["StateChanged"](1, 1, 0, 0, 0))
    wire.step(50)
    handle = wire.host.close(wire.now)
    wire.step(50)
    assert handle.ok and wire.host.state is LinkState.CLOSED and wire.controller.session is None
    wire.step(50)
    assert wire.controller.stats.naks_tx == 0 and wire.host.stats.naks_rx == 0


def test_a_close_whose_answer_is_lost_still_ends_cleanly_and_runs_once():
    """The Closed reply is lost: the host sends its Close again; the controller has forgotten the session (every
    event was acknowledged) and answers NO_SESSION under its NAK key, echoing the Close's tag: closed."""
    from test_auth_replay import Wire
    wire = Wire()
    wire.connect()
    close = wire.host.close(wire.now)
    wire.controller.feed(wire.host.take_all(wire.now), wire.now)
    wire.controller.poll(wire.now)
    lost = wire.controller.take_all(wire.now)           # the Closed: never reaches the host
    assert lost
    for _ in range(3):
        wire.now += 0.01
        wire.controller.poll(wire.now)
    assert wire.controller.session is None               # nothing left to acknowledge: forgotten
    wire.step(3000)
    assert wire.host.state is LinkState.CLOSED
    assert [m.spec.name for m in wire.executed].count("Close") == 1
    assert close.done


def test_the_controller_says_nothing_more_after_the_close_and_does_not_watch_the_link(bench):
    assert bench.call(M["SetTelemetryRate"](30)).ok
    assert bench.call(M["Enable"]()).ok
    assert bench.close_session(CloseWhy.STOPPED)
    telemetry = len(bench.telemetry)
    bench.run_for(10.0)
    assert len(bench.telemetry) == telemetry
    assert bench.controller.supervisor.faults == Fault.NONE
    assert bench.controller.telemetry_hz == int(bench.controller.params["telemetry_hz"])   # the next session's rate
    assert events_named(bench, "SessionClosed")[-1].why == CloseWhy.STOPPED


def test_a_recorded_close_played_back_in_a_later_session_does_nothing():
    from test_auth_replay import Wire
    wire = Wire()
    wire.connect()
    wire.host.close(wire.now)
    recorded = wire.host.take_all(wire.now)
    wire.controller.feed(recorded, wire.now)
    wire.step(200)
    assert wire.host.state is LinkState.CLOSED
    wire.connect()
    ran = len(wire.executed)
    wire.controller.feed(recorded, wire.now)             # the old session's Close, played back
    wire.step(100)
    assert len(wire.executed) == ran and wire.controller.state is LinkState.UP
    assert wire.call(M["Ping"](3)).ok


# ---- through the real interface: `aspod sim` and `aspod teleop` as processes over a pty ----

import re                                                        # noqa: E402
import signal                                                    # noqa: E402

import pytest                                                    # noqa: E402

from host_tools.worlds.child import PIPE, Child                 # noqa: E402
from tests import test_e2e                                       # noqa: E402

env, sim_factory = test_e2e.env, test_e2e.sim_factory            # the fixtures, shared
SESSION = "enable\nhome all\nwait all 120\nmoveby j1 5\nwait all 60\nstatus\nquit\n"


@pytest.mark.pty
def test_two_scripted_teleop_sessions_in_a_row_need_no_reset(sim_factory):
    """The finding: every session ended in LINK_LOST, so the second one's `enable` was refused until a `reset`."""
    sim = sim_factory("--pty", "--no-tracker")
    for run in range(2):
        done = sim.teleop(SESSION, timeout_s=600)
        out = done.stdout.decode()
        assert done.returncode == 0, f"session {run + 1}: {done.stderr.decode()}{out[-2000:]}"
        assert "state=ENABLED" in out and "FAULT" not in out
        sim.child.wait_stderr(r"ENABLED -> IDLE \(SESSION_CLOSED\)")
        sim.child.seen.clear()
    assert "LINK_LOST" not in "".join(sim.child.seen)


@pytest.mark.pty
def test_teleop_stopped_by_sigterm_closes_its_session(sim_factory):
    sim = sim_factory("--pty", "--no-tracker")
    host = Child(["teleop", sim.url], stdin=PIPE, env=sim.env)
    host.proc.stdin.write(b"enable\nstatus\nwait 3600\n")          # a pause the signal ends
    host.proc.stdin.close()                                     # a script: read to its end first
    while "state=ENABLED" not in host.line(60):
        pass
    host.proc.send_signal(signal.SIGTERM)
    assert host.proc.wait(timeout=60) == 128 + signal.SIGTERM
    sim.child.wait_stderr(r"the host closed its session \(stopped\)")
    done = sim.teleop("status\nenable\nquit\n")
    assert done.returncode == 0 and "state=IDLE" in done.stdout.decode(), done.stderr.decode()


@pytest.mark.pty
def test_the_first_wait_of_a_session_counts_the_controllers_time(sim_factory):
    """The finding: before the first TelemetryStatus a wait counted wall seconds, so on `aspod sim --speed 0.01`
    `wait all 20` gave up after 0.3 simulated s. At --speed 0.1, `wait all 1` over a homing that takes longer
    must wait one simulated second (10 wall s), not one wall second."""
    sim = sim_factory("--pty", "--no-tracker", "--speed", "0.1")
    done = sim.teleop("telemetry 0\nenable\nhome all\nwait all 1\nstatus\nquit\n", "--keep-going", timeout_s=600)
    out = done.stdout.decode()
    uptimes = [int(ms) for ms in re.findall(r"uptime_ms=(\d+)", out)]
    assert "FAIL wait all: timed out after 1 s" in out and uptimes, out
    assert uptimes[-1] >= 1000, out          # the controller's own time went on by the second waited (before: 0.1 s)
