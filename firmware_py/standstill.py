"""Standstill monitoring: while the controller's outputs are off, no joint or solar-tracker axis moves and no motor
draws current.

With the outputs off (IDLE, FAULT, ESTOP: every channel braked, nothing driven; CTRL_OUTPUTS says so every
10 ms) a joint that moves, or a motor that draws current, is driven by something the controller did not
command: another node on the HAL bus sending MOTOR_CMD and CTRL_OUTPUTS, a motor driver that does not obey,
a brake that does not hold its load. Industrial drives watch for the same (IEC 61800-5-2's "safe operating
stop" monitors a stopped axis for motion). The controller faults UNCOMMANDED_MOTION instead of reporting the
arm idle while it moves.

The health task (100 Hz) calls `check`. After the outputs go off, each joint has `still_settle_s` to brake to
rest (slower than STILL_DPS: the mount from its top speed takes about 1 s and 11 deg); where it rests is its
anchor. A joint further than `still_deg` from its anchor, one not at rest when its time is up, or a motor current
above `still_current_a` on two checks running, trips. The current is judged from the moment the outputs go off:
a braked motor whose bridge is off draws none, braking or not (0.0 A in every stop the review of 2026-11-25
made). After a trip the anchors of the joints at rest (and of the one that tripped) move to where they are, so
that motion that goes on is seen again; a joint still braking keeps braking unjudged until it rests. `reset` is refused while a joint turns (`still_moving`).
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Optional, Sequence

from firmware_py.params import ParamSpec, ParamStore

STILL_DPS = 0.5      # a joint slower than this (its estimated speed) is at rest


def parameter_table() -> list[ParamSpec]:
    return [
        ParamSpec("still_deg", 0.5, 0.01, 30.0, "deg",
                  "outputs off: a joint moving further than this faults (UNCOMMANDED_MOTION)"),
        ParamSpec("still_current_a", 0.5, 0.01, 50.0, "A",
                  "outputs off: a motor current above this on two health checks running faults "
                  "(UNCOMMANDED_MOTION)"),
        ParamSpec("still_settle_s", 2.0, 1.5, 60.0, "s",
                  "after the outputs go off, the time a joint has to brake to rest (UNCOMMANDED_MOTION if it is "
                  "not); the mount takes 1 s from its top speed"),
    ]


@dataclass(frozen=True)
class Uncommanded:
    """What tripped: the channel (its name: j1, mount, tracker az, ...), and what was seen there, for people."""

    channel: str
    detail: str


class StandstillWatch:
    """The standstill of the named `channels` while the outputs are off.

    A channel given no speed (None: the solar tracker's axes, whose angles come at 0.01 deg) is anchored where it
    is once `still_settle_s` has passed (the tracker, at most 0.59 deg/s, brakes at once); one given no current
    (None) is judged by its position alone."""

    def __init__(self, params: ParamStore, channels: Sequence[str]) -> None:
        self.params = params
        self.channels = tuple(channels)
        self._off_since: Optional[float] = None
        self._anchor: list[Optional[float]] = [None] * len(self.channels)   # where each channel came to rest [rad]
        self._current_seen = [False] * len(self.channels)
        self._last_speeds: list[float] = [0.0] * len(self.channels)

    def check(self, now: float, outputs_on: bool, positions_rad: Sequence[float],
              speeds_rad_s: Sequence[Optional[float]], currents_a: Sequence[Optional[float]],
              encoders_ok: Sequence[bool]) -> Optional[Uncommanded]:
        """None while all is still (or the outputs are on, or the joints are still braking); what moved else.
        The sequences are the watched channels', in the order of `channels`. A channel whose position sensor is
        faulted (`encoders_ok` False: a count that jumped or stopped, ENCODER or HAL_STALE; no angle yet) is not
        judged by its position, which is the sensor's fault; it is anchored again once it is trusted and rests."""
        n = len(self.channels)
        if outputs_on:
            if self._off_since is not None:    # the outputs came on: the standstill is forgotten (once)
                self._off_since, self._anchor = None, [None] * n
                self._current_seen = [False] * n
            return None
        if self._off_since is None:
            self._off_since = now
        p = self.params
        self._last_speeds = [0.0 if v is None else v for v in speeds_rad_s]
        settled = now - self._off_since >= p["still_settle_s"]
        limit_rad, limit_a = math.radians(p["still_deg"]), p["still_current_a"]
        over = [i is not None and abs(i) > limit_a for i in currents_a]
        found: Optional[Uncommanded] = None
        for i, name in enumerate(self.channels):
            pos, speed = positions_rad[i], speeds_rad_s[i]
            anchor = self._anchor[i]
            if not encoders_ok[i]:
                self._anchor[i] = None
            elif anchor is None:
                if speed is None:
                    if settled:
                        self._anchor[i] = pos
                elif abs(math.degrees(speed)) < STILL_DPS:
                    self._anchor[i] = pos
                elif settled and found is None:
                    found = Uncommanded(name, f"still turning at {math.degrees(speed):+.1f} deg/s "
                                              f"{p['still_settle_s']:g} s after the outputs went off (still_settle_s)")
            elif found is None and abs(pos - anchor) > limit_rad:
                found = Uncommanded(name, f"moved {math.degrees(pos - anchor):+.2f} deg with the outputs off "
                                          f"(still_deg {p['still_deg']:g})")
            if found is None and over[i] and self._current_seen[i]:
                found = Uncommanded(name, f"drew {currents_a[i]:+.2f} A with the outputs off "
                                          f"(still_current_a {limit_a:g})")
        self._current_seen = over
        if found is not None:
            # motion that goes on is seen again from here: the channels anchored, and the one that tripped; a joint
            # still braking (or with its sensor faulted) is anchored only once it rests, as before
            tripped = self.channels.index(found.channel)
            self._anchor = [pos if (self._anchor[i] is not None or i == tripped) else None
                            for i, pos in enumerate(positions_rad)]
        return found

    def still_moving(self) -> bool:
        """Whether the last check saw a joint turning or a motor drawing current (`reset` waits until neither)."""
        return any(self._current_seen) or any(abs(math.degrees(v)) >= STILL_DPS for v in self._last_speeds)


class ForeignCommands:
    """Commands for the hardware that another node sends: frames with the controller's own IDs (MOTOR_CMD,
    CTRL_OUTPUTS, TRACKER_CMD, CTRL_SYNC) that it did not send, in any state, outputs on or off. Fed the HAL's
    `foreign_frames()` count at every health check; more than STRAY_FRAMES of them within WINDOW_S trips, a
    stray frame or two (a restarted node's last frames still on their way) does not.

    The count is judged by its high-water mark: on a bus that echoes a node's frames back, the count is the echoes
    beyond the frames sent, which dips while the node's own echoes are on their way, and a dip and its recovery
    are not new frames. A node sending them every 20 ms is seen at its third, at 40 ms; one sending fewer than three
    a second is not seen by its frames (a command of the controller's own replaces each within 10 ms, and with
    the outputs off `StandstillWatch` sees what it moves)."""

    WINDOW_S = 1.0
    STRAY_FRAMES = 2

    def __init__(self) -> None:
        self.seen = 0                                       # the high-water mark of the count
        self._recent: deque[tuple[float, int]] = deque()    # (when, the mark then) for the marks within WINDOW_S

    def check(self, now: float, foreign_frames: int) -> Optional[Uncommanded]:
        while self._recent and now - self._recent[0][0] > self.WINDOW_S:
            self._recent.popleft()
        if foreign_frames <= self.seen:
            return None
        before = self._recent[0][1] if self._recent else self.seen   # the mark as the window opened
        self._recent.append((now, self.seen))
        self.seen = foreign_frames
        if foreign_frames - before <= self.STRAY_FRAMES:
            return None
        return Uncommanded("HAL bus", f"another node sends this controller's own frames (MOTOR_CMD, CTRL_OUTPUTS, "
                                      f"TRACKER_CMD or CTRL_SYNC): {foreign_frames - before} in "
                                      f"{self.WINDOW_S:g} s, {foreign_frames} so far")
