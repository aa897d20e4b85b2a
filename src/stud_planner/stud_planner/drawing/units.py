"""Units: DXF $INSUNITS codes and names -> metres, and the unit a drawing's coordinates are in.

The drawing frame these units convert into (metres, origin O, x toward A) is :mod:`.frame`."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from stud_planner.drawing.layout_types import DrawingError

__all__ = ["UNITS", "DrawingUnits", "drawing_units", "units_to_metres"]

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


@dataclass(frozen=True)
class DrawingUnits:
    """The unit of a drawing's coordinates: its $INSUNITS code as found (0: unitless or absent), the
    unit's name, metres per drawing unit, and whether the unit was assumed (``units_if_unitless``)."""

    insunits: int
    name: str
    metres_per_unit: float
    assumed: bool


def drawing_units(doc: Any, path: Path, units_if_unitless: str, warns: list[str]) -> DrawingUnits:
    """The unit of ezdxf document ``doc`` (file ``path``, for the messages); appends a warning to
    ``warns`` when the unit is assumed. Raises DrawingError for an unknown ``units_if_unitless``."""
    insunits = int(doc.header.get("$INSUNITS", 0) or 0)
    if insunits in UNITS:
        _, unit_name, scale = units_to_metres(insunits)
        return DrawingUnits(insunits, unit_name, scale, False)
    try:
        _, unit_name, scale = units_to_metres(units_if_unitless)
    except ValueError as exc:
        raise DrawingError(f"{path}: units_if_unitless: {exc}") from exc
    what = "no $INSUNITS" if "$INSUNITS" not in doc.header else f"$INSUNITS {insunits} (unitless)"
    if insunits not in (0,):
        what = f"unsupported $INSUNITS code {insunits}"
    warns.append(f"{path.name}: {what}: coordinates taken as {unit_name} (units_if_unitless)")
    return DrawingUnits(insunits, unit_name, scale, True)
