"""Deterministic synthetic RGB-D scenes with exact ground truth.

Used by the tests, the benchmarks, the simulated camera node and the demo. A scene is the
paper's set-up: a working plane (world z = 0, z up, metres), a marking board (a flat raised
plate carrying the dark circular marks O, A, B) and one curved steel component (a dome, a
horizontal cylinder section, a tilted plate or a flat plate) with the stud positions drawn on
it as small dark circles or crosses.

Frames: the drawing frame has its origin at mark O, x toward A, y toward B (metres); the
board is printed in that frame and ``SceneSpec.drawing_to_world`` (a 2D rigid pose) places it
on the working plane, so the true ``M_local2world`` of a scene is exactly that pose. Stud
positions are given in the drawing frame, as in a layout drawing.

Rendering casts one ray per pixel through :class:`~stud_perception.camera_model.CameraModel`
(the one Eq. 1 implementation) and intersects it analytically with every solid, so the
noise-free depth, the surface of each pixel and the per-stud surface points and normals are
exact. Depth is the optical-frame z, quantised to millimetres in the 16UC1 image.
"""
from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any, ClassVar, Union

import cv2
import numpy as np

from stud_perception.camera_model import CameraModel, nadir_rotation
from stud_perception.depth_image import depth_m_to_mm, depth_mm_to_m
from stud_perception.welded_studs import (DEFAULT_STUD_DIAMETER_M, DEFAULT_STUD_LENGTH_M, StudCylinder,
                                         WeldDefectError, parse_weld_defects)


class SceneError(ValueError):
    """A scene description that cannot be rendered (names the field and the value)."""


# Surface ids of :attr:`RenderedView.surface_id`.
SURFACE_NONE = -1
SURFACE_TABLE = 0
SURFACE_BOARD = 1
SURFACE_COMPONENT = 2
SURFACE_OBSTACLE = 3
SURFACE_STUD = 4  # a welded stud (stud_perception.welded_studs)

# Appearance (8-bit grey levels before shading, BGR tints). Dark marks on a light board
# and a mid-grey table give the contrast the paper's Hough stage relies on.
_TABLE_GREY = 120.0
_BOARD_GREY = 228.0
_MARK_GREY = 22.0
_STEEL_GREY = 185.0
_STUD_MARK_GREY = 30.0
_STUD_GREY = 205.0  # bright steel of a welded stud
_TINT_BGR = {
    SURFACE_TABLE: (0.92, 1.0, 1.06),
    SURFACE_BOARD: (1.0, 1.0, 1.0),
    SURFACE_COMPONENT: (1.04, 1.0, 0.97),
    SURFACE_OBSTACLE: (1.0, 0.98, 0.92),
    SURFACE_STUD: (0.98, 0.98, 1.02),
}
# Lambertian shading with a light slightly off vertical, so curvature is visible in colour.
_LIGHT_DIR_W = np.array([0.25, 0.15, 1.0]) / np.linalg.norm([0.25, 0.15, 1.0])
_AMBIENT = 0.35
_WALL_SHADE = 0.55
# A stud counts as visible when the rendered depth at its pixel agrees with its own depth:
# larger than the nearest-pixel rounding error on steep surfaces, smaller than a board edge.
_VISIBLE_TOL_M = 0.002


def _pair(value, name: str) -> tuple[float, float]:
    arr = np.asarray(value, dtype=np.float64).ravel()
    if arr.shape != (2,) or not np.all(np.isfinite(arr)):
        raise SceneError(f"{name} must be two finite numbers, got {value!r}")
    return float(arr[0]), float(arr[1])


# -- 2D pose -------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Pose2D:
    """Rigid 2D transform drawing -> world on the working plane: rotate by ``yaw_rad``, then
    translate by (``x_m``, ``y_m``)."""

    x_m: float = 0.0
    y_m: float = 0.0
    yaw_rad: float = 0.0

    def matrix(self) -> np.ndarray:
        """3x3 homogeneous matrix (the form of the paper's M_local2world, Eq. 2)."""
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        return np.array([[c, -s, self.x_m], [s, c, self.y_m], [0.0, 0.0, 1.0]])

    def apply(self, xy_m) -> np.ndarray:
        """Points (..., 2) drawing -> world, metres."""
        xy = np.asarray(xy_m, dtype=np.float64)
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        return np.stack([c * xy[..., 0] - s * xy[..., 1] + self.x_m, s * xy[..., 0] + c * xy[..., 1] + self.y_m], -1)

    def apply_inverse(self, xy_m) -> np.ndarray:
        """Points (..., 2) world -> drawing, metres."""
        xy = np.asarray(xy_m, dtype=np.float64)
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        dx, dy = xy[..., 0] - self.x_m, xy[..., 1] - self.y_m
        return np.stack([c * dx + s * dy, -s * dx + c * dy], -1)


# -- solids --------------------------------------------------------------------------------------
# Every solid is a prism over a footprint on the working plane, capped by a height field:
# {(x, y, z): (x, y) in footprint, 0 <= z <= top(x, y)}. Rays come from a camera above the
# plane; ``intersect`` returns the ray parameter t of the first hit (inf for a miss) and
# whether the hit is on a vertical wall rather than the top. Directions are per metre of
# optical depth, so t is the optical-frame depth of the hit.
_INF = np.inf


def _first_positive(*ts: np.ndarray) -> np.ndarray:
    best = np.full(ts[0].shape, _INF)
    for t in ts:
        best = np.where((t > 0) & (t < best), t, best)
    return best


def _box_corners(centre_xy: np.ndarray, half_axes: np.ndarray, top_m: float) -> np.ndarray:
    """(8, 3) corners of the prism over the rectangle centre +- half_axes[0] +- half_axes[1], z in [0, top]."""
    corners = []
    for a in (-1, 1):
        for b in (-1, 1):
            xy = centre_xy + a * half_axes[0] + b * half_axes[1]
            corners += [[xy[0], xy[1], 0.0], [xy[0], xy[1], top_m]]
    return np.array(corners)


@dataclass(frozen=True)
class Dome:
    """Spherical cap on the working plane: base circle of ``base_radius_m`` at ``centre_xy_m``
    (world), apex ``height_m`` above the plane."""

    centre_xy_m: tuple[float, float]
    base_radius_m: float
    height_m: float
    kind: ClassVar[str] = "dome"

    def __post_init__(self) -> None:
        object.__setattr__(self, "centre_xy_m", _pair(self.centre_xy_m, "dome centre_xy_m"))
        if not (self.base_radius_m > 0 and 0 < self.height_m <= self.base_radius_m):
            raise SceneError(
                f"dome needs 0 < height_m <= base_radius_m, got height_m={self.height_m}, "
                f"base_radius_m={self.base_radius_m}"
            )

    @property
    def sphere_radius_m(self) -> float:
        r, h = self.base_radius_m, self.height_m
        return (r * r + h * h) / (2.0 * h)

    @property
    def sphere_centre_w(self) -> np.ndarray:
        return np.array([*self.centre_xy_m, self.height_m - self.sphere_radius_m])

    def top_height(self, x, y):
        """(z of the cap at world (x, y), inside footprint) — vectorised, metres."""
        c = self.sphere_centre_w
        rho2 = (np.asarray(x) - c[0]) ** 2 + (np.asarray(y) - c[1]) ** 2
        inside = rho2 <= self.base_radius_m**2
        z = c[2] + np.sqrt(np.maximum(self.sphere_radius_m**2 - rho2, 0.0))
        return np.where(inside, np.maximum(z, 0.0), 0.0), inside

    def top_normal(self, x, y) -> np.ndarray:
        """Unit outward normal (..., 3) of the cap above world (x, y)."""
        c = self.sphere_centre_w
        z, _ = self.top_height(x, y)
        n = np.stack(np.broadcast_arrays(np.asarray(x) - c[0], np.asarray(y) - c[1], z - c[2]), -1)
        return n / self.sphere_radius_m

    def bounding_box_w(self) -> np.ndarray:
        """(8, 3) corners of a world box enclosing the solid (to cast only the rays that may hit)."""
        r = self.base_radius_m
        return _box_corners(np.asarray(self.centre_xy_m), np.array([[r, 0.0], [0.0, r]]), self.height_m)

    def intersect(self, o: np.ndarray, dx, dy, dz):
        c = self.sphere_centre_w
        ox, oy, oz = o - c
        a = dx * dx + dy * dy + dz * dz
        b = dx * ox + dy * oy + dz * oz
        cc = ox * ox + oy * oy + oz * oz - self.sphere_radius_m**2
        disc = b * b - a * cc
        with np.errstate(invalid="ignore"):
            t = (-b - np.sqrt(disc)) / a
        # Rays come from above: a near-side hit below the plane is hidden by the plane itself.
        ok = (disc >= 0) & (o[2] + t * dz >= 0.0)
        return np.where(ok, t, _INF), np.zeros(t.shape, dtype=bool)


@dataclass(frozen=True)
class Cylinder:
    """Section of a horizontal cylinder (axis parallel to the plane): ``radius_m``, axis through
    world ``centre_xy_m`` at yaw ``axis_yaw_rad``, ``length_m`` along the axis, crown
    ``height_m`` above the plane (``height_m <= radius_m``, the sagitta of the section)."""

    centre_xy_m: tuple[float, float]
    radius_m: float
    axis_yaw_rad: float
    length_m: float
    height_m: float
    kind: ClassVar[str] = "cylinder"

    def __post_init__(self) -> None:
        object.__setattr__(self, "centre_xy_m", _pair(self.centre_xy_m, "cylinder centre_xy_m"))
        if not (self.radius_m > 0 and 0 < self.height_m <= self.radius_m and self.length_m > 0):
            raise SceneError(
                f"cylinder needs 0 < height_m <= radius_m and length_m > 0, got radius_m={self.radius_m}, "
                f"height_m={self.height_m}, length_m={self.length_m}"
            )

    @property
    def axis_z_m(self) -> float:
        return self.height_m - self.radius_m

    @property
    def half_chord_m(self) -> float:
        return math.sqrt(self.radius_m**2 - self.axis_z_m**2)

    def _local(self, x, y):
        c, s = math.cos(self.axis_yaw_rad), math.sin(self.axis_yaw_rad)
        dx, dy = np.asarray(x) - self.centre_xy_m[0], np.asarray(y) - self.centre_xy_m[1]
        return c * dx + s * dy, -s * dx + c * dy  # along the axis, across it

    def top_height(self, x, y):
        along, across = self._local(x, y)
        inside = (np.abs(along) <= self.length_m / 2) & (np.abs(across) <= self.half_chord_m)
        z = self.axis_z_m + np.sqrt(np.maximum(self.radius_m**2 - across**2, 0.0))
        return np.where(inside, np.maximum(z, 0.0), 0.0), inside

    def top_normal(self, x, y) -> np.ndarray:
        _, across = self._local(x, y)
        z, _ = self.top_height(x, y)
        c, s = math.cos(self.axis_yaw_rad), math.sin(self.axis_yaw_rad)
        n = np.stack(np.broadcast_arrays(-s * across, c * across, z - self.axis_z_m), -1)
        return n / self.radius_m

    def bounding_box_w(self) -> np.ndarray:
        c, s = math.cos(self.axis_yaw_rad), math.sin(self.axis_yaw_rad)
        half = np.array([[c, s], [-s, c]]) * np.array([[self.length_m / 2], [self.half_chord_m]])
        return _box_corners(np.asarray(self.centre_xy_m), half, self.height_m)

    def intersect(self, o: np.ndarray, dx, dy, dz):
        c, s = math.cos(self.axis_yaw_rad), math.sin(self.axis_yaw_rad)
        ox, oy = o[0] - self.centre_xy_m[0], o[1] - self.centre_xy_m[1]
        oz = o[2] - self.axis_z_m
        al_o, ac_o = c * ox + s * oy, -s * ox + c * oy
        al_d, ac_d = c * dx + s * dy, -s * dx + c * dy
        # Curved top: circle in the (across, z) plane.
        a = ac_d * ac_d + dz * dz
        b = ac_o * ac_d + oz * dz
        cc = ac_o * ac_o + oz * oz - self.radius_m**2
        disc = b * b - a * cc
        with np.errstate(invalid="ignore", divide="ignore"):
            t_top = (-b - np.sqrt(disc)) / a
        ok = (disc >= 0) & (o[2] + t_top * dz >= 0) & (np.abs(al_o + t_top * al_d) <= self.length_m / 2)
        t_top = np.where(ok, t_top, _INF)
        # Flat end faces (circular segments) at along = +-length/2.
        t_ends = []
        for end in (-self.length_m / 2, self.length_m / 2):
            with np.errstate(invalid="ignore", divide="ignore"):
                t = (end - al_o) / al_d
            ac, z = ac_o + t * ac_d, oz + t * dz
            ok = np.isfinite(t) & (z + self.axis_z_m >= 0) & (ac * ac + z * z <= self.radius_m**2)
            t_ends.append(np.where(ok, t, _INF))
        t_wall = _first_positive(*t_ends)
        t = _first_positive(t_top, t_wall)
        return t, np.isfinite(t_wall) & (t_wall < t_top)


@dataclass(frozen=True)
class Trough:
    """Concave section of a horizontal cylinder -- the inside of a tank shell or a pipe: the top
    of a block of ``width_m`` (across the axis) x ``length_m`` (along it) is the lower arc of a
    circle of ``radius_m``, its rims ``rim_height_m`` above the plane; axis through world
    ``centre_xy_m`` at yaw ``axis_yaw_rad``. Its slope at the rims is asin(width / (2 radius))."""

    centre_xy_m: tuple[float, float]
    radius_m: float
    axis_yaw_rad: float
    length_m: float
    width_m: float
    rim_height_m: float
    kind: ClassVar[str] = "trough"

    def __post_init__(self) -> None:
        object.__setattr__(self, "centre_xy_m", _pair(self.centre_xy_m, "trough centre_xy_m"))
        if not (self.radius_m > 0 and 0 < self.width_m < 2 * self.radius_m and self.length_m > 0):
            raise SceneError(
                f"trough needs 0 < width_m < 2 radius_m and length_m > 0, got radius_m={self.radius_m}, "
                f"width_m={self.width_m}, length_m={self.length_m}"
            )
        if not self.rim_height_m > self.sagitta_m:
            raise SceneError(
                f"trough bottom would be below the working plane: rim_height_m={self.rim_height_m} must exceed "
                f"its depth {self.sagitta_m:.4f} m (radius_m={self.radius_m}, width_m={self.width_m})"
            )

    @property
    def sagitta_m(self) -> float:
        r, c = self.radius_m, self.width_m / 2
        return r - math.sqrt(r * r - c * c)

    @property
    def axis_z_m(self) -> float:
        """Height of the circle's centre (above the rims)."""
        return self.rim_height_m + math.sqrt(self.radius_m**2 - (self.width_m / 2) ** 2)

    def _local(self, x, y):
        c, s = math.cos(self.axis_yaw_rad), math.sin(self.axis_yaw_rad)
        dx, dy = np.asarray(x) - self.centre_xy_m[0], np.asarray(y) - self.centre_xy_m[1]
        return c * dx + s * dy, -s * dx + c * dy  # along the axis, across it

    def top_height(self, x, y):
        along, across = self._local(x, y)
        inside = (np.abs(along) <= self.length_m / 2) & (np.abs(across) <= self.width_m / 2)
        z = self.axis_z_m - np.sqrt(np.maximum(self.radius_m**2 - across**2, 0.0))
        return np.where(inside, z, 0.0), inside

    def top_normal(self, x, y) -> np.ndarray:
        _, across = self._local(x, y)
        c, s = math.cos(self.axis_yaw_rad), math.sin(self.axis_yaw_rad)
        up = np.sqrt(np.maximum(self.radius_m**2 - across**2, 0.0))
        n = np.stack(np.broadcast_arrays(s * across, -c * across, up), -1)  # toward the axis
        return n / self.radius_m

    def bounding_box_w(self) -> np.ndarray:
        c, s = math.cos(self.axis_yaw_rad), math.sin(self.axis_yaw_rad)
        half = np.array([[c, s], [-s, c]]) * np.array([[self.length_m / 2], [self.width_m / 2]])
        return _box_corners(np.asarray(self.centre_xy_m), half, self.rim_height_m)

    def intersect(self, o: np.ndarray, dx, dy, dz):
        c, s = math.cos(self.axis_yaw_rad), math.sin(self.axis_yaw_rad)
        ox, oy = o[0] - self.centre_xy_m[0], o[1] - self.centre_xy_m[1]
        oz = o[2] - self.axis_z_m
        al_o, ac_o = c * ox + s * oy, -s * ox + c * oy
        al_d, ac_d = c * dx + s * dy, -s * dx + c * dy
        hl, hw = self.length_m / 2, self.width_m / 2
        # Concave top: the ray's exit from the circle in the (across, z) plane (the far root).
        a = ac_d * ac_d + dz * dz
        b = ac_o * ac_d + oz * dz
        cc = ac_o * ac_o + oz * oz - self.radius_m**2
        disc = b * b - a * cc
        with np.errstate(invalid="ignore", divide="ignore"):
            t_top = (-b + np.sqrt(disc)) / a
        ok = ((disc >= 0) & (np.abs(al_o + t_top * al_d) <= hl) & (np.abs(ac_o + t_top * ac_d) <= hw)
              & (oz + t_top * dz <= self.rim_height_m - self.axis_z_m))
        t_top = np.where(ok, t_top, _INF)
        # Outer walls: the two long sides (up to the rims) and the two ends (up to the arc).
        walls = []
        for end in (-hw, hw):
            with np.errstate(invalid="ignore", divide="ignore"):
                t = (end - ac_o) / ac_d
            z = o[2] + t * dz
            ok = np.isfinite(t) & (np.abs(al_o + t * al_d) <= hl) & (z >= 0) & (z <= self.rim_height_m)
            walls.append(np.where(ok, t, _INF))
        for end in (-hl, hl):
            with np.errstate(invalid="ignore", divide="ignore"):
                t = (end - al_o) / al_d
            ac, z = ac_o + t * ac_d, o[2] + t * dz
            top = self.axis_z_m - np.sqrt(np.maximum(self.radius_m**2 - ac * ac, 0.0))
            ok = np.isfinite(t) & (np.abs(ac) <= hw) & (z >= 0) & (z <= top)
            walls.append(np.where(ok, t, _INF))
        t_wall = _first_positive(*walls)
        t = _first_positive(t_top, t_wall)
        return t, np.isfinite(t_wall) & (t_wall < t_top)


@dataclass(frozen=True)
class Plate:
    """Rectangular plate: footprint ``size_m`` = (length along the plate's x, width along its y)
    centred at world ``centre_xy_m``, x at ``yaw_rad``; top at ``height_m`` over the centre,
    tilted by ``tilt_rad`` about the plate's x axis (the top rises toward +y). ``tilt_rad = 0``
    is the flat ``plane`` kind; the marking board is a flat plate too."""

    centre_xy_m: tuple[float, float]
    size_m: tuple[float, float]
    yaw_rad: float
    height_m: float
    tilt_rad: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "centre_xy_m", _pair(self.centre_xy_m, "plate centre_xy_m"))
        object.__setattr__(self, "size_m", _pair(self.size_m, "plate size_m"))
        if min(self.size_m) <= 0 or self.height_m <= 0:
            raise SceneError(
                f"plate needs a positive size and height, got size_m={self.size_m}, height_m={self.height_m}"
            )
        if not abs(self.tilt_rad) < math.radians(80):
            raise SceneError(f"plate tilt {math.degrees(self.tilt_rad):.1f} deg is beyond 80 deg")
        low = self.height_m - abs(math.tan(self.tilt_rad)) * self.size_m[1] / 2
        if low < 0:
            raise SceneError(
                f"tilted plate dips below the working plane (low edge at {low * 1000:.1f} mm): raise height_m "
                f"above {abs(math.tan(self.tilt_rad)) * self.size_m[1] / 2:.4f} m or reduce tilt/width"
            )

    @property
    def kind(self) -> str:
        return "tilted_plane" if self.tilt_rad != 0 else "plane"

    def _local(self, x, y):
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        dx, dy = np.asarray(x) - self.centre_xy_m[0], np.asarray(y) - self.centre_xy_m[1]
        return c * dx + s * dy, -s * dx + c * dy

    def top_height(self, x, y):
        px, py = self._local(x, y)
        inside = (np.abs(px) <= self.size_m[0] / 2) & (np.abs(py) <= self.size_m[1] / 2)
        z = self.height_m + math.tan(self.tilt_rad) * py
        return np.where(inside, z, 0.0), inside

    def top_normal(self, x, y) -> np.ndarray:
        k = math.tan(self.tilt_rad)
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        n = np.array([k * s, -k * c, 1.0]) / math.sqrt(1 + k * k)  # gradient of z is k * e_y
        shape = np.broadcast(np.asarray(x), np.asarray(y)).shape
        return np.broadcast_to(n, shape + (3,)).copy()

    def bounding_box_w(self) -> np.ndarray:
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        half = np.array([[c, s], [-s, c]]) * np.array([[self.size_m[0] / 2], [self.size_m[1] / 2]])
        top = self.height_m + abs(math.tan(self.tilt_rad)) * self.size_m[1] / 2
        return _box_corners(np.asarray(self.centre_xy_m), half, top)

    def intersect(self, o: np.ndarray, dx, dy, dz):
        k = math.tan(self.tilt_rad)
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        ox, oy = o[0] - self.centre_xy_m[0], o[1] - self.centre_xy_m[1]
        px_o, py_o = c * ox + s * oy, -s * ox + c * oy
        px_d, py_d = c * dx + s * dy, -s * dx + c * dy
        hx, hy = self.size_m[0] / 2, self.size_m[1] / 2
        with np.errstate(invalid="ignore", divide="ignore"):
            t_top = (self.height_m + k * py_o - o[2]) / (dz - k * py_d)
        ok = (np.abs(px_o + t_top * px_d) <= hx) & (np.abs(py_o + t_top * py_d) <= hy)
        t_top = np.where(ok, t_top, _INF)
        walls = []
        for axis_o, axis_d, other_o, other_d, half, other_half, across in (
            (px_o, px_d, py_o, py_d, hx, hy, False),
            (py_o, py_d, px_o, px_d, hy, hx, True),
        ):
            for side in (-half, half):
                with np.errstate(invalid="ignore", divide="ignore"):
                    t = (side - axis_o) / axis_d
                z = o[2] + t * dz
                py_hit = side if across else py_o + t * py_d
                ok = np.isfinite(t) & (np.abs(other_o + t * other_d) <= other_half) & (z >= 0) & (
                    z <= self.height_m + k * py_hit
                )
                walls.append(np.where(ok, t, _INF))
        t_wall = _first_positive(*walls)
        t = _first_positive(t_top, t_wall)
        return t, np.isfinite(t_wall) & (t_wall < t_top)


Component = Union[Dome, Cylinder, Trough, Plate]


# -- scene description ------------------------------------------------------------------------
@dataclass(frozen=True)
class MarkingBoard:
    """The marking board: a flat plate of ``thickness_m`` with dark filled circles O, A, B of
    ``mark_diameter_m`` at ``marks_drawing_m`` (drawing frame, metres, rows O, A, B). The plate
    covers the marks' bounding box plus ``margin_m`` beyond each mark's edge."""

    marks_drawing_m: tuple[tuple[float, float], ...] = ((0.0, 0.0), (0.13, 0.0), (0.0, 0.10))
    mark_diameter_m: float = 0.02
    thickness_m: float = 0.005
    margin_m: float = 0.012

    def __post_init__(self) -> None:
        marks = np.asarray(self.marks_drawing_m, dtype=np.float64)
        if marks.shape != (3, 2):
            raise SceneError(f"board marks_drawing_m must be 3 (x, y) pairs O, A, B, got shape {marks.shape}")
        object.__setattr__(self, "marks_drawing_m", tuple(tuple(float(c) for c in m) for m in marks))
        if self.mark_diameter_m <= 0 or self.thickness_m <= 0 or self.margin_m < 0:
            raise SceneError(
                f"board needs positive mark_diameter_m and thickness_m, margin_m >= 0, got "
                f"{self.mark_diameter_m}, {self.thickness_m}, {self.margin_m}"
            )


@dataclass(frozen=True)
class SceneSpec:
    """Everything a view of the work cell shows (world frame, metres).

    ``drawing_to_world`` places the drawing frame (and with it the board) on the plane;
    ``studs_drawing_m`` (N, 2) are stud positions in the drawing frame, ``stud_ids`` their
    names; ``stud_mark_style`` is ``circle``, ``cross`` or ``none``. ``obstacles``: flat boxes
    standing on the plane (stiffeners, webs, flanges: world frame, their tops ``height_m`` above
    the plane) that a welding gun must not hit. ``specular_lobe_deg``: the component is shiny
    steel -- a structured-light camera gets no depth where the surface mirrors its projector into
    the camera, within this angle (0: a matte part). ``stud_length_m`` / ``stud_diameter_m``: the
    welded studs' size, ``weld_defects``: {stud id: WeldDefect} (stud_perception.welded_studs).
    """

    component: Component | None
    board: MarkingBoard = field(default_factory=MarkingBoard)
    drawing_to_world: Pose2D = field(default_factory=Pose2D)
    studs_drawing_m: tuple[tuple[float, float], ...] = ()
    stud_ids: tuple[str, ...] = ()
    stud_mark_diameter_m: float = 0.008
    stud_mark_style: str = "circle"
    obstacles: tuple[Plate, ...] = ()
    specular_lobe_deg: float = 0.0
    stud_length_m: float = DEFAULT_STUD_LENGTH_M
    stud_diameter_m: float = DEFAULT_STUD_DIAMETER_M
    weld_defects: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not (0.001 <= self.stud_length_m <= 1.0 and 0.001 <= self.stud_diameter_m <= 0.1):
            raise SceneError(f"stud_length_mm={self.stud_length_m * 1e3:g} and stud_diameter_mm="
                             f"{self.stud_diameter_m * 1e3:g} must be in [1, 1000] and [1, 100] mm")
        object.__setattr__(self, "obstacles", tuple(self.obstacles))
        for i, ob in enumerate(self.obstacles):
            if not isinstance(ob, Plate) or ob.tilt_rad != 0:
                raise SceneError(f"obstacle {i} must be a flat box (plane kind), got {ob!r}")
        if not 0.0 <= self.specular_lobe_deg < 45.0:
            raise SceneError(f"specular_lobe_deg must be in [0, 45), got {self.specular_lobe_deg}")
        studs = np.asarray(self.studs_drawing_m, dtype=np.float64).reshape(-1, 2)
        object.__setattr__(self, "studs_drawing_m", tuple(tuple(float(c) for c in p) for p in studs))
        ids = tuple(str(i) for i in self.stud_ids) or tuple(f"S{i + 1:04d}" for i in range(len(studs)))
        if len(ids) != len(studs):
            raise SceneError(f"{len(ids)} stud ids for {len(studs)} stud positions")
        object.__setattr__(self, "stud_ids", ids)
        if self.stud_mark_style not in ("circle", "cross", "none"):
            raise SceneError(f"stud_mark_style must be circle, cross or none, got {self.stud_mark_style!r}")
        if self.stud_mark_diameter_m <= 0:
            raise SceneError(f"stud_mark_diameter_m must be positive, got {self.stud_mark_diameter_m}")

    # -- derived geometry ---------------------------------------------------------------------
    @property
    def M_local2world(self) -> np.ndarray:
        """True drawing -> world transform (3x3 homogeneous, metres), the target of Eq. 2-3."""
        return self.drawing_to_world.matrix()

    @property
    def marks_world_m(self) -> np.ndarray:
        """(3, 3) world centres of O, A, B on the board's top face."""
        xy = self.drawing_to_world.apply(np.asarray(self.board.marks_drawing_m))
        return np.column_stack([xy, np.full(3, self.board.thickness_m)])

    @property
    def studs_world_xy_m(self) -> np.ndarray:
        """(N, 2) stud positions on the working plane (world XY)."""
        return self.drawing_to_world.apply(np.asarray(self.studs_drawing_m).reshape(-1, 2))

    @property
    def board_plate(self) -> Plate:
        marks = np.asarray(self.board.marks_drawing_m)
        pad = self.board.mark_diameter_m / 2 + self.board.margin_m
        lo, hi = marks.min(axis=0) - pad, marks.max(axis=0) + pad
        centre = self.drawing_to_world.apply((lo + hi) / 2)
        return Plate(
            centre_xy_m=(float(centre[0]), float(centre[1])),
            size_m=(float(hi[0] - lo[0]), float(hi[1] - lo[1])),
            yaw_rad=self.drawing_to_world.yaw_rad,
            height_m=self.board.thickness_m,
        )


# -- vectorised ground-truth surface -----------------------------------------------------------
def _top_surface(scene: SceneSpec, x, y):
    """(height z (...), surface id (...)) of the topmost surface above world (x, y)."""
    x, y = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
    z = np.zeros(x.shape)
    sid = np.full(x.shape, SURFACE_TABLE, dtype=np.int8)
    zb, inb = scene.board_plate.top_height(x, y)
    z = np.where(inb, zb, z)
    sid[inb] = SURFACE_BOARD
    solids = [(SURFACE_COMPONENT, scene.component)] if scene.component is not None else []
    for surf, solid in solids + [(SURFACE_OBSTACLE, ob) for ob in scene.obstacles]:
        zc, inc = solid.top_height(x, y)
        higher = inc & (zc >= z)
        z = np.where(higher, zc, z)
        sid[higher] = surf
    return z, sid


def surface_height(scene: SceneSpec, x, y) -> np.ndarray:
    """World z (metres) of the top surface above world (x, y); vectorised over any shape."""
    return _top_surface(scene, x, y)[0]


def surface_normal(scene: SceneSpec, x, y) -> np.ndarray:
    """Unit outward normal (..., 3) of the top surface above world (x, y)."""
    _, sid = _top_surface(scene, x, y)
    x, y = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
    n = np.zeros(x.shape + (3,))
    n[..., 2] = 1.0
    on_comp = sid == SURFACE_COMPONENT
    if scene.component is not None and on_comp.any():
        n[on_comp] = scene.component.top_normal(x[on_comp], y[on_comp])
    return n


# -- rendering ---------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class RenderedView:
    """One synthetic RGB-D frame with its ground truth.

    Images (H, W): ``color_bgr`` uint8 (H, W, 3); ``depth_mm`` uint16 16UC1 (0 = no depth);
    ``depth_exact_m`` float64 noise-free optical-frame z before quantisation and holes (NaN
    where the ray hits nothing); ``surface_id`` int8 (SURFACE_* constants); ``hole_mask`` bool
    (depth removed by the hole model). Per stud (N = len(scene.stud_ids)): ``studs_world_m``
    (N, 3) the surface point above the stud's world XY, ``stud_normals_w`` (N, 3) unit outward
    normals, ``stud_pixels_uv`` (N, 2) its projection, ``stud_visible`` (N,) in the image and
    not occluded. Marks: ``marks_world_m`` (3, 3) O, A, B and ``marks_pixels_uv`` (3, 2).
    :func:`distort_view` turns it into the raw images of a camera with lens distortion.
    """

    color_bgr: np.ndarray
    depth_mm: np.ndarray
    depth_exact_m: np.ndarray
    surface_id: np.ndarray
    hole_mask: np.ndarray
    camera: CameraModel
    scene: SceneSpec
    seed: int
    studs_world_m: np.ndarray
    stud_normals_w: np.ndarray
    stud_pixels_uv: np.ndarray
    stud_visible: np.ndarray
    marks_world_m: np.ndarray
    marks_pixels_uv: np.ndarray
    #: Lens distortion of the images (CameraInfo D and distortion_model); () for a pinhole view.
    distortion_d: tuple = ()
    distortion_model: str = "plumb_bob"

    @property
    def depth_m(self) -> np.ndarray:
        """The 16UC1 depth as float32 metres, NaN = no depth (what a matcher sees)."""
        return depth_mm_to_m(self.depth_mm)

    def exact_points_world(self) -> np.ndarray:
        """(H, W, 3) exact world point of every pixel's surface (NaN where nothing is hit)."""
        v, u = np.mgrid[0:self.camera.height, 0:self.camera.width]
        return self.camera.pixel_to_world(u, v, self.depth_exact_m)


def _image_window(camera: CameraModel, corners_w: np.ndarray):
    """Slices (rows, cols) of the image a world box can appear in, or None if it cannot."""
    u, v, z = camera.world_to_pixel(corners_w)
    if np.any(z <= 0):  # a corner behind the camera: the projection is unbounded
        return (slice(None), slice(None))
    u0, u1 = int(max(math.floor(u.min()) - 1, 0)), int(min(math.ceil(u.max()) + 2, camera.width))
    v0, v1 = int(max(math.floor(v.min()) - 1, 0)), int(min(math.ceil(v.max()) + 2, camera.height))
    if u0 >= u1 or v0 >= v1:
        return None
    return (slice(v0, v1), slice(u0, u1))


def _coverage(signed_dist_m: np.ndarray, pixel_m: np.ndarray) -> np.ndarray:
    """Area fraction of a pixel inside a shape from the signed distance of its centre.

    A one-pixel linear ramp is the box-filtered edge: it anti-aliases the marks so their
    image centroids are unbiased to well below 0.1 px, which the marker tests rely on.
    """
    return np.clip(0.5 - signed_dist_m / pixel_m, 0.0, 1.0)


def _hole_mask(shape: tuple[int, int], fraction: float, blob_px: float, rng: np.random.Generator) -> np.ndarray:
    """Random elliptical blobs covering at least ``fraction`` of the image (deterministic per rng)."""
    mask = np.zeros(shape, dtype=np.uint8)
    if fraction <= 0:
        return mask.astype(bool)
    h, w = shape
    target = fraction * h * w
    mean_area = math.pi * blob_px * blob_px
    covered = 0
    while covered < target:
        # Add roughly half of what is missing per round, so the overshoot stays near one blob.
        n = max(1, int(0.5 * (target - covered) / mean_area))
        cx = rng.uniform(0, w, n)
        cy = rng.uniform(0, h, n)
        ax = rng.uniform(0.5, 1.5, (n, 2)) * blob_px
        ang = rng.uniform(0, 180, n)
        for i in range(n):  # cv2 draws one ellipse per call; n is small (tens to hundreds)
            cv2.ellipse(
                mask, (int(cx[i]), int(cy[i])), (max(1, int(round(ax[i, 0]))), max(1, int(round(ax[i, 1])))),
                float(ang[i]), 0, 360, 1, -1,
            )
        covered = int(np.count_nonzero(mask))
    return mask.astype(bool)


def _stud_mark_coverage(scene, camera, hit_x, hit_y, depth, px_m_per_depth):
    """(H, W) darkness coverage of the stud marks, gathered in small patches around each stud."""
    h, w = depth.shape
    cover = np.zeros(h * w, dtype=np.float32)
    if scene.stud_mark_style == "none" or not scene.stud_ids:
        return cover.reshape(h, w)
    xy = scene.studs_world_xy_m
    z = surface_height(scene, xy[:, 0], xy[:, 1])
    u, v, zc = camera.world_to_pixel(np.column_stack([xy, z]))
    r_m = scene.stud_mark_diameter_m / 2
    with np.errstate(invalid="ignore", divide="ignore"):
        r_px = camera.fx * r_m / zc
    keep = camera.in_image(u, v, margin=-float(np.nanmax(r_px, initial=0.0)) - 2) & (zc > 0)
    if not keep.any():
        return cover.reshape(h, w)
    half = int(math.ceil(np.max(r_px[keep]) * 1.6)) + 2  # 1.6: tilted views stretch a mark
    offs = np.arange(-half, half + 1)
    dv, du = [a.ravel() for a in np.meshgrid(offs, offs, indexing="ij")]
    yaw = scene.drawing_to_world.yaw_rad
    cy, sy = math.cos(yaw), math.sin(yaw)
    idx_keep = np.flatnonzero(keep)
    flat_x, flat_y, flat_d = hit_x.ravel(), hit_y.ravel(), depth.ravel()
    chunk = max(1, 2_000_000 // du.size)
    for s in range(0, idx_keep.size, chunk):
        k = idx_keep[s:s + chunk]
        cols = np.rint(u[k])[:, None].astype(np.int64) + du[None, :]
        rows = np.rint(v[k])[:, None].astype(np.int64) + dv[None, :]
        ok = (cols >= 0) & (cols < w) & (rows >= 0) & (rows < h)
        flat = np.where(ok, rows * w + cols, 0)
        ex = flat_x[flat] - xy[k, 0][:, None]
        ey = flat_y[flat] - xy[k, 1][:, None]
        if scene.stud_mark_style == "circle":
            sd = np.hypot(ex, ey) - r_m
        else:  # cross with arms along the drawing axes, arm width a fifth of its length
            lx, ly = cy * ex + sy * ey, -sy * ex + cy * ey
            arm = r_m / 5
            sd = np.minimum(
                np.maximum(np.abs(lx) - r_m, np.abs(ly) - arm), np.maximum(np.abs(ly) - r_m, np.abs(lx) - arm)
            )
        cov = _coverage(sd, flat_d[flat] * px_m_per_depth)
        cov = np.where(ok & np.isfinite(cov), cov, 0.0).astype(np.float32)
        np.maximum.at(cover, flat.ravel(), cov.ravel())
    return cover.reshape(h, w)


def render(
    scene: SceneSpec,
    camera: CameraModel,
    seed: int = 0,
    depth_noise_m: float = 0.0,
    hole_fraction: float = 0.0,
    hole_blob_px: float = 6.0,
    color_noise: float = 0.0,
    mark_depth_dropout: bool = False,
    projector_offset_m: tuple[float, float, float] = (0.05, 0.0, 0.0),
    welded: tuple[StudCylinder, ...] = (),
) -> RenderedView:
    """Ray-cast ``scene`` through ``camera`` into a colour + 16UC1 depth pair with ground truth.

    ``depth_noise_m``: std of Gaussian noise on the optical z before mm quantisation.
    ``hole_fraction``: fraction of pixels removed from the depth as random blobs of about
    ``hole_blob_px`` radius. ``color_noise``: std of Gaussian noise in grey levels.
    ``mark_depth_dropout``: structured light returns nothing from dark paint, so the marks
    and stud marks lose their depth too. ``projector_offset_m``: the structured-light
    projector's position in the optical frame; with the scene's ``specular_lobe_deg``, the
    component loses its depth where it mirrors the projector into the camera (a hole that moves
    with the viewpoint, unlike a dark mark). ``welded``: the studs standing on the part
    (stud_perception.welded_studs.welded_stud), seen like any other solid. Everything random is drawn from ``seed``, one
    independent stream per effect, so changing one effect leaves the others' pattern alone.
    """
    if not (0.0 <= hole_fraction < 1.0):
        raise SceneError(f"hole_fraction must be in [0, 1), got {hole_fraction}")
    if depth_noise_m < 0 or color_noise < 0 or hole_blob_px <= 0:
        raise SceneError(
            f"noise levels must be >= 0 and hole_blob_px > 0, got depth_noise_m={depth_noise_m}, "
            f"color_noise={color_noise}, hole_blob_px={hole_blob_px}"
        )
    rng_depth, rng_holes, rng_color = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(3))
    h, w = camera.height, camera.width
    v_pix, u_pix = np.mgrid[0:h, 0:w]
    d = camera.ray_directions_world(u_pix, v_pix)  # (H, W, 3), unit optical z: t is the depth
    dx, dy, dz = d[..., 0], d[..., 1], d[..., 2]
    o = camera.position_w

    # Nearest hit over the plane, the board and the component; each solid is cast only over
    # the image rectangle its bounding box projects to.
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(dz < 0, -o[2] / dz, _INF)
    sid = np.where(np.isfinite(t), SURFACE_TABLE, SURFACE_NONE).astype(np.int8)
    wall = np.zeros((h, w), dtype=bool)
    solids = [(SURFACE_BOARD, scene.board_plate)]
    if scene.component is not None:
        solids.append((SURFACE_COMPONENT, scene.component))
    solids += [(SURFACE_OBSTACLE, ob) for ob in scene.obstacles]
    solids += [(SURFACE_STUD, stud) for stud in welded]
    for surf, solid in solids:
        win = _image_window(camera, solid.bounding_box_w())
        if win is None:
            continue
        t_s, wall_s = solid.intersect(o, dx[win], dy[win], dz[win])
        closer = (t_s > 0) & (t_s < t[win])
        t[win] = np.where(closer, t_s, t[win])
        sid[win][closer] = surf
        wall[win] = np.where(closer, wall_s, wall[win])
    hit = np.isfinite(t)
    depth_exact = np.where(hit, t, np.nan)
    hit_x = o[0] + depth_exact * dx
    hit_y = o[1] + depth_exact * dy
    px_per_depth = 1.0 / camera.fx  # pixel footprint: metres per pixel per metre of depth

    # Shading: Lambert on the top faces, a flat darker shade on walls (float32: colour only).
    grey_lut = np.array([0.0, _TABLE_GREY, _BOARD_GREY, _STEEL_GREY, _STEEL_GREY, _STUD_GREY], dtype=np.float32)
    shade = np.full((h, w), _AMBIENT + (1 - _AMBIENT) * _LIGHT_DIR_W[2], dtype=np.float32)
    comp_top = (sid == SURFACE_COMPONENT) & ~wall
    specular = np.zeros((h, w), dtype=bool)
    if comp_top.any():
        n = scene.component.top_normal(hit_x[comp_top], hit_y[comp_top])
        shade[comp_top] = _AMBIENT + (1 - _AMBIENT) * np.clip(n @ _LIGHT_DIR_W, 0, 1)
        if scene.specular_lobe_deg > 0:
            p_hit = np.column_stack([hit_x[comp_top], hit_y[comp_top], o[2] + depth_exact[comp_top] * dz[comp_top]])
            projector = camera.R_wc @ np.asarray(projector_offset_m, dtype=np.float64) + o
            to_cam = o - p_hit
            to_proj = projector - p_hit
            half = (to_cam / np.linalg.norm(to_cam, axis=1, keepdims=True)
                    + to_proj / np.linalg.norm(to_proj, axis=1, keepdims=True))
            cos_half = np.einsum("ni,ni->n", n, half) / np.linalg.norm(half, axis=1)
            specular[comp_top] = cos_half > math.cos(math.radians(scene.specular_lobe_deg))
    shade[wall] = _WALL_SHADE
    grey = grey_lut[sid + 1] * shade

    # Marks O, A, B on the board top, anti-aliased from the exact hit points.
    on_board = (sid == SURFACE_BOARD) & ~wall
    mark_cover = np.zeros((h, w), dtype=np.float32)
    if on_board.any():
        local = scene.drawing_to_world.apply_inverse(np.column_stack([hit_x[on_board], hit_y[on_board]]))
        marks = np.asarray(scene.board.marks_drawing_m)
        dist = np.min(np.hypot(local[:, 0, None] - marks[None, :, 0], local[:, 1, None] - marks[None, :, 1]), axis=1)
        mark_cover[on_board] = _coverage(dist - scene.board.mark_diameter_m / 2, depth_exact[on_board] * px_per_depth)
    grey = grey * (1 - mark_cover) + np.float32(_MARK_GREY) * mark_cover
    stud_cover = _stud_mark_coverage(scene, camera, hit_x, hit_y, depth_exact, px_per_depth)
    stud_cover[sid == SURFACE_STUD] = 0.0  # the marks are painted on the part, not on a stud standing there
    grey = grey * (1 - stud_cover) + np.float32(_STUD_MARK_GREY) * stud_cover

    tint_lut = np.ones((6, 3), dtype=np.float32)
    for surf, bgr in _TINT_BGR.items():
        tint_lut[surf + 1] = bgr
    color = grey[..., None] * tint_lut[sid + 1]
    if color_noise > 0:
        color += rng_color.normal(0.0, color_noise, color.shape).astype(np.float32)
    color_bgr = np.clip(np.rint(color), 0, 255).astype(np.uint8)

    # Depth: noise, then mm quantisation, then holes (0 = no depth, REP 118).
    depth_noisy = depth_exact
    if depth_noise_m > 0:
        depth_noisy = depth_exact + rng_depth.normal(0.0, depth_noise_m, depth_exact.shape)
    depth_mm = depth_m_to_mm(depth_noisy)
    holes = _hole_mask((h, w), hole_fraction, hole_blob_px, rng_holes)
    depth_mm[holes] = 0
    if mark_depth_dropout:
        depth_mm[(mark_cover > 0.5) | (stud_cover > 0.5)] = 0
    depth_mm[specular] = 0
    holes = holes | specular

    # Ground truth per stud and mark.
    xy = scene.studs_world_xy_m
    z = surface_height(scene, xy[:, 0], xy[:, 1])
    studs_w = np.column_stack([xy, z])
    normals = surface_normal(scene, xy[:, 0], xy[:, 1])
    su, sv, sz = camera.world_to_pixel(studs_w)
    visible = camera.in_image(su, sv) & (sz > 0)
    vis_idx = np.flatnonzero(visible)
    if vis_idx.size:
        d_pix = depth_exact[np.rint(sv[vis_idx]).astype(int), np.rint(su[vis_idx]).astype(int)]
        visible[vis_idx] = np.abs(d_pix - sz[vis_idx]) < _VISIBLE_TOL_M
    marks_w = scene.marks_world_m
    mu, mv, _ = camera.world_to_pixel(marks_w)
    return RenderedView(
        color_bgr=color_bgr,
        depth_mm=depth_mm,
        depth_exact_m=depth_exact,
        surface_id=np.where(hit, sid, SURFACE_NONE).astype(np.int8),
        hole_mask=holes,
        camera=camera,
        scene=scene,
        seed=int(seed),
        studs_world_m=studs_w,
        stud_normals_w=normals,
        stud_pixels_uv=np.column_stack([su, sv]),
        stud_visible=visible,
        marks_world_m=marks_w,
        marks_pixels_uv=np.column_stack([mu, mv]),
    )


# -- cameras for synthetic views ----------------------------------------------------------------
DEMO_IMAGE_SIZE = (1280, 960)
DEMO_FOV_WIDTH_M = 0.46   # field of view width at DEMO_FOV_DISTANCE_M (paper: ~460 x 360 mm)
DEMO_FOV_DISTANCE_M = 0.5


@lru_cache(maxsize=4)
def _raw_to_pinhole_maps(K: tuple, D: tuple, fisheye: bool, w: int, h: int) -> tuple[np.ndarray, np.ndarray]:
    """For every raw pixel, the pinhole pixel on its ray (about a second for 1280x960: cached)."""
    K, D = np.array(K).reshape(3, 3), np.array(D)
    v, u = np.mgrid[0:h, 0:w]
    raw = np.stack([u, v], axis=-1).reshape(-1, 1, 2).astype(np.float64)
    if fisheye:
        ideal = cv2.fisheye.undistortPoints(raw, K, D.reshape(4, 1), P=K)
    else:
        ideal = cv2.undistortPoints(raw, K, D, P=K, criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-9))
    return (ideal[:, 0, 0].reshape(h, w).astype(np.float32), ideal[:, 0, 1].reshape(h, w).astype(np.float32))


def distort_view(view: RenderedView, d, model: str = "plumb_bob") -> RenderedView:
    """The raw images a camera with K = ``view.camera.K`` and lens distortion ``d`` (OpenCV order;
    ``model`` 'plumb_bob'/'rational_polynomial' or 'equidistant') delivers of the same scene: each
    raw pixel takes the pinhole view's value along its ray (colour bilinear, depth and labels
    nearest), and the truth's pixels move likewise. Pixels whose ray leaves the pinhole image get
    no depth. What :class:`stud_perception.rectify.Rectifier` undoes."""
    K = view.camera.K
    D = np.asarray(d, dtype=np.float64).ravel()
    fisheye = model == "equidistant"
    h, w = view.depth_mm.shape
    map_u, map_v = _raw_to_pinhole_maps(tuple(K.ravel().tolist()), tuple(D.tolist()), fisheye, w, h)
    ui, vi = np.rint(map_u).astype(np.int64), np.rint(map_v).astype(np.int64)
    inside = (ui >= 0) & (ui < w) & (vi >= 0) & (vi < h)
    ui, vi = np.clip(ui, 0, w - 1), np.clip(vi, 0, h - 1)

    def nearest(img, outside):
        return np.where(inside, img[vi, ui], outside).astype(img.dtype)

    def distort_pixels(uv):
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        xn = np.column_stack([(uv[:, 0] - K[0, 2]) / K[0, 0], (uv[:, 1] - K[1, 2]) / K[1, 1]])
        if fisheye:
            return cv2.fisheye.distortPoints(xn.reshape(-1, 1, 2), K, D.reshape(4, 1)).reshape(-1, 2)
        pts = np.column_stack([xn, np.ones(len(xn))])
        return cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K, D)[0].reshape(-1, 2)

    return dataclasses.replace(
        view,
        color_bgr=cv2.remap(view.color_bgr, map_u, map_v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT),
        depth_mm=nearest(view.depth_mm, 0), depth_exact_m=nearest(view.depth_exact_m, np.nan),
        surface_id=nearest(view.surface_id, SURFACE_NONE), hole_mask=nearest(view.hole_mask, False),
        stud_pixels_uv=distort_pixels(view.stud_pixels_uv), marks_pixels_uv=distort_pixels(view.marks_pixels_uv),
        distortion_d=tuple(D.tolist()), distortion_model=model)


def view_camera(
    target_w,
    distance_m: float = 0.5,
    yaw_rad: float = 0.0,
    tilt_rad: float = 0.0,
    tilt_azimuth_rad: float = 0.0,
    width: int = DEMO_IMAGE_SIZE[0],
    height: int = DEMO_IMAGE_SIZE[1],
    fov_width_m: float = DEMO_FOV_WIDTH_M,
    fov_distance_m: float = DEMO_FOV_DISTANCE_M,
) -> CameraModel:
    """A camera ``distance_m`` from world point ``target_w`` looking at it.

    The viewing direction is tilted ``tilt_rad`` from straight down, the camera leaning
    toward azimuth ``tilt_azimuth_rad`` (world, from +X); ``yaw_rad`` turns the image about
    the optical axis (0: a nadir camera has optical x along world +X).
    """
    up = np.array([
        math.sin(tilt_rad) * math.cos(tilt_azimuth_rad),
        math.sin(tilt_rad) * math.sin(tilt_azimuth_rad),
        math.cos(tilt_rad),
    ])
    # Rotation taking world +Z to `up` (Rodrigues about Z x up).
    axis = np.array([-up[1], up[0], 0.0])
    s = np.linalg.norm(axis)
    if s < 1e-12:
        R_tilt = np.eye(3)
    else:
        k = axis / s
        Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        R_tilt = np.eye(3) + math.sin(tilt_rad) * Kx + (1 - math.cos(tilt_rad)) * Kx @ Kx
    R_wc = R_tilt @ nadir_rotation(yaw_rad)
    t_wc = np.asarray(target_w, dtype=np.float64) + distance_m * up
    return CameraModel.from_fov(width, height, fov_width_m, fov_distance_m, R_wc=R_wc, t_wc=t_wc)


def demo_camera() -> CameraModel:
    """The demo's nadir 1280x960 camera, 0.5 m above the dome's apex, over the demo scene."""
    return CameraModel.from_fov(
        *DEMO_IMAGE_SIZE, DEMO_FOV_WIDTH_M, DEMO_FOV_DISTANCE_M, t_wc=np.array([-0.02, 0.0, 0.55])
    )


# -- bundled scenes -------------------------------------------------------------------------------
_DEMO_DOME = Dome(centre_xy_m=(0.09, 0.02), base_radius_m=0.20, height_m=0.05)
# Board frame (= drawing frame): O at (-0.135, -0.11), x toward +Y world, so y points to -X.
_DEMO_POSE = Pose2D(x_m=-0.135, y_m=-0.11, yaw_rad=math.pi / 2)


def demo_dome_scene() -> SceneSpec:
    """The paper's set-up: a 50 mm high dome (base radius 0.2 m; normals 0 deg at the apex,
    ~14 deg at the outer studs) with 17 studs, and the marking board beside it
    (|OA| = 130 mm, |OB| = 100 mm, 20 mm marks, 5 mm plate). Pair with :func:`demo_camera`."""
    # Studs: apex, a ring of 8 at 50 mm and a ring of 8 at 100 mm (world, around the apex).
    ang = np.arange(8) * (2 * math.pi / 8)
    ring1 = np.column_stack([0.05 * np.cos(ang), 0.05 * np.sin(ang)])
    ring2 = np.column_stack([0.10 * np.cos(ang + math.pi / 8), 0.10 * np.sin(ang + math.pi / 8)])
    world = np.vstack([[0.0, 0.0], ring1, ring2]) + np.asarray(_DEMO_DOME.centre_xy_m)
    drawing = _DEMO_POSE.apply_inverse(world)
    return SceneSpec(
        component=_DEMO_DOME,
        board=MarkingBoard(),
        drawing_to_world=_DEMO_POSE,
        studs_drawing_m=tuple(map(tuple, np.round(drawing, 6))),
        stud_mark_diameter_m=0.008,
    )


def grid_stud_scene(
    n_studs: int,
    base: SceneSpec | None = None,
    extent_m: tuple[float, float] = (0.24, 0.18),
    centre_world_xy_m: tuple[float, float] | None = None,
) -> SceneSpec:
    """``base`` (default: the demo dome) with ``n_studs`` studs on a near-square world grid of
    ``extent_m`` (x, y) centred on ``centre_world_xy_m`` (default: the component's centre), for
    scaling benchmarks (tested up to 10,000). Stud marks shrink with the grid pitch so
    neighbouring marks never merge."""
    if n_studs < 1:
        raise SceneError(f"n_studs must be >= 1, got {n_studs}")
    base = base if base is not None else demo_dome_scene()
    if centre_world_xy_m is None:
        centre_world_xy_m = base.component.centre_xy_m if base.component is not None else (0.0, 0.0)
    ex, ey = extent_m
    cols = max(1, math.ceil(math.sqrt(n_studs * ex / ey)))
    rows = math.ceil(n_studs / cols)
    gx = np.linspace(-ex / 2, ex / 2, cols) if cols > 1 else np.zeros(1)
    gy = np.linspace(-ey / 2, ey / 2, rows) if rows > 1 else np.zeros(1)
    yy, xx = np.meshgrid(gy, gx, indexing="ij")
    world = np.column_stack([xx.ravel(), yy.ravel()])[:n_studs] + np.asarray(centre_world_xy_m)
    pitch = min(ex / max(cols - 1, 1), ey / max(rows - 1, 1))
    drawing = base.drawing_to_world.apply_inverse(world)
    return dataclasses.replace(
        base,
        studs_drawing_m=tuple(map(tuple, drawing)),
        stud_ids=tuple(f"S{i + 1:05d}" for i in range(n_studs)),
        stud_mark_diameter_m=min(base.stud_mark_diameter_m, 0.5 * pitch),
    )


# -- plain-dict / file form -----------------------------------------------------------------------
def _take(d: dict, name: str, allowed: set[str]) -> dict:
    if not isinstance(d, dict):
        raise SceneError(f"scene {name} must be a mapping, got {type(d).__name__}")
    unknown = set(d) - allowed
    if unknown:
        raise SceneError(f"unknown key(s) {sorted(unknown)} in scene {name}; allowed: {sorted(allowed)}")
    return d


def _component_from_dict(d: dict | None) -> Component | None:
    if d is None:
        return None
    kind = d.get("kind")
    try:
        if kind == "dome":
            _take(d, "component (dome)", {"kind", "centre_xy_m", "base_radius_m", "height_m"})
            return Dome(d["centre_xy_m"], float(d["base_radius_m"]), float(d["height_m"]))
        if kind == "cylinder":
            _take(d, "component (cylinder)",
                  {"kind", "centre_xy_m", "radius_m", "axis_yaw_deg", "length_m", "height_m"})
            return Cylinder(
                d["centre_xy_m"], float(d["radius_m"]), math.radians(float(d.get("axis_yaw_deg", 0.0))),
                float(d["length_m"]), float(d["height_m"]),
            )
        if kind == "trough":
            _take(d, "component (trough)",
                  {"kind", "centre_xy_m", "radius_m", "axis_yaw_deg", "length_m", "width_m", "rim_height_m"})
            return Trough(
                d["centre_xy_m"], float(d["radius_m"]), math.radians(float(d.get("axis_yaw_deg", 0.0))),
                float(d["length_m"]), float(d["width_m"]), float(d["rim_height_m"]),
            )
        if kind in ("tilted_plane", "plane"):
            keys = {"kind", "centre_xy_m", "size_m", "yaw_deg", "height_m"}
            if kind == "tilted_plane":
                keys.add("tilt_deg")
            _take(d, f"component ({kind})", keys)
            return Plate(
                d["centre_xy_m"], d["size_m"], math.radians(float(d.get("yaw_deg", 0.0))), float(d["height_m"]),
                math.radians(float(d.get("tilt_deg", 0.0))) if kind == "tilted_plane" else 0.0,
            )
    except KeyError as exc:
        raise SceneError(f"scene component ({kind}) misses key {exc.args[0]!r}") from None
    raise SceneError(f"unknown component kind {kind!r}: use dome, cylinder, trough, tilted_plane or plane")


def _component_to_dict(c: Component | None) -> dict | None:
    if c is None:
        return None
    if isinstance(c, Dome):
        return {"kind": "dome", "centre_xy_m": list(c.centre_xy_m), "base_radius_m": c.base_radius_m,
                "height_m": c.height_m}
    if isinstance(c, Cylinder):
        return {
            "kind": "cylinder", "centre_xy_m": list(c.centre_xy_m), "radius_m": c.radius_m,
            "axis_yaw_deg": math.degrees(c.axis_yaw_rad), "length_m": c.length_m, "height_m": c.height_m,
        }
    if isinstance(c, Trough):
        return {
            "kind": "trough", "centre_xy_m": list(c.centre_xy_m), "radius_m": c.radius_m,
            "axis_yaw_deg": math.degrees(c.axis_yaw_rad), "length_m": c.length_m, "width_m": c.width_m,
            "rim_height_m": c.rim_height_m,
        }
    d = {"kind": c.kind, "centre_xy_m": list(c.centre_xy_m), "size_m": list(c.size_m),
         "yaw_deg": math.degrees(c.yaw_rad), "height_m": c.height_m}
    if c.tilt_rad != 0:
        d["tilt_deg"] = math.degrees(c.tilt_rad)
    return d


def scene_from_dict(d: dict[str, Any]) -> SceneSpec:
    """Build a scene from plain data (as loaded from YAML/JSON). Angles are in degrees there::

        {"component": {"kind": "dome", "centre_xy_m": [0.09, 0.02], "base_radius_m": 0.2, "height_m": 0.05},
         "board": {"marks_drawing_m": [[0, 0], [0.13, 0], [0, 0.1]], "mark_diameter_m": 0.02,
                   "thickness_m": 0.005, "margin_m": 0.018},
         "drawing_to_world": {"x_m": -0.135, "y_m": -0.11, "yaw_deg": 90},
         "studs": {"xy_m": [[0.1, 0.2]], "ids": ["S1"], "mark_diameter_m": 0.008, "mark_style": "circle"},
         "obstacles": [{"centre_xy_m": [0.1, 0.0], "size_m": [0.3, 0.012], "yaw_deg": 0, "height_m": 0.12}],
         "specular_lobe_deg": 3.0}

    Component kinds: ``dome`` (centre_xy_m, base_radius_m, height_m), ``cylinder`` (centre_xy_m,
    radius_m, axis_yaw_deg, length_m, height_m), ``trough`` (centre_xy_m, radius_m, axis_yaw_deg,
    length_m, width_m, rim_height_m), ``tilted_plane`` / ``plane`` (centre_xy_m, size_m, yaw_deg,
    height_m, tilt_deg). ``obstacles`` are flat boxes (stiffeners); ``specular_lobe_deg`` makes the
    component shiny (see :class:`SceneSpec`).
    """
    _take(d, "", {"component", "board", "drawing_to_world", "studs", "obstacles", "specular_lobe_deg",
                  "stud_length_mm", "stud_diameter_mm", "weld_defects"})
    board_keys = {"marks_drawing_m", "mark_diameter_m", "thickness_m", "margin_m"}
    board = MarkingBoard(**_take(d.get("board", {}), "board", board_keys))
    pose_d = _take(d.get("drawing_to_world", {}), "drawing_to_world", {"x_m", "y_m", "yaw_deg"})
    pose = Pose2D(
        float(pose_d.get("x_m", 0.0)), float(pose_d.get("y_m", 0.0)), math.radians(float(pose_d.get("yaw_deg", 0.0)))
    )
    studs = _take(d.get("studs", {}), "studs", {"xy_m", "ids", "mark_diameter_m", "mark_style"})
    obstacles = d.get("obstacles", [])
    if not isinstance(obstacles, list):
        raise SceneError(f"scene obstacles must be a list of boxes, got {type(obstacles).__name__}")
    boxes = []
    for i, ob in enumerate(obstacles):
        _take(ob, f"obstacles[{i}]", {"centre_xy_m", "size_m", "yaw_deg", "height_m"})
        try:
            boxes.append(Plate(ob["centre_xy_m"], ob["size_m"], math.radians(float(ob.get("yaw_deg", 0.0))),
                               float(ob["height_m"])))
        except KeyError as exc:
            raise SceneError(f"scene obstacles[{i}] misses key {exc.args[0]!r}") from None
    return SceneSpec(
        component=_component_from_dict(d.get("component")),
        board=board,
        drawing_to_world=pose,
        studs_drawing_m=tuple(map(tuple, np.asarray(studs.get("xy_m", []), dtype=np.float64).reshape(-1, 2))),
        stud_ids=tuple(studs.get("ids", ())),
        stud_mark_diameter_m=float(studs.get("mark_diameter_m", 0.008)),
        stud_mark_style=str(studs.get("mark_style", "circle")),
        obstacles=tuple(boxes),
        specular_lobe_deg=float(d.get("specular_lobe_deg", 0.0)),
        stud_length_m=1e-3 * _mm(d, "stud_length_mm", DEFAULT_STUD_LENGTH_M * 1e3),
        stud_diameter_m=1e-3 * _mm(d, "stud_diameter_mm", DEFAULT_STUD_DIAMETER_M * 1e3),
        weld_defects=_weld_defects(d.get("weld_defects"), studs.get("ids", ()), len(studs.get("xy_m", []))),
    )


def _mm(d: dict, name: str, default: float) -> float:
    value = d.get(name, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise SceneError(f"scene {name}={value!r}: expected a number in mm")
    return float(value)


def _weld_defects(data, ids, n_studs: int) -> dict:
    ids = tuple(str(i) for i in ids) or tuple(f"S{i + 1:04d}" for i in range(n_studs))
    try:
        return parse_weld_defects(data, ids)
    except WeldDefectError as exc:
        raise SceneError(str(exc)) from None


def scene_to_dict(scene: SceneSpec) -> dict[str, Any]:
    """Plain-data form of ``scene`` (inverse of :func:`scene_from_dict`), JSON/YAML-serialisable."""
    b = scene.board
    return {
        "component": _component_to_dict(scene.component),
        "board": {"marks_drawing_m": [list(m) for m in b.marks_drawing_m], "mark_diameter_m": b.mark_diameter_m,
                  "thickness_m": b.thickness_m, "margin_m": b.margin_m},
        "drawing_to_world": {"x_m": scene.drawing_to_world.x_m, "y_m": scene.drawing_to_world.y_m,
                             "yaw_deg": math.degrees(scene.drawing_to_world.yaw_rad)},
        "studs": {"xy_m": [list(p) for p in scene.studs_drawing_m], "ids": list(scene.stud_ids),
                  "mark_diameter_m": scene.stud_mark_diameter_m, "mark_style": scene.stud_mark_style},
        "obstacles": [{"centre_xy_m": list(ob.centre_xy_m), "size_m": list(ob.size_m),
                       "yaw_deg": math.degrees(ob.yaw_rad), "height_m": ob.height_m} for ob in scene.obstacles],
        "specular_lobe_deg": scene.specular_lobe_deg,
        "stud_length_mm": scene.stud_length_m * 1e3, "stud_diameter_mm": scene.stud_diameter_m * 1e3,
        "weld_defects": {sid: defect.to_dict() for sid, defect in scene.weld_defects.items()},
    }


def load_scene(path: str | Path) -> SceneSpec:
    """Read a scene from a ``.json`` file, or ``.yaml``/``.yml`` when PyYAML is installed."""
    path = Path(path)
    text = path.read_text()
    if path.suffix.lower() in (".yaml", ".yml"):
        try:
            import yaml
        except ImportError:
            raise SceneError(f"{path}: PyYAML is not installed; install it or write the scene as JSON") from None
        data = yaml.safe_load(text)
    else:
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise SceneError(f"{path}: not valid JSON ({exc})") from None
    return scene_from_dict(data)
