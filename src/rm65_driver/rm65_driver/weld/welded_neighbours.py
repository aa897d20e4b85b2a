"""Studs already welded as obstacles for the gun's foot at the next stud.

A welded stud stands ``stud_length_m`` out of the surface along its own normal. Welding another
stud, the gun's foot (the ferrule grip and the chuck around the new stud) comes down along that
stud's normal to the surface, so for the last ``stud_length_m`` + clearance of its travel it passes
beside every welded neighbour. The foot needs ``min_spacing_m`` of room around its axis there (its
radius, the stud head's and a margin: a property of the gun and the stud, set by the cell).

Both are segments: the welded stud from its base to its top, the foot's axis from the new stud's base
up to the welded studs' height plus the clearance. On a convex part (a dome) the tops lean apart, on
a concave one (a trough) they lean together: the segments' closest distance counts, not the bases'.
Pure numpy, metres, `world` frame.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np


@dataclass(frozen=True)
class WeldedNeighbour:
    """The welded stud nearest the gun's foot at a stud: its id and the distance between the axes (m)."""

    stud_id: str
    distance_m: float


def segment_distances(a0: np.ndarray, a1: np.ndarray, b0: np.ndarray, b1: np.ndarray) -> np.ndarray:
    """The closest distance (n,) between segment a0-a1 (3,) and each segment b0[k]-b1[k] (n, 3);
    a segment may be a point."""
    a0, a1 = np.asarray(a0, dtype=np.float64), np.asarray(a1, dtype=np.float64)
    b0, b1 = np.atleast_2d(np.asarray(b0, dtype=np.float64)), np.atleast_2d(np.asarray(b1, dtype=np.float64))
    d1, d2, r = a1 - a0, b1 - b0, a0 - b0  # (3,), (n, 3), (n, 3)
    aa, ee = float(d1 @ d1), np.einsum("ij,ij->i", d2, d2)
    ff, bb, cc = np.einsum("ij,ij->i", d2, r), d2 @ d1, r @ d1
    eps = 1e-18
    # s along a, t along b (Ericson, Real-Time Collision Detection, 5.1.9), clamped to the segments.
    with np.errstate(invalid="ignore", divide="ignore"):
        if aa <= eps:  # a is a point
            s = np.zeros(len(b0))
        else:
            denom = aa * ee - bb * bb
            s = np.where(ee <= eps, -cc / aa, np.where(denom > eps, (bb * ff - cc * ee) / denom, 0.0))
            s = np.clip(s, 0.0, 1.0)
        t = np.where(ee > eps, (bb * s + ff) / ee, 0.0)
        t_in = np.clip(t, 0.0, 1.0)
        if aa > eps:  # t clamped to an end of b: s again, for that end
            s = np.where(t != t_in, np.clip((bb * t_in - cc) / aa, 0.0, 1.0), s)
    p = a0 + s[:, None] * d1
    q = b0 + t_in[:, None] * d2
    return np.linalg.norm(p - q, axis=1)


def nearest_welded(position: np.ndarray, normal: np.ndarray, welded: Sequence[tuple[str, np.ndarray, np.ndarray]],
                   stud_length_m: float, clearance_m: float) -> WeldedNeighbour | None:
    """The welded stud (id, base position (3,), unit normal (3,)) nearest the gun's foot welding a stud at
    ``position`` along ``normal``; None without welded studs."""
    if not welded:
        return None
    n = np.asarray(normal, dtype=np.float64)
    base = np.asarray(position, dtype=np.float64)
    foot_top = base + (stud_length_m + clearance_m) * n
    P = np.array([w[1] for w in welded], dtype=np.float64).reshape(-1, 3)
    N = np.array([w[2] for w in welded], dtype=np.float64).reshape(-1, 3)
    d = segment_distances(base, foot_top, P, P + stud_length_m * N)
    k = int(np.argmin(d))
    return WeldedNeighbour(welded[k][0], float(d[k]))


__all__ = ["WeldedNeighbour", "nearest_welded", "segment_distances"]
