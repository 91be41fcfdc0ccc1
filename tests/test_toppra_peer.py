"""bench.toppra_peer: the checker on profiles worked out by hand, and toppra on one planar 2-link arm.

The arm: unit masses and lengths, uniform rods (centre of mass at 0.5, inertia 1/12 about it), gravity 9.81 in -y,
angles from the x axis (q2 relative to link 1); torque bounds |u1| <= 30, |u2| <= 20 N m. The path, in joint space,
goes from hanging straight down to (60 deg, 90 deg) along a straight line bent by a half sine on joint 2.
"""
from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from bench.toppra_peer import (PeerResult, implied_torques, implied_u, toppra_solve, traversal_time,
                               worst_violation)

needs_toppra = pytest.mark.skipif(importlib.util.find_spec("toppra") is None,
                                  reason="toppra is not installed (the bench extra: pip install toppra)")

GRAVITY = 9.81
LOWER, UPPER = np.array([-30.0, -20.0]), np.array([30.0, 20.0])
Q_START, Q_END = np.array([-np.pi / 2, 0.0]), np.array([np.pi / 3, np.pi / 2])
BEND = np.array([0.0, 1.0])


def arm_inverse_dynamics(q, qd, qdd):
    """Joint torques of the planar 2-link arm of uniform unit rods."""
    m, length, lc, inertia = 1.0, 1.0, 0.5, 1.0 / 12.0
    c2, s2 = np.cos(q[1]), np.sin(q[1])
    m11 = 2 * inertia + m * lc ** 2 + m * (length ** 2 + lc ** 2 + 2 * length * lc * c2)
    m12 = inertia + m * (lc ** 2 + length * lc * c2)
    m22 = inertia + m * lc ** 2
    h = m * length * lc * s2
    g1 = (m * lc + m * length) * GRAVITY * np.cos(q[0]) + m * lc * GRAVITY * np.cos(q[0] + q[1])
    g2 = m * lc * GRAVITY * np.cos(q[0] + q[1])
    return np.array([m11 * qdd[0] + m12 * qdd[1] - h * (2 * qd[0] * qd[1] + qd[1] ** 2) + g1,
                     m12 * qdd[0] + m22 * qdd[1] + h * qd[0] ** 2 + g2])


def bent_path(s, order=0):
    """q(s) = start + (end - start) s + BEND sin(pi s), and its first two derivatives in s."""
    s = np.asarray(s, float)[:, None]
    if order == 0:
        return Q_START + (Q_END - Q_START) * s + BEND * np.sin(np.pi * s)
    if order == 1:
        return (Q_END - Q_START) + BEND * np.pi * np.cos(np.pi * s)
    return -BEND * np.pi ** 2 * np.sin(np.pi * s)


def line_path(s, order=0):
    """One joint, q = s."""
    s = np.asarray(s, float)[:, None]
    return s if order == 0 else (np.ones_like(s) if order == 1 else np.zeros_like(s))


def unit_inertia(q, qd, qdd):
    return np.asarray(qdd, float)


# ---- the checker, without toppra ----------------------------------------------------------------------------------

def test_constant_acceleration_violation_is_the_excess_over_the_bound():
    # x from 0 to 2 over s in [0, 1]: u = 1, torque 1 everywhere against |tau| <= 0.5 (100 % past) or <= 0.8 (25 %)
    grid, x = np.array([0.0, 1.0]), np.array([0.0, 2.0])
    assert implied_u(grid, x) == pytest.approx([1.0])
    assert worst_violation(grid, x, line_path, unit_inertia, [-0.5], [0.5]) == pytest.approx(1.0)
    assert worst_violation(grid, x, line_path, unit_inertia, [-2.0], [0.8]) == pytest.approx(0.25)
    assert worst_violation(grid, x, line_path, unit_inertia, [-2.0], [2.0]) == 0.0


def test_lower_bound_and_the_side_of_each_grid_point():
    # accelerate then brake: u = +1 then -3 over [0, 1] and [1, 4/3]; the braking side of s = 1 breaks the lower bound
    grid, x = np.array([0.0, 1.0, 4.0 / 3.0]), np.array([0.0, 2.0, 0.0])
    assert implied_u(grid, x) == pytest.approx([1.0, -3.0])
    assert worst_violation(grid, x, line_path, unit_inertia, [-2.0], [1.0], per_interval=0) == pytest.approx(0.5)


def test_violation_between_grid_points_is_found():
    # q = sin(pi s) at constant x = 1 (u = 0): tau = q'' x = -pi^2 sin(pi s), 0 at both grid points, -pi^2 midway
    def sine(s, order=0):
        s = np.asarray(s, float)[:, None]
        return [np.sin(np.pi * s), np.pi * np.cos(np.pi * s), -np.pi ** 2 * np.sin(np.pi * s)][order]

    grid, x = np.array([0.0, 1.0]), np.array([1.0, 1.0])
    s, tau = implied_torques(grid, x, sine, unit_inertia, per_interval=1)
    assert s == pytest.approx([0.0, 0.5, 1.0])
    assert tau[:, 0] == pytest.approx([0.0, -np.pi ** 2, 0.0])
    assert worst_violation(grid, x, sine, unit_inertia, [-np.pi ** 2 / 2], [1.0], per_interval=0) == 0.0
    assert worst_violation(grid, x, sine, unit_inertia, [-np.pi ** 2 / 2], [1.0], per_interval=1) == pytest.approx(1.0)


def test_traversal_time_of_constant_acceleration():
    # from rest, u = 1 over s in [0, 2]: s = t^2 / 2, so t = 2; split in two intervals it is the same
    assert traversal_time([0.0, 2.0], [0.0, 4.0]) == pytest.approx(2.0)
    assert traversal_time([0.0, 1.0, 2.0], [0.0, 2.0, 4.0]) == pytest.approx(2.0)
    assert traversal_time([0.0, 1.0, 2.0], [0.0, 0.0, 4.0]) == float("inf")


# ---- toppra on the arm ------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def arm_results() -> dict[tuple[str, int], PeerResult]:
    return {(scheme, n): toppra_solve(bent_path, arm_inverse_dynamics, LOWER, UPPER, n, scheme)
            for scheme in ("collocation", "interpolation") for n in (20, 100)}


def _violation(result: PeerResult, per_interval: int = 20) -> float:
    return worst_violation(result.grid_s, result.x, bent_path, arm_inverse_dynamics, LOWER, UPPER, per_interval)


@needs_toppra
def test_toppra_on_the_arm(arm_results):
    print("\ntoppra", next(iter(arm_results.values())).toppra_version, "on the 2-link arm, rest to rest:")
    for (scheme, n), r in arm_results.items():
        assert r.ok, r.reason
        assert r.x[0] == 0.0 and r.x[-1] == 0.0 and r.grid_s.shape == (n,) and r.u.shape == (n - 1,)
        assert np.all(r.x[1:-1] > 0.0)
        assert r.u == pytest.approx(r.u_solver, abs=1e-5)
        assert 0.0 < r.setup_time_s < r.solve_time_s
        print(f"  {scheme:13s} {n:3d} points: time {r.traversal_time_s:.4f} s, worst violation "
              f"{100 * _violation(r):.2f} %, solve {1e6 * r.solve_time_per_gridpoint_s:.0f} us per grid point")
    times = [r.traversal_time_s for r in arm_results.values()]
    assert max(times) / min(times) < 1.05
    # collocation keeps only the start of each interval inside the bounds, interpolation both ends
    assert _violation(arm_results["collocation", 20]) > _violation(arm_results["collocation", 100]) > 0.01
    for n in (20, 100):
        assert _violation(arm_results["interpolation", n]) < _violation(arm_results["collocation", n])
        assert _violation(arm_results["interpolation", n], per_interval=0) < 1e-6


@needs_toppra
def test_toppra_keeps_the_start_of_each_interval_within_bounds(arm_results):
    """Checks the bounds reached toppra the right way round: under collocation the torque at each interval's start
    (with that interval's u) is what toppra bounded."""
    for n in (20, 100):
        r = arm_results["collocation", n]
        _, tau = implied_torques(r.grid_s, r.x, bent_path, arm_inverse_dynamics, per_interval=0)
        starts = tau[0::2]
        assert np.all(starts <= UPPER + 1e-6) and np.all(starts >= LOWER - 1e-6)
        assert np.max(np.abs(starts) / UPPER) > 0.99          # and it uses them: time-optimal touches a bound


@needs_toppra
def test_toppra_time_agrees_with_its_own_parametrizer(arm_results):
    import toppra
    r = arm_results["interpolation", 100]
    traj = toppra.ParametrizeConstAccel(None, r.grid_s, np.sqrt(r.x))
    assert traj.duration == pytest.approx(r.traversal_time_s, rel=1e-12)


@needs_toppra
def test_infeasible_instance_is_a_result_not_an_exception():
    r = toppra_solve(bent_path, arm_inverse_dynamics, [-1.0, -1.0], [1.0, 1.0], 20)
    assert not r.ok and "controllable" in r.reason and r.toppra_version


@needs_toppra
def test_raising_dynamics_is_a_result_not_an_exception():
    def broken(q, qd, qdd):
        raise RuntimeError("no model")

    r = toppra_solve(bent_path, broken, LOWER, UPPER, 20, "interpolation")
    assert not r.ok and "RuntimeError: no model" in r.reason


def test_caller_mistakes_raise():
    with pytest.raises(ValueError):
        toppra_solve(bent_path, arm_inverse_dynamics, LOWER, UPPER, 20, "spline")
    with pytest.raises(ValueError):
        toppra_solve(bent_path, arm_inverse_dynamics, LOWER[:1], UPPER[:1], 20)
