"""`aspod plan --output FILE` (without --arm-to): the two-arm plan as both example arms' knots in one trajectory file
(version 2), which `load_trajectory(path, arm)` and teleop's `traj load FILE arm N` read one arm of (issue 39)."""
from __future__ import annotations

import dataclasses
import json
import math
import re

import pytest

from bench.bench_two_arms import carry
from firmware_py.arm_config import EXAMPLE_ARM, ArmDescription
from hil_sim.held_object import GraspState
from host_tools.apps.arm_plan import homed_pose_rad
from host_tools.apps.two_arm_plan import arm_knots, controller_knots, executable_plan, start_pose_deg
from host_tools.cli.main import main
from host_tools.client.trajectory import load_trajectory
from host_tools.plan.errors import PlanError
from host_tools.plan.example import report_problem
from host_tools.teleop.words import completions
from protocol.messages import TRAJECTORY_JOINTS
from protocol.states import ControllerState, MotionOutcome

PLAN = ["plan", "--links", "rod", "--gravity", "--objective", "time", "--nodes", "199"]     # the bench's 200 points


@pytest.fixture(scope="module")
def two_arm_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("two") / "two.json"
    assert main([*PLAN, "--output", str(path)]) == 0
    return path


def test_each_arm_of_the_file_is_arm_knots_of_the_executable_plan(two_arm_file):
    """The report's example, in Earth gravity with rod links (the emulated example arms): the minimum-time plan within
    0.8 of its torque limits, run 2x slower, as the bench runs it; each arm's knots as `arm_knots` makes them, j3, j4
    and the mount where `home all` leaves the example arm's."""
    problem = report_problem(gravity=True, links="rod")
    limited, profile = executable_plan(problem, 0.8, 2.0, 200)
    held = [math.degrees(q) for q in homed_pose_rad(EXAMPLE_ARM).values()]
    doc = json.loads(two_arm_file.read_text())
    assert doc["version"] == 2 and "two example arms" in doc["about"]["arms"]
    assert doc["about"]["duration_s"] == round(profile.duration, 6) == pytest.approx(1.060, abs=1e-3)   # the bench's
    for arm, start in zip((1, 2), start_pose_deg(problem)):
        knots = load_trajectory(two_arm_file, arm)
        assert len(knots) == 60
        assert knots == arm_knots(limited, profile, len(knots), arm - 1, held)
        assert knots[0].q_deg[:2] == pytest.approx(start, abs=1e-9)
        assert all(abs(v) <= 360.0 for k in knots for v in k.qd_deg_s)


def test_the_file_carries_the_object_on_two_example_arms(two_arm_file):
    """bench/bench_two_arms.py's `carry` (the lock-step bench, two example arms, the object between them) with each
    arm's knots from the file, started on one tick: the bench's goals hold. Measured: the bench's own figures (its
    knots are the file's), the object within 6.79 mm of its path, the squeeze at most 2.8 N."""
    got = carry("earth", two_arm_file)
    assert got["plan_s"] == pytest.approx(json.loads(two_arm_file.read_text())["about"]["duration_s"], abs=1e-6)
    assert got["path_m"] < 0.01 and got["squeeze_n"] < 0.2 * got["limit_n"], got
    assert got["states"] == {(GraspState.HELD, GraspState.HELD)}, got
    assert got["controllers"] == (ControllerState.ENABLED, ControllerState.ENABLED), got
    assert got["ends"] == 2 * len(TRAJECTORY_JOINTS) and got["outcomes"] == {MotionOutcome.DONE}, got


def test_a_plan_past_a_limit_is_refused_naming_it_and_nothing_is_written(tmp_path, capsys):
    """At the full torque limits and the plan's own pace, arm 2's shoulder would pass the TrajPoint's 360 deg/s: refused,
    and the file already there (a one-arm file of --arm-to) is left as it was."""
    path = tmp_path / "kept.json"
    assert main(["plan", "--arm-to", "j1=5", "--knots", "4", "--output", str(path)]) == 0
    before = path.read_bytes()
    capsys.readouterr()
    assert main([*PLAN, "--torque-share", "1", "--slower", "1", "--output", str(path)]) == 2
    captured = capsys.readouterr()
    assert "arm 2 (example arm) j1 reaches 371." in captured.err and "above 360 deg/s (the TrajPoint's" in captured.err
    assert captured.out == "" and path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["kept.json"]       # no temporary left either


def test_a_plan_past_a_soft_limit_is_refused_naming_the_joint_and_its_parameter():
    """An example arm whose elbow stops at 140 deg: arm 2's elbow ends at 149.36 deg."""
    elbow = dataclasses.replace(EXAMPLE_ARM.drive("j2"), soft_max_deg=140.0)
    narrow = ArmDescription("narrow", (EXAMPLE_ARM.drives[0], elbow, *EXAMPLE_ARM.drives[2:]), EXAMPLE_ARM.masses,
                            EXAMPLE_ARM.gripper)
    limited, profile = executable_plan(report_problem(gravity=True, links="rod"), 0.8, 2.0, 200)
    with pytest.raises(PlanError, match=r"arm 1 \(narrow arm\) j2 reaches 141.88 deg, above its soft limit 140 deg "
                                        r"\(j2_max_deg\)"):
        controller_knots(limited, profile, 41, narrow)


def test_options_out_of_place_and_an_output_over_an_input_are_refused(tmp_path, capsys):
    problem = tmp_path / "problem.json"
    problem.write_text("{}")
    mine = problem.read_text()
    assert main(["plan", "--problem", str(problem), "--output", str(problem)]) == 2
    assert main(["plan", "--slower", "3"]) == 2
    assert main(["plan", "--arm-to", "j1=5", "--torque-share", "0.5"]) == 2
    with pytest.raises(SystemExit) as refused:
        main(["plan", "--torque-share", "1.5", "--output", str(tmp_path / "a.json")])
    assert refused.value.code == 2
    err = capsys.readouterr().err
    assert "the problem file (--problem), an input of this run" in err and problem.read_text() == mine
    assert "--slower: only with --output" in err and "--arm-to plans ASPOD's own arm" in err
    assert "--torque-share: 1.5 is outside 0.05..1.0" in err
    assert not (tmp_path / "a.json").exists()


def _edited(tmp_path, source, change) -> str:
    doc = json.loads(source.read_text())
    change(doc)
    path = tmp_path / "edited.json"
    path.write_text(json.dumps(doc))
    return str(path)


@pytest.mark.parametrize("arm, change, said", [
    (None, None, "a two-arm trajectory file: say which arm's knots (arm 1 or arm 2)"),
    (3, None, "a two-arm trajectory file has arms 1 and 2, not arm 3"),
    (0, None, "has arms 1 and 2, not arm 0"),
    (1, lambda d: d["arms"].pop(), "`arms` must be a list of 2 arms"),
    (1, lambda d: d["arms"][1].update(extra=1), "`arms` must be a list of 2 arms"),
    (1, lambda d: d["arms"][1]["knots"][3]["q"].pop(), "arm 2: knot 3: a knot has 5 positions"),
    (2, lambda d: d["arms"][0]["knots"][1].update(t=0.0), "arm 1: a trajectory's knots start at t = 0 s"),
    (1, lambda d: d.update(knots=d.pop("arms")[0]["knots"]), "`arms` must be a list"),
])
def test_a_bad_two_arm_file_or_arm_number_says_what_is_wrong(tmp_path, two_arm_file, arm, change, said):
    path = two_arm_file if change is None else _edited(tmp_path, two_arm_file, change)
    with pytest.raises(ValueError, match=re.escape(said)):
        load_trajectory(path, arm)


def test_a_one_arm_file_is_arm_1_and_has_no_arm_2(tmp_path):
    path = tmp_path / "one.json"
    assert main(["plan", "--arm-to", "j1=5", "--knots", "4", "--output", str(path)]) == 0
    assert load_trajectory(path, 1) == load_trajectory(path)
    with pytest.raises(ValueError, match=r"a one-arm trajectory file \(aspod plan --arm-to\): it has no arm 2"):
        load_trajectory(path, 2)


def test_teleop_words_name_the_arm_and_refuse_a_two_arm_file_without_one(tmp_path, two_arm_file, capsys):
    assert completions("traj load two.json a", 18, "a") == ["arm"]
    assert completions("traj load two.json arm ", 23, "") == ["1", "2"]
    assert completions("traj run ", 9, "") == []
    script = tmp_path / "s.txt"
    for line, said in ((f"traj load {two_arm_file}", "say which arm's knots (arm 1 or arm 2)"),
                       (f"traj load {two_arm_file} arm 3", "traj load FILE arm 1 | traj load FILE arm 2, not `arm 3`"),
                       (f"traj load {two_arm_file} side 1", "not `side 1`"),
                       (f"traj load {two_arm_file} arm", "traj load FILE [arm 1|2] | traj run | traj clear")):
        script.write_text(f"enable\n{line}\n")
        assert main(["bench", str(script)]) == 2, line
        err = capsys.readouterr().err
        assert "line 2:" in err and said in err, (line, err)


def test_arm_2_of_the_file_loaded_into_aspods_arm_is_refused_by_its_controller_and_nothing_moves(tmp_path,
                                                                                                  two_arm_file,
                                                                                                  capsys):
    """teleop's script mode on the lock-step simulator, whose arm is ASPOD's: the knots upload (each within the
    TrajPoint's ranges), and TrajRun is refused with the controller's reason: the joints do not stand where the knots
    start (homed at -1.146 deg; arm 2's shoulder starts at 112.45 deg, past ASPOD's j1 soft limit, 85). Nothing
    moves."""
    script = tmp_path / "s.txt"
    script.write_text(f"enable\nhome all\nwait all\ntraj load {two_arm_file} arm 2\ntraj run\nwait all\n")
    capsys.readouterr()
    assert main(["bench", str(script), "--json"]) == 1
    doc = json.loads(capsys.readouterr().out)
    steps = {step["line"]: step for step in doc["steps"]}
    assert steps[4]["ok"] and "knots loaded" in steps[4]["output"][-1]
    assert not steps[5]["ok"] and "TRAJ_ENDPOINTS" in steps[5]["output"][1]
    assert {m["line"] for m in doc["motions"]} == {2}                   # the homing's, and nothing of line 5
    assert all(abs(deg - -1.146) < 0.01 for deg in doc["plant"]["joints_deg"].values()), doc["plant"]["joints_deg"]
