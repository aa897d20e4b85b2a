"""Camera node: `ros2 run stud_perception camera` (simulated structured-light RGB-D camera).

Publishes one triggered, synchronised RGB-D shot, as the paper takes one overhead shot
after the arm has moved: ``/camera/color/image_raw`` (bgr8), ``/camera/depth/image_raw``
(16UC1 mm, registered to colour), ``/camera/color/camera_info`` and ``/camera/pose`` (the
optical frame in ``world``), all with one stamp. Shots come on ``/camera/trigger``
(std_srvs/Trigger) or at ``rate_hz``. A post-weld inspection shot, on
``/camera/trigger_inspection``, goes out on the same four topics under ``/camera/inspection/``
(stud_common.names.shot_topics): the inspector takes it, the matcher never plans welds on it.

The camera pose comes from parameters, or from the arm (``pose_source:=arm``): the tool
pose in ``/arm/state`` times the hand-eye transform (tool -> optical frame). Like a real cell,
the sim has two of those: the image is rendered with the TRUE one (``true_hand_eye_*``, by
default the believed one), ``/camera/pose`` carries the BELIEVED one (``hand_eye_*``, or
``hand_eye_file``), which is also published on ``/calibration/hand_eye`` (docs/CALIBRATION.md).
On a rail the same holds for the carriage: ``/arm/state`` places the tool on the straight, exact rail
the cell believes in (its ``rail_position_m``, the encoder's), the image is rendered where the arm truly
is, with the rail's TRUE deviation (``true_rail_*``, sim-only: scale, offset, yaw per metre;
:func:`stud_common.frames.true_world_correction`); the welded studs of ``/arm/welds`` stand where they
truly are the same way.

With a real camera, run the vendor's ROS 2 driver instead and remap its topics onto the
four above (docs/LAUNCH.md, *Hardware mode: the camera*); nothing downstream depends on this node.
"""
from __future__ import annotations

import math
import threading

import numpy as np
from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image
from std_srvs.srv import Trigger

from stud_common import hand_eye_ros, names, ros_io
from stud_common.frames import RailDeviation, true_world_correction
from stud_common.hand_eye_in_use import camera_in_world
from stud_common.ros_io import Param, three_numbers
from stud_common.rotations import transform, transform_xyz_rpy
from stud_perception import image_io
from stud_perception.camera_model import CameraModel
from stud_perception.rectify import FISHEYE_MODELS, PINHOLE_MODELS, has_distortion
from stud_perception.scene import demo_dome_scene
from stud_perception.scene_cameras import (
    DEMO_FOV_DISTANCE_M,
    DEMO_FOV_WIDTH_M,
    DEMO_IMAGE_SIZE,
    distort_view,
    view_camera,
)
from stud_perception.scene_file import load_scene
from stud_perception.scene_render import render
from stud_perception.scene_sensor import MAX_DEPTH_NOISE_M
from stud_perception.scene_solids import SceneError
from stud_perception.welded_studs import DefectsByPosition, StudCylinder, welded_stud

OPTICAL_FRAME = "camera_color_optical_frame"


def _distortion_d(d) -> str | None:
    lengths = (4, 5, 8, 12, 14)
    return None if len(d) in lengths else f"distortion_d needs {' or '.join(map(str, lengths))} numbers, got {list(d)}"


PARAMS = [
    Param("source", "sim", "where frames come from; only 'sim' here (real cameras: run the vendor driver)",
          choices=("sim",), read_only=True),
    Param("scene_file", "", "scene description (.json/.yaml, docs/SCENES.md); "
          "empty: the bundled dome"),
    Param("image_width", DEMO_IMAGE_SIZE[0], "image width [px]", min=16, max=8192),
    Param("image_height", DEMO_IMAGE_SIZE[1], "image height [px]", min=16, max=8192),
    Param("fov_width_m", DEMO_FOV_WIDTH_M, "field-of-view width at fov_distance_m [m]", min=0.01, max=10.0),
    Param("fov_distance_m", DEMO_FOV_DISTANCE_M, "distance at which fov_width_m is spanned [m]", min=0.05, max=10.0),
    Param("depth_encoding", "16UC1", "depth image encoding: '16UC1' (mm, 0 = none; what RGB-D drivers send) or "
          "'32FC1' (m, NaN = none; not quantised)", choices=("16UC1", "32FC1")),
    Param("depth_noise_m", 0.0005, "std of Gaussian depth noise [m] (at most the cell's working envelope: beyond "
          "it the hand-eye cannot be verified to 0.5 mm / 0.15 deg)", min=0.0, max=MAX_DEPTH_NOISE_M),
    Param("depth_noise_correlation_px", 1.5, "how far the depth noise is correlated across pixels, as a real "
          "structured-light camera's is (sigma of a Gaussian blur of the noise; 0: independent pixels) [px]",
          min=0.0, max=20.0),
    Param("hole_fraction", 0.0, "fraction of depth pixels lost in blobs", min=0.0, max=0.9),
    Param("mark_depth_dropout", False, "dark paint returns no depth (marks and stud marks lose depth)"),
    Param("render_welded_studs", True, "show the studs the arm welds (/arm/welds) in later shots, in their weld "
          "collars, with the scene's weld_defects (each on the weld nearest to its scene stud), its stud_length_mm, "
          "stud_diameter_mm, collar_height_mm and collar_width_mm (for the post-weld inspection)"),
    Param("seed", 0, "random seed of noise and holes (incremented per shot)", min=0, max=2**31 - 1),
    Param("rate_hz", 0.0, "shots per second; 0: only on /camera/trigger", min=0.0, max=30.0),
    Param("pose_source", "param", "'param': camera_xyz_m/yaw/tilt; 'arm': /arm/state tool pose x hand-eye",
          choices=("param", "arm")),
    Param("camera_xyz_m", [0.31, -0.03, 0.60], "optical centre in world [m] (pose_source=param)",
          validate=three_numbers("camera_xyz_m")),
    Param("camera_yaw_deg", 90.0, "image rotation about the optical axis [deg]", min=-360.0, max=360.0),
    Param("camera_tilt_deg", 0.0, "viewing direction tilt from straight down [deg]", min=0.0, max=60.0),
    Param("camera_tilt_azimuth_deg", 0.0, "azimuth the camera leans toward [deg]", min=-360.0, max=360.0),
    Param("max_pose_age_s", 1.0, "pose_source=arm: refuse a shot when the last /arm/state is older [s]",
          min=0.01, max=60.0),
    # pose_source=arm: the BELIEVED hand-eye (typed, or hand_eye_file) poses /camera/pose, as on a real
    # cell; the image is rendered with the TRUE one, which a real cell never knows.
    *hand_eye_ros.PARAMS,
    Param("true_hand_eye_xyz_m", [math.nan] * 3, "sim only: the camera's TRUE optical frame origin in the tool "
          "frame, used to render [m]; NaN: the believed hand-eye", validate=three_numbers("true_hand_eye_xyz_m"),
          nan_means="the believed hand-eye"),
    Param("true_hand_eye_rpy_deg", [math.nan] * 3, "sim only: the camera's TRUE orientation in the tool frame, "
          "roll-pitch-yaw, used to render [deg]; NaN: the believed hand-eye",
          validate=three_numbers("true_hand_eye_rpy_deg"),
          nan_means="the believed hand-eye"),
    Param("true_rail_scale_ppm", 0.0, "sim only, with a rail: the carriage really travels (1 + this x 1e-6) m per "
          "metre the encoder counts, used to render [ppm]", min=-1e5, max=1e5),
    Param("true_rail_offset_m", 0.0, "sim only, with a rail: where the encoder's zero really is along the rail, "
          "used to render [m]", min=-1.0, max=1.0),
    Param("true_rail_yaw_urad_per_m", 0.0, "sim only, with a rail: the carriage's heading turns this much per metre "
          "(a rail bent in plan), used to render [urad/m]", min=-1e5, max=1e5),
    Param("distortion_model", "plumb_bob", "lens distortion model of the raw images (CameraInfo distortion_model)",
          choices=PINHOLE_MODELS + FISHEYE_MODELS),
    Param("distortion_d", [0.0, 0.0, 0.0, 0.0, 0.0], "lens distortion coefficients of the raw images, OpenCV "
          "order (CameraInfo D; zeros: a pinhole camera)", validate=_distortion_d),
]


def camera_pose_from_tool(R_wt: np.ndarray, t_wt: np.ndarray, hand_eye_xyz_m, hand_eye_rpy_deg):
    """Optical frame in world (R, t) from the tool pose in world and a hand-eye (xyz m, rpy deg)."""
    T = camera_in_world(transform(R_wt, t_wt), transform_xyz_rpy(hand_eye_xyz_m, hand_eye_rpy_deg))
    return T[:3, :3], T[:3, 3]


def depth_image(view, encoding: str, noise_m: float, seed: int) -> np.ndarray:
    """The depth image of a rendered view: 16UC1 mm as rendered, or 32FC1 metres (the exact depth
    with the same holes and Gaussian noise of ``noise_m``, without mm quantisation)."""
    if encoding == "16UC1":
        return view.depth_mm
    depth = view.depth_exact_m.copy()
    if noise_m > 0:
        depth += np.random.default_rng(seed).normal(0.0, noise_m, depth.shape)
    depth[view.depth_mm == 0] = np.nan
    return depth.astype(np.float32)


def shot_messages(view, depth_encoding: str, stamp, noise_m: float = 0.0, seed: int = 0,
                  pose_camera: CameraModel | None = None) -> dict:
    """The four messages of one shot (colour, depth, camera info, optical-frame pose), one stamp.
    ``/camera/pose`` is ``pose_camera``'s pose (the believed one) when given, else the rendered one."""
    camera = view.camera
    posed = pose_camera if pose_camera is not None else camera
    pose = PoseStamped()
    pose.header.stamp, pose.header.frame_id = stamp, "world"
    pose.pose = ros_io.rt_to_pose(posed.R_wc, posed.t_wc)
    return {
        "color": image_io.numpy_to_image(view.color_bgr, "bgr8", stamp, OPTICAL_FRAME),
        "depth": image_io.numpy_to_image(depth_image(view, depth_encoding, noise_m, seed), depth_encoding, stamp,
                                       OPTICAL_FRAME),
        "info": image_io.camera_info_from_model(camera, stamp, OPTICAL_FRAME, view.distortion_d, view.distortion_model),
        "pose": pose,
    }


class CameraNode(Node):
    def __init__(self) -> None:
        super().__init__("camera")
        self.p = ros_io.declare_params(self, PARAMS)
        try:
            self.scene = load_scene(self.p["scene_file"]) if self.p["scene_file"] else demo_dome_scene()
        except (OSError, SceneError) as exc:
            self.get_logger().fatal(f"cannot load scene_file '{self.p['scene_file']}': {exc}")
            raise SystemExit(2) from None
        q = ros_io.CAMERA_PUB_QOS
        types = {"color": Image, "depth": Image, "info": CameraInfo, "pose": PoseStamped}
        # per kind of shot (False: a view to match, True: a post-weld inspection shot), its four publishers
        self.pubs = {inspection: {k: self.create_publisher(types[k], topic, q)
                                  for k, topic in names.shot_topics(inspection).items()}
                     for inspection in (False, True)}
        self.create_service(Trigger, names.CAMERA_TRIGGER, self._on_trigger)
        self.create_service(Trigger, names.CAMERA_TRIGGER_INSPECTION, self._on_trigger_inspection)
        self.diag = ros_io.Diagnostics(self, hardware_id="sim_rgbd_camera")
        self.hand_eye = hand_eye_ros.hand_eye_in_use(self, self.p)  # believed: poses /camera/pose
        self.true_hand_eye = (tuple(v if math.isfinite(v) else b for v, b in
                                    zip(self.p["true_hand_eye_xyz_m"], self.hand_eye.xyz_m)),
                              tuple(v if math.isfinite(v) else b for v, b in
                                    zip(self.p["true_hand_eye_rpy_deg"], self.hand_eye.rpy_deg)))
        self.rail_deviation = RailDeviation(self.p["true_rail_scale_ppm"], self.p["true_rail_offset_m"],
                                            self.p["true_rail_yaw_urad_per_m"])
        self._rail_m = 0.0  # the carriage in the last /arm/state (the encoder's, m)
        if self.p["pose_source"] == "arm":
            self.calibration_topic = hand_eye_ros.CalibrationTopic(self, self.hand_eye)
        self.create_timer(1.0, self.diag.publish)
        self._arm_tool_pose: tuple[np.ndarray, np.ndarray] | None = None
        self._shots = 0
        self._lock = threading.Lock()
        if self.p["pose_source"] == "arm":
            from stud_welding_msgs.msg import ArmState

            self.create_subscription(ArmState, names.ARM_STATE, self._on_arm_state, ros_io.RESULT_QOS)
        # Studs the arm welds stand in later shots, where the arm welded them (with the defect of the
        # scene stud nearest to the weld, whatever either calls it): what a post-weld inspection sees.
        self._welded: dict[str, StudCylinder] = {}
        self._scene_stud_of: dict[str, str] = {}  # weld's stud id -> the scene stud it welded
        self._defects = DefectsByPosition(self.scene.studs_world_xy_m, self.scene.stud_ids, self.scene.weld_defects)
        self._told_not_welded: tuple[str, ...] = ()
        if self.p["render_welded_studs"]:
            from stud_welding_msgs.msg import WeldRecord

            welds_qos = QoSProfile(depth=10000, reliability=ReliabilityPolicy.RELIABLE,
                                   durability=DurabilityPolicy.TRANSIENT_LOCAL)
            self.create_subscription(WeldRecord, names.ARM_WELDS, self._on_weld, welds_qos)
        if self.p["rate_hz"] > 0:
            self.create_timer(1.0 / self.p["rate_hz"], self._on_timer)
        self.get_logger().info(
            f"sim camera {self.p['image_width']}x{self.p['image_height']}, scene "
            f"'{self.p['scene_file'] or 'bundled dome'}' ({len(self.scene.stud_ids)} studs), pose from "
            f"{self.p['pose_source']}, {'%.1f Hz' % self.p['rate_hz'] if self.p['rate_hz'] else 'on /camera/trigger'}")

    def _true_pose(self, R: np.ndarray, t: np.ndarray, rail_m: float) -> tuple[np.ndarray, np.ndarray]:
        """A pose the driver reports in world, moved to where the rail's true deviation puts it."""
        if self.rail_deviation == RailDeviation():
            return R, t
        C = true_world_correction(rail_m, self.rail_deviation)
        return C[:3, :3] @ R, C[:3, :3] @ t + C[:3, 3]

    def _on_weld(self, msg) -> None:
        R, t = self._true_pose(*ros_io.pose_to_rt(msg.tool_pose), msg.rail_position_m)
        scene_id, distance_m = self._defects.nearest(t)
        if scene_id is None:
            self.get_logger().warn(f"weld of {msg.stud_id!r} at {np.round(t, 4).tolist()} m "
                                   f"is {distance_m * 1e3:.1f} mm "
                                   f"from the nearest scene stud (more than {self._defects.reach_m * 1e3:.1f} mm, half "
                                   "the scene's stud spacing): shown without a scene defect", throttle_duration_sec=5.0)
        defect = self.scene.weld_defects.get(scene_id) if scene_id is not None else None
        if defect is not None:
            self.get_logger().info(f"weld of {msg.stud_id!r} is scene stud {scene_id!r}: shown with its defect "
                                   f"({', '.join(defect.kinds())})")
        scene = self.scene
        stud = welded_stud(msg.stud_id, t, R[:, 2], defect, length_m=scene.stud_length_m,
                           diameter_m=scene.stud_diameter_m, collar_height_m=scene.collar_height_m,
                           collar_width_m=scene.collar_width_m)
        with self._lock:
            if scene_id is not None:
                self._scene_stud_of[msg.stud_id] = scene_id
            if stud is None:
                self._welded.pop(msg.stud_id, None)
            else:
                self._welded[msg.stud_id] = stud

    def _say_defects_not_welded(self) -> None:
        """Once the arm has welded, log (when it changes) which scene studs with a defect no weld has
        reached yet: a defect that never shows is said, never silently dropped."""
        if not self._scene_stud_of:
            return
        waiting = tuple(self._defects.never_welded(self._scene_stud_of.values()))
        if waiting != self._told_not_welded:
            self._told_not_welded = waiting
            if waiting:
                self.get_logger().warn(f"{len(waiting)} weld defect(s) of the scene not shown: their stud was never "
                                       "welded (so far): " + ", ".join(
                                           f"{sid} ({', '.join(self.scene.weld_defects[sid].kinds())})"
                                           for sid in waiting))

    # -- pose -----------------------------------------------------------------------------------
    def _on_arm_state(self, msg) -> None:
        self._arm_tool_pose = ros_io.pose_to_rt(msg.tool_pose)
        self._rail_m = msg.rail_position_m
        self._arm_pose_time = self.get_clock().now()

    def camera_model(self, true_pose: bool = False) -> CameraModel | None:
        """The camera as posed by the believed hand-eye (``/camera/pose``), or with ``true_pose`` by the
        true one (what is rendered); the same for ``pose_source=param``."""
        p = self.p
        template = view_camera((0.0, 0.0, 0.0), distance_m=1.0, yaw_rad=math.radians(p["camera_yaw_deg"]),
                               tilt_rad=math.radians(p["camera_tilt_deg"]),
                               tilt_azimuth_rad=math.radians(p["camera_tilt_azimuth_deg"]),
                               width=p["image_width"], height=p["image_height"], fov_width_m=p["fov_width_m"],
                               fov_distance_m=p["fov_distance_m"])
        if p["pose_source"] == "param":
            return template.with_pose(template.R_wc, np.asarray(p["camera_xyz_m"], dtype=float))
        if self._arm_tool_pose is None:
            return None
        if (self.get_clock().now() - self._arm_pose_time).nanoseconds * 1e-9 > p["max_pose_age_s"]:
            return None  # a stale pose would put the picture somewhere else than the pose says
        xyz, rpy = self.true_hand_eye if true_pose else (self.hand_eye.xyz_m, self.hand_eye.rpy_deg)
        tool = self._true_pose(*self._arm_tool_pose, self._rail_m) if true_pose else self._arm_tool_pose
        return template.with_pose(*camera_pose_from_tool(*tool, xyz, rpy))

    # -- shots ------------------------------------------------------------------------------------
    def shoot(self, inspection: bool = False) -> tuple[bool, str]:
        """One shot on the matching view's topics, or with ``inspection`` on the inspection shot's."""
        with self._lock:
            camera, believed = self.camera_model(true_pose=True), self.camera_model()
            if camera is None or believed is None:
                self.get_logger().warn("no shot: no fresh /arm/state (pose_source=arm)", throttle_duration_sec=5.0)
                return False, "no fresh camera pose: waiting for /arm/state"
            view = render(self.scene, camera, seed=self.p["seed"] + self._shots,
                          depth_noise_m=self.p["depth_noise_m"], hole_fraction=self.p["hole_fraction"],
                          depth_noise_correlation_px=self.p["depth_noise_correlation_px"],
                          mark_depth_dropout=self.p["mark_depth_dropout"], welded=tuple(self._welded.values()))
            if has_distortion(self.p["distortion_d"]):  # raw images of a lens with distortion
                view = distort_view(view, self.p["distortion_d"], self.p["distortion_model"])
            self._shots += 1
            self._say_defects_not_welded()
            stamp = self.get_clock().now().to_msg()
            shot = shot_messages(view, self.p["depth_encoding"], stamp, self.p["depth_noise_m"],
                                 self.p["seed"] + self._shots - 1, pose_camera=believed)
            for key, pub in self.pubs[inspection].items():
                pub.publish(shot[key])
            self.diag.set(self.diag.OK, "publishing", shots=self._shots, visible_studs=int(view.stud_visible.sum()))
            return True, f"{'inspection ' if inspection else ''}shot {self._shots} at {stamp.sec}.{stamp.nanosec:09d}"

    def _on_trigger(self, _request, response):
        response.success, response.message = self.shoot()
        return response

    def _on_trigger_inspection(self, _request, response):
        response.success, response.message = self.shoot(inspection=True)
        return response

    def _on_timer(self) -> None:
        self.shoot()


def main(args=None) -> int:
    """`ros2 run stud_perception camera`: spin until Ctrl-C; the process exit code."""
    return ros_io.spin_node(CameraNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
