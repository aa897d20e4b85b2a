"""The weld collar (flash) of a welded stud, measured from the shots before and after the weld.

A drawn-arc stud weld leaves a ring of weld metal around the stud's base, shaped by the ceramic
ferrule: the collar. The codes ask for it all around (360 deg) and, GB 50205, at least 1 mm high; a
gap is the mark of arc blow or a cold side. The collar is a few millimetres high, too low for the
stud's own test ("came 5 mm closer"), so it is measured per pixel: the same pixel of the two shots
(one camera pose) sees the collar's top after the weld and the part's surface behind it before, and
``(X_after - X_before) . n`` -- the two points lie on one ray -- is how high the collar stands above
the surface there, exact on a plane and to a few hundredths of a millimetre on a curved part over
the 10 mm of a collar.

Around the stud's measured base, in the plane across the surface normal, the ring
``collar_search_from_mm`` .. ``collar_search_to_mm`` beyond the stud's surface is cut into
``collar_sectors`` sectors; a sector is *seen* when enough of its pixels show the ring (not the
stud's side in front of it, not a hole), and *covered* when their median height reaches
``min_collar_height_mm``. A camera that sees the stud from aside cannot see the collar behind it: up
to a third of the ring on a part's slope. That part is *unseen*, reported as such
(``collar_seen_deg``), never counted as covered or as a gap.

Frames and units: `world`, metres in; degrees and millimetres out. No ROS here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from stud_common.rotations import frame_from_normal
from stud_perception.camera_model import CameraModel


@dataclass(frozen=True)
class CollarSettings:
    """How the collar is looked for: the ring searched, ``from_mm`` .. ``to_mm`` beyond the stud's
    surface (inside any real collar: an M16's is 2.5-3.5 mm wide), cut in ``sectors``; a sector needs
    ``min_points`` pixels to be seen; heights above ``max_height_mm`` are not collar (the stud's side,
    a neighbour)."""

    from_mm: float = 1.0
    to_mm: float = 2.5
    sectors: int = 36
    min_points: int = 8
    max_height_mm: float = 12.0

    def __post_init__(self) -> None:
        if not (0 <= self.from_mm < self.to_mm and self.sectors >= 4 and self.min_points >= 1
                and self.max_height_mm > 0):
            raise ValueError(f"collar search {self}: expected 0 <= from_mm < to_mm, sectors >= 4, min_points >= 1, "
                             "max_height_mm > 0")


@dataclass(frozen=True)
class CollarMeasurement:
    """One stud's collar: the degrees of the circle seen and, of those, covered by a collar of at least
    the minimum height; its height (median over the covered sectors, mm; None when none is); the
    largest gap seen (degrees) and its centre's azimuth in the tangent frame of the surface normal
    (stud_common.rotations.frame_from_normal; None without a gap); the per-sector median heights
    (mm, NaN where unseen), sector k spanning azimuths [k, k+1) * 360 / sectors - 180 deg."""

    seen_deg: float
    covered_deg: float
    height_mm: float | None
    gap_deg: float
    gap_azimuth_deg: float | None
    sector_heights_mm: tuple[float, ...]

    @property
    def uncovered_seen_deg(self) -> float:
        return self.seen_deg - self.covered_deg


def _sector_height(h_mm: np.ndarray) -> float:
    """One sector's collar height from its points' heights: a trimmed mean (a fifth off each end) --
    robust to a stray point, and finer than the depth's millimetre steps, which a median is not."""
    h = np.sort(h_mm)
    cut = h.size // 5
    return float(np.mean(h[cut:h.size - cut]))


def _largest_run(mask: np.ndarray) -> tuple[int, int]:
    """(start, length) of the longest circular run of True in ``mask`` (length 0: none)."""
    n = len(mask)
    if mask.all():
        return 0, n
    best = (0, 0)
    start = int(np.argmin(mask))  # a False: runs never wrap past it
    run = 0
    for k in range(1, n + 1):
        i = (start + k) % n
        if mask[i]:
            run += 1
            if run > best[1]:
                best = ((i - run + 1) % n, run)
        else:
            run = 0
    return best


def measure_collar(before_m: np.ndarray, after_m: np.ndarray, camera: CameraModel, base_w, axis_w, normal_w,
                   stud_radius_m: float, min_height_mm: float,
                   settings: CollarSettings = CollarSettings()) -> CollarMeasurement:
    """The collar around a stud whose base is ``base_w`` (3,) and axis ``axis_w`` (3,, unit), on a surface
    of unit normal ``normal_w`` (3,), from the depth of the same camera pose before and after the weld
    ((H, W) metres, NaN = none)."""
    b = np.asarray(base_w, dtype=np.float64).reshape(3)
    a = np.asarray(axis_w, dtype=np.float64).reshape(3)
    R = frame_from_normal(np.asarray(normal_w, dtype=np.float64).reshape(3))
    e1, e2, n = R[:, 0], R[:, 1], R[:, 2]
    r_from = stud_radius_m + settings.from_mm * 1e-3
    r_to = stud_radius_m + settings.to_mm * 1e-3
    ring = np.array([[math.cos(t), math.sin(t)] for t in np.linspace(0, 2 * math.pi, 16, endpoint=False)])
    disc = b + (r_to + 0.002) * ring @ np.vstack([e1, e2])
    u, v, z = camera.world_to_pixel(np.vstack([disc, disc + settings.max_height_mm * 1e-3 * n]))
    empty = CollarMeasurement(0.0, 0.0, None, 0.0, None, (math.nan,) * settings.sectors)
    if np.any(z <= 0) or not np.all(np.isfinite(u)):
        return empty
    h_img, w_img = after_m.shape
    u0, u1 = max(int(math.floor(u.min())), 0), min(int(math.ceil(u.max())) + 1, w_img)
    v0, v1 = max(int(math.floor(v.min())), 0), min(int(math.ceil(v.max())) + 1, h_img)
    if u0 >= u1 or v0 >= v1:
        return empty
    bef, aft = before_m[v0:v1, u0:u1], after_m[v0:v1, u0:u1]
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(bef) & np.isfinite(aft) & (bef > 0) & (aft > 0)
    vv, uu = np.nonzero(ok)
    if not vv.size:
        return empty
    uu, vv = (uu + u0).astype(np.float64), (vv + v0).astype(np.float64)
    Xa = camera.pixel_to_world(uu, vv, aft[ok])
    Xb = camera.pixel_to_world(uu, vv, bef[ok])
    height = (Xa - Xb) @ n  # the point above the surface behind it, along the normal (same ray)
    q = Xa - b
    q_t = q - np.outer(q @ n, n)
    rho = np.linalg.norm(q_t, axis=1)
    off_axis = np.linalg.norm(q - np.outer(q @ a, a), axis=1)  # the stud's side lies at its radius from the axis
    keep = ((rho >= r_from) & (rho <= r_to) & (off_axis >= r_from) & (height <= settings.max_height_mm * 1e-3)
            & (height >= -settings.max_height_mm * 1e-3))
    phi = np.arctan2(q_t[keep] @ e2, q_t[keep] @ e1)
    k = settings.sectors
    sector = np.clip(((phi + math.pi) / (2 * math.pi) * k).astype(int), 0, k - 1)
    heights_mm = height[keep] * 1e3
    med = np.full(k, math.nan)
    for i in range(k):
        h_i = heights_mm[sector == i]
        if h_i.size >= settings.min_points:
            med[i] = _sector_height(h_i)
    seen = np.isfinite(med)
    covered = seen & (med >= min_height_mm)
    step = 360.0 / k
    start, length = _largest_run(seen & ~covered)
    gap_az = None
    if length:
        centre = (start + length / 2) * step - 180.0
        gap_az = float((centre + 180.0) % 360.0 - 180.0)
    return CollarMeasurement(seen_deg=float(seen.sum() * step), covered_deg=float(covered.sum() * step),
                             height_mm=float(np.median(med[covered])) if covered.any() else None,
                             gap_deg=float(length * step), gap_azimuth_deg=gap_az,
                             sector_heights_mm=tuple(float(x) for x in med))


__all__ = ["CollarMeasurement", "CollarSettings", "measure_collar"]
