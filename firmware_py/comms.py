"""The comms task: moves bytes between the paced UART and the link endpoint.

Each run: bytes the line has delivered -> `link.feed`; `link.poll` (timers,
retransmits, heartbeats, the link watchdog); then, while the transmitter is idle,
the next frame -> the wire. It polls every `poll_period_s` (1 ms by default), and runs
sooner when a frame it sends finishes on the wire or a frame it receives has fully
arrived. While a frame is arriving it starts no telemetry frame, so the line is free
for the reply (telemetry is held at most `max_telemetry_hold_s`).

Over a port that says when bytes arrive (`notifies`: `BufferPort`, the lock-step world's line)
it skips the polls that would find nothing, which are most of them (a frame takes
4-8 ms on the wire at 115200 baud, telemetry goes at 10 Hz): while no bytes are arriving
it sleeps until the poll that would first have seen something. That is the poll after
bytes arrived or another task gave the link work (a frame or an event queued:
`LinkEndpoint.on_work`), the first poll at or after the link's next timer
(`LinkEndpoint.next_timer_s`: heartbeat, retransmission, watchdog), and at least every
`max_idle_s`; the end of a frame on the wire wakes it as before. So it sees everything
at the same poll as a task that never slept (`scheduler.poll_tick`), and the world
runs as it did when it polled.

Its own stalls are not the host's silence, but they do not hide it either. When a run starts
more than `excused_after_s` after the time it asked for (the process was descheduled, the host
is overloaded), what the host sent meanwhile is still in the OS buffer and starts arriving now,
at line rate. So the link watchdog may not fire until one longest frame (plus a poll) after the
run (`stall_grace_s`): a host that sent anything during the stall is heard first. The watchdog's
count moves forward by never more than the stall (`stalls_excused_s` sums it), and since the host's
last frame by never more in all than the longest stall and one grace: a controller late at every run
(an overloaded host: each run a stall of its own) does not renew the excuse at every run. So a dead
host is still found one link timeout after its last frame, plus at most its longest stall and a
grace, however often the controller is stopped.
"""
from __future__ import annotations

from typing import Callable, Optional

from protocol.framing import MAX_ENCODED
from protocol.link import LinkEndpoint
from timebase.scheduler import poll_tick

from firmware_py.uart import PacedUart


class CommsTask:
    def __init__(self, link: LinkEndpoint, uart: PacedUart, poll_period_s: float = 0.001,
                 max_telemetry_hold_s: float = 0.05, max_idle_s: float = 0.05, excused_after_s: float = 0.05) -> None:
        self.link = link
        self.uart = uart
        self.poll_period_s = poll_period_s
        self.max_telemetry_hold_s = max_telemetry_hold_s
        self.max_idle_s = max_idle_s
        self._holding_since: float | None = None
        self.sleeps = getattr(uart.port, "notifies", False)     # the port says when bytes arrive
        self._wake: Callable[[float], None] = lambda at_s: None
        self._now: Callable[[], float] = lambda: 0.0
        self._last_s: Optional[float] = None
        self._running = False
        self.excused_after_s = excused_after_s
        self._asked_s: Optional[float] = None    # the wake time the last run asked for
        self.stall_grace_s = uart.wire_time_s(MAX_ENCODED + 1) + poll_period_s   # one longest frame, one poll
        self.stalls_excused_s = 0.0
        self._judged_rx: Optional[float] = None       # the last frame's time as the last step left it
        self._longest_stall_s = 0.0                    # since the last frame: the longest stall ...
        self._excused_since_rx_s = 0.0                 # ... and the excuses granted

    def attach(self, wake: Callable[[float], None], now: Callable[[], float]) -> None:
        """`wake(at_s)` brings this task's next run forward to `at_s` (the scheduler's `wake` for it)."""
        if self.sleeps:
            self._wake, self._now = wake, now
            self.uart.port.on_input = self._work
            self.link.on_work = self._work

    def _work(self) -> None:
        """Bytes arrived or the link has work: run at the next poll (during a run, the run sees to it)."""
        if not self._running:
            now = self._now()
            self._wake(now if self._last_s is None else poll_tick(self._last_s, self.poll_period_s, now, after=True))

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
        self._running = True
        self._last_s = now
        asked = self._asked_s
        last_rx = self.link.last_valid_rx_s
        if last_rx != self._judged_rx:                 # a frame came since the last excuse: they begin again
            self._longest_stall_s = self._excused_since_rx_s = 0.0
        if asked is not None and now - asked > self.excused_after_s and last_rx is not None:
            # hear out what the host sent while we were stopped before judging its silence; since the last frame,
            # never more in all than the longest stall and a grace (a controller late at every run would otherwise
            # renew the excuse at every run, and find a dead host late or never)
            stall = now - asked
            self._longest_stall_s = max(self._longest_stall_s, stall)
            heard_by = now + self.stall_grace_s - self.link.config.link_timeout_s
            excused = min(stall, heard_by - last_rx,
                          self._longest_stall_s + self.stall_grace_s - self._excused_since_rx_s)
            if excused > 0:
                self.link.last_valid_rx_s = last_rx + excused
                self.stalls_excused_s += excused
                self._excused_since_rx_s += excused
        self._judged_rx = self.link.last_valid_rx_s
        try:
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
        finally:
            self._running = False
        wake = now + self.poll_period_s
        if self.sleeps and not self.uart.rx_busy:     # while a frame arrives it polls, as ever
            wake = poll_tick(now, self.poll_period_s, min(self.link.next_timer_s(), now + self.max_idle_s))
        for deadline in (self.uart.next_tx_deadline(), self.uart.next_rx_deadline()):
            if deadline is not None and now < deadline < wake:
                wake = deadline
        self._asked_s = wake
        return wake
