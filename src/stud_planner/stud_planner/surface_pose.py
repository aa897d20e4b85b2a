"""Weld pose at matched studs: surface normal from a local plane fit, inclination, tool pose.

The matcher gives the point where a stud's vertical line meets the surface; the welding gun must
approach along the surface normal there. The normal comes from a least-squares plane through the
3D points (Eq. 1 of every valid pixel) of a window around the match. The window is specified in
metres on the surface, not pixels, because the normal's noise falls with the window's extent: at
0.5 mm depth noise a 7x7-11x11 px window gives 2-4 deg, a ~20 mm window well under 1 deg (ANCHORS.md),
the order of the paper's 5 deg acceptance limit. Each fit reports its RMS, fill ratio and an
estimated normal uncertainty so a planner can refuse to weld on a bad estimate.

Frames and units: `world` (z up), metres; normals are unit vectors oriented away from the surface,
toward the camera; quaternions are (x, y, z, w) of a frame whose z-axis is the normal and whose
x-axis is world X projected onto the tangent plane (world Y when the normal is along X).
Vectorised over studs (in chunks, to bound memory).
"""
from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from stud_perception.camera_model import CameraModel
from stud_perception.rotations import matrix_to_quaternion as quaternion_from_matrix

#: Paper: M16x150 shear stud, tool-top offset along the normal.
M16X150_TOP_OFFSET_M = 0.013
#: Paper: maximum inclination of the weld surface to world z the gun can weld.
DEFAULT_INCLINATION_LIMIT_DEG = 5.0


class SurfaceStatus(IntEnum):
    OK = 0
    NOT_MATCHED = 1  # no matched point (NaN input or the caller's mask)
    TOO_FEW_POINTS = 2  # fewer than min_points valid depths or fill ratio below min_fill_ratio
    BAD_FIT = 3  # plane-fit RMS above max_rms_m or too many outliers (a step/edge in the window)


@dataclass(frozen=True)
class SurfacePoses:
    """Per-stud surface pose, N studs.

    - ``position_w`` (N, 3) m: the matched point moved along world z onto the fitted plane (the
      fit averages the depth noise out of the height; XY is the match's);
    - ``normal_w`` (N, 3): unit normal, toward the camera;
    - ``quat_xyzw`` (N, 4): orientation whose z-axis is the normal;
    - ``inclination_deg`` (N,): angle between normal and world z;
    - ``normal_sigma_deg`` (N,): 1-sigma normal uncertainty from the fit's RMS and point spread;
    - ``plane_rms_m`` (N,): RMS distance of the inliers to the plane;
    - ``fill_ratio`` (N,): valid depths / pixels sampled in the window;
    - ``outlier_ratio`` (N,): valid points rejected by the robust pass;
    - ``n_points`` (N,) int: inliers used;
    - ``status`` (N,) int8 :class:`SurfaceStatus`.
    NaN where a value could not be estimated.
    """

    position_w: np.ndarray
    normal_w: np.ndarray
    quat_xyzw: np.ndarray
    inclination_deg: np.ndarray
    normal_sigma_deg: np.ndarray
    plane_rms_m: np.ndarray
    fill_ratio: np.ndarray
    outlier_ratio: np.ndarray
    n_points: np.ndarray
    status: np.ndarray

    def __len__(self) -> int:
        return int(self.status.shape[0])

    @property
    def ok(self) -> np.ndarray:
        return self.status == SurfaceStatus.OK


def inclination_deg(normal_w: np.ndarray) -> np.ndarray:
    """Angle (deg) between unit normals (..., 3) and world +z."""
    n = np.asarray(normal_w, dtype=np.float64)
    return np.degrees(np.arccos(np.clip(n[..., 2], -1.0, 1.0)))


def inclination_within_limit(inclination_deg: np.ndarray, limit_deg: float = DEFAULT_INCLINATION_LIMIT_DEG) -> np.ndarray:
    """True where the surface is flat enough to weld (paper: 5 deg); NaN inclination is not."""
    inc = np.asarray(inclination_deg, dtype=np.float64)
    return np.isfinite(inc) & (inc <= limit_deg)


def offset_along_normal(points_w: np.ndarray, normals_w: np.ndarray, offset_m: float = M16X150_TOP_OFFSET_M) -> np.ndarray:
    """Points (..., 3) moved ``offset_m`` along the unit normals (e.g. the tool top of an M16x150 stud)."""
    return np.asarray(points_w, dtype=np.float64) + offset_m * np.asarray(normals_w, dtype=np.float64)


def frame_from_normal(normal_w: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3), columns (x, y, z): z = normal, x = world X projected onto the
    tangent plane (world Y when the normal is within ~0.06 deg of X), y = z cross x."""
    n = np.asarray(normal_w, dtype=np.float64)
    n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    ex = np.array([1.0, 0.0, 0.0])
    ey = np.array([0.0, 1.0, 0.0])
    x = ex - n[..., 0:1] * n
    norm = np.linalg.norm(x, axis=-1, keepdims=True)
    alt = ey - n[..., 1:2] * n
    x = np.where(norm > 1e-3, x, alt)
    x = x / np.linalg.norm(x, axis=-1, keepdims=True)
    y = np.cross(n, x)
    return np.stack([x, y, n], axis=-1)


def quaternion_from_normal(normal_w: np.ndarray) -> np.ndarray:
    """(x, y, z, w) of :func:`frame_from_normal` -- the pose orientation whose z-axis is the normal."""
    return quaternion_from_matrix(frame_from_normal(normal_w))


_MOMENT_PAIRS = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


def _window_features(camera: CameraModel, u0, v0, du, dv, depth, p_stud) -> np.ndarray:
    """(n, 9, M) per-sample features [x, y, z, xx, xy, xz, yy, yz, zz] of the window points
    relative to the stud, so that every weighted plane fit over the same points is one weighted
    sum (feature-major: each feature row is contiguous; Eq. 1 writes x, y, z in place)."""
    n, M = depth.shape
    F = np.empty((n, 9, M))
    camera.window_to_world(u0, v0, du, dv, depth, minus_w=p_stud, out=F[:, :3].transpose(1, 0, 2))
    for k, (i, j) in enumerate(_MOMENT_PAIRS):
        np.multiply(F[:, i], F[:, j], out=F[:, 3 + k])
    return F


def _fit_planes(F: np.ndarray, w: np.ndarray):
    """Weighted PCA plane per row from moment features F (n, 9, M) and weights w (n, M) in {0, 1}.

    Returns centroid (n, 3), unit normal (n, 3) (smallest-eigenvalue eigenvector), eigenvalues
    (n, 3) ascending (weighted variances, m^2), weight sums (n,). Raw moments are fine here: the
    points are relative to the stud (centimetres), far from cancellation trouble in float64.
    """
    wsum = w.sum(axis=1)
    safe = np.maximum(wsum, 1.0)
    m = np.matmul(F, w[:, :, None])[..., 0] / safe[:, None]
    c = m[:, :3]
    C = np.empty((F.shape[0], 3, 3))
    for k, (i, j) in enumerate(_MOMENT_PAIRS):
        C[:, i, j] = C[:, j, i] = m[:, 3 + k] - c[:, i] * c[:, j]
    evals, evecs = np.linalg.eigh(C)
    return c, evecs[..., 0], evals, wsum, C


def _height_regression_normals(C: np.ndarray) -> np.ndarray:
    """Unit normals of the least-squares height planes z = a + b x + c y, from covariances C (n, 3, 3).

    The seed of the robust fit: unlike PCA, whose smallest-variance axis can swing into the
    plane when a few far outliers add as much variance as the window's extent, a regression of
    z on (x, y) only shifts and tilts (our surfaces are well under 90 deg from horizontal).
    """
    A = C[:, :2, :2]
    det = A[:, 0, 0] * A[:, 1, 1] - A[:, 0, 1] ** 2
    safe = np.where(np.abs(det) > 1e-30, det, np.inf)
    b = (A[:, 1, 1] * C[:, 0, 2] - A[:, 0, 1] * C[:, 1, 2]) / safe
    c = (A[:, 0, 0] * C[:, 1, 2] - A[:, 0, 1] * C[:, 0, 2]) / safe
    n = np.column_stack([-b, -c, np.ones_like(b)])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def estimate_surface_poses(
    points_w: np.ndarray,
    pixel_uv: np.ndarray,
    depth_m: np.ndarray,
    camera: CameraModel,
    *,
    window_m: float = 0.02,
    max_samples_per_side: int = 31,
    min_points: int = 12,
    min_fill_ratio: float = 0.3,
    max_rms_m: float = 0.0015,
    max_outlier_ratio: float = 0.2,
    outlier_k: float = 3.0,
    outlier_floor_m: float = 0.001,
    robust_passes: int = 5,
    valid: np.ndarray | None = None,
    chunk: int = 1024,
) -> SurfacePoses:
    """Normals and weld poses at N matched points by a robust least-squares plane fit.

    Inputs: ``points_w`` (N, 3) matched points in `world` (m); ``pixel_uv`` (N, 2) their pixels;
    ``depth_m`` (H, W) metres, NaN = invalid; ``valid`` (N,) optional mask of studs to process
    (e.g. ``matches.ok``).

    The window is a square of side ``window_m`` on the surface, converted to pixels at the point's
    optical depth (f * window / z), sampled on a grid of at most ``max_samples_per_side`` per side
    (the normal's accuracy comes from the window's extent; more samples add little and cost memory).
    Every valid sample is back-projected with Eq. 1 (:meth:`CameraModel.window_to_world`). Seeded by
    a least-squares height plane, up to ``robust_passes`` times the points farther than
    max(outlier_k * 1.4826 * MAD, outlier_floor_m) from the current plane are dropped (flying
    pixels, a sliver of floor behind a part's edge) and a PCA (total least squares) plane is
    refitted to the rest; with no outliers the result is the PCA plane of all valid points.
    ``normal_sigma_deg`` ~ RMS / sqrt(n * lambda_mid), the LS slope uncertainty on the worse-spread
    in-plane axis. Status: TOO_FEW_POINTS (< min_points or fill < min_fill_ratio), BAD_FIT
    (RMS > max_rms_m or outliers > max_outlier_ratio), else OK.
    """
    P0 = np.asarray(points_w, dtype=np.float64).reshape(-1, 3)
    uv = np.asarray(pixel_uv, dtype=np.float64).reshape(-1, 2)
    n = P0.shape[0]
    depth = np.asarray(depth_m)
    H, W = depth.shape
    ok_in = np.all(np.isfinite(P0), axis=1) & np.all(np.isfinite(uv), axis=1)
    if valid is not None:
        ok_in &= np.asarray(valid, dtype=bool)

    out = dict(
        position_w=np.full((n, 3), np.nan), normal_w=np.full((n, 3), np.nan), quat_xyzw=np.full((n, 4), np.nan),
        inclination_deg=np.full(n, np.nan), normal_sigma_deg=np.full(n, np.nan), plane_rms_m=np.full(n, np.nan),
        fill_ratio=np.full(n, np.nan), outlier_ratio=np.full(n, np.nan), n_points=np.zeros(n, dtype=np.int64),
        status=np.full(n, SurfaceStatus.NOT_MATCHED, dtype=np.int8),
    )
    k = int(max_samples_per_side)
    grid = np.arange(k) - (k - 1) / 2.0  # sample indices, centred
    gj, gi = np.meshgrid(grid, grid, indexing="ij")
    gi, gj = gi.ravel(), gj.ravel()
    cam_pos = camera.position_w

    for start in range(0, n, chunk):
        idx = np.arange(start, min(start + chunk, n))
        idx = idx[ok_in[idx]]
        if idx.size == 0:
            continue
        z_cam = camera.world_to_camera(P0[idx])[:, 2]
        half_px = 0.5 * window_m * camera.fx / np.maximum(z_cam, 1e-6)
        # Integer pixel step so every sample is a real pixel (no interpolation inside the fit).
        step = np.maximum(1, np.ceil(2 * half_px / max(k - 1, 1))).astype(np.int64)
        u0 = np.rint(uv[idx, 0]).astype(np.int64)
        v0 = np.rint(uv[idx, 1]).astype(np.int64)
        # Offsets from a table per distinct step (a handful), not arithmetic on (n, M) arrays.
        steps, which = np.unique(step, return_inverse=True)
        off_u = np.rint(gi[None, :] * steps[:, None]).astype(np.int64)[which]
        off_v = np.rint(gj[None, :] * steps[:, None]).astype(np.int64)[which]
        reach = half_px + 0.5 * step
        in_window = (np.abs(off_u) <= reach[:, None]) & (np.abs(off_v) <= reach[:, None])
        U = u0[:, None] + off_u
        V = v0[:, None] + off_v
        ext = np.rint(np.abs(grid).max() * step)  # the grid's farthest offset, either axis
        edge = (u0 - ext < 0) | (u0 + ext >= W) | (v0 - ext < 0) | (v0 + ext >= H)
        if edge.any():  # samples of windows that cross the image border are not in the window
            in_window[edge] &= (U[edge] >= 0) & (U[edge] < W) & (V[edge] >= 0) & (V[edge] < H)
            U, V = np.clip(U, 0, W - 1), np.clip(V, 0, H - 1)
        d = np.take(depth.reshape(-1), V * W + U).astype(np.float64)
        good = in_window & np.isfinite(d)
        p_stud = P0[idx]
        # Eq. 1 on the window, relative to the stud. Invalid samples get depth 0, a finite point
        # that weight 0 keeps out of every fit and the median.
        F = _window_features(camera, u0, v0, off_u, off_v, np.where(good, d, 0.0), p_stud)

        c, nrm_pca, evals, wsum, C = _fit_planes(F, good.astype(np.float64))
        nrm = _height_regression_normals(C) if robust_passes > 0 else nrm_pca
        refit = np.zeros(idx.size, dtype=bool)
        # Robust passes from a regression seed: drop points farther from the current plane than a
        # multiple of the median absolute distance (robust to a few gross outliers -- flying
        # pixels, a sliver of floor) and refit by PCA, only the rows whose inlier set changed.
        inl = good.copy()
        rows = np.arange(idx.size)
        for _ in range(robust_passes):
            g = good[rows]
            r = np.abs(np.matmul(nrm[rows, None, :], F[rows, :3])[:, 0]
                       - np.einsum("ni,ni->n", c[rows], nrm[rows])[:, None])
            # Median over the valid entries of each row: sort with invalid = +inf, take the middle.
            mid = np.maximum(g.sum(axis=1) - 1, 0) // 2
            kth = np.flatnonzero(np.bincount(mid))  # the distinct median positions, sorted
            # A partition at the (few) distinct median positions gives the same medians as a full
            # sort at a fraction of the cost; rows with many different hole counts fall back to sort.
            r_masked = np.where(g, r, np.inf)
            r_sorted = np.partition(r_masked, kth, axis=1) if kth.size <= 16 else np.sort(r_masked, axis=1)
            mad = np.take_along_axis(r_sorted, mid[:, None], axis=1)[:, 0]
            thr = np.maximum(outlier_k * 1.4826 * np.where(np.isfinite(mad), mad, 0.0), outlier_floor_m)
            new_inl = g & (r <= thr[:, None])
            changed = (new_inl != inl[rows]).any(axis=1)
            rows, new_inl = rows[changed], new_inl[changed]
            if rows.size == 0:
                break
            inl[rows] = new_inl
            c[rows], nrm[rows], evals[rows], wsum[rows], _ = _fit_planes(F[rows], new_inl.astype(np.float64))
            refit[rows] = True
        # Rows whose inliers never changed: all valid points are inliers, so the PCA plane stands.
        nrm = np.where(refit[:, None], nrm, nrm_pca)
        c = c + p_stud

        # Orient toward the camera (away from the surface, as seen).
        flip = np.einsum("ni,ni->n", nrm, cam_pos - c) < 0
        nrm = np.where(flip[:, None], -nrm, nrm)
        rms = np.sqrt(np.maximum(evals[:, 0], 0.0))
        with np.errstate(invalid="ignore", divide="ignore"):
            sigma = np.degrees(rms / np.sqrt(np.maximum(wsum, 1.0) * np.maximum(evals[:, 1], 1e-18)))
        n_valid = good.sum(axis=1)
        n_window = in_window.sum(axis=1)
        fill = n_valid / np.maximum(n_window, 1)
        outl = 1.0 - wsum / np.maximum(n_valid, 1)

        status = np.full(idx.size, SurfaceStatus.OK, dtype=np.int8)
        few = (wsum < max(min_points, 3)) | (fill < min_fill_ratio)
        bad = ~few & ((rms > max_rms_m) | (outl > max_outlier_ratio))
        status[bad] = SurfaceStatus.BAD_FIT
        status[few] = SurfaceStatus.TOO_FEW_POINTS
        have = ~few

        with np.errstate(invalid="ignore", divide="ignore"):
            # Height of the plane at the match's XY: n . (p - c) = 0 solved for z.
            p = p_stud
            z_plane = c[:, 2] - (nrm[:, 0] * (p[:, 0] - c[:, 0]) + nrm[:, 1] * (p[:, 1] - c[:, 1])) / nrm[:, 2]
        pos = np.column_stack([p[:, :2], np.where(np.abs(nrm[:, 2]) > 1e-6, z_plane, p[:, 2])])

        j = idx[have]
        out["position_w"][j] = pos[have]
        out["normal_w"][j] = nrm[have]
        out["quat_xyzw"][j] = quaternion_from_normal(nrm[have])
        out["inclination_deg"][j] = inclination_deg(nrm[have])
        out["normal_sigma_deg"][j] = sigma[have]
        out["plane_rms_m"][j] = rms[have]
        out["outlier_ratio"][j] = outl[have]
        out["n_points"][idx] = wsum.astype(np.int64)
        out["fill_ratio"][idx] = fill
        out["status"][idx] = status
    return SurfacePoses(**out)


def estimate_surface_poses_for_matches(matches, depth_m: np.ndarray, camera: CameraModel, **kwargs) -> SurfacePoses:
    """:func:`estimate_surface_poses` on the OK studs of a :class:`stud_planner.matching.MatchResults`."""
    return estimate_surface_poses(matches.point_w, matches.pixel_uv, depth_m, camera, valid=matches.ok, **kwargs)


__all__ = [
    "DEFAULT_INCLINATION_LIMIT_DEG",
    "M16X150_TOP_OFFSET_M",
    "SurfacePoses",
    "SurfaceStatus",
    "estimate_surface_poses",
    "estimate_surface_poses_for_matches",
    "frame_from_normal",
    "inclination_deg",
    "inclination_within_limit",
    "offset_along_normal",
    "quaternion_from_matrix",
    "quaternion_from_normal",
]
