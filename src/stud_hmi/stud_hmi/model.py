"""What the HMI shows, ROS-free: the stud table, the job's progress and timing, the alarms, the
safety banner, which buttons are valid now, and the decisions waiting for the operator.

The node (hmi_node) converts messages to the plain values taken here; this module decides
what the page says, and builds the JSON-ready dicts it renders (see docs/HMI.md).

By concern: :mod:`~stud_hmi.stud_table` (the per-stud table: targets, weld states,
inspection, rework), :mod:`~stud_hmi.alarms` (codes, severities, the alarm list),
:mod:`~stud_hmi.job_clock` (the job's states and its clock), :mod:`~stud_hmi.calibration_display`
(the calibration display); here :class:`CellView` puts them together with the arm, the cell, the
buttons and the decisions. The names of those modules are importable from here too.

Per-stud state: a stud's *target* (status, pose, errors) comes from ``/weld_targets``, one
view at a time; its *weld state* comes from the arm: the WeldJob feedback (phase per stud),
``/arm/state`` (the stud being processed) and the WeldJob results (welded / skipped / failed
lists, the truth). The two are kept apart, so a new view never clears a weld. A welded stud's
*inspection* verdict comes from ``/inspection/result`` and the operator's rework decision on it
from ``/inspection/rework``; the bend tests the QA record lists, with their results, from
``/inspection/bend_tests``. Every decision the page sends is signed with the operator's name, which
the page asks once per session (``operator`` in the command; stud_inspection.operator_log checks it).
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any, Iterable

from stud_common.vocabulary import ArmMode, CellState, TargetStatus
from stud_hmi.alarms import ALARMS, DIAG_CODE, STATE_SOURCES, Alarm, AlarmDef, AlarmList, Code, Severity
from stud_hmi.calibration_display import HandEyeDisplay, hand_eye_text, same_hand_eye
from stud_hmi.job_clock import ENDED_STATES, OPERATOR_STOP_TEXT, RUNNING_STATES, JobClock
from stud_hmi.stud_table import (
    FINAL_WELD_STATES,
    STATUS_NOT_SEEN,
    STATUS_OUT_OF_VIEW,
    WELD_ACTIVE,
    WELD_FAILED,
    WELD_NONE,
    WELD_SKIPPED,
    WELD_WELDED,
    StudTable,
    TargetInfo,
)
from stud_inspection.operator_log import OperatorError, operator_name

__all__ = [
    "ArmMode", "CellState", "TargetStatus",
    "ALARMS", "DIAG_CODE", "STATE_SOURCES", "Alarm", "AlarmDef", "AlarmList", "Code", "Severity",
    "HandEyeDisplay", "hand_eye_text", "same_hand_eye",
    "ENDED_STATES", "OPERATOR_STOP_TEXT", "RUNNING_STATES", "JobClock",
    "FINAL_WELD_STATES", "STATUS_NOT_SEEN", "STATUS_OUT_OF_VIEW", "WELD_ACTIVE", "WELD_FAILED", "WELD_NONE",
    "WELD_SKIPPED", "WELD_WELDED", "StudTable", "TargetInfo",
    "ArmInfo", "CellInfo", "Timeouts", "BEND_RESULTS", "COMMANDS", "STUD_DECISIONS", "CellView",
]


def _enum_or_int(enum_type, value: int):
    try:
        return enum_type(value)
    except ValueError:
        return int(value)


def _text(value) -> str:
    return str(getattr(value, "text", value))


# -- inputs, as plain values ---------------------------------------------------------------------
@dataclass(frozen=True)
class ArmInfo:
    """``/arm/state``, the fields the HMI uses."""

    mode: int                       # ArmMode
    connected: bool
    current_stud: str = ""
    message: str = ""
    errors: tuple[str, ...] = ()    # decoded controller errors
    uncertain: tuple[str, ...] = ()  # journal: started, never confirmed (not the stud being welded now)


@dataclass(frozen=True)
class CellInfo:
    """``/cell/status``."""

    state: int                      # CellState
    station: int = 0
    stations_total: int = 0
    studs_total: int = 0
    studs_welded: int = 0
    studs_failed: int = 0
    unreachable: tuple[str, ...] = ()
    message: str = ""
    unreachable_reasons: tuple[str, ...] = ()   # one per unreachable id ("unreachable: approach pose ...")


@dataclass(frozen=True)
class Timeouts:
    """When an input counts as lost [s] (the driver publishes /arm/state at 10 Hz, the sequencer
    /cell/status every 1 s, every node /diagnostics every 1 s)."""

    arm_s: float = 2.0
    cell_s: float = 5.0
    diagnostics_s: float = 10.0


#: Page commands and what each does (the node maps them to services).
COMMANDS = ("start", "pause", "resume", "stop", "estop", "ack", "resolve_stud", "record_rework", "record_bend_test")
#: Bend-test results the page sends (stud_inspection.bend.BendResult's values).
BEND_RESULTS = ("pass", "fail")
#: Decisions on an uncertain stud (ResolveStud): the page's words -> welded?
STUD_DECISIONS = {"welded": True, "weld_again": False}


class CellView:
    """Everything the page shows, from the cell's inputs: the table, progress and timing, alarms,
    the safety banner, the valid buttons, and the decisions waiting for the operator."""

    def __init__(self, timeouts: Timeouts = Timeouts(), max_history: int = 50) -> None:
        self.timeouts = timeouts
        self.table = StudTable()
        self.alarms = AlarmList(max_history)
        self.clock = JobClock()
        self.arm: ArmInfo | None = None
        self.cell: CellInfo | None = None
        self._arm_at: float | None = None   # when /arm/state last came
        self._cell_at: float | None = None
        self._diag_at: dict[str, float] = {}
        self.part = {"part": "", "drawing": "", "drawing_file": "", "studs": 0, "warnings": []}
        self.has_layout = False
        self.registration: dict | None = None
        self.hand_eye = HandEyeDisplay()
        self.bend_tests: list[dict] = []   # the QA record's list (/inspection/bend_tests), results and all
        self.bend_code = ""
        self.changed = True

    # -- inputs ----------------------------------------------------------------------------------
    def set_layout(self, stud_ids: Iterable[str], drawing_file: str, part_name: str = "",
                   warnings: Iterable[str] = ()) -> None:
        ids = list(stud_ids)
        self.table.set_layout(ids)
        stem = os.path.splitext(os.path.basename(drawing_file))[0]
        self.part = {"part": part_name or stem, "drawing": os.path.basename(drawing_file),
                     "drawing_file": drawing_file, "studs": len(ids), "warnings": list(warnings)}
        self.has_layout = True
        self._rework_alarm(None)
        self.changed = True

    def on_arm(self, arm: ArmInfo, now: float) -> bool:
        """``/arm/state``; True when the stud table changed (another stud in progress)."""
        self.arm, self._arm_at = arm, now
        table_changed = self.table.arm_progress(arm.current_stud)
        mode = _enum_or_int(ArmMode, arm.mode)
        causes: dict[tuple[str, str], str] = {}
        src = "rm65_driver"
        if mode == ArmMode.ESTOP:
            causes[Code.ESTOP, src] = (f"{arm.message or 'e-stop engaged'}: the arm refuses every motion; release it "
                                       "at the cell (/arm/estop false) once the cell is safe")
        elif mode == ArmMode.FAULT:
            causes[Code.ARM_FAULT, src] = "; ".join(filter(None, (arm.message, *arm.errors))) or "fault"
        if mode == ArmMode.DISCONNECTED or not arm.connected:
            causes[Code.ARM_DISCONNECTED, src] = arm.message or "the driver has no connection to the controller"
        if arm.uncertain:
            causes[Code.UNCERTAIN, src] = (f"{len(arm.uncertain)} stud(s) started but never confirmed: "
                                           f"{', '.join(arm.uncertain[:10])}{' …' if len(arm.uncertain) > 10 else ''}"
                                           " — decide on the page: weld again or mark as welded")
        self.alarms.update("arm", causes, now)
        self.alarms.update("arm_link", {}, now)
        self.changed = True
        return table_changed

    def on_cell(self, cell: CellInfo, now: float) -> bool:
        """``/cell/status``; True when the stud table changed (studs named unreachable, or no longer)."""
        self.cell, self._cell_at = cell, now
        table_changed = self.table.set_unreachable(dict(zip(cell.unreachable, cell.unreachable_reasons)))
        self.clock.cell_state(cell.state, now)
        causes: dict[tuple[str, str], str] = {}
        src = "cell_sequencer"
        if cell.state == CellState.FAILED and not cell.message.startswith(OPERATOR_STOP_TEXT):
            causes[Code.CELL_FAILED, src] = cell.message or "the job ended in failure"
        if cell.unreachable:
            causes[Code.UNREACHABLE, src] = (f"{len(cell.unreachable)} stud(s) the arm cannot weld "
                                             "(see the stud table): "
                                             f"{', '.join(cell.unreachable[:10])}"
                                             f"{' …' if len(cell.unreachable) > 10 else ''}")
        self.alarms.update("cell", causes, now)
        self.alarms.update("cell_link", {}, now)
        self.changed = True
        return table_changed

    def on_registration(self, valid: bool, residual_mm: float, message: str, now: float) -> None:
        self.registration = {"valid": valid, "residual_mm": residual_mm, "message": message}
        causes = {} if valid else {(Code.REGISTRATION, "registration"): message or "not valid"}
        self.alarms.update("registration", causes, now)
        self.changed = True

    def on_hand_eye(self, node: str, summary: dict, now: float) -> None:
        """``/calibration/hand_eye`` of one node (HandEyeInUse.summary(), JSON)."""
        self.alarms.update("calibration", self.hand_eye.update(node, summary), now)
        self.changed = True

    def weld_feedback(self, stud_id: str, phase: str, now: float) -> None:
        if self.table.weld_feedback(stud_id, phase):
            self.clock.welded(now)
        self.changed = True

    def job_result(self, welded: Iterable[str], skipped: Iterable[str], failed: Iterable[str]) -> None:
        self.table.job_result(welded, skipped, failed)
        self.changed = True

    def on_inspection(self, verdicts: Iterable[tuple[str, str, Iterable[str]]], now: float) -> None:
        """One station's ``/inspection/result``: (stud id, verdict, reasons) per stud."""
        for sid, verdict, reasons in verdicts:
            self.table.inspected(sid, verdict, reasons)
        self._rework_alarm(now)
        self.changed = True

    def on_rework(self, stud_id: str, decision: str, now: float) -> None:
        self.table.rework_decided(stud_id, decision)
        self._rework_alarm(now)
        self.changed = True

    def on_bend_tests(self, tests: Iterable[dict], qa_code: str) -> None:
        """``/inspection/bend_tests``: the studs to bend-test (stud_id, reasons, angle_deg, direction,
        result, operator, time), the newest list replacing the last."""
        self.bend_tests = [dict(t) for t in tests]
        self.bend_code = qa_code
        self.table.bend_results({t["stud_id"]: t.get("result") or "to do" for t in self.bend_tests})
        self.changed = True

    def _rework_alarm(self, now: float | None) -> None:
        waiting = [r["stud_id"] for r in self.table.awaiting_rework()]
        causes = {}
        if waiting:
            causes[Code.REWORK, "inspector"] = (f"{len(waiting)} stud(s) did not pass inspection: "
                                               f"{', '.join(waiting[:10])}{' …' if len(waiting) > 10 else ''}"
                                               " — decide on the page: rework or accept")
        self.alarms.update("inspection", causes, now if now is not None else 0.0)

    def on_diagnostic(self, name: str, level: int, message: str, now: float) -> None:
        """One /diagnostics status. Nodes in :data:`STATE_SOURCES` are alarmed from their topics."""
        if name in STATE_SOURCES:
            return
        self._diag_at[name] = now
        code = DIAG_CODE.get(level)
        self.alarms.update(f"diag:{name}", {(code, name): message} if code else {}, now)

    def tick(self, now: float) -> None:
        """Inputs that stopped: /arm/state, /cell/status, a node's diagnostics."""
        t = self.timeouts
        if self._arm_at is not None and now - self._arm_at > t.arm_s:
            self.alarms.update("arm_link", {(Code.ARM_LOST, "rm65_driver"): (
                f"no /arm/state for {now - self._arm_at:.0f} s: is the arm driver running? "
                "(the page shows its last state)")}, now)
        if self._cell_at is not None and now - self._cell_at > t.cell_s:
            self.alarms.update("cell_link", {(Code.CELL_LOST, "cell_sequencer"): (
                f"no /cell/status for {now - self._cell_at:.0f} s: is the cell sequencer running?")}, now)
        for name, at in list(self._diag_at.items()):
            if now - at > t.diagnostics_s:  # no longer reported: its cause is not known to be there
                self.alarms.update(f"diag:{name}", {}, now)
                del self._diag_at[name]

    def acknowledge(self, key: str, now: float) -> int:
        return self.alarms.acknowledge(key, now)

    # -- what the page shows -----------------------------------------------------------------------
    @property
    def arm_mode(self):
        return None if self.arm is None else _enum_or_int(ArmMode, self.arm.mode)

    @property
    def cell_state(self):
        return None if self.cell is None else _enum_or_int(CellState, self.cell.state)

    def arm_stale_s(self, now: float) -> float | None:
        if self._arm_at is None or now - self._arm_at <= self.timeouts.arm_s:
            return None
        return now - self._arm_at

    def safety(self, now: float) -> dict | None:
        """The full-width banner: the e-stop latch or an arm FAULT (None: neither)."""
        mode, arm = self.arm_mode, self.arm
        if arm is None or mode not in (ArmMode.ESTOP, ArmMode.FAULT):
            return None
        stale = self.arm_stale_s(now)
        if mode == ArmMode.ESTOP:
            out: dict[str, Any] = {"kind": "estop", "title": "E-STOP LATCHED",
                   "text": (arm.message or "e-stop engaged") + ". The arm refuses every motion. Make the cell safe, "
                           "then release the latch at the cell (/arm/estop false)."}
        else:
            out = {"kind": "fault", "title": "ARM FAULT",
                   "text": "; ".join(filter(None, (arm.message, *arm.errors))) or "fault"}
        out["stale_s"] = stale
        if stale is not None:
            out["text"] += f" (last known state, {stale:.0f} s ago: the arm driver is silent)"
        return out

    def _arm_blocks_motion(self, now: float) -> str | None:
        mode = self.arm_mode
        if self.arm is None:
            return "no /arm/state: is the arm driver running?"
        if self.arm_stale_s(now) is not None:
            return "the arm driver is silent (no /arm/state)"
        if mode == ArmMode.ESTOP:
            return "e-stop latched"
        if mode == ArmMode.FAULT:
            return "the arm is in FAULT"
        if mode == ArmMode.DISCONNECTED or not self.arm.connected:
            return "the arm controller is not connected"
        return None

    def controls(self, now: float) -> dict[str, dict]:
        """Per button: ``enabled`` and ``why`` (why not, or what it will do)."""
        state, arm_block = self.cell_state, self._arm_blocks_motion(now)
        cell_lost = self._cell_at is not None and now - self._cell_at > self.timeouts.cell_s

        def c(ok: bool, why: str) -> dict:
            return {"enabled": bool(ok), "why": why}

        if state is None or cell_lost:
            no_cell = "no /cell/status: is the cell sequencer running?"
            start = pause = resume = c(False, no_cell)
        else:
            if state not in ENDED_STATES:
                start = c(False, f"a job is under way ({_text(state)})")
            elif arm_block:
                start = c(False, arm_block)
            elif not self.has_layout:
                start = c(False, "no drawing loaded (/drawing/layout)")
            else:
                start = c(True, f"start the job on {self.part['drawing'] or 'the drawing'}")
            pause = (c(True, "pause the job at the next safe point") if state in RUNNING_STATES
                     else c(False, f"no job is moving ({_text(state)})"))
            if state != CellState.PAUSED:
                resume = c(False, f"the job is not paused ({_text(state)})")
            elif arm_block:
                resume = c(False, arm_block)
            else:
                resume = c(True, "resume the paused job")
        mode = self.arm_mode
        moving_arm = mode in (ArmMode.MOVING, ArmMode.WELDING, ArmMode.PAUSED)
        under_way = state is not None and state not in ENDED_STATES
        if under_way or moving_arm or state is None or cell_lost or self.arm is None:
            stop = c(True, "stop the job and the arm")
        else:
            stop = c(False, f"nothing is running (cell {_text(state)}, arm {_text(mode)})")
        estop = c(True, "software stop of the arm and the job, latched (not the safety-rated e-stop)")
        return {"start": start, "pause": pause, "resume": resume, "stop": stop, "estop": estop}

    def decisions(self, now: float) -> dict:
        """The operator decisions the page offers: uncertain studs (the journal) and studs that did
        not pass inspection (rework or accept)."""
        mode = self.arm_mode
        if self.arm is None:
            why = "no /arm/state: is the arm driver running?"
        elif self.arm_stale_s(now) is not None:
            why = "the arm driver is silent (no /arm/state)"
        elif mode == ArmMode.FAULT:
            why = "the arm is in FAULT: resolve the journal first (/arm/resolve_journal)"
        elif mode == ArmMode.DISCONNECTED:
            why = "the arm driver is not connected"
        else:
            why = ""
        uncertain = list(self.arm.uncertain) if self.arm is not None else []
        pending = [t for t in self.bend_tests if not t.get("result")]
        return {"uncertain": uncertain, "uncertain_enabled": not why, "uncertain_why": why,
                "rework": self.table.awaiting_rework(),
                "bend_tests": pending + [t for t in self.bend_tests if t.get("result")], "bend_code": self.bend_code}

    def check_command(self, cmd: str, msg: dict, now: float) -> str | None:
        """Why ``cmd`` is not valid now (None: it is). Stop and e-stop are never refused here."""
        if cmd in ("stop", "estop", "ack"):
            return None
        if cmd in ("start", "pause", "resume"):
            c = self.controls(now)[cmd]
            return None if c["enabled"] else c["why"]
        if cmd == "resolve_stud":
            d = self.decisions(now)
            sid, decision = msg.get("stud_id"), msg.get("decision")
            if decision not in STUD_DECISIONS:
                return f"decision must be one of {list(STUD_DECISIONS)}, got {decision!r}"
            if not d["uncertain_enabled"]:
                return d["uncertain_why"]
            if sid not in d["uncertain"]:
                return f"{sid!r} is not an uncertain stud of the arm's journal"
            return None
        if cmd in ("record_rework", "record_bend_test"):
            if not isinstance(msg.get("stud_id"), str) or not msg.get("stud_id"):
                return "no stud_id given"
            if not isinstance(msg.get("note", ""), str):
                return "note must be a string"
            try:
                signer = msg.get("operator")
                operator_name(signer if isinstance(signer, str) else "")
            except OperatorError as exc:
                return f"{exc} (the page asks for it once per session)"
            if cmd == "record_bend_test":
                if msg.get("result") not in BEND_RESULTS:
                    return f"result must be one of {list(BEND_RESULTS)}, got {msg.get('result')!r}"
                angle = msg.get("angle_deg")
                if angle is not None and (isinstance(angle, bool) or not isinstance(angle, (int, float))):
                    return f"angle_deg must be a number, got {angle!r}"
            # the inspector checks the decision and the verdict (one place: stud_inspection.rework, .bend)
            return None
        return f"unknown command {cmd!r}; expected one of {list(COMMANDS)}"

    def progress(self, now: float) -> dict:
        """Studs, not stations: welded / total from the studs' weld states (the cell's own count
        when it is higher: it also knows studs welded before the HMI started)."""
        counts = self.table.weld_counts()
        total = len(self.table.stud_ids) or (self.cell.studs_total if self.cell else 0)
        welded = max(counts[WELD_WELDED], self.cell.studs_welded if self.cell else 0)
        unreachable = set(self.cell.unreachable) if self.cell else set()
        weld_of = {sid: self.table.weld_state(sid) for sid in self.table.stud_ids}
        unreachable_open = sum(1 for s in unreachable if weld_of.get(s, WELD_NONE) not in FINAL_WELD_STATES)
        remaining = max(0, total - welded - counts[WELD_FAILED] - counts[WELD_SKIPPED] - unreachable_open)
        cycle = self.clock.cycle_s
        running = self.clock.running
        eta = remaining * cycle if (running and cycle is not None) else (0.0 if self.clock.ended and not remaining
                                                                         else None)
        return {"welded": welded, "total": total, "failed": counts[WELD_FAILED], "skipped": counts[WELD_SKIPPED],
                "active": counts[WELD_ACTIVE], "remaining": remaining, "unreachable": len(unreachable),
                "percent": 100.0 * welded / total if total else 0.0,
                "station": self.cell.station if self.cell else 0,
                "stations_total": self.cell.stations_total if self.cell else 0,
                "running": running, "elapsed_s": self.clock.active_s(now), "cycle_s": cycle,
                "last_cycle_s": self.clock.last_cycle_s, "eta_s": eta}

    def calibration(self) -> dict | None:
        """The hand-eye in use (the first node's; ``agree`` false when nodes differ)."""
        return self.hand_eye.message()

    def status_message(self, now: float) -> dict:
        """The ``status`` WebSocket message (docs/HMI.md)."""
        cell = self.cell
        return {"type": "status", "now": now, "safety": self.safety(now), "controls": self.controls(now),
                "progress": self.progress(now), "decisions": self.decisions(now),
                "part": self.part, "calibration": self.calibration(), "registration": self.registration,
                "cell": None if cell is None else {"state": _text(self.cell_state), "state_code": int(cell.state),
                                                   "message": cell.message},
                "arm": None if self.arm is None else {"mode": _text(self.arm_mode), "stale_s": self.arm_stale_s(now)}}

