"""The comms task: moves bytes between the paced UART and the link endpoint.

Each run: bytes the line has delivered -> `link.feed`; `link.poll` (timers,
retransmits, heartbeats, the link watchdog); then, while the transmitter is idle,
the next frame -> the wire. It wakes every `poll_period_s` (1 ms by default), or
sooner when a frame finishes on the wire.
"""
from __future__ import annotations

from protocol.link import LinkEndpoint

from firmware_py.uart import PacedUart


class CommsTask:
    def __init__(self, link: LinkEndpoint, uart: PacedUart, poll_period_s: float = 0.001) -> None:
        self.link = link
        self.uart = uart
        self.poll_period_s = poll_period_s

    def step(self, now: float) -> float:
        data = self.uart.receive(now)
        if data:
            self.link.feed(data, now)
        self.link.poll(now)
        while self.uart.tx_idle(now):
            frame = self.link.take_frame(now)
            if frame is None:
                break
            self.uart.transmit(frame, now)
        self.uart.flush(now)
        wake = now + self.poll_period_s
        deadline = self.uart.next_deadline()
        return min(wake, deadline) if deadline is not None and deadline > now else wake
