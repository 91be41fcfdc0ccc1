"""Teleop's pause (`wait SECONDS`) and `box`'s wait for a fresh reading count the controller's seconds where its time
is simulated, as `wait all` and `wait aligned` do: a script that passes on a fast machine passes on a slow one.

The client here is a stand-in on a SimClock whose controller runs at a quarter of real time (a paced world on a busy
machine), with a TelemetryStatus every 100 ms of its own time and, from 0.3 s on, a TelemetryTracker beside it. Under
load the box's first reading came after the 0.5 s of wall time `box` waited (tests/test_sim_sun_options.py)."""
from __future__ import annotations

import io
from types import SimpleNamespace

from host_tools.teleop.session import Session
from host_tools.teleop.words import parse_line
from protocol.link import LinkState
from protocol.messages import SCHEMA
from protocol.states import TimingMode
from timebase import SimClock

RTF = 0.25


def _message(name: str, **values):
    spec = SCHEMA[name]
    return spec.type(**{f.name: values.get(f.name, 0) for f in spec.fields})


class SlowController:
    """What Session uses of a client; its controller's time runs at RTF of the (simulated) wall clock."""

    def __init__(self) -> None:
        self.clock = SimClock()
        self.io_error = None
        self.telemetry_listeners, self.event_listeners = [], []
        self.link = SimpleNamespace(state=LinkState.UP, stats=SimpleNamespace(crc_errors=0, auth_errors=0),
                                    event_from_earlier_session=False)
        self.uptime_ms = 0

    def tick(self) -> None:
        """100 ms of the controller's time: its telemetry."""
        self.clock.advance_by(0.1 / RTF)
        self.uptime_ms += 100
        said = [_message("TelemetryStatus", uptime_ms=self.uptime_ms, timing=int(TimingMode.PACED), rtf_recent=RTF)]
        if self.uptime_ms >= 300:
            said.append(_message("TelemetryTracker", uptime_ms=self.uptime_ms))
        for msg in said:
            for listener in list(self.telemetry_listeners):
                listener(msg, self.clock.now())

    def wait_for(self, predicate, timeout_s: float) -> bool:
        end = self.clock.now() + timeout_s
        while not predicate():
            if self.clock.now() >= end:
                return False
            self.tick()
        return True


def test_a_pause_is_the_controllers_seconds():
    client = SlowController()
    session = Session(client, io.StringIO())
    client.tick()                                        # the session's first TelemetryStatus
    start_s, start_ms = client.clock.now(), client.uptime_ms
    assert session.run_step(parse_line("wait 1", 1))
    assert client.uptime_ms - start_ms >= 1000           # (a second of the wall clock was 250 ms of the controller's)
    assert client.clock.now() - start_s >= 1.0 / RTF - 1e-9


def test_box_waits_for_a_reading_in_the_controllers_seconds():
    client = SlowController()
    out = io.StringIO()
    session = Session(client, out)
    client.tick()                                        # no TelemetryTracker yet: it comes 0.2 s of its time later
    assert session.run_step(parse_line("box", 1))
    assert "no TelemetryTracker yet" not in out.getvalue(), out.getvalue()
