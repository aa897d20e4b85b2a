"""Matcher node (weld targets from one view): `ros2 run stud_planner matcher`.

For every synchronised view (depth, camera info, ``/camera/pose``; images with sensor-data QoS so
best-effort camera drivers work) with a layout (``/drawing/layout``) and a valid registration
(``/registration/result``), it runs three steps (matching/view_targets.plan_view):

1. drawing -> world XY of every stud (Eq. 2, registration.local_to_world);
2. matching: the pixel whose back-projection (Eq. 1) lies within ``tolerance_m`` of the stud's
   world XY, by the ``algorithm`` parameter -- ``batch`` (default, ours: every stud at once, a
   secant search along each stud's vertical line in the depth image, holes filled only where a
   stud's samples touch one: matching/matchers.py), or the paper's baselines ``fpm`` (quadrant
   search from the image centre, then a 25x25 window) and ``bfs`` (pixel by pixel), both in
   matching/paper_baselines.py;
3. the weld pose: a quadric fitted to the window around each match (matching/surface_pose.py,
   summed-area tables of its moments: matching/window_moments.py), its normal and 1-sigma, the
   lean bound, the gun-clearance check (matching/gun_clearance.py) and each stud's status;

and publishes

* ``/weld_targets`` (WeldTargetArray: every stud of the drawing, in drawing order, with status),
* ``/weld_targets/poses`` (PoseArray, frame ``world``, same stamp): the poses of the targets whose
  status is OK, in ``/weld_targets`` order -- the k-th pose is the k-th OK target of the
  WeldTargetArray with the same stamp; studs without a usable pose are left out (RViz and
  Foxglove cannot draw NaN),
* ``/weld_targets/markers`` (MarkerArray: per in-view stud an arrow along its normal and its id as text,
  coloured by status: stud_planner.matching.target_markers),
* ``/weld_targets/overlay`` (the colour image with matched pixels and ids, the paper's Fig. 11), and the
  same as JPEG on ``/weld_targets/overlay/compressed`` (sensor_msgs/CompressedImage, for remote viewers;
  encoded only while it has a subscriber),
* ``/diagnostics`` (input ages and rates, last match time, counts by status).

Colour is needed only for the overlay, so the node subscribes to ``/camera/color/image_raw`` only
while ``/weld_targets/overlay`` or its ``compressed`` topic has a subscriber (and ``publish_overlay``
is true), and the colour never holds back ``/weld_targets``: the overlay of a view follows when its
colour image (same stamp) arrives. A 1280x960 colour frame costs as much transport as the matching
(the lazy subscription of ROS image pipelines).

The depth noise's correlation (it widens the normals' 1-sigma) is measured on a frame and reused
for the same camera's next frames at the same pose (``noise_correlation_reuse_s``); it is measured
again after a frame's targets are out, so a camera streaming from one pose never waits for it, and
a shot from a new pose is measured on itself.

Missing inputs give a throttled "waiting for ..." log; a registration older than
``max_registration_age_s`` (measured between stamps) is stale: nothing is published and
the reason is logged.

A long part (a layout with reference marks, welded from a rail) may be registered view by view: with
``per_view_registration`` (the registration node's parameter of the same name registers every view on
the marks it sees, its result stamped with the view), each view is matched with the registration of
its own stamp -- never with a neighbour's, whichever arrives first -- and waits for it; a view whose
registration failed is not matched. Replaying such a part's bag (``--mode replay``) gives the targets
``ros2 run stud_planner plan`` gives. Without reference marks the latest registration is used, as ever.
"""
from __future__ import annotations

import functools
import time
from collections import OrderedDict, deque

from geometry_msgs.msg import Point, Pose, PoseArray, PoseStamped, Quaternion
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.subscription import Subscription
from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from std_msgs.msg import Header
from stud_welding_msgs.msg import Registration, StudLayout, WeldTargetArray
from visualization_msgs.msg import MarkerArray

from stud_common import names, ros_io
from stud_common.ros_io import Param
from stud_perception import image_io
from stud_planner.matching.gun_clearance import GunModel
from stud_planner.matching.target_cdr import weld_target_array_cdr
from stud_planner.matching.target_markers import target_markers
from stud_planner.matching.view_targets import (
    ALGORITHMS,
    NoiseMemory,
    PlannerConfig,
    draw_targets_overlay,
    plan_view,
    view_noise_correlation,
)
from stud_planner.msg_convert import LayoutView, layout_from_msg, registration_from_msg

_PLAN = PlannerConfig()  # the planner's defaults are its own; the parameters expose them
PARAMS = [
    ros_io.SENSOR_QOS_PARAM,
    Param("algorithm", _PLAN.algorithm, "matcher: 'batch' (ours), 'fpm' or 'bfs' (the paper's)", choices=ALGORITHMS),
    Param("tolerance_m", _PLAN.tol_m, "match tolerance on world XY [m] (paper: 1 mm)", min=1e-5, max=0.02),
    Param("fpm_window_px", _PLAN.fpm_window_px, "FPM brute-force window side [px] (paper: 25)", min=3, max=201),
    Param("hole_window_px", _PLAN.hole_window_px, "missing-depth window side [px] (paper: 7)", min=3, max=63),
    Param("normal_window_m", _PLAN.normal_window_m, "side of the surface patch the normal is fitted on [m]",
          min=0.002, max=0.2),
    Param("normal_samples_per_side", _PLAN.normal_samples_per_side, "depth samples per side of the normal's patch "
          "at most (81: every pixel of a 20 mm patch at 0.45 m; fewer is faster and noisier)", min=5, max=161),
    Param("max_normal_rms_m", _PLAN.max_normal_rms_m, "largest fit RMS for a trusted normal [m]", min=1e-5, max=0.05),
    Param("noise_correlation_max_lag_px", _PLAN.noise_correlation_max_lag_px, "the normal's 1-sigma is widened by "
          "the depth noise's correlation across pixels, measured on each frame up to this lag; 0: take the noise as "
          "independent (a real camera's normal error is then understated several-fold) [px]", min=0, max=64),
    Param("sample_step_max_loss", _PLAN.sample_step_max_loss, "where the measured noise correlation makes "
          "neighbouring pixels redundant, the normal's patch is sampled every few pixels (faster) at a cost of at "
          "most this fraction of the normal's 1-sigma; 0: every pixel", min=0.0, max=1.0),
    Param("noise_correlation_reuse_s", 2.0, "a frame's measured noise correlation is reused for the same camera's "
          "frames at the same pose (1 mm, 0.1 deg) for up to this long, and measured again after a frame's targets "
          "are published once it is half that old, so a steady stream never waits for it; a new pose is measured "
          "on its own frame; 0: measured on every frame before its targets [s]", min=0.0, max=60.0),
    Param("lean_budget_deg", _PLAN.lean_budget_deg, "the most a welded stud may lean from the true normal (the "
          "code's 5 deg); a target whose normal is too uncertain for it is normal_uncertain -- the slope never "
          "refuses [deg]", min=0.1, max=45.0),
    Param("arm_orientation_error_deg", _PLAN.arm_orientation_error_deg, "the arm's orientation error, its share of "
          "the lean budget [deg]", min=0.0, max=10.0),
    Param("normal_sigma_k", _PLAN.normal_sigma_k, "coverage factor on the normal's 1-sigma in the lean bound",
          min=0.5, max=10.0),
    Param("check_gun_clearance", _PLAN.check_gun_clearance, "refuse studs where the gun would touch the part "
          "(gun_blocked)"),
    Param("gun_radius_m", _PLAN.gun.radius_m, "the welding gun's radius about the stud (body, foot) [m]",
          min=0.001, max=0.5),
    Param("gun_length_m", _PLAN.gun.length_m, "surface to the gun's top at the approach pose (gun length + "
          "standoff) [m]", min=0.01, max=2.0),
    Param("tool_offset_m", _PLAN.tool_offset_m, "report the point this far along the normal [m] (0: on the surface)",
          min=-0.5, max=0.5),
    Param("bfs_max_pixels", _PLAN.bfs_max_pixels or 0, "BFS only: pixels evaluated per stud at most (0: all)",
          min=0, max=100_000_000),
    Param("max_registration_age_s", 0.0, "a registration older than this (stamps) is stale [s]; 0: never",
          min=0.0, max=1e6),
    Param("sync_slop_s", 0.0, "stamps closer than this belong to one view [s] (0: equal stamps)", min=0.0, max=1.0),
    Param("per_view_registration", False, "with a layout that has reference marks (a long part): match each view "
          "with the registration of its own stamp (the registration node's per_view_registration registers every "
          "view), waiting for it, instead of the latest registration"),
    Param("publish_overlay", True, "publish /weld_targets/overlay (and /weld_targets/overlay/compressed)"),
    Param("overlay_jpeg_quality", 80, "JPEG quality of /weld_targets/overlay/compressed", min=1, max=100),
    image_io.IMAGES_RECTIFIED_PARAM,
]
_ODD = ("fpm_window_px", "hole_window_px")


def _odd(name: str, value: int) -> str | None:
    return None if value % 2 else f"{name}={value}: must be odd"


def _put_bounded(items: OrderedDict, key, value, limit: int = 5) -> None:
    """Add an entry, dropping the oldest beyond ``limit`` (views waiting for their other half)."""
    items[key] = value
    while len(items) > limit:
        items.popitem(last=False)


class MatcherNode(Node):
    def __init__(self) -> None:
        super().__init__("matcher")
        params = [p if p.name not in _ODD else Param(p.name, p.default, p.description, p.min, p.max,
                                                     validate=functools.partial(_odd, p.name))
                  for p in PARAMS]
        self.p = ros_io.declare_params(self, params, on_change=lambda _changes: self._on_params_changed())
        self._noise = NoiseMemory(self.p["noise_correlation_reuse_s"])
        self.layout: StudLayout | None = None
        self._layout_view: LayoutView | None = None  # layout_from_msg(self.layout), once per layout
        self.registration: Registration | None = None
        self.view_index = 0
        self._pending: dict | None = None  # the last view that came before the layout or registration
        # per_view_registration: registrations by their view's stamp (ns), and views waiting for theirs
        self._view_registrations: OrderedDict[int, Registration] = OrderedDict()
        self._views_waiting: OrderedDict[int, dict] = OrderedDict()
        self._arrivals: dict[str, deque] = {k: deque(maxlen=20) for k in ("color", "depth", "info", "pose")}
        self._color_sub: Subscription | None = None  # only while the overlay has a subscriber
        self._colors: OrderedDict[int, Image] = OrderedDict()  # stamp ns -> colour image, newest last
        self._overlays_due: OrderedDict[int, tuple] = OrderedDict()  # stamp ns -> (targets, decoded view)
        self.pub_targets = self.create_publisher(WeldTargetArray, names.WELD_TARGETS, ros_io.RESULT_QOS)
        self.pub_poses = self.create_publisher(PoseArray, names.WELD_TARGET_POSES, ros_io.RESULT_QOS)
        self.pub_markers = self.create_publisher(MarkerArray, names.WELD_TARGET_MARKERS, ros_io.RESULT_QOS)
        self.pub_overlay = self.create_publisher(
            Image, names.WELD_TARGET_OVERLAY, ros_io.RESULT_QOS,
            event_callbacks=PublisherEventCallbacks(matched=lambda _info: self._update_color_subscription()))
        self.pub_overlay_jpeg = self.create_publisher(
            CompressedImage, names.WELD_TARGET_OVERLAY_COMPRESSED, ros_io.RESULT_QOS,
            event_callbacks=PublisherEventCallbacks(matched=lambda _info: self._update_color_subscription()))
        self.diag = ros_io.Diagnostics(self)
        self.diag.set(self.diag.OK, "waiting for inputs")  # idle is normal: not a warning on the operator's HMI
        self.create_timer(1.0, self._publish_diagnostics)
        self.create_subscription(StudLayout, names.DRAWING_LAYOUT, self._on_layout, ros_io.LATCHED_QOS)
        # latched on the publisher's side; a deeper reader history so that a registration per view is never
        # replaced by the next before it is taken
        self.create_subscription(Registration, names.REGISTRATION_RESULT, self._on_registration,
                                 QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                                            durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self.sync = ros_io.StampSync(["depth", "info", "pose"], self._on_view,
                                     slop_ns=int(self.p["sync_slop_s"] * 1e9),
                                     on_drop=ros_io.warn_dropped(self, "view"))
        for name, topic, typ in (("depth", names.DEPTH_IMAGE, Image),
                                 ("info", names.CAMERA_INFO, CameraInfo), ("pose", names.CAMERA_POSE, PoseStamped)):
            self.create_subscription(typ, topic, functools.partial(self._on_input, name),
                                     ros_io.sensor_qos(self.p["sensor_qos"]))
        self._update_color_subscription()
        self.get_logger().info(f"matcher '{self.p['algorithm']}' waiting for /drawing/layout, /registration/result "
                               "and synchronised RGB-D views")

    # -- inputs ------------------------------------------------------------------------------------
    def _on_layout(self, msg: StudLayout) -> None:
        self.layout = msg
        self._layout_view = layout_from_msg(msg)
        self.get_logger().info(f"layout '{msg.source_file}' with {len(msg.studs)} studs")
        self._retry_pending()

    def _on_registration(self, msg: Registration) -> None:
        self.registration = msg
        if self.p["per_view_registration"]:  # kept by stamp even before the layout says whether it is needed
            stamp = ros_io.stamp_to_ns(msg.header.stamp)
            view = self._pop_near(self._views_waiting, stamp) if self._per_view() else None
            if view is not None:
                self._match_with(view, msg)
                return
            _put_bounded(self._view_registrations, stamp, msg, limit=20)
            if self._per_view():
                return
        if not msg.valid:
            self.get_logger().warn(f"registration not valid: {msg.message}", throttle_duration_sec=10.0)
            return
        self._retry_pending()

    def _per_view(self) -> bool:
        """Each view with the registration of its own stamp: asked for, and a layout with reference marks."""
        return bool(self.p["per_view_registration"] and self.layout is not None
                    and len(self.layout.reference_mark_labels))

    def _retry_pending(self) -> None:
        """A view that came just before the layout or its registration: match it now (it may be the
        station's only shot), unless the other is still missing (then it waits on)."""
        if self._pending is not None:
            view, self._pending = self._pending, None
            self._on_view(view)

    def _on_input(self, name: str, msg) -> None:
        self._arrivals[name].append(time.monotonic())
        self.sync.add(name, msg)

    def _on_params_changed(self) -> None:
        self._noise = NoiseMemory(self.p["noise_correlation_reuse_s"])  # measured under the old settings: forgotten
        self._update_color_subscription()

    def _update_color_subscription(self) -> None:
        """Subscribe to colour while the overlay is wanted and watched; unsubscribe otherwise."""
        wanted = bool(self.p["publish_overlay"]) and (self.pub_overlay.get_subscription_count() > 0
                                                       or self.pub_overlay_jpeg.get_subscription_count() > 0)
        if wanted and self._color_sub is None:
            self._color_sub = self.create_subscription(Image, names.COLOR_IMAGE, self._on_color,
                                                       ros_io.sensor_qos(self.p["sensor_qos"]))
            self.get_logger().info("/weld_targets/overlay has a subscriber: subscribing to /camera/color/image_raw")
        elif not wanted and self._color_sub is not None:
            self.destroy_subscription(self._color_sub)
            self._color_sub = None
            self._colors.clear()
            self._overlays_due.clear()
            self.get_logger().info("no overlay wanted: unsubscribed from /camera/color/image_raw")

    def _on_color(self, msg: Image) -> None:
        self._arrivals["color"].append(time.monotonic())
        stamp = ros_io.stamp_to_ns(msg.header.stamp)
        due = self._pop_near(self._overlays_due, stamp)
        if due is not None:
            targets, decoded = due
            self._publish_overlay(targets, decoded, msg)
            return
        _put_bounded(self._colors, stamp, msg)

    def _pop_near(self, items: OrderedDict, stamp_ns: int):
        """Remove and return the entry whose stamp is within ``sync_slop_s`` of ``stamp_ns`` (or None)."""
        slop = int(self.p["sync_slop_s"] * 1e9)
        key = next((k for k in items if abs(k - stamp_ns) <= slop), None)
        return None if key is None else items.pop(key)

    def planner_config(self) -> PlannerConfig:
        p = self.p
        return PlannerConfig(algorithm=p["algorithm"], tol_m=p["tolerance_m"], fpm_window_px=p["fpm_window_px"],
                             hole_window_px=p["hole_window_px"], normal_window_m=p["normal_window_m"],
                             normal_samples_per_side=p["normal_samples_per_side"],
                             max_normal_rms_m=p["max_normal_rms_m"], lean_budget_deg=p["lean_budget_deg"],
                             arm_orientation_error_deg=p["arm_orientation_error_deg"],
                             normal_sigma_k=p["normal_sigma_k"], check_gun_clearance=p["check_gun_clearance"],
                             noise_correlation_max_lag_px=p["noise_correlation_max_lag_px"],
                             sample_step_max_loss=p["sample_step_max_loss"],
                             gun=GunModel(radius_m=p["gun_radius_m"], length_m=p["gun_length_m"]),
                             tool_offset_m=p["tool_offset_m"], bfs_max_pixels=p["bfs_max_pixels"] or None)

    def _not_ready(self, stamp) -> str | None:
        if self.layout is None:
            return "waiting for /drawing/layout"
        if self.registration is None:
            return "waiting for /registration/result"
        if not self.registration.valid:
            return f"waiting for a valid registration (last: {self.registration.message})"
        max_age = self.p["max_registration_age_s"]
        age = (ros_io.stamp_to_ns(stamp) - ros_io.stamp_to_ns(self.registration.header.stamp)) * 1e-9
        if max_age > 0 and age > max_age:
            return (f"registration is stale ({age:.1f} s older than the view, limit {max_age:.1f} s): "
                    "targets not published")
        return None

    # -- one view ------------------------------------------------------------------------------------
    def _on_view(self, view: dict) -> None:
        stamp = view["depth"].header.stamp
        if self._per_view():
            registration = self._pop_near(self._view_registrations, ros_io.stamp_to_ns(stamp))
            if registration is None:  # its registration is still on its way
                _put_bounded(self._views_waiting, ros_io.stamp_to_ns(stamp), view)
            else:
                self._match_with(view, registration)
            return
        reason = self._not_ready(stamp)
        if reason:
            self.get_logger().info(reason, throttle_duration_sec=5.0)
            self.diag.set(self.diag.WARN, reason)
            self._pending = view
            return
        self._pending = None
        assert self.registration is not None  # views wait for it
        self._match(view, self.registration)

    def _match_with(self, view: dict, registration: Registration) -> None:
        """per_view_registration: a view and the registration of its stamp met; an invalid one is no match."""
        if not registration.valid:
            why = f"view not matched: its registration failed: {registration.message}"
            self.get_logger().warn(why, throttle_duration_sec=5.0)
            self.diag.set(self.diag.WARN, why)
            return
        self._match(view, registration)

    def _match(self, view: dict, registration: Registration) -> None:
        """One view's targets with ``registration``, published."""
        stamp = view["depth"].header.stamp
        try:
            decoded = image_io.decode_depth_view(view["info"], view["pose"].pose, view["depth"],
                                                 self.p["images_rectified"], image_io.view_topics(self))
        except (ros_io.MessageError, ValueError) as exc:
            self.get_logger().error(f"unusable view: {exc}", throttle_duration_sec=5.0)
            self.diag.set(self.diag.ERROR, f"unusable view: {exc}")
            return
        if decoded.rectifier is not None:
            self.get_logger().info(image_io.rectification_note(view["info"]), once=True)
        camera, depth = decoded.camera, decoded.depth_m
        layout = self._layout_view
        assert layout is not None  # views wait for it
        now = time.monotonic()
        reused = self._noise.recall(camera, now)
        targets = plan_view(layout.ids, layout.xy_m, registration_from_msg(registration), depth, camera,
                            self.planner_config(), noise=reused, view_index=self.view_index)
        self._publish(targets, decoded, stamp,
                      noise_age_s=None if reused is None else now - self._noise.measured_at_s)
        self.view_index += 1
        # After the targets are out: this frame's noise, for the frames after it.
        if reused is None:
            self._noise.remember(camera, targets.poses.noise, time.monotonic())
        elif self._noise.refresh_due(time.monotonic()):
            self._noise.remember(camera, view_noise_correlation(targets, depth, camera), time.monotonic())

    def _publish(self, targets, decoded: image_io.DepthView, stamp, noise_age_s: float | None = None) -> None:
        # First: it is what the cell waits for. Written as CDR bytes straight from the arrays (a
        # tenth of the cost of 100 WeldTarget objects through rclpy's conversion).
        self.pub_targets.publish(weld_target_array_cdr(targets, self.view_index, stamp.sec, stamp.nanosec, "world"))
        header = Header(stamp=stamp, frame_id="world")
        # Visualisation topics are built only when somebody listens (a MarkerArray of 100 arrows
        # costs more than the matching itself).
        if self.pub_poses.get_subscription_count():
            self.pub_poses.publish(self._poses(targets, header))
        if self.pub_markers.get_subscription_count():
            self.pub_markers.publish(self._markers(targets, header))
        if self._color_sub is not None:  # the overlay, now or when the view's colour image arrives
            stamp_ns = ros_io.stamp_to_ns(stamp)
            color = self._pop_near(self._colors, stamp_ns)
            if color is not None:
                self._publish_overlay(targets, decoded, color)
            else:
                _put_bounded(self._overlays_due, stamp_ns, (targets, decoded))
        counts = targets.counts()
        widened = targets.sigma_inflation()
        summary = (f"view {self.view_index}: {counts.get('ok', 0)}/{len(targets.ids)} ok "
                   f"({', '.join(f'{k} {v}' for k, v in sorted(counts.items()) if k != 'ok') or 'no failures'}), "
                   f"{targets.algorithm} {targets.match_time_s * 1e3:.1f} ms, "
                   f"{targets.matches.total_iterations} iterations"
                   + (f", normal sigma x{widened:.1f} for the depth noise's correlation" if widened >= 1.5 else "")
                   + ("" if noise_age_s is None else f", noise correlation of a frame {noise_age_s:.2f} s before"))
        self.get_logger().info(summary)
        self.diag.set(self.diag.OK, summary, last_match_time_ms=f"{targets.match_time_s * 1e3:.2f}",
                      normal_sigma_inflation=f"{widened:.2f}",
                      noise_correlation_from=("this frame" if noise_age_s is None
                                              else f"a frame {noise_age_s:.2f} s before"),
                      **{f"count_{k}": v for k, v in counts.items()})

    def _publish_overlay(self, targets, decoded: image_io.DepthView, color_msg: Image) -> None:
        try:
            color = decoded.color(color_msg)
        except (ros_io.MessageError, ValueError) as exc:
            self.get_logger().warn(f"no overlay: unusable colour image: {exc}", throttle_duration_sec=10.0)
            return
        overlay = draw_targets_overlay(color, targets, decoded.camera)
        stamp, frame = color_msg.header.stamp, color_msg.header.frame_id
        if self.pub_overlay.get_subscription_count():
            self.pub_overlay.publish(image_io.numpy_to_image(overlay, "bgr8", stamp, frame))
        if self.pub_overlay_jpeg.get_subscription_count():
            self.pub_overlay_jpeg.publish(image_io.bgr_to_compressed(overlay, stamp, frame,
                                                                   self.p["overlay_jpeg_quality"]))

    @staticmethod
    def _poses(targets, header: Header) -> PoseArray:
        """The usable targets' poses (status OK: matched, with a trusted normal, so finite), in
        /weld_targets order: the k-th pose is the k-th OK target of that view's WeldTargetArray.
        The others are left out: a NaN pose is nothing RViz or Foxglove can draw."""
        ok = targets.ok
        return PoseArray(header=header, poses=[
            Pose(position=Point(x=p[0], y=p[1], z=p[2]), orientation=Quaternion(x=q[0], y=q[1], z=q[2], w=q[3]))
            for p, q in zip(targets.position_w[ok].tolist(), targets.message_quat_xyzw[ok].tolist())])

    @staticmethod
    def _markers(targets, header: Header) -> MarkerArray:
        return target_markers(targets, header)

    def _publish_diagnostics(self) -> None:
        self._update_color_subscription()  # in case a matched event was missed
        now = time.monotonic()
        for name, times in self._arrivals.items():
            if times:
                rate = (len(times) - 1) / (times[-1] - times[0]) if len(times) > 1 and times[-1] > times[0] else 0.0
                self.diag.values[f"{name}_age_s"] = f"{now - times[-1]:.2f}"
                self.diag.values[f"{name}_rate_hz"] = f"{rate:.2f}"
            else:
                self.diag.values[f"{name}_age_s"] = ("not subscribed (no overlay subscriber)"
                                                     if name == "color" and self._color_sub is None
                                                     else "never received")
        self.diag.publish()


def main(args=None) -> int:
    """`ros2 run stud_planner matcher`: spin until Ctrl-C; the process exit code."""
    return ros_io.spin_node(MatcherNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
