"""The arm's planned moves beside its trapezoid moves at the report's 1/2 RPM (`python -m bench --only plan`).

The pick-and-place on the lock-step bench twice, on Earth and in orbit: each arm move as the firmware's trapezoids
(every joint at its default 3 deg/s, coordinated to end together), then as a time-optimal trajectory planned from
the firmware's drive model (host_tools/apps/planned_moves.py). Per move: the simulated time the step took (with
its settling), the plan's own duration, and the gripper tip's error against the report's 1 cm.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from host_tools.apps.planned_moves import run_both


@dataclass
class ArmMovesBench:
    runs: dict = field(default_factory=dict)
    error: str = ""


def main(quick: bool = False) -> ArmMovesBench:
    bench = ArmMovesBench()
    print("The arm's moves: trapezoids at 1/2 RPM beside time-optimal trajectories (the pick-and-place, lock-step)")
    for gravity in ("orbit",) if quick else ("earth", "orbit"):
        try:
            run = run_both(gravity)
        except Exception as exc:        # noqa: BLE001 (a bench row, not a crash)
            bench.error = f"{gravity}: {type(exc).__name__}: {exc}"
            print(f"  {gravity}: FAILED: {bench.error}")
            continue
        bench.runs[gravity] = run
        print(f"  {gravity}: {'step':<16} {'trapezoid':>10} {'planned':>9} {'plan':>7} {'error trap':>11} "
              f"{'error plan':>11}")
        for row in run["moves"]:
            plan = "" if math.isnan(row["plan_s"]) else f"{row['plan_s']:.2f}s"
            print(f"  {'':<7} {row['step']:<16} {row['trapezoid_s']:9.2f}s {row['planned_s']:8.2f}s {plan:>7} "
                  f"{1000 * row['trapezoid_error_m']:8.3f} mm {1000 * row['planned_error_m']:8.3f} mm")
        ok = run["max_planned_error_m"] <= run["spec_m"]
        print(f"  {'':<7} {'all moves':<16} {run['trapezoid_s']:9.2f}s {run['planned_s']:8.2f}s; worst planned "
              f"error {1000 * run['max_planned_error_m']:.3f} mm against {1000 * run['spec_m']:.0f} mm: "
              f"{'met' if ok else 'NOT met'}")
    print("  (a step's time includes its settling; the trajectory moves j1..j4 and the mount)")
    return bench
