"""A live host: `HostLink` over any pyserial URL (or several redundant ones), pumped by a background thread.

The pump reads the line (`client/lines.py`: one port, or several joined frame by frame) with a short
timeout, feeds the link, runs its timers and writes what it queued. Callers `call()` a command and wait for
its single outcome; telemetry and events are kept and handed to listeners.
"""
from __future__ import annotations

import termios
import threading
from typing import Callable, Optional

import serial

from protocol.errors import LinkError
from protocol.host_link import CommandHandle, HostLink
from protocol.link import LinkConfig, LinkState
from protocol.reasons import Reason
from protocol.schema import Direction, Message
from timebase import Clock, RealClock

from host_tools.client.control import ControlClient
from host_tools.client.lines import open_lines
from host_tools.sessions.capture import CaptureWriter



class HostClient:
    """`control`: the simulator's control endpoint beside this link, if it has one (teleop's `sim` words); closed
    with the client."""

    def __init__(self, url: str, psk: bytes, *, baud: int = 115200, config: Optional[LinkConfig] = None,
                 clock: Optional[Clock] = None, capture: Optional[CaptureWriter] = None,
                 control: Optional[ControlClient] = None) -> None:
        self.clock = clock or RealClock()
        self.capture = capture      # every byte both ways, stamped with the wall clock's Unix time
        self.url = url
        self.control = control
        try:
            self.line = open_lines(url, baud, self.clock)
        except ValueError as exc:
            raise LinkError(Reason.NO_SESSION, str(exc)) from exc
        self.event_listeners: list[Callable[[Message, float], None]] = []
        self.telemetry_listeners: list[Callable[[Message, float], None]] = []
        self.events: list[Message] = []
        self.link = HostLink(psk, config, on_telemetry=self._telemetry, on_event=self._event)
        self.io_error: Optional[str] = None
        # the longest time between two turns of the pump (reading, the link's timers, writing): a host held up
        # that long sends nothing, heartbeats neither, whatever the controller does
        self.pump_pause_max_s = 0.0
        self._cond = threading.Condition()
        self._stop = False
        self._thread = threading.Thread(target=self._pump, name="aspod-link", daemon=True)
        self._thread.start()

    # ---- pump thread ----
    def _pump(self) -> None:
        last = self.clock.now()
        while not self._stop:
            try:
                data = self.line.read()
                with self._cond:
                    now = self.clock.now()
                    self.pump_pause_max_s = max(self.pump_pause_max_s, now - last)
                    last = now
                    if data:
                        if self.capture is not None:
                            self.capture.write("link", Direction.TO_HOST, data, RealClock.wall_time())
                        self.link.feed(data, now)
                    self.link.poll(now)
                    self._flush(now)
                    self._cond.notify_all()
            except (serial.SerialException, OSError) as exc:
                with self._cond:
                    self.io_error = str(exc)
                    self.link.abandon(self.clock.now(), f"{self.url}: {exc}")
                    self._cond.notify_all()
                return

    def _flush(self, now: float) -> None:
        """Write what the link queued (called with the lock held)."""
        out = self.link.take_all(now)
        if out:
            self.line.write(out)
            if self.capture is not None:
                self.capture.write("link", Direction.TO_CONTROLLER, out, RealClock.wall_time())

    def _telemetry(self, msg: Message, now: float) -> None:
        for listener in self.telemetry_listeners:
            listener(msg, now)

    def _event(self, msg: Message, now: float) -> None:
        self.events.append(msg)
        for listener in self.event_listeners:
            listener(msg, now)

    # ---- caller side ----
    def wait_for(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        """Wait (on the pump's notifications) until `predicate()` holds under the lock."""
        deadline = self.clock.now() + timeout_s
        with self._cond:
            while not predicate():
                left = deadline - self.clock.now()
                if left <= 0 or self.io_error is not None:
                    return predicate()
                self._cond.wait(min(left, 0.05))
            return True

    def connect(self, timeout_s: float = 10.0) -> None:
        """Handshake; raises `LinkError` with the reason if refused or unanswered."""
        with self._cond:
            self.link.connect(self.clock.now())
            self.link.poll(self.clock.now())
            self._flush(self.clock.now())
        settled = (LinkState.UP, LinkState.REFUSED, LinkState.SUSPENDED)
        self.wait_for(lambda: self.link.state in settled, timeout_s)
        with self._cond:
            if self.link.state is LinkState.UP:
                return
            if self.link.refusal is not None and self.link.refusal.reason is not Reason.LINK_SUSPENDED:
                raise LinkError(self.link.refusal.reason, self.link.refusal.detail)
            if self.link.stats.auth_errors:
                raise LinkError(Reason.BAD_MAC, f"{self.url} answers, but none of its {self.link.stats.auth_errors} "
                                "frame(s) verify under this key: the two ends have different keys (--key-file)")
            raise LinkError(Reason.LINK_SUSPENDED, self.io_error or f"no answer from {self.url} in {timeout_s} s")

    def submit(self, msg: Message) -> CommandHandle:
        with self._cond:
            now = self.clock.now()
            handle = self.link.submit(msg, now)
            try:
                self._flush(now)   # on the wire now, not after the pump's next read
            except (serial.SerialException, OSError) as exc:
                self.io_error = str(exc)      # the port is gone: the command fails now, with the reason
                self.link.abandon(now, f"{self.url}: {exc}")
                self._cond.notify_all()
            return handle

    def call(self, msg: Message, timeout_s: float = 30.0) -> CommandHandle:
        """Send `msg` and wait for its outcome (the link's retry limit ends it well before `timeout_s`)."""
        handle = self.submit(msg)
        self.wait_for(lambda: handle.done, timeout_s)
        return handle

    def close(self) -> None:
        """Stop the pump, send what the link still has queued, then close the port.

        What is queued may be the Acks of the last events: without them the controller offers those events
        again to the next host (marked as from an earlier session, but a host should not leave them behind).
        Unread input is discarded first, so that a TCP connection ends with FIN after the last bytes rather
        than with a reset, which may discard what is still in flight.
        """
        self._stop = True
        self._thread.join(timeout=2.0)
        with self._cond:
            try:
                self._flush(self.clock.now())
                self.line.reset_input_buffer()
            except (serial.SerialException, OSError, termios.error):
                pass                          # the port is gone already (a pty's tcflush: termios.error)
        self.line.close()
        if self.capture is not None:
            self.capture.close()
        if self.control is not None:
            self.control.close()
