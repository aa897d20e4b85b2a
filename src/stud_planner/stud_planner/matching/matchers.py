"""Stud matchers: find where each stud's planar world position meets the observed surface.

A stud's planar world position (x_w, y_w) is known from the registered drawing, its height
is not. The weld point is where the world vertical line L = {(x_w, y_w, z)} meets the surface
seen in the depth image. Three matchers, one result type (:class:`MatchResults`):

- :func:`match_bfs` -- the paper's brute-force baseline: every pixel in row-major order until
  the back-projected XY (Eq. 1) is within ``tol_m`` of the target. Per-pixel Python on purpose.
- :func:`match_fpm` -- the paper's fast positioning method: quadrant search from the image
  centre (Eq. 3-6), then a 25x25 brute-force window. The quadrant rule is generalised from the
  paper's fixed axes (u opposite to world X, v along world Y) to any camera yaw/tilt through the
  local Jacobian d(XY_w)/d(u, v). Per-pixel Python on purpose (a faithful baseline).
- :func:`match_batch` -- ours: all studs of a frame at once, vectorised over studs. Solves
  h(pi(x_w, y_w, z)) = z for z along L by a safeguarded secant iteration on bilinearly sampled
  depth, i.e. a handful of depth look-ups per stud, sub-pixel, any camera orientation.

Frames and units: ``targets_xy_w`` (N, 2) metres in `world` (the arm's base frame, z up; the part
may lie at any height in it: the heights searched come from the depth image, :func:`observed_z_range`);
``depth_m`` (H, W) float32 metres of optical-frame z, NaN = invalid (REP 118), indexed
``[v, u]``; pixels (u, v) are column/row. Eq. 1 and its inverse are only ever evaluated through
:class:`stud_perception.camera_model.CameraModel`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum
from typing import Iterator

import numpy as np

from stud_perception.camera_model import CameraModel
from stud_perception.depth_image import FillRule, SampleStatus, fill_depth_at, sample_depth_bilinear
from stud_common.vocabulary import TargetStatus


#: Margin (m) added around the heights the depth image shows (:func:`observed_z_range`).
Z_RANGE_MARGIN_M = 0.05


def _depth_samples(depth_m: np.ndarray, stride: int = 16) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every ``stride``-th pixel of a depth image: u (1, w), v (h, 1) and depth (h, w), NaN where invalid."""
    sub = depth_m[::stride, ::stride]
    sub = np.where(sub > 0, sub, np.nan)  # NaN stays NaN
    u = np.arange(0, depth_m.shape[1], stride, dtype=np.float64)[None, :]
    v = np.arange(0, depth_m.shape[0], stride, dtype=np.float64)[:, None]
    return u, v, sub


def observed_z_range(depth_m: np.ndarray, camera: CameraModel, stride: int = 16,
                     margin_m: float = Z_RANGE_MARGIN_M) -> tuple[float, float, float]:
    """(z_min, z_max, z_median) in world metres of the surfaces this depth image shows.

    The heights a stud's weld point may have: the range searched along its vertical line, and the
    range over which "out of view" is decided (perspective makes any vertical line enter the image
    far enough below the plane, so the range must be finite). Taken from the view itself -- Eq. 1
    on every ``stride``-th pixel with depth, plus ``margin_m`` -- so it holds wherever the world
    frame is: a robot base on a pedestal puts the part well below z = 0, a floor-mounted one above.
    An image without any depth gives a range around the camera's own height.
    """
    u, v, sub = _depth_samples(depth_m, stride)
    zw = camera.pixel_to_world(u, v, sub)[..., 2]
    zw = zw[np.isfinite(zw)]
    if zw.size == 0:
        z = float(camera.position_w[2])
        return z - 10.0, z + 10.0, z
    return float(zw.min()) - margin_m, float(zw.max()) + margin_m, float(np.median(zw))


class MatchStatus(IntEnum):
    """Per-stud outcome of the matching: the matcher's subset of stud_common.vocabulary.TargetStatus."""

    OK = TargetStatus.OK
    OUT_OF_VIEW = TargetStatus.OUT_OF_VIEW
    NO_DEPTH = TargetStatus.NO_DEPTH
    NOT_CONVERGED = TargetStatus.NOT_CONVERGED
    DEPTH_DISCONTINUITY = TargetStatus.DEPTH_DISCONTINUITY


class MatchingError(ValueError):
    """Inputs a matcher cannot work with (shapes, sizes), with the offending value."""


@dataclass(frozen=True)
class MatchResult:
    """One stud's match. ``point_w`` (3,) metres in `world` is Eq. 1 of ``pixel_uv`` with the depth
    used there; ``xy_residual_m`` = |point_w[:2] - target|; NaN fields when nothing was found."""

    pixel_uv: tuple[float, float]
    point_w: np.ndarray
    iterations: int
    xy_residual_m: float
    status: MatchStatus
    hole_rule: FillRule

    @property
    def ok(self) -> bool:
        return self.status == MatchStatus.OK


@dataclass(frozen=True)
class MatchResults:
    """Matches of N studs of one frame, struct-of-arrays; ``results[i]`` is a :class:`MatchResult`.

    - ``pixel_uv`` (N, 2) float64 px, sub-pixel for the batch matcher, NaN if none;
    - ``point_w`` (N, 3) float64 m, `world`;
    - ``iterations`` (N,) int64: depth look-ups (batch) or pixels evaluated (BFS/FPM, the paper's count);
    - ``xy_residual_m`` (N,) float64 m;
    - ``status`` (N,) int8 :class:`MatchStatus`; ``hole_rule`` (N,) int8 :class:`FillRule`;
    - ``algorithm``: "bfs", "fpm" or "batch".
    """

    algorithm: str
    pixel_uv: np.ndarray
    point_w: np.ndarray
    iterations: np.ndarray
    xy_residual_m: np.ndarray
    status: np.ndarray
    hole_rule: np.ndarray

    def __post_init__(self) -> None:
        for name in ("pixel_uv", "point_w", "iterations", "xy_residual_m", "status", "hole_rule"):
            getattr(self, name).setflags(write=False)

    def __len__(self) -> int:
        return int(self.status.shape[0])

    def __getitem__(self, i: int) -> MatchResult:
        return MatchResult(
            pixel_uv=(float(self.pixel_uv[i, 0]), float(self.pixel_uv[i, 1])),
            point_w=self.point_w[i].copy(),
            iterations=int(self.iterations[i]),
            xy_residual_m=float(self.xy_residual_m[i]),
            status=MatchStatus(int(self.status[i])),
            hole_rule=FillRule(int(self.hole_rule[i])),
        )

    def __iter__(self) -> Iterator[MatchResult]:
        return (self[i] for i in range(len(self)))

    @property
    def ok(self) -> np.ndarray:
        """(N,) bool: usable matches."""
        return self.status == MatchStatus.OK

    @property
    def total_iterations(self) -> int:
        return int(self.iterations.sum())


# ---------------------------------------------------------------------------------------------
# Input checks and small geometry helpers (no Eq. 1 here: that is CameraModel's)
# ---------------------------------------------------------------------------------------------
def _check_inputs(targets_xy_w, depth_m, camera: CameraModel) -> tuple[np.ndarray, np.ndarray]:
    xy = np.asarray(targets_xy_w, dtype=np.float64)
    if xy.ndim == 1 and xy.shape == (2,):
        xy = xy[None, :]
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise MatchingError(f"targets_xy_w must have shape (N, 2), got {xy.shape}")
    depth = np.asarray(depth_m)
    if depth.shape != (camera.height, camera.width):
        raise MatchingError(
            f"depth image shape {depth.shape} does not match the camera's {camera.height}x{camera.width} (HxW)"
        )
    if not np.issubdtype(depth.dtype, np.floating):
        raise MatchingError(f"depth_m must be float metres with NaN = invalid, got dtype {depth.dtype}")
    return xy, depth


def _empty_results(algorithm: str, n: int) -> dict:
    return dict(
        algorithm=algorithm,
        pixel_uv=np.full((n, 2), np.nan),
        point_w=np.full((n, 3), np.nan),
        iterations=np.zeros(n, dtype=np.int64),
        xy_residual_m=np.full(n, np.nan),
        status=np.full(n, MatchStatus.NOT_CONVERGED, dtype=np.int8),
        hole_rule=np.full(n, FillRule.NONE, dtype=np.int8),
    )


def line_in_view_z_interval(
    camera: CameraModel, targets_xy_w: np.ndarray, z_min_m: float, z_max_m: float, min_depth_m: float = 1e-3
) -> tuple[np.ndarray, np.ndarray]:
    """Heights z in [z_min_m, z_max_m] at which the vertical line (x_w, y_w, z) projects inside the image.

    View-frustum clipping, exact: with P_c(z) = A + z B (optical frame, from
    :meth:`CameraModel.world_to_camera`), each image bound ``0 <= u <= W-1``, ``0 <= v <= H-1`` and
    ``z_c >= min_depth_m`` is linear in z. Returns (lo, hi), each (N,); lo > hi means never in view.
    """
    xy = np.asarray(targets_xy_w, dtype=np.float64).reshape(-1, 2)
    n = xy.shape[0]
    A = camera.world_to_camera(np.column_stack([xy, np.zeros(n)]))
    B = camera.world_to_camera(np.column_stack([xy, np.ones(n)])) - A
    lo = np.full(n, float(z_min_m))
    hi = np.full(n, float(z_max_m))
    # (alpha + beta z) >= 0 for each constraint; u = fx x/z + cx >= 0 <=> fx x + cx z >= 0, etc.
    fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
    W1, H1 = camera.width - 1, camera.height - 1
    constraints = [
        (fx * A[:, 0] + cx * A[:, 2], fx * B[:, 0] + cx * B[:, 2]),  # u >= 0
        (-(fx * A[:, 0] + (cx - W1) * A[:, 2]), -(fx * B[:, 0] + (cx - W1) * B[:, 2])),  # u <= W-1
        (fy * A[:, 1] + cy * A[:, 2], fy * B[:, 1] + cy * B[:, 2]),  # v >= 0
        (-(fy * A[:, 1] + (cy - H1) * A[:, 2]), -(fy * B[:, 1] + (cy - H1) * B[:, 2])),  # v <= H-1
        (A[:, 2] - min_depth_m, B[:, 2]),  # in front of the camera
    ]
    with np.errstate(divide="ignore", invalid="ignore"):
        for alpha, beta in constraints:
            root = -alpha / beta
            lo = np.where(beta > 0, np.maximum(lo, root), lo)
            hi = np.where(beta < 0, np.minimum(hi, root), hi)
            never = (beta == 0) & (alpha < 0)
            lo = np.where(never, np.inf, lo)
    # Shrink by a hair so rounding never puts an iterate a femtometre outside the image.
    span = hi - lo
    pad = np.where(span > 0, np.minimum(1e-9, 0.25 * span), 0.0)
    return lo + pad, hi - pad


# ---------------------------------------------------------------------------------------------
# Depth look-ups: the hole rule and the safe bilinear sampler live in stud_perception.depth_image;
# here only the policy for a sample that touches a hole or a depth step.
# ---------------------------------------------------------------------------------------------
def _depth_at_pixel(depth_m: np.ndarray, u: int, v: int, window_px: int, fallback: str) -> tuple[float, FillRule]:
    """Depth (m) at one integer pixel for the per-pixel baselines: the pixel's own depth, else
    :func:`fill_depth_at` (the paper's 7x7 mean; ``fallback`` "plane"/"none")."""
    z = float(depth_m[v, u])
    if math.isfinite(z):
        return z, FillRule.DIRECT
    f = fill_depth_at(depth_m, u, v, window=window_px, max_window=max(window_px, 31), fallback=fallback)
    return float(f.depth_m), FillRule(int(f.rule))


class _PixelFills:
    """:func:`fill_depth_at` of integer pixels of one depth image, each pixel computed once.

    A stud whose look-ups touch a hole revisits the same few pixels on every iteration of the
    batch matcher; filling each once (vectorised over the pixels first seen in a call) keeps the
    cost of holes to the pixels the studs' samples touch. The pixels met so far are kept sorted by
    their linear index (a few per stud that touches a hole), looked up by bisection.
    """

    def __init__(self, depth_m: np.ndarray, window_px: int, max_window_px: int) -> None:
        self._depth_m, self._window, self._max_window = depth_m, window_px, max_window_px
        self._keys = np.zeros(0, dtype=np.int64)
        self._value = np.zeros(0)
        self._rule = np.zeros(0, dtype=np.int8)
        self._spread = np.zeros(0)

    def __call__(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(depth_m, FillRule int8, spread_m) at in-image integer pixels (u, v), any shape."""
        W = self._depth_m.shape[1]
        lin = v * W + u
        pos = np.minimum(np.searchsorted(self._keys, lin), max(self._keys.size - 1, 0))
        known = (self._keys[pos] == lin) if self._keys.size else np.zeros(lin.shape, dtype=bool)
        new = np.unique(lin[~known])
        if new.size:
            flat = self._depth_m.reshape(-1)
            value = flat[new].astype(np.float64)
            rule = np.full(new.size, FillRule.DIRECT, dtype=np.int8)
            spread = np.zeros(new.size)
            hole = np.flatnonzero(~(value > 0))  # NaN compares False
            if hole.size:
                f = fill_depth_at(self._depth_m, new[hole] % W, new[hole] // W, window=self._window,
                                  max_window=self._max_window, fallback="plane")
                value[hole], rule[hole], spread[hole] = f.depth_m, f.rule, f.spread_m
            keys = np.concatenate([self._keys, new])
            order = np.argsort(keys, kind="stable")
            self._keys = keys[order]
            self._value = np.concatenate([self._value, value])[order]
            self._rule = np.concatenate([self._rule, rule])[order]
            self._spread = np.concatenate([self._spread, spread])[order]
            pos = np.searchsorted(self._keys, lin)
        return self._value[pos], self._rule[pos], self._spread[pos]


def _depth_at_subpixel(
    depth_m: np.ndarray, u: np.ndarray, v: np.ndarray, window_px: int, max_window_px: int, discontinuity_m: float,
    fills: _PixelFills | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bilinear depth at sub-pixel (u, v) (n,), in-image, with holes filled and steps respected.

    :func:`sample_depth_bilinear` answers most queries. Where it refuses (a corner has no depth,
    or the corners straddle a step larger than ``discontinuity_m``), the four corners are filled
    by :func:`fill_depth_at` (paper 7x7 mean, then plane fit up to ``max_window_px``) -- a fill
    whose window itself straddles a step (spread > discontinuity_m / 2) is refused -- and only
    the corners on the nearest corner's side of any step are blended (weights renormalised), so
    the value is never a mix of part and floor; such samples are flagged.
    Returns (depth_m (n,), worst FillRule used (n,) int8, on_step (n,) bool).
    """
    s = sample_depth_bilinear(depth_m, u, v, max_step_m=discontinuity_m)
    z = np.array(s.depth_m, dtype=np.float64)
    rule = np.full(z.shape, FillRule.DIRECT, dtype=np.int8)
    on_step = np.zeros(z.shape, dtype=bool)
    redo = np.flatnonzero(s.status != SampleStatus.OK)
    if redo.size == 0:
        return z, rule, on_step
    H, W = depth_m.shape
    ur, vr = u[redo], v[redo]
    u0 = np.clip(np.floor(ur), 0, W - 2).astype(np.int64)
    v0 = np.clip(np.floor(vr), 0, H - 2).astype(np.int64)
    fu = np.clip(ur - u0, 0.0, 1.0)
    fv = np.clip(vr - v0, 0.0, 1.0)
    cu = np.stack([u0, u0 + 1, u0, u0 + 1], axis=1)
    cv = np.stack([v0, v0, v0 + 1, v0 + 1], axis=1)
    w = np.stack([(1 - fu) * (1 - fv), fu * (1 - fv), (1 - fu) * fv, fu * fv], axis=1)
    if fills is None:
        fills = _PixelFills(depth_m, window_px, max_window_px)
    d, crule, spread = fills(cu, cv)
    with np.errstate(invalid="ignore"):
        straddle = (crule != FillRule.DIRECT) & (crule != FillRule.NONE) & ~(spread <= 0.5 * discontinuity_m)
    d[straddle] = np.nan
    # Reference: the heaviest corner that has a depth.
    ref = np.argmax(np.where(np.isfinite(d), w + 1.0, w), axis=1)
    rows = np.arange(redo.size)
    d_ref = d[rows, ref]
    with np.errstate(invalid="ignore"):
        consistent = np.isfinite(d) & (np.abs(d - d_ref[:, None]) <= discontinuity_m)
    wc = np.where(consistent, w, 0.0)
    wsum = wc.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        zr = np.where(wsum > 0, (wc * np.where(consistent, d, 0.0)).sum(axis=1) / wsum, np.nan)
    # All consistent corners at zero weight (query exactly on the reference's far edge): take it.
    zr = np.where((wsum == 0) & np.isfinite(d_ref), d_ref, zr)
    z[redo] = zr
    rule[redo] = np.where(np.isfinite(zr), np.where(consistent, crule, 0).max(axis=1), FillRule.NONE)
    on_step[redo] = (np.isfinite(d) & ~consistent).any(axis=1) | straddle.any(axis=1)
    return z, rule, on_step


# ---------------------------------------------------------------------------------------------
# BFS: the paper's baseline
# ---------------------------------------------------------------------------------------------
def _store_best_pixel(out: dict, k: int, best: tuple, camera: CameraModel) -> None:
    """Write the best pixel a per-pixel search found for stud ``k`` (BFS and FPM): its pixel, its
    Eq. 1 point, XY residual and hole rule. ``best`` = (dist, u, v, z, rule), u < 0 when none."""
    dist, u, v, z, rule = best
    if u >= 0:
        out["pixel_uv"][k] = (u, v)
        out["point_w"][k] = camera.pixel_to_world(u, v, z)
        out["xy_residual_m"][k] = dist
        out["hole_rule"][k] = rule


def _closer(camera: CameraModel, u: int, v: int, z: float, rule, xt: float, yt: float, best: tuple) -> tuple:
    """One brute-force evaluation (BFS, FPM's window): Eq. 1 for pixel (u, v) at depth z, one pixel
    at a time (the baselines' cost), and its XY distance to the target. Returns (dist, best), best
    replaced by this pixel when it is closer."""
    P = camera.pixel_to_world(u, v, z)
    dist = math.hypot(P[0] - xt, P[1] - yt)
    return dist, ((dist, u, v, z, rule) if dist < best[0] else best)


def match_bfs(
    targets_xy_w,
    depth_m: np.ndarray,
    camera: CameraModel,
    tol_m: float = 0.001,
    max_pixels: int | None = None,
    hole_window_px: int = 7,
    z_range_m: tuple[float, float] | None = None,
) -> MatchResults:
    """The paper's brute-force search (BFS): for each target, evaluate pixels in row-major order
    (v outer, u inner) until Eq. 1 of the pixel lands within ``tol_m`` of (x_w, y_w).

    Deliberately a per-pixel Python loop calling :meth:`CameraModel.pixel_to_world` one pixel at a
    time: it is the baseline the paper's Tables 1-2 time, and its cost is the point. One
    iteration = one pixel evaluated. Missing depth takes the paper's rule (mean of the valid depths
    in a ``hole_window_px`` square window, no fallback); pixels without any depth are counted and skipped.

    ``max_pixels`` caps the pixels evaluated per target (for sampling in benchmarks); a capped
    search that has not met the tolerance reports NOT_CONVERGED with ``iterations == max_pixels``.
    Unmatched targets: OUT_OF_VIEW if the vertical line never enters the image for heights in
    ``z_range_m`` (default: :func:`observed_z_range`) -- decided before the scan, with 0
    iterations, since no pixel can match such a target --, NO_DEPTH if no pixel had depth, else
    NOT_CONVERGED (best pixel reported).
    """
    xy, depth = _check_inputs(targets_xy_w, depth_m, camera)
    out = _empty_results("bfs", xy.shape[0])
    H, W = depth.shape
    limit = H * W if max_pixels is None else min(int(max_pixels), H * W)
    lo, hi = line_in_view_z_interval(camera, xy, *(z_range_m or observed_z_range(depth, camera)[:2]))
    for k, (xt, yt) in enumerate(xy):
        if lo[k] > hi[k]:
            out["status"][k] = MatchStatus.OUT_OF_VIEW
            continue
        best = (np.inf, -1, -1, np.nan, FillRule.NONE)
        evaluated = 0
        any_depth = False
        found = False
        for v in range(H):
            row = depth[v]
            for u in range(W):
                if evaluated >= limit:
                    break
                evaluated += 1
                z = float(row[u])
                rule = FillRule.DIRECT
                if not math.isfinite(z):
                    z, rule = _depth_at_pixel(depth, u, v, hole_window_px, "none")
                    if not math.isfinite(z):
                        continue
                any_depth = True
                dist, best = _closer(camera, u, v, z, rule, xt, yt, best)
                if dist < tol_m:
                    found = True
                    break
            if found or evaluated >= limit:
                break
        out["iterations"][k] = evaluated
        _store_best_pixel(out, k, best, camera)
        if found:
            out["status"][k] = MatchStatus.OK
        elif not any_depth and evaluated == H * W:
            out["status"][k] = MatchStatus.NO_DEPTH
        else:
            out["status"][k] = MatchStatus.NOT_CONVERGED
    return MatchResults(**out)


# ---------------------------------------------------------------------------------------------
# FPM: the paper's fast positioning method, with a Jacobian quadrant rule
# ---------------------------------------------------------------------------------------------
def xy_jacobian_at_height(camera: CameraModel, u: float, v: float, z_w: float) -> np.ndarray:
    """d(x_w, y_w)/d(u, v) (2x2, m/px) of the ray through (u, v) cut at world height ``z_w``.

    The local linear model the FPM's quadrant rule needs: how the back-projected XY moves when
    the pixel moves, for a surface locally at the current height. Built from Eq. 1 via
    :meth:`CameraModel.pixel_to_world` (1-px finite differences are exact to O(1e-3 px)
    here because the map is projective and smooth). For a nadir camera with the paper's axes it
    is diag(-z/fx, z/fy), i.e. the paper's Eq. 3-6 sign rule.
    """
    uu = np.array([u, u + 1.0, u])
    vv = np.array([v, v, v + 1.0])
    rays = camera.ray_directions_world(uu, vv)  # world direction per metre of optical depth
    with np.errstate(divide="ignore", invalid="ignore"):
        depth_at_height = (z_w - camera.position_w[2]) / rays[:, 2]
    P = camera.pixel_to_world(uu, vv, depth_at_height)
    return np.column_stack([P[1, :2] - P[0, :2], P[2, :2] - P[0, :2]])


def _window_order(window_px: int, order: str) -> tuple[np.ndarray, np.ndarray]:
    """Offsets (du, dv) of a window_px x window_px window in scan order: "row_major" (top-left
    first, as a brute-force scan) or "nearest_first" (by distance from the centre, row-major ties)."""
    r = np.arange(-(window_px // 2), window_px // 2 + 1)
    dv, du = (a.ravel() for a in np.meshgrid(r, r, indexing="ij"))
    if order == "row_major":
        return du, dv
    if order == "nearest_first":
        idx = np.argsort(du * du + dv * dv, kind="stable")
        return du[idx], dv[idx]
    raise MatchingError(f"window_order must be 'row_major' or 'nearest_first', got {order!r}")


def match_fpm(
    targets_xy_w,
    depth_m: np.ndarray,
    camera: CameraModel,
    tol_m: float = 0.001,
    window_px: int = 25,
    hole_window_px: int = 7,
    max_halvings: int | None = None,
    hole_fallback: bool = True,
    z_range_m: tuple[float, float] | None = None,
    quadrant_early_exit: bool = False,
    window_order: str = "row_major",
) -> MatchResults:
    """The paper's fast positioning method (FPM), per stud, per pixel (a faithful baseline).

    1. Quadrant search (paper Eq. 3-6): start at the image centre with steps (W/4, H/4); at each
       step back-project the current pixel with its depth (Eq. 1), move one step into the
       quadrant containing the target and halve the steps; ``max_halvings`` = ceil(log4(W*H))
       steps (11 for 1280x960), or fewer with ``quadrant_early_exit`` (stop once within ``tol_m``).
       Generalisation: the quadrant is the sign of J^-1 (target - XY), J = d(XY_w)/d(u, v) of
       :func:`xy_jacobian_at_height` at the current pixel and height, so it works for any camera
       yaw/tilt; with the paper's axes it reduces to the paper's comparisons.
    2. Brute force over a ``window_px`` x ``window_px`` window around the result, like BFS
       (``window_order="row_major"``) or nearest pixels first, stopping at the first within ``tol_m``.

    Iterations are counted the paper's way: one per pixel evaluated (quadrant steps + window
    pixels). The defaults are our reading of the paper: its 217 iterations per stud fit 11 steps
    plus a row-major window scan that meets 1 mm about 9 rows down (and its BFS 534,115 fits the
    mean row-major index of a stud, i.e. both are per-stud means). ``quadrant_early_exit=True``
    with ``window_order="nearest_first"`` is the cheap variant (~9 per stud).
    Missing depth: the paper's 7x7 mean, then (``hole_fallback``) the plane-fit fallback.
    A stud not matched within tolerance: OUT_OF_VIEW if its vertical line never enters the image
    (heights in ``z_range_m``, default :func:`observed_z_range`), NO_DEPTH if no pixel of the final window had depth, else
    NOT_CONVERGED (the best pixel evaluated is reported).
    """
    xy, depth = _check_inputs(targets_xy_w, depth_m, camera)
    out = _empty_results("fpm", xy.shape[0])
    H, W = depth.shape
    if max_halvings is None:
        max_halvings = math.ceil(math.log(W * H, 4))
    win_du, win_dv = _window_order(window_px, window_order)
    lo, hi = line_in_view_z_interval(camera, xy, *(z_range_m or observed_z_range(depth, camera)[:2]))

    def depth_at(u: int, v: int) -> tuple[float, FillRule]:
        return _depth_at_pixel(depth, u, v, hole_window_px, "plane" if hole_fallback else "none")

    sub = _depth_samples(depth)[2]
    sub = sub[np.isfinite(sub)]
    z_typical = float(np.median(sub)) if sub.size else float(camera.position_w[2])

    for k, (xt, yt) in enumerate(xy):
        target = np.array([xt, yt])
        uc, vc = W / 2.0, H / 2.0
        su, sv = W / 4.0, H / 4.0
        iterations = 0
        best = (np.inf, -1, -1, np.nan, FillRule.NONE)
        # Before any depth is read, assume the image's typical depth (only steers the first step).
        z_last = z_typical
        found = False
        for _ in range(max_halvings):
            ui = int(min(max(round(uc), 0), W - 1))
            vi = int(min(max(round(vc), 0), H - 1))
            z, rule = depth_at(ui, vi)
            iterations += 1
            if math.isfinite(z):
                z_last = z
            else:  # no depth: steer with the last depth seen (the step decision only needs a sign)
                z = z_last
            P = camera.pixel_to_world(ui, vi, z)
            delta = target - P[:2]
            dist = float(np.hypot(*delta))
            if rule != FillRule.NONE and dist < best[0]:
                best = (dist, ui, vi, z, rule)
            if quadrant_early_exit and dist < tol_m and rule != FillRule.NONE:
                found = True
                break
            J = xy_jacobian_at_height(camera, ui, vi, P[2])
            try:
                duv = np.linalg.solve(J, delta)
            except np.linalg.LinAlgError:
                break  # ray parallel to the surface model: no direction to go
            uc = min(max(uc + np.sign(duv[0]) * su, 0.0), W - 1.0)
            vc = min(max(vc + np.sign(duv[1]) * sv, 0.0), H - 1.0)
            su, sv = su / 2.0, sv / 2.0
        window_depth = False  # NO_DEPTH is about the neighbourhood the search ended in
        if not found:
            u0 = int(min(max(round(uc), 0), W - 1))
            v0 = int(min(max(round(vc), 0), H - 1))
            for du, dv in zip(win_du, win_dv):
                u, v = u0 + int(du), v0 + int(dv)
                if not (0 <= u < W and 0 <= v < H):
                    continue
                iterations += 1
                z, rule = depth_at(u, v)
                if not math.isfinite(z):
                    continue
                window_depth = True
                dist, best = _closer(camera, u, v, z, rule, xt, yt, best)
                if dist < tol_m:
                    found = True
                    break
        out["iterations"][k] = iterations
        _store_best_pixel(out, k, best, camera)
        if found:
            out["status"][k] = MatchStatus.OK
        elif lo[k] > hi[k]:
            out["status"][k] = MatchStatus.OUT_OF_VIEW
        elif not window_depth:
            out["status"][k] = MatchStatus.NO_DEPTH
        else:
            out["status"][k] = MatchStatus.NOT_CONVERGED
    return MatchResults(**out)


# ---------------------------------------------------------------------------------------------
# Batch: ours
# ---------------------------------------------------------------------------------------------
def match_batch(
    targets_xy_w,
    depth_m: np.ndarray,
    camera: CameraModel,
    tol_m: float = 0.001,
    *,
    converge_xy_m: float = 1e-4,
    z_range_m: tuple[float, float] | None = None,
    z_init_m: float | None = None,
    max_lookups: int = 12,
    z_bracket_tol_m: float = 2e-5,
    hole_window_px: int = 7,
    hole_max_window_px: int = 31,
    discontinuity_m: float = 0.004,
) -> MatchResults:
    """All studs of a frame at once: where the vertical line (x_w, y_w, z) meets the observed surface.

    For each stud, solve g(z) = h(z) - z = 0 with h(z) the height of Eq. 1 of the pixel
    pi(x_w, y_w, z) (:meth:`CameraModel.world_to_pixel`) at its bilinearly sampled depth. The
    first step is the plain fixed point z1 = h(z0) from the working plane; then a secant update,
    kept inside the bracket [g > 0, g < 0] seen so far (bisection when the secant leaves it):
    plain fixed point oscillates or diverges where |dh/dz| >= 1 (steep surfaces near the image
    edge), the safeguarded secant does not, and it stops at ``converge_xy_m`` (well under the
    paper's 1 mm, near the depth noise's effect on XY). Bilinear depth makes g continuous, so the
    iteration converges on noisy depth too. Iterates are clipped to the heights at which the line
    is in view (:func:`line_in_view_z_interval`) within ``z_range_m``; by default the heights the
    depth image shows (:func:`observed_z_range`), whose median is the first guess ``z_init_m``.

    Result per stud (``iterations`` = depth look-ups, each one bilinear sample):
    - OK: |XY(point_w) - target| < ``tol_m``; ``point_w`` is Eq. 1 of the sub-pixel ``pixel_uv``;
    - OUT_OF_VIEW: the line never enters the image in ``z_range_m``, or the surface point is
      outside it (the iterate is pinned at the image border);
    - NO_DEPTH: a hole the paper's 7x7 mean and the plane-fit fallback (up to ``hole_max_window_px``,
      :func:`stud_perception.depth_image.fill_depth_at`) cannot fill;
    - DEPTH_DISCONTINUITY: the final sample, or its hole fill, straddles a depth step larger than
      ``discontinuity_m`` (part edge vs floor), or the bracket collapsed onto a jump of g (the line
      passes behind an occluding edge): the point is reported but must not be welded;
    - NOT_CONVERGED: none of the above, ``max_lookups`` reached outside ``tol_m``.
    Vectorised over studs; the loop is over look-ups (<= max_lookups), on the still-active studs.
    """
    xy, depth = _check_inputs(targets_xy_w, depth_m, camera)
    n = xy.shape[0]
    out = _empty_results("batch", n)
    if z_range_m is None or z_init_m is None:
        z_min, z_max, z_mid = observed_z_range(depth, camera)
        z_range_m = z_range_m or (z_min, z_max)
        z_init_m = z_mid if z_init_m is None else z_init_m
    zlo, zhi = line_in_view_z_interval(camera, xy, z_range_m[0], z_range_m[1])
    in_view = zlo <= zhi
    out["status"][~in_view] = MatchStatus.OUT_OF_VIEW
    active = np.flatnonzero(in_view)
    if active.size == 0:
        return MatchResults(**out)

    fills = _PixelFills(depth, hole_window_px, hole_max_window_px)
    lookup = [0]  # look-ups so far; a stud takes part in every one from the first until it settles

    def evaluate(idx: np.ndarray, z: np.ndarray):
        P = np.column_stack([xy[idx], z])
        u, v, _ = camera.world_to_pixel(P)
        # z is inside the in-view interval, so u, v are in the image up to rounding.
        u = np.clip(u, 0.0, camera.width - 1.0)
        v = np.clip(v, 0.0, camera.height - 1.0)
        d, rule, step = _depth_at_subpixel(depth, u, v, hole_window_px, hole_max_window_px, discontinuity_m, fills)
        Q = camera.pixel_to_world(u, v, d)  # Eq. 1 at the sub-pixel
        g = Q[:, 2] - z
        res = np.hypot(Q[:, 0] - xy[idx, 0], Q[:, 1] - xy[idx, 1])
        lookup[0] += 1
        out["iterations"][idx] = lookup[0]
        got = np.isfinite(d)
        # Keep the latest sample that had depth; it is what the result reports.
        kept = (idx, u, v, Q, res, rule) if got.all() else (idx[got], u[got], v[got], Q[got], res[got], rule[got])
        j = kept[0]
        out["pixel_uv"][j, 0], out["pixel_uv"][j, 1] = kept[1], kept[2]
        out["point_w"][j], out["xy_residual_m"][j], out["hole_rule"][j] = kept[3:]
        return g, res, step, got

    idx = active
    lo_b = np.full(n, -np.inf)  # highest z seen with g > 0 (the surface is above it)
    hi_b = np.full(n, np.inf)  # lowest z seen with g < 0
    g_lo = np.full(n, np.nan)  # g at lo_b / hi_b, to measure a jump of g when the bracket collapses
    g_hi = np.full(n, np.nan)
    on_step = np.zeros(n, dtype=bool)

    def usable(j: np.ndarray) -> np.ndarray:
        """Status of finished studs j whose last sample had depth: OK within tol_m unless on a step."""
        within = out["xy_residual_m"][j] < tol_m
        return np.where(on_step[j], MatchStatus.DEPTH_DISCONTINUITY,
                        np.where(within, MatchStatus.OK, MatchStatus.NOT_CONVERGED)).astype(np.int8)

    def step_and_settle(idx: np.ndarray, z: np.ndarray):
        """One look-up at heights z for studs idx; settle the finished ones; return the rest's
        (keep mask over idx, idx, z, g)."""
        g, res, step, got = evaluate(idx, z)
        on_step[idx] = step
        out["status"][idx[~got]] = MatchStatus.NO_DEPTH
        done = got & (res < converge_xy_m)
        out["status"][idx[done]] = usable(idx[done])
        keep = got & ~done
        idx, z, g = idx[keep], z[keep], g[keep]
        up, down = g > 0, g < 0
        lo_b[idx[up]] = np.maximum(lo_b[idx[up]], z[up])
        g_lo[idx[up]] = np.where(lo_b[idx[up]] == z[up], g[up], g_lo[idx[up]])
        hi_b[idx[down]] = np.minimum(hi_b[idx[down]], z[down])
        g_hi[idx[down]] = np.where(hi_b[idx[down]] == z[down], g[down], g_hi[idx[down]])
        return keep, idx, z, g

    z_prev = np.clip(z_init_m, zlo[idx], zhi[idx])
    _, idx, z_prev, g_prev = step_and_settle(idx, z_prev)
    z_cur = np.clip(z_prev + g_prev, zlo[idx], zhi[idx])  # plain fixed point as the first step
    for _ in range(max_lookups - 1):
        if idx.size == 0:
            break
        keep, idx, z_cur, g_cur = step_and_settle(idx, z_cur)
        z_prev, g_prev = z_prev[keep], g_prev[keep]
        if idx.size == 0:
            break
        denom = g_cur - g_prev
        with np.errstate(divide="ignore", invalid="ignore"):
            secant = z_cur - g_cur * (z_cur - z_prev) / denom
        # Where the secant is undefined (two equal g), a damped fixed-point step.
        z_new = np.where(np.isfinite(secant) & (np.abs(denom) > 1e-12), secant, z_cur + 0.5 * g_cur)
        lo, hi = lo_b[idx], hi_b[idx]
        bracketed = np.isfinite(lo) & np.isfinite(hi)
        leaves = bracketed & ((z_new <= np.minimum(lo, hi)) | (z_new >= np.maximum(lo, hi)))
        z_new = np.where(leaves, 0.5 * (lo + hi), z_new)
        z_new_c = np.clip(z_new, zlo[idx], zhi[idx])
        # Pushed out of view again from the same border: the surface point is not in the image.
        at_border = (z_new_c != z_new) & (z_new_c == z_cur)
        # Bracket collapsed without convergence: g jumps over zero -- an occluding edge when the
        # jump is a depth step, else the best we can do on this depth.
        collapsed = bracketed & ~at_border & (np.abs(hi - lo) < z_bracket_tol_m)
        j = idx[at_border]
        out["status"][j] = np.where(out["xy_residual_m"][j] < tol_m, usable(j), MatchStatus.OUT_OF_VIEW)
        j = idx[collapsed]
        jump = (g_lo[j] - g_hi[j]) > discontinuity_m
        out["status"][j] = np.where(jump, MatchStatus.DEPTH_DISCONTINUITY, usable(j))
        keep = ~(at_border | collapsed)
        idx, z_prev, g_prev, z_cur = idx[keep], z_cur[keep], g_cur[keep], z_new_c[keep]

    # Out of look-ups: usable if within the paper's tolerance, unless on a depth step.
    if idx.size:
        out["status"][idx] = usable(idx)
    return MatchResults(**out)
