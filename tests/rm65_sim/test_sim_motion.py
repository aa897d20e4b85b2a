"""The simulated arm's time law: trapezoidal, within every speed and acceleration, scaled by ``v``."""
from __future__ import annotations

import numpy as np
import pytest

from rm65_driver.kinematics.rm65 import RM65Kinematics, matrix_to_pose6, trapezoid_profile
from rm65_driver.protocol import messages as P
from rm65_sim.motion import LineSegment, Motion, MotionLimits, SegmentProfile, junction_speed, line_segment, plan_motion
from rm65_sim.simulator import ArmSimulator


def test_a_long_move_cruises_and_a_short_one_is_a_triangle():
    # 50 mm at 0.15 m/s and 0.48 m/s^2 (30 % of 0.5 m/s, 1.6 m/s^2): L/v + v/a
    T, ta = trapezoid_profile([0.05], [0.15], [0.48])
    assert T == pytest.approx(0.05 / 0.15 + 0.15 / 0.48) and ta == pytest.approx(0.15 / 0.48)
    # 10 mm at 0.05 m/s and 0.16 m/s^2 never reaches 0.05 m/s: 2 sqrt(L/a), half of it speeding up
    T, ta = trapezoid_profile([0.01], [0.05], [0.16])
    assert T == pytest.approx(2 * np.sqrt(0.01 / 0.16)) and ta == pytest.approx(T / 2)
    assert trapezoid_profile([0.0, 0.0], [1.0, 1.0], [1.0, 1.0]) == (0.0, 0.0)


def test_every_component_of_a_synchronised_move_stays_within_its_speed_and_acceleration():
    rng = np.random.default_rng(7)
    for _ in range(500):
        L = rng.uniform(0, 2, 6) * (rng.random(6) < 0.8)
        v = rng.uniform(0.2, 4, 6)
        a = rng.uniform(0.5, 20, 6)
        T, ta = trapezoid_profile(L, v, a)
        assert 0 < ta <= T / 2 + 1e-12
        peak_v = L / (T - ta)  # the shared law's cruise speed, per component
        peak_a = L / (ta * (T - ta))
        assert np.all(peak_v <= v * (1 + 1e-9)) and np.all(peak_a <= a * (1 + 1e-9))
        # and no faster law exists: at 0.999 T no acceleration time keeps every component within both
        # (nor is it faster than the slowest component alone)
        alone = np.where(L >= v * v / a, L / v + v / a, 2 * np.sqrt(L / a))
        assert T >= alone.max() * (1 - 1e-12)
        Ts = 0.999 * T
        tas = np.linspace(1e-6, Ts / 2, 2001)[:, None]
        ok = np.all(L <= v * (Ts - tas) * (1 + 1e-9), axis=1) & np.all(L <= a * tas * (Ts - tas) * (1 + 1e-9), axis=1)
        assert not ok.any()


@pytest.mark.parametrize("accel_fraction", [0.05, 0.3, 0.5])
def test_the_time_law_starts_and_ends_at_rest_and_never_exceeds_its_cruise_speed(accel_fraction):
    tau = np.linspace(0, 1, 20001)
    law = SegmentProfile.rest_to_rest(2.0, 2.0 * accel_fraction)
    assert law.duration_s == pytest.approx(2.0)
    s = np.array([law.fraction_at(2.0 * t) for t in tau])
    speed = np.diff(s) / np.diff(tau)
    assert s[0] == 0 and s[-1] == pytest.approx(1.0)
    assert np.all(np.diff(s) >= 0)
    assert speed[0] < 1e-3 and speed[-1] < 1e-3
    assert speed.max() == pytest.approx(1 / (1 - accel_fraction), rel=1e-3)


def test_a_joint_move_at_v_percent_takes_its_speed_and_acceleration_at_v_percent():
    kin = RM65Kinematics()
    q0 = np.radians([0, 0, 90, 0, 90, 0])
    q1 = np.radians([60, 10, 80, 0, 90, 0])
    msg = P.movej(q1, 30)
    path, T, ta, code = plan_motion(kin, "movej", msg, q0, lambda: (np.eye(4), np.eye(4)), MotionLimits())
    assert code == 0 and path is not None
    v, a = 0.3 * np.radians(180), 0.3 * np.radians(600)  # J1, the slowest here
    assert T == pytest.approx(np.radians(60) / v + v / a) and ta == pytest.approx(v / a)
    # the simulated joints follow it: J1 never faster than 30 % of 180 deg/s, nor accelerating faster
    m = Motion("movej", path, SegmentProfile.rest_to_rest(T, ta), conn_id=0)
    t = np.linspace(0, T, 4001)
    q = np.array([m.joints_at(x / T) for x in t])
    dq = np.diff(q[:, 0]) / np.diff(t)
    assert np.abs(dq).max() <= v * 1.001
    assert np.abs(np.diff(dq) / np.diff(t[:-1])).max() <= a * 1.01
    np.testing.assert_allclose(q[-1], q1, atol=1e-12)


def test_a_short_linear_move_costs_its_acceleration_too():
    kin = RM65Kinematics()
    q0 = np.radians([0, 20, 70, 0, 90, 0])
    T0 = kin.fk(q0)
    goal = T0.copy()
    goal[:3, 3] += [0, 0, 0.05]  # 50 mm up at 30 %
    path, T, ta, code = plan_motion(kin, "movel", P.movel(matrix_to_pose6(goal), 30), q0,
                                    lambda: (np.eye(4), np.eye(4)), MotionLimits())
    assert code == 0
    assert T >= (0.05 / 0.15 + 0.15 / 0.48) * (1 - 1e-4)  # at least the line's own trapezoid
    assert T < 1.2 * (0.05 / 0.15 + 0.15 / 0.48)  # the joints are not the limit here


# -- connected motions (trajectory_connect=1) ---------------------------------------------------------------
def _line(start, end, speed=0.15, accel=0.48, turns=False):
    return LineSegment(np.asarray(start, float), np.asarray(end, float), turns, speed, accel)


def test_a_line_continuing_another_is_joined_at_the_lower_speed_and_a_corner_or_a_turn_at_rest():
    fast = _line([0, 0, 0.05], [0, 0, 0.01])
    slow = _line([0, 0, 0.01], [0, 0, 0.0], speed=0.05, accel=0.16)
    assert junction_speed(fast, slow) == pytest.approx(0.05)
    sideways = _line([0, 0, 0.01], [0.01, 0, 0.01], speed=0.05, accel=0.16)
    assert junction_speed(fast, sideways) == 0.0  # a corner: no blend radius, so a stop
    assert junction_speed(fast, _line([0, 0, 0.01], [0, 0, 0.0], turns=True)) == 0.0
    assert junction_speed(fast, _line([0, 0, 0.02], [0, 0, 0.0])) == 0.0  # does not start where the first ends
    # too short to stop from the faster speed: the junction speed is what the second line can still stop from
    tiny = _line([0, 0, 0.01], [0, 0, 0.0099], speed=0.15, accel=0.48)
    assert junction_speed(fast, tiny) == pytest.approx(np.sqrt(2 * 0.48 * 1e-4))


@pytest.mark.parametrize("u, w", [(0.0, 0.05), (0.05, 0.0), (0.0, 0.0), (0.02, 0.05)])
def test_a_segment_goes_from_its_start_speed_to_its_end_speed_within_its_limits(u, w):
    prof = SegmentProfile(length=0.04, u=u, w=w, speed=0.15, accel=0.48)
    T = prof.duration_s
    t = np.linspace(0, T, 40001)
    d = np.array([prof.fraction_at(x) for x in t]) * prof.length
    v = np.diff(d) / np.diff(t)
    assert d[0] == 0 and d[-1] == pytest.approx(prof.length)
    assert v[0] == pytest.approx(u, abs=2e-4) and v[-1] == pytest.approx(w, abs=2e-4)
    assert v.max() <= 0.15 * 1.001
    assert np.abs(np.diff(v) / np.diff(t[:-1])).max() <= 0.48 * 1.01
    if u == w == 0:  # from rest to rest it is the plain trapezoid
        assert T == pytest.approx(trapezoid_profile([0.04], [0.15], [0.48])[0])


def test_the_fast_approach_joined_to_the_slow_final_move_saves_the_stop_between_them():
    """The weld cycle's approach: 40 mm at 30 %, then the last 10 mm at 10 %, one line (the default limits)."""
    kin = RM65Kinematics()
    q0 = np.radians([0, 20, 70, 0, 90, 0])
    T0 = kin.fk(q0)
    short, contact = T0.copy(), T0.copy()
    short[:3, 3] -= [0, 0, 0.04]
    contact[:3, 3] -= [0, 0, 0.05]
    frames = lambda: (np.eye(4), np.eye(4))  # noqa: E731
    p1, T1, a1, _ = plan_motion(kin, "movel", P.movel(matrix_to_pose6(short), 30), q0, frames, MotionLimits())
    p2, T2, a2, _ = plan_motion(kin, "movel", P.movel(matrix_to_pose6(contact), 10), p1[-1], frames, MotionLimits())
    first = Motion("movel", p1, SegmentProfile.rest_to_rest(T1, a1), 0, connect_next=True,
                   line=line_segment(kin, p1, np.eye(4), T1, a1))
    second = Motion("movel", p2, SegmentProfile.rest_to_rest(T2, a2), 0, line=line_segment(kin, p2, np.eye(4), T2, a2))
    ArmSimulator._join(first, second)
    assert (first.profile.length == pytest.approx(0.04, rel=1e-4)
            and second.profile.length == pytest.approx(0.01, rel=1e-4))
    # handed over at the slow move's speed: the 10 mm at 10 % (0.05 m/s, 0.16 m/s^2) peak at 0.04 m/s from rest,
    # and the junction takes no more than that (conservative: the slow move could cruise at 0.05 from a flying start)
    assert first.profile.w == pytest.approx(second.line.speed) and first.profile.w == pytest.approx(0.04, rel=1e-3)
    joined, apart = first.duration_s + second.duration_s, T1 + T2
    assert apart == pytest.approx(2 * np.sqrt(0.04 / 0.48) + 2 * np.sqrt(0.01 / 0.16), rel=1e-3)  # two triangles
    assert 0.15 < apart - joined < 0.3  # about 0.23 s a stud
    # the joined pair still ends exactly at the contact pose, and the first never leaves its line
    np.testing.assert_allclose(second.joints_at(1.0), p2[-1], atol=1e-12)
    np.testing.assert_allclose(first.joints_at(1.0), p1[-1], atol=1e-12)
