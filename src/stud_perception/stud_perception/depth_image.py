"""Depth images: unit conversion at the edge, the paper's hole rule, safe sub-pixel sampling.

Conventions (REP 118): a 16UC1 depth image holds millimetres with 0 = no depth; a 32FC1
image holds metres with NaN = no depth. The core works on float metres with NaN; the
conversions below are the only place millimetres appear. Depth is the optical-frame z
(not the ray length). Pixel (u, v) means column u, row v, with integer values at pixel
centres (the convention of K in :mod:`stud_perception.camera_model`), so ``depth_m[v, u]``.

Missing depth (paper): the depth of a pixel without a measurement is the mean of the valid
depths in the 7x7 window around it. Structured-light cameras also lose larger areas (dark
paint, specular steel), where a 7x7 window holds nothing; :func:`fill_depth_at` then grows
the window and, by default, fits a plane to the valid neighbours, and says per pixel which
rule produced the value (:class:`FillRule`) so callers can report it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum
from functools import lru_cache
from typing import Literal

import numpy as np

MM_PER_M = 1000.0
# Largest depth a 16UC1 image can hold (65.535 m); beyond it the pixel is written as invalid.
_MAX_DEPTH_MM = np.iinfo(np.uint16).max


#: What fills a hole when no window holds valid depth (fill_depth_at).
Fallback = Literal["plane", "grow", "none"]


class DepthImageError(ValueError):
    """A depth image or query that cannot be used (wrong encoding, shape, parameter)."""


class FillRule(IntEnum):
    """Which rule produced a depth value in :func:`fill_depth_at`."""

    DIRECT = 0        # the pixel itself has a measurement
    MEAN_WINDOW = 1   # paper rule: mean of the valid depths in the (default 7x7) window
    GROWN_WINDOW = 2  # mean of the valid depths in a larger window (large hole)
    PLANE_FIT = 3     # plane fitted to the valid depths of a larger window, evaluated at (u, v)
    NONE = 4          # no valid depth within the largest window: value is NaN


class SampleStatus(IntEnum):
    """Outcome of :func:`sample_depth_bilinear` per query."""

    OK = 0
    OUT_OF_IMAGE = 1
    INVALID_DEPTH = 2   # a neighbour that carries weight has no depth
    DISCONTINUITY = 3   # the neighbours differ by more than the step threshold


# -- unit conversion at the edge -------------------------------------------------------------
def depth_mm_to_m(depth_mm: np.ndarray) -> np.ndarray:
    """16UC1 depth (uint16 millimetres, 0 = invalid) -> float32 metres with NaN = invalid."""
    depth_mm = np.asarray(depth_mm)
    if depth_mm.dtype != np.uint16:
        raise DepthImageError(f"16UC1 depth must be uint16 millimetres, got dtype {depth_mm.dtype}")
    depth_m = depth_mm.astype(np.float32) / np.float32(MM_PER_M)
    depth_m[depth_mm == 0] = np.nan
    return depth_m


def depth_m_to_mm(depth_m: np.ndarray) -> np.ndarray:
    """Float metres (NaN/inf/<= 0 = invalid) -> 16UC1 uint16 millimetres (0 = invalid).

    Values are rounded to the nearest millimetre; depths beyond 65.535 m, and depths that
    round to 0 mm, become 0 (invalid) rather than wrapping or aliasing to "no depth".
    """
    depth_mm = np.asarray(depth_m, dtype=np.float64) * MM_PER_M
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(depth_mm) & (depth_mm >= 0.5) & (depth_mm < _MAX_DEPTH_MM + 0.5)
    out = np.zeros(depth_mm.shape, dtype=np.uint16)
    out[valid] = np.rint(depth_mm[valid]).astype(np.uint16)
    return out


def depth_image_to_m(data: np.ndarray, encoding: str) -> np.ndarray:
    """A depth image as published (``16UC1``/``mono16`` mm, or ``32FC1`` m) -> float32 metres, NaN invalid."""
    enc = encoding.upper()
    if enc in ("16UC1", "MONO16"):
        return depth_mm_to_m(np.asarray(data, dtype=np.uint16))
    if enc == "32FC1":
        depth_m = np.array(data, dtype=np.float32, copy=True)
        with np.errstate(invalid="ignore"):
            depth_m[~(np.isfinite(depth_m) & (depth_m > 0))] = np.nan
        return depth_m
    raise DepthImageError(f"depth encoding {encoding!r} is not supported: use 16UC1 (mm) or 32FC1 (m)")


# -- hole filling -------------------------------------------------------------------------------
@dataclass(frozen=True)
class FilledDepth:
    """Per-query result of :func:`fill_depth_at`; every array has the shape of the query.

    ``depth_m``: float64 metres (NaN when ``rule == NONE``); ``rule``: int8 :class:`FillRule`
    codes; ``n_used``: valid samples behind the value (1 for DIRECT); ``window_px``: side of the
    window that produced it (1 for DIRECT, 0 for NONE); ``spread_m``: standard deviation of the
    averaged samples, or the RMS residual of the plane fit (0 for DIRECT, NaN for NONE), so a
    caller can refuse values drawn from a window that straddles a depth edge.
    """

    depth_m: np.ndarray
    rule: np.ndarray
    n_used: np.ndarray
    window_px: np.ndarray
    spread_m: np.ndarray


def _window_samples(depth_m: np.ndarray, ui: np.ndarray, vi: np.ndarray, window: int):
    """Depths of the ``window`` x ``window`` neighbourhoods of integer pixels (ui, vi).

    Returns (values (N, w*w) float64 with NaN for invalid or outside, du (w*w,), dv (w*w,)).
    """
    h, w = depth_m.shape
    half = window // 2
    offs, du, dv = _window_offsets(window)
    vals = np.empty((ui.size, window, window))
    interior = (ui >= half) & (ui < w - half) & (vi >= half) & (vi < h - half)
    if window <= min(h, w):
        # Whole windows as views of the image, copied row by row (row-major, as du, dv are raveled).
        k = np.flatnonzero(interior)
        vals[k] = np.lib.stride_tricks.sliding_window_view(depth_m, (window, window))[vi[k] - half, ui[k] - half]
    else:
        interior[:] = False
    k = np.flatnonzero(~interior)
    if k.size:  # windows the image border cuts: gather rows x columns, NaN outside
        cols = ui[k, None] + offs[None, :]
        rows = vi[k, None] + offs[None, :]
        inside = ((rows >= 0) & (rows < h))[:, :, None] & ((cols >= 0) & (cols < w))[:, None, :]
        edge = depth_m[np.clip(rows, 0, h - 1)[:, :, None], np.clip(cols, 0, w - 1)[:, None, :]].astype(np.float64)
        edge[~inside] = np.nan
        vals[k] = edge
    return vals.reshape(ui.size, -1), du, dv


@lru_cache(maxsize=None)
def _window_offsets(window: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Offsets of a ``window`` x ``window`` neighbourhood: (offs (w,) int, du (w*w,), dv (w*w,)
    float64, row-major), built once per size (read-only)."""
    half = window // 2
    offs = np.arange(-half, half + 1)
    dv, du = np.meshgrid(offs, offs, indexing="ij")
    out = offs, du.ravel().astype(np.float64), dv.ravel().astype(np.float64)
    for a in out:
        a.setflags(write=False)
    return out


@lru_cache(maxsize=None)
def _plane_design(window: int) -> tuple[np.ndarray, np.ndarray]:
    """The plane fit's design [1, du, dv] (w*w, 3) of a window and its outer products (w*w, 9)."""
    _, du, dv = _window_offsets(window)
    A = np.stack([np.ones_like(du), du, dv], axis=1)
    AA = (A[:, :, None] * A[:, None, :]).reshape(-1, 9)
    for a in (A, AA):
        a.setflags(write=False)
    return A, AA


def _mean_of_valid(vals: np.ndarray):
    valid = np.isfinite(vals)
    n = valid.sum(axis=1)
    filled = np.where(valid, vals, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = filled.sum(axis=1) / n
        # One pass for the spread: sum of squares about the mean (depths are ~0.1-10 m and their
        # spreads >= 1e-6 m, far inside float64's range of exact cancellation).
        var = np.maximum(np.einsum("nk,nk->n", filled, filled) / n - mean * mean, 0.0)
    return mean, n, np.sqrt(var)


def _plane_fit(vals, du, dv, frac_u, frac_v, min_points: int, min_spread_px: float):
    """Fit inverse depth as an affine function of (du, dv) per row; evaluate at (frac_u, frac_v).

    Inverse depth, not depth, because a plane imaged by a pinhole camera has 1/z exactly affine
    in (u, v): the fit is then exact on planar patches at any tilt, and nearly so on the gently
    curved parts this project welds on. Returns (depth (N,), ok (N,), n (N,), rms_m (N,)).
    """
    valid = vals > 0  # NaN compares False
    n = valid.sum(axis=1)
    wgt = valid.astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(valid, 1.0 / vals, 0.0)
    # Normal equations of [1, du, dv] . p = 1/z, batched over queries.
    A, AA = _plane_design(math.isqrt(du.size))                             # (k, 3), (k, 9)
    # As matrix products (BLAS): sum_k wgt_nk A_ki A_kj and sum_k wgt_nk inv_nk A_ki.
    AtA = (wgt @ AA).reshape(-1, 3, 3)                                     # (N, 3, 3)
    Atb = inv @ A                                                          # (N, 3); inv is 0 where invalid
    # Refuse fits whose samples do not spread in both image directions (a line of samples
    # cannot fix a plane): smallest eigenvalue of the (du, dv) scatter, in pixels^2.
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_uv = AtA[:, 0, 1:] / n[:, None]
        cov = AtA[:, 1:, 1:] / n[:, None, None] - mean_uv[:, :, None] * mean_uv[:, None, :]
    a, b, d = cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1]
    with np.errstate(invalid="ignore"):  # smallest eigenvalue of the symmetric 2x2, closed form
        min_eig = 0.5 * (a + d) - np.sqrt(0.25 * (a - d) ** 2 + b * b)
    ok = (n >= min_points) & (min_eig >= min_spread_px**2)  # NaN (no samples) is not ok
    depth = np.full(vals.shape[0], np.nan)
    rms = np.full(vals.shape[0], np.nan)
    if ok.any():
        p = np.linalg.solve(AtA[ok], Atb[ok][:, :, None])[:, :, 0]       # (M, 3)
        inv_at = p[:, 0] + p[:, 1] * frac_u[ok] + p[:, 2] * frac_v[ok]
        with np.errstate(divide="ignore", invalid="ignore"):
            res = vals[ok] - 1.0 / (p @ A.T)  # the fitted depth at every sample
        res = np.where(valid[ok], res, 0.0)
        good = inv_at > 0  # an extrapolated plane may pass behind the camera: not a depth
        idx = np.flatnonzero(ok)
        depth[idx[good]] = 1.0 / inv_at[good]
        rms[idx] = np.sqrt(np.einsum("ij,ij->i", res, res) / n[ok])
        ok[idx[~good]] = False
    return depth, ok, n, rms


def _check_fill_args(depth_m, window: int, max_window: int, grow_step_px: int, fallback: str) -> np.ndarray:
    """The depth image of :func:`fill_depth_at` as an array, after checking its parameters."""
    depth_m = np.asarray(depth_m)
    if depth_m.ndim != 2:
        raise DepthImageError(f"depth image must be 2-D (H, W), got shape {depth_m.shape}")
    if window < 1 or window % 2 == 0 or max_window < window or max_window % 2 == 0:
        raise DepthImageError(
            f"windows must be odd with window <= max_window, got window={window}, max_window={max_window}"
        )
    if grow_step_px < 2 or grow_step_px % 2:
        raise DepthImageError(f"grow_step_px must be even and >= 2 (windows stay odd), got {grow_step_px}")
    if fallback not in ("plane", "grow", "none"):
        raise DepthImageError(f"fallback must be 'plane', 'grow' or 'none', got {fallback!r}")
    return depth_m


def _fill_pending(depth_m: np.ndarray, pending: np.ndarray, uf, vf, ui, vi, sizes: list[int], fallback: str,
                  min_valid: int, min_plane_points: int, outs: tuple) -> None:
    """Rules 2-3 of :func:`fill_depth_at` for the queries ``pending`` (pixels without depth), window
    size by window size; results into ``outs`` = (depth, rule, n_used, window_px, spread)."""
    out_depth, out_rule, out_n, out_win, out_spread = outs

    def store(sel, depth, rule, n, size, spread):
        out_depth[sel] = depth
        out_rule[sel] = rule
        out_n[sel] = n
        out_win[sel] = size
        out_spread[sel] = spread

    for k, size in enumerate(sizes):
        if pending.size == 0:
            break
        vals, du, dv = _window_samples(depth_m, ui[pending], vi[pending], size)
        last = k == len(sizes) - 1
        if k == 0 or fallback == "grow" or last:  # the plane rule uses the mean only at the end
            mean, n, std = _mean_of_valid(vals)
        fit_ok = np.zeros(pending.size, dtype=bool)
        if k == 0:
            take_mean, rule = n >= min_valid, FillRule.MEAN_WINDOW
        elif fallback == "grow":
            take_mean, rule = n >= min_valid, FillRule.GROWN_WINDOW
        else:
            frac_u = uf[pending] - ui[pending]
            frac_v = vf[pending] - vi[pending]
            z_fit, fit_ok, n_fit, rms = _plane_fit(vals, du, dv, frac_u, frac_v, min_plane_points, 1.0)
            store(pending[fit_ok], z_fit[fit_ok], FillRule.PLANE_FIT, n_fit[fit_ok], size, rms[fit_ok])
            # A plane needs more samples than a mean: only the largest window falls back to the mean.
            take_mean = (~fit_ok & (n >= min_valid)) if last else np.zeros_like(fit_ok)
            rule = FillRule.GROWN_WINDOW
        if take_mean.any():
            store(pending[take_mean], mean[take_mean], rule, n[take_mean], size, std[take_mean])
        pending = pending[~(fit_ok | take_mean)]


def fill_depth_at(
    depth_m: np.ndarray,
    u,
    v,
    window: int = 7,
    max_window: int = 31,
    fallback: Fallback = "plane",
    min_valid: int = 1,
    min_plane_points: int = 8,
    grow_step_px: int = 4,
    chunk: int = 4096,
) -> FilledDepth:
    """Depth at pixels (u, v) (any matching shapes, pixels) of a float-metre image, holes filled.

    Rules, in order, per query (the pixel is the nearest integer pixel to (u, v); a query
    outside the image, or non-finite, gets ``NONE``):

    1. ``DIRECT``: the pixel has a depth.
    2. ``MEAN_WINDOW`` (paper): mean of the valid depths in the ``window`` x ``window``
       neighbourhood, when it holds at least ``min_valid``.
    3. For larger holes, unless ``fallback == "none"``, the window grows by ``grow_step_px``
       (even) per step up to ``max_window``: with ``"plane"`` (default) the first window holding ``min_plane_points``
       valid depths spread in both directions gives a ``PLANE_FIT`` (inverse depth affine in
       (u, v), evaluated at the sub-pixel (u, v)); a hole too large even for that, but with some
       valid neighbours in ``max_window``, gets their mean (``GROWN_WINDOW``). With ``"grow"`` the
       first grown window with ``min_valid`` depths gives their mean (``GROWN_WINDOW``).
    4. ``NONE``: nothing usable; depth NaN.
    """
    depth_m = _check_fill_args(depth_m, window, max_window, grow_step_px, fallback)
    u_arr, v_arr = np.broadcast_arrays(np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64))
    shape = u_arr.shape
    uf = u_arr.ravel()
    vf = v_arr.ravel()
    n_q = uf.size
    h, w = depth_m.shape

    outs = _no_fill(n_q)
    out_depth, out_rule, out_n, out_win, out_spread = outs

    finite = np.isfinite(uf) & np.isfinite(vf)
    ui = np.where(finite, np.rint(np.where(finite, uf, 0.0)), -(10**9)).astype(np.int64)
    vi = np.where(finite, np.rint(np.where(finite, vf, 0.0)), -(10**9)).astype(np.int64)
    in_img = (ui >= 0) & (ui < w) & (vi >= 0) & (vi < h)

    # 1. direct measurement
    centre = np.full(n_q, np.nan)
    centre[in_img] = depth_m[vi[in_img], ui[in_img]]
    direct = np.isfinite(centre) & (centre > 0)
    out_depth[direct] = centre[direct]
    out_rule[direct] = FillRule.DIRECT
    out_n[direct] = 1
    out_win[direct] = 1
    out_spread[direct] = 0.0

    sizes = _window_sizes(window, max_window, grow_step_px, fallback)
    todo = np.flatnonzero(~direct & in_img)
    for start in range(0, todo.size, chunk):  # chunks bound the (N, w*w) temporaries
        _fill_pending(depth_m, todo[start:start + chunk], uf, vf, ui, vi, sizes, fallback, min_valid,
                      min_plane_points, outs)

    return FilledDepth(
        depth_m=out_depth.reshape(shape),
        rule=out_rule.reshape(shape),
        n_used=out_n.reshape(shape),
        window_px=out_win.reshape(shape),
        spread_m=out_spread.reshape(shape),
    )


def _no_fill(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """FilledDepth's arrays (depth_m, rule, n_used, window_px, spread_m) for ``n`` queries, none filled."""
    return (np.full(n, np.nan), np.full(n, FillRule.NONE, dtype=np.int8), np.zeros(n, dtype=np.int32),
            np.zeros(n, dtype=np.int32), np.full(n, np.nan))


def _window_sizes(window: int, max_window: int, grow_step_px: int, fallback: str) -> list[int]:
    """The windows :func:`fill_depth_at` tries, in order."""
    sizes = [window]
    if fallback != "none":
        sizes += list(range(window + grow_step_px, max_window, grow_step_px))
        if max_window > window:
            sizes.append(max_window)
    return sizes


def fill_holes_at(depth_m: np.ndarray, ui: np.ndarray, vi: np.ndarray, window: int = 7, max_window: int = 31,
                  min_valid: int = 1, min_plane_points: int = 8, grow_step_px: int = 4,
                  chunk: int = 4096) -> FilledDepth:
    """:func:`fill_depth_at` (``fallback="plane"``) of integer in-image pixels (ui, vi) (n,) that
    have no depth, without its general preparation (any shape, sub-pixel, out-of-image and direct
    queries): the same values, for callers that already know their pixels are holes (a matcher
    that fills the few a stud touches, a call at a time)."""
    depth_m = _check_fill_args(depth_m, window, max_window, grow_step_px, "plane")
    ui = np.asarray(ui, dtype=np.int64).ravel()
    vi = np.asarray(vi, dtype=np.int64).ravel()
    n_q = ui.size
    outs = _no_fill(n_q)
    sizes = _window_sizes(window, max_window, grow_step_px, "plane")
    uf, vf = ui.astype(np.float64), vi.astype(np.float64)
    todo = np.arange(n_q)
    for start in range(0, n_q, chunk):
        _fill_pending(depth_m, todo[start:start + chunk], uf, vf, ui, vi, sizes, "plane", min_valid,
                      min_plane_points, outs)
    return FilledDepth(*outs)


# -- sub-pixel sampling ------------------------------------------------------------------------
@dataclass(frozen=True)
class DepthSample:
    """Result of :func:`sample_depth_bilinear`: ``depth_m`` (float64, NaN unless OK) and
    ``status`` (int8 :class:`SampleStatus`), both shaped like the query."""

    depth_m: np.ndarray
    status: np.ndarray


def sample_depth_bilinear(depth_m: np.ndarray, u, v, max_step_m: float = 0.005) -> DepthSample:
    """Bilinear depth at sub-pixel (u, v), refusing to blend what should not be blended.

    Interpolating between a valid and an invalid pixel, or across a depth edge (the four
    neighbours with non-zero weight differ by more than ``max_step_m``), would invent a surface
    that is not there; such queries return NaN with status INVALID_DEPTH / DISCONTINUITY.
    """
    depth_m = np.asarray(depth_m)
    h, w = depth_m.shape
    u_arr, v_arr = np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64)
    if u_arr.shape != v_arr.shape:
        u_arr, v_arr = np.broadcast_arrays(u_arr, v_arr)
    shape = u_arr.shape
    uf = u_arr.ravel()
    vf = v_arr.ravel()
    status = np.full(uf.size, SampleStatus.OK, dtype=np.int8)
    out = np.full(uf.size, np.nan)
    with np.errstate(invalid="ignore"):
        inside = np.isfinite(uf) & np.isfinite(vf) & (uf >= 0) & (uf <= w - 1) & (vf >= 0) & (vf <= h - 1)
    status[~inside] = SampleStatus.OUT_OF_IMAGE
    idx = np.flatnonzero(inside)
    if idx.size == 0:
        return DepthSample(depth_m=out.reshape(shape), status=status.reshape(shape))
    ui, vi = (uf, vf) if idx.size == uf.size else (uf[idx], vf[idx])  # usually all in the image
    # Clamp the base pixel so a query on the last row/column still has a 2x2 cell.
    u0 = np.minimum(ui.astype(np.int64), max(w - 2, 0))  # in-image, so truncation is floor
    v0 = np.minimum(vi.astype(np.int64), max(h - 2, 0))
    fu = ui - u0
    fv = vi - v0
    du = np.minimum(u0 + 1, w - 1) - u0
    dv = (np.minimum(v0 + 1, h - 1) - v0) * w
    flat = depth_m.reshape(-1)
    i00 = v0 * w + u0
    z00, z01, z10, z11 = (flat[i].astype(np.float64) for i in (i00, i00 + du, i00 + dv, i00 + dv + du))
    # Fast path: all four corners have depth and lie within the step threshold. NaN fails every
    # comparison, so a missing corner falls to the exact path below, which also handles corners
    # of zero weight (a query on a pixel's row or column may ignore a hole beside it).
    lo = np.minimum(np.minimum(z00, z01), np.minimum(z10, z11))
    hi = np.maximum(np.maximum(z00, z01), np.maximum(z10, z11))
    with np.errstate(invalid="ignore"):
        easy = (lo > 0) & (hi - lo <= max_step_m)
    top = z00 + fu * (z01 - z00)
    bottom = z10 + fu * (z11 - z10)
    val = top + fv * (bottom - top)
    hard = np.flatnonzero(~easy)
    if hard.size == 0 and idx.size == uf.size:
        out = val
    else:
        out[idx[easy]] = val[easy]
    if hard.size:
        z = np.stack([z00[hard], z01[hard], z10[hard], z11[hard]], axis=1)
        fu, fv = fu[hard], fv[hard]
        wt = np.stack([(1 - fu) * (1 - fv), fu * (1 - fv), (1 - fu) * fv, fu * fv], axis=1)
        used = wt > 0
        with np.errstate(invalid="ignore"):
            bad = (used & ~(np.isfinite(z) & (z > 0))).any(axis=1)
        zu = np.where(used & ~bad[:, None], z, np.nan)
        with np.errstate(invalid="ignore"):
            zb = np.where(bad[:, None], 0.0, zu)
            step = np.fmax.reduce(zb, axis=1) - np.fmin.reduce(zb, axis=1)  # nanmax - nanmin, without copies
        jump = ~bad & (step > max_step_m)
        good = ~bad & ~jump
        val = (np.where(used, z, 0.0) * wt).sum(axis=1)
        j = idx[hard]
        out[j[good]] = val[good]
        status[j[bad]] = SampleStatus.INVALID_DEPTH
        status[j[jump]] = SampleStatus.DISCONTINUITY
    return DepthSample(depth_m=out.reshape(shape), status=status.reshape(shape))
