"""RM-65 driver node: `ros2 run rm65_driver driver` — a thin rclpy adapter over the ROS-free core.

Talks to the controller's JSON-over-TCP port (:mod:`.arm_client`), runs weld jobs
(:mod:`.weld_sequence`) with the journal (:mod:`.journal`) and the pre-motion checks
(:mod:`.safety`). Everything that decides anything lives there; this file declares parameters,
converts messages, and publishes.

Interfaces
  publishes  /arm/state (stud_welding_msgs/ArmState, reliable depth 10), /joint_states
             (sensor_msgs/JointState, joint1..joint6, rad), /diagnostics, and with
             ``publish_camera_pose`` /camera/pose (geometry_msgs/PoseStamped: weld-tool pose ×
             hand-eye, the optical frame in ``world``) — all at ``state_rate_hz``.
  action     /arm/weld_job (stud_welding_msgs/action/WeldJob); a cancel is graceful (see
             weld_sequence: motions before the trigger stop at once, a started weld completes).
  services   /arm/stop, /arm/pause, /arm/resume, /arm/estop (std_srvs/Trigger);
             /arm/resolve_stud (stud_welding_msgs/srv/ResolveStud);
             /arm/resolve_journal (stud_welding_msgs/srv/ResolveJournal).
  subscribes /arm/estop (std_msgs/Bool): true engages the e-stop latch, false releases it.

Weld-journal FAULT: a journal found damaged at start-up (anything but a torn last line), or one
that fails or changes while the driver runs, puts the driver in ``ArmState.MODE_FAULT``;
``/arm/state.message`` and ``/diagnostics`` (ERROR) name the file and the lines. Every weld job is
aborted at once with that message until an operator resolves it with /arm/resolve_journal
(accept the intact part, or load the intact copy); see :func:`.journal_repair.repair_journal`.

Parameters are checked at start-up, each against its range and all together against what the
weld job accepts (:class:`WeldParams`, :class:`SafetyLimits`): a bad value ends the node with one
line naming it and exit code 2.

The e-stop here is a *software* stop (``set_arm_stop`` + trigger output low + a latch that refuses
new jobs until released). It is not a safety-rated emergency stop: the cell's hardware e-stop
chain must stay wired to the controller.

Addresses: ``arm_ip`` defaults to 127.0.0.1 (the simulator, ``ros2 run rm65_driver simulator``)
so nothing in this repository reaches for real hardware by default; the factory address of a
real RM-65 controller is 192.168.1.18, port 8080.
"""
from __future__ import annotations

import os
import threading
import time
from pathlib import Path

import numpy as np
from geometry_msgs.msg import PoseStamped
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool
from std_srvs.srv import Trigger
from stud_welding_msgs.action import WeldJob
from stud_welding_msgs.msg import ArmState, WeldRecord, WeldTarget
from stud_welding_msgs.srv import MoveTo, ResolveJournal, ResolveStud

from stud_common import hand_eye_ros, ros_io
from stud_common.ros_io import Param

from . import protocol as P
from .arm_client import ArmClient, ArmError
from .journal import Journal
from .journal_records import JournalError
from .journal_repair import ACTION_ACCEPT_INTACT, ACTION_LOAD_BACKUP, repair_journal
from .journal_scan import JournalCorrupt
from .kinematics import D6_BY_VARIANT, DHModel, RM65Kinematics
from .safety import SafetyChecker, SafetyLimits
from .weld_job import JobResult, StudTarget, WeldParams
from .weld_sequence import WeldSequence

JOINT_NAMES = [f"joint{i}" for i in range(1, 7)]


def _vec3(name: str):
    return lambda v: None if len(v) == 3 else f"{name} needs 3 numbers, got {list(v)}"


def _default_journal() -> str:
    home = os.environ.get("ROS_HOME") or os.path.join(os.path.expanduser("~"), ".ros")
    return os.path.join(home, "stud_welding", "weld_journal.jsonl")


PARAMS = [
    Param("arm_ip", "127.0.0.1", "controller address; the real RM-65's factory address is 192.168.1.18 "
          "(default here: loopback, the simulator)", read_only=True),
    Param("tcp_port", P.DEFAULT_PORT, "controller JSON port (8080)", min=1, max=65535, read_only=True),
    Param("arm_variant", "RM65-B", "arm variant (sets the flange distance d6 of the kinematics)",
          choices=tuple(D6_BY_VARIANT), read_only=True),
    Param("connect_timeout_s", 2.0, "TCP connect timeout [s]", min=0.1, max=30.0),
    Param("reply_timeout_s", 1.0, "wait for a command's reply [s]", min=0.1, max=10.0),
    Param("state_rate_hz", 10.0, "arm state polling and /arm/state, /joint_states rate [Hz] "
          "(RealMan: poll no faster than every 20 ms)", min=0.5, max=50.0),
    Param("standoff_m", 0.05, "approach distance from the surface along the normal [m]", min=0.005, max=0.3),
    Param("tool_offset_m", 0.15, "flange -> weld-gun tip along the flange z axis (weld_tool frame) [m]",
          min=0.0, max=0.5),
    Param("plunge_m", 0.0, "how far beyond the surface the tip is commanded (gun spring travel) [m]",
          min=0.0, max=0.02),
    Param("tool_payload_kg", 1.0, "weld gun mass for the controller's tool frame [kg]", min=0.0, max=5.0),
    Param("tool_frame_name", "weld_gun", "controller tool frame name (<= 10 characters)",
          validate=lambda v: None if 0 < len(v) <= 10 else f"tool_frame_name {v!r} must be 1..10 characters"),
    Param("trigger_io", 1, "digital output that triggers the weld gun (controller DO 1..4, tool DO 1..2); "
          "it sources 2 mA at most: use an external relay module", min=1, max=4),
    Param("trigger_on_tool", False, "trigger through the tool-flange DO instead of the controller DO"),
    Param("set_io_mode", True, "switch the trigger IO to output mode before a job (Gen-3 controllers)"),
    Param("pulse_s", 0.2, "trigger pulse length [s]", min=0.0, max=5.0),
    Param("dwell_s", 0.5, "hold still after the pulse while the gun completes the weld [s]", min=0.0, max=10.0),
    Param("joint_speed_pct", 30, "joint-move speed [% of max]", min=1, max=100),
    Param("linear_speed_pct", 10, "linear-move speed [% of max]", min=1, max=100),
    Param("final_approach_m", 0.01, "the slow controlled final move: this last stretch before the contact at "
          "linear_speed_pct; the rest of the standoff and the retract at approach_speed_pct (0: the whole "
          "standoff slow) [m]", min=0.0, max=0.3),
    Param("approach_speed_pct", 30, "the fast straight approach to final_approach_m and the retract "
          "[% of max; within max_linear_speed_pct]", min=1, max=100),
    Param("stud_order", "tour", "the order a job's studs are welded in: 'tour' (a short joint-space path from "
          "the current joints and back), 'path' (no way back) or 'given' (the request's)",
          choices=("tour", "path", "given")),
    Param("max_joint_speed_pct", 50, "speed cap for joint moves [%]", min=1, max=100),
    Param("max_linear_speed_pct", 30, "speed cap for linear moves [%]", min=1, max=100),
    Param("workspace_min_m", [-0.70, -0.70, -0.02], "workspace box lower corner, world [m]",
          validate=_vec3("workspace_min_m")),
    Param("workspace_max_m", [0.70, 0.70, 1.10], "workspace box upper corner, world [m]",
          validate=_vec3("workspace_max_m")),
    Param("max_tool_tilt_deg", 60.0, "how far this cell's gun may lean from vertical (hose, cable, gun body) -- a "
          "property of the cell: studs are welded along the surface normal at any slope up to it [deg]",
          min=0.0, max=90.0),
    Param("yaw_step_deg", 15.0, "the free rotation about the stud's axis is searched in these steps for the "
          "reachable solution nearest the current joints [deg]", min=1.0, max=180.0),
    Param("motion_timeout_s", 60.0, "a motion that has not arrived by then aborts the job [s]", min=1.0, max=600.0),
    Param("reconnect_timeout_s", 10.0, "reconnection attempts before a job aborts [s]", min=0.5, max=300.0),
    Param("on_disconnect", "continue", "after a connection loss mid-weld: 'continue' with the next studs or 'abort'",
          choices=("continue", "abort")),
    Param("journal_file", "", "weld journal (JSON lines); empty: $ROS_HOME/stud_welding/weld_journal.jsonl",
          read_only=True),
    Param("publish_camera_pose", False, "publish /camera/pose = weld-tool pose x hand-eye (an eye-in-hand camera)"),
    *hand_eye_ros.PARAMS,  # hand_eye_xyz_m / hand_eye_rpy_deg, or hand_eye_file (/arm/move_to FRAME_CAMERA)
]


#: ResolveJournal.action -> journal_repair.repair_journal action
JOURNAL_ACTIONS = {ResolveJournal.Request.ACTION_ACCEPT_INTACT: ACTION_ACCEPT_INTACT,
                   ResolveJournal.Request.ACTION_LOAD_BACKUP: ACTION_LOAD_BACKUP}


def job_config(p: dict) -> tuple[WeldParams, SafetyLimits]:
    """The weld job's parameters and limits from the node's parameter values (raises ValueError)."""
    params = WeldParams(
        standoff_m=p["standoff_m"], tool_offset_m=p["tool_offset_m"], plunge_m=p["plunge_m"],
        tool_payload_kg=p["tool_payload_kg"], tool_frame_name=p["tool_frame_name"], trigger_io=p["trigger_io"],
        trigger_on_tool=p["trigger_on_tool"], set_io_mode=p["set_io_mode"], pulse_s=p["pulse_s"],
        dwell_s=p["dwell_s"], joint_speed_pct=p["joint_speed_pct"], linear_speed_pct=p["linear_speed_pct"],
        motion_timeout_s=p["motion_timeout_s"], reconnect_timeout_s=p["reconnect_timeout_s"],
        on_disconnect=p["on_disconnect"], final_approach_m=p["final_approach_m"],
        approach_speed_pct=p["approach_speed_pct"], stud_order=p["stud_order"])
    limits = SafetyLimits(
        workspace_min_m=tuple(p["workspace_min_m"]), workspace_max_m=tuple(p["workspace_max_m"]),
        max_tool_tilt_deg=p["max_tool_tilt_deg"], yaw_step_deg=p["yaw_step_deg"],
        max_joint_speed_pct=p["max_joint_speed_pct"], max_linear_speed_pct=p["max_linear_speed_pct"])
    return params, limits


def job_config_problem(p: dict) -> str | None:
    """Why the weld job would refuse these parameter values together (None: it accepts them)."""
    lo, hi = list(p["workspace_min_m"]), list(p["workspace_max_m"])
    if len(lo) == len(hi) == 3 and any(a >= b for a, b in zip(lo, hi)):
        return f"workspace_min_m={lo} must be below workspace_max_m={hi} on every axis (x, y, z)"
    try:
        job_config(p)
    except ValueError as exc:
        return f"combination refused by the weld job: {exc}"
    return None


WELDS_QOS = QoSProfile(depth=10000, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


# -- message <-> core conversions --------------------------------------------------------------


def target_from_msg(msg: WeldTarget) -> tuple[StudTarget | None, str]:
    """WeldTarget -> StudTarget, or (None, reason) for a target the matcher did not mark usable.

    The normal is ``msg.normal``; if that is zero, the z axis of ``msg.pose`` (outward normal).
    """
    if msg.status != WeldTarget.STATUS_OK:
        return None, f"matcher status {msg.status_text or msg.status}"
    n = np.array([msg.normal.x, msg.normal.y, msg.normal.z])
    if np.linalg.norm(n) < 1e-9:
        R, _ = ros_io.pose_to_rt(msg.pose)
        n = R[:, 2]
    p = msg.pose.position
    return StudTarget(msg.stud_id, [p.x, p.y, p.z], n), ""


def result_to_msg(res: JobResult, pre_skipped: list[tuple[str, str]]) -> WeldJob.Result:
    out = WeldJob.Result()
    out.welded = list(res.welded)
    out.skipped = [sid for sid, _ in pre_skipped] + list(res.skipped)
    out.failed = list(res.failed)
    out.messages = [f"{sid}: {why}" for sid, why in pre_skipped] + list(res.messages)
    out.success = bool(res.success)
    out.message = res.message
    return out


class DriverNode(Node):
    def __init__(self) -> None:
        super().__init__("rm65_driver")
        self.p = ros_io.declare_params(self, PARAMS, check=job_config_problem)
        p = self.p
        self.hand_eye = hand_eye_ros.hand_eye_in_use(self, p)
        self.calibration_topic = hand_eye_ros.CalibrationTopic(self, self.hand_eye)
        self.kin = RM65Kinematics(dh=DHModel.rm65(D6_BY_VARIANT[p["arm_variant"]]))
        self.client = ArmClient(p["arm_ip"], p["tcp_port"], p["connect_timeout_s"], p["reply_timeout_s"])
        self.journal_path = Path(p["journal_file"] or _default_journal()).expanduser()
        self.journal: Journal | None = None
        self._journal_fault: JournalError | None = None  # damage found when opening (the FAULT)
        try:
            self._open_journal()
        except OSError as exc:
            self.get_logger().fatal(f"cannot open the weld journal '{self.journal_path}': {exc}")
            raise SystemExit(2) from None
        self.sequence: WeldSequence | None = None
        self._job_lock = threading.Lock()
        self._estop = False
        self._message = ""
        self._last_state = None
        self._connected_logged: bool | None = None

        group = ReentrantCallbackGroup()
        self.pub_state = self.create_publisher(ArmState, "/arm/state", ros_io.RESULT_QOS)
        self.pub_joints = self.create_publisher(JointState, "/joint_states", 10)
        # Every confirmed weld, for the QA record and the inspection: reliable, and transient local
        # with a deep history so a subscriber that (re)starts mid-job still gets this job's welds.
        self.pub_welds = self.create_publisher(WeldRecord, "/arm/welds", WELDS_QOS)
        self.pub_camera = (self.create_publisher(PoseStamped, "/camera/pose", ros_io.CAMERA_PUB_QOS)
                           if p["publish_camera_pose"] else None)
        self.diag = ros_io.Diagnostics(self, hardware_id=f"RM65 {p['arm_ip']}:{p['tcp_port']}")
        self.create_timer(1.0, self.diag.publish, callback_group=group)
        self.create_service(Trigger, "/arm/stop", self._on_stop, callback_group=group)
        self.create_service(Trigger, "/arm/pause", self._on_pause, callback_group=group)
        self.create_service(Trigger, "/arm/resume", self._on_resume, callback_group=group)
        self.create_service(Trigger, "/arm/estop", self._on_estop_srv, callback_group=group)
        self.create_service(ResolveStud, "/arm/resolve_stud", self._on_resolve, callback_group=group)
        self.create_service(ResolveJournal, "/arm/resolve_journal", self._on_resolve_journal, callback_group=group)
        self.create_service(MoveTo, "/arm/move_to", self._on_move_to, callback_group=group)
        self.create_subscription(Bool, "/arm/estop", self._on_estop_topic, 10, callback_group=group)
        self.action = ActionServer(self, WeldJob, "/arm/weld_job", execute_callback=self._execute,
                                   goal_callback=self._on_goal, cancel_callback=self._on_cancel,
                                   callback_group=group)
        self._running = True
        self._wake = threading.Event()
        self._poller = threading.Thread(target=self._poll_loop, name="rm65-state", daemon=True)
        self._poller.start()
        self.get_logger().info(f"RM65 driver for {p['arm_ip']}:{p['tcp_port']} ({p['arm_variant']}), "
                               f"state at {p['state_rate_hz']:.1f} Hz, trigger DO{p['trigger_io']}"
                               f"{' (tool)' if p['trigger_on_tool'] else ''}")

    # -- the weld journal ------------------------------------------------------------------------
    def _open_journal(self) -> None:
        """Open the journal; damage puts the driver in FAULT instead (OSError: cannot read it at all)."""
        try:
            self.journal = Journal(self.journal_path)
        except JournalCorrupt as exc:
            self.journal, self._journal_fault = None, exc
            self.get_logger().error(f"FAULT: {exc}")
            return
        self._journal_fault = None
        for w in self.journal.warnings:
            self.get_logger().warn(f"weld journal: {w}")
        self.get_logger().info(f"weld journal {self.journal_path}: {len(self.journal.welded_ids)} welded, "
                               f"{len(self.journal.uncertain_ids)} uncertain stud(s)")

    @property
    def journal_fault(self) -> JournalError | None:
        """Why the journal cannot be trusted or written now (None: it can)."""
        if self._journal_fault is not None:
            return self._journal_fault
        j = self.journal
        return j.fault if j is not None else None

    def _fault_text(self, fault: JournalError) -> str:
        return f"weld journal FAULT: {fault} (weld jobs refused until /arm/resolve_journal)"

    # -- configuration per job ------------------------------------------------------------------
    def _make_sequence(self) -> WeldSequence:
        params, limits = job_config(self.p)
        assert self.journal is not None
        return WeldSequence(self.client, self.journal, SafetyChecker(self.kin, limits, params.tool_T), params)

    @property
    def tool_T(self) -> np.ndarray:
        T = np.eye(4)
        T[2, 3] = self.p["tool_offset_m"]
        return T

    # -- state publishing -------------------------------------------------------------------------
    def _poll_loop(self) -> None:
        backoff = 0.2
        while self._running:
            period = 1.0 / self.p["state_rate_hz"]
            t0 = time.monotonic()
            seq = self.sequence
            job_running = seq is not None and seq.running
            if not self.client.connected and not job_running:  # a running job reconnects by itself
                try:
                    self.client.connect()
                    backoff = 0.2
                except ArmError as exc:
                    self._log_connection(False, str(exc))
                    self._publish(None)
                    self._sleep(backoff)
                    backoff = min(backoff * 2, 5.0)
                    continue
            reading = None
            if self.client.connected:
                try:
                    reading = self.client.get_state()
                except ArmError as exc:
                    self.get_logger().warn(f"arm state not read: {exc}", throttle_duration_sec=5.0)
            self._log_connection(self.client.connected, self.client.last_error)
            self._publish(reading)
            self._sleep(period - (time.monotonic() - t0))

    def _sleep(self, seconds: float) -> None:
        self._wake.wait(max(0.0, seconds))  # set at shutdown

    def _log_connection(self, connected: bool, why: str) -> None:
        if connected != self._connected_logged:
            if connected:
                self.get_logger().info(f"connected to the controller at {self.p['arm_ip']}:{self.p['tcp_port']}")
            else:
                self.get_logger().warn(f"controller {self.p['arm_ip']}:{self.p['tcp_port']} not connected: {why}")
            self._connected_logged = connected

    def _mode(self, reading) -> int:
        seq = self.sequence
        if self._estop:
            return ArmState.MODE_ESTOP
        if self.journal_fault is not None:
            return ArmState.MODE_FAULT
        if not self.client.connected:
            return ArmState.MODE_DISCONNECTED
        if reading is not None and reading.error_codes:
            return ArmState.MODE_FAULT
        if self.client.paused:
            return ArmState.MODE_PAUSED
        if seq is not None and seq.running:
            return ArmState.MODE_WELDING if seq.phase in ("weld", "dwell") else ArmState.MODE_MOVING
        return ArmState.MODE_IDLE

    def _publish(self, reading) -> None:
        stamp = self.get_clock().now().to_msg()
        msg = ArmState()
        msg.header.stamp = stamp
        msg.header.frame_id = "world"
        msg.mode = self._mode(reading)
        msg.connected = self.client.connected
        seq = self.sequence
        if seq is not None and seq.running:
            msg.current_stud, msg.done, msg.total = seq.current_stud, seq.done, seq.total
        fault = self.journal_fault
        msg.message = self._fault_text(fault) if fault is not None else self._message
        msg.uncertain_studs = self.uncertain_studs()
        if reading is not None:
            self._last_state = reading
            T_tool = self.kin.fk(reading.joints_rad) @ self.tool_T  # weld_tool in world, whatever the controller's tool frame
            msg.joints = [float(v) for v in reading.joints_rad]
            msg.tool_pose = ros_io.rt_to_pose(T_tool[:3, :3], T_tool[:3, 3])
            msg.error_codes = [int(c) & 0xFFFF for c in reading.error_codes]
            msg.errors = reading.errors_text
            js = JointState()
            js.header.stamp = stamp
            js.name = JOINT_NAMES
            js.position = [float(v) for v in reading.joints_rad]
            self.pub_joints.publish(js)
            if self.pub_camera is not None:
                T_cam = T_tool @ self._hand_eye()
                cam = PoseStamped()
                cam.header.stamp = stamp
                cam.header.frame_id = "world"
                cam.pose = ros_io.rt_to_pose(T_cam[:3, :3], T_cam[:3, 3])
                self.pub_camera.publish(cam)
        self.pub_state.publish(msg)
        self._update_diagnostics(msg)

    def _publish_weld(self, stud_id: str, joints_rad: np.ndarray, job_id: str) -> None:
        T_tool = self.kin.fk(joints_rad) @ self.tool_T
        msg = WeldRecord(stud_id=stud_id, job_id=job_id, joints=[float(v) for v in joints_rad],
                         tool_pose=ros_io.rt_to_pose(T_tool[:3, :3], T_tool[:3, 3]))
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.header.frame_id = "world"
        self.pub_welds.publish(msg)

    def _hand_eye(self) -> np.ndarray:
        return self.hand_eye.T_tool_cam

    def uncertain_studs(self) -> list[str]:
        """The journal's uncertain studs that wait for an operator decision (/arm/resolve_stud):
        not the stud being welded now -- started and not yet confirmed is every weld's normal course."""
        journal = self.journal
        if journal is None:
            return []
        seq = self.sequence
        busy = seq.current_stud if seq is not None and seq.running else ""
        return sorted(s for s in journal.uncertain_ids if s != busy)

    def _update_diagnostics(self, msg: ArmState) -> None:
        d = self.diag
        journal, fault = self.journal, self.journal_fault
        values = dict(connected=msg.connected, mode=msg.mode, job=f"{msg.done}/{msg.total}",
                      current_stud=msg.current_stud, errors="; ".join(msg.errors) or "none",
                      uncertain_studs=len(msg.uncertain_studs) if journal is not None else "unknown",
                      journal_file=str(self.journal_path),
                      journal_damaged_lines=(", ".join(f"{Path(f).name}:{n}" for f, n in fault.report.lines[:20])
                                             if isinstance(fault, JournalCorrupt) else "none"))
        if self._estop:
            d.set(d.ERROR, "e-stop engaged (publish false on /arm/estop to release)", **values)
        elif fault is not None:
            d.set(d.ERROR, self._fault_text(fault), **values)
        elif not msg.connected:
            d.set(d.ERROR, f"controller not connected: {self.client.last_error}", **values)
        elif msg.errors:
            d.set(d.ERROR, "controller error: " + "; ".join(msg.errors), **values)
        elif msg.uncertain_studs:
            d.set(d.WARN, f"{len(msg.uncertain_studs)} uncertain stud(s) need an operator decision "
                          f"(/arm/resolve_stud): {', '.join(msg.uncertain_studs[:10])}", **values)
        else:
            d.set(d.OK, "connected", **values)

    # -- weld job action --------------------------------------------------------------------------
    def _on_goal(self, goal) -> GoalResponse:
        seq = self.sequence
        if self._estop:
            self.get_logger().warn("weld job rejected: e-stop engaged")
            return GoalResponse.REJECT
        if seq is not None and seq.running:
            self.get_logger().warn("weld job rejected: a job is already running")
            return GoalResponse.REJECT
        if self.journal_fault is not None:  # accepted, to be aborted with the reason (a rejection carries none)
            self.get_logger().warn("weld job refused: the weld journal is in FAULT")
        return GoalResponse.ACCEPT

    def _on_cancel(self, _goal_handle) -> CancelResponse:
        seq = self.sequence
        if seq is not None and seq.running:
            self.get_logger().info("weld job cancel requested: stopping at the next safe point")
            seq.cancel()
        return CancelResponse.ACCEPT

    def _execute(self, goal_handle) -> WeldJob.Result:
        goal = goal_handle.request
        fault = self.journal_fault
        if fault is not None:
            out = WeldJob.Result(success=False, message=f"refused: {self._fault_text(fault)}")
            goal_handle.abort()
            return out
        targets, pre_skipped = [], []
        for t in goal.targets:
            st, why = target_from_msg(t)
            if st is None:
                pre_skipped.append((t.stud_id, why))
            else:
                targets.append(st)
        with self._job_lock:
            seq = self._make_sequence()
            total = len(goal.targets)

            def feedback(stud_id: str, phase: str, done: int, _total: int) -> None:
                fb = WeldJob.Feedback(stud_id=stud_id, phase=phase, done=done + len(pre_skipped), total=total)
                goal_handle.publish_feedback(fb)

            seq.on_phase = feedback
            seq.on_welded = lambda stud_id, q, job=seq: self._publish_weld(stud_id, q, job.job_id)
            self.sequence = seq
            self.get_logger().info(f"weld job: {len(targets)} target(s), {len(pre_skipped)} not usable, "
                                   f"resume={goal.resume}")
            try:
                res = seq.run(targets, resume=goal.resume)
            except Exception as exc:  # the job must end with a result, never hang the action
                self.get_logger().error(f"weld job crashed: {exc!r}")
                seq.halt("internal error")
                res = JobResult(message=f"internal error: {exc!r}")
        self._message = res.message
        if self.journal_fault is not None:
            self.get_logger().error(f"FAULT: {self.journal_fault}")
        out = result_to_msg(res, pre_skipped)
        if goal_handle.is_cancel_requested:
            goal_handle.canceled()
        elif res.success:
            goal_handle.succeed()
        else:
            goal_handle.abort()
        text = (f"weld job ended: {res.message}; welded {len(out.welded)}, skipped {len(out.skipped)}, "
                f"failed {len(out.failed)}")
        # Two call sites: rclpy refuses one call site logging at two severities (ValueError), which
        # used to lose the result of every job that ended otherwise than the one before it.
        if res.success:
            self.get_logger().info(text)
        else:
            self.get_logger().warn(text)
        return out

    # -- services ---------------------------------------------------------------------------------
    def _stop_now(self, reason: str) -> tuple[bool, str]:
        seq = self.sequence
        if seq is not None and seq.running:
            seq.halt(reason)  # stop + trigger low + the job ends
            return True, f"stop sent; weld job halting ({reason})"
        try:
            self.client.stop(wait_reply=False)
        except ArmError as exc:
            return False, f"stop not sent: {exc}"
        try:
            self.client.set_do(self.p["trigger_io"], False, tool=self.p["trigger_on_tool"])
        except ArmError:
            pass  # the output may not be configured yet; the stop went out
        return True, "stop sent"

    def _on_move_to(self, req, resp):
        """Joint-space move of the weld tool (or, through the hand-eye transform, the camera) to a
        world pose: IK within joint limits and the workspace box are checked before anything is sent.
        Used by the cell sequencer to put the camera over a station."""
        resp.success, resp.message = self.move_to(req.pose, camera=req.frame == MoveTo.Request.FRAME_CAMERA)
        return resp

    def move_to(self, pose, camera: bool) -> tuple[bool, str]:
        if self._estop:
            return False, "e-stop engaged"
        seq = self.sequence
        if seq is not None and seq.running:
            return False, "a weld job is running"
        R, t = ros_io.pose_to_rt(pose)
        T_goal = np.eye(4)
        T_goal[:3, :3], T_goal[:3, 3] = R, t
        if camera:
            T_goal = T_goal @ np.linalg.inv(self._hand_eye())  # camera pose -> weld_tool pose
        lo, hi = np.asarray(self.p["workspace_min_m"]), np.asarray(self.p["workspace_max_m"])
        if np.any(T_goal[:3, 3] < lo) or np.any(T_goal[:3, 3] > hi):
            return False, f"tool position {np.round(T_goal[:3, 3], 3).tolist()} m is outside the workspace box"
        seed = self._last_state.joints_rad if self._last_state is not None else None
        ik = self.kin.ik(T_goal, q_seed=seed, tool=self.tool_T)
        if not ik.success:
            return False, f"unreachable: {ik.message or 'no IK solution within the joint limits'}"
        speed = min(self.p["joint_speed_pct"], self.p["max_joint_speed_pct"])
        try:
            with self._job_lock:
                self.client.move_joints_and_wait(ik.q, speed, timeout_s=self.p["motion_timeout_s"])
        except ArmError as exc:
            return False, f"move failed: {exc}"
        what = "camera" if camera else "tool"
        self.get_logger().info(f"moved the {what} to {np.round(t, 3).tolist()} m")
        return True, f"{what} at {np.round(t, 4).tolist()} m"

    def _on_stop(self, _req, resp):
        resp.success, resp.message = self._stop_now("stop requested")
        self.get_logger().warn(f"/arm/stop: {resp.message}")
        return resp

    def _on_pause(self, _req, resp):
        return self._pause_or_resume("pause", resp)

    def _on_resume(self, _req, resp):
        if self._estop:
            resp.success, resp.message = False, "e-stop engaged: publish false on /arm/estop first"
            return resp
        return self._pause_or_resume("resume", resp)

    def _pause_or_resume(self, verb: str, resp):
        """``verb`` ("pause"/"resume") the running weld job, or the arm itself when no job runs."""
        try:
            seq = self.sequence
            getattr(seq if seq is not None and seq.running else self.client, verb)()
            resp.success, resp.message = True, f"{verb}d"
        except ArmError as exc:
            resp.success, resp.message = False, f"{verb} failed: {exc}"
        return resp

    def _engage_estop(self, source: str) -> tuple[bool, str]:
        self._estop = True
        ok, text = self._stop_now(f"e-stop ({source})")
        self._message = f"e-stop engaged ({source})"
        self.get_logger().error(f"E-STOP from {source}: {text}")
        return ok, text

    def _on_estop_srv(self, _req, resp):
        resp.success, resp.message = self._engage_estop("/arm/estop service")
        return resp

    def _on_estop_topic(self, msg: Bool) -> None:
        if msg.data:
            self._engage_estop("/arm/estop topic")
        elif self._estop:
            self._estop = False
            self._message = "e-stop released"
            self.get_logger().warn("e-stop released from /arm/estop topic")

    def _on_resolve(self, req, resp):
        if self.journal is None or self.journal_fault is not None:
            resp.success = False
            resp.message = f"{self._fault_text(self.journal_fault)}: resolve the journal first"  # type: ignore[arg-type]
            return resp
        welded = req.decision == ResolveStud.Request.DECISION_WELDED
        if req.decision not in (ResolveStud.Request.DECISION_WELDED, ResolveStud.Request.DECISION_NOT_WELDED):
            resp.success, resp.message = False, f"unknown decision {req.decision}"
            return resp
        try:
            self.journal.resolve(req.stud_id, welded=welded, note="operator via /arm/resolve_stud")
            resp.success = True
            resp.message = f"{req.stud_id} recorded as {'welded' if welded else 'not welded'}"
            self.get_logger().info(f"resolve_stud: {resp.message}")
        except JournalError as exc:
            resp.success, resp.message = False, str(exc)
        return resp

    def _on_resolve_journal(self, req, resp):
        resp.success, resp.message = self.resolve_journal(req.action, req.note)
        if resp.success:
            self.get_logger().warn(f"resolve_journal: {resp.message}")
        else:
            self.get_logger().error(f"resolve_journal: {resp.message}")
        return resp

    def resolve_journal(self, action_code: int, note: str) -> tuple[bool, str]:
        """Leave the journal FAULT by an operator's ``action_code`` (ResolveJournal.ACTION_*)."""
        action = JOURNAL_ACTIONS.get(action_code)
        if action is None:
            return False, f"unknown action {action_code}: expected {sorted(JOURNAL_ACTIONS)}"
        if self.journal_fault is None:
            return False, f"the weld journal {self.journal_path} is not in FAULT: nothing to resolve"
        seq = self.sequence
        if seq is not None and seq.running:
            return False, "a weld job is running"
        with self._job_lock:
            if self.journal is not None:
                self.journal.close()  # it failed or changed while open: read it again from the disk
                self.journal = None
            done = ""
            try:
                done = repair_journal(self.journal_path, action, note=note or "operator via /arm/resolve_journal")
            except (JournalError, OSError) as exc:
                done = f"not repaired: {exc}"
            try:
                self._open_journal()
            except OSError as exc:
                self._journal_fault = JournalError(f"cannot open the weld journal {self.journal_path}: {exc}")
        fault = self.journal_fault
        if fault is not None:
            return False, f"{done}; still in FAULT: {fault}"
        assert self.journal is not None
        self._message = f"weld journal resolved ({action}): {done}"
        return True, (f"{done}; journal: {len(self.journal.welded_ids)} welded, "
                      f"{len(self.journal.uncertain_ids)} uncertain stud(s)")

    # -- shutdown ---------------------------------------------------------------------------------
    def shutdown(self) -> None:
        self._running = False
        self._wake.set()
        seq = self.sequence
        if seq is not None and seq.running:
            seq.halt("driver shutting down")
        self._poller.join(timeout=2.0)
        self.client.close()
        if self.journal is not None:
            self.journal.close()


def main(args=None) -> int:
    """Spin on a multi-threaded executor (a weld job blocks one thread while stop services stay
    responsive); Ctrl-C shuts the node down cleanly."""
    return ros_io.spin_node(DriverNode, args, multithreaded=True)


if __name__ == "__main__":
    raise SystemExit(main())
