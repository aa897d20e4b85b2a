"""Welded studs as the simulated camera sees them: cylinders standing on the part in their weld
collar, defects and all.

After a weld the stud stands where the gun put it: its base at the weld point, its axis along the
gun's axis (outward), in a ring of weld metal at its base -- the collar, or flash -- that the
ceramic ferrule shaped: ``collar_height_mm`` high, ``collar_width_mm`` wide beyond the stud's
surface (the scene's; an M16's collar is about 21-23 mm across and 4-5 mm high), all around it. A
scene can make some welds go wrong, keyed by the scene's stud ids (the scene file's
``weld_defects``, an interface: validated here with errors that name the stud and the field)::

    "weld_defects": {"S0004": {"lean_deg": 8.0, "lean_azimuth_deg": 30.0},
                     "S0007": {"offset_mm": [4.0, 0.0]},
                     "S0011": {"missing": true},
                     "S0013": {"height_mm": 128.0},
                     "S0015": {"collar_coverage_deg": 250.0, "collar_gap_azimuth_deg": 90.0}}

- ``lean_deg`` / ``lean_azimuth_deg``: the stud leans this far from the gun's axis, toward this
  azimuth in the weld point's tangent frame (x = world X projected onto the tangent plane, y =
  normal x x: stud_common.rotations.frame_from_normal);
- ``offset_mm``: its base lies this far from the weld point, (x, y) in that tangent frame;
- ``missing``: no stud stands there (the arc failed, or it fell off);
- ``height_mm``: it stands this tall instead of the scene's ``stud_length_mm`` (burn-off gone wrong);
- ``collar_coverage_deg``: its collar covers only this much of the 360 deg (arc blow: a one-sided
  collar), the gap centred on ``collar_gap_azimuth_deg`` (the tangent frame's, as the lean's);
- ``collar_height_mm``: its collar stands this high instead of the scene's (0: no collar at all).

Defects are the scene's: the camera attaches each to the weld nearest to its scene stud's position
(:class:`DefectsByPosition`), whatever the welding cell calls that stud.

The scene's ``stud_length_mm`` (after weld, default 150: an M16x150) and ``stud_diameter_mm``
(default 16) size every stud. Frames and units: `world`, metres, unit axes.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from stud_common.rotations import frame_from_normal

#: An M16x150 shear stud, as welded, in its weld collar (ferrule-shaped: about 22 mm across, 4 mm high).
DEFAULT_STUD_LENGTH_M = 0.150
DEFAULT_STUD_DIAMETER_M = 0.016
DEFAULT_COLLAR_HEIGHT_M = 0.004
DEFAULT_COLLAR_WIDTH_M = 0.003
#: How far below the part's tangent plane the collar's ring reaches (into the part), so a curved part
#: never shows a slit under it [m].
_COLLAR_FOOT_M = 0.002


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
    collar_coverage_deg: float = 360.0
    collar_gap_azimuth_deg: float = 0.0
    collar_height_mm: float | None = None

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
        if self.collar_coverage_deg < 360.0:
            d.update(collar_coverage_deg=self.collar_coverage_deg, collar_gap_azimuth_deg=self.collar_gap_azimuth_deg)
        if self.collar_height_mm is not None:
            d["collar_height_mm"] = self.collar_height_mm
        return d

    def kinds(self) -> list[str]:
        """What goes wrong, in words (for logs): e.g. ``["lean 8 deg", "collar 250 deg"]``."""
        out = []
        if self.missing:
            out.append("missing")
        if self.lean_deg:
            out.append(f"lean {self.lean_deg:g} deg")
        if any(self.offset_mm):
            out.append(f"offset {math.hypot(*self.offset_mm):g} mm")
        if self.height_mm is not None:
            out.append(f"height {self.height_mm:g} mm")
        if self.collar_coverage_deg < 360.0:
            out.append(f"collar {self.collar_coverage_deg:g} deg")
        if self.collar_height_mm is not None:
            out.append(f"collar height {self.collar_height_mm:g} mm")
        return out


_FIELDS = {"lean_deg", "lean_azimuth_deg", "offset_mm", "missing", "height_mm", "collar_coverage_deg",
           "collar_gap_azimuth_deg", "collar_height_mm"}


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
            collar_coverage_deg=_number(sid, "collar_coverage_deg", d.get("collar_coverage_deg", 360.0), 0.0, 360.0),
            collar_gap_azimuth_deg=_number(sid, "collar_gap_azimuth_deg", d.get("collar_gap_azimuth_deg", 0.0),
                                           -360.0, 360.0),
            collar_height_mm=(None if d.get("collar_height_mm") is None
                              else _number(sid, "collar_height_mm", d["collar_height_mm"], 0.0, 50.0)),
        )
    return out


@dataclass(frozen=True)
class StudCollar:
    """A weld collar: a ring of weld metal around a stud's base ``centre_w`` (3,), in the plane across
    the surface normal ``up_w`` (3,, unit): from the stud's ``inner_radius_m`` out ``width_m``, its
    flat top ``height_m`` above the surface, covering ``coverage_deg`` of the circle -- the gap centred
    on ``gap_azimuth_deg`` in the tangent frame of ``up_w`` (stud_common.rotations.frame_from_normal).
    Its foot reaches a little into the part. Ray-cast like the scene's solids (world, metres)."""

    centre_w: np.ndarray
    up_w: np.ndarray
    inner_radius_m: float
    width_m: float
    height_m: float
    coverage_deg: float = 360.0
    gap_azimuth_deg: float = 0.0

    @property
    def outer_radius_m(self) -> float:
        return self.inner_radius_m + self.width_m

    def bounding_box_w(self) -> np.ndarray:
        """(8, 3) corners of a world box enclosing the ring."""
        ends = np.vstack([self.centre_w - _COLLAR_FOOT_M * self.up_w, self.centre_w + self.height_m * self.up_w])
        r = self.outer_radius_m
        lo, hi = ends.min(axis=0) - r, ends.max(axis=0) + r
        return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])

    def covers(self, azimuth_rad) -> np.ndarray:
        """Whether the collar stands at these azimuths (tangent frame, radians; any shape)."""
        if self.coverage_deg >= 360.0:
            return np.ones(np.shape(azimuth_rad), dtype=bool)
        off = np.angle(np.exp(1j * (np.asarray(azimuth_rad) - math.radians(self.gap_azimuth_deg))))
        return np.abs(off) >= math.radians(360.0 - self.coverage_deg) / 2

    def intersect(self, o: np.ndarray, dx, dy, dz):
        """Ray parameter of the first hit of rays o + t (dx, dy, dz) (inf: a miss) and whether it is on
        a wall (the outer wall or a gap's end face) rather than the top. The inner wall lies against
        the stud and the foot inside the part: never seen."""
        R = frame_from_normal(self.up_w)
        e1, e2, a = R[:, 0], R[:, 1], R[:, 2]
        w = np.asarray(o, dtype=np.float64) - self.centre_w
        w1, w2, wa = float(w @ e1), float(w @ e2), float(w @ a)
        d1 = dx * e1[0] + dy * e1[1] + dz * e1[2]
        d2 = dx * e2[0] + dy * e2[1] + dz * e2[2]
        da = dx * a[0] + dy * a[1] + dz * a[2]
        r_in, r_out, h = self.inner_radius_m, self.outer_radius_m, self.height_m

        def inside(t, radial_ok=True, height_ok=True):
            x, y, s = w1 + t * d1, w2 + t * d2, wa + t * da
            rho = np.hypot(x, y)
            ok = (t > 0) & np.isfinite(t) & self.covers(np.arctan2(y, x))
            if radial_ok:
                ok &= (rho >= r_in) & (rho <= r_out)
            if height_ok:
                ok &= (s >= -_COLLAR_FOOT_M) & (s <= h)
            return ok

        with np.errstate(invalid="ignore", divide="ignore"):
            t_top = (h - wa) / da
            t_top = np.where(inside(t_top, height_ok=False), t_top, np.inf)
            A = d1 * d1 + d2 * d2
            B = w1 * d1 + w2 * d2
            disc = B * B - A * (w1 * w1 + w2 * w2 - r_out**2)
            t_out = (-B - np.sqrt(disc)) / A
            t_out = np.where((disc >= 0) & inside(t_out, radial_ok=False), t_out, np.inf)
            t_wall = t_out
            if self.coverage_deg < 360.0:  # the gap's two end faces: half-planes through the axis
                half = math.radians(360.0 - self.coverage_deg) / 2
                for phi in (math.radians(self.gap_azimuth_deg) - half, math.radians(self.gap_azimuth_deg) + half):
                    n1, n2 = -math.sin(phi), math.cos(phi)
                    t_end = -(w1 * n1 + w2 * n2) / (d1 * n1 + d2 * n2)
                    x, y = w1 + t_end * d1, w2 + t_end * d2
                    along = x * math.cos(phi) + y * math.sin(phi)
                    s = wa + t_end * da
                    ok = ((t_end > 0) & (along >= r_in) & (along <= r_out) & (s >= -_COLLAR_FOOT_M) & (s <= h))
                    t_wall = np.minimum(t_wall, np.where(ok, t_end, np.inf))
        t = np.minimum(t_top, t_wall)
        return t, np.isfinite(t_wall) & (t_wall < t_top)


@dataclass(frozen=True)
class StudCylinder:
    """A welded stud: a solid cylinder from ``base_w`` (3,) along the unit ``axis_w`` (3,) for
    ``length_m``, of ``radius_m`` (world, metres). Ray-cast like the scene's solids."""

    stud_id: str
    base_w: np.ndarray
    axis_w: np.ndarray
    length_m: float
    radius_m: float
    collar: StudCollar | None = None  # its weld collar (rendered as a solid of its own)

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
                collar_height_m: float = DEFAULT_COLLAR_HEIGHT_M, collar_width_m: float = DEFAULT_COLLAR_WIDTH_M,
                ) -> StudCylinder | None:
    """The stud a weld at ``weld_point_w`` (3,) with the gun along ``gun_axis_w`` (3,, into the part)
    leaves standing, in its collar (``collar_height_m`` high, ``collar_width_m`` wide; none when 0),
    with ``defect`` applied; None when the defect says it is missing."""
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
    collar_h = collar_height_m if defect.collar_height_mm is None else 1e-3 * defect.collar_height_mm
    collar = None
    if collar_h > 0 and collar_width_m > 0 and defect.collar_coverage_deg > 0:
        collar = StudCollar(base, up, diameter_m / 2, collar_width_m, collar_h, defect.collar_coverage_deg,
                            defect.collar_gap_azimuth_deg)
    return StudCylinder(stud_id, base, axis / np.linalg.norm(axis), length, diameter_m / 2, collar)


class DefectsByPosition:
    """A scene's weld defects attached to welds by where the studs are, not by what anyone calls them.

    A scene file numbers its studs its own way; the welding cell numbers the drawing's (``S0001``...).
    A weld at ``weld_point_w`` takes the defect of the scene stud nearest to it in world XY, if that
    stud lies within ``reach_m`` (default: half the smallest spacing between the scene's studs, so no
    weld can take two studs' defects). ``studs_xy_w`` (N, 2) and ``stud_ids`` (N,) are the scene's.
    """

    def __init__(self, studs_xy_w, stud_ids, defects: Mapping[str, WeldDefect], reach_m: float | None = None):
        self.xy = np.asarray(studs_xy_w, dtype=np.float64).reshape(-1, 2)
        self.ids = tuple(stud_ids)
        self.defects = dict(defects)
        if reach_m is None:
            d = np.linalg.norm(self.xy[:, None] - self.xy[None], axis=-1) if len(self.xy) > 1 else np.zeros((1, 1))
            d[np.eye(len(d), dtype=bool)] = np.inf
            reach_m = 0.5 * float(d.min()) if len(self.xy) > 1 else 0.05
        self.reach_m = reach_m

    def nearest(self, weld_point_w) -> tuple[str | None, float]:
        """The scene stud a weld at ``weld_point_w`` (3,) made (None: none within reach) and its distance [m]."""
        if not len(self.xy):
            return None, math.inf
        d = np.linalg.norm(self.xy - np.asarray(weld_point_w, dtype=np.float64).reshape(-1)[:2], axis=1)
        k = int(np.argmin(d))
        return (self.ids[k] if d[k] <= self.reach_m else None), float(d[k])

    def never_welded(self, welded_scene_ids) -> list[str]:
        """The scene studs with a defect that no weld has reached (in scene order)."""
        done = set(welded_scene_ids)
        return [sid for sid in self.ids if sid in self.defects and sid not in done]


__all__ = ["DEFAULT_COLLAR_HEIGHT_M", "DEFAULT_COLLAR_WIDTH_M", "DEFAULT_STUD_DIAMETER_M", "DEFAULT_STUD_LENGTH_M",
           "DefectsByPosition", "StudCollar", "StudCylinder", "WeldDefect", "WeldDefectError", "parse_weld_defects",
           "welded_stud"]
