"""The state publisher on a rail, over DDS: /tf carries world -> carriage from rail_joint, /tf_static
carriage -> base_link, and the chain ends where the driver's kinematics put the flange."""
from __future__ import annotations

import numpy as np
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage

from rm65_driver.kinematics.rm65 import RM65Kinematics, pose_to_matrix, rotation_angle
from rm65_driver.kinematics.robot_description import JOINT_NAMES
from rm65_driver.kinematics.urdf_model import parse_urdf
from rosproc import ros2_run, wait_for
from stud_common import frames, ros_io, tf_io
from stud_common.frames import world_T_base

MOUNT = [0.05, -0.02, 0.10]


def _matrix(t) -> np.ndarray:
    tr, r = t.transform.translation, t.transform.rotation
    return pose_to_matrix([tr.x, tr.y, tr.z], [r.x, r.y, r.z, r.w])


def test_tf_chains_world_carriage_base_with_the_rail_joint(ros_node, procs, tmp_path):
    procs.append(ros2_run("rm65_driver", "state_publisher", tmp_path / "sp.log",
                          {"rail_length_m": 6.0, "rail_mount_xyz_m": MOUNT, "registration_topic": ""}))
    descriptions: list[String] = []
    static: list[TFMessage] = []
    moving: list[TFMessage] = []
    ros_node.create_subscription(String, "/robot_description", descriptions.append, ros_io.LATCHED_QOS)
    ros_node.create_subscription(TFMessage, "/tf_static", static.append, tf_io.TF_STATIC_QOS)
    ros_node.create_subscription(TFMessage, "/tf", moving.append, tf_io.TF_QOS)
    joints = ros_node.create_publisher(JointState, "/joint_states", 10)
    wait_for(lambda: descriptions and static, 30, ros_node.spin, "the latched /robot_description and /tf_static")
    assert parse_urdf(descriptions[-1].data).joint(frames.RAIL_JOINT).type == "prismatic"
    fixed = {t.child_frame_id: t for t in static[-1].transforms}
    assert fixed[frames.BASE_LINK].header.frame_id == frames.CARRIAGE
    np.testing.assert_allclose(_matrix(fixed[frames.BASE_LINK])[:3, 3], MOUNT, atol=1e-12)
    assert frames.CARRIAGE not in fixed

    q = np.radians([10, 20, 30, 40, 50, 60])
    js = JointState(name=[*JOINT_NAMES, frames.RAIL_JOINT], position=[*q.tolist(), 2.25])
    js.header.stamp = ros_io.ns_to_stamp(1_700_000_000_000_000_000)

    def joints_published() -> bool:
        joints.publish(js)
        return bool(moving)

    wait_for(joints_published, 30, ros_node.spin, "/tf after /joint_states")
    tf = {t.child_frame_id: t for t in moving[-1].transforms}
    assert set(tf) == {frames.CARRIAGE} | {f"link{i}" for i in range(1, 7)}
    assert tf[frames.CARRIAGE].header.frame_id == frames.WORLD and tf[frames.CARRIAGE].header.stamp == js.header.stamp
    np.testing.assert_allclose(_matrix(tf[frames.CARRIAGE]), world_T_base(2.25), atol=1e-12)
    T = np.eye(4)
    for child in (frames.CARRIAGE, frames.BASE_LINK, "link1", "link2", "link3", "link4", "link5", "link6",
                  frames.FLANGE):
        T = T @ _matrix(tf.get(child) or fixed[child])
    expected = world_T_base(2.25, MOUNT) @ RM65Kinematics().fk(q)
    assert np.linalg.norm(T[:3, 3] - expected[:3, 3]) < 1e-6
    assert rotation_angle(T[:3, :3], expected[:3, :3]) < 1e-6
