"""Pre-motion safety checks: reach, limits, workspace box, the gun's tilt, the free rotation about the stud,
speed caps."""
from __future__ import annotations

import numpy as np
import pytest

from rm65_driver.kinematics.rm65 import RM65Kinematics, tool_pose_facing
from rm65_driver.weld.safety import SafetyChecker, SafetyLimits
from rm65_testing import HOME_DEG

KIN = RM65Kinematics()
TOOL = np.eye(4)
TOOL[2, 3] = 0.15
HOME = np.radians(HOME_DEG)


def checker(**kw) -> SafetyChecker:
    return SafetyChecker(KIN, SafetyLimits(**kw), TOOL)


def test_reachable_target_gets_a_plan_on_the_normal():
    n = np.array([0.02, -0.03, 1.0])
    n /= np.linalg.norm(n)
    v = checker().check_target([0.32, 0.05, 0.02], n, 0.05, HOME)
    assert v.ok, v.reason
    p = v.plan
    np.testing.assert_allclose(p.T_contact[:3, 3], [0.32, 0.05, 0.02], atol=1e-12)
    np.testing.assert_allclose(p.T_approach[:3, 3], np.array([0.32, 0.05, 0.02]) + 0.05 * n, atol=1e-12)
    np.testing.assert_allclose(p.T_contact[:3, 2], -n, atol=1e-12)  # tool axis into the surface
    np.testing.assert_allclose((KIN.fk(p.q_contact) @ TOOL)[:3, 3], p.T_contact[:3, 3], atol=1e-5)
    assert KIN.within_limits(p.q_approach) and KIN.within_limits(p.q_contact)


@pytest.mark.parametrize(
    "position, normal, expect",
    [
        ([0.68, 0.0, 0.0], [0, 0, 1], "out of reach"),
        ([0.9, 0.0, 0.0], [0, 0, 1], "workspace box"),
        ([0.50, 0.0, 0.0], [0, 0, 1], "unreachable"),
        ([0.30, 0.0, 0.0], [np.sin(np.radians(70)), 0, np.cos(np.radians(70))],
         "tilt 70.0 deg from vertical > the cell's max_tool_tilt_deg 60.0 deg"),
        ([0.30, 0.0, -0.1], [0, 0, 1], "workspace box"),
        ([0.30, 0.0, np.nan], [0, 0, 1], "not finite"),
        ([0.30, 0.0, 0.0], [0, 0, 0], "not a usable direction"),
    ],
)
def test_rejections_carry_a_reason(position, normal, expect):
    v = checker().check_target(position, normal, 0.05, HOME)
    assert not v.ok and expect in v.reason, v.reason


def test_the_tool_tilt_limit_is_a_cell_parameter_not_the_studs_5_degrees():
    tilted = [np.sin(np.radians(40)), 0, np.cos(np.radians(40))]
    assert checker().check_tool_tilt(tilted) is None  # 40 deg slopes are welded along their normal
    assert "tilt 40.0 deg" in checker(max_tool_tilt_deg=30.0).check_tool_tilt(tilted)
    assert "tilt 180.0 deg" in checker().check_tool_tilt([0, 0, -1])


@pytest.mark.parametrize("slope_deg, azimuth_deg", [(20, 0), (20, 200), (30, 90), (35, -60), (45, -60)])
def test_steep_studs_get_a_plan_with_the_gun_along_their_normal(slope_deg, azimuth_deg):
    s, a = np.radians(slope_deg), np.radians(azimuth_deg)
    n = np.array([np.sin(s) * np.cos(a), np.sin(s) * np.sin(a), np.cos(s)])
    v = checker().check_target([0.30, 0.05, 0.03], n, 0.05, HOME)
    assert v.ok, v.reason
    for q, T in ((v.plan.q_contact, v.plan.T_contact), (v.plan.q_approach, v.plan.T_approach)):
        tip = KIN.fk(q) @ TOOL
        np.testing.assert_allclose(tip[:3, 3], T[:3, 3], atol=1e-5)
        assert np.degrees(np.arccos(np.clip(tip[:3, 2] @ -n, -1, 1))) < 0.01  # gun axis = -normal


def test_the_rotation_about_the_stud_is_the_one_nearest_the_current_joints():
    n = np.array([0.0, 0.3, 1.0]) / np.linalg.norm([0.0, 0.3, 1.0])
    c = checker()
    v = c.check_target([0.30, 0.0, 0.02], n, 0.05, HOME)
    assert v.ok
    # every other rotation that is reachable lies farther from the current joints
    best = np.linalg.norm(v.plan.q_approach - HOME)
    for yaw in c.yaw_candidates_deg:
        T = tool_pose_facing(np.array([0.30, 0.0, 0.02]) + 0.05 * n, n,
                             x_hint=(KIN.fk(HOME) @ TOOL)[:3, 0], yaw=np.radians(yaw))
        res = KIN.ik(T, HOME, tool=TOOL)
        if res.success:
            assert np.linalg.norm(res.q - HOME) >= best - 1e-6
    assert len(c.yaw_candidates_deg) == 24 and sorted(c.yaw_candidates_deg)[:2] == [-165.0, -150.0]


def test_an_off_axis_gun_turns_to_the_rotation_nearest_the_current_joints():
    # A gun mounted 0.12 m beside the flange axis: the flange circles the stud as the tool turns,
    # so the rotation about the stud changes the whole arm, not only the wrist.
    tool = np.eye(4)
    tool[:3, 3] = [0.12, 0.0, 0.15]
    target = np.array([0.19, 0.0, 0.05])
    searched = SafetyChecker(KIN, SafetyLimits(), tool).check_target(target, [0, 0, 1], 0.05, HOME)
    two_ways = SafetyChecker(KIN, SafetyLimits(yaw_step_deg=180.0), tool).check_target(target, [0, 0, 1], 0.05, HOME)
    assert searched.ok and two_ways.ok
    np.testing.assert_allclose((KIN.fk(searched.plan.q_contact) @ tool)[:3, 3], target, atol=1e-5)
    assert (np.linalg.norm(searched.plan.q_approach - HOME)
            < np.linalg.norm(two_ways.plan.q_approach - HOME) - np.radians(5))


def test_speed_caps():
    c = checker(max_joint_speed_pct=40, max_linear_speed_pct=10)
    assert c.check_speed(40, linear=False) is None
    assert "speed cap" in c.check_speed(41, linear=False)
    assert "linear speed 20 %" in c.check_speed(20, linear=True)


def test_joint_move_through_the_box_ceiling_is_rejected():
    low_ceiling = checker(workspace_max_m=(0.7, 0.7, 0.5))
    # From the folded "tool down behind" pose the joint move swings the arm up over the top.
    why = low_ceiling.check_joint_path(np.radians([0, 0, 90, 0, 90, 0]), np.radians(HOME_DEG), "approach move")
    assert why and "leaves the workspace box" in why


def test_bad_limits_are_refused():
    with pytest.raises(ValueError):
        SafetyLimits(workspace_min_m=(0, 0, 0), workspace_max_m=(1, 1, 0))
    with pytest.raises(ValueError):
        SafetyLimits(max_joint_speed_pct=0)
