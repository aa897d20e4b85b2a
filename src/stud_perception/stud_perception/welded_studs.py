"""Welded studs as the simulated camera sees them: cylinders standing on the part, defects and all.

After a weld the stud stands where the gun put it: its base at the weld point, its axis along the
gun's axis (outward). A scene can make some welds go wrong, keyed by the scene's stud ids (the
scene file's ``weld_defects``, an interface: validated here with errors that name the stud and the
field)::

    "weld_defects": {"S0004": {"lean_deg": 8.0, "lean_azimuth_deg": 30.0},
                     "S0007": {"offset_mm": [4.0, 0.0]},
                     "S0011": {"missing": true},
                     "S0013": {"height_mm": 128.0}}

- ``lean_deg`` / ``lean_azimuth_deg``: the stud leans this far from the gun's axis, toward this
  azimuth in the weld point's tangent frame (x = world X projected onto the tangent plane, y =
  normal x x: stud_common.rotations.frame_from_normal);
- ``offset_mm``: its base lies this far from the weld point, (x, y) in that tangent frame;
- ``missing``: no stud stands there (the arc failed, or it fell off);
- ``height_mm``: it stands this tall instead of the scene's ``stud_length_mm`` (burn-off gone wrong).

The scene's ``stud_length_mm`` (after weld, default 150: an M16x150) and ``stud_diameter_mm``
(default 16) size every stud. Frames and units: `world`, metres, unit axes.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from stud_common.rotations import frame_from_normal

#: An M16x150 shear stud, as welded.
DEFAULT_STUD_LENGTH_M = 0.150
DEFAULT_STUD_DIAMETER_M = 0.016


class WeldDefectError(ValueError):
    """A weld_defects entry that cannot be simulated (names the stud id, the field and the value)."""


@dataclass(frozen=True)
class WeldDefect:
    """What goes wrong with one stud's weld (see the module doc); the default is a good weld."""

    lean_deg: float = 0.0
    lean_azimuth_deg: float = 0.0
    offset_mm: tuple[float, float] = (0.0, 0.0)
    missing: bool = False
    height_mm: float | None = None

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {}
        if self.lean_deg:
            d.update(lean_deg=self.lean_deg, lean_azimuth_deg=self.lean_azimuth_deg)
        if any(self.offset_mm):
            d["offset_mm"] = list(self.offset_mm)
        if self.missing:
            d["missing"] = True
        if self.height_mm is not None:
            d["height_mm"] = self.height_mm
        return d


_FIELDS = {"lean_deg", "lean_azimuth_deg", "offset_mm", "missing", "height_mm"}


def _number(sid: str, name: str, value: Any, lo: float, hi: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise WeldDefectError(f"weld_defects[{sid!r}].{name}={value!r}: expected a finite number")
    if not lo <= float(value) <= hi:
        raise WeldDefectError(f"weld_defects[{sid!r}].{name}={value!r}: expected a number in [{lo}, {hi}]")
    return float(value)


def parse_weld_defects(data: Any, stud_ids: tuple[str, ...]) -> dict[str, WeldDefect]:
    """``weld_defects`` of a scene file -> {stud id: WeldDefect}; every id must be a stud of the scene."""
    if data is None:
        return {}
    if not isinstance(data, Mapping):
        raise WeldDefectError(f"weld_defects must be a mapping of stud id -> defect, got {type(data).__name__}")
    known = set(stud_ids)
    out = {}
    for sid, d in data.items():
        if sid not in known:
            raise WeldDefectError(f"weld_defects names stud {sid!r}, which is not a stud of the scene "
                                  f"(its ids: {', '.join(sorted(known)[:8])}{', ...' if len(known) > 8 else ''})")
        if not isinstance(d, Mapping):
            raise WeldDefectError(f"weld_defects[{sid!r}] must be a mapping, got {type(d).__name__}")
        unknown = set(d) - _FIELDS
        if unknown:
            raise WeldDefectError(f"weld_defects[{sid!r}] has unknown field(s) {sorted(unknown)}; "
                                  f"allowed: {sorted(_FIELDS)}")
        offset = d.get("offset_mm", (0.0, 0.0))
        if not isinstance(offset, (list, tuple)) or len(offset) != 2:
            raise WeldDefectError(f"weld_defects[{sid!r}].offset_mm={offset!r}: expected two numbers (x, y) in mm")
        missing = d.get("missing", False)
        if not isinstance(missing, bool):
            raise WeldDefectError(f"weld_defects[{sid!r}].missing={missing!r}: expected true or false")
        out[sid] = WeldDefect(
            lean_deg=_number(sid, "lean_deg", d.get("lean_deg", 0.0), 0.0, 60.0),
            lean_azimuth_deg=_number(sid, "lean_azimuth_deg", d.get("lean_azimuth_deg", 0.0), -360.0, 360.0),
            offset_mm=(_number(sid, "offset_mm[0]", offset[0], -50.0, 50.0),
                       _number(sid, "offset_mm[1]", offset[1], -50.0, 50.0)),
            missing=missing,
            height_mm=None if d.get("height_mm") is None else _number(sid, "height_mm", d["height_mm"], 1.0, 1000.0),
        )
    return out


@dataclass(frozen=True)
class StudCylinder:
    """A welded stud: a solid cylinder from ``base_w`` (3,) along the unit ``axis_w`` (3,) for
    ``length_m``, of ``radius_m`` (world, metres). Ray-cast like the scene's solids."""

    stud_id: str
    base_w: np.ndarray
    axis_w: np.ndarray
    length_m: float
    radius_m: float

    @property
    def top_w(self) -> np.ndarray:
        return self.base_w + self.length_m * self.axis_w

    def bounding_box_w(self) -> np.ndarray:
        """(8, 3) corners of a world box enclosing the cylinder."""
        ends = np.vstack([self.base_w, self.top_w])
        lo, hi = ends.min(axis=0) - self.radius_m, ends.max(axis=0) + self.radius_m
        return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])

    def intersect(self, o: np.ndarray, dx, dy, dz):
        """Ray parameter of the first hit of rays o + t (dx, dy, dz) (inf: a miss) and whether it is
        on the side (a wall) rather than the top cap. The base lies on the part: never seen."""
        a = self.axis_w
        w = np.asarray(o, dtype=np.float64) - self.base_w
        wa = float(w @ a)
        da = dx * a[0] + dy * a[1] + dz * a[2]
        dpx, dpy, dpz = dx - da * a[0], dy - da * a[1], dz - da * a[2]
        wp = w - wa * a
        A = dpx * dpx + dpy * dpy + dpz * dpz
        B = dpx * wp[0] + dpy * wp[1] + dpz * wp[2]
        C = float(wp @ wp) - self.radius_m**2
        disc = B * B - A * C
        with np.errstate(invalid="ignore", divide="ignore"):
            t_side = (-B - np.sqrt(disc)) / A
            s_side = wa + t_side * da
            t_side = np.where((disc >= 0) & (s_side >= 0) & (s_side <= self.length_m) & (t_side > 0), t_side, np.inf)
            t_cap = (self.length_m - wa) / da
            px, py, pz = w[0] + t_cap * dx, w[1] + t_cap * dy, w[2] + t_cap * dz
            s = px * a[0] + py * a[1] + pz * a[2]
            r2 = px * px + py * py + pz * pz - s * s
            t_cap = np.where((r2 <= self.radius_m**2) & (t_cap > 0), t_cap, np.inf)
        t = np.minimum(t_side, t_cap)
        return t, np.isfinite(t_side) & (t_side < t_cap)


def welded_stud(stud_id: str, weld_point_w, gun_axis_w, defect: WeldDefect | None = None,
                length_m: float = DEFAULT_STUD_LENGTH_M, diameter_m: float = DEFAULT_STUD_DIAMETER_M,
                ) -> StudCylinder | None:
    """The stud a weld at ``weld_point_w`` (3,) with the gun along ``gun_axis_w`` (3,, into the part)
    leaves standing, with ``defect`` applied; None when the defect says it is missing."""
    defect = defect or WeldDefect()
    if defect.missing:
        return None
    up = -np.asarray(gun_axis_w, dtype=np.float64).reshape(3)
    up /= np.linalg.norm(up)
    R = frame_from_normal(up)
    x, y = R[:, 0], R[:, 1]
    base = np.asarray(weld_point_w, dtype=np.float64).reshape(3) + 1e-3 * (defect.offset_mm[0] * x
                                                                          + defect.offset_mm[1] * y)
    lean, az = math.radians(defect.lean_deg), math.radians(defect.lean_azimuth_deg)
    axis = math.cos(lean) * up + math.sin(lean) * (math.cos(az) * x + math.sin(az) * y)
    length = length_m if defect.height_mm is None else 1e-3 * defect.height_mm
    return StudCylinder(stud_id, base, axis / np.linalg.norm(axis), length, diameter_m / 2)


__all__ = ["DEFAULT_STUD_DIAMETER_M", "DEFAULT_STUD_LENGTH_M", "StudCylinder", "WeldDefect", "WeldDefectError",
           "parse_weld_defects", "welded_stud"]
