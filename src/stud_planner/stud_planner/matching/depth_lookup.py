"""The batch matcher's depth look-ups: bilinear samples, holes filled where a sample touches one, steps respected.

The hole rule and the safe bilinear sampler live in :mod:`stud_perception.depth_image`; here only
the policy for a sample that touches a hole or a depth step, and the per-frame cache of filled pixels.
"""
from __future__ import annotations

import numpy as np

from stud_perception.depth_image import FillRule, SampleStatus, fill_holes_at, sample_depth_bilinear

#: Up to this many new pixels in one call, the holes around them are filled with them (see
#: :meth:`PixelFills._with_holes_around`); beyond, the per-pixel cost of filling dominates.
PREFETCH_BELOW = 128
PREFETCH_RADIUS_PX = 2


class PixelFills:
    """:func:`~stud_perception.depth_image.fill_depth_at` of integer pixels of one depth image, each computed once.

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

    def _with_holes_around(self, new: np.ndarray, flat: np.ndarray, W: int) -> np.ndarray:
        """``new`` (sorted linear indices) and the hole pixels not yet known within
        :data:`PREFETCH_RADIUS_PX` of its holes: a stud's next look-ups land a pixel or two away,
        and filling them now saves a call of :func:`fill_depth_at` (whose fixed cost is what few
        studs pay). Filled values depend on the pixel alone, so this changes no result."""
        holes = new[~(flat[new] > 0)]  # NaN compares False
        if holes.size == 0:
            return new
        H = flat.size // W
        r = np.arange(-PREFETCH_RADIUS_PX, PREFETCH_RADIUS_PX + 1)
        hu, hv = holes % W, holes // W
        shape = (holes.size, r.size, r.size)
        U = np.broadcast_to(hu[:, None, None] + r[None, None, :], shape).ravel()
        V = np.broadcast_to(hv[:, None, None] + r[None, :, None], shape).ravel()
        inside = (U >= 0) & (U < W) & (V >= 0) & (V < H)
        near = V[inside] * W + U[inside]
        near = np.unique(near[~(flat[near] > 0)])
        if self._keys.size:
            pos = np.minimum(np.searchsorted(self._keys, near), self._keys.size - 1)
            near = near[self._keys[pos] != near]
        return np.union1d(new, near)

    def __call__(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(depth_m, FillRule int8, spread_m) at in-image integer pixels (u, v), any shape."""
        W = self._depth_m.shape[1]
        lin = v * W + u
        pos = np.minimum(np.searchsorted(self._keys, lin), max(self._keys.size - 1, 0))
        known = (self._keys[pos] == lin) if self._keys.size else np.zeros(lin.shape, dtype=bool)
        new = np.unique(lin[~known])
        if new.size:
            flat = self._depth_m.reshape(-1)
            if new.size <= PREFETCH_BELOW:
                new = self._with_holes_around(new, flat, W)
            value = flat[new].astype(np.float64)
            rule = np.full(new.size, FillRule.DIRECT, dtype=np.int8)
            spread = np.zeros(new.size)
            hole = np.flatnonzero(~(value > 0))  # NaN compares False
            if hole.size:
                f = fill_holes_at(self._depth_m, new[hole] % W, new[hole] // W, window=self._window,
                                  max_window=self._max_window)
                value[hole], rule[hole], spread[hole] = f.depth_m, f.rule, f.spread_m
            keys = np.concatenate([self._keys, new])
            order = np.argsort(keys, kind="stable")
            self._keys = keys[order]
            self._value = np.concatenate([self._value, value])[order]
            self._rule = np.concatenate([self._rule, rule])[order]
            self._spread = np.concatenate([self._spread, spread])[order]
            pos = np.searchsorted(self._keys, lin)
        return self._value[pos], self._rule[pos], self._spread[pos]


_CORNER_DU = np.array([0, 1, 0, 1])
_CORNER_DV = np.array([0, 0, 1, 1])


def depth_at_subpixel(
    depth_m: np.ndarray, u: np.ndarray, v: np.ndarray, window_px: int, max_window_px: int, discontinuity_m: float,
    fills: PixelFills | None = None,
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
    z = s.depth_m  # float64, the sample's own array
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
    cu = u0[:, None] + _CORNER_DU  # corners (u0, v0), (u0 + 1, v0), (u0, v0 + 1), (u0 + 1, v0 + 1)
    cv = v0[:, None] + _CORNER_DV
    w = (np.where(_CORNER_DU, fu[:, None], (1 - fu)[:, None])
         * np.where(_CORNER_DV, fv[:, None], (1 - fv)[:, None]))  # bilinear weights
    if fills is None:
        fills = PixelFills(depth_m, window_px, max_window_px)
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

