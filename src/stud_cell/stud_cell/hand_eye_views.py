"""Camera poses for the hand-eye calibration and its daily check: views of the marking board.

Every view looks at one point of the board (the centre of the marks' bounding box) from
``distance_m``, tilted from straight down by one of ``tilts_deg`` toward an azimuth spread
around the board, and turned about its optical axis by up to ``yaw_span_deg``, so the tool's
orientations spread about all three axes (a hand-eye needs rotations about two different axes at
least; :func:`stud_perception.hand_eye.rotation_spread_deg` measures it). The first view is
straight down with yaw 0: the pose the cell's registration station uses, reachable by design.
Whether the others are reachable is for the arm driver to say (``/arm/move_to`` refuses what its
IK or workspace cannot do); the calibrator skips those. :class:`ViewAimer` aims the views through
the best hand-eye known so far. Pure numpy: no ROS.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from stud_common.hand_eye_in_use import HandEyeLimits
from stud_common.rotations import transform
from stud_perception.hand_eye import BoardShot, board_points_m, calibrate_hand_eye
from stud_perception.hand_eye_solvers import HandEyeError, rotation_angle_deg
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


def board_centre_w(T_world_board: np.ndarray, drawing_marks_m) -> np.ndarray:
    """World point (3,) the views look at: the centre of the marks' bounding box on the board."""
    board = board_points_m(drawing_marks_m)
    return (np.asarray(T_world_board) @ np.append((board.min(axis=0) + board.max(axis=0)) / 2.0, 1.0))[:3]


#: Shots a preliminary hand-eye is solved from, at the least, and the spread of their orientations
#: about two axes it needs (below it the estimate is undetermined about one axis).
REAIM_MIN_SHOTS = 6
REAIM_MIN_SPREAD_DEG = 10.0


class ViewAimer:
    """Calibration views, aimed through the best hand-eye known so far.

    The first views go through the believed hand-eye (the driver's camera frame). A camera mounted
    3 deg off that value sees the board 16 mm off at 0.3 m, and the tilted views cut a mark at the
    image border: a third of them were lost on rendered shots, and the calibration then lacked poses.
    Once :data:`REAIM_MIN_SHOTS` shots spread :data:`REAIM_MIN_SPREAD_DEG` about two axes and agree
    with a preliminary calibration within the residual limits, the remaining views are planned again
    around the board that estimate sees and commanded as tool poses through it (re-estimated at each
    new shot). Aiming only decides where the arm looks: the calibration itself uses every shot, and
    is judged against the full limits as before.

    ``plan``: views around a board point (``plan_calibration_views`` with the settings bound);
    ``target_w``: the board point from the first look, through the believed hand-eye.
    """

    def __init__(self, plan: Callable[[np.ndarray], list[CalibrationView]], target_w, drawing_marks_m,
                 limits: HandEyeLimits = HandEyeLimits()) -> None:
        self._plan = plan
        self._marks = np.asarray(drawing_marks_m, dtype=np.float64)
        self._limits = dataclasses.replace(limits, min_poses=REAIM_MIN_SHOTS,
                                           min_rotation_spread_deg=REAIM_MIN_SPREAD_DEG)
        self.views = plan(np.asarray(target_w, dtype=np.float64))
        self.T_tool_cam: np.ndarray | None = None  # the estimate the views are aimed through; None: the believed
        self.aimed_from = 0  # shots the estimate in use was solved from

    def tool_pose(self, view: CalibrationView) -> np.ndarray | None:
        """Weld-tool pose (4, 4) in world that puts the camera at ``view`` through the estimate; None
        before there is one (command the camera frame: the driver's believed hand-eye)."""
        if self.T_tool_cam is None:
            return None
        return transform(view.R_world_cam, view.t_world_cam) @ np.linalg.inv(self.T_tool_cam)

    def update(self, shots: list[BoardShot], believed_T_tool_cam: np.ndarray) -> str | None:
        """Re-estimate from ``shots``; a line for the log when the views are (re-)aimed, else None."""
        if len(shots) < REAIM_MIN_SHOTS:
            return None
        try:
            result = calibrate_hand_eye(shots, self._marks, self._limits)
        except HandEyeError:
            return None
        if not result.accepted:  # the shots do not agree with one hand-eye yet: keep the aim
            return None
        first = self.T_tool_cam is None
        self.T_tool_cam, self.aimed_from = result.T_tool_cam, len(shots)
        self.views = self._plan(board_centre_w(result.T_world_board, self._marks))
        if not first:
            return None
        mm = 1e3 * float(np.linalg.norm(result.T_tool_cam[:3, 3] - believed_T_tool_cam[:3, 3]))
        deg = float(rotation_angle_deg(result.T_tool_cam[:3, :3], believed_T_tool_cam[:3, :3]))
        return (f"views aimed through the hand-eye of the first {len(shots)} shots from now on "
                f"({mm:.2f} mm / {deg:.3f} deg from the believed value)")
