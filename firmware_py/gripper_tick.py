"""The gripper's tick, the one implementation: plain functions over numbers (`Gripper.update`, firmware_py/gripper.py,
and the world's fast loop, host_tools/worlds/fast_loop.py, compiled by numba)."""
from __future__ import annotations

from firmware_py.estimator import unwrap_delta

_CONFIRM_S = 0.03                 # jaws still this long at grip current: gripped
OPEN, CLOSE = 1, -1               # a move's direction, as the duty's sign
VELOCITY_WINDOW_S = 0.02          # the velocity is measured over this long
NONE = float("nan")               # a time that is not (`moving_tick`)
NO_COUNT = -1                     # a count not had yet (counts are 0 .. 2**32 - 1)
# how a tick of a move ends it (`moving_tick`)
GOES_ON, AT_OPEN_SWITCH, AT_CLOSED_SWITCH, GRIPPED, TIMED_OUT = range(5)


def track(now: float, count: int, ref_count: int, ref_m: float, m_per_count: float, vel_m_s: float, vel_count: int,
          vel_s: float) -> tuple[float, float, int, float]:
    """A tick of the gripper's tracking, the one implementation (`Gripper._track`, and the world's fast loop,
    host_tools/worlds/fast_loop.py): the opening from the count (relative to the count `ref_count` at which it was
    `ref_m`), and the velocity over `VELOCITY_WINDOW_S` since the count `vel_count` at `vel_s`. Counts are 32-bit
    and wrap: differences are taken modulo 2**32. Returns (opening_m, vel_m_s, vel_count, vel_s)."""
    opening_m = ref_m + unwrap_delta(count, ref_count) * m_per_count
    if now - vel_s >= VELOCITY_WINDOW_S:
        vel_m_s = unwrap_delta(count, vel_count) * m_per_count / (now - vel_s)
        vel_count, vel_s = count, now
    return opening_m, vel_m_s, vel_count, vel_s


def moving_tick(now: float, count: int, i_a: float, closed_switch: bool, open_switch: bool, direction: int,
                started_s: float, still_since: float, last_count: int, grip_current_a: float, grip_duty: float,
                timeout_s: float) -> tuple[int, float, int, float]:
    """A tick of a move, the one implementation (`Gripper.update`, and the world's fast loop,
    host_tools/worlds/fast_loop.py): opening, the open end switch ends it; closing, the closed end switch, or the
    jaws still (the count as at the tick before, `last_count`; NO_COUNT: none yet) at `grip_current_a` or more for
    `_CONFIRM_S` since `still_since` (NONE: not still) ends it gripped; past `timeout_s` since `started_s` it has
    timed out. Returns (how it ended: GOES_ON or what ended it, still_since, last_count, the duty if it goes on)."""
    if direction == OPEN:
        if open_switch:
            return AT_OPEN_SWITCH, still_since, last_count, 0.0
    else:
        if closed_switch:
            return AT_CLOSED_SWITCH, still_since, last_count, 0.0
        moving = last_count == NO_COUNT or count != last_count
        if abs(i_a) >= grip_current_a and not moving:
            if not still_since == still_since:
                still_since = now
            elif now - still_since >= _CONFIRM_S:
                return GRIPPED, still_since, last_count, 0.0
        else:
            still_since = NONE
    last_count = count
    if now - started_s > timeout_s:
        return TIMED_OUT, still_since, last_count, 0.0
    return GOES_ON, still_since, last_count, direction * grip_duty
