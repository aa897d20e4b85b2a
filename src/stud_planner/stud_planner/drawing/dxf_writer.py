"""Write stud-layout drawings (DXF) the way civil engineers' CAD programs do.

Used by the tests and by ``tools/make_demo_drawings.py``. Input is in the ``drawing`` frame
(metres, origin at O, x toward A, y toward B); the writer places that frame in the DXF's WCS
with ``origin_wcs_m`` / ``rotation_deg`` (and ``mirror_frame``), converts to ``units``, and
draws the studs as circles, optionally as INSERTs of a block (rotated, scaled, mirrored,
nested) or as circles with extrusion (0, 0, -1), as mirrored drawings contain them. How it draws is one
frozen configuration, :class:`LayoutDxfOptions` (changed with :meth:`LayoutDxfOptions.with_changes`, as
the reader's :class:`~stud_planner.drawing.LayoutOptions` is).

:func:`stud_planner.drawing.layout.read_layout` on the written file gives back the input
(to float precision), which is what the round-trip tests check.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import ezdxf
import numpy as np
from ezdxf.math import OCS

from stud_planner.drawing.units import units_to_metres

__all__ = ["LayoutDxfOptions", "write_layout_dxf", "write_scene_drawing"]

_FLIP = (0.0, 0.0, -1.0)


def _rot(deg: float) -> np.ndarray:
    a = math.radians(deg)
    return np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])


@dataclass(frozen=True)
class LayoutDxfOptions:
    """How :func:`write_layout_dxf` draws a layout, by concern.

    The file:
        dxfversion: "R12", "R2000", ... "R2018" (R12 files carry no units: coordinates are in ``units`` all the same).
        units: "mm", "cm", "m", "in", "ft", ... or "unitless" ($INSUNITS 0, coordinates in ``unitless_as``).
        unitless_as: the unit of the coordinates when ``units`` is "unitless".
        binary: write binary DXF.

    The drawing frame's place in the WCS:
        origin_wcs_m: where the drawing frame's origin sits in the WCS (metres).
        rotation_deg: the drawing frame's rotation in the WCS (degrees, counter-clockwise).
        mirror_frame: flip the WCS y axis, so B ends up clockwise from A.

    The studs:
        stud_diameter_m: one diameter for all studs or one per stud (m).
        stud_layer: one layer for all studs or one per stud.

    The marks and their labels:
        mark_diameter_m: the diameter of every mark circle (m).
        mark_layer: the layer of the mark circles.
        labels: write TEXT (``label_kind="text"``) or MTEXT (``"mtext"``, R2000+) labels O/A/B (M1, ...) by the marks.
        label_layer: the layer of those labels.
        label_kind: "text" or "mtext".

    The entities' form (what mirrored and block-based drawings contain):
        as_blocks: studs as INSERTs of block ``STUD`` (a circle of diameter ``1 / block_scale``
            on layer 0, off the block origin, with a non-zero base point).
        block_rotation_deg: the INSERTs' rotation (degrees).
        block_scale: the INSERTs' scale is ``block_scale x stud diameter``.
        mirror_blocks: INSERTs with a negative x scale.
        nested_blocks: wrap ``STUD`` in a block ``STUD_GROUP`` that inserts it rotated by 30 deg at scale 0.5.
        ocs_flip: plain circles (and INSERTs) written with extrusion (0, 0, -1), OCS coordinates.
    """

    dxfversion: str = "R2010"
    units: str = "mm"
    unitless_as: str = "mm"
    binary: bool = False
    origin_wcs_m: Sequence[float] = (0.0, 0.0)
    rotation_deg: float = 0.0
    mirror_frame: bool = False
    stud_diameter_m: float | Sequence[float] = 0.019
    stud_layer: str | Sequence[str] = "STUDS"
    mark_diameter_m: float = 0.03
    mark_layer: str = "MARKS"
    labels: bool = True
    label_layer: str = "TEXT"
    label_kind: str = "text"
    as_blocks: bool = False
    block_rotation_deg: float = 0.0
    block_scale: float = 1.0
    mirror_blocks: bool = False
    nested_blocks: bool = False
    ocs_flip: bool = False

    def __post_init__(self) -> None:
        # sequences (lists, arrays) are kept as tuples: the options stay immutable (and comparable)
        object.__setattr__(self, "origin_wcs_m", tuple(float(v) for v in self.origin_wcs_m))
        if not isinstance(self.stud_diameter_m, (int, float)):
            object.__setattr__(self, "stud_diameter_m",
                               tuple(float(v) for v in np.ravel(np.asarray(self.stud_diameter_m, dtype=np.float64))))
        if not isinstance(self.stud_layer, str):
            object.__setattr__(self, "stud_layer", tuple(self.stud_layer))

    def with_changes(self, **changes: Any) -> "LayoutDxfOptions":
        """A copy with ``changes`` (field name -> value; an unknown name is a TypeError)."""
        return dataclasses.replace(self, **changes)


def write_layout_dxf(
    path: str | Path,
    studs_xy_m: np.ndarray | Sequence[Sequence[float]],
    marks_xy_m: Mapping[str, Sequence[float]],
    options: LayoutDxfOptions | None = None,
) -> Path:
    """Write a DXF with stud circles, the three marks O, A, B and any reference marks; return the path.

    Args:
        path: the DXF file to write (its folder is created).
        studs_xy_m: (N, 2) stud centres, drawing frame, metres.
        marks_xy_m: {"O": (x, y), "A": ..., "B": ...}, drawing frame, metres; further entries
            (``"M1": (x, y)``, ...) are reference marks, drawn on the mark layer like O, A, B.
        options: how to draw them (:class:`LayoutDxfOptions`; None: its defaults, a labelled R2010 mm drawing
            of 19 mm studs and 30 mm marks).
    """
    o = options or LayoutDxfOptions()
    path = Path(path)
    studs = np.asarray(studs_xy_m, dtype=np.float64).reshape(-1, 2)
    n = studs.shape[0]
    unitless = o.units == "unitless"
    insunits, _, scale = (0, "", units_to_metres(o.unitless_as)[2]) if unitless else units_to_metres(o.units)
    k = 1.0 / scale  # drawing units per metre
    diam = np.broadcast_to(np.asarray(o.stud_diameter_m, dtype=np.float64), (n,))
    layers = [o.stud_layer] * n if isinstance(o.stud_layer, str) else list(o.stud_layer)
    if len(layers) != n:
        raise ValueError(f"stud_layer: {len(layers)} layers for {n} studs")
    to_wcs = _frame_to_wcs(o.origin_wcs_m, o.rotation_deg, o.mirror_frame, k)
    doc = _new_document(o.dxfversion, insunits, layers, o.mark_layer, o.label_layer)
    msp = doc.modelspace()
    stud_wcs = to_wcs(studs)
    if not o.as_blocks:
        for p, r, lay in zip(stud_wcs, diam * k / 2.0, layers):
            _add_circle(msp, p, r, lay, o.ocs_flip)
    else:
        block = _stud_block(doc, o.block_scale, o.nested_blocks)
        _add_stud_inserts(msp, block, stud_wcs, diam * k, layers, o.block_rotation_deg, o.block_scale,
                          o.mirror_blocks, o.ocs_flip)
    _add_marks(msp, marks_xy_m, to_wcs, o.mark_diameter_m * k / 2.0, o.mark_layer, o.ocs_flip,
               o.label_layer if o.labels else None, o.label_kind)
    path.parent.mkdir(parents=True, exist_ok=True)
    doc.saveas(path, fmt="bin" if o.binary else "asc")
    return path


def _add_marks(msp, marks_xy_m: Mapping[str, Sequence[float]], to_wcs, mark_r: float, mark_layer: str,
               ocs_flip: bool, label_layer: str | None, label_kind: str) -> None:
    """The marks O, A, B and any reference marks (M1, ...), labelled on ``label_layer`` unless None."""
    missing = [name for name in ("O", "A", "B") if name not in marks_xy_m]
    if missing:
        raise ValueError(f"marks_xy_m lacks {', '.join(missing)}")
    for name in ("O", "A", "B", *(m for m in marks_xy_m if m not in ("O", "A", "B"))):
        p = to_wcs(marks_xy_m[name])[0]
        _add_circle(msp, p, mark_r, mark_layer, ocs_flip)
        if label_layer is not None:
            _add_label(msp, name, p, mark_r, label_layer, label_kind)


def _frame_to_wcs(origin_wcs_m: Sequence[float], rotation_deg: float, mirror_frame: bool, k: float):
    """drawing frame (m) -> WCS (drawing units, ``k`` per metre), as a function of (N, 2) points."""
    M = _rot(rotation_deg) @ (np.diag([1.0, -1.0]) if mirror_frame else np.eye(2))
    t = np.asarray(origin_wcs_m, dtype=np.float64)

    def to_wcs(xy_m: np.ndarray) -> np.ndarray:
        return (np.asarray(xy_m, dtype=np.float64).reshape(-1, 2) @ M.T + t) * k

    return to_wcs


def _new_document(dxfversion: str, insunits: int, stud_layers: list[str], mark_layer: str, label_layer: str):
    doc = ezdxf.new(dxfversion, setup=False)
    if doc.dxfversion != "AC1009":  # R12 has no $INSUNITS: R12 drawings are always unitless
        doc.header["$INSUNITS"] = insunits
        doc.header["$MEASUREMENT"] = 0 if insunits in (1, 2, 3, 8, 9, 10, 21, 22, 23, 24) else 1
    for name, color in ((mark_layer, 1), (label_layer, 7)):
        if name not in doc.layers:
            doc.layers.add(name, color=color)
    for name in dict.fromkeys(stud_layers):
        if name not in doc.layers:
            doc.layers.add(name, color=3)
    return doc


def _add_circle(layout, center_wcs, radius: float, layer: str, ocs_flip: bool) -> None:
    c = (float(center_wcs[0]), float(center_wcs[1]), 0.0)
    if ocs_flip:
        layout.add_circle(OCS(_FLIP).from_wcs(c), radius, dxfattribs={"layer": layer, "extrusion": _FLIP})
    else:
        layout.add_circle(c, radius, dxfattribs={"layer": layer})


def _add_label(msp, name: str, mark_wcs: np.ndarray, mark_r: float, layer: str, kind: str) -> None:
    h = 2.0 * mark_r
    pos = (float(mark_wcs[0] + 1.2 * mark_r), float(mark_wcs[1] + 1.2 * mark_r), 0.0)
    if kind == "mtext":
        msp.add_mtext(name, dxfattribs={"layer": layer, "insert": pos, "char_height": h})
    else:
        msp.add_text(name, height=h, dxfattribs={"layer": layer, "insert": pos})


def _stud_block(doc, block_scale: float, nested_blocks: bool) -> tuple[str, np.ndarray, float]:
    """Block STUD: a circle of diameter ``1 / block_scale`` at an offset, base point elsewhere (both
    exercise the transform), optionally inside STUD_GROUP. Returns (block to insert, local position
    of the circle centre in it, the block's length scale)."""
    offset, base = np.array([3.0, -2.0]), np.array([1.0, 1.0])
    stud_block = doc.blocks.new("STUD", base_point=(*base, 0.0))
    stud_block.add_circle((*offset, 0.0), 0.5 / block_scale, dxfattribs={"layer": "0"})
    if not nested_blocks:
        return "STUD", offset - base, 1.0
    group = doc.blocks.new("STUD_GROUP", base_point=(0.0, 0.0, 0.0))
    inner_ins, inner_rot, inner_scale = np.array([10.0, 5.0]), 30.0, 0.5
    group.add_blockref("STUD", (*inner_ins, 0.0), dxfattribs={
        "layer": "0", "rotation": inner_rot, "xscale": inner_scale, "yscale": inner_scale})
    return "STUD_GROUP", inner_ins + _rot(inner_rot) @ (inner_scale * (offset - base)), inner_scale


def _add_stud_inserts(msp, block: tuple[str, np.ndarray, float], stud_wcs: np.ndarray, diam_units: np.ndarray,
                      layers: list[str], rotation_deg: float, block_scale: float, mirror: bool, ocs_flip: bool) -> None:
    """One INSERT of ``block`` (:func:`_stud_block`) per stud, its circle landing on the stud."""
    block_name, local, unit_scale = block
    sx = -1.0 if mirror else 1.0
    for p, d_units, lay in zip(stud_wcs, diam_units, layers):
        s = block_scale * d_units / unit_scale  # block circle (1 / block_scale) * unit_scale -> d_units
        A = _rot(rotation_deg) @ np.diag([sx * s, s])
        ins = p - A @ local
        attribs = {"layer": lay, "rotation": rotation_deg, "xscale": sx * s, "yscale": s, "zscale": s}
        if ocs_flip:
            # INSERT in the OCS of extrusion -Z (OCS x = -WCS x): WCS = F (ins_ocs + A local)
            attribs["extrusion"] = _FLIP
            ins_ocs = np.array([-p[0], p[1]]) - A @ local
            msp.add_blockref(block_name, (*ins_ocs, 0.0), dxfattribs=attribs)
        else:
            msp.add_blockref(block_name, (*ins, 0.0), dxfattribs=attribs)


def write_scene_drawing(
    path: str | Path, studs_xy_m: np.ndarray | Sequence[Sequence[float]], marks: Mapping[str, Sequence[float]],
    options: LayoutDxfOptions | None = None,
) -> Path:
    """Hook for demo scenes: studs and marks O/A/B (drawing frame, m) as :func:`write_layout_dxf` draws them
    with ``options`` (None: a labelled R2010 mm drawing of 19 mm studs and 30 mm marks)."""
    return write_layout_dxf(path, studs_xy_m, marks, options)
