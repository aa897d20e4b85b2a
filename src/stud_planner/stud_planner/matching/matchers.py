"""Stud matchers: find where each stud's planar world position meets the observed surface.

A stud's planar world position (x_w, y_w) is known from the registered drawing, its height
is not. The weld point is where the world vertical line L = {(x_w, y_w, z)} meets the surface
seen in the depth image. Three matchers, one result type (:class:`MatchResults`):

- :func:`match_bfs` -- the paper's brute-force baseline: every pixel in row-major order until
  the back-projected XY (Eq. 1) is within ``tol_m`` of the target. Per-pixel Python on purpose.
- :func:`match_fpm` -- the paper's fast positioning method: quadrant search from the image
  centre (Eq. 3-6), then a 25x25 brute-force window, with the quadrant rule generalised to any
  camera yaw/tilt. Per-pixel Python on purpose (a faithful baseline).
- :func:`match_batch` -- ours: all studs of a frame at once, vectorised over studs. Solves
  h(pi(x_w, y_w, z)) = z for z along L by a safeguarded secant iteration on bilinearly sampled
  depth, i.e. a handful of depth look-ups per stud, sub-pixel, any camera orientation.

This module is the public import path of all three and of the shared types. Where they live:
the result types, input checks and height ranges in :mod:`stud_planner.matching.match_common`,
the paper's baselines in :mod:`stud_planner.matching.paper_baselines`, the batch matcher's depth
look-ups (holes, steps) in :mod:`stud_planner.matching.depth_lookup`, the batch matcher here.

Frames and units: ``targets_xy_w`` (N, 2) metres in `world` (the arm's base frame, z up; the part
may lie at any height in it: the heights searched come from the depth image, :func:`observed_z_range`);
``depth_m`` (H, W) float32 metres of optical-frame z, NaN = invalid (REP 118), indexed
``[v, u]``; pixels (u, v) are column/row. Eq. 1 and its inverse are only ever evaluated through
:class:`stud_perception.camera_model.CameraModel`.
"""
from __future__ import annotations

import math

import numpy as np

from stud_perception.camera_model import CameraModel, VerticalLines
from stud_perception.depth_image import FillRule
from stud_planner.matching.depth_lookup import PixelFills, depth_at_subpixel
from stud_planner.matching.match_common import (
    Z_RANGE_MARGIN_M,
    MatchingError,
    MatchResult,
    MatchResults,
    MatchStatus,
    check_inputs,
    empty_results,
    line_in_view_z_interval,
    observed_z_range,
)
from stud_planner.matching.paper_baselines import match_bfs, match_fpm, xy_jacobian_at_height


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
    xy, depth = check_inputs(targets_xy_w, depth_m, camera)
    n = xy.shape[0]
    out = empty_results("batch", n)
    if z_range_m is None or z_init_m is None:
        z_min, z_max, z_mid = observed_z_range(depth, camera)
        z_range_m = z_range_m or (z_min, z_max)
        z_init_m = z_mid if z_init_m is None else z_init_m
    lines = camera.vertical_lines(xy)
    zlo, zhi = camera.lines_in_view(lines, z_range_m[0], z_range_m[1], 1e-3)
    in_view = zlo <= zhi
    out["status"][~in_view] = MatchStatus.OUT_OF_VIEW
    active = np.flatnonzero(in_view)
    if active.size:
        search = _SecantSearch(xy, depth, camera, lines, out, zlo, zhi, tol_m=tol_m, converge_xy_m=converge_xy_m,
                               z_bracket_tol_m=z_bracket_tol_m, hole_window_px=hole_window_px,
                               hole_max_window_px=hole_max_window_px, discontinuity_m=discontinuity_m)
        search.run(active, z_init_m, max_lookups)
    return MatchResults(**out)


#: From this many studs still searching down, :class:`_SecantSearch` takes them one at a time.
_ONE_BY_ONE = 4


class _SecantSearch:
    """The state of :func:`match_batch`'s search over the studs of one frame: the result arrays
    ``out`` it fills in, each stud's bracket [lo_b, hi_b] of heights (g > 0 below the surface,
    g < 0 above) with g there, and whether its last sample straddled a depth step."""

    def __init__(self, xy: np.ndarray, depth: np.ndarray, camera: CameraModel, lines: VerticalLines, out: dict,
                 zlo: np.ndarray, zhi: np.ndarray, *, tol_m: float, converge_xy_m: float, z_bracket_tol_m: float,
                 hole_window_px: int, hole_max_window_px: int, discontinuity_m: float) -> None:
        n = xy.shape[0]
        self.xy, self.depth, self.camera, self.out, self.zlo, self.zhi = xy, depth, camera, out, zlo, zhi
        self.tol_m, self.converge_xy_m, self.z_bracket_tol_m = tol_m, converge_xy_m, z_bracket_tol_m
        self.hole_window_px, self.hole_max_window_px, self.discontinuity_m = (hole_window_px, hole_max_window_px,
                                                                              discontinuity_m)
        self.fills = PixelFills(depth, hole_window_px, hole_max_window_px)
        self.lookup = 0  # look-ups so far; a stud takes part in every one from the first until it settles
        self.lo_b = np.full(n, -np.inf)  # highest z seen with g > 0 (the surface is above it)
        self.hi_b = np.full(n, np.inf)  # lowest z seen with g < 0
        self.g_lo = np.full(n, np.nan)  # g at lo_b / hi_b, to measure a jump of g when the bracket collapses
        self.g_hi = np.full(n, np.nan)
        self.on_step = np.zeros(n, dtype=bool)
        self.lines = lines  # each stud's pixel is projective in its height z: a few operations a look-up

    def run(self, idx: np.ndarray, z_init_m: float, max_lookups: int) -> None:
        """Search studs ``idx`` from the height ``z_init_m``: a plain fixed-point step first, then
        safeguarded secant steps, up to ``max_lookups`` look-ups in all; every stud settled."""
        zlo, zhi = self.zlo, self.zhi
        z_prev = np.clip(z_init_m, zlo[idx], zhi[idx])
        _, idx, z_prev, g_prev = self.step_and_settle(idx, z_prev)
        z_cur = np.clip(z_prev + g_prev, zlo[idx], zhi[idx])  # plain fixed point as the first step
        for k in range(max_lookups - 1):
            if idx.size == 0:
                break
            if idx.size <= _ONE_BY_ONE:  # the last few studs: plain floats, a look-up each costs ~10x less
                for i, zp, gp, zc in zip(idx.tolist(), z_prev.tolist(), g_prev.tolist(), z_cur.tolist()):
                    self._finish_one(i, zp, gp, zc, max_lookups - 1 - k)
                return
            keep, idx, z_cur, g_cur = self.step_and_settle(idx, z_cur)
            z_prev, g_prev = z_prev[keep], g_prev[keep]
            if idx.size == 0:
                break
            idx, z_prev, g_prev, z_cur = self.secant_step(idx, z_prev, g_prev, z_cur, g_cur)
        # Out of look-ups: usable if within the paper's tolerance, unless on a depth step.
        if idx.size:
            self.out["status"][idx] = self.usable(idx)

    # -- the last few studs, one at a time: the same steps as the vectorised ones, on Python floats
    # (IEEE doubles, the same operations in the same order: the same results), so that a stud that
    # needs a few more look-ups than the rest does not pay ~90 numpy calls for each.
    def _finish_one(self, i: int, z_prev: float, g_prev: float, z_cur: float, lookups: int) -> None:
        """Stud ``i`` from its last (z, g) and next height to settled, in at most ``lookups`` look-ups:
        :meth:`step_and_settle` and :meth:`secant_step` for one stud."""
        out, lookup = self.out, self.lookup
        for _ in range(lookups):
            lookup += 1
            g_cur, res, got = self._evaluate_one(i, z_cur, lookup)
            if not got:
                out["status"][i] = MatchStatus.NO_DEPTH
                return
            if res < self.converge_xy_m:
                out["status"][i] = self._usable_one(i)
                return
            if g_cur > 0 and z_cur >= self.lo_b[i]:
                self.lo_b[i], self.g_lo[i] = z_cur, g_cur
            elif g_cur < 0 and z_cur <= self.hi_b[i]:
                self.hi_b[i], self.g_hi[i] = z_cur, g_cur
            z_next, settled = self._secant_one(i, z_prev, g_prev, z_cur, g_cur)
            if settled is not None:
                out["status"][i] = settled
                return
            z_prev, g_prev, z_cur = z_cur, g_cur, z_next
        out["status"][i] = self._usable_one(i)  # out of look-ups

    def _usable_one(self, i: int) -> int:
        """:meth:`usable` of one stud."""
        if self.on_step[i]:
            return MatchStatus.DEPTH_DISCONTINUITY
        return MatchStatus.OK if self.out["xy_residual_m"][i] < self.tol_m else MatchStatus.NOT_CONVERGED

    def _evaluate_one(self, i: int, z: float, lookup: int) -> tuple[float, float, bool]:
        """:meth:`evaluate` of one stud at height z, as look-up number ``lookup``: (g, residual, had depth)."""
        cam, out = self.camera, self.out
        u, v = self.lines.pixel_at_one(i, z)
        u, v = min(max(u, 0.0), cam.width - 1.0), min(max(v, 0.0), cam.height - 1.0)
        d = self._easy_sample(u, v)
        rule, step = FillRule.DIRECT, False
        if d is None:  # a hole or a step: the vectorised rule, for this one sample
            dd, rr, ss = depth_at_subpixel(self.depth, np.array([u]), np.array([v]), self.hole_window_px,
                                           self.hole_max_window_px, self.discontinuity_m, self.fills)
            d, rule, step = float(dd[0]), FillRule(int(rr[0])), bool(ss[0])
        self.on_step[i] = step
        out["iterations"][i] = lookup
        if not math.isfinite(d):
            return math.nan, math.nan, False
        q = cam.pixel_to_world_one(u, v, d)  # Eq. 1
        res = float(np.hypot(q[0] - self.xy[i, 0], q[1] - self.xy[i, 1]))
        out["pixel_uv"][i] = (u, v)
        out["point_w"][i] = q
        out["xy_residual_m"][i], out["hole_rule"][i] = res, rule
        return float(q[2] - z), res, True

    def _easy_sample(self, u: float, v: float) -> float | None:
        """:func:`sample_depth_bilinear`'s plain case at an in-image (u, v): the bilinear depth when
        all four corners have depth within the step threshold, else None."""
        H, W = self.depth.shape
        u0, v0 = min(int(u), max(W - 2, 0)), min(int(v), max(H - 2, 0))
        fu, fv = u - u0, v - v0
        row0, row1 = self.depth[v0], self.depth[min(v0 + 1, H - 1)]
        u1 = min(u0 + 1, W - 1)
        z00, z01, z10, z11 = float(row0[u0]), float(row0[u1]), float(row1[u0]), float(row1[u1])
        if not (z00 > 0 and z01 > 0 and z10 > 0 and z11 > 0):  # NaN compares False
            return None
        if not max(z00, z01, z10, z11) - min(z00, z01, z10, z11) <= self.discontinuity_m:
            return None
        top = z00 + fu * (z01 - z00)
        bottom = z10 + fu * (z11 - z10)
        return top + fv * (bottom - top)

    def _secant_one(self, i: int, z_prev: float, g_prev: float, z_cur: float, g_cur: float):
        """:meth:`secant_step` of one stud: (next height, None) or (_, the status it settles with)."""
        denom = g_cur - g_prev
        secant = z_cur - g_cur * (z_cur - z_prev) / denom if denom != 0 else math.nan
        z_new = secant if (math.isfinite(secant) and abs(denom) > 1e-12) else z_cur + 0.5 * g_cur
        lo, hi = float(self.lo_b[i]), float(self.hi_b[i])
        bracketed = math.isfinite(lo) and math.isfinite(hi)
        if bracketed and (z_new <= min(lo, hi) or z_new >= max(lo, hi)):
            z_new = 0.5 * (lo + hi)
        z_new_c = min(max(z_new, float(self.zlo[i])), float(self.zhi[i]))
        if z_new_c != z_new and z_new_c == z_cur:  # pushed out of view again from the same border
            within = self.out["xy_residual_m"][i] < self.tol_m
            return z_new_c, (self._usable_one(i) if within else MatchStatus.OUT_OF_VIEW)
        if bracketed and abs(hi - lo) < self.z_bracket_tol_m:  # the bracket collapsed
            jump = (self.g_lo[i] - self.g_hi[i]) > self.discontinuity_m
            return z_new_c, (MatchStatus.DEPTH_DISCONTINUITY if jump else self._usable_one(i))
        return z_new_c, None

    def evaluate(self, idx: np.ndarray, z: np.ndarray):
        """One look-up for studs ``idx`` at heights ``z``: the pixel of (x_w, y_w, z), its depth, and
        g = height of Eq. 1 there - z; the latest sample with depth is stored in ``out``.
        Returns (g, XY residual, on a step, had depth), each over ``idx``."""
        camera, xy, out = self.camera, self.xy, self.out
        u, v = self.lines.pixels_at(idx, z)  # z is inside the in-view interval: in the image up to rounding
        u, v = np.clip(u, 0.0, camera.width - 1.0), np.clip(v, 0.0, camera.height - 1.0)
        d, rule, step = depth_at_subpixel(self.depth, u, v, self.hole_window_px, self.hole_max_window_px,
                                          self.discontinuity_m, self.fills)
        Q = camera.pixel_to_world(u, v, d)  # Eq. 1 at the sub-pixel
        g = Q[:, 2] - z
        res = np.hypot(Q[:, 0] - xy[idx, 0], Q[:, 1] - xy[idx, 1])
        self.lookup += 1
        out["iterations"][idx] = self.lookup
        got = np.isfinite(d)
        # Keep the latest sample that had depth; it is what the result reports.
        kept = (idx, u, v, Q, res, rule) if got.all() else (idx[got], u[got], v[got], Q[got], res[got], rule[got])
        j = kept[0]
        out["pixel_uv"][j, 0], out["pixel_uv"][j, 1] = kept[1], kept[2]
        out["point_w"][j], out["xy_residual_m"][j], out["hole_rule"][j] = kept[3:]
        return g, res, step, got

    def usable(self, j: np.ndarray) -> np.ndarray:
        """Status of finished studs j whose last sample had depth: OK within tol_m unless on a step."""
        within = self.out["xy_residual_m"][j] < self.tol_m
        return np.where(self.on_step[j], MatchStatus.DEPTH_DISCONTINUITY,
                        np.where(within, MatchStatus.OK, MatchStatus.NOT_CONVERGED)).astype(np.int8)

    def step_and_settle(self, idx: np.ndarray, z: np.ndarray):
        """One look-up at heights z for studs idx; settle the finished ones; return the rest's
        (keep mask over idx, idx, z, g)."""
        out, lo_b, hi_b, g_lo, g_hi = self.out, self.lo_b, self.hi_b, self.g_lo, self.g_hi
        g, res, step, got = self.evaluate(idx, z)
        self.on_step[idx] = step
        done = got & (res < self.converge_xy_m)
        keep = got & ~done
        if not keep.all():
            out["status"][idx[~got]] = MatchStatus.NO_DEPTH
            out["status"][idx[done]] = self.usable(idx[done])
            idx, z, g = idx[keep], z[keep], g[keep]
        up, down = g > 0, g < 0
        lo_b[idx[up]] = np.maximum(lo_b[idx[up]], z[up])
        g_lo[idx[up]] = np.where(lo_b[idx[up]] == z[up], g[up], g_lo[idx[up]])
        hi_b[idx[down]] = np.minimum(hi_b[idx[down]], z[down])
        g_hi[idx[down]] = np.where(hi_b[idx[down]] == z[down], g[down], g_hi[idx[down]])
        return keep, idx, z, g

    def secant_step(self, idx, z_prev, g_prev, z_cur, g_cur):
        """The next heights of studs ``idx`` from their last two (z, g): the secant, kept inside the
        bracket (bisection when it leaves it), clipped to the in-view interval; studs pinned at the
        image border or whose bracket collapsed are settled. Returns (idx, z_prev, g_prev, z_next)
        of the studs still searching."""
        out = self.out
        denom = g_cur - g_prev
        with np.errstate(divide="ignore", invalid="ignore"):
            secant = z_cur - g_cur * (z_cur - z_prev) / denom
        # Where the secant is undefined (two equal g), a damped fixed-point step.
        z_new = np.where(np.isfinite(secant) & (np.abs(denom) > 1e-12), secant, z_cur + 0.5 * g_cur)
        lo, hi = self.lo_b[idx], self.hi_b[idx]
        bracketed = np.isfinite(lo) & np.isfinite(hi)
        leaves = bracketed & ((z_new <= np.minimum(lo, hi)) | (z_new >= np.maximum(lo, hi)))
        z_new = np.where(leaves, 0.5 * (lo + hi), z_new)
        z_new_c = np.clip(z_new, self.zlo[idx], self.zhi[idx])
        # Pushed out of view again from the same border: the surface point is not in the image.
        at_border = (z_new_c != z_new) & (z_new_c == z_cur)
        # Bracket collapsed without convergence: g jumps over zero -- an occluding edge when the
        # jump is a depth step, else the best we can do on this depth.
        collapsed = bracketed & ~at_border & (np.abs(hi - lo) < self.z_bracket_tol_m)
        settled = at_border | collapsed
        if not settled.any():  # the usual case: nobody settles here (skip the bookkeeping)
            return idx, z_cur, g_cur, z_new_c
        j = idx[at_border]
        out["status"][j] = np.where(out["xy_residual_m"][j] < self.tol_m, self.usable(j), MatchStatus.OUT_OF_VIEW)
        j = idx[collapsed]
        jump = (self.g_lo[j] - self.g_hi[j]) > self.discontinuity_m
        out["status"][j] = np.where(jump, MatchStatus.DEPTH_DISCONTINUITY, self.usable(j))
        keep = ~settled
        return idx[keep], z_cur[keep], g_cur[keep], z_new_c[keep]

__all__ = ["MatchResult", "MatchResults", "MatchStatus", "MatchingError", "Z_RANGE_MARGIN_M",
           "line_in_view_z_interval", "match_batch", "match_bfs", "match_fpm", "observed_z_range",
           "xy_jacobian_at_height"]
