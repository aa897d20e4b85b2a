"""The robot state publisher over DDS: latched model and static frames, /tf from /joint_states,
world -> drawing from a registration."""
from __future__ import annotations

import math

import numpy as np
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from stud_welding_msgs.msg import Registration
from tf2_msgs.msg import TFMessage

from rm65_driver.kinematics.rm65 import RM65Kinematics, pose_to_matrix, rotation_angle
from rm65_driver.kinematics.robot_description import JOINT_NAMES
from rm65_driver.kinematics.urdf_model import parse_urdf
from rosproc import ros2_run, wait_for
from stud_common import frames, ros_io, tf_io


def _matrix(t) -> np.ndarray:
    tr, r = t.transform.translation, t.transform.rotation
    return pose_to_matrix([tr.x, tr.y, tr.z], [r.x, r.y, r.z, r.w])


def test_state_publisher_publishes_model_static_frames_tf_and_the_drawing_frame(ros_node, procs, tmp_path):
    procs.append(ros2_run("rm65_driver", "state_publisher", tmp_path / "sp.log",
                          {"hand_eye_xyz_m": [0.05, 0.0, -0.10], "hand_eye_rpy_deg": [0.0, 0.0, 90.0]}))
    descriptions: list[String] = []
    static: list[TFMessage] = []
    moving: list[TFMessage] = []
    ros_node.create_subscription(String, "/robot_description", descriptions.append, ros_io.LATCHED_QOS)
    ros_node.create_subscription(TFMessage, "/tf_static", static.append, tf_io.TF_STATIC_QOS)
    ros_node.create_subscription(TFMessage, "/tf", moving.append, tf_io.TF_QOS)
    joints = ros_node.create_publisher(JointState, "/joint_states", 10)
    registration = ros_node.create_publisher(Registration, "/registration/result", ros_io.LATCHED_QOS)

    wait_for(lambda: descriptions and static, 30, ros_node.spin, "the latched /robot_description and /tf_static")
    model = parse_urdf(descriptions[-1].data)
    fixed = {t.child_frame_id: t for t in static[-1].transforms}
    assert fixed[frames.BASE_LINK].header.frame_id == frames.WORLD
    assert fixed[frames.WELD_TOOL].header.frame_id == frames.FLANGE
    assert abs(fixed[frames.WELD_TOOL].transform.translation.z - 0.15) < 1e-9
    cam = fixed[frames.CAMERA_OPTICAL]
    assert cam.header.frame_id == frames.WELD_TOOL and abs(cam.transform.translation.x - 0.05) < 1e-9
    assert rotation_angle(_matrix(cam)[:3, :3], model.joint("camera_joint").origin[:3, :3]) < 1e-9

    q = np.radians([10, 20, 30, 40, 50, 60])
    js = JointState(name=list(JOINT_NAMES), position=q.tolist())
    js.header.stamp = ros_io.ns_to_stamp(1_700_000_000_000_000_000)

    def joints_published() -> bool:
        joints.publish(js)
        return bool(moving)

    wait_for(joints_published, 30, ros_node.spin, "/tf after /joint_states")
    tf = {t.child_frame_id: t for t in moving[-1].transforms}
    assert set(tf) == {f"link{i}" for i in range(1, 7)}
    assert tf["link1"].header.stamp == js.header.stamp
    # Chain the published frames like a TF consumer: world -> ... -> rm65_flange equals the kinematics FK.
    T = np.eye(4)
    for child in (frames.BASE_LINK, "link1", "link2", "link3", "link4", "link5", "link6", frames.FLANGE):
        T = T @ _matrix(tf.get(child) or fixed[child])
    expected = RM65Kinematics().fk(q)
    assert np.linalg.norm(T[:3, 3] - expected[:3, 3]) < 1e-6
    assert rotation_angle(T[:3, :3], expected[:3, :3]) < 1e-6

    yaw = math.radians(30.0)
    reg = Registration(valid=True, message="ok")
    reg.header.frame_id = "world"
    reg.m_local2world = [math.cos(yaw), -math.sin(yaw), 0.4, math.sin(yaw), math.cos(yaw), -0.1, 0.0, 0.0, 1.0]
    reg.mark_o.x, reg.mark_o.y, reg.mark_o.z = 0.4, -0.1, 0.02
    registration.publish(reg)
    wait_for(lambda: frames.DRAWING in {t.child_frame_id for t in static[-1].transforms}, 30, ros_node.spin,
             "world -> drawing on /tf_static")
    latest = {t.child_frame_id: t for t in static[-1].transforms}
    assert frames.BASE_LINK in latest, "the static message keeps every static frame"
    drawing = _matrix(latest[frames.DRAWING])
    np.testing.assert_allclose(drawing[:3, 3], [0.4, -0.1, 0.02], atol=1e-9)
    assert abs(math.atan2(drawing[1, 0], drawing[0, 0]) - yaw) < 1e-9


def test_with_a_hand_eye_file_the_camera_frame_is_the_calibrated_one_not_the_typed_one(ros_node, procs, tmp_path):
    import json
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "perception"))
    from stud_common.hand_eye_in_use import load_hand_eye_file
    from stud_perception.hand_eye import calibrate_hand_eye
    from stud_perception.hand_eye_file import calibration_record, write_yaml
    from test_hand_eye import DRAWING, X_OFF, reachable_tool_poses, synthetic_shots

    path = write_yaml(tmp_path / "hand_eye.yaml",
                      calibration_record(calibrate_hand_eye(synthetic_shots(X_OFF, reachable_tool_poses(), 11),
                                                            DRAWING)), "test file")
    calibrated = load_hand_eye_file(path)
    typed = [0.05, 0.0, -0.10]
    assert np.linalg.norm(np.subtract(calibrated.xyz_m, typed)) > 1e-3  # the two differ: the test can tell
    procs.append(ros2_run("rm65_driver", "state_publisher", tmp_path / "sp.log",
                          {"hand_eye_xyz_m": typed, "hand_eye_rpy_deg": [0.0, 0.0, 0.0], "hand_eye_file": str(path)}))
    static: list[TFMessage] = []
    calibration: list[String] = []
    ros_node.create_subscription(TFMessage, "/tf_static", static.append, tf_io.TF_STATIC_QOS)
    ros_node.create_subscription(String, "/calibration/hand_eye", calibration.append, ros_io.LATCHED_QOS)
    wait_for(lambda: static and calibration, 30, ros_node.spin, "/tf_static and /calibration/hand_eye")
    cam = {t.child_frame_id: t for t in static[-1].transforms}[frames.CAMERA_OPTICAL]
    tr = cam.transform.translation
    np.testing.assert_allclose([tr.x, tr.y, tr.z], calibrated.xyz_m, atol=1e-9)
    summary = json.loads(calibration[-1].data)
    assert summary["source"] == "file" and summary["node"] == "state_publisher"
