"""Weld pose at matched studs: the surface normal from a local quadric fit, its uncertainty, the tool pose.

The matcher gives the point where a stud's vertical line meets the surface; the welding gun
approaches along the surface normal there, whatever the slope. The normal comes from a
least-squares fit to the 3D points (Eq. 1 of every valid pixel) of a window around the match.
The window is specified in metres on the surface, not pixels, because the normal's noise falls
with the window's extent: at 0.5 mm depth noise a 7x7-11x11 px window gives 2-4 deg, a ~20 mm
window well under 1 deg.

The fitted surface is a quadric height field in the tangent frame of a first normal estimate,
h = b0 + b1 u + b2 v + b3 u^2 + b4 uv + b5 v^2, and the normal is its gradient at the stud.
A plane fits a curved part badly wherever the window's points are not centred on the stud (a
hole on one side, the image border): its tilt is the surface's at the points' centroid, off by
(centroid offset) / (radius of curvature) -- 2 deg for 5 mm on a 150 mm dome. The quadric's
gradient at the stud has no such bias, and on a symmetric window its slope terms are
uncorrelated with the curvature terms, so it costs no precision there.

Each fit reports its 1-sigma normal uncertainty (from the least-squares covariance: the residual
variance times the inverse normal matrix, so it grows with the depth noise, with holes and with
a lop-sided window), the RMS of the residuals, the fill ratio and the outlier ratio, so a planner
can refuse to weld on a normal it cannot trust.

Frames and units: `world` (z up), metres; normals are unit vectors oriented away from the
surface, toward the camera; quaternions are (x, y, z, w) of a frame whose z-axis is the normal
and whose x-axis is world X projected onto the tangent plane (world Y when the normal is along X).
The fit needs only sums over the window's valid pixels, so most windows take them from
summed-area tables of per-block moments (one pass over the frame, then constant work per stud:
:mod:`stud_planner.matching.window_moments`); the robust pixel path is kept for the windows whose plain
fit is rougher than the frame's noise (both fits: :mod:`stud_planner.matching.quadric_fit`). Vectorised
over studs (the pixel path in chunks, to bound memory).
"""
from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from stud_common.rotations import frame_from_normal
from stud_common.rotations import matrix_to_quaternion as quaternion_from_matrix
from stud_perception.camera_model import CameraModel
from stud_planner.matching.noise_correlation import NoiseCorrelation, measure_noise_correlation
from stud_planner.matching.quadric_fit import (
    N_TERMS,
    InverseDepthFit,
    fast_fits,
    fit_inverse_depth,
    frame_noise_m,
    window_blocks,
)
from stud_planner.matching.window_moments import BlockMoments

#: Paper: M16x150 shear stud, tool-top offset along the normal.
M16X150_TOP_OFFSET_M = 0.013


class SurfaceStatus(IntEnum):
    OK = 0
    NOT_MATCHED = 1  # no matched point (NaN input or the caller's mask)
    TOO_FEW_POINTS = 2  # fewer than min_points valid depths or fill ratio below min_fill_ratio
    BAD_FIT = 3  # fit RMS above max_rms_m or too many outliers (a step/edge in the window)


@dataclass(frozen=True)
class SurfacePoses:
    """Per-stud surface pose, N studs.

    - ``position_w`` (N, 3) m: the matched point moved along world z onto the fitted surface (the
      fit averages the depth noise out of the height; XY is the match's);
    - ``normal_w`` (N, 3): unit normal, toward the camera;
    - ``quat_xyzw`` (N, 4): orientation whose z-axis is the normal;
    - ``inclination_deg`` (N,): angle between normal and world z (the slope: information only);
    - ``normal_sigma_deg`` (N,): 1-sigma uncertainty of the normal's direction about its least
      certain axis, from the fit's covariance widened by the depth noise's correlation;
    - ``sigma_inflation`` (N,): the factor the fit's own 1-sigma was multiplied by for that
      correlation (1: independent noise; :mod:`stud_planner.matching.noise_correlation`);
    - ``fit_rms_m`` (N,): RMS distance of the inliers to the fitted surface;
    - ``fill_ratio`` (N,): valid depths / pixels sampled in the window;
    - ``outlier_ratio`` (N,): valid points rejected by the robust pass;
    - ``n_points`` (N,) int: inliers used;
    - ``status`` (N,) int8 :class:`SurfaceStatus`;
    - ``noise``: the depth noise's correlation the 1-sigmas were widened by (measured on this frame,
      or given: one measured on an earlier frame of the same camera).
    NaN where a value could not be estimated.
    """

    position_w: np.ndarray
    normal_w: np.ndarray
    quat_xyzw: np.ndarray
    inclination_deg: np.ndarray
    normal_sigma_deg: np.ndarray
    sigma_inflation: np.ndarray
    fit_rms_m: np.ndarray
    fill_ratio: np.ndarray
    outlier_ratio: np.ndarray
    n_points: np.ndarray
    status: np.ndarray
    noise: NoiseCorrelation

    def __len__(self) -> int:
        return int(self.status.shape[0])

    @property
    def ok(self) -> np.ndarray:
        return self.status == SurfaceStatus.OK


def inclination_deg(normal_w: np.ndarray) -> np.ndarray:
    """Angle (deg) between unit normals (..., 3) and world +z."""
    n = np.asarray(normal_w, dtype=np.float64)
    return np.degrees(np.arccos(np.clip(n[..., 2], -1.0, 1.0)))


def offset_along_normal(points_w: np.ndarray, normals_w: np.ndarray,
                        offset_m: float = M16X150_TOP_OFFSET_M) -> np.ndarray:
    """Points (..., 3) moved ``offset_m`` along the unit normals (e.g. the tool top of an M16x150 stud)."""
    return np.asarray(points_w, dtype=np.float64) + offset_m * np.asarray(normals_w, dtype=np.float64)


def quaternion_from_normal(normal_w: np.ndarray) -> np.ndarray:
    """(x, y, z, w) of :func:`frame_from_normal` -- the pose orientation whose z-axis is the normal."""
    return quaternion_from_matrix(frame_from_normal(normal_w))


def tangent_basis(normal_w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (..., 3) spanning the plane normal to each unit normal (..., 3): the x and
    y axes of :func:`frame_from_normal`."""
    R = frame_from_normal(normal_w)
    return R[..., 0], R[..., 1]


def _vertical_line_hit(fit: InverseDepthFit, camera: CameraModel, xy_w: np.ndarray, z0_w: np.ndarray,
                       iterations: int = 4) -> np.ndarray:
    """World z (n,) where the vertical lines through ``xy_w`` (n, 2) meet the fitted surfaces
    (Newton's method on F = Z w(X/Z, Y/Z) - 1 from z0_w, the matched heights)."""
    R_cw = camera.R_wc.T
    dX = R_cw[:, 2]  # d(optical point) / d(world z)
    z = z0_w.astype(np.float64).copy()
    for _ in range(iterations):
        P = np.column_stack([xy_w, z])
        X = (P - camera.t_wc) @ R_cw.T
        xt, yt = X[:, 0] / X[:, 2], X[:, 1] / X[:, 2]
        F = fit.residual_f(xt, yt, X[:, 2])
        g = fit.gradient(xt, yt)  # dF/dX
        with np.errstate(invalid="ignore", divide="ignore"):
            dz = np.where(np.isfinite(F / (g @ dX)), F / (g @ dX), 0.0)
        z -= dz
        if not np.any(np.abs(dz) > 1e-12):  # converged (quadratically, from the matched height)
            break
    return z


@dataclass(frozen=True)
class SurfaceFitConfig:
    """How :func:`estimate_surface_poses` fits each stud's window (metres, pixels).

    The window: ``window_m`` a side on the surface, sampled at most ``max_samples_per_side`` pixels
    a side. The fast path (``fast_fit``): the plain least-squares fit of a window of whole 8x8-pixel
    blocks from moment sums (:mod:`stud_planner.matching.window_moments`), standing where its RMS is at
    most ``fast_fit_noise_ratio`` times the frame's noise (at least ``fast_fit_floor_m``) and within
    ``max_rms_m``; every other window takes the robust pixel path (:func:`window_blocks`,
    :func:`fit_inverse_depth`: samples beyond max(``outlier_k`` MAD-scaled, ``outlier_floor_m``)
    dropped, up to ``robust_passes`` times, ``chunk`` windows at a time). The normal's 1-sigma is
    widened by the depth noise's correlation measured beside the studs up to
    ``noise_correlation_max_lag_px`` (0: the noise taken as independent;
    :mod:`stud_planner.matching.noise_correlation`); correlated samples being redundant, windows are
    sampled every s-th row and column, s the largest step (up to 4) that widens the 1-sigma by at most
    ``sample_step_max_loss`` (0: every pixel; summed-area tables always sum every pixel). A fit is
    TOO_FEW_POINTS under ``min_points`` (at least the quadric's terms + 2) or a fill under
    ``min_fill_ratio``, BAD_FIT over ``max_rms_m`` or ``max_outlier_ratio``."""

    window_m: float = 0.02
    max_samples_per_side: int = 81
    min_points: int = 12
    min_fill_ratio: float = 0.1
    max_rms_m: float = 0.0015
    max_outlier_ratio: float = 0.2
    outlier_k: float = 3.0
    outlier_floor_m: float = 0.001
    robust_passes: int = 5
    chunk: int = 256
    fast_fit: bool = True
    fast_fit_noise_ratio: float = 1.25
    fast_fit_floor_m: float = 1e-4
    noise_correlation_max_lag_px: int = 16
    sample_step_max_loss: float = 0.05

    def __post_init__(self) -> None:
        if not 0 <= self.noise_correlation_max_lag_px <= 64:
            raise ValueError(f"noise_correlation_max_lag_px={self.noise_correlation_max_lag_px} must be in [0, 64] px")
        if not 0 <= self.sample_step_max_loss <= 1:
            raise ValueError(f"sample_step_max_loss={self.sample_step_max_loss} must be in [0, 1] (a fraction of "
                             "the normal's 1-sigma)")


def estimate_surface_poses(points_w: np.ndarray, pixel_uv: np.ndarray, depth_m: np.ndarray, camera: CameraModel,
                           config: SurfaceFitConfig = SurfaceFitConfig(), *, valid: np.ndarray | None = None,
                           target_xy_w: np.ndarray | None = None,
                           noise: NoiseCorrelation | None = None) -> SurfacePoses:
    """Normals and weld poses at N matched points by a robust least-squares quadric fit of each
    stud's window (the fits and their settings: :class:`SurfaceFitConfig`).

    ``points_w`` (N, 3) matched points in `world` (m); ``pixel_uv`` (N, 2) their pixels; ``depth_m``
    (H, W) metres, NaN = invalid; ``valid`` (N,) the studs to fit (e.g. ``matches.ok``); ``target_xy_w``
    (N, 2): the studs' own world XY (the drawing's), where the weld point and the normal are taken (else
    the match's XY, which the matcher's tolerance allows to be a millimetre off -- a third of a degree of
    normal on a 150 mm dome); ``noise``: the depth noise's correlation of an earlier frame of the same
    camera (:func:`frame_noise_correlation`), else measured on this one beside the studs.

    Every valid sample of a window enters a quadric fit of 1/z over normalised image coordinates
    (exact for planes, the quadratic terms take the curvature). The weld point is where the stud's
    vertical line meets the fitted surface (the fit averages the depth noise out of the height), the
    normal is the surface's there (Eq. 1's camera: ``R_wc`` takes it to `world`); ``normal_sigma_deg``
    is its 1-sigma about the least certain axis, from the fit's covariance, widened by the square root
    of the variance inflation of the frame's correlated depth noise.
    """
    P0 = np.asarray(points_w, dtype=np.float64).reshape(-1, 3)
    uv = np.asarray(pixel_uv, dtype=np.float64).reshape(-1, 2)
    n = P0.shape[0]
    depth = np.asarray(depth_m)
    ok_in = np.all(np.isfinite(P0), axis=1) & np.all(np.isfinite(uv), axis=1)
    if valid is not None:
        ok_in &= np.asarray(valid, dtype=bool)
    target_xy = P0[:, :2] if target_xy_w is None else np.asarray(target_xy_w, dtype=np.float64).reshape(-1, 2)
    out = dict(
        position_w=np.full((n, 3), np.nan), normal_w=np.full((n, 3), np.nan), quat_xyzw=np.full((n, 4), np.nan),
        inclination_deg=np.full(n, np.nan), normal_sigma_deg=np.full(n, np.nan), sigma_inflation=np.full(n, np.nan),
        fit_rms_m=np.full(n, np.nan),
        fill_ratio=np.full(n, np.nan), outlier_ratio=np.full(n, np.nan), n_points=np.zeros(n, dtype=np.int64),
        status=np.full(n, SurfaceStatus.NOT_MATCHED, dtype=np.int8),
    )
    studs = np.flatnonzero(ok_in)
    # The noise's correlation beside the studs: it widens every sigma, and the fast path's gate
    # needs the noise's whole standard deviation (8x8-pixel blocks see only its fast part).
    if noise is None:
        noise = _noise_beside(P0[studs], uv[studs], depth, camera, config.window_m, config.noise_correlation_max_lag_px)
    fitted = _fit_windows(studs, P0, uv, depth, camera, config, noise)
    if fitted is not None:  # one pass for all: its fixed cost is paid once
        idx, fit, z0_w, z_cam, n_in, n_valid, n_window, step = fitted
        inflation = np.sqrt(np.minimum(noise.inflation(step), np.maximum(n_in, 1)))
        _store_poses(out, idx, fit, camera, target_xy[idx], z0_w, z_cam, n_in, n_valid, n_window, inflation, config)
    return SurfacePoses(**out, noise=noise)


def _fit_windows(studs: np.ndarray, P0: np.ndarray, uv: np.ndarray, depth: np.ndarray, camera: CameraModel,
                 config: SurfaceFitConfig, noise: NoiseCorrelation) -> tuple | None:
    """The fits of studs ``studs``' windows, the fast path's where it stands, the robust path's for the
    rest: (idx, fit, z0_w, z_cam, n_in, n_valid, n_window, step) of all, or None for no stud."""
    sample_step = noise.redundant_step(config.sample_step_max_loss)
    robust = studs
    fitted = []
    if config.fast_fit and robust.size:
        batch, robust = _fast_path_fits(robust, P0, uv, depth, camera, config, noise_sigma_m=noise.sigma_m,
                                        step=sample_step)
        fitted.append(batch)
    for start in range(0, robust.size, config.chunk):
        fitted.append(_pixel_path_fits(robust[start:start + config.chunk], P0, uv, depth, camera, config.window_m,
                                       max_per_side=int(config.max_samples_per_side),
                                       robust_passes=config.robust_passes, outlier_k=config.outlier_k,
                                       outlier_floor_m=config.outlier_floor_m, min_step=sample_step))
    fitted = [b for b in fitted if b[0].size]
    if not fitted:
        return None
    return fitted[0] if len(fitted) == 1 else _concatenate(fitted)


def frame_noise_correlation(points_w: np.ndarray, pixel_uv: np.ndarray, depth_m: np.ndarray, camera: CameraModel,
                            config: SurfaceFitConfig = SurfaceFitConfig(), *,
                            valid: np.ndarray | None = None) -> NoiseCorrelation:
    """The depth noise's correlation of this frame, measured as :func:`estimate_surface_poses`
    measures it for studs at ``points_w`` / ``pixel_uv`` (``valid`` as there): to be given to the
    fits of a later frame of the same camera (a camera's noise is the same from frame to frame).
    The measurement costs about as much as matching a hundred studs."""
    P0 = np.asarray(points_w, dtype=np.float64).reshape(-1, 3)
    uv = np.asarray(pixel_uv, dtype=np.float64).reshape(-1, 2)
    ok = np.all(np.isfinite(P0), axis=1) & np.all(np.isfinite(uv), axis=1)
    if valid is not None:
        ok &= np.asarray(valid, dtype=bool)
    return _noise_beside(P0[ok], uv[ok], np.asarray(depth_m), camera, config.window_m,
                         config.noise_correlation_max_lag_px)


def _noise_beside(points_w: np.ndarray, uv: np.ndarray, depth: np.ndarray, camera: CameraModel, window_m: float,
                  max_lag_px: int) -> NoiseCorrelation:
    """The noise's correlation along the windows' edges of studs at ``points_w`` / ``uv`` (all
    usable): the stud's own place may be a painted mark without depth."""
    z_cam = camera.world_to_camera(points_w)[:, 2] if points_w.shape[0] else np.ones(1)
    edge_px = float(np.median(camera.pixels_across(0.5 * window_m, z_cam)))
    return measure_noise_correlation(depth, uv, max_lag_px=max_lag_px, beside_px=edge_px)


def _fast_path_fits(idx: np.ndarray, P0: np.ndarray, uv: np.ndarray, depth: np.ndarray, camera: CameraModel,
                    config: SurfaceFitConfig, *, noise_sigma_m: float = float("nan"), step: int = 1):
    """The plain fits from block moment sums of studs ``idx`` where they stand (see
    :func:`estimate_surface_poses`): ((idx, fit, z0_w, z_cam, n_in, n_valid, n_window, step) of those,
    the studs left for the pixel path); the fits sample every ``step``-th pixel where the sums come
    from the windows' own pixels, every pixel where from summed-area tables.

    The gate is the frame's noise: the larger of the blocks' plane-fit RMS and ``noise_sigma_m``
    (the noise's whole standard deviation, NaN: not measured). Noise correlated over a few pixels
    looks smooth to an 8x8 block, whose plane takes up its slow part, while a 20 mm window's fit
    sees all of it: against the blocks alone, 94-100 % of the windows of a frame with noise
    correlated over 1.5-3 px failed the gate and took the robust path, twice the time."""
    z_cam = camera.world_to_camera(P0[idx])[:, 2]
    y_ref = 1.0 / float(np.median(z_cam))
    moments = BlockMoments(depth, y_ref)
    fit, n_valid, n_window, eligible, step = fast_fits(moments, camera, uv[idx], z_cam, config.window_m, step)
    rms_m = fit.rms_w * z_cam**2
    noise_m = frame_noise_m(moments)
    if np.isfinite(noise_sigma_m):
        noise_m = max(noise_m, noise_sigma_m) if np.isfinite(noise_m) else noise_sigma_m
    gate_floor_m = config.fast_fit_floor_m
    gate_m = max(config.fast_fit_noise_ratio * noise_m, gate_floor_m) if np.isfinite(noise_m) else gate_floor_m
    few = (n_valid < _min_points(config)) | (n_valid < config.min_fill_ratio * np.maximum(n_window, 1))
    # The plain fit stands where the window is as smooth as the frame's noise says it can be;
    # elsewhere (a step, an edge, flying pixels, a rough patch) the robust path decides.
    take = eligible & (few | ((rms_m <= gate_m) & (rms_m <= config.max_rms_m)))
    k = np.flatnonzero(take)
    batch = (idx[k], fit if k.size == take.size else fit.take(k), P0[idx[k], 2], z_cam[k], n_valid[k], n_valid[k],
             n_window[k], np.full(k.size, step, dtype=np.int64))
    return batch, idx[~take]


def _pixel_path_fits(idx: np.ndarray, P0: np.ndarray, uv: np.ndarray, depth: np.ndarray, camera: CameraModel,
                     window_m: float, *, max_per_side: int, robust_passes: int, outlier_k: float,
                     outlier_floor_m: float, min_step: int = 1):
    """The robust fits of the pixels of studs ``idx``' windows, sampled at least every ``min_step``
    pixels: (idx, fit, z0_w, z_cam, n_in, n_valid, n_window, the sample step in pixels)."""
    p_stud = P0[idx]
    z_cam = camera.world_to_camera(p_stud)[:, 2]
    win = window_blocks(camera, depth, uv[idx], z_cam, window_m, max_per_side, min_step)
    scale = 0.5 * window_m / np.maximum(z_cam, 1e-6)
    floor_w = outlier_floor_m / np.maximum(z_cam, 1e-6) ** 2  # 1 mm of depth, in 1/z
    fit = fit_inverse_depth(win, camera, scale, robust_passes, outlier_k, floor_w)
    assert fit.inliers is not None  # a fit of windows keeps its inlier masks
    return (idx, fit.without_inliers(), p_stud[:, 2], z_cam, fit.inliers.sum(axis=(1, 2)), win.good.sum(axis=(1, 2)),
            win.n_window, win.step)


def _concatenate(batches: list[tuple]) -> tuple:
    """One (idx, fit, per-stud arrays...) of several, in order."""
    return (np.concatenate([b[0] for b in batches]), InverseDepthFit.concatenate([b[1] for b in batches]),
            *(np.concatenate([b[i] for b in batches]) for i in range(2, len(batches[0]))))


def _min_points(config: SurfaceFitConfig) -> int:
    """The fewest points a fit may stand on: the config's, and at least the quadric's terms + 2."""
    return max(config.min_points, N_TERMS + 2)


def _store_poses(out: dict, idx: np.ndarray, fit: InverseDepthFit, camera: CameraModel, target_xy: np.ndarray,
                 z0_w: np.ndarray, z_cam: np.ndarray, n_in: np.ndarray, n_valid: np.ndarray, n_window: np.ndarray,
                 inflation: np.ndarray, config: SurfaceFitConfig) -> None:
    """Weld point, normal, its uncertainty (the fit's own times ``inflation``) and the status of studs
    ``idx`` from their fits, into ``out``."""
    if idx.size == 0:
        return
    z_w = _vertical_line_hit(fit, camera, target_xy, z0_w)
    pos = np.column_stack([target_xy, z_w])
    X = camera.world_to_camera(pos)
    nrm_c, sigma_rad = fit.normal_at(X[:, 0] / X[:, 2], X[:, 1] / X[:, 2])
    nrm = nrm_c @ camera.R_wc.T
    sigma = np.degrees(sigma_rad * inflation)
    rms_m = fit.rms_w * z_cam**2  # d(1/z) = dz / z^2

    fill = n_valid / np.maximum(n_window, 1)
    outl = 1.0 - n_in / np.maximum(n_valid, 1)
    status = np.full(idx.size, SurfaceStatus.OK, dtype=np.int8)
    few = (n_in < _min_points(config)) | (fill < config.min_fill_ratio)
    finite = np.all(np.isfinite(pos), axis=1) & np.all(np.isfinite(nrm), axis=1)
    bad = ~few & ((rms_m > config.max_rms_m) | (outl > config.max_outlier_ratio) | ~finite)
    status[bad] = SurfaceStatus.BAD_FIT
    status[few] = SurfaceStatus.TOO_FEW_POINTS
    have = ~few & finite

    j = idx[have]
    out["position_w"][j] = pos[have]
    out["normal_w"][j] = nrm[have]
    out["quat_xyzw"][j] = quaternion_from_normal(nrm[have])
    out["inclination_deg"][j] = inclination_deg(nrm[have])
    out["normal_sigma_deg"][j] = sigma[have]
    out["sigma_inflation"][j] = inflation[have]
    out["fit_rms_m"][j] = rms_m[have]
    out["outlier_ratio"][j] = outl[have]
    out["n_points"][idx] = n_in
    out["fill_ratio"][idx] = fill
    out["status"][idx] = status


def estimate_surface_poses_for_matches(matches, depth_m: np.ndarray, camera: CameraModel,
                                       config: SurfaceFitConfig = SurfaceFitConfig(), *,
                                       target_xy_w: np.ndarray | None = None,
                                       noise: NoiseCorrelation | None = None) -> SurfacePoses:
    """:func:`estimate_surface_poses` on the OK studs of a :class:`stud_planner.matching.matchers.MatchResults`
    (pass ``target_xy_w``, the studs' world XY, to take the poses on their own vertical lines)."""
    return estimate_surface_poses(matches.point_w, matches.pixel_uv, depth_m, camera, config, valid=matches.ok,
                                  target_xy_w=target_xy_w, noise=noise)


__all__ = [
    "M16X150_TOP_OFFSET_M",
    "SurfaceFitConfig",
    "SurfacePoses",
    "SurfaceStatus",
    "estimate_surface_poses",
    "estimate_surface_poses_for_matches",
    "frame_from_normal",
    "frame_noise_correlation",
    "inclination_deg",
    "offset_along_normal",
    "quaternion_from_matrix",
    "quaternion_from_normal",
    "tangent_basis",
]
