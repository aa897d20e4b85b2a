"""Robot state publisher: `ros2 run rm65_driver state_publisher` (robot_state_publisher is not in the wheels).

Publishes the arm's URDF latched on ``/robot_description`` (std_msgs/String) and its frames as
robot_state_publisher does: the fixed joints once on ``/tf_static`` (``world -> base_link``,
``link6 -> rm65_flange``, ``rm65_flange -> weld_tool``, ``weld_tool -> camera_color_optical_frame``
from the hand-eye: ``hand_eye_file`` when given, as every node that poses the camera), the moving
joints on ``/tf`` for every ``/joint_states`` message, stamped with it.
On a rail (``rail_length_m`` > 0, the driver's value) ``world -> carriage`` is the moving
``rail_joint`` (the driver's ``/joint_states``) and ``carriage -> base_link`` a static frame
(``rail_mount_xyz_m``), so TF carries world -> carriage -> base_link.

It is also the cell's one static broadcaster for ``world -> drawing``: from the latest valid
``/registration/result`` (origin at mark O, on the height measured for it). One node owning
``/tf_static`` means its latched message always holds every static frame of the cell, so
``ros2 topic echo --once /tf_static`` shows them all (``registration_topic:=''`` turns that off).

The URDF is :func:`rm65_driver.kinematics.robot_description.rm65_urdf` for the parameters below, or the file
``robot_description_file`` (then the parameters describing the arm are not used). The math is
:mod:`rm65_driver.kinematics.urdf_model` (pure, tested against the kinematics module).
"""
from __future__ import annotations

import math
from pathlib import Path

from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from stud_welding_msgs.msg import Registration

from rm65_driver.kinematics.rm65 import D6_BY_VARIANT
from rm65_driver.kinematics.robot_description import RM65Description, rm65_urdf
from rm65_driver.kinematics.urdf_model import RobotModel, UrdfError, parse_urdf
from stud_common import frames, hand_eye_ros, names, ros_io, tf_io
from stud_common.ros_io import Param, three_numbers

PARAMS = [
    Param("robot_description_file", "", "URDF file to publish instead of the generated RM-65 model "
          "(empty: generate it from the parameters below)", read_only=True),
    Param("arm_variant", "RM65-B", "arm variant (its flange distance d6)", choices=tuple(D6_BY_VARIANT),
          read_only=True),
    Param("tool_offset_m", 0.15, "flange -> weld-gun tip along flange z (weld_tool) [m]; as the driver's",
          min=0.0, max=0.5, read_only=True),
    *hand_eye_ros.PARAMS,  # weld_tool -> camera_color_optical_frame: the typed hand-eye or hand_eye_file
    Param("publish_camera_frame", True, "include weld_tool -> camera_color_optical_frame (false when the camera "
          "driver publishes its own frames: a frame has one parent)", read_only=True),
    Param("rail_length_m", 0.0, "the rail's travel [m], as the driver's: world -> carriage is then the prismatic "
          "rail_joint; 0: no rail, world -> base_link fixed", min=0.0, max=100.0, read_only=True),
    Param("rail_mount_xyz_m", [0.0, 0.0, 0.0], "carriage -> base_link [m], as the driver's",
          validate=three_numbers("rail_mount_xyz_m"), read_only=True),
    Param("rail_max_speed_m_s", 0.5, "rail_joint's velocity limit in the model [m/s], as the driver's",
          min=0.001, max=10.0, read_only=True),
    Param("registration_topic", names.REGISTRATION_RESULT, "publish world -> drawing from this topic's latest valid "
          "registration (empty: do not)", read_only=True),
]


class StatePublisherNode(Node):
    def __init__(self) -> None:
        super().__init__("state_publisher")
        self.p = ros_io.declare_params(self, PARAMS)
        # the same hand-eye as the nodes that pose the camera: a calibration file when one is given
        self.hand_eye = hand_eye_ros.hand_eye_in_use(self, self.p)
        self.urdf_text = self._load_description()
        try:
            self.model: RobotModel = parse_urdf(self.urdf_text)
        except UrdfError as exc:
            self.get_logger().fatal(f"robot description unusable: {exc}")
            raise SystemExit(2) from None
        self._moving = {j.name: j for j in self.model.moving_joints}
        self._missing_logged: frozenset[str] = frozenset()
        self._joint_states = 0

        # The description and the static frames are latched: a viewer started later gets them.
        self.pub_description = self.create_publisher(String, names.ROBOT_DESCRIPTION, ros_io.LATCHED_QOS)
        self.pub_description.publish(String(data=self.urdf_text))
        self.calibration = hand_eye_ros.CalibrationTopic(self, self.hand_eye)
        self.static = tf_io.StaticFrames(self)
        self.moving = tf_io.MovingFrames(self)
        stamp = self.get_clock().now().to_msg()
        self.static.set([tf_io.transform_stamped(j.parent, j.child, j.origin, stamp) for j in self.model.fixed_joints])
        # /joint_states as the driver publishes it (reliable, depth 10); a frame is only as old as its message.
        self.create_subscription(JointState, names.JOINT_STATES, self._on_joints, 10)
        if self.p["registration_topic"]:
            self.create_subscription(Registration, self.p["registration_topic"], self._on_registration,
                                     ros_io.LATCHED_QOS)
        self.diag = ros_io.Diagnostics(self)
        # Not a warning: a cell without an arm (replay) never sends joints, and the model and static
        # frames are out already.
        self.diag.set(self.diag.OK, "model and static frames published; no /joint_states yet")
        self.create_timer(1.0, self.diag.publish)
        self.get_logger().info(f"robot '{self.model.name}': {len(self.model.links)} links, "
                               f"{len(self._moving)} moving joints; static frames "
                               f"{', '.join(self.static.children)}")

    def _load_description(self) -> str:
        path = self.p["robot_description_file"]
        if path:
            try:
                return Path(path).expanduser().read_text()
            except OSError as exc:
                self.get_logger().fatal(f"cannot read robot_description_file '{path}': {exc.strerror or exc}")
                raise SystemExit(2) from None
        return rm65_urdf(RM65Description(
            variant=self.p["arm_variant"], tool_offset_m=self.p["tool_offset_m"],
            hand_eye_xyz_m=self.hand_eye.xyz_m, hand_eye_rpy_deg=self.hand_eye.rpy_deg,
            include_camera=self.p["publish_camera_frame"], rail_length_m=self.p["rail_length_m"],
            rail_mount_xyz_m=tuple(self.p["rail_mount_xyz_m"]), rail_max_speed_m_s=self.p["rail_max_speed_m_s"]))

    def _on_joints(self, msg: JointState) -> None:
        stamp = msg.header.stamp if (msg.header.stamp.sec or msg.header.stamp.nanosec) \
            else self.get_clock().now().to_msg()
        transforms = []
        for name, q in zip(msg.name, msg.position):
            joint = self._moving.get(name)
            if joint is not None and math.isfinite(q):
                transforms.append(tf_io.transform_stamped(joint.parent, joint.child, joint.transform(q), stamp))
        self.moving.publish(transforms)
        self._joint_states += 1
        missing = frozenset(self._moving) - set(msg.name)
        if missing != self._missing_logged:
            if missing:
                self.get_logger().warn(f"/joint_states lacks {sorted(missing)}: their links have no TF")
            self._missing_logged = missing
        level = self.diag.WARN if missing else self.diag.OK
        self.diag.set(level, f"publishing {len(transforms)} moving frames" +
                      (f"; missing joints {sorted(missing)}" if missing else ""), joint_states=self._joint_states)

    def _on_registration(self, msg: Registration) -> None:
        if not msg.valid:
            return  # keep the last valid drawing frame
        try:
            T = frames.drawing_in_world(msg.m_local2world, msg.mark_o.z)
        except ValueError as exc:
            self.get_logger().warn(f"no drawing frame from {self.p['registration_topic']}: {exc}",
                                   throttle_duration_sec=10.0)
            return
        self.static.set([tf_io.transform_stamped(frames.WORLD, frames.DRAWING, T, msg.header.stamp)])
        self.get_logger().info(f"world -> drawing: origin {[round(v, 4) for v in T[:3, 3]]} m, "
                               f"yaw {math.degrees(math.atan2(T[1, 0], T[0, 0])):.2f} deg")


def main(args=None) -> int:
    """`ros2 run rm65_driver state_publisher`: spin until Ctrl-C; the process exit code."""
    return ros_io.spin_node(StatePublisherNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
