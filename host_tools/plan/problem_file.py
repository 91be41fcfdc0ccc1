"""A planning problem from a JSON file (`aspod plan --problem FILE`); every part is optional but the path:

    {"path":    {"kind": "line", "start": [0.688, 0.331], "end": [1.716, 0.504]},
     "arms":    {"separation": 2.0, "lengths": [1, 1], "masses": [1, 1], "elbows": [1, 1], "links": "point"},
     "object":  {"mass": 0.25, "size": [0.25, 0.1], "grasps": [[-0.125, 0], [0.125, 0]]},
     "gravity": 9.81,
     "limits":  {"symmetric": [30, 20, 35, 15]},
     "motors":  {"resistance_ohm": [6, 6, 6, 6], "torque_constant": [0.035, 0.035, 0.035, 0.035],
                 "ratio": [1600, 600, 1600, 600], "efficiency": [0.69, 0.71, 0.69, 0.71], "drive_w": 42},
     "weights": [1, 1, 1, 1]}

`limits` may instead give "lower" and "upper", and "back_emf" (per joint) for DC motors' voltage limits
(bounds.py; both minimum-time methods plan them, --method reach with order 1 only). `motors` (one value a joint;
efficiency optional, 1; drive_w, the drives' draw while enabled, optional, 0) price the electrical and heat
objectives (motors.py; without them, ASPOD's own drives), `weights` each joint's share of a minimum-cost plan
(`aspod plan --weights` over them). Paths: "line" (start, end), "polynomial" (x, y: coefficients, lowest power
first), "piecewise" (knots, pieces). Anything else, or a value of the wrong kind, is refused with the reason.
"""
from __future__ import annotations

import math
from pathlib import Path

from host_tools import strict_json
from host_tools.plan.bounds import Limits
from host_tools.plan.errors import PlanError, finite
from host_tools.plan.example import LIMITS
from host_tools.plan.model import GRAVITY, Held, two_arms
from host_tools.plan.motors import Motors
from host_tools.plan.paths import path_from_dict
from host_tools.plan.phase import Problem
from protocol import files

MAX_BYTES = 1 << 20
KEYS = {"path", "arms", "object", "gravity", "limits", "motors", "weights"}
# Magnitudes far beyond any arm's, within which the planner's arithmetic stays well inside a float (its torques
# go as mass x length^2 x speed^2); beyond them a problem is refused, not computed into overflows and NaNs.
# Below, a link's length and mass, and a joint's range of torque, are at least a millimetre, a gram (or nothing:
# a massless link or object) and a milli-newton-metre: smaller ones are the planner's zeros and divisors.
MAX_LENGTH_M, MIN_LENGTH_M = 1e3, 1e-3    # links, the arms' separation, the object's size and grasps: a kilometre
MAX_MASS_KG, MIN_MASS_KG = 1e6, 1e-3      # links and the object: a thousand tonnes
MAX_LIMIT, MIN_LIMIT_RANGE = 1e9, 1e-3    # torque limits, N m (or a motor's voltage, V)
MAX_BACK_EMF = 1e6                        # back-emf constants, per joint
MAX_MOTOR = 1e6                           # a motor's resistance (ohm), torque constant (N m/A), gear ratio; a weight


def _numbers(value, n: int, what: str, bound: float) -> tuple:
    """`n` finite numbers, each of magnitude at most `bound`; PlanError naming `what` else."""
    if not isinstance(value, (list, tuple)) or len(value) != n or not all(finite(v) is not None for v in value):
        raise PlanError("file", f"{what} must be a list of {n} finite numbers")
    numbers = tuple(float(v) for v in value)
    if any(abs(v) > bound for v in numbers):
        raise PlanError("file", f"{what} must be within -{bound:g}..{bound:g}, not {max(numbers, key=abs):g}")
    return numbers


SECTION_KEYS = {"arms": {"separation", "lengths", "masses", "elbows", "links"},
                "object": {"mass", "size", "grasps"}, "limits": {"symmetric", "lower", "upper", "back_emf"},
                "motors": {"resistance_ohm", "torque_constant", "ratio", "efficiency", "drive_w"}}


def _section(spec: dict, key: str) -> dict:
    value = spec.get(key, {})
    if not isinstance(value, dict):
        raise PlanError("file", f"'{key}' must be an object")
    unknown = set(value) - SECTION_KEYS[key]
    if unknown:
        raise PlanError("file", f"unknown keys in '{key}': {sorted(unknown)} (known: {sorted(SECTION_KEYS[key])})")
    return value


def _at_least(numbers: tuple, least: float, what: str, zero: bool = False) -> tuple:
    """`numbers`, each at least `least` (or 0 if `zero`); PlanError naming `what` else."""
    below = [v for v in numbers if v < least and not (zero and v == 0)]
    if below:
        raise PlanError("file", f"{what} must be {'0 or ' if zero else ''}at least {least:g}, not {min(below):g}")
    return numbers


def problem_from_dict(spec: dict) -> Problem:
    if not isinstance(spec, dict):
        raise PlanError("file", "a problem is a JSON object")
    unknown = set(spec) - KEYS
    if unknown:
        raise PlanError("file", f"unknown keys {sorted(unknown)} (known: {sorted(KEYS)})")
    if "path" not in spec:
        raise PlanError("file", "a problem needs a 'path'")
    arms, held, limits = _section(spec, "arms"), _section(spec, "object"), _section(spec, "limits")
    grasps = held.get("grasps", [[-0.125, 0], [0.125, 0]])
    if not isinstance(grasps, list) or len(grasps) != 2:
        raise PlanError("file", "object.grasps must be a list of two points [x, y]")
    size = _numbers(held.get("size", [0.25, 0.1]), 2, "object.size", MAX_LENGTH_M)
    if any(v <= 0 for v in size):
        raise PlanError("file", "object.size must be two lengths above 0")
    gravity = spec.get("gravity", GRAVITY)
    if finite(gravity) is None or not 0 <= gravity <= 100:
        raise PlanError("file", "'gravity' is a number of m/s^2 from 0 to 100")
    separation = _numbers([arms.get("separation", 2.0)], 1, "arms.separation", MAX_LENGTH_M)[0]
    elbows = _numbers(arms.get("elbows", [1, 1]), 2, "arms.elbows", math.inf)
    if any(e not in (1.0, -1.0) for e in elbows):
        raise PlanError("file", "arms.elbows are +1 or -1 each (the sign of the elbow angle)")
    lengths = _at_least(_numbers(arms.get("lengths", [1, 1]), 2, "arms.lengths", MAX_LENGTH_M), MIN_LENGTH_M,
                        "arms.lengths")
    masses = _at_least(_numbers(arms.get("masses", [1, 1]), 2, "arms.masses", MAX_MASS_KG), MIN_MASS_KG,
                       "arms.masses", zero=True)
    mass = _at_least(_numbers([held.get("mass", 0.25)], 1, "object.mass", MAX_MASS_KG), MIN_MASS_KG, "object.mass",
                     zero=True)[0]
    system = two_arms(separation, lengths, masses, tuple(int(e) for e in elbows), str(arms.get("links", "rod")),
                      Held(mass, size, tuple(_numbers(g, 2, "object.grasps[]", MAX_LENGTH_M) for g in grasps)),
                      float(gravity))
    if len(system.held.grasps) != 2 or system.held.grasps[0] == system.held.grasps[1]:
        raise PlanError("file", "object.grasps needs two different points")
    back_emf = limits.get("back_emf")
    emf = None if back_emf is None else _numbers(back_emf, 4, "limits.back_emf", MAX_BACK_EMF)
    if "symmetric" in limits:
        bounds = Limits.symmetric(_numbers(limits["symmetric"], 4, "limits.symmetric", MAX_LIMIT), emf)
    elif "lower" in limits or "upper" in limits:
        bounds = Limits(_numbers(limits.get("lower"), 4, "limits.lower", MAX_LIMIT),
                        _numbers(limits.get("upper"), 4, "limits.upper", MAX_LIMIT), emf)
    else:
        bounds = Limits.symmetric(LIMITS)
    narrow = [j for j in range(len(bounds.lower)) if bounds.upper[j] - bounds.lower[j] < MIN_LIMIT_RANGE]
    if narrow:
        j = narrow[0]
        raise PlanError("file", f"joint {j + 1}'s limits [{bounds.lower[j]:g}, {bounds.upper[j]:g}] are less than "
                                f"{MIN_LIMIT_RANGE:g} apart")
    return Problem(system, path_from_dict(spec["path"]), bounds, motors=_motors(spec),
                   weights=None if "weights" not in spec else _at_least(
                       _numbers(spec["weights"], 4, "weights", MAX_MOTOR), 0.0, "weights"))


def _motors(spec: dict):
    if "motors" not in spec:
        return None
    given = _section(spec, "motors")
    missing = sorted({"resistance_ohm", "torque_constant", "ratio"} - set(given))
    if missing:
        raise PlanError("file", f"motors needs {', '.join(missing)} (one value a joint)")
    values = [_numbers(given[key], 4, f"motors.{key}", MAX_MOTOR) for key in ("resistance_ohm", "torque_constant",
                                                                              "ratio")]
    efficiency = _numbers(given.get("efficiency", [1, 1, 1, 1]), 4, "motors.efficiency", 1.0)
    drive_w = _at_least(_numbers([given.get("drive_w", 0.0)], 1, "motors.drive_w", MAX_MOTOR), 0.0, "motors.drive_w")
    return Motors(*values, efficiency, drive_w[0])


def load_problem(path: Path) -> Problem:
    try:
        spec = strict_json.loads(files.read_bounded(path, MAX_BYTES).decode("utf-8"))
    except files.InputFileError as e:
        raise PlanError("file", str(e)) from None
    except ValueError as e:           # not UTF-8, not JSON, nested too deeply, a number out of range
        raise PlanError("file", f"{path} is not a problem file: {e}") from None
    return problem_from_dict(spec)
