"""A controller of the link alone, for `aspod conform --host` (a host implementation connects to it) and for the
suite's own tests (controllers broken in one rule each are this one with its link patched).

`PlayedController` is a `ControllerLink` (or a class given) with a small application: Ping, GetStatus, Reset,
Enable, Disable, SetTelemetryRate (TelemetryStatus at that rate), one harmless parameter (`toy_gain`), EStop,
Stop, Close; the link's loss latches LINK_LOST in FAULT; everything else is refused NOT_ALLOWED_IN_STATE. It has
no plant: it drives nothing. `serve(port, done)` runs it on a port of host_tools/worlds/ports.py (a pty, a TCP
server, a device) in the caller's thread until `done()`, on the wall clock.
"""
from __future__ import annotations

from typing import Callable, Optional

from protocol.controller_link import ControllerLink
from protocol.framing import FrameReceiver
from protocol.link import LinkConfig
from protocol.messages import SCHEMA
from protocol.reasons import Reason
from protocol.schema import Message
from protocol.states import ControllerState, Fault
from timebase import Clock, RealClock

M = SCHEMA
PARAM, PARAM_LO, PARAM_HI = "toy_gain", 0.0, 10.0
IDLE_WAIT_S = 0.001           # the serving loop's pause when the line and the link have nothing


class PlayedController:
    def __init__(self, psk: bytes, link_class=ControllerLink, config: Optional[LinkConfig] = None,
                 failsafe: bool = True, receiver: Optional[FrameReceiver] = None, clock: Optional[Clock] = None,
                 on_frame_out: Callable[[bytes, float], None] = lambda wire, now: None,
                 on_bytes_in: Callable[[bytes, float], None] = lambda data, now: None) -> None:
        self.psk = psk
        self.clock = clock or RealClock()
        self.started_s = self.clock.now()
        self.state, self.faults = ControllerState.IDLE, 0
        self.telemetry_hz, self.gain = 10, 1.0
        self.failsafe = failsafe
        self.link = link_class(psk, self.execute, config or LinkConfig(), on_link_lost=self.lost)
        if receiver is not None:
            self.link._rx = receiver
        self.on_frame_out = on_frame_out      # each frame as it goes out (a watcher of the host)
        self.on_bytes_in = on_bytes_in        # what came from the host, before the link has it
        self.drop: Callable[[bytes, float], bool] = lambda wire, now: False   # True: this frame never goes out
        self.injected: list[bytes] = []       # frames made outside the link, written at the next turn
        self._telemetry_due = 0.0

    def uptime_ms(self) -> int:
        return int((self.clock.now() - self.started_s) * 1000) & 0xFFFFFFFF

    def _change(self, state: ControllerState, reason: Reason) -> None:
        old, self.state = self.state, state
        self.link.send_event(M["StateChanged"].type(int(state), int(old), int(reason), self.faults, self.uptime_ms()))

    def lost(self, now: float) -> None:
        if self.failsafe:
            self.faults |= Fault.LINK_LOST
            self._change(ControllerState.FAULT, Reason.LINK_TIMEOUT)

    def _param(self, name: str, value: Optional[float]) -> Message:
        if name != PARAM:
            return M["ParamValue"].type(int(Reason.UNKNOWN_PARAM), name, 0.0, 0.0, 0.0, 0, 1, "", "")
        reason = Reason.OK
        if value is not None:
            if PARAM_LO <= value <= PARAM_HI:
                self.gain = value
            else:
                reason = Reason.OUT_OF_RANGE
        return M["ParamValue"].type(int(reason), PARAM, self.gain, PARAM_LO, PARAM_HI, 0, 1, "",
                                    "a number that changes nothing")

    def execute(self, msg: Message, urgent: bool, now: float) -> Message:
        """The application: one command in, its reply out (the link calls it once per sequence number)."""
        name, ok = msg.spec.name, int(Reason.OK)
        if name == "Ping":
            return M["Pong"].type(ok, msg.token, self.uptime_ms())
        if name == "GetStatus":
            return M["Status"].type(ok, int(self.state), self.faults, 0, self.uptime_ms(), 28.0, 25.0,
                                    self.link.commands_executed & 0xFFFFFFFF, self.telemetry_hz, 0, 0.0, 0.0, 0.0)
        if name == "SetTelemetryRate":
            self.telemetry_hz = msg.rate_hz
            return M["Result"].type(ok)
        if name == "ParamList":
            if msg.index != 0:
                return M["ParamValue"].type(int(Reason.OUT_OF_RANGE), "", 0.0, 0.0, 0.0, 0, 1, "", "")
            return self._param(PARAM, None)
        if name in ("ParamGet", "ParamSet"):
            return self._param(msg.name, msg.value if name == "ParamSet" else None)
        if name == "EStop":
            self.faults |= Fault.ESTOP
            self._change(ControllerState.ESTOP, Reason.HOST_REQUEST)
            return M["Result"].type(ok)
        if name == "Reset":
            self.faults = 0
            if self.state is not ControllerState.IDLE:
                self._change(ControllerState.IDLE, Reason.HOST_REQUEST)
            return M["Result"].type(ok)
        if name in ("Enable", "Disable"):
            state = ControllerState.ENABLED if name == "Enable" else ControllerState.IDLE
            if self.state in (ControllerState.IDLE, ControllerState.ENABLED) and state is not self.state:
                self._change(state, Reason.HOST_REQUEST)
            return M["Result"].type(ok if self.state is state else int(Reason.NOT_ALLOWED_IN_STATE))
        if name == "Stop":
            return M["Result"].type(ok)
        if name == "Close":
            if self.state is ControllerState.ENABLED:
                self._change(ControllerState.IDLE, Reason.HOST_REQUEST)
            self.telemetry_hz = 10
            self.link.send_event(M["SessionClosed"].type(msg.why, int(self.state), self.faults, self.uptime_ms()))
            self.link.close_session()
            return M["Closed"].type(ok, int(self.state), self.faults, self.link.last_event_seq,
                                    int(self.link.config.link_timeout_s * 1000))
        return M["Result"].type(int(Reason.NOT_ALLOWED_IN_STATE))

    def _telemetry(self, now: float) -> None:
        if self.telemetry_hz == 0 or self.link.quiet or self.link.session is None or now < self._telemetry_due:
            return
        self._telemetry_due = max(self._telemetry_due + 1.0 / self.telemetry_hz, now - 0.5)
        self.link.send_telemetry(M["TelemetryStatus"].type(
            self.uptime_ms(), int(self.state), 0, self.faults, 28.0, 25.0, self.link.commands_executed & 0xFFFFFFFF,
            0, 0, 0, 0, 0, 0, 0, 0, 0.0, 0.0))

    def step(self, port) -> bool:
        """One turn on `port`: read, feed, timers, telemetry, write; True if anything moved."""
        data = port.read(4096)
        now = self.clock.now()
        if data:
            self.on_bytes_in(data, now)
            self.link.feed(data, now)
        self.link.poll(now)
        self._telemetry(now)
        moved = bool(data)
        while (wire := self.link.take_frame(now)) is not None:
            moved = True
            self.on_frame_out(wire, now)
            if not self.drop(wire, now):
                _write_all(port, wire, self.clock)
        while self.injected:
            moved = True
            _write_all(port, self.injected.pop(0), self.clock)
        return moved

    def serve(self, port, done: Callable[[], bool]) -> None:
        """Serve `port` until `done()`."""
        if hasattr(port, "live_session"):         # a TCP server: it admits by what a client proves
            port.live_session = lambda: self.link.session if not self.link.link_lost else None
            port.vouch = self.link.vouch
        while not done():
            if not self.step(port):
                self.clock.sleep(IDLE_WAIT_S)


def _write_all(port, data: bytes, clock: Clock, bound_s: float = 2.0) -> None:
    """Write all of `data` (a port may take part of it), giving up after `bound_s` (nobody reads: the bytes are
    gone, as on a real line)."""
    until = clock.now() + bound_s
    while data and clock.now() < until:
        sent = port.write(data)
        data = data[sent:]
        if data:
            clock.sleep(IDLE_WAIT_S)
