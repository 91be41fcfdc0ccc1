"""The wrist force sensor: an arm holding the object two arms carry hears its grasp from the plant, and a slip or a
drop is its fault (GRIP_SLIP; docs/two_arms.md).

The plant sends GRASP_FORCE on an arm's bus while it holds the object: the force across the grasp, the grip's limit
(friction x the jaws' force), the squeeze between the two grasps and the grasp's state (`GraspState`), every 10 ms and
at once when the state changes. A change into SLIPPING or DROPPED (from HELD or FREE, or a slip turning into a drop)
calls `on_loss` with the reading, at the frame: a slip that holds again within a tick still reaches it, since each
change is a frame of its own. Without an object no frame comes and nothing here changes.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional

from firmware_py.hal import ControllerHal
from protocol.states import GraspState

LOST = (GraspState.SLIPPING, GraspState.DROPPED)


@dataclass(frozen=True)
class GraspReading:
    """One GRASP_FORCE frame: the grasp's state, the force across it, the grip's limit and the squeeze [N]."""

    state: GraspState
    force_n: float
    limit_n: float
    squeeze_n: float


class GraspWatch:
    """The last GRASP_FORCE heard (`reading`, None until one comes) and `losses`, the slips and drops it reported."""

    def __init__(self, hal: ControllerHal, on_loss: Callable[[GraspReading, float], None]) -> None:
        self.reading: Optional[GraspReading] = None
        self.losses = 0
        self.lost: Optional[GraspReading] = None          # the reading of the last slip or drop
        self._on_loss = on_loss
        hal.on_frame("GRASP_FORCE", self._on_grasp, ("state", "force_n", "limit_n", "squeeze_n"))

    def _on_grasp(self, values: list, now: float) -> None:
        reading = GraspReading(GraspState(int(values[0])), *values[1:])     # ValueError: a bad frame, counted
        before = self.reading.state if self.reading is not None else GraspState.FREE
        self.reading = reading
        if reading.state in LOST and reading.state is not before:
            self.losses += 1
            self.lost = reading
            self._on_loss(reading, now)
