"""RM-65 driver node: `ros2 run rm65_driver driver` — a thin rclpy adapter over the ROS-free core.

Talks to the controller's JSON-over-TCP port (:mod:`~rm65_driver.protocol.arm_client`), runs weld
jobs (:mod:`~rm65_driver.weld.weld_sequence`) with the journal (:mod:`~rm65_driver.journal.writer`)
and the pre-motion checks (:mod:`~rm65_driver.weld.safety`). Everything that decides anything lives
there. The adapter itself, by concern: the parameters (:mod:`.params`), the state its parts share
(:mod:`.shared_state`), state polling and publishing with the diagnostics (:mod:`.status`), the
services and the e-stop (:mod:`.services`) -- each an object the node owns; this module converts
messages, runs the WeldJob action and holds ``main``.

Interfaces
  publishes  /arm/state (stud_welding_msgs/ArmState, reliable depth 10), /joint_states
             (sensor_msgs/JointState, joint1..joint6, rad), /diagnostics, and with
             ``publish_camera_pose`` /camera/pose (geometry_msgs/PoseStamped: weld-tool pose ×
             hand-eye, the optical frame in ``world``) — all at ``state_rate_hz``; /arm/reach_config
             (std_msgs/String, latched: JSON of the reach test's configuration, :mod:`rm65_driver.weld.reach`).
  action     /arm/weld_job (stud_welding_msgs/action/WeldJob); a cancel is graceful (see
             weld_sequence: motions before the trigger stop at once, a started weld completes).
  services   /arm/stop, /arm/pause, /arm/resume, /arm/estop (std_srvs/Trigger);
             /arm/move_to (stud_welding_msgs/srv/MoveTo; with a rail, optionally the carriage first);
             /arm/rail_move (stud_welding_msgs/srv/RailMove: the carriage, with a rail);
             /arm/resolve_stud (stud_welding_msgs/srv/ResolveStud);
             /arm/resolve_journal (stud_welding_msgs/srv/ResolveJournal).
  subscribes /arm/estop (std_msgs/Bool): true engages the e-stop latch, false releases it.

Weld-journal FAULT: a journal found damaged at start-up (anything but a torn last line), or one
that fails or changes while the driver runs, puts the driver in ``ArmState.MODE_FAULT``;
``/arm/state.message`` and ``/diagnostics`` (ERROR) name the file and the lines. Every weld job is
aborted at once with that message until an operator resolves it with /arm/resolve_journal
(accept the intact part, or load the intact copy); see :func:`~rm65_driver.journal.repair.repair_journal`.

Parameters (:mod:`.params`) are checked at start-up, each against its range and all
together against what the weld job accepts (:class:`~rm65_driver.weld.weld_job.WeldParams`,
:class:`~rm65_driver.weld.safety.SafetyLimits`): a bad value ends the node with one line naming it
and exit code 2.

The e-stop here is a *software* stop (``set_arm_stop`` + trigger output low + a latch that refuses
new jobs until released). It is not a safety-rated emergency stop: the cell's hardware e-stop
chain must stay wired to the controller.

The rail (``rail_length_m`` > 0; :mod:`~rm65_driver.rail.control`): the arm rides a linear axis, the
controller's expansion joint. ``world`` is then the rail's frame; the weld targets and /arm/move_to poses
arrive in it and are converted to the arm's base with the carriage's position
(:func:`stud_common.frames.world_T_base`); /arm/state, /joint_states (``rail_joint``, m) and /arm/welds
carry the carriage. The carriage moves only while the arm is still and never during a weld job; stop
and e-stop stop it too. With ``rail_length_m`` 0 there is no rail and ``world`` is the arm's base frame.

Addresses: ``arm_ip`` defaults to 127.0.0.1 (the simulator, ``ros2 run rm65_driver simulator``)
so nothing in this repository reaches for real hardware by default; the factory address of a
real RM-65 controller is 192.168.1.18, port 8080.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from std_msgs.msg import String
from stud_welding_msgs.action import WeldJob
from stud_welding_msgs.msg import WeldTarget

from rm65_driver.driver.params import (
    PARAMS,
    default_journal,
    goal_tolerances,
    job_config,
    job_config_problem,
    rail_axis,
)
from rm65_driver.driver.services import DriverServices
from rm65_driver.driver.shared_state import DriverState
from rm65_driver.driver.status import DriverStatus
from rm65_driver.kinematics.rm65 import D6_BY_VARIANT, DHModel, RM65Kinematics
from rm65_driver.protocol.arm_client import ArmClient, ArmError
from rm65_driver.rail.control import RailControl, target_in_base
from rm65_driver.weld.goal_checks import GoalTolerances, check_target_fields
from rm65_driver.weld.weld_job import JobResult, StudTarget
from rm65_driver.weld.weld_sequence import WeldSequence
from stud_common import hand_eye_ros, names, ros_io
from stud_common.vocabulary import WeldPhase

# -- message <-> core conversions --------------------------------------------------------------


def target_from_msg(msg: WeldTarget, tol: GoalTolerances = GoalTolerances()) -> tuple[StudTarget | None, str]:
    """WeldTarget -> StudTarget, or (None, reason) for a target the matcher did not mark usable or
    whose position, normal and orientation are not consistent (:mod:`.goal_checks`: the normal is
    the authority, the orientation must agree with it)."""
    if msg.status != WeldTarget.STATUS_OK:
        return None, f"matcher status {msg.status_text or msg.status}"
    p, n, q = msg.pose.position, msg.normal, msg.pose.orientation
    return check_target_fields(msg.stud_id, (p.x, p.y, p.z), (n.x, n.y, n.z), (q.x, q.y, q.z, q.w), tol)


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


class DriverNode(Node):
    """The driver: parameters and the weld-job action here; what its parts share in :attr:`state`
    (:class:`DriverState`), state publishing in :attr:`status`, services in :attr:`arm_services` (not
    ``services``: rclpy's :class:`Node` lists its service servers under that name)."""

    def __init__(self) -> None:
        super().__init__("rm65_driver")
        p = ros_io.declare_params(self, PARAMS, check=job_config_problem)
        if not p["stud_length_mm"] > 0:
            self.get_logger().warn(f"stud_length_mm not set: the retract (standoff_m={p['standoff_m']:g} m) is not "
                                   "checked against the welded stud's height; set it to the stud's standing height")
        hand_eye = hand_eye_ros.hand_eye_in_use(self, p)
        self.calibration_topic = hand_eye_ros.CalibrationTopic(self, hand_eye)
        client = ArmClient(p["arm_ip"], p["tcp_port"], p["connect_timeout_s"], p["reply_timeout_s"])
        self.state = DriverState(p, self.get_logger(), client,
                                 RM65Kinematics(dh=DHModel.rm65(D6_BY_VARIANT[p["arm_variant"]])), hand_eye,
                                 Path(p["journal_file"] or default_journal()).expanduser(),
                                 RailControl(client, rail_axis(p), p["rail_mount_xyz_m"]))
        if self.state.rail.present and p["workspace_max_m"][0] < p["rail_length_m"]:
            self.get_logger().warn(f"the workspace box is in world, the rail's frame: it ends at x = "
                                   f"{p['workspace_max_m'][0]:g} m, the rail runs to {p['rail_length_m']:g} m; every "
                                   "pose beyond the box is refused (widen workspace_max_m)")
        try:
            self.state.open_journal()
        except OSError as exc:
            self.get_logger().fatal(f"cannot open the weld journal '{self.state.journal_path}': {exc}")
            raise SystemExit(2) from None

        group = ReentrantCallbackGroup()
        self.status = DriverStatus(self, self.state, group)
        self.arm_services = DriverServices(self, self.state, group)
        self.action = ActionServer(self, WeldJob, names.ARM_WELD_JOB, execute_callback=self._execute,
                                   goal_callback=self._on_goal, cancel_callback=self._on_cancel,
                                   callback_group=group)
        # The reach test's configuration for the planner (rm65_driver.weld.reach): reliable + transient local.
        self.pub_reach_config = self.create_publisher(String, names.ARM_REACH_CONFIG, ros_io.LATCHED_QOS)
        self._reach_config_sent = ""
        self._publish_reach_config()
        self.create_timer(1.0, self._publish_reach_config, callback_group=group)
        self.status.start()
        self.get_logger().info(f"RM65 driver for {p['arm_ip']}:{p['tcp_port']} ({p['arm_variant']}), "
                               f"state at {p['state_rate_hz']:.1f} Hz, trigger DO{p['trigger_io']}"
                               f"{' (tool)' if p['trigger_on_tool'] else ''}"
                               + (f", on a rail of {p['rail_length_m']:g} m" if self.state.rail.present else ""))

    # -- configuration per job ------------------------------------------------------------------
    def _make_sequence(self, world_T_base: np.ndarray | None = None) -> WeldSequence:
        s = self.state
        params, _limits = job_config(s.p)
        assert s.journal is not None
        return WeldSequence(s.client, s.journal, s.safety_checker(world_T_base), params)

    def _publish_reach_config(self) -> None:
        """``/arm/reach_config`` (latched): the configuration of this driver's reach test, whenever it
        changed (a parameter set at run time), so the planner's verdicts stay the driver's."""
        text = self.state.reach().config.to_json()
        if text != self._reach_config_sent:
            self.pub_reach_config.publish(String(data=text))
            self._reach_config_sent = text

    def _job_base_in_world(self) -> tuple[np.ndarray | None, float, str]:
        """The arm's base in world for a job (the carriage read now), the carriage (m), or (None, 0, why not)."""
        rail = self.state.rail
        if not rail.present:
            return np.eye(4), 0.0, ""
        try:
            reading = rail.read()
        except ArmError as exc:
            return None, 0.0, f"the carriage's position is unknown: {exc}"
        if reading is not None and reading.moving:
            return None, 0.0, "the carriage is moving: a weld job starts only with it still"
        return rail.world_T_base(), rail.position_m, ""

    # -- weld job action --------------------------------------------------------------------------
    def _on_goal(self, goal) -> GoalResponse:
        seq = self.state.sequence
        if self.state.estop:
            self.get_logger().warn("weld job rejected: e-stop engaged")
            return GoalResponse.REJECT
        if seq is not None and seq.running:
            self.get_logger().warn("weld job rejected: a job is already running")
            return GoalResponse.REJECT
        if self.state.journal_fault is not None:  # accepted, to be aborted with the reason (a rejection carries none)
            self.get_logger().warn("weld job refused: the weld journal is in FAULT")
        return GoalResponse.ACCEPT

    def _on_cancel(self, _goal_handle) -> CancelResponse:
        seq = self.state.sequence
        if seq is not None and seq.running:
            self.get_logger().info("weld job cancel requested: stopping at the next safe point")
            seq.cancel()
        return CancelResponse.ACCEPT

    def _execute(self, goal_handle) -> WeldJob.Result:
        goal = goal_handle.request
        s = self.state
        fault = s.journal_fault
        if fault is not None:
            out = WeldJob.Result(success=False, message=f"refused: {s.fault_text(fault)}")
            goal_handle.abort()
            return out
        targets, pre_skipped = [], []
        tol = goal_tolerances(s.p)
        for t in goal.targets:
            st, why = target_from_msg(t, tol)
            if st is None:
                pre_skipped.append((t.stud_id, why))
            else:
                targets.append(st)
        with s.job_lock:
            W, carriage_m, why = self._job_base_in_world()
            if W is None:
                self.get_logger().warn(f"weld job refused: {why}")
                goal_handle.abort()
                return WeldJob.Result(success=False, message=f"refused: {why}")
            if s.rail.present:
                targets = [target_in_base(t, W) for t in targets]
            seq = self._make_sequence(W)
            if s.rail.present:  # journalled with each weld: its world pose is the carriage's x the joints'
                seq.cycle.rail_position_m = carriage_m
            total = len(goal.targets)

            def feedback(stud_id: str, phase: WeldPhase, done: int, _total: int) -> None:
                fb = WeldJob.Feedback(stud_id=stud_id, phase=str(phase), done=done + len(pre_skipped), total=total)
                goal_handle.publish_feedback(fb)

            seq.on_phase = feedback
            seq.on_welded = lambda stud_id, q, job=seq, W=W, c=carriage_m: self.status.publish_weld(
                stud_id, q, job.job_id, W, c)
            s.sequence = seq
            self.get_logger().info(f"weld job: {len(targets)} target(s), {len(pre_skipped)} not usable, "
                                   f"resume={goal.resume}")
            try:
                res = seq.run(targets, resume=goal.resume)
            except Exception as exc:  # the job must end with a result, never hang the action
                self.get_logger().error(f"weld job crashed: {exc!r}")
                seq.halt("internal error")
                res = JobResult(message=f"internal error: {exc!r}")
        s.message = res.message
        if s.journal_fault is not None:
            self.get_logger().error(f"FAULT: {s.journal_fault}")
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
        # would lose the result of a job that ended otherwise than the one before it.
        if res.success:
            self.get_logger().info(text)
        else:
            self.get_logger().warn(text)
        return out

    # -- shutdown ---------------------------------------------------------------------------------
    def shutdown(self) -> None:
        s = self.state
        self.status.stop()
        seq = s.sequence
        if seq is not None and seq.running:
            seq.halt("driver shutting down")
        self.status.join(timeout_s=2.0)
        s.client.close()
        if s.journal is not None:
            s.journal.close()


def main(args=None) -> int:
    """Spin on a multi-threaded executor (a weld job blocks one thread while stop services stay
    responsive); Ctrl-C shuts the node down cleanly."""
    return ros_io.spin_node(DriverNode, args, multithreaded=True)


if __name__ == "__main__":
    raise SystemExit(main())
