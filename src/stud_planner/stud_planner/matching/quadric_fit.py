"""Quadric fits of inverse depth over the studs' windows, and the frame's depth noise.

:func:`stud_planner.matching.surface_pose.estimate_surface_poses` fits, in each stud's window,
w(a, b) = 1/z as a quadric over normalised image coordinates. Two ways to the same least-squares
fit: from the window's pixels (:func:`window_blocks`, :func:`fit_inverse_depth`, with robust
passes that drop outliers) or, for windows of whole blocks, from moment sums
(:func:`fast_fits`, :mod:`stud_planner.matching.window_moments`). :func:`frame_noise_m` is the
frame's depth noise, against which a plain fit is judged smooth enough to stand.

Pure numpy; no ROS.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stud_perception.camera_model import CameraModel
from stud_planner.matching.window_moments import BLOCK_PX, BlockMoments, powers_of

#: Quadric terms of the fit in the window's normalised image coordinates: 1, a, b, a^2, ab, b^2.
N_TERMS = 6


@dataclass(frozen=True)
class InverseDepthFit:
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

    def take(self, k: np.ndarray) -> "InverseDepthFit":
        """The fits of windows ``k``."""
        return InverseDepthFit(x0=self.x0[k], y0=self.y0[k], scale=self.scale[k], beta=self.beta[k],
                               cov=self.cov[k], inliers=None if self.inliers is None else self.inliers[k],
                               rms_w=self.rms_w[k])

    def without_inliers(self) -> "InverseDepthFit":
        """The same fits without the (large) inlier masks."""
        return self if self.inliers is None else InverseDepthFit(
            x0=self.x0, y0=self.y0, scale=self.scale, beta=self.beta, cov=self.cov, inliers=None, rms_w=self.rms_w)

    @staticmethod
    def concatenate(fits: list["InverseDepthFit"]) -> "InverseDepthFit":
        """The fits of several batches of windows, in order (without inlier masks)."""
        return InverseDepthFit(**{f: np.concatenate([getattr(x, f) for x in fits])
                                  for f in ("x0", "y0", "scale", "beta", "cov", "rms_w")}, inliers=None)

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
class PixelWindows:
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


def window_blocks(camera: CameraModel, depth: np.ndarray, uv: np.ndarray, z_cam: np.ndarray, window_m: float,
                  max_per_side: int, min_step: int = 1) -> PixelWindows:
    """The pixel samples of each stud's window (``uv`` (n, 2) px, ``z_cam`` (n,) its optical depth, m):
    a square of ``window_m`` sampled every ``step`` px, at most ``max_per_side`` a side (:class:`PixelWindows`)."""
    H, W = depth.shape
    half_px = camera.pixels_across(0.5 * window_m, z_cam)
    step = np.maximum(max(int(min_step), 1), np.ceil(2 * half_px / max(max_per_side - 1, 1))).astype(np.int64)
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
    return PixelWindows(u0=u0, v0=v0, step=step, grid=grid.astype(np.float64), good=good, inv_z=inv_z,
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


#: Below this many matrices LAPACK's per-matrix calls cost less than the batch-wide Cholesky's
#: few hundred numpy operations (a robust pass often refits one or two windows).
_LAPACK_BELOW = 200


def _inverse_spd(A: np.ndarray) -> np.ndarray:
    """Inverses (n, m, m) of symmetric positive (semi-)definite matrices (n, m, m), by a Cholesky
    factorisation written out over the batch: np.linalg.inv pays a per-matrix overhead that
    dominates at 6x6 for many matrices; for fewer than :data:`_LAPACK_BELOW` positive definite
    ones, LAPACK's (the same values up to rounding). A pivot that rounding leaves at or below zero is clamped to a
    tiny positive value, so a degenerate window gets a huge (honest) covariance instead of NaN."""
    if A.shape[0] < _LAPACK_BELOW:
        try:
            np.linalg.cholesky(A)  # raises unless every matrix is positive definite
            return np.linalg.inv(A)
        except np.linalg.LinAlgError:
            pass  # a degenerate window: the clamped factorisation below
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


def _robust_refits(win: PixelWindows, rows: np.ndarray, inl: np.ndarray, resid: np.ndarray, beta: np.ndarray,
                   A_inv: np.ndarray, var: np.ndarray, a: np.ndarray, b: np.ndarray, ca: np.ndarray, cb: np.ndarray,
                   robust_passes: int, outlier_k: float, floor_w: np.ndarray) -> None:
    """Up to ``robust_passes`` robust passes over windows ``rows``: drop the samples farther from
    the fit than max(outlier_k * 1.4826 * MAD, floor_w) and refit, until the inliers stop changing.
    Updates ``inl``, ``resid``, ``beta``, ``A_inv`` and ``var`` (all windows' arrays) in place."""
    good = win.good
    for _ in range(robust_passes):
        r = resid[rows].reshape(rows.size, -1)
        g = good[rows].reshape(rows.size, -1)
        # Median over the valid entries of each row: sort with invalid = +inf, take the middle.
        mid = np.maximum(g.sum(axis=1) - 1, 0) // 2
        r_all = np.where(g, r, np.inf)
        kth = np.unique(mid)  # a partial sort puts these places right (a few rows: a few places)
        r_sorted = np.partition(r_all, kth, axis=1) if kth.size <= 16 else np.sort(r_all, axis=1)
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


def fit_inverse_depth(win: PixelWindows, camera: CameraModel, scale: np.ndarray, robust_passes: int, outlier_k: float,
                      floor_w: np.ndarray, trigger_k: float = 4.5) -> InverseDepthFit:
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
        _robust_refits(win, rows, inl, resid, beta, A_inv, var, a, b, ca, cb, robust_passes, outlier_k, floor_w)
    x0 = (win.u0 - camera.cx) / camera.fx
    y0 = (win.v0 - camera.cy) / camera.fy
    return InverseDepthFit(x0=x0, y0=y0, scale=scale, beta=beta, cov=var[:, None, None] * A_inv, inliers=inl,
                           rms_w=np.sqrt(var))


def fast_fits(moments: BlockMoments, camera: CameraModel, uv: np.ndarray, z_cam: np.ndarray, window_m: float,
              step: int = 1):
    """Plain least-squares quadric fits of 1/z over block-aligned windows, from moment sums
    (:mod:`stud_planner.matching.window_moments`): the fit :func:`fit_inverse_depth` makes before any
    robust pass, on every valid pixel of a window of whole blocks around each stud (every
    ``step``-th of each row and column where the sums come from the windows' own pixels).

    Returns (fit, n_valid (n,), n_window (n,), eligible (n,) bool, the sample step used); a window
    under two blocks a side, or one the image border cuts to nothing, is not eligible (the pixel
    path takes it).
    """
    b = BLOCK_PX
    half = camera.pixels_across(0.5 * window_m, z_cam)
    c0, c1 = np.rint((uv[:, 0] - half) / b), np.rint((uv[:, 0] + half + 1.0) / b)
    r0, r1 = np.rint((uv[:, 1] - half) / b), np.rint((uv[:, 1] + half + 1.0) / b)
    eligible = (c1 - c0 >= 2) & (r1 - r0 >= 2)
    c0, c1 = np.clip(c0, 0, moments.n_cols), np.clip(c1, 0, moments.n_cols)
    r0, r1 = np.clip(r0, 0, moments.n_rows), np.clip(r1, 0, moments.n_rows)
    eligible &= (c1 > c0) & (r1 > r0)
    c0, c1, r0, r1 = (np.where(eligible, a, 0).astype(np.int64) for a in (c0, c1, r0, r1))
    c1, r1 = np.maximum(c1, c0 + 1), np.maximum(r1, r0 + 1)
    sums = moments.window_sums(r0, r1, c0, c1, step=step)
    scale = 0.5 * window_m / np.maximum(z_cam, 1e-6)
    ca, cb = 1.0 / (camera.fx * scale), 1.0 / (camera.fy * scale)  # window units per pixel
    beta, A_inv, rhs = _solve_normal_equations(sums.mw, sums.my, ca, cb)
    n_valid = np.rint(sums.mw[:, 0, 0]).astype(np.int64)
    var = np.maximum(sums.yy - np.einsum("ni,ni->n", beta, rhs), 0.0) / np.maximum(n_valid - len(_TERMS), 1)
    beta[:, 0] += moments.y_ref  # the sums are of 1/z - y_ref
    fit = InverseDepthFit(x0=(sums.centre_uv[:, 0] - camera.cx) / camera.fx,
                          y0=(sums.centre_uv[:, 1] - camera.cy) / camera.fy, scale=scale, beta=beta,
                          cov=var[:, None, None] * A_inv, inliers=None, rms_w=np.sqrt(var))
    return fit, n_valid, sums.n_window, eligible, sums.step


def frame_noise_m(moments: BlockMoments, stride: int = 4) -> float:
    """The frame's depth noise (m, 1-sigma): the median RMS of plane fits of 1/z to every
    ``stride``-th block in both directions that has depth in every pixel (curvature is nil over
    a block; a block on an edge is an outlier the median ignores). With all pixels present the
    design is the same for every block, and its columns 1, u, v are orthogonal over the block: the
    residual sum of squares is that about the block's mean less the two slopes' shares, two
    products for all blocks. NaN if no such block."""
    b = BLOCK_PX
    depth = moments.depth_blocks[::stride, :, ::stride, :]  # a view: (rows, b, cols, b)
    z = np.ascontiguousarray(depth.transpose(0, 2, 1, 3)).reshape(-1, b * b)
    z = z[np.all(z > 0, axis=1)].astype(np.float64)  # NaN compares False
    if z.shape[0] < _MIN_NOISE_BLOCKS:  # speckled depth: few whole blocks, take three-quarter-full ones
        return _frame_noise_from_sums(moments, stride)
    g = np.arange(b) - (b - 1) / 2.0
    slopes = np.column_stack([np.tile(g, b), np.repeat(g, b)])  # u, v of the pixels, each summing to 0
    y = 1.0 / z
    y_mean = y.mean(axis=1)
    y -= y_mean[:, None]
    s = y @ slopes
    rss = np.einsum("kj,kj->k", y, y) - (s * s) @ (1.0 / np.einsum("ji,ji->i", slopes, slopes))
    var_w = np.maximum(rss, 0.0) / (b * b - 3)
    z_mean = 1.0 / y_mean
    return float(np.median(np.sqrt(var_w) * z_mean * z_mean))


#: Whole blocks the noise estimate wants before it settles for partly holed ones.
_MIN_NOISE_BLOCKS = 30


def _frame_noise_from_sums(moments: BlockMoments, stride: int) -> float:
    """:func:`frame_noise_m` over the blocks that are three-quarters full, from their sums."""
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
