"""The stud layout of a drawing: circles -> marks -> drawing frame -> studs in their stable order,
with their ids and the warnings."""
from __future__ import annotations

import gc
import math
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import ezdxf.lldxf.const as dxfconst
import numpy as np
from stud_common.rotations import float3
from stud_planner.drawing.circles import _LABEL_LETTERS, read_circles
from stud_planner.drawing.dxf_file import _one_line
from stud_planner.drawing.layout_types import CircleSet, DrawingError, DrawingLayout, Mark, Stud
from stud_planner.drawing.limits import DrawingLimits
from stud_planner.drawing.marks import _fmt_pats, _identify_marks, _layer_matcher
from stud_planner.drawing.neighbours import _TooDense, close_pairs



# -- the layout ------------------------------------------------------------------------------------
def read_layout(
    path: str | Path,
    *,
    stud_layers: str | Sequence[str] = ("STUDS",),
    mark_layer: str | Sequence[str] = "MARKS",
    units_if_unitless: str = "mm",
    min_diameter_m: float | None = None,
    max_diameter_m: float | None = None,
    min_spacing_m: float | None = None,
    duplicate_tol_m: float = 1e-3,
    diameter_outlier_ratio: float = 1.5,
    label_distance_factor: float = 3.0,
    perpendicular_tol_deg: float = 0.5,
    collinear_tol_deg: float = 1.0,
    right_angle_ambiguity_deg: float = 2.0,
    include_hidden_layers: bool = False,
    gun_spacing_m: float = 0.0,
    limits: DrawingLimits | None = None,
) -> DrawingLayout:
    """Read the stud layout of a DXF drawing (see the module docstring for every rule).

    Args:
        stud_layers: layer name(s) or fnmatch patterns of the stud circles, case-insensitive.
        mark_layer: layer name(s) or patterns of the O/A/B mark circles.
        units_if_unitless: unit of a drawing without $INSUNITS ("mm", "cm", "m", "in", ...).
        min_diameter_m, max_diameter_m: keep only stud circles in this diameter range (m).
        min_spacing_m: warn about studs closer than this (m); None = 2.5 x the median stud
            diameter (the smallest transverse spacing EN 1994-1-1 6.6.5.7 allows), 0 = off.
        duplicate_tol_m: studs closer than this are one stud (the first in id order is kept).
        diameter_outlier_ratio: warn about studs whose diameter differs from the median by
            more than this factor.
        label_distance_factor: an O/A/B label names a mark within this many mark diameters.
        perpendicular_tol_deg: warn when angle AOB differs from 90 deg by more.
        collinear_tol_deg: marks whose triangle has an angle below this are collinear (error).
        right_angle_ambiguity_deg: geometry rule: the right angle must be this much clearer
            than the runner-up, else the marks are ambiguous (error).
        include_hidden_layers: also read layers that are frozen or off (by default their
            entities are skipped with a warning, as CAD does not show them).
        gun_spacing_m: warn about stud pairs closer than the weld gun's foot needs beside a
            welded stud (the arm driver's ``min_stud_spacing_m``): of each such pair the driver
            welds one and refuses the other. 0 = off.
        limits: the work budget of the block expansion (default: :class:`DrawingLimits`' defaults,
            far beyond any real drawing); crossing one raises :class:`DrawingLimitError`.

    Raises:
        DrawingError: one line naming the file and the problem.
    """
    path = Path(path)
    with _bulk_allocation():
        cs = read_circles(path, units_if_unitless=units_if_unitless, include_hidden_layers=include_hidden_layers,
                          limits=limits)
        try:
            return _build_layout(path, cs, _Rules(
                stud_layers, mark_layer, min_diameter_m, max_diameter_m, min_spacing_m,
                duplicate_tol_m, diameter_outlier_ratio, label_distance_factor, perpendicular_tol_deg,
                collinear_tol_deg, right_angle_ambiguity_deg, gun_spacing_m,
            ))
        except DrawingError:
            raise
        except Exception as exc:
            raise DrawingError(f"{path}: cannot interpret the drawing ({type(exc).__name__}: {_one_line(exc)})") from exc


@contextmanager
def _bulk_allocation():
    """Python's cyclic garbage collector paused while a drawing's hundreds of thousands of objects
    (ezdxf entities, studs) are built, none of which is garbage before the layout is done: its
    collections, which revisit every live object, made reading a 250,000-stud drawing
    superlinear. What ezdxf leaves behind is collected once the collector runs again."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


def _ids_list(ids: Sequence[str], limit: int = 5) -> str:
    shown = ", ".join(ids[:limit])
    return shown + (f", ... (+{len(ids) - limit})" if len(ids) > limit else "")


ORDER_TOL_M = 1e-4  # studs whose y (x) differ by less are in one row (column) for the id order


def _runs(values: np.ndarray, tol: float, within: np.ndarray | None = None) -> np.ndarray:
    """Index of the run each value falls in: runs are maximal chains of sorted values with gaps
    < ``tol`` (inside each group of ``within``, if given), so values equal within float noise
    share an index however large they are, and no fixed grid boundary can split them."""
    if values.size == 0:
        return np.zeros(0, dtype=np.int64)
    groups = np.zeros(values.size, dtype=np.int64) if within is None else within
    order = np.lexsort((values, groups))
    new = (np.diff(values[order]) >= tol) | (np.diff(groups[order]) != 0)
    run = np.empty(values.size, dtype=np.int64)
    run[order] = np.cumsum(np.concatenate([[0], new.astype(np.int64)]))
    return run


@dataclass(frozen=True)
class _Rules:
    """The options of :func:`read_layout` (its docstring says what each one does)."""

    stud_layers: str | Sequence[str]
    mark_layer: str | Sequence[str]
    min_diameter_m: float | None
    max_diameter_m: float | None
    min_spacing_m: float | None
    duplicate_tol_m: float
    diameter_outlier_ratio: float
    label_distance_factor: float
    perpendicular_tol_deg: float
    collinear_tol_deg: float
    right_angle_ambiguity_deg: float
    gun_spacing_m: float = 0.0


@dataclass(frozen=True)
class _Frame:
    """The drawing frame the marks define: ``T`` maps WCS (drawing units) to the frame (metres)."""

    T: np.ndarray
    angle_deg: float
    mirrored: bool
    mark_d: dict[str, float]  # mark diameters (m)

    def to_drawing(self, xy_units: np.ndarray) -> np.ndarray:
        return xy_units @ self.T[:2, :2].T + self.T[:2, 2]


def _drawing_frame(path: Path, cs: CircleSet, marks_idx: dict[str, int], rules: _Rules, warns: list[str]) -> _Frame:
    """Frame: x along OA, y perpendicular on B's side; metres. Refuses coincident or collinear marks."""
    s = cs.metres_per_unit
    O, A, B = (cs.centers_wcs[marks_idx[k]] * s for k in _LABEL_LETTERS)
    oa, ob = A - O, B - O
    d_oa, d_ob = float(np.hypot(*oa)), float(np.hypot(*ob))
    mark_d = {k: 2.0 * float(cs.radii[marks_idx[k]]) * s for k in _LABEL_LETTERS}
    for p, q, dist in (("O", "A", d_oa), ("O", "B", d_ob), ("A", "B", float(np.hypot(*(B - A))))):
        if dist <= max(mark_d[p], mark_d[q], rules.duplicate_tol_m):
            raise DrawingError(f"{path}: marks coincident: {p} and {q} are {dist * 1e3:.3f} mm apart "
                               f"(mark diameter {max(mark_d[p], mark_d[q]) * 1e3:.1f} mm)")
    cross = oa[0] * ob[1] - oa[1] * ob[0]
    angle = math.degrees(math.atan2(abs(cross), float(oa @ ob)))
    if angle < rules.collinear_tol_deg or angle > 180.0 - rules.collinear_tol_deg:
        raise DrawingError(f"{path}: marks collinear: angle AOB is {angle:.2f} deg, O, A, B define no frame")
    mirrored = bool(cross < 0)
    ex = oa / d_oa
    ey = np.array([-ex[1], ex[0]]) * (-1.0 if mirrored else 1.0)
    R = np.stack([ex, ey])  # rows: drawing axes in WCS
    T = np.eye(3)
    T[:2, :2] = R * s
    T[:2, 2] = -R @ O
    if abs(angle - 90.0) > rules.perpendicular_tol_deg:
        warns.append(f"{path.name}: marks not perpendicular: angle AOB is {angle:.2f} deg; x runs along OA, "
                     f"y perpendicular to it on B's side")
    if mirrored:
        warns.append(f"{path.name}: B is clockwise from A in the DXF: the drawing frame is mirrored relative to "
                     f"the DXF (drawn as seen from below?); check the mark labels")
    return _Frame(T, angle, mirrored, mark_d)


def _marks(cs: CircleSet, marks_idx: dict[str, int], frame: _Frame) -> dict[str, Mark]:
    """O, A, B and the reference marks (in ``marks_idx``'s order) in the drawing frame."""
    marks = {}
    for k, i in marks_idx.items():
        dx, dy = frame.to_drawing(cs.centers_wcs[i][None, :])[0]
        diameter = frame.mark_d[k] if k in frame.mark_d else 2.0 * float(cs.radii[i]) * cs.metres_per_unit
        marks[k] = Mark(k, float(dx), float(dy), float(cs.centers_wcs[i][0]), float(cs.centers_wcs[i][1]),
                        diameter, cs.layers[i])
    return marks


def _diameter_filter(path: Path, cs: CircleSet, idx: np.ndarray, rules: _Rules,
                     warns: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """The stud candidates ``idx`` within the diameter range, and their diameters (m)."""
    diam = 2.0 * cs.radii[idx] * cs.metres_per_unit
    keep = np.ones(idx.size, dtype=bool)
    if rules.min_diameter_m is not None:
        keep &= diam >= rules.min_diameter_m
    if rules.max_diameter_m is not None:
        keep &= diam <= rules.max_diameter_m
    if not keep.all():
        lo = f"{rules.min_diameter_m * 1e3:g}" if rules.min_diameter_m is not None else "0"
        hi = f"{rules.max_diameter_m * 1e3:g}" if rules.max_diameter_m is not None else "inf"
        warns.append(f"{path.name}: {np.count_nonzero(~keep)} circles on stud layers outside the diameter filter "
                     f"[{lo}, {hi}] mm ignored")
    idx, diam = idx[keep], diam[keep]
    if idx.size == 0:
        raise DrawingError(
            f"{path}: no studs found: no circles on layer(s) {_fmt_pats(rules.stud_layers)} pass the diameter filter"
            f"{cs.skipped_summary()}; layers: {cs.layer_summary()}"
        )
    return idx, diam


def _stud_order(xy: np.ndarray, diam: np.ndarray, layer_arr: np.ndarray) -> np.ndarray:
    """Deterministic order: layer, row (y), column (x), then diameter and exact coordinates. Rows
    and columns are runs of values less than ORDER_TOL_M apart, so float noise from the CAD
    placement (a rotated or shifted copy) never moves a stud across a grid boundary."""
    layer_key = np.array([lay.casefold() for lay in layer_arr])
    row = _runs(xy[:, 1], ORDER_TOL_M)
    col = _runs(xy[:, 0], ORDER_TOL_M, within=row)
    return np.lexsort((xy[:, 0], xy[:, 1], diam, col, row, layer_key))


def _first_of_duplicates(name: str, xy: np.ndarray, duplicate_tol_m: float, warns: list[str]) -> np.ndarray:
    """Duplicates (any layer): keep the first in order. Returns the mask of the studs kept."""
    alive = np.ones(len(xy), dtype=bool)
    try:
        i, j, _ = close_pairs(xy, duplicate_tol_m)
        for a, b in sorted(zip(i.tolist(), j.tolist())):
            if alive[a]:
                alive[b] = False
        dense = False
    except _TooDense:
        cells = np.floor(xy / duplicate_tol_m).astype(np.int64)
        _, first = np.unique(cells, axis=0, return_index=True)
        alive[:] = False
        alive[first] = True
        dense = True
    n_dup = int(np.count_nonzero(~alive))
    if n_dup:
        extra = " (approximate: too many coincident circles for the exact check)" if dense else ""
        warns.append(f"{name}: {n_dup} duplicate studs within {duplicate_tol_m * 1e3:g} mm removed{extra}")
    return alive


def _check_studs(name: str, xy: np.ndarray, diam: np.ndarray, ids: list[str], marks: dict[str, Mark],
                 rules: _Rules) -> list[str]:
    """Checks that only warn: odd diameters, studs too close, on a mark, outside the marks' quadrant."""
    warns = []
    n = len(xy)
    median_d = float(np.median(diam))
    ratio = rules.diameter_outlier_ratio
    if ratio and ratio > 1.0:
        odd = np.flatnonzero((diam > median_d * ratio) | (diam < median_d / ratio))
        if odd.size:
            warns.append(f"{name}: {odd.size} studs with unusual diameter (median {median_d * 1e3:.2f} mm): "
                         + ", ".join(f"{ids[k]} {diam[k] * 1e3:.2f} mm" for k in odd[:5])
                         + (f", ... (+{odd.size - 5})" if odd.size > 5 else ""))
    spacing = 2.5 * median_d if rules.min_spacing_m is None else float(rules.min_spacing_m)
    for limit, what, consequence in (
            (spacing, "min spacing", ""),
            (float(rules.gun_spacing_m), "the weld gun's foot allows (gun_spacing_m)",
             ": the arm driver welds one stud of each pair and refuses the other")):
        if not (limit > 0 and n > 1):
            continue
        try:
            i, j, d = close_pairs(xy, limit)
            if i.size:
                o = np.argsort(d, kind="stable")[:5]
                pairs = ", ".join(f"{ids[i[k]]}-{ids[j[k]]} {d[k] * 1e3:.1f} mm" for k in o)
                more = f", ... (+{i.size - 5})" if i.size > 5 else ""
                warns.append(f"{name}: {i.size} stud pairs closer than {what} {limit * 1e3:.1f} mm: "
                             f"{pairs}{more}{consequence}")
        except _TooDense as exc:
            warns.append(f"{name}: spacing check skipped: {exc.args[0]} candidate pairs closer than "
                         f"{limit * 1e3:.1f} mm (are the drawing units right?)")
    for k in _LABEL_LETTERS:  # a ring of the mark symbol drawn on a stud layer?
        m = marks[k]
        on_mark = np.flatnonzero(np.hypot(xy[:, 0] - m.x_m, xy[:, 1] - m.y_m)
                                 < max(0.5 * m.diameter_m, rules.duplicate_tol_m))
        if on_mark.size:
            warns.append(f"{name}: {_ids_list([ids[j] for j in on_mark])} on a stud layer lie(s) on mark {k}: part "
                         f"of the mark symbol drawn on the wrong layer? (kept as studs)")
    outside = np.flatnonzero((xy[:, 0] < -1e-9) | (xy[:, 1] < -1e-9))
    if outside.size:
        warns.append(f"{name}: {outside.size} studs outside the marks' quadrant (negative x or y): "
                     f"{_ids_list([ids[k] for k in outside])}")
    return warns


def _build_layout(path: Path, cs: CircleSet, rules: _Rules) -> DrawingLayout:
    warns = list(cs.warnings)
    s = cs.metres_per_unit
    name = path.name
    stud_match, _ = _layer_matcher(rules.stud_layers)
    hit = {lay: stud_match(lay) for lay in set(cs.layers)}  # a few layers, many circles
    is_stud = np.array([hit[lay] for lay in cs.layers], dtype=bool)
    if not is_stud.any():
        raise DrawingError(
            f"{path}: no studs found: no circles on layer(s) {_fmt_pats(rules.stud_layers)}{cs.skipped_summary()}; "
            f"layers: {cs.layer_summary()}"
        )

    marks_idx, rule, mark_warns, mark_members = _identify_marks(
        path, cs, rules.mark_layer, rules.duplicate_tol_m / s, rules.label_distance_factor, rules.collinear_tol_deg,
        rules.right_angle_ambiguity_deg, stud_match,
    )
    warns += mark_warns
    frame = _drawing_frame(path, cs, marks_idx, rules, warns)
    marks = _marks(cs, marks_idx, frame)

    # Stud candidates: stud layers, minus the mark circles (and their concentric rings), diameter filter.
    is_stud[list(marks_idx.values())] = False
    is_stud[mark_members] = False
    idx, diam = _diameter_filter(path, cs, np.flatnonzero(is_stud), rules, warns)
    xy = frame.to_drawing(cs.centers_wcs[idx])
    layer_arr = np.array([cs.layers[i] for i in idx], dtype=object)
    order = _stud_order(xy, diam, layer_arr)
    xy, diam, layer_arr = xy[order], diam[order], layer_arr[order]
    alive = _first_of_duplicates(name, xy, rules.duplicate_tol_m, warns)
    xy, diam, layer_arr = xy[alive], diam[alive], layer_arr[alive]
    n = len(xy)
    width = max(4, len(str(n)))
    ids = [f"S{k + 1:0{width}d}" for k in range(n)]
    studs = tuple(map(Stud, ids, xy[:, 0].tolist(), xy[:, 1].tolist(), diam.tolist(), layer_arr.tolist()))
    warns += _check_studs(name, xy, diam, ids, marks, rules)

    bbox = (float(xy[:, 0].min()), float(xy[:, 1].min()), float(xy[:, 0].max()), float(xy[:, 1].max()))
    return DrawingLayout(
        source_file=str(path), dxf_version=cs.dxf_version,
        dxf_release=dxfconst.acad_release.get(cs.dxf_version, cs.dxf_version), read_mode=cs.read_mode,
        source_units=cs.source_units, insunits=cs.insunits, units_assumed=cs.units_assumed,
        metres_per_unit=s, studs=studs, mark_o=marks["O"], mark_a=marks["A"], mark_b=marks["B"],
        mark_diameter_m=float(np.mean(list(frame.mark_d.values()))), marks_rule=rule,
        angle_aob_deg=float(frame.angle_deg), mirrored=frame.mirrored,
        wcs_to_drawing=tuple(float3(row) for row in frame.T), bbox_m=bbox,
        stud_layers=tuple(sorted(set(layer_arr.tolist()), key=str.casefold)), warnings=warns,
        invalid_entities=cs.invalid_entities,
        reference_marks=tuple(m for k, m in marks.items() if k not in _LABEL_LETTERS),
    )
