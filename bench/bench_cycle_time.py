#!/usr/bin/env python3
"""Benchmark: the weld cell's cycle time per stud, the arm simulator at real motion time (not a test).

Runs the simulated cell on a bundled part (``ros2 run stud_planner demo --part P --time-scale 1
--no-hmi``) while a listener in this process records, as they arrive, the sequencer's
``/cell/status`` states and the driver's ``/arm/weld_job`` feedback phases; the weld journal's
``started`` records split the approach phase into the move between studs and the fast approach.
Prints studs per hour and the seconds per stud of every category (stud_cell/cycle_time.py):
registration, station moves, shots, moves between studs, approach, descent, weld, dwell, retract,
weld-job overhead, post-weld inspection. Target: <= 2 s per stud, everything included.

Beside each measured figure, the floor at the run's own driver settings (its ``params/arm_driver.yaml``
over the driver's defaults; :mod:`rm65_sim.cycle_floor`, the simulator's time law): the least a stud
can take as the driver sequences it (its stops, with no move between studs and no per-job work) and
with every corner blended (one stop a stud). A figure above the floor is what the moves between studs,
the per-job work and the software cost; a target below the floor is out of reach at those settings.

Usage (after ``bash tools/setup.sh && source ros2_ws/setup.bash``)::

    ROS_DOMAIN_ID=70 python bench/bench_cycle_time.py [--part dome shell] [--out /tmp/cycle] [--arm-port 18170]

The demo's own arguments after ``--`` are passed on (e.g. ``-- --var arm_time_scale=1.0``).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from stud_welding_msgs.action import WeldJob
from stud_welding_msgs.msg import CellStatus

import yaml

from rm65_driver.driver import params as driver_params
from rm65_driver.journal.scan import read_records
from rm65_sim.cycle_floor import StudTimeFloor, stud_time_floor
from stud_cell.cycle_time import CycleEvent, format_split, motion_from_journal, split_cycle

TARGET_S_PER_STUD = 2.0


class Listener(Node):
    """Records (arrival time, kind, name, stud) of cell states and weld phases."""

    def __init__(self) -> None:
        super().__init__("bench_cycle_time")
        self.events: list[CycleEvent] = []
        self._lock = threading.Lock()
        latched = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.create_subscription(CellStatus, "/cell/status", self._on_status, latched)
        self.create_subscription(WeldJob.Impl.FeedbackMessage, "/arm/weld_job/_action/feedback", self._on_feedback,
                                 QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))

    def _on_status(self, msg: CellStatus) -> None:
        # The sequencer's stamp (system clock, this machine): a latched status delivered late, when the
        # listener is matched after the job began, keeps its time.
        stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
        with self._lock:
            self.events.append(CycleEvent(stamp if stamp > 0 else time.time(), "cell", msg.state_text))

    def _on_feedback(self, msg) -> None:  # no stamp: the arrival (matched long before the first weld)
        with self._lock:
            self.events.append(CycleEvent(time.time(), "weld", msg.feedback.phase, msg.feedback.stud_id))


def driver_floor(params_file: Path) -> StudTimeFloor:
    """The stud time floor of the weld job a run's driver had: its parameters file over the defaults."""
    values = {p.name: p.default for p in driver_params.PARAMS}
    values.update(yaml.safe_load(params_file.read_text())["/**"]["ros__parameters"])
    return stud_time_floor(driver_params.job_config(values)[0])


def run_part(part: str, out: Path, arm_port: int, extra: list[str]) -> dict:
    rclpy.init()
    node = Listener()
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    spinner = threading.Thread(target=ex.spin, daemon=True)
    spinner.start()
    cmd = ["ros2", "run", "stud_planner", "demo", "--part", part, "--time-scale", "1", "--no-hmi",
           "--out", str(out), "--arm-port", str(arm_port), *extra]
    print("bench: " + " ".join(cmd), flush=True)
    t0 = time.monotonic()
    with open(out.parent / f"{out.name}.log", "w") as log:
        code = subprocess.call(cmd, stdout=log, stderr=subprocess.STDOUT)
    wall = time.monotonic() - t0
    time.sleep(0.5)  # the last status is already in (the sequencer exits after publishing it)
    ex.shutdown()
    node.destroy_node()
    rclpy.try_shutdown()
    summary_file = out / "summary.json"
    summary = json.loads(summary_file.read_text()) if summary_file.exists() else {}
    journal = out / "weld_journal.jsonl"
    records = list(read_records(journal)) if journal.exists() else []
    welded = len({r["stud"] for r in records if r.get("event") == "welded"})
    split = split_cycle(node.events, welded, motion_from_journal(records))
    print(format_split(split, f"{part} (demo exit {code}, ok={summary.get('ok')}, "
                              f"{summary.get('stations')} station(s), demo wall {wall:.0f} s)"))
    verdict = "met" if split.s_per_stud <= TARGET_S_PER_STUD else f"missed by {split.s_per_stud - 2.0:.2f} s"
    print(f"  target <= {TARGET_S_PER_STUD:.1f} s/stud: {verdict}", flush=True)
    floor = driver_floor(out / "params" / "arm_driver.yaml")
    in_station = sum(split.per_stud(k) for k in ("approach", "descent", "weld", "dwell", "retract"))
    print(f"  floor at this run's driver settings (no move between studs, no per-job work): "
          f"{floor.as_sequenced_s:.2f} s/stud as sequenced (approach {floor.approach_s:.2f}, weld + dwell "
          f"{floor.weld_s:.2f}, retract {floor.retract_s:.2f}), {floor.blended_s:.2f} s with every corner blended; "
          f"measured {in_station:.2f} s/stud in those phases, {split.per_stud('moves_between_studs'):.2f} moving "
          f"between studs, {split.s_per_stud - in_station - split.per_stud('moves_between_studs'):.2f} the rest "
          f"(registration, stations, shots, inspection, job overhead)", flush=True)
    return {"part": part, "exit": code, "ok": summary.get("ok"), "stations": summary.get("stations"),
            "studs": welded, "total_s": round(split.total_s, 2), "s_per_stud": round(split.s_per_stud, 3),
            "studs_per_hour": round(split.studs_per_hour, 0),
            "per_stud_s": {k: round(split.per_stud(k), 3) for k in split.seconds},
            "floor_s_per_stud": {"as_sequenced": round(floor.as_sequenced_s, 3), "blended": round(floor.blended_s, 3),
                                 "approach": round(floor.approach_s, 3), "weld": round(floor.weld_s, 3),
                                 "retract": round(floor.retract_s, 3)}}


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    extra = argv[argv.index("--") + 1:] if "--" in argv else []
    argv = argv[:argv.index("--")] if "--" in argv else argv
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--part", nargs="+", default=["dome", "shell"], choices=["dome", "shell"])
    ap.add_argument("--out", type=Path, default=Path("/tmp") / f"cycle_bench_{os.getpid()}")
    ap.add_argument("--arm-port", type=int, default=18170, help="arm simulator port (not 8080: other cells)")
    ap.add_argument("--json", type=Path, help="also write the figures here")
    args = ap.parse_args(argv)
    if "ROS_DOMAIN_ID" not in os.environ:
        print("bench: set ROS_DOMAIN_ID (another cell on this machine would mix with ours)", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    rows = [run_part(part, args.out / part, args.arm_port, extra) for part in args.part]
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0 if all(r["ok"] for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
