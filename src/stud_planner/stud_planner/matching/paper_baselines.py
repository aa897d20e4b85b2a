"""The paper's matchers, per stud and per pixel on purpose (faithful baselines): BFS and FPM.

- :func:`match_bfs` -- the paper's brute-force baseline: every pixel in row-major order until
  the back-projected XY (Eq. 1) is within ``tol_m`` of the target.
- :func:`match_fpm` -- the paper's fast positioning method: quadrant search from the image
  centre (Eq. 3-6), then a 25x25 brute-force window. The quadrant rule is generalised from the
  paper's fixed axes (u opposite to world X, v along world Y) to any camera yaw/tilt through the
  local Jacobian d(XY_w)/d(u, v).

Both return :class:`stud_planner.matching.match_common.MatchResults`; import them from
:mod:`stud_planner.matching.matchers` (which re-exports them) or from here.
"""
from __future__ import annotations

import math

import numpy as np

from stud_perception.camera_model import CameraModel
from stud_perception.depth_image import Fallback, FillRule, fill_depth_at
from stud_planner.matching.match_common import (
    MatchingError,
    MatchResults,
    MatchStatus,
    check_inputs,
    depth_samples,
    empty_results,
    line_in_view_z_interval,
    observed_z_range,
)


def _depth_at_pixel(depth_m: np.ndarray, u: int, v: int, window_px: int, fallback: Fallback) -> tuple[float, FillRule]:
    """Depth (m) at one integer pixel for the per-pixel baselines: the pixel's own depth, else
    :func:`fill_depth_at` (the paper's 7x7 mean; ``fallback`` "plane"/"none")."""
    z = float(depth_m[v, u])
    if math.isfinite(z):
        return z, FillRule.DIRECT
    f = fill_depth_at(depth_m, u, v, window=window_px, max_window=max(window_px, 31), fallback=fallback)
    return float(f.depth_m), FillRule(int(f.rule))


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
    xy, depth = check_inputs(targets_xy_w, depth_m, camera)
    out = empty_results("bfs", xy.shape[0])
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
    (heights in ``z_range_m``, default :func:`observed_z_range`), NO_DEPTH if no pixel of the final window had
    depth, else NOT_CONVERGED (the best pixel evaluated is reported).
    """
    xy, depth = check_inputs(targets_xy_w, depth_m, camera)
    out = empty_results("fpm", xy.shape[0])
    H, W = depth.shape
    if max_halvings is None:
        max_halvings = math.ceil(math.log(W * H, 4))
    win_du, win_dv = _window_order(window_px, window_order)
    lo, hi = line_in_view_z_interval(camera, xy, *(z_range_m or observed_z_range(depth, camera)[:2]))

    def depth_at(u: int, v: int) -> tuple[float, FillRule]:
        return _depth_at_pixel(depth, u, v, hole_window_px, "plane" if hole_fallback else "none")

    sub = depth_samples(depth)[2]
    sub = sub[np.isfinite(sub)]
    z_typical = float(np.median(sub)) if sub.size else float(camera.position_w[2])

    for k, (xt, yt) in enumerate(xy):
        # Before any depth is read, assume the image's typical depth (only steers the first step).
        (uc, vc), iterations, best, found = _fpm_quadrant_search(camera, depth_at, xt, yt, z_typical, max_halvings,
                                                                 tol_m, quadrant_early_exit)
        window_depth = False  # NO_DEPTH is about the neighbourhood the search ended in
        if not found:
            u0 = int(min(max(round(uc), 0), W - 1))
            v0 = int(min(max(round(vc), 0), H - 1))
            scanned, window_depth, best, found = _fpm_window_scan(camera, depth_at, xt, yt, u0, v0, win_du, win_dv,
                                                                  tol_m, best)
            iterations += scanned
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




def _fpm_quadrant_search(camera: CameraModel, depth_at, xt: float, yt: float, z_typical: float, max_halvings: int,
                         tol_m: float, early_exit: bool):
    """FPM step 1 for one stud (paper Eq. 3-6, the quadrant by the local Jacobian): from the image
    centre, ``max_halvings`` steps of halving size toward the target. Returns ((uc, vc) where it
    ended, pixels evaluated, best (dist, u, v, z, rule) seen, found within ``tol_m`` (early exit only))."""
    H, W = camera.height, camera.width
    target = np.array([xt, yt])
    uc, vc = W / 2.0, H / 2.0
    su, sv = W / 4.0, H / 4.0
    iterations = 0
    best = (np.inf, -1, -1, np.nan, FillRule.NONE)
    z_last = z_typical
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
        if early_exit and dist < tol_m and rule != FillRule.NONE:
            return (uc, vc), iterations, best, True
        J = xy_jacobian_at_height(camera, ui, vi, P[2])
        try:
            duv = np.linalg.solve(J, delta)
        except np.linalg.LinAlgError:
            break  # ray parallel to the surface model: no direction to go
        uc = min(max(uc + np.sign(duv[0]) * su, 0.0), W - 1.0)
        vc = min(max(vc + np.sign(duv[1]) * sv, 0.0), H - 1.0)
        su, sv = su / 2.0, sv / 2.0
    return (uc, vc), iterations, best, False


def _fpm_window_scan(camera: CameraModel, depth_at, xt: float, yt: float, u0: int, v0: int, win_du, win_dv,
                     tol_m: float, best: tuple):
    """FPM step 2 for one stud: the brute-force window around (u0, v0), offsets in scan order,
    until a pixel lands within ``tol_m``. Returns (pixels evaluated, any had depth, best, found)."""
    H, W = camera.height, camera.width
    iterations, window_depth = 0, False
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
            return iterations, window_depth, best, True
    return iterations, window_depth, best, False
