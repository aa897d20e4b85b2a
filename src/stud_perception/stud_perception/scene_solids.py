"""The synthetic scene's solids: the 2D drawing -> world pose and the parts' surfaces.

Every solid (a dome, a horizontal cylinder section, a trough, a flat or tilted plate; the marking
board and the obstacles are plates too) is a prism over a footprint on the working plane (world
z = 0, z up, metres) capped by a height field, with its exact top height and outward normal at any
world (x, y) and an analytic ray intersection (:mod:`stud_perception.scene_render` casts one ray
per pixel through them). :class:`SceneError` is the one error of every scene module.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar, Union

import numpy as np

class SceneError(ValueError):
    """A scene description that cannot be rendered (names the field and the value)."""



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
