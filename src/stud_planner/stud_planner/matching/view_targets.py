"""Weld targets for one view: drawing -> world XY (Eq. 2), match (BFS / FPM / batch), pose, status.

The core the matcher node and the offline planner share. For each stud of the drawing it
returns the weld point on the surface, the outward normal, the pose quaternion (z along
the normal), the surface's slope, the normal's uncertainty, the gun's clearance and one status:

``ok`` | ``out_of_view`` | ``no_depth`` | ``not_converged`` | ``depth_discontinuity`` (from the
matcher) | ``no_normal`` (too few points or a bad fit: no normal at all) | ``normal_uncertain``
(the welded stud could lean more than the lean budget from the true normal) | ``gun_blocked``
(the gun would touch the part along its approach, descent or retract).

The gun is welded along the normal at any slope: the slope (``inclination_deg``, against world z)
is information, never a refusal. What limits a stud is the code's 5 deg (the paper's Fig. 9:
13 mm top offset for an M16x150), the most the *welded stud* may lean from the true
perpendicular: an error budget, consumed by the normal's uncertainty (``normal_sigma_k`` times its
1-sigma) and the arm's orientation error. ``lean_bound_deg`` is that sum: the worst lean the
target could give. Status codes equal the STATUS_* constants of stud_welding_msgs/WeldTarget.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import cv2
import numpy as np

from stud_common.vocabulary import VIEW_DEPENDENT, MatchAlgorithm, TargetStatus, choices
from stud_perception.camera_model import CameraModel
from stud_perception.registration import local_to_world
from stud_planner.matching.gun_clearance import Clearance, GunModel, gun_clearance
from stud_planner.matching.match_common import observed_heights, z_range_of
from stud_planner.matching.matchers import MatchResults, MatchStatus, match_batch, match_bfs, match_fpm
from stud_planner.matching.noise_correlation import NoiseCorrelation
from stud_planner.matching.surface_pose import (
    SurfaceFitConfig,
    SurfacePoses,
    SurfaceStatus,
    estimate_surface_poses_for_matches,
    frame_noise_correlation,
    offset_along_normal,
)
from stud_planner.matching.target_table import STATUS_TEXTS, TargetTable, centre_offset

# The target statuses are stud_common.vocabulary.TargetStatus (the WeldTarget.STATUS_* values); the
# names below are the arrays' spelling of them.
(STATUS_OK, STATUS_OUT_OF_VIEW, STATUS_NO_DEPTH, STATUS_NOT_CONVERGED, STATUS_NORMAL_UNCERTAIN, STATUS_UNREACHABLE,
 STATUS_NO_NORMAL, STATUS_DEPTH_DISCONTINUITY, STATUS_GUN_BLOCKED) = (int(s) for s in TargetStatus)
STATUS_TEXT = {int(s): s.text for s in TargetStatus}
VIEW_DEPENDENT_STATUSES = frozenset(int(s) for s in VIEW_DEPENDENT)
ALGORITHMS = choices(MatchAlgorithm)  # the matcher node's and plan's choices
_FIT = SurfaceFitConfig()  # the surface fit's defaults are its own; the planner's fields take them


@dataclass(frozen=True)
class PlannerConfig:
    """Matcher and pose settings (metres, pixels, degrees).

    ``lean_budget_deg``: the most a welded stud may lean from the true normal (the code's 5 deg);
    ``arm_orientation_error_deg`` is the arm's share of it, ``normal_sigma_k`` the coverage factor
    on the normal's 1-sigma (3: 99 % of a 2D normal error), ``normal_sigma_floor_deg`` what the
    fit's covariance cannot see (depth quantisation, the quadric's model error), added in
    quadrature; a target whose ``lean_bound_deg`` = k * sqrt(sigma^2 + floor^2) + arm error
    exceeds the budget is ``normal_uncertain``. The 1-sigma is the fit's own, widened by the depth
    noise's correlation across pixels as the frame shows it up to ``noise_correlation_max_lag_px``
    (0: the noise is taken as independent, which understates a real camera's normal error
    several-fold: :mod:`stud_planner.matching.noise_correlation`). Where that correlation makes
    neighbouring pixels redundant, the normal's window is sampled every few pixels, at a cost of at
    most ``sample_step_max_loss`` of the normal's 1-sigma (0: every pixel). ``gun``: the volume the gun
    sweeps about the stud's axis, checked against the view (``check_gun_clearance``).
    ``tool_offset_m``: the reported position is moved this far along the normal (0: the surface
    point; the paper's M16x150 stud top is 13 mm -> use the arm driver's tool offset instead).
    """

    algorithm: str = MatchAlgorithm.BATCH.value  # a MatchAlgorithm's text
    tol_m: float = 0.001
    fpm_window_px: int = 25
    hole_window_px: int = 7
    normal_window_m: float = _FIT.window_m
    normal_samples_per_side: int = _FIT.max_samples_per_side
    max_normal_rms_m: float = _FIT.max_rms_m
    lean_budget_deg: float = 5.0
    arm_orientation_error_deg: float = 0.5
    normal_sigma_k: float = 3.0
    normal_sigma_floor_deg: float = 0.1
    noise_correlation_max_lag_px: int = _FIT.noise_correlation_max_lag_px
    sample_step_max_loss: float = _FIT.sample_step_max_loss
    check_gun_clearance: bool = True
    gun: GunModel = GunModel()
    tool_offset_m: float = 0.0
    bfs_max_pixels: int | None = None

    def __post_init__(self) -> None:
        if self.algorithm not in ALGORITHMS:
            raise ValueError(f"algorithm '{self.algorithm}' unknown; expected one of {list(ALGORITHMS)}")
        if not 0 < self.lean_budget_deg <= 90 or not 0 <= self.arm_orientation_error_deg < self.lean_budget_deg:
            raise ValueError(f"lean_budget_deg={self.lean_budget_deg} must be in (0, 90] and above "
                             f"arm_orientation_error_deg={self.arm_orientation_error_deg} >= 0")
        if not self.normal_sigma_k > 0:
            raise ValueError(f"normal_sigma_k={self.normal_sigma_k} must be positive")
        _ = self.surface_fit  # the surface fit checks its own settings (ValueError)

    @property
    def surface_fit(self) -> SurfaceFitConfig:
        """The surface fit's settings (:func:`estimate_surface_poses`): these ``normal_*`` and noise
        fields, the fit's own defaults for the rest."""
        return SurfaceFitConfig(window_m=self.normal_window_m, max_samples_per_side=self.normal_samples_per_side,
                                max_rms_m=self.max_normal_rms_m,
                                noise_correlation_max_lag_px=self.noise_correlation_max_lag_px,
                                sample_step_max_loss=self.sample_step_max_loss)


@dataclass(frozen=True, eq=False)
class ViewTargets(TargetTable):
    """The weld targets of one view (a :class:`TargetTable`) and how they came about: where the drawing
    puts each stud on the world plane (``target_xy_w`` (N, 2)), the matches, the surface poses, the
    gun's clearance, the settings and the matcher's time."""

    target_xy_w: np.ndarray
    matches: MatchResults
    poses: SurfacePoses
    clearance: Clearance
    algorithm: str
    match_time_s: float
    config: "PlannerConfig"

    def reason(self, i: int) -> str:
        """Why stud ``i`` is not usable, with the figure behind it ("" when it is)."""
        return str(self.reasons[i])

    def sigma_inflation(self) -> float:
        """The median factor the normals' 1-sigma was widened by for the depth noise's correlation
        (1: independent noise or no normal)."""
        f = self.poses.sigma_inflation[np.isfinite(self.poses.sigma_inflation)]
        return float(np.median(f)) if f.size else 1.0


def _reasons(status: np.ndarray, poses: SurfacePoses, clearance: Clearance, lean_bound_deg: np.ndarray,
             config: PlannerConfig) -> np.ndarray:
    """(N,) why each target is not usable, with the figure behind it ("" when it is)."""
    reasons = STATUS_TEXTS[status]
    reasons[status == STATUS_OK] = ""
    for i in np.flatnonzero(np.isin(status, (STATUS_NORMAL_UNCERTAIN, STATUS_GUN_BLOCKED, STATUS_NO_NORMAL))).tolist():
        st = int(status[i])
        if st == STATUS_NORMAL_UNCERTAIN:
            reasons[i] = (f"normal 1-sigma {poses.normal_sigma_deg[i]:.2f} deg (fill {poses.fill_ratio[i]:.0%} of the "
                          f"window): the stud could lean up to {lean_bound_deg[i]:.1f} deg > "
                          f"{config.lean_budget_deg:g} deg budget")
        elif st == STATUS_GUN_BLOCKED:
            reasons[i] = (f"the gun ({config.gun.radius_m * 1e3:.0f} mm radius) would touch the part "
                          f"{-clearance.clearance_m[i] * 1e3:.1f} mm inside it, {clearance.along_m[i] * 1e3:.0f} mm "
                          "up the stud's axis")
        elif poses.status[i] == SurfaceStatus.BAD_FIT:
            reasons[i] = (f"no trustworthy normal: the window is not one smooth surface (fit RMS "
                          f"{poses.fit_rms_m[i] * 1e3:.2f} mm, {poses.outlier_ratio[i]:.0%} outliers: an edge or "
                          "a step)")
        else:
            reasons[i] = f"no trustworthy normal: too few depth points (fill {poses.fill_ratio[i]:.0%} of the window)"
    return reasons


def match(algorithm: str, targets_xy_w: np.ndarray, depth_m: np.ndarray, camera: CameraModel,
          config: PlannerConfig, heights: tuple | None | str = "observe") -> MatchResults:
    """Match with ``algorithm``; ``heights``: the view's :func:`observed_heights` if known (batch only)."""
    if algorithm == MatchAlgorithm.BATCH:
        z_range = None if isinstance(heights, str) else z_range_of(heights, camera)
        return match_batch(targets_xy_w, depth_m, camera, tol_m=config.tol_m, hole_window_px=config.hole_window_px,
                           z_range_m=None if z_range is None else z_range[:2],
                           z_init_m=None if z_range is None else z_range[2])
    if algorithm == MatchAlgorithm.FPM:
        return match_fpm(targets_xy_w, depth_m, camera, tol_m=config.tol_m, window_px=config.fpm_window_px,
                         hole_window_px=config.hole_window_px)
    return match_bfs(targets_xy_w, depth_m, camera, tol_m=config.tol_m, hole_window_px=config.hole_window_px,
                     max_pixels=config.bfs_max_pixels)


def plan_view(ids: list[str], drawing_xy_m: np.ndarray, M_local2world: np.ndarray, depth_m: np.ndarray,
              camera: CameraModel, config: PlannerConfig = PlannerConfig(),
              noise: NoiseCorrelation | None = None, view_index: int = 0) -> ViewTargets:
    """Match every stud of the drawing on this view and estimate its weld pose (see module doc).

    ``noise``: the depth noise's correlation measured on an earlier frame of the same camera
    (:func:`view_noise_correlation`), to skip measuring it on this one; None: measured here.
    ``view_index``: the view's number, every target's ``view_index``."""
    drawing_xy_m = np.asarray(drawing_xy_m, dtype=np.float64).reshape(-1, 2)
    target_xy_w = local_to_world(M_local2world, drawing_xy_m)
    t0 = time.perf_counter()
    heights = observed_heights(depth_m, camera)  # once: the matcher's heights and the gun's top
    matches = match(config.algorithm, target_xy_w, depth_m, camera, config, heights)
    match_time = time.perf_counter() - t0
    poses = estimate_surface_poses_for_matches(matches, depth_m, camera, config.surface_fit, target_xy_w=target_xy_w,
                                               noise=noise)
    status = matches.status.astype(np.uint8).copy()
    matched = status == MatchStatus.OK
    status[matched & ~poses.ok] = STATUS_NO_NORMAL
    lean_bound = (config.normal_sigma_k * np.hypot(poses.normal_sigma_deg, config.normal_sigma_floor_deg)
                  + config.arm_orientation_error_deg)
    uncertain = matched & poses.ok & ~(lean_bound <= config.lean_budget_deg)
    status[uncertain] = STATUS_NORMAL_UNCERTAIN
    position = np.where(poses.ok[:, None], poses.position_w, matches.point_w)
    usable = status == STATUS_OK
    if config.check_gun_clearance:
        z_top = z_range_of(heights, camera, margin_m=0.0)[1]
        clearance = gun_clearance(position, poses.normal_w, depth_m, camera, config.gun, valid=usable, z_top_w=z_top)
    else:
        clearance = Clearance(np.full(len(ids), np.nan), np.full(len(ids), np.nan), np.zeros(len(ids), np.int64))
    status[usable & clearance.blocked] = STATUS_GUN_BLOCKED
    if config.tool_offset_m:
        position = np.where(poses.ok[:, None], offset_along_normal(position, poses.normal_w, config.tool_offset_m),
                            position)
    lean_bound = np.where(poses.ok, lean_bound, np.nan)
    return ViewTargets(ids=list(ids), drawing_xy_m=drawing_xy_m, position_w=position, quat_xyzw=poses.quat_xyzw,
                       normal_w=poses.normal_w, pixel_uv=matches.pixel_uv,
                       view_index=np.full(len(ids), view_index, np.int64), iterations=matches.iterations,
                       xy_error_m=matches.xy_residual_m, inclination_deg=poses.inclination_deg,
                       normal_rms_m=poses.fit_rms_m, normal_sigma_deg=poses.normal_sigma_deg,
                       lean_bound_deg=lean_bound, fill_ratio=poses.fill_ratio, gun_clearance_m=clearance.clearance_m,
                       status=status, reasons=_reasons(status, poses, clearance, lean_bound, config),
                       centre_offset=centre_offset(matches.pixel_uv, camera.cx, camera.cy, camera.width, camera.height),
                       target_xy_w=target_xy_w, matches=matches, poses=poses, clearance=clearance,
                       algorithm=config.algorithm, match_time_s=match_time, config=config)


def view_noise_correlation(targets: ViewTargets, depth_m: np.ndarray, camera: CameraModel) -> NoiseCorrelation:
    """The depth noise's correlation of the frame ``targets`` were planned on, measured as
    :func:`plan_view` measures it, for a later frame of the same camera (``plan_view(noise=...)``)."""
    return frame_noise_correlation(targets.matches.point_w, targets.matches.pixel_uv, depth_m, camera,
                                   targets.config.surface_fit, valid=targets.matches.ok)


class NoiseMemory:
    """The depth noise's correlation of a camera's last measured frame, for its next frames at the
    same pose: measuring it costs about as much as matching a hundred studs, and a camera's noise
    does not change from one frame to the next.

    A measurement is recalled for up to ``max_age_s`` for a camera with the same intrinsics and
    size, moved at most ``max_shift_m`` and turned at most ``max_turn_deg`` (a new station's shot
    is measured on itself). From half that age on, :meth:`refresh_due` says to measure again on
    the frame just planned, after its targets are out: a steady stream never measures before its
    targets. ``max_age_s`` 0: nothing is recalled (every frame measured before its targets)."""

    def __init__(self, max_age_s: float, max_shift_m: float = 0.001, max_turn_deg: float = 0.1) -> None:
        self.max_age_s, self.max_shift_m, self.max_turn_deg = float(max_age_s), float(max_shift_m), float(max_turn_deg)
        self._camera: CameraModel | None = None
        self._noise: NoiseCorrelation | None = None
        self._at = float("-inf")

    def recall(self, camera: CameraModel, now_s: float) -> NoiseCorrelation | None:
        """The measurement to reuse for a frame of ``camera`` at ``now_s`` (monotonic s), or None."""
        if (self._noise is None or not self.max_age_s > 0 or not now_s - self._at <= self.max_age_s
                or not self._same_camera(camera)):
            return None
        return self._noise

    @property
    def measured_at_s(self) -> float:
        """When the measurement recalled was taken (monotonic s; -inf: none yet)."""
        return self._at

    def refresh_due(self, now_s: float) -> bool:
        """Whether the frame just planned should be measured for the frames after it."""
        return self.max_age_s > 0 and now_s - self._at >= 0.5 * self.max_age_s

    def remember(self, camera: CameraModel, noise: NoiseCorrelation, now_s: float) -> None:
        self._camera, self._noise, self._at = camera, noise, float(now_s)

    def _same_camera(self, camera: CameraModel) -> bool:
        was = self._camera
        if (was is None or (was.width, was.height) != (camera.width, camera.height)
                or not np.array_equal(was.K, camera.K)):
            return False
        cos_turn = 0.5 * (np.trace(was.R_wc.T @ camera.R_wc) - 1.0)
        return bool(np.linalg.norm(was.t_wc - camera.t_wc) <= self.max_shift_m
                    and cos_turn >= np.cos(np.radians(self.max_turn_deg)))


# -- overlay (the paper's Fig. 11) ---------------------------------------------------------------------
STATUS_BGR = {
    STATUS_OK: (40, 200, 40), STATUS_NORMAL_UNCERTAIN: (0, 165, 255), STATUS_NO_NORMAL: (0, 200, 255),
    STATUS_GUN_BLOCKED: (0, 80, 255),
    STATUS_NO_DEPTH: (220, 0, 220), STATUS_NOT_CONVERGED: (0, 0, 230), STATUS_DEPTH_DISCONTINUITY: (0, 0, 230),
    STATUS_UNREACHABLE: (200, 100, 0), STATUS_OUT_OF_VIEW: (128, 128, 128),
}


def draw_targets_overlay(color_bgr: np.ndarray, targets: ViewTargets, camera: CameraModel,
                         label: bool = True) -> np.ndarray:
    """Colour image with each in-view stud's matched pixel, its normal and its id, coloured by status."""
    img = color_bgr.copy()
    scale = max(1.0, img.shape[1] / 1280)
    for i, sid in enumerate(targets.ids):
        st = int(targets.status[i])
        if st == STATUS_OUT_OF_VIEW:
            continue
        uv = targets.matches.pixel_uv[i]
        if not np.all(np.isfinite(uv)):  # no pixel: show where the drawing puts it on the plane
            u, v, _ = camera.world_to_pixel(np.append(targets.target_xy_w[i], 0.0))
            if not (np.isfinite(u) and np.isfinite(v)):
                continue
            uv = np.array([u, v])
        colour = STATUS_BGR.get(st, (0, 0, 255))
        centre = (int(round(uv[0])), int(round(uv[1])))
        cv2.circle(img, centre, int(6 * scale), colour, 2, cv2.LINE_AA)
        n, p = targets.normal_w[i], targets.position_w[i]
        if np.all(np.isfinite(n)) and np.all(np.isfinite(p)):
            tip_u, tip_v, _ = camera.world_to_pixel(p + 0.03 * n)
            if np.isfinite(tip_u) and np.isfinite(tip_v):
                cv2.line(img, centre, (int(round(float(tip_u))), int(round(float(tip_v)))), colour, 1, cv2.LINE_AA)
        if label:
            text = sid if st == STATUS_OK else f"{sid} {STATUS_TEXT[st]}"
            cv2.putText(img, text, (centre[0] + 8, centre[1] - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.45 * scale, colour, 1,
                        cv2.LINE_AA)
    return img
