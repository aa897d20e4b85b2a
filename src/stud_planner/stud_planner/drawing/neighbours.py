"""Neighbour search by grid hash (O(N) for sane spacing): duplicates and close stud pairs."""
from __future__ import annotations

import numpy as np

__all__ = ["TooDenseError", "close_pairs"]


class TooDenseError(Exception):
    """More candidate pairs than :func:`close_pairs` examines (``args[0]``: how many): the points are
    far denser than the radius (a drawing in metres read as mm puts everything in one cell)."""


def close_pairs(xy: np.ndarray, radius: float,
                max_candidates: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Index pairs (i < j) of points closer than ``radius``, and their distances.

    Grid hash with cell = radius: each point is compared with its own cell and four forward
    neighbours only. Raises :class:`TooDenseError` when more than ``max_candidates`` candidate pairs
    would be examined (e.g. a drawing in metres read as mm puts everything in one cell).
    """
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    n = xy.shape[0]
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0))
    if n < 2 or not radius > 0:
        return empty
    if max_candidates is None:
        max_candidates = 50 * n + 1_000_000
    lo = xy.min(axis=0)
    span = float(np.max(xy.max(axis=0) - lo))
    cell_size = max(radius, span / 1e8)  # keeps the cell keys inside int64
    cells = np.floor((xy - lo) / cell_size).astype(np.int64) + 1
    ny = int(cells[:, 1].max()) + 3
    key = cells[:, 0] * ny + cells[:, 1]
    order = np.argsort(key, kind="stable")
    skey = key[order]
    idx = np.arange(n)
    out_i, out_j, out_d = [], [], []
    for dx, dy in ((0, 0), (1, -1), (1, 0), (1, 1), (0, 1)):
        nkey = key + dx * ny + dy
        first = np.searchsorted(skey, nkey, "left")
        count = np.searchsorted(skey, nkey, "right") - first
        total = int(count.sum())
        if total > max_candidates:
            raise TooDenseError(total)
        if total == 0:
            continue
        ii = np.repeat(idx, count)
        offsets = np.arange(total) - np.repeat(np.cumsum(count) - count, count)
        jj = order[np.repeat(first, count) + offsets]
        if dx == 0 and dy == 0:
            keep = ii < jj
            ii, jj = ii[keep], jj[keep]
        d = np.hypot(*(xy[ii] - xy[jj]).T)
        near = d < radius
        out_i.append(ii[near])
        out_j.append(jj[near])
        out_d.append(d[near])
    if not out_i:
        return empty
    i, j, d = np.concatenate(out_i), np.concatenate(out_j), np.concatenate(out_d)
    swap = i > j
    i[swap], j[swap] = j[swap], i[swap]
    return i, j, d
