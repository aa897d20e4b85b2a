"""The sim camera on a rail: /camera/pose is where the cell believes the camera (the straight, exact rail of
/arm/state), the image is rendered where the rail's TRUE deviation puts it (sim-only true_rail_*)."""
from __future__ import annotations

import numpy as np
from geometry_msgs.msg import PoseStamped
from sensor_msgs.msg import Image
from std_srvs.srv import Trigger
from stud_welding_msgs.msg import ArmState

from rosproc import REPO, ros2_run, wait_for
from stud_common import ros_io
from stud_common.frames import RailDeviation, true_world_correction
from stud_common.rotations import rpy_to_matrix
from stud_perception import image_io
from stud_perception.camera_node import camera_pose_from_tool
from stud_perception.hand_eye_solvers import rotation_angle_deg
from stud_perception.scene_cameras import view_camera
from stud_perception.scene_file import load_scene
from stud_perception.scene_render import render

SCENE_FILE = REPO / "src" / "stud_perception" / "config" / "dome_scene.json"
HAND_EYE = [0.05, 0.0, -0.10]
DEVIATION = RailDeviation(scale_ppm=2000.0, offset_m=0.004, yaw_urad_per_m=3000.0)  # gross, to be seen at 0.05 m


def test_sim_camera_renders_where_the_rail_truly_put_the_arm(ros_node, procs, tmp_path):
    params = {"scene_file": str(SCENE_FILE), "depth_noise_m": 0.0, "pose_source": "arm", "hand_eye_xyz_m": HAND_EYE,
              "true_rail_scale_ppm": DEVIATION.scale_ppm, "true_rail_offset_m": DEVIATION.offset_m,
              "true_rail_yaw_urad_per_m": DEVIATION.yaw_urad_per_m, "seed": 3}
    procs.append(ros2_run("stud_perception", "camera", tmp_path / "camera.log", params))
    poses, colors = [], []
    ros_node.create_subscription(PoseStamped, "/camera/pose", poses.append, ros_io.SENSOR_QOS)
    ros_node.create_subscription(Image, "/camera/color/image_raw", colors.append, ros_io.SENSOR_QOS)
    state_pub = ros_node.create_publisher(ArmState, "/arm/state", ros_io.RESULT_QOS)
    tool_R = rpy_to_matrix(np.pi, 0.0, np.pi / 2)
    tool_t = np.array([0.30, -0.17, 0.40])  # in world, as the driver reports it with the carriage at 0.05 m
    state = ArmState(connected=True, rail_position_m=0.05)
    state.tool_pose = ros_io.rt_to_pose(tool_R, tool_t)
    trigger = ros_node.create_client(Trigger, "/camera/trigger")
    wait_for(trigger.service_is_ready, 30, spin=ros_node.spin, what=f"/camera/trigger\n{procs[0].output()}")

    def shot() -> bool:
        state.header.stamp = ros_node.get_clock().now().to_msg()
        state_pub.publish(state)
        for _ in range(5):
            ros_node.spin()
        future = trigger.call_async(Trigger.Request())
        wait_for(future.done, 20, spin=ros_node.spin, what="a trigger reply")
        return future.result().success
    wait_for(shot, 30, what=f"a shot posed by /arm/state\n{procs[0].output()}")
    wait_for(lambda: poses and colors, 30, spin=ros_node.spin, what="the shot's pose and image")

    R, t = ros_io.pose_to_rt(poses[-1].pose)
    R_bel, t_bel = camera_pose_from_tool(tool_R, tool_t, HAND_EYE, [0.0, 0.0, 0.0])
    assert np.linalg.norm(t - t_bel) < 1e-9 and rotation_angle_deg(R, R_bel) < 1e-6  # believed: the straight rail
    C = true_world_correction(0.05, DEVIATION)
    R_true, t_true = camera_pose_from_tool(C[:3, :3] @ tool_R, C[:3, :3] @ tool_t + C[:3, 3], HAND_EYE, [0.0] * 3)
    assert np.linalg.norm(t_true - t_bel) > 0.004  # the offset, the scale and the bend: mm
    template = view_camera((0.0, 0.0, 0.0), distance_m=1.0, yaw_rad=np.radians(90.0))
    truth = render(load_scene(SCENE_FILE), template.with_pose(R_true, t_true), seed=3, depth_noise_m=0.0)
    believed = render(load_scene(SCENE_FILE), template.with_pose(R_bel, t_bel), seed=3, depth_noise_m=0.0)
    image = image_io.color_to_bgr(colors[-1])
    assert np.array_equal(image, truth.color_bgr)  # rendered where the rail truly is ...
    assert not np.array_equal(image, believed.color_bgr)  # ... not where /camera/pose says
