"""Entity collection: what a drawing's modelspace holds, block references expanded.

One handler per DXF entity type (:attr:`EntityCollector.handlers`, a dispatch table as ezdxf's drawing
add-on has: CIRCLE, TEXT, MTEXT, INSERT; every other type holds nothing we read); whether CAD shows an
entity is decided before any handler runs, in :mod:`.visibility`. A label's text is read here and
named by :func:`~stud_planner.drawing.marks.mark_label`.

Block references (INSERT, MINSERT) are expanded recursively with their full transform (insertion
point, base point, rotation, non-uniform and negative scale, extrusion, nesting); entities on layer
"0" inside a block take the INSERT's layer. The expansion is budgeted (:mod:`.limits`): nesting depth,
MINSERT cells, text size and the entities all block references produce are counted *before* anything
is expanded, so a drawing that asks for 10^10 circles stops at once with a
:class:`~stud_planner.drawing.limits.DrawingLimitError` naming the block, its level and the count.

The result, :class:`Content`, is arrays in WCS (drawing units); which of its circles are usable
is :mod:`.circles`."""
from __future__ import annotations

import itertools
import math
from collections import Counter
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from stud_planner.drawing.layout_types import one_line
from stud_planner.drawing.limits import DrawingLimitError, DrawingLimits
from stud_planner.drawing.marks import mark_label
from stud_planner.drawing.plain_circles import PlainCircles
from stud_planner.drawing.visibility import Visibility

__all__ = ["Content", "EntityCollector", "insert_matrices", "matrix_of"]


@dataclass
class Content:
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
    def empty(cls) -> "Content":
        z = np.zeros((0, 3))
        return cls(z, z, z, np.empty(0, dtype=object), z, (), Counter(), np.empty(0, dtype=object))


def matrix_of(m: Any) -> np.ndarray:
    """ezdxf Matrix44 -> (4, 4) numpy, row-vector convention (p' = [p, 1] @ M)."""
    return np.fromiter(iter(m), dtype=np.float64, count=16).reshape(4, 4)


def _apply(content: Content, mats: np.ndarray, ins_layers: Sequence[str | None],
           ins_handles: Sequence[str | None]) -> Content:
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
    return Content(centers, u, v, layers.astype(object), label_pos, content.label_letters * k, nonpos, handles)


def _concat(parts: list[Content]) -> Content:
    parts = [p for p in parts if p.centers.shape[0] or p.label_pos.shape[0] or p.nonpositive]
    if not parts:
        return Content.empty()
    if len(parts) == 1:
        return parts[0]
    nonpos: Counter = Counter()
    for p in parts:
        nonpos.update(p.nonpositive)
    return Content(
        np.concatenate([p.centers for p in parts]), np.concatenate([p.u for p in parts]),
        np.concatenate([p.v for p in parts]), np.concatenate([p.layers for p in parts]),
        np.concatenate([p.label_pos for p in parts]),
        tuple(itertools.chain.from_iterable(p.label_letters for p in parts)), nonpos,
        np.concatenate([p.handles for p in parts]),
    )


def _label_name(e: Any, dxftype: str) -> str | None:
    """The mark a TEXT, MTEXT or ATTRIB names (:func:`mark_label`), or None."""
    try:
        raw = e.dxf.text if dxftype in ("TEXT", "ATTRIB") else e.text
    except Exception:
        return None
    # A label is one letter, but MTEXT formatting codes may wrap it in a long raw string.
    if not raw or len(raw) > 4096:
        return None
    if dxftype == "MTEXT":
        raw = e.plain_text()
    return mark_label(raw)


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
    """What one :meth:`EntityCollector.scan` gathers from its entities, before numpy turns it into a
    :class:`Content`: circles and labels of the container itself, and its INSERTs per block name."""

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
        letter = _label_name(e, dxftype)
        if letter:
            self.label_pos.append(_label_position(e, dxftype))
            self.letters.append(letter)

    def content(self) -> Content:
        z = np.zeros((0, 3))
        return Content(
            np.array(self.centers, dtype=np.float64).reshape(-1, 3), np.array(self.us, dtype=np.float64).reshape(-1, 3),
            np.array(self.vs, dtype=np.float64).reshape(-1, 3), np.array(self.layers, dtype=object),
            np.array(self.label_pos, dtype=np.float64).reshape(-1, 3) if self.label_pos else z, tuple(self.letters),
            self.nonpositive, np.array(self.handles, dtype=object),
        )


class EntityCollector:
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
        self.cache: dict[str, Content] = {}
        self.skipped_inserts: Counter = Counter()
        self.layer_entities: Counter = Counter()
        self.visibility = Visibility(doc.layers, include_hidden_layers)
        #: entity type -> handler(entity, type, effective layer, buffer); other types hold nothing we read
        self.handlers: dict[str, Callable[[Any, str, str | None, _ScanBuffer], None]] = {
            "CIRCLE": self._circle, "TEXT": self._label, "MTEXT": self._label, "INSERT": self._insert}

    def modelspace(self, plain: PlainCircles | None = None) -> Content:
        """The document's modelspace, block references expanded; ``plain``: its CIRCLE entities read
        as arrays (:mod:`~stud_planner.drawing.plain_circles`; then cut out of the document)."""
        return self.scan(self.doc.modelspace(), (), in_block=False, plain=plain)

    def skip_insert(self, name: str, reason: str, count: int = 1) -> None:
        """Count ``count`` references to block ``name`` left out for ``reason`` (warned about once)."""
        self.skipped_inserts[(name, reason)] += count

    def block_content(self, name: str, stack: tuple[str, ...]) -> tuple[Content | None, str]:
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

    def _with_plain(self, own: Content, plain: PlainCircles) -> Content:
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
        return _concat([Content(plain.centers[take], u, v, layers[take], np.zeros((0, 3)), (), Counter(), handles),
                        own])

    def scan(self, entities: Iterable[Any], stack: tuple[str, ...], in_block: bool,
             plain: PlainCircles | None = None) -> Content:
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
            return  # no text: no label (as _label_name decides)
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
                mats = self._minsert_cells(e, name, buf) if e.mcount > 1 else matrix_of(e.matrix44())[None]
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
        base = matrix_of(e.matrix44())
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
                     stack: tuple[str, ...]) -> Content | None:
        """Block ``name``'s content placed by all its INSERTs of one container (None: nothing placed)."""
        mats, ins_layers, ins_handles = [], [], []
        if simple:
            mats.append(insert_matrices(np.array([r[:7] for r in simple], dtype=np.float64), self.base_point(name)))
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
            self.skip_insert(name, f"expansion failed ({type(exc).__name__}: {one_line(exc)})",
                             int(np.count_nonzero(ok)))
            return None

    def _count_expansion(self, name: str, k: int, content: Content, stack: tuple[str, ...]) -> None:
        """Counts ``k`` placements of ``content`` against ``max_expanded_entities`` before they are made."""
        n = content.centers.shape[0] + content.label_pos.shape[0]
        if self.expanded + k * n > self.limits.max_expanded_entities:
            where = f"block {stack[-1]!r}" if stack else "modelspace"
            raise DrawingLimitError(
                f"{self.source}: block {name!r} (nesting level {len(stack) + 1}) "
                f"placed {k:,} time{'s' if k != 1 else ''} in {where} "
                f"would expand {k * n:,} entities ({k:,} x {n:,}; {self.expanded:,} expanded before), beyond the "
                f"limit max_expanded_entities = {self.limits.max_expanded_entities:,}", "max_expanded_entities",
                self.expanded + k * n)
        self.expanded += k * n


def insert_matrices(params: np.ndarray, base: np.ndarray) -> np.ndarray:
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
