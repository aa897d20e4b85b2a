"""Collecting circles from modelspace with block expansion (INSERT/MINSERT, full transforms,
nesting, layer 0 inheritance), visibility, and the labels next to them.

Each DXF entity type we read has its handler (:attr:`_Collector.handlers`: CIRCLE, TEXT, MTEXT,
INSERT; every other type holds nothing we use); whether CAD shows an entity is decided before
any handler runs, in :mod:`stud_planner.drawing.visibility`.

Block expansion is budgeted (:mod:`stud_planner.drawing.limits`): nesting depth, MINSERT cells,
text size and the entities all block references produce are counted *before* anything is
expanded, so a drawing that asks for 10^10 circles stops at once with a
:class:`~stud_planner.drawing.limits.DrawingLimitError` naming the block, its level and the count."""
from __future__ import annotations

import itertools
import math
import re
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from stud_planner.drawing.plain_circles import PlainCircles
from stud_planner.drawing.dxf_file import _check_file, _load_document, _load_with_plain_circles, _one_line
from stud_planner.drawing.layout_types import CircleSet, DrawingError
from stud_planner.drawing.limits import DrawingLimitError, DrawingLimits
from stud_planner.drawing.units import UNITS, units_to_metres
from stud_planner.drawing.visibility import Visibility


# -- collecting circles (with block expansion) -----------------------------------------------------
#: A circle whose centre coordinate or radius exceeds this (metres, in WCS), or is NaN/inf, is
#: left out as invalid. No projected coordinate system on Earth goes beyond 4e7 m (site and
#: survey coordinates of a geo-referenced drawing stay far below), while 1e300 or inf are what a
#: broken export or a corrupt file writes; such values would also overflow the frame arithmetic.
MAX_COORDINATE_M = 1e8
_LABEL_LETTERS = ("O", "A", "B")
#: a reference mark's label: M1, M2, ... (``M01`` and ``M 1`` read as M1)
_REFERENCE_LABEL = re.compile(r"M\s*0*([1-9][0-9]{0,5})")
_TEXT_CODES = re.compile(r"%%[uUoOkK]")
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
        np.concatenate([p.label_pos for p in parts]),
        tuple(itertools.chain.from_iterable(p.label_letters for p in parts)), nonpos,
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
    if text in _LABEL_LETTERS:
        return text
    ref = _REFERENCE_LABEL.fullmatch(text)
    return f"M{ref.group(1)}" if ref else None


def _label_position(e: Any, dxftype: str) -> tuple[float, float, float]:
    if dxftype == "MTEXT":
        return tuple(e.dxf.insert)  # MTEXT insert is WCS
    dxf = e.dxf
    p = dxf.insert
    if (dxf.get("halign", 0) or dxf.get("valign", 0)) and dxf.hasattr("align_point"):
        q = dxf.align_point
        p = (p + q) * 0.5 if dxf.get("halign", 0) in (3, 5) else q  # ALIGNED / FIT span both points
    return tuple(e.ocs().to_wcs(p))


#: INSERT parameters of the common case (extrusion +Z, no MINSERT), one row per reference:
#: (x, y, z, xscale, yscale, zscale, rotation_deg, layer, handle)
_SimpleInsert = tuple
#: any other INSERT reference, or the cells of a MINSERT: (transforms (k, 4, 4), layer, handle)
_GeneralInsert = tuple


@dataclass
class _ScanBuffer:
    """What one :meth:`_Collector.scan` gathers from its entities, before numpy turns it into a
    :class:`_Content`: circles and labels of the container itself, and its INSERTs per block name."""

    centers: list = field(default_factory=list)
    us: list = field(default_factory=list)
    vs: list = field(default_factory=list)
    layers: list = field(default_factory=list)
    handles: list = field(default_factory=list)
    label_pos: list = field(default_factory=list)
    letters: list = field(default_factory=list)
    nonpositive: Counter = field(default_factory=Counter)
    # INSERTs per block name: common case as raw parameters, turned into matrices in one numpy
    # pass; the rest through ezdxf's Insert.matrix44().
    simple: dict[str, list[_SimpleInsert]] = field(default_factory=dict)
    general: dict[str, list[_GeneralInsert]] = field(default_factory=dict)
    #: the container scanned (a block's name, or None for modelspace) and its nesting level (0: modelspace)
    container: str | None = None
    level: int = 0

    def where(self) -> str:
        return "modelspace" if self.container is None else f"block {self.container!r} (nesting level {self.level})"

    def add_label(self, e: Any, dxftype: str) -> None:
        letter = _label_letter(e, dxftype)
        if letter:
            self.label_pos.append(_label_position(e, dxftype))
            self.letters.append(letter)

    def content(self) -> _Content:
        z = np.zeros((0, 3))
        return _Content(
            np.array(self.centers, dtype=np.float64).reshape(-1, 3), np.array(self.us, dtype=np.float64).reshape(-1, 3),
            np.array(self.vs, dtype=np.float64).reshape(-1, 3), np.array(self.layers, dtype=object),
            np.array(self.label_pos, dtype=np.float64).reshape(-1, 3) if self.label_pos else z, tuple(self.letters),
            self.nonpositive, np.array(self.handles, dtype=object),
        )


class _Collector:
    """Walks modelspace and block definitions; caches each block's flattened content.

    One handler per DXF entity type (:attr:`handlers`, as ezdxf's drawing add-on dispatches);
    whether an entity is shown at all is decided before, in one place (:class:`Visibility`)."""

    def __init__(self, doc: Any, include_hidden_layers: bool = False, limits: DrawingLimits | None = None,
                 source: str = "<document>") -> None:
        self.doc = doc
        self.limits = limits or DrawingLimits()
        self.source = source  # the file, for the limit errors
        #: the work done so far, against :attr:`limits`: entities block references produced, MINSERT cells
        self.expanded = 0
        self.minsert_cells = 0
        self.cache: dict[str, _Content] = {}
        self.skipped_inserts: Counter = Counter()
        self.layer_entities: Counter = Counter()
        self.visibility = Visibility(doc.layers, include_hidden_layers)
        #: entity type -> handler(entity, type, effective layer, buffer); other types hold nothing we read
        self.handlers: dict[str, Callable[[Any, str, str | None, _ScanBuffer], None]] = {
            "CIRCLE": self._circle, "TEXT": self._label, "MTEXT": self._label, "INSERT": self._insert}

    def skip_insert(self, name: str, reason: str, count: int = 1) -> None:
        self.skipped_inserts[(name, reason)] += count

    def block_content(self, name: str, stack: tuple[str, ...]) -> tuple[_Content | None, str]:
        """Flattened content of block ``name`` (cached), or (None, why not). ``stack``: the blocks
        being expanded, from modelspace's down (their names as spelled)."""
        key = name.casefold()
        if key in self.cache:
            return self.cache[key], ""
        if any(key == outer.casefold() for outer in stack):
            return None, "recursive block reference"
        level = len(stack) + 1
        if level > self.limits.max_block_depth:
            chain = [*stack, name]
            shown = " > ".join(chain if len(chain) <= 6 else [*chain[:3], "...", *chain[-2:]])
            raise DrawingLimitError(
                f"{self.source}: block {name!r} is nested {level} levels deep (modelspace > {shown}), beyond "
                f"the limit max_block_depth = {self.limits.max_block_depth}", "max_block_depth", level)
        block = self.doc.blocks.get(name)
        if block is None:
            return None, "block definition missing"
        content = self.scan(block, stack + (name,), in_block=True)
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
        take = self.visibility.plain_circles_shown(layers, names, plain.invisible)
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
        entities, read by :mod:`~stud_planner.drawing.plain_circles` (``entities`` then holds no CIRCLE); they go
        through the same rules as the circles read here."""
        buf = _ScanBuffer(container=stack[-1] if stack else None, level=len(stack))
        for e in entities:
            t = e.dxftype()
            try:
                layer = e.dxf.layer
            except Exception:
                layer = "0"
            if not in_block:
                self.layer_entities[layer] += 1
            handler = self.handlers.get(t)
            if handler is None or not self.visibility.entity_shown(e, t, layer, in_block):
                continue
            handler(e, t, None if (in_block and layer == "0") else layer, buf)
        own = buf.content()
        if plain is not None:
            own = self._with_plain(own, plain)
        parts = [own]
        for name in list(buf.simple) + [n for n in buf.general if n not in buf.simple]:
            placed = self._place_block(name, buf.simple.get(name, []), buf.general.get(name, []), stack)
            if placed is not None:
                parts.append(placed)
        return _concat(parts)

    # -- the handlers: layer None = layer "0" in a block (inherits the INSERT's layer) ----------------
    @staticmethod
    def _circle(e: Any, dxftype: str, layer: str | None, buf: _ScanBuffer) -> None:
        dxf = e.dxf
        r = float(dxf.radius)
        if r <= 0.0:  # NaN goes on, to be left out with the other non-finite values
            buf.nonpositive[layer] += 1
            return
        c = dxf.center
        ez = dxf.extrusion
        if ez.x == 0.0 and ez.y == 0.0 and ez.z > 0.0:
            buf.centers.append((c.x, c.y, c.z))
            buf.us.append((r, 0.0, 0.0))
            buf.vs.append((0.0, r, 0.0))
        else:  # OCS -> WCS (arbitrary axis algorithm), e.g. extrusion (0, 0, -1)
            ocs = e.ocs()
            buf.centers.append(tuple(ocs.to_wcs(c)))
            buf.us.append(tuple(ocs.ux * r))
            buf.vs.append(tuple(ocs.uy * r))
        buf.layers.append(layer)
        buf.handles.append(dxf.handle)

    def _label(self, e: Any, dxftype: str, layer: str | None, buf: _ScanBuffer) -> None:
        self._check_text(e, dxftype, buf)
        buf.add_label(e, dxftype)

    def _check_text(self, e: Any, dxftype: str, buf: _ScanBuffer) -> None:
        """The text size limit, before a label is looked at."""
        try:
            n = len(e.dxf.text if dxftype in ("TEXT", "ATTRIB") else e.text)
        except Exception:
            return  # no text: no label (as _label_letter decides)
        if n > self.limits.max_text_chars:
            raise DrawingLimitError(
                f"{self.source}: {dxftype} (handle {e.dxf.get('handle', '?')}) in {buf.where()} has {n:,} "
                f"characters, beyond the limit max_text_chars = {self.limits.max_text_chars:,}", "max_text_chars", n)

    def _insert(self, e: Any, dxftype: str, layer: str | None, buf: _ScanBuffer) -> None:
        for attrib in getattr(e, "attribs", ()):
            self._check_text(attrib, "ATTRIB", buf)
            buf.add_label(attrib, "ATTRIB")
        dxf = e.dxf
        name = dxf.get("name", "")
        try:
            ez = dxf.extrusion
            if e.mcount <= 1 and ez.x == 0.0 and ez.y == 0.0 and ez.z > 0.0:
                p = dxf.insert
                buf.simple.setdefault(name, []).append((
                    p.x, p.y, p.z, dxf.xscale, dxf.yscale, dxf.zscale, dxf.rotation, layer, dxf.handle))
            else:
                mats = self._minsert_cells(e, name, buf) if e.mcount > 1 else _matrix(e.matrix44())[None]
                buf.general.setdefault(name, []).append((mats, layer, dxf.handle))
        except DrawingLimitError:
            raise
        except Exception as exc:  # e.g. ZeroDivisionError on a zero extrusion vector
            self.skip_insert(name, f"transform failed ({type(exc).__name__})")

    def _minsert_cells(self, e: Any, name: str, buf: _ScanBuffer) -> np.ndarray:
        """(k, 4, 4) transforms of a MINSERT's grid cells, counted against ``max_minsert_cells``
        before any is made. The cells of ezdxf's ``Insert.multi_insert`` in its order (row by row),
        computed as arrays: the grid offset (column x column_spacing, row x row_spacing) is in the
        OCS, rotated with the INSERT and not scaled; a zero spacing collapses its direction to one
        cell, as ezdxf yields each location once."""
        dxf = e.dxf
        row_count, col_count = int(dxf.row_count), int(dxf.column_count)
        dx, dy = float(dxf.column_spacing), float(dxf.row_spacing)
        rows = (row_count if dy else 1) if row_count > 0 else 0
        cols = (col_count if dx else 1) if col_count > 0 else 0
        cells = rows * cols
        if self.minsert_cells + cells > self.limits.max_minsert_cells:
            raise DrawingLimitError(
                f"{self.source}: MINSERT (handle {dxf.get('handle', '?')}) of block {name!r} in {buf.where()} has "
                f"{rows:,} x {cols:,} = {cells:,} cells ({self.minsert_cells:,} in MINSERTs before), beyond the "
                f"limit max_minsert_cells = {self.limits.max_minsert_cells:,}", "max_minsert_cells",
                self.minsert_cells + cells)
        self.minsert_cells += cells
        base = _matrix(e.matrix44())
        r, c = np.divmod(np.arange(cells, dtype=np.int64), max(cols, 1))
        ox, oy = c * dx, r * dy
        a = math.radians(float(dxf.rotation))
        if a:
            ca, sa = math.cos(a), math.sin(a)
            ox, oy = ox * ca - oy * sa, ox * sa + oy * ca
        ocs = e.ocs()
        mats = np.repeat(base[None], cells, axis=0)
        mats[:, 3, :3] += ox[:, None] * np.array(tuple(ocs.ux)) + oy[:, None] * np.array(tuple(ocs.uy))
        return mats

    # -- block expansion ----------------------------------------------------------------------------
    def _place_block(self, name: str, simple: list[_SimpleInsert], general: list[_GeneralInsert],
                     stack: tuple[str, ...]) -> _Content | None:
        """Block ``name``'s content placed by all its INSERTs of one container (None: nothing placed)."""
        mats, ins_layers, ins_handles = [], [], []
        if simple:
            mats.append(_insert_matrices(np.array([r[:7] for r in simple], dtype=np.float64), self.base_point(name)))
            ins_layers += [r[7] for r in simple]
            ins_handles += [r[8] for r in simple]
        if general:
            mats.append(np.concatenate([m for m, _, _ in general]))
            ins_layers += [lay for m, lay, _ in general for _ in range(len(m))]
            ins_handles += [h for m, _, h in general for _ in range(len(m))]
        M = np.concatenate(mats)
        # rows 0, 1 = images of the block's x and y axes; a zero z scale is harmless in 2D
        ok = np.all(np.isfinite(M), axis=(1, 2)) & (np.min(np.linalg.norm(M[:, :2, :3], axis=2), axis=1) > 1e-12)
        if not ok.all():
            self.skip_insert(name, "degenerate transform (zero scale)", int(np.count_nonzero(~ok)))
        if not ok.any():
            return None
        try:
            content, why = self.block_content(name, stack)
            if content is None:
                self.skip_insert(name, why, int(np.count_nonzero(ok)))
                return None
            self._count_expansion(name, int(np.count_nonzero(ok)), content, stack)
            return _apply(content, M[ok], [lay for lay, good in zip(ins_layers, ok) if good],
                          [h for h, good in zip(ins_handles, ok) if good])
        except DrawingLimitError:
            raise
        except Exception as exc:
            self.skip_insert(name, f"expansion failed ({type(exc).__name__}: {_one_line(exc)})",
                             int(np.count_nonzero(ok)))
            return None


    def _count_expansion(self, name: str, k: int, content: _Content, stack: tuple[str, ...]) -> None:
        """Counts ``k`` placements of ``content`` against ``max_expanded_entities`` before they are made."""
        n = content.centers.shape[0] + content.label_pos.shape[0]
        if self.expanded + k * n > self.limits.max_expanded_entities:
            where = f"block {stack[-1]!r}" if stack else "modelspace"
            raise DrawingLimitError(
                f"{self.source}: block {name!r} (nesting level {len(stack) + 1}) placed {k:,} time{'s' if k != 1 else ''} in {where} "
                f"would expand {k * n:,} entities ({k:,} x {n:,}; {self.expanded:,} expanded before), beyond the "
                f"limit max_expanded_entities = {self.limits.max_expanded_entities:,}", "max_expanded_entities",
                self.expanded + k * n)
        self.expanded += k * n


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


def _drawing_units(doc: Any, path: Path, units_if_unitless: str, warns: list[str]) -> tuple[int, str, float, bool]:
    """($INSUNITS code, unit name, metres per unit, assumed?) of ``doc``; warns when assumed."""
    insunits = int(doc.header.get("$INSUNITS", 0) or 0)
    if insunits in UNITS:
        _, unit_name, scale = units_to_metres(insunits)
        return insunits, unit_name, scale, False
    try:
        _, unit_name, scale = units_to_metres(units_if_unitless)
    except ValueError as exc:
        raise DrawingError(f"{path}: units_if_unitless: {exc}") from exc
    what = "no $INSUNITS" if "$INSUNITS" not in doc.header else f"$INSUNITS {insunits} (unitless)"
    if insunits not in (0,):
        what = f"unsupported $INSUNITS code {insunits}"
    warns.append(f"{path.name}: {what}: coordinates taken as {unit_name} (units_if_unitless)")
    return insunits, unit_name, scale, True


@dataclass(frozen=True)
class _Shapes:
    """Which collected circles are circles in plan view with a position: per circle (bool masks)."""

    axis: np.ndarray      # length of the circle's first in-plane axis (its radius when kept)
    radii: np.ndarray     # geometric mean of both axes
    uniform: np.ndarray   # both axes of one length and square (no non-uniform block scale)
    planar: np.ndarray    # parallel to XY
    shown: np.ndarray     # usable values, radius > 0, not on a hidden layer
    invalid: np.ndarray   # non-finite or out-of-range values (and not hidden)

    @property
    def ok(self) -> np.ndarray:
        return self.uniform & self.planar & self.shown

    @classmethod
    def of(cls, content: _Content, hidden: np.ndarray, limit: float) -> "_Shapes":
        """``limit``: the largest coordinate or radius in drawing units (:data:`MAX_COORDINATE_M`)."""
        u, v = content.u, content.v
        with np.errstate(over="ignore", invalid="ignore"):
            nu, nv = np.linalg.norm(u, axis=1), np.linalg.norm(v, axis=1)
            normal = np.cross(u, v)
            nn = np.linalg.norm(normal, axis=1)
        # Non-finite or absurd values (NaN, inf, 1e300: a corrupt file or a broken export) are no
        # position at all: such a circle is left out, named by handle and layer, never planned.
        with np.errstate(invalid="ignore"):
            usable = (np.all(np.isfinite(content.centers), axis=1) & np.all(np.isfinite(u), axis=1)
                      & np.all(np.isfinite(v), axis=1)
                      & (np.max(np.abs(content.centers[:, :2]), axis=1, initial=0.0) <= limit)
                      & (np.maximum(nu, nv) <= limit))
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            uniform = (np.abs(nu - nv) <= _SHAPE_TOL * np.maximum(nu, nv)) & (
                np.abs(np.einsum("ij,ij->i", u, v)) <= _SHAPE_TOL * nu * nv
            )
            planar = np.abs(normal[:, 2]) >= (1.0 - _SHAPE_TOL) * nn
        shown = usable & (nu > 0) & ~hidden  # a hidden circle is counted once, as hidden
        radii = np.sqrt(nu * nv)  # equal to nu within _SHAPE_TOL for the circles kept
        return cls(nu, radii, uniform, planar, shown, ~usable & ~hidden)


def _invalid_entities(content: _Content, layers: np.ndarray, shapes: _Shapes, unit_name: str) -> tuple[str, ...]:
    return tuple(
        f"handle {content.handles[k]} on layer {layers[k]}: centre ({content.centers[k, 0]:g}, "
        f"{content.centers[k, 1]:g}), radius {float(shapes.axis[k]):g} {unit_name}"
        for k in np.flatnonzero(shapes.invalid).tolist())


def _shape_warnings(file_name: str, content: _Content, layers: np.ndarray, shapes: _Shapes, skipped: dict[str, int],
                    invalid_entities: tuple[str, ...]) -> list[str]:
    """The warnings for circles left out for their values or their shape."""
    warns = []
    if invalid_entities:
        warns.append(f"{file_name}: {len(invalid_entities)} circle{'s' if len(invalid_entities) != 1 else ''} with "
                     f"non-finite or out-of-range values (beyond {MAX_COORDINATE_M:g} m) left out: "
                     + "; ".join(invalid_entities[:5])
                     + (f"; ... (+{len(invalid_entities) - 5})" if len(invalid_entities) > 5 else ""))
    if skipped["radius<=0"]:
        on = sorted({"0" if k is None else k for k in content.nonpositive}, key=str.casefold)
        warns.append(f"{file_name}: {skipped['radius<=0']} circles with radius <= 0 skipped (layers: {', '.join(on)})")
    if skipped["non-uniform scale"]:
        on = sorted(set(layers[~shapes.uniform & shapes.shown]), key=str.casefold)
        warns.append(f"{file_name}: {skipped['non-uniform scale']} circles in non-uniformly scaled block references "
                     f"are ellipses and were skipped (layers: {', '.join(on)})")
    if skipped["not parallel to XY"]:
        on = sorted(set(layers[shapes.uniform & ~shapes.planar & shapes.shown]), key=str.casefold)
        warns.append(f"{file_name}: {skipped['not parallel to XY']} circles not parallel to the XY plane skipped "
                     f"(layers: {', '.join(on)})")
    return warns


def _insert_warnings(file_name: str, skipped_inserts: Counter) -> list[str]:
    warns = []
    for (name, reason), count in sorted(skipped_inserts.items()):
        times = f"{count} references" if count > 1 else "1 reference"
        warns.append(f"{file_name}: INSERT of block {name!r}: {reason}; {times} skipped, rest of the drawing kept")
    return warns


def collect_circles(
    doc: Any,
    path: str | Path = "<document>",
    *,
    read_mode: str = "read",
    units_if_unitless: str = "mm",
    include_hidden_layers: bool = False,
    warnings: Sequence[str] = (),
    plain: PlainCircles | None = None,
    limits: DrawingLimits | None = None,
) -> CircleSet:
    """All circles of ``doc``'s modelspace with INSERTs expanded, in WCS (drawing units).

    Also reads the units and the O/A/B (and M1, M2, ...) labels; see the module docstring for what is skipped.
    ``plain``: the modelspace CIRCLE entities read by :mod:`~stud_planner.drawing.plain_circles` and cut out of
    ``doc`` (what :func:`read_circles` does for a large file); the result is the same. ``limits``: the work
    budget of the block expansion (:class:`~stud_planner.drawing.limits.DrawingLimits`; crossing one raises
    :class:`~stud_planner.drawing.limits.DrawingLimitError`, a :class:`DrawingError`).
    """
    path = Path(path)
    warns = list(warnings)
    insunits, unit_name, scale, assumed = _drawing_units(doc, path, units_if_unitless, warns)

    collector = _Collector(doc, include_hidden_layers, limits, str(path))
    content = collector.scan(doc.modelspace(), (), in_block=False, plain=plain)
    visibility = collector.visibility

    layers = np.array(["0" if lay is None else lay for lay in content.layers], dtype=object)
    hidden = visibility.inherited_hidden(layers)
    shapes = _Shapes.of(content, hidden, MAX_COORDINATE_M / scale)
    skipped = {
        "radius<=0": int(sum(content.nonpositive.values())),
        "non-uniform scale": int(np.count_nonzero(~shapes.uniform & shapes.shown)),
        "not parallel to XY": int(np.count_nonzero(shapes.uniform & ~shapes.planar & shapes.shown)),
        "invisible": int(visibility.invisible["CIRCLE"]),
        "frozen or off layer": visibility.hidden_circles(),
        "non-finite or out of range": int(np.count_nonzero(shapes.invalid)),
    }
    invalid_entities = _invalid_entities(content, layers, shapes, unit_name)
    warns += _shape_warnings(path.name, content, layers, shapes, skipped, invalid_entities)
    warns += visibility.warnings(path.name)
    warns += _insert_warnings(path.name, collector.skipped_inserts)

    labels = tuple(
        (letter, float(p[0]), float(p[1])) for letter, p in zip(content.label_letters, content.label_pos)
    )
    ok = shapes.ok
    return CircleSet(
        source_file=str(path), dxf_version=str(doc.dxfversion), read_mode=read_mode, insunits=insunits,
        source_units=unit_name, metres_per_unit=scale, units_assumed=assumed,
        centers_wcs=np.ascontiguousarray(content.centers[ok, :2]), radii=shapes.radii[ok],
        layers=tuple(layers[ok]), labels=labels, layer_entities=dict(collector.layer_entities),
        skipped=skipped, warnings=warns, invalid_entities=invalid_entities,
    )


def read_circles(path: str | Path, *, units_if_unitless: str = "mm", include_hidden_layers: bool = False,
                 plain_circles: bool = True, limits: DrawingLimits | None = None) -> CircleSet:
    """Open ``path`` and return every usable circle (INSERTs expanded); no stud/mark logic.

    ``plain_circles``: read the modelspace's plain CIRCLE entities of an ASCII file with
    :mod:`~stud_planner.drawing.plain_circles` (arrays, ~20x faster than ezdxf's objects: a 250,000-stud drawing
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
                               include_hidden_layers=include_hidden_layers, warnings=warns, plain=plain,
                               limits=limits)
    except DrawingError:
        raise
    except Exception as exc:  # a file ezdxf loads but cannot walk: never a traceback for the user
        raise DrawingError(f"{path}: cannot interpret the drawing ({type(exc).__name__}: {_one_line(exc)})") from exc
