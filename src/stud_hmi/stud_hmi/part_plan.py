"""The plan of the whole part as the operator's page draws it, ROS-free: every stud of the drawing
at its place, coloured by one state, the rail with the carriage and the arm's reach around it, the
station being worked (its camera footprint and the studs in it), and the studs the cell cannot
weld with the reason (docs/HMI.md, "The plan of the part").

Places. Before a valid registration the plan is in *drawing* coordinates (``frame`` "drawing":
the part's place along the rail is not known yet). Once ``/registration/result`` is valid it is in
*world* (the rail's frame on a rail: x along it): a stud's XY is the drawing's through
M_local2world (Eq. 2), or, once a view matched it, the matched world position (measured, so it
also holds where one registration does not reach along a long part).

States (:class:`PlanState`): one per stud, derived in :func:`plan_state` from the stud table's row
(its target status, weld state, inspection verdict and rework decision: the table's vocabulary,
:mod:`stud_hmi.stud_table`, :class:`~stud_common.vocabulary.TargetStatus`,
:class:`~stud_inspection.inspection.Verdict`), the cell's plan (planned, unreachable) and the weld
journal's uncertain studs. The page colours a stud by the CSS class ``ps-<state>``.

The view: :func:`fit_view` is how the page fits the part into its drawing area on load (the
page's plan.js does the same sum; the browser test holds the two together).
"""
from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Iterable, Sequence

import numpy as np

from stud_common.vocabulary import TargetStatus
from stud_hmi.job_clock import ENDED_STATES
from stud_hmi.stud_table import STATUS_NOT_SEEN, WELD_ACTIVE, WELD_FAILED, WELD_SKIPPED, WELD_WELDED
from stud_inspection.inspection import Verdict
from stud_perception.registration import local_to_world

#: The smallest radius the page draws a stud with [px] (a stud smaller on screen is drawn this big),
#: sent to the page with the plan.
MIN_MARKER_PX = 3.0
#: The arm's working radius about its base [m] (the RM-65's 610 mm), the default of the node's ``arm_reach_m``.
RM65_REACH_M = 0.61


class PlanState(str, enum.Enum):
    """A stud's state on the plan, in the order the legend lists them; the value is the CSS class
    suffix and the word the page shows (underscores as spaces)."""

    NOT_SEEN = "not_seen"          # in the drawing; no job has planned it, no view has seen it
    PLANNED = "planned"            # the job's stations cover it; no view has matched it yet
    OK = "ok"                      # matched, a usable weld target
    UNCERTAIN = "uncertain"        # matched without a usable target, or the journal's started-never-confirmed
    UNREACHABLE = "unreachable"    # the cell cannot weld it (the reason beside the plan)
    WELDING = "welding"            # the arm is on it now
    WELDED = "welded"              # welded (the journal), not inspected yet
    FAILED = "failed"              # the weld failed, or the driver's checks skipped it
    QA_PASS = "qa_pass"            # inspected and passed (or accepted by the operator)
    QA_FAIL = "qa_fail"            # inspected and failed or missing (rework)

    @property
    def label(self) -> str:
        return {PlanState.QA_PASS: "QA pass", PlanState.QA_FAIL: "QA fail"}.get(self, self.value.replace("_", " "))


_QA_FAIL_VERDICTS = frozenset({Verdict.FAIL.value, Verdict.MISSING.value})
_NOT_SEEN_STATUSES = frozenset({STATUS_NOT_SEEN, TargetStatus.OUT_OF_VIEW.text})
_UNREACHABLE_STATUS = TargetStatus.UNREACHABLE.text
#: A stud the cell names unreachable without saying why (a sequencer older than ``unreachable_reasons``).
NO_REASON = "unreachable (the cell gave no reason)"


def plan_state(row: dict, planned: bool = False, unreachable: bool = False, journal_uncertain: bool = False
               ) -> PlanState:
    """One stud's state from its stud-table row (:meth:`StudTable.rows`), whether the cell's job
    planned it (stations cover it), names it unreachable, or the weld journal holds it uncertain.

    What is known last about the stud wins: an inspection verdict over the weld, a weld over the
    plan, the plan over the match of a view."""
    verdict, rework = row.get("inspection", ""), row.get("rework", "")
    if verdict == Verdict.PASS.value or (verdict in _QA_FAIL_VERDICTS and rework == "accept"):
        return PlanState.QA_PASS
    if verdict in _QA_FAIL_VERDICTS:
        return PlanState.QA_FAIL
    if journal_uncertain:
        return PlanState.UNCERTAIN
    weld = row.get("weld", "")
    if weld == WELD_ACTIVE:
        return PlanState.WELDING
    if weld == WELD_WELDED:
        return PlanState.WELDED
    if weld in (WELD_FAILED, WELD_SKIPPED):
        return PlanState.FAILED
    status = row.get("status", STATUS_NOT_SEEN)
    if unreachable or status == _UNREACHABLE_STATUS:
        return PlanState.UNREACHABLE
    if status == TargetStatus.OK.text:
        return PlanState.OK
    if status in _NOT_SEEN_STATUSES:
        return PlanState.PLANNED if planned else PlanState.NOT_SEEN
    return PlanState.UNCERTAIN  # no_depth, normal_uncertain, not_converged, ...: no usable target from its view


@dataclass(frozen=True)
class RailConfig:
    """The rail as the arm driver has it (the node's parameters of the same names) and the arm's reach."""

    length_m: float = 0.0                                      # 0: no rail given (travel seen still shows one)
    mount_xyz_m: tuple[float, float, float] = (0.0, 0.0, 0.0)  # carriage -> the arm's base [m]
    reach_m: float = RM65_REACH_M                              # the arm's working radius about its base [m]


@dataclass(frozen=True)
class StationInfo:
    """``/cell/status``, the fields the plan uses (camera ones empty when the sequencer does not say)."""

    state: int                                      # CellState
    station: int = 0
    stations_total: int = 0
    unreachable: tuple[str, ...] = ()
    unreachable_reasons: tuple[str, ...] = ()       # parallel to unreachable (may be empty)
    camera_xyz_m: tuple[float, ...] = ()            # world [m]
    camera_yaw_rad: float = 0.0
    camera_footprint_m: tuple[float, ...] = ()      # (width along image x, height along image y) [m]


def footprint_corners(camera_xy_m: Sequence[float], yaw_rad: float, footprint_m: Sequence[float]) -> np.ndarray:
    """The four corners (4, 2) of a nadir camera's footprint centred under it, its image x along yaw."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    hw, hh = footprint_m[0] / 2.0, footprint_m[1] / 2.0
    local = np.array([[-hw, -hh], [hw, -hh], [hw, hh], [-hw, hh]])
    return local @ np.array([[c, s], [-s, c]]) + np.asarray(camera_xy_m[:2], dtype=np.float64)


def in_footprint(xy_m: np.ndarray, camera_xy_m: Sequence[float], yaw_rad: float, footprint_m: Sequence[float]
                 ) -> np.ndarray:
    """Which points (N, 2) lie in the footprint (bool (N,))."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    d = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2) - np.asarray(camera_xy_m[:2], dtype=np.float64)
    u, v = d @ np.array([c, s]), d @ np.array([-s, c])
    return (np.abs(u) <= footprint_m[0] / 2.0) & (np.abs(v) <= footprint_m[1] / 2.0)


def bounds(xy_m: np.ndarray) -> tuple[float, float, float, float] | None:
    """(x_min, y_min, x_max, y_max) of the finite points (N, 2); None without any."""
    xy = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
    xy = xy[np.all(np.isfinite(xy), axis=1)]
    if not len(xy):
        return None
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])


def fit_view(box: Sequence[float], width_px: float, height_px: float, margin_px: float = 24.0,
             min_extent_m: float = 0.05) -> tuple[tuple[float, float], float]:
    """The view that fits ``box`` (x_min, y_min, x_max, y_max) [m] into a drawing area of
    ``width_px`` x ``height_px`` with ``margin_px`` free on each side: (its centre [m], pixels per
    metre). A box narrower than ``min_extent_m`` counts as that wide (one stud is not a point)."""
    w = max(box[2] - box[0], min_extent_m)
    h = max(box[3] - box[1], min_extent_m)
    scale = min(max(width_px - 2 * margin_px, 1.0) / w, max(height_px - 2 * margin_px, 1.0) / h)
    return ((box[0] + box[2]) / 2.0, (box[1] + box[3]) / 2.0), scale


def _r(v: float) -> float:
    return round(float(v), 5)  # 10 µm: the page draws, it does not measure


class PartPlan:
    """The plan's inputs (layout, registration, /cell/status, the carriage) and the ``plan`` message."""

    def __init__(self, rail: RailConfig = RailConfig()) -> None:
        self.rail = rail
        self.ids: list[str] = []
        self._drawing_xy = np.zeros((0, 2))
        self._diameter_m = np.zeros(0)
        self._marks: list[tuple[str, tuple[float, float]]] = []
        self._mark_diameter_m = 0.0
        self._m_local2world: np.ndarray | None = None
        self.registration_message = ""
        self.cell: StationInfo | None = None
        self.uncertain: tuple[str, ...] = ()
        self.carriage_m: float | None = None
        self.carriage_moving = False
        self._travel_seen: tuple[float, float] | None = None  # (min, max) carriage position seen off zero
        self.layout_revision = 0
        self._has_layout = False
        self.changed = True

    # -- inputs ----------------------------------------------------------------------------------------
    def set_layout(self, ids: Iterable[str], xy_m, diameters_m=None,
                   marks: Iterable[tuple[str, tuple[float, float]]] = (), mark_diameter_m: float = 0.0) -> None:
        """``/drawing/layout``: stud ids, their drawing XY (N, 2) [m] and diameters [m], the marks
        (label, drawing XY). A second, different drawing forgets the registration (it was of
        another part), as the stud table forgets its rows."""
        ids = list(ids)
        xy = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
        if len(xy) != len(ids):
            raise ValueError(f"layout: {len(ids)} stud ids but {len(xy)} positions")
        d = np.zeros(len(ids)) if diameters_m is None else np.asarray(diameters_m, dtype=np.float64).reshape(-1)
        if self._has_layout and (ids != self.ids or not np.array_equal(xy, self._drawing_xy)):
            self._m_local2world, self.registration_message = None, ""
        self.ids, self._drawing_xy, self._diameter_m = ids, xy, d
        self._marks = [(str(label), (float(p[0]), float(p[1]))) for label, p in marks]
        self._mark_diameter_m = float(mark_diameter_m)
        self._has_layout = True
        self.layout_revision += 1
        self.changed = True

    def set_registration(self, valid: bool, m_local2world, message: str = "") -> None:
        """``/registration/result``: a valid one places the part in world (the newest valid one
        counts; an invalid one leaves the last valid place)."""
        if not valid:
            return
        M = np.asarray(m_local2world, dtype=np.float64).reshape(3, 3)
        if not np.all(np.isfinite(M)):
            return
        if self._m_local2world is None or not np.array_equal(M, self._m_local2world):
            self._m_local2world, self.registration_message = M, message
            self.changed = True

    def on_cell(self, info: StationInfo) -> None:
        if info != self.cell:
            self.cell = info
            self.changed = True

    def on_arm(self, rail_position_m: float, rail_moving: bool, uncertain: Iterable[str] = ()) -> None:
        """``/arm/state``: the carriage (drawn from :meth:`carriage`, sent with every arm message)
        and the journal's uncertain studs."""
        uncertain = tuple(uncertain)
        if uncertain != self.uncertain:
            self.uncertain = uncertain
            self.changed = True
        pos = float(rail_position_m)
        if not math.isfinite(pos):
            return
        self.carriage_m, self.carriage_moving = pos, bool(rail_moving)
        if pos != 0.0 or rail_moving:
            lo, hi = self._travel_seen or (pos, pos)
            seen = (min(lo, pos), max(hi, pos))
            if self._travel_seen is None:
                self.changed = True  # a rail appears (the plan re-sent; the carriage goes with /arm/state)
            self._travel_seen = seen

    # -- what the page draws ---------------------------------------------------------------------------
    @property
    def registered(self) -> bool:
        return self._m_local2world is not None

    @property
    def has_rail(self) -> bool:
        """A rail is drawn when the parameters give one or the carriage has been seen off zero."""
        return self.rail.length_m > 0 or self._travel_seen is not None

    def positions(self, rows: Iterable[dict] = ()) -> np.ndarray:
        """The studs' XY (N, 2) in the plan's frame, in layout order (module docstring)."""
        if self._m_local2world is None:
            return self._drawing_xy.copy()
        xy = local_to_world(self._m_local2world, self._drawing_xy).reshape(-1, 2)
        index = {sid: i for i, sid in enumerate(self.ids)}
        for row in rows:
            i, p = index.get(row["stud_id"]), row.get("position_mm")
            if i is not None and p is not None and p[0] is not None and p[1] is not None \
                    and math.isfinite(p[0]) and math.isfinite(p[1]):
                xy[i] = (p[0] / 1000.0, p[1] / 1000.0)
        return xy

    def marks_xy(self) -> np.ndarray:
        xy = np.array([p for _label, p in self._marks], dtype=np.float64).reshape(-1, 2)
        return xy if self._m_local2world is None else local_to_world(self._m_local2world, xy).reshape(-1, 2)

    def part_bounds(self, rows: Iterable[dict] = ()) -> tuple[float, float, float, float] | None:
        """The part's box (studs and marks) in the plan's frame: what "fit" shows."""
        return bounds(np.vstack([self.positions(rows), self.marks_xy()]))

    def _station(self, xy: np.ndarray) -> dict | None:
        cell = self.cell
        if cell is None or cell.state in ENDED_STATES or len(cell.camera_xyz_m) != 3 or not self.registered:
            return None  # (the camera is in world: not drawn over a plan in drawing coordinates)
        cam = [float(v) for v in cell.camera_xyz_m]
        out: dict = {"index": cell.station, "total": cell.stations_total, "camera_xyz_m": [_r(v) for v in cam],
                     "yaw_rad": cell.camera_yaw_rad, "footprint_m": None, "corners_m": None, "stud_ids": []}
        fp = cell.camera_footprint_m
        if len(fp) == 2 and all(math.isfinite(v) and v > 0 for v in fp):
            out["footprint_m"] = [_r(v) for v in fp]
            out["corners_m"] = [[_r(a), _r(b)] for a, b in footprint_corners(cam, cell.camera_yaw_rad, fp)]
            if len(xy):
                inside = in_footprint(xy, cam, cell.camera_yaw_rad, fp)
                out["stud_ids"] = [sid for sid, k in zip(self.ids, inside) if k]
        return out

    def _rail(self, part: tuple[float, float, float, float] | None) -> dict | None:
        if not self.has_rail:
            return None
        if self.rail.length_m > 0:
            extent = [0.0, self.rail.length_m]
        else:  # travel seen, length not given: from zero to the farthest of what is known
            lo, hi = self._travel_seen or (0.0, 0.0)
            far = part[2] if (part is not None and self.registered) else hi
            extent = [min(0.0, lo), max(hi, far, 0.0)]
        return {"length_m": self.rail.length_m or None, "extent_m": [_r(v) for v in extent],
                "mount_xyz_m": list(self.rail.mount_xyz_m), "reach_m": self.rail.reach_m}

    def carriage(self) -> dict | None:
        """Where the carriage is (None: no rail, or no /arm/state yet): the arm's base in world and its reach."""
        if not self.has_rail or self.carriage_m is None:
            return None
        mx, my, _mz = self.rail.mount_xyz_m
        return {"position_m": self.carriage_m, "moving": self.carriage_moving,
                "base_xy_m": [_r(self.carriage_m + mx), _r(my)], "reach_m": self.rail.reach_m}

    def _reasons(self) -> dict[str, str]:
        cell = self.cell
        if cell is None:
            return {}
        reasons = list(cell.unreachable_reasons) if len(cell.unreachable_reasons) == len(cell.unreachable) else []
        return {sid: (reasons[i] if reasons and reasons[i] else NO_REASON) for i, sid in enumerate(cell.unreachable)}

    def message(self, rows: Sequence[dict] = ()) -> dict:
        """The ``plan`` WebSocket message (docs/HMI.md) from the stud table's rows."""
        by_id = {r["stud_id"]: r for r in rows}
        reasons = self._reasons()
        planned = self.cell is not None and self.cell.stations_total > 0
        uncertain = set(self.uncertain)
        xy = self.positions(rows)
        frame = "world" if self.registered else "drawing"
        studs, counts, unreachable = [], {s: 0 for s in PlanState}, []
        for i, sid in enumerate(self.ids):
            row = by_id.get(sid, {"stud_id": sid})
            state = plan_state(row, planned, sid in reasons, sid in uncertain)
            counts[state] += 1
            reason = ""
            if state == PlanState.UNREACHABLE:
                reason = reasons.get(sid) or (f"unreachable: its target (view {row.get('view')}) is out of the "
                                              "arm's reach")
                unreachable.append({"stud_id": sid, "reason": reason})
            studs.append({"stud_id": sid, "xy_m": [_r(xy[i, 0]), _r(xy[i, 1])], "d_m": _r(self._diameter_m[i]),
                          "state": state.value, "detail": _detail(row, state, reason, xy[i], frame,
                                                                  sid in uncertain)})
        part = bounds(np.vstack([xy, self.marks_xy()]))
        return {"type": "plan", "frame": frame, "registered": self.registered,
                "registration": self.registration_message, "layout_revision": self.layout_revision,
                "marker_min_px": MIN_MARKER_PX, "studs": studs,
                "bounds_m": None if part is None else [_r(v) for v in part],
                "marks": [{"label": label, "xy_m": [_r(p[0]), _r(p[1])], "d_m": _r(self._mark_diameter_m)}
                          for (label, _d), p in zip(self._marks, self.marks_xy())],
                "states": [{"state": s.value, "label": s.label, "count": counts[s]} for s in PlanState],
                "station": self._station(xy), "rail": self._rail(part), "carriage": self.carriage(),
                "unreachable": unreachable}


def _detail(row: dict, state: PlanState, reason: str, xy: np.ndarray, frame: str, journal_uncertain: bool) -> str:
    """What the page says of one stud when it is pointed at: its state, then why, then the facts."""
    parts = [state.label]
    if reason:
        parts.append(reason)
    if journal_uncertain:
        parts.append("the gun started on it but the weld was never confirmed: decide on the page")
    status = row.get("status", STATUS_NOT_SEEN)
    if status != STATUS_NOT_SEEN:
        parts.append(f"target {status.replace('_', ' ')}" + (f" (view {row['view']})" if row.get("view") is not None
                                                            else ""))
    if row.get("weld"):
        parts.append(f"weld {row['weld']}" + (f" ({row['phase']})" if row["weld"] == WELD_ACTIVE and row.get("phase")
                                             else ""))
    if row.get("inspection"):
        why = row.get("inspection_reasons") or []
        parts.append(f"inspection {row['inspection'].replace('_', ' ')}" + (f": {', '.join(why)}" if why else "")
                     + (f" → {row['rework']}" if row.get("rework") else ""))
    parts.append(f"x {xy[0] * 1e3:.1f}, y {xy[1] * 1e3:.1f} mm ({frame})")
    return " · ".join(parts)


__all__ = ["MIN_MARKER_PX", "NO_REASON", "RM65_REACH_M", "PartPlan", "PlanState", "RailConfig", "StationInfo", "bounds",
           "fit_view", "footprint_corners", "in_footprint", "plan_state"]
