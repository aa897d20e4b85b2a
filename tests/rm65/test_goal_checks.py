"""A weld goal's targets are consistent or refused before any motion (rm65_driver.weld.goal_checks): the
normal is the authority and must be a finite unit vector, the orientation a unit quaternion
(normalised within a tolerance) whose z axis agrees with the normal. Every target the cell's own
matcher produces passes; a goal mixing good targets with a zero normal, a NaN normal and a normal
30 deg off its pose's axis welds only the good ones, over real TCP with the simulator counting the
trigger edges, and names each bad one with its reason."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rm65_driver.kinematics.rm65 import matrix_to_quat_xyzw, tool_pose_facing
from rm65_driver.weld.goal_checks import GoalTolerances, check_target_fields
from rm65_driver.weld.weld_job import StudTarget
from rm65_testing import dome_targets, welds_per_stud
from stud_planner.matching.surface_pose import quaternion_from_normal

P0 = (0.30, 0.0, 0.03)


def _rotated(n: np.ndarray, deg: float) -> np.ndarray:
    """``n`` turned by ``deg`` about an axis perpendicular to it."""
    axis = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    axis /= np.linalg.norm(axis)
    a = math.radians(deg)
    return n * math.cos(a) + np.cross(axis, n) * math.sin(a) + axis * (axis @ n) * (1 - math.cos(a))


unit_normals = st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(0.05, 1)).map(
    lambda v: np.array(v) / np.linalg.norm(v))


# -- the rules ------------------------------------------------------------------------------------
@settings(max_examples=200, deadline=None)
@given(n=unit_normals)
def test_every_target_the_matcher_makes_passes_with_its_unit_normal(n):
    q = quaternion_from_normal(n[None])[0]  # what the matcher puts in pose.orientation
    target, why = check_target_fields("S0001", P0, n, q)
    assert target is not None, why
    np.testing.assert_allclose(target.normal, n, atol=1e-12)
    # the driver tests' own messages (tool z = -normal: the pose's z along +normal) too
    q_tool = matrix_to_quat_xyzw(tool_pose_facing(P0, -n)[:3, :3])
    assert check_target_fields("S0001", P0, n, q_tool)[0] is not None


@pytest.mark.parametrize("normal,quat,reason", [
    ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0), "normal (0, 0, 0) is not a unit vector (|n| = 0; expected 1 within 0.001)"),
    ((math.nan, 0.0, 1.0), (0.0, 0.0, 0.0, 1.0), "normal (nan, 0, 1) is not a unit vector (|n| = nan"),
    ((0.0, 0.0, math.inf), (0.0, 0.0, 0.0, 1.0), "normal (0, 0, inf) is not a unit vector"),
    ((0.0, 0.0, 2.0), (0.0, 0.0, 0.0, 1.0), "normal (0, 0, 2) is not a unit vector (|n| = 2;"),
    ((0.0, 0.0, 1.0), (0.0, 0.0, 0.0, 0.0), "pose orientation (x, y, z, w) (0, 0, 0, 0) is not a unit quaternion "
                                            "(|q| = 0; expected 1 within 0.01)"),
    ((0.0, 0.0, 1.0), (0.0, 0.0, math.nan, 1.0), "is not a unit quaternion (|q| = nan"),
    ((0.0, 0.0, 1.0), (0.0, 0.0, 0.0, 1.5), "(|q| = 1.5;"),
    ((0.0, 0.0, 1.0), (1.0, 0.0, 0.0, 0.0), "are 180.00 deg apart (> 1 deg): which way to weld is not clear"),
])
def test_a_meaningless_or_disagreeing_target_is_refused_naming_the_field_and_value(normal, quat, reason):
    target, why = check_target_fields("S0001", P0, normal, quat)
    assert target is None and reason in why, why


def test_a_normal_off_its_orientation_beyond_the_tolerance_is_refused_and_within_it_kept():
    n = np.array([0.1, -0.2, 1.0]) / np.linalg.norm([0.1, -0.2, 1.0])
    q = quaternion_from_normal(n[None])[0]
    for deg, ok in ((0.9, True), (1.1, False), (30.0, False)):
        target, why = check_target_fields("S0001", P0, _rotated(n, deg), q)
        assert (target is not None) == ok, (deg, why)
        if not ok:
            assert f"are {deg:.2f} deg apart (> 1 deg)" in why
    assert check_target_fields("S0001", P0, _rotated(n, 3.0), q, GoalTolerances(axis_tol_deg=5.0))[0] is not None


def test_a_nearly_unit_quaternion_is_normalised_and_the_normal_is_the_direction_welded():
    n = np.array([0.0, 0.6, 0.8])
    q = quaternion_from_normal(n[None])[0] * 1.008  # a float32 / rounded-decimals producer
    target, why = check_target_fields("S0001", P0, n * (1 + 5e-4), q)
    assert target is not None, why
    np.testing.assert_allclose(target.normal, n, atol=1e-12)  # unit, the normal's direction
    np.testing.assert_allclose(target.position, P0)


def test_a_non_finite_position_is_refused():
    target, why = check_target_fields("S0001", (0.3, math.nan, 0.0), (0, 0, 1), (0, 0, 0, 1))
    assert target is None and why == "position (0.3, nan, 0) is not finite"


def test_tolerances_must_be_positive():
    for bad in (0.0, -1.0, math.nan, math.inf):
        with pytest.raises(ValueError, match="expected a positive finite number"):
            GoalTolerances(axis_tol_deg=bad)


# -- the driver node, over real TCP with the simulator ---------------------------------------------
def test_a_goal_with_bad_targets_welds_only_the_good_ones_and_names_each_bad_one(sim, tmp_path):
    pytest.importorskip("stud_welding_msgs.msg", reason="workspace not built/sourced (source ros2_ws/setup.bash)")
    import rclpy
    from rclpy.action import ActionClient
    from rclpy.node import Node
    from stud_welding_msgs.action import WeldJob
    from stud_welding_msgs.msg import ArmState

    from test_driver_node import RELIABLE_10, NodeProc, spin_until, weld_target_msg

    good = dome_targets(rings=((0.0, 1), (0.05, 5)))
    bad_sites = [StudTarget(name, t.position, t.normal)
                 for name, t in zip(("B_ZERO", "B_NAN", "B_OFF30"), dome_targets(rings=((0.10, 3),)))]
    zero, nan, off = (weld_target_msg(t) for t in bad_sites)
    zero.normal.x = zero.normal.y = zero.normal.z = 0.0  # the goal: zero normal, identity orientation
    zero.pose.orientation.x = zero.pose.orientation.y = zero.pose.orientation.z = 0.0
    zero.pose.orientation.w = 1.0
    nan.normal.x = math.nan
    off.normal.x, off.normal.y, off.normal.z = (float(v) for v in _rotated(bad_sites[2].normal, 30.0))
    msgs = [weld_target_msg(t) for t in good[:3]] + [zero, nan, off] + [weld_target_msg(t) for t in good[3:]]

    rclpy.init()
    probe = Node("goal_checks_probe")
    proc = NodeProc(sim.port, tmp_path, pulse_s=0.01, dwell_s=0.01, standoff_m=0.04, state_rate_hz=20.0,
                    joint_speed_pct=50, linear_speed_pct=20)
    try:
        states = []
        probe.create_subscription(ArmState, "/arm/state", states.append, RELIABLE_10)
        action = ActionClient(probe, WeldJob, "/arm/weld_job")
        spin_until(probe, lambda: states and states[-1].connected and action.server_is_ready(), 30, "driver", proc)
        fut = action.send_goal_async(WeldJob.Goal(targets=msgs))
        spin_until(probe, fut.done, 20, "goal response", proc)
        rfut = fut.result().get_result_async()
        spin_until(probe, rfut.done, 120, "job result", proc)
        res = rfut.result().result
    finally:
        proc.stop()
        probe.destroy_node()
        rclpy.try_shutdown()

    assert sorted(res.welded) == sorted(t.stud_id for t in good), (res.message, list(res.messages))
    assert list(res.skipped) == ["B_ZERO", "B_NAN", "B_OFF30"] and not list(res.failed)
    messages = dict(m.split(": ", 1) for m in res.messages)
    assert messages["B_ZERO"].startswith("normal (0, 0, 0) is not a unit vector (|n| = 0;"), messages
    assert messages["B_NAN"].startswith("normal (nan, "), messages
    assert "are 30.00 deg apart (> 1 deg): which way to weld is not clear" in messages["B_OFF30"], messages
    # the simulator's own count of trigger edges: every good stud once, no bad site ever
    counts = welds_per_stud(sim, good + bad_sites)
    assert all(counts[t.stud_id] == 1 for t in good), counts
    assert all(counts[t.stud_id] == 0 for t in bad_sites), counts
