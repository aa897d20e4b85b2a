"""Marker registration node: `ros2 run stud_perception registration`.

Inputs: ``/drawing/layout`` (for |OA|, |OB|, |AB| and the mark size) and one synchronised
RGB-D view (colour, depth, camera info, ``/camera/pose``, matched by stamp). Finds O, A, B
(Hough + sub-pixel, markers.py), lifts them with Eq. 1 and publishes ``/registration/result``
(Registration, reliable + transient local) and ``/registration/overlay``.

By default the node registers on the first view where the marks are found and then holds
that result (the board does not move during a job); ``/registration/trigger`` re-runs it on
the next view, ``continuous:=true`` registers every view. A bad view publishes
``valid=false`` with the reason (logged once per distinct reason) and never kills the node.

Long parts: when the layout carries reference marks (M1, M2, ...), every view is registered on
all the marks it sees (stud_perception.mark_registration): the first one needs O, A, B, each
later one names its marks by the nearest registration made before (the rail's error between two
stations stays within ``gate_m``), and a view with too few marks publishes the nearest registration
with ``extrapolated_distance`` set (valid, the message says how far). ``labels_used``,
``mark_residuals`` and ``residual_max`` say which marks the fit used and how well each agreed; a
new layout starts the trail afresh. Without reference marks the node behaves as before.
With ``per_view_registration`` and such a layout every view is registered (as ``continuous``, for long
parts only), each result stamped with its view: the matcher's parameter of the same name matches every
view with its own registration (a long part's bag replayed: ``--mode replay`` sets both).
"""
from __future__ import annotations

import functools
import math

import numpy as np
from geometry_msgs.msg import Point, PoseStamped
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image
from std_srvs.srv import Trigger
from stud_welding_msgs.msg import Registration, StudLayout

from stud_common import names, ros_io
from stud_common.ros_io import Param
from stud_perception import image_io
from stud_perception.mark_registration import MarkFitConfig, RegistrationTrail
from stud_perception.markers import MarkDetectorConfig
from stud_perception.registration import (
    BOARD_LABELS,
    MarkRegistration,
    layout_marks_m,
    layout_reference_marks_m,
    local_to_world,
)
from stud_perception.view_registration import config_for_layout, draw_registration_overlay, register_view

PARAMS = [
    ros_io.SENSOR_QOS_PARAM,
    Param("continuous", False, "register every view (true) or once, then on /registration/trigger (false)"),
    Param("method", "eq3", "transform from the marks: 'eq3' (paper) or 'least_squares'",
          choices=("eq3", "least_squares")),
    Param("distance_tol_m", 0.004, "allowed |measured - drawing| of |OA|, |OB|, |AB| [m]", min=1e-4, max=0.05),
    Param("depth_min_m", 0.25, "nearest camera-to-board distance searched [m]", min=0.05, max=5.0),
    Param("depth_max_m", 1.2, "farthest camera-to-board distance searched [m]", min=0.1, max=10.0),
    Param("min_contrast", 40.0, "least grey-level difference between a mark and its surround", min=1.0, max=255.0),
    Param("sync_slop_s", 0.0, "stamps closer than this belong to one view [s] (0: equal stamps)", min=0.0, max=1.0),
    Param("publish_overlay", True, "publish /registration/overlay"),
    Param("gate_m", 0.03, "with reference marks: a dark disc is named after a drawing mark only within this distance "
          "of where the nearest earlier registration puts it [m] (below half the smallest mark spacing, above the "
          "rail's error between stations)", min=0.001, max=0.5),
    Param("max_residual_m", 0.002, "with reference marks: the largest distance a mark may lie from the fit over all "
          "marks seen [m]; beyond it the registration is refused (a wrong association)", min=1e-4, max=0.05),
    Param("min_marks", 2, "with reference marks: the fewest marks a registration uses (2: the plane is known)",
          min=2, max=20),
    Param("per_view_registration", False, "with reference marks: register every view (the trail), each result "
          "stamped with its view, for the matcher's per_view_registration; without them, as before"),
    image_io.IMAGES_RECTIFIED_PARAM,
]


class RegistrationNode(Node):
    def __init__(self) -> None:
        super().__init__("registration")
        self.p = ros_io.declare_params(self, PARAMS)
        self.layout: StudLayout | None = None
        self.trail = RegistrationTrail()  # registrations along a part with reference marks
        self.armed = True  # register on the next complete view
        self._pending: dict | None = None  # the last view that came before the layout
        self._last_reason = ""
        self.pub_result = self.create_publisher(Registration, names.REGISTRATION_RESULT, ros_io.LATCHED_QOS)
        self.pub_overlay = self.create_publisher(Image, names.REGISTRATION_OVERLAY, ros_io.RESULT_QOS)
        self.diag = ros_io.Diagnostics(self)
        self.diag.set(self.diag.OK, "waiting for /drawing/layout and a view")  # idle: not a warning
        self.create_timer(1.0, self.diag.publish)
        self.create_subscription(StudLayout, names.DRAWING_LAYOUT, self._on_layout, ros_io.LATCHED_QOS)
        self.sync = ros_io.StampSync(["color", "depth", "info", "pose"], self._on_view,
                                     slop_ns=int(self.p["sync_slop_s"] * 1e9),
                                     on_drop=ros_io.warn_dropped(self, "view"))
        for name, topic, typ in (("color", names.COLOR_IMAGE, Image), ("depth", names.DEPTH_IMAGE, Image),
                                 ("info", names.CAMERA_INFO, CameraInfo), ("pose", names.CAMERA_POSE, PoseStamped)):
            self.create_subscription(typ, topic, functools.partial(self.sync.add, name),
                                     ros_io.sensor_qos(self.p["sensor_qos"]))
        self.create_service(Trigger, names.REGISTRATION_TRIGGER, self._on_trigger)
        self.get_logger().info("waiting for /drawing/layout and a synchronised RGB-D view")

    def _on_layout(self, msg: StudLayout) -> None:
        self.layout = msg
        self.trail.clear()
        self.armed = True  # a new drawing needs a new registration
        self.get_logger().info(f"layout '{msg.source_file}': marks |OA|={msg.mark_a.x * 1e3:.1f} mm, "
                               f"mark diameter {msg.mark_diameter * 1e3:.1f} mm")
        if self._pending is not None:  # the board view may have come first (bag replay, slow drawing node)
            view, self._pending = self._pending, None
            self._on_view(view)

    def _on_trigger(self, _req, resp):
        self.armed = True
        resp.success, resp.message = True, "registration will run on the next view"
        return resp

    def _on_view(self, view: dict) -> None:
        if self.layout is None:
            self.get_logger().info("view received, waiting for /drawing/layout", throttle_duration_sec=10.0)
            self._pending = view
            return
        every_view = self.p["per_view_registration"] and len(self.layout.reference_mark_labels) > 0
        if not (self.armed or self.p["continuous"] or every_view):
            return
        stamp = view["color"].header.stamp
        try:
            decoded = image_io.decode_view(view["info"], view["pose"].pose, view["depth"], view["color"],
                                           self.p["images_rectified"], image_io.view_topics(self))
        except (ros_io.MessageError, ValueError) as exc:
            self._publish_invalid(stamp, f"unusable view: {exc}")
            return
        if decoded.rectifier is not None:
            self.get_logger().info(image_io.rectification_note(view["info"]), once=True)
        camera, color, depth = decoded.camera, decoded.color_bgr, decoded.depth_m
        marks = layout_marks_m(self.layout)
        config = config_for_layout(MarkDetectorConfig(
            depth_range_m=(self.p["depth_min_m"], self.p["depth_max_m"]), distance_tol_m=self.p["distance_tol_m"],
            min_contrast=self.p["min_contrast"]), self.layout.mark_diameter)
        try:
            references = layout_reference_marks_m(self.layout)
            if references:
                fit = MarkFitConfig(gate_m=self.p["gate_m"], max_residual_m=self.p["max_residual_m"],
                                    min_marks=self.p["min_marks"], method=self.p["method"])
                all_marks = {**dict(zip(BOARD_LABELS, marks)), **references}
                result = self.trail.register(color, depth, camera, all_marks, config, fit)
            else:
                result = register_view(color, depth, camera, marks, config, method=self.p["method"])
        except ValueError as exc:  # sizes of colour/depth/camera info disagree, or a malformed layout
            self._publish_invalid(stamp, f"unusable view: {exc}")
            return
        if self.p["publish_overlay"]:
            self.pub_overlay.publish(image_io.numpy_to_image(draw_registration_overlay(color, result, camera), "bgr8",
                                                           stamp, view["color"].header.frame_id))
        if not result.ok:
            self._publish_invalid(stamp, result.message)
            return
        reg = result.registration
        assert reg is not None  # an ok result carries its registration
        self.pub_result.publish(registration_msg(reg, result.message, stamp))
        self.armed = False
        self._last_reason = ""
        self.get_logger().info(result.message)
        self.diag.set(self.diag.OK if not reg.extrapolated else self.diag.WARN, result.message,
                      residual_mm=f"{reg.residual_m * 1e3:.3f}", residual_max_mm=f"{reg.residual_max_m * 1e3:.3f}",
                      marks=",".join(reg.labels_used), extrapolated_m=f"{reg.extrapolated_m:.3f}")

    def _publish_invalid(self, stamp, reason: str) -> None:
        msg = Registration(valid=False, message=reason)
        msg.header.stamp, msg.header.frame_id = stamp, "world"
        self.pub_result.publish(msg)
        if reason != self._last_reason:  # log once per distinct reason
            self.get_logger().warn(f"registration failed: {reason}")
            self._last_reason = reason
        self.diag.set(self.diag.WARN, f"registration failed: {reason}")


def registration_msg(reg: MarkRegistration, message: str, stamp) -> Registration:
    """The Registration message of a valid registration. O, A, B the fit did not see are put where the
    transform puts them, at the mean height of the marks it used (the drawing frame's height there)."""
    msg = Registration(valid=True, message=message, residual=float(reg.residual_m))
    msg.header.stamp, msg.header.frame_id = stamp, "world"
    msg.m_local2world = [float(v) for v in reg.M_local2world.ravel()]
    oab = np.array(reg.marks_world_m, dtype=np.float64)
    unseen = ~np.isfinite(oab).all(axis=1)
    if unseen.any():
        oab[unseen, :2] = local_to_world(reg.M_local2world, reg.marks_drawing_m[unseen])
        oab[unseen, 2] = float(np.mean(reg.marks_used_world_m[:, 2]))
    msg.mark_o, msg.mark_a, msg.mark_b = (Point(x=float(p[0]), y=float(p[1]), z=float(p[2])) for p in oab)
    msg.angle_aob = math.radians(float(reg.angle_AOB_deg))
    msg.labels_used = list(reg.labels_used)
    msg.marks_used = [Point(x=float(p[0]), y=float(p[1]), z=float(p[2])) for p in reg.marks_used_world_m]
    msg.mark_residuals = [float(r) for r in reg.mark_residuals_m]
    msg.residual_max = float(reg.residual_max_m)
    msg.extrapolated_distance = float(reg.extrapolated_m)
    return msg


def main(args=None) -> int:
    """`ros2 run stud_perception registration`: spin until Ctrl-C; the process exit code."""
    return ros_io.spin_node(RegistrationNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
