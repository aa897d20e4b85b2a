"""The arm driver's services: stop, pause, resume, e-stop (service and topic), move_to, rail_move,
resolve_stud and resolve_journal.

:class:`DriverServices` is a member of :class:`~rm65_driver.driver.driver_node.DriverNode` (it creates
the services; the state they act on is the node's :class:`~rm65_driver.driver.shared_state.DriverState`).
The e-stop is a *software* stop (``set_arm_stop`` + trigger output low + a
latch that refuses new jobs until ``false`` on ``/arm/estop``), not a safety-rated one.
``move_to`` checks the workspace box (m) and the reach test (:mod:`rm65_driver.weld.reach`: the IK within the
joint limits, as the planner checks the pose) before anything moves.

With a rail: ``rail_move`` (and ``move_to`` with ``move_rail``) moves the carriage while the arm is
still -- it takes the job lock an arm move and a weld job hold, checks that the controller runs no
arm trajectory, and is refused during a weld job; stop and e-stop stop the carriage too
(``expand_set_speed`` 0 besides ``set_arm_stop``).
"""
from __future__ import annotations

import numpy as np
from rclpy.callback_groups import CallbackGroup
from rclpy.node import Node
from std_msgs.msg import Bool
from std_srvs.srv import Trigger
from stud_welding_msgs.srv import MoveTo, RailMove, ResolveJournal, ResolveStud

from rm65_driver.driver.shared_state import DriverState
from rm65_driver.journal.records import JournalError
from rm65_driver.journal.repair import ACTION_ACCEPT_INTACT, ACTION_LOAD_BACKUP, repair_journal
from rm65_driver.protocol.arm_client import ArmCommandError, ArmError
from rm65_driver.rail.axis import RailRequestError
from stud_common import names, ros_io
from stud_common.hand_eye_in_use import tool_in_world

#: ResolveJournal.action -> journal.repair.repair_journal action
JOURNAL_ACTIONS = {ResolveJournal.Request.ACTION_ACCEPT_INTACT: ACTION_ACCEPT_INTACT,
                   ResolveJournal.Request.ACTION_LOAD_BACKUP: ACTION_LOAD_BACKUP}


class DriverServices:
    """Service and e-stop handlers of :class:`~rm65_driver.driver.driver_node.DriverNode` (state lives in
    :class:`~rm65_driver.driver.shared_state.DriverState`)."""

    def __init__(self, node: Node, state: DriverState, group: CallbackGroup) -> None:
        self._node = node
        self.state = state
        node.create_service(Trigger, names.ARM_STOP, self._on_stop, callback_group=group)
        node.create_service(Trigger, names.ARM_PAUSE, self._on_pause, callback_group=group)
        node.create_service(Trigger, names.ARM_RESUME, self._on_resume, callback_group=group)
        node.create_service(Trigger, names.ARM_ESTOP, self._on_estop_srv, callback_group=group)
        node.create_service(ResolveStud, names.ARM_RESOLVE_STUD, self._on_resolve, callback_group=group)
        node.create_service(ResolveJournal, names.ARM_RESOLVE_JOURNAL, self._on_resolve_journal, callback_group=group)
        node.create_service(MoveTo, names.ARM_MOVE_TO, self._on_move_to, callback_group=group)
        if state.rail.present:
            node.create_service(RailMove, names.ARM_RAIL_MOVE, self._on_rail_move, callback_group=group)
        node.create_subscription(Bool, names.ARM_ESTOP, self._on_estop_topic, 10, callback_group=group)

    # -- services ---------------------------------------------------------------------------------
    def _stop_now(self, reason: str) -> tuple[bool, str]:
        s = self.state
        seq = s.sequence
        if seq is not None and seq.running:
            seq.halt(reason)  # stop + trigger low + the job ends
            self._stop_rail()
            return True, f"stop sent; weld job halting ({reason})"
        try:
            s.client.stop(wait_reply=False)
        except ArmError as exc:
            return False, f"stop not sent: {exc}"
        self._stop_rail()
        try:
            s.client.set_do(s.p["trigger_io"], False, tool=s.p["trigger_on_tool"])
        except ArmError:
            pass  # the output may not be configured yet; the stop went out
        return True, "stop sent"

    def _stop_rail(self) -> None:
        """The axis's own stop, besides the arm's (whether set_arm_stop stops it is undocumented)."""
        try:
            self.state.rail.stop()
        except ArmError as exc:
            self._node.get_logger().warn(f"rail stop (expand_set_speed 0) not confirmed: {exc}")

    def _on_move_to(self, req, resp):
        """Joint-space move of the weld tool (or, through the hand-eye transform, the camera) to a
        world pose: IK within joint limits and the workspace box are checked before anything is sent.
        Used by the cell sequencer to put the camera over a station."""
        resp.success, resp.message = self.move_to(req.pose, camera=req.frame == MoveTo.Request.FRAME_CAMERA,
                                                  rail_position_m=req.rail_position_m if req.move_rail else None)
        return resp

    def move_to(self, pose, camera: bool, rail_position_m: float | None = None) -> tuple[bool, str]:
        """The tool (or camera) to a ``world`` pose; with ``rail_position_m`` the carriage there first."""
        s = self.state
        if s.estop:
            return False, "e-stop engaged"
        seq = s.sequence
        if seq is not None and seq.running:
            return False, "a weld job is running"
        why = self._rail_move_problem(rail_position_m) if rail_position_m is not None else ""
        if why:
            return False, why
        if s.rail.moving:
            return False, "the carriage is moving"
        R, t = ros_io.pose_to_rt(pose)
        T_goal = np.eye(4)
        T_goal[:3, :3], T_goal[:3, 3] = R, t
        if camera:
            T_goal = tool_in_world(T_goal, s.hand_eye_T())  # camera pose -> weld_tool pose
        lo, hi = np.asarray(s.p["workspace_min_m"]), np.asarray(s.p["workspace_max_m"])
        if np.any(T_goal[:3, 3] < lo) or np.any(T_goal[:3, 3] > hi):
            return False, f"tool position {np.round(T_goal[:3, 3], 3).tolist()} m is outside the workspace box"
        seed = s.last_state.joints_rad if s.last_state is not None else None
        T_base = T_goal
        if s.rail.present:  # world -> the arm's base, with the carriage where it will be
            T_base = np.linalg.inv(s.rail.world_T_base(rail_position_m)) @ T_goal
        # Whether: the reach test the planner applies too (rm65_driver.weld.reach); then the solution
        # nearest the current joints, or the verdict's own when the search from here finds none.
        W = s.rail.world_T_base(rail_position_m) if s.rail.present else np.eye(4)
        verdict = s.reach().tool_poses(T_base[None], W)[0]
        if not verdict.ok:
            where = f" with the carriage at {rail_position_m:.3f} m" if rail_position_m is not None else ""
            return False, f"unreachable{where}: {verdict.reason}"
        ik = s.kin.ik(T_base, q_seed=seed, tool=s.tool_T, prefer_signs=s.p["preferred_joint_signs"])
        q = ik.q if ik.success else verdict.q
        assert q is not None  # an accepted verdict carries its solution
        speed = min(s.p["joint_speed_pct"], s.p["max_joint_speed_pct"])
        try:
            with s.job_lock:
                if rail_position_m is not None:
                    self._move_rail_locked(rail_position_m, s.p["rail_speed_pct"])
                s.client.move_joints_and_wait(q, speed, timeout_s=s.p["motion_timeout_s"])
        except ArmError as exc:
            return False, f"move failed: {exc}"
        what = "camera" if camera else "tool"
        self._node.get_logger().info(f"moved the {what} to {np.round(t, 3).tolist()} m")
        return True, f"{what} at {np.round(t, 4).tolist()} m"

    # -- the rail ---------------------------------------------------------------------------------
    def _on_rail_move(self, req, resp):
        speed = int(req.speed_pct) or self.state.p["rail_speed_pct"]
        resp.success, resp.message = self.rail_move(req.position_m, speed)
        resp.position_m = self.state.rail.position_m
        if resp.success:  # two call sites: rclpy refuses one call site logging at two severities
            self._node.get_logger().info(f"/arm/rail_move: {resp.message}")
        else:
            self._node.get_logger().warn(f"/arm/rail_move: {resp.message}")
        return resp

    def _rail_move_problem(self, position_m: float, speed_pct: int = 1) -> str:
        """Why the carriage cannot go to ``position_m`` now ("" if it can)."""
        s = self.state
        if s.rail.axis is None:
            return "this driver has no rail (rail_length_m is 0)"
        if s.estop:
            return "e-stop engaged"
        seq = s.sequence
        if seq is not None and seq.running:
            return "a weld job is running: the carriage moves only between jobs"
        if not 1 <= speed_pct <= 100:
            return f"rail speed {speed_pct} %: expected 1..100"
        try:
            s.rail.axis.check_position(position_m)
        except RailRequestError as exc:
            return str(exc)
        return ""

    def rail_move(self, position_m: float, speed_pct: int) -> tuple[bool, str]:
        """The carriage to ``position_m`` (m) at ``speed_pct`` %, the arm still; returns once it arrived."""
        why = self._rail_move_problem(position_m, speed_pct)
        if why:
            return False, why
        try:
            with self.state.job_lock:
                reached = self._move_rail_locked(position_m, speed_pct)
        except ArmError as exc:
            return False, f"rail move failed: {exc}"
        return True, f"carriage at {reached:.4f} m"

    def _move_rail_locked(self, position_m: float, speed_pct: int) -> float:
        """Under the job lock: move the carriage, refused while the controller runs an arm trajectory."""
        s = self.state
        if s.client.current_trajectory() != "none":
            raise ArmCommandError("expand_set_pos", 0, "the arm is moving: the carriage moves only while it is still")
        return s.rail.move(position_m, speed_pct, timeout_s=s.p["motion_timeout_s"])

    def _on_stop(self, _req, resp):
        resp.success, resp.message = self._stop_now("stop requested")
        self._node.get_logger().warn(f"/arm/stop: {resp.message}")
        return resp

    def _on_pause(self, _req, resp):
        return self._pause_or_resume("pause", resp)

    def _on_resume(self, _req, resp):
        if self.state.estop:
            resp.success, resp.message = False, "e-stop engaged: publish false on /arm/estop first"
            return resp
        return self._pause_or_resume("resume", resp)

    def _pause_or_resume(self, verb: str, resp):
        """``verb`` ("pause"/"resume") the running weld job, or the arm itself when no job runs."""
        try:
            seq = self.state.sequence
            getattr(seq if seq is not None and seq.running else self.state.client, verb)()
            resp.success, resp.message = True, f"{verb}d"
        except ArmError as exc:
            resp.success, resp.message = False, f"{verb} failed: {exc}"
        return resp

    def _engage_estop(self, source: str) -> tuple[bool, str]:
        self.state.estop = True
        ok, text = self._stop_now(f"e-stop ({source})")
        self.state.message = f"e-stop engaged ({source})"
        self._node.get_logger().error(f"E-STOP from {source}: {text}")
        return ok, text

    def _on_estop_srv(self, _req, resp):
        resp.success, resp.message = self._engage_estop("/arm/estop service")
        return resp

    def _on_estop_topic(self, msg: Bool) -> None:
        if msg.data:
            self._engage_estop("/arm/estop topic")
        elif self.state.estop:
            self.state.estop = False
            self.state.message = "e-stop released"
            self._node.get_logger().warn("e-stop released from /arm/estop topic")

    def _on_resolve(self, req, resp):
        if self.state.journal is None or self.state.journal_fault is not None:
            resp.success = False
            resp.message = f"{self.state.fault_text(self.state.journal_fault)}: resolve the journal first"
            return resp
        welded = req.decision == ResolveStud.Request.DECISION_WELDED
        if req.decision not in (ResolveStud.Request.DECISION_WELDED, ResolveStud.Request.DECISION_NOT_WELDED):
            resp.success, resp.message = False, f"unknown decision {req.decision}"
            return resp
        try:
            self.state.journal.resolve(req.stud_id, welded=welded, note="operator via /arm/resolve_stud")
            resp.success = True
            resp.message = f"{req.stud_id} recorded as {'welded' if welded else 'not welded'}"
            self._node.get_logger().info(f"resolve_stud: {resp.message}")
        except JournalError as exc:
            resp.success, resp.message = False, str(exc)
        return resp

    def _on_resolve_journal(self, req, resp):
        resp.success, resp.message = self.resolve_journal(req.action, req.note)
        if resp.success:
            self._node.get_logger().warn(f"resolve_journal: {resp.message}")
        else:
            self._node.get_logger().error(f"resolve_journal: {resp.message}")
        return resp

    def resolve_journal(self, action_code: int, note: str) -> tuple[bool, str]:
        """Leave the journal FAULT by an operator's ``action_code`` (ResolveJournal.ACTION_*)."""
        s = self.state
        action = JOURNAL_ACTIONS.get(action_code)
        if action is None:
            return False, f"unknown action {action_code}: expected {sorted(JOURNAL_ACTIONS)}"
        if s.journal_fault is None:
            return False, f"the weld journal {s.journal_path} is not in FAULT: nothing to resolve"
        seq = s.sequence
        if seq is not None and seq.running:
            return False, "a weld job is running"
        with s.job_lock:
            if s.journal is not None:
                s.journal.close()  # it failed or changed while open: read it again from the disk
                s.journal = None
            done = ""
            try:
                done = repair_journal(s.journal_path, action, note=note or "operator via /arm/resolve_journal")
            except (JournalError, OSError) as exc:
                done = f"not repaired: {exc}"
            try:
                s.open_journal()
            except OSError as exc:
                s.open_fault = JournalError(f"cannot open the weld journal {s.journal_path}: {exc}")
        fault = s.journal_fault
        if fault is not None:
            return False, f"{done}; still in FAULT: {fault}"
        assert s.journal is not None
        s.message = f"weld journal resolved ({action}): {done}"
        return True, (f"{done}; journal: {len(s.journal.welded_ids)} welded, "
                      f"{len(s.journal.uncertain_ids)} uncertain stud(s)")
