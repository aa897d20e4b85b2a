"""Camera poses for the hand-eye calibration and its daily check: views of the marking board.

Every view looks at one point of the board (the centre of the marks' bounding box) from
``distance_m``, tilted from straight down by one of ``tilts_deg`` toward an azimuth spread
around the board, and turned about its optical axis by up to ``yaw_span_deg``, so the tool's
orientations spread about all three axes (a hand-eye needs rotations about two different axes at
least; :func:`stud_perception.hand_eye.rotation_spread_deg` measures it). The first view is
straight down with yaw 0: the pose the cell's registration station uses, reachable by design.
Whether the others are reachable is for the arm driver to say (``/arm/move_to`` refuses what its
IK or workspace cannot do); the calibrator skips those. Pure numpy: no ROS.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from stud_perception.scene_cameras import view_camera


class ViewPlanError(ValueError):
    """Settings from which no calibration views follow (names the setting and the value)."""


@dataclass(frozen=True)
class CalibrationView:
    """A camera pose: optical frame ``R_world_cam`` (3, 3) and ``t_world_cam`` (3,) m in `world`,
    and how it was made (degrees)."""

    index: int
    R_world_cam: np.ndarray
    t_world_cam: np.ndarray
    tilt_deg: float
    azimuth_deg: float
    yaw_deg: float

    def describe(self) -> str:
        return (f"view {self.index}: tilt {self.tilt_deg:.0f} deg toward {self.azimuth_deg:.0f} deg, yaw "
                f"{self.yaw_deg:+.0f} deg, camera at {np.round(self.t_world_cam, 3).tolist()} m")


def _view(index: int, target_w, distance_m: float, tilt: float, azimuth: float, yaw: float) -> CalibrationView:
    cam = view_camera(target_w, distance_m, math.radians(yaw), math.radians(tilt), math.radians(azimuth))
    return CalibrationView(index, cam.R_wc, cam.t_wc, tilt, azimuth % 360.0, yaw)


def station_view(camera_xyz_w, index: int = 0) -> CalibrationView:
    """Straight down (yaw 0) from ``camera_xyz_w`` (3,) m: the look that finds the board."""
    return _view(index, np.asarray(camera_xyz_w, dtype=np.float64) - [0.0, 0.0, 1.0], 1.0, 0.0, 0.0, 0.0)


def plan_calibration_views(target_w, distance_m: float = 0.30, tilts_deg=(10.0, 20.0, 30.0),
                           views_per_tilt: int = 12, yaw_span_deg: float = 30.0) -> list[CalibrationView]:
    """The views of a calibration, first straight down (yaw 0, then -/+ ``yaw_span_deg``), then per
    tilt ``views_per_tilt`` azimuths, each ring turned against the previous one and the yaw cycling
    through -span, 0, +span. ``target_w`` (3,): the board point looked at, world metres."""
    _check(distance_m, tilts_deg, views_per_tilt, yaw_span_deg)
    views = [_view(0, target_w, distance_m, 0.0, 0.0, 0.0)]
    for yaw in (-yaw_span_deg, yaw_span_deg):
        views.append(_view(len(views), target_w, distance_m, 0.0, 0.0, yaw))
    cycle = (-yaw_span_deg, 0.0, yaw_span_deg)
    for ring, tilt in enumerate(tilts_deg):
        offset = ring * 360.0 / views_per_tilt / len(tilts_deg)
        for k in range(views_per_tilt):
            azimuth = offset + k * 360.0 / views_per_tilt
            views.append(_view(len(views), target_w, distance_m, float(tilt), azimuth, cycle[(k + ring) % 3]))
    return views


def plan_check_views(target_w, distance_m: float = 0.30, tilt_deg: float = 25.0, azimuths: int = 8,
                     yaw_span_deg: float = 30.0) -> list[CalibrationView]:
    """The candidate views of a check (``verify``): straight down, then ``azimuths`` views at
    ``tilt_deg`` around the board, the yaw alternating -/+ ``yaw_span_deg`` (the caller takes the
    first few reachable ones). A wrong hand-eye makes them disagree about where the board is."""
    _check(distance_m, (tilt_deg,), azimuths, yaw_span_deg)
    views = [_view(0, target_w, distance_m, 0.0, 0.0, 0.0)]
    # every other azimuth first: the first few reachable views are spread around the board
    order = list(range(0, azimuths, 2)) + list(range(1, azimuths, 2))
    for k in order:
        views.append(_view(len(views), target_w, distance_m, tilt_deg, k * 360.0 / azimuths,
                           yaw_span_deg * (1 if k % 2 else -1)))
    return views


def _check(distance_m: float, tilts_deg, count: int, yaw_span_deg: float) -> None:
    if not 0.05 <= distance_m <= 2.0:
        raise ViewPlanError(f"view distance_m must be within 0.05..2.0 m, got {distance_m}")
    if not tilts_deg or any(not 0.0 < t <= 60.0 for t in tilts_deg):
        raise ViewPlanError(f"view tilts_deg must be within (0, 60] deg, got {list(tilts_deg)}")
    if count < 1:
        raise ViewPlanError(f"views per tilt must be at least 1, got {count}")
    if not 0.0 <= yaw_span_deg <= 90.0:
        raise ViewPlanError(f"yaw_span_deg must be within 0..90 deg, got {yaw_span_deg}")
