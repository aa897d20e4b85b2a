"""Read a stud layout from a 2D DXF drawing: stud circles plus the marks O, A, B.

Pure Python (ezdxf + numpy), no ROS: the layout node converts :class:`StudLayout` to
``stud_welding_msgs/StudLayout`` (field for field; lengths are already metres).

What is read
    * DXF R12 .. R2018 (and the pre-R12 files ezdxf accepts), ASCII or binary, via
      ``ezdxf.readfile``; a damaged file that only ``ezdxf.recover.readfile`` can read is
      used with a warning. A file that does not end in ``EOF`` (or a closed section) is
      *truncated* and refused: a partial entity list would silently drop studs.
    * Large drawings: the plain CIRCLE entities of an ASCII file's modelspace are read as
      arrays by :mod:`stud_planner.dxf_plain_circles` and ezdxf loads the rest of the file; the
      same rules apply to both and the result is identical (tested on the whole corpus), so a
      bridge's 250,000 studs take seconds, not ezdxf's minutes. ``read_circles(...,
      plain_circles=False)`` reads everything through ezdxf.
    * Modelspace only. INSERT (and MINSERT) block references are expanded recursively with
      their full transform (insertion point, block base point, rotation, non-uniform and
      negative scale, extrusion, nesting). Entities on layer ``0`` inside a block take the
      layer of the INSERT that places them (the DXF convention), so a ``STUD`` block drawn
      on layer 0 and inserted on ``STUDS`` yields studs on ``STUDS``.
    * ``Circle.dxf.center`` is in the entity's OCS: centres are taken to WCS with the
      arbitrary-axis algorithm, so circles with extrusion (0, 0, -1) (mirrored drawings)
      land where CAD shows them.

Decisions (each one is reported as a warning when it applies)
    * A circle that a block reference scales non-uniformly is an ellipse, not a stud
      circle: it is **skipped** (as ezdxf's own ``virtual_entities`` turns it into an ELLIPSE;
      taking its centre would hide a drawing error). Circles whose plane is not parallel to XY
      (tilted extrusion) are skipped likewise. Rounding-level differences (< 0.01 %) are not
      non-uniform.
    * ezdxf reports ``$INSUNITS`` 6 (metres) for a file without a HEADER section; such a file
      is treated as unitless, since it says nothing about its units.
    * Circles with radius <= 0 are skipped.
    * A circle with a non-finite (NaN, inf) or absurd coordinate or radius (beyond
      ``MAX_COORDINATE_M``, 1e8 m, in WCS -- 1e300 is not a position) is **left out with a
      warning naming its handle and layer** (``StudLayout.invalid_entities`` lists each one,
      ``plan`` repeats them as report warnings): it has no position to weld at. Left out rather
      than refused, like the other skips above, so that one broken entity of a 250,000-stud
      drawing does not stop the job; a mark left out is an error all the same (marks missing).
    * What CAD does not show is not part of the drawing: entities flagged invisible (group
      60) and entities on layers that are frozen or off are skipped (a frozen INSERT hides its
      whole block, an off one what inherits its layer), with a warning per layer;
      ``include_hidden_layers`` reads hidden layers all the same. An old revision's studs on a
      frozen ``STUDS_OLD`` must not be welded because a pattern ``STUDS*`` matches it.
    * A degenerate INSERT (zero scale, a transform that raises in ezdxf) is skipped; the rest
      of the drawing is kept.
    * Unitless drawings (``$INSUNITS`` 0 or absent) use ``units_if_unitless`` (default mm).

Marks (``marks_rule``)
    * ``"labels"``: each circle on the mark layer takes the letter of its nearest TEXT /
      MTEXT / ATTRIB whose text is ``O``, ``A`` or ``B`` (case-insensitive), if that label is
      within ``label_distance_factor`` mark diameters of the circle's centre. Used when each
      letter names exactly one circle.
    * ``"geometry"``: otherwise, with exactly three mark circles: O is the vertex whose angle
      is closest to 90 deg; A and B are then chosen so that OA x OB > 0 (B counter-clockwise
      from A, a right-handed frame).
    Concentric mark circles (centres within ``duplicate_tol_m``) count as one mark (the
    largest circle), so a target symbol drawn as two rings is one mark.

Drawing frame (INTERFACES.md, frame ``drawing``)
    Origin at O, x along OA, y perpendicular to x on B's side; metres. If the labels put B
    clockwise from A the frame is a reflection of the DXF's WCS (``mirrored=True``, warned:
    the drawing is probably seen from below); the coordinates are still "along OA" and
    "toward B". If angle AOB is not 90 deg (within ``perpendicular_tol_deg``) a warning
    gives the angle.

Stud order and ids
    Studs are sorted by (layer name, case-folded), then row (drawing y), then drawing x in the
    row, then diameter and the exact coordinates; a row holds the studs whose y differ by less
    than 0.1 mm (chained), and x within a row is compared the same way, so the float noise of a
    rotated or shifted placement never reorders studs. Ids are ``S0001``, ``S0002``,
    ... in that order (4 digits; all ids get 5 digits from 10 000 studs on, so that text order
    stays id order). The key depends only on the geometry, so ids do not change when a CAD
    program reorders entities in the file. Duplicates (centres within ``duplicate_tol_m``, any
    layer) keep the first stud in this order.

Warnings (``StudLayout.warnings``, one line each) and errors
    Warned: duplicates removed, stud pairs closer than ``min_spacing_m``, diameters far from
    the median, studs outside the marks' quadrant (x < 0 or y < 0), non-perpendicular or
    mirrored marks, assumed units, recovered files, and everything skipped above.
    Refused with :class:`DrawingError` (one line naming the file): missing file, not a DXF,
    truncated/corrupt file, no studs (listing the layers with entity and circle counts), marks
    missing or ambiguous (how many circles on which layer), collinear or coincident marks.
    The duplicate and spacing checks use a grid hash (:func:`close_pairs`), O(N) for sane
    spacing. Reading is linear in the number of studs: 250,000 in about 4 s on the project's
    2-core machine (``bench/bench_plan_scaling.py``).
"""
from __future__ import annotations

import fnmatch
import gc
import io
import math
import re
from collections import Counter
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Sequence

import ezdxf
import ezdxf.lldxf.const as dxfconst
import numpy as np
from ezdxf import recover

from .dxf_plain_circles import PlainCircles, split_plain_circles

__all__ = [
    "DrawingError",
    "Stud",
    "Mark",
    "StudLayout",
    "CircleSet",
    "read_layout",
    "read_circles",
    "collect_circles",
    "load_document",
    "close_pairs",
    "UNITS",
    "units_to_metres",
]


class DrawingError(Exception):
    """A drawing that cannot be used; the message names the file and the problem (one line)."""


# -- units -----------------------------------------------------------------------------------------
# $INSUNITS code -> (name, metres per drawing unit). Exact SI definitions (1 in = 25.4 mm).
UNITS: dict[int, tuple[str, float]] = {
    1: ("in", 0.0254),
    2: ("ft", 0.3048),
    3: ("mi", 1609.344),
    4: ("mm", 1e-3),
    5: ("cm", 1e-2),
    6: ("m", 1.0),
    7: ("km", 1e3),
    8: ("uin", 0.0254e-6),
    9: ("mil", 0.0254e-3),
    10: ("yd", 0.9144),
    11: ("angstrom", 1e-10),
    12: ("nm", 1e-9),
    13: ("um", 1e-6),
    14: ("dm", 0.1),
    15: ("dam", 10.0),
    16: ("hm", 100.0),
    17: ("Gm", 1e9),
    18: ("au", 149_597_870_700.0),
    19: ("ly", 9_460_730_472_580_800.0),
    20: ("pc", 3.0856775814913673e16),
    21: ("us_ft", 1200.0 / 3937.0),
    22: ("us_in", 100.0 / 3937.0),
    23: ("us_yd", 3600.0 / 3937.0),
    24: ("us_mi", 6_336_000.0 / 3937.0),
}
_UNIT_ALIASES = {
    "inch": "in", "inches": "in", '"': "in", "feet": "ft", "foot": "ft", "'": "ft",
    "millimeter": "mm", "millimetre": "mm", "millimeters": "mm", "millimetres": "mm",
    "centimeter": "cm", "centimetre": "cm", "meter": "m", "metre": "m", "meters": "m",
    "metres": "m", "µm": "um", "micron": "um", "microns": "um", "yard": "yd", "yards": "yd",
    "mile": "mi", "miles": "mi", "decimeter": "dm", "decimetre": "dm",
}
_UNIT_ALIASES = {k.casefold(): v for k, v in _UNIT_ALIASES.items()}  # "µm" folds to Greek mu
_UNIT_BY_NAME = {name.casefold(): (code, name, f) for code, (name, f) in UNITS.items()}


def units_to_metres(name_or_code: str | int) -> tuple[int, str, float]:
    """``"mm"`` / ``4`` -> ``(4, "mm", 0.001)``: $INSUNITS code, name, metres per unit."""
    if isinstance(name_or_code, (int, np.integer)) and not isinstance(name_or_code, bool):
        code = int(name_or_code)
        if code not in UNITS:
            raise ValueError(f"unsupported $INSUNITS code {code}")
        return (code, *UNITS[code])
    key = str(name_or_code).strip().casefold()
    key = _UNIT_ALIASES.get(key, key).casefold()
    if key not in _UNIT_BY_NAME:
        known = ", ".join(name for name, _ in UNITS.values())
        raise ValueError(f"unknown unit {name_or_code!r} (known: {known})")
    return _UNIT_BY_NAME[key]


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
    """Mark ``name`` (O, A or B): centre in the ``drawing`` frame (m) and in DXF WCS (drawing units)."""

    name: str
    x_m: float
    y_m: float
    wcs_x: float
    wcs_y: float
    diameter_m: float
    layer: str


@dataclass(frozen=True)
class StudLayout:
    """A stud layout in the ``drawing`` frame (origin O, x toward A, y toward B; metres).

    ``wcs_to_drawing`` is the 3x3 homogeneous map ``[x_m, y_m, 1] = T @ [x_wcs, y_wcs, 1]`` from
    DXF WCS (drawing units) to the drawing frame (metres): unit scale times a rigid motion
    (a reflection too when ``mirrored``). ``bbox_m`` is (xmin, ymin, xmax, ymax) of the stud
    centres in the drawing frame. ``studs`` are in id order (module docstring).
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

    @property
    def marks(self) -> dict[str, Mark]:
        return {"O": self.mark_o, "A": self.mark_a, "B": self.mark_b}

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
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "StudLayout":
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
            wcs_to_drawing=tuple(tuple(float(v) for v in r) for r in d["wcs_to_drawing"]),
            bbox_m=tuple(float(v) for v in d["bbox_m"]), stud_layers=tuple(d["stud_layers"]),
            warnings=list(d["warnings"]), invalid_entities=tuple(d.get("invalid_entities", ())),
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
    labels: tuple[tuple[str, float, float], ...]  # (letter O/A/B, x, y) in WCS
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


# -- reading the file ------------------------------------------------------------------------------
_BINARY_SENTINEL = b"AutoCAD Binary DXF\r\n\x1a\x00"
# Line ends: CR LF (DOS), LF (Unix) and a lone CR (classic Mac OS), all of which ezdxf reads.
_EOL = rb"(?:\r\n|\r|\n)"
_ASCII_EOF = re.compile(rb"(?:^|[\r\n])[ \t]*0[ \t]*" + _EOL + rb"[ \t]*EOF[ \t]*(?:[\r\n]|$)")
_ASCII_HEAD = re.compile(rb"^(?:\xef\xbb\xbf)?\s*(?:999\s*" + _EOL + rb"[^\r\n]*" + _EOL + rb"\s*)*0\s*" + _EOL
                         + rb"\s*SECTION\b")
_ASCII_TAIL_ENDSEC = re.compile(rb"[\r\n][ \t]*0[ \t]*" + _EOL + rb"[ \t]*ENDSEC\s*$")


def _one_line(text: object) -> str:
    return " ".join(str(text).split())


def _check_file(path: Path) -> tuple[bytes, list[str]]:
    """Raise DrawingError for a missing, empty, non-DXF or truncated file; return its bytes and warnings."""
    if not path.exists():
        raise DrawingError(f"{path}: file not found")
    if path.is_dir():
        raise DrawingError(f"{path}: is a directory, not a DXF file")
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise DrawingError(f"{path}: cannot read ({_one_line(exc.strerror or exc)})") from exc
    if not data.strip():
        raise DrawingError(f"{path}: empty file, not a DXF")
    if data.startswith(_BINARY_SENTINEL):
        if b"EOF\x00" not in data[-64:]:
            raise DrawingError(f"{path}: truncated or corrupt binary DXF (no EOF at the end of the file)")
        return data, []
    if re.match(rb"AC[0-9.]{4}", data[:6]):
        raise DrawingError(f"{path}: not a DXF file (this looks like a DWG; export it as DXF)")
    if not _ASCII_HEAD.match(data[:4096]):
        head = _one_line(data[:24].decode("latin-1"))[:24]
        raise DrawingError(f"{path}: not a DXF file (starts with {head!r}, expected '0 / SECTION')")
    if _ASCII_EOF.search(data, max(0, len(data) - 65536)) or _ASCII_EOF.search(data):  # the end first: 30 MB
        return data, []
    if not _ASCII_TAIL_ENDSEC.search(data[-256:]):
        raise DrawingError(f"{path}: truncated or corrupt DXF (the file ends inside a section, no EOF)")
    return data, [f"{path.name}: no EOF marker after the last section: the file may be incomplete"]


def load_document(path: str | Path) -> tuple[Any, str, list[str]]:
    """Open a DXF with ezdxf: ``(doc, read_mode, warnings)``; read_mode ``"read"`` or ``"recover"``.

    Raises DrawingError (one line, naming the file) for anything ezdxf cannot read.
    """
    path = Path(path)
    data, file_warns = _check_file(path)
    return _load_document(path, data, file_warns)


def _load_document(path: Path, data: bytes, file_warns: list[str]) -> tuple[Any, str, list[str]]:
    try:
        doc, mode, warns = ezdxf.readfile(path), "read", []
    except Exception as exc:  # ezdxf raises DXFStructureError, IOError, IndexError, struct.error ...
        first = f"{type(exc).__name__}: {_one_line(exc)}"
        if data.startswith(_BINARY_SENTINEL):  # ezdxf.recover reads ASCII only
            raise DrawingError(f"{path}: truncated or corrupt binary DXF ({first})") from exc
        try:
            doc, auditor = recover.readfile(path)
        except Exception as exc2:
            raise DrawingError(f"{path}: truncated or corrupt DXF, ezdxf cannot read or recover it "
                               f"({type(exc2).__name__}: {_one_line(exc2)})") from exc2
        mode = "recover"
        warns = [f"{path.name}: damaged DXF ({first}); read with ezdxf.recover ({len(auditor.errors)} errors, "
                 f"{len(auditor.fixes)} fixes): check the layout against the drawing"]
    _drop_default_insunits(doc, data)
    return doc, mode, file_warns + warns


def _drop_default_insunits(doc: Any, data: bytes) -> None:
    """ezdxf fills a missing HEADER with defaults ($INSUNITS 6 = metres): keep only what the file says."""
    end = data.find(b"ENTITIES")
    if b"$INSUNITS" not in data[: end if end > 0 else len(data)] and "$INSUNITS" in doc.header:
        del doc.header["$INSUNITS"]


def _load_with_plain_circles(path: Path, data: bytes) -> tuple[Any, PlainCircles | None]:
    """``(doc, circles)``: ezdxf's document of ``path`` without its plain modelspace circles, and
    those circles (:mod:`dxf_plain_circles`); ``(None, None)`` when that does not apply (binary
    file, no plain circles, any doubt) or ezdxf cannot read the rest: then ezdxf reads the file
    whole, as :func:`load_document` does, with its errors and its recovery."""
    if data.startswith(_BINARY_SENTINEL):
        return None, None
    try:
        from ezdxf.filemanagement import dxf_file_info
        from ezdxf.lldxf.validator import is_dxf_file

        if not is_dxf_file(str(path)):
            return None, None
        encoding = dxf_file_info(str(path)).encoding
        # what ezdxf.readfile reads: the file decoded as it detects, universal newlines
        text = io.TextIOWrapper(io.BytesIO(data), encoding=encoding, errors="surrogateescape", newline=None).read()
        split = split_plain_circles(text)
        if split is None:
            return None, None
        rest, plain = split
        del text, split
        doc = ezdxf.read(io.StringIO(rest))
        doc.filename = str(path)
    except Exception:  # whatever goes wrong here, the whole-file path gives the user's error
        return None, None
    # ezdxf's rule for an entity of the ENTITIES section (EntitySection._build): owned by
    # *Model_Space -> modelspace, by *Paper_Space -> paperspace, else its paperspace flag (67)
    keys = [None if br is None else br.dxf.handle
            for br in (doc.block_records.get("*Model_Space"), doc.block_records.get("*Paper_Space"))]
    in_paperspace = np.array([o != keys[0] and (o == keys[1] or flag != 0)
                              for o, flag in zip(plain.owners, plain.paperspace.tolist())], dtype=bool)
    if in_paperspace.any():
        plain = plain.without(in_paperspace)
    _drop_default_insunits(doc, data)
    return doc, plain


# -- collecting circles (with block expansion) -----------------------------------------------------
#: A circle whose centre coordinate or radius exceeds this (metres, in WCS), or is NaN/inf, is
#: left out as invalid. No projected coordinate system on Earth goes beyond 4e7 m (site and
#: survey coordinates of a geo-referenced drawing stay far below), while 1e300 or inf are what a
#: broken export or a corrupt file writes; such values would also overflow the frame arithmetic.
MAX_COORDINATE_M = 1e8
_LABEL_LETTERS = ("O", "A", "B")
_TEXT_CODES = re.compile(r"%%[uUoOkK]")
_MAX_NESTING = 32
# A transformed circle whose axes differ in length or squareness by more than this (relative),
# or whose plane tilts from XY by more than acos(1 - this) (0.8 deg), is an ellipse in plan view.
# Rounded scale factors in real files (1.000001) stay circles.
_SHAPE_TOL = 1e-4


@dataclass
class _Content:
    """Circles and labels of one container (block or modelspace) in its own coordinates.

    Circles: centre (n, 3), radius-scaled in-plane axes ``u``, ``v`` (n, 3); their images under
    a transform give the transformed circle (or ellipse). ``layers`` None = layer "0" in a block
    (inherits the INSERT's layer).
    """

    centers: np.ndarray
    u: np.ndarray
    v: np.ndarray
    layers: np.ndarray  # object array of str | None
    label_pos: np.ndarray  # (m, 3)
    label_letters: tuple[str, ...]
    nonpositive: Counter
    handles: np.ndarray  # object array: the circle's handle, or the modelspace INSERT's that places it

    @classmethod
    def empty(cls) -> "_Content":
        z = np.zeros((0, 3))
        return cls(z, z, z, np.empty(0, dtype=object), z, (), Counter(), np.empty(0, dtype=object))


def _matrix(m: Any) -> np.ndarray:
    """ezdxf Matrix44 -> (4, 4) numpy, row-vector convention (p' = [p, 1] @ M)."""
    return np.fromiter(iter(m), dtype=np.float64, count=16).reshape(4, 4)


def _apply(content: _Content, mats: np.ndarray, ins_layers: Sequence[str | None],
           ins_handles: Sequence[str | None]) -> _Content:
    """Place ``content`` with k transforms (k, 4, 4); entity layer None takes the INSERT's layer.
    Each placed circle is named by the handle of the INSERT that places it (the entity a CAD user selects)."""
    k, n = mats.shape[0], content.centers.shape[0]
    L, t = mats[:, :3, :3], mats[:, 3, :3]
    centers = (np.einsum("nj,kji->kni", content.centers, L) + t[:, None, :]).reshape(k * n, 3)
    u = np.einsum("nj,kji->kni", content.u, L).reshape(k * n, 3)
    v = np.einsum("nj,kji->kni", content.v, L).reshape(k * n, 3)
    inherit = np.array([None if (lay is None or lay == "0") else lay for lay in ins_layers], dtype=object)
    is_zero = np.array([lay is None for lay in content.layers], dtype=bool)
    layers = np.where(is_zero[None, :], inherit[:, None], content.layers[None, :]).reshape(k * n)
    m = content.label_pos.shape[0]
    label_pos = (np.einsum("nj,kji->kni", content.label_pos, L) + t[:, None, :]).reshape(k * m, 3)
    nonpos = Counter({lay: c * k for lay, c in content.nonpositive.items()})
    handles = np.repeat(np.array(list(ins_handles), dtype=object), n)
    return _Content(centers, u, v, layers.astype(object), label_pos, content.label_letters * k, nonpos, handles)


def _concat(parts: list[_Content]) -> _Content:
    parts = [p for p in parts if p.centers.shape[0] or p.label_pos.shape[0] or p.nonpositive]
    if not parts:
        return _Content.empty()
    if len(parts) == 1:
        return parts[0]
    nonpos: Counter = Counter()
    for p in parts:
        nonpos.update(p.nonpositive)
    return _Content(
        np.concatenate([p.centers for p in parts]), np.concatenate([p.u for p in parts]),
        np.concatenate([p.v for p in parts]), np.concatenate([p.layers for p in parts]),
        np.concatenate([p.label_pos for p in parts]), sum((p.label_letters for p in parts), ()), nonpos,
        np.concatenate([p.handles for p in parts]),
    )


def _label_letter(e: Any, dxftype: str) -> str | None:
    try:
        raw = e.dxf.text if dxftype in ("TEXT", "ATTRIB") else e.text
    except Exception:
        return None
    # A label is one letter, but MTEXT formatting codes may wrap it in a long raw string.
    if not raw or len(raw) > 4096:
        return None
    if dxftype == "MTEXT":
        raw = e.plain_text()
    text = _TEXT_CODES.sub("", raw).strip().upper()
    return text if text in _LABEL_LETTERS else None


def _label_position(e: Any, dxftype: str) -> tuple[float, float, float]:
    if dxftype == "MTEXT":
        return tuple(e.dxf.insert)  # MTEXT insert is WCS
    dxf = e.dxf
    p = dxf.insert
    if (dxf.get("halign", 0) or dxf.get("valign", 0)) and dxf.hasattr("align_point"):
        q = dxf.align_point
        p = (p + q) * 0.5 if dxf.get("halign", 0) in (3, 5) else q  # ALIGNED / FIT span both points
    return tuple(e.ocs().to_wcs(p))


class _Collector:
    """Walks modelspace and block definitions; caches each block's flattened content."""

    def __init__(self, doc: Any, include_hidden_layers: bool = False) -> None:
        self.doc = doc
        self.cache: dict[str, _Content] = {}
        self.skipped_inserts: Counter = Counter()
        self.layer_entities: Counter = Counter()
        # What CAD does not show is not part of the drawing: invisible entities (group 60) and
        # layers that are frozen or off are left out (and counted for a warning).
        self.hidden_layers: dict[str, str] = {}
        for lay in doc.layers if not include_hidden_layers else ():
            state = "frozen" if lay.is_frozen() else "off" if lay.is_off() else None
            if state:
                self.hidden_layers[lay.dxf.name.casefold()] = state
        self.invisible: Counter = Counter()  # entity type -> count
        self.on_hidden_layer: Counter = Counter()  # (layer, entity type) -> count

    def skip_insert(self, name: str, reason: str, count: int = 1) -> None:
        self.skipped_inserts[(name, reason)] += count

    def block_content(self, name: str, stack: tuple[str, ...]) -> tuple[_Content | None, str]:
        """Flattened content of block ``name`` (cached), or (None, why not)."""
        key = name.casefold()
        if key in self.cache:
            return self.cache[key], ""
        if key in stack:
            return None, "recursive block reference"
        if len(stack) >= _MAX_NESTING:
            return None, f"nesting deeper than {_MAX_NESTING}"
        block = self.doc.blocks.get(name)
        if block is None:
            return None, "block definition missing"
        content = self.scan(block, stack + (key,), in_block=True)
        self.cache[key] = content
        return content, ""

    def base_point(self, name: str) -> np.ndarray:
        block = self.doc.blocks.get(name)
        if block is None:
            return np.zeros(3)
        return np.array(tuple(block.block.dxf.get("base_point", (0.0, 0.0, 0.0))), dtype=np.float64)

    def _with_plain(self, own: _Content, plain: PlainCircles) -> _Content:
        """``own`` (a modelspace scan without CIRCLE entities) plus the plain circles, with the
        rules :meth:`scan` applies to a modelspace CIRCLE: counted on its layer, skipped when
        invisible, on a hidden layer, or of radius <= 0."""
        layers = np.array(plain.layers, dtype=object)
        names, counts = np.unique(layers, return_counts=True) if len(plain) else ((), ())
        for lay, c in zip(names, counts):
            self.layer_entities[lay] += int(c)
        if plain.invisible.any():
            self.invisible["CIRCLE"] += int(np.count_nonzero(plain.invisible))
        visible = ~plain.invisible
        state = {lay: self.hidden_layers.get(lay.casefold()) for lay in names}
        hidden = visible & np.array([bool(state[lay]) for lay in layers.tolist()], dtype=bool)
        for lay in set(layers[hidden].tolist()):
            self.on_hidden_layer[(lay, "CIRCLE")] += int(np.count_nonzero(hidden & (layers == lay)))
        take = visible & ~hidden
        r = plain.radius
        nonpositive = take & (r <= 0.0)
        for lay in set(layers[nonpositive].tolist()):
            own.nonpositive[lay] += int(np.count_nonzero(nonpositive & (layers == lay)))
        take &= ~nonpositive
        n = int(np.count_nonzero(take))
        u = np.zeros((n, 3))
        v = np.zeros((n, 3))
        u[:, 0] = r[take]
        v[:, 1] = r[take]
        handles = np.array(plain.handles, dtype=object)[take]
        return _concat([_Content(plain.centers[take], u, v, layers[take], np.zeros((0, 3)), (), Counter(), handles),
                        own])

    def scan(self, entities: Iterable[Any], stack: tuple[str, ...], in_block: bool,
             plain: PlainCircles | None = None) -> _Content:
        """Circles and labels of ``entities`` (INSERTs expanded). ``plain``: the modelspace's CIRCLE
        entities, read by :mod:`dxf_plain_circles` (``entities`` then holds no CIRCLE); they go
        through the same rules as the circles read here."""
        centers, us, vs, layers, lpos, letters, handles = [], [], [], [], [], [], []
        nonpos: Counter = Counter()
        # INSERTs per block name: common case (extrusion +Z, no MINSERT) as raw parameters,
        # turned into matrices in one numpy pass; the rest through ezdxf's Insert.matrix44().
        simple: dict[str, list[tuple]] = {}
        general: dict[str, list[tuple[np.ndarray, str | None, str | None]]] = {}
        for e in entities:
            t = e.dxftype()
            try:
                layer = e.dxf.layer
            except Exception:
                layer = "0"
            if not in_block:
                self.layer_entities[layer] += 1
            if t in ("CIRCLE", "TEXT", "MTEXT", "INSERT"):
                if e.dxf.get("invisible", 0):
                    self.invisible[t] += 1
                    continue
                # A frozen INSERT hides all of its block; an off one only what inherits its layer
                # (layer "0" inside), which is checked once layers are resolved.
                state = self.hidden_layers.get(layer.casefold())
                if state and (t != "INSERT" or state == "frozen") and not (in_block and layer == "0"):
                    self.on_hidden_layer[(layer, t)] += 1
                    continue
            eff_layer = None if (in_block and layer == "0") else layer
            if t == "CIRCLE":
                dxf = e.dxf
                r = float(dxf.radius)
                if r <= 0.0:  # NaN goes on, to be left out with the other non-finite values
                    nonpos[eff_layer] += 1
                    continue
                c = dxf.center
                ez = dxf.extrusion
                if ez.x == 0.0 and ez.y == 0.0 and ez.z > 0.0:
                    centers.append((c.x, c.y, c.z))
                    us.append((r, 0.0, 0.0))
                    vs.append((0.0, r, 0.0))
                else:  # OCS -> WCS (arbitrary axis algorithm), e.g. extrusion (0, 0, -1)
                    ocs = e.ocs()
                    centers.append(tuple(ocs.to_wcs(c)))
                    us.append(tuple(ocs.ux * r))
                    vs.append(tuple(ocs.uy * r))
                layers.append(eff_layer)
                handles.append(dxf.handle)
            elif t in ("TEXT", "MTEXT"):
                letter = _label_letter(e, t)
                if letter:
                    lpos.append(_label_position(e, t))
                    letters.append(letter)
            elif t == "INSERT":
                for attrib in getattr(e, "attribs", ()):
                    letter = _label_letter(attrib, "ATTRIB")
                    if letter:
                        lpos.append(_label_position(attrib, "ATTRIB"))
                        letters.append(letter)
                dxf = e.dxf
                name = dxf.get("name", "")
                try:
                    ez = dxf.extrusion
                    if e.mcount <= 1 and ez.x == 0.0 and ez.y == 0.0 and ez.z > 0.0:
                        p = dxf.insert
                        simple.setdefault(name, []).append((
                            p.x, p.y, p.z, dxf.xscale, dxf.yscale, dxf.zscale, dxf.rotation, eff_layer, dxf.handle))
                    else:
                        refs = list(e.multi_insert()) if e.mcount > 1 else [e]
                        for ref in refs:
                            general.setdefault(name, []).append((_matrix(ref.matrix44()), eff_layer, dxf.handle))
                except Exception as exc:  # e.g. ZeroDivisionError on a zero extrusion vector
                    self.skip_insert(name, f"transform failed ({type(exc).__name__})")
        z = np.zeros((0, 3))
        own = _Content(
            np.array(centers, dtype=np.float64).reshape(-1, 3), np.array(us, dtype=np.float64).reshape(-1, 3),
            np.array(vs, dtype=np.float64).reshape(-1, 3), np.array(layers, dtype=object),
            np.array(lpos, dtype=np.float64).reshape(-1, 3) if lpos else z, tuple(letters), nonpos,
            np.array(handles, dtype=object),
        )
        if plain is not None:
            own = self._with_plain(own, plain)
        parts = [own]
        for name in list(simple) + [n for n in general if n not in simple]:
            mats, ins_layers, ins_handles = [], [], []
            if name in simple:
                rows = simple[name]
                mats.append(_insert_matrices(np.array([r[:7] for r in rows], dtype=np.float64), self.base_point(name)))
                ins_layers += [r[7] for r in rows]
                ins_handles += [r[8] for r in rows]
            if name in general:
                mats.append(np.stack([m for m, _, _ in general[name]]))
                ins_layers += [lay for _, lay, _ in general[name]]
                ins_handles += [h for _, _, h in general[name]]
            M = np.concatenate(mats)
            # rows 0, 1 = images of the block's x and y axes; a zero z scale is harmless in 2D
            ok = np.all(np.isfinite(M), axis=(1, 2)) & (np.min(np.linalg.norm(M[:, :2, :3], axis=2), axis=1) > 1e-12)
            if not ok.all():
                self.skip_insert(name, "degenerate transform (zero scale)", int(np.count_nonzero(~ok)))
            if not ok.any():
                continue
            try:
                content, why = self.block_content(name, stack)
                if content is None:
                    self.skip_insert(name, why, int(np.count_nonzero(ok)))
                    continue
                parts.append(_apply(content, M[ok], [lay for lay, good in zip(ins_layers, ok) if good],
                                    [h for h, good in zip(ins_handles, ok) if good]))
            except Exception as exc:
                self.skip_insert(name, f"expansion failed ({type(exc).__name__}: {_one_line(exc)})",
                                 int(np.count_nonzero(ok)))
        return _concat(parts)


def _insert_matrices(params: np.ndarray, base: np.ndarray) -> np.ndarray:
    """(k, 4, 4) INSERT transforms (row-vector convention, as ezdxf's ``Insert.matrix44``) for
    extrusion +Z; ``params`` rows are (x, y, z, xscale, yscale, zscale, rotation_deg)."""
    k = params.shape[0]
    a = np.radians(params[:, 6])
    c, s = np.cos(a), np.sin(a)
    sx, sy, sz = params[:, 3], params[:, 4], params[:, 5]
    M = np.zeros((k, 4, 4))
    M[:, 0, 0], M[:, 0, 1] = sx * c, sx * s
    M[:, 1, 0], M[:, 1, 1] = -sy * s, sy * c
    M[:, 2, 2] = sz
    M[:, 3, :3] = params[:, :3] - np.einsum("j,kji->ki", base, M[:, :3, :3])
    M[:, 3, 3] = 1.0
    return M


def collect_circles(
    doc: Any,
    path: str | Path = "<document>",
    *,
    read_mode: str = "read",
    units_if_unitless: str = "mm",
    include_hidden_layers: bool = False,
    warnings: Sequence[str] = (),
    plain: PlainCircles | None = None,
) -> CircleSet:
    """All circles of ``doc``'s modelspace with INSERTs expanded, in WCS (drawing units).

    Also reads the units and the O/A/B labels; see the module docstring for what is skipped.
    ``plain``: the modelspace CIRCLE entities read by :mod:`dxf_plain_circles` and cut out of
    ``doc`` (what :func:`read_circles` does for a large file); the result is the same.
    """
    path = Path(path)
    warns = list(warnings)
    insunits = int(doc.header.get("$INSUNITS", 0) or 0)
    if insunits in UNITS:
        _, unit_name, scale = units_to_metres(insunits)
        assumed = False
    else:
        try:
            _, unit_name, scale = units_to_metres(units_if_unitless)
        except ValueError as exc:
            raise DrawingError(f"{path}: units_if_unitless: {exc}") from exc
        assumed = True
        what = "no $INSUNITS" if "$INSUNITS" not in doc.header else f"$INSUNITS {insunits} (unitless)"
        if insunits not in (0,):
            what = f"unsupported $INSUNITS code {insunits}"
        warns.append(f"{path.name}: {what}: coordinates taken as {unit_name} (units_if_unitless)")

    collector = _Collector(doc, include_hidden_layers)
    content = collector.scan(doc.modelspace(), (), in_block=False, plain=plain)

    layers = np.array(["0" if lay is None else lay for lay in content.layers], dtype=object)
    hidden_names = {lay for lay in set(layers.tolist()) if lay.casefold() in collector.hidden_layers}
    hidden = np.isin(layers, list(hidden_names))
    for lay in hidden_names:  # circles that inherit a hidden layer (layer "0" in a block)
        collector.on_hidden_layer[(lay, "CIRCLE")] += int(np.count_nonzero(layers == lay))
    u, v = content.u, content.v
    with np.errstate(over="ignore", invalid="ignore"):
        nu, nv = np.linalg.norm(u, axis=1), np.linalg.norm(v, axis=1)
        normal = np.cross(u, v)
        nn = np.linalg.norm(normal, axis=1)
    # Non-finite or absurd values (NaN, inf, 1e300: a corrupt file or a broken export) are no
    # position at all: such a circle is left out, named by handle and layer, never planned.
    limit = MAX_COORDINATE_M / scale
    with np.errstate(invalid="ignore"):
        usable = (np.all(np.isfinite(content.centers), axis=1) & np.all(np.isfinite(u), axis=1)
                  & np.all(np.isfinite(v), axis=1) & (np.max(np.abs(content.centers[:, :2]), axis=1, initial=0.0) <= limit)
                  & (np.maximum(nu, nv) <= limit))
    invalid = ~usable & ~hidden
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        uniform = (np.abs(nu - nv) <= _SHAPE_TOL * np.maximum(nu, nv)) & (
            np.abs(np.einsum("ij,ij->i", u, v)) <= _SHAPE_TOL * nu * nv
        )
        planar = np.abs(normal[:, 2]) >= (1.0 - _SHAPE_TOL) * nn
    shown = usable & (nu > 0) & ~hidden  # a hidden circle is counted once, as hidden
    ok = uniform & planar & shown
    radii = np.sqrt(nu * nv)  # equal to nu within _SHAPE_TOL for the circles kept
    skipped = {
        "radius<=0": int(sum(content.nonpositive.values())),
        "non-uniform scale": int(np.count_nonzero(~uniform & shown)),
        "not parallel to XY": int(np.count_nonzero(uniform & ~planar & shown)),
        "invisible": int(collector.invisible["CIRCLE"]),
        "frozen or off layer": int(sum(n for (_, t), n in collector.on_hidden_layer.items() if t == "CIRCLE")),
        "non-finite or out of range": int(np.count_nonzero(invalid)),
    }
    invalid_entities = tuple(
        f"handle {content.handles[k]} on layer {layers[k]}: centre ({content.centers[k, 0]:g}, "
        f"{content.centers[k, 1]:g}), radius {float(nu[k]):g} {unit_name}" for k in np.flatnonzero(invalid).tolist())
    if invalid_entities:
        warns.append(f"{path.name}: {len(invalid_entities)} circle{'s' if len(invalid_entities) != 1 else ''} with "
                     f"non-finite or out-of-range values (beyond {MAX_COORDINATE_M:g} m) left out: "
                     + "; ".join(invalid_entities[:5])
                     + (f"; ... (+{len(invalid_entities) - 5})" if len(invalid_entities) > 5 else ""))
    if skipped["radius<=0"]:
        on = sorted({"0" if k is None else k for k in content.nonpositive}, key=str.casefold)
        warns.append(f"{path.name}: {skipped['radius<=0']} circles with radius <= 0 skipped (layers: {', '.join(on)})")
    if skipped["non-uniform scale"]:
        on = sorted(set(layers[~uniform & shown]), key=str.casefold)
        warns.append(f"{path.name}: {skipped['non-uniform scale']} circles in non-uniformly scaled block references "
                     f"are ellipses and were skipped (layers: {', '.join(on)})")
    if skipped["not parallel to XY"]:
        on = sorted(set(layers[uniform & ~planar & shown]), key=str.casefold)
        warns.append(f"{path.name}: {skipped['not parallel to XY']} circles not parallel to the XY plane skipped "
                     f"(layers: {', '.join(on)})")
    if collector.invisible:
        what = ", ".join(f"{n} {t}" for t, n in sorted(collector.invisible.items()))
        warns.append(f"{path.name}: invisible entities (DXF group 60) skipped, as CAD does not show them: {what}")
    if collector.on_hidden_layer:
        per_layer: dict[str, Counter] = {}
        for (lay, t), n in collector.on_hidden_layer.items():
            per_layer.setdefault(lay, Counter())[t] += n
        what = "; ".join(f"{lay} ({collector.hidden_layers[lay.casefold()]}): "
                         + ", ".join(f"{n} {t}" for t, n in sorted(c.items()))
                         for lay, c in sorted(per_layer.items(), key=lambda kv: kv[0].casefold()))
        warns.append(f"{path.name}: entities on frozen or off layers skipped, as CAD does not show them: {what}")
    for (name, reason), count in sorted(collector.skipped_inserts.items()):
        times = f"{count} references" if count > 1 else "1 reference"
        warns.append(f"{path.name}: INSERT of block {name!r}: {reason}; {times} skipped, rest of the drawing kept")

    labels = tuple(
        (letter, float(p[0]), float(p[1])) for letter, p in zip(content.label_letters, content.label_pos)
    )
    return CircleSet(
        source_file=str(path), dxf_version=str(doc.dxfversion), read_mode=read_mode, insunits=insunits,
        source_units=unit_name, metres_per_unit=scale, units_assumed=assumed,
        centers_wcs=np.ascontiguousarray(content.centers[ok, :2]), radii=radii[ok],
        layers=tuple(layers[ok]), labels=labels, layer_entities=dict(collector.layer_entities),
        skipped=skipped, warnings=warns, invalid_entities=invalid_entities,
    )


def read_circles(path: str | Path, *, units_if_unitless: str = "mm", include_hidden_layers: bool = False,
                 plain_circles: bool = True) -> CircleSet:
    """Open ``path`` and return every usable circle (INSERTs expanded); no stud/mark logic.

    ``plain_circles``: read the modelspace's plain CIRCLE entities of an ASCII file with
    :mod:`dxf_plain_circles` (arrays, ~20x faster than ezdxf's objects: a 250,000-stud drawing
    in seconds) and the rest with ezdxf; False: everything with ezdxf. The result is the same."""
    path = Path(path)
    data, file_warns = _check_file(path)
    plain = None
    if plain_circles:
        doc, plain = _load_with_plain_circles(path, data)
    if plain is not None:
        mode, warns = "read", file_warns
    else:
        doc, mode, warns = _load_document(path, data, file_warns)
    try:
        return collect_circles(doc, path, read_mode=mode, units_if_unitless=units_if_unitless,
                               include_hidden_layers=include_hidden_layers, warnings=warns, plain=plain)
    except DrawingError:
        raise
    except Exception as exc:  # a file ezdxf loads but cannot walk: never a traceback for the user
        raise DrawingError(f"{path}: cannot interpret the drawing ({type(exc).__name__}: {_one_line(exc)})") from exc


# -- neighbour search (grid hash, O(N) for sane spacing) -------------------------------------------
class _TooDense(Exception):
    pass


def close_pairs(xy: np.ndarray, radius: float, max_candidates: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Index pairs (i < j) of points closer than ``radius``, and their distances.

    Grid hash with cell = radius: each point is compared with its own cell and four forward
    neighbours only. Raises _TooDense when more than ``max_candidates`` candidate pairs
    would be examined (e.g. a drawing in metres read as mm puts everything in one cell).
    """
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    n = xy.shape[0]
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0))
    if n < 2 or not radius > 0:
        return empty
    if max_candidates is None:
        max_candidates = 50 * n + 1_000_000
    lo = xy.min(axis=0)
    span = float(np.max(xy.max(axis=0) - lo))
    cell_size = max(radius, span / 1e8)  # keeps the cell keys inside int64
    cells = np.floor((xy - lo) / cell_size).astype(np.int64) + 1
    ny = int(cells[:, 1].max()) + 3
    key = cells[:, 0] * ny + cells[:, 1]
    order = np.argsort(key, kind="stable")
    skey = key[order]
    idx = np.arange(n)
    out_i, out_j, out_d = [], [], []
    for dx, dy in ((0, 0), (1, -1), (1, 0), (1, 1), (0, 1)):
        nkey = key + dx * ny + dy
        first = np.searchsorted(skey, nkey, "left")
        count = np.searchsorted(skey, nkey, "right") - first
        total = int(count.sum())
        if total > max_candidates:
            raise _TooDense(total)
        if total == 0:
            continue
        ii = np.repeat(idx, count)
        offsets = np.arange(total) - np.repeat(np.cumsum(count) - count, count)
        jj = order[np.repeat(first, count) + offsets]
        if dx == 0 and dy == 0:
            keep = ii < jj
            ii, jj = ii[keep], jj[keep]
        d = np.hypot(*(xy[ii] - xy[jj]).T)
        near = d < radius
        out_i.append(ii[near])
        out_j.append(jj[near])
        out_d.append(d[near])
    if not out_i:
        return empty
    i, j, d = np.concatenate(out_i), np.concatenate(out_j), np.concatenate(out_d)
    swap = i > j
    i[swap], j[swap] = j[swap], i[swap]
    return i, j, d


# -- marks and the frame ---------------------------------------------------------------------------
def _layer_matcher(patterns: str | Sequence[str]):
    pats = [patterns] if isinstance(patterns, str) else list(patterns)
    pats = [p.casefold() for p in pats if p]

    def match(layer: str) -> bool:
        lay = layer.casefold()
        # the exact name first: AutoCAD allows [ ] in layer names, which fnmatch reads as a class
        return any(lay == p or fnmatch.fnmatchcase(lay, p) for p in pats)

    return match, pats


def _fmt_pats(patterns: str | Sequence[str]) -> str:
    return ", ".join([patterns] if isinstance(patterns, str) else list(patterns))


def _merge_concentric(path: Path, idx: np.ndarray, xy: np.ndarray, r: np.ndarray, tol: float) -> np.ndarray:
    """Indices of mark circles with concentric duplicates merged (the largest circle is kept)."""
    if idx.size < 2:
        return idx
    order = idx[np.lexsort((xy[idx, 1], xy[idx, 0], -r[idx]))]  # largest first, then by position
    alive = np.ones(order.size, dtype=bool)
    try:
        i, j, _ = close_pairs(xy[order], tol)
    except _TooDense:
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


def _identify_marks(
    path: Path, cs: CircleSet, mark_layer: str | Sequence[str], dup_tol_units: float,
    label_distance_factor: float, collinear_tol_deg: float, right_angle_ambiguity_deg: float,
) -> tuple[dict[str, int], str, list[str], np.ndarray]:
    """Pick the O, A, B circles (indices into ``cs``).

    Returns (marks, rule, warnings, members): ``members`` are all mark-layer circles concentric
    with a chosen mark (the rings of a target symbol), which are never studs.
    """
    match, _ = _layer_matcher(mark_layer)
    xy, r = cs.centers_wcs, cs.radii
    hit = {lay: match(lay) for lay in set(cs.layers)}
    on_layer = np.array([k for k, lay in enumerate(cs.layers) if hit[lay]], dtype=np.int64)
    cand = _merge_concentric(path, on_layer, xy, r, dup_tol_units)
    where = f"on layer {_fmt_pats(mark_layer)}"
    warns: list[str] = []
    if cand.size < 3:
        raise DrawingError(
            f"{path}: marks missing: found {cand.size} mark circle{'s' if cand.size != 1 else ''} {where}, "
            f"need 3 (O, A, B){cs.skipped_summary()}; layers: {cs.layer_summary()}"
        )

    # Labels: each candidate circle takes the letter of its nearest O/A/B label within reach.
    by_letter: dict[str, list[int]] = {k: [] for k in _LABEL_LETTERS}
    if cs.labels:
        lab_xy = np.array([(x, y) for _, x, y in cs.labels])
        letters = [lt for lt, _, _ in cs.labels]
        for k in cand:
            d = np.hypot(*(lab_xy - xy[k]).T)
            j = int(np.argmin(d))
            if d[j] <= label_distance_factor * 2.0 * r[k]:
                by_letter[letters[j]].append(int(k))
    labelled = {lt: ks for lt, ks in by_letter.items() if ks}
    multi = {lt: ks for lt, ks in labelled.items() if len(ks) > 1}
    if multi:
        lt, ks = next(iter(multi.items()))
        raise DrawingError(f"{path}: marks ambiguous: label {lt!r} is nearest to {len(ks)} mark circles {where}")
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
    marks = {"O": int(cand[o]), "A": int(cand[a]), "B": int(cand[b])}
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
) -> StudLayout:
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

    Raises:
        DrawingError: one line naming the file and the problem.
    """
    path = Path(path)
    with _bulk_allocation():
        cs = read_circles(path, units_if_unitless=units_if_unitless, include_hidden_layers=include_hidden_layers)
        try:
            return _build_layout(
                path, cs, stud_layers, mark_layer, min_diameter_m, max_diameter_m, min_spacing_m,
                duplicate_tol_m, diameter_outlier_ratio, label_distance_factor, perpendicular_tol_deg,
                collinear_tol_deg, right_angle_ambiguity_deg,
            )
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


def _build_layout(
    path: Path, cs: CircleSet, stud_layers, mark_layer, min_diameter_m, max_diameter_m, min_spacing_m,
    duplicate_tol_m, diameter_outlier_ratio, label_distance_factor, perpendicular_tol_deg,
    collinear_tol_deg, right_angle_ambiguity_deg,
) -> StudLayout:
    warns = list(cs.warnings)
    s = cs.metres_per_unit
    name = path.name
    stud_match, _ = _layer_matcher(stud_layers)
    hit = {lay: stud_match(lay) for lay in set(cs.layers)}  # a few layers, many circles
    is_stud = np.array([hit[lay] for lay in cs.layers], dtype=bool)
    if not is_stud.any():
        raise DrawingError(
            f"{path}: no studs found: no circles on layer(s) {_fmt_pats(stud_layers)}{cs.skipped_summary()}; "
            f"layers: {cs.layer_summary()}"
        )

    marks_idx, rule, mark_warns, mark_members = _identify_marks(
        path, cs, mark_layer, duplicate_tol_m / s, label_distance_factor, collinear_tol_deg,
        right_angle_ambiguity_deg,
    )
    warns += mark_warns

    # Frame: x along OA, y perpendicular on B's side; metres.
    O, A, B = (cs.centers_wcs[marks_idx[k]] * s for k in _LABEL_LETTERS)
    oa, ob = A - O, B - O
    d_oa, d_ob = float(np.hypot(*oa)), float(np.hypot(*ob))
    mark_d = {k: 2.0 * float(cs.radii[marks_idx[k]]) * s for k in _LABEL_LETTERS}
    for p, q, dist in (("O", "A", d_oa), ("O", "B", d_ob), ("A", "B", float(np.hypot(*(B - A))))):
        if dist <= max(mark_d[p], mark_d[q], duplicate_tol_m):
            raise DrawingError(f"{path}: marks coincident: {p} and {q} are {dist * 1e3:.3f} mm apart "
                               f"(mark diameter {max(mark_d[p], mark_d[q]) * 1e3:.1f} mm)")
    cross = oa[0] * ob[1] - oa[1] * ob[0]
    angle = math.degrees(math.atan2(abs(cross), float(oa @ ob)))
    if angle < collinear_tol_deg or angle > 180.0 - collinear_tol_deg:
        raise DrawingError(f"{path}: marks collinear: angle AOB is {angle:.2f} deg, O, A, B define no frame")
    mirrored = bool(cross < 0)
    ex = oa / d_oa
    ey = np.array([-ex[1], ex[0]]) * (-1.0 if mirrored else 1.0)
    R = np.stack([ex, ey])  # rows: drawing axes in WCS
    T = np.eye(3)
    T[:2, :2] = R * s
    T[:2, 2] = -R @ O
    if abs(angle - 90.0) > perpendicular_tol_deg:
        warns.append(f"{name}: marks not perpendicular: angle AOB is {angle:.2f} deg; x runs along OA, "
                     f"y perpendicular to it on B's side")
    if mirrored:
        warns.append(f"{name}: B is clockwise from A in the DXF: the drawing frame is mirrored relative to "
                     f"the DXF (drawn as seen from below?); check the mark labels")

    def to_drawing(xy_units: np.ndarray) -> np.ndarray:
        return xy_units @ T[:2, :2].T + T[:2, 2]

    marks = {}
    for k in _LABEL_LETTERS:
        i = marks_idx[k]
        dx, dy = to_drawing(cs.centers_wcs[i][None, :])[0]
        marks[k] = Mark(k, float(dx), float(dy), float(cs.centers_wcs[i][0]), float(cs.centers_wcs[i][1]),
                        mark_d[k], cs.layers[i])

    # Stud candidates: stud layers, minus the mark circles (and their concentric rings), diameter filter.
    is_stud[list(marks_idx.values())] = False
    is_stud[mark_members] = False
    idx = np.flatnonzero(is_stud)
    diam = 2.0 * cs.radii[idx] * s
    keep = np.ones(idx.size, dtype=bool)
    if min_diameter_m is not None:
        keep &= diam >= min_diameter_m
    if max_diameter_m is not None:
        keep &= diam <= max_diameter_m
    if not keep.all():
        lo = f"{min_diameter_m * 1e3:g}" if min_diameter_m is not None else "0"
        hi = f"{max_diameter_m * 1e3:g}" if max_diameter_m is not None else "inf"
        warns.append(f"{name}: {np.count_nonzero(~keep)} circles on stud layers outside the diameter filter "
                     f"[{lo}, {hi}] mm ignored")
    idx, diam = idx[keep], diam[keep]
    if idx.size == 0:
        raise DrawingError(
            f"{path}: no studs found: no circles on layer(s) {_fmt_pats(stud_layers)} pass the diameter filter"
            f"{cs.skipped_summary()}; layers: {cs.layer_summary()}"
        )
    xy = to_drawing(cs.centers_wcs[idx])
    layer_arr = np.array([cs.layers[i] for i in idx], dtype=object)

    # Deterministic order: layer, row (y), column (x), then diameter and exact coordinates. Rows
    # and columns are runs of values less than ORDER_TOL_M apart, so float noise from the CAD
    # placement (a rotated or shifted copy) never moves a stud across a grid boundary.
    layer_key = np.array([lay.casefold() for lay in layer_arr])
    row = _runs(xy[:, 1], ORDER_TOL_M)
    col = _runs(xy[:, 0], ORDER_TOL_M, within=row)
    order = np.lexsort((xy[:, 0], xy[:, 1], diam, col, row, layer_key))
    xy, diam, layer_arr = xy[order], diam[order], layer_arr[order]

    # Duplicates (any layer): keep the first in order.
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
    xy, diam, layer_arr = xy[alive], diam[alive], layer_arr[alive]
    n = len(xy)
    width = max(4, len(str(n)))
    ids = [f"S{k + 1:0{width}d}" for k in range(n)]
    studs = tuple(map(Stud, ids, xy[:, 0].tolist(), xy[:, 1].tolist(), diam.tolist(), layer_arr.tolist()))

    # Checks that only warn.
    median_d = float(np.median(diam))
    if diameter_outlier_ratio and diameter_outlier_ratio > 1.0:
        odd = np.flatnonzero((diam > median_d * diameter_outlier_ratio) | (diam < median_d / diameter_outlier_ratio))
        if odd.size:
            warns.append(f"{name}: {odd.size} studs with unusual diameter (median {median_d * 1e3:.2f} mm): "
                         + ", ".join(f"{ids[k]} {diam[k] * 1e3:.2f} mm" for k in odd[:5])
                         + (f", ... (+{odd.size - 5})" if odd.size > 5 else ""))
    spacing = 2.5 * median_d if min_spacing_m is None else float(min_spacing_m)
    if spacing > 0 and n > 1:
        try:
            i, j, d = close_pairs(xy, spacing)
            if i.size:
                o = np.argsort(d, kind="stable")[:5]
                pairs = ", ".join(f"{ids[i[k]]}-{ids[j[k]]} {d[k] * 1e3:.1f} mm" for k in o)
                more = f", ... (+{i.size - 5})" if i.size > 5 else ""
                warns.append(f"{name}: {i.size} stud pairs closer than min spacing {spacing * 1e3:.1f} mm: {pairs}{more}")
        except _TooDense as exc:
            warns.append(f"{name}: spacing check skipped: {exc.args[0]} candidate pairs closer than "
                         f"{spacing * 1e3:.1f} mm (are the drawing units right?)")
    for k in _LABEL_LETTERS:  # a ring of the mark symbol drawn on a stud layer?
        m = marks[k]
        on_mark = np.flatnonzero(np.hypot(xy[:, 0] - m.x_m, xy[:, 1] - m.y_m) < max(0.5 * m.diameter_m, duplicate_tol_m))
        if on_mark.size:
            warns.append(f"{name}: {_ids_list([ids[j] for j in on_mark])} on a stud layer lie(s) on mark {k}: part "
                         f"of the mark symbol drawn on the wrong layer? (kept as studs)")
    outside = np.flatnonzero((xy[:, 0] < -1e-9) | (xy[:, 1] < -1e-9))
    if outside.size:
        warns.append(f"{name}: {outside.size} studs outside the marks' quadrant (negative x or y): "
                     f"{_ids_list([ids[k] for k in outside])}")

    bbox = (float(xy[:, 0].min()), float(xy[:, 1].min()), float(xy[:, 0].max()), float(xy[:, 1].max()))
    return StudLayout(
        source_file=str(path), dxf_version=cs.dxf_version,
        dxf_release=dxfconst.acad_release.get(cs.dxf_version, cs.dxf_version), read_mode=cs.read_mode,
        source_units=cs.source_units, insunits=cs.insunits, units_assumed=cs.units_assumed,
        metres_per_unit=s, studs=studs, mark_o=marks["O"], mark_a=marks["A"], mark_b=marks["B"],
        mark_diameter_m=float(np.mean(list(mark_d.values()))), marks_rule=rule, angle_aob_deg=float(angle),
        mirrored=mirrored, wcs_to_drawing=tuple(tuple(float(v) for v in row) for row in T), bbox_m=bbox,
        stud_layers=tuple(sorted(set(layer_arr.tolist()), key=str.casefold)), warnings=warns,
        invalid_entities=cs.invalid_entities,
    )
