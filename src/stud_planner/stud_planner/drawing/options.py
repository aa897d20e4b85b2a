"""The options of reading a stud layout: one frozen configuration, changed with
:meth:`LayoutOptions.with_changes` (as ezdxf's drawing add-on configures its frontend), handed to every step of
:func:`~stud_planner.drawing.read_layout`."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Sequence

from stud_planner.drawing.limits import DrawingLimits

__all__ = ["LayoutOptions"]


def _patterns(value: str | Sequence[str]) -> str | tuple[str, ...]:
    return value if isinstance(value, str) else tuple(value)


@dataclass(frozen=True)
class LayoutOptions:
    """How :func:`~stud_planner.drawing.read_layout` reads a drawing (the package docstring has every rule).

    Attributes:
        stud_layers: layer name(s) or fnmatch patterns of the stud circles, case-insensitive.
        mark_layer: layer name(s) or patterns of the O/A/B (and M1, M2, ...) mark circles.
        units_if_unitless: unit of a drawing without $INSUNITS ("mm", "cm", "m", "in", ...).
        min_diameter_m, max_diameter_m: keep only stud circles in this diameter range (m); None: no bound.
        min_spacing_m: warn about studs closer than this (m); None = 2.5 x the median stud
            diameter (the smallest transverse spacing EN 1994-1-1 6.6.5.7 allows), 0 = off.
        duplicate_tol_m: studs closer than this are one stud (the first in id order is kept); mark
            circles closer than this are one mark (the rings of a target symbol).
        diameter_outlier_ratio: warn about studs whose diameter differs from the median by
            more than this factor.
        label_distance_factor: an O/A/B label names a mark within this many mark diameters.
        perpendicular_tol_deg: warn when angle AOB differs from 90 deg by more.
        collinear_tol_deg: marks whose triangle has an angle below this are collinear (error).
        right_angle_ambiguity_deg: geometry rule: the right angle must be this much clearer
            than the runner-up, else the marks are ambiguous (error).
        include_hidden_layers: also read layers that are frozen or off (by default their
            entities are skipped with a warning, as CAD does not show them).
        gun_spacing_m: warn about stud pairs closer than the weld gun's foot needs beside a
            welded stud (the arm driver's ``min_stud_spacing_m``): of each such pair the driver
            welds one and refuses the other. 0 = off.
        limits: the work budget of the block expansion (None: :class:`DrawingLimits`' defaults,
            far beyond any real drawing); crossing one raises :class:`~stud_planner.drawing.DrawingLimitError`.
    """

    stud_layers: str | Sequence[str] = ("STUDS",)
    mark_layer: str | Sequence[str] = "MARKS"
    units_if_unitless: str = "mm"
    min_diameter_m: float | None = None
    max_diameter_m: float | None = None
    min_spacing_m: float | None = None
    duplicate_tol_m: float = 1e-3
    diameter_outlier_ratio: float = 1.5
    label_distance_factor: float = 3.0
    perpendicular_tol_deg: float = 0.5
    collinear_tol_deg: float = 1.0
    right_angle_ambiguity_deg: float = 2.0
    include_hidden_layers: bool = False
    gun_spacing_m: float = 0.0
    limits: DrawingLimits | None = None

    def __post_init__(self) -> None:
        # a list of layer patterns is kept as a tuple: the options stay immutable (and hashable)
        object.__setattr__(self, "stud_layers", _patterns(self.stud_layers))
        object.__setattr__(self, "mark_layer", _patterns(self.mark_layer))

    def with_changes(self, **changes: Any) -> "LayoutOptions":
        """A copy with ``changes`` (field name -> value; an unknown name is a TypeError)."""
        return dataclasses.replace(self, **changes)
