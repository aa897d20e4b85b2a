"""Camera stations that cover every stud of a drawing (pure numpy, no ROS).

After registration every stud has a world XY (Eq. 2). The camera sees a rectangle of
``fov_m`` (width, height) on the part from its station height; stations tile the studs'
bounding box with rectangles shrunk by ``overlap`` so that each stud is assigned to the
station whose footprint it lies in the *inner* part of (the most central view, away from
the image border where depth and normals are worst). Empty tiles are dropped, stations are
visited in a serpentine order, and a station the arm cannot put the camera at makes its
studs "unreachable" (reported, never silently dropped).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np


class StationPlanningError(ValueError):
    """Settings no station plan can come from (named value)."""


@dataclass(frozen=True)
class Station:
    """A camera station: optical centre in `world` (m), image yaw (rad), and the studs assigned
    to it (indices into the stud list) — the studs this station's shot is used to weld."""

    index: int
    camera_xyz_w: tuple[float, float, float]
    yaw_rad: float
    stud_indices: tuple[int, ...]


@dataclass(frozen=True)
class StationPlan:
    stations: tuple[Station, ...]
    unreachable: tuple[int, ...]  # stud indices no reachable station covers

    @property
    def covered(self) -> int:
        return sum(len(s.stud_indices) for s in self.stations)


def plan_stations(studs_xy_w: np.ndarray, fov_m: tuple[float, float], camera_height_m: float,
                  overlap: float = 0.15, yaw_rad: float = 0.0,
                  camera_reachable: Callable[[np.ndarray], bool] | None = None,
                  plane_z_m: float = 0.0) -> StationPlan:
    """Stations for studs at ``studs_xy_w`` (N, 2) with a nadir camera ``camera_height_m`` above
    the working plane (world height ``plane_z_m``, e.g. the registered marks' height: the world
    is the arm's base frame, which need not lie in the plane) whose footprint is ``fov_m`` =
    (width along image x, height along image y) at the part (for a camera yawed by ``yaw_rad``).
    ``overlap`` in [0, 0.9): fraction of the footprint kept free at the border.
    ``camera_reachable(xyz) -> bool``: can the arm put the camera there."""
    xy = np.asarray(studs_xy_w, dtype=np.float64).reshape(-1, 2)
    if not (0.0 <= overlap < 0.9):
        raise StationPlanningError(f"overlap={overlap}: expected 0 <= overlap < 0.9")
    if min(fov_m) <= 0 or camera_height_m <= 0:
        raise StationPlanningError(f"fov_m={fov_m} and camera_height_m={camera_height_m} must be positive")
    if len(xy) == 0:
        return StationPlan((), ())
    # Work in the camera's image axes so tiles align with the footprint.
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    R = np.array([[c, -s], [s, c]])
    local = xy @ R  # world -> yawed frame
    tile = np.array(fov_m, dtype=np.float64) * (1.0 - overlap)
    lo, hi = local.min(axis=0), local.max(axis=0)
    n_tiles = np.maximum(1, np.ceil((hi - lo) / tile - 1e-9)).astype(int)
    origin = (lo + hi) / 2 - n_tiles * tile / 2  # centre the tiling on the studs
    cell = np.clip(np.floor((local - origin) / tile).astype(int), 0, n_tiles - 1)
    stations: list[Station] = []
    unreachable: list[int] = []
    for row in range(n_tiles[1]):
        cols = range(n_tiles[0]) if row % 2 == 0 else reversed(range(n_tiles[0]))  # serpentine
        for col in cols:
            members = np.flatnonzero((cell[:, 0] == col) & (cell[:, 1] == row))
            if len(members) == 0:
                continue
            centre_local = origin + (np.array([col, row]) + 0.5) * tile
            centre_w = R @ centre_local
            xyz = np.array([centre_w[0], centre_w[1], plane_z_m + camera_height_m])
            if camera_reachable is not None and not camera_reachable(xyz):
                unreachable.extend(int(i) for i in members)
                continue
            stations.append(Station(len(stations) + 1, (float(xyz[0]), float(xyz[1]), float(xyz[2])),
                                    float(yaw_rad), tuple(int(i) for i in members)))
    return StationPlan(tuple(stations), tuple(sorted(unreachable)))


def footprint_m(fov_width_m: float, fov_distance_m: float, aspect_hw: float, camera_height_m: float,
                part_height_m: float = 0.0) -> tuple[float, float]:
    """Field of view (width, height) on a part ``part_height_m`` tall seen from ``camera_height_m``,
    for a camera spanning ``fov_width_m`` at ``fov_distance_m`` with image aspect height/width."""
    distance = camera_height_m - part_height_m
    if distance <= 0:
        raise StationPlanningError(f"camera at {camera_height_m} m is not above the part top {part_height_m} m")
    width = fov_width_m * distance / fov_distance_m
    return width, width * aspect_hw


def reshoot_station(stud_xy_w, attempt: int, offset_m: float, camera_height_m: float, plane_z_m: float = 0.0,
                    yaw_rad: float = 0.0, index: int = 0, stud_index: int = 0) -> Station:
    """A station to see one stud again from another direction: the camera ``offset_m`` beside the
    stud (a different viewing angle -- holes from a specular reflection or a shadow move with it),
    turned 90 deg further round the stud on each ``attempt`` (45, 135, 225, 315 deg, ...), nadir,
    ``camera_height_m`` above the plane. The stud stays well inside the image for offsets up to
    a quarter of the footprint."""
    if offset_m < 0 or camera_height_m <= 0:
        raise StationPlanningError(f"offset_m={offset_m} must be >= 0 and camera_height_m={camera_height_m} > 0")
    a = math.radians(45.0 + 90.0 * attempt)
    x, y = (float(v) for v in np.asarray(stud_xy_w, dtype=np.float64).reshape(2))
    xyz = (x + offset_m * math.cos(a), y + offset_m * math.sin(a), plane_z_m + camera_height_m)
    return Station(index, xyz, float(yaw_rad), (int(stud_index),))
