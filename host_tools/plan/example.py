"""The report's numerical example (section 4): unit-mass, unit-length links, bases 2.0 m apart, an object of
0.25 kg, 0.25 m long and 0.1 m high, torque limits |u1| < 30, |u2| < 20, |u3| < 35, |u4| < 15 N m.

What the report does not say, and what is chosen here (docs/planning.md says why):

- **The path.** The report's w(s) is garbled; only "1/2 s" survives. The path here is the straight line
  w(s) = (0.688 + 1.028 s, 0.331 + 0.173 s), found by a search for the line whose switching points come
  nearest the three the report gives.
- **The model that matches.** With the links as point masses at their far ends, gravity off, and both elbow
  angles positive, three of this planner's candidate switching points fall within 1.6 % in s and 1 % in s' of
  the report's three (`REPORTED`). Gravity on, or uniform rods, move them much further (the report's text does
  not give its link model or whether gravity acts: its arms may have worked in a horizontal plane).
- **Joint numbering.** Here: arm 1's shoulder and elbow, then arm 2's. The report's zero-inertia joints come out
  swapped (its a4 at s = 0.2634 is this model's a1; its a1 at 0.9337 is this a4): its numbering, lost with its
  Fig. 8, may run the other way round the chain.
"""
from __future__ import annotations

from hil_sim.held_object import ObjectParams
from host_tools.plan.bounds import Limits
from host_tools.plan.model import GRAVITY, Held, two_arms
from host_tools.plan.paths import PolynomialPath
from host_tools.plan.phase import Problem

LIMITS = (30.0, 20.0, 35.0, 15.0)                     # N m, report section 4
PATH = ((0.688, 0.331), (0.688 + 1.028, 0.331 + 0.173))

# The report's switching points (section 4.2): (kind, joint as the report numbers it, s, s')
REPORTED = (("zero-inertia", 4, 0.2634, 5.956), ("tangent", None, 0.8, 6.968), ("zero-inertia", 1, 0.9337, 6.098))

# The report's dynamic-programming grid (section 4.3): 101 points in s, 201 speeds 0.005 apart
DP_INTERVALS, DP_SPEEDS, DP_SPEED_STEP = 100, 201, 0.005


def report_problem(gravity: bool = False, links: str = "point", path=PATH) -> Problem:
    """The example as planned here; `gravity` and `links` change the model (the defaults match the report), `path`
    the object's straight line ((x0, z0), (x1, z1), m: the example's, `PATH`, unless given). Its object is the
    plant's (`ObjectParams`: the report's 0.25 kg, 0.25 m x 0.1 m, held at its ends), one declaration for the plan,
    its grip check (host_tools/apps/two_arm_plan.py) and the object the plant's two arms carry."""
    held = ObjectParams()
    system = two_arms(separation=2.0, lengths=(1.0, 1.0), masses=(1.0, 1.0), elbows=(1, 1), links=links,
                      held=Held(mass=held.mass_kg, size=held.size_m, grasps=held.grasps_m),
                      gravity=GRAVITY if gravity else 0.0)
    return Problem(system, PolynomialPath.line(*path), Limits.symmetric(LIMITS))


def beside_report(points) -> list[dict]:
    """Each of the report's switching points beside the nearest candidate of the same kind found here."""
    rows = []
    for kind, joint, s, sd in REPORTED:
        same = [p for p in points if p.kind == kind] or list(points)
        if not same:
            continue
        near = min(same, key=lambda p: abs(p.s - s) / s + abs(p.sd - sd) / sd)
        rows.append({"kind": kind, "report": {"joint": joint, "s": s, "sd": sd}, "here": near.describe(),
                     "error_s": round((near.s - s) / s, 5), "error_sd": round((near.sd - sd) / sd, 5)})
    return rows
