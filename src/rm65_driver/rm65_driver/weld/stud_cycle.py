"""One stud's cycle on the arm: approach, descend, trigger, dwell, retract; and what the controller
needs before it (tool frame, trigger output) and after a lost connection (set up again, back out).

Used by :class:`~rm65_driver.weld.weld_sequence.WeldSequence`, which decides which stud comes next
and what the journal already settles. Once a stud has passed its safety check, in order:

3. ``approach``: ``movej`` to the checked joint solution of the approach (clearance) pose (through
   a detour's waypoints when the straight joint move would leave the workspace box),
   ``standoff_m`` out along the surface normal, tool z pointing into the surface; then, with
   ``final_approach_m`` shorter than the standoff, a fast ``movel`` (``approach_speed_pct``)
   along the normal to the short standoff ``final_approach_m`` from the surface;
4. ``descend``: the slow controlled final ``movel`` (``linear_speed_pct``) along the normal to
   the contact pose (tool tip on the surface, or ``plunge_m`` beyond it). With
   ``connected_approach`` the fast and the slow ``movel`` go as one connected trajectory
   (``trajectory_connect`` 1 on the first): on their shared line the arm slows down to the slow
   speed instead of stopping at the short standoff; a stop or cancel during it acts as during
   either move;
5. ``weld``: journal ``started`` (fsync'ed), digital output ``trigger_io`` high for ``pulse_s``,
   then low. **The controller's outputs source at most 2 mA (docs/RM65_PROTOCOL.md §1.8): a real
   stud-welding gun must be triggered through an external relay / opto-coupled FET module on
   that output, never wired to it directly.**
6. ``dwell`` ``dwell_s`` (the gun completes its cycle), journal ``welded``;
7. ``retract``: ``movel`` back to the approach pose (at ``approach_speed_pct`` when the fast
   approach is on: away from the surface nothing is touched).

The next stud is planned during the dwell (:class:`LookAhead`).
"""
from __future__ import annotations

import logging
import time
from typing import Callable

import numpy as np

from rm65_driver.journal.records import JournalError
from rm65_driver.journal.writer import Journal
from rm65_driver.kinematics.rm65 import matrix_to_pose6
from rm65_driver.protocol.arm_client import (
    ArmClient,
    ArmCommandError,
    ArmConnectionError,
    ArmError,
    ArmStopped,
    ArmTimeout,
)
from rm65_driver.weld.job_control import JobControl, JobEnded
from rm65_driver.weld.safety import SafetyChecker, StudPlan, TargetCheck
from rm65_driver.weld.weld_job import JobResult, StudTarget, WeldedCallback, WeldParams
from rm65_driver.weld.welded_neighbours import nearest_welded
from stud_common.vocabulary import JournalStatus, WeldPhase

#: Journal statuses of a stud that stands on the part (an uncertain one may)
_STANDING = (JournalStatus.WELDED, JournalStatus.UNCERTAIN)

_log = logging.getLogger("rm65_driver.weld.weld_sequence")  # the weld job's one logger, whichever part writes

#: The next stud's plan, made during this stud's dwell from the joints its retract is planned to end
#: at, is used only if the arm's joints, read before the next stud, are within this of them (rad, each
#: joint; 0.57 deg), and the joint move to it is checked again from where the arm really is; otherwise
#: the stud is planned again. The controller ends a linear move on its own inverse kinematics: 0.3-1
#: mrad from ours on the simulator. What the start joints decide in a plan besides the joint move (the
#: IK seed, the preferred rotation about the stud's axis) gives a plan as valid from either.
LOOKAHEAD_TOL_RAD = 0.01


class LookAhead:
    """The next stud's plan, made while the weld cools and the arm stands still."""

    def __init__(self, safety: SafetyChecker, params: WeldParams) -> None:
        self.safety = safety
        self.params = params
        self.planned: tuple[str, np.ndarray, TargetCheck] | None = None  # (stud, from joints, check) for the next stud
        self.used = 0  # next-stud plans made during a dwell and used (for tests and logs)

    def plan(self, nxt: StudTarget | None, q_from: np.ndarray) -> None:
        """Plan ``nxt`` from ``q_from``, the joints this stud's retract ends at, while the weld cools
        and the arm stands still: between the studs it then costs nothing (it took 0.07-0.2 s of
        the arm's time a stud). A plan that cannot be made is simply made again later."""
        self.planned = None
        if nxt is None:
            return
        p = self.params
        try:
            check = self.safety.check_target(nxt.position, nxt.normal, p.standoff_m, q_from, p.plunge_m)
        except Exception:  # never let an optimisation end a weld: the stud is planned again before it
            _log.exception("planning %s ahead failed; it is planned again before its move", nxt.stud_id)
            return
        self.planned = (nxt.stud_id, np.array(q_from, dtype=np.float64), check)

    def take(self, t: StudTarget, q_now: np.ndarray) -> TargetCheck | None:
        """The plan made ahead for ``t``, if it was made for it from where the arm is (None otherwise)."""
        planned, self.planned = self.planned, None
        if planned is None or planned[0] != t.stud_id:
            return None
        check, q_now = planned[2], np.asarray(q_now, dtype=np.float64)
        if not check.ok or not np.max(np.abs(planned[1] - q_now)) <= LOOKAHEAD_TOL_RAD:
            return None  # a refusal may depend on the start: planned again, as is a start elsewhere
        assert check.plan is not None
        if self.safety.check_joint_path(q_now, check.plan.waypoints[0], "approach move"):
            return None
        self.used += 1
        return check


class StudCycle:
    """Welds one stud at a time for a weld job (:attr:`control`: its flags and progress).

    Targets are in the arm's base frame; the journal's weld points are in ``world``, where
    ``safety.world_T_base`` puts the base (the identity without a rail)."""

    def __init__(self, client: ArmClient, journal: Journal, safety: SafetyChecker, params: WeldParams,
                 control: JobControl, on_welded: WeldedCallback | None = None):
        self.client = client
        self.journal = journal
        self.safety = safety
        self.params = params
        self.control = control
        self.on_welded = on_welded
        self.lookahead = LookAhead(safety, params)
        self.job_targets: list[StudTarget] = []  # where the job's studs stand once welded (min_stud_spacing_m)
        self.below_clearance = False  # the tool is nearer the surface than the standoff (fast approach on)
        # On a rail: the carriage's position (m, the encoder's) for this job, journalled with each weld so
        # the weld's world pose can be rebuilt from its joints (stud_common.frames.world_T_base); None: no rail.
        self.rail_position_m: float | None = None

    def start_job(self, targets: list[StudTarget]) -> None:
        """Forget the last job: a new one welds ``targets``."""
        self.below_clearance = False
        self.lookahead.planned = None
        self.job_targets = list(targets)

    # -- the arm's stop and the trigger, from any thread ---------------------------------------------
    def stop_arm(self) -> None:
        try:
            self.client.stop(wait_reply=False)
        except ArmError as exc:
            _log.error("could not send the stop command: %s", exc)

    def trigger_low(self) -> bool:
        try:
            self.client.set_do(self.params.trigger_io, False, tool=self.params.trigger_on_tool)
            return True
        except ArmError as exc:
            _log.error("could not set the trigger output %d low: %s", self.params.trigger_io, exc)
            return False

    def _abort_motion(self) -> None:
        self.stop_arm()
        self.trigger_low()

    # -- one stud ------------------------------------------------------------------------------------
    def _move(self, kind: str, target, v: int) -> None:
        """One motion of the job; any stop requested since the job began raises ArmStopped."""
        p = self.params
        if kind == "joint":
            self.client.move_joints_and_wait(target, v, p.motion_timeout_s, stop_count=self.control.epoch)
        else:
            self.client.move_linear_and_wait(matrix_to_pose6(target), v, p.motion_timeout_s,
                                             stop_count=self.control.epoch)

    def _timed_move(self, kind: str, target, v: int) -> float:
        """:meth:`_move`, returning how long it took (s), for the journal's ``motion_s``."""
        t0 = time.monotonic()
        self._move(kind, target, v)
        return round(time.monotonic() - t0, 4)

    def _connected_approach(self, t: StudTarget, T_short: np.ndarray, T_contact: np.ndarray) -> dict[str, float]:
        """The fast approach and the slow final move as one trajectory; their times (s) for ``motion_s``.

        The phase turns to ``descend`` when the controller hands over to the slow move (a controller
        that reports only the end leaves it at ``approach``, and the split at the end).
        """
        p = self.params
        t0 = time.monotonic()
        handover: list[float] = []

        def on_handover(_: int) -> None:
            handover.append(time.monotonic())
            self.control.set_phase(t, WeldPhase.DESCEND)

        self.client.move_linear_path_and_wait(
            [(matrix_to_pose6(T_short), p.approach_speed_pct), (matrix_to_pose6(T_contact), p.linear_speed_pct)],
            p.motion_timeout_s, stop_count=self.control.epoch, on_handover=on_handover)
        t1 = time.monotonic()
        if not handover:
            self.control.set_phase(t, WeldPhase.DESCEND)
        mid = handover[0] if handover else t1
        return {WeldPhase.APPROACH: round(mid - t0, 4), WeldPhase.DESCEND: round(t1 - mid, 4)}

    def do_stud(self, t: StudTarget, res: JobResult, nxt: StudTarget | None = None) -> JournalStatus:
        """Weld one stud (``nxt``: the one after it, planned during the dwell); returns the status it
        leaves in the journal: WELDED or SKIPPED. Raises ArmConnectionError / JobEnded."""
        p, c = self.params, self.control
        try:
            q_now = self.client.get_state().joints_rad
        except ArmConnectionError:
            raise
        except ArmError as exc:
            self._abort_motion()
            raise JobEnded(f"aborted at {t.stud_id}: cannot read the arm state: {exc}") from exc
        crowded = self._welded_too_close(t)
        check = (TargetCheck(False, crowded) if crowded else self.lookahead.take(t, q_now)
                 or self.safety.check_target(t.position, t.normal, p.standoff_m, q_now, p.plunge_m))
        if not check.ok:
            try:
                self.journal.skipped(t.stud_id, check.reason, job=c.job_id)
            except JournalError as exc:
                raise JobEnded(f"aborted at {t.stud_id}: {exc}") from exc
            res.skipped.append(t.stud_id)
            res.messages.append(f"{t.stud_id}: {check.reason}")
            c.finish_one(t, WeldPhase.SKIP)
            return JournalStatus.SKIPPED
        plan = check.plan
        assert plan is not None
        try:
            c.between_phases()
            if c.cancelled:
                raise JobEnded("cancelled")
            c.set_phase(t, WeldPhase.APPROACH)
            motion_s = {"move": sum(self._timed_move("joint", q, p.joint_speed_pct) for q in plan.waypoints)}
            if p.fast_approach:
                self.below_clearance = True  # from here on, a recovery backs out along the normal
                T_short = plan.T_contact.copy()
                T_short[:3, 3] = t.position + p.final_approach_m * t.normal
                c.between_phases()
                if c.cancelled:
                    self._back_out(plan)
                    raise JobEnded("cancelled")
                if p.connected_approach:
                    motion_s.update(self._connected_approach(t, T_short, plan.T_contact))
                else:
                    motion_s[WeldPhase.APPROACH] = self._timed_move("linear", T_short, p.approach_speed_pct)
            if WeldPhase.DESCEND not in motion_s:
                c.between_phases()
                if c.cancelled:
                    if p.fast_approach:
                        self._back_out(plan)
                    raise JobEnded("cancelled")
                c.set_phase(t, WeldPhase.DESCEND)
                motion_s[WeldPhase.DESCEND] = self._timed_move("linear", plan.T_contact, p.linear_speed_pct)
            c.between_phases()
            if c.cancelled:
                self._back_out(plan)
                raise JobEnded("cancelled")
            c.set_phase(t, WeldPhase.WELD)
            self._weld(t, plan, motion_s, lambda: self.lookahead.plan(nxt, plan.q_approach))
            c.between_phases()
            c.set_phase(t, WeldPhase.RETRACT)
            self._move("linear", plan.T_approach, p.approach_speed_pct if p.fast_approach else p.linear_speed_pct)
            self.below_clearance = False
        except ArmStopped as exc:
            if c.halted:
                raise JobEnded(c.stop_message()) from exc
            if c.cancelled:
                if self.journal.status(t.stud_id) not in _STANDING:
                    self._back_out(plan)
                raise JobEnded("cancelled") from exc
            self._abort_motion()
            raise JobEnded(f"aborted at {t.stud_id}: the arm was stopped from outside the job") from exc
        except (ArmCommandError, ArmTimeout, JournalError) as exc:
            self._abort_motion()
            raise JobEnded(f"aborted at {t.stud_id} ({c.phase}): {exc}") from exc
        with c.lock:
            c.done += 1
        return JournalStatus.WELDED

    def _welded_too_close(self, t: StudTarget) -> str:
        """Why the gun's foot has no room at ``t`` beside the studs standing on the part: welded or
        uncertain (one the journal cannot rule out stands there too), by this job or any before it
        (their weld points from the journal), and this job's by their targets where the journal has
        no point; "" if it has room, or the check is off."""
        p = self.params
        if not p.min_stud_spacing_m > 0:
            return ""
        B = np.linalg.inv(self.safety.world_T_base)  # the journal's world -> this job's base frame
        standing = {sid: (B[:3, :3] @ pos + B[:3, 3], B[:3, :3] @ n) for sid, pos, n in self.journal.standing_studs()}
        for o in self.job_targets:
            if o.stud_id not in standing and self.journal.status(o.stud_id) in _STANDING:
                standing[o.stud_id] = (o.position, o.normal)
        welded = [(sid, pos, n) for sid, (pos, n) in standing.items() if sid != t.stud_id]
        near = nearest_welded(t.position, t.normal, welded, p.stud_length_m, p.stud_clearance_m)
        if near is None or near.distance_m >= p.min_stud_spacing_m:
            return ""
        return (f"welded stud {near.stud_id} stands {near.distance_m * 1e3:.0f} mm from the gun foot's axis, which "
                f"needs {p.min_stud_spacing_m * 1e3:.0f} mm (min_stud_spacing_m): the gun would hit it")

    def _weld(self, t: StudTarget, plan: StudPlan, motion_s: dict[str, float] | None = None,
              during_dwell: Callable[[], None] | None = None) -> None:
        p, c = self.params, self.control
        # The joints the controller reports at the contact pose: the gun's real axis at the weld
        # (forward kinematics), for the QA record and the demo's check against the true normal.
        q_at_weld = self.client.get_state().joints_rad
        # Durable *before* the trigger: after a crash this stud reads "uncertain", never "not welded".
        W = self.safety.world_T_base
        extra: dict = {"motion_s": motion_s} if motion_s else {}
        if self.rail_position_m is not None:
            extra["rail_position_m"] = float(self.rail_position_m)
        self.journal.started(t.stud_id, job=c.job_id, position=W[:3, :3] @ t.position + W[:3, 3],
                             normal=W[:3, :3] @ t.normal, joints=plan.q_contact, joints_at_weld=q_at_weld, **extra)
        try:
            self.client.set_do(p.trigger_io, True, tool=p.trigger_on_tool)
            c.sleep(p.pulse_s, interruptible=True)
        finally:
            low = self.trigger_low()
        if not low:
            raise ArmConnectionError("the trigger output could not be set low")
        c.check_halt()
        c.set_phase(t, WeldPhase.DWELL)
        dwell_end = time.monotonic() + p.dwell_s
        if during_dwell is not None:  # the gun holds the stud still: the dwell is at least dwell_s
            during_dwell()
        c.sleep(dwell_end - time.monotonic(), interruptible=True)
        c.check_halt()
        self.journal.welded(t.stud_id, job=c.job_id)
        if self.on_welded is not None:
            try:
                self.on_welded(t.stud_id, np.asarray(q_at_weld, dtype=np.float64))
            except Exception:
                _log.exception("welded callback failed")

    def _back_out(self, plan: StudPlan) -> None:
        """Straight back out along the normal to the approach pose (after a cancel, not a halt)."""
        with self.control.lock:
            if self.control.halted:
                return
            stop_count = self.client.stop_count  # a later halt still interrupts this move
        try:
            self.client.move_linear_and_wait(matrix_to_pose6(plan.T_approach), self.params.linear_speed_pct,
                                             self.params.motion_timeout_s, stop_count=stop_count)
            self.below_clearance = False
        except ArmError as exc:
            _log.error("could not back out along the normal: %s", exc)

    # -- the controller: set up, and set up again after a lost connection ----------------------------
    def recover(self, t: StudTarget, phase: str) -> None:
        """After a connection loss: reconnect, trigger low, wait until idle, set up the controller
        again, back out along the normal.

        The controller may have restarted (power cycle, watchdog): then its IO is back in input
        mode, where a DO cannot be driven, and its tool frame is the factory one. So the trigger IO
        is put in output mode and low at once, and everything else :meth:`prepare` sets is set
        again before the first motion.
        """
        p = self.params
        self.control.check_halt()
        self.client.reconnect(p.reconnect_timeout_s)
        try:
            self._prepare_trigger()
        except ArmError as exc:
            raise ArmConnectionError(f"the trigger output could not be set low after reconnecting: {exc}") from exc
        self.client.wait_idle(p.motion_timeout_s)
        self.prepare()
        self.control.check_halt()
        if phase in (WeldPhase.DESCEND, WeldPhase.WELD, WeldPhase.DWELL, WeldPhase.RETRACT) or self.below_clearance:
            # Straight back along the normal to the standoff, keeping the current orientation.
            T_back = self.safety.kin.fk(self.client.get_state().joints_rad) @ p.tool_T
            T_back[:3, 3] = t.position + p.standoff_m * t.normal
            self._move("linear", T_back, p.linear_speed_pct)
            self.below_clearance = False

    def prepare(self) -> None:
        """Work frame check, tool frame, trigger output mode and level (idempotent): everything a
        job needs of the controller, and what a restarted controller no longer has."""
        p = self.params
        if p.require_base_work_frame:
            name, pose = self.client.current_work_frame()
            if not np.allclose(pose, 0.0, atol=1e-6):
                raise ArmCommandError("get_current_work_frame", 0x100E,
                                      f"active work frame {name!r} is not the base frame (pose {pose.tolist()}); "
                                      "weld targets are in the base frame")
        self.client.set_tool_frame(p.tool_frame_name, [0.0, 0.0, p.tool_offset_m, 0.0, 0.0, 0.0], p.tool_payload_kg)
        self._prepare_trigger()

    def _prepare_trigger(self) -> None:
        """Trigger IO to output mode (a Gen-3 controller starts with its IO as inputs), then low."""
        p = self.params
        if p.set_io_mode:
            self.client.set_io_output_mode(p.trigger_io, tool=p.trigger_on_tool)
        self.client.set_do(p.trigger_io, False, tool=p.trigger_on_tool)
