"""The operator's stud table, ROS-free: one row per stud with its target (from ``/weld_targets``, one
view at a time), its weld state (WeldJob feedback, ``/arm/state``, the WeldJob results), its
inspection verdict and the operator's rework decision. The two first are kept apart, so a new view
never clears a weld (docs/HMI.md, the ``targets`` message)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

from stud_common.vocabulary import TargetStatus, WeldPhase
from stud_inspection.rework import NEEDS_DECISION

#: Weld states of a stud, as sent in the rows' ``weld`` field.
WELD_NONE, WELD_ACTIVE, WELD_WELDED, WELD_SKIPPED, WELD_FAILED = "", "active", "welded", "skipped", "failed"
#: A stud in one of these weld states is done with (no longer "remaining").
FINAL_WELD_STATES = (WELD_WELDED, WELD_SKIPPED, WELD_FAILED)
#: WeldJob feedback phases while a stud is being worked on (rm65_driver.weld.weld_sequence).
_ACTIVE_PHASES = (WeldPhase.APPROACH, WeldPhase.DESCEND, WeldPhase.WELD, WeldPhase.DWELL)
#: The driver reports "retract" only after the weld is confirmed and journalled as welded.
_WELDED_PHASE = WeldPhase.RETRACT
STATUS_OUT_OF_VIEW = TargetStatus.OUT_OF_VIEW.text
STATUS_NOT_SEEN = "not_seen"  # in the drawing, in no view yet
STATUS_UNREACHABLE = "unreachable"  # the cell named it as one it cannot weld (/cell/status, with the reason)


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
        self._unreachable: dict[str, str] = {}  # stud -> why the cell cannot weld it (/cell/status)
        self._bend: dict[str, str] = {}    # stud -> its bend test: "to do", "pass" or "fail"
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
            self._bend.clear()
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

    def set_unreachable(self, reasons: dict[str, str]) -> bool:
        """The studs the cell names as ones it cannot weld, with the reason (``/cell/status``); True if that changed."""
        if reasons == self._unreachable:
            return False
        for sid in reasons:
            self._known(sid)
        self._unreachable = dict(reasons)
        return True

    def bend_results(self, results: dict[str, str]) -> None:
        """The QA record's bend-test list: stud -> "to do", "pass" or "fail" (the whole list, newest)."""
        for sid in results:
            self._known(sid)
        self._bend = dict(results)

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
        if state not in FINAL_WELD_STATES and stud_id == self._active:
            return WELD_ACTIVE
        return state

    def rows(self) -> list[dict]:
        out = []
        for sid in self._order:
            t = self._targets.get(sid)
            weld = self.weld_state(sid)
            named = sid in self._unreachable and weld != WELD_WELDED
            row = {"stud_id": sid, "status": STATUS_UNREACHABLE if named else t.status if t else STATUS_NOT_SEEN,
                   "status_code": t.status_code if t else None,
                   "inclination_deg": t.inclination_deg if t else None,
                   "position_mm": [v * 1000.0 for v in t.position_m] if t else None,
                   "xy_error_mm": t.xy_error_m * 1000.0 if t else None,
                   "view": t.view if t else None,
                   "weld": weld, "phase": self._phase.get(sid, ""), "welded": weld == WELD_WELDED,
                   "inspection": self._inspection.get(sid, ("", ()))[0],
                   "inspection_reasons": list(self._inspection.get(sid, ("", ()))[1]),
                    "rework": self._rework.get(sid, ""), "bend": self._bend.get(sid, ""),
                    "reason": self._unreachable.get(sid, "") if named else ""}
            out.append(row)
        return out

    def weld_counts(self) -> dict[str, int]:
        """How many studs are welded, failed, skipped, being welded, or not yet (``""``)."""
        counts = {state: 0 for state in (WELD_NONE, WELD_ACTIVE, *FINAL_WELD_STATES)}
        for sid in self._order:
            counts[self.weld_state(sid)] += 1
        return counts

    def counts(self) -> dict[str, int]:
        counts: dict[str, int] = {}
        for sid in self._order:
            t = self._targets.get(sid)
            key = t.status if t else STATUS_NOT_SEEN
            if sid in self._unreachable and self.weld_state(sid) != WELD_WELDED:
                key = STATUS_UNREACHABLE
            counts[key] = counts.get(key, 0) + 1
        return counts

    def message(self) -> dict:
        """The ``targets`` WebSocket message (docs/HMI.md)."""
        rows = self.rows()
        return {"type": "targets", "view": self.view, "algorithm": self.algorithm, "rows": rows,
                "counts": self.counts(), "welded": sum(r["welded"] for r in rows), "total": len(rows)}
