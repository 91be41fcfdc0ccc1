"""The hostile controller (`aspod fuzz --as-controller`, host_tools/fuzz/hostile.py) against real hosts over real
ptys: `aspod teleop`, a ground tool on `HostClient` and its copy with a planted defect; and what it found in teleop.

Every wait on a host is judged on the host's own time (host_tools/worlds/own_time.py), never on the wall clock."""
from __future__ import annotations

import io
from types import SimpleNamespace

from host_tools.teleop.session import Session
from host_tools.teleop.words import parse_line
from protocol.host_link import CommandHandle
from protocol.link import LinkState
from protocol.messages import SCHEMA
from protocol.reasons import Reason
from protocol.reliable import Outcome
from timebase import SimClock


class RefusingController:
    """What teleop's Session uses of a client: every command refused by a `Result` (a reply the protocol allows for
    any command: docs/protocol.md)."""

    def __init__(self, reason: Reason) -> None:
        self.reason = reason
        self.clock = SimClock()
        self.io_error = None
        self.telemetry_listeners, self.event_listeners = [], []
        self.link = SimpleNamespace(state=LinkState.UP, stats=SimpleNamespace(crc_errors=0, auth_errors=0),
                                    event_from_earlier_session=False)

    def call(self, msg, timeout_s: float = 30.0) -> CommandHandle:
        handle = CommandHandle(msg, self.clock.now())
        handle._finish(Outcome.REJECTED, self.reason, self.clock.now(), SCHEMA["Result"].type(int(self.reason)))
        return handle


def test_teleop_says_a_motion_refused_by_a_result_and_goes_on():
    """Found by the hostile controller: a Move refused with a `Result` (not a MotionAccepted) crashed teleop, which
    read the refusal's `limit` (AttributeError: 'Result' object has no attribute 'limit'). A controller answers so
    whenever a command's payload does not decode (protocol/controller_link.py)."""
    for reason in (Reason.OUT_OF_RANGE, Reason.NOT_ALLOWED_IN_STATE):
        out = io.StringIO()
        session = Session(RefusingController(reason), out)
        assert not session.run_step(parse_line("move j1 10", 1))
        assert reason.name in out.getvalue()
