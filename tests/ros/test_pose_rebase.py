"""Replay with another calibration: pose_rebase turns a recorded camera pose back into its tool pose
and poses the camera again with the hand-eye in use, keeping the stamp."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from geometry_msgs.msg import PoseStamped

from rosproc import ros2_run, wait_for
from stud_common import ros_io
from stud_common.rotations import rpy_to_matrix, transform, transform_xyz_rpy
from stud_perception.hand_eye import rebase_camera_pose

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "perception"))


def test_rebase_is_the_tool_pose_times_the_hand_eye_in_use():
    T_tool = transform(rpy_to_matrix(*np.radians([170.0, 5.0, 30.0])), [0.3, -0.1, 0.45])
    X_rec, X_use = transform_xyz_rpy([0.05, 0.0, -0.10], [0, 0, 0]), transform_xyz_rpy([0.056, -0.004, -0.097],
                                                                                         [1.0, -0.5, 0.8])
    np.testing.assert_allclose(rebase_camera_pose(T_tool @ X_rec, X_rec, X_use), T_tool @ X_use, atol=1e-12)
    np.testing.assert_allclose(rebase_camera_pose(T_tool @ X_rec, X_rec, X_rec), T_tool @ X_rec, atol=1e-12)


def test_pose_rebase_node_reposes_recorded_poses_with_the_calibration_file(ros_node, procs, tmp_path):
    from stud_common.hand_eye_in_use import load_hand_eye_file
    from stud_perception.hand_eye import calibrate_hand_eye
    from stud_perception.hand_eye_file import calibration_record, write_yaml
    from test_hand_eye import DRAWING, X_OFF, reachable_tool_poses, synthetic_shots

    path = write_yaml(tmp_path / "hand_eye.yaml",
                      calibration_record(calibrate_hand_eye(synthetic_shots(X_OFF, reachable_tool_poses(), 11),
                                                            DRAWING)), "test file")
    X_use = load_hand_eye_file(path).T_tool_cam
    typed_xyz, typed_rpy = [0.05, 0.0, -0.10], [0.0, 0.0, 0.0]
    X_rec = transform_xyz_rpy(typed_xyz, typed_rpy)
    procs.append(ros2_run("stud_perception", "pose_rebase", tmp_path / "rebase.log",
                          {"recorded_hand_eye_xyz_m": typed_xyz, "recorded_hand_eye_rpy_deg": typed_rpy,
                           "hand_eye_xyz_m": typed_xyz, "hand_eye_rpy_deg": typed_rpy, "hand_eye_file": str(path)}))
    got: list[PoseStamped] = []
    ros_node.create_subscription(PoseStamped, "/camera/pose", got.append, ros_io.SENSOR_QOS)
    pub = ros_node.create_publisher(PoseStamped, "/camera/pose_recorded", ros_io.CAMERA_PUB_QOS)
    T_tool = transform(rpy_to_matrix(*np.radians([180.0, 0.0, 20.0])), [0.25, -0.05, 0.5])
    T_rec = T_tool @ X_rec
    msg = PoseStamped(pose=ros_io.rt_to_pose(T_rec[:3, :3], T_rec[:3, 3]))
    msg.header.frame_id, msg.header.stamp = "world", ros_io.ns_to_stamp(1_700_000_000_123_456_789)

    def sent_and_received() -> bool:
        pub.publish(msg)
        return bool(got)

    wait_for(sent_and_received, 30, ros_node.spin, "a re-posed /camera/pose")
    R, t = ros_io.pose_to_rt(got[-1].pose)
    expected = T_tool @ X_use
    np.testing.assert_allclose(t, expected[:3, 3], atol=1e-9)
    np.testing.assert_allclose(R, expected[:3, :3], atol=1e-9)
    assert np.linalg.norm(t - T_rec[:3, 3]) > 1e-3        # it did move: the file differs from the typed value
    assert got[-1].header.stamp == msg.header.stamp and got[-1].header.frame_id == "world"
