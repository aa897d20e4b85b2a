#!/usr/bin/env python3
"""Full weld poses side by side: ours against independent peer methods, on the same frame, one core.

Prints a table (a benchmark, not a test). The scene is a held-out-like one, not the demo's easy
view: the library dome (stud_perception.scene.demo_dome_scene, 50 mm high over 400 mm) on a grid of
N studs, seen by a 1280x960 camera 0.5 m away, yawed 35 deg and tilted 8 deg, with 0.5 mm depth
noise, 1 mm quantisation (16UC1) and 4 % holes. For each method and N: the wall time per frame (best
of ``--repeat``), the largest normal error against the exact truth over the visible studs, and the
coverage (visible studs given a usable pose).

Methods:
- ``ours full``: view_planning.plan_view -- match (batch) + normal + its uncertainty + status +
  the gun-clearance check; ``ours, no clearance``: the same without the clearance check;
  ``ours match only``: matching.match_batch (no normals).
- ``peer A``: two re-projections of the stud's vertical line at the image's median height, a 7x7
  mean of valid depths each (matching only);
- ``peer B``: peer A + normals from summed-area tables of the point moments (a PCA plane over a
  fixed 41x41 px window);
- ``peer C``: a scipy KD-tree over the back-projected cloud (every 2nd pixel) + PCA normals of
  the 10 mm neighbourhood of the nearest point to each stud's vertical line (needs scipy:
  ``pip install -r bench/requirements.txt``);
- ``FPM (paper)``: the paper's fast positioning method, per-pixel Python (17 and 100 studs only).

Usage: python bench/bench_poses.py [--sizes 17 100 1000 10000] [--repeat 3]
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
REPO = Path(__file__).resolve().parents[1]
for pkg in ("stud_perception", "stud_planner", "rm65_driver", "stud_common"):
    sys.path.insert(0, str(REPO / "src" / pkg))

import numpy as np  # noqa: E402

from stud_perception.scene import demo_dome_scene, grid_stud_scene, render, view_camera  # noqa: E402

try:  # the refactor moves these modules into subpackages; either layout works
    from stud_planner.matching.matchers import match_batch, match_fpm  # type: ignore  # noqa: E402
except ImportError:
    from stud_planner.matching import match_batch, match_fpm  # noqa: E402
try:
    from stud_planner.matching.view_targets import PlannerConfig, plan_view  # type: ignore  # noqa: E402
except ImportError:
    from stud_planner.view_planning import PlannerConfig, plan_view  # noqa: E402


def scene_and_view(n: int, seed: int = 7):
    scene = grid_stud_scene(n, demo_dome_scene(), extent_m=(0.26, 0.2))
    c = scene.component.centre_xy_m
    cam = view_camera((c[0], c[1], 0.0), 0.5, yaw_rad=math.radians(35.0), tilt_rad=math.radians(8.0),
                      tilt_azimuth_rad=math.radians(60.0))
    view = render(scene, cam, seed=seed, depth_noise_m=0.0005, hole_fraction=0.04)
    return scene, view


def _mean7(depth, u, v):
    """7x7 mean of valid depths around pixels (u, v) (float arrays), vectorised; NaN where none."""
    H, W = depth.shape
    ui, vi = np.rint(u).astype(int), np.rint(v).astype(int)
    ok = (ui >= 3) & (ui < W - 3) & (vi >= 3) & (vi < H - 3)
    off = np.arange(-3, 4)
    du, dv = np.meshgrid(off, off)
    U = np.clip(ui[:, None] + du.ravel(), 0, W - 1)
    V = np.clip(vi[:, None] + dv.ravel(), 0, H - 1)
    d = depth[V, U]
    with np.errstate(invalid="ignore"):
        m = np.nanmean(np.where(d > 0, d, np.nan), axis=1)
    return np.where(ok, m, np.nan)


def peer_a(xy, depth, cam):
    """Two re-projections of the vertical line at the median height, a 7x7 depth mean each."""
    valid = depth[np.isfinite(depth) & (depth > 0)]
    v0, u0 = np.array(depth.shape) // 2
    z = np.full(len(xy), float(cam.pixel_to_world(np.array([u0]), np.array([v0]), np.array([np.median(valid)]))[0, 2]))
    for _ in range(2):
        u, v, _ = cam.world_to_pixel(np.column_stack([xy, z]))
        d = _mean7(depth, u, v)
        P = cam.pixel_to_world(u, v, d)
        z = P[:, 2]
    u, v, _ = cam.world_to_pixel(np.column_stack([xy, z]))
    return np.column_stack([xy, z]), u, v


class _SatNormals:
    """Normals from summed-area tables of the point moments over a fixed pixel window (peer B)."""

    def __init__(self, depth, cam, half=20):
        H, W = depth.shape
        vv, uu = np.mgrid[0:H, 0:W]
        ok = np.isfinite(depth) & (depth > 0)
        P = cam.pixel_to_world(uu.astype(float), vv.astype(float), np.where(ok, depth, 0.0))
        P = P - np.nanmean(P[ok], axis=0)
        w = ok.astype(float)
        feats = [w] + [w * P[..., i] for i in range(3)] + [w * P[..., i] * P[..., j] for i in range(3)
                                                           for j in range(i, 3)]
        self.sat = [np.pad(f.cumsum(0).cumsum(1), ((1, 0), (1, 0))) for f in feats]
        self.half, self.H, self.W = half, H, W
        self.shift = np.nanmean(cam.pixel_to_world(uu.astype(float), vv.astype(float), np.where(ok, depth, 0.0))[ok],
                                axis=0)

    def normals(self, u, v, cam_pos):
        h = self.half
        u0 = np.clip(np.rint(u).astype(int) - h, 0, self.W)
        u1 = np.clip(np.rint(u).astype(int) + h + 1, 0, self.W)
        v0 = np.clip(np.rint(v).astype(int) - h, 0, self.H)
        v1 = np.clip(np.rint(v).astype(int) + h + 1, 0, self.H)
        s = [S[v1, u1] - S[v0, u1] - S[v1, u0] + S[v0, u0] for S in self.sat]
        n = np.maximum(s[0], 1.0)
        m = np.stack(s[1:4], -1) / n[:, None]
        C = np.empty((len(u), 3, 3))
        k = 4
        for i in range(3):
            for j in range(i, 3):
                C[:, i, j] = C[:, j, i] = s[k] / n - m[:, i] * m[:, j]
                k += 1
        _, vecs = np.linalg.eigh(C)
        nrm = vecs[..., 0]
        flip = np.einsum("ni,ni->n", nrm, cam_pos - (m + self.shift)) < 0
        return np.where(flip[:, None], -nrm, nrm)


def peer_c(xy, depth, cam, tree_cache):
    """KD-tree over every 2nd pixel's 3D point; PCA normal of the 10 mm ball at the nearest point."""
    from scipy.spatial import cKDTree

    if "tree" not in tree_cache:
        vv, uu = np.mgrid[0:depth.shape[0]:2, 0:depth.shape[1]:2]
        d = depth[vv, uu]
        ok = np.isfinite(d) & (d > 0)
        pts = cam.pixel_to_world(uu[ok].astype(float), vv[ok].astype(float), d[ok])
        t0 = time.perf_counter()
        tree_cache.update(tree=cKDTree(pts[:, :2]), pts=pts, build_s=time.perf_counter() - t0)
    tree, pts = tree_cache["tree"], tree_cache["pts"]
    _, idx = tree.query(xy)
    near = tree.query_ball_point(pts[idx, :2], 0.01)
    normals = np.full((len(xy), 3), np.nan)
    for i, nb in enumerate(near):
        if len(nb) >= 10:
            X = pts[nb] - pts[nb].mean(axis=0)
            _, vecs = np.linalg.eigh(X.T @ X)
            n = vecs[:, 0]
            normals[i] = n if n[2] > 0 else -n
    return pts[idx], normals


def _angle_max(n, truth, mask):
    ok = mask & np.all(np.isfinite(n), axis=1)
    if not ok.any():
        return float("nan"), 0.0
    err = np.degrees(np.arccos(np.clip(np.sum(n[ok] * truth[ok], axis=1), -1, 1)))
    return float(err.max()), float(ok.sum() / max(mask.sum(), 1))


def best_of(fn, repeat):
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[17, 100, 1000, 10000])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    try:
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    except (AttributeError, OSError):
        pass
    rows = []
    for n in args.sizes:
        scene, view = scene_and_view(n)
        cam, depth = view.camera, view.depth_m
        ids, dxy, M = list(scene.stud_ids), np.asarray(scene.studs_drawing_m), scene.M_local2world
        xy = scene.studs_world_xy_m
        vis = view.stud_visible
        truth = view.stud_normals_w
        res = {}
        t, out = best_of(lambda: plan_view(ids, dxy, M, depth, cam, PlannerConfig()), args.repeat)
        res["ours full (match+normal+sigma+status+clearance)"] = (t, *_angle_max(np.where(out.ok[:, None], out.normal_w, np.nan), truth, vis))
        t, out = best_of(lambda: plan_view(ids, dxy, M, depth, cam, PlannerConfig(check_gun_clearance=False)), args.repeat)
        res["ours, no clearance"] = (t, *_angle_max(np.where(out.ok[:, None], out.normal_w, np.nan), truth, vis))
        t, out = best_of(lambda: match_batch(xy, depth, cam), args.repeat)
        res["ours match only"] = (t, float("nan"), float(out.ok[vis].mean()))
        t, out = best_of(lambda: peer_a(xy, depth, cam), args.repeat)
        res["peer A: 2 re-projections + 7x7 (match only)"] = (t, float("nan"), float(np.isfinite(out[0][vis, 2]).mean()))

        def b():
            P, u, v = peer_a(xy, depth, cam)
            return _SatNormals(depth, cam).normals(u, v, cam.position_w)
        t, out = best_of(b, args.repeat)
        res["peer B: A + summed-area-table normals"] = (t, *_angle_max(out, truth, vis))
        try:
            cache: dict = {}
            t, out = best_of(lambda: peer_c(xy, depth, cam, cache), 1)
            res[f"peer C: KD-tree (build {cache['build_s'] * 1e3:.0f} ms) + PCA"] = (t, *_angle_max(out[1], truth, vis))
        except ImportError:
            res["peer C: KD-tree (scipy missing: pip install -r bench/requirements.txt)"] = (float("nan"),) * 3
        if n <= 100:
            t, out = best_of(lambda: match_fpm(xy, depth, cam), 1)
            res["FPM (paper, matching, per-pixel Python)"] = (t, float("nan"), float(out.ok[vis].mean()))
        rows.append((n, res))
    names = list(dict.fromkeys(k for _, r in rows for k in r))
    print("Full weld poses, one frame, one core: 1280x960 dome, camera yawed 35 deg, tilted 8 deg, 0.5 mm noise, "
          "1 mm quantisation, 4 % holes")
    print(f"{'method':52s} " + " ".join(f"{n:>22d}" for n, _ in rows))
    for name in names:
        cells = []
        for _n, r in rows:
            if name not in r:
                cells.append(f"{'-':>22s}")
                continue
            t, err, cov = r[name]
            e = "" if math.isnan(err) else f" {err:.2f}deg"
            cells.append(f"{t * 1e3:9.1f} ms{e:>8s} {cov * 100:3.0f}%")
        print(f"{name:52s} " + " ".join(cells))
    print("cells: time per frame, max normal error over the visible studs, coverage of the visible studs")
    for n, r in rows:
        ours = r["ours full (match+normal+sigma+status+clearance)"][0]
        peer = r["peer B: A + summed-area-table normals"][0]
        print(f"  N={n}: ours full / peer B = {ours / peer:.2f}; ours without clearance / peer B = "
              f"{r['ours, no clearance'][0] / peer:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
