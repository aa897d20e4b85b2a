"""The reach test (rm65_driver.weld.reach): one verdict per stud or camera pose from the stud, the cell's
configuration and the arm base's pose only; its wire form; the driver's way to an accepted stud from
wherever the arm stands (rm65_driver.weld.reach_move), down to a weld through the simulator."""
from __future__ import annotations

import json

import numpy as np
import pytest

from rm65_driver.journal.writer import Journal
from rm65_driver.kinematics.rm65 import RM65Kinematics, pose6_to_matrix
from rm65_driver.protocol.arm_client import ArmClient
from rm65_driver.weld.reach import Reach, ReachConfig, ReachConfigError
from rm65_driver.weld.reach_move import detour, joint_path_problem, plan_move
from rm65_driver.weld.safety import SafetyChecker, SafetyLimits
from rm65_driver.weld.weld_job import StudTarget, WeldParams
from rm65_driver.weld.weld_sequence import WeldSequence
from rm65_sim.config import SimulatorConfig
from rm65_sim.simulator import ArmSimulator
from rm65_testing import FAST, HOME_DEG, welds_per_stud

REACH = Reach(ReachConfig(standoff_m=0.06, preferred_joint_signs=(0, 0, -1, 0, -1, 0)))
#: The arm folded over backwards, the tool tucked beside the base: a straight joint move from here
#: to a stud in front swings the upper arm through the table.
FOLDED_DEG = (-100.0, 116.0, 134.0, -161.0, -45.0, 0.0)


def tilted(slope_deg: float, azimuth_deg: float) -> np.ndarray:
    s, a = np.radians(slope_deg), np.radians(azimuth_deg)
    return np.array([np.sin(s) * np.cos(a), np.sin(s) * np.sin(a), np.cos(s)])


def test_an_accepted_stud_gets_a_plan_on_its_normal_and_a_straight_descent():
    n = tilted(25, 120)
    v = REACH.stud([0.30, 0.05, 0.05], n)
    assert v.ok, v.reason
    assert v.T_approach is not None and v.q_approach is not None and v.q_contact is not None and v.descent is not None
    tip = REACH.kin.fk(v.q_contact, REACH.tool_T)
    np.testing.assert_allclose(tip[:3, 3], [0.30, 0.05, 0.05], atol=1e-5)
    np.testing.assert_allclose(tip[:3, 2], -n, atol=1e-5)
    np.testing.assert_allclose(v.T_approach[:3, 3], np.array([0.30, 0.05, 0.05]) + 0.06 * n, atol=1e-12)
    assert np.all(np.abs(np.diff(v.descent, axis=0)) < np.radians(10))   # no joint jump on the way down
    assert np.sign(v.q_approach[2]) == np.sign(v.q_approach[4]) == -1     # the working branch
    assert 1 <= len(v.options) <= len(REACH.yaw_candidates_deg)


@pytest.mark.parametrize("position, normal, expect", [
    ([0.68, 0.0, 0.0], [0, 0, 1], "approach pose out of reach (flange"),
    ([0.9, 0.0, 0.0], [0, 0, 1], "approach pose leaves the workspace box"),
    ([0.50, 0.0, 0.0], [0, 0, 1], "approach pose: no IK solution inside the joint limits (best residual"),
    ([0.30, 0.0, 0.0], tilted(70, 0), "the gun would tilt 70.0 deg from vertical > the cell's max_tool_tilt_deg 60.0"),
    ([0.30, 0.0, -0.1], [0, 0, 1], "approach pose leaves the workspace box at (0.300, 0.000, -0.040)"),
    ([0.30, 0.0, -0.03], [0, 0, 1], "contact pose leaves the workspace box"),
    ([0.30, 0.0, np.nan], [0, 0, 1], "position [0.3, 0.0, nan] is not finite"),
])
def test_a_refused_stud_is_refused_with_the_pose_and_the_test_that_failed(position, normal, expect):
    v = REACH.stud(position, normal)
    assert not v.ok and v.reason.startswith(expect), v.reason


def test_the_verdict_depends_on_the_stud_and_the_base_pose_only():
    p, n = np.array([0.32, -0.08, 0.07]), tilted(22, 200)
    a, b = REACH.stud(p, n), REACH.stud(p, n)
    assert a.ok and a.yaw_rad == b.yaw_rad
    np.testing.assert_array_equal(a.q_approach, b.q_approach)
    # on a rail (a box 3 m long in world): the base moved 1.5 m along world x and turned 30 deg, the
    # stud moved with it is the same stud
    rail = Reach(ReachConfig(standoff_m=0.06, preferred_joint_signs=(0, 0, -1, 0, -1, 0),
                             workspace_min_m=(-0.7, -0.7, -0.02), workspace_max_m=(3.0, 0.7, 1.1)))
    B = pose6_to_matrix([1.5, 0.2, 0.0, 0.0, 0.0, np.radians(30)])
    moved = rail.stud(B[:3, :3] @ p + B[:3, 3], B[:3, :3] @ n, world_T_base=B)
    assert moved.ok and moved.yaw_rad == a.yaw_rad
    np.testing.assert_allclose(moved.q_approach, a.q_approach, atol=1e-6)
    assert not rail.stud(p, n, world_T_base=pose6_to_matrix([1.5, 0, 0, 0, 0, 0])).ok   # 1.2 m behind the arm
    # the workspace box is the cell's, in world: the same stud beyond its end is refused, the base beside it
    far = rail.stud([3.1, 0.0, 0.05], [0, 0, 1], world_T_base=pose6_to_matrix([2.8, 0, 0, 0, 0, 0]))
    assert not far.ok and far.reason.startswith("approach pose leaves the workspace box at (3.100"), far.reason


def test_camera_poses_checked_together_get_each_the_verdict_it_gets_alone():
    he = np.eye(4)
    he[:3, 3] = (0.05, 0.0, -0.10)
    reach = Reach(ReachConfig(hand_eye_T=tuple(he.ravel()), preferred_joint_signs=(0, 0, -1, 0, -1, 0)))
    nadir = np.diag([1.0, -1.0, -1.0])
    poses = []
    for x in np.linspace(0.05, 0.55, 6):
        for z in (0.3, 0.45, 0.6):
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = nadir, (x, -0.1, z)
            poses.append(T)
    together = reach.cameras(np.array(poses))
    alone = [reach.camera(T) for T in poses]
    assert [v.ok for v in together] == [v.ok for v in alone] and 0 < sum(v.ok for v in alone) < len(poses)
    for t, a, T in zip(together, alone, poses):
        assert t.reason == a.reason
        if a.ok:
            np.testing.assert_array_equal(t.q, a.q)
            cam = reach.kin.fk(a.q, reach.tool_T) @ he
            np.testing.assert_allclose(cam[:3, 3], T[:3, 3], atol=1e-5)


def test_the_configuration_goes_over_the_wire_exactly_and_bad_ones_are_named():
    c = ReachConfig(standoff_m=0.0613, tool_T=tuple(pose6_to_matrix([0.01, 0.0, 0.151, 0.0, 0.1, 0.0]).ravel()),
                    preferred_joint_signs=(0, 0, -1, 0, -1, 0), d6_m=0.1725)
    assert ReachConfig.from_json(c.to_json()) == c
    with pytest.raises(ReachConfigError, match=r"unknown reach config key\(s\) \['gun'\]"):
        ReachConfig.from_dict({**json.loads(c.to_json()), "gun": 1})
    with pytest.raises(ReachConfigError, match="preferred_joint_signs"):
        ReachConfig(preferred_joint_signs=(0, 2, 0, 0, 0, 0))
    with pytest.raises(ReachConfigError, match="standoff_m"):
        ReachConfig(standoff_m=-0.01)
    with pytest.raises(ReachConfigError, match="not JSON"):
        ReachConfig.from_json("{standoff")


def test_the_safety_checkers_reach_is_the_one_it_applies():
    tool = np.eye(4)
    tool[2, 3] = 0.15
    checker = SafetyChecker(RM65Kinematics(), SafetyLimits(max_tool_tilt_deg=40.0), tool,
                            prefer_signs=(0, 0, -1, 0, -1, 0))
    reach = checker.reach_for(0.06)
    assert reach.config.max_tool_tilt_deg == 40.0 and reach.config.standoff_m == 0.06
    p, n = [0.30, 0.0, 0.02], tilted(45, 90)
    assert checker.check_target(p, n, 0.06, np.radians(HOME_DEG)).reason == f"unreachable: {reach.stud(p, n).reason}"


def test_from_a_folded_arm_the_driver_takes_a_detour_instead_of_refusing_the_stud():
    q_folded = np.radians(FOLDED_DEG)
    v = REACH.stud([0.30, 0.0, 0.03], [0, 0, 1])
    assert v.ok and v.q_approach is not None
    assert joint_path_problem(REACH, q_folded, v.q_approach, "move")   # the straight move hits the table
    via, why = detour(REACH, q_folded, v.q_approach)
    assert via, why
    legs = [q_folded, *via, v.q_approach]
    assert not any(joint_path_problem(REACH, a, b, "leg") for a, b in zip(legs[:-1], legs[1:]))
    move, why = plan_move(REACH, v, q_folded)
    assert move is not None and move.via, why


def test_a_stud_is_welded_from_a_folded_start_through_the_detour_the_controller_is_sent(tmp_path):
    sim = ArmSimulator(host="127.0.0.1", port=0, config=SimulatorConfig(time_scale=FAST, initial_joints_deg=FOLDED_DEG))
    sim.start()
    client = ArmClient("127.0.0.1", sim.port, connect_timeout_s=1.0, reply_timeout_s=1.0, backoff_s=(0.02, 0.2))
    try:
        client.connect()
        params = WeldParams(standoff_m=0.06, tool_offset_m=0.15, pulse_s=0.01, dwell_s=0.01, motion_timeout_s=5.0)
        safety = SafetyChecker(RM65Kinematics(), SafetyLimits(), params.tool_T, prefer_signs=(0, 0, -1, 0, -1, 0))
        seq = WeldSequence(client, Journal(tmp_path / "weld.jsonl"), safety, params)
        target = StudTarget("S1", [0.30, 0.0, 0.03], [0, 0, 1])
        res = seq.run([target])
        assert res.welded == ["S1"], res.messages
        assert welds_per_stud(sim, [target]) == {"S1": 1}
        joint_moves = [np.radians(c.msg["joint"]) / 1000.0 for c in sim.commands_named("movej")]
        assert len(joint_moves) >= 2   # a waypoint, then the approach
        legs = [np.radians(FOLDED_DEG), *joint_moves]
        assert not any(joint_path_problem(REACH, a, b, "leg") for a, b in zip(legs[:-1], legs[1:]))
    finally:
        client.close()
        sim.stop()
