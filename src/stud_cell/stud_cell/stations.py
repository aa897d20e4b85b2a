"""Camera stations that cover every stud of a drawing (pure numpy, no ROS).

After registration every stud has a world XY (Eq. 2). The camera sees a rectangle of
``fov_m`` (width, height) on the part from its station height; stations tile the studs'
bounding box with rectangles shrunk by ``overlap`` so that each stud is assigned to the
station whose footprint it lies in the *inner* part of (the most central view, away from
the image border where depth and normals are worst). Empty tiles are dropped, stations are
visited in a serpentine order, and a station the arm cannot put the camera at makes its
studs "unreachable" (reported, never silently dropped).

Fewer stations: every station costs a camera move, a shot and an inspection. The tiling is fixed
to a grid, so a cluster of studs astride a tile border costs two stations where one would see it.
With ``fewest`` a greedy set cover also places inner footprints freely -- every
placement can be slid until a stud touches its left and one its bottom edge, so those (N^2)
placements are the candidates -- and it is taken when it needs fewer stations than the grid
(each stud to the chosen station it is most central in; stations visited nearest-first from the
grid's first). Up to ``FEWEST_MAX_STUDS`` studs; beyond, the grid.
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


FEWEST_MAX_STUDS = 300  # the candidates grow as N^2


def plan_stations(studs_xy_w: np.ndarray, fov_m: tuple[float, float], camera_height_m: float,
                  overlap: float = 0.15, yaw_rad: float = 0.0,
                  camera_reachable: Callable[[np.ndarray], bool] | None = None,
                  plane_z_m: float = 0.0, fewest: bool = False) -> StationPlan:
    """Stations for studs at ``studs_xy_w`` (N, 2) with a nadir camera ``camera_height_m`` above
    the working plane (world height ``plane_z_m``, e.g. the registered marks' height: the world
    is the arm's base frame, which need not lie in the plane) whose footprint is ``fov_m`` =
    (width along image x, height along image y) at the part (for a camera yawed by ``yaw_rad``).
    ``overlap`` in [0, 0.9): fraction of the footprint kept free at the border.
    ``camera_reachable(xyz) -> bool``: can the arm put the camera there. ``fewest``: a free placement
    when it needs fewer stations than the grid (module docstring)."""
    grid = _grid_stations(studs_xy_w, fov_m, camera_height_m, overlap, yaw_rad, camera_reachable, plane_z_m)
    xy = np.asarray(studs_xy_w, dtype=np.float64).reshape(-1, 2)
    if not fewest or len(xy) > FEWEST_MAX_STUDS or len(grid.stations) <= 1:
        return grid
    free = _fewest_stations(xy, fov_m, camera_height_m, overlap, yaw_rad, camera_reachable, plane_z_m)
    better = (len(free.unreachable) <= len(grid.unreachable) and len(free.stations) < len(grid.stations))
    return free if better else grid


def _fewest_stations(xy: np.ndarray, fov_m: tuple[float, float], camera_height_m: float, overlap: float,
                     yaw_rad: float, camera_reachable: Callable[[np.ndarray], bool] | None,
                     plane_z_m: float) -> StationPlan:
    """Greedy set cover by inner footprints placed with a stud on their left and one on their bottom edge."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    R = np.array([[c, -s], [s, c]])
    local = xy @ R
    half = np.array(fov_m, dtype=np.float64) * (1.0 - overlap) / 2
    eps = 1e-9 * max(1.0, float(np.max(np.abs(local))))
    centres = np.stack(np.meshgrid(local[:, 0] + half[0], local[:, 1] + half[1], indexing="ij"), -1).reshape(-1, 2)
    centres = np.unique(centres, axis=0)
    covers = np.all(np.abs(local[None, :, :] - centres[:, None, :]) <= half + eps, axis=2)  # (C, N)
    left = np.ones(len(xy), dtype=bool)
    usable = np.ones(len(centres), dtype=bool)
    chosen: list[np.ndarray] = []
    while left.any():
        gain = np.where(usable, (covers & left).sum(axis=1), -1)
        k = int(np.argmax(gain))
        if gain[k] <= 0:
            break
        members = covers[k] & left
        # Slide the footprint to the middle of what it takes (still inside: that span is < the footprint).
        span = local[members]
        centre = (span.min(axis=0) + span.max(axis=0)) / 2
        xyz = np.array([*(R @ centre), plane_z_m + camera_height_m])
        usable[k] = False
        if camera_reachable is not None and not camera_reachable(xyz):
            continue
        chosen.append(centre)
        left &= ~np.all(np.abs(local - centre) <= half + eps, axis=1)
    if not chosen:
        return StationPlan((), tuple(int(i) for i in np.flatnonzero(left)))
    C = np.asarray(chosen)
    rel = np.abs(local[:, None, :] - C[None, :, :]) / half  # (N, S), 1 = the inner footprint's border
    inside = np.all(rel <= 1 + eps, axis=2)
    owner = np.where(inside.any(axis=1), np.argmin(np.where(inside, rel.max(axis=2), np.inf), axis=1), -1)
    order = _nearest_first(C)
    stations: list[Station] = []
    for k in order:
        members = tuple(int(i) for i in np.flatnonzero(owner == k))
        if not members:
            continue
        w = R @ C[k]
        stations.append(Station(len(stations) + 1, (float(w[0]), float(w[1]), float(plane_z_m + camera_height_m)),
                                float(yaw_rad), members))
    return StationPlan(tuple(stations), tuple(int(i) for i in np.flatnonzero(owner < 0)))


def _nearest_first(points: np.ndarray) -> list[int]:
    """Visiting order from the lowest-then-leftmost point, always to the nearest one left."""
    left = list(range(len(points)))
    here = min(left, key=lambda i: (points[i, 1], points[i, 0]))
    order = [here]
    left.remove(here)
    while left:
        here = min(left, key=lambda i: float(np.linalg.norm(points[i] - points[order[-1]])))
        order.append(here)
        left.remove(here)
    return order


def _grid_stations(studs_xy_w: np.ndarray, fov_m: tuple[float, float], camera_height_m: float,
                   overlap: float, yaw_rad: float, camera_reachable: Callable[[np.ndarray], bool] | None,
                   plane_z_m: float) -> StationPlan:
    """The grid tiling (module docstring)."""
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
