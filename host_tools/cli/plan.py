"""`aspod plan`: the report's trajectory planning (docs/planning.md).

    aspod plan                                   the report's example: minimum time, then minimum energy
    aspod plan --json --plot figures             ... as JSON, and its Figs. 11-17 as PNG files
    aspod plan --objective thermal --max-time 2  minimum heat in the motors within 2 s
    aspod plan --problem FILE                    a path, arms and limits of your own (host_tools/plan/problem_file.py)

Exit status: 0 planned, 2 a problem refused (out of reach, limits too weak, a grid too coarse: the reason says).
"""
from __future__ import annotations

import json

from host_tools.cli.settings import PlanSettings
from host_tools.exit_codes import EXIT_OK
from host_tools.plan.energy import DpGrid, costs_of, plan_cost_optimal
from host_tools.plan.example import REPORTED, beside_report, report_problem
from host_tools.plan.problem_file import load_problem
from host_tools.plan.timeopt import plan_time_optimal


def run_plan(settings: PlanSettings) -> int:
    example = settings.problem is None
    problem = report_problem(settings.gravity, settings.links) if example else load_problem(settings.problem)
    fastest = plan_time_optimal(problem, settings.nodes, settings.integrator)
    cost = None
    if settings.objective != "time":
        cost = plan_cost_optimal(problem, settings.objective,
                                 DpGrid(settings.dp_intervals, settings.dp_speeds, settings.dp_speed_step),
                                 settings.max_time)
    result = {
        "problem": "the report's example" if example else str(settings.problem),
        "model": {"links": problem.system.arms[0].links, "gravity": problem.system.gravity,
                  "path": problem.path.describe(), "limits": problem.limits.describe()},
        "time_optimal": {"integrator": fastest.integrator, "nodes": settings.nodes,
                         "duration_s": round(fastest.duration, 6),
                         "switching_points": [p.describe() for p in fastest.switching_points],
                         "islands": len(fastest.grid.speeds.islands),
                         "worst_violation": round(fastest.profile.worst_violation, 6),
                         "saturated_time": round(fastest.profile.saturated_time, 4),
                         "costs": costs_of(fastest.grid.t, fastest.profile.sd)},
    }
    if example:
        result["beside_report"] = beside_report(fastest.switching_points)
    if cost is not None:
        result["cost_optimal"] = {"objective": cost.objective, "duration_s": round(cost.profile.duration, 6),
                                  "max_time": settings.max_time, "time_weight": cost.time_weight,
                                  "grid": {"intervals": cost.grid.intervals, "speeds": cost.grid.speeds,
                                           "speed_step": cost.grid.speed_step},
                                  "worst_violation": round(cost.profile.worst_violation, 6), "costs": cost.costs}
    if settings.plot is not None:
        from host_tools.plan.plots import draw
        files = draw(settings.plot, fastest, cost, REPORTED if example else ())
        result["figures"] = [str(f) for f in files]
    if settings.as_json:
        print(json.dumps(result, indent=1))
    else:
        print(_text(result))
    return EXIT_OK


def _text(result: dict) -> str:
    to = result["time_optimal"]
    lines = [f"{result['problem']}: links {result['model']['links']}, gravity {result['model']['gravity']} m/s^2",
             f"minimum time ({to['integrator']}, {to['nodes']} intervals): {to['duration_s']:.4f} s, "
             f"a joint saturated {to['saturated_time']:.1%} of the time, worst excess {to['worst_violation']:.2%}",
             "  candidate switching points:"]
    for p in to["switching_points"]:
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
    lines.append("costs of each plan (energy: the report's sum u.dq, J; work: sum |u dq|, J; thermal: sum u^2 dt):")
    for name, costs in (("minimum time", to["costs"]),) + (
            (("minimum " + result["cost_optimal"]["objective"], result["cost_optimal"]["costs"]),)
            if "cost_optimal" in result else ()):
        lines.append(f"  {name:16} " + "  ".join(f"{k} {v:.4g}" for k, v in costs.items()))
    for f in result.get("figures", []):
        lines.append(f"  figure: {f}")
    return "\n".join(lines)
