#!/usr/bin/env python3
"""Long parts: render cost of a 6 m girder view, and registration along it on the reference marks.

The scene is stud_perception.scene.girder_scene (6 m, 30 mm camber, 2.5 deg cross slope, a reference
mark every 200 mm) with ``--studs`` studs (rows of three; default 300). The camera (1280x960, the demo's
field) visits stations every ``--step`` m along the girder, 0.5 m above the crown, tilted 8 deg; the
cell believes it where the commanded carriage position puts it, while the true carriage is off by a
scale error, an offset and a yaw per metre (``--rail-*``). Each view (0.5 mm depth noise correlated over
2 px, 3 % holes, no depth on dark paint) is registered with stud_perception.mark_registration's
RegistrationTrail -- the first one on the board's O, A, B, the rest on the reference marks they see,
named by the nearest earlier registration. Per station: render and registration time, the marks used,
the RMS / max residual, and the error of the registration at the studs within 0.35 m of the camera
against the transform the arm needs there (the truth seen through the rail's error), next to the error
the start's registration alone would leave.
Run: source ros2_ws/setup.bash && python bench/bench_long_part.py [--studs 300] [--step 0.3]
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
for pkg in ("stud_common", "stud_perception"):
    sys.path.insert(0, str(REPO / "src" / pkg))

import numpy as np  # noqa: E402

from stud_perception.mark_registration import MarkFitConfig, RegistrationTrail  # noqa: E402
from stud_perception.markers import MarkDetectorConfig  # noqa: E402
from stud_perception.registration import local_to_world  # noqa: E402
from stud_perception.scene import girder_scene  # noqa: E402
from stud_perception.scene_cameras import view_camera  # noqa: E402
from stud_perception.scene_render import render  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--studs", type=int, default=300, help="studs on the girder (rows of three)")
    ap.add_argument("--step", type=float, default=0.3, help="station spacing along the girder [m]")
    ap.add_argument("--rail-scale-ppm", type=float, default=1000.0)
    ap.add_argument("--rail-offset-mm", type=float, default=0.5)
    ap.add_argument("--rail-yaw-urad-per-m", type=float, default=50.0)
    args = ap.parse_args()
    rows = max(1, math.ceil(args.studs / 3))
    scene = girder_scene(row_pitch_m=6.0 / rows)
    marks = {"O": (0.0, 0.0), "A": (0.13, 0.0), "B": (0.0, 0.1), **scene.reference_marks_drawing_m}
    print(f"girder 6 m: {len(scene.stud_ids)} studs, {len(scene.reference_marks)} reference marks; rail error "
          f"{args.rail_scale_ppm:g} ppm, {args.rail_offset_mm:g} mm, {args.rail_yaw_urad_per_m:g} urad/m")

    def believed(cam):
        x = float(cam.position_w[0])
        dx, dyaw = args.rail_scale_ppm * 1e-6 * x + args.rail_offset_mm * 1e-3, args.rail_yaw_urad_per_m * 1e-6 * x
        c, s = math.cos(-dyaw), math.sin(-dyaw)
        Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        return cam.with_pose(Rz @ cam.R_wc, Rz @ cam.position_w - np.array([dx, 0.0, 0.0])), Rz, dx

    def error_mm(M, cam_true, Rz, dx) -> float:
        near = np.linalg.norm(scene.studs_world_xy_m - cam_true.position_w[:2], axis=1) < 0.35
        xy = np.asarray(scene.studs_drawing_m)[near]
        if not len(xy):
            return float("nan")
        T = np.eye(3)
        T[:2, :2], T[0, 2] = Rz[:2, :2], -dx
        want = local_to_world(T @ scene.M_local2world, xy)
        return float(np.linalg.norm(local_to_world(M, xy) - want, axis=1).max() * 1e3)

    trail = RegistrationTrail()
    stations = [(0.37, -0.2)] + [(float(x), 0.0) for x in np.arange(0.6, 6.2, args.step)] + [(6.5, 0.0)]
    t_render, t_reg, errors = [], [], []
    print(f"{'x m':>6} {'render s':>8} {'reg s':>6}  {'marks':<22} {'rms mm':>6} {'max mm':>6} {'err mm':>7} "
          f"{'start mm':>8}  note")
    for i, (x, y) in enumerate(stations):
        cam_true = view_camera((x, y, 0.15), 0.5, tilt_rad=math.radians(8), tilt_azimuth_rad=math.radians(60))
        t0 = time.perf_counter()
        view = render(scene, cam_true, seed=i, depth_noise_m=0.0005, depth_noise_correlation_px=2.0,
                      hole_fraction=0.03, color_noise=2.0, mark_depth_dropout=True)
        t1 = time.perf_counter()
        cam, Rz, dx = believed(cam_true)
        result = trail.register(view.color_bgr, view.depth_m, cam, marks, MarkDetectorConfig(), MarkFitConfig())
        t2 = time.perf_counter()
        t_render.append(t1 - t0)
        t_reg.append(t2 - t1)
        if not result.ok:
            print(f"{x:6.2f} {t1 - t0:8.2f} {t2 - t1:6.2f}  refused: {result.message}")
            continue
        reg = result.registration
        err = error_mm(reg.M_local2world, cam_true, Rz, dx)
        start = error_mm(trail.stations[0].registration.M_local2world, cam_true, Rz, dx)
        note = f"extrapolated {reg.extrapolated_m:.2f} m" if reg.extrapolated else ""
        if not reg.extrapolated:
            errors.append(err)
        print(f"{x:6.2f} {t1 - t0:8.2f} {t2 - t1:6.2f}  {','.join(reg.labels_used):<22} {reg.residual_m * 1e3:6.3f} "
              f"{reg.residual_max_m * 1e3:6.3f} {err:7.3f} {start:8.2f}  {note}")
    print(f"render 1280x960: median {np.median(t_render):.2f} s, max {np.max(t_render):.2f} s; registration median "
          f"{np.median(t_reg):.3f} s; error at the studs over {len(errors)} registered stations: max "
          f"{np.nanmax(errors):.3f} mm, median {np.nanmedian(errors):.3f} mm")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
