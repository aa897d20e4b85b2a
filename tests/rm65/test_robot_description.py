"""The RM-65 URDF: its joint origins chained give the kinematics module's FK, and the file is current."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rm65_driver.kinematics.rm65 import D6_BY_VARIANT, JOINT_LIMITS_DEG, DHModel, RM65Kinematics, rotation_angle
from rm65_driver.kinematics.robot_description import JOINT_NAMES, RM65Description, rm65_urdf
from rm65_driver.kinematics.urdf_model import UrdfError, parse_urdf
from stud_common import frames

URDF_FILE = Path(__file__).resolve().parents[2] / "src" / "rm65_driver" / "urdf" / "rm65.urdf"
MODEL = parse_urdf(URDF_FILE.read_text())
KIN = RM65Kinematics()
LIMITS_RAD = np.radians(JOINT_LIMITS_DEG)


def _assert_same_pose(A: np.ndarray, B: np.ndarray) -> None:
    assert np.linalg.norm(A[:3, 3] - B[:3, 3]) < 1e-6
    assert rotation_angle(A[:3, :3], B[:3, :3]) < 1e-6


def test_committed_urdf_is_the_generator_output_at_its_defaults():
    assert URDF_FILE.read_text() == rm65_urdf(), "regenerate urdf/rm65.urdf (see robot_description.py)"


def test_urdf_frames_form_the_documented_chain():
    assert MODEL.root == frames.WORLD
    chain = [j.child for j in MODEL.chain(frames.WORLD, frames.CAMERA_OPTICAL)]
    assert chain == [frames.BASE_LINK, "link1", "link2", "link3", "link4", "link5", "link6", frames.FLANGE,
                     frames.WELD_TOOL, frames.CAMERA_OPTICAL]
    assert [j.name for j in MODEL.moving_joints] == list(JOINT_NAMES)
    for j, (lo, hi) in zip(MODEL.moving_joints, LIMITS_RAD):
        assert j.type == "revolute" and j.lower == pytest.approx(lo) and j.upper == pytest.approx(hi)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(0.0, 1.0), min_size=6, max_size=6))
def test_urdf_forward_kinematics_equals_the_kinematics_module(fractions):
    q = LIMITS_RAD[:, 0] + np.asarray(fractions) * (LIMITS_RAD[:, 1] - LIMITS_RAD[:, 0])
    positions = dict(zip(JOINT_NAMES, q))
    _assert_same_pose(MODEL.frame_transform(frames.WORLD, frames.FLANGE, positions), KIN.fk(q))
    tool = np.eye(4)
    tool[2, 3] = 0.15
    _assert_same_pose(MODEL.frame_transform(frames.WORLD, frames.WELD_TOOL, positions), KIN.fk(q, tool))


def test_urdf_matches_the_sdk_pose_at_zero_joints():
    T = MODEL.frame_transform(frames.WORLD, frames.FLANGE, {})
    np.testing.assert_allclose(T[:3, 3], [0.0, 0.0, 0.8505], atol=1e-9)  # 240.5 + 256 + 210 + 144 mm


def test_variant_tool_offset_and_hand_eye_reach_the_urdf():
    desc = RM65Description(variant="RM65-6F", tool_offset_m=0.2, hand_eye_xyz_m=(0.05, 0.0, -0.1),
                           hand_eye_rpy_deg=(0.0, 10.0, 90.0))
    model = parse_urdf(rm65_urdf(desc))
    kin = RM65Kinematics(dh=DHModel.rm65(D6_BY_VARIANT["RM65-6F"]))
    q = np.radians([10, 20, 30, 40, 50, 60])
    tool = np.eye(4)
    tool[2, 3] = 0.2
    positions = dict(zip(JOINT_NAMES, q))
    _assert_same_pose(model.frame_transform(frames.WORLD, frames.WELD_TOOL, positions), kin.fk(q, tool))
    _assert_same_pose(model.frame_transform(frames.WELD_TOOL, frames.CAMERA_OPTICAL, {}), desc.hand_eye)
    assert frames.CAMERA_OPTICAL not in parse_urdf(rm65_urdf(RM65Description(include_camera=False))).links


@pytest.mark.parametrize("text, reason", [
    ("<robot/>", "at least one"),
    ("<robot><link name='a'/><link name='b'/></robot>", "2 trees"),
    ("<robot><link name='a'/><link name='b'/><joint name='j' type='revolute'><parent link='a'/>"
     "<child link='b'/></joint></robot>", "needs <limit>"),
    ("<robot><link name='a'/><joint name='j' type='fixed'><parent link='a'/><child link='c'/></joint></robot>",
     "not declared"),
    ("<robot><link name='a'/><link name='b'/><joint name='j' type='fixed'><parent link='a'/><child link='b'/>"
     "<origin xyz='1 2'/></joint></robot>", "not 3"),
    ("<robt/>", "expected <robot>"),
])
def test_bad_urdf_is_refused_with_a_reason(text, reason):
    with pytest.raises(UrdfError, match=reason):
        parse_urdf(text)
