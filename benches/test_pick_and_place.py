"""The report's pick-and-place as a bench: every move of the demo scene through the protocol, the positioning error
at the gripper measured against the report's 1 cm, on whatever target `pytest` is given (the lock-step world by
default). Run: `pytest benches/` (docs/benches.md)."""
from __future__ import annotations

import pytest

from host_tools.apps import pick_place


def test_every_step_of_the_pick_and_place_lands_within_a_centimetre(aspod_target):
    if not hasattr(aspod_target, "bench"):     # the positioning error is measured on the plant's true gripper
        pytest.skip("needs the lock-step world: the demo scene's kinematics against the plant's true gripper, "
                    "in process")
    demo = pick_place.PickAndPlace.on_bench(aspod_target.bench)
    demo.prepare()
    worst_mm = 0.0
    for step in pick_place.steps(demo.scene):
        result = demo.run_step(step)
        error_mm = round(result.position_error_m * 1e3, 3)
        worst_mm = max(worst_mm, error_mm)
        aspod_target.measure(f"{result.name.replace(' ', '_')}_error_mm", error_mm, "mm")
        aspod_target.measure("worst_error_mm", worst_mm, "mm")      # so far: a campaign's one figure per run
        assert result.position_error_m <= pick_place.SPEC_M, f"{result.name}: {result.position_error_m * 1e3:.2f} mm"
    aspod_target.measure("homing_s", round(demo.homing_s, 3), "s")
