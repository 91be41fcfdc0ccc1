"""The lock-step world's line: host and comms sleep through empty polls and do the very same work."""
from __future__ import annotations

import hashlib

from firmware_py.controller import ControllerConfig
from host_tools.worlds.world import LockstepBench
from protocol.link import LinkConfig
from protocol.messages import MESSAGES as M
from protocol.states import Axis, ControllerState, GripAction


class Dropper:
    """Loses every `every`-th chunk written in one direction, and records what passes."""

    def __init__(self, every: int) -> None:
        self.every, self.writes, self.wire = every, 0, hashlib.sha256()

    def __call__(self, data: bytes) -> bytes:
        self.writes += 1
        if self.writes % self.every == 0:
            return b""
        self.wire.update(data)
        return data


def session(sleeping_line: bool) -> tuple:
    """Handshake, telemetry, commands and events over a line that loses frames (retransmissions both
    ways), the host gone past the link timeout (the watchdog), back again (a new session), a reset."""
    up, down = Dropper(6), Dropper(7)     # chosen so that both ends lose reliable frames and send them again
    config = ControllerConfig(link=LinkConfig(link_timeout_s=0.5, heartbeat_s=0.1))
    b = LockstepBench(seed=4, controller_config=config, to_controller=up, to_host=down, sleeping_line=sleeping_line)
    try:
        assert b.connect()
        assert b.call(M["SetTelemetryRate"](20)).ok and b.call(M["Enable"]()).ok
        for axis, speed in ((Axis.J1, 1.0), (Axis.MOUNT, -2.0)):
            assert b.call(M["Jog"](int(axis), speed)).ok
        assert b.call(M["Grip"](int(GripAction.CLOSE))).ok
        b.run_for(1.0)
        assert b.call(M["Stop"]()).ok
        b.run_for(0.5)
        event_retransmits = b.controller.link.stats.retransmits     # counted per session
        b.host_alive = False
        assert b.wait_until(lambda: b.controller.supervisor.state is ControllerState.FAULT, 1.0)
        b.run_for(0.3)
        b.host_alive = True
        assert b.connect()
        assert b.call(M["Reset"]()).ok
        b.run_for(0.5)
        runs = {name: task.stats.runs for name, task in b.world.scheduler.tasks.items()}
        return (up.wire.hexdigest(), down.wire.hexdigest(), b.clock.now(), b.world.plant.arm.pos_rad.tolist(),
                len(b.telemetry), len(b.events), b.host.stats.retransmits, event_retransmits), runs
    finally:
        b.close()


def test_a_sleeping_line_does_the_same_work_at_the_same_polls_as_a_polled_one():
    polled, polled_runs = session(sleeping_line=False)
    slept, slept_runs = session(sleeping_line=True)
    assert slept == polled
    assert polled[6] > 0 and polled[7] > 0           # both ends had to send again
    ticks = round(polled[2] * 1000)
    assert polled_runs["comms"] >= ticks and polled_runs["host"] >= ticks     # a poll every 1 ms
    # most polls found nothing to do: the sleeping tasks skipped them
    assert slept_runs["comms"] < 0.3 * polled_runs["comms"] and slept_runs["host"] < 0.3 * polled_runs["host"]
    assert slept_runs["arm"] == polled_runs["arm"]
