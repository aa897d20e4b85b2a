#!/usr/bin/env python3
"""Replay a demo job's recorded sensor bag and compare the targets with the job's (issue 35's "Done means").

A demo run on the girder (``ros2 run stud_planner demo --part girder --out OUT``) leaves ``OUT/sensor_bag``
(every view the registration and the matcher saw, with its ``/camera/pose`` in world: the carriage is in it)
and ``OUT/cell_bag`` (the job's own ``/weld_targets``, one message per view, stamped with the view). This
runs, as a user would, with the job's matcher settings (its ``normal_window_m``, from ``OUT/params``),

* ``ros2 run stud_planner plan --drawing D --bag OUT/sensor_bag --out OUT/replay/plan.json --normal-window-m W`` and
* ``ros2 run stud_planner cell --mode replay --bag OUT/sensor_bag --drawing D --no-hmi --var normal_window_m=W``
  (listening to its ``/weld_targets`` here until every view's came, then Ctrl-C),

and prints, per pair, the largest distance between the targets of the same stud from the same view (stamp)
where both are ``ok``: the job against the replay, the job against ``plan`` (at the view ``plan`` kept for
each stud), ``plan`` against the replay. Exit 0 when all are within ``--tol-mm`` (0.1).

Usage (after ``bash tools/setup.sh && source ros2_ws/setup.bash``)::

    ROS_DOMAIN_ID=27 python tools/replay_check.py --out out/girder [--drawing D] [--tol-mm 0.1]
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

import numpy as np  # noqa: E402

Targets = dict[int, dict[str, np.ndarray]]  # view stamp (ns) -> stud id -> position (m), ok targets only


def targets_by_stamp(arrays) -> Targets:
    """stud_welding_msgs/WeldTargetArray messages -> the ok targets per view stamp."""
    out: Targets = {}
    for a in arrays:
        stamp = a.header.stamp.sec * 1_000_000_000 + a.header.stamp.nanosec
        out[stamp] = {t.stud_id: np.array([t.pose.position.x, t.pose.position.y, t.pose.position.z])
                      for t in a.targets if t.status_text == "ok"}
    return out


def plan_targets(report: dict) -> Targets:
    """A ``plan`` report's ok targets at the view it kept for each stud (its ``view_stamps_ns``)."""
    out: Targets = {}
    stamps = report.get("view_stamps_ns") or []
    for t in report["targets"]:
        if t["status"] == "ok" and t.get("view") is not None and t["view"] < len(stamps):
            out.setdefault(stamps[t["view"]], {})[t["stud_id"]] = np.asarray(t["position_m"], dtype=np.float64)
    return out


def compare(a: Targets, b: Targets) -> tuple[int, float]:
    """(pairs compared, largest distance in m) over the (stamp, stud) pairs ok in both."""
    worst, n = 0.0, 0
    for stamp, studs in a.items():
        for sid, p in studs.items():
            q = b.get(stamp, {}).get(sid)
            if q is not None:
                n += 1
                worst = max(worst, float(np.linalg.norm(p - q)))
    return n, worst


def run_replay(bag: Path, drawing: Path, out: Path, stamps: set[int], timeout_s: float,
               normal_window_m: float) -> Targets:
    """``cell --mode replay`` on ``bag`` (the job's ``normal_window_m``); its /weld_targets until every stamp of
    ``stamps`` came (or the time-out after the bag ended), then Ctrl-C."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from stud_welding_msgs.msg import WeldTargetArray

    from stud_common import ros_io

    rclpy.init()
    node = rclpy.create_node("replay_check")
    arrays: list = []
    lock = threading.Lock()

    def keep(msg) -> None:
        with lock:
            arrays.append(msg)

    node.create_subscription(WeldTargetArray, "/weld_targets", keep, ros_io.RESULT_QOS)
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    threading.Thread(target=ex.spin, daemon=True).start()
    out.mkdir(parents=True, exist_ok=True)
    log = out / "replay.out"
    cmd = ["ros2", "run", "stud_planner", "cell", "--mode", "replay", "--bag", str(bag), "--drawing", str(drawing),
           "--out", str(out / "cell"), "--no-hmi", "--var", f"normal_window_m={normal_window_m}"]
    print("replay_check: " + " ".join(cmd), flush=True)
    with open(log, "w") as f:
        cell = subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT, start_new_session=True)
    ended_at = None
    try:
        while True:
            with lock:
                got = targets_by_stamp(arrays)
            if stamps <= set(got):
                break
            if ended_at is None and "bag_play exited" in log.read_text():
                ended_at = time.monotonic()
            if cell.poll() is not None or (ended_at is not None and time.monotonic() - ended_at > timeout_s):
                print(f"replay_check: targets of {len(stamps - set(got))} view(s) never came (see {log})",
                      file=sys.stderr)
                break
            time.sleep(0.2)
    finally:
        if cell.poll() is None:
            os.killpg(cell.pid, signal.SIGINT)
            cell.wait(timeout=60)
        ex.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    return got


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True, help="the demo's output folder (sensor_bag/, cell_bag/)")
    ap.add_argument("--drawing", type=Path, default=REPO / "src" / "stud_planner" / "data" / "girder_demo.dxf")
    ap.add_argument("--tol-mm", type=float, default=0.1)
    ap.add_argument("--timeout-s", type=float, default=60.0, help="after the bag ended, for the last targets")
    args = ap.parse_args(argv)
    if "ROS_DOMAIN_ID" not in os.environ:
        print("replay_check: set ROS_DOMAIN_ID (another cell on this machine would mix with ours)", file=sys.stderr)
        return 2
    from stud_bringup.demo_score import read_topics

    sensor_bag, work = args.out / "sensor_bag", args.out / "replay"
    job = targets_by_stamp(read_topics(args.out / "cell_bag", ["/weld_targets"])["/weld_targets"])
    if not job or not (sensor_bag / "metadata.yaml").exists():
        print(f"replay_check: {args.out} has no cell_bag /weld_targets or no sensor_bag", file=sys.stderr)
        return 2
    work.mkdir(parents=True, exist_ok=True)
    # the matcher's settings of the job (its parameters file): the replay matches as the job did
    from stud_bringup.demo import run_params

    window = float(run_params(args.out, "matcher").get("normal_window_m", 0.02))
    t0 = time.monotonic()
    cmd = ["ros2", "run", "stud_planner", "plan", "--drawing", str(args.drawing), "--bag", str(sensor_bag),
           "--out", str(work / "plan.json"), "--normal-window-m", str(window)]
    print("replay_check: " + " ".join(cmd), flush=True)
    if subprocess.call(cmd) != 0:
        return 1
    report = json.loads((work / "plan.json").read_text())
    planned = plan_targets(report)
    print(f"replay_check: plan took {time.monotonic() - t0:.0f} s for {report['views']} views")
    replayed = run_replay(sensor_bag, args.drawing, work, set(report["view_stamps_ns"]) & set(job), args.timeout_s,
                          window)
    rows = [("job vs --mode replay", compare(job, replayed)), ("job vs plan", compare(planned, job)),
            ("plan vs --mode replay", compare(planned, replayed))]
    tol = args.tol_mm * 1e-3
    ok = all(n > 0 and worst <= tol for _, (n, worst) in rows)
    for name, (n, worst) in rows:
        print(f"  {name:<24} {n:4d} targets compared, largest difference {worst * 1e3:.4f} mm")
    print(f"replay_check: {'PASSED' if ok else 'FAILED'} (tolerance {args.tol_mm:g} mm)")
    (work / "replay_check.json").write_text(json.dumps(
        {"ok": ok, "tol_mm": args.tol_mm,
         **{name: {"compared": n, "max_mm": worst * 1e3} for name, (n, worst) in rows}},
        indent=1))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
