"""The arm driver's services: stop, pause, resume, e-stop (service and topic), move_to,
resolve_stud and resolve_journal.

:class:`DriverServices` is a part of :class:`~rm65_driver.driver_node.DriverNode` (the services
are created there). The e-stop is a *software* stop (``set_arm_stop`` + trigger output low + a
latch that refuses new jobs until ``false`` on ``/arm/estop``), not a safety-rated one.
``move_to`` checks the workspace box (m) and the reach test (:mod:`.reach`: the IK within the joint
limits, as the planner checks the pose) before anything moves.
"""
from __future__ import annotations


import numpy as np
from std_msgs.msg import Bool
from stud_welding_msgs.srv import MoveTo, ResolveJournal, ResolveStud

from stud_common import ros_io
from stud_common.hand_eye_in_use import tool_in_world

from .arm_client import ArmError
from .driver_base import DriverBase
from .journal_records import JournalError
from .journal_repair import ACTION_ACCEPT_INTACT, ACTION_LOAD_BACKUP, repair_journal

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
            T_goal = tool_in_world(T_goal, self._hand_eye())  # camera pose -> weld_tool pose
        lo, hi = np.asarray(self.p["workspace_min_m"]), np.asarray(self.p["workspace_max_m"])
        if np.any(T_goal[:3, 3] < lo) or np.any(T_goal[:3, 3] > hi):
            return False, f"tool position {np.round(T_goal[:3, 3], 3).tolist()} m is outside the workspace box"
        # Whether: the reach test the planner applies too (rm65_driver.reach); then the solution
        # nearest the current joints, or the verdict's own when the search from here finds none.
        verdict = self.reach().tool_poses(T_goal[None])[0]
        if not verdict.ok:
            return False, f"unreachable: {verdict.reason}"
        seed = self._last_state.joints_rad if self._last_state is not None else None
        ik = self.kin.ik(T_goal, q_seed=seed, tool=self.tool_T, prefer_signs=self.p["preferred_joint_signs"])
        q = ik.q if ik.success else verdict.q
        assert q is not None  # an accepted verdict carries its solution
        speed = min(self.p["joint_speed_pct"], self.p["max_joint_speed_pct"])
        try:
            with self._job_lock:
                self.client.move_joints_and_wait(q, speed, timeout_s=self.p["motion_timeout_s"])
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
