"""The object two hands carry (`hil_sim/held_object.py`): its statics, its dynamics at the plant's 1 ms step,
slip and drop, and bad input. Each test checks a physical law or figure, not a code path."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from hil_sim.held_object import GraspRefused, HeldObject, ObjectParams
from protocol.states import GraspState

DT = 0.001                                      # the plant's step
P = ObjectParams()                              # the report's example object, the grasps chosen here
M, G = P.mass_kg, P.gravity_m_s2
K = P.stiffness_n_m[0]
HANDS = ((0.5, 0.3), (0.75, 0.3))               # 0.25 m apart, level: the grasps' distance
STILL = ((0.0, 0.0), (0.0, 0.0))
JAWS = (118.0, 118.0)                           # the plant's jaws at hold duty 0.3 (docs/second_arm_sources.md)
LIMIT = P.friction * JAWS[0]                    # 59 N


def held(params: ObjectParams = P, hands=HANDS) -> HeldObject:
    obj = HeldObject(params)
    obj.grasp(hands)
    return obj


def run(obj: HeldObject, seconds: float, hands=HANDS, velocities=STILL, jaws=JAWS) -> None:
    for _ in range(round(seconds / DT)):
        obj.step(DT, hands, velocities, jaws)


def apart(d: float, hands=HANDS):
    """Each hand moved d outwards along the grasp line (the hands 2 d further apart)."""
    (x0, z0), (x1, z1) = hands
    return ((x0 - d, z0), (x1 + d, z1))


def energy(obj: HeldObject, hands) -> float:
    """Kinetic, spring and gravitational energy (J), from the object's public state."""
    p = obj.params
    vx, vz, w = obj.velocity
    springs = sum(0.5 * k * (h[a] - g[a]) ** 2
                  for h, g in zip(hands, obj.grasp_points_m) for a, k in enumerate(p.stiffness_n_m))
    return 0.5 * p.mass_kg * (vx * vx + vz * vz) + 0.5 * p.inertia_kg_m2 * w * w + springs + \
        p.mass_kg * p.gravity_m_s2 * obj.pose[1]


def test_the_stiffest_mode_is_well_inside_the_steps_stable_range():
    """The object turning on its grasps is the fastest mode: omega^2 = 2 k r^2 / I (r = 0.125 m), a 19.5 ms
    period. Velocity Verlet is stable while omega dt < 2, i.e. the period above pi dt: 6.2 times inside."""
    r = P.grasps_m[1][0]
    assert P.inertia_kg_m2 == pytest.approx(M * (0.25 ** 2 + 0.1 ** 2) / 12)       # a uniform block
    turning = 2 * math.pi / math.sqrt(2 * K * r * r / P.inertia_kg_m2)
    assert P.stiffest_period_s() == pytest.approx(turning, rel=1e-9)
    assert P.stiffest_period_s() == pytest.approx(0.0195, abs=0.0001)
    assert P.stiffest_period_s() / (math.pi * DT) > 6.0
    assert P.damping_ratio(0) == pytest.approx(0.70) and P.damping_ratio(1) == pytest.approx(0.70)


def test_at_rest_in_earth_gravity_each_hand_carries_half_the_weight():
    """Symmetric grasps share the weight: each hand carries m g / 2 down, nothing squeezes. Placed at rest with
    its springs slack, the object sags by m g / 2k and settles within 0.1 s (damping ratio 0.7 at 32 Hz)."""
    obj = held()
    z0 = obj.pose[1]
    run(obj, 0.1)
    for fx, fz in obj.hand_forces:
        assert fx == pytest.approx(0.0, abs=1e-12)
        assert fz == pytest.approx(-M * G / 2, rel=1e-3)
    assert obj.squeeze_n == pytest.approx(0.0, abs=1e-12)
    assert z0 - obj.pose[1] == pytest.approx(M * G / (2 * K), rel=1e-3)              # 0.245 mm
    assert obj.pose[2] == pytest.approx(0.0, abs=1e-12)
    assert obj.carried_n == pytest.approx((M * G / 2, M * G / 2), rel=1e-3)
    assert obj.states == (GraspState.HELD, GraspState.HELD)


def test_hands_pulled_apart_by_d_hold_a_tension_of_k_d():
    """Each hand d = 4 mm further out stretches each grasp spring by d: the internal force is k d = 20 N of
    tension (a negative squeeze), whatever gravity does across the line."""
    d = 0.004
    obj = held()
    run(obj, 0.3, hands=apart(d))
    assert obj.squeeze_n == pytest.approx(-K * d, rel=1e-6)
    assert obj.hand_forces[0][0] == pytest.approx(K * d, rel=1e-6)        # the object pulls hand 0 inwards (+x)
    assert obj.hand_forces[1][0] == pytest.approx(-K * d, rel=1e-6)
    assert obj.states == (GraspState.HELD, GraspState.HELD)


def test_undamped_the_energy_is_conserved_over_10_s():
    """Without damping, kicked into every mode (the hands jump a few mm each and stay), the energy stays within
    velocity Verlet's bound, (omega dt)^2 / 4 of the fastest mode (2.6 %), for 10 s at 1 ms steps and does not
    drift: stable, symplectic. In orbit, so that all
    of the energy is the oscillation's (gravity's constant force the step integrates exactly)."""
    obj = held(dataclasses.replace(P, damping_n_s_m=(0.0, 0.0), gravity_m_s2=0.0))
    kicked = ((0.503, 0.304), (0.748, 0.295))
    obj.step(DT, kicked, STILL, JAWS)
    energies = []
    for _ in range(10_000):
        obj.step(DT, kicked, STILL, JAWS)
        energies.append(energy(obj, kicked))
    e = np.array(energies)
    swing = e.max() - e.min()
    assert e[0] > 0.05                                            # J: the kick's 3 to 5 mm a grasp
    bound = (2 * math.pi * DT / P.stiffest_period_s()) ** 2 / 4     # Verlet's, for the fastest mode: 2.6 %
    assert abs(e / e[0] - 1).max() < bound, f"energy off by {abs(e / e[0] - 1).max():.2%}"
    assert abs(e[-1000:].mean() - e[:1000].mean()) < 0.05 * swing  # no drift from the first second to the last
    assert obj.states == (GraspState.HELD, GraspState.HELD)


def test_in_orbit_at_rest_nothing_moves():
    obj = held(dataclasses.replace(P, gravity_m_s2=0.0))
    pose = obj.pose
    run(obj, 10.0)
    assert obj.pose == pose
    assert obj.velocity == (0.0, 0.0, 0.0)
    assert obj.carried_n == (0.0, 0.0) and obj.squeeze_n == 0.0


def test_a_squeeze_past_friction_times_the_jaws_slips_and_the_force_stays_at_the_limit():
    """The hands close 2 cm each over 1 s: 200 N of squeeze if the grasps held. Past friction x jaws (0.5 x
    118 N = 59 N) both slip, the grasp points sliding inwards; the squeeze stays at the limit. Once the hands
    stop the grasps hold where the slip left them, the spring's share of the limit (the damper's 0.7 N gone)."""
    obj = held()
    start = obj.grasp_points_m
    peak = 0.0
    for k in range(1, 1001):
        obj.step(DT, apart(-0.02 * k / 1000), ((0.02, 0.0), (-0.02, 0.0)), JAWS)
        peak = max(peak, obj.squeeze_n)
        assert max(obj.carried_n) <= LIMIT * (1 + 1e-9)
    assert peak == pytest.approx(LIMIT, rel=1e-3)
    assert obj.states == (GraspState.SLIPPING, GraspState.SLIPPING)
    event = obj.last_event
    assert event.state is GraspState.SLIPPING and event.limit_n == pytest.approx(LIMIT)
    assert event.force_n > LIMIT and "slips" in event.reason
    run(obj, 0.2, hands=apart(-0.02))
    assert obj.states == (GraspState.HELD, GraspState.HELD)
    damper = P.damping_n_s_m[0] * 0.02                              # its share of the force while it slid
    assert all(LIMIT - damper * 1.01 < f <= LIMIT for f in obj.carried_n)
    slid = obj.grasp_points_m[0][0] - start[0][0]
    assert slid == pytest.approx(0.02 - obj.squeeze_n / K, abs=1e-6)  # 2 cm less the spring's stretch (11.7 mm)
    assert obj.grasp_points_m[1][0] - start[1][0] == pytest.approx(-slid, abs=1e-9)


def test_pulled_at_its_ends_the_object_slides_out_of_the_jaws():
    """The example's grasps are at the object's very ends: a tension past the limit slides the grasp points
    outwards, off the object, and both grasps let go."""
    obj = held()
    for k in range(1, 1001):
        obj.step(DT, apart(0.02 * k / 1000), ((-0.02, 0.0), (0.02, 0.0)), JAWS)
        if GraspState.DROPPED in obj.states:
            break
    assert obj.states == (GraspState.DROPPED, GraspState.DROPPED)
    assert "slid off" in obj.last_event.reason
    assert obj.last_event.force_n == pytest.approx(LIMIT, rel=0.05)


def test_hands_closing_through_each_other_slide_the_grasps_along_without_a_fault():
    """The hands close 15 cm each, past each other: the grasp points slide together, meet and part; every
    reading stays finite, and no grasp carries more than its limit."""
    obj = held()
    for k in range(1, 1501):
        obj.step(DT, apart(-0.15 * k / 1500), ((0.1, 0.0), (-0.1, 0.0)), JAWS)
        assert max(obj.carried_n) <= LIMIT * (1 + 1e-9)
        assert all(math.isfinite(v) for v in (*obj.pose, *obj.velocity, obj.squeeze_n))
    assert (obj.grasp_points_m[0][0] - obj.grasp_points_m[1][0]) > 0          # they have crossed


def test_past_twice_the_limit_at_once_the_grasps_let_go():
    """The hands close 1.5 cm each at once: 75 N a grasp, within twice 59 N, a slip; 2.5 cm, 125 N: a drop."""
    obj = held()
    obj.step(DT, apart(-0.015), STILL, JAWS)
    assert obj.states == (GraspState.SLIPPING, GraspState.SLIPPING)
    obj = held()
    obj.step(DT, apart(-0.025), STILL, JAWS)
    assert obj.states == (GraspState.DROPPED, GraspState.DROPPED)
    assert obj.last_event.force_n > 2 * LIMIT and "twice" in obj.last_event.reason
    assert obj.hand_forces == ((0.0, 0.0), (0.0, 0.0)) and obj.squeeze_n == 0.0


@pytest.mark.parametrize("gravity", [G, 0.0], ids=["earth", "orbit"])
def test_jaws_opened_the_object_drops_and_is_a_free_body(gravity):
    """Carried along at 0.5 m/s, then the jaws open: both grasps let go and the object falls at g (in orbit it
    drifts on at its speed)."""
    obj = held(dataclasses.replace(P, gravity_m_s2=gravity))
    speed = (0.5, 0.0)
    hands = HANDS
    for _ in range(300):
        hands = tuple((x + speed[0] * DT, z) for x, z in hands)
        obj.step(DT, hands, (speed, speed), JAWS)
    obj.step(DT, hands, (speed, speed), (0.0, 0.0))
    assert obj.states == (GraspState.DROPPED, GraspState.DROPPED)
    assert "jaws are open" in obj.last_event.reason and obj.last_event.grasp == 1
    (x0, z0, _), (vx0, vz0, _) = obj.pose, obj.velocity
    run(obj, 0.3, hands=hands, velocities=(speed, speed), jaws=(0.0, 0.0))
    t = 0.3
    assert obj.velocity[1] - vz0 == pytest.approx(-gravity * t, abs=1e-9)
    assert obj.pose[1] - z0 == pytest.approx(vz0 * t - gravity * t * t / 2, abs=1e-9)
    assert obj.pose[0] - x0 == pytest.approx(vx0 * t, abs=1e-12)
    assert vx0 == pytest.approx(0.5, abs=1e-3)
    assert obj.hand_forces == ((0.0, 0.0), (0.0, 0.0))


def example_run(gravity: bool):
    """The report's example path, the hands carrying the object along the planner's minimum-time profile."""
    from host_tools.plan.example import PATH, report_problem
    from host_tools.plan.reach import plan_reach
    profile = plan_reach(report_problem(gravity=gravity), 100).profile
    (x0, z0), (x1, z1) = PATH
    dx, dz = x1 - x0, z1 - z0
    grasps = P.grasps_m
    obj = held(dataclasses.replace(P, gravity_m_s2=G if gravity else 0.0),
               hands=tuple((x0 + gx, z0 + gz) for gx, gz in grasps))
    worst, squeeze, carried, time = 0.0, 0.0, 0.0, 0.0
    end = profile.duration + 0.2                    # and at rest after it
    for k in range(1, round(end / DT) + 1):
        time = k * DT
        i = min(np.searchsorted(profile.t, time) - 1, len(profile.sdd) - 1)
        if time >= profile.duration:
            s, sd = 1.0, 0.0
        else:
            tau = time - profile.t[i]
            s, sd = profile.s[i] + profile.sd[i] * tau + profile.sdd[i] * tau * tau / 2, \
                profile.sd[i] + profile.sdd[i] * tau
        cx, cz = x0 + dx * s, z0 + dz * s
        obj.step(DT, tuple((cx + gx, cz + gz) for gx, gz in grasps), ((dx * sd, dz * sd),) * 2, JAWS)
        worst = max(worst, math.hypot(obj.pose[0] - cx, obj.pose[1] - cz))
        squeeze, carried = max(squeeze, abs(obj.squeeze_n)), max(carried, *obj.carried_n)
        assert obj.states == (GraspState.HELD, GraspState.HELD)
    return profile, worst, squeeze, carried


@pytest.mark.parametrize("gravity", [True, False], ids=["earth", "orbit"])
def test_the_object_follows_two_hands_along_the_reports_example(gravity):
    """Along the example's line (1.04 m) at the planner's minimum time (0.58 s in Earth gravity, 0.50 s in
    orbit: peak 3.6 and 4.1 m/s, 17 and 22 m/s^2), faster than the ~0.7 s the issue names, the object stays
    within 1 mm of the path, ten times inside the 1 cm goal: its mass over the two grasps' stiffness lags it
    m a / 2k (0.5 mm at 22 m/s^2), its weight sags it m g / 2k (0.25 mm). The grasps hold, the squeeze stays
    near 0 (the hands keep their distance), and no grasp comes near its 59 N."""
    profile, worst, squeeze, carried = example_run(gravity)
    assert profile.duration < 0.7
    assert worst < 0.001, f"the object strayed {worst * 1000:.2f} mm from the path"
    assert squeeze < 0.01
    assert carried < 0.2 * LIMIT


def test_damping_does_not_narrow_the_stable_step():
    """The dampers are implicit: a grasp damped 100 times over (ratio 70) still settles, no oscillation grows."""
    obj = held(dataclasses.replace(P, damping_n_s_m=(3500.0, 3500.0)))
    run(obj, 0.01, hands=apart(0.003))
    run(obj, 2.0, hands=apart(0.003))
    assert obj.squeeze_n == pytest.approx(-K * 0.003, rel=1e-3)
    assert all(math.isfinite(v) for v in (*obj.pose, *obj.velocity))


def test_grasp_refuses_hands_the_wrong_distance_apart():
    obj = HeldObject(P)
    with pytest.raises(GraspRefused, match=r"0\.2700 m apart and the grasps 0\.2500 m"):
        obj.grasp(apart(0.01))
    assert obj.states == (GraspState.FREE, GraspState.FREE) and obj.event_count == 0
    obj.grasp(apart(0.002))                 # within the 5 mm tolerance: the springs share the 4 mm
    run(obj, 0.2, hands=apart(0.002))
    assert obj.squeeze_n == pytest.approx(-K * 0.002, rel=1e-3)


def test_a_grasp_follows_the_hands_line_at_any_angle():
    """Hands on a line at 30 degrees: the object is placed turned 30 degrees, its centre between them."""
    a = math.radians(30)
    hands = ((1.0, 0.0), (1.0 + 0.25 * math.cos(a), 0.25 * math.sin(a)))
    obj = held(dataclasses.replace(P, gravity_m_s2=0.0), hands=hands)
    x, z, th = obj.pose
    assert th == pytest.approx(a) and (x, z) == pytest.approx((1.0 + 0.125 * math.cos(a), 0.125 * math.sin(a)))
    assert np.allclose(obj.grasp_points_m, hands, rtol=0, atol=1e-12)


@pytest.mark.parametrize("call, message", [
    (lambda o: o.step(DT, ((math.nan, 0.3), (0.75, 0.3)), STILL, JAWS), "hands must be finite"),
    (lambda o: o.step(DT, HANDS, ((0.0, math.inf), (0.0, 0.0)), JAWS), "hand_velocities must be finite"),
    (lambda o: o.step(-DT, HANDS, STILL, JAWS), "dt_s and the jaw forces must be >= 0"),
    (lambda o: o.step(math.nan, HANDS, STILL, JAWS), "dt_s must be finite"),
    (lambda o: o.step(DT, HANDS, STILL, (-1.0, 118.0)), "jaw forces must be >= 0"),
    (lambda o: o.step(DT, (0.5, 0.3), STILL, JAWS), "two \\(x, z\\) pairs"),
    (lambda o: o.step(DT, HANDS, STILL, 118.0), "two \\(x, z\\) pairs"),
    (lambda o: o.grasp(((0.5, math.nan), (0.75, 0.3))), "hands must be two finite"),
])
def test_bad_input_is_refused_and_changes_nothing(call, message):
    obj = held()
    run(obj, 0.05)
    before = (obj.pose, obj.velocity, obj.hand_forces, obj.states, obj.event_count, obj.t_s)
    with pytest.raises(ValueError, match=message):
        call(obj)
    assert (obj.pose, obj.velocity, obj.hand_forces, obj.states, obj.event_count, obj.t_s) == before


@pytest.mark.parametrize("change, message", [
    (dict(mass_kg=-0.25), "mass_kg must be finite and > 0"),
    (dict(mass_kg=math.nan), "mass_kg must be finite"),
    (dict(stiffness_n_m=(0.0, 5000.0)), "stiffness_n_m must be finite and > 0"),
    (dict(damping_n_s_m=(-1.0, 35.0)), "damping_n_s_m must be finite and >= 0"),
    (dict(friction=0.0), "friction must be finite and > 0"),
    (dict(gravity_m_s2=-9.8), "gravity_m_s2 must be finite and >= 0"),
    (dict(grasps_m=((0.0, 0.0), (0.0, 0.0))), "must be apart"),
    (dict(grasps_m=((-0.2, 0.0), (0.2, 0.0))), "outside the object"),
])
def test_bad_settings_are_refused(change, message):
    with pytest.raises(ValueError, match=message):
        ObjectParams(**change)
