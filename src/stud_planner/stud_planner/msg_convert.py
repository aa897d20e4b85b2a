"""stud_planner's message <-> core conversions (one place, so nodes stay thin).

Image/CameraInfo conversions are stud_perception.image_io's, poses stud_common.ros_io's; this module
handles our own interfaces: layouts, registrations, weld targets (a WeldTargetArray as a TargetTable;
the other way, the hot path, is target_cdr) and inspection results.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from geometry_msgs.msg import Point, Pose, PoseArray, Quaternion
from stud_welding_msgs.msg import Registration, Stud, StudLayout, WeldTargetArray

from stud_perception.registration import layout_marks_m, layout_reference_marks_m
from stud_planner import drawing
from stud_planner.matching.target_cdr import WELD_TARGET_BLOCK
from stud_planner.matching.target_table import TargetTable, centre_offset


def layout_to_msg(layout: drawing.DrawingLayout, stamp=None) -> StudLayout:
    """A DrawingLayout -> StudLayout message (frame ``drawing``, metres), stamped ``stamp`` when given."""
    msg = StudLayout()
    if stamp is not None:
        msg.header.stamp = stamp
    msg.header.frame_id = "drawing"
    msg.source_file = layout.source_file
    msg.source_units = layout.source_units
    msg.mark_o = Point(x=layout.mark_o.x_m, y=layout.mark_o.y_m)
    msg.mark_a = Point(x=layout.mark_a.x_m, y=layout.mark_a.y_m)
    msg.mark_b = Point(x=layout.mark_b.x_m, y=layout.mark_b.y_m)
    msg.mark_diameter = float(layout.mark_diameter_m)
    msg.reference_mark_labels = [m.name for m in layout.reference_marks]
    msg.reference_marks = [Point(x=m.x_m, y=m.y_m) for m in layout.reference_marks]
    msg.studs = [Stud(id=s.id, x=s.x_m, y=s.y_m, diameter=s.diameter_m, layer=s.layer) for s in layout.studs]
    msg.warnings = list(layout.warnings)
    return msg


@dataclass(frozen=True)
class LayoutView:
    """What the matcher and the registration need of a StudLayout message (numpy, metres, drawing frame)."""

    ids: list[str]
    xy_m: np.ndarray          # (N, 2)
    marks_m: np.ndarray       # (3, 2) O, A, B
    mark_diameter_m: float
    source_file: str
    reference_marks_m: dict[str, np.ndarray] = field(default_factory=dict)  # label -> (2,), label order


def layout_from_msg(msg: StudLayout) -> LayoutView:
    """A StudLayout message -> :class:`LayoutView` (stud ids, centres (N, 2), marks; metres, drawing frame)."""
    return LayoutView(
        ids=[s.id for s in msg.studs],
        xy_m=np.array([(s.x, s.y) for s in msg.studs], dtype=np.float64).reshape(-1, 2),
        marks_m=layout_marks_m(msg),
        mark_diameter_m=float(msg.mark_diameter),
        source_file=msg.source_file,
        reference_marks_m=layout_reference_marks_m(msg),
    )


def layout_poses(msg: StudLayout) -> PoseArray:
    """The studs as a PoseArray in the `drawing` frame (for RViz / Foxglove)."""
    arr = PoseArray()
    arr.header = msg.header
    arr.poses = [Pose(position=Point(x=s.x, y=s.y), orientation=Quaternion(w=1.0)) for s in msg.studs]
    return arr


def registration_from_msg(msg: Registration) -> np.ndarray:
    """Registration message -> M_local2world (3, 3)."""
    return np.asarray(msg.m_local2world, dtype=np.float64).reshape(3, 3)


def weld_target_table(msg: WeldTargetArray, image: tuple[float, float, int, int] | None = None) -> TargetTable:
    """A WeldTargetArray's targets as a :class:`TargetTable` (fields by target_cdr's layout; an
    orientation sent as the identity for want of a normal stays the identity). ``image``: (cx, cy,
    width, height) of the camera the targets were matched with, for the centre offset that breaks
    :func:`choose_best`'s ties (None: unknown, NaN)."""
    targets = msg.targets
    n = len(targets)
    widths: dict[str, int] = {}
    for _field, _kind, column, k in WELD_TARGET_BLOCK:
        if k is not None:
            widths[column] = max(widths.get(column, 0), k + 1)
    columns: dict[str, np.ndarray] = {}
    for wire_name, kind, column, k in WELD_TARGET_BLOCK:
        path = wire_name.split(".")  # "pose.position.x": nested messages
        values = []
        for t in targets:
            value = t
            for name in path:
                value = getattr(value, name)
            values.append(value)
        if k is None:
            columns[column] = np.array(values, dtype=np.int64 if kind == "uint32" else np.float64).reshape(n)
        else:
            columns.setdefault(column, np.full((n, widths[column]), np.nan))[:, k] = values
    pixel_uv = columns["pixel_uv"]
    offset = np.full(n, np.nan) if image is None else centre_offset(pixel_uv, *image)
    return TargetTable(ids=[t.stud_id for t in targets], **columns,
                       status=np.array([t.status for t in targets], dtype=np.uint8).reshape(n),
                       reasons=np.array([t.reason for t in targets], dtype=object).reshape(n), centre_offset=offset)


def _finite_or_none(x: float, scale: float = 1.0) -> float | None:
    x = float(x)
    return x * scale if np.isfinite(x) else None


def _xyz(v) -> list[float]:
    return [float(v.x), float(v.y), float(v.z)]


def inspection_rows(result) -> list[dict]:
    """An ``InspectionResult`` message's studs as QA-record fields (qa_report rows' ``verdict``,
    ``reasons``, ``measured``), in the order of its studs."""
    rows = []
    for s in result.studs:
        measured = None
        if s.measured:
            measured = {"position_m": _xyz(s.base), "axis": _xyz(s.axis), "lean_deg": float(s.lean_deg),
                        "offset_mm": [float(s.offset_x_mm), float(s.offset_y_mm)], "height_mm": float(s.height_mm)}
            collar = (s.collar_seen_deg, s.collar_coverage_deg, s.collar_height_mm, s.collar_gap_deg,
                      s.collar_gap_azimuth_deg) if s.collar_measured else (None,) * 5
            measured.update(zip(("collar_seen_deg", "collar_coverage_deg", "collar_height_mm", "collar_gap_deg",
                                 "collar_gap_azimuth_deg"), (_finite_or_none(v) if v is not None else None
                                                             for v in collar)))
        rows.append({"verdict": s.verdict_text, "reasons": list(s.reasons), "measured": measured})
    return rows


def inspection_extras(result) -> tuple[list[dict], dict]:
    """An ``InspectionResult`` message's unexpected objects and the limits its studs were judged against."""
    unexpected = [{"position_m": _xyz(p), "height_mm": float(h)}
                  for p, h in zip(result.unexpected_objects, result.unexpected_heights_mm)]
    limits = {"max_lean_deg": result.max_lean_deg, "position_tol_mm": result.position_tol_mm,
              "nominal_length_mm": result.nominal_length_mm, "height_tol_mm": result.height_tol_mm,
              "height_tol_below_mm": result.height_tol_below_mm, "stud_diameter_mm": result.stud_diameter_mm,
              "min_collar_coverage_deg": result.min_collar_coverage_deg,
              "min_collar_height_mm": result.min_collar_height_mm, "min_collar_seen_deg": result.min_collar_seen_deg,
              "qa_code": result.qa_code}
    return unexpected, limits
