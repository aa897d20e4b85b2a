"""The arm driver's services: stop, pause, resume, e-stop (service and topic), move_to, rail_move,
resolve_stud and resolve_journal.

:class:`DriverServices` is a part of :class:`~rm65_driver.driver_node.DriverNode` (the services
are created there). The e-stop is a *software* stop (``set_arm_stop`` + trigger output low + a
latch that refuses new jobs until ``false`` on ``/arm/estop``), not a safety-rated one.
``move_to`` checks the workspace box (m) and the IK within the joint limits before anything moves.

With a rail: ``rail_move`` (and ``move_to`` with ``move_rail``) moves the carriage while the arm is
still -- it takes the job lock an arm move and a weld job hold, checks that the controller runs no
arm trajectory, and is refused during a weld job; stop and e-stop stop the carriage too
(``expand_set_speed`` 0 besides ``set_arm_stop``).
"""
from __future__ import annotations


import numpy as np
from std_msgs.msg import Bool
from stud_welding_msgs.srv import MoveTo, ResolveJournal, ResolveStud

from stud_common import ros_io
from stud_common.hand_eye_in_use import tool_in_world

from .arm_client import ArmCommandError, ArmError
from .driver_base import DriverBase
from .journal_records import JournalError
from .journal_repair import ACTION_ACCEPT_INTACT, ACTION_LOAD_BACKUP, repair_journal
from .rail import RailRequestError

#: ResolveJournal.action -> journal_repair.repair_journal action
JOURNAL_ACTIONS = {ResolveJournal.Request.ACTION_ACCEPT_INTACT: ACTION_ACCEPT_INTACT,
                   ResolveJournal.Request.ACTION_LOAD_BACKUP: ACTION_LOAD_BACKUP}


class DriverServices(DriverBase):
    """Service and e-stop handlers of :class:`~rm65_driver.driver_node.DriverNode` (state lives there)."""

    # -- services ---------------------------------------------------------------------------------
    def _stop_now(self, reason: str) -> tuple[bool, str]:
        seq = self.sequence
        if seq is not None and seq.running:
            seq.halt(reason)  # stop + trigger low + the job ends
            self._stop_rail()
            return True, f"stop sent; weld job halting ({reason})"
        try:
            self.client.stop(wait_reply=False)
        except ArmError as exc:
            return False, f"stop not sent: {exc}"
        self._stop_rail()
        try:
            self.client.set_do(self.p["trigger_io"], False, tool=self.p["trigger_on_tool"])
        except ArmError:
            pass  # the output may not be configured yet; the stop went out
        return True, "stop sent"

    def _stop_rail(self) -> None:
        """The axis's own stop, besides the arm's (whether set_arm_stop stops it is undocumented)."""
        try:
            self.rail.stop()
        except ArmError as exc:
            self.get_logger().warn(f"rail stop (expand_set_speed 0) not confirmed: {exc}")

    def _on_move_to(self, req, resp):
        """Joint-space move of the weld tool (or, through the hand-eye transform, the camera) to a
        world pose: IK within joint limits and the workspace box are checked before anything is sent.
        Used by the cell sequencer to put the camera over a station."""
        resp.success, resp.message = self.move_to(req.pose, camera=req.frame == MoveTo.Request.FRAME_CAMERA,
                                                  rail_position_m=req.rail_position_m if req.move_rail else None)
        return resp

    def move_to(self, pose, camera: bool, rail_position_m: float | None = None) -> tuple[bool, str]:
        """The tool (or camera) to a ``world`` pose; with ``rail_position_m`` the carriage there first."""
        if self._estop:
            return False, "e-stop engaged"
        seq = self.sequence
        if seq is not None and seq.running:
            return False, "a weld job is running"
        why = self._rail_move_problem(rail_position_m) if rail_position_m is not None else ""
        if why:
            return False, why
        if self.rail.moving:
            return False, "the carriage is moving"
        R, t = ros_io.pose_to_rt(pose)
        T_goal = np.eye(4)
        T_goal[:3, :3], T_goal[:3, 3] = R, t
        if camera:
            T_goal = tool_in_world(T_goal, self._hand_eye())  # camera pose -> weld_tool pose
        lo, hi = np.asarray(self.p["workspace_min_m"]), np.asarray(self.p["workspace_max_m"])
        if np.any(T_goal[:3, 3] < lo) or np.any(T_goal[:3, 3] > hi):
            return False, f"tool position {np.round(T_goal[:3, 3], 3).tolist()} m is outside the workspace box"
        seed = self._last_state.joints_rad if self._last_state is not None else None
        T_base = T_goal
        if self.rail.present:  # world -> the arm's base, with the carriage where it will be
            T_base = np.linalg.inv(self.rail.world_T_base(rail_position_m)) @ T_goal
        ik = self.kin.ik(T_base, q_seed=seed, tool=self.tool_T, prefer_signs=self.p["preferred_joint_signs"])
        if not ik.success:
            where = f" with the carriage at {rail_position_m:.3f} m" if rail_position_m is not None else ""
            return False, f"unreachable{where}: {ik.message or 'no IK solution within the joint limits'}"
        speed = min(self.p["joint_speed_pct"], self.p["max_joint_speed_pct"])
        try:
            with self._job_lock:
                if rail_position_m is not None:
                    self._move_rail_locked(rail_position_m, self.p["rail_speed_pct"])
                self.client.move_joints_and_wait(ik.q, speed, timeout_s=self.p["motion_timeout_s"])
        except ArmError as exc:
            return False, f"move failed: {exc}"
        what = "camera" if camera else "tool"
        self.get_logger().info(f"moved the {what} to {np.round(t, 3).tolist()} m")
        return True, f"{what} at {np.round(t, 4).tolist()} m"

    # -- the rail ---------------------------------------------------------------------------------
    def _on_rail_move(self, req, resp):
        speed = int(req.speed_pct) or self.p["rail_speed_pct"]
        resp.success, resp.message = self.rail_move(req.position_m, speed)
        resp.position_m = self.rail.position_m
        if resp.success:  # two call sites: rclpy refuses one call site logging at two severities
            self.get_logger().info(f"/arm/rail_move: {resp.message}")
        else:
            self.get_logger().warn(f"/arm/rail_move: {resp.message}")
        return resp

    def _rail_move_problem(self, position_m: float, speed_pct: int = 1) -> str:
        """Why the carriage cannot go to ``position_m`` now ("" if it can)."""
        if not self.rail.present or self.rail.axis is None:
            return "this driver has no rail (rail_length_m is 0)"
        if self._estop:
            return "e-stop engaged"
        seq = self.sequence
        if seq is not None and seq.running:
            return "a weld job is running: the carriage moves only between jobs"
        if not 1 <= speed_pct <= 100:
            return f"rail speed {speed_pct} %: expected 1..100"
        try:
            self.rail.axis.check_position(position_m)
        except RailRequestError as exc:
            return str(exc)
        return ""

    def rail_move(self, position_m: float, speed_pct: int) -> tuple[bool, str]:
        """The carriage to ``position_m`` (m) at ``speed_pct`` %, the arm still; returns once it arrived."""
        why = self._rail_move_problem(position_m, speed_pct)
        if why:
            return False, why
        try:
            with self._job_lock:
                reached = self._move_rail_locked(position_m, speed_pct)
        except ArmError as exc:
            return False, f"rail move failed: {exc}"
        return True, f"carriage at {reached:.4f} m"

    def _move_rail_locked(self, position_m: float, speed_pct: int) -> float:
        """Under the job lock: move the carriage, refused while the controller runs an arm trajectory."""
        if self.client.current_trajectory() != "none":
            raise ArmCommandError("expand_set_pos", 0, "the arm is moving: the carriage moves only while it is still")
        return self.rail.move(position_m, speed_pct, timeout_s=self.p["motion_timeout_s"])

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
            resp.message = f"{self._fault_text(self.journal_fault)}: resolve the journal first"
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
