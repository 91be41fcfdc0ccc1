"""`aspod plan`: the model, the report's time-optimal and dynamic-programming planners, its example, the command."""
from __future__ import annotations

import dataclasses
import json
import os
import re
import sys
import warnings

import numpy as np
import pytest

from host_tools.plan.bounds import Limits
from host_tools.plan.energy import DpGrid, Pricing, costs_of, plan_cost_optimal, profile_costs
from host_tools.plan.errors import PlanError
from host_tools.plan.example import REPORTED, report_problem
from host_tools.cli.main import main
from host_tools.plan.model import Held, two_arms
from host_tools.plan.paths import PiecewisePath, PolynomialPath
from host_tools.plan.phase import Problem
from host_tools.plan.problem_file import load_problem, problem_from_dict
from host_tools.plan.reach import plan_reach
from host_tools.plan.timeopt import plan_time_optimal
from host_tools.worlds.child import run

CURVED = PolynomialPath((0.9, 0.3, 0.1), (0.5, 0.4, -0.2))


def _energy(system, q, qd):
    """Kinetic plus potential energy of both arms and the object, from first principles (not from the model's
    dynamics), to check the model's torques against."""
    total = 0.0
    for k, arm in enumerate(system.arms):
        a, w = q[:, 2 * k:2 * k + 2], qd[:, 2 * k:2 * k + 2]
        (m1, m2), (l1, _), (r1, r2), (i1, i2) = arm.masses, arm.lengths, arm.centres, arm.inertias
        q1, q12, w12 = a[:, 0], a[:, 0] + a[:, 1], w[:, 0] + w[:, 1]
        v1 = r1 * w[:, 0]
        v2 = np.hypot(-l1 * np.sin(q1) * w[:, 0] - r2 * np.sin(q12) * w12, l1 * np.cos(q1) * w[:, 0] + r2 * np.cos(q12) * w12)
        height = m1 * (arm.base[1] + r1 * np.sin(q1)) + m2 * (arm.base[1] + l1 * np.sin(q1) + r2 * np.sin(q12))
        total = total + 0.5 * (m1 * v1 ** 2 + i1 * w[:, 0] ** 2 + m2 * v2 ** 2 + i2 * w12 ** 2) + system.gravity * height
    hand = system.arms[0].forward(q[:, :2])
    v = np.einsum("nij,nj->ni", system.arms[0].jacobian(q[:, :2]), qd[:, :2])
    return total + 0.5 * system.held.mass * (v ** 2).sum(1) + system.held.mass * system.gravity * hand[:, 1]


@pytest.mark.parametrize("links", ["rod", "point"])
def test_the_parameterized_dynamics_deliver_the_power_the_chain_takes(links):
    """u . q' = dE/dt along s(t) = s0 + s' t + s'' t^2 / 2, for u = a s'' + b s'^2 + c: the closed chain's
    torques are right (inertia, Coriolis, gravity, the object's share), and the squeeze does no work."""
    system = two_arms(links=links)
    s, sd, sdd, dt = np.linspace(0.05, 0.95, 9), 1.7, -0.9, 1e-6
    co = system.coefficients(CURVED, s)
    hands = system.hands(co.joints.q)
    assert np.allclose(hands[:, 1] - hands[:, 0], [0.25, 0.0], atol=1e-12)        # the chain is closed

    def energy(t):
        jp = system.joint_path(CURVED, s + sd * t + sdd * t * t / 2)
        return _energy(system, jp.q, jp.q_s * (sd + sdd * t))
    rate = (energy(dt) - energy(-dt)) / (2 * dt)
    u = co.a * sdd + co.b * sd ** 2 + co.c
    assert np.allclose((u * co.joints.q_s * sd).sum(1), rate, rtol=1e-6, atol=1e-6)
    assert np.allclose((co.n * co.joints.q_s).sum(1), 0.0, atol=1e-12)


def test_the_example_finds_the_reports_three_switching_points():
    """The report's zero-inertia points (0.2634, 5.956), (0.9337, 6.098) and tangent point (0.8, 6.968): each
    within 1.6 % in s and 1 % in s' of a candidate of the same kind found here."""
    plan = plan_time_optimal(report_problem(), nodes=1000)
    for kind, _, s, sd in REPORTED:
        near = min((p for p in plan.switching_points if p.kind == kind), key=lambda p: abs(p.s - s))
        assert abs(near.s - s) / s < 0.016 and abs(near.sd - sd) / sd < 0.01, (kind, near)


def test_the_minimum_time_profile_saturates_a_joint_throughout_and_keeps_every_limit():
    for integrator in ("ab2", "rk4"):
        plan = plan_time_optimal(report_problem(), nodes=2000, integrator=integrator)
        assert plan.profile.saturated_time > 0.99
        assert plan.profile.worst_violation < 0.002          # at the nodes, the grid's O(h)
        assert (plan.profile.sd <= plan.grid.mvc * (1 + 1e-9)).all()
    coarse = plan_time_optimal(report_problem(), nodes=200).duration
    fine = plan_time_optimal(report_problem(), nodes=4000).duration
    assert abs(coarse - fine) / fine < 1e-3


def test_the_reports_energy_index_cannot_choose_a_profile():
    """sum u^T dq is the change of potential energy whatever the profile: the same for the minimum-time plan and
    every dynamic-programming plan, and 0 with gravity off."""
    for gravity, expected in ((True, None), (False, 0.0)):
        problem = report_problem(gravity=gravity)
        fastest = plan_time_optimal(problem, nodes=1000)
        plans = [costs_of(fastest.grid.t, fastest.profile.sd, Pricing.of(problem))["energy"]]
        for objective, bound in (("energy", None), ("thermal", 2.0), ("work", 3.0)):
            plans.append(plan_cost_optimal(problem, objective, max_time=bound).costs["energy"])
        jp = problem.system.joint_path(problem.path, [0.0, 1.0])
        rise = np.diff(_energy(problem.system, jp.q, np.zeros_like(jp.q)))[0]
        assert np.allclose(plans, expected if expected is not None else rise, atol=1e-3 * max(1.0, abs(rise)))


def test_minimum_heat_within_a_time_bound_meets_the_bound_and_costs_more_the_tighter_it_is():
    """With gravity, holding the object costs heat too: unbounded, the cheapest motion is neither the fastest nor
    the slowest; a time bound tighter than it is met, at a higher cost."""
    problem = report_problem(gravity=True)
    free = plan_cost_optimal(problem, "thermal")                          # the report's grid: s' up to 1 /s
    tight = plan_cost_optimal(problem, "thermal", max_time=0.97 * free.profile.duration)
    assert tight.profile.duration <= 0.97 * free.profile.duration
    assert tight.costs["thermal"] > free.costs["thermal"]
    assert tight.profile.worst_violation == 0.0 and free.profile.worst_violation == 0.0
    assert free.profile.duration < 0.2 * plan_cost_optimal(problem, "work").profile.duration
    assert tight.profile.duration > plan_time_optimal(problem, nodes=1000).duration


def test_the_electrical_energy_chooses_a_profile_in_earth_and_in_orbit_and_the_reports_index_says_it_cannot(
        tmp_path):
    """The default objective: the motors' work, their copper losses (ASPOD's J1 and J2 drives, R i^2) and the
    drives' own draw. With gravity and without, its plan lies between the fastest and a crawl and costs less by
    it than either; the report's index is the same for every profile, and `aspod plan` says so, naming what it
    equals (the rise of potential energy: 3.759 J with gravity, 0 without)."""
    for gravity in (True, False):
        problem = report_problem(gravity=gravity)
        pricing = Pricing.of(problem)
        fastest = plan_time_optimal(problem, nodes=1000)
        grid = DpGrid(100, 201, 1.2 * fastest.profile.sd.max() / 200)
        cheapest = plan_cost_optimal(problem, "electrical", grid)
        crawl = plan_cost_optimal(problem, "energy")                    # the report's grid: its tie-break, slow
        assert fastest.duration < cheapest.profile.duration < crawl.profile.duration / 10
        assert cheapest.costs["electrical"] < costs_of(fastest.grid.t, fastest.profile.sd, pricing)["electrical"]
        assert cheapest.costs["electrical"] < crawl.costs["electrical"] / 5
        said = run([sys.executable, "-m", "host_tools.cli.main", "plan", "--objective", "energy", "--json",
                    "--nodes", "300", "--dp-intervals", "40"] + ["--gravity"] * gravity, text=True, timeout_s=300)
        co = json.loads(said.stdout)["cost_optimal"]
        assert co["chooses"] is False and "cannot choose" in co["why"]
        assert f"{3.759 if gravity else 0.0:.3f}" in co["why"] and "potential energy" in co["why"]


def test_a_plans_costs_are_priced_again_from_its_profile_as_the_dp_priced_them():
    """`profile_costs` (the objective's prediction for a plan executed: bench/bench_two_arms.py) gives a
    cost-optimal plan's profile the costs the DP gave it, with regeneration and without, and the drives' share
    of the electrical energy; and the example along another straight line is that line's problem."""
    problem = report_problem(gravity=True, links="rod")
    for regen in (False, True):
        pricing = Pricing.of(problem, regen=regen)
        plan = plan_cost_optimal(problem, "electrical", DpGrid(40, 61, 0.05), pricing=pricing)
        again = profile_costs(problem, plan.profile, pricing)
        assert again == {**plan.costs, "drives": pytest.approx(pricing.drive_w * plan.profile.duration, rel=1e-12)}
        assert again["electrical"] > again["drives"] > 0
    up = report_problem(gravity=True, links="rod", path=((1.0, 0.3), (1.0, 0.9)))
    assert up.path(np.array([0.0, 1.0])).w == pytest.approx(np.array([[1.0, 0.3], [1.0, 0.9]]), abs=1e-15)


def test_weights_and_regeneration_price_the_plan_and_bad_ones_are_refused(tmp_path):
    problem = report_problem(gravity=True)
    grid = DpGrid(40, 101, 0.08)
    plain = plan_cost_optimal(problem, "electrical", grid)
    back = plan_cost_optimal(problem, "electrical", grid, pricing=Pricing.of(problem, regen=True))
    assert back.costs["electrical"] < plain.costs["electrical"]        # what the arms give back on the way down
    heavy = plan_cost_optimal(problem, "electrical", grid, pricing=Pricing.of(problem, weights=(1, 1, 10, 10)))
    assert heavy.costs["electrical"] > plain.costs["electrical"]
    for weights in ((1, 1, 1), (1, 1, -1, 1), (1, 1, float("nan"), 1)):
        with pytest.raises(PlanError, match="weight"):
            Pricing.of(problem, weights=weights)
    spec = {"path": {"kind": "line", "start": [0.688, 0.331], "end": [1.716, 0.504]}, "weights": [2, 1, 1, 1],
            "motors": {"resistance_ohm": [1, 1, 1, 1], "torque_constant": [0.1, 0.1, 0.1, 0.1],
                       "ratio": [100, 100, 100, 100], "drive_w": 5}}
    (tmp_path / "p.json").write_text(json.dumps(spec))
    out = json.loads(run([sys.executable, "-m", "host_tools.cli.main", "plan", "--problem", str(tmp_path / "p.json"),
                          "--json", "--nodes", "200", "--dp-intervals", "20"], text=True, timeout_s=300).stdout)
    assert out["model"]["weights"] == [2, 1, 1, 1] and out["model"]["motors"]["drive_w"] == 5
    assert out["model"]["motors"]["copper_w_per_nm2"] == [0.01] * 4                  # 1 / (0.1 x 100)^2
    for bad, reason in (({"resistance_ohm": [1, 1, 1, 1]}, "torque_constant"),
                        ({**spec["motors"], "efficiency": [1, 1, 1, 2]}, "motors.efficiency"),
                        ({**spec["motors"], "volts": 3}, "unknown keys")):
        (tmp_path / "bad.json").write_text(json.dumps({**spec, "motors": bad}))
        done = run([sys.executable, "-m", "host_tools.cli.main", "plan", "--problem", str(tmp_path / "bad.json")],
                   text=True, timeout_s=300)
        assert done.returncode == 2 and reason in done.stderr, done.stderr
    done = run([sys.executable, "-m", "host_tools.cli.main", "plan", "--weights", "1,x,1,1"], text=True, timeout_s=60)
    assert done.returncode == 2 and "--weights" in done.stderr


def test_state_dependent_limits_keep_the_voltage_within_bounds():
    """DC motors (back-emf): the bounded quantity u + K q' stays within its limits, and the motion is slower."""
    torque = plan_time_optimal(Problem(two_arms(), CURVED, Limits.symmetric((30, 20, 35, 15))), nodes=1000)
    motors = Problem(two_arms(), CURVED, Limits.symmetric((30, 20, 35, 15), back_emf=(2.0, 1.5, 2.0, 1.5)))
    plan = plan_time_optimal(motors, nodes=1000)
    assert plan.duration > torque.duration
    assert plan.profile.worst_violation < 0.01 and plan.profile.saturated_time > 0.98


def test_a_speed_cap_bounds_the_time_optimal_the_dp_and_the_reachability_profiles():
    free = report_problem()                                       # its minimum-time profile peaks near 7 /s
    fastest = plan_time_optimal(dataclasses.replace(free, speed_cap=3.0), 400)
    assert fastest.profile.sd.max() <= 3.0 + 1e-9 and fastest.duration > plan_time_optimal(free, 400).duration
    grid = DpGrid(20, 41, 0.1)                                    # speeds up to 4 /s, 0.1 apart
    within = plan_cost_optimal(free, "thermal", grid, max_time=0.8)     # the coolest within 0.8 s peaks at 2.0 /s
    capped = plan_cost_optimal(dataclasses.replace(free, speed_cap=1.85), "thermal", grid, max_time=0.8)
    assert capped.profile.sd.max() <= 1.85 < within.profile.sd.max() and capped.profile.duration <= 0.8
    reached = plan_reach(dataclasses.replace(free, speed_cap=3.0), 50)      # x <= 3^2 at the grid points: all along
    assert np.sqrt(reached.x).max() <= 3.0 + 1e-9 and reached.duration > fastest.duration


def test_a_jump_in_the_paths_curvature_is_a_discontinuity_candidate():
    up = PolynomialPath((0.9, 0.5), (0.4, 0.2))
    bend = PolynomialPath((0.9 - 0.5 * 0.5 ** 2, 0.5 + 0.5, -0.5), (0.4, 0.2))      # same w and w' at s = 0.5
    plan = plan_time_optimal(Problem(two_arms(), PiecewisePath([0, 0.5, 1], [up, bend]),
                                     Limits.symmetric((30, 20, 35, 15))), nodes=1000)
    assert [p.s for p in plan.switching_points if p.kind == "discontinuity"] == [0.5]
    assert plan.profile.worst_violation < 0.02          # at the nodes: O(1/nodes), 0.4 % at 4000


@pytest.mark.parametrize("spec, what, said", [
    ({"path": {"kind": "line", "start": [0.2, 0.3], "end": [3.5, 0.3]}}, "reach", "leaves arm"),
    ({"path": {"kind": "line", "start": [0.9, 0.5], "end": [1.1, 0.6]}, "limits": {"symmetric": [3, 2, 3, 2]}},
     "bounds", "too weak to hold the object still"),
    ({"path": {"kind": "line", "start": [0.9, 0.5]}}, "path", "end"),
    ({"path": {"kind": "spiral"}}, "path", "unknown path kind"),
    ({"path": {"kind": "line", "start": [0.9, 0.5], "end": [1, 1]}, "limits": {"symmetric": [1, 2]}}, "file",
     "4 finite numbers"),
    ({"path": {"kind": "line", "start": [0.9, 0.5], "end": [1, 1]}, "gravity": "lots"}, "file", "gravity"),
    ({"path": {"kind": "line", "start": [0.9, 0.5], "end": [1, 1]}, "colour": 1}, "file", "unknown keys"),
    ({"path": {"kind": "line", "start": [0.9, 0.5], "end": [1, 1]}, "limits": {"symetric": [30, 20, 35, 15]}},
     "file", "unknown keys in 'limits'"),
    ({"path": {"kind": "line", "start": [0.9, 0.5], "end": [1, 1]}, "arms": {"elbows": [1.5, 1]}}, "file", "+1 or -1"),
    ({"path": {"kind": "piecewise", "knots": [0, 0.5, 1], "pieces": [
        {"kind": "line", "start": [0.9, 0.5], "end": [1.0, 0.5]},
        {"kind": "line", "start": [1.0, 0.5], "end": [1.0, 0.8]}]}}, "path", "jumps"),
])
def test_bad_problems_are_refused_with_the_reason(spec, what, said):
    with pytest.raises(PlanError) as caught:
        problem = problem_from_dict(spec)
        plan_time_optimal(problem, nodes=200)
    assert caught.value.what == what and said in caught.value.reason, caught.value


def test_a_grid_too_coarse_for_the_limits_is_refused():
    with pytest.raises(PlanError, match="grid: no admissible profile"):
        plan_cost_optimal(report_problem(gravity=True), "energy", DpGrid(intervals=4, speeds=5, speed_step=5.0))
    with pytest.raises(PlanError, match="grid"):
        plan_time_optimal(report_problem(), nodes=5)


def test_the_command_plans_the_example_as_json_and_draws_the_figures(tmp_path):
    done = run([sys.executable, "-m", "host_tools.cli.main", "plan", "--json", "--plot", str(tmp_path / "f"),
                "--nodes", "500"], text=True, timeout_s=300)
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    assert len(out["beside_report"]) == 3 and all(abs(r["error_s"]) < 0.016 for r in out["beside_report"])
    assert out["cost_optimal"]["objective"] == "electrical" and "why" not in out["cost_optimal"]    # can choose
    assert len(out["figures"]) == 7
    assert all((tmp_path / "f" / name).stat().st_size > 10_000 for name in
               ("fig11_limit_curves.png", "fig14_time_optimal_torques.png", "fig17_comparison.png"))
    bad = run([sys.executable, "-m", "host_tools.cli.main", "plan", "--problem", str(tmp_path / "none.json")],
              text=True, timeout_s=120)
    assert bad.returncode == 2 and "cannot read" in bad.stderr
    (tmp_path / "far.json").write_text(json.dumps({"path": {"kind": "line", "start": [0.2, 0.3], "end": [3.5, 0.3]}}))
    far = run([sys.executable, "-m", "host_tools.cli.main", "plan", "--problem", str(tmp_path / "far.json")],
              text=True, timeout_s=120)
    assert far.returncode == 2 and "reach" in far.stderr and far.stdout == ""


LINE = {"kind": "line", "start": [0.9, 0.5], "end": [1, 1]}


@pytest.mark.parametrize("spec, said", [
    ({"path": LINE, "object": {"grasps": 5}}, "object.grasps"),
    ({"path": LINE, "object": {"grasps": [[0, 0], "ab"]}}, "object.grasps"),
    ({"path": {"kind": "line", "start": [int("1" + "0" * 400), 0.5], "end": [1, 1]}}, "path.start"),
    ({"path": {"kind": "line", "start": [True, 0.5], "end": [1, 1]}}, "path.start"),
    ({"path": {"kind": "polynomial", "x": [0.9, False], "y": [0.5, 0.1]}}, "path.x"),
    ({"path": {"kind": "piecewise", "knots": [0, int("9" * 400)], "pieces": [LINE]}}, "path.knots"),
    ({"path": {"kind": "piecewise", "knots": [0, 1], "pieces": [{"kind": "piecewise", "knots": [0, 1],
                                                                  "pieces": [LINE]}]}}, "another piecewise"),
    ({"path": LINE, "object": {"size": [-0.25, 0.1]}}, "object.size"),
    ({"path": LINE, "gravity": int("1" + "0" * 400)}, "gravity"),
])
def test_values_of_the_wrong_kind_are_refused_naming_the_key(spec, said):
    with pytest.raises(PlanError) as caught:
        problem_from_dict(spec)
    assert said in caught.value.reason, caught.value


def test_a_problem_file_is_read_bounded_a_fifo_or_deep_nesting_refused(tmp_path):
    fifo = tmp_path / "fifo.json"
    os.mkfifo(fifo)
    with pytest.raises(PlanError, match="FIFO"):
        load_problem(fifo)                          # refused without opening it: no writer, no hang
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(PlanError, match="nests deeper than 32 levels"):
        load_problem(deep)
    for text, said in (('{"gravity": NaN}', "NaN is not a number JSON allows"), ('{"gravity": 1e400}', "out of range"),
                       ("\udcff", "not a problem file"), ('{"path": ', "not JSON")):
        (tmp_path / "bad.json").write_text(text, errors="surrogateescape")
        with pytest.raises(PlanError, match=said):
            load_problem(tmp_path / "bad.json")
    big = tmp_path / "big.json"
    big.write_text(" " * (2 << 20) + "{}")
    with pytest.raises(PlanError, match="larger than"):
        load_problem(big)


# ---- extreme numbers: refused with a true reason, never a NaN in it, never numpy's RuntimeWarning -----------------

REACHABLE = {"kind": "line", "start": [0.688, 0.331], "end": [1.716, 0.504]}


def _plan_quietly(capsys, tmp_path, spec: dict, *options: str) -> tuple[int, str]:
    """`aspod plan` on `spec` in this process: its exit status and stderr; fails on any RuntimeWarning."""
    (tmp_path / "p.json").write_text(json.dumps(spec))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        status = main(["plan", "--problem", str(tmp_path / "p.json"), "--nodes", "200", *options])
    assert not [w for w in caught if issubclass(w.category, RuntimeWarning)], [str(w.message) for w in caught]
    err = capsys.readouterr().err
    assert "nan" not in err.lower().replace("nanos", "").split() and "RuntimeWarning" not in err
    return status, err


@pytest.mark.parametrize("section, key, value, said", [
    ("arms", "masses", [1e300, 1e300], "arms.masses must be within -1e+06..1e+06, not 1e+300"),
    ("arms", "lengths", [1e200, 1e200], "arms.lengths must be within -1000..1000, not 1e+200"),
    ("arms", "separation", 1e9, "arms.separation must be within -1000..1000"),
    ("object", "mass", 1e308, "object.mass must be within -1e+06..1e+06, not 1e+308"),
    ("object", "size", [1e300, 1], "object.size must be within -1000..1000"),
    ("limits", "symmetric", [1e300] * 4, "limits.symmetric must be within -1e+09..1e+09, not 1e+300"),
    ("limits", "lower", [-1e308] * 4, "limits.lower must be within -1e+09..1e+09, not -1e+308"),
    ("arms", "masses", [1e-300, 1], "arms.masses must be 0 or at least 0.001, not 1e-300"),
    ("arms", "masses", [-1, 1], "arms.masses must be 0 or at least 0.001, not -1"),
    ("arms", "masses", [0, 1e-4], "arms.masses must be 0 or at least 0.001, not 0.0001"),
    ("object", "mass", 1e-12, "object.mass must be 0 or at least 0.001, not 1e-12"),
    ("arms", "lengths", [1e-9, 1], "arms.lengths must be at least 0.001, not 1e-09"),
    ("limits", "symmetric", [30, 1e-300, 35, 15], "joint 2's limits [-1e-300, 1e-300] are less than 0.001 apart"),
    ("limits", "back_emf", [1e300] * 4, "limits.back_emf must be within -1e+06..1e+06"),
])
def test_magnitudes_far_beyond_any_arms_are_refused_naming_the_key(capsys, tmp_path, section, key, value, said):
    status, err = _plan_quietly(capsys, tmp_path, {"path": REACHABLE, section: {key: value}})
    assert status == 2 and said in err


@pytest.mark.parametrize("spec", [
    {"path": REACHABLE, "limits": {"symmetric": [1e-3] * 4}},
    {"path": REACHABLE, "arms": {"masses": [1e-3, 1e-3]}, "object": {"mass": 1e-3}, "limits": {"symmetric": [1e-3] * 4}},
    {"path": REACHABLE, "arms": {"masses": [1e6, 1e6]}, "object": {"mass": 1e6}},
    {"path": REACHABLE, "limits": {"lower": [-30, -20, -35, 14.9], "upper": [30, 20, 35, 15]}},
])
def test_too_weak_to_hold_names_a_torque_outside_the_limits_it_names(capsys, tmp_path, spec):
    status, err = _plan_quietly(capsys, tmp_path, spec, "--objective", "time")
    assert status == 2, err
    said = re.search(r"joint (\d) needs (\S+) N m against its limits \[(\S+), (\S+)\]", err)
    assert said, err
    needs, lo, hi = (float(said.group(k)) for k in (2, 3, 4))
    assert not lo <= needs <= hi


def test_the_largest_numbers_a_problem_file_takes_plan_or_are_refused_without_a_warning(capsys, tmp_path):
    for masses, limits in (([1e6, 1e6], [1e9] * 4), ([0, 0], [1e9] * 4), ([1e-3, 1e-3], [1e-3] * 4),
                           ([1e-3, 1e6], [1e9, 1e-3, 1, 1e9])):
        status, err = _plan_quietly(capsys, tmp_path, {"path": REACHABLE, "arms": {"masses": masses},
                                                       "object": {"mass": masses[0]}, "gravity": 100,
                                                       "limits": {"symmetric": limits, "back_emf": [1e6] * 4}},
                                    "--objective", "energy", "--dp-intervals", "20", "--dp-speeds", "21")
        assert status in (0, 2) and "Traceback" not in err, err


@pytest.mark.parametrize("system, limits", [
    (two_arms(held=Held(1e308)), Limits.symmetric((30, 20, 35, 15))),
    (two_arms(lengths=(1e200, 1e200)), Limits.symmetric((30, 20, 35, 15))),
    (two_arms(), Limits.symmetric((30, 20, 35, 15), back_emf=(1e308,) * 4)),
])
def test_coefficients_that_overflow_are_refused_where_they_are_computed(system, limits):
    """Past the problem file's bounds (built in code): the torques' terms are checked finite, not planned with."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        with pytest.raises(PlanError) as caught:
            plan_time_optimal(Problem(system, PolynomialPath.line((0.688, 0.331), (1.716, 0.504)), limits), nodes=200)
    assert caught.value.what in ("bounds", "reach") and "nan" not in str(caught.value), caught.value


def test_a_plan_with_a_number_that_is_not_finite_is_found_where_it_is():
    from host_tools.cli.plan import _not_finite
    assert _not_finite({"a": [1.0, {"b": 2}], "c": None, "d": "nan"}) == ""
    assert _not_finite({"a": [1.0, {"b": float("nan")}]}) == "a.1.b"
    assert _not_finite({"time_optimal": {"costs": {"energy": np.float64("inf")}}}) == "time_optimal.costs.energy"


def test_a_maximum_velocity_curve_that_cannot_be_followed_is_refused_not_planned_past_the_limits():
    """A back-and-forth path with gravity and DC motors: every switching-point candidate between s = 0.32 and
    0.74 is discarded, so the lowest of the curves there was the maximum velocity curve itself, rising at
    s'' = +164 where only -216..-215 is admissible: a 'plan' 517 % over a limit (found by the review of
    2026-11-24). Now refused with the span and the way out; the reachability planner plans it within its limits."""
    from host_tools.plan.reach import sampled_torques
    problem = problem_from_dict({"path": {"kind": "polynomial", "x": [0.9, 1.0, -1.0], "y": [0.5, 0.2, 0.0]},
                                 "gravity": 9.81, "limits": {"symmetric": [30, 20, 35, 15],
                                                             "back_emf": [2, 1.5, 2, 1.5]}})
    with pytest.raises(PlanError) as refused:
        plan_time_optimal(problem, 1000)
    assert refused.value.what == "switching" and "--method reach" in refused.value.reason
    span = [float(v) for v in re.findall(r"s = ([\d.]+) to ([\d.]+)", refused.value.reason)[0]]
    assert 0.3 < span[0] < 0.55 < 0.73 < span[1] < 0.75
    plan = plan_reach(problem, 200)
    _, effort = sampled_torques(problem, plan, 20)
    assert np.all(np.abs(effort) <= np.array([30, 20, 35, 15]) * (1 + 1e-9))


def test_a_plan_past_a_limit_is_said_on_stderr_not_only_in_its_figures(tmp_path, capsys):
    """DC motors with six times the bench's back-emf constants: the phase-plane plan passes a voltage limit at its
    grid points by a few per cent (its x integrated from rest, docs/planning.md); aspod plan prints it and says
    so on stderr, with the way out. The reachability plan of the same problem is within its limits: no word."""
    spec = {"path": {"kind": "polynomial", "x": [0.9, 0.3, 0.1], "y": [0.5, 0.4, -0.2]},
            "limits": {"symmetric": [30, 20, 35, 15], "back_emf": [12, 9, 12, 9]}}
    (tmp_path / "p.json").write_text(json.dumps(spec))
    assert main(["plan", "--problem", str(tmp_path / "p.json"), "--nodes", "1000", "--json"]) == 0
    out, err = capsys.readouterr()
    excess = json.loads(out)["time_optimal"]["worst_violation"]
    assert 0.01 < excess < 0.2
    assert f"this plan passes a limit by {100 * excess:.1f} % at its grid points; --method reach" in err
    assert main(["plan", "--problem", str(tmp_path / "p.json"), "--nodes", "100", "--method", "reach"]) == 0
    assert "passes a limit" not in capsys.readouterr().err
