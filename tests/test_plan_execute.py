"""`aspod sim --arms 2` and `aspod plan --execute`: the report's two arms carry its example's object, planned and
executed through the two controllers' links (docs/two_arms.md), and a plan the controllers would not allow is
refused before anything moves.

The end-to-end tests run `aspod sim` and `aspod plan` as real subprocesses over TCP, in real time (the sim paced at
4x); their waits are bounded on the children's own time (host_tools/worlds/child.py), the plan's on the controllers'
(host_tools/apps/two_arm_execute.py), so a busy machine slows them, never fails them.
"""
from __future__ import annotations

import json
import math
import os
import signal
import sys
from pathlib import Path

import numpy as np
import pytest

from firmware_py.arm_config import EXAMPLE_ARM
from host_tools.apps.arm_plan import ARM_JOINTS
from host_tools.apps.two_arm_execute import ArmLimits, check_arm, path_error_m, planned_torques, tracking_error_deg
from host_tools.apps.two_arm_plan import controller_knots, executable_plan
from host_tools.client.control import ControlClient, find_control, simulator_key_file
from host_tools.worlds.child import Child, run
from host_tools.plan.example import PATH, report_problem

ASPOD = [sys.executable, "-m", "host_tools.cli.main"]
PLAN = ["plan", "--links", "rod", "--objective", "time", "--json"]


# ---- the checks before anything moves, against limits read from a controller --------------------------------

@pytest.fixture(scope="module")
def example_plan():
    problem = report_problem(gravity=True, links="rod")
    limited, profile = executable_plan(problem, 0.8, 2.0, 201)
    knots = controller_knots(limited, profile, 60, EXAMPLE_ARM)
    path = limited.system.joint_path(limited.path, profile.s)
    return limited, profile, knots, planned_torques(limited, profile), path.q_s * profile.sd[:, None]


def _limits(**change) -> ArmLimits:
    """The example arm's defaults with its speeds raised to 600 deg/s, a 28 V supply, Earth's gravity."""
    table = {p.name: p.default for p in EXAMPLE_ARM.parameter_table()}
    values = dict(soft_deg={j: (table[f"{j}_min_deg"], table[f"{j}_max_deg"]) for j in ARM_JOINTS},
                  speed_dps={j: 600.0 for j in ARM_JOINTS},
                  current_a={j: table[f"{j}_i_lim_a"] for j in ARM_JOINTS}, gravity_m_s2=9.80665, supply_v=28.0)
    values.update(change)
    return ArmLimits(**values)


def _check(example_plan, arm: int, limits: ArmLimits) -> list:
    _, _, knots, torques, speeds = example_plan
    return check_arm(arm + 1, knots[arm], torques[:, 2 * arm:2 * arm + 2], speeds[:, 2 * arm:2 * arm + 2], limits,
                     EXAMPLE_ARM, 9.80665)


def test_the_example_passes_the_example_arms_limits(example_plan):
    assert _check(example_plan, 0, _limits()) == [] and _check(example_plan, 1, _limits()) == []


def test_the_planned_torques_are_within_the_share_of_the_limits_the_plan_was_made_in(example_plan):
    limited, _, _, torques, _ = example_plan
    assert np.all(torques <= np.array(limited.limits.upper) + 1e-6)
    assert np.all(torques >= np.array(limited.limits.lower) - 1e-6)
    assert np.abs(torques).max() > 0.5 * np.array(limited.limits.upper).max()     # it uses them: not all zero


@pytest.mark.parametrize("change, said", [
    (dict(soft_deg={**_limits().soft_deg, "j2": (-3.0, 120.0)}), "arm 1 j2 reaches 141.8"),
    (dict(speed_dps={j: 3.0 for j in ARM_JOINTS}), "deg/s, above j1_speed_dps 3 (--set-speeds raises it to 5"),
    (dict(current_a={**_limits().current_a, "j1": 2.0}), "needs"),
    (dict(supply_v=5.0), "V (back EMF and its armature's drop at the plan's speed and torque), above the supply's "
                          "5.0 V"),
    (dict(gravity_m_s2=0.0), "the controller's gravity_m_s2 is 0, the plan's 9.80665"),
])
def test_a_limit_the_plan_would_pass_is_named(example_plan, change, said):
    problems = _check(example_plan, 0, _limits(**change))
    assert problems and any(said in p.text for p in problems), [p.text for p in problems]
    assert all(p.text.startswith("arm 1") for p in problems)


def test_a_speed_parameter_under_the_plan_says_what_to_raise_it_to_within_its_range(example_plan):
    problems = _check(example_plan, 1, _limits(speed_dps={j: 3.0 for j in ARM_JOINTS}))
    raised = dict(p.raise_to for p in problems)
    assert set(raised) == {"j1_speed_dps", "j2_speed_dps"}
    assert raised["j1_speed_dps"] == pytest.approx(159.6, abs=1.0) and raised["j2_speed_dps"] == pytest.approx(
        92.1, abs=1.0)          # the curve's top speeds (aspod plan --output says 159.6 and 92.1 at 2000 nodes)
    curr = _check(example_plan, 1, _limits(current_a={j: 0.5 for j in ARM_JOINTS}))
    assert curr and all(p.raise_to is None for p in curr)       # only a speed parameter is ever raised


def test_the_tracking_error_is_measured_from_the_start_that_fits_best(example_plan):
    """Telemetry 40 ms late against the curve with a known 0.3 deg offset: the start found, the error 0.3."""
    knots = example_plan[2][0]
    from firmware_py.hermite import HermiteProfile
    curves = [HermiteProfile([k.t_s for k in knots], [math.radians(k.q_deg[j]) for k in knots],
                             [math.radians(k.qd_deg_s[j]) for k in knots]) for j in (0, 1)]
    start_ms = 5040
    samples = [(start_ms + t, math.degrees(curves[0].sample(t / 1000)[0]) + 0.3,
                math.degrees(curves[1].sample(t / 1000)[0]) - 0.1) for t in range(0, 1100, 33)]
    error, found = tracking_error_deg(samples, knots, 5000)
    assert found == start_ms and error == pytest.approx(0.3, abs=1e-6)


def test_the_path_error_is_the_distance_to_the_nearest_point_of_the_path():
    problem = report_problem(gravity=True, links="rod")
    (x0, z0), (x1, z1) = PATH
    middle = ((x0 + x1) / 2, (z0 + z1) / 2)
    normal = np.array([-(z1 - z0), x1 - x0]) / math.hypot(x1 - x0, z1 - z0)
    off = (middle[0] + 0.004 * normal[0], middle[1] + 0.004 * normal[1])
    assert path_error_m(problem, [middle]) < 1e-6
    assert path_error_m(problem, [middle, off]) == pytest.approx(0.004, abs=1e-5)


# ---- the command line's refusals (nothing is started) ---------------------------------------------------------

@pytest.mark.parametrize("args, said", [
    (["--execute", "socket://127.0.0.1:1"], "give the two arms' links"),
    (["--execute", "socket://127.0.0.1:1,socket://127.0.0.1:1"], "give the two arms' links"),
    (["--set-speeds"], "--set-speeds: only with --execute"),
    (["--key-file", "k.key"], "--key-file: only with --execute"),
    (["--arm-to", "j1=10", "--execute", "a,b"], "--execute are the two arms' plan's"),
])
def test_bad_execute_options_are_refused_with_a_reason(args, said):
    done = run([*ASPOD, "plan", "--links", "rod", *args], timeout_s=60)
    assert done.returncode == 2 and said in done.stderr.decode(), done.stderr.decode()


def test_execute_needs_the_example_arms_rod_links():
    done = run([*ASPOD, "plan", "--execute", "a,b"], timeout_s=60)
    assert done.returncode == 2 and "plan them with --links rod" in done.stderr.decode()


def test_two_arm_sim_options_not_built_are_refused():
    done = run([*ASPOD, "sim", "--arms", "2", "--port", "/dev/null"], timeout_s=60)
    assert done.returncode == 2 and "--arms 2 with --port is not built" in done.stderr.decode()


# ---- end to end: aspod sim --arms 2, aspod plan --execute --------------------------------------------------

class TwoArmSim:
    def __init__(self, tmp_path: Path, *options: str) -> None:
        self.env = {**os.environ, "XDG_CONFIG_HOME": str(tmp_path / "config")}
        self.child = Child(["sim", "--arms", "2", "--tcp", "0", "--no-tracker", "--speed", "4", *options],
                           env=self.env)
        lines = [self.child.line(30.0) for _ in range(4)]
        said = dict(line.split(" ", 1) for line in lines)
        assert set(said) == {"ASPOD-LINK", "ASPOD-KEY", "ASPOD-LINK2", "ASPOD-CONTROL"}, lines
        self.links = f"{said['ASPOD-LINK']},{said['ASPOD-LINK2']}"
        self.control = Path(said["ASPOD-CONTROL"])

    def plan(self, *options: str):
        return run([*ASPOD, *PLAN, "--execute", self.links, *options], timeout_s=600, env=self.env,
                   peers=(self.child.proc.pid,))

    def state(self) -> dict:
        with ControlClient(self.control) as control:
            return control.request({"op": "state"})["state"]

    def stop(self) -> None:
        self.child.stop(signal.SIGTERM, timeout_s=10)


def _carried(done) -> dict:
    assert done.returncode == 0, done.stderr.decode()[-3000:]
    executed = json.loads(done.stdout)["executed"]
    assert all(outcome == "DONE" for arm in executed["outcomes"] for outcome in arm.values()), executed
    assert len(executed["outcomes"][0]) == len(executed["outcomes"][1]) == 5
    ob = executed["object"]
    assert ob["grasps"] == ["HELD"] and ob["readings"] > 20, ob
    assert ob["path_error_mm"] < 10.0, ob               # the goal: within 1 cm of its path
    assert ob["squeeze_n"] < 57.0, ob                   # within the grip's limit (friction 0.5 x 118 N jaws)
    assert max(executed["tracking_deg"]) < 2.0, executed
    assert executed["plan_s"] <= executed["ended_s"] < executed["plan_s"] + 3.0, executed
    return executed


@pytest.mark.pty
@pytest.mark.long
def test_two_arm_sim_refuses_then_carries_the_object_twice_in_earth_gravity(tmp_path):
    sim = TwoArmSim(tmp_path)
    try:
        link1, link2 = sim.links.split(",")
        # a host on either link finds the key; only the first arm's link has the endpoint, which acts on its plant
        assert simulator_key_file(link1, sim.env) == simulator_key_file(link2, sim.env) is not None
        assert find_control(link1, sim.env) == sim.control and find_control(link2, sim.env) is None
        before = sim.state()
        refused = sim.plan("--gravity")          # the example arm's speed parameters are ASPOD's 3 deg/s
        assert refused.returncode == 2, refused.stderr.decode()
        assert "nothing moved" in refused.stderr.decode() and "j1_speed_dps 3" in refused.stderr.decode()
        assert sim.state()["joints_deg"] == before["joints_deg"]      # nothing moved indeed
        mixed = sim.plan("--set-speeds")         # a plan for orbit on arms in Earth gravity
        assert mixed.returncode == 2 and "gravity_m_s2 is 9.80665, the plan's 0" in mixed.stderr.decode()
        first = _carried(sim.plan("--gravity", "--set-speeds"))
        assert sim.state()["object"]["held"] is False       # the session closed: outputs off, the jaws let go
        again = _carried(sim.plan("--gravity", "--set-speeds"))      # opened again: another object
        assert again["plan_s"] == first["plan_s"]
    finally:
        sim.stop()


@pytest.mark.pty
@pytest.mark.long
def test_two_arm_sim_carries_the_object_in_orbit(tmp_path):
    sim = TwoArmSim(tmp_path, "--gravity", "orbit")
    try:
        done = sim.plan("--set-speeds", "--plot", str(tmp_path / "figures"))
        _carried(done)
        figure = tmp_path / "figures" / "two_arm_carry.png"      # plan against execution, from the endpoint
        assert str(figure) in json.loads(done.stdout)["figures"]
        assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and figure.stat().st_size > 20_000
    finally:
        sim.stop()
