"""The shot node turns a streaming RGB-D driver into one triggered shot with the arm's camera pose.

This test plays a vendor driver (colour, registered depth and camera info streaming at 15 Hz on
the driver's own topics, stamps slightly apart as real drivers do) and the arm (/arm/state); the
shot node runs as its own process."""
from __future__ import annotations

import threading
import time

import numpy as np
from geometry_msgs.msg import PoseStamped
from sensor_msgs.msg import CameraInfo, Image
from std_srvs.srv import Trigger
from stud_welding_msgs.msg import ArmState

from rosproc import ros2_run, wait_for
from stud_common import ros_io
from stud_perception.camera_model import nadir_rotation
from stud_perception.camera_node import camera_pose_from_tool, shot_messages
from stud_perception.scene_cameras import view_camera
from stud_perception.scene_file import load_scene
from stud_perception.scene_render import render
from test_sensor_nodes import DEMO_SCENE

HAND_EYE = ([0.05, 0.0, -0.10], [0.0, 0.0, 90.0])


def test_trigger_republishes_one_synchronised_frame_with_the_arm_pose(ros_node, procs, tmp_path):
    procs.append(ros2_run("stud_perception", "shot", tmp_path / "shot.log",
                          {"hand_eye_xyz_m": HAND_EYE[0], "hand_eye_rpy_deg": HAND_EYE[1], "settle_s": 0.2}))
    cam = view_camera((0, 0, 0), 1.0, width=320, height=240)
    view = render(load_scene(DEMO_SCENE), cam.with_pose(cam.R_wc, np.array([0.3, 0.0, 0.5])))
    drv = {k: ros_node.create_publisher(t, f"/camera_driver/{topic}", ros_io.SENSOR_QOS) for k, t, topic in (
        ("color", Image, "color/image_raw"), ("depth", Image, "aligned_depth_to_color/image_raw"),
        ("info", CameraInfo, "color/camera_info"))}
    arm = ros_node.create_publisher(ArmState, "/arm/state", ros_io.RESULT_QOS)
    tool_R, tool_t = nadir_rotation(0.3), np.array([0.25, 0.05, 0.40])
    got: dict[str, list] = {"color": [], "depth": [], "info": [], "pose": []}
    for key, topic, typ in (("color", "/camera/color/image_raw", Image), ("depth", "/camera/depth/image_raw", Image),
                            ("info", "/camera/color/camera_info", CameraInfo), ("pose", "/camera/pose", PoseStamped)):
        ros_node.create_subscription(typ, topic, got[key].append, ros_io.SENSOR_QOS)
    stop = threading.Event()
    streamed: list[int] = []

    def stream():  # the "driver" and the "arm", from another thread (the test node spins in this one)
        k = 0
        while not stop.is_set():
            now = ros_node.get_clock().now().nanoseconds
            shot = shot_messages(view, "16UC1", ros_io.ns_to_stamp(now))
            for i, key in enumerate(("color", "depth", "info")):
                shot[key].header.stamp = ros_io.ns_to_stamp(now + i * 2_000_000)  # 0-4 ms apart
                drv[key].publish(shot[key])
            streamed.append(now)
            state = ArmState(mode=ArmState.MODE_IDLE, connected=True)
            state.header.stamp = ros_io.ns_to_stamp(now)
            state.tool_pose = ros_io.rt_to_pose(tool_R, tool_t)
            arm.publish(state)
            k += 1
            time.sleep(1 / 15)

    thread = threading.Thread(target=stream, daemon=True)
    thread.start()
    try:
        client = ros_node.create_client(Trigger, "/camera/trigger")
        wait_for(client.service_is_ready, 30, spin=ros_node.spin, what=f"shot node\n{procs[0].output()}")
        time.sleep(0.5)  # streaming well under way: frames before the trigger must not be taken
        t_trigger = ros_node.get_clock().now().nanoseconds
        future = client.call_async(Trigger.Request())
        wait_for(future.done, 15, spin=ros_node.spin, what="trigger reply")
        assert future.result().success, future.result().message
        wait_for(lambda: all(got.values()), 10, spin=ros_node.spin, what="the shot")
    finally:
        stop.set()
        thread.join()
    assert all(len(v) == 1 for v in got.values()), {k: len(v) for k, v in got.items()}  # one shot, not a stream
    stamps = {k: ros_io.stamp_to_ns(v[0].header.stamp) for k, v in got.items()}
    assert len(set(stamps.values())) == 1, stamps
    assert stamps["depth"] >= t_trigger + 0.2e9  # settled: taken after trigger + settle_s
    R, t = ros_io.pose_to_rt(got["pose"][0].pose)
    R_exp, t_exp = camera_pose_from_tool(tool_R, tool_t, *HAND_EYE)
    assert np.allclose(R, R_exp, atol=1e-6) and np.allclose(t, t_exp, atol=1e-6)
    assert got["depth"][0].encoding == "16UC1" and got["depth"][0].width == 320
