"""What the HMI shows, ROS-free: the stud table, the job's progress and timing, the alarms, the
safety banner, which buttons are valid now, and the decisions waiting for the operator.

The node (hmi_node) converts messages to the plain values taken here; this module decides
what the page says, and builds the JSON-ready dicts it renders (see docs/HMI.md).

Per-stud state: a stud's *target* (status, pose, errors) comes from ``/weld_targets``, one
view at a time; its *weld state* comes from the arm: the WeldJob feedback (phase per stud),
``/arm/state`` (the stud being processed) and the WeldJob results (welded / skipped / failed
lists, the truth). The two are kept apart, so a new view never clears a weld. A welded stud's
*inspection* verdict comes from ``/inspection/result`` and the operator's rework decision on it
from ``/inspection/rework``.
"""
from __future__ import annotations

import enum
import math
import os
from dataclasses import dataclass
from typing import Iterable

from stud_common.vocabulary import ArmMode, CellState, TargetStatus
from stud_planner.cell.rework import NEEDS_DECISION

#: Weld states of a stud, as sent in the rows' ``weld`` field.
WELD_NONE, WELD_ACTIVE, WELD_WELDED, WELD_SKIPPED, WELD_FAILED = "", "active", "welded", "skipped", "failed"
_FINAL = (WELD_WELDED, WELD_SKIPPED, WELD_FAILED)
#: WeldJob feedback phases while a stud is being worked on (rm65_driver.weld_sequence).
_ACTIVE_PHASES = ("approach", "descend", "weld", "dwell")
#: The driver reports "retract" only after the weld is confirmed and journalled as welded.
_WELDED_PHASE = "retract"
STATUS_OUT_OF_VIEW = TargetStatus.OUT_OF_VIEW.text
STATUS_NOT_SEEN = "not_seen"  # in the drawing, in no view yet


@dataclass(frozen=True)
class TargetInfo:
    """One stud's match on one view, in the message's units (metres, degrees)."""

    stud_id: str
    status: str                               # WeldTarget.status_text, "ok" when usable
    status_code: int                          # WeldTarget.STATUS_*
    position_m: tuple[float, float, float]    # world frame; NaN when not matched
    xy_error_m: float
    inclination_deg: float
    view: int


class StudTable:
    """The operator's stud table: one row per stud, drawing order first, then order of appearance."""

    def __init__(self) -> None:
        self._order: dict[str, None] = {}  # an ordered set
        self._targets: dict[str, TargetInfo] = {}
        self._weld: dict[str, str] = {}
        self._phase: dict[str, str] = {}
        self._active = ""  # the stud the arm is on now
        self._inspection: dict[str, tuple[str, tuple[str, ...]]] = {}  # stud -> (verdict, reasons)
        self._rework: dict[str, str] = {}  # stud -> the operator's decision ("rework" / "accept")
        self._has_layout = False
        self.view = -1
        self.algorithm = ""

    def _known(self, stud_id: str) -> None:
        if stud_id:
            self._order.setdefault(stud_id, None)

    def set_layout(self, stud_ids: Iterable[str]) -> None:
        """The drawing: its studs in drawing order (those in no view yet are "not seen").

        The first layout only orders what is known (it may arrive after the first view or job
        result when the HMI starts before the drawing node); a later one is another drawing:
        everything is forgotten."""
        ids = dict.fromkeys(stud_ids)
        if self._has_layout:
            self._targets.clear()
            self._weld.clear()
            self._phase.clear()
            self._inspection.clear()
            self._rework.clear()
            self._active = ""
            self.view = -1
            self._order = ids
        else:
            self._order = {**ids, **self._order}
        self._has_layout = True

    def update_view(self, targets: Iterable[TargetInfo], view: int = -1, algorithm: str = "") -> None:
        """The targets of one view. A stud out of this view keeps its result from an earlier view
        (the cell shoots several stations; each sees part of the drawing)."""
        for t in targets:
            self._known(t.stud_id)
            old = self._targets.get(t.stud_id)
            if t.status == STATUS_OUT_OF_VIEW and old is not None and old.status != STATUS_OUT_OF_VIEW:
                continue
            self._targets[t.stud_id] = t
        self.view, self.algorithm = view, algorithm

    def weld_feedback(self, stud_id: str, phase: str) -> bool:
        """WeldJob feedback: ``phase`` of ``stud_id`` (approach, descend, weld, dwell, retract, skip).
        True when this reports the stud welded for the first time."""
        self._known(stud_id)
        self._phase[stud_id] = phase
        newly = False
        if phase == _WELDED_PHASE:
            newly = self._weld.get(stud_id) != WELD_WELDED
            self._weld[stud_id] = WELD_WELDED
        if phase in _ACTIVE_PHASES:
            self._active = stud_id
        elif self._active == stud_id:
            self._active = ""
        return newly

    def arm_progress(self, current_stud: str) -> bool:
        """``/arm/state``: the stud being processed now ("" between studs and jobs). True if that changed."""
        if current_stud == self._active:
            return False
        self._known(current_stud)
        self._active = current_stud
        return True

    def job_result(self, welded: Iterable[str], skipped: Iterable[str], failed: Iterable[str]) -> list[str]:
        """A finished WeldJob: its lists are the truth for the studs they name. Returns the studs
        it reports welded that were not known welded before."""
        newly = []
        for ids, state in ((skipped, WELD_SKIPPED), (failed, WELD_FAILED), (welded, WELD_WELDED)):
            for sid in ids:
                self._known(sid)
                if state == WELD_WELDED and self._weld.get(sid) != WELD_WELDED:
                    newly.append(sid)
                self._weld[sid] = state
        self._active = ""
        return newly

    def inspected(self, stud_id: str, verdict: str, reasons: Iterable[str] = ()) -> None:
        """``/inspection/result``: the newest verdict of a stud (``Verdict`` values)."""
        self._known(stud_id)
        self._inspection[stud_id] = (verdict, tuple(reasons))

    def rework_decided(self, stud_id: str, decision: str) -> None:
        """``/inspection/rework``: the operator's decision on a stud that did not pass (the newest counts)."""
        self._known(stud_id)
        self._rework[stud_id] = decision

    def awaiting_rework(self) -> list[dict]:
        """Inspected studs that did not pass and have no decision yet, in table order."""
        out = []
        for sid in self._order:
            verdict, reasons = self._inspection.get(sid, ("", ()))
            if verdict in NEEDS_DECISION and sid not in self._rework:
                out.append({"stud_id": sid, "verdict": verdict, "reasons": list(reasons)})
        return out

    @property
    def stud_ids(self) -> list[str]:
        return list(self._order)

    def weld_state(self, stud_id: str) -> str:
        state = self._weld.get(stud_id, WELD_NONE)
        if state not in _FINAL and stud_id == self._active:
            return WELD_ACTIVE
        return state

    def rows(self) -> list[dict]:
        out = []
        for sid in self._order:
            t = self._targets.get(sid)
            weld = self.weld_state(sid)
            row = {"stud_id": sid, "status": t.status if t else STATUS_NOT_SEEN,
                   "status_code": t.status_code if t else None,
                   "inclination_deg": t.inclination_deg if t else None,
                   "position_mm": [v * 1000.0 for v in t.position_m] if t else None,
                   "xy_error_mm": t.xy_error_m * 1000.0 if t else None,
                   "view": t.view if t else None,
                   "weld": weld, "phase": self._phase.get(sid, ""), "welded": weld == WELD_WELDED,
                   "inspection": self._inspection.get(sid, ("", ()))[0],
                   "inspection_reasons": list(self._inspection.get(sid, ("", ()))[1]),
                   "rework": self._rework.get(sid, "")}
            out.append(row)
        return out

    def weld_counts(self) -> dict[str, int]:
        """How many studs are welded, failed, skipped, being welded, or not yet (``""``)."""
        counts = {state: 0 for state in (WELD_NONE, WELD_ACTIVE, *_FINAL)}
        for sid in self._order:
            counts[self.weld_state(sid)] += 1
        return counts

    def counts(self) -> dict[str, int]:
        counts: dict[str, int] = {}
        for sid in self._order:
            t = self._targets.get(sid)
            key = t.status if t else STATUS_NOT_SEEN
            counts[key] = counts.get(key, 0) + 1
        return counts

    def message(self) -> dict:
        """The ``targets`` WebSocket message (docs/HMI.md)."""
        rows = self.rows()
        return {"type": "targets", "view": self.view, "algorithm": self.algorithm, "rows": rows,
                "counts": self.counts(), "welded": sum(r["welded"] for r in rows), "total": len(rows)}



# -- the cell's and the arm's states: stud_common.vocabulary (tests check them against the messages) ---
#: A job is under way in these states (PAUSED is under way too, but does not move).
RUNNING_STATES = frozenset({CellState.REGISTERING, CellState.MOVING, CellState.SHOOTING, CellState.MATCHING,
                            CellState.WELDING, CellState.INSPECTING})
#: No job runs: a new one may start.
ENDED_STATES = frozenset({CellState.IDLE, CellState.DONE, CellState.FAILED})
#: The sequencer ends a job the operator stopped in FAILED with this message: not an alarm.
OPERATOR_STOP_TEXT = "stopped by the operator"


def _enum_or_int(enum_type, value: int):
    try:
        return enum_type(value)
    except ValueError:
        return int(value)


def _text(value) -> str:
    return value.text if isinstance(value, enum.Enum) else str(value)


class Severity(enum.IntEnum):
    WARNING = 1    # needs the operator's attention; the job goes on
    ERROR = 2      # the job stops, or cannot start
    CRITICAL = 3   # safety: the arm is stopped and will not move

    @property
    def text(self) -> str:
        return self.name.lower()


@dataclass(frozen=True)
class AlarmDef:
    code: str
    severity: Severity
    title: str


class Code:
    """Alarm codes (docs/HMI.md lists each with its cause and what to do)."""

    ESTOP, ARM_FAULT, ARM_DISCONNECTED, ARM_LOST, UNCERTAIN = "A100", "A101", "A102", "A103", "A104"
    CELL_FAILED, CELL_LOST, UNREACHABLE = "A110", "A111", "A112"
    REGISTRATION = "A120"
    REWORK = "A130"
    HAND_EYE = "A140"
    NODE_WARN, NODE_ERROR, NODE_STALE = "A201", "A202", "A203"


ALARMS: dict[str, AlarmDef] = {d.code: d for d in (
    AlarmDef(Code.ESTOP, Severity.CRITICAL, "e-stop latched"),
    AlarmDef(Code.ARM_FAULT, Severity.CRITICAL, "arm in FAULT"),
    AlarmDef(Code.ARM_DISCONNECTED, Severity.ERROR, "arm controller not connected"),
    AlarmDef(Code.ARM_LOST, Severity.ERROR, "no arm state"),
    AlarmDef(Code.UNCERTAIN, Severity.WARNING, "uncertain studs need a decision"),
    AlarmDef(Code.CELL_FAILED, Severity.ERROR, "cell job failed"),
    AlarmDef(Code.CELL_LOST, Severity.ERROR, "no cell status"),
    AlarmDef(Code.UNREACHABLE, Severity.WARNING, "studs no station reaches"),
    AlarmDef(Code.REGISTRATION, Severity.WARNING, "registration not valid"),
    AlarmDef(Code.REWORK, Severity.WARNING, "studs need a rework decision"),
    AlarmDef(Code.HAND_EYE, Severity.ERROR, "nodes use different hand-eye calibrations"),
    AlarmDef(Code.NODE_WARN, Severity.WARNING, "node warning"),
    AlarmDef(Code.NODE_ERROR, Severity.ERROR, "node error"),
    AlarmDef(Code.NODE_STALE, Severity.ERROR, "node stale"),
)}
_DIAG_CODE = {1: Code.NODE_WARN, 2: Code.NODE_ERROR, 3: Code.NODE_STALE}
#: Nodes whose health the HMI reads from a topic of their own, with more detail than their
#: /diagnostics: their diagnostics raise no second alarm for the same cause.
STATE_SOURCES = {"rm65_driver": "/arm/state", "cell_sequencer": "/cell/status"}


@dataclass
class Alarm:
    code: str
    source: str
    text: str
    raised: float                 # s since the epoch
    acked: float | None = None
    cleared: float | None = None

    @property
    def key(self) -> str:
        return f"{self.code}@{self.source}"

    @property
    def severity(self) -> Severity:
        return ALARMS[self.code].severity

    def to_dict(self) -> dict:
        d = ALARMS[self.code]
        return {"key": self.key, "code": self.code, "severity": d.severity.text, "title": d.title,
                "source": self.source, "text": self.text, "raised": self.raised, "acked": self.acked is not None,
                "acked_at": self.acked, "cleared": self.cleared}


class AlarmList:
    """Alarms with a code and a severity: raised while their cause is there, acknowledged by the
    operator, cleared (moved to the history) when the cause is gone -- acknowledged or not.

    Each input (a *scope*: the arm, the cell, one node's diagnostics, ...) reports the complete set
    of alarms it causes now; what it reported before and not now has cleared. A cause that stays
    is one alarm however often it is reported (no repeat counts), and its acknowledgement stays.
    """

    def __init__(self, history: int = 50) -> None:
        self.history_size = history
        self._active: dict[str, Alarm] = {}
        self._history: list[Alarm] = []
        self._scopes: dict[str, set[str]] = {}
        self.changed = False

    def update(self, scope: str, causes: dict[tuple[str, str], str], now: float) -> None:
        """``causes``: (code, source) -> text, everything ``scope`` raises now."""
        keys = set()
        for (code, source), text in causes.items():
            alarm = Alarm(code, source, text, now)
            keys.add(alarm.key)
            old = self._active.get(alarm.key)
            if old is None:
                self._active[alarm.key] = alarm
                self.changed = True
            elif old.text != text:
                old.text = text
                self.changed = True
        for key in self._scopes.get(scope, set()) - keys:
            self._clear(key, now)
        self._scopes[scope] = keys

    def _clear(self, key: str, now: float) -> None:
        alarm = self._active.pop(key, None)
        if alarm is None:
            return
        alarm.cleared = now
        self._history.insert(0, alarm)
        del self._history[self.history_size:]
        self.changed = True

    def acknowledge(self, key: str, now: float) -> int:
        """Acknowledge one active alarm by its ``key`` ("A100@rm65_driver"), or all with "all";
        returns how many were acknowledged."""
        n = 0
        for alarm in self._active.values():
            if (key == "all" or alarm.key == key) and alarm.acked is None:
                alarm.acked = now
                n += 1
        self.changed = self.changed or n > 0
        return n

    def active(self) -> list[Alarm]:
        """Most severe first, then newest first."""
        return sorted(self._active.values(), key=lambda a: (-a.severity, -a.raised))

    def message(self) -> dict:
        """The ``alarms`` WebSocket message (docs/HMI.md)."""
        active = self.active()
        return {"type": "alarms", "active": [a.to_dict() for a in active],
                "history": [a.to_dict() for a in self._history],
                "unacked": sum(a.acked is None for a in active),
                "highest": active[0].severity.text if active else ""}


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


@dataclass(frozen=True)
class Timeouts:
    """When an input counts as lost [s] (the driver publishes /arm/state at 10 Hz, the sequencer
    /cell/status every 1 s, every node /diagnostics every 1 s)."""

    arm_s: float = 2.0
    cell_s: float = 5.0
    diagnostics_s: float = 10.0


class JobClock:
    """Time of the running job without its pauses, and the cycle per stud from the welds' times."""

    def __init__(self) -> None:
        self.started: float | None = None
        self.ended: float | None = None
        self._paused_since: float | None = None
        self._paused_s = 0.0
        self._welds: list[float] = []  # active job time of each weld reported [s]

    def cell_state(self, state: int, now: float) -> None:
        under_way = state in RUNNING_STATES or state == CellState.PAUSED
        if under_way and (self.started is None or self.ended is not None):
            self.started, self.ended, self._paused_since, self._paused_s, self._welds = now, None, None, 0.0, []
        if self.started is None or self.ended is not None:
            return
        if state == CellState.PAUSED and self._paused_since is None:
            self._paused_since = now
        elif state != CellState.PAUSED and self._paused_since is not None:
            self._paused_s += now - self._paused_since
            self._paused_since = None
        if state in ENDED_STATES:
            self.ended = now

    @property
    def running(self) -> bool:
        return self.started is not None and self.ended is None

    def active_s(self, now: float) -> float | None:
        """Job time so far (or of the ended job) without pauses [s]; None before the first job."""
        if self.started is None:
            return None
        end = self.ended if self.ended is not None else now
        paused = self._paused_s + (end - self._paused_since if self._paused_since is not None else 0.0)
        return max(0.0, end - self.started - paused)

    def welded(self, now: float) -> None:
        if self.running:
            self._welds.append(self.active_s(now) or 0.0)

    @property
    def cycle_s(self) -> float | None:
        """Mean time per stud between the job's first and last weld (moves and shots between
        stations included, pauses not); None before the second weld."""
        w = self._welds
        return (w[-1] - w[0]) / (len(w) - 1) if len(w) >= 2 else None

    @property
    def last_cycle_s(self) -> float | None:
        w = self._welds
        return w[-1] - w[-2] if len(w) >= 2 else None


def _same_hand_eye(a: dict, b: dict, tol_m: float = 1e-4, tol_deg: float = 0.01) -> bool:
    try:
        return (all(abs(x - y) <= tol_m for x, y in zip(a["xyz_m"], b["xyz_m"], strict=True))
                and all(abs(x - y) <= tol_deg for x, y in zip(a["rpy_deg"], b["rpy_deg"], strict=True)))
    except (KeyError, TypeError, ValueError):
        return False


#: Page commands and what each does (the node maps them to services).
COMMANDS = ("start", "pause", "resume", "stop", "estop", "ack", "resolve_stud", "record_rework")
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
        self._hand_eye: dict[str, dict] = {}  # publishing node -> summary
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

    def on_cell(self, cell: CellInfo, now: float) -> None:
        self.cell, self._cell_at = cell, now
        self.clock.cell_state(cell.state, now)
        causes: dict[tuple[str, str], str] = {}
        src = "cell_sequencer"
        if cell.state == CellState.FAILED and not cell.message.startswith(OPERATOR_STOP_TEXT):
            causes[Code.CELL_FAILED, src] = cell.message or "the job ended in failure"
        if cell.unreachable:
            causes[Code.UNREACHABLE, src] = (f"{len(cell.unreachable)} stud(s) no station can reach: "
                                             f"{', '.join(cell.unreachable[:10])}"
                                             f"{' …' if len(cell.unreachable) > 10 else ''}")
        self.alarms.update("cell", causes, now)
        self.alarms.update("cell_link", {}, now)
        self.changed = True

    def on_registration(self, valid: bool, residual_mm: float, message: str, now: float) -> None:
        self.registration = {"valid": valid, "residual_mm": residual_mm, "message": message}
        causes = {} if valid else {(Code.REGISTRATION, "registration"): message or "not valid"}
        self.alarms.update("registration", causes, now)
        self.changed = True

    def on_hand_eye(self, node: str, summary: dict, now: float) -> None:
        """``/calibration/hand_eye`` of one node (HandEyeInUse.summary(), JSON)."""
        self._hand_eye[node] = summary
        first = next(iter(self._hand_eye.values()))
        differ = [n for n, s in self._hand_eye.items() if not _same_hand_eye(first, s)]
        causes = {}
        if differ:
            causes[Code.HAND_EYE, "calibration"] = "; ".join(
                f"{n}: {_hand_eye_text(s)}" for n, s in sorted(self._hand_eye.items()))
        self.alarms.update("calibration", causes, now)
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
        code = _DIAG_CODE.get(level)
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
            out = {"kind": "estop", "title": "E-STOP LATCHED",
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
        return {"uncertain": uncertain, "uncertain_enabled": not why, "uncertain_why": why,
                "rework": self.table.awaiting_rework()}

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
        if cmd == "record_rework":
            if not isinstance(msg.get("stud_id"), str) or not msg.get("stud_id"):
                return "no stud_id given"
            if not isinstance(msg.get("note", ""), str):
                return "note must be a string"
            return None  # the inspector checks the decision and the verdict (one place: stud_planner.cell.rework)
        return f"unknown command {cmd!r}; expected one of {list(COMMANDS)}"

    def progress(self, now: float) -> dict:
        """Studs, not stations: welded / total from the studs' weld states (the cell's own count
        when it is higher: it also knows studs welded before the HMI started)."""
        counts = self.table.weld_counts()
        total = len(self.table.stud_ids) or (self.cell.studs_total if self.cell else 0)
        welded = max(counts[WELD_WELDED], self.cell.studs_welded if self.cell else 0)
        unreachable = set(self.cell.unreachable) if self.cell else set()
        weld_of = {sid: self.table.weld_state(sid) for sid in self.table.stud_ids}
        unreachable_open = sum(1 for s in unreachable if weld_of.get(s, WELD_NONE) not in _FINAL)
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
        if not self._hand_eye:
            return None
        first = next(iter(self._hand_eye.values()))
        return {**first, "text": _hand_eye_text(first), "nodes": sorted(self._hand_eye),
                "agree": all(_same_hand_eye(first, s) for s in self._hand_eye.values())}

    def status_message(self, now: float) -> dict:
        """The ``status`` WebSocket message (docs/HMI.md)."""
        cell = self.cell
        return {"type": "status", "now": now, "safety": self.safety(now), "controls": self.controls(now),
                "progress": self.progress(now), "decisions": self.decisions(now),
                "part": self.part, "calibration": self.calibration(), "registration": self.registration,
                "cell": None if cell is None else {"state": _text(self.cell_state), "state_code": int(cell.state),
                                                   "message": cell.message},
                "arm": None if self.arm is None else {"mode": _text(self.arm_mode), "stale_s": self.arm_stale_s(now)}}


def _hand_eye_text(s: dict) -> str:
    """One line: where the hand-eye comes from and its values."""
    xyz = ", ".join(f"{v * 1000:.1f}" for v in s.get("xyz_m") or [])
    rpy = ", ".join(f"{v:.2f}" for v in s.get("rpy_deg") or [])
    if s.get("source") == "file":
        rms = s.get("position_rms_mm")
        extra = f", residual {rms:.2f} mm" if isinstance(rms, (int, float)) and math.isfinite(rms) else ""
        return f"file {os.path.basename(s.get('path') or '')} ({s.get('date') or 'undated'}{extra}): xyz [{xyz}] mm, rpy [{rpy}]°"
    return f"typed values: xyz [{xyz}] mm, rpy [{rpy}]°"
