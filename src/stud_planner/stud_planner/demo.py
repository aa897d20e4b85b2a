"""The one-command demo: `ros2 run stud_planner demo [--out DIR]` (what `bash demo.sh` runs).

Runs the whole weld cell in simulation on the bundled dome drawing (`ros2 run stud_planner cell
--mode sim`, the sequencer starting the job by itself and ending the launch when done):
registration over the marking board, camera stations, matching, simulated welding of every
stud through the RM-65 controller simulator over TCP, with the topics recorded to an MCAP bag.
Then it scores the result against the scene's exact truth and prints a summary. Left in the
output folder: ``weld_report.json`` (per stud: status, position, normal, welded), ``summary.json``,
``overlays/*.png`` (the matcher's overlays), ``cell_bag/`` (rosbag2 MCAP, opens in Foxglove),
``weld_journal.jsonl`` and every node's log. Exit code 0 only if every stud was welded within
the accuracy limits.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from stud_perception.scene import load_scene, surface_height, surface_normal
from stud_perception.strict_json import write_json

RECORDED_TOPICS = ["/drawing/layout", "/registration/result", "/weld_targets", "/weld_targets/poses",
                   "/weld_targets/markers", "/weld_targets/overlay", "/arm/state", "/joint_states", "/cell/status",
                   "/camera/pose", "/camera/color/camera_info", "/tf", "/tf_static", "/robot_description"]


def share_file(package: str, relative: str) -> Path:
    from ament_index_python.packages import get_package_share_directory

    return Path(get_package_share_directory(package)) / relative


def score(report: dict, scene_file: Path) -> dict:
    """Per-stud errors of the welded targets against the scene truth (metres, degrees)."""
    scene = load_scene(scene_file)
    truth_xy = dict(zip(scene.stud_ids, scene.studs_world_xy_m))
    rows = []
    for t in report["targets"]:
        if t.get("position_m") is None or t["stud_id"] not in truth_xy:
            continue
        x, y = truth_xy[t["stud_id"]]
        true_p = np.array([x, y, float(surface_height(scene, np.array([x]), np.array([y]))[0])])
        true_n = np.asarray(surface_normal(scene, np.array([x]), np.array([y]))).reshape(-1, 3)[0]
        p, n = np.asarray(t["position_m"], float), np.asarray(t["normal"], float)
        rows.append({"stud_id": t["stud_id"], "xy_error_m": float(np.linalg.norm(p[:2] - true_p[:2])),
                     "z_error_m": float(abs(p[2] - true_p[2])),
                     "normal_error_deg": float(np.degrees(np.arccos(np.clip(n @ true_n, -1, 1))))})
    return {"studs": rows,
            "max_xy_error_mm": 1e3 * max((r["xy_error_m"] for r in rows), default=float("nan")),
            "mean_xy_error_mm": 1e3 * float(np.mean([r["xy_error_m"] for r in rows])) if rows else float("nan"),
            "max_z_error_mm": 1e3 * max((r["z_error_m"] for r in rows), default=float("nan")),
            "max_normal_error_deg": max((r["normal_error_deg"] for r in rows), default=float("nan"))}


def export_overlays(bag_dir: Path, out_dir: Path) -> int:
    """The matcher's overlay images from the recorded bag as PNG files."""
    import cv2
    from ros2_lite.bag import open_bag

    from stud_perception import ros_io

    if not bag_dir.exists():
        return 0
    out_dir.mkdir(parents=True, exist_ok=True)
    n = 0
    with open_bag(bag_dir) as bag:
        for item in bag.messages(["/weld_targets/overlay"]):
            n += 1
            cv2.imwrite(str(out_dir / f"overlay_{n:02d}.png"), ros_io.color_to_bgr(item.message()))
    return n


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="demo", description="Run the simulated weld cell on the bundled dome drawing.")
    ap.add_argument("--out", type=Path, default=Path("out") / "demo", help="output folder (default: out/demo)")
    ap.add_argument("--no-hmi", action="store_true", help="do not start the web HMI")
    ap.add_argument("--time-scale", type=float, default=0.25, help="arm simulator motion time factor (1 = real time)")
    ap.add_argument("--max-xy-error-mm", type=float, default=1.0, help="accuracy limit on the weld points")
    ap.add_argument("--max-normal-error-deg", type=float, default=3.0, help="accuracy limit on the normals")
    ap.add_argument("--var", dest="vars", action="append", default=[], metavar="NAME=VALUE",
                    help="passed on to `cell` (a ${NAME} of cell.yaml), e.g. hand_eye_file=PATH or "
                         "'true_hand_eye_xyz_m=[0.056, -0.004, -0.097]' (docs/CALIBRATION.md)")
    ap.add_argument("--arm-port", type=int, default=8080, help="TCP port of the arm simulator (default: 8080)")
    ap.add_argument("--hmi-port", type=int, default=8090, help="port of the operator page (default: 8090)")
    args = ap.parse_args(argv)
    out = args.out.resolve()
    if out.exists():
        # a demo starts a new job: a new journal (and its mirror, else the driver would see the journal missing)
        for stale in ("weld_journal.jsonl", "weld_journal.jsonl.mirror", "weld_report.json", "summary.json"):
            (out / stale).unlink(missing_ok=True)
        import shutil

        shutil.rmtree(out / "cell_bag", ignore_errors=True)
        shutil.rmtree(out / "overlays", ignore_errors=True)
    out.mkdir(parents=True, exist_ok=True)
    cmd = ["ros2", "run", "stud_planner", "cell", "--mode", "sim", "--out", str(out),
           "--set", "cell_sequencer.auto_start=true", "--set", "cell_sequencer.exit_when_done=true",
           "--var", f"arm_time_scale={args.time_scale}", "--var", f"arm_port={args.arm_port}",
           "--var", f"hmi_port={args.hmi_port}", "--with", "bag_record"]
    for var in args.vars:
        cmd += ["--var", var]
    # Another cell on this machine with the same domain would mix with ours: say which one we use.
    print(f"demo: ROS_DOMAIN_ID={os.environ.get('ROS_DOMAIN_ID', '0')} (set ROS_DOMAIN_ID to run beside another "
          "cell; `ros2 topic list` in a shell with the same value sees this one)", flush=True)
    if args.no_hmi:
        cmd.append("--no-hmi")
    else:
        print(f"demo: the operator screen is at http://127.0.0.1:{args.hmi_port}/ while the job runs", flush=True)
    print("demo: " + " ".join(cmd), flush=True)
    t0 = time.monotonic()
    code = subprocess.call(cmd, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    elapsed = time.monotonic() - t0

    report_file = out / "weld_report.json"
    if not report_file.exists():
        print(f"demo: FAILED: the cell ended with exit code {code} and no report ({report_file}); see {out}/*.log",
              file=sys.stderr)
        return 1
    report = json.loads(report_file.read_text())
    acc = score(report, share_file("stud_perception", "config/dome_scene.json"))
    overlays = export_overlays(out / "cell_bag", out / "overlays")
    welded = sum(bool(t.get("welded")) for t in report["targets"])
    total = len(report["targets"])
    ok = (code == 0 and welded == total and acc["max_xy_error_mm"] <= args.max_xy_error_mm
          and acc["max_normal_error_deg"] <= args.max_normal_error_deg)
    summary = {"ok": ok, "cell_exit_code": code, "studs_total": total, "studs_welded": welded,
               "stations": report.get("stations"), "unreachable": report.get("unreachable", []),
               "time_s": round(elapsed, 1), "accuracy": {k: v for k, v in acc.items() if k != "studs"},
               "overlays": overlays}
    write_json(out / "summary.json", {**summary, "per_stud": acc["studs"]})
    print()
    print("=" * 72)
    print(f" weld-cell demo: {'PASSED' if ok else 'FAILED'}")
    print(f"   studs welded        {welded}/{total} over {report.get('stations')} camera station(s)"
          + (f", unreachable: {', '.join(report['unreachable'])}" if report.get("unreachable") else ""))
    print(f"   weld-point error    max {acc['max_xy_error_mm']:.2f} mm XY (mean {acc['mean_xy_error_mm']:.2f}), "
          f"max {acc['max_z_error_mm']:.2f} mm Z   [paper: 7.1 mm XY, 2.09 mm Z]")
    print(f"   normal error        max {acc['max_normal_error_deg']:.2f} deg")
    print(f"   time                {elapsed:.0f} s (arm simulator at {args.time_scale:g}x real motion time)")
    print(f"   output              {out}/  (weld_report.json, summary.json, overlays/ [{overlays}], cell_bag/, logs)")
    print("=" * 72)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
