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
fit is rougher than the frame's noise. Vectorised over studs (the pixel path in chunks, to bound
memory).
"""
from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from stud_perception.camera_model import CameraModel
from stud_common.rotations import frame_from_normal
from stud_common.rotations import matrix_to_quaternion as quaternion_from_matrix
from stud_planner.matching.window_moments import BLOCK_PX, BlockMoments, powers_of

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
      certain axis, from the fit's covariance;
    - ``fit_rms_m`` (N,): RMS distance of the inliers to the fitted surface;
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
    fit_rms_m: np.ndarray
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


def offset_along_normal(points_w: np.ndarray, normals_w: np.ndarray, offset_m: float = M16X150_TOP_OFFSET_M) -> np.ndarray:
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


#: Quadric terms of the fit in the window's normalised image coordinates: 1, a, b, a^2, ab, b^2.
_N_TERMS = 6


@dataclass(frozen=True)
class _InverseDepthFit:
    """Robust quadric fits w(a, b) = 1/z of n windows (all arrays (n, ...)).

    (a, b) are normalised image coordinates (x~ = (u - cx)/fx, y~ = (v - cy)/fy) relative to the
    window's centre (``x0``, ``y0``), divided by ``scale`` so the normal matrix is well
    conditioned. ``beta`` (n, 6), ``cov`` (n, 6, 6) its covariance, ``inliers`` (n, k, k) bool,
    ``rms_w`` (n,) the residual RMS in 1/m.
    """

    x0: np.ndarray
    y0: np.ndarray
    scale: np.ndarray
    beta: np.ndarray
    cov: np.ndarray
    inliers: np.ndarray | None
    rms_w: np.ndarray

    def take(self, k: np.ndarray) -> "_InverseDepthFit":
        """The fits of windows ``k``."""
        return _InverseDepthFit(x0=self.x0[k], y0=self.y0[k], scale=self.scale[k], beta=self.beta[k],
                                cov=self.cov[k], inliers=None if self.inliers is None else self.inliers[k],
                                rms_w=self.rms_w[k])

    def gradient_map(self, xt: np.ndarray, yt: np.ndarray) -> np.ndarray:
        """(n, 3, 6) linear map beta -> g = (w_x, w_y, w - w_x x~ - w_y y~) at normalised image
        coordinates (xt, yt): the (unnormalised) surface normal in the optical frame there.

        The surface is F(X) = Z w(X/Z, Y/Z) - 1 = 0, whose gradient is that g; for a plane
        n . X = d, w = (n_x x~ + n_y y~ + n_z) / d is linear and g = n / d exactly.
        """
        s = self.scale
        a, b = (xt - self.x0) / s, (yt - self.y0) / s
        one, zero = np.ones_like(a), np.zeros_like(a)
        w = np.stack([one, a, b, a * a, a * b, b * b], axis=-1)
        w_x = np.stack([zero, one, zero, 2 * a, b, zero], axis=-1) / s[:, None]
        w_y = np.stack([zero, zero, one, zero, a, 2 * b], axis=-1) / s[:, None]
        return np.stack([w_x, w_y, w - w_x * xt[:, None] - w_y * yt[:, None]], axis=1)

    def gradient(self, xt: np.ndarray, yt: np.ndarray) -> np.ndarray:
        """(n, 3) g = :meth:`gradient_map` @ beta, evaluated directly."""
        s, B = self.scale, self.beta
        a, b = (xt - self.x0) / s, (yt - self.y0) / s
        w = B[:, 0] + B[:, 1] * a + B[:, 2] * b + B[:, 3] * a * a + B[:, 4] * a * b + B[:, 5] * b * b
        w_x = (B[:, 1] + 2 * B[:, 3] * a + B[:, 4] * b) / s
        w_y = (B[:, 2] + B[:, 4] * a + 2 * B[:, 5] * b) / s
        return np.column_stack([w_x, w_y, w - w_x * xt - w_y * yt])

    def residual_f(self, xt: np.ndarray, yt: np.ndarray, z: np.ndarray) -> np.ndarray:
        """F = z w(x~, y~) - 1 at optical-frame points given as (x~, y~, z)."""
        s = self.scale
        a, b = (xt - self.x0) / s, (yt - self.y0) / s
        B = self.beta
        w = B[:, 0] + B[:, 1] * a + B[:, 2] * b + B[:, 3] * a * a + B[:, 4] * a * b + B[:, 5] * b * b
        return z * w - 1.0

    def normal_at(self, xt: np.ndarray, yt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Unit normals (n, 3) in the optical frame, toward the camera, at (x~, y~), and the
        1-sigma (rad) of their direction about the least certain axis."""
        L = self.gradient_map(xt, yt)
        g = self.gradient(xt, yt)
        norm = np.linalg.norm(g, axis=1, keepdims=True)
        n = g / norm
        n = np.where((n[:, 2:3] > 0), -n, n)  # the camera looks along +z: toward it is -z
        cov_g = np.matmul(np.matmul(L, self.cov), np.swapaxes(L, 1, 2)) / (norm * norm)[:, :, None]
        return n, np.sqrt(_largest_tangent_variance(cov_g, n))


def _largest_tangent_variance(C: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Largest eigenvalue (n,) of (I - n n^T) C (I - n n^T): the variance of a unit normal ``n``
    (k, 3) about its least certain axis, from the covariance ``C`` (k, 3, 3) of the unnormalised
    gradient divided by its squared length. Closed form: the two tangent eigenvalues have the sum
    tr C - n^T C n and the product n^T adj(C) n (the 2x2 minor of C in any tangent basis)."""
    c00, c11, c22 = C[:, 0, 0], C[:, 1, 1], C[:, 2, 2]
    c01, c02, c12 = C[:, 0, 1], C[:, 0, 2], C[:, 1, 2]
    n0, n1, n2 = n[:, 0], n[:, 1], n[:, 2]
    nCn = c00 * n0 * n0 + c11 * n1 * n1 + c22 * n2 * n2 + 2 * (c01 * n0 * n1 + c02 * n0 * n2 + c12 * n1 * n2)
    nAn = ((c11 * c22 - c12 * c12) * n0 * n0 + (c00 * c22 - c02 * c02) * n1 * n1 + (c00 * c11 - c01 * c01) * n2 * n2
           + 2 * ((c02 * c12 - c01 * c22) * n0 * n1 + (c01 * c12 - c02 * c11) * n0 * n2
                  + (c01 * c02 - c00 * c12) * n1 * n2))
    half = 0.5 * (c00 + c11 + c22 - nCn)
    return np.maximum(half + np.sqrt(np.maximum(half * half - nAn, 0.0)), 0.0)


#: The fit's terms as powers (p, q) of the window coordinates (a, b): 1, a, b, a^2, ab, b^2.
_TERMS = ((0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2))
_TP = np.array([t[0] for t in _TERMS])
_TQ = np.array([t[1] for t in _TERMS])


@dataclass(frozen=True)
class _Windows:
    """The windows of n studs as k x k blocks of pixels (rows v, columns u), all (n, ...).

    A window is a square of ``window_m`` at the stud's optical depth (f * window / z) sampled
    with an integer pixel ``step`` (every sample a real pixel); sample (i, j) is pixel
    (u0 + g_j step, v0 + g_i step) with g = -(k-1)/2 .. (k-1)/2. ``good`` (n, k, k): inside the
    window and the image, with depth; ``inv_z`` (n, k, k) 1/depth there (0 elsewhere);
    ``n_window`` (n,) samples inside the window and the image.
    """

    u0: np.ndarray
    v0: np.ndarray
    step: np.ndarray
    grid: np.ndarray
    good: np.ndarray
    inv_z: np.ndarray
    n_window: np.ndarray


def _window_blocks(camera: CameraModel, depth: np.ndarray, uv: np.ndarray, z_cam: np.ndarray, window_m: float,
                   max_per_side: int) -> _Windows:
    H, W = depth.shape
    half_px = 0.5 * window_m * camera.fx / np.maximum(z_cam, 1e-6)
    step = np.maximum(1, np.ceil(2 * half_px / max(max_per_side - 1, 1))).astype(np.int64)
    reach = half_px + 0.5 * step
    half_k = int(np.max(np.floor(reach / step)))
    grid = np.arange(-half_k, half_k + 1)
    u0 = np.rint(uv[:, 0]).astype(np.int64)
    v0 = np.rint(uv[:, 1]).astype(np.int64)
    off = grid[None, :] * step[:, None]
    U, V = u0[:, None] + off, v0[:, None] + off
    inside = np.abs(off) <= reach[:, None]  # the window is separable: rows x columns
    col_ok = inside & (U >= 0) & (U < W)
    row_ok = inside & (V >= 0) & (V < H)
    d = depth[np.clip(V, 0, H - 1)[:, :, None], np.clip(U, 0, W - 1)[:, None, :]]
    good = row_ok[:, :, None] & col_ok[:, None, :] & (d > 0)  # NaN compares False
    inv_z = np.zeros(d.shape)
    np.divide(1.0, d, out=inv_z, where=good)
    return _Windows(u0=u0, v0=v0, step=step, grid=grid.astype(np.float64), good=good, inv_z=inv_z,
                    n_window=row_ok.sum(axis=1) * col_ok.sum(axis=1))


def _moments(weights: np.ndarray, values: np.ndarray | None, grid: np.ndarray, order: int) -> np.ndarray:
    """sum_ij weights_ij values_ij g_j^p g_i^q for p, q <= order: (n, order + 1, order + 1) [p, q].

    Separable: a matrix product over the columns, then one over the rows."""
    G = grid[:, None] ** np.arange(order + 1)[None, :]  # (k, order + 1)
    data = weights if values is None else weights * values
    return np.einsum("nip,iq->npq", np.matmul(data, G), G)


def _solve_normal_equations(Mw: np.ndarray, My: np.ndarray, ca: np.ndarray, cb: np.ndarray):
    """beta (n, 6) and A^-1 (n, 6, 6) of the quadric fit from the grid moments, with a = ca g_u,
    b = cb g_v: A_ij = ca^(p_i+p_j) cb^(q_i+q_j) Mw[p_i+p_j, q_i+q_j], rhs_i = ca^p_i cb^q_i My[p_i, q_i]."""
    P, Q = _TP[:, None] + _TP[None, :], _TQ[:, None] + _TQ[None, :]
    pa, pb = powers_of(ca, 4), powers_of(cb, 4)
    Mw = Mw * pa[:, :, None] * pb[:, None, :]
    A = Mw[:, P, Q]
    rhs = My[:, _TP, _TQ] * pa[:, _TP] * pb[:, _TQ]
    # A tiny ridge keeps windows with too few or collinear points solvable; their covariance is
    # then huge, which is what the uncertainty should say.
    A += 1e-9 * np.eye(len(_TERMS))
    A_inv = _inverse_spd(A)
    return np.einsum("nij,nj->ni", A_inv, rhs), A_inv, rhs


def _inverse_spd(A: np.ndarray) -> np.ndarray:
    """Inverses (n, m, m) of symmetric positive (semi-)definite matrices (n, m, m), by a Cholesky
    factorisation written out over the batch: np.linalg.inv pays a per-matrix overhead that
    dominates at 6x6. A pivot that rounding leaves at or below zero is clamped to a tiny positive
    value, so a degenerate window gets a huge (honest) covariance instead of NaN."""
    m = A.shape[-1]
    a = np.ascontiguousarray(np.moveaxis(A, 0, -1))  # (m, m, n): each entry a contiguous vector
    L: list[list] = [[None] * m for _ in range(m)]
    tiny = 1e-300
    for j in range(m):
        L[j][j] = np.sqrt(np.maximum(a[j][j] - sum(L[j][k] * L[j][k] for k in range(j)), tiny))
        inv = 1.0 / L[j][j]
        for i in range(j + 1, m):
            L[i][j] = (a[i][j] - sum(L[i][k] * L[j][k] for k in range(j))) * inv
    Li: list[list] = [[None] * m for _ in range(m)]  # L^-1, lower triangular
    for i in range(m):
        Li[i][i] = 1.0 / L[i][i]
        for j in range(i):
            Li[i][j] = -sum(L[i][k] * Li[k][j] for k in range(j, i)) * Li[i][i]
    out = np.empty(a.shape)
    for j in range(m):  # A^-1 = L^-T L^-1
        for k in range(j, m):
            out[j, k] = out[k, j] = sum(Li[i][j] * Li[i][k] for i in range(k, m))
    return np.moveaxis(out, -1, 0)


def _evaluate(beta: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The quadric (n, k, k) on the grid: a (n, k) per column, b (n, k) per row."""
    A, B = a[:, None, :], b[:, :, None]
    return (beta[:, 0, None, None] + beta[:, 1, None, None] * A + beta[:, 2, None, None] * B
            + beta[:, 3, None, None] * A * A + beta[:, 4, None, None] * A * B + beta[:, 5, None, None] * B * B)


def _fit_inverse_depth(win: _Windows, camera: CameraModel, scale: np.ndarray, robust_passes: int, outlier_k: float,
                       floor_w: np.ndarray, trigger_k: float = 4.5) -> _InverseDepthFit:
    """Robust quadric fits of 1/z over the windows' normalised image coordinates.

    The depth noise of an RGB-D camera lies along its rays, that is in z alone at a fixed pixel:
    fitting 1/z as a function of the pixel keeps every error in the dependent variable. (A fit
    to the 3D points instead has errors in all three coordinates, correlated along the ray,
    which tilts the normal of a sloped surface by sigma^2 sin(2 theta) / (2 s^2): 0.35 deg at
    0.8 mm noise on a 20 deg slope with a 20 mm window.)

    The least-squares fit of every window comes from moment sums (:func:`_moments`, a few
    operations per sample). Windows whose worst residual is beyond ``trigger_k`` times the RMS
    (flying pixels, a sliver of floor behind a part's edge -- a clean window of a few thousand
    Gaussian samples rarely is) get robust passes: up to ``robust_passes`` times, samples farther
    from the fit than max(outlier_k * 1.4826 * MAD, floor_w) are dropped and the fit redone.
    """
    ca = win.step / (camera.fx * scale)  # a = ca * g_u: window units per grid step
    cb = win.step / (camera.fy * scale)
    a, b = ca[:, None] * win.grid[None, :], cb[:, None] * win.grid[None, :]
    good = win.good
    w = good.astype(np.float64)
    Mw = _moments(w, None, win.grid, 4)
    My = _moments(w, win.inv_z, win.grid, 2)
    yy = np.einsum("nij,nij->n", win.inv_z, win.inv_z)
    beta, A_inv, rhs = _solve_normal_equations(Mw, My, ca, cb)
    n_in = good.sum(axis=(1, 2))
    var = np.maximum(yy - np.einsum("ni,ni->n", beta, rhs), 0.0) / np.maximum(n_in - len(_TERMS), 1)
    inl = good
    resid = np.abs(win.inv_z - _evaluate(beta, a, b))
    worst = np.max(np.where(good, resid, 0.0), axis=(1, 2))
    rows = np.flatnonzero(worst > np.maximum(trigger_k * np.sqrt(var), floor_w))
    if rows.size and robust_passes > 0:
        inl = good.copy()
        for _ in range(robust_passes):
            r = resid[rows].reshape(rows.size, -1)
            g = good[rows].reshape(rows.size, -1)
            # Median over the valid entries of each row: sort with invalid = +inf, take the middle.
            mid = np.maximum(g.sum(axis=1) - 1, 0) // 2
            r_sorted = np.sort(np.where(g, r, np.inf), axis=1)
            mad = np.take_along_axis(r_sorted, mid[:, None], axis=1)[:, 0]
            thr = np.maximum(outlier_k * 1.4826 * np.where(np.isfinite(mad), mad, 0.0), floor_w[rows])
            new_inl = (g & (r <= thr[:, None])).reshape(good[rows].shape)
            changed = (new_inl != inl[rows]).any(axis=(1, 2))
            rows, new_inl = rows[changed], new_inl[changed]
            if rows.size == 0:
                break
            inl[rows] = new_inl
            wr = new_inl.astype(np.float64)
            Mw_r, My_r = _moments(wr, None, win.grid, 4), _moments(wr, win.inv_z[rows], win.grid, 2)
            beta[rows], A_inv[rows], rhs_r = _solve_normal_equations(Mw_r, My_r, ca[rows], cb[rows])
            yy_r = np.einsum("nij,nij,nij->n", wr, win.inv_z[rows], win.inv_z[rows])
            n_r = new_inl.sum(axis=(1, 2))
            var[rows] = (np.maximum(yy_r - np.einsum("ni,ni->n", beta[rows], rhs_r), 0.0)
                         / np.maximum(n_r - len(_TERMS), 1))
            resid[rows] = np.abs(win.inv_z[rows] - _evaluate(beta[rows], a[rows], b[rows]))
    x0 = (win.u0 - camera.cx) / camera.fx
    y0 = (win.v0 - camera.cy) / camera.fy
    return _InverseDepthFit(x0=x0, y0=y0, scale=scale, beta=beta, cov=var[:, None, None] * A_inv, inliers=inl,
                            rms_w=np.sqrt(var))


def _vertical_line_hit(fit: _InverseDepthFit, camera: CameraModel, xy_w: np.ndarray, z0_w: np.ndarray,
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


def estimate_surface_poses(
    points_w: np.ndarray,
    pixel_uv: np.ndarray,
    depth_m: np.ndarray,
    camera: CameraModel,
    *,
    window_m: float = 0.02,
    max_samples_per_side: int = 81,
    min_points: int = 12,
    min_fill_ratio: float = 0.1,
    max_rms_m: float = 0.0015,
    max_outlier_ratio: float = 0.2,
    outlier_k: float = 3.0,
    outlier_floor_m: float = 0.001,
    robust_passes: int = 5,
    valid: np.ndarray | None = None,
    target_xy_w: np.ndarray | None = None,
    chunk: int = 256,
    fast_fit: bool = True,
    fast_fit_noise_ratio: float = 1.25,
    fast_fit_floor_m: float = 1e-4,
) -> SurfacePoses:
    """Normals and weld poses at N matched points by a robust least-squares fit of the window.

    Inputs: ``points_w`` (N, 3) matched points in `world` (m); ``pixel_uv`` (N, 2) their pixels;
    ``depth_m`` (H, W) metres, NaN = invalid; ``valid`` (N,) optional mask of studs to process
    (e.g. ``matches.ok``); ``target_xy_w`` (N, 2) optional: the studs' own world XY (the drawing's),
    where the weld point and the normal are taken (else at the match's XY, which the matcher's
    tolerance allows to be a millimetre off -- a third of a degree of normal on a 150 mm dome).

    Every valid sample of the window enters a quadric fit of 1/z over normalised image
    coordinates (exact for planes, the quadratic terms take the curvature). With ``fast_fit``
    (default) the plain least-squares fit of a window of whole 8x8-pixel blocks comes from moment
    sums (:mod:`stud_planner.matching.window_moments`: summed-area tables for many studs, the window's own
    pixels for few), and it stands where its RMS is at most ``fast_fit_noise_ratio`` times the
    frame's noise (the median RMS of plane fits to sample blocks; at least ``fast_fit_floor_m``)
    and within ``max_rms_m``. Every other window -- a step, an edge, flying pixels, a window under
    two blocks a side -- and every window with ``fast_fit=False`` takes the robust pixel path
    (:func:`_window_blocks`, :func:`_fit_inverse_depth`: outliers beyond a MAD-scaled threshold
    dropped, up to ``robust_passes`` times). The weld point is where the stud's vertical line meets
    the fitted surface (the fit averages the depth noise out of the height), the normal is the
    surface's there (Eq. 1's camera: ``R_wc`` takes it to `world`). ``normal_sigma_deg`` is the
    1-sigma uncertainty of the normal's direction about its least certain axis, from the fit's
    covariance. Status: TOO_FEW_POINTS (< min_points or fill < min_fill_ratio), BAD_FIT (RMS >
    max_rms_m or outliers > max_outlier_ratio), else OK.
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
        inclination_deg=np.full(n, np.nan), normal_sigma_deg=np.full(n, np.nan), fit_rms_m=np.full(n, np.nan),
        fill_ratio=np.full(n, np.nan), outlier_ratio=np.full(n, np.nan), n_points=np.zeros(n, dtype=np.int64),
        status=np.full(n, SurfaceStatus.NOT_MATCHED, dtype=np.int8),
    )

    limits = _Limits(min_points=max(min_points, _N_TERMS + 2), min_fill_ratio=min_fill_ratio, max_rms_m=max_rms_m,
                     max_outlier_ratio=max_outlier_ratio)
    robust = np.flatnonzero(ok_in)
    if fast_fit and robust.size:
        z_cam = camera.world_to_camera(P0[robust])[:, 2]
        y_ref = 1.0 / float(np.median(z_cam))
        moments = BlockMoments(depth, y_ref)
        fit, n_valid, n_window, eligible = _fast_fits(moments, camera, uv[robust], z_cam, window_m)
        rms_m = fit.rms_w * z_cam**2
        noise_m = _frame_noise_m(moments)
        gate_m = max(fast_fit_noise_ratio * noise_m, fast_fit_floor_m) if np.isfinite(noise_m) else fast_fit_floor_m
        few = (n_valid < limits.min_points) | (n_valid < min_fill_ratio * np.maximum(n_window, 1))
        # The plain fit stands where the window is as smooth as the frame's noise says it can be;
        # elsewhere (a step, an edge, flying pixels, a rough patch) the robust path decides.
        take = eligible & (few | ((rms_m <= gate_m) & (rms_m <= max_rms_m)))
        k = np.flatnonzero(take)
        _store_poses(out, robust[k], fit if k.size == take.size else fit.take(k), camera, target_xy[robust[k]],
                     P0[robust[k], 2], z_cam[k], n_valid[k], n_valid[k], n_window[k], limits)
        robust = robust[~take]
    for start in range(0, robust.size, chunk):
        idx = robust[start:start + chunk]
        p_stud = P0[idx]
        z_cam = camera.world_to_camera(p_stud)[:, 2]
        win = _window_blocks(camera, depth, uv[idx], z_cam, window_m, int(max_samples_per_side))
        scale = 0.5 * window_m / np.maximum(z_cam, 1e-6)
        floor_w = outlier_floor_m / np.maximum(z_cam, 1e-6) ** 2  # 1 mm of depth, in 1/z
        fit = _fit_inverse_depth(win, camera, scale, robust_passes, outlier_k, floor_w)
        _store_poses(out, idx, fit, camera, target_xy[idx], p_stud[:, 2], z_cam, fit.inliers.sum(axis=(1, 2)),
                     win.good.sum(axis=(1, 2)), win.n_window, limits)
    return SurfacePoses(**out)


@dataclass(frozen=True)
class _Limits:
    """What a fit must meet to be OK (see :func:`estimate_surface_poses`)."""

    min_points: int
    min_fill_ratio: float
    max_rms_m: float
    max_outlier_ratio: float


def _store_poses(out: dict, idx: np.ndarray, fit: _InverseDepthFit, camera: CameraModel, target_xy: np.ndarray,
                 z0_w: np.ndarray, z_cam: np.ndarray, n_in: np.ndarray, n_valid: np.ndarray, n_window: np.ndarray,
                 limits: _Limits) -> None:
    """Weld point, normal, its uncertainty and the status of studs ``idx`` from their fits, into ``out``."""
    if idx.size == 0:
        return
    z_w = _vertical_line_hit(fit, camera, target_xy, z0_w)
    pos = np.column_stack([target_xy, z_w])
    X = camera.world_to_camera(pos)
    nrm_c, sigma_rad = fit.normal_at(X[:, 0] / X[:, 2], X[:, 1] / X[:, 2])
    nrm = nrm_c @ camera.R_wc.T
    sigma = np.degrees(sigma_rad)
    rms_m = fit.rms_w * z_cam**2  # d(1/z) = dz / z^2

    fill = n_valid / np.maximum(n_window, 1)
    outl = 1.0 - n_in / np.maximum(n_valid, 1)
    status = np.full(idx.size, SurfaceStatus.OK, dtype=np.int8)
    few = (n_in < limits.min_points) | (fill < limits.min_fill_ratio)
    finite = np.all(np.isfinite(pos), axis=1) & np.all(np.isfinite(nrm), axis=1)
    bad = ~few & ((rms_m > limits.max_rms_m) | (outl > limits.max_outlier_ratio) | ~finite)
    status[bad] = SurfaceStatus.BAD_FIT
    status[few] = SurfaceStatus.TOO_FEW_POINTS
    have = ~few & finite

    j = idx[have]
    out["position_w"][j] = pos[have]
    out["normal_w"][j] = nrm[have]
    out["quat_xyzw"][j] = quaternion_from_normal(nrm[have])
    out["inclination_deg"][j] = inclination_deg(nrm[have])
    out["normal_sigma_deg"][j] = sigma[have]
    out["fit_rms_m"][j] = rms_m[have]
    out["outlier_ratio"][j] = outl[have]
    out["n_points"][idx] = n_in
    out["fill_ratio"][idx] = fill
    out["status"][idx] = status


def _fast_fits(moments: BlockMoments, camera: CameraModel, uv: np.ndarray, z_cam: np.ndarray, window_m: float):
    """Plain least-squares quadric fits of 1/z over block-aligned windows, from moment sums
    (:mod:`stud_planner.matching.window_moments`): the fit :func:`_fit_inverse_depth` makes before any
    robust pass, on every valid pixel of a window of whole blocks around each stud.

    Returns (fit, n_valid (n,), n_window (n,), eligible (n,) bool); a window under two blocks a
    side, or one the image border cuts to nothing, is not eligible (the pixel path takes it).
    """
    b = BLOCK_PX
    half = 0.5 * window_m * camera.fx / np.maximum(z_cam, 1e-6)
    c0, c1 = np.rint((uv[:, 0] - half) / b), np.rint((uv[:, 0] + half + 1.0) / b)
    r0, r1 = np.rint((uv[:, 1] - half) / b), np.rint((uv[:, 1] + half + 1.0) / b)
    eligible = (c1 - c0 >= 2) & (r1 - r0 >= 2)
    c0, c1 = np.clip(c0, 0, moments.n_cols), np.clip(c1, 0, moments.n_cols)
    r0, r1 = np.clip(r0, 0, moments.n_rows), np.clip(r1, 0, moments.n_rows)
    eligible &= (c1 > c0) & (r1 > r0)
    c0, c1, r0, r1 = (np.where(eligible, a, 0).astype(np.int64) for a in (c0, c1, r0, r1))
    c1, r1 = np.maximum(c1, c0 + 1), np.maximum(r1, r0 + 1)
    sums = moments.window_sums(r0, r1, c0, c1)
    scale = 0.5 * window_m / np.maximum(z_cam, 1e-6)
    ca, cb = 1.0 / (camera.fx * scale), 1.0 / (camera.fy * scale)  # window units per pixel
    beta, A_inv, rhs = _solve_normal_equations(sums.mw, sums.my, ca, cb)
    n_valid = np.rint(sums.mw[:, 0, 0]).astype(np.int64)
    var = np.maximum(sums.yy - np.einsum("ni,ni->n", beta, rhs), 0.0) / np.maximum(n_valid - len(_TERMS), 1)
    beta[:, 0] += moments.y_ref  # the sums are of 1/z - y_ref
    fit = _InverseDepthFit(x0=(sums.centre_uv[:, 0] - camera.cx) / camera.fx,
                           y0=(sums.centre_uv[:, 1] - camera.cy) / camera.fy, scale=scale, beta=beta,
                           cov=var[:, None, None] * A_inv, inliers=None, rms_w=np.sqrt(var))
    return fit, n_valid, sums.n_window, eligible


def _frame_noise_m(moments: BlockMoments, stride: int = 4) -> float:
    """The frame's depth noise (m, 1-sigma): the median RMS of plane fits of 1/z to every
    ``stride``-th block in both directions that has depth in every pixel (curvature is nil over
    a block; a block on an edge is an outlier the median ignores). With all pixels present the
    design is the same for every block, so the residuals are one product with the projector off
    the plane's span. NaN if no such block."""
    b = BLOCK_PX
    depth = moments.depth_blocks[::stride, :, ::stride, :]  # a view: (rows, b, cols, b)
    z = np.ascontiguousarray(depth.transpose(0, 2, 1, 3)).reshape(-1, b * b).astype(np.float64)
    z = z[np.all(z > 0, axis=1)]  # NaN compares False
    if z.shape[0] < _MIN_NOISE_BLOCKS:  # speckled depth: few whole blocks, take three-quarter-full ones
        return _frame_noise_from_sums(moments, stride)
    g = np.arange(b) - (b - 1) / 2.0
    X = np.column_stack([np.ones(b * b), np.tile(g, b), np.repeat(g, b)])  # 1, u, v of the pixels
    off_plane = np.eye(b * b) - X @ np.linalg.solve(X.T @ X, X.T)
    y = 1.0 / z
    r = y @ off_plane
    var_w = np.einsum("kj,kj->k", r, r) / (b * b - 3)
    z_mean = 1.0 / y.mean(axis=1)
    return float(np.median(np.sqrt(var_w) * z_mean * z_mean))


#: Whole blocks the noise estimate wants before it settles for partly holed ones.
_MIN_NOISE_BLOCKS = 30


def _frame_noise_from_sums(moments: BlockMoments, stride: int) -> float:
    """:func:`_frame_noise_m` over the blocks that are three-quarters full, from their sums."""
    r, c = (a.ravel() for a in np.meshgrid(np.arange(0, moments.n_rows, stride),
                                           np.arange(0, moments.n_cols, stride), indexing="ij"))
    s = moments.window_sums(r, r + 1, c, c + 1, use_table=False)
    n = s.mw[:, 0, 0]
    use = n >= 0.75 * BLOCK_PX**2
    if not use.any():
        return float("nan")
    mw, my, yy, n = s.mw[use], s.my[use], s.yy[use], n[use]
    A = np.stack([np.stack([mw[:, 0, 0], mw[:, 1, 0], mw[:, 0, 1]], -1),
                  np.stack([mw[:, 1, 0], mw[:, 2, 0], mw[:, 1, 1]], -1),
                  np.stack([mw[:, 0, 1], mw[:, 1, 1], mw[:, 0, 2]], -1)], 1)
    rhs = np.stack([my[:, 0, 0], my[:, 1, 0], my[:, 0, 1]], -1)
    beta = np.linalg.solve(A, rhs[:, :, None])[:, :, 0]
    var_w = np.maximum(yy - np.einsum("ni,ni->n", beta, rhs), 0.0) / (n - 3)
    z = 1.0 / (moments.y_ref + my[:, 0, 0] / n)
    return float(np.median(np.sqrt(var_w) * z * z))


def estimate_surface_poses_for_matches(matches, depth_m: np.ndarray, camera: CameraModel, **kwargs) -> SurfacePoses:
    """:func:`estimate_surface_poses` on the OK studs of a :class:`stud_planner.matching.matchers.MatchResults`
    (pass ``target_xy_w``, the studs' world XY, to take the poses on their own vertical lines)."""
    return estimate_surface_poses(matches.point_w, matches.pixel_uv, depth_m, camera, valid=matches.ok, **kwargs)


__all__ = [
    "M16X150_TOP_OFFSET_M",
    "SurfacePoses",
    "SurfaceStatus",
    "estimate_surface_poses",
    "estimate_surface_poses_for_matches",
    "frame_from_normal",
    "inclination_deg",
    "offset_along_normal",
    "quaternion_from_matrix",
    "quaternion_from_normal",
    "tangent_basis",
]
