"""Gun clearance: would the welding gun touch the part on its way along a stud's normal?

The gun approaches a stud along the surface normal, descends to it and retracts the same way,
so the volume it sweeps is a cylinder about the stud's axis: from the surface out to the gun's
top at the approach pose. On a convex part nothing of the part enters it; on a concave one (the
inside of a shell, a saddle) or next to a stiffener, web or flange, the part can. The check uses
what the camera saw: every depth pixel whose 3D point (Eq. 1) lies inside that cylinder, higher
than ``margin_m`` above the stud along the axis (the surface the gun stands on rises a little
under its foot on a concave part), is part of the part in the gun's way.

What the depth image does not show (holes, surfaces hidden from the camera) cannot be checked:
the result says how many samples it saw.

Frames and units: `world`, metres; the cylinder's axis is the unit outward normal.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stud_perception.camera_model import CameraModel
from stud_planner.matching.surface_pose import tangent_basis


@dataclass(frozen=True)
class GunModel:
    """The volume the gun sweeps about a stud's axis (metres).

    ``radius_m``: the gun's radius about the stud (body, foot, spark shield), ``length_m``: from
    the surface to the gun's top at the approach pose (gun length plus the approach standoff),
    ``margin_m``: how far above the weld point, along the axis, the part may rise under the gun (a
    concave part rises under its foot: 3.8 mm at 30 mm on a 120 mm radius; the depth noise on top).
    """

    radius_m: float = 0.03
    length_m: float = 0.30
    margin_m: float = 0.008

    def __post_init__(self) -> None:
        if not (self.radius_m > 0 and self.length_m > self.margin_m >= 0):
            raise ValueError(f"gun model needs radius_m > 0 and length_m > margin_m >= 0, got {self}")


@dataclass(frozen=True)
class Clearance:
    """Per stud (N,): ``clearance_m`` the distance from the gun's side to the nearest point of the
    part inside its length (negative: that far inside the gun; when nothing rises beside the stud,
    the farthest distance checked, a lower bound), ``along_m`` that point's height up the axis,
    ``samples`` depth points checked; NaN / 0 where nothing was checked."""

    clearance_m: np.ndarray
    along_m: np.ndarray
    samples: np.ndarray

    @property
    def blocked(self) -> np.ndarray:
        return np.isfinite(self.clearance_m) & (self.clearance_m < 0)


_RING = np.array([[1, 0], [-1, 0], [0, 1], [0, -1], [0.7071, 0.7071], [-0.7071, 0.7071], [0.7071, -0.7071],
                  [-0.7071, -0.7071]])


def _sampled_clearance(p, nrm, depth, camera: CameraModel, gun: GunModel, z_top_w: float, k: int):
    """Clearance, height along the axis of the nearest point and samples (n,) of n studs at
    weld points ``p`` (n, 3) with normals ``nrm`` (n, 3), on a k x k grid over each cylinder's image box."""
    length = np.full(len(p), gun.length_m)
    up = nrm[:, 2] > 1e-3
    length[up] = np.clip((z_top_w - p[up, 2]) / nrm[up, 2] + gun.radius_m, gun.margin_m, gun.length_m)
    t1, t2 = tangent_basis(nrm)
    offsets = gun.radius_m * (_RING[None, :, :1] * t1[:, None, :] + _RING[None, :, 1:] * t2[:, None, :])
    corners = np.concatenate([p[:, None] + offsets, (p + length[:, None] * nrm)[:, None] + offsets], axis=1)
    u, v, zc = camera.world_to_pixel(corners)
    seen = np.all(np.isfinite(u) & np.isfinite(v), axis=1)
    W, H = camera.width, camera.height
    u_lo, u_hi = np.clip(np.fmin.reduce(u, axis=1), 0, W - 1), np.clip(np.fmax.reduce(u, axis=1), 0, W - 1)
    v_lo, v_hi = np.clip(np.fmin.reduce(v, axis=1), 0, H - 1), np.clip(np.fmax.reduce(v, axis=1), 0, H - 1)
    g = np.linspace(0.0, 1.0, k)
    gu, gv = np.meshgrid(g, g)
    U = np.rint(u_lo[:, None] + gu.ravel()[None, :] * (u_hi - u_lo)[:, None])
    V = np.rint(v_lo[:, None] + gv.ravel()[None, :] * (v_hi - v_lo)[:, None])
    d = np.take(depth.reshape(-1), (V * W + U).astype(np.int64)).astype(np.float64)
    have = seen[:, None] & np.isfinite(d) & (d > 0)
    d[~have] = 0.0
    s, rho = _axial_radial(camera, U, V, d, p, nrm)  # relative to the weld points
    inside_length = have & (s > gun.margin_m) & (s < gun.length_m)
    # The nearest point counts only with two more beside it: a flying pixel or a noise spike alone
    # does not block a stud (a wall, a stiffener, a neighbour's body gives many). Only the studs
    # with three points in the gun's length need the third nearest.
    clear = np.max(np.where(have, rho, -np.inf), axis=1)  # nothing rises beside the stud: at least what was seen
    along = np.full(len(p), np.nan)
    kth = min(2, d.shape[1] - 1)
    crowded = np.flatnonzero(np.count_nonzero(inside_length, axis=1) > kth)
    if crowded.size:
        rho_in = np.where(inside_length[crowded], rho[crowded], np.inf)
        third = np.argpartition(rho_in, kth, axis=1)[:, kth]
        clear[crowded] = rho[crowded, third]
        along[crowded] = s[crowded, third]
    clear -= gun.radius_m
    counted = have.any(axis=1)
    return np.where(counted, clear, np.nan), np.where(counted, along, np.nan), have.sum(axis=1)


def _axial_radial(camera: CameraModel, U: np.ndarray, V: np.ndarray, d: np.ndarray, p: np.ndarray, nrm: np.ndarray):
    """Eq. 1 of pixels (U, V) (n, M) at depths d, relative to the weld points p (n, 3): the height
    s along each unit axis ``nrm`` (n, 3) and the distance rho from it, (n, M) each. Component by
    component (the ray is linear in the pixel), no (3, n, M) array."""
    base, per_u, per_v = camera.ray_basis_world()  # Eq. 1's ray, linear in the pixel
    origin = camera.t_wc - p  # (n, 3)
    s = np.zeros(d.shape)
    xx = np.zeros(d.shape)
    x = np.empty(d.shape)
    tmp = np.empty(d.shape)
    for i in range(3):
        np.multiply(U, per_u[i], out=x)
        np.multiply(V, per_v[i], out=tmp)
        x += tmp
        x += base[i]
        x *= d
        x += origin[:, i, None]
        np.multiply(x, nrm[:, i, None], out=tmp)
        s += tmp
        np.multiply(x, x, out=tmp)
        xx += tmp
    xx -= s * s
    return s, np.sqrt(np.maximum(xx, 0.0, out=xx), out=xx)


def gun_clearance(points_w: np.ndarray, normals_w: np.ndarray, depth_m: np.ndarray, camera: CameraModel,
                  gun: GunModel = GunModel(), valid: np.ndarray | None = None, z_top_w: float = np.inf,
                  samples_per_side: int = 32, coarse_per_side: int = 12, sure_clear_m: float = 0.015,
                  chunk: int = 512) -> Clearance:
    """The gun's clearance at N studs: weld points ``points_w`` (N, 3) with unit outward normals
    ``normals_w`` (N, 3), against the depth image ``depth_m`` (H, W, metres, NaN = none).

    The image box the cylinder projects to is sampled on a square grid per stud (vectorised over
    studs, in chunks): first ``coarse_per_side``, then ``samples_per_side`` for the studs the
    coarse look does not find clear by more than ``sure_clear_m`` (a coarse grid can only
    overestimate the clearance, and only by its spacing: a few mm). Only the part of the cylinder
    below ``z_top_w``, the highest world z the view shows (e.g. from
    :func:`stud_planner.matching.matchers.observed_z_range`), can meet the part, and only that part is
    projected (the rest may reach behind the camera).
    """
    P = np.asarray(points_w, dtype=np.float64).reshape(-1, 3)
    N = np.asarray(normals_w, dtype=np.float64).reshape(-1, 3)
    n = P.shape[0]
    ok = np.all(np.isfinite(P), axis=1) & np.all(np.isfinite(N), axis=1)
    if valid is not None:
        ok &= np.asarray(valid, dtype=bool)
    clearance = np.full(n, np.nan)
    along = np.full(n, np.nan)
    samples = np.zeros(n, dtype=np.int64)
    depth = np.asarray(depth_m)
    idx = np.flatnonzero(ok)
    for k, pick in ((coarse_per_side, None), (samples_per_side, "refine")):
        if pick == "refine":
            idx = idx[~(clearance[idx] > sure_clear_m)]
        for start in range(0, idx.size, chunk):
            j = idx[start:start + chunk]
            clearance[j], along[j], samples[j] = _sampled_clearance(P[j], N[j], depth, camera, gun, z_top_w, k)
    return Clearance(clearance_m=clearance, along_m=along, samples=samples)


__all__ = ["Clearance", "GunModel", "gun_clearance"]
