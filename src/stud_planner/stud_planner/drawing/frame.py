"""The drawing frame the marks define (INTERFACES.md, frame ``drawing``): origin at O, x along OA, y
perpendicular to x on B's side; metres. The map from DXF WCS (drawing units, :mod:`.units`) to it,
and the marks placed in it."""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from stud_planner.drawing.layout_types import CircleSet, DrawingError, Mark
from stud_planner.drawing.marks import MARK_LETTERS
from stud_planner.drawing.options import LayoutOptions

__all__ = ["DrawingFrame", "drawing_frame", "marks_in_frame"]


@dataclass(frozen=True)
class DrawingFrame:
    """The drawing frame: ``T`` (3, 3) maps WCS (drawing units) to the frame (metres),
    ``[x_m, y_m, 1] = T @ [x_wcs, y_wcs, 1]``; ``angle_deg`` is angle AOB; ``mirrored`` when B is
    clockwise from A in the WCS (T is then a reflection); ``mark_d`` the diameters of O, A, B (m)."""

    T: np.ndarray
    angle_deg: float
    mirrored: bool
    mark_d: dict[str, float]

    def to_drawing(self, xy_units: np.ndarray) -> np.ndarray:
        """(N, 2) WCS points (drawing units) -> (N, 2) drawing frame (m)."""
        return xy_units @ self.T[:2, :2].T + self.T[:2, 2]


def drawing_frame(path: Path, cs: CircleSet, marks_idx: dict[str, int], options: LayoutOptions,
                  warns: list[str]) -> DrawingFrame:
    """The frame of the marks O, A, B (``marks_idx``: their circles in ``cs``); warns (into ``warns``)
    when AOB is not a right angle within ``options.perpendicular_tol_deg`` or the frame is mirrored.

    Raises:
        DrawingError: coincident or collinear marks.
    """
    s = cs.metres_per_unit
    O, A, B = (cs.centers_wcs[marks_idx[k]] * s for k in MARK_LETTERS)
    oa, ob = A - O, B - O
    d_oa, d_ob = float(np.hypot(*oa)), float(np.hypot(*ob))
    mark_d = {k: 2.0 * float(cs.radii[marks_idx[k]]) * s for k in MARK_LETTERS}
    for p, q, dist in (("O", "A", d_oa), ("O", "B", d_ob), ("A", "B", float(np.hypot(*(B - A))))):
        if dist <= max(mark_d[p], mark_d[q], options.duplicate_tol_m):
            raise DrawingError(f"{path}: marks coincident: {p} and {q} are {dist * 1e3:.3f} mm apart "
                               f"(mark diameter {max(mark_d[p], mark_d[q]) * 1e3:.1f} mm)")
    cross = oa[0] * ob[1] - oa[1] * ob[0]
    angle = math.degrees(math.atan2(abs(cross), float(oa @ ob)))
    if angle < options.collinear_tol_deg or angle > 180.0 - options.collinear_tol_deg:
        raise DrawingError(f"{path}: marks collinear: angle AOB is {angle:.2f} deg, O, A, B define no frame")
    mirrored = bool(cross < 0)
    ex = oa / d_oa
    ey = np.array([-ex[1], ex[0]]) * (-1.0 if mirrored else 1.0)
    R = np.stack([ex, ey])  # rows: drawing axes in WCS
    T = np.eye(3)
    T[:2, :2] = R * s
    T[:2, 2] = -R @ O
    if abs(angle - 90.0) > options.perpendicular_tol_deg:
        warns.append(f"{path.name}: marks not perpendicular: angle AOB is {angle:.2f} deg; x runs along OA, "
                     f"y perpendicular to it on B's side")
    if mirrored:
        warns.append(f"{path.name}: B is clockwise from A in the DXF: the drawing frame is mirrored relative to "
                     f"the DXF (drawn as seen from below?); check the mark labels")
    return DrawingFrame(T, angle, mirrored, mark_d)


def marks_in_frame(cs: CircleSet, marks_idx: dict[str, int], frame: DrawingFrame) -> dict[str, Mark]:
    """O, A, B and the reference marks (in ``marks_idx``'s order) in the drawing frame."""
    marks = {}
    for k, i in marks_idx.items():
        dx, dy = frame.to_drawing(cs.centers_wcs[i][None, :])[0]
        diameter = frame.mark_d[k] if k in frame.mark_d else 2.0 * float(cs.radii[i]) * cs.metres_per_unit
        marks[k] = Mark(k, float(dx), float(dy), float(cs.centers_wcs[i][0]), float(cs.centers_wcs[i][1]),
                        diameter, cs.layers[i])
    return marks
