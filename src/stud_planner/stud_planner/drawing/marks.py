"""The marks: O, A, B (by their labels or by geometry) and the reference marks M1, M2, ... (by labels).

:func:`mark_label` reads a label's text (entity collection hands it every TEXT, MTEXT and ATTRIB);
:func:`identify_marks` picks the mark circles among a drawing's circles. The frame the marks define
is :mod:`.frame`."""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from stud_planner.drawing.layers import format_patterns, layer_matcher
from stud_planner.drawing.layout_types import CircleSet, DrawingError
from stud_planner.drawing.neighbours import TooDenseError, close_pairs
from stud_planner.drawing.options import LayoutOptions

__all__ = ["MARK_LETTERS", "MarkChoice", "identify_marks", "mark_label"]

#: the marks every drawing has, in frame order: origin, x axis, y side
MARK_LETTERS = ("O", "A", "B")
#: a reference mark's label: M1, M2, ... (``M01`` and ``M 1`` read as M1)
_REFERENCE_LABEL = re.compile(r"M\s*0*([1-9][0-9]{0,5})")
#: TEXT control codes (underline, overline, strike-through) around a label
_TEXT_CODES = re.compile(r"%%[uUoOkK]")


def mark_label(text: str) -> str | None:
    """The mark a label's plain ``text`` names: "O", "A", "B", "M1", "M2", ...; None for any other text."""
    text = _TEXT_CODES.sub("", text).strip().upper()
    if text in MARK_LETTERS:
        return text
    ref = _REFERENCE_LABEL.fullmatch(text)
    return f"M{ref.group(1)}" if ref else None


@dataclass(frozen=True, eq=False)
class MarkChoice:
    """The mark circles of a drawing (indices into its :class:`CircleSet`).

    ``marks`` maps O, A, B and each reference mark's label to its circle (reference marks after
    O, A, B, in label order: M1, M2, ..., M10); ``rule`` is "labels" or "geometry"; ``members`` are
    all mark-layer circles concentric with a chosen mark (the rings of a target symbol), which are
    never studs."""

    marks: dict[str, int]
    rule: str
    warnings: list[str]
    members: np.ndarray


def _merge_concentric(path: Path, idx: np.ndarray, xy: np.ndarray, r: np.ndarray, tol: float) -> np.ndarray:
    """Indices of mark circles with concentric duplicates merged (the largest circle is kept)."""
    if idx.size < 2:
        return idx
    order = idx[np.lexsort((xy[idx, 1], xy[idx, 0], -r[idx]))]  # largest first, then by position
    alive = np.ones(order.size, dtype=bool)
    try:
        i, j, _ = close_pairs(xy[order], tol)
    except TooDenseError:
        raise DrawingError(f"{path}: marks ambiguous: too many coincident circles on the mark layer") from None
    for a, b in sorted(zip(i.tolist(), j.tolist())):
        if alive[a]:
            alive[b] = False
    kept = order[alive]
    return kept[np.lexsort((xy[kept, 1], xy[kept, 0]))]


def _angle_deg(p: np.ndarray, q: np.ndarray, s: np.ndarray) -> float:
    """Angle at p between pq and ps, degrees."""
    a, b = q - p, s - p
    return math.degrees(math.atan2(abs(a[0] * b[1] - a[1] * b[0]), float(a @ b)))


def identify_marks(path: Path, cs: CircleSet, options: LayoutOptions,
                   is_stud_layer: Callable[[str], bool] | None = None) -> MarkChoice:
    """Pick the O, A, B circles and the reference marks M1, M2, ... among ``cs``'s circles on
    ``options.mark_layer``. ``is_stud_layer``: whether a layer holds studs (an unlabelled circle on a
    layer that is both is a stud, not a mark missing its label).

    Raises:
        DrawingError: marks missing, ambiguous, coincident or collinear (one line naming ``path``).
    """
    mark_layer = options.mark_layer
    dup_tol_units = options.duplicate_tol_m / cs.metres_per_unit
    collinear_tol_deg, right_angle_ambiguity_deg = options.collinear_tol_deg, options.right_angle_ambiguity_deg
    match = layer_matcher(mark_layer)
    xy, r = cs.centers_wcs, cs.radii
    hit = {lay: match(lay) for lay in set(cs.layers)}
    on_layer = np.array([k for k, lay in enumerate(cs.layers) if hit[lay]], dtype=np.int64)
    cand = _merge_concentric(path, on_layer, xy, r, dup_tol_units)
    where = f"on layer {format_patterns(mark_layer)}"
    warns: list[str] = []
    if cand.size < 3:
        raise DrawingError(
            f"{path}: marks missing: found {cand.size} mark circle{'s' if cand.size != 1 else ''} {where}, "
            f"need 3 (O, A, B){cs.skipped_summary()}; layers: {cs.layer_summary()}"
        )

    labelled = _labelled(cs, cand, options.label_distance_factor)
    multi = {lt: ks for lt, ks in labelled.items() if len(ks) > 1}
    if multi:
        lt, ks = next(iter(multi.items()))
        raise DrawingError(f"{path}: marks ambiguous: label {lt!r} is nearest to {len(ks)} mark circles {where}")
    refs = _reference_marks(path, cs, cand, labelled, where, warns)
    if refs:
        cand = cand[~np.isin(cand, list(refs.values()))]
        labelled = {lt: ks for lt, ks in labelled.items() if lt in MARK_LETTERS}
        marks, rule, board_warns, _ = _identify_marks_of(path, cs, cand, labelled, where, collinear_tol_deg,
                                                         right_angle_ambiguity_deg, on_layer, dup_tol_units)
        extra = [int(k) for k in cand if k not in marks.values()
                 and not (is_stud_layer is not None and is_stud_layer(cs.layers[k]))]
        if extra:
            at = ", ".join(f"({xy[k, 0]:g}, {xy[k, 1]:g})" for k in extra[:5]) + (", ..." if len(extra) > 5 else "")
            raise DrawingError(
                f"{path}: marks ambiguous: {len(extra)} unlabelled circle(s) {where} at {at} (drawing units) "
                f"in a drawing with reference marks {', '.join(refs)}: label each mark circle (O, A, B or M1, M2, ...) "
                "or move other circles off the mark layer"
            )
        marks.update(refs)
        return MarkChoice(marks, rule, warns + board_warns, _members(marks, on_layer, xy, dup_tol_units))
    return MarkChoice(*_identify_marks_of(path, cs, cand, labelled, where, collinear_tol_deg, right_angle_ambiguity_deg,
                                          on_layer, dup_tol_units, warns))


def _reference_marks(path: Path, cs: CircleSet, cand: np.ndarray, labelled: dict[str, list[int]], where: str,
                     warns: list[str]) -> dict[str, int]:
    """The reference marks among the labelled circles: label -> circle, in label order (M1, M2, ...,
    M10). An M label next to no mark circle is warned about (a thread size such as M16 on another
    layer is text like any other)."""
    refs = {lt: ks[0] for lt, ks in labelled.items() if lt not in MARK_LETTERS}
    refs = dict(sorted(refs.items(), key=lambda kv: int(kv[0][1:])))
    unused = sorted({lt for lt, _, _ in cs.labels if lt not in MARK_LETTERS} - set(refs), key=lambda t: int(t[1:]))
    if refs and unused:
        warns.append(f"{path.name}: label(s) {', '.join(unused)} name no mark circle {where} (no reference mark "
                     "read for them)")
    return refs


def _identify_marks_of(path: Path, cs: CircleSet, cand: np.ndarray, labelled: dict[str, list[int]], where: str,
                       collinear_tol_deg: float, right_angle_ambiguity_deg: float, on_layer: np.ndarray,
                       dup_tol_units: float, warns: list[str] | None = None) -> tuple[dict[str, int], str, list[str],
                                                                                       np.ndarray]:
    """O, A, B among the board's candidate circles ``cand``, by labels or by geometry."""
    xy, r = cs.centers_wcs, cs.radii
    warns = [] if warns is None else warns
    if cand.size < 3:
        raise DrawingError(
            f"{path}: marks missing: found {cand.size} mark circle{'s' if cand.size != 1 else ''} {where} besides "
            f"the reference marks, need 3 (O, A, B)"
        )
    if len(labelled) == 3:
        marks = {lt: ks[0] for lt, ks in labelled.items()}
        if cand.size > 3:
            warns.append(f"{path.name}: {cand.size - 3} unlabelled circles {where} ignored (marks found by labels)")
        return marks, "labels", warns, _members(marks, on_layer, xy, dup_tol_units)

    if cand.size > 3:
        raise DrawingError(
            f"{path}: marks ambiguous: found {cand.size} mark circles {where} but only "
            f"{len(labelled)} of the labels O, A, B next to them; need exactly 3 circles or all three labels"
        )
    marks = _marks_by_geometry(path, xy, r, cand, where, collinear_tol_deg, right_angle_ambiguity_deg)
    if labelled:
        disagree = [lt for lt, ks in labelled.items() if marks[lt] != ks[0]]
        if disagree:
            raise DrawingError(
                f"{path}: marks ambiguous: label(s) {', '.join(disagree)} disagree with the geometry rule "
                f"(right angle at O, B counter-clockwise from A); label all three marks"
            )
        warns.append(f"{path.name}: only label(s) {', '.join(sorted(labelled))} found next to the marks; "
                     f"marks identified by geometry")
    return marks, "geometry", warns, _members(marks, on_layer, xy, dup_tol_units)


def _members(marks: dict[str, int], on_layer: np.ndarray, xy: np.ndarray, tol: float) -> np.ndarray:
    centres = xy[list(marks.values())]
    d = np.hypot(*(xy[on_layer][:, None, :] - centres[None, :, :]).transpose(2, 0, 1))
    return on_layer[np.any(d <= tol, axis=1)]


def _labelled(cs: CircleSet, cand: np.ndarray, label_distance_factor: float) -> dict[str, list[int]]:
    """Labels: each candidate circle takes the letter of its nearest O/A/B (or M1, M2, ...) label within
    reach. Returns letter -> the circles it names (letters naming none left out), O, A, B first."""
    xy, r = cs.centers_wcs, cs.radii
    by_letter: dict[str, list[int]] = {k: [] for k in MARK_LETTERS}
    by_letter.update({lt: [] for lt, _, _ in cs.labels if lt not in by_letter})
    if cs.labels:
        lab_xy = np.array([(x, y) for _, x, y in cs.labels])
        letters = [lt for lt, _, _ in cs.labels]
        for k in cand:
            d = np.hypot(*(lab_xy - xy[k]).T)
            j = int(np.argmin(d))
            if d[j] <= label_distance_factor * 2.0 * r[k]:
                by_letter[letters[j]].append(int(k))
    return {lt: ks for lt, ks in by_letter.items() if ks}


def _marks_by_geometry(path: Path, xy: np.ndarray, r: np.ndarray, cand: np.ndarray, where: str,
                       collinear_tol_deg: float, right_angle_ambiguity_deg: float) -> dict[str, int]:
    """The geometry rule on exactly 3 circles: O at the clear right angle, B counter-clockwise from A."""
    p = [xy[k] for k in cand]
    for s1, s2 in ((0, 1), (0, 2), (1, 2)):
        dist = math.dist(p[s1], p[s2])
        if dist <= 2.0 * max(r[cand[s1]], r[cand[s2]]):
            raise DrawingError(f"{path}: marks coincident: two of the 3 mark circles {where} overlap "
                               f"(centres {dist:g} drawing units apart)")
    angles = [_angle_deg(p[k], p[(k + 1) % 3], p[(k + 2) % 3]) for k in range(3)]
    if max(angles) > 180.0 - collinear_tol_deg:
        raise DrawingError(f"{path}: marks collinear: the 3 mark circles {where} lie on one line "
                           f"(angles {', '.join(f'{a:.2f}' for a in angles)} deg), they define no frame")
    off = sorted(range(3), key=lambda k: abs(angles[k] - 90.0))
    if abs(angles[off[1]] - 90.0) - abs(angles[off[0]] - 90.0) < right_angle_ambiguity_deg:
        shown = ", ".join(f"{a:.1f}" for a in angles)
        raise DrawingError(
            f"{path}: marks ambiguous: no clear right angle among the mark triangle's angles ({shown} deg); "
            f"label the marks O, A, B"
        )
    o = off[0]
    a, b = (o + 1) % 3, (o + 2) % 3
    oa, ob = p[a] - p[o], p[b] - p[o]
    if oa[0] * ob[1] - oa[1] * ob[0] < 0:
        a, b = b, a
    return {"O": int(cand[o]), "A": int(cand[a]), "B": int(cand[b])}
