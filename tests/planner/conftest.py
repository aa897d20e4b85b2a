"""Analytic depth scenes for the planner tests: ray-cast planes, a dome (sphere cap) and a box.

Every pixel's ray comes from :meth:`CameraModel.ray_directions_world` (world direction per metre of
optical depth), so the ray parameter of a hit *is* the depth the camera would report.
TODO: move to ``stud_perception.scene`` fixtures once that module settles; these stay analytic
(exact ground truth: height and normal at any XY) which the matcher tests need.
"""
from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
import pytest

from stud_perception.camera_model import CameraModel, nadir_rotation


def rotation_about(axis, angle_rad: float) -> np.ndarray:
    a = np.asarray(axis, float)
    a = a / np.linalg.norm(a)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle_rad) * K + (1 - np.cos(angle_rad)) * K @ K


def camera_pose(
    base: CameraModel, yaw_deg: float = 0.0, tilt_deg: float = 0.0, tilt_azimuth_deg: float = 0.0,
    distance_m: float = 0.5, look_at_w=(0.0, 0.0, 0.0),
) -> CameraModel:
    """``base`` intrinsics, looking at ``look_at_w`` from ``distance_m``: nadir, yawed about world Z,
    then tilted by ``tilt_deg`` about a horizontal axis at ``tilt_azimuth_deg``."""
    az = np.radians(tilt_azimuth_deg)
    R = rotation_about([np.cos(az), np.sin(az), 0.0], np.radians(tilt_deg)) @ nadir_rotation(np.radians(yaw_deg))
    t = np.asarray(look_at_w, float) - distance_m * R[:, 2]
    return base.with_pose(R, t)


@dataclass(frozen=True)
class Plane:
    """Plane through ``point_w`` with unit normal ``normal_w`` (world)."""

    point_w: tuple = (0.0, 0.0, 0.0)
    normal_w: tuple = (0.0, 0.0, 1.0)

    def hit(self, origin, rays):
        n = np.asarray(self.normal_w, float)
        n = n / np.linalg.norm(n)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (n @ (np.asarray(self.point_w, float) - origin)) / (rays @ n)
        return np.where(s > 0, s, np.inf)

    def height(self, xy):
        n = np.asarray(self.normal_w, float)
        n = n / np.linalg.norm(n)
        p = np.asarray(self.point_w, float)
        xy = np.asarray(xy, float)
        return p[2] - (n[0] * (xy[..., 0] - p[0]) + n[1] * (xy[..., 1] - p[1])) / n[2]

    def normal(self, xy):
        n = np.asarray(self.normal_w, float)
        n = n / np.linalg.norm(n)
        return np.broadcast_to(n, np.shape(xy)[:-1] + (3,)).copy()


@dataclass(frozen=True)
class Dome:
    """Sphere cap of base radius ``radius_m`` and height ``height_m`` on the floor z = 0, plus the floor."""

    centre_xy: tuple = (0.0, 0.0)
    radius_m: float = 0.2
    height_m: float = 0.03

    @property
    def sphere_radius_m(self) -> float:
        return (self.radius_m**2 + self.height_m**2) / (2 * self.height_m)

    @property
    def centre_w(self) -> np.ndarray:
        return np.array([*self.centre_xy, self.height_m - self.sphere_radius_m])

    def hit(self, origin, rays):
        R, c = self.sphere_radius_m, self.centre_w
        oc = origin - c
        a = np.einsum("...i,...i->...", rays, rays)
        b = 2 * rays @ oc
        cc = oc @ oc - R * R
        disc = b * b - 4 * a * cc
        with np.errstate(invalid="ignore"):
            s = (-b - np.sqrt(disc)) / (2 * a)
        z = origin[2] + s * rays[..., 2]
        s_cap = np.where((disc >= 0) & (z >= 0) & (s > 0), s, np.inf)
        return np.minimum(s_cap, Plane().hit(origin, rays))

    def height(self, xy):
        d2 = np.sum((np.asarray(xy, float) - np.asarray(self.centre_xy)) ** 2, axis=-1)
        R = self.sphere_radius_m
        return np.where(d2 < self.radius_m**2, self.centre_w[2] + np.sqrt(np.maximum(R * R - d2, 0)), 0.0)

    def normal(self, xy):
        xy = np.asarray(xy, float)
        p = np.concatenate([xy, self.height(xy)[..., None]], axis=-1)
        n = (p - self.centre_w) / self.sphere_radius_m
        inside = np.sum((xy - np.asarray(self.centre_xy)) ** 2, axis=-1) < self.radius_m**2
        return np.where(inside[..., None], n, np.array([0.0, 0.0, 1.0]))


@dataclass(frozen=True)
class Box:
    """Axis-aligned block [x0, x1] x [y0, y1] x [0, top_m] on the floor z = 0, plus the floor."""

    x_m: tuple = (0.0, 0.2)
    y_m: tuple = (-0.2, 0.2)
    top_m: float = 0.03

    def hit(self, origin, rays):
        lo = np.array([self.x_m[0], self.y_m[0], 0.0])
        hi = np.array([self.x_m[1], self.y_m[1], self.top_m])
        with np.errstate(divide="ignore", invalid="ignore"):
            t1 = (lo - origin) / rays
            t2 = (hi - origin) / rays
        tmin = np.nanmax(np.minimum(t1, t2), axis=-1)
        tmax = np.nanmin(np.maximum(t1, t2), axis=-1)
        s_box = np.where((tmax >= tmin) & (tmin > 0), tmin, np.inf)
        return np.minimum(s_box, Plane().hit(origin, rays))

    def inside(self, xy):
        xy = np.asarray(xy, float)
        return (xy[..., 0] >= self.x_m[0]) & (xy[..., 0] <= self.x_m[1]) & (xy[..., 1] >= self.y_m[0]) & (
            xy[..., 1] <= self.y_m[1])

    def height(self, xy):
        return np.where(self.inside(xy), self.top_m, 0.0)

    def normal(self, xy):
        return np.broadcast_to(np.array([0.0, 0.0, 1.0]), np.shape(xy)[:-1] + (3,)).copy()


def render_depth(camera: CameraModel, surface, noise_m: float = 0.0, hole_fraction: float = 0.0,
                 seed: int = 0) -> np.ndarray:
    """Depth image (H, W) float32 metres, NaN = invalid, of ``surface`` seen by ``camera``.

    ``hole_fraction`` of the pixels are removed in small clumps (1-3 px squares), like the
    speckle dropouts of a structured-light camera.
    """
    v, u = np.mgrid[0 : camera.height, 0 : camera.width]
    rays = camera.ray_directions_world(u, v)
    s = surface.hit(camera.position_w, rays)
    depth = np.where(np.isfinite(s), s, np.nan)
    rng = np.random.default_rng(seed)
    if noise_m > 0:
        depth = depth + rng.normal(0.0, noise_m, depth.shape)
    if hole_fraction > 0:
        mask = np.zeros(depth.shape, bool)
        n_seeds = int(hole_fraction * depth.size / 4.0)
        su = rng.integers(0, camera.width, n_seeds)
        sv = rng.integers(0, camera.height, n_seeds)
        size = rng.integers(1, 4, n_seeds)
        for du in range(3):
            for dv in range(3):
                sel = (du < size) & (dv < size)
                mask[np.clip(sv[sel] + dv, 0, camera.height - 1), np.clip(su[sel] + du, 0, camera.width - 1)] = True
        depth[mask] = np.nan
    return depth.astype(np.float32)


@pytest.fixture
def cam_full() -> CameraModel:
    """The paper's camera: 1280x960, ~460 mm wide field of view at 0.5 m, nadir."""
    return CameraModel.from_fov(1280, 960, 0.46, 0.5)


@pytest.fixture
def cam_small() -> CameraModel:
    """160x120 crop at the paper's pixel pitch (~0.36 mm at 0.5 m), for the per-pixel baselines:
    a coarser pixel would leave no pixel within the paper's 1 mm of a target."""
    return CameraModel.from_fov(160, 120, 0.0575, 0.5)


@pytest.fixture
def cam_paper(cam_full) -> CameraModel:
    """Nadir with the paper's axes: u opposite to world X, v along world Y."""
    return cam_full.with_pose(nadir_rotation(np.pi), cam_full.t_wc)


@pytest.fixture(scope="session")
def scenes() -> SimpleNamespace:
    """The analytic scene kit, as a fixture so test modules need not import ``conftest``
    (several conftest.py files share that module name)."""
    return SimpleNamespace(
        Plane=Plane, Dome=Dome, Box=Box, render_depth=render_depth, camera_pose=camera_pose,
        rotation_about=rotation_about,
    )
