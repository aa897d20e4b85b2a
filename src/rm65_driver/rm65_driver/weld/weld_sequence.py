"""The weld job: approach, descend, trigger, dwell, retract — for each stud, resumable, never twice.

Pure Python on top of :class:`~rm65_driver.protocol.arm_client.ArmClient`,
:class:`~rm65_driver.journal.writer.Journal` and :class:`~rm65_driver.weld.safety.SafetyChecker`; the ROS
node only converts ``WeldTarget`` messages to :class:`~rm65_driver.weld.weld_job.StudTarget` and forwards
feedback. The job's inputs and result (:class:`~rm65_driver.weld.weld_job.WeldParams`, ``JobResult``) are in
:mod:`.weld_job`.

Per target, in order:

1. journal says **welded** -> not touched (reported welded when ``resume``, else skipped
   "already welded"); journal says **uncertain** -> refused (failed, "needs an operator
   decision": ``/arm/resolve_stud``);
2. safety check: the reach verdict (:mod:`.reach`, the planner's own test: gun tilt from
   vertical, workspace, reach/IK inside the joint limits for some rotation about the stud's axis,
   straight descent feasible), then the rotation and solution nearest the current joints
   (:mod:`.reach_move`); with ``min_stud_spacing_m``, room for the gun's foot beside the job's studs
   already welded or uncertain: :mod:`.welded_neighbours`): a rejection is journaled
   ``skipped(reason)`` and nothing is sent;
3.-7. the stud's cycle (:mod:`.stud_cycle`): ``approach``, ``descend`` along the normal, ``weld``
   (journal ``started``, then the trigger pulse), ``dwell`` (journal ``welded``), ``retract`` to
   the approach pose. The next stud is planned during the dwell.

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
from typing import Sequence

import numpy as np

from rm65_driver.journal.records import JournalError
from rm65_driver.journal.writer import Journal
from rm65_driver.kinematics.rm65 import tool_pose_facing
from rm65_driver.protocol.arm_client import ArmClient, ArmConnectionError, ArmError
from rm65_driver.weld.job_control import JobControl, JobEnded
from rm65_driver.weld.safety import SafetyChecker
from rm65_driver.weld.stud_cycle import StudCycle
from rm65_driver.weld.stud_order import order_by_path
from rm65_driver.weld.weld_job import JobResult, PhaseCallback, StudTarget, WeldedCallback, WeldParams, new_job_id
from stud_common.vocabulary import JournalStatus, OnDisconnect, StudOrder, WeldPhase

_log = logging.getLogger(__name__)

#: How a job goes on after a connection loss at a stud (:meth:`WeldSequence._after_connection_loss`).
_RETRY, _NEXT, _END = "retry", "next", "end"


class WeldSequence:
    """Runs weld jobs on one arm; thread-safe control (:meth:`cancel`, :meth:`halt`, :meth:`pause`).

    Its parts: :attr:`control` (the job's flags and progress, :mod:`.job_control`) and :attr:`cycle`
    (one stud on the arm, :mod:`.stud_cycle`)."""

    def __init__(self, client: ArmClient, journal: Journal, safety: SafetyChecker, params: WeldParams,
                 on_phase: PhaseCallback | None = None, on_welded: WeldedCallback | None = None):
        self.client = client
        self.journal = journal
        self.safety = safety
        self.params = params
        if not np.allclose(safety.tool_T, params.tool_T):
            raise ValueError("the safety checker's tool transform differs from params.tool_T")
        self.control = JobControl(on_phase)
        self.cycle = StudCycle(client, journal, safety, params, self.control, on_welded)

    # -- what the driver reads and sets ------------------------------------------------------------
    @property
    def running(self) -> bool:
        return self.control.running

    @property
    def current_stud(self) -> str:
        return self.control.current_stud

    @property
    def phase(self) -> str:
        return self.control.phase

    @property
    def done(self) -> int:
        return self.control.done

    @property
    def total(self) -> int:
        return self.control.total

    @property
    def job_id(self) -> str:
        """The running (or last) job's id; in every journal record it writes."""
        return self.control.job_id

    @property
    def plans_ahead_used(self) -> int:
        """Next-stud plans made during a dwell and used (for tests and logs)."""
        return self.cycle.lookahead.used

    @property
    def on_phase(self) -> PhaseCallback | None:
        return self.control.on_phase

    @on_phase.setter
    def on_phase(self, callback: PhaseCallback | None) -> None:
        self.control.on_phase = callback

    @property
    def on_welded(self) -> WeldedCallback | None:
        return self.cycle.on_welded

    @on_welded.setter
    def on_welded(self, callback: WeldedCallback | None) -> None:
        self.cycle.on_welded = callback

    # ------------------------------------------------------------------------------------
    # control from other threads
    # ------------------------------------------------------------------------------------
    def cancel(self) -> None:
        """Graceful stop: motions before the trigger are stopped now; a started weld completes."""
        c = self.control
        with c.lock:
            c.cancelled = True
            phase = c.phase
            c.paused = False
            c.wake.notify_all()
        if phase in (WeldPhase.APPROACH, WeldPhase.DESCEND):
            self.cycle.stop_arm()

    def halt(self, reason: str = "stop requested") -> None:
        """Immediate stop: ``set_arm_stop`` now, trigger output low, job ends, nothing else moves."""
        c = self.control
        with c.lock:
            c.halted = True
            c.halt_reason = reason
            c.paused = False
            c.wake.notify_all()
        self.cycle.stop_arm()
        self.cycle.trigger_low()

    def pause(self) -> None:
        """Pause the running motion on its path; no new phase starts until :meth:`resume`."""
        c = self.control
        with c.lock:
            c.paused = True
        try:
            self.client.pause()
        except ArmError:
            with c.lock:
                c.paused = False  # not paused: the job must not wait for a resume that never comes
                c.wake.notify_all()
            raise

    def resume(self) -> None:
        self.client.resume()
        c = self.control
        with c.lock:
            c.paused = False
            c.wake.notify_all()

    # ------------------------------------------------------------------------------------
    # the job
    # ------------------------------------------------------------------------------------
    def run(self, targets: Sequence[StudTarget], resume: bool = True) -> JobResult:
        """Weld ``targets`` in order (blocking). See the module docstring for the rules."""
        res = JobResult()
        c = self.control
        with c.lock:
            if c.running:
                res.message = "a weld job is already running"
                return res
            c.running = True
            c.cancelled = c.halted = c.paused = False
            self.cycle.start_job(list(targets))
            c.total, c.done = len(targets), 0
            c.job_id = res.job_id = new_job_id()
        try:
            self._run(list(targets), resume, res)
        finally:
            with c.lock:
                c.running = False
                c.current_stud = c.phase = ""
        _log.info("weld job ended: %s", res.message)
        return res

    def _run(self, targets: list[StudTarget], resume: bool, res: JobResult) -> None:
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
            self.cycle.prepare()
        except ArmError as exc:
            res.message = f"job not started: {exc}"
            return

        with self.control.lock:
            self.control.epoch = self.client.stop_count  # any stop from now on ends every motion of this job
        request_order = {t.stud_id: k for k, t in enumerate(targets)}
        if self.params.stud_order != StudOrder.GIVEN:
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
            if self.journal.status(t.stud_id) in (JournalStatus.WELDED, JournalStatus.UNCERTAIN):
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
                              q_end=q_now if p.stud_order == StudOrder.TOUR else None)
        return [solved[k] for k in order] + rest

    def _weld_all(self, targets: list[StudTarget], resume: bool, res: JobResult) -> None:
        c = self.control
        i = 0
        reconnects = 0
        while i < len(targets):
            t = targets[i]
            if c.cancelled or c.halted:
                self._end_unprocessed(targets[i:], res)
                res.message = c.stop_message()
                return
            if self._settled_by_journal(t, resume, res):
                i += 1
                continue
            try:
                outcome = self.cycle.do_stud(t, res, targets[i + 1] if i + 1 < len(targets) else None)
            except ArmConnectionError as exc:
                reconnects += 1
                step = self._after_connection_loss(targets, i, reconnects, exc, res)
                if step == _END:
                    return
                if step == _NEXT:
                    i += 1
                    reconnects = 0
                continue  # the same stud again (it was never triggered), or the next one
            except JobEnded as end:
                self._after_job_ended(targets, i, end, res)
                return
            reconnects = 0
            if outcome == JournalStatus.WELDED:
                res.welded.append(t.stud_id)
            i += 1
        self.cycle.trigger_low()
        stopped = c.cancelled or c.halted
        res.success = not res.failed and not stopped
        res.message = c.stop_message() if stopped else (
            f"done: {len(res.welded)} welded, {len(res.skipped)} skipped, {len(res.failed)} failed")

    def _settled_by_journal(self, t: StudTarget, resume: bool, res: JobResult) -> bool:
        """A stud the journal already decides (welded: not touched; uncertain: refused); True if so."""
        status = self.journal.status(t.stud_id)
        if status == JournalStatus.WELDED:
            if resume:
                res.welded.append(t.stud_id)
            else:
                res.skipped.append(t.stud_id)
                res.messages.append(f"{t.stud_id}: already welded (journal); not welded again")
            self.control.finish_one(t, WeldPhase.SKIP)
            return True
        if status == JournalStatus.UNCERTAIN:
            res.failed.append(t.stud_id)
            res.messages.append(f"{t.stud_id}: uncertain in the journal (started, never confirmed): "
                                "needs an operator decision (resolve_stud) before it can be welded")
            self.control.finish_one(t, WeldPhase.SKIP)
            return True
        return False

    def _after_connection_loss(self, targets: list[StudTarget], i: int, reconnects: int, exc: ArmConnectionError,
                               res: JobResult) -> str:
        """Recover from a connection loss at ``targets[i]`` (the ``reconnects``-th there) and say how the
        job goes on: :data:`_RETRY` the same stud (never triggered), :data:`_NEXT` stud, or :data:`_END`."""
        t = targets[i]
        phase = self.control.phase
        status = self.journal.status(t.stud_id)
        _log.warning("connection lost at stud %s (phase %s, journal %s): %s", t.stud_id, phase, status, exc)
        recovered = ""
        try:
            self.cycle.recover(t, phase)
        except (ArmError, JobEnded) as exc2:
            recovered = str(exc2)
        if status == JournalStatus.WELDED:  # lost during the retract: the stud is done
            res.welded.append(t.stud_id)
        elif status == JournalStatus.UNCERTAIN:
            res.failed.append(t.stud_id)
            res.messages.append(f"{t.stud_id}: uncertain (connection lost after the trigger); "
                                "not re-welded, needs an operator decision")
        if recovered:
            self._end_unprocessed(targets[i:], res)
            res.message = f"aborted: connection lost at {t.stud_id} and not recovered: {recovered}"
            return _END
        if status in (JournalStatus.WELDED, JournalStatus.UNCERTAIN):
            self.control.finish_one(t, WeldPhase.SKIP)
            if status == JournalStatus.UNCERTAIN and self.params.on_disconnect == OnDisconnect.ABORT:
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

    def _after_job_ended(self, targets: list[StudTarget], i: int, end: JobEnded, res: JobResult) -> None:
        """The job ended (cancel, halt, abort) at ``targets[i]``: the stud's outcome from the journal."""
        t = targets[i]
        status = self.journal.status(t.stud_id)
        if status == JournalStatus.WELDED:
            res.welded.append(t.stud_id)
        elif status == JournalStatus.UNCERTAIN:
            res.failed.append(t.stud_id)
            res.messages.append(f"{t.stud_id}: uncertain (job ended after the trigger): "
                                "needs an operator decision")
        elif not str(end).startswith(("cancelled", "halted")):
            res.failed.append(t.stud_id)
            res.messages.append(f"{t.stud_id}: {end}")
        self._end_unprocessed(targets[i:], res)
        res.message = str(end)

    def _end_unprocessed(self, rest: Sequence[StudTarget], res: JobResult) -> None:
        for t in rest:
            if t.stud_id not in res.welded and t.stud_id not in res.failed and t.stud_id not in res.skipped:
                res.messages.append(f"{t.stud_id}: not processed (job ended)")
