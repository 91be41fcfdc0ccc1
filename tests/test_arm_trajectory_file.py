"""`aspod plan --arm-to ... --output FILE`: a minimum-time move of ASPOD's own arm as a trajectory file, which
`load_trajectory` (teleop's `traj load`) reads back and the controller runs from the homed pose (issue 36)."""
from __future__ import annotations

import json
import math

import pytest

from host_tools.cli.main import main
from host_tools.client.trajectory import load_trajectory, send_trajectory
from protocol.messages import TRAJECTORY_JOINTS
from protocol.states import MotionOutcome
from tests.test_trajectory import done, holding_deg, homed_bench

TARGET = {"j1": 20.0, "j2": -15.0, "j3": 10.0, "mount": 30.0}


def test_a_planned_file_runs_from_the_homed_pose_to_its_target(tmp_path):
    path = tmp_path / "move.json"
    assert main(["plan", "--arm-to", "j1=20,j2=-15", "--arm-to", "j3=10,mount=30", "--output", str(path)]) == 0
    knots = load_trajectory(path)
    assert len(knots) == 41 and knots[0].t_s == 0.0
    bench = homed_bench()
    assert [round(q, 9) for q in knots[0].q_deg] == [round(q, 9) for q in holding_deg(bench)]
    ids = send_trajectory(bench, knots)
    assert bench.wait_until(lambda: all(done(bench, int(a), i) for a, i in zip(TRAJECTORY_JOINTS, ids)),
                            knots[-1].t_s + 10.0)
    assert all(done(bench, int(a), i).outcome == MotionOutcome.DONE for a, i in zip(TRAJECTORY_JOINTS, ids))
    ended = dict(zip([a.name.lower() for a in TRAJECTORY_JOINTS], holding_deg(bench)))
    assert all(abs(ended[name] - deg) < 0.05 for name, deg in TARGET.items()), ended
    bench.close()


def _file(tmp_path, text: str):
    path = tmp_path / "t.json"
    path.write_text(text)
    return path


def _good(tmp_path) -> dict:
    path = tmp_path / "good.json"
    assert main(["plan", "--arm-to", "j1=5", "--knots", "4", "--output", str(path)]) == 0
    return json.loads(path.read_text())


@pytest.mark.parametrize("change, said", [
    (lambda d: d.update(format="other"), "not a trajectory file"),
    (lambda d: d.update(version=3), "version 3"),
    (lambda d: d.update(version=2), "`arms` must be a list of 2 arms"),
    (lambda d: d["knots"][1].update(t=0.0), "times increase strictly"),
    (lambda d: d["knots"][2]["q"].pop(), "knot 2: a knot has 5 positions"),
    (lambda d: d["knots"][1]["qd"].__setitem__(0, "fast"), "knot 1: its values must be numbers"),
    (lambda d: d["knots"][3].update(t=1e9), "knot 3:"),
    (lambda d: d.update(knots=d["knots"][:1]), "2 to 256 knots"),
])
def test_a_bad_trajectory_file_says_what_is_wrong_and_where(tmp_path, change, said):
    doc = _good(tmp_path)
    change(doc)
    with pytest.raises(ValueError, match=said):
        load_trajectory(_file(tmp_path, json.dumps(doc)))


def test_not_json_and_options_out_of_place_are_refused(tmp_path, capsys):
    with pytest.raises(ValueError, match="not JSON"):
        load_trajectory(_file(tmp_path, "j1 20\n"))
    script = tmp_path / "keep.py"
    script.write_text("print('mine')\n")
    assert main(["plan", "--arm-to", "j1=5", "--output", str(script)]) == 2     # not a trajectory file: kept
    assert script.read_text() == "print('mine')\n"
    assert main(["plan", "--arm-to", "j7=5"]) == 2
    assert main(["plan", "--arm-to", f"j1={math.nan}"]) == 2
    assert main(["plan", "--knots", "5"]) == 2
    assert main(["plan", "--payload-kg", "1"]) == 2
    err = capsys.readouterr().err
    assert "not a joint of the trajectory" in err and "-360..360" in err
    assert "--knots: only with --output (the two arms' trajectory file), --execute or --arm-to" in err
    assert "--payload-kg: only with --arm-to" in err


def test_teleop_traj_words_load_run_and_clear_a_planned_file(tmp_path, capsys):
    """`traj load FILE`, `traj run`, `traj clear` (issue 36), in a script on the simulated clock."""
    move = tmp_path / "m.json"
    assert main(["plan", "--arm-to", "j1=10,j2=-5", "--output", str(move)]) == 0
    knots = load_trajectory(move)
    assert len(knots) > 41          # more than asked: 41 knots' cubics passed j1's speed limit (see knots_within_speed)
    script = tmp_path / "s.txt"
    script.write_text(f"enable\nhome all\nwait all\ntraj load {move}\ntraj run\nwait all\ntraj clear\n")
    capsys.readouterr()
    assert main(["bench", str(script), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    ran = [m for m in doc["motions"] if m["line"] == 5]
    assert len(ran) == 5 and {m["outcome"] for m in ran} == {"DONE"}, ran
    assert doc["ok"]


def test_a_script_with_a_bad_trajectory_file_sends_nothing_and_run_needs_a_load(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text('{"format": "aspod-trajectory", "version": 1}\n')
    script = tmp_path / "s.txt"
    script.write_text(f"enable\ntraj load {bad}\n")
    assert main(["bench", str(script)]) == 2
    err = capsys.readouterr().err
    assert "line 2: traj load:" in err and "joints" in err
    script.write_text("enable\ntraj run\n")
    assert main(["bench", str(script)]) == 1
    assert "no trajectory loaded in this session" in capsys.readouterr().out
    script.write_text("traj fly\n")
    assert main(["bench", str(script)]) == 2
