"""The weld-target record: N studs' weld targets as one table of numpy columns, the fields of
``stud_welding_msgs/WeldTarget``, with their weld-report rows and the rule that keeps a stud's best view.

One type owns these fields. A view's targets (``view_targets.ViewTargets``) are a table; the offline
plan's best targets over all views are a table (:meth:`TargetTable.merge`); the cell builds a table
from each WeldTargetArray (``msg_convert.weld_target_table``). The wire form is
:mod:`stud_planner.matching.target_cdr` (its field layout is tested against the ``.msg``); the report
form is :meth:`TargetTable.report_entries` (the offline report's keys, docs/INTERFACES.md). Which
view's target a stud keeps is :func:`choose_best`, for ``plan`` and the cell alike. No ROS import.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields
from functools import cached_property
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from stud_common.vocabulary import TargetStatus

#: Status value -> its text (status_text), as an array to index with a status column.
STATUS_TEXTS = np.array([s.text for s in sorted(TargetStatus)], dtype=object)
assert [int(s) for s in sorted(TargetStatus)] == list(range(len(TargetStatus)))  # values index STATUS_TEXTS


@dataclass(frozen=True, eq=False)
class TargetTable:
    """Weld targets of N studs, in drawing order; NaN where there is no value. Beside each column the
    WeldTarget field it is."""

    ids: list[str]                # stud_id
    drawing_xy_m: np.ndarray      # (N, 2) m, drawing frame: drawing_x, drawing_y
    position_w: np.ndarray        # (N, 3) m, world: pose.position (on the surface, or the tool offset along the normal)
    quat_xyzw: np.ndarray         # (N, 4) z along the normal: pose.orientation (the identity on the wire where NaN)
    normal_w: np.ndarray          # (N, 3) unit outward normal, world: normal
    pixel_uv: np.ndarray          # (N, 2) px, the match in the view's image: pixel_u, pixel_v
    view_index: np.ndarray        # (N,) int64, the view matched on (-1: none): view_index
    iterations: np.ndarray        # (N,) int64, depth look-ups or pixels evaluated: iterations
    xy_error_m: np.ndarray        # (N,) m, |back-projected XY - target XY|: xy_error
    inclination_deg: np.ndarray   # (N,) the surface's slope against world z (information): inclination
    normal_rms_m: np.ndarray      # (N,) m, RMS of the fit that gave the normal: normal_rms
    normal_sigma_deg: np.ndarray  # (N,) the normal's 1-sigma: normal_sigma
    lean_bound_deg: np.ndarray    # (N,) the worst lean from the true normal the target could give: lean_bound
    fill_ratio: np.ndarray        # (N,) valid depth pixels of the normal's window: fill_ratio
    gun_clearance_m: np.ndarray   # (N,) m, the gun's side to the part (< 0: it would touch): gun_clearance
    status: np.ndarray            # (N,) uint8 TargetStatus: status (and status_text)
    reasons: np.ndarray           # (N,) str (object array), why a target is not usable, "" if it is: reason
    centre_offset: np.ndarray     # (N,) the match's distance from the principal point over the image's half
    #                               diagonal (0 centre, 1 corner; NaN: unknown). Not on the wire: the
    #                               tie-break of choose_best

    @classmethod
    def unseen(cls, ids: list[str], drawing_xy_m: np.ndarray) -> "TargetTable":
        """The table before any view: every stud ``out_of_view``, on no view (``view_index`` -1)."""
        n = len(ids)

        def nan(*shape):
            return np.full((n, *shape), np.nan)

        return cls(ids=list(ids), drawing_xy_m=np.asarray(drawing_xy_m, dtype=np.float64).reshape(n, 2),
                   position_w=nan(3), quat_xyzw=nan(4), normal_w=nan(3), pixel_uv=nan(2),
                   view_index=np.full(n, -1, np.int64), iterations=np.zeros(n, np.int64), xy_error_m=nan(),
                   inclination_deg=nan(), normal_rms_m=nan(), normal_sigma_deg=nan(), lean_bound_deg=nan(),
                   fill_ratio=nan(), gun_clearance_m=nan(), status=np.full(n, TargetStatus.OUT_OF_VIEW, np.uint8),
                   reasons=np.full(n, TargetStatus.OUT_OF_VIEW.text, dtype=object), centre_offset=nan())

    def __len__(self) -> int:
        return len(self.ids)

    @property
    def ok(self) -> np.ndarray:
        """(N,) bool: usable targets (weld them)."""
        return self.status == TargetStatus.OK

    @cached_property
    def status_text(self) -> list[str]:
        """(N,) status names, built once (callers read them per stud)."""
        return STATUS_TEXTS[self.status].tolist()

    @property
    def message_quat_xyzw(self) -> np.ndarray:
        """(N, 4) the orientations messages carry: the identity where there is no normal (NaN)."""
        quat = np.array(self.quat_xyzw, dtype=np.float64).reshape(-1, 4)
        quat[~np.all(np.isfinite(quat), axis=1)] = (0.0, 0.0, 0.0, 1.0)
        return quat

    def counts(self) -> dict[str, int]:
        """Number of targets per status text."""
        vals, n = np.unique(self.status, return_counts=True)
        return {STATUS_TEXTS[int(v)]: int(c) for v, c in zip(vals, n)}

    def best_view_key(self) -> "BestViewKey":
        """What :func:`choose_best` compares, per stud."""
        return BestViewKey(self.status, self.lean_bound_deg, self.centre_offset, self.view_index)

    def merge(self, other: "TargetTable") -> "TargetTable":
        """Per stud, the target :func:`choose_best` keeps of this table's and ``other``'s (the same
        studs in the same order; ``other`` is typically one more view)."""
        if other.ids is not self.ids and other.ids != self.ids:
            raise ValueError(f"cannot merge targets of different studs ({len(self.ids)} and {len(other.ids)} ids, "
                             "or another order)")
        take = choose_best(self.best_view_key(), other.best_view_key())
        if not take.any():
            return self
        columns = {}
        for name in COLUMNS:
            column = getattr(self, name).copy()
            column[take] = getattr(other, name)[take]
            columns[name] = column
        return TargetTable(ids=self.ids, **columns)

    def report_entries(self, with_stud: bool = True) -> list[dict]:
        """The weld report's ``targets``: one entry per stud, in table order, with the offline report's
        keys (docs/INTERFACES.md), then the normal's 1-sigma, the lean bound, the window's fill, the gun's
        clearance and, for a stud that is not usable, ``reason``. Values that are not finite are None
        (JSON null). A stud on no view (``view_index`` -1) has its id, drawing position and status only.
        ``with_stud`` False: without ``stud_id`` and ``drawing_xy_mm`` (the cell has them from the layout)."""
        texts = self.status_text
        xy_mm = (np.asarray(self.drawing_xy_m, dtype=np.float64).reshape(-1, 2) * 1e3).tolist()
        out = [({"stud_id": sid, "drawing_xy_mm": xy} if with_stud else {}) | {"status": texts[i]}
               for i, (sid, xy) in enumerate(zip(self.ids, xy_mm))]
        seen = np.flatnonzero(self.view_index >= 0)
        pos, nrm, pix = (_nullable(a[seen]) for a in (self.position_w, self.normal_w, self.pixel_uv))
        err, inc = _nullable(self.xy_error_m[seen] * 1e3), _nullable(self.inclination_deg[seen])
        views, its = self.view_index[seen].tolist(), self.iterations[seen].tolist()
        sig, lean, fill, clear = (_nullable(a) for a in (self.normal_sigma_deg[seen], self.lean_bound_deg[seen],
                                                         self.fill_ratio[seen], self.gun_clearance_m[seen] * 1e3))
        reasons = self.reasons[seen].tolist()
        for k, i in enumerate(seen.tolist()):
            out[i].update(position_m=pos[k], normal=nrm[k], pixel=pix[k], view=views[k], iterations=its[k],
                          xy_error_mm=err[k], inclination_deg=inc[k], normal_sigma_deg=sig[k],
                          lean_bound_deg=lean[k], fill_ratio=fill[k], gun_clearance_mm=clear[k])
            if reasons[k]:
                out[i]["reason"] = reasons[k]
        return out


#: The table's columns (every field but ``ids``), in declaration order.
COLUMNS = tuple(f.name for f in fields(TargetTable) if f.name != "ids")


def centre_offset(pixel_uv: np.ndarray, cx: float, cy: float, width: int, height: int) -> np.ndarray:
    """(N,) distance of pixels ``pixel_uv`` (N, 2) from the principal point (cx, cy), over the half
    diagonal of a ``width`` x ``height`` image: 0 at the centre, about 1 in a corner; NaN for NaN pixels."""
    uv = np.asarray(pixel_uv, dtype=np.float64).reshape(-1, 2)
    return np.linalg.norm(uv - np.array([cx, cy]), axis=1) / (np.hypot(width, height) / 2)


class BestViewKey(NamedTuple):
    """What decides between two views' targets of a stud (arrays over studs, or one stud's values)."""

    status: ArrayLike          # TargetStatus values
    lean_bound_deg: ArrayLike  # NaN: unknown (worst)
    centre_offset: ArrayLike   # NaN: unknown (worst)
    view_index: ArrayLike


def choose_best(held: BestViewKey, offered: BestViewKey) -> np.ndarray:
    """Where the ``offered`` target of a stud replaces the ``held`` one (bool, per stud): the one rule by
    which both ``plan`` (the offline report) and the cell (stud_cell.job, the studs it welds from
    another station's view) keep a stud's best view.

    A usable (``ok``) target beats any other. Between usable ones the smaller lean bound wins: it is
    the worst lean the welded stud could get from that view's normal (k times the normal's 1-sigma plus
    the arm's error), what a view is worth to the weld; a match central in its image often has the
    surer normal, but a hole in its window or a grazing view can make it the worse one, and the lean
    bound says so. Equal bounds (noise-free depth, both at the floor) go to the match nearer the image
    centre (least lens distortion left after rectification), then to the earlier view. A stud no view
    made usable keeps the earliest view that saw it (with its status and reason); an ``out_of_view``
    target replaces nothing."""
    ok, fallback = int(TargetStatus.OK), 1
    rank_h, rank_o = _rank(held.status), _rank(offered.status)
    lean_h, lean_o = _worst_if_nan(held.lean_bound_deg), _worst_if_nan(offered.lean_bound_deg)
    centre_h, centre_o = _worst_if_nan(held.centre_offset), _worst_if_nan(offered.centre_offset)
    view_h, view_o = np.asarray(held.view_index), np.asarray(offered.view_index)
    same = rank_o == rank_h
    earlier = view_o < view_h
    better_ok = (lean_o < lean_h) | ((lean_o == lean_h) & ((centre_o < centre_h) | ((centre_o == centre_h) & earlier)))
    return (rank_o < rank_h) | (same & (rank_o == ok) & better_ok) | (same & (rank_o == fallback) & earlier)


def _rank(status) -> np.ndarray:
    """0 usable, 1 seen but not usable, 2 not seen (out_of_view)."""
    status = np.asarray(status)
    return np.where(status == TargetStatus.OK, 0, np.where(status == TargetStatus.OUT_OF_VIEW, 2, 1))


def _worst_if_nan(values) -> np.ndarray:
    values = np.asarray(values, dtype=np.float64)
    return np.where(np.isnan(values), np.inf, values)


def _nullable(values: np.ndarray) -> list:
    """``values.tolist()`` with None where a value is not finite (JSON's null: no value)."""
    values = np.asarray(values, dtype=np.float64)
    out = values.tolist()
    bad = ~np.isfinite(values)
    if values.ndim == 1:
        for i in np.flatnonzero(bad).tolist():
            out[i] = None
    else:
        for i in np.flatnonzero(bad.any(axis=1)).tolist():
            out[i] = [v if math.isfinite(v) else None for v in out[i]]
    return out


__all__ = ["COLUMNS", "STATUS_TEXTS", "BestViewKey", "TargetTable", "centre_offset", "choose_best"]
