"""Shot node: `ros2 run stud_perception shot` — a real, streaming RGB-D driver as a triggered camera.

Vendor drivers (Percipio camport_ros2, realsense-ros, ...) stream colour, registered depth and
camera info continuously; our graph wants one synchronised shot after the arm has stopped, with
the camera pose at that moment (the paper's "move, then take one overhead shot"). On
``/camera/trigger`` (std_srvs/Trigger) this node waits for the first complete frame set (colour,
depth, info matched by stamp within ``sync_slop_s``) stamped at least ``settle_s`` after the
request, and republishes it on ``/camera/color/image_raw``, ``/camera/depth/image_raw``,
``/camera/color/camera_info`` with ``/camera/pose`` = the last ``/arm/state`` tool pose x the
hand-eye transform (``hand_eye_*`` or ``hand_eye_file``), all with the frame's stamp. Point the
``input_*_topic`` parameters at the driver's topics (depth must be registered/aligned to colour).
``/camera/trigger_inspection`` takes a post-weld inspection shot the same way and publishes it under
``/camera/inspection/`` (stud_common.names.shot_topics), where the matcher does not look.
"""
from __future__ import annotations

import functools
import threading

from geometry_msgs.msg import PoseStamped
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image
from std_srvs.srv import Trigger
from stud_welding_msgs.msg import ArmState

from stud_common import hand_eye_ros, names, ros_io
from stud_common.ros_io import Param
from stud_perception.camera_node import OPTICAL_FRAME, camera_pose_from_tool

PARAMS = [
    Param("input_color_topic", "/camera_driver/color/image_raw", "the driver's colour image topic"),
    Param("input_depth_topic", "/camera_driver/aligned_depth_to_color/image_raw",
          "the driver's depth topic, registered to colour (16UC1 mm or 32FC1 m)"),
    Param("input_info_topic", "/camera_driver/color/camera_info", "the driver's colour camera info"),
    Param("sync_slop_s", 0.03, "colour/depth/info stamps closer than this are one frame [s]", min=0.0, max=1.0),
    Param("settle_s", 0.1, "use only frames stamped this long after the trigger (arm vibration) [s]",
          min=0.0, max=10.0),
    Param("timeout_s", 5.0, "give up a trigger without a frame after this [s]", min=0.1, max=60.0),
    Param("max_pose_age_s", 0.5, "refuse the shot if the last /arm/state is older than this at the frame [s]",
          min=0.01, max=60.0),
    *hand_eye_ros.PARAMS,  # hand_eye_xyz_m / hand_eye_rpy_deg, or hand_eye_file
]


class ShotNode(Node):
    def __init__(self) -> None:
        super().__init__("shot")
        self.p = ros_io.declare_params(self, PARAMS)
        group = ReentrantCallbackGroup()
        q = ros_io.CAMERA_PUB_QOS
        types = {"color": Image, "depth": Image, "info": CameraInfo, "pose": PoseStamped}
        # per kind of shot (False: a view to match, True: a post-weld inspection shot), its four publishers
        self.pubs = {inspection: {k: self.create_publisher(types[k], topic, q)
                                  for k, topic in names.shot_topics(inspection).items()}
                     for inspection in (False, True)}
        self._arm: tuple[int, object] | None = None  # (receive time ns, tool pose)
        self._wanted_after_ns: int | None = None
        self._frame: dict | None = None
        self._got = threading.Event()
        self._lock = threading.Lock()
        self.sync = ros_io.StampSync(["color", "depth", "info"], self._on_frame,
                                     slop_ns=int(self.p["sync_slop_s"] * 1e9))
        for name, typ in (("color", Image), ("depth", Image), ("info", CameraInfo)):
            self.create_subscription(typ, self.p[f"input_{name}_topic"], functools.partial(self._add, name),
                                     ros_io.SENSOR_QOS, callback_group=group)
        self.create_subscription(ArmState, names.ARM_STATE, self._on_arm, ros_io.RESULT_QOS, callback_group=group)
        self.create_service(Trigger, names.CAMERA_TRIGGER, self._on_trigger, callback_group=group)
        self.create_service(Trigger, names.CAMERA_TRIGGER_INSPECTION,
                            lambda req, resp: self._on_trigger(req, resp, inspection=True), callback_group=group)
        self.diag = ros_io.Diagnostics(self)
        self.hand_eye = hand_eye_ros.hand_eye_in_use(self, self.p)
        self.calibration_topic = hand_eye_ros.CalibrationTopic(self, self.hand_eye)
        self.create_timer(1.0, self.diag.publish, callback_group=group)
        self.get_logger().info(f"shots from {self.p['input_color_topic']}, {self.p['input_depth_topic']} on "
                               "/camera/trigger")

    def _add(self, name: str, msg) -> None:
        with self._lock:
            self.sync.add(name, msg)

    def _on_arm(self, msg: ArmState) -> None:
        self._arm = (self.get_clock().now().nanoseconds, msg.tool_pose)

    def _on_frame(self, frame: dict) -> None:
        after = self._wanted_after_ns
        if after is None or ros_io.stamp_to_ns(frame["depth"].header.stamp) < after or self._got.is_set():
            return
        self._frame = frame
        self._got.set()

    def _on_trigger(self, _req, resp, inspection: bool = False):
        self._got.clear()
        self._frame = None
        self._wanted_after_ns = self.get_clock().now().nanoseconds + int(self.p["settle_s"] * 1e9)
        ok = self._got.wait(self.p["settle_s"] + self.p["timeout_s"])
        self._wanted_after_ns = None
        if not ok or self._frame is None:
            resp.success, resp.message = False, (f"no synchronised colour/depth/info frame within "
                                                 f"{self.p['timeout_s']:.1f} s (is the driver streaming?)")
            self.diag.set(self.diag.WARN, resp.message)
            return resp
        frame = self._frame
        stamp = frame["depth"].header.stamp
        if self._arm is None or ros_io.stamp_to_ns(stamp) - self._arm[0] > self.p["max_pose_age_s"] * 1e9:
            resp.success, resp.message = False, "no fresh /arm/state for the camera pose"
            return resp
        R, t = camera_pose_from_tool(*ros_io.pose_to_rt(self._arm[1]), self.hand_eye.xyz_m, self.hand_eye.rpy_deg)
        pubs = self.pubs[inspection]
        for key in ("color", "depth", "info"):
            msg = frame[key]
            msg.header.stamp = stamp  # one stamp for the whole shot
            msg.header.frame_id = msg.header.frame_id or OPTICAL_FRAME
            pubs[key].publish(msg)
        pose = PoseStamped()
        pose.header.stamp, pose.header.frame_id = stamp, "world"
        pose.pose = ros_io.rt_to_pose(R, t)
        pubs["pose"].publish(pose)
        resp.success, resp.message = True, f"shot at {stamp.sec}.{stamp.nanosec:09d}"
        self.diag.set(self.diag.OK, resp.message)
        return resp


def main(args=None) -> int:
    """`ros2 run stud_perception shot`: spin until Ctrl-C; the process exit code."""
    return ros_io.spin_node(ShotNode, args, multithreaded=True)


if __name__ == "__main__":
    raise SystemExit(main())
