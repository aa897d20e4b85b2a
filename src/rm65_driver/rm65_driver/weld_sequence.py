"""The weld job: approach, descend, trigger, dwell, retract — for each stud, resumable, never twice.

Pure Python on top of :class:`~rm65_driver.arm_client.ArmClient`,
:class:`~rm65_driver.journal.Journal` and :class:`~rm65_driver.safety.SafetyChecker`; the ROS
node only converts ``WeldTarget`` messages to :class:`~rm65_driver.weld_job.StudTarget` and forwards
feedback. The job's inputs and result (:class:`~rm65_driver.weld_job.WeldParams`, ``JobResult``) are in
:mod:`.weld_job`.

Per target, in order:

1. journal says **welded** -> not touched (reported welded when ``resume``, else skipped
   "already welded"); journal says **uncertain** -> refused (failed, "needs an operator
   decision": ``/arm/resolve_stud``);
2. safety check: the reach verdict (:mod:`.reach`, the planner's own test: gun tilt from
   vertical, workspace, reach/IK inside the joint limits for some rotation about the stud's axis,
   straight descent feasible), then the rotation and solution nearest the current joints
   (:mod:`.reach_move`); with ``min_stud_spacing_m``, room for the gun's foot beside the job's studs
   already welded or uncertain: :mod:`.welded_studs`): a rejection is journaled
   ``skipped(reason)`` and nothing is sent;
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
   then low. **The controller's outputs source at most 2 mA (RM65_PROTOCOL.md §1.8): a real
   stud-welding gun must be triggered through an external relay / opto-coupled FET module on
   that output, never wired to it directly.**
6. ``dwell`` ``dwell_s`` (the gun completes its cycle), journal ``welded``;
7. ``retract``: ``movel`` back to the approach pose (at ``approach_speed_pct`` when the fast
   approach is on: away from the surface nothing is touched).

Order: with ``stud_order`` "path" the job's studs are welded along a short path through their
approach joints from the arm's current joints (:mod:`.stud_order`, nearest neighbour + 2-opt);
"tour" also counts the way back to the start (the cell shoots the station again after its
welds); "given" keeps the request's order. Every stud is still processed exactly once and the
result lists it in the request's order.

Stops: :meth:`WeldSequence.cancel` is graceful (motions before the trigger are stopped at once and
the tool backs out along the normal; once the trigger fired, the weld, dwell and retract finish;
then the job ends). :meth:`WeldSequence.halt` (stop / e-stop) sends ``set_arm_stop`` at once,
drops the trigger output and ends the job with no further motion.

Errors: a controller error (refused command, failed motion) aborts the job with the decoded
error; the journal stays consistent (a stud that was triggered but not confirmed stays
*uncertain*). A lost connection triggers a reconnect with back-off; then everything a freshly
started controller lacks is set again -- trigger IO in output mode and low first, then (once the
arm is idle) the work-frame check and the tool frame -- and the arm backs out along the normal.
A stud not yet triggered is retried; a triggered one is reported *uncertain* (never re-welded)
and the job continues with the next studs (``on_disconnect="continue"``, default) or ends
(``"abort"``).

Journal: every record of a job carries the job's id (:attr:`WeldSequence.job_id`). A job does not
start on a journal that failed or changed behind its back (:meth:`Journal.verify`), and a record
that cannot be written (disk full, I/O error) ends the job before its next motion: a stud whose
``started`` was not written is never triggered; one whose ``welded`` was not written stays
uncertain.
"""
from __future__ import annotations

import logging
import threading
import time
from typing import Callable, Sequence

import numpy as np

from .arm_client import ArmClient, ArmCommandError, ArmConnectionError, ArmError, ArmStopped, ArmTimeout
from .journal import Journal
from .journal_records import JournalError
from .kinematics import matrix_to_pose6, tool_pose_facing
from .safety import SafetyChecker, StudPlan, TargetCheck
from .stud_order import order_by_path
from .welded_studs import nearest_welded
from .weld_job import JobResult, PhaseCallback, StudTarget, WeldedCallback, WeldParams, new_job_id

_log = logging.getLogger(__name__)


class _JobEnded(Exception):
    """Internal: the job stops here (cancel, halt, abort); ``message`` goes to the result."""


#: How a job goes on after a connection loss at a stud (:meth:`WeldSequence._after_connection_loss`).
_RETRY, _NEXT, _END = "retry", "next", "end"

#: The next stud's plan, made during this stud's dwell from the joints its retract is planned to end
#: at, is used only if the arm's joints, read before the next stud, are within this of them (rad, each
#: joint; 0.57 deg), and the joint move to it is checked again from where the arm really is; otherwise
#: the stud is planned again. The controller ends a linear move on its own inverse kinematics: 0.3-1
#: mrad from ours on the simulator. What the start joints decide in a plan besides the joint move (the
#: IK seed, the preferred rotation about the stud's axis) gives a plan as valid from either.
LOOKAHEAD_TOL_RAD = 0.01


class WeldSequence:
    """Runs weld jobs on one arm; thread-safe control (:meth:`cancel`, :meth:`halt`, :meth:`pause`)."""

    def __init__(self, client: ArmClient, journal: Journal, safety: SafetyChecker, params: WeldParams,
                 on_phase: PhaseCallback | None = None, on_welded: WeldedCallback | None = None):
        self.client = client
        self.journal = journal
        self.safety = safety
        self.params = params
        self.on_phase = on_phase
        self.on_welded = on_welded
        if not np.allclose(safety.tool_T, params.tool_T):
            raise ValueError("the safety checker's tool transform differs from params.tool_T")
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)
        self._job_targets: list[StudTarget] = []
        self._cancel = False
        self._halt = False
        self._halt_reason = ""
        self._paused = False
        self._epoch = 0  # client.stop_count when the job started
        self.running = False
        self.current_stud = ""
        self.phase = ""
        self.done = 0
        self.total = 0
        self.job_id = ""  # of the running (or last) job; in every journal record it writes
        self._below_clearance = False  # the tool is nearer the surface than the standoff (fast approach on)
        self._planned: tuple[str, np.ndarray, TargetCheck] | None = None  # (stud, from joints, check) for the next stud
        self.plans_ahead_used = 0  # next-stud plans made during a dwell and used (for tests and logs)

    # ------------------------------------------------------------------------------------
    # control from other threads
    # ------------------------------------------------------------------------------------
    def cancel(self) -> None:
        """Graceful stop: motions before the trigger are stopped now; a started weld completes."""
        with self._lock:
            self._cancel = True
            phase = self.phase
            self._paused = False
            self._wake.notify_all()
        if phase in ("approach", "descend"):
            self._stop_arm()

    def halt(self, reason: str = "stop requested") -> None:
        """Immediate stop: ``set_arm_stop`` now, trigger output low, job ends, nothing else moves."""
        with self._lock:
            self._halt = True
            self._halt_reason = reason
            self._paused = False
            self._wake.notify_all()
        self._stop_arm()
        self._trigger_low()

    def pause(self) -> None:
        """Pause the running motion on its path; no new phase starts until :meth:`resume`."""
        with self._lock:
            self._paused = True
        try:
            self.client.pause()
        except ArmError:
            with self._lock:
                self._paused = False  # not paused: the job must not wait for a resume that never comes
                self._wake.notify_all()
            raise

    def resume(self) -> None:
        self.client.resume()
        with self._lock:
            self._paused = False
            self._wake.notify_all()

    def _stop_arm(self) -> None:
        try:
            self.client.stop(wait_reply=False)
        except ArmError as exc:
            _log.error("could not send the stop command: %s", exc)

    def _trigger_low(self) -> bool:
        try:
            self.client.set_do(self.params.trigger_io, False, tool=self.params.trigger_on_tool)
            return True
        except ArmError as exc:
            _log.error("could not set the trigger output %d low: %s", self.params.trigger_io, exc)
            return False

    # ------------------------------------------------------------------------------------
    # the job
    # ------------------------------------------------------------------------------------
    def run(self, targets: Sequence[StudTarget], resume: bool = True) -> JobResult:
        """Weld ``targets`` in order (blocking). See the module docstring for the rules."""
        res = JobResult()
        with self._lock:
            if self.running:
                res.message = "a weld job is already running"
                return res
            self.running = True
            self._cancel = self._halt = self._paused = False
            self._below_clearance = False
            self._planned = None
            self.total, self.done = len(targets), 0
            self.job_id = res.job_id = new_job_id()
        try:
            self._run(list(targets), resume, res)
        finally:
            with self._lock:
                self.running = False
                self.current_stud = self.phase = ""
        _log.info("weld job ended: %s", res.message)
        return res

    def _run(self, targets: list[StudTarget], resume: bool, res: JobResult) -> None:
        self._job_targets = list(targets)  # where the job's studs stand once welded (min_stud_spacing_m)
        ids = [t.stud_id for t in targets]
        if len(set(ids)) != len(ids):
            res.message = "duplicate stud ids in the job: " + ", ".join(sorted({i for i in ids if ids.count(i) > 1}))
            return
        for v, linear in ((self.params.joint_speed_pct, False), (self.params.linear_speed_pct, True),
                          (self.params.approach_speed_pct, True)):
            why = self.safety.check_speed(v, linear)
            if why:
                res.message = f"job refused: {why}"
                return
        try:
            self.journal.verify()
        except JournalError as exc:
            res.message = f"job refused: {exc}"
            return
        try:
            if not self.client.connected:
                self.client.reconnect(self.params.reconnect_timeout_s)
            self._prepare()
        except ArmError as exc:
            res.message = f"job not started: {exc}"
            return

        with self._lock:
            self._epoch = self.client.stop_count  # any stop from now on ends every motion of this job
        request_order = {t.stud_id: k for k, t in enumerate(targets)}
        if self.params.stud_order != "given":
            try:
                targets = self._ordered(targets)
            except ArmError as exc:
                res.message = f"job not started: {exc}"
                return
        try:
            self._weld_all(targets, resume, res)
        finally:
            for ids_ in (res.welded, res.skipped, res.failed):  # the request's order, whatever the welding order
                ids_.sort(key=lambda sid: request_order.get(sid, len(request_order)))

    def _ordered(self, targets: list[StudTarget]) -> list[StudTarget]:
        """``targets`` along a short joint-space path from the current joints (:mod:`.stud_order`).
        Each stud's place comes from the IK of its approach pose at the wrist's current yaw; one
        without a solution keeps its relative place at the end (its own check refuses it)."""
        p = self.params
        q_now = self.client.get_state().joints_rad
        kin, tool_T = self.safety.kin, self.safety.tool_T
        x_hint = (kin.fk(q_now) @ tool_T)[:3, 0]
        solved, Q, rest = [], [], []
        for t in targets:
            if self.journal.status(t.stud_id) in ("welded", "uncertain"):
                rest.append(t)  # not moved to: the journal decides at once
                continue
            ik = kin.ik(tool_pose_facing(t.position + p.standoff_m * t.normal, t.normal, x_hint=x_hint), q_now,
                        tool=tool_T)
            if ik.success:
                solved.append(t)
                Q.append(ik.q)
            else:
                rest.append(t)
        if not solved:
            return targets
        order = order_by_path(q_now, np.asarray(Q), kin.max_speed_rad_s,
                              q_end=q_now if p.stud_order == "tour" else None)
        return [solved[k] for k in order] + rest

    def _weld_all(self, targets: list[StudTarget], resume: bool, res: JobResult) -> None:
        i = 0
        reconnects = 0
        while i < len(targets):
            t = targets[i]
            if self._cancel or self._halt:
                self._end_unprocessed(targets[i:], res)
                res.message = self._stop_message()
                return
            if self._settled_by_journal(t, resume, res):
                i += 1
                continue
            try:
                outcome = self._do_stud(t, res, targets[i + 1] if i + 1 < len(targets) else None)
            except ArmConnectionError as exc:
                reconnects += 1
                step = self._after_connection_loss(targets, i, reconnects, exc, res)
                if step == _END:
                    return
                if step == _NEXT:
                    i += 1
                    reconnects = 0
                continue  # the same stud again (it was never triggered), or the next one
            except _JobEnded as end:
                self._after_job_ended(targets, i, end, res)
                return
            reconnects = 0
            if outcome == "welded":
                res.welded.append(t.stud_id)
            i += 1
        self._trigger_low()
        stopped = self._cancel or self._halt
        res.success = not res.failed and not stopped
        res.message = self._stop_message() if stopped else (
            f"done: {len(res.welded)} welded, {len(res.skipped)} skipped, {len(res.failed)} failed")

    def _settled_by_journal(self, t: StudTarget, resume: bool, res: JobResult) -> bool:
        """A stud the journal already decides (welded: not touched; uncertain: refused); True if so."""
        status = self.journal.status(t.stud_id)
        if status == "welded":
            if resume:
                res.welded.append(t.stud_id)
            else:
                res.skipped.append(t.stud_id)
                res.messages.append(f"{t.stud_id}: already welded (journal); not welded again")
            self._finish_one(t, "skip")
            return True
        if status == "uncertain":
            res.failed.append(t.stud_id)
            res.messages.append(f"{t.stud_id}: uncertain in the journal (started, never confirmed): "
                                "needs an operator decision (resolve_stud) before it can be welded")
            self._finish_one(t, "skip")
            return True
        return False

    def _after_connection_loss(self, targets: list[StudTarget], i: int, reconnects: int, exc: ArmConnectionError,
                               res: JobResult) -> str:
        """Recover from a connection loss at ``targets[i]`` (the ``reconnects``-th there) and say how the
        job goes on: :data:`_RETRY` the same stud (never triggered), :data:`_NEXT` stud, or :data:`_END`."""
        t = targets[i]
        phase = self.phase
        status = self.journal.status(t.stud_id)
        _log.warning("connection lost at stud %s (phase %s, journal %s): %s", t.stud_id, phase, status, exc)
        recovered = ""
        try:
            self._recover(t, phase)
        except (ArmError, _JobEnded) as exc2:
            recovered = str(exc2)
        if status == "welded":  # lost during the retract: the stud is done
            res.welded.append(t.stud_id)
        elif status == "uncertain":
            res.failed.append(t.stud_id)
            res.messages.append(f"{t.stud_id}: uncertain (connection lost after the trigger); "
                                "not re-welded, needs an operator decision")
        if recovered:
            self._end_unprocessed(targets[i:], res)
            res.message = f"aborted: connection lost at {t.stud_id} and not recovered: {recovered}"
            return _END
        if status in ("welded", "uncertain"):
            self._finish_one(t, "skip")
            if status == "uncertain" and self.params.on_disconnect == "abort":
                self._end_unprocessed(targets[i + 1:], res)
                res.message = "aborted after a connection loss mid-weld (on_disconnect=abort)"
                return _END
            return _NEXT
        if reconnects > self.params.max_reconnects_per_stud:
            res.failed.append(t.stud_id)
            res.messages.append(f"{t.stud_id}: connection lost {reconnects} times at this stud")
            self._end_unprocessed(targets[i + 1:], res)
            res.message = "aborted: the connection keeps dropping"
            return _END
        return _RETRY

    def _after_job_ended(self, targets: list[StudTarget], i: int, end: _JobEnded, res: JobResult) -> None:
        """The job ended (cancel, halt, abort) at ``targets[i]``: the stud's outcome from the journal."""
        t = targets[i]
        status = self.journal.status(t.stud_id)
        if status == "welded":
            res.welded.append(t.stud_id)
        elif status == "uncertain":
            res.failed.append(t.stud_id)
            res.messages.append(f"{t.stud_id}: uncertain (job ended after the trigger): "
                                "needs an operator decision")
        elif not str(end).startswith(("cancelled", "halted")):
            res.failed.append(t.stud_id)
            res.messages.append(f"{t.stud_id}: {end}")
        self._end_unprocessed(targets[i:], res)
        res.message = str(end)

    def _stop_message(self) -> str:
        return f"halted: {self._halt_reason}" if self._halt else "cancelled"

    def _end_unprocessed(self, rest: Sequence[StudTarget], res: JobResult) -> None:
        for t in rest:
            if t.stud_id not in res.welded and t.stud_id not in res.failed and t.stud_id not in res.skipped:
                res.messages.append(f"{t.stud_id}: not processed (job ended)")

    def _finish_one(self, t: StudTarget, phase: str) -> None:
        with self._lock:
            self.done += 1
        self._set_phase(t, phase)

    def _set_phase(self, t: StudTarget, phase: str) -> None:
        with self._lock:
            self.current_stud, self.phase = t.stud_id, phase
            done, total = self.done, self.total
        _log.info("stud %s: %s (%d/%d)", t.stud_id, phase, done, total)
        if self.on_phase is not None:
            try:
                self.on_phase(t.stud_id, phase, done, total)
            except Exception:
                _log.exception("phase callback failed")

    # ------------------------------------------------------------------------------------
    def _prepare(self) -> None:
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

    def _wait_not_paused(self) -> None:
        with self._wake:
            while self._paused and not (self._halt or self._cancel):
                self._wake.wait(0.1)

    def _sleep(self, seconds: float, interruptible: bool) -> None:
        """Wait ``seconds``; a halt ends it early (a cancel does not: the weld completes)."""
        end = time.monotonic() + seconds
        with self._wake:
            while (left := end - time.monotonic()) > 0:
                if interruptible and self._halt:
                    return
                self._wake.wait(left)

    def _check_halt(self) -> None:
        if self._halt:
            raise _JobEnded(self._stop_message())

    def _move(self, kind: str, target, v: int) -> None:
        """One motion of the job; any stop requested since the job began raises ArmStopped."""
        p = self.params
        if kind == "joint":
            self.client.move_joints_and_wait(target, v, p.motion_timeout_s, stop_count=self._epoch)
        else:
            self.client.move_linear_and_wait(matrix_to_pose6(target), v, p.motion_timeout_s, stop_count=self._epoch)

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
            self._set_phase(t, "descend")

        self.client.move_linear_path_and_wait(
            [(matrix_to_pose6(T_short), p.approach_speed_pct), (matrix_to_pose6(T_contact), p.linear_speed_pct)],
            p.motion_timeout_s, stop_count=self._epoch, on_handover=on_handover)
        t1 = time.monotonic()
        if not handover:
            self._set_phase(t, "descend")
        mid = handover[0] if handover else t1
        return {"approach": round(mid - t0, 4), "descend": round(t1 - mid, 4)}

    def _between_phases(self) -> None:
        self._wait_not_paused()
        self._check_halt()

    def _do_stud(self, t: StudTarget, res: JobResult, nxt: StudTarget | None = None) -> str:
        """Weld one stud (``nxt``: the one after it, planned during the dwell); returns "welded" or
        "skipped". Raises ArmConnectionError / _JobEnded."""
        p = self.params
        try:
            q_now = self.client.get_state().joints_rad
        except ArmConnectionError:
            raise
        except ArmError as exc:
            self._abort_motion()
            raise _JobEnded(f"aborted at {t.stud_id}: cannot read the arm state: {exc}") from exc
        crowded = self._welded_too_close(t)
        check = (TargetCheck(False, crowded) if crowded else self._planned_check(t, q_now)
                 or self.safety.check_target(t.position, t.normal, p.standoff_m, q_now, p.plunge_m))
        if not check.ok:
            try:
                self.journal.skipped(t.stud_id, check.reason, job=self.job_id)
            except JournalError as exc:
                raise _JobEnded(f"aborted at {t.stud_id}: {exc}") from exc
            res.skipped.append(t.stud_id)
            res.messages.append(f"{t.stud_id}: {check.reason}")
            self._finish_one(t, "skip")
            return "skipped"
        plan = check.plan
        assert plan is not None
        try:
            self._between_phases()
            if self._cancel:
                raise _JobEnded("cancelled")
            self._set_phase(t, "approach")
            motion_s = {"move": sum(self._timed_move("joint", q, p.joint_speed_pct) for q in plan.waypoints)}
            if p.fast_approach:
                self._below_clearance = True  # from here on, a recovery backs out along the normal
                T_short = plan.T_contact.copy()
                T_short[:3, 3] = t.position + p.final_approach_m * t.normal
                self._between_phases()
                if self._cancel:
                    self._back_out(plan)
                    raise _JobEnded("cancelled")
                if p.connected_approach:
                    motion_s.update(self._connected_approach(t, T_short, plan.T_contact))
                else:
                    motion_s["approach"] = self._timed_move("linear", T_short, p.approach_speed_pct)
            if "descend" not in motion_s:
                self._between_phases()
                if self._cancel:
                    if p.fast_approach:
                        self._back_out(plan)
                    raise _JobEnded("cancelled")
                self._set_phase(t, "descend")
                motion_s["descend"] = self._timed_move("linear", plan.T_contact, p.linear_speed_pct)
            self._between_phases()
            if self._cancel:
                self._back_out(plan)
                raise _JobEnded("cancelled")
            self._set_phase(t, "weld")
            self._weld(t, plan, motion_s, lambda: self._plan_ahead(nxt, plan.q_approach))
            self._between_phases()
            self._set_phase(t, "retract")
            self._move("linear", plan.T_approach, p.approach_speed_pct if p.fast_approach else p.linear_speed_pct)
            self._below_clearance = False
        except ArmStopped as exc:
            if self._halt:
                raise _JobEnded(self._stop_message()) from exc
            if self._cancel:
                if self.journal.status(t.stud_id) not in ("welded", "uncertain"):
                    self._back_out(plan)
                raise _JobEnded("cancelled") from exc
            self._abort_motion()
            raise _JobEnded(f"aborted at {t.stud_id}: the arm was stopped from outside the job") from exc
        except (ArmCommandError, ArmTimeout, JournalError) as exc:
            self._abort_motion()
            raise _JobEnded(f"aborted at {t.stud_id} ({self.phase}): {exc}") from exc
        with self._lock:
            self.done += 1
        return "welded"

    def _plan_ahead(self, nxt: StudTarget | None, q_from: np.ndarray) -> None:
        """Plan ``nxt`` from ``q_from``, the joints this stud's retract ends at, while the weld cools
        and the arm stands still: between the studs it then costs nothing (it took 0.07-0.2 s of
        the arm's time a stud). A plan that cannot be made is simply made again later."""
        self._planned = None
        if nxt is None:
            return
        p = self.params
        try:
            check = self.safety.check_target(nxt.position, nxt.normal, p.standoff_m, q_from, p.plunge_m)
        except Exception:  # never let an optimisation end a weld: the stud is planned again before it
            _log.exception("planning %s ahead failed; it is planned again before its move", nxt.stud_id)
            return
        self._planned = (nxt.stud_id, np.array(q_from, dtype=np.float64), check)

    def _welded_too_close(self, t: StudTarget) -> str:
        """Why the gun's foot has no room at ``t`` beside the studs standing on the part: welded or
        uncertain (one the journal cannot rule out stands there too), by this job or any before it
        (their weld points from the journal), and this job's by their targets where the journal has
        no point; "" if it has room, or the check is off."""
        p = self.params
        if not p.min_stud_spacing_m > 0:
            return ""
        standing = {sid: (np.asarray(pos), np.asarray(n)) for sid, pos, n in self.journal.standing_studs()}
        for o in self._job_targets:
            if o.stud_id not in standing and self.journal.status(o.stud_id) in ("welded", "uncertain"):
                standing[o.stud_id] = (o.position, o.normal)
        welded = [(sid, pos, n) for sid, (pos, n) in standing.items() if sid != t.stud_id]
        near = nearest_welded(t.position, t.normal, welded, p.stud_length_m, p.stud_clearance_m)
        if near is None or near.distance_m >= p.min_stud_spacing_m:
            return ""
        return (f"welded stud {near.stud_id} stands {near.distance_m * 1e3:.0f} mm from the gun foot's axis, which "
                f"needs {p.min_stud_spacing_m * 1e3:.0f} mm (min_stud_spacing_m): the gun would hit it")

    def _planned_check(self, t: StudTarget, q_now: np.ndarray) -> TargetCheck | None:
        """The plan made ahead for ``t``, if it was made for it from where the arm is (None otherwise)."""
        planned, self._planned = self._planned, None
        if planned is None or planned[0] != t.stud_id:
            return None
        check, q_now = planned[2], np.asarray(q_now, dtype=np.float64)
        if not check.ok or not np.max(np.abs(planned[1] - q_now)) <= LOOKAHEAD_TOL_RAD:
            return None  # a refusal may depend on the start: planned again, as is a start elsewhere
        assert check.plan is not None
        if self.safety.check_joint_path(q_now, check.plan.waypoints[0], "approach move"):
            return None
        self.plans_ahead_used += 1
        return check

    def _weld(self, t: StudTarget, plan: StudPlan, motion_s: dict[str, float] | None = None,
              during_dwell: Callable[[], None] | None = None) -> None:
        p = self.params
        # The joints the controller reports at the contact pose: the gun's real axis at the weld
        # (forward kinematics), for the QA record and the demo's check against the true normal.
        q_at_weld = self.client.get_state().joints_rad
        # Durable *before* the trigger: after a crash this stud reads "uncertain", never "not welded".
        self.journal.started(t.stud_id, job=self.job_id, position=t.position, normal=t.normal, joints=plan.q_contact,
                             joints_at_weld=q_at_weld, **({"motion_s": motion_s} if motion_s else {}))
        try:
            self.client.set_do(p.trigger_io, True, tool=p.trigger_on_tool)
            self._sleep(p.pulse_s, interruptible=True)
        finally:
            low = self._trigger_low()
        if not low:
            raise ArmConnectionError("the trigger output could not be set low")
        self._check_halt()
        self._set_phase(t, "dwell")
        dwell_end = time.monotonic() + p.dwell_s
        if during_dwell is not None:  # the gun holds the stud still: the dwell is at least dwell_s
            during_dwell()
        self._sleep(dwell_end - time.monotonic(), interruptible=True)
        self._check_halt()
        self.journal.welded(t.stud_id, job=self.job_id)
        if self.on_welded is not None:
            try:
                self.on_welded(t.stud_id, np.asarray(q_at_weld, dtype=np.float64))
            except Exception:
                _log.exception("welded callback failed")

    def _back_out(self, plan: StudPlan) -> None:
        """Straight back out along the normal to the approach pose (after a cancel, not a halt)."""
        with self._lock:
            if self._halt:
                return
            stop_count = self.client.stop_count  # a later halt still interrupts this move
        try:
            self.client.move_linear_and_wait(matrix_to_pose6(plan.T_approach), self.params.linear_speed_pct,
                                             self.params.motion_timeout_s, stop_count=stop_count)
            self._below_clearance = False
        except ArmError as exc:
            _log.error("could not back out along the normal: %s", exc)

    def _abort_motion(self) -> None:
        self._stop_arm()
        self._trigger_low()

    def _recover(self, t: StudTarget, phase: str) -> None:
        """After a connection loss: reconnect, trigger low, wait until idle, set up the controller
        again, back out along the normal.

        The controller may have restarted (power cycle, watchdog): then its IO is back in input
        mode, where a DO cannot be driven, and its tool frame is the factory one. So the trigger IO
        is put in output mode and low at once, and everything else :meth:`_prepare` sets is set
        again before the first motion.
        """
        p = self.params
        self._check_halt()
        self.client.reconnect(p.reconnect_timeout_s)
        try:
            self._prepare_trigger()
        except ArmError as exc:
            raise ArmConnectionError(f"the trigger output could not be set low after reconnecting: {exc}") from exc
        self.client.wait_idle(p.motion_timeout_s)
        self._prepare()
        self._check_halt()
        if phase in ("descend", "weld", "dwell", "retract") or self._below_clearance:
            # Straight back along the normal to the standoff, keeping the current orientation.
            T_back = self.safety.kin.fk(self.client.get_state().joints_rad) @ p.tool_T
            T_back[:3, 3] = t.position + p.standoff_m * t.normal
            self._move("linear", T_back, p.linear_speed_pct)
            self._below_clearance = False
