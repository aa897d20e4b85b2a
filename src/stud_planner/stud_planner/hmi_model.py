"""What the HMI shows, ROS-free: the per-stud table and the "last errors" list.

The node (hmi_node) converts messages to the plain values taken here; this module decides
what a row says, and builds the JSON-ready dicts the page renders (see docs/HMI.md).

Per-stud state: a stud's *target* (status, pose, errors) comes from ``/weld_targets``, one
view at a time; its *weld state* comes from the arm: the WeldJob feedback (phase per stud),
``/arm/state`` (the stud being processed) and the WeldJob results (welded / skipped / failed
lists, the truth). The two are kept apart, so a new view never clears a weld.
"""
from __future__ import annotations

import time
from collections import OrderedDict
from dataclasses import dataclass
from typing import Iterable

#: Weld states of a stud, as sent in the rows' ``weld`` field.
WELD_NONE, WELD_ACTIVE, WELD_WELDED, WELD_SKIPPED, WELD_FAILED = "", "active", "welded", "skipped", "failed"
_FINAL = (WELD_WELDED, WELD_SKIPPED, WELD_FAILED)
#: WeldJob feedback phases while a stud is being worked on (rm65_driver.weld_sequence).
_ACTIVE_PHASES = ("approach", "descend", "weld", "dwell")
#: The driver reports "retract" only after the weld is confirmed and journalled as welded.
_WELDED_PHASE = "retract"
STATUS_OUT_OF_VIEW = "out_of_view"
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

    def weld_feedback(self, stud_id: str, phase: str) -> None:
        """WeldJob feedback: ``phase`` of ``stud_id`` (approach, descend, weld, dwell, retract, skip)."""
        self._known(stud_id)
        self._phase[stud_id] = phase
        if phase == _WELDED_PHASE:
            self._weld[stud_id] = WELD_WELDED
        if phase in _ACTIVE_PHASES:
            self._active = stud_id
        elif self._active == stud_id:
            self._active = ""

    def arm_progress(self, current_stud: str) -> bool:
        """``/arm/state``: the stud being processed now ("" between studs and jobs). True if that changed."""
        if current_stud == self._active:
            return False
        self._known(current_stud)
        self._active = current_stud
        return True

    def job_result(self, welded: Iterable[str], skipped: Iterable[str], failed: Iterable[str]) -> None:
        """A finished WeldJob: its lists are the truth for the studs they name."""
        for ids, state in ((skipped, WELD_SKIPPED), (failed, WELD_FAILED), (welded, WELD_WELDED)):
            for sid in ids:
                self._known(sid)
                self._weld[sid] = state
        self._active = ""

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
                   "weld": weld, "phase": self._phase.get(sid, ""), "welded": weld == WELD_WELDED}
            out.append(row)
        return out

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


@dataclass
class ErrorEntry:
    name: str
    level: str
    message: str
    first: float   # s since the epoch
    last: float
    count: int = 1
    active: bool = True


LEVEL_TEXT = {0: "ok", 1: "warn", 2: "error", 3: "stale"}


class ErrorLog:
    """The last WARN/ERROR/STALE diagnostics, newest first, one entry per (source, message).

    /diagnostics repeats a status every second: a repeat counts, it does not add a line. An entry
    is ``active`` while its source still reports it; an OK status (or another message) from the
    same source makes it inactive (kept as history).
    """

    def __init__(self, max_items: int = 50) -> None:
        self.max_items = max_items
        self._items: OrderedDict[tuple[str, str], ErrorEntry] = OrderedDict()
        self.changed = False

    def update(self, name: str, level: int, message: str, now: float | None = None) -> None:
        now = time.time() if now is None else now
        for (n, m), e in self._items.items():
            if n == name and m != message and e.active:
                e.active = False
                self.changed = True
        if level == 0:
            return
        key = (name, message)
        entry = self._items.pop(key, None)
        if entry is None:
            entry = ErrorEntry(name, LEVEL_TEXT.get(level, str(level)), message, now, now)
        else:
            entry.count += 1
            entry.last = now
            entry.level = LEVEL_TEXT.get(level, str(level))
            entry.active = True
        self._items[key] = entry
        self.changed = True
        while len(self._items) > self.max_items:
            self._items.popitem(last=False)

    def message(self) -> dict:
        """The ``errors`` WebSocket message (docs/HMI.md), newest first."""
        items = [{"name": e.name, "level": e.level, "message": e.message, "count": e.count,
                  "first": e.first, "last": e.last, "active": e.active} for e in reversed(self._items.values())]
        return {"type": "errors", "items": items}
