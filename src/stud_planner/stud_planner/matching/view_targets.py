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
from functools import cached_property

import cv2
import numpy as np

from stud_perception.camera_model import CameraModel
from stud_perception.registration import local_to_world
from stud_common.vocabulary import VIEW_DEPENDENT, MatchAlgorithm, TargetStatus, choices
from stud_planner.matching.gun_clearance import Clearance, GunModel, gun_clearance
from stud_planner.matching.match_common import observed_heights, z_range_of
from stud_planner.matching.matchers import MatchResults, MatchStatus, match_batch, match_bfs, match_fpm
from stud_planner.matching.noise_correlation import NoiseCorrelation
from stud_planner.matching.surface_pose import (SurfacePoses, SurfaceStatus, estimate_surface_poses_for_matches,
                                                frame_noise_correlation, offset_along_normal)

# The target statuses are stud_common.vocabulary.TargetStatus (the WeldTarget.STATUS_* values); the
# names below are the arrays' spelling of them.
(STATUS_OK, STATUS_OUT_OF_VIEW, STATUS_NO_DEPTH, STATUS_NOT_CONVERGED, STATUS_NORMAL_UNCERTAIN, STATUS_UNREACHABLE,
 STATUS_NO_NORMAL, STATUS_DEPTH_DISCONTINUITY, STATUS_GUN_BLOCKED) = (int(s) for s in TargetStatus)
STATUS_TEXT = {int(s): s.text for s in TargetStatus}
VIEW_DEPENDENT_STATUSES = frozenset(int(s) for s in VIEW_DEPENDENT)
ALGORITHMS = choices(MatchAlgorithm)  # the matcher node's and plan's choices


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
    normal_window_m: float = 0.02
    normal_samples_per_side: int = 81
    max_normal_rms_m: float = 0.0015
    lean_budget_deg: float = 5.0
    arm_orientation_error_deg: float = 0.5
    normal_sigma_k: float = 3.0
    normal_sigma_floor_deg: float = 0.1
    noise_correlation_max_lag_px: int = 16
    sample_step_max_loss: float = 0.05
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
        if not 0 <= self.noise_correlation_max_lag_px <= 64:
            raise ValueError(f"noise_correlation_max_lag_px={self.noise_correlation_max_lag_px} must be in [0, 64] px")
        if not 0 <= self.sample_step_max_loss <= 1:
            raise ValueError(f"sample_step_max_loss={self.sample_step_max_loss} must be in [0, 1] (a fraction of "
                             "the normal's 1-sigma)")


@dataclass(frozen=True, eq=False)
class ViewTargets:
    """Targets of N studs on one view (arrays in stud order; NaN where there is no value)."""

    ids: list[str]
    drawing_xy_m: np.ndarray     # (N, 2)
    target_xy_w: np.ndarray      # (N, 2) where the drawing puts each stud on the world plane
    position_w: np.ndarray       # (N, 3)
    normal_w: np.ndarray         # (N, 3)
    quat_xyzw: np.ndarray        # (N, 4)
    inclination_deg: np.ndarray  # (N,) the surface's slope against world z (information)
    normal_rms_m: np.ndarray     # (N,) RMS of the fit that gave the normal
    normal_sigma_deg: np.ndarray  # (N,) the normal's 1-sigma uncertainty
    lean_bound_deg: np.ndarray   # (N,) the worst lean from the true normal the target could give
    gun_clearance_m: np.ndarray  # (N,) the gun's clearance to the part (negative: it would touch)
    status: np.ndarray           # (N,) uint8, STATUS_*
    matches: MatchResults
    poses: SurfacePoses
    clearance: Clearance
    algorithm: str
    match_time_s: float
    config: "PlannerConfig"

    @cached_property
    def status_text(self) -> list[str]:
        """(N,) status names, built once (read per stud by callers: a property rebuilding the
        list on each access made a per-stud loop quadratic)."""
        return [STATUS_TEXT[s] for s in self.status.tolist()]

    def reason(self, i: int) -> str:
        """Why stud ``i`` is not usable, with the figure behind it ("" when it is)."""
        st = int(self.status[i])
        if st == STATUS_NORMAL_UNCERTAIN:
            return (f"normal 1-sigma {self.normal_sigma_deg[i]:.2f} deg (fill {self.poses.fill_ratio[i]:.0%} of the "
                    f"window): the stud could lean up to {self.lean_bound_deg[i]:.1f} deg > "
                    f"{self.config.lean_budget_deg:g} deg budget")
        if st == STATUS_GUN_BLOCKED:
            return (f"the gun ({self.config.gun.radius_m * 1e3:.0f} mm radius) would touch the part "
                    f"{-self.gun_clearance_m[i] * 1e3:.1f} mm inside it, {self.clearance.along_m[i] * 1e3:.0f} mm "
                    "up the stud's axis")
        if st == STATUS_NO_NORMAL:
            p = self.poses
            if p.status[i] == SurfaceStatus.BAD_FIT:
                return (f"no trustworthy normal: the window is not one smooth surface (fit RMS "
                        f"{p.fit_rms_m[i] * 1e3:.2f} mm, {p.outlier_ratio[i]:.0%} outliers: an edge or a step)")
            return f"no trustworthy normal: too few depth points (fill {p.fill_ratio[i]:.0%} of the window)"
        return "" if st == STATUS_OK else STATUS_TEXT[st]

    @property
    def ok(self) -> np.ndarray:
        return self.status == STATUS_OK

    @property
    def message_quat_xyzw(self) -> np.ndarray:
        """(N, 4) the orientations messages carry: the identity where there is no normal (NaN)."""
        quat = np.array(self.quat_xyzw, dtype=np.float64).reshape(-1, 4)
        quat[~np.all(np.isfinite(quat), axis=1)] = (0.0, 0.0, 0.0, 1.0)
        return quat

    def counts(self) -> dict[str, int]:
        vals, n = np.unique(self.status, return_counts=True)
        return {STATUS_TEXT[int(v)]: int(c) for v, c in zip(vals, n)}

    def sigma_inflation(self) -> float:
        """The median factor the normals' 1-sigma was widened by for the depth noise's correlation
        (1: independent noise or no normal)."""
        f = self.poses.sigma_inflation[np.isfinite(self.poses.sigma_inflation)]
        return float(np.median(f)) if f.size else 1.0


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
              noise: NoiseCorrelation | None = None) -> ViewTargets:
    """Match every stud of the drawing on this view and estimate its weld pose (see module doc).

    ``noise``: the depth noise's correlation measured on an earlier frame of the same camera
    (:func:`view_noise_correlation`), to skip measuring it on this one; None: measured here."""
    drawing_xy_m = np.asarray(drawing_xy_m, dtype=np.float64).reshape(-1, 2)
    target_xy_w = local_to_world(M_local2world, drawing_xy_m)
    t0 = time.perf_counter()
    heights = observed_heights(depth_m, camera)  # once: the matcher's heights and the gun's top
    matches = match(config.algorithm, target_xy_w, depth_m, camera, config, heights)
    match_time = time.perf_counter() - t0
    poses = estimate_surface_poses_for_matches(matches, depth_m, camera, window_m=config.normal_window_m,
                                               max_samples_per_side=config.normal_samples_per_side,
                                               max_rms_m=config.max_normal_rms_m, target_xy_w=target_xy_w,
                                               noise_correlation_max_lag_px=config.noise_correlation_max_lag_px,
                                               sample_step_max_loss=config.sample_step_max_loss, noise=noise)
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
    return ViewTargets(ids=list(ids), drawing_xy_m=drawing_xy_m, target_xy_w=target_xy_w, position_w=position,
                       normal_w=poses.normal_w, quat_xyzw=poses.quat_xyzw, inclination_deg=poses.inclination_deg,
                       normal_rms_m=poses.fit_rms_m, normal_sigma_deg=poses.normal_sigma_deg,
                       lean_bound_deg=np.where(poses.ok, lean_bound, np.nan), gun_clearance_m=clearance.clearance_m,
                       status=status, matches=matches, poses=poses, clearance=clearance, algorithm=config.algorithm,
                       match_time_s=match_time, config=config)


def view_noise_correlation(targets: ViewTargets, depth_m: np.ndarray, camera: CameraModel) -> NoiseCorrelation:
    """The depth noise's correlation of the frame ``targets`` were planned on, measured as
    :func:`plan_view` measures it, for a later frame of the same camera (``plan_view(noise=...)``)."""
    return frame_noise_correlation(targets.matches.point_w, targets.matches.pixel_uv, depth_m, camera,
                                   window_m=targets.config.normal_window_m,
                                   max_lag_px=targets.config.noise_correlation_max_lag_px, valid=targets.matches.ok)


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
        if was is None or (was.width, was.height) != (camera.width, camera.height) or not np.array_equal(was.K, camera.K):
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
