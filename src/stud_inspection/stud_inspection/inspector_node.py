"""Inspector node: `ros2 run stud_planner inspector` -- the post-weld inspection as a service.

Keeps the last ``view_cache`` RGB-D views of the camera topics (depth, camera info, pose, colour; one
stamp each, as the matcher takes them). ``/inspection/inspect`` (stud_welding_msgs/srv/Inspect) names
the view the targets were matched on (before the welds) and asks for a later shot of the same
station; the node measures and judges every welded stud (stud_inspection.inspection), publishes the
result on ``/inspection/result`` (reliable, transient local: the last station's stays for a late
HMI) and, with ``overlay_dir``, writes the shot with every stud coloured by its verdict.

``/inspection/record_rework`` (stud_welding_msgs/srv/RecordRework) records an operator's decision
on a stud that did not pass (``rework`` or ``accept``, stud_inspection.rework): one JSON line with its
time in ``rework_file``, and a ReworkDecision on ``/inspection/rework`` (reliable, transient local,
deep history: a late HMI gets every decision). A decision never makes the cell weld a stud again.
"""
from __future__ import annotations

import functools
import os
import threading
import time
from collections import OrderedDict
from pathlib import Path

import cv2
import numpy as np
from geometry_msgs.msg import Point, PoseStamped, Vector3
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image
from stud_welding_msgs.msg import InspectionResult, ReworkDecision, StudInspection
from stud_welding_msgs.srv import Inspect, RecordRework

from stud_common import ros_io
from stud_perception import image_io
from stud_common.ros_io import Param
from stud_inspection import qa_report, rework
from stud_inspection.inspection import InspectionLimits, Verdict, draw_inspection_overlay, inspect_studs
from stud_common import names

_LIMITS = InspectionLimits()
PARAMS = [
    ros_io.SENSOR_QOS_PARAM,
    Param("max_lean_deg", _LIMITS.max_lean_deg, "the most a welded stud may lean from the surface normal (the code's "
          "5 deg) [deg]", min=0.1, max=45.0),
    Param("position_tol_mm", _LIMITS.position_tol_mm, "the most the stud's base may lie from the planned point [mm]",
          min=0.05, max=100.0),
    Param("nominal_length_mm", _LIMITS.nominal_length_mm, "the stud's length after weld [mm]", min=1.0, max=1000.0),
    Param("height_tol_mm", _LIMITS.height_tol_mm, "allowed deviation of the standing height from the nominal "
          "length (burn-off) [mm]", min=0.05, max=100.0),
    Param("stud_diameter_mm", _LIMITS.stud_diameter_mm, "stud diameter [mm]", min=1.0, max=100.0),
    Param("overlay_dir", "", "write each inspection's overlay PNG here (empty: none)"),
    Param("qa_dir", "", "the folder of the job's QA record (the sequencer's qa_dir): each decision re-writes "
          "its rework column (empty: decisions only go to rework_file and /inspection/rework)"),
    Param("rework_file", "", "append operator rework decisions here (JSON lines); empty: "
          f"<overlay_dir>/{rework.FILE_NAME}, or $ROS_HOME/stud_welding/{rework.FILE_NAME} without overlay_dir",
          read_only=True),
    Param("view_cache", 8, "views kept for inspections to refer to", min=2, max=64),
    Param("wait_s", 20.0, "longest wait for the shot after the welds [s]", min=0.5, max=600.0),
    Param("sync_slop_s", 0.0, "stamps closer than this belong to one view [s]", min=0.0, max=1.0),
    image_io.IMAGES_RECTIFIED_PARAM,
]
_VERDICT_CODE = {Verdict.PASS: StudInspection.VERDICT_PASS, Verdict.FAIL: StudInspection.VERDICT_FAIL,
                 Verdict.MISSING: StudInspection.VERDICT_MISSING,
                 Verdict.NOT_INSPECTED: StudInspection.VERDICT_NOT_INSPECTED,
                 Verdict.NOT_WELDED: StudInspection.VERDICT_NOT_WELDED}


#: Every rework decision of the session stays for a late subscriber (the HMI).
REWORK_QOS = QoSProfile(depth=10000, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def rework_path(p: dict) -> Path:
    if p["rework_file"]:
        return Path(p["rework_file"]).expanduser()
    if p["overlay_dir"]:
        return Path(p["overlay_dir"]) / rework.FILE_NAME
    home = os.environ.get("ROS_HOME") or os.path.join(os.path.expanduser("~"), ".ros")
    return Path(home) / "stud_welding" / rework.FILE_NAME


def limits_from(p: dict) -> InspectionLimits:
    return InspectionLimits(max_lean_deg=p["max_lean_deg"], position_tol_mm=p["position_tol_mm"],
                            nominal_length_mm=p["nominal_length_mm"], height_tol_mm=p["height_tol_mm"],
                            stud_diameter_mm=p["stud_diameter_mm"])


def result_msg(targets, inspection, station: int, stamp, overlay_file: str) -> InspectionResult:
    """The InspectionResult message of ``inspection`` (one entry per target, in their order)."""
    msg = InspectionResult(station=int(station), overlay_file=overlay_file)
    msg.header.stamp, msg.header.frame_id = stamp, "world"
    lim = inspection.limits
    msg.max_lean_deg, msg.position_tol_mm = lim.max_lean_deg, lim.position_tol_mm
    msg.nominal_length_mm, msg.height_tol_mm = lim.nominal_length_mm, lim.height_tol_mm
    msg.stud_diameter_mm = lim.stud_diameter_mm
    for t, m in zip(targets, inspection.studs):
        s = StudInspection(stud_id=t.stud_id, verdict=_VERDICT_CODE[m.verdict], verdict_text=m.verdict.value,
                           reasons=list(m.reasons), planned_position=t.pose.position, planned_normal=t.normal,
                           measured=m.position_m is not None)
        if s.measured:
            s.base = Point(x=m.position_m[0], y=m.position_m[1], z=m.position_m[2])
            s.axis = Vector3(x=m.axis[0], y=m.axis[1], z=m.axis[2])
            s.lean_deg, s.height_mm = m.lean_deg, m.height_mm
            s.offset_x_mm, s.offset_y_mm = m.offset_mm
        msg.studs.append(s)
    msg.unexpected_objects = [Point(x=o.position_m[0], y=o.position_m[1], z=o.position_m[2]) for o in inspection.unexpected]
    msg.unexpected_heights_mm = [o.height_mm for o in inspection.unexpected]
    return msg


class InspectorNode(Node):
    def __init__(self) -> None:
        super().__init__("inspector")
        self.p = ros_io.declare_params(self, PARAMS)
        try:
            self.limits = limits_from(self.p)
        except ValueError as exc:
            self.get_logger().fatal(f"bad inspection limits: {exc}")
            raise SystemExit(2) from None
        self._views: OrderedDict[int, tuple] = OrderedDict()  # stamp ns -> (depth m, camera, colour bgr)
        self._cond = threading.Condition()
        cb = ReentrantCallbackGroup()
        self.pub_result = self.create_publisher(InspectionResult, names.INSPECTION_RESULT, ros_io.LATCHED_QOS)
        # Both kinds of shot are kept: the views the targets were matched on (before the welds) and the
        # post-weld inspection shots, on topics of their own (names.shot_topics).
        types = {"depth": Image, "color": Image, "info": CameraInfo, "pose": PoseStamped}
        for inspection in (False, True):
            sync = ros_io.StampSync(["depth", "info", "pose", "color"], self._on_view,
                                    slop_ns=int(self.p["sync_slop_s"] * 1e9), on_drop=ros_io.warn_dropped(self, "view"))
            for name, topic in names.shot_topics(inspection).items():
                self.create_subscription(types[name], topic, functools.partial(self._on_input, sync, name),
                                         ros_io.sensor_qos(self.p["sensor_qos"]), callback_group=cb)
        self.create_service(Inspect, names.INSPECTION_INSPECT, self._on_inspect, callback_group=cb)
        self._verdicts: dict[str, str] = {}  # stud id -> its newest verdict (this session's inspections)
        self.rework_file = rework_path(self.p)
        self.pub_rework = self.create_publisher(ReworkDecision, names.INSPECTION_REWORK, REWORK_QOS)
        self.create_service(RecordRework, names.INSPECTION_RECORD_REWORK, self._on_record_rework, callback_group=cb)
        self.diag = ros_io.Diagnostics(self)
        self.diag.set(self.diag.OK, "waiting for an inspection")
        self.create_timer(1.0, self.diag.publish)
        self.get_logger().info(f"inspector ready: /inspection/inspect (lean <= {self.limits.max_lean_deg:g} deg, "
                               f"position +- {self.limits.position_tol_mm:g} mm, height "
                               f"{self.limits.nominal_length_mm:g} +- {self.limits.height_tol_mm:g} mm)")

    def _on_input(self, sync: ros_io.StampSync, name: str, msg) -> None:
        with self._cond:
            sync.add(name, msg)

    def _on_view(self, view: dict) -> None:
        try:
            camera = image_io.camera_model_from_msgs(view["info"], view["pose"].pose, self.p["images_rectified"])
            rectifier = image_io.camera_rectifier(view["info"], self.p["images_rectified"])
            depth = image_io.depth_to_metres(view["depth"], rectifier)
            color = image_io.color_to_bgr(view["color"], rectifier)
        except (ros_io.MessageError, ValueError) as exc:
            self.get_logger().error(f"unusable view: {exc}", throttle_duration_sec=5.0)
            return
        self._views[ros_io.stamp_to_ns(view["depth"].header.stamp)] = (depth, camera, color)
        while len(self._views) > self.p["view_cache"]:
            self._views.popitem(last=False)
        self._cond.notify_all()

    def _on_inspect(self, req, resp):
        before_ns, after_ns = ros_io.stamp_to_ns(req.before_stamp), ros_io.stamp_to_ns(req.after_not_before)
        deadline = time.monotonic() + self.p["wait_s"]
        with self._cond:
            while True:
                after = next(((k, v) for k, v in reversed(self._views.items()) if k >= after_ns), None)
                if after is not None or time.monotonic() > deadline:
                    break
                self._cond.wait(0.1)
            before = self._views.get(before_ns)
        if before is None:
            resp.success, resp.message = False, (f"the view before the welds (stamp {before_ns}) is no longer kept "
                                                 f"(view_cache {self.p['view_cache']})")
            return resp
        if after is None:
            resp.success, resp.message = False, f"no shot after the welds within {self.p['wait_s']:g} s"
            return resp
        (stamp_ns, (depth, camera, color)), (depth_before, _cam, _c) = after, before
        ids = [t.stud_id for t in req.targets]
        planned = np.array([(t.pose.position.x, t.pose.position.y, t.pose.position.z) for t in req.targets]).reshape(-1, 3)
        normals = np.array([(t.normal.x, t.normal.y, t.normal.z) for t in req.targets]).reshape(-1, 3)
        welded = np.array([sid in set(req.welded_ids) for sid in ids], dtype=bool)
        inspection = inspect_studs(planned, normals, welded, depth_before, depth, camera, self.limits)
        overlay_file = ""
        if self.p["overlay_dir"]:
            out = Path(self.p["overlay_dir"])
            out.mkdir(parents=True, exist_ok=True)
            overlay_file = str(out / f"inspection_station_{req.station:02d}_{stamp_ns}.png")
            cv2.imwrite(overlay_file, draw_inspection_overlay(color, ids, planned, inspection, camera))
        resp.result = result_msg(req.targets, inspection, req.station, ros_io.ns_to_stamp(stamp_ns), overlay_file)
        self.pub_result.publish(resp.result)
        with self._cond:
            self._verdicts.update((s.stud_id, s.verdict_text) for s in resp.result.studs)
        counts = {}
        for m in inspection.studs:
            counts[m.verdict.value] = counts.get(m.verdict.value, 0) + 1
        summary = ", ".join(f"{k} {v}" for k, v in sorted(counts.items()))
        self.get_logger().info(f"station {req.station}: {summary}"
                               + (f", {len(inspection.unexpected)} unexpected object(s)" if inspection.unexpected else ""))
        self.diag.set(self.diag.OK, f"station {req.station}: {summary}")
        resp.success, resp.message = True, summary
        return resp

    def _update_qa_record(self) -> str:
        """Every decision so far into the QA record's rework column; what happened, for the reply."""
        if not self.p["qa_dir"]:
            return ""
        qa_dir = Path(self.p["qa_dir"])
        try:
            with qa_report.locked(qa_dir):
                decisions = rework.latest_decisions(self.rework_file)
                doc = qa_report.apply_rework(qa_dir, {s: r.for_qa_record() for s, r in decisions.items()})
        except (rework.ReworkError, ValueError, OSError) as exc:
            self.get_logger().error(f"QA record not updated with the decision: {exc}")
            return f"; the QA record was NOT updated ({exc})"
        if doc is None:
            return f"; {qa_dir / qa_report.JSON_NAME} does not exist yet: the cell writes it with this decision"
        return f"; QA record updated ({qa_dir / qa_report.JSON_NAME})"

    def _on_record_rework(self, req, resp):
        with self._cond:
            verdict = self._verdicts.get(req.stud_id.strip())
        try:
            record = rework.make_record(req.stud_id, req.decision, req.note, verdict, time.time())
            rework.append_record(self.rework_file, record)
        except (rework.ReworkError, OSError) as exc:
            resp.success, resp.message = False, f"not recorded: {exc}"
            self.get_logger().warn(f"rework decision on {req.stud_id!r} {resp.message}")
            return resp
        msg = ReworkDecision(stud_id=record.stud_id, decision=record.decision, verdict=record.verdict,
                             note=record.note)
        msg.header.stamp = ros_io.ns_to_stamp(int(record.stamp * 1e9))
        self.pub_rework.publish(msg)
        resp.success = True
        resp.message = (f"{record.stud_id} ({record.verdict}): {record.decision} recorded in {self.rework_file}"
                        + self._update_qa_record())
        self.get_logger().info(f"operator: {resp.message}" + (f" -- {record.note}" if record.note else ""))
        return resp


def main(args=None) -> int:
    return ros_io.spin_node(InspectorNode, args, multithreaded=True)


if __name__ == "__main__":
    raise SystemExit(main())
