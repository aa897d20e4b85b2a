"""Re-pose a recording's camera poses with the hand-eye in use: `ros2 run stud_perception pose_rebase`.

A recorded bag's ``/camera/pose`` was made with the hand-eye believed when it was recorded. Played
with ``ros2 bag play --remap /camera/pose:=/camera/pose_recorded``, this node turns each recorded pose
back into the tool pose it came from and poses the camera again with the hand-eye in use
(``hand_eye_file``, or the typed ``hand_eye_xyz_m`` / ``hand_eye_rpy_deg``), on ``/camera/pose``
with the recorded stamp, so the images and the new pose still meet by stamp:

    T_world_cam = T_world_cam_recorded · inv(recorded hand-eye) · hand-eye in use

``recorded_hand_eye_xyz_m`` / ``recorded_hand_eye_rpy_deg`` say which hand-eye the recording used
(the cell's typed values by default). With both the same, the poses pass unchanged. The hand-eye in
use is published on ``/calibration/hand_eye`` like every node that poses the camera.
"""
from __future__ import annotations

from geometry_msgs.msg import PoseStamped
from rclpy.node import Node

from stud_common import hand_eye_ros, names, ros_io
from stud_common.ros_io import Param, three_numbers
from stud_common.rotations import transform, transform_xyz_rpy
from stud_perception.hand_eye import rebase_camera_pose

PARAMS = [
    ros_io.SENSOR_QOS_PARAM,
    Param("input_topic", names.CAMERA_POSE_RECORDED, "the recorded camera poses (the bag's /camera/pose, remapped)",
          read_only=True),
    Param("output_topic", names.CAMERA_POSE, "the camera poses with the hand-eye in use", read_only=True),
    Param("recorded_hand_eye_xyz_m", [0.0, 0.0, 0.0], "optical frame origin in the weld-tool frame the recording "
          "was made with [m]", validate=three_numbers("recorded_hand_eye_xyz_m"), read_only=True),
    Param("recorded_hand_eye_rpy_deg", [0.0, 0.0, 0.0], "optical frame orientation in the weld-tool frame the "
          "recording was made with, roll-pitch-yaw [deg]", validate=three_numbers("recorded_hand_eye_rpy_deg"),
          read_only=True),
    *hand_eye_ros.PARAMS,
]


class PoseRebaseNode(Node):
    def __init__(self) -> None:
        super().__init__("pose_rebase")
        self.p = ros_io.declare_params(self, PARAMS)
        self.in_use = hand_eye_ros.hand_eye_in_use(self, self.p)
        self.calibration = hand_eye_ros.CalibrationTopic(self, self.in_use)
        self.T_recorded = transform_xyz_rpy(self.p["recorded_hand_eye_xyz_m"], self.p["recorded_hand_eye_rpy_deg"])
        self.T_in_use = self.in_use.T_tool_cam
        self.pub = self.create_publisher(PoseStamped, self.p["output_topic"], ros_io.CAMERA_PUB_QOS)
        self.create_subscription(PoseStamped, self.p["input_topic"], self._on_pose,
                                 ros_io.sensor_qos(self.p["sensor_qos"]))
        self.count = 0
        self.diag = ros_io.Diagnostics(self)
        self.diag.set(self.diag.OK, f"waiting for {self.p['input_topic']}")
        self.create_timer(1.0, self.diag.publish)
        self.get_logger().info(f"re-posing {self.p['input_topic']} -> {self.p['output_topic']} with the hand-eye "
                               f"from {self.in_use.source} (recorded with xyz {self.p['recorded_hand_eye_xyz_m']} m, "
                               f"rpy {self.p['recorded_hand_eye_rpy_deg']} deg)")

    def _on_pose(self, msg: PoseStamped) -> None:
        R, t = ros_io.pose_to_rt(msg.pose)
        T = rebase_camera_pose(transform(R, t), self.T_recorded, self.T_in_use)
        out = PoseStamped(header=msg.header, pose=ros_io.rt_to_pose(T[:3, :3], T[:3, 3]))
        self.pub.publish(out)
        self.count += 1
        self.diag.set(self.diag.OK, f"{self.count} pose(s) re-posed")


def main(args=None) -> int:
    """`ros2 run stud_perception pose_rebase`: spin until Ctrl-C; the process exit code."""
    return ros_io.spin_node(PoseRebaseNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
