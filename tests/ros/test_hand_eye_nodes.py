"""The hand-eye at the nodes: the sim camera renders with the TRUE hand-eye and poses /camera/pose with the
BELIEVED one from a calibration file, announces it on /calibration/hand_eye, and a refused file stops the
node at start-up with the reason (exit code 2)."""
from __future__ import annotations

import json

import numpy as np
import yaml
from geometry_msgs.msg import PoseStamped
from sensor_msgs.msg import Image
from std_msgs.msg import String
from std_srvs.srv import Trigger
from stud_welding_msgs.msg import ArmState

from rosproc import REPO, ros2_run, wait_for
from stud_common import ros_io
from stud_common.rotations import matrix_to_quaternion, rpy_to_matrix
from stud_perception import image_io
from stud_perception.camera_node import camera_pose_from_tool
from stud_perception.hand_eye_solvers import rotation_angle_deg
from stud_perception.scene_cameras import view_camera
from stud_perception.scene_file import load_scene
from stud_perception.scene_render import render

SCENE_FILE = REPO / "src" / "stud_perception" / "config" / "dome_scene.json"
FILE_XYZ, FILE_RPY = [0.0561, -0.0041, -0.0968], [0.9, -0.45, 0.85]
TRUE_XYZ, TRUE_RPY = [0.056, -0.004, -0.097], [1.0, -0.5, 0.8]


def calibration_file(path, accepted=True, used=16):
    q = matrix_to_quaternion(rpy_to_matrix(*np.radians(FILE_RPY)))
    path.write_text(yaml.safe_dump({
        "format": "stud_welding/hand_eye 1", "date": "2025-06-02T09:14:05+02:00", "accepted": accepted,
        "hand_eye": {"frame": "weld_tool", "child_frame": "camera_color_optical_frame", "xyz_m": FILE_XYZ,
                     "rpy_deg": FILE_RPY, "quaternion_xyzw": [float(v) for v in q]},
        "residuals": {"position_rms_mm": 0.07, "position_max_mm": 0.15, "rotation_rms_deg": 0.06,
                      "rotation_max_deg": 0.12, "reprojection_rms_px": 0.01},
        "poses": {"used": used, "rotation_spread_deg": [60.0, 47.0, 38.0]},
        "problems": [] if accepted else ["rotations about one axis only"]}))
    return path


def test_sim_camera_renders_with_the_true_hand_eye_and_poses_with_the_calibration(ros_node, procs, tmp_path):
    cal = calibration_file(tmp_path / "hand_eye.yaml")
    params = {"scene_file": str(SCENE_FILE), "depth_noise_m": 0.0, "pose_source": "arm", "hand_eye_file": str(cal),
              "hand_eye_xyz_m": [0.05, 0.0, -0.10], "true_hand_eye_xyz_m": TRUE_XYZ,
              "true_hand_eye_rpy_deg": TRUE_RPY, "seed": 3}
    procs.append(ros2_run("stud_perception", "camera", tmp_path / "camera.log", params))
    calib, poses, colors = [], [], []
    ros_node.create_subscription(String, "/calibration/hand_eye", calib.append, ros_io.LATCHED_QOS)
    ros_node.create_subscription(PoseStamped, "/camera/pose", poses.append, ros_io.SENSOR_QOS)
    ros_node.create_subscription(Image, "/camera/color/image_raw", colors.append, ros_io.SENSOR_QOS)
    state_pub = ros_node.create_publisher(ArmState, "/arm/state", ros_io.RESULT_QOS)
    wait_for(lambda: calib, 30, spin=ros_node.spin, what=f"/calibration/hand_eye\n{procs[0].output()}")
    announced = json.loads(calib[-1].data)
    assert announced["source"] == "file" and announced["path"] == str(cal.resolve())
    assert announced["date"] == "2025-06-02T09:14:05+02:00" and announced["position_rms_mm"] == 0.07
    assert np.allclose(announced["xyz_m"], FILE_XYZ) and announced["node"] == "camera"

    # the tool straight down over the board, the camera riding on it
    tool_R = rpy_to_matrix(np.pi, 0.0, np.pi / 2)
    tool_t = np.array([0.30, -0.17, 0.40])
    state = ArmState(connected=True)
    state.tool_pose = ros_io.rt_to_pose(tool_R, tool_t)
    trigger = ros_node.create_client(Trigger, "/camera/trigger")
    wait_for(trigger.service_is_ready, 30, spin=ros_node.spin, what="/camera/trigger")

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
    R_file, t_file = camera_pose_from_tool(tool_R, tool_t, FILE_XYZ, FILE_RPY)
    assert np.linalg.norm(t - t_file) < 1e-9 and rotation_angle_deg(R, R_file) < 1e-6  # believed: the file
    R_true, t_true = camera_pose_from_tool(tool_R, tool_t, TRUE_XYZ, TRUE_RPY)
    template = view_camera((0.0, 0.0, 0.0), distance_m=1.0, yaw_rad=np.radians(90.0))
    truth = render(load_scene(SCENE_FILE), template.with_pose(R_true, t_true), seed=3, depth_noise_m=0.0)
    believed = render(load_scene(SCENE_FILE), template.with_pose(R_file, t_file), seed=3, depth_noise_m=0.0)
    image = image_io.color_to_bgr(colors[-1])
    assert np.array_equal(image, truth.color_bgr)  # rendered with the true hand-eye ...
    assert not np.array_equal(image, believed.color_bgr)  # ... not with the one /camera/pose says


def test_a_refused_calibration_file_stops_the_node_with_the_reason(procs, tmp_path):
    cal = calibration_file(tmp_path / "hand_eye.yaml", accepted=False)
    procs.append(ros2_run("stud_perception", "camera", tmp_path / "camera.log",
                          {"pose_source": "arm", "hand_eye_file": str(cal)}))
    wait_for(lambda: procs[0].popen.poll() is not None, 30, what="the camera node to refuse the file")
    assert procs[0].popen.returncode == 2
    out = procs[0].output()
    assert (f"hand_eye_file: {cal}: accepted is False: the calibration was refused "
            "(rotations about one axis only)") in out
    few = calibration_file(tmp_path / "few.yaml", used=8)
    procs.append(ros2_run("rm65_driver", "driver", tmp_path / "driver.log", {"hand_eye_file": str(few)}))
    wait_for(lambda: procs[1].popen.poll() is not None, 30, what="the driver to refuse the file")
    assert procs[1].popen.returncode == 2
    assert "refused: poses.used 8: too few poses, need at least 12" in procs[1].output()
