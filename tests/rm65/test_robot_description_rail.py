"""The URDF on a rail: world -> carriage (prismatic rail_joint along x) -> base_link (the mount), and
without a rail exactly the document it always was."""
from __future__ import annotations

import numpy as np
import pytest

from rm65_driver.kinematics.rm65 import RM65Kinematics, rotation_angle
from rm65_driver.kinematics.robot_description import JOINT_NAMES, RM65Description, rm65_urdf
from rm65_driver.kinematics.urdf_model import parse_urdf
from stud_common import frames
from stud_common.frames import world_T_base

MOUNT = (0.05, -0.02, 0.10)


def test_no_rail_is_the_fixed_base_of_before():
    assert rm65_urdf(RM65Description(rail_length_m=0.0)) == rm65_urdf()
    model = parse_urdf(rm65_urdf())
    assert frames.CARRIAGE not in model.links and model.joint("world_joint").type == "fixed"


def test_the_rail_is_a_prismatic_joint_along_world_x_under_the_mounted_base():
    model = parse_urdf(rm65_urdf(RM65Description(rail_length_m=6.0, rail_mount_xyz_m=MOUNT, rail_max_speed_m_s=0.8)))
    rail = model.joint(frames.RAIL_JOINT)
    assert (rail.type, rail.parent, rail.child) == ("prismatic", frames.WORLD, frames.CARRIAGE)
    assert (rail.lower, rail.upper, rail.velocity) == (0.0, 6.0, 0.8)
    np.testing.assert_array_equal(rail.axis, [1.0, 0.0, 0.0])
    assert [j.name for j in model.moving_joints] == [frames.RAIL_JOINT, *JOINT_NAMES]
    chain = [j.child for j in model.chain(frames.WORLD, frames.WELD_TOOL)]
    assert chain[:2] == [frames.CARRIAGE, frames.BASE_LINK]
    assert "world_joint" not in [j.name for j in model.joints]
    q = np.radians([10, -20, -90, 15, -60, 30])
    tool = np.eye(4)
    tool[2, 3] = 0.15
    for c in (0.0, 1.0, 5.75):
        T = model.frame_transform(frames.WORLD, frames.WELD_TOOL, {frames.RAIL_JOINT: c, **dict(zip(JOINT_NAMES, q))})
        expected = world_T_base(c, MOUNT) @ RM65Kinematics().fk(q, tool)
        assert np.linalg.norm(T[:3, 3] - expected[:3, 3]) < 1e-9
        assert rotation_angle(T[:3, :3], expected[:3, :3]) < 1e-9


def test_a_negative_rail_is_refused():
    with pytest.raises(ValueError, match="rail_length_m=-1"):
        RM65Description(rail_length_m=-1.0)
