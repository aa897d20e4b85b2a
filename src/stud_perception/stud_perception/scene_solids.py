"""The synthetic scene's solids: the 2D drawing -> world pose and the parts' surfaces.

Every solid (a dome, a horizontal cylinder section, a trough, a cambered girder flange, a flat or
tilted plate; the marking board and the obstacles are plates too) is a prism over a footprint on the
working plane (world z = 0, z up, metres) capped by a height field, with its exact top height and
outward normal at any world (x, y) and an analytic ray intersection (:mod:`stud_perception.scene_render`
casts one ray per pixel through them). :class:`SceneError` is the one error of every scene module.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar, Union

import numpy as np


class SceneError(ValueError):
    """A scene description that cannot be rendered (names the field and the value)."""



def finite_pair(value, name: str) -> tuple[float, float]:
    """``value`` as two finite floats (an (x, y) in metres); SceneError naming ``name`` otherwise."""
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
        object.__setattr__(self, "centre_xy_m", finite_pair(self.centre_xy_m, "dome centre_xy_m"))
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
        object.__setattr__(self, "centre_xy_m", finite_pair(self.centre_xy_m, "cylinder centre_xy_m"))
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
        object.__setattr__(self, "centre_xy_m", finite_pair(self.centre_xy_m, "trough centre_xy_m"))
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
        object.__setattr__(self, "centre_xy_m", finite_pair(self.centre_xy_m, "plate centre_xy_m"))
        object.__setattr__(self, "size_m", finite_pair(self.size_m, "plate size_m"))
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



@dataclass(frozen=True)
class Girder:
    """A cambered flange plate, the top of a bridge girder laid along the rail: its centreline
    starts at world ``start_xy_m`` and heads ``yaw_rad`` from world +X (0: along the rail) for
    ``length_m``; the plate is ``width_m`` wide, its edges vertical. At distance u in [0, L] along
    the centreline and v across it (v > 0 to the left of the heading) the top is at

        z(u, v) = height_m - (R - c) + sqrt(R^2 - (u - L/2)^2) + v tan(cross_slope)

    with c = ``camber_m`` (the crown's rise over the ends, at mid-length) and
    R = (L^2/4 + c^2) / (2c): a circular arc through the ends at ``height_m`` (a flat plate when
    c = 0), tilted across by ``cross_slope_rad`` (the top rises toward +v)."""

    start_xy_m: tuple[float, float]
    yaw_rad: float
    length_m: float
    width_m: float
    camber_m: float
    cross_slope_rad: float
    height_m: float
    kind: ClassVar[str] = "girder"

    def __post_init__(self) -> None:
        object.__setattr__(self, "start_xy_m", finite_pair(self.start_xy_m, "girder start_xy_m"))
        for name in ("yaw_rad", "length_m", "width_m", "camber_m", "cross_slope_rad", "height_m"):
            if not math.isfinite(getattr(self, name)):
                raise SceneError(f"girder {name} must be finite, got {getattr(self, name)!r}")
        if not (self.length_m > 0 and self.width_m > 0):
            raise SceneError(f"girder needs length_m > 0 and width_m > 0, got length_m={self.length_m}, "
                             f"width_m={self.width_m}")
        if not 0 <= self.camber_m < self.length_m / 2:
            raise SceneError(f"girder camber_m must be in [0, length_m / 2) (a crown above the ends), got "
                             f"camber_m={self.camber_m} for length_m={self.length_m}")
        if not abs(self.cross_slope_rad) < math.radians(45):
            raise SceneError(f"girder cross_slope_deg {math.degrees(self.cross_slope_rad):.1f} must be within "
                             f"(-45, 45)")
        low = self.height_m - abs(math.tan(self.cross_slope_rad)) * self.width_m / 2
        if low <= 0:
            raise SceneError(f"girder dips to the working plane (low edge at {low * 1000:.1f} mm at its ends): "
                             f"raise height_m above {self.height_m - low:.4f} m or reduce cross_slope_deg/width_m")

    @property
    def centre_xy_m(self) -> tuple[float, float]:
        """World XY of the footprint's centre (mid-length on the centreline)."""
        h = self.length_m / 2
        return (self.start_xy_m[0] + h * math.cos(self.yaw_rad), self.start_xy_m[1] + h * math.sin(self.yaw_rad))

    @property
    def radius_m(self) -> float:
        """R of the camber arc (inf for a flat plate)."""
        c, L = self.camber_m, self.length_m
        return (L * L / 4 + c * c) / (2 * c) if c > 0 else math.inf

    def _local(self, x, y):
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        dx, dy = np.asarray(x) - self.start_xy_m[0], np.asarray(y) - self.start_xy_m[1]
        return c * dx + s * dy, -s * dx + c * dy  # u along the centreline, v to its left

    def _crown(self, a):
        """Rise of the camber arc over the ends at ``a = u - L/2`` (0 at the ends, c at mid-length)."""
        if self.camber_m == 0:
            return np.zeros(np.shape(a))
        R, c = self.radius_m, self.camber_m
        # sqrt(R^2 - a^2) - (R - c), written without the cancellation of two ~R terms
        return c - np.square(a) / (np.sqrt(np.maximum(R * R - np.square(a), 0.0)) + R)

    def top_height(self, x, y):
        """(z of the top at world (x, y), inside footprint) -- vectorised, metres."""
        u, v = self._local(x, y)
        inside = (u >= 0) & (u <= self.length_m) & (np.abs(v) <= self.width_m / 2)
        z = self.height_m + self._crown(u - self.length_m / 2) + v * math.tan(self.cross_slope_rad)
        return np.where(inside, z, 0.0), inside

    def top_normal(self, x, y) -> np.ndarray:
        """Unit outward normal (..., 3) of the top above world (x, y): (-dz/du, -dz/dv, 1) turned to world."""
        u, _ = self._local(x, y)
        shape = np.broadcast(np.asarray(x), np.asarray(y)).shape
        a = np.broadcast_to(u - self.length_m / 2, shape)
        if self.camber_m == 0:
            dzdu = np.zeros(shape)
        else:
            dzdu = -a / np.sqrt(np.maximum(self.radius_m**2 - a * a, 1e-300))
        k = math.tan(self.cross_slope_rad)
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        inv = 1.0 / np.sqrt(dzdu * dzdu + (k * k + 1.0))
        n = np.empty(shape + (3,))
        n[..., 0] = -(c * dzdu - s * k) * inv
        n[..., 1] = -(s * dzdu + c * k) * inv
        n[..., 2] = inv
        return n

    def bounding_box_w(self) -> np.ndarray:
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        half = np.array([[c, s], [-s, c]]) * np.array([[self.length_m / 2], [self.width_m / 2]])
        centre = np.asarray(self.start_xy_m) + half[0]
        top = self.height_m + self.camber_m + abs(math.tan(self.cross_slope_rad)) * self.width_m / 2
        return _box_corners(centre, half, top)

    def _top_t(self, o: np.ndarray, u_o, v_o, u_d, v_d, dz):
        """Ray parameter of the first hit of the (unbounded) top surface, inf for none."""
        k = math.tan(self.cross_slope_rad)
        if self.camber_m == 0:
            with np.errstate(invalid="ignore", divide="ignore"):
                return (self.height_m + k * v_o - o[2]) / (dz - k * v_d)
        # Top: (R + e)^2 + a^2 = R^2 with a = u - L/2 and e = z - k v - height_m - c (e <= 0 on the
        # arc's upper half); quadratic in t with e = e0 + e1 t, a = a0 + a1 t, solved without the
        # cancellation of R-sized terms (R is ~100 m for a few cm of camber over metres).
        R = self.radius_m
        e0, e1 = o[2] - k * v_o - self.height_m - self.camber_m, dz - k * v_d
        a0, a1 = u_o - self.length_m / 2, u_d
        qa = e1 * e1 + a1 * a1
        qb = e0 * e1 + R * e1 + a0 * a1  # half the linear coefficient
        qc = e0 * e0 + 2 * R * e0 + a0 * a0
        disc = qb * qb - qa * qc
        with np.errstate(invalid="ignore", divide="ignore"):
            root = np.sqrt(disc)
            q = -(qb + np.where(qb >= 0, root, -root))
            t1, t2 = q / qa, qc / q
        t_near = np.minimum(t1, t2)
        # a ray from above enters the circle through the arc's upper half (R + e >= 0); an entry
        # through the lower half is below the plate, which the plane hides
        return np.where((disc >= 0) & (R + e0 + e1 * t_near >= 0), t_near, _INF)

    def intersect(self, o: np.ndarray, dx, dy, dz):
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        ox, oy = o[0] - self.start_xy_m[0], o[1] - self.start_xy_m[1]
        u_o, v_o = c * ox + s * oy, -s * ox + c * oy
        u_d, v_d = c * dx + s * dy, -s * dx + c * dy
        L, hw = self.length_m, self.width_m / 2
        t_top = self._top_t(o, u_o, v_o, u_d, v_d, dz)
        ok = (np.abs(u_o + t_top * u_d - L / 2) <= L / 2) & (np.abs(v_o + t_top * v_d) <= hw) & (o[2] + t_top * dz >= 0)
        t_top = np.where(ok & np.isfinite(t_top), t_top, _INF)
        # The solid is convex (a concave top over a rectangle), so a ray meets it in one interval: where it
        # enters through the top, no wall comes first. Walls are cast for the other rays only.
        rest = ~np.isfinite(t_top)
        t_wall = np.full(np.shape(t_top), _INF)
        if rest.any():
            u_o_r, v_o_r = np.broadcast_to(u_o, rest.shape)[rest], np.broadcast_to(v_o, rest.shape)[rest]
            u_d_r, v_d_r, dz_r = u_d[rest], v_d[rest], np.broadcast_to(dz, rest.shape)[rest]
            walls = []
            for axis_o, axis_d, other_o, other_d, lo, hi, other_lo, other_hi, is_end in (
                (u_o_r, u_d_r, v_o_r, v_d_r, 0.0, L, -hw, hw, True),
                (v_o_r, v_d_r, u_o_r, u_d_r, -hw, hw, 0.0, L, False),
            ):
                for side in (lo, hi):
                    with np.errstate(invalid="ignore", divide="ignore"):
                        t = (side - axis_o) / axis_d
                    z = o[2] + t * dz_r
                    other = other_o + t * other_d
                    uu, vv = (side, other) if is_end else (other, side)
                    top = self.height_m + self._crown(uu - L / 2) + vv * math.tan(self.cross_slope_rad)
                    ok = np.isfinite(t) & (other >= other_lo) & (other <= other_hi) & (z >= 0) & (z <= top)
                    walls.append(np.where(ok, t, _INF))
            t_wall[rest] = _first_positive(*walls)
        t = _first_positive(t_top, t_wall)
        return t, np.isfinite(t_wall) & (t_wall < t_top)

Component = Union[Dome, Cylinder, Trough, Plate, Girder]
