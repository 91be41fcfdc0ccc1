"""Fuzzing your own controller with `aspod fuzz` (docs/fuzzing.md, "Your own code").

A controller of a user's own on this project's link (`protocol.controller_link.ControllerLink`): a lamp dimmer with
handlers of its own for Ping, ParamGet and ParamSet (two parameters, `gain` and `level`) that refuses every other
command. Its ParamSet handler has a real bug: setting `gain` works out the lamp's step as `level / gain` without
looking at the value first, so `gain` 0 raises ZeroDivisionError inside the controller.

The fuzz target holds the host's end (`protocol.host_link.HostLink`) and the key, connected to the controller in
memory on a simulated clock, so every command it sends is authentic and in sequence and reaches a handler; the
payloads come from the project's grammar (`host_tools.fuzz.grammar`), with the controller's parameter names as the
words for the `name` field:

    aspod fuzz examples/fuzz_controller.py:target --runs 20000

finds the bug (a ParamSet of `gain` 0) and saves every command since the world was built, shrunk.
"""
from __future__ import annotations

import math
from types import MappingProxyType

from protocol.controller_link import ControllerLink
from protocol.host_link import HostLink
from protocol.link import LinkState
from protocol.messages import SCHEMA
from protocol.reasons import Reason

KEY = bytes(range(32))                 # the link's key; both ends hold it
TICK_S = 0.001


class DimmerController:
    """The user's controller: its state, and one handler a command, as `ControllerLink` calls them."""

    LIMITS = {"gain": (0.0, 10.0), "level": (0.0, 100.0)}

    def __init__(self, key: bytes) -> None:
        self.values = {"gain": 1.0, "level": 50.0}
        self.step = 50.0
        self.link = ControllerLink(key, self.handle)

    def handle(self, msg, urgent: bool, now: float):
        name = msg.spec.name
        if name == "Ping":
            return SCHEMA["Pong"].type(Reason.OK, msg.token, int(now * 1000) & 0xFFFFFFFF)
        if name in ("ParamGet", "ParamSet"):
            return self._param(msg, name == "ParamSet")
        return SCHEMA["Result"].type(Reason.UNKNOWN_MESSAGE)     # not a command this controller has

    def _param(self, msg, setting: bool):
        names = list(self.values)
        if msg.name not in self.values:
            return SCHEMA["ParamValue"].type(Reason.UNKNOWN_PARAM, msg.name, 0.0, 0.0, 0.0, 0, len(names), "", "")
        lo, hi = self.LIMITS[msg.name]
        result = Reason.OK
        if setting and not lo <= msg.value <= hi:
            result = Reason.OUT_OF_RANGE
        elif setting:
            self.values[msg.name] = msg.value
            self.step = self.values["level"] / self.values["gain"]    # the bug: gain 0 is in range
        return SCHEMA["ParamValue"].type(result, msg.name, self.values[msg.name], lo, hi, names.index(msg.name),
                                         len(names), "", "")


class DimmerTarget:
    """The controller behind a live session: each input is a few commands from the grammar, sent in sequence by
    the host. Oracles: nothing escapes the controller; every command is answered (by its reply or a refusal)."""

    stateful = True                    # one world between inputs, built anew every `fresh_every`
    fresh_every = 200
    words = MappingProxyType({"name": ("gain", "level")})
    commands = tuple(SCHEMA[n] for n in ("Ping", "ParamGet", "ParamSet", "Enable", "GetStatus"))

    def fresh(self) -> None:
        self.now = 0.0
        self.controller = DimmerController(KEY)
        self.host = HostLink(KEY)
        self.host.connect(self.now)
        self._run(lambda: self.host.state is LinkState.UP, 5.0)

    def _run(self, done, most_s: float) -> bool:
        """Both ends, tick by tick on the simulated clock, until `done()` or `most_s` simulated seconds pass."""
        end = self.now + most_s
        while not done():
            if self.now > end:
                return False
            self.now += TICK_S
            for side, other in ((self.host, self.controller.link), (self.controller.link, self.host)):
                side.poll(self.now)
                data = side.take_all(self.now)
                if data:
                    other.feed(data, self.now)
        return True

    def one_input(self, data: bytes) -> None:
        from host_tools.fuzz.grammar import FdpDraw, draw_payload
        draw = FdpDraw(data)
        handles = []
        for _ in range(1 + draw.pick(3)):
            spec = self.commands[draw.pick(len(self.commands))]
            handles.append(self.host.submit_payload(spec, draw_payload(spec, draw, self.words), self.now))
        if not self._run(lambda: all(h.done for h in handles), 5.0):
            raise AssertionError(f"a command not answered in 5 simulated s: {[h.describe() for h in handles]}")
        if not all(math.isfinite(v) for v in self.controller.values.values()):
            raise AssertionError(f"a parameter not finite: {self.controller.values}")


def target() -> DimmerTarget:
    return DimmerTarget()
