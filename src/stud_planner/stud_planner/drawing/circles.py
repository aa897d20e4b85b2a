"""The circles of a drawing: what entity collection (:mod:`.entities`) found, checked for shape and
values, in WCS (drawing units), with the drawing's units and the O/A/B (M1, ...) labels -- a
:class:`~stud_planner.drawing.layout_types.CircleSet`. No stud or mark logic.

Left out, counted and warned about: circles of radius <= 0, circles a block scales non-uniformly
(ellipses), circles not parallel to XY, circles with non-finite or absurd values (beyond
:data:`MAX_COORDINATE_M`, named by handle and layer), and what CAD does not show (:mod:`.visibility`)."""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from stud_planner.drawing.dxf_file import open_drawing
from stud_planner.drawing.entities import Content, EntityCollector
from stud_planner.drawing.layout_types import CircleSet, DrawingError, one_line
from stud_planner.drawing.limits import DrawingLimits
from stud_planner.drawing.plain_circles import PlainCircles
from stud_planner.drawing.units import drawing_units

__all__ = ["MAX_COORDINATE_M", "collect_circles", "read_circles"]

#: A circle whose centre coordinate or radius exceeds this (metres, in WCS), or is NaN/inf, is
#: left out as invalid. No projected coordinate system on Earth goes beyond 4e7 m (site and
#: survey coordinates of a geo-referenced drawing stay far below), while 1e300 or inf are what a
#: broken export or a corrupt file writes; such values would also overflow the frame arithmetic.
MAX_COORDINATE_M = 1e8
# A transformed circle whose axes differ in length or squareness by more than this (relative),
# or whose plane tilts from XY by more than acos(1 - this) (0.8 deg), is an ellipse in plan view.
# Rounded scale factors in real files (1.000001) stay circles.
_SHAPE_TOL = 1e-4


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
    def of(cls, content: Content, hidden: np.ndarray, limit: float) -> "_Shapes":
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


def _invalid_entities(content: Content, layers: np.ndarray, shapes: _Shapes, unit_name: str) -> tuple[str, ...]:
    return tuple(
        f"handle {content.handles[k]} on layer {layers[k]}: centre ({content.centers[k, 0]:g}, "
        f"{content.centers[k, 1]:g}), radius {float(shapes.axis[k]):g} {unit_name}"
        for k in np.flatnonzero(shapes.invalid).tolist())


def _shape_warnings(file_name: str, content: Content, layers: np.ndarray, shapes: _Shapes, skipped: dict[str, int],
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
    units = drawing_units(doc, path, units_if_unitless, warns)
    unit_name, scale = units.name, units.metres_per_unit

    collector = EntityCollector(doc, include_hidden_layers, limits, str(path))
    content = collector.modelspace(plain)
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
        source_file=str(path), dxf_version=str(doc.dxfversion), read_mode=read_mode, insunits=units.insunits,
        source_units=unit_name, metres_per_unit=scale, units_assumed=units.assumed,
        centers_wcs=np.ascontiguousarray(content.centers[ok, :2]), radii=shapes.radii[ok],
        layers=tuple(layers[ok]), labels=labels, layer_entities=dict(collector.layer_entities),
        skipped=skipped, warnings=warns, invalid_entities=invalid_entities,
    )


def read_circles(path: str | Path, *, units_if_unitless: str = "mm", include_hidden_layers: bool = False,
                 plain_circles: bool = True, limits: DrawingLimits | None = None) -> CircleSet:
    """Open ``path`` and return every usable circle (INSERTs expanded); no stud/mark logic.

    ``plain_circles``: read the modelspace's plain CIRCLE entities of an ASCII file with
    :mod:`~stud_planner.drawing.plain_circles` (arrays instead of ezdxf's objects: a 250,000-stud drawing
    in seconds) and the rest with ezdxf; False: everything with ezdxf. The result is the same."""
    path = Path(path)
    opened = open_drawing(path, plain_circles=plain_circles)
    try:
        return collect_circles(opened.doc, path, read_mode=opened.read_mode, units_if_unitless=units_if_unitless,
                               include_hidden_layers=include_hidden_layers, warnings=opened.warnings,
                               plain=opened.plain, limits=limits)
    except DrawingError:
        raise
    except Exception as exc:  # a file ezdxf loads but cannot walk: never a traceback for the user
        raise DrawingError(f"{path}: cannot interpret the drawing ({type(exc).__name__}: {one_line(exc)})") from exc
