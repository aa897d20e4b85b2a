"""Operator HMI node: `ros2 run stud_planner hmi`, then open http://127.0.0.1:8090/ on the cell PC.

A thin adapter between ROS and the web page: messages become plain values for
:mod:`stud_hmi.model` (what a row says) and JSON for :mod:`stud_hmi.server`
(HTTP + one WebSocket, ``/ws``); the page's buttons become std_srvs/Trigger calls. Everything an
integrator needs to build another HMI on the same interfaces is in docs/HMI.md.

  subscribes  /weld_targets (WeldTargetArray), /weld_targets/overlay (Image; downscaled, JPEG,
              at most ``overlay_rate_hz``), /arm/state (ArmState), /cell/status (CellStatus) — all
              RESULT_QOS; /registration/result (Registration), /drawing/layout (StudLayout),
              /inspection/result (InspectionResult), /calibration/hand_eye (String, JSON) —
              LATCHED_QOS; /inspection/rework (ReworkDecision, every decision); /inspection/bend_tests
              (BendTestPlan, LATCHED_QOS: the QA record's bend-test list); /diagnostics
              (WARN/ERROR/STALE -> alarms); /arm/weld_job/_action/feedback and .../status (the
              WeldJob action's own topics, read only: which stud is being welded, which jobs finished)
  calls       /cell/start, /cell/pause, /cell/resume, /cell/stop (the cell sequencer), /arm/stop,
              /arm/estop (rm65_driver) — std_srvs/Trigger; /arm/resolve_stud (ResolveStud: the
              uncertain-stud decision); /inspection/record_rework (RecordRework: the rework decision),
              /inspection/record_bend_test (RecordBendTest), both signed with the operator's name;
              /arm/weld_job/_action/get_result for the welded/skipped/failed lists of finished jobs
  publishes   /diagnostics (address, connected browsers)

What the page says (alarms, the safety banner, which buttons are valid, progress and timing) is
decided in :mod:`stud_hmi.model` (CellView), the plan of the part (every stud where it is, the
carriage on its rail, the station being worked) in :mod:`stud_hmi.part_plan`; this node feeds them
and sends their messages.

The server binds to 127.0.0.1 unless ``bind_address`` says otherwise: the page can start and
stop the cell, so opening it to a network is the integrator's decision, and takes an
``access_token`` to command anything (without one the page is view only); requests that name
another host (DNS rebinding) or come from another site's page are refused (docs/HMI.md). The E-stop button is a
*software* stop (see rm65_driver); it does not replace the cell's hardware e-stop chain.
"""
from __future__ import annotations

import base64
import json
import logging
import os
import queue
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import cv2
from action_msgs.msg import GoalStatus, GoalStatusArray
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.qos import qos_profile_action_status_default
from sensor_msgs.msg import Image
from std_msgs.msg import String
from std_srvs.srv import Trigger
from stud_welding_msgs.action import WeldJob
from stud_welding_msgs.msg import (
    ArmState,
    BendTestPlan,
    CellStatus,
    InspectionResult,
    Registration,
    ReworkDecision,
    StudLayout,
    WeldTargetArray,
)
from stud_welding_msgs.srv import RecordBendTest, RecordRework, ResolveStud

from stud_common import hand_eye_ros, names, ros_io
from stud_common.ros_io import Param, three_numbers
from stud_hmi.model import STUD_DECISIONS, ArmInfo, ArmMode, CellInfo, CellView, TargetInfo, Timeouts
from stud_hmi.part_plan import RM65_REACH_M, PartPlan, RailConfig, StationInfo
from stud_hmi.server import INSPECTION_OVERLAY_URL, HmiServer, WebSocketConnection, default_static_dir
from stud_inspection.inspector_node import REWORK_QOS
from stud_perception import image_io

PARAMS = [
    Param("port", 8090, "TCP port of the HMI page and its WebSocket (/ws)", min=1, max=65535, read_only=True),
    Param("bind_address", "127.0.0.1", "address to listen on: 127.0.0.1 = this computer only; 0.0.0.0 = every "
          "network interface (only on a cell network you trust: the page starts and stops the cell)", read_only=True),
    Param("allowed_origins", "", "comma-separated extra browser origins allowed to open the WebSocket "
          "(e.g. 'http://cell-pc:8090' behind a proxy); the page's own origin is always allowed; their host names "
          "pass the Host check", read_only=True),
    Param("access_token", "", "token (or PIN) a browser must give to open the WebSocket: open the page as "
          "http://host:port/?token=...; empty: none -- then, bound beyond loopback, the page is view only (its "
          "buttons move the arm)", read_only=True),
    Param("part_name", "", "the part shown on the page beside the drawing (empty: the drawing file's name without "
          "its extension)"),
    Param("static_dir", "", "folder holding index.html (a custom page); empty: the page shipped with stud_hmi",
          read_only=True),
    Param("inspection_overlay_dir", "", "serve inspection overlays (the PNG an /inspection/result names) only from "
          "this folder, the inspector's overlay_dir (empty: any PNG file)", read_only=True),
    Param("overlay_max_width", 960, "downscale the overlay to at most this width for the browser [px]",
          min=64, max=8192),
    Param("overlay_rate_hz", 5.0, "send at most this many overlay frames per second to the browsers [Hz]",
          min=0.1, max=30.0),
    Param("overlay_jpeg_quality", 80, "JPEG quality of the overlay sent to the browsers (1-100)", min=10, max=100),
    Param("service_timeout_s", 5.0, "a button's service call that has not answered after this is reported "
          "as failed [s]", min=0.1, max=120.0),
    Param("max_alarm_history", 50, "cleared alarms kept in the alarm history", min=1, max=1000),
    Param("arm_timeout_s", 2.0, "no /arm/state for this long raises alarm A103 and greys the motion buttons [s]",
          min=0.2, max=60.0),
    Param("cell_timeout_s", 5.0, "no /cell/status for this long raises alarm A111 [s] (the sequencer re-sends it "
          "every second)", min=1.0, max=600.0),
    Param("diagnostics_timeout_s", 10.0, "a node's WARN/ERROR alarm clears when the node has not repeated it for "
          "this long [s] (nodes publish /diagnostics every second)", min=1.0, max=600.0),
    Param("table_rate_hz", 5.0, "send the stud table at most this often when it changes [Hz]", min=0.2, max=50.0),
    # The plan of the part (stud_hmi.part_plan): the rail as the arm driver has it (pass the driver's values).
    Param("rail_length_m", 0.0, "the rail's travel as the arm driver's rail_length_m [m]: the plan draws the rail "
          "and the carriage; 0: no rail given (one is still drawn once /arm/state shows the carriage off zero)",
          min=0.0, max=100.0, read_only=True),
    Param("rail_mount_xyz_m", [0.0, 0.0, 0.0], "the arm's base on the carriage, as the driver's rail_mount_xyz_m "
          "[m]: the reach circle is drawn about it", validate=three_numbers("rail_mount_xyz_m"), read_only=True),
    Param("arm_reach_m", RM65_REACH_M, "the arm's working radius about its base, drawn around the carriage [m]",
          min=0.05, max=5.0, read_only=True),
]

@dataclass(frozen=True)
class ServiceCall:
    """One service a page command calls: its name, type, and the request built from the page's message."""

    name: str
    srv_type: type
    request: Callable[[dict], object]


def _trigger(name: str) -> ServiceCall:
    return ServiceCall(name, Trigger, lambda _msg: Trigger.Request())


def _resolve_request(msg: dict) -> ResolveStud.Request:
    welded = STUD_DECISIONS[msg["decision"]]
    return ResolveStud.Request(stud_id=msg["stud_id"], decision=ResolveStud.Request.DECISION_WELDED if welded
                               else ResolveStud.Request.DECISION_NOT_WELDED)


def _rework_request(msg: dict) -> RecordRework.Request:
    return RecordRework.Request(stud_id=str(msg.get("stud_id", "")), decision=str(msg.get("decision", "")),
                                note=str(msg.get("note", "")), operator_name=str(msg.get("operator", "")))


def _bend_request(msg: dict) -> RecordBendTest.Request:
    angle = msg.get("angle_deg")
    return RecordBendTest.Request(stud_id=str(msg.get("stud_id", "")), result=str(msg.get("result", "")),
                                  angle_deg=float(angle) if angle is not None else float("nan"),
                                  note=str(msg.get("note", "")), operator_name=str(msg.get("operator", "")))


#: Page command -> the services it calls, in this order (all are called; see docs/HMI.md). "ack"
#: (acknowledge alarms) is the HMI's own and calls none.
COMMANDS: dict[str, tuple[ServiceCall, ...]] = {
    "start": (_trigger(names.CELL_START),),
    "pause": (_trigger(names.CELL_PAUSE),),
    "resume": (_trigger(names.CELL_RESUME),),
    "stop": (_trigger(names.CELL_STOP), _trigger(names.ARM_STOP)),
    "estop": (_trigger(names.ARM_ESTOP), _trigger(names.CELL_STOP)),
    "ack": (),
    "resolve_stud": (ServiceCall(names.ARM_RESOLVE_STUD, ResolveStud, _resolve_request),),
    "record_rework": (ServiceCall(names.INSPECTION_RECORD_REWORK, RecordRework, _rework_request),),
    "record_bend_test": (ServiceCall(names.INSPECTION_RECORD_BEND_TEST, RecordBendTest, _bend_request),),
}
_PROVIDER = {"/cell": "the cell sequencer (stud_planner cell_sequencer)", "/arm": "the arm driver (rm65_driver driver)",
             "/inspection": "the inspector (stud_planner inspector)"}
_JOB_STATUS = {GoalStatus.STATUS_SUCCEEDED: "succeeded", GoalStatus.STATUS_CANCELED: "canceled",
               GoalStatus.STATUS_ABORTED: "aborted"}
WELD_JOB = names.ARM_WELD_JOB


@dataclass
class _Call:
    """One page command: its service calls, answered to the browser when all are done."""

    conn: WebSocketConnection
    cmd: str
    id: object
    services: tuple[ServiceCall, ...]
    deadline: float
    results: dict = field(default_factory=dict)    # service -> (success, message)
    futures: dict = field(default_factory=dict)    # service -> Future


class _RosLogHandler(logging.Handler):
    """The server thread's log records (connects, refused origins) into the node's log."""

    def __init__(self, logger) -> None:
        super().__init__(logging.INFO)
        self.logger = logger

    def emit(self, record: logging.LogRecord) -> None:
        text = record.getMessage()
        if record.levelno >= logging.ERROR:
            self.logger.error(text)
        elif record.levelno >= logging.WARNING:
            self.logger.warn(text)
        else:
            self.logger.info(text)


class HmiNode(Node):
    def __init__(self) -> None:
        super().__init__("hmi")
        self.p = ros_io.declare_params(self, PARAMS, on_change=self._on_params)
        self.view = CellView(Timeouts(self.p["arm_timeout_s"], self.p["cell_timeout_s"],
                                      self.p["diagnostics_timeout_s"]), self.p["max_alarm_history"])
        self.table = self.view.table
        self.plan = PartPlan(RailConfig(self.p["rail_length_m"], tuple(self.p["rail_mount_xyz_m"]),
                                        self.p["arm_reach_m"]))
        self._table_dirty = False
        self._overlay: Image | None = None
        self._layout_key: tuple | None = None
        self._commands: queue.SimpleQueue = queue.SimpleQueue()  # from the server thread
        self._calls: list[_Call] = []
        self._jobs_seen: dict[bytes, float] = {}                  # goal uuid -> its stamp (results asked for)
        self._jobs_to_fetch: dict[bytes, Any] = {}             # goal uuid -> GoalInfo

        self.clients_by_name = {c.name: self.create_client(c.srv_type, c.name)
                                for calls in COMMANDS.values() for c in calls}
        self.result_client = self.create_client(WeldJob.Impl.GetResultService, f"{WELD_JOB}/_action/get_result")
        self._wake = self.create_guard_condition(self._drain_commands)

        self.create_subscription(WeldTargetArray, names.WELD_TARGETS, self._on_targets, ros_io.RESULT_QOS)
        self.create_subscription(Image, names.WELD_TARGET_OVERLAY, self._on_overlay, ros_io.RESULT_QOS)
        self.create_subscription(ArmState, names.ARM_STATE, self._on_arm, ros_io.RESULT_QOS)
        self.create_subscription(CellStatus, names.CELL_STATUS, self._on_cell, ros_io.RESULT_QOS)
        self.create_subscription(Registration, names.REGISTRATION_RESULT, self._on_registration, ros_io.LATCHED_QOS)
        self.create_subscription(StudLayout, names.DRAWING_LAYOUT, self._on_layout, ros_io.LATCHED_QOS)
        self.create_subscription(InspectionResult, names.INSPECTION_RESULT, self._on_inspection, ros_io.LATCHED_QOS)
        self.create_subscription(ReworkDecision, names.INSPECTION_REWORK, self._on_rework, REWORK_QOS)
        self.create_subscription(BendTestPlan, names.INSPECTION_BEND_TESTS, self._on_bend_tests, ros_io.LATCHED_QOS)
        self.create_subscription(String, hand_eye_ros.TOPIC, self._on_hand_eye, ros_io.LATCHED_QOS)
        self.create_subscription(DiagnosticArray, names.DIAGNOSTICS, self._on_diagnostics, 50)
        self.create_subscription(WeldJob.Impl.FeedbackMessage, f"{WELD_JOB}/_action/feedback", self._on_feedback, 10)
        self.create_subscription(GoalStatusArray, f"{WELD_JOB}/_action/status", self._on_job_status,
                                 qos_profile_action_status_default)

        static_dir = self.p["static_dir"] or default_static_dir()
        origins = [o.strip() for o in self.p["allowed_origins"].split(",") if o.strip()]
        self._log_handler = _RosLogHandler(self.get_logger())
        logging.getLogger("stud_hmi.server").addHandler(self._log_handler)
        logging.getLogger("stud_hmi.server").setLevel(logging.INFO)
        try:
            self.server = HmiServer(static_dir, self.p["bind_address"], self.p["port"], on_command=self._on_command,
                                    allowed_origins=origins, hello={"version": 1, "commands": list(COMMANDS)},
                                    access_token=self.p["access_token"])
        except (OSError, FileNotFoundError) as exc:
            self.get_logger().fatal(f"cannot serve the HMI on {self.p['bind_address']}:{self.p['port']}: {exc} "
                                    "(set the port / bind_address / static_dir parameters)")
            raise SystemExit(2) from None
        self.server.start()

        self.diag = ros_io.Diagnostics(self)
        self.create_timer(1.0, self._publish_diagnostics)
        self.create_timer(0.1, self._check_calls)
        self.create_timer(1.0, self._tick)
        self._table_timer = self.create_timer(1.0 / self.p["table_rate_hz"], self._flush)
        self._overlay_timer = self.create_timer(1.0 / self.p["overlay_rate_hz"], self._send_overlay)
        self.get_logger().info(f"HMI on {self.server.address} (WebSocket /ws); "
                               + ("reachable from this computer only" if self.server.loopback_only
                                  else f"listening on {self.p['bind_address']}")
                               + ("; the WebSocket needs the access token" if self.p["access_token"] else ""))
        if self.server.commands_need_token:
            self.get_logger().warn(f"bound to {self.p['bind_address']} without an access_token: the page is VIEW ONLY "
                                   "(its buttons move the arm); set access_token to command from the network")

    def _on_params(self, update: dict) -> None:
        if "overlay_rate_hz" in update:
            self.destroy_timer(self._overlay_timer)
            self._overlay_timer = self.create_timer(1.0 / update["overlay_rate_hz"], self._send_overlay)
        if "table_rate_hz" in update:
            self.destroy_timer(self._table_timer)
            self._table_timer = self.create_timer(1.0 / update["table_rate_hz"], self._flush)
        if "max_alarm_history" in update:
            self.view.alarms.history_size = update["max_alarm_history"]
        timeouts = {k: update.get(f"{k}_timeout_s", self.p[f"{k}_timeout_s"]) for k in ("arm", "cell", "diagnostics")}
        self.view.timeouts = Timeouts(timeouts["arm"], timeouts["cell"], timeouts["diagnostics"])

    # -- ROS -> page -------------------------------------------------------------------------------
    def _on_layout(self, msg: StudLayout) -> None:
        # A reload of the same drawing keeps the weld states; another drawing starts a new table.
        key = (msg.source_file, tuple((s.id, round(s.x, 6), round(s.y, 6)) for s in msg.studs))
        if key != self._layout_key:
            self._layout_key = key
            self.view.set_layout((s.id for s in msg.studs), msg.source_file, self.p["part_name"], msg.warnings)
            self.plan.set_layout([s.id for s in msg.studs], [(s.x, s.y) for s in msg.studs],
                                 [s.diameter for s in msg.studs],
                                 [("O", (msg.mark_o.x, msg.mark_o.y)), ("A", (msg.mark_a.x, msg.mark_a.y)),
                                  ("B", (msg.mark_b.x, msg.mark_b.y)),
                                  *((label, (m.x, m.y)) for label, m in zip(msg.reference_mark_labels,
                                                                            msg.reference_marks))],
                                 msg.mark_diameter)
            self._table_dirty = True

    def _on_targets(self, msg: WeldTargetArray) -> None:
        self.table.update_view((TargetInfo(t.stud_id, t.status_text, int(t.status),
                                           (t.pose.position.x, t.pose.position.y, t.pose.position.z),
                                           t.xy_error, t.inclination, int(t.view_index)) for t in msg.targets),
                               view=int(msg.view_index), algorithm=msg.algorithm)
        self._table_dirty = True
        self._flush()  # a new view is worth showing at once

    def _on_feedback(self, msg) -> None:
        fb = msg.feedback
        self.view.weld_feedback(fb.stud_id, fb.phase, time.time())
        self._table_dirty = True

    def _on_job_status(self, msg: GoalStatusArray) -> None:
        for s in msg.status_list:
            uuid = bytes(s.goal_info.goal_id.uuid)
            if s.status in _JOB_STATUS and uuid not in self._jobs_seen:
                self._jobs_seen[uuid] = ros_io.stamp_to_ns(s.goal_info.stamp) * 1e-9
                self._jobs_to_fetch[uuid] = s.goal_info
        while len(self._jobs_seen) > 1000:
            self._jobs_seen.pop(next(iter(self._jobs_seen)))
        self._fetch_job_results()

    def _fetch_job_results(self) -> None:
        if not self._jobs_to_fetch or not self.result_client.service_is_ready():
            return
        for uuid, info in sorted(self._jobs_to_fetch.items(), key=lambda kv: ros_io.stamp_to_ns(kv[1].stamp)):
            future = self.result_client.call_async(WeldJob.Impl.GetResultService.Request(goal_id=info.goal_id))
            future.add_done_callback(self._on_job_result)
        self._jobs_to_fetch.clear()

    def _on_job_result(self, future) -> None:
        resp = future.result()
        if resp is None or resp.status not in _JOB_STATUS:
            return  # expired on the server (result_timeout) or unknown
        r = resp.result
        self.view.job_result(r.welded, r.skipped, r.failed)
        self._table_dirty = True
        self.server.publish({"type": "job", "status": _JOB_STATUS[resp.status], "success": r.success,
                             "message": r.message, "welded": list(r.welded), "skipped": list(r.skipped),
                             "failed": list(r.failed), "messages": list(r.messages)})
        self._flush()

    def _on_arm(self, msg: ArmState) -> None:
        if self.view.on_arm(ArmInfo(int(msg.mode), bool(msg.connected), msg.current_stud, msg.message,
                                    tuple(msg.errors), tuple(msg.uncertain_studs)), time.time()):
            self._table_dirty = True
        self.plan.on_arm(msg.rail_position_m, msg.rail_moving, msg.uncertain_studs)
        p = msg.tool_pose.position
        mode = self.view.arm_mode
        self.server.publish({
            "type": "arm", "mode": mode.text if isinstance(mode, ArmMode) else str(mode), "mode_code": int(msg.mode),
            "connected": bool(msg.connected), "current_stud": msg.current_stud, "done": int(msg.done),
            "total": int(msg.total), "error_codes": [int(c) for c in msg.error_codes], "errors": list(msg.errors),
            "message": msg.message, "tool_position_mm": [p.x * 1000.0, p.y * 1000.0, p.z * 1000.0],
            "joints_deg": [v * 57.29577951308232 for v in msg.joints],
            "uncertain_studs": list(msg.uncertain_studs),
            "rail_position_m": msg.rail_position_m, "rail_moving": bool(msg.rail_moving),
            "carriage": self.plan.carriage()})

    def _on_cell(self, msg: CellStatus) -> None:
        if self.view.on_cell(CellInfo(int(msg.state), int(msg.station), int(msg.stations_total), int(msg.studs_total),
                                      int(msg.studs_welded), int(msg.studs_failed), tuple(msg.unreachable), msg.message,
                                      tuple(msg.unreachable_reasons)), time.time()):
            self._table_dirty = True
        self.plan.on_cell(StationInfo(int(msg.state), int(msg.station), int(msg.stations_total),
                                      tuple(msg.unreachable), tuple(msg.unreachable_reasons),
                                      tuple(msg.camera_xyz_m), float(msg.camera_yaw_rad),
                                      tuple(msg.camera_footprint_m)))
        self.server.publish({
            "type": "cell", "state": msg.state_text, "state_code": int(msg.state), "station": int(msg.station),
            "stations_total": int(msg.stations_total), "studs_total": int(msg.studs_total),
            "studs_welded": int(msg.studs_welded), "studs_failed": int(msg.studs_failed),
            "unreachable": list(msg.unreachable), "unreachable_reasons": list(msg.unreachable_reasons),
            "message": msg.message})

    def _on_registration(self, msg: Registration) -> None:
        self.view.on_registration(bool(msg.valid), msg.residual * 1000.0, msg.message, time.time())
        self.plan.set_registration(bool(msg.valid), msg.m_local2world, msg.message)
        self.server.publish({"type": "registration", "valid": bool(msg.valid), "residual_mm": msg.residual * 1000.0,
                             "message": msg.message})

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        now = time.time()
        for s in msg.status:
            level = s.level[0] if isinstance(s.level, (bytes, bytearray)) else int(s.level)
            self.view.on_diagnostic(s.name, level, s.message, now)

    def _on_inspection(self, msg: InspectionResult) -> None:
        self.view.on_inspection(((s.stud_id, s.verdict_text, tuple(s.reasons)) for s in msg.studs), time.time())
        self._table_dirty = True
        # The overlay PNG the inspector wrote: served as the one file at INSPECTION_OVERLAY_URL (the
        # server checks it is a PNG); the page is told its URL, or that there is none to show.
        within = self.p["inspection_overlay_dir"] or None
        url = self.server.expose_png(INSPECTION_OVERLAY_URL, msg.overlay_file, within) if msg.overlay_file else None
        if msg.overlay_file and url is None:
            where = f" in {within}" if within else ""
            self.get_logger().warn(f"/inspection/result station {msg.station}: overlay_file {msg.overlay_file!r} "
                                   f"is not a readable PNG{where}: not shown", throttle_duration_sec=10.0)
        self.server.publish({"type": "inspection_overlay", "url": url, "station": int(msg.station),
                             "file": os.path.basename(msg.overlay_file),
                             "stamp": ros_io.stamp_to_ns(msg.header.stamp) * 1e-9})

    def _on_rework(self, msg: ReworkDecision) -> None:
        self.view.on_rework(msg.stud_id, msg.decision, time.time())
        self._table_dirty = True

    def _on_bend_tests(self, msg: BendTestPlan) -> None:
        def number(x: float) -> float | None:
            return float(x) if x == x else None  # NaN: not said

        self.view.on_bend_tests(({"stud_id": t.stud_id, "reasons": list(t.reasons), "angle_deg": number(t.angle_deg),
                                  "direction": t.direction, "result": t.result, "bent_deg": number(t.bent_deg),
                                  "note": t.note, "operator": t.operator_name, "time": t.time} for t in msg.studs),
                                msg.qa_code)
        self._table_dirty = True

    def _on_hand_eye(self, msg: String) -> None:
        try:
            summary = json.loads(msg.data)
        except ValueError as exc:
            self.get_logger().warn(f"{hand_eye_ros.TOPIC}: not JSON ({exc})", throttle_duration_sec=10.0)
            return
        if isinstance(summary, dict):
            self.view.on_hand_eye(str(summary.get("node", "?")), summary, time.time())

    def _on_overlay(self, msg: Image) -> None:
        self._overlay = msg  # encoded by the rate-capped timer: only the newest frame matters

    def _send_overlay(self) -> None:
        msg = self._overlay
        if msg is None or self.server.client_count == 0:
            return  # (kept: the first browser to connect gets it)
        self._overlay = None
        try:
            bgr = image_io.color_to_bgr(msg)
        except ros_io.MessageError as exc:
            self.get_logger().warn(f"/weld_targets/overlay: {exc}", throttle_duration_sec=10.0)
            self.diag.set(self.diag.WARN, f"overlay not shown: {exc}")
            return
        h, w = bgr.shape[:2]
        max_w = self.p["overlay_max_width"]
        if w > max_w:
            bgr = cv2.resize(bgr, (max_w, max(1, round(h * max_w / w))), interpolation=cv2.INTER_AREA)
        ok, jpeg = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, int(self.p["overlay_jpeg_quality"])])
        if not ok:
            self.get_logger().warn("overlay: JPEG encoding failed", throttle_duration_sec=10.0)
            return
        self.server.publish({"type": "overlay", "jpeg_base64": base64.b64encode(jpeg.tobytes()).decode("ascii"),
                             "width": int(bgr.shape[1]), "height": int(bgr.shape[0]),
                             "source_width": int(w), "source_height": int(h),
                             "stamp": ros_io.stamp_to_ns(msg.header.stamp) * 1e-9})

    def _flush(self) -> None:
        if self._table_dirty or self.plan.changed:  # the plan's colours are the table's states
            self.plan.changed = False
            self.server.publish(self.plan.message(self.table.rows()))
        if self._table_dirty:
            self._table_dirty = False
            self.server.publish(self.table.message())
        if self.view.changed:
            self.view.changed = False
            self.server.publish(self.view.status_message(time.time()))
        if self.view.alarms.changed:
            self.view.alarms.changed = False
            self.server.publish(self.view.alarms.message())

    def _tick(self) -> None:
        """Once a second: inputs that went silent, and the job's clock on the page."""
        self.view.tick(time.time())
        self.view.changed = True
        self._flush()

    # -- page -> ROS (buttons) -----------------------------------------------------------------------
    def _on_command(self, conn: WebSocketConnection, msg: dict) -> None:
        """Server thread: hand the command to the executor (rclpy calls stay on one thread)."""
        self._commands.put((conn, msg))
        self._wake.trigger()

    def _drain_commands(self) -> None:
        while True:
            try:
                conn, msg = self._commands.get_nowait()
            except queue.Empty:
                return
            try:
                self._start_call(conn, msg)
            except Exception as exc:  # a bug here must not take the operator's buttons down
                self.get_logger().error(f"command {msg!r} failed: {exc!r}")
                self.server.reply(conn, {"type": "reply", "cmd": msg.get("cmd"), "id": msg.get("id"), "ok": False,
                                         "results": [], "error": f"internal error: {exc!r}"})

    def _start_call(self, conn: WebSocketConnection, msg: dict) -> None:
        cmd, cid = msg.get("cmd"), msg.get("id")
        if not isinstance(cmd, str) or cmd not in COMMANDS:
            self.server.reply(conn, {"type": "reply", "cmd": cmd, "id": cid, "ok": False, "results": [],
                                     "error": f"unknown command {cmd!r}; expected one of {list(COMMANDS)}"})
            return
        now = time.time()
        refused = self.view.check_command(cmd, msg, now)
        if refused:
            self.get_logger().warn(f"operator: {cmd} (from {conn.peer}) refused: {refused}")
            self.server.reply(conn, {"type": "reply", "cmd": cmd, "id": cid, "ok": False, "results": [],
                                     "error": f"not valid now: {refused}"})
            return
        if cmd == "ack":
            n = self.view.acknowledge(str(msg.get("alarm", "all")), now)
            self.get_logger().info(f"operator: acknowledged {n} alarm(s) ({msg.get('alarm', 'all')}, from {conn.peer})")
            self.server.reply(conn, {"type": "reply", "cmd": cmd, "id": cid, "ok": True, "results": [],
                                     "message": f"{n} alarm(s) acknowledged"})
            self._flush()
            return
        what = (f" {msg.get('stud_id')} {msg.get('decision') or msg.get('result')}"
                + (f" by {msg.get('operator')}" if msg.get("operator") else "")) if "stud_id" in msg else ""
        self.get_logger().info(f"operator: {cmd}{what} (from {conn.peer}) -> "
                               f"{', '.join(c.name for c in COMMANDS[cmd])}")
        call = _Call(conn, cmd, cid, COMMANDS[cmd], time.monotonic() + self.p["service_timeout_s"])
        for service in call.services:
            srv, client = service.name, self.clients_by_name[service.name]
            if not client.service_is_ready():
                provider = _PROVIDER.get("/" + srv.split("/")[1], "its provider")
                call.results[srv] = (False, f"{srv} is not available: is {provider} running?")
                continue
            future = client.call_async(service.request(msg))
            call.futures[srv] = future
            future.add_done_callback(lambda f, c=call, s=srv: self._on_service_done(c, s, f))
        self._calls.append(call)
        self._maybe_reply(call)

    def _on_service_done(self, call: _Call, srv: str, future) -> None:
        if srv in call.results:
            return  # already timed out
        try:
            resp = future.result()
            call.results[srv] = (bool(resp.success), resp.message)
        except Exception as exc:  # the call itself failed (service gone mid-call)
            call.results[srv] = (False, f"{srv} call failed: {exc}")
        self._maybe_reply(call)

    def _check_calls(self) -> None:
        now = time.monotonic()
        for call in list(self._calls):
            if now < call.deadline:
                continue
            for srv, future in call.futures.items():
                if srv not in call.results:
                    self.clients_by_name[srv].remove_pending_request(future)
                    call.results[srv] = (False, f"{srv} did not answer within {self.p['service_timeout_s']:.1f} s")
            self._maybe_reply(call)
        self._fetch_job_results()

    def _maybe_reply(self, call: _Call) -> None:
        if call not in self._calls or len(call.results) < len(call.services):
            return
        self._calls.remove(call)
        results = [{"service": s.name, "success": call.results[s.name][0], "message": call.results[s.name][1]}
                   for s in call.services]
        ok = all(r["success"] for r in results)
        text = "; ".join(f"{r['service']}: {'ok' if r['success'] else 'FAILED'} {r['message']}".rstrip()
                         for r in results)
        if ok:  # (rclpy refuses two severities from one call site)
            self.get_logger().info(f"operator: {call.cmd} -> {text}")
        else:
            self.get_logger().warn(f"operator: {call.cmd} -> {text}")
        self.server.reply(call.conn, {"type": "reply", "cmd": call.cmd, "id": call.id, "ok": ok, "results": results,
                                      "message": text})

    # -- housekeeping ----------------------------------------------------------------------------------
    def _publish_diagnostics(self) -> None:
        self.diag.set(self.diag.OK, f"serving {self.server.address}", clients=self.server.client_count,
                      bind_address=self.p["bind_address"], port=self.server.port)
        self.diag.publish()

    def destroy_node(self) -> None:
        # After Ctrl-C the ROS context is already shut down: the server's last lines cannot go to rosout.
        handler = getattr(self, "_log_handler", None)
        if handler is not None:
            logging.getLogger("stud_hmi.server").removeHandler(handler)
        server = getattr(self, "server", None)
        if server is not None:
            server.stop()
        super().destroy_node()


def main(args=None) -> int:
    """`ros2 run stud_hmi hmi`: spin until Ctrl-C; the process exit code."""
    return ros_io.spin_node(HmiNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
