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

A controller waiting for the plant's tick cannot tell from its own time, which stands still, whether the plant
is gone or only slow. `stalled_s()` says how long the plant has had to send its tick: the wall time waited, less
what a `WaitJudge` (host_tools/worlds/own_time.py: the plant's process and this one, read from /proc) excuses
because the plant, or this process, waited for a CPU; the controller's watch judges that against
`lockstep_wait_s`. A plant whose process has ended or is stopped is excused nothing.

Lock-step knows one plant and one controller per bus. `PlantsWatch` (fed by the follower's `on_tick`)
and `ControllersWatch` (fed by the leader's `on_answer`) tell from the sync frames when a second
plant or controller shares it, for the node to say so on its log (docs/separate_processes.md, "One
pair per bus"); they change nothing the clocks do.
"""
from __future__ import annotations

import math
from collections import deque
from typing import Any, Callable, Optional, Protocol

import can

from protocol.hal import BusView, HalCodec
from timebase import Clock, PacedClock, RateMeter, TimingReport

REOFFER_S = 0.1          # the plant sends its last PLANT_SYNC again after this long without an answer
MAX_SYNC_GAP_TICKS = 100  # a PLANT_SYNC further ahead than this (or behind) is a new plant: resynchronise
MAX_HELD_FRAMES = 4096    # frames read while waiting, kept for the node's next poll
# A second node on the bus (`PlantsWatch`, `ControllersWatch`): said when BURST_COUNT of its signs come within
# BURST_WINDOW_S of wall time; again only once none has come for BURST_QUIET_S, and never within BURST_REPEAT_S.
BURST_COUNT = 10
BURST_WINDOW_S = 2.0
BURST_QUIET_S = 5.0
BURST_REPEAT_S = 30.0
ANSWER_CREDIT = 16        # PLANT_SYNCs a plant has sent that may still be answered (ControllersWatch)


class WaitJudge(Protocol):
    """Judges the follower's wait for the plant's tick beyond the wall clock (host_tools/worlds/own_time.py)."""

    def begin(self) -> None:
        """A wait for the plant's next tick begins now."""

    def own_s(self, waited_s: float) -> float:
        """Of the `waited_s` wall seconds since `begin`, those the plant had to send its tick in: the time it, or this
        process, waited for a CPU does not count; a plant gone or stopped had them all."""


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

    Build it on the controller's bus and give the controller's HAL `tap` instead of the bus. Time
    starts at 0 and stands still until the first PLANT_SYNC; from then on each new tick grants one
    more `period_us` (taken from the frame). When the scheduler asks to go past what is granted,
    everything due has run: the clock sends CTRL_SYNC(tick + 1) and waits on the bus. Until the
    first PLANT_SYNC it sends CTRL_SYNC(0) every `REOFFER_S`, which a plant already waiting answers
    at once with its last PLANT_SYNC (a controller started after the plant picks it up without
    waiting for the plant's next re-offer). `stalled_s()` is how long the plant has had to send its
    tick since the controller began to wait for it: the wall time waited, less what `judge` (a
    `WaitJudge`; None: nothing) excuses. The controller's watch turns a long one into HAL_STALE (a
    plant that died freezes time, so its own time cannot tell). `longest_wait_s` is the longest wall
    time a tick took to come, after the first.

    `speed` is the pace its plant was asked for, where the controller knows it (`aspod sim --hal` passes its
    --speed on): its real-time factor and lag are judged against it. `aspod firmware` does not know its
    plant's, and judges against real time.
    """

    def __init__(self, bus: Any, wall: Clock, codec: Optional[HalCodec] = None, speed: float = 1.0,
                 judge: Optional[WaitJudge] = None) -> None:
        codec = codec or HalCodec()
        self.wall = wall
        self.speed = speed
        self.judge = judge
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
        self.longest_wait_s = 0.0
        self.waits = 0                     # waits for a tick begun (one a tick, while the plant keeps up)
        wall_now = wall.now()
        # the wait for the plant begins when the controller first waits for a tick (`advance`), not here: the rest of
        # its start-up, seconds of wall time on a busy machine, is not the plant's silence
        self._waiting_since: Optional[float] = None
        self._first_grant: Optional[tuple[float, float]] = None
        self._hello_s = -math.inf          # wall time CTRL_SYNC(0) was last sent, before the first PLANT_SYNC
        self.meter = RateMeter(wall_now, 0.0)
        self.on_tick: Optional[Callable[[int], None]] = None    # shown every PLANT_SYNC's tick (a PlantsWatch)

    def now(self) -> float:
        return self._now

    def _on_sync(self, msg: can.Message) -> None:
        try:
            tick, lockstep, period_us = self._sync.unpack(msg.data)
        except ValueError:
            return                          # the node's poll counts it as a bad frame
        tick = int(tick)
        if self.on_tick is not None:
            self.on_tick(tick)
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
        wall_now = self.wall.now()
        if self._waiting_since is not None and self._first_grant is not None:
            self.longest_wait_s = max(self.longest_wait_s, wall_now - self._waiting_since)
        self._waiting_since = None
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
                self.waits += 1
                if self.judge is not None:
                    self.judge.begin()
            left = wall_deadline - wall_now
            if not self.tap.wait(max(0.0, min(left, REOFFER_S))) and left <= 0:
                return                      # nothing came, and the wall clock's tasks are due
        if deadline > self._now:
            self._now = float(deadline)

    def waited_s(self) -> float:
        """Wall seconds since the controller began to wait for the plant's next tick (0 while time is granted); the
        wait is the `waits`-th."""
        since = self._waiting_since
        return 0.0 if since is None else max(0.0, self.wall.now() - since)

    def stalled_s(self) -> float:
        """Seconds the plant has had to send its next tick and has not (0 while time is granted): the wall time spent
        waiting for it, less what `judge` excuses. A tick the bus holds already ends the wait first: a controller
        busy elsewhere, or blocked, when it came is late to read it, and the plant was not silent."""
        self._take_delivered()
        waited_s = self.waited_s()
        if waited_s == 0.0 or self.judge is None:
            return waited_s
        return min(waited_s, self.judge.own_s(waited_s))

    def _take_delivered(self) -> None:
        """While waiting: see the frames the bus holds now, without blocking (held for the node's next poll)."""
        for _ in range(MAX_HELD_FRAMES):
            if self._waiting_since is None or not self.tap.wait(0.0):
                return

    def timing(self) -> TimingReport:
        wall_now = self.wall.now()
        lag = 0.0
        if self._first_grant is not None:
            wall0, sim0 = self._first_grant
            lag = max(0.0, (wall_now - wall0) - (self._now - sim0) / self.speed)
        return TimingReport("lockstep", self.meter.recent(wall_now, self._now), self.meter.total(wall_now, self._now),
                            lag, speed=self.speed)


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
        self.on_answer: Optional[Callable[[int], None]] = None  # shown every CTRL_SYNC's tick (a ControllersWatch)
        self._waiting_since: Optional[float] = None
        self._offered_s = 0.0              # wall time of the last PLANT_SYNC sent again

    def now(self) -> float:
        return self.pace.now()

    def _on_done(self, msg: can.Message) -> None:
        try:
            (tick,) = self._done.unpack(msg.data)
        except ValueError:
            return
        if self.on_answer is not None:
            self.on_answer(int(tick))
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
        return TimingReport("lockstep", report.rtf_recent, report.rtf_total, report.lag_s, report.slipped_s,
                            report.speed)


class BurstWatch:
    """Says when events come in a burst: `count` of them within `window_s` (the time is the caller's).

    `note(now)` records one event and is True when it is time to say so: the first time the burst is
    seen; then not again while the events go on, and once they have stopped (none for `quiet_s`) and
    come back, not before `repeat_s` after the last time it said so. `in_window` is how many events
    the window held at the last note.
    """

    def __init__(self, count: int = BURST_COUNT, window_s: float = BURST_WINDOW_S, quiet_s: float = BURST_QUIET_S,
                 repeat_s: float = BURST_REPEAT_S) -> None:
        if count < 1 or not window_s > 0:
            raise ValueError(f"count must be >= 1 and window_s > 0, got {count}, {window_s}")
        self.count, self.window_s, self.quiet_s, self.repeat_s = count, window_s, quiet_s, repeat_s
        self._times: deque[float] = deque(maxlen=count)
        self._last_s = -math.inf           # the last event
        self._said_s = -math.inf           # the last time it said so
        self._on = False                   # said so, and the events have not stopped since
        self.events = 0
        self.said = 0
        self.in_window = 0

    def note(self, now: float) -> bool:
        self.events += 1
        if now - self._last_s >= self.quiet_s:
            self._on = False               # they had stopped: this is a new burst, if it becomes one
        self._last_s = now
        times = self._times
        times.append(now)
        while times and now - times[0] > self.window_s:
            times.popleft()
        self.in_window = len(times)
        if self._on or len(times) < self.count or now - self._said_s < self.repeat_s:
            return False
        self._on = True
        self._said_s = now
        self.said += 1
        return True


class PlantsWatch:
    """The controller's view of PLANT_SYNC: are two plants ticking on this bus?

    One plant's ticks only ever go forward: by one, by more when frames are lost (beyond
    `MAX_SYNC_GAP_TICKS` a resync), or back once when the plant restarts from 0 (a resync, or up to
    `MAX_SYNC_GAP_TICKS` old syncs while the new plant catches up with the last tick, each tick ahead
    of the one before). Two plants interleave theirs, and the tick goes back at every change from the
    one ahead to the one behind: `BURST_COUNT` steps back within `BURST_WINDOW_S` (`BurstWatch`) are
    said. A frame replayed or overtaken on the bus goes back once too. Feed `seen(tick, now)` every
    PLANT_SYNC's tick (`LockstepFollower.on_tick`) with the wall time; it returns the line to log when
    it is time to say so.
    """

    def __init__(self, burst: Optional[BurstWatch] = None) -> None:
        self.burst = burst or BurstWatch()
        self._last: Optional[int] = None
        self.steps_back = 0

    def seen(self, tick: int, now: float) -> Optional[str]:
        last, self._last = self._last, tick
        if last is None:
            return None
        back = (last - tick) & 0xFFFF_FFFF
        if back == 0 or back >= 0x8000_0000:
            return None                     # the same tick again, or one ahead of it
        self.steps_back += 1
        if not self.burst.note(now):
            return None
        burst = self.burst
        return (f"PLANT_SYNC from two plants (ticks near {last} and near {tick}; the tick went back "
                f"{burst.in_window} times in {burst.window_s:g} s): another aspod plant (or another node sending "
                "PLANT_SYNC) on this bus? the controller's time runs ahead of either plant's; give each pair its "
                "own --channel / --bus-arg port")


class ControllersWatch:
    """The plant's view of CTRL_SYNC: is more than one controller answering its ticks, or one answering another plant?

    One controller answers each PLANT_SYNC it receives at most once (a new tick once it has run it, the
    same tick again or one just behind at once), so a plant alone with it gets at most as many CTRL_SYNCs as
    it has sent PLANT_SYNCs (its ticks and its re-offers), fewer when frames are lost; a controller
    starting adds a CTRL_SYNC(0) or two ("I am here"). Two controllers answer every tick twice; a
    controller that also follows another plant answers that plant's ticks too. Feed `answer(now, offered,
    others)` every CTRL_SYNC (`LockstepLeader.on_answer`) with the wall time, the PLANT_SYNCs sent so far
    and, if known, how many frames with the plant's own IDs it has received that it did not send
    (`HalEndpoint.foreign_frames`: above 0, another plant). Each
    answer uses up one PLANT_SYNC sent (at most `ANSWER_CREDIT` are kept, so a long wait alone does not
    hide a later second controller); answers beyond them are said after `BURST_COUNT` within
    `BURST_WINDOW_S` (`BurstWatch`), naming another plant if `others` grew since it last said so, else
    another controller. It returns the line to log when it is time to say so.
    """

    def __init__(self, burst: Optional[BurstWatch] = None, credit: int = ANSWER_CREDIT) -> None:
        self.burst = burst or BurstWatch()
        self.max_credit = credit
        self._offered = 0
        self._credit = 0
        self._others_said = 0
        self.unasked = 0                    # CTRL_SYNCs beyond the PLANT_SYNCs sent

    def answer(self, now: float, offered: int, others: int = 0) -> Optional[str]:
        self._credit = min(self.max_credit, self._credit + max(0, offered - self._offered))
        self._offered = offered
        if self._credit > 0:
            self._credit -= 1
            return None
        self.unasked += 1
        if not self.burst.note(now):
            return None
        burst = self.burst
        seen = (f"{burst.in_window} CTRL_SYNC answers in {burst.window_s:g} s beyond the PLANT_SYNCs this plant "
                "sent; it re-offers its ticks, sync_resends climbs")
        plant, self._others_said = others > self._others_said, max(self._others_said, others)
        if plant:
            return (f"another plant's frames on this bus ({seen}; {others} frames with this plant's IDs that it did "
                    "not send): another aspod plant on this bus? its controller follows both; give each pair its "
                    "own --channel / --bus-arg port")
        return (f"CTRL_SYNC from two controllers ({seen}): another aspod firmware on this bus? both drive this "
                "plant; give each pair its own --channel / --bus-arg port")
