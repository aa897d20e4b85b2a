"""Pre-motion safety checks: reach, limits, workspace box, inclination, speed caps."""
from __future__ import annotations

import numpy as np
import pytest

from rm65_driver.kinematics import RM65Kinematics
from rm65_driver.safety import SafetyChecker, SafetyLimits
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
        ([0.30, 0.0, 0.0], [np.sin(np.radians(7)), 0, np.cos(np.radians(7))], "inclination 7.0 deg > 5.0 deg"),
        ([0.30, 0.0, -0.1], [0, 0, 1], "workspace box"),
        ([0.30, 0.0, np.nan], [0, 0, 1], "not finite"),
        ([0.30, 0.0, 0.0], [0, 0, 0], "not a usable direction"),
    ],
)
def test_rejections_carry_a_reason(position, normal, expect):
    v = checker().check_target(position, normal, 0.05, HOME)
    assert not v.ok and expect in v.reason, v.reason


def test_inclination_limit_and_stud_axis_are_parameters():
    tilted = [np.sin(np.radians(7)), 0, np.cos(np.radians(7))]
    assert checker(max_inclination_deg=8.0).check_inclination(tilted) is None
    assert checker(stud_axis=tuple(tilted)).check_inclination(tilted) is None
    assert "inclination" in checker().check_inclination([0, 0, -1])


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
