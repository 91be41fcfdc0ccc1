"""Lock-step over the HAL bus: plant and controller in separate processes share one simulated time.

As in PX4's and ArduPilot's lock-step SITL, the plant owns simulated time and the controller
follows it tick by tick (docs/hal_bus.md, "Lock-step"):

1. The plant integrates tick N, sends its frames for it, and PLANT_SYNC(N) last.
2. The controller's time advances one tick per PLANT_SYNC. It runs every task due by then
   (its motor loops read the tick's feedback and send their commands), then answers
   CTRL_SYNC(N + 1): "my commands for your tick N + 1 are out".
3. The plant integrates tick N + 1 only once CTRL_SYNC(>= N + 1) has come (tick 0 is free).

So neither side ever sees the other's stalls as time passing: a descheduled process stops
both, and the world runs as fast as the slower of the two allows, up to the pace the plant
keeps (real time, `--speed X`, or as fast as possible). Frames lost on the bus (UDP
multicast can drop under load) cost only time: while the plant waits it sends its last
PLANT_SYNC again every `reoffer_s` of wall time, and the controller answers a PLANT_SYNC it
has already answered by sending its CTRL_SYNC again.

`SyncTap` wraps a node's python-can bus so that the clock sees the other side's sync frames
as they pass, whoever reads them; `LockstepFollower` is the controller's clock and
`LockstepLeader` the plant's. Both are `timebase.Clock`s driven through `advance(deadline,
wall_deadline)` (`timebase.scheduler.run_live`): they wait on the bus for the sync they
need, on the wall clock given to them, and return in time for the wall-clock tasks (the link
to the host, the parent-process watch) that share their thread.
"""
from __future__ import annotations

import math
from collections import deque
from typing import Any, Callable, Optional

import can

from protocol.hal import BusView, HalCodec
from timebase import Clock, PacedClock, RateMeter, TimingReport

REOFFER_S = 0.1          # the plant sends its last PLANT_SYNC again after this long without an answer
MAX_SYNC_GAP_TICKS = 100  # a PLANT_SYNC further ahead than this (or behind) is a new plant: resynchronise
MAX_HELD_FRAMES = 4096    # frames read while waiting, kept for the node's next poll


class SyncTap(BusView):
    """A python-can bus whose frames with id `sync_id` are shown to `on_sync` as they pass.

    The node polls it as it would the bus (`recv(timeout=0)`); the clock calls `wait(timeout_s)`
    to block for the next frame, which is then held (at most `MAX_HELD_FRAMES`; beyond that the
    oldest are dropped and counted in `dropped`) until the node's next poll, so no frame is lost
    to the wait. Everything else (`send`, `shutdown`, attributes) is the wrapped bus's.
    """

    def __init__(self, bus: Any, sync_id: int, on_sync: Callable[[can.Message], None]) -> None:
        super().__init__(bus)
        self.sync_id = sync_id
        self.on_sync = on_sync
        self._held: deque[Any] = deque()    # can.Message, or a can.CanError met while waiting
        self.dropped = 0

    def _seen(self, msg: Optional[can.Message]) -> Optional[can.Message]:
        if msg is not None and msg.arbitration_id == self.sync_id and not (
                msg.is_extended_id or msg.is_error_frame or msg.is_remote_frame):
            self.on_sync(msg)
        return msg

    def recv(self, timeout: Optional[float] = None) -> Optional[can.Message]:
        if self._held:
            held = self._held.popleft()
            if isinstance(held, can.CanError):
                raise held                  # met while waiting: the node's poll counts it (bus_errors)
            return held
        return self._seen(self.bus.recv(timeout))

    def wait(self, timeout_s: float) -> bool:
        """Block up to `timeout_s` for one frame; True if one came (held for the node's next poll).

        A `can.CanError` from the bus (udp_multicast: a datagram on the port that is not a frame) is
        held in the frame's place and raised at the node's next poll, which counts it in `bus_errors`
        as it does the errors its own reads meet; the wait itself never raises it."""
        try:
            msg: Any = self._seen(self.bus.recv(max(0.0, timeout_s)))
        except can.CanError as exc:
            msg = exc
        if msg is None:
            return False
        if len(self._held) >= MAX_HELD_FRAMES:
            self._held.popleft()
            self.dropped += 1
        self._held.append(msg)
        return True


class LockstepFollower(Clock):
    """The controller's clock in lock-step: its time advances one plant tick per PLANT_SYNC.

    Build it on the controller's bus and give the controller's HAL `tap` instead of the bus.
    Time starts at 0 and stands still until the first PLANT_SYNC; from then on each new tick
    grants one more `period_us` (taken from the frame). When the scheduler asks to go past
    what is granted, everything due has run: the clock sends CTRL_SYNC(tick + 1) and waits on
    the bus. Until the first PLANT_SYNC it sends CTRL_SYNC(0) every `REOFFER_S`, which a plant
    already waiting answers at once with its last PLANT_SYNC (a controller started after the
    plant picks it up without waiting for the plant's next re-offer). `stalled_s()` is how long (wall time) it has been waiting for the plant: the
    controller's watch turns a long wait into HAL_STALE (a plant that died freezes time, so
    only the wall clock can tell).
    """

    def __init__(self, bus: Any, wall: Clock, codec: Optional[HalCodec] = None) -> None:
        codec = codec or HalCodec()
        self.wall = wall
        self._sync = codec.layout("PLANT_SYNC", ("tick", "lockstep", "period_us"))
        self._done = codec.layout("CTRL_SYNC", ("tick",))
        self.tap = SyncTap(bus, self._sync.frame_id, self._on_sync)
        self._now = 0.0
        self._granted_s = -math.inf        # nothing may run before the plant's first tick
        self._grant_base_s = 0.0           # granted = base + ticks * period since the first PLANT_SYNC
        self._grant_ticks = 0
        self._half_tick_s = 0.0005
        self._period_s = 0.001             # the tick's length the last granting PLANT_SYNC said
        self.plant_tick: Optional[int] = None
        self.plant_lockstep: Optional[bool] = None   # what the last PLANT_SYNC said
        self._answered = True              # CTRL_SYNC sent for the last PLANT_SYNC
        self.resyncs = 0                   # ticks that jumped (a new plant, lost frames beyond MAX_SYNC_GAP_TICKS)
        self.old_syncs = 0                 # PLANT_SYNCs up to MAX_SYNC_GAP_TICKS behind the last: answered, granted nothing
        self.syncs_sent = 0
        self.send_errors = 0
        wall_now = wall.now()
        self._waiting_since: Optional[float] = wall_now
        self._first_grant: Optional[tuple[float, float]] = None
        self._hello_s = -math.inf          # wall time CTRL_SYNC(0) was last sent, before the first PLANT_SYNC
        self.meter = RateMeter(wall_now, 0.0)

    def now(self) -> float:
        return self._now

    def _on_sync(self, msg: can.Message) -> None:
        try:
            tick, lockstep, period_us = self._sync.unpack(msg.data)
        except ValueError:
            return                          # the node's poll counts it as a bad frame
        tick = int(tick)
        period_s = max(1, int(period_us)) * 1e-6
        self.plant_lockstep = bool(lockstep)
        last = self.plant_tick
        if last is not None:
            gap = (tick - last) & 0xFFFF_FFFF
            if gap == 0:                    # the plant is waiting for an answer it did not get
                if self._answered:
                    self._send_done()
                return
            if 0 < (last - tick) & 0xFFFF_FFFF <= MAX_SYNC_GAP_TICKS:
                # a tick just behind the last: a frame replayed or overtaken on the bus, not a new tick. It grants
                # nothing (taken as a new plant it granted a tick, and the plant's re-offer of its own tick that
                # the answer drew one more: two ticks ahead of the plant per such frame). It is answered, so a
                # plant counting again from below the last tick (restarted within its first ticks) is followed.
                self.old_syncs += 1
                self._send_sync((tick + 1) & 0xFFFF_FFFF)
                return
            if gap > MAX_SYNC_GAP_TICKS:
                self.resyncs += 1
                gap = 1
            if period_s != self._period_s:  # ticks from here on are this long: those granted keep their length
                self._grant_base_s, self._grant_ticks = self._granted_s, 0
        else:
            gap = 1
            self._grant_base_s, self._grant_ticks = self._now - period_s, 0   # the first tick grants the present moment
        self._period_s = period_s
        self._half_tick_s = period_s / 2
        self.plant_tick = tick
        self._grant_ticks += gap
        self._granted_s = self._grant_base_s + self._grant_ticks * period_s   # counted, not summed (no drift)
        self._answered = False
        self._waiting_since = None
        wall_now = self.wall.now()
        if self._first_grant is None:         # measured from the first tick: the wait for the plant is not slowness
            self._first_grant = (wall_now, self._now)
            self.meter = RateMeter(wall_now, self._now)
        self.meter.sample(wall_now, self._now)

    def _send_done(self) -> None:
        self._answered = True
        self._send_sync((self.plant_tick + 1) & 0xFFFF_FFFF)

    def _send_sync(self, tick: int) -> None:
        try:
            self.tap.send(self._done.message((tick,)), timeout=0)
        except can.CanError:
            self.send_errors += 1
            return
        self.syncs_sent += 1

    def sleep_until(self, deadline: float) -> None:
        self.advance(deadline, math.inf)

    def advance(self, deadline: float, wall_deadline: float) -> None:
        wall = self.wall
        while deadline > self._granted_s + self._half_tick_s:
            wall_now = wall.now()
            if self.plant_tick is None:
                if wall_now - self._hello_s >= REOFFER_S:
                    self._hello_s = wall_now
                    self._send_sync(0)      # "a controller is here": a waiting plant offers its tick at once
            elif not self._answered:
                self._send_done()           # everything due by the granted time has run
            if self._waiting_since is None:
                self._waiting_since = wall_now
            left = wall_deadline - wall_now
            if not self.tap.wait(max(0.0, min(left, REOFFER_S))) and left <= 0:
                return                      # nothing came, and the wall clock's tasks are due
        if deadline > self._now:
            self._now = float(deadline)

    def stalled_s(self) -> float:
        """Wall seconds spent waiting for the plant's next tick (0 while time is granted)."""
        since = self._waiting_since
        return 0.0 if since is None else max(0.0, self.wall.now() - since)

    def timing(self) -> TimingReport:
        wall_now = self.wall.now()
        lag = 0.0
        if self._first_grant is not None:
            wall0, sim0 = self._first_grant
            lag = max(0.0, (wall_now - wall0) - (self._now - sim0))
        return TimingReport("lockstep", self.meter.recent(wall_now, self._now), self.meter.total(wall_now, self._now),
                            lag)


class LockstepLeader(Clock):
    """The plant's clock in lock-step: paced by `pace` (a `PacedClock`), gated by the controller's CTRL_SYNC.

    Time may reach tick N (N * `period_s`) only once CTRL_SYNC(>= N) has come; tick 0 is free.
    While it waits it calls `reoffer()` (the plant sends its last PLANT_SYNC again) every
    `reoffer_s` of wall time. Give the plant node `tap` instead of its bus.
    """

    def __init__(self, bus: Any, pace: PacedClock, period_s: float, reoffer: Callable[[], None],
                 codec: Optional[HalCodec] = None, reoffer_s: float = REOFFER_S) -> None:
        if not period_s > 0:
            raise ValueError(f"period_s must be > 0, got {period_s}")
        codec = codec or HalCodec()
        self.pace = pace
        self.wall = pace.wall
        self.period_s = period_s
        self.reoffer = reoffer
        self.reoffer_s = reoffer_s
        self._done = codec.layout("CTRL_SYNC", ("tick",))
        self.tap = SyncTap(bus, self._done.frame_id, self._on_done)
        self.controller_tick = 0           # the highest tick the controller has released
        self.reoffers = 0
        self.ignored = 0                   # CTRL_SYNC for ticks this plant never published
        self._waiting_since: Optional[float] = None
        self._offered_s = 0.0              # wall time of the last PLANT_SYNC sent again

    def now(self) -> float:
        return self.pace.now()

    def _on_done(self, msg: can.Message) -> None:
        try:
            (tick,) = self._done.unpack(msg.data)
        except ValueError:
            return
        published = round(self.pace.now() / self.period_s)    # the plant's last tick: its time is that tick's
        # the frame carries the tick modulo 2**32 (49.7 days at 1 kHz): take the one nearest the plant's
        tick = published + ((int(tick) - published + 0x8000_0000) & 0xFFFF_FFFF) - 0x8000_0000
        if tick > published + 1:
            self.ignored += 1               # beyond anything this plant published: a stale answer to another plant
        elif tick > self.controller_tick:
            self.controller_tick = tick
        else:
            self._offered_s = -math.inf     # a controller that has not seen our last PLANT_SYNC: offer it now

    def granted_s(self) -> float:
        return self.controller_tick * self.period_s

    def sleep_until(self, deadline: float) -> None:
        self.advance(deadline, math.inf)

    def advance(self, deadline: float, wall_deadline: float) -> None:
        wall = self.wall
        half = self.period_s / 2
        while deadline > self.granted_s() + half:
            wall_now = wall.now()
            if self._waiting_since is None:
                self._waiting_since = self._offered_s = wall_now
            if wall_now - self._offered_s >= self.reoffer_s:
                self.reoffer()
                self.reoffers += 1
                self._offered_s = wall_now
            left = wall_deadline - wall_now
            if not self.tap.wait(max(0.0, min(left, self.reoffer_s - (wall_now - self._offered_s)))) and left <= 0:
                return                      # nothing came, and the wall clock's tasks are due
        self._waiting_since = None
        self.pace.advance(deadline, wall_deadline)

    def stalled_s(self) -> float:
        """Wall seconds spent waiting for the controller's CTRL_SYNC (0 while not waiting)."""
        since = self._waiting_since
        return 0.0 if since is None else max(0.0, self.wall.now() - since)

    def timing(self) -> TimingReport:
        report = self.pace.timing()
        return TimingReport("lockstep", report.rtf_recent, report.rtf_total, report.lag_s, report.slipped_s)
