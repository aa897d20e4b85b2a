"""The rest of the cell, faked in the test process with real rclpy publishers and service servers:
what the HMI node subscribes to, and the services its buttons call (counting calls, keeping the
decision requests)."""
from __future__ import annotations

import json
import math
import time
import urllib.request

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.action import ActionServer
from sensor_msgs.msg import Image
from std_msgs.msg import String
from std_srvs.srv import Trigger
from stud_welding_msgs.action import WeldJob
from stud_welding_msgs.msg import (
    ArmState,
    BendTest,
    BendTestPlan,
    CellStatus,
    InspectionResult,
    ReworkDecision,
    Stud,
    StudInspection,
    StudLayout,
    WeldTarget,
    WeldTargetArray,
)
from stud_welding_msgs.srv import RecordBendTest, RecordRework, ResolveStud

from rosproc import wait_for
from stud_common import ros_io
from stud_hmi.model import CellState
from stud_perception import image_io

NAN = math.nan


def target(stud_id: str, status: int, xyz_m=(NAN, NAN, NAN), incl_deg=NAN, xy_error_m=NAN, view=0) -> WeldTarget:
    t = WeldTarget(stud_id=stud_id, status=status, inclination=incl_deg, xy_error=xy_error_m, view_index=view)
    t.status_text = {WeldTarget.STATUS_OK: "ok", WeldTarget.STATUS_NO_DEPTH: "no_depth",
                     WeldTarget.STATUS_OUT_OF_VIEW: "out_of_view",
                     WeldTarget.STATUS_NORMAL_UNCERTAIN: "normal_uncertain"}[status]
    t.pose.position.x, t.pose.position.y, t.pose.position.z = xyz_m
    return t


class FakeCell:
    """Publishers of /weld_targets, overlay, /arm/state, /cell/status, /diagnostics; Trigger servers
    for ``services`` (call counts in ``calls``); optionally a WeldJob action server."""

    def __init__(self, node, services=("/cell/stop", "/arm/stop"), decisions: bool = False):
        self.node = node
        self.calls = {s: 0 for s in services}
        self._srvs = [node.create_service(Trigger, s, self._handler(s)) for s in services]
        self.resolved: list[tuple[str, int]] = []     # /arm/resolve_stud requests (stud id, decision)
        self.reworked: list[tuple[str, str, str]] = []  # /inspection/record_rework requests (stud, decision, note)
        self.operators: list[str] = []                 # who signed each of them
        self.bent: list[tuple[str, str, float, str, str]] = []  # /inspection/record_bend_test (stud, result, angle,
                                                                 # note, operator)
        if decisions:
            self._srvs.append(node.create_service(ResolveStud, "/arm/resolve_stud", self._on_resolve))
            self._srvs.append(node.create_service(RecordRework, "/inspection/record_rework", self._on_rework))
            self._srvs.append(node.create_service(RecordBendTest, "/inspection/record_bend_test", self._on_bend))
        self.pub_bend_tests = node.create_publisher(BendTestPlan, "/inspection/bend_tests", ros_io.LATCHED_QOS)
        self.pub_inspection = node.create_publisher(InspectionResult, "/inspection/result", ros_io.LATCHED_QOS)
        self.pub_rework = node.create_publisher(ReworkDecision, "/inspection/rework", ros_io.LATCHED_QOS)
        self.pub_hand_eye = node.create_publisher(String, "/calibration/hand_eye", ros_io.LATCHED_QOS)
        self.pub_targets = node.create_publisher(WeldTargetArray, "/weld_targets", ros_io.RESULT_QOS)
        self.pub_overlay = node.create_publisher(Image, "/weld_targets/overlay", ros_io.RESULT_QOS)
        self.pub_arm = node.create_publisher(ArmState, "/arm/state", ros_io.RESULT_QOS)
        self.pub_cell = node.create_publisher(CellStatus, "/cell/status", ros_io.RESULT_QOS)
        self.pub_diag = node.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.pub_layout = node.create_publisher(StudLayout, "/drawing/layout", ros_io.LATCHED_QOS)
        self.job_result: WeldJob.Result | None = None

    def _handler(self, name: str):
        def handle(_req, resp):
            self.calls[name] += 1
            resp.success, resp.message = True, f"{name} done (fake)"
            return resp
        return handle

    def _on_resolve(self, req, resp):
        self.resolved.append((req.stud_id, int(req.decision)))
        resp.success, resp.message = True, f"{req.stud_id} recorded (fake)"
        return resp

    def _on_rework(self, req, resp):
        self.reworked.append((req.stud_id, req.decision, req.note))
        self.operators.append(req.operator_name)
        resp.success, resp.message = True, f"{req.stud_id}: {req.decision} recorded (fake)"
        return resp

    def _on_bend(self, req, resp):
        self.bent.append((req.stud_id, req.result, req.angle_deg, req.note, req.operator_name))
        resp.success, resp.message = True, f"{req.stud_id}: bend test {req.result} recorded (fake)"
        return resp

    def wait_for_hmi(self, port: int, proc, timeout_s: float = 30.0) -> None:
        """Until the HMI answers /healthz and subscribes to our topics (DDS discovery)."""
        def healthy() -> bool:
            assert proc.popen.poll() is None, f"hmi exited:\n{proc.output()}"
            try:
                return json.loads(urllib.request.urlopen(f"http://127.0.0.1:{port}/healthz", timeout=1).read())["ok"]
            except OSError:
                return False
        wait_for(healthy, timeout_s, spin=self.node.spin, what=f"hmi /healthz on port {port}")
        wait_for(lambda: all(self.node.count_subscribers(t) >= 1 for t in
                             ("/weld_targets", "/weld_targets/overlay", "/arm/state", "/cell/status")),
                 timeout_s, spin=self.node.spin, what="the hmi's subscriptions")

    # -- publishing ------------------------------------------------------------------------------------
    def targets(self, targets: list[WeldTarget], view: int = 0) -> None:
        arr = WeldTargetArray(targets=targets, algorithm="batch", view_index=view)
        arr.header.frame_id = "world"
        self.pub_targets.publish(arr)

    def layout(self, stud_ids: list[str], source_file: str = "part.dxf") -> None:
        """Latched, as the drawing node publishes it."""
        self.pub_layout.publish(StudLayout(source_file=source_file, studs=[
            Stud(id=sid, x=0.01 * i, y=0.0) for i, sid in enumerate(stud_ids)]))

    def overlay(self, width: int = 1280, height: int = 960) -> None:
        img = np.zeros((height, width, 3), np.uint8)
        img[:, : width // 2] = (0, 0, 255)  # left half red (BGR)
        self.pub_overlay.publish(image_io.numpy_to_image(img, "bgr8", frame_id="camera_color_optical_frame"))

    def arm(self, mode=ArmState.MODE_WELDING, current_stud="S0001", done=1, total=3, uncertain=(),
            errors=("joint 3 over temperature",), message="welding S0001") -> None:
        msg = ArmState(mode=mode, current_stud=current_stud, done=done, total=total, connected=True,
                       error_codes=[0x5001] * len(errors), errors=list(errors), message=message,
                       uncertain_studs=list(uncertain))
        msg.tool_pose.position.x, msg.tool_pose.position.z = 0.25, NAN
        self.pub_arm.publish(msg)

    def cell(self, state=CellStatus.STATE_WELDING, studs_welded=1, studs_total=3, unreachable=("S0099",),
             message="station 2: welding") -> None:
        text = CellState(state).text
        self.pub_cell.publish(CellStatus(state=state, state_text=text, station=2, stations_total=4,
                                         studs_total=studs_total, studs_welded=studs_welded, studs_failed=0,
                                         unreachable=list(unreachable), message=message))

    def inspection(self, verdicts: dict[str, tuple[str, list[str]]], station: int = 1, overlay_file: str = "") -> None:
        """A latched /inspection/result: stud id -> (verdict text, reasons)."""
        codes = {"pass": 0, "fail": 1, "missing": 2, "not_inspected": 3, "not_welded": 4}
        self.pub_inspection.publish(InspectionResult(station=station, overlay_file=str(overlay_file), studs=[
            StudInspection(stud_id=sid, verdict=codes[v], verdict_text=v, reasons=list(r))
            for sid, (v, r) in verdicts.items()]))

    def rework_recorded(self, stud_id: str, decision: str, verdict: str = "fail") -> None:
        self.pub_rework.publish(ReworkDecision(stud_id=stud_id, decision=decision, verdict=verdict))

    def bend_tests(self, tests: list[tuple[str, str, str]], qa_code: str = "gb50205") -> None:
        """A latched /inspection/bend_tests: (stud id, reason, result "" / "pass" / "fail") per stud, bent 30 deg."""
        self.pub_bend_tests.publish(BendTestPlan(qa_code=qa_code, seed=7, lot_welded=len(tests), studs=[
            BendTest(stud_id=sid, reasons=[why], angle_deg=30.0, result=result, bent_deg=30.0 if result else NAN,
                     operator_name="B. Welder" if result else "", time="2025-05-01T10:30:00+00:00" if result else "")
            for sid, why, result in tests]))

    def hand_eye(self, node: str, summary: dict) -> None:
        self.pub_hand_eye.publish(String(data=json.dumps({**summary, "node": node})))

    def diagnostic(self, name: str, level: int, message: str) -> None:
        self.pub_diag.publish(DiagnosticArray(status=[DiagnosticStatus(level=bytes([level]), name=name,
                                                                       message=message)]))

    # -- the arm's weld job action ----------------------------------------------------------------------
    def serve_weld_job(self, phases: list[tuple[str, str]], result: WeldJob.Result) -> ActionServer:
        """A WeldJob server that sends ``phases`` as feedback and ends with ``result``."""
        def execute(goal_handle):
            for i, (sid, phase) in enumerate(phases):
                goal_handle.publish_feedback(WeldJob.Feedback(stud_id=sid, phase=phase, done=i, total=len(phases)))
                time.sleep(0.05)
            goal_handle.succeed()
            return result
        self._action = ActionServer(self.node, WeldJob, "/arm/weld_job", execute_callback=execute)
        return self._action
