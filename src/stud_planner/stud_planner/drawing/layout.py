"""The stud layout of a drawing, composed from its concerns: the circles (:mod:`.circles`, from
:mod:`.entities` and :mod:`.dxf_file`), the marks (:mod:`.marks`), the drawing frame (:mod:`.frame`),
then the studs: stud layers (:mod:`.layers`), diameter filter, stable order and ids, duplicates
and the spacing checks (:mod:`.neighbours`), and the warnings."""
from __future__ import annotations

import gc
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Sequence

import ezdxf.lldxf.const as dxfconst
import numpy as np

from stud_common.rotations import float3
from stud_planner.drawing.circles import read_circles
from stud_planner.drawing.frame import drawing_frame, marks_in_frame
from stud_planner.drawing.layers import format_patterns, layer_matcher
from stud_planner.drawing.layout_types import CircleSet, DrawingError, DrawingLayout, Mark, Stud, one_line
from stud_planner.drawing.marks import MARK_LETTERS, identify_marks
from stud_planner.drawing.neighbours import TooDenseError, close_pairs
from stud_planner.drawing.options import LayoutOptions

__all__ = ["ORDER_TOL_M", "read_layout"]

ORDER_TOL_M = 1e-4  # studs whose y (x) differ by less are in one row (column) for the id order


def read_layout(path: str | Path, options: LayoutOptions | None = None, **changes: Any) -> DrawingLayout:
    """Read the stud layout of a DXF drawing (the package docstring has every rule).

    Args:
        path: the DXF file.
        options: how to read it (:class:`LayoutOptions`; None: its defaults).
        **changes: options changed for this call, by name (``read_layout(path, stud_layers=["S*"])``):
            the same as ``options.with_changes(**changes)``.

    Raises:
        DrawingError: one line naming the file and the problem.
    """
    path = Path(path)
    opts = options or LayoutOptions()
    if changes:
        opts = opts.with_changes(**changes)
    with _bulk_allocation():
        cs = read_circles(path, units_if_unitless=opts.units_if_unitless,
                          include_hidden_layers=opts.include_hidden_layers, limits=opts.limits)
        try:
            return _build_layout(path, cs, opts)
        except DrawingError:
            raise
        except Exception as exc:
            raise DrawingError(f"{path}: cannot interpret the drawing ({type(exc).__name__}: {one_line(exc)})") from exc


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


def _diameter_filter(path: Path, cs: CircleSet, idx: np.ndarray, opts: LayoutOptions,
                     warns: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """The stud candidates ``idx`` within the diameter range, and their diameters (m)."""
    diam = 2.0 * cs.radii[idx] * cs.metres_per_unit
    keep = np.ones(idx.size, dtype=bool)
    if opts.min_diameter_m is not None:
        keep &= diam >= opts.min_diameter_m
    if opts.max_diameter_m is not None:
        keep &= diam <= opts.max_diameter_m
    if not keep.all():
        lo = f"{opts.min_diameter_m * 1e3:g}" if opts.min_diameter_m is not None else "0"
        hi = f"{opts.max_diameter_m * 1e3:g}" if opts.max_diameter_m is not None else "inf"
        warns.append(f"{path.name}: {np.count_nonzero(~keep)} circles on stud layers outside the diameter filter "
                     f"[{lo}, {hi}] mm ignored")
    idx, diam = idx[keep], diam[keep]
    if idx.size == 0:
        raise DrawingError(
            f"{path}: no studs found: no circles on layer(s) {format_patterns(opts.stud_layers)} "
            "pass the diameter filter"
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
    except TooDenseError:
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
                 opts: LayoutOptions) -> list[str]:
    """Checks that only warn: odd diameters, studs too close, on a mark, outside the marks' quadrant."""
    warns = []
    n = len(xy)
    median_d = float(np.median(diam))
    ratio = opts.diameter_outlier_ratio
    if ratio and ratio > 1.0:
        odd = np.flatnonzero((diam > median_d * ratio) | (diam < median_d / ratio))
        if odd.size:
            warns.append(f"{name}: {odd.size} studs with unusual diameter (median {median_d * 1e3:.2f} mm): "
                         + ", ".join(f"{ids[k]} {diam[k] * 1e3:.2f} mm" for k in odd[:5])
                         + (f", ... (+{odd.size - 5})" if odd.size > 5 else ""))
    spacing = 2.5 * median_d if opts.min_spacing_m is None else float(opts.min_spacing_m)
    for limit, what, consequence in (
            (spacing, "min spacing", ""),
            (float(opts.gun_spacing_m), "the weld gun's foot allows (gun_spacing_m)",
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
        except TooDenseError as exc:
            warns.append(f"{name}: spacing check skipped: {exc.args[0]} candidate pairs closer than "
                         f"{limit * 1e3:.1f} mm (are the drawing units right?)")
    for k in MARK_LETTERS:  # a ring of the mark symbol drawn on a stud layer?
        m = marks[k]
        on_mark = np.flatnonzero(np.hypot(xy[:, 0] - m.x_m, xy[:, 1] - m.y_m)
                                 < max(0.5 * m.diameter_m, opts.duplicate_tol_m))
        if on_mark.size:
            warns.append(f"{name}: {_ids_list([ids[j] for j in on_mark])} on a stud layer lie(s) on mark {k}: part "
                         f"of the mark symbol drawn on the wrong layer? (kept as studs)")
    outside = np.flatnonzero((xy[:, 0] < -1e-9) | (xy[:, 1] < -1e-9))
    if outside.size:
        warns.append(f"{name}: {outside.size} studs outside the marks' quadrant (negative x or y): "
                     f"{_ids_list([ids[k] for k in outside])}")
    return warns


def _build_layout(path: Path, cs: CircleSet, opts: LayoutOptions) -> DrawingLayout:
    warns = list(cs.warnings)
    s = cs.metres_per_unit
    name = path.name
    stud_match = layer_matcher(opts.stud_layers)
    hit = {lay: stud_match(lay) for lay in set(cs.layers)}  # a few layers, many circles
    is_stud = np.array([hit[lay] for lay in cs.layers], dtype=bool)
    if not is_stud.any():
        raise DrawingError(
            f"{path}: no studs found: no circles on layer(s) {format_patterns(opts.stud_layers)}"
            f"{cs.skipped_summary()}; layers: {cs.layer_summary()}"
        )

    choice = identify_marks(path, cs, opts, stud_match)
    marks_idx, rule = choice.marks, choice.rule
    warns += choice.warnings
    frame = drawing_frame(path, cs, marks_idx, opts, warns)
    marks = marks_in_frame(cs, marks_idx, frame)

    # Stud candidates: stud layers, minus the mark circles (and their concentric rings), diameter filter.
    is_stud[list(marks_idx.values())] = False
    is_stud[choice.members] = False
    idx, diam = _diameter_filter(path, cs, np.flatnonzero(is_stud), opts, warns)
    xy = frame.to_drawing(cs.centers_wcs[idx])
    layer_arr = np.array([cs.layers[i] for i in idx], dtype=object)
    order = _stud_order(xy, diam, layer_arr)
    xy, diam, layer_arr = xy[order], diam[order], layer_arr[order]
    alive = _first_of_duplicates(name, xy, opts.duplicate_tol_m, warns)
    xy, diam, layer_arr = xy[alive], diam[alive], layer_arr[alive]
    n = len(xy)
    width = max(4, len(str(n)))
    ids = [f"S{k + 1:0{width}d}" for k in range(n)]
    studs = tuple(map(Stud, ids, xy[:, 0].tolist(), xy[:, 1].tolist(), diam.tolist(), layer_arr.tolist()))
    warns += _check_studs(name, xy, diam, ids, marks, opts)

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
        reference_marks=tuple(m for k, m in marks.items() if k not in MARK_LETTERS),
    )
