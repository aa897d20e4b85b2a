"""RM65 kinematics: FK against the documented SDK test poses, IK round trips, pose helpers."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rm65_driver.kinematics.rm65 import (
    JOINT_LIMITS_DEG,
    RM65Kinematics,
    euler_zyx_to_matrix,
    invert_transform,
    matrix_to_euler_zyx,
    matrix_to_pose6,
    matrix_to_quat_xyzw,
    pose6_to_matrix,
    pose_to_matrix,
    quat_xyzw_to_matrix,
    rotation_angle,
    tool_pose_facing,
)

KIN = RM65Kinematics()

# docs/RM65_PROTOCOL.md §3.3: official SDK rm_algo_forward_kinematics, flange in base, [m, rad].
FK_VECTORS = [
    ([0, 0, 0, 0, 0, 0], [0, 0, 0.8505, 0, 0, np.pi]),
    ([0, 0, 90, 0, 90, 0], [-0.21, 0, 0.3525, np.pi, 0, 0]),
    ([0, 0, -90, 0, -90, 0], [0.21, 0, 0.3525, np.pi, 0, 0]),
    ([10, 20, 30, 40, 50, 60], [-0.355661, -0.134713, 0.610811, 1.607163, 0.008369, -0.880735]),
]


@pytest.mark.parametrize("joints_deg, pose", FK_VECTORS)
def test_fk_matches_the_documented_sdk_test_poses(joints_deg, pose):
    T = KIN.fk(np.radians(joints_deg))
    np.testing.assert_allclose(T[:3, 3], pose[:3], atol=1e-6)
    # compare orientations as matrices (Euler angles wrap at ±pi)
    assert rotation_angle(T[:3, :3], euler_zyx_to_matrix(*pose[3:])) < 2e-6


def test_fk_is_vectorised():
    Q = np.radians([v[0] for v in FK_VECTORS])
    T = KIN.fk(Q)
    assert T.shape == (4, 4, 4)
    for i, (_, pose) in enumerate(FK_VECTORS):
        np.testing.assert_allclose(T[i, :3, 3], pose[:3], atol=1e-6)


def test_sdk_euler_convention_quaternion():
    # SDK rm_algo_euler2quaternion([0.1,0.2,0.3]) = [w,x,y,z] = [0.98335, 0.03427, 0.10602, 0.14357]
    q = matrix_to_quat_xyzw(euler_zyx_to_matrix(0.1, 0.2, 0.3))
    np.testing.assert_allclose(q, [0.03427, 0.10602, 0.14357, 0.98335], atol=1e-5)


def test_ik_recovers_the_documented_joint_vector():
    T = KIN.fk(np.radians([10, 20, 30, 40, 50, 60]))
    res = KIN.ik(T, q_seed=np.radians([5, 15, 35, 45, 45, 55]))
    assert res.success
    np.testing.assert_allclose(np.degrees(res.q), [10, 20, 30, 40, 50, 60], atol=1e-3)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.floats(min_value=-0.9, max_value=0.9), min_size=6, max_size=6))
def test_ik_round_trip_from_a_nearby_seed(fractions):
    lim = np.radians(JOINT_LIMITS_DEG)
    q = lim[:, 1] * np.array(fractions)
    q[5] = np.clip(q[5], -3.0, 3.0)
    T = KIN.fk(q)
    res = KIN.ik(T, q_seed=q + 0.05)
    assert res.success, res.message
    T2 = KIN.fk(res.q)
    assert np.linalg.norm(T2[:3, 3] - T[:3, 3]) < 1e-5
    assert rotation_angle(T2, T) < 1e-4
    assert KIN.within_limits(res.q)


def test_ik_with_a_tool_and_a_far_seed_uses_restarts():
    tool = np.eye(4)
    tool[2, 3] = 0.15
    T = tool_pose_facing([0.35, 0.1, 0.0], [0, 0, 1])
    res = KIN.ik(T, q_seed=np.zeros(6), tool=tool)
    assert res.success
    np.testing.assert_allclose(KIN.fk(res.q, tool)[:3, 3], [0.35, 0.1, 0.0], atol=1e-5)
    np.testing.assert_allclose(KIN.fk(res.q, tool)[:3, 2], [0, 0, -1], atol=1e-5)


def test_ik_takes_the_preferred_branch_over_the_nearer_one():
    """A camera pose over the marking board has an elbow-and-wrist-up and a down solution. From a
    start pose with J3, J5 positive the nearest is up; the cell's stations are reached down, so a
    cell that prefers J3, J5 negative gets the down one, and keeps the nearest when it has no such one."""
    tool = np.eye(4)
    tool[2, 3] = 0.15
    T = tool_pose_facing([0.25, -0.29, 0.19], [0, 0, 1])
    start = np.radians([0, 0, 90, 0, 90, 0])
    nearest = KIN.ik(T, q_seed=start, tool=tool)
    assert nearest.success and nearest.q[2] > 0 and nearest.q[4] > 0
    down = KIN.ik(T, q_seed=start, tool=tool, prefer_signs=[0, 0, -1, 0, -1, 0])
    assert down.success and down.q[2] < 0 and down.q[4] < 0
    np.testing.assert_allclose(KIN.fk(down.q, tool)[:3, 3], T[:3, 3], atol=1e-5)
    # no solution has J3 and J5 of opposite signs here: the preference gives way to the nearest
    impossible = KIN.ik(T, q_seed=start, tool=tool, prefer_signs=[0, 0, 1, 0, -1, 0])
    assert impossible.success and np.sign(impossible.q[2]) == np.sign(impossible.q[4])
    either = KIN.ik(T, q_seed=start, tool=tool, prefer_signs=[0, 0, 0, 0, 0, 0])
    np.testing.assert_allclose(either.q, nearest.q, atol=1e-9)
    with pytest.raises(ValueError, match="prefer_signs must hold -1, 0 or 1"):
        KIN.ik(T, q_seed=start, tool=tool, prefer_signs=[0, 0, -2, 0, 0, 0])


def test_unreachable_pose_fails_with_a_reason():
    T = tool_pose_facing([0.9, 0.0, 0.0], [0, 0, 1])
    res = KIN.ik(T, q_seed=np.zeros(6))
    assert not res.success and "no IK solution" in res.message
    assert not KIN.in_reach([0.9, 0.0, 0.0])
    assert KIN.in_reach([0.3, 0.0, 0.2])


def test_ik_respects_joint_limits():
    # a pose that needs J2 beyond 130 deg (flange far behind and low)
    q = np.radians([0, 128, 0, 0, 0, 0])
    T = KIN.fk(q)
    tight = RM65Kinematics(limits_rad=np.radians(np.array(JOINT_LIMITS_DEG)
                                                 * [[1, 1], [0.5, 0.5], [1, 1], [1, 1], [1, 1], [1, 1]]))
    res = tight.ik(T, q_seed=q)
    assert not res.success or tight.within_limits(res.q)
    assert KIN.limit_violations(np.radians([0, 131, 0, 0, 0, 0]))[0].startswith("joint2=131.00 deg")


def test_max_reach_equals_the_documented_working_radius():
    rng = np.random.default_rng(0)
    lim = np.radians(JOINT_LIMITS_DEG)
    Q = rng.uniform(lim[:, 0], lim[:, 1], size=(20000, 6))
    d = np.linalg.norm(KIN.fk(Q)[:, :3, 3] - [0, 0, 0.2405], axis=1)
    assert d.max() <= 0.610 + 1e-9
    assert d.max() > 0.59


@settings(max_examples=50, deadline=None)
@given(st.floats(-3.1, 3.1), st.floats(-1.5, 1.5), st.floats(-3.1, 3.1))
def test_euler_zyx_round_trip(rx, ry, rz):
    R = euler_zyx_to_matrix(rx, ry, rz)
    np.testing.assert_allclose(euler_zyx_to_matrix(*matrix_to_euler_zyx(R)), R, atol=1e-9)
    np.testing.assert_allclose(quat_xyzw_to_matrix(matrix_to_quat_xyzw(R)), R, atol=1e-9)


def test_pose_helpers_round_trip():
    p = [0.1, -0.2, 0.3, 0.4, -0.5, 0.6]
    T = pose6_to_matrix(p)
    np.testing.assert_allclose(matrix_to_pose6(T), p, atol=1e-12)
    np.testing.assert_allclose(invert_transform(T) @ T, np.eye(4), atol=1e-12)
    T2 = pose_to_matrix(T[:3, 3], matrix_to_quat_xyzw(T[:3, :3]))
    np.testing.assert_allclose(T2, T, atol=1e-12)
    assert np.allclose(matrix_to_euler_zyx(euler_zyx_to_matrix(0.0, np.pi / 2, 0.3)), [0, np.pi / 2, 0.3])


def test_tool_pose_facing_points_into_the_surface():
    n = np.array([0.05, 0.0, 1.0])
    T = tool_pose_facing([0.3, 0, 0], n, yaw=0.7)
    np.testing.assert_allclose(T[:3, 2], -n / np.linalg.norm(n), atol=1e-12)
    np.testing.assert_allclose(T[:3, :3].T @ T[:3, :3], np.eye(3), atol=1e-12)
    assert np.linalg.det(T[:3, :3]) > 0


def test_linear_path_stays_on_the_line():
    tool = np.eye(4)
    tool[2, 3] = 0.15
    q0 = KIN.ik(tool_pose_facing([0.3, 0, 0.05], [0, 0, 1]), np.radians([0, -30, -100, 0, -50, 0]), tool).q
    goal = tool_pose_facing([0.3, 0, 0.0], [0, 0, 1])
    path, why = KIN.linear_path(q0, goal, tool)
    assert path is not None, why
    tips = KIN.fk(path, tool)[:, :3, 3]
    np.testing.assert_allclose(tips[:, :2], np.tile([0.3, 0.0], (len(tips), 1)), atol=1e-5)
    assert len(path) >= 10
