"""Camera stations the arm can reach: a station plan made to pass the driver's reach test.

:func:`~stud_cell.stations.plan_stations` tiles the studs with camera footprints; nothing in
that says the arm can hold the camera there. :func:`reachable_stations` asks the driver's own test
(:class:`~stud_cell.cell_reach.CellReach`) for every station and, for one the arm cannot
reach, looks for another nadir pose that still holds all its studs in the inner footprint: the
camera higher or lower (``height_steps_m``), the footprint slid within the room its studs leave, the
image turned by 180 deg (the camera beside the gun moves with the wrist) or 90 deg. When no such
pose exists the station's studs are split in two along their longer spread and each half placed the
same way; a single stud no reachable pose sees is reported with the reason, never silently
dropped. A station the plan sends is one the driver accepts.

Pure numpy; world frame, metres, radians.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from stud_cell.stations import Station, StationPlan, footprint_m

#: ``cameras_ok([(xyz, yaw), ...]) -> [bool, ...]``: the driver's verdicts on nadir camera poses.
CamerasOk = Callable[[Sequence[tuple[np.ndarray, float]]], Sequence[bool]]

#: Image turns tried (rad, added to the station's yaw): the same footprint first, then turned a quarter.
_TURNS = (0.0, math.pi, math.pi / 2, -math.pi / 2)
#: The camera stays at least this far above the part's top [m] (its nearest focus, the studs' tops).
MIN_CLEARANCE_M = 0.12


@dataclass(frozen=True)
class StationGeometry:
    """How a station sees: the camera's field of view (``fov_width_m`` at ``fov_distance_m``, image
    height / width ``image_aspect``), the part's top ``part_height_m`` above the working plane at
    world height ``plane_z_m``, the border kept free ``overlap``, the nominal camera height above the
    plane and the height changes tried (``height_steps_m``, in order)."""

    fov_width_m: float
    fov_distance_m: float
    image_aspect: float
    part_height_m: float
    camera_height_m: float
    plane_z_m: float = 0.0
    overlap: float = 0.15
    height_steps_m: tuple[float, ...] = (0.0, 0.05, -0.05, 0.10)

    def inner_half(self, height_m: float) -> np.ndarray:
        """Half the inner footprint (x, y along the image axes) at the part's top from ``height_m`` above the plane."""
        w, h = footprint_m(self.fov_width_m, self.fov_distance_m, self.image_aspect, height_m, self.part_height_m)
        return np.array([w, h]) * (1.0 - self.overlap) / 2

    def heights(self) -> list[float]:
        return [self.camera_height_m + dh for dh in self.height_steps_m
                if self.camera_height_m + dh - self.part_height_m >= MIN_CLEARANCE_M]


def _rot(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s], [s, c]])


def candidate_poses(members_xy: np.ndarray, nominal_xy: np.ndarray, yaw_rad: float,
                    geom: StationGeometry) -> list[tuple[np.ndarray, float]]:
    """Nadir camera poses ``(xyz, yaw)`` whose inner footprint holds every one of ``members_xy``
    (N, 2), in the order tried: the nominal pose first, then by height step, image turn, and the
    distance the footprint slides from the nominal centre."""
    xy = np.asarray(members_xy, dtype=np.float64).reshape(-1, 2)
    out: list[tuple[np.ndarray, float]] = []
    for h in geom.heights():
        half = geom.inner_half(h)
        for turn in _TURNS:
            yaw = yaw_rad + turn
            R = _rot(yaw)
            local = xy @ R
            lo, hi = local.max(axis=0) - half, local.min(axis=0) + half
            if np.any(lo > hi + 1e-9):
                continue
            hi = np.maximum(hi, lo)
            nominal = np.asarray(nominal_xy, dtype=np.float64) @ R
            grid = np.stack(np.meshgrid(*(np.linspace(a, b, 3) for a, b in zip(lo, hi)), indexing="ij"), -1)
            centres = np.vstack([np.clip(nominal, lo, hi)[None], grid.reshape(-1, 2)])
            centres = centres[np.argsort(np.linalg.norm(centres - nominal, axis=1), kind="stable")]
            unique, first = np.unique(np.round(centres, 6), axis=0, return_index=True)
            for c in unique[np.argsort(first)]:
                w = R @ c
                out.append((np.array([w[0], w[1], geom.plane_z_m + h]), yaw))
    return out


def place_station(members_xy: np.ndarray, nominal_xy: np.ndarray, yaw_rad: float, geom: StationGeometry,
                  cameras_ok: CamerasOk) -> tuple[tuple[np.ndarray, float] | None, int]:
    """The first reachable pose of :func:`candidate_poses` (None if none is) and how many were tried."""
    poses = candidate_poses(members_xy, nominal_xy, yaw_rad, geom)
    if not poses:
        return None, 0
    if cameras_ok(poses[:1])[0]:  # most stations: the nominal pose
        return poses[0], 1
    ok = list(cameras_ok(poses[1:]))
    for pose, good in zip(poses[1:], ok):
        if good:
            return pose, len(poses)
    return None, len(poses)


def reachable_stations(plan: StationPlan, studs_xy: np.ndarray, geom: StationGeometry,
                       cameras_ok: CamerasOk) -> tuple[StationPlan, dict[int, str]]:
    """``plan`` with every station at a pose ``cameras_ok`` accepts (module docstring): the new plan,
    in the old one's visiting order, and why each stud no reachable station sees cannot be seen
    (stud index -> reason; those studs are in the plan's ``unreachable`` too)."""
    xy = np.asarray(studs_xy, dtype=np.float64).reshape(-1, 2)
    placed: list[tuple[tuple[float, float, float], float, tuple[int, ...]]] = []
    reasons: dict[int, str] = {}

    def place(members: list[int], nominal_xy: np.ndarray, yaw: float) -> None:
        pose, tried = place_station(xy[members], nominal_xy, yaw, geom, cameras_ok)
        if pose is not None:
            x, y, z = (float(v) for v in pose[0])
            placed.append(((x, y, z), float(pose[1]), tuple(members)))
            return
        if len(members) == 1:
            heights = ", ".join(f"{h:.2f}" for h in geom.heights())
            reasons[members[0]] = (f"no camera pose the arm reaches sees it ({tried} nadir poses tried: {heights} m "
                                   "above the plane, slid and turned)")
            return
        local = xy[members] @ _rot(yaw)
        axis = int(np.argmax(np.ptp(local, axis=0)))
        order = [members[k] for k in np.argsort(local[:, axis], kind="stable")]
        for half in (order[: len(order) // 2], order[len(order) // 2:]):
            place(half, xy[half].mean(axis=0), yaw)

    for station in plan.stations:
        place(list(station.stud_indices), np.asarray(station.camera_xyz_w[:2]), station.yaw_rad)
    stations = tuple(Station(k + 1, xyz, yaw, members) for k, (xyz, yaw, members) in enumerate(placed))
    return StationPlan(stations, tuple(sorted(set(plan.unreachable) | set(reasons)))), reasons


__all__ = ["CamerasOk", "StationGeometry", "candidate_poses", "place_station", "reachable_stations"]
