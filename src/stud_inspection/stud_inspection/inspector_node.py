"""Inspector node: `ros2 run stud_planner inspector` -- the post-weld inspection as a service.

Keeps the last ``view_cache`` RGB-D views of the camera topics (depth, camera info, pose, colour; one
stamp each, as the matcher takes them). ``/inspection/inspect`` (stud_welding_msgs/srv/Inspect) names
the view the targets were matched on (before the welds) and asks for a later shot of the same
station; the node measures and judges every welded stud (stud_inspection.inspection), publishes the
result on ``/inspection/result`` (reliable, transient local: the last station's stays for a late
HMI) and, with ``overlay_dir``, writes the shot with every stud coloured by its verdict.

The limits are the ``qa_code`` profile's (stud_inspection.qa_codes: GB 50205, EN ISO 14555, AWS
D1.1), each overridable by the parameter of its name.

``/inspection/record_rework`` (stud_welding_msgs/srv/RecordRework) records an operator's decision
on a stud that did not pass (``rework`` or ``accept``, stud_inspection.rework): one JSON line with its
time and the operator's name in ``rework_file``, and a ReworkDecision on ``/inspection/rework``
(reliable, transient local, deep history: a late HMI gets every decision). A decision never makes
the cell weld a stud again. ``/inspection/record_bend_test`` (RecordBendTest) records a bend-test
result the same way (stud_inspection.bend, ``bend_file``). Each entry re-writes the job's QA record
in ``qa_dir`` (its rework column, its bend-test list: a failed test adds the stud's neighbours), and
the record's bend-test list goes out on ``/inspection/bend_tests`` (BendTestPlan, latched) whenever
the record is written -- by this node or by the cell at the end of the job.
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
from stud_welding_msgs.msg import BendTest, BendTestPlan, InspectionResult, ReworkDecision, StudInspection
from stud_welding_msgs.srv import Inspect, RecordBendTest, RecordRework

from stud_common import names, ros_io
from stud_common.ros_io import Param
from stud_inspection import bend, qa_codes, qa_report, rework
from stud_inspection.inspection import InspectionLimits, Verdict, draw_inspection_overlay, inspect_studs
from stud_inspection.qa_params import LIMIT_PARAMS, QA_CODE_PARAM, overrides
from stud_perception import image_io

_LIMITS = InspectionLimits()
PARAMS = [
    ros_io.SENSOR_QOS_PARAM,
    QA_CODE_PARAM,
    *LIMIT_PARAMS,
    Param("nominal_length_mm", _LIMITS.nominal_length_mm, "the stud's length after weld [mm]", min=1.0, max=1000.0),
    Param("stud_diameter_mm", _LIMITS.stud_diameter_mm, "stud diameter [mm]", min=1.0, max=100.0),
    Param("min_collar_seen_deg", _LIMITS.min_collar_seen_deg, "a collar the camera sees less of (the rest hidden "
          "behind the stud) is not judged: the stud is not_inspected [deg]", min=0.0, max=360.0),
    Param("overlay_dir", "", "write each inspection's overlay PNG here (empty: none)"),
    Param("qa_dir", "", "the folder of the job's QA record (the sequencer's qa_dir): each decision re-writes "
          "its rework column (empty: decisions only go to rework_file and /inspection/rework)"),
    Param("rework_file", "", "append operator rework decisions here (JSON lines); empty: "
          f"<overlay_dir>/{rework.FILE_NAME}, or $ROS_HOME/stud_welding/{rework.FILE_NAME} without overlay_dir",
          read_only=True),
    Param("bend_file", "", f"append bend-test results here (JSON lines); empty: {bend.FILE_NAME} beside rework_file",
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
REWORK_QOS = QoSProfile(depth=10000, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)


def rework_path(p: dict) -> Path:
    """The rework decisions file: ``rework_file``, else in ``overlay_dir``, else in $ROS_HOME (~/.ros)/stud_welding."""
    if p["rework_file"]:
        return Path(p["rework_file"]).expanduser()
    if p["overlay_dir"]:
        return Path(p["overlay_dir"]) / rework.FILE_NAME
    home = os.environ.get("ROS_HOME") or os.path.join(os.path.expanduser("~"), ".ros")
    return Path(home) / "stud_welding" / rework.FILE_NAME


def bend_path(p: dict) -> Path:
    """The bend-test file: ``bend_file``, else beside the rework decisions file (:func:`rework_path`)."""
    return Path(p["bend_file"]).expanduser() if p["bend_file"] else rework_path(p).with_name(bend.FILE_NAME)


def limits_from(p: dict) -> InspectionLimits:
    """The ``qa_code`` profile's limits with the overrides set, for studs of the design given
    (CodeError / ValueError naming the value)."""
    code = qa_codes.profile(p["qa_code"], overrides(p, LIMIT_PARAMS))
    return code.limits(nominal_length_mm=p["nominal_length_mm"], stud_diameter_mm=p["stud_diameter_mm"],
                       min_collar_seen_deg=p["min_collar_seen_deg"])


def result_msg(targets, inspection, station: int, stamp, overlay_file: str, qa_code: str = "") -> InspectionResult:
    """The InspectionResult message of ``inspection`` (one entry per target, in their order)."""
    msg = InspectionResult(station=int(station), overlay_file=overlay_file, qa_code=qa_code)
    msg.header.stamp, msg.header.frame_id = stamp, "world"
    lim = inspection.limits
    msg.max_lean_deg, msg.position_tol_mm = lim.max_lean_deg, lim.position_tol_mm
    msg.nominal_length_mm, msg.height_tol_mm = lim.nominal_length_mm, lim.height_tol_mm
    msg.stud_diameter_mm, msg.height_tol_below_mm = lim.stud_diameter_mm, lim.height_below_mm
    msg.min_collar_coverage_deg, msg.min_collar_height_mm = lim.min_collar_coverage_deg, lim.min_collar_height_mm
    msg.min_collar_seen_deg = lim.min_collar_seen_deg
    nan = float("nan")
    for t, m in zip(targets, inspection.studs):
        s = StudInspection(stud_id=t.stud_id, verdict=_VERDICT_CODE[m.verdict], verdict_text=m.verdict.value,
                           reasons=list(m.reasons), planned_position=t.pose.position, planned_normal=t.normal,
                           measured=m.position_m is not None)
        if s.measured:
            s.base = Point(x=m.position_m[0], y=m.position_m[1], z=m.position_m[2])
            s.axis = Vector3(x=m.axis[0], y=m.axis[1], z=m.axis[2])
            s.lean_deg, s.height_mm = m.lean_deg, m.height_mm
            s.offset_x_mm, s.offset_y_mm = m.offset_mm
        if m.collar is not None:
            c = m.collar
            s.collar_measured = True
            s.collar_seen_deg, s.collar_coverage_deg, s.collar_gap_deg = c.seen_deg, c.covered_deg, c.gap_deg
            s.collar_height_mm = nan if c.height_mm is None else c.height_mm
            s.collar_gap_azimuth_deg = nan if c.gap_azimuth_deg is None else c.gap_azimuth_deg
        msg.studs.append(s)
    msg.unexpected_objects = [Point(x=o.position_m[0], y=o.position_m[1], z=o.position_m[2])
                              for o in inspection.unexpected]
    msg.unexpected_heights_mm = [o.height_mm for o in inspection.unexpected]
    return msg


class InspectorNode(Node):
    def __init__(self) -> None:
        super().__init__("inspector")
        self.p = ros_io.declare_params(self, PARAMS)
        try:
            self.limits = limits_from(self.p)
        except ValueError as exc:  # qa_codes.CodeError too
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
        self.bend_file = bend_path(self.p)
        self.pub_rework = self.create_publisher(ReworkDecision, names.INSPECTION_REWORK, REWORK_QOS)
        self.create_service(RecordRework, names.INSPECTION_RECORD_REWORK, self._on_record_rework, callback_group=cb)
        self.create_service(RecordBendTest, names.INSPECTION_RECORD_BEND_TEST, self._on_record_bend_test,
                            callback_group=cb)
        self.pub_bend_tests = self.create_publisher(BendTestPlan, names.INSPECTION_BEND_TESTS, ros_io.LATCHED_QOS)
        self._record_seen: tuple | None = None  # (mtime ns, size) of the QA record last published
        if self.p["qa_dir"]:
            self.create_timer(1.0, self._watch_record, callback_group=cb)
        self.diag = ros_io.Diagnostics(self)
        self.diag.set(self.diag.OK, "waiting for an inspection")
        self.create_timer(1.0, self.diag.publish)
        lim = self.limits
        self.get_logger().info(f"inspector ready: /inspection/inspect ({self.p['qa_code']}: lean <= "
                               f"{lim.max_lean_deg:g} deg, position +- {lim.position_tol_mm:g} mm, height "
                               f"{lim.nominal_length_mm:g} +{lim.height_tol_mm:g}/-{lim.height_below_mm:g} mm, collar "
                               f"{lim.min_collar_coverage_deg:g} deg >= {lim.min_collar_height_mm:g} mm)")

    def _on_input(self, sync: ros_io.StampSync, name: str, msg) -> None:
        with self._cond:
            sync.add(name, msg)

    def _on_view(self, view: dict) -> None:
        try:
            decoded = image_io.decode_view(view["info"], view["pose"].pose, view["depth"], view["color"],
                                           self.p["images_rectified"], image_io.view_topics(self))
        except (ros_io.MessageError, ValueError) as exc:
            self.get_logger().error(f"unusable view: {exc}", throttle_duration_sec=5.0)
            return
        self._views[ros_io.stamp_to_ns(view["depth"].header.stamp)] = (decoded.depth_m, decoded.camera,
                                                                        decoded.color_bgr)
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
        planned = np.array([(t.pose.position.x, t.pose.position.y, t.pose.position.z)
                            for t in req.targets]).reshape(-1, 3)
        normals = np.array([(t.normal.x, t.normal.y, t.normal.z) for t in req.targets]).reshape(-1, 3)
        welded = np.array([sid in set(req.welded_ids) for sid in ids], dtype=bool)
        inspection = inspect_studs(planned, normals, welded, depth_before, depth, camera, self.limits)
        overlay_file = ""
        if self.p["overlay_dir"]:
            out = Path(self.p["overlay_dir"])
            out.mkdir(parents=True, exist_ok=True)
            overlay_file = str(out / f"inspection_station_{req.station:02d}_{stamp_ns}.png")
            cv2.imwrite(overlay_file, draw_inspection_overlay(color, ids, planned, inspection, camera))
        resp.result = result_msg(req.targets, inspection, req.station, ros_io.ns_to_stamp(stamp_ns), overlay_file,
                                 self.p["qa_code"])
        self.pub_result.publish(resp.result)
        with self._cond:
            self._verdicts.update((s.stud_id, s.verdict_text) for s in resp.result.studs)
        counts = {}
        for m in inspection.studs:
            counts[m.verdict.value] = counts.get(m.verdict.value, 0) + 1
        summary = ", ".join(f"{k} {v}" for k, v in sorted(counts.items()))
        self.get_logger().info(f"station {req.station}: {summary}"
                               + (f", {len(inspection.unexpected)} unexpected object(s)"
                                  if inspection.unexpected else ""))
        self.diag.set(self.diag.OK, f"station {req.station}: {summary}")
        resp.success, resp.message = True, summary
        return resp

    def _update_qa_record(self) -> str:
        """Every decision and bend result so far into the QA record (and its bend-test list out on
        /inspection/bend_tests); what happened, for the reply."""
        if not self.p["qa_dir"]:
            return ""
        qa_dir = Path(self.p["qa_dir"])
        try:
            with qa_report.locked(qa_dir):
                decisions = rework.latest_decisions(self.rework_file)
                bends = bend.latest_results(self.bend_file)
                doc = qa_report.apply_operator_entries(qa_dir, {s: r.for_qa_record() for s, r in decisions.items()},
                                                       {s: r.for_qa_record() for s, r in bends.items()})
        except (ValueError, OSError) as exc:  # ReworkError, BendError: ValueErrors naming the file and line
            self.get_logger().error(f"QA record not updated: {exc}")
            return f"; the QA record was NOT updated ({exc})"
        if doc is None:
            return f"; {qa_dir / qa_report.JSON_NAME} does not exist yet: the cell writes it with this entry"
        self._watch_record()
        return f"; QA record updated ({qa_dir / qa_report.JSON_NAME})"

    def _watch_record(self) -> None:
        """Publish the QA record's bend-test list when the record changed (the cell wrote it at the end
        of its job, or an entry here re-wrote it)."""
        path = Path(self.p["qa_dir"]) / qa_report.JSON_NAME
        try:
            st = path.stat()
        except FileNotFoundError:
            return
        key = (st.st_mtime_ns, st.st_size)
        with self._cond:
            if key == self._record_seen:
                return
            self._record_seen = key
        try:
            doc = qa_report.read_record(path.parent)
        except ValueError as exc:
            self.get_logger().warn(f"bend-test list not published: {exc}", throttle_duration_sec=30.0)
            return
        if doc is not None:
            self.pub_bend_tests.publish(bend_plan_msg(doc, self.get_clock().now().to_msg()))

    def _known_verdict(self, stud_id: str) -> str | None:
        """The stud's verdict: this session's inspection, else the job's QA record."""
        with self._cond:
            verdict = self._verdicts.get(stud_id)
        if verdict is None and self.p["qa_dir"]:
            try:
                doc = qa_report.read_record(Path(self.p["qa_dir"]))
            except ValueError:
                doc = None
            row = next((r for r in (doc or {}).get("studs", []) if r["stud_id"] == stud_id), None)
            verdict = None if row is None or row["verdict"] == "not_welded" else row["verdict"]
        return verdict

    def _on_record_bend_test(self, req, resp):
        sid = req.stud_id.strip()
        try:
            record = bend.make_record(sid, req.result, float(req.angle_deg), req.note, req.operator_name,
                                      self._known_verdict(sid), time.time())
            bend.append_record(self.bend_file, record)
        except (bend.BendError, OSError) as exc:
            resp.success, resp.message = False, f"not recorded: {exc}"
            self.get_logger().warn(f"bend test of {req.stud_id!r} {resp.message}")
            return resp
        resp.success = True
        resp.message = (f"{record.stud_id}: bend test {record.result} by {record.operator} recorded in "
                        f"{self.bend_file}" + self._update_qa_record())
        self.get_logger().info(f"operator: {resp.message}" + (f" -- {record.note}" if record.note else ""))
        return resp

    def _on_record_rework(self, req, resp):
        verdict = self._known_verdict(req.stud_id.strip())
        try:
            record = rework.make_record(req.stud_id, req.decision, req.note, verdict, time.time(), req.operator_name)
            rework.append_record(self.rework_file, record)
        except (rework.ReworkError, OSError) as exc:
            resp.success, resp.message = False, f"not recorded: {exc}"
            self.get_logger().warn(f"rework decision on {req.stud_id!r} {resp.message}")
            return resp
        msg = ReworkDecision(stud_id=record.stud_id, decision=record.decision, verdict=record.verdict,
                             note=record.note, operator_name=record.operator)
        msg.header.stamp = ros_io.ns_to_stamp(int(record.stamp * 1e9))
        self.pub_rework.publish(msg)
        resp.success = True
        resp.message = (f"{record.stud_id} ({record.verdict}): {record.decision} by {record.operator} recorded in "
                        f"{self.rework_file}"
                        + self._update_qa_record())
        self.get_logger().info(f"operator: {resp.message}" + (f" -- {record.note}" if record.note else ""))
        return resp


def bend_plan_msg(doc: dict, stamp) -> BendTestPlan:
    """The BendTestPlan message of a QA record (its ``sampling`` list; empty without one)."""
    nan = float("nan")
    sampling = doc.get("sampling") or {}
    msg = BendTestPlan(qa_code=str((doc.get("code") or {}).get("profile", "")), seed=int(sampling.get("seed", 0)),
                       lot_welded=int(sampling.get("lot_welded", 0)))
    msg.header.stamp, msg.header.frame_id = stamp, "world"
    for t in sampling.get("bend_tests", []):
        msg.studs.append(BendTest(stud_id=t["stud_id"], reasons=list(t["reasons"]),
                                  angle_deg=nan if t.get("angle_deg") is None else float(t["angle_deg"]),
                                  direction=t.get("direction") or "", result=t.get("result") or "",
                                  bent_deg=nan if t.get("bent_deg") is None else float(t["bent_deg"]),
                                  note=t.get("note") or "", operator_name=t.get("operator") or "",
                                  time=t.get("time") or ""))
    return msg


def main(args=None) -> int:
    """`ros2 run stud_inspection inspector`: spin until Ctrl-C; the process exit code."""
    return ros_io.spin_node(InspectorNode, args, multithreaded=True)


if __name__ == "__main__":
    raise SystemExit(main())
