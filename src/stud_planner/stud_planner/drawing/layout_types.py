"""The drawing reader's result types: studs, marks, the layout (drawing frame, metres), the raw
circle set, and the one error a drawing that cannot be used raises."""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from stud_common.rotations import float3


class DrawingError(Exception):
    """A drawing that cannot be used; the message names the file and the problem (one line)."""


def one_line(text: object) -> str:
    """``text`` with its whitespace runs (newlines too) folded to single spaces: for one-line errors."""
    return " ".join(str(text).split())


def _float4(values) -> tuple[float, float, float, float]:
    a, b, c, d = (float(v) for v in values)
    return a, b, c, d


# -- result types ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class Stud:
    """One stud: centre in the ``drawing`` frame (metres), drawn circle diameter (m), DXF layer."""

    id: str
    x_m: float
    y_m: float
    diameter_m: float
    layer: str


@dataclass(frozen=True)
class Mark:
    """Mark ``name`` (O, A, B, or a reference mark M1, M2, ...): centre in the ``drawing`` frame (m) and
    in DXF WCS (drawing units)."""

    name: str
    x_m: float
    y_m: float
    wcs_x: float
    wcs_y: float
    diameter_m: float
    layer: str


@dataclass(frozen=True)
class DrawingLayout:
    """A stud layout in the ``drawing`` frame (origin O, x toward A, y toward B; metres).

    ``wcs_to_drawing`` is the 3x3 homogeneous map ``[x_m, y_m, 1] = T @ [x_wcs, y_wcs, 1]`` from
    DXF WCS (drawing units) to the drawing frame (metres): unit scale times a rigid motion
    (a reflection too when ``mirrored``). ``bbox_m`` is (xmin, ymin, xmax, ymax) of the stud
    centres in the drawing frame. ``studs`` are in id order (module docstring).
    ``reference_marks``: the marks M1, M2, ... painted along a long part beside O, A, B (circles
    on the mark layer labelled like O, A, B), in label order (M1, M2, ..., M10).
    """

    source_file: str
    dxf_version: str          # $ACADVER, e.g. "AC1024"
    dxf_release: str          # e.g. "R2010"
    read_mode: str            # "read" (ezdxf.readfile) or "recover" (ezdxf.recover.readfile)
    source_units: str         # $INSUNITS name ("mm", "in", ...), or the assumed unit if unitless
    insunits: int             # $INSUNITS code as found (0 = unitless or absent)
    units_assumed: bool       # True when the drawing is unitless and units_if_unitless was used
    metres_per_unit: float
    studs: tuple[Stud, ...]
    mark_o: Mark
    mark_a: Mark
    mark_b: Mark
    mark_diameter_m: float    # mean of the three mark diameters
    marks_rule: str           # "labels" or "geometry"
    angle_aob_deg: float
    mirrored: bool
    wcs_to_drawing: tuple[tuple[float, float, float], ...]
    bbox_m: tuple[float, float, float, float]
    stud_layers: tuple[str, ...]  # layers the studs came from (as spelled in the file)
    warnings: list[str] = field(default_factory=list)
    #: circles left out for non-finite or out-of-range values, one line each (handle, layer, values)
    invalid_entities: tuple[str, ...] = ()
    reference_marks: tuple[Mark, ...] = ()

    @property
    def marks(self) -> dict[str, Mark]:
        return {"O": self.mark_o, "A": self.mark_a, "B": self.mark_b}

    def marks_xy_m(self) -> np.ndarray:
        """(3, 2) float64 marks O, A, B, drawing frame, metres."""
        return np.array([(m.x_m, m.y_m) for m in (self.mark_o, self.mark_a, self.mark_b)], dtype=np.float64)

    def reference_marks_xy_m(self) -> dict[str, tuple[float, float]]:
        """The reference marks: label -> drawing (x, y), metres, in label order ({} without any)."""
        return {m.name: (m.x_m, m.y_m) for m in self.reference_marks}

    def studs_xy_m(self) -> np.ndarray:
        """(N, 2) float64 stud centres, drawing frame, metres, id order."""
        n = len(self.studs)
        xy = np.empty((n, 2), dtype=np.float64)  # column by column: a list of N tuples costs 10x more
        xy[:, 0] = np.fromiter((s.x_m for s in self.studs), np.float64, n)
        xy[:, 1] = np.fromiter((s.y_m for s in self.studs), np.float64, n)
        return xy

    def drawing_to_wcs(self, xy_m: np.ndarray) -> np.ndarray:
        """(N, 2) drawing-frame metres -> (N, 2) DXF WCS in drawing units."""
        T = np.linalg.inv(np.array(self.wcs_to_drawing))
        xy = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
        return xy @ T[:2, :2].T + T[:2, 2]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (lengths in metres unless the key says otherwise)."""
        return {
            "source_file": self.source_file,
            "dxf_version": self.dxf_version,
            "dxf_release": self.dxf_release,
            "read_mode": self.read_mode,
            "source_units": self.source_units,
            "insunits": self.insunits,
            "units_assumed": self.units_assumed,
            "metres_per_unit": self.metres_per_unit,
            "frame_id": "drawing",
            "marks_rule": self.marks_rule,
            "angle_aob_deg": self.angle_aob_deg,
            "mirrored": self.mirrored,
            "mark_diameter_m": self.mark_diameter_m,
            "marks": {k: _mark_dict(m) for k, m in self.marks.items()},
            "wcs_to_drawing": [list(r) for r in self.wcs_to_drawing],
            "bbox_m": list(self.bbox_m),
            "stud_layers": list(self.stud_layers),
            "studs": [
                {"id": s.id, "x_m": s.x_m, "y_m": s.y_m, "diameter_m": s.diameter_m, "layer": s.layer}
                for s in self.studs
            ],
            "warnings": list(self.warnings),
            "invalid_entities": list(self.invalid_entities),
            "reference_marks": [_mark_dict(m) for m in self.reference_marks],
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "DrawingLayout":
        """Inverse of :meth:`to_dict`."""
        marks = {k: Mark(name=k, **{f: v for f, v in m.items() if f != "name"}) for k, m in d["marks"].items()}
        return cls(
            source_file=d["source_file"], dxf_version=d["dxf_version"], dxf_release=d["dxf_release"],
            read_mode=d["read_mode"], source_units=d["source_units"], insunits=int(d["insunits"]),
            units_assumed=bool(d["units_assumed"]), metres_per_unit=float(d["metres_per_unit"]),
            studs=tuple(Stud(**s) for s in d["studs"]),
            mark_o=marks["O"], mark_a=marks["A"], mark_b=marks["B"],
            mark_diameter_m=float(d["mark_diameter_m"]), marks_rule=d["marks_rule"],
            angle_aob_deg=float(d["angle_aob_deg"]), mirrored=bool(d["mirrored"]),
            wcs_to_drawing=tuple(float3(r) for r in d["wcs_to_drawing"]),
            bbox_m=_float4(d["bbox_m"]), stud_layers=tuple(d["stud_layers"]),
            warnings=list(d["warnings"]), invalid_entities=tuple(d.get("invalid_entities", ())),
            reference_marks=tuple(Mark(**m) for m in d.get("reference_marks", ())),
        )


def _mark_dict(m: Mark) -> dict[str, Any]:
    return {"name": m.name, "x_m": m.x_m, "y_m": m.y_m, "wcs_x": m.wcs_x, "wcs_y": m.wcs_y,
            "diameter_m": m.diameter_m, "layer": m.layer}


@dataclass(frozen=True, eq=False)
class CircleSet:
    """All usable circles of a drawing's modelspace, INSERTs expanded, in DXF WCS (drawing units).

    ``centers_wcs`` (N, 2) and ``radii`` (N,) are in drawing units; ``layers`` the effective
    layer of each circle. ``layer_entities`` counts modelspace entities per layer (direct, not
    expanded); ``skipped`` counts circles left out by reason (``"radius<=0"``,
    ``"non-uniform scale"``, ``"not parallel to XY"``, ``"invisible"``, ``"frozen or off layer"``,
    ``"non-finite or out of range"``), and ``invalid_entities`` names the last ones.
    """

    source_file: str
    dxf_version: str
    read_mode: str
    insunits: int
    source_units: str
    metres_per_unit: float
    units_assumed: bool
    centers_wcs: np.ndarray
    radii: np.ndarray
    layers: tuple[str, ...]
    labels: tuple[tuple[str, float, float], ...]  # (label O/A/B or M1, M2, ..., x, y) in WCS
    layer_entities: dict[str, int]
    skipped: dict[str, int]
    warnings: list[str]
    invalid_entities: tuple[str, ...] = ()  # circles left out for non-finite/out-of-range values (handle, layer)

    def __len__(self) -> int:
        return int(self.radii.shape[0])

    def skipped_summary(self) -> str:
        """``"; skipped while reading: 5 circles (non-uniform scale)"`` or "" -- for an error that
        would otherwise hide why the circles a user expected are not there."""
        parts = [f"{n} circle{'s' if n != 1 else ''} ({why})" for why, n in self.skipped.items() if n]
        return "; skipped while reading: " + ", ".join(parts) if parts else ""

    def layer_summary(self, limit: int = 30) -> str:
        """``"0 (12 entities, 3 circles), WALLS (40 entities)"``: layers that hold anything."""
        circles = Counter(self.layers)
        names = sorted(set(self.layer_entities) | set(circles), key=str.casefold)
        if not names:
            return "none (modelspace is empty)"
        parts = []
        for name in names[:limit]:
            n_ent, n_circ = self.layer_entities.get(name, 0), circles.get(name, 0)
            text = f"{name} ({n_ent} entities"
            text += f", {n_circ} circles)" if n_circ else ")"
            parts.append(text)
        if len(names) > limit:
            parts.append(f"... (+{len(names) - limit} more)")
        return ", ".join(parts)
