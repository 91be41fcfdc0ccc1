"""The report's two arms carry one object, planned and executed (issue 39): bench/bench_two_arms.py's `carry`, along
the report's example and two of the bench's other paths, in Earth gravity and in orbit, held to the issue's goals;
the energy the plant measured against the electrical objective's prediction; and the figure of a carry
(host_tools/apps/two_arm_figure.py)."""
from __future__ import annotations

import sys

import numpy as np
import pytest

from bench.bench_two_arms import PATHS, TICK_S, carry
from hil_sim.arm_params import EXAMPLE_ARM_PLANT, J1, J2
from hil_sim.held_object import GraspState
from host_tools.apps.two_arm_figure import CarryTrace, carry_trace, write_carry_figure
from host_tools.apps.two_arm_plan import executable_plan, start_pose_deg
from host_tools.plan.example import report_problem
from host_tools.outputs import PNG, Claims
from host_tools.plan.motors import example_arm_drives
from kernels.extras import MissingExtra
from protocol.messages import TRAJECTORY_JOINTS
from protocol.states import ControllerState, MotionOutcome

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _held_to_the_goals(got: dict) -> None:
    """What every carry must do: the object within 1 cm of its path and the squeeze far inside the grip's limit
    (the plan's: 0 N), both grasps holding all the way, both controllers enabled, every joint DONE; each arm within
    2 degrees of its plan, every joint settled within 2 s of the plan's end; the trace what was measured."""
    assert got["path_m"] < 0.01, got
    assert got["squeeze_n"] < 0.2 * got["limit_n"], got
    assert got["states"] == {(GraspState.HELD, GraspState.HELD)}, got
    assert got["controllers"] == (ControllerState.ENABLED, ControllerState.ENABLED), got
    assert got["ends"] == 2 * len(TRAJECTORY_JOINTS) and got["outcomes"] == {MotionOutcome.DONE}, got
    assert max(got["tracking_deg"]) < 2.0, got
    assert got["plan_s"] < got["settled_s"] < got["plan_s"] + 2.0, got
    trace = got["trace"]
    assert trace.times_s[0] == pytest.approx(TICK_S) and trace.times_s[-1] == pytest.approx(got["plan_s"] + 0.5,
                                                                                              abs=TICK_S)
    assert trace.path_error_m.max() == got["path_m"] and np.abs(trace.squeeze_n).max() == got["squeeze_n"]


def _ratios(got: dict) -> dict:
    measured, predicted = got["energy"]["measured"], got["energy"]["predicted"]
    return {key: measured[key] / predicted[key] for key in ("drawn", "regen", "copper", "drives")}


@pytest.mark.parametrize("gravity", ["earth", "orbit"])
def test_two_arms_carry_the_object_along_the_reports_example_within_a_centimetre(gravity):
    """Measured (seed 5): Earth, a 1.06 s plan: the object within 6.8 mm of its path, the squeeze at most 2.8 N;
    orbit, 0.90 s: 5.3 mm, 4.3 N; the grip holds to 57 N (Earth) and 58 N (orbit).

    The energy the shoulders' and elbows' motors drew over the plan's time, measured by the plant (duty x supply x
    current, every tick), against the electrical objective's prediction for the plan with the example arm's motors:
    Earth 75.8 J against 67.2 (1.13) without regeneration, 70.0 against 62.4 (1.12) with it, the copper 64.2
    against 60.3; orbit 22.5 against 11.9 (1.89), 17.4 against 7.6 (2.30), the copper 13.8 against 7.6. In orbit
    the planned torques are all dynamic, and what the planner leaves out weighs most: the drives' rotors and
    friction, the plant's diagonal model's other torques, the loops' own (docs/planning.md). The drives' own draw
    is the prediction's within the supply's sag (43.6 J against 44.5)."""
    got = carry(gravity)
    _held_to_the_goals(got)
    ratios = _ratios(got)
    low, high = (1.0, 1.25) if gravity == "earth" else (1.5, 2.5)
    assert low < ratios["drawn"] < high and low < ratios["regen"] < high, (ratios, got["energy"])
    assert 1.0 < ratios["copper"] < (1.15 if gravity == "earth" else 2.0), (ratios, got["energy"])
    assert 0.95 < ratios["drives"] < 1.0, (ratios, got["energy"])        # the supply sags under load below 28 V
    measured = got["energy"]["measured"]
    assert measured["copper"] < measured["regen"] < measured["drawn"]      # they do work, and some comes back


@pytest.mark.parametrize("gravity, name", [("earth", "diagonal"), ("orbit", "reversed")])
def test_two_arms_carry_the_object_along_other_paths(gravity, name):
    """Two of the bench's three other paths: the diagonal down and away from arm 1 in Earth gravity (the object's
    potential energy falls: the plan's work is -11.3 J), the example backwards in orbit (the bench's largest path
    error). Measured (seed 5): diagonal, Earth: 2.5 mm, 0.9 N, 33.0 J against 31.6 (1.04) without regeneration,
    31.0 against 30.2 (1.03) with it; reversed, orbit: 7.6 mm, 3.0 N, 19.9 J against 11.6 (1.72), 15.3 against
    7.6 (2.03)."""
    got = carry(gravity, path=dict(PATHS)[name])
    _held_to_the_goals(got)
    ratios = _ratios(got)
    low, high = (1.0, 1.2) if gravity == "earth" else (1.4, 2.3)
    assert low < ratios["drawn"] < high and low < ratios["regen"] < high, (ratios, got["energy"])
    if gravity == "earth":          # downhill: the copper loss is more than all they draw, some work comes back
        assert got["energy"]["predicted"]["work"] < -10.0 and got["energy"]["measured"]["regen"] < \
            got["energy"]["measured"]["copper"], got["energy"]


def test_the_objectives_prediction_takes_the_plants_motors():
    """The prediction prices the copper loss with the plant's own example arm drives: c = R / kt_out^2 at each
    shoulder and elbow, the loss R i^2 of the current i = u / kt_out the plant's motor needs for a torque u."""
    drives = [EXAMPLE_ARM_PLANT.channels[j].drive for j in (J1, J2)] * 2
    expected = [d.motor.r_ohm / d.kt_out_nm_a ** 2 for d in drives]
    assert example_arm_drives().copper() == pytest.approx(expected, rel=1e-12)


def test_a_carrys_trace_sets_the_plan_beside_what_was_measured():
    """`carry_trace` takes the plan's object and joints at the measured times: from the path's start, along it, to
    its end, where it stands after the plan's end, the joints the arms' start pose first; a carry 5 mm above its
    plan is 5 mm off it, one with a joint 1 degree behind is that much off."""
    problem, plan = executable_plan(report_problem(gravity=True, links="rod", path=dict(PATHS)["lift"]), 0.8, 2.0, 50)
    times = np.linspace(0.0, plan.duration + 0.5, 300)[1:]
    first = carry_trace(problem, plan, times, np.zeros((299, 2)), np.zeros(299), np.zeros((299, 4)))
    planned = first.object_planned_m
    assert planned[:, 0] == pytest.approx(np.full(299, 1.0)) and np.all(np.diff(planned[:, 1]) >= 0)
    assert planned[0] == pytest.approx([1.0, 0.3], abs=1e-4) and planned[-1] == pytest.approx([1.0, 0.9])
    assert np.degrees(first.joints_planned_rad[0]) == pytest.approx(np.ravel(start_pose_deg(problem)), abs=0.05)
    behind = first.joints_planned_rad - np.radians([1.0, 0.0, 0.0, 0.0])
    off = carry_trace(problem, plan, times, planned + [0.0, 0.005], np.zeros(299), behind)
    assert off.path_error_m == pytest.approx(np.full(299, 0.005), abs=1e-12)
    assert np.degrees(off.tracking_error_rad) == pytest.approx(np.tile([-1.0, 0.0, 0.0, 0.0], (299, 1)), abs=1e-9)
    assert off.plan_s == plan.duration


def _trace(n: int = 400) -> CarryTrace:
    """A carry's trace made up: a 1 s plan, the execution lagging it by 5 ms."""
    t = np.arange(1, n + 1) * 0.004
    s = np.clip(t, 0.0, 1.0)
    lag = np.clip(t - 0.005, 0.0, 1.0)
    line = np.array([[0.688, 0.331]]) + np.outer(s, [1.028, 0.173])
    done = np.array([[0.688, 0.331]]) + np.outer(lag, [1.028, 0.173])
    joints = np.radians(np.outer(s, [25.0, -75.0, -80.0, 45.0]) + [-40.5, 141.9, 112.5, 103.9])
    late = np.radians(np.outer(lag, [25.0, -75.0, -80.0, 45.0]) + [-40.5, 141.9, 112.5, 103.9])
    return CarryTrace(t, done, line, np.sin(7 * t), late, joints, 1.0)


def test_a_carrys_figure_is_a_png_of_plan_against_execution_written_whole(tmp_path):
    """A real PNG (matplotlib reads it back), of a size for the docs; written over an earlier figure, and nothing
    left beside it."""
    import matplotlib.image
    path = tmp_path / "carry.png"
    write_carry_figure(_trace(), path, "made up")
    first = path.read_bytes()
    assert first.startswith(PNG_SIGNATURE) and 0 < len(first) < 150_000
    height, width, _ = matplotlib.image.imread(path).shape
    assert (width, height) == (800, 680)
    write_carry_figure(_trace(200), path)
    assert path.read_bytes() != first and path.read_bytes().startswith(PNG_SIGNATURE)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["carry.png"]


def test_a_carrys_figure_is_refused_over_an_input_or_without_matplotlib_and_a_bad_trace_with_its_reason(
        tmp_path, monkeypatch):
    """Claimed as a command claims its `--plot` (host_tools/outputs.py): refused on an input of the run, by any
    name, and on a file that is not a PNG; without matplotlib, MissingExtra and the file as it was; a trace that is
    not one, ValueError saying what."""
    problem = tmp_path / "problem.json"
    problem.write_text('{"path": {}}')
    claims = Claims([("the problem file (--problem)", problem)])
    with pytest.raises(ValueError, match="that is the problem file .*an input of this run"):
        claims.file(tmp_path / "." / "problem.json", "--plot", PNG)
    notes = tmp_path / "notes.png"
    notes.write_text("my notes")
    with pytest.raises(ValueError, match="an existing file that is not a PNG image"):
        claims.file(notes, "--plot", PNG)
    output = claims.file(tmp_path / "carry.png", "--plot", PNG)
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    with pytest.raises(MissingExtra, match=r"needs the plot extra \(matplotlib is not installed\)"):
        write_carry_figure(_trace(), output)
    monkeypatch.undo()
    assert problem.read_text() == '{"path": {}}' and notes.read_text() == "my notes"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.png", "problem.json"]
    good = _trace()
    for change, reason in (({"squeeze_n": np.full(400, np.nan)}, "squeeze_n is not finite"),
                           ({"object_m": good.object_m[:-1]}, "object_m has 399 samples, times_s 400"),
                           ({"joints_rad": good.joints_rad[:, :2]}, r"joints_rad must be of shape \(n, 4\)"),
                           ({"times_s": good.times_s[::-1]}, "times_s must increase"),
                           ({"plan_s": 0.0}, "plan_s must be a positive number")):
        fields = {**good.__dict__, **change}
        with pytest.raises(ValueError, match=reason):
            CarryTrace(**fields)
    write_carry_figure(good, output)
    assert (tmp_path / "carry.png").read_bytes().startswith(PNG_SIGNATURE)
