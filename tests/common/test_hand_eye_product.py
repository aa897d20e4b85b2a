"""The hand-eye product, written once (stud_common.hand_eye_in_use): camera in world from the tool
pose, and the tool pose that puts the camera somewhere."""
from __future__ import annotations

import numpy as np

from stud_common.hand_eye_in_use import camera_in_world, tool_in_world
from stud_common.rotations import rpy_to_matrix, transform, transform_xyz_rpy


def test_the_camera_is_the_tool_pose_times_the_hand_eye_and_back():
    T_world_tool = transform(rpy_to_matrix(0.3, -1.1, 2.0), [0.31, -0.12, 0.44])
    T_tool_cam = transform_xyz_rpy([0.056, -0.004, -0.097], [1.0, -0.5, 0.8])
    T_cam = camera_in_world(T_world_tool, T_tool_cam)
    # the optical frame's origin: the hand-eye offset carried by the tool's rotation
    np.testing.assert_allclose(T_cam[:3, 3], T_world_tool[:3, :3] @ [0.056, -0.004, -0.097] + T_world_tool[:3, 3],
                               atol=1e-12)
    np.testing.assert_allclose(T_cam[:3, :3], T_world_tool[:3, :3] @ T_tool_cam[:3, :3], atol=1e-12)
    np.testing.assert_allclose(tool_in_world(T_cam, T_tool_cam), T_world_tool, atol=1e-12)
