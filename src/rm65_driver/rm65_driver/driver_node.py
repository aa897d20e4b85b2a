"""RM-65 driver node: `ros2 run rm65_driver driver` — a thin rclpy adapter over the ROS-free core.

Talks to the controller's JSON-over-TCP port (:mod:`.arm_client`), runs weld jobs
(:mod:`.weld_sequence`) with the journal (:mod:`.journal`) and the pre-motion checks
(:mod:`.safety`). Everything that decides anything lives there. The adapter itself, by concern:
the parameters (:mod:`.driver_params`), state polling and publishing with the diagnostics
(:mod:`.driver_status`), the services and the e-stop (:mod:`.driver_services`); this module
converts messages, opens the journal, runs the WeldJob action and holds ``main``.

Interfaces
  publishes  /arm/state (stud_welding_msgs/ArmState, reliable depth 10), /joint_states
             (sensor_msgs/JointState, joint1..joint6, rad), /diagnostics, and with
             ``publish_camera_pose`` /camera/pose (geometry_msgs/PoseStamped: weld-tool pose ×
             hand-eye, the optical frame in ``world``) — all at ``state_rate_hz``; /arm/reach_config
             (std_msgs/String, latched: JSON of the reach test's configuration, :mod:`.reach`).
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

Parameters (:mod:`.driver_params`) are checked at start-up, each against its range and all
together against what the weld job accepts (:class:`~.weld_job.WeldParams`,
:class:`~.safety.SafetyLimits`): a bad value ends the node with one line naming it and exit code 2.

The e-stop here is a *software* stop (``set_arm_stop`` + trigger output low + a latch that refuses
new jobs until released). It is not a safety-rated emergency stop: the cell's hardware e-stop
chain must stay wired to the controller.

Addresses: ``arm_ip`` defaults to 127.0.0.1 (the simulator, ``ros2 run rm65_driver simulator``)
so nothing in this repository reaches for real hardware by default; the factory address of a
real RM-65 controller is 192.168.1.18, port 8080.
"""
from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
from geometry_msgs.msg import PoseStamped
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, String
from std_srvs.srv import Trigger
from stud_welding_msgs.action import WeldJob
from stud_welding_msgs.msg import ArmState, WeldRecord, WeldTarget
from stud_welding_msgs.srv import MoveTo, ResolveJournal, ResolveStud

from stud_common import hand_eye_ros, ros_io

from .arm_client import ArmClient
from .driver_params import PARAMS, default_journal, job_config, job_config_problem, safety_checker
from .driver_services import DriverServices
from .driver_status import DriverStatus
from .journal import Journal
from .journal_records import JournalError
from .journal_scan import JournalCorrupt
from .kinematics import D6_BY_VARIANT, DHModel, RM65Kinematics
from .reach import Reach
from .safety import SafetyChecker
from .weld_job import JobResult, StudTarget
from .weld_sequence import WeldSequence
from stud_common import names

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
    return StudTarget(msg.stud_id, np.array([p.x, p.y, p.z]), n), ""


def result_to_msg(res: JobResult, pre_skipped: list[tuple[str, str]]) -> WeldJob.Result:
    """The action's result: the job's, after the targets refused before it started (``pre_skipped``)."""
    out = WeldJob.Result()
    out.welded = list(res.welded)
    out.skipped = [sid for sid, _ in pre_skipped] + list(res.skipped)
    out.failed = list(res.failed)
    out.messages = [f"{sid}: {why}" for sid, why in pre_skipped] + list(res.messages)
    out.success = bool(res.success)
    out.message = res.message
    return out


class DriverNode(DriverStatus, DriverServices, Node):
    """The driver: parameters, journal and weld-job action here; state in :class:`DriverStatus`,
    services in :class:`DriverServices`."""

    def __init__(self) -> None:
        super().__init__("rm65_driver")
        self.p = ros_io.declare_params(self, PARAMS, check=job_config_problem)
        p = self.p
        if not p["stud_length_mm"] > 0:
            self.get_logger().warn(f"stud_length_mm not set: the retract (standoff_m={p['standoff_m']:g} m) is not "
                                   "checked against the welded stud's height; set it to the stud's standing height")
        self.hand_eye = hand_eye_ros.hand_eye_in_use(self, p)
        self.calibration_topic = hand_eye_ros.CalibrationTopic(self, self.hand_eye)
        self.kin = RM65Kinematics(dh=DHModel.rm65(D6_BY_VARIANT[p["arm_variant"]]))
        self.client = ArmClient(p["arm_ip"], p["tcp_port"], p["connect_timeout_s"], p["reply_timeout_s"])
        self.journal_path = Path(p["journal_file"] or default_journal()).expanduser()
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
        self.pub_state = self.create_publisher(ArmState, names.ARM_STATE, ros_io.RESULT_QOS)
        self.pub_joints = self.create_publisher(JointState, names.JOINT_STATES, 10)
        # Every confirmed weld, for the QA record and the inspection: reliable, and transient local
        # with a deep history so a subscriber that (re)starts mid-job still gets this job's welds.
        self.pub_welds = self.create_publisher(WeldRecord, names.ARM_WELDS, WELDS_QOS)
        self.pub_camera = (self.create_publisher(PoseStamped, names.CAMERA_POSE, ros_io.CAMERA_PUB_QOS)
                           if p["publish_camera_pose"] else None)
        self.diag = ros_io.Diagnostics(self, hardware_id=f"RM65 {p['arm_ip']}:{p['tcp_port']}")
        self.create_timer(1.0, self.diag.publish, callback_group=group)
        # The reach test's configuration for the planner (rm65_driver.reach): reliable + transient local.
        self.pub_reach_config = self.create_publisher(String, names.ARM_REACH_CONFIG, ros_io.LATCHED_QOS)
        self._reach_config_sent = ""
        self._publish_reach_config()
        self.create_timer(1.0, self._publish_reach_config, callback_group=group)
        self.create_service(Trigger, names.ARM_STOP, self._on_stop, callback_group=group)
        self.create_service(Trigger, names.ARM_PAUSE, self._on_pause, callback_group=group)
        self.create_service(Trigger, names.ARM_RESUME, self._on_resume, callback_group=group)
        self.create_service(Trigger, names.ARM_ESTOP, self._on_estop_srv, callback_group=group)
        self.create_service(ResolveStud, names.ARM_RESOLVE_STUD, self._on_resolve, callback_group=group)
        self.create_service(ResolveJournal, names.ARM_RESOLVE_JOURNAL, self._on_resolve_journal, callback_group=group)
        self.create_service(MoveTo, names.ARM_MOVE_TO, self._on_move_to, callback_group=group)
        self.create_subscription(Bool, names.ARM_ESTOP, self._on_estop_topic, 10, callback_group=group)
        self.action = ActionServer(self, WeldJob, names.ARM_WELD_JOB, execute_callback=self._execute,
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
        params, _limits = job_config(self.p)
        assert self.journal is not None
        return WeldSequence(self.client, self.journal, self.safety_checker(), params)

    def safety_checker(self) -> SafetyChecker:
        """The checks of a weld job and of /arm/move_to with the parameters as they are now."""
        return safety_checker(self.p, self._hand_eye(), self.kin)

    def reach(self) -> Reach:
        """The reach test as the planner gets it (``/arm/reach_config``)."""
        params, _limits = job_config(self.p)
        return self.safety_checker().reach_for(params.standoff_m, params.plunge_m)

    def _publish_reach_config(self) -> None:
        """``/arm/reach_config`` (latched): the configuration of this driver's reach test, whenever it
        changed (a parameter set at run time), so the planner's verdicts stay the driver's."""
        text = self.reach().config.to_json()
        if text != self._reach_config_sent:
            self.pub_reach_config.publish(String(data=text))
            self._reach_config_sent = text

    @property
    def tool_T(self) -> np.ndarray:
        T = np.eye(4)
        T[2, 3] = self.p["tool_offset_m"]
        return T

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
