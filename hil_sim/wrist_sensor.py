"""Each arm's wrist force sensor while two arms hold the object: GRASP_FORCE on that arm's own bus (docs/two_arms.md).

The object's step (hil_sim/two_arms.py) gives each grasp's force, the grip's limit (friction x its jaws' force), the
squeeze and the grasp's state; a real arm would measure them at its wrist. `step()`, after the object's step, sends
each arm's controller its own grasp's reading: every `every_n` steps (the DBC's 10 ms), and at once when its grasp's
state changes, so that a slip or a drop reaches the controller in the tick it happens, however short. Sent after the
tick's PLANT_SYNC (the object moves once both arms' plants have stepped): a controller reads it with the next tick's
frames. Nothing is sent until the world takes the object, so an arm without one sees no new frame.
"""
from __future__ import annotations

from typing import Optional, Sequence

from hil_sim.hal_node import PlantNode
from hil_sim.two_arms import TwoArmPlant
from protocol.states import GraspState

ORDER = ("force_n", "limit_n", "squeeze_n", "state")


class WristSensors:
    """GRASP_FORCE for each arm of `pair`, arm k's on `nodes[k]`'s bus. `sent` counts the frames sent per arm."""

    def __init__(self, pair: TwoArmPlant, nodes: Sequence[PlantNode]) -> None:
        if len(nodes) != 2:
            raise ValueError(f"one plant node per arm, two arms: got {len(nodes)}")
        self.pair, self.nodes = pair, tuple(nodes)
        codec = self.nodes[0].codec
        self.every_n = max(1, round((codec.cycle_time_s("GRASP_FORCE") or 0.0) / self.nodes[0].period_s))
        self._layouts = tuple(node.codec.layout("GRASP_FORCE", ORDER) for node in self.nodes)
        self._force_range = codec.limits("GRASP_FORCE", "force_n")
        self._squeeze_range = codec.limits("GRASP_FORCE", "squeeze_n")
        self._states: list[Optional[GraspState]] = [None, None]      # the state each arm's last frame carried
        self._steps = 0
        self.sent = [0, 0]

    def step(self) -> None:
        """Each arm's reading, if due or if its grasp's state changed since its last frame."""
        due = self._steps % self.every_n == 0
        self._steps += 1
        held = self.pair.object
        force_range, squeeze = self._force_range, _within(held.squeeze_n, self._squeeze_range)
        for k, state in enumerate(held.states):
            if not due and state is self._states[k]:
                continue
            values = (_within(held.carried_n[k], force_range), _within(held.limits_n[k], force_range), squeeze,
                      int(state))
            if self.nodes[k].send_frame(self._layouts[k], values):
                self._states[k] = state
                self.sent[k] += 1


def _within(value: float, limits: tuple[float, float]) -> float:
    """`value` saturated at the signal's declared range, as a sensor's ADC would."""
    low, high = limits
    return low if value < low else high if value > high else value


__all__ = ["WristSensors"]
