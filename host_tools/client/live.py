"""A live host: `HostLink` over any pyserial URL (or several redundant ones), pumped by a background thread.

The pump reads the line (`client/lines.py`: one port, or several joined frame by frame) with a short
timeout, feeds the link, runs its timers and writes what it queued. Callers `call()` a command and wait for
its single outcome; telemetry and events are kept and handed to listeners.
"""
from __future__ import annotations

import logging
import termios
import threading
from typing import Callable, Optional

import serial

from protocol.errors import LinkError
from protocol.host_link import CommandHandle, HostLink
from protocol.link import LinkConfig, LinkState
from protocol.reasons import Reason
from protocol.schema import Direction, Message
from protocol.states import CloseWhy
from timebase import Clock, RealClock

from host_tools.client.control import ControlClient
from host_tools.client.lines import open_lines
from host_tools.sessions.capture import CaptureWriter

log = logging.getLogger("aspod")
CLOSE_WAIT_MIN_S = 1.0
CLOSE_WAIT_MAX_S = 30.0


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
        self._closed = False
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
        self._tell(self.telemetry_listeners, msg, now)

    def _event(self, msg: Message, now: float) -> None:
        self.events.append(msg)
        self._tell(self.event_listeners, msg, now)

    def _tell(self, listeners: list, msg: Message, now: float) -> None:
        """Hand `msg` to each listener. One that raises is logged with its traceback and the others still hear it:
        before, it ended the pump thread, the link went silent for good, and every later call waited its whole
        timeout with nothing to say why (found by `aspod fuzz --as-controller`, docs/fuzzing.md)."""
        for listener in listeners:
            try:
                listener(msg, now)
            except Exception:      # noqa: BLE001 (the caller's bug: said, and the link goes on)
                log.exception(f"aspod: a listener of {msg.spec.name} on {self.url} raised; the link goes on")

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
            link = self.link
            if link.refusal is not None and link.refusal.reason is not Reason.LINK_SUSPENDED:
                raise LinkError(link.refusal.reason, link.refusal.detail)
            if self.io_error is not None:
                raise LinkError(Reason.LINK_SUSPENDED, self.io_error)
            seen = link.handshake_seen
            why = seen.why_not_up(link.hellos_sent, link.stats.auth_errors, link.stats.bytes_rx)
            reason = Reason.BAD_MAC if seen.verified == 0 and link.stats.auth_errors else Reason.LINK_SUSPENDED
            raise LinkError(reason, f"{self.url}: no session in {timeout_s:g} s: {why}")

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

    def close_session(self, why: CloseWhy = CloseWhy.DONE) -> bool:
        """End the session cleanly (`HostLink.close`): a Close after the commands already sent, then the
        controller's events up to its last; True once it is CLOSED. Waits at most `close_wait_s` (the
        controller's link timeout, twice: a controller that answers nothing for so long has long faulted)."""
        with self._cond:
            if self.link.state is not LinkState.UP or self.io_error is not None or not self._thread.is_alive():
                return self.link.state is LinkState.CLOSED
            now = self.clock.now()
            self.link.close(now, why)
            try:
                self._flush(now)
            except (serial.SerialException, OSError) as exc:
                self.io_error = str(exc)
                self.link.abandon(now, f"{self.url}: {exc}")
                return False
        return self.wait_for(lambda: self.link.state is not LinkState.CLOSING, self.close_wait_s()) and \
            self.link.state is LinkState.CLOSED

    def close_wait_s(self) -> float:
        info = self.link.controller_info
        timeout_s = info.link_timeout_ms / 1000.0 if info is not None else 3.0
        return min(CLOSE_WAIT_MAX_S, max(CLOSE_WAIT_MIN_S, 2 * timeout_s))

    def close(self, why: CloseWhy = CloseWhy.DONE) -> None:
        """Close the session (`close_session`, if it is up), stop the pump, send what the link still has queued,
        then close the port.

        What is queued may be the Acks of the last events: without them the controller offers those events
        again to the next host (marked as from an earlier session, but a host should not leave them behind).
        Unread input is discarded first, so that a TCP connection ends with FIN after the last bytes rather
        than with a reset, which may discard what is still in flight.
        """
        if self._closed:
            return                            # closed already (teleop's `connect URL` left it for another)
        self._closed = True
        try:
            self.close_session(why)
        finally:
            self._shut()

    def _shut(self) -> None:
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
