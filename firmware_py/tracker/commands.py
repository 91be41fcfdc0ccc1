"""The tracker's commands: the control box's switches and dials (BoxSwitch, BoxDial, GetBoxState, each answered by
BoxState) and its clock (SetClock), beside the `TrackerController` that owns them (task.py)."""
from __future__ import annotations

from typing import Callable

from protocol.messages import MESSAGES as M
from protocol.reasons import Reason
from protocol.schema import Message

from firmware_py.handlers import CommandOwner, handles
from firmware_py.tracker.task import TrackerController


class TrackerCommands(CommandOwner):
    """The commands of `tracker`; `wake(now)` runs the tracker's task at `now`, so that its outputs follow a box
    change at once, not at its next 10 ms tick."""

    def __init__(self, tracker: TrackerController, wake: Callable[[float], None]) -> None:
        self.tracker = tracker
        self._wake = wake

    def _box_state(self, reason: Reason) -> Message:
        box = self.tracker.box
        return M["BoxState"](int(reason), int(box.main), int(box.sensor),
                             int(box.mode[0]), int(box.direction[0]), int(box.speed[0]), box.dial_pct(0),
                             int(box.mode[1]), int(box.direction[1]), int(box.speed[1]), box.dial_pct(1))

    @handles("BoxSwitch")
    def _box_switch(self, msg: Message, now: float) -> Message:
        reason, _detail = self.tracker.switch(msg.switch, msg.position, msg.axis)
        if reason is Reason.OK:
            self._wake(now)
        return self._box_state(reason)

    @handles("BoxDial")
    def _box_dial(self, msg: Message, now: float) -> Message:
        reason, _detail = self.tracker.dial(msg.percent, msg.axis)
        if reason is Reason.OK:
            self._wake(now)
        return self._box_state(reason)

    @handles("GetBoxState")
    def _get_box_state(self, msg: Message, now: float) -> Message:
        return self._box_state(Reason.OK)

    @handles("SetClock")
    def _set_clock(self, msg: Message, now: float) -> Message:
        self.tracker.set_clock(msg.utc_s + msg.utc_ms / 1000.0, now)
        return M["Result"](int(Reason.OK))
