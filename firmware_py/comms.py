"""The comms task: moves bytes between the paced UART and the link endpoint.

Each run: bytes the line has delivered -> `link.feed`; `link.poll` (timers,
retransmits, heartbeats, the link watchdog); then, while the transmitter is idle,
the next frame -> the wire. It wakes every `poll_period_s` (1 ms by default), or
sooner: when a frame it sends finishes on the wire, or when a frame it receives
has fully arrived. While a frame is arriving it starts no telemetry frame, so the
line is free for the reply (telemetry is held at most `max_telemetry_hold_s`).
"""
from __future__ import annotations

from protocol.link import LinkEndpoint

from firmware_py.uart import PacedUart


class CommsTask:
    def __init__(self, link: LinkEndpoint, uart: PacedUart, poll_period_s: float = 0.001,
                 max_telemetry_hold_s: float = 0.05) -> None:
        self.link = link
        self.uart = uart
        self.poll_period_s = poll_period_s
        self.max_telemetry_hold_s = max_telemetry_hold_s
        self._holding_since: float | None = None

    def _telemetry_may_start(self, now: float) -> bool:
        """Not while a request is arriving: a frame on the wire cannot be pre-empted, and
        the reply would wait behind it. Held at most `max_telemetry_hold_s`."""
        if not self.uart.rx_busy:
            self._holding_since = None
            return True
        if self._holding_since is None:
            self._holding_since = now
        return now - self._holding_since >= self.max_telemetry_hold_s

    def step(self, now: float) -> float:
        data = self.uart.receive(now)
        if data:
            self.link.feed(data, now)
        self.link.poll(now)
        telemetry = self._telemetry_may_start(now)
        while self.uart.tx_idle(now):
            frame = self.link.take_frame(now, telemetry)
            if frame is None:
                break
            self.uart.transmit(frame, now)
        self.uart.flush(now)
        wake = now + self.poll_period_s
        for deadline in (self.uart.next_tx_deadline(), self.uart.next_rx_deadline()):
            if deadline is not None and now < deadline < wake:
                wake = deadline
        return wake
