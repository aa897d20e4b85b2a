"""Where to look for the marking board: camera poses that search the table for the marks O, A, B.

The registration needs the three marks in one view. When no registration station is given, or the
marks are not where it looks, the cell searches: first the view from the highest camera pose the
arm reaches over the search area (the widest footprint), then, greedily, the reachable pose whose
view would newly hold the whole board at most places on the table, until every place of the area a
reachable view covers is covered or ``max_shots`` is reached. A pose "covers" a board position
when a board there, turned any way, lies inside its footprint: the footprint shrunk by
``board_radius_m`` (the smallest circle holding the marks, their size, and a margin for the image
border).

Pure numpy: the reach of a pose is a callback (the driver's test, ``CellReach.cameras``); world
frame, metres, radians.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

#: Spacing of the candidate camera positions and of the board positions counted [m].
GRID_M = 0.075
RASTER_M = 0.01

#: The table the arm reaches from a fixed base (world x_min, y_min, x_max, y_max, m): the search's area
#: when none is given; on a rail it stretches along the rail's travel (:func:`search_area`).
ARM_TABLE_XY_M = (0.0, -0.55, 0.65, 0.55)


class BoardSearchError(ValueError):
    """Search settings no pose can come from (named value)."""


@dataclass(frozen=True)
class SearchPlan:
    """The poses to shoot, in order (``(xyz, yaw)``, world), and how much of the area their views
    cover (``covered``, 0..1) -- the rest no reachable view holds a board in."""

    poses: tuple[tuple[tuple[float, float, float], float], ...]
    covered: float
    area_xy_m: tuple[float, float, float, float]
    heights_m: tuple[float, ...]

    def describe(self) -> str:
        x0, y0, x1, y1 = self.area_xy_m
        return (f"{len(self.poses)} search pose(s) over x {x0:.2f}..{x1:.2f} m, y {y0:.2f}..{y1:.2f} m, camera "
                f"{min(self.heights_m, default=0):.2f}..{max(self.heights_m, default=0):.2f} m above the plane, "
                f"{100 * self.covered:.0f} % of that area within a reachable view")


def board_radius_m(marks_xy_m: np.ndarray | None, mark_diameter_m: float, margin_m: float = 0.005) -> float:
    """Radius of the smallest circle holding the three marks O, A, B whole, plus ``margin_m``."""
    if marks_xy_m is None or len(marks_xy_m) != 3:
        return 0.12
    m = np.asarray(marks_xy_m, dtype=np.float64).reshape(3, 2)
    sides = [np.linalg.norm(m[(i + 1) % 3] - m[(i + 2) % 3]) for i in range(3)]
    a, b, c = sorted(sides)
    if a * a + b * b <= c * c:   # right or obtuse: the longest side is the diameter
        r = c / 2
    else:                        # acute: the circumcircle
        u, v = m[1] - m[0], m[2] - m[0]
        r = a * b * c / (2 * abs(u[0] * v[1] - u[1] * v[0]))   # abc / (4 x area)
    return float(r) + mark_diameter_m / 2 + margin_m


def search_area(area_xy_m: Sequence[float], max_shots: int, rail_length_m: float = 0.0
                ) -> tuple[tuple[float, float, float, float], int]:
    """The area to search and the most shots for it: ``area_xy_m`` when given (4 numbers) with
    ``max_shots``; empty -- none given -- the arm's table (:data:`ARM_TABLE_XY_M`) stretched by the
    rail's travel ``rail_length_m`` along world x, with ``max_shots`` for each table length of it (a part
    laid anywhere along the rail is found without the operator saying where)."""
    if len(area_xy_m):
        x0, y0, x1, y1 = (float(v) for v in area_xy_m)
        return (x0, y0, x1, y1), int(max_shots)
    x0, y0, x1, y1 = ARM_TABLE_XY_M
    x1 += max(float(rail_length_m), 0.0)
    return (x0, y0, x1, y1), int(math.ceil(max_shots * (x1 - x0) / (ARM_TABLE_XY_M[2] - ARM_TABLE_XY_M[0]) - 1e-9))


def search_plan(area_xy_m: Sequence[float], plane_z_m: float, heights_m: Sequence[float], fov_width_m: float,
                fov_distance_m: float, image_aspect: float, board_radius: float,
                cameras_ok: Callable[[list[tuple[np.ndarray, float]]], Sequence[bool]] | None,
                max_shots: int) -> SearchPlan:
    """The search (module docstring) over ``area_xy_m`` = (x_min, y_min, x_max, y_max), camera
    ``heights_m`` above the plane (any order; the highest reachable at each place is used), nadir,
    image yaw 0 or 180 deg. ``cameras_ok``: None -- every pose is taken as reachable (the arm driver
    refuses what it cannot do)."""
    x0, y0, x1, y1 = (float(v) for v in area_xy_m)
    if not (x1 > x0 and y1 > y0):
        raise BoardSearchError(f"board_search_area_xy_m={list(area_xy_m)}: expected [x_min, y_min, x_max, y_max] "
                               "with x_max > x_min and y_max > y_min")
    heights = sorted((float(h) for h in heights_m), reverse=True)
    if not heights or min(heights) <= 0:
        raise BoardSearchError(f"board search heights {list(heights_m)} must be positive")
    gx = np.arange(x0, x1 + 1e-9, GRID_M)
    gy = np.arange(y0, y1 + 1e-9, GRID_M)
    spots = np.array([(x, y) for x in gx for y in gy])
    chosen_h = np.full(len(spots), np.nan)
    chosen_yaw = np.zeros(len(spots))
    left = np.arange(len(spots))
    for h in heights:  # the highest reachable pose at each place
        if len(left) == 0:
            break
        poses = [(np.array([*spots[i], plane_z_m + h]), yaw) for i in left for yaw in (0.0, math.pi)]
        ok = np.ones(len(poses), bool) if cameras_ok is None else np.asarray(cameras_ok(poses), bool)
        ok = ok.reshape(-1, 2)
        hit = ok.any(axis=1)
        chosen_h[left[hit]] = h
        chosen_yaw[left[hit]] = np.where(ok[hit, 0], 0.0, math.pi)
        left = left[~hit]
        if cameras_ok is None:
            break
    usable = np.flatnonzero(np.isfinite(chosen_h))
    rx = np.arange(x0, x1 + 1e-9, RASTER_M)
    ry = np.arange(y0, y1 + 1e-9, RASTER_M)
    cells = np.array([(x, y) for x in rx for y in ry])
    covers = np.zeros((len(usable), len(cells)), bool)
    for k, i in enumerate(usable):
        half_w = fov_width_m * chosen_h[i] / fov_distance_m / 2 - board_radius
        half_h = fov_width_m * image_aspect * chosen_h[i] / fov_distance_m / 2 - board_radius
        if half_w > 0 and half_h > 0:
            d = np.abs(cells - spots[i])
            covers[k] = (d[:, 0] <= half_w) & (d[:, 1] <= half_h)
    order: list[int] = []
    seen = np.zeros(len(cells), bool)
    while len(order) < max_shots and len(usable):
        gain = (covers & ~seen).sum(axis=1).astype(float)
        if order:  # nearest first among equal gains
            last = spots[usable[order[-1]]]
            gain -= 1e-6 * np.linalg.norm(spots[usable] - last, axis=1)
        else:      # the highest, widest view first; nearest the area's centre among equals
            gain += 1e3 * len(cells) * chosen_h[usable] - 1e-6 * np.linalg.norm(
                spots[usable] - np.array([(x0 + x1) / 2, (y0 + y1) / 2]), axis=1)
        k = int(np.argmax(gain))
        if not (covers[k] & ~seen).any():
            break
        order.append(k)
        seen |= covers[k]
    shots = tuple(((float(spots[usable[k]][0]), float(spots[usable[k]][1]), float(plane_z_m + chosen_h[usable[k]])),
                   float(chosen_yaw[usable[k]])) for k in order)
    return SearchPlan(shots, float(seen.mean()) if len(cells) else 0.0, (x0, y0, x1, y1), tuple(heights))


__all__ = ["ARM_TABLE_XY_M", "BoardSearchError", "SearchPlan", "board_radius_m", "search_area", "search_plan"]
