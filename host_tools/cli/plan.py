"""`aspod plan`: the report's trajectory planning (docs/planning.md).

    aspod plan                                   the report's example: minimum time, then minimum electrical energy
    aspod plan --json --plot figures             ... as JSON, and its Figs. 11-17 as PNG files
    aspod plan --objective thermal --max-time 2  minimum heat in the motors within 2 s
    aspod plan --problem FILE                    a path, arms and limits of your own (host_tools/plan/problem_file.py)
    aspod plan --method reach --squeeze free     minimum time by reachability, the squeeze force free
    aspod plan --method reach --order 2          ... s'' linear between grid points placed where time is lost
    aspod plan --arm-to j1=20 --output move.json ASPOD's own arm: a trajectory file for teleop's `traj load`
    aspod plan --links rod --output two.json     the two arms' plan: both arms' knots, `traj load two.json arm 1|2`
    aspod plan --links rod --execute L1,L2       ... carried out on two controllers (aspod sim --arms 2)

Exit status: 0 planned, 2 a problem refused (out of reach, limits too weak, a grid too coarse: the reason says).
"""
from __future__ import annotations

import argparse
import json
import logging
import math
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import numpy as np

from host_tools.cli.options import bounded, squeeze_force, weights_list
from host_tools.cli.settings import ArmMoveSettings, PlanSettings, TwoArmSettings
from host_tools.exit_codes import EXIT_FAILED, EXIT_OK
from host_tools.plan.energy import DpGrid, Pricing, costs_of, motors_of, plan_cost_optimal, potential_rise
from host_tools.plan.example import REPORTED, beside_report, report_problem
from host_tools.plan.problem_file import load_problem
from host_tools.plan.reach import plan_reach_checked
from host_tools.plan.errors import PlanError
from host_tools.plan.timeopt import TimeOptimal, plan_time_optimal

log = logging.getLogger("aspod")
EXCESS_WARNED = 0.01      # a time-optimal plan past a limit by more than this share of it is said on stderr
CARRY_FIGURE = "two_arm_carry.png"    # --execute --plot DIR: plan against execution, beside Figs. 11-17
SPAN_MARGIN = 1.2         # the DP's speeds span this times the minimum-time plan's highest s' (by default)


def _reach_result(problem, settings: PlanSettings, pricing: Pricing) -> tuple[dict, float]:
    """The reachability planner's minimum time, on nodes + 1 grid points (order 2: placed where time is lost), its
    excess checked between them; and its highest s'."""
    plan, excess, rounds = plan_reach_checked(problem, settings.nodes + 1, settings.squeeze, order=settings.order,
                                              placed=settings.order == 2)
    out = {"method": "reach", "order": plan.order, "nodes": len(plan.s) - 1, "duration_s": round(plan.duration, 6),
           "worst_violation_between_nodes": excess, "refined": rounds,
           "saturated_time": round(plan.profile.saturated_time, 4),
           "solve_time_s": round(plan.solve_time_s, 4),
           "squeeze": None if settings.squeeze is None else {
               "bound_n": None if np.isinf(settings.squeeze) else settings.squeeze,
               "max_n": round(float(np.abs(plan.squeeze).max()), 4)}}
    if plan.iterations:                                  # back-emf limits: the linearized plans it took
        out["back_emf_plans"] = plan.iterations
    if settings.squeeze is None and plan.order == 1:     # costs_of takes s'' constant between the nodes
        out["costs"] = costs_of(problem.terms(plan.s), plan.profile.sd, pricing)
    return out, float(np.max(plan.profile.sd))


def run_arm_plan(arm: ArmMoveSettings, nodes: int, as_json: bool) -> int:
    """ASPOD's own arm from `arm.start_deg` to `arm.target_deg` in minimum time, within the controller's default
    current and speed limits and the supply (host_tools/apps/arm_plan.py); the knots written to `arm.output`, a
    file teleop's `traj load` takes. PlanError (exit 2) for a move it cannot plan."""
    from firmware_py.arm_config import ASPOD_ARM
    from hil_sim.arm_params import GRAVITY_M_S2
    from host_tools.apps.arm_plan import ArmPlanSettings, knots_within_speed, plan_move
    from host_tools.client.trajectory import trajectory_json
    defaults = {p.name: p.default for p in ASPOD_ARM.parameter_table()}
    start = {name: math.radians(deg) for name, deg in arm.start_deg}
    target = {name: math.radians(deg) for name, deg in arm.target_deg}
    current = {name: defaults[f"{name}_i_lim_a"] for name in start}
    speed = {name: math.radians(defaults[f"{name}_speed_dps"]) for name in start}
    move = plan_move(start, target, GRAVITY_M_S2[arm.gravity], arm.payload_kg, current, speed,
                     ArmPlanSettings(nodes=min(nodes, 20000), knots=arm.knots))
    knots = knots_within_speed(move.knots, speed, arm.knots)
    about = {"tool": "aspod plan", "from_deg": dict(arm.start_deg), "to_deg": dict(arm.target_deg),
             "gravity": arm.gravity, "payload_kg": arm.payload_kg, "duration_s": round(move.duration_s, 6),
             "limits": "the controller's default current and speed limits"}
    if arm.output is not None:
        arm.output.write_text(trajectory_json([knots], about))
    if as_json:
        print(json.dumps({**about, "moving": list(move.names), "knots": len(knots),
                          "output": None if arm.output is None else str(arm.output)}, indent=2))
    else:
        print(f"ASPOD's arm, {', '.join(move.names)}: {move.duration_s:.3f} s in minimum time ({arm.gravity}, "
              f"payload {arm.payload_kg:g} kg), {len(knots)} knots"
              + (f", written to {arm.output}: at the start pose, teleop's `traj load {arm.output}` then `traj run`"
                 if arm.output is not None else ""))
    return EXIT_OK


def run_plan(settings: PlanSettings) -> int:
    """Plan; PlanError (exit 2) for a problem refused, or one whose plan came out with a number that is not finite
    (numpy's RuntimeWarnings on the way are kept from the user: the result is checked instead)."""
    if settings.arm is not None:
        return run_arm_plan(settings.arm, settings.nodes, settings.as_json)
    problem = report_problem(settings.gravity, settings.links) if settings.problem is None else load_problem(
        settings.problem)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", RuntimeWarning)
        # the arms' knots first: a plan they refuse is refused before anything is printed, written or moved
        two_arms = None if settings.two_arms is None else _two_arm_knots(problem, settings)
        result, fastest = _plan(problem, settings)
    for w in caught:
        if not issubclass(w.category, RuntimeWarning):      # anything else is said as it would have been
            warnings.showwarning(w.message, w.category, w.filename, w.lineno)
    where = _not_finite(result)
    if where:
        raise PlanError("bounds", f"the plan's {where} came out as no finite number: the problem's masses, lengths "
                                  "or limits are too far apart to plan with")
    _warn_of_excess(result["time_optimal"])
    if settings.plot is not None and fastest is not None:
        from host_tools.plan.plots import draw
        files = draw(settings.plot, fastest, result.get("_cost"), REPORTED if settings.problem is None else ())
        result["figures"] = [str(f) for f in files]
    if two_arms is not None and settings.two_arms.output is not None:
        from host_tools.client.trajectory import trajectory_json
        settings.two_arms.output.write_text(trajectory_json(two_arms.knots, two_arms.about))
        result["trajectory_file"] = {"output": str(settings.two_arms.output), **two_arms.shown}
    if two_arms is not None and settings.two_arms.execute:
        from host_tools.apps.two_arm_execute import execute
        from host_tools.cli.main import host_key
        wanted = settings.two_arms
        keys = (host_key(wanted.key_file, wanted.execute[0]), host_key(wanted.key_file, wanted.execute[1]))
        result["executed"], trace = execute(two_arms.limited, two_arms.profile, two_arms.knots, wanted, keys,
                                            lambda text: log.info(f"aspod plan: {text}"))
        if settings.plot is not None and trace is not None:
            from host_tools.apps.two_arm_figure import write_carry_figure
            figure = settings.plot / CARRY_FIGURE
            settings.plot.mkdir(parents=True, exist_ok=True)
            write_carry_figure(trace, figure, "aspod plan --execute: plan (dashed) against execution")
            result.setdefault("figures", []).append(str(figure))
    return _print(settings, result)


@dataclass(frozen=True)
class TwoArmKnots:
    """The two arms' plan as their controllers take it: the problem within the torque share, the slowed profile,
    each arm's knots, and what a trajectory file says of them (`about`) and the output shows (`shown`)."""
    limited: Any
    profile: Any
    knots: tuple[list, list]
    about: dict
    shown: dict


def _two_arm_knots(problem, settings: PlanSettings) -> TwoArmKnots:
    """The minimum-time plan within a share of the torque limits, run slower, as each example arm's knots
    (host_tools/apps/two_arm_plan.py); PlanError naming the arm, the joint and the limit (soft limit, speed) the
    curve through them would pass."""
    from firmware_py.arm_config import EXAMPLE_ARM
    from host_tools.apps.two_arm_plan import SHOULDER, ELBOW, controller_knots, curve_bounds_deg, executable_plan
    wanted: TwoArmSettings = settings.two_arms
    limited, profile = executable_plan(problem, wanted.torque_share, wanted.slower, settings.nodes + 1)
    arms = controller_knots(limited, profile, wanted.knots, EXAMPLE_ARM)
    about = {"tool": "aspod plan", "arms": f"two {EXAMPLE_ARM.name} arms (firmware_py/arm_config.py EXAMPLE_ARM), "
                                           "arm 1's controller leading (docs/two_arms.md)",
             "problem": "the report's example" if settings.problem is None else str(settings.problem),
             "links": problem.system.arms[0].links, "gravity_m_s2": problem.system.gravity,
             "plan": f"minimum time by reachability within {wanted.torque_share:g} of the torque limits, run "
                     f"{wanted.slower:g}x slower",
             "torque_share": wanted.torque_share, "slower": wanted.slower, "duration_s": round(profile.duration, 6),
             "start_deg": [[round(k[0].q_deg[j], 4) for j in (SHOULDER, ELBOW)] for k in arms],
             "top_speed_dps": [[math.ceil(curve_bounds_deg(k, j)[2] * 10) / 10 for j in (SHOULDER, ELBOW)]
                               for k in arms]}     # rounded up: a speed parameter set to it lets the curve run
    shown = {"knots": [len(k) for k in arms],
             **{key: about[key] for key in ("plan", "duration_s", "start_deg", "top_speed_dps")}}
    return TwoArmKnots(limited, profile, arms, about, shown)


def _warn_of_excess(to: dict) -> None:
    """A plan past a limit is still printed (its figures are the method's), but not silently: the phase-plane
    method's s'' between grid points passes a limit by O(h) across tangent switching points and along steep limit
    curves (more than 1 % on half of 34 random problems at 1000 nodes; far more on some, docs/planning.md);
    reachability passes one only if its refinement rounds ran out."""
    if to["method"] == "reach":
        excess, how = to["worst_violation_between_nodes"], f"after {to['refined']} rounds of halving intervals"
        hint = "give more --nodes"
    else:
        excess, how, hint = to["worst_violation"], "at its grid points", "--method reach plans within every limit"
    if excess > EXCESS_WARNED:
        log.warning("aspod plan: this plan passes a limit by %.1f %% %s; %s", 100 * excess, how, hint)


def _plan(problem, settings: PlanSettings) -> tuple[dict, Optional[TimeOptimal]]:
    """The result (its "_cost": the DP plan, for the figures), and the phase plane's plan (None by reachability)."""
    example = settings.problem is None
    pricing = Pricing.of(problem, settings.weights, settings.regen)
    if settings.method == "reach":
        reach, peak = _reach_result(problem, settings, pricing)
        return _with_cost(problem, settings, pricing, {
            "problem": "the report's example" if example else str(settings.problem),
            "model": _model(problem, pricing), "time_optimal": reach}, peak), None
    fastest = plan_time_optimal(problem, settings.nodes, settings.integrator)
    result = {
        "problem": "the report's example" if example else str(settings.problem),
        "model": _model(problem, pricing),
        "time_optimal": {"method": "phase", "integrator": fastest.integrator, "nodes": settings.nodes,
                         "duration_s": round(fastest.duration, 6),
                         "switching_points": [p.describe() for p in fastest.switching_points],
                         "islands": len(fastest.grid.speeds.islands),
                         "worst_violation": round(fastest.profile.worst_violation, 6),
                         "saturated_time": round(fastest.profile.saturated_time, 4),
                         "costs": costs_of(fastest.grid.t, fastest.profile.sd, pricing)},
    }
    if example:
        result["beside_report"] = beside_report(fastest.switching_points)
    return _with_cost(problem, settings, pricing, result, float(np.max(fastest.profile.sd))), fastest


def _not_finite(value: Any, where: str = "") -> str:
    """Where in a result (dicts, lists, numbers) a number is NaN or infinite ("" if none is)."""
    if isinstance(value, dict):
        value = {k: v for k, v in value.items() if k != "_cost"}
        items = value.items()
    elif isinstance(value, (list, tuple)):
        items = enumerate(value)
    else:
        return where if isinstance(value, (float, np.floating)) and not math.isfinite(value) else ""
    for key, item in items:
        found = _not_finite(item, f"{where}.{key}" if where else str(key))
        if found:
            return found
    return ""


def _model(problem, pricing: Pricing) -> dict:
    return {"links": problem.system.arms[0].links, "gravity": problem.system.gravity,
            "path": problem.path.describe(), "limits": problem.limits.describe(),
            "motors": motors_of(problem).describe(), "weights": [float(w) for w in pricing.weights],
            "regeneration": pricing.regen}


def _with_cost(problem, settings: PlanSettings, pricing: Pricing, result: dict, peak_sd: float) -> dict:
    """The dynamic-programming plan, when the objective is not time alone (kept as "_cost" for the figures); its
    grid's speeds span `peak_sd`, the minimum-time plan's highest s', unless --dp-speed-step says otherwise."""
    if settings.objective == "time":
        return result
    step = settings.dp_speed_step or SPAN_MARGIN * peak_sd / (settings.dp_speeds - 1)
    cost = plan_cost_optimal(problem, settings.objective, DpGrid(settings.dp_intervals, settings.dp_speeds, step),
                             settings.max_time, pricing)
    result["cost_optimal"] = {"objective": cost.objective, "duration_s": round(cost.profile.duration, 6),
                              "max_time": settings.max_time, "time_weight": cost.time_weight,
                              "grid": {"intervals": cost.grid.intervals, "speeds": cost.grid.speeds,
                                       "speed_step": cost.grid.speed_step},
                              "worst_violation": round(cost.profile.worst_violation, 6), "costs": cost.costs}
    fastest_cost = result["time_optimal"].get("costs", {}).get(settings.objective)
    if fastest_cost is not None and cost.costs[settings.objective] > fastest_cost * (1 + 1e-6) and (
            settings.max_time is None or result["time_optimal"]["duration_s"] <= settings.max_time):
        result["cost_optimal"]["coarse"] = (
            f"the minimum-time plan costs less by this objective ({fastest_cost:.4g} against "
            f"{cost.costs[settings.objective]:.4g}): the grid does not hold the cheapest profile; give more "
            f"--dp-speeds or --dp-intervals, or a --dp-speed-step that spans the minimum-time plan's speeds")
    if settings.objective == "energy" and not np.any(pricing.weights != pricing.weights[0]):
        rise = potential_rise(problem)
        result["cost_optimal"]["chooses"] = False
        result["cost_optimal"]["why"] = (
            f"the report's index, sum u.dq, cannot choose a profile: from rest to rest it equals the change of the "
            f"potential energy along the path, {rise * pricing.weights[0]:.4f} J here, for every profile (this one is "
            f"the grid's tie-break); --objective electrical or thermal can choose")
    result["_cost"] = cost
    return result


def _print(settings: PlanSettings, result: dict) -> int:
    result.pop("_cost", None)
    print(json.dumps(result, indent=1) if settings.as_json else _text(result))
    return EXIT_OK


def _text(result: dict) -> str:
    to = result["time_optimal"]
    lines = [f"{result['problem']}: links {result['model']['links']}, gravity {result['model']['gravity']} m/s^2"]
    if to["method"] == "reach":
        squeeze = to["squeeze"]
        lines.append(f"minimum time (reachability, order {to['order']}, {to['nodes']} intervals): "
                     f"{to['duration_s']:.4f} s, a joint saturated {to['saturated_time']:.1%} of the time, "
                     f"worst excess between nodes "
                     f"{to['worst_violation_between_nodes']:.2%}, planned in {to['solve_time_s'] * 1e3:.1f} ms"
                     + ("" if squeeze is None else f"; the squeeze free (largest {squeeze['max_n']:.3g} N)"))
    else:
        lines += [f"minimum time ({to['integrator']}, {to['nodes']} intervals): {to['duration_s']:.4f} s, "
                  f"a joint saturated {to['saturated_time']:.1%} of the time, worst excess {to['worst_violation']:.2%}",
                  "  candidate switching points:"]
    for p in to.get("switching_points", []):
        joint = f" joint {p['joint']}" if p["joint"] else ""
        lines.append(f"    {p['kind']:13}{joint:9} s = {p['s']:.4f}  s' = {p['sd']:.3f}  "
                     f"{'kept' if p['kept'] else 'discarded: ' + p['why']}")
    for row in result.get("beside_report", []):
        r, h = row["report"], row["here"]
        lines.append(f"  report {row['kind']:13} ({r['s']}, {r['sd']})  here ({h['s']:.4f}, {h['sd']:.3f})  "
                     f"off by {row['error_s']:+.1%} in s, {row['error_sd']:+.1%} in s'")
    if "cost_optimal" in result:
        co = result["cost_optimal"]
        lines.append(f"minimum {co['objective']} (dynamic programming, {co['grid']['intervals']} x "
                     f"{co['grid']['speeds']}): {co['duration_s']:.4f} s")
        for note in ("why", "coarse"):
            if note in co:
                lines.append(f"  {co[note]}")
    motors = result["model"]["motors"]
    lines.append(f"motors: {motors['source']}; weights {', '.join(f'{w:g}' for w in result['model']['weights'])}"
                 + (", with regeneration" if result["model"]["regeneration"] else ""))
    lines.append("costs of each plan, J (electrical: work + copper loss R i^2"
                 + ("" if result["model"]["regeneration"] else ", none given back") + "; energy: the report's "
                 "sum u.dq, the same for every profile; work: sum |u dq|; thermal: copper loss):")
    for name, costs in ((("minimum time", to["costs"]),) if "costs" in to else ()) + (
            (("minimum " + result["cost_optimal"]["objective"], result["cost_optimal"]["costs"]),)
            if "cost_optimal" in result else ()):
        lines.append(f"  {name:16} " + "  ".join(f"{k} {v:.4g}" for k, v in costs.items()))
    for f in result.get("figures", []):
        lines.append(f"  figure: {f}")
    if "trajectory_file" in result:
        tf = result["trajectory_file"]
        lines.append(f"trajectory file {tf['output']}: {tf['plan']}: {tf['duration_s']:.3f} s")
        for arm, (count, (j1, j2), (v1, v2)) in enumerate(zip(tf["knots"], tf["start_deg"], tf["top_speed_dps"]), 1):
            lines.append(f"  arm {arm}: {count} knots from j1 {j1:.2f}, j2 {j2:.2f} deg, at most {v1:g} and {v2:g} "
                         f"deg/s (`traj load {tf['output']} arm {arm}`)")
        lines.append("  each arm's controller runs its knots from their start, at rest, with j1_speed_dps and "
                     "j2_speed_dps at least those speeds")
    if "executed" in result:
        ex = result["executed"]
        lines.append(f"executed on {', '.join(ex['links'])}: plan {ex['plan_s']:.3f} s, every joint's motion ended "
                     f"at {ex['ended_s']:.3f} s")
        for arm, (err, ends) in enumerate(zip(ex["tracking_deg"], ex["outcomes"]), 1):
            lines.append(f"  arm {arm}: shoulder and elbow within {err:.2f} deg of their knots' curve (telemetry); "
                         + ", ".join(f"{axis} {outcome}" for axis, outcome in ends.items()))
        ob = ex["object"]
        lines.append("  the object: no control endpoint beside the links, not seen" if ob is None else
                     f"  the object (the simulator's truth, {ob['readings']} readings): within "
                     f"{ob['path_error_mm']:.2f} mm of its path, squeeze at most {ob['squeeze_n']:.2f} N, grasps "
                     f"{', '.join(ob['grasps'])}")
    return "\n".join(lines)


# ---- the command line: its options, examples and run --------------------------------------------------------

EXAMPLES = [
    "aspod plan",
    "aspod plan --json --plot figures",
    "aspod plan --objective thermal --max-time 2",
    "aspod plan --objective electrical --weights 1,1,2,2 --regen",
    "aspod plan --problem my_path.json --objective time --integrator ab2",
    "aspod plan --method reach --nodes 99 --squeeze free --objective time",
    "aspod plan --method reach --order 2 --nodes 99 --objective time",
    "aspod plan --arm-to j1=20,j2=-15 --output move.json",
    "aspod plan --links rod --gravity --objective time --output two.json",
    "aspod plan --links rod --gravity --objective time --execute LINK,LINK2 --set-speeds",
]


def add_options(plan: argparse.ArgumentParser) -> None:
    plan.add_argument("--problem", type=Path, default=None, metavar="FILE",
                      help="a path, arms, object and limits from a JSON file (default: the report's example)")
    plan.add_argument("--objective", choices=("time", "electrical", "energy", "work", "thermal"),
                      default="electrical",
                      help="time: the minimum-time plan alone; otherwise also the dynamic-programming plan "
                           "minimising this: electrical (default), the energy the motors draw, their work and copper "
                           "losses; energy, the report's index, which cannot choose a profile (it is the change of "
                           "potential energy for all); work; thermal, the copper losses")
    plan.add_argument("--weights", type=weights_list, default=None, metavar="W1,W2,W3,W4",
                      help="each joint's weight in the minimum-cost plan (default: the problem file's, else 1 each)")
    plan.add_argument("--regen", action="store_true",
                      help="electrical: energy a joint gives back returns to the supply (default: it is lost)")
    plan.add_argument("--max-time", type=bounded(float, 1e-6, 1e6), default=None, metavar="S",
                      help="the minimum-cost plan's time bound in seconds")
    plan.add_argument("--method", choices=("phase", "reach"), default="phase",
                      help="minimum time: phase, the report's switching points on the phase plane (default); reach, "
                           "reachability (TOPP-RA), every torque within its limits between grid points too")
    plan.add_argument("--squeeze", type=squeeze_force, default=None, metavar="N|free",
                      help="--method reach: the squeeze force between the grasps a free variable, |squeeze| <= N "
                           "newtons, or unbounded (free); default none, the load shared without squeeze")
    plan.add_argument("--order", type=int, choices=(1, 2), default=1,
                      help="--method reach: 1, s'' constant between grid points (default; takes --squeeze); 2, s'' "
                           "linear, on grid points placed where time is lost (within 0.1 %% of a dense plan at 100)")
    plan.add_argument("--integrator", choices=("ab2", "rk4"), default="rk4",
                      help="limit curves by the report's 2nd-order Adams-Bashforth, or 4th-order Runge-Kutta "
                           "(default)")
    # at most plan.reach.MAX_GRIDPOINTS - 1 (a reach plan takes nodes + 1 points; not imported: the CLI starts light)
    plan.add_argument("--nodes", type=bounded(int, 10, 199_999), default=2000,
                      help="intervals in s for the minimum-time plan (default 2000)")
    plan.add_argument("--dp-intervals", type=bounded(int, 2, 5000), default=100,
                      help="dynamic programming: intervals in s (default 100, the report's)")
    plan.add_argument("--dp-speeds", type=bounded(int, 3, 2001), default=201,
                      help="dynamic programming: speeds per node (default 201, the report's)")
    plan.add_argument("--dp-speed-step", type=bounded(float, 1e-6, 100.0), default=None, metavar="STEP",
                      help="dynamic programming: the step between speeds, 1/s (default: the speeds span the "
                           "minimum-time plan's highest s'; the report's 0.005 spans 0..1, a fifth of it)")
    plan.add_argument("--gravity", action="store_true",
                      help="the example with gravity on (the report's points are matched with it off)")
    plan.add_argument("--links", choices=("point", "rod"), default="point",
                      help="the example's links: point masses at their far ends (default), or uniform rods")
    plan.add_argument("--json", action="store_true", help="print one JSON object")
    plan.add_argument("--plot", type=Path, default=None, metavar="DIR",
                      help="draw the report's Figs. 11-17 into DIR; with --execute also the carry, plan against "
                           "execution (two_arm_carry.png, from the simulator's control endpoint)")
    plan.add_argument("--output", type=Path, default=None, metavar="FILE.json",
                      help="write the trajectory file teleop's `traj load` takes: without --arm-to, the two arms' "
                           "plan, each example arm's knots (`traj load FILE arm 1|2`), refused if a joint would "
                           "pass its soft limit or speed limit")
    plan.add_argument("--torque-share", type=bounded(float, 0.05, 1.0), default=None, metavar="F",
                      help="--output: the file's plan is the minimum-time plan within this share of the torque "
                           "limits (default 0.8: the rest is the loops' to follow it with)")
    plan.add_argument("--slower", type=bounded(float, 1.0, 100.0), default=None, metavar="X",
                      help="--output: ... run X times slower (default 2: the loops lag its fastest accelerations)")
    plan.add_argument("--knots", type=bounded(int, 2, 256), default=None, metavar="N",
                      help="knots of the trajectory (of each arm's), at least (default 41 with --arm-to, 60 for two "
                           "arms, as their bench; more, up to the controller's 256, where the curve between them would "
                           "pass a joint's speed limit)")
    plan.add_argument("--execute", default=None, metavar="LINK,LINK2",
                      help="carry the plan out on two example arms' controllers, arm 1's (it leads) first, e.g. "
                           "aspod sim --arms 2's ASPOD-LINK and ASPOD-LINK2: checked against each controller's "
                           "limits (soft limits, speed, current, supply, gravity) before anything moves, then each arm "
                           "homed, at the start, jaws closed on the object, both started on one tick and measured "
                           "(docs/two_arms.md)")
    plan.add_argument("--key-file", type=Path, default=None,
                      help="--execute: the links' key file (default: each simulator's own, found from its link)")
    plan.add_argument("--set-speeds", action="store_true",
                      help="--execute: raise a joint's speed parameter under the plan's need to it (said), within its "
                           "range, instead of refusing the plan")
    arm = plan.add_argument_group("ASPOD's own arm (a trajectory file for teleop's `traj load`)")
    arm.add_argument("--arm-to", action="append", default=[], metavar="J=DEG[,J=DEG]",
                     help="plan a minimum-time move of ASPOD's arm to these angles (j1..j4, mount; repeatable) "
                          "within the controller's default current and speed limits")
    arm.add_argument("--arm-from", action="append", default=None, metavar="J=DEG[,J=DEG]",
                     help="the start pose (default: where `home all` leaves each joint, -1.146 deg); the arm must "
                          "stand there for `traj run`")
    arm.add_argument("--arm-gravity", choices=("earth", "orbit"), default=None, help="(default earth)")
    arm.add_argument("--payload-kg", type=bounded(float, 0.0, 1000.0), default=None, metavar="M",
                     help="mass in the gripper (default 0)")


def run(args: argparse.Namespace) -> int:
    from host_tools.apps.two_arm_execute import ExecuteError
    from host_tools.cli import settings
    try:
        return run_plan(settings.plan_settings(args))
    except ExecuteError as exc:
        log.error(f"aspod plan: --execute: {exc}")
        return EXIT_FAILED
