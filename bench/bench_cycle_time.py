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

``--part girder`` (issue 35: the 6 m girder welded from the rail, everything included -- rail moves,
a registration at each carriage position, the post-weld inspection): the listener also follows
``/arm/state`` for the carriage's moves (their count and the seconds it moved), and the floor adds the
rail's share: the least travel the part needs -- from where the first studs along the rail can be
welded to where the last ones can, by the driver's reach test at the run's settings
(``cycle_floor.carriage_range``) -- in one move at the run's ``rail_speed_pct``, spread over the studs.
Its target is the issue's >= 1,200 studs/h (3 s/stud); the dome's and the shell's stays <= 2 s/stud.

Usage (after ``bash tools/setup.sh && source ros2_ws/setup.bash``)::

    ROS_DOMAIN_ID=70 python bench/bench_cycle_time.py [--part dome shell girder] [--out /tmp/cycle] [--arm-port 18170]

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

import numpy as np
import rclpy
import yaml
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from stud_welding_msgs.action import WeldJob
from stud_welding_msgs.msg import ArmState, CellStatus

from rm65_driver.driver import params as driver_params
from rm65_driver.journal.scan import read_records
from rm65_sim.cycle_floor import RailFloor, StudTimeFloor, carriage_range, rail_floor, stud_time_floor
from stud_bringup.demo_parts import PARTS
from stud_bringup.demo_score import rail_moves
from stud_cell.cycle_time import CycleEvent, format_split, motion_from_journal, split_cycle

TARGET_S_PER_STUD = 2.0
#: Per part, the target (s/stud): issue 35 asks >= 1,200 studs/h of the girder, rail and all.
TARGETS_S_PER_STUD = {"girder": 3600.0 / 1200.0}


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
        self.states: list[ArmState] = []  # the carriage's moves (a part on a rail)
        self.create_subscription(ArmState, "/arm/state", self._on_state, QoSProfile(depth=100,
                                 reliability=ReliabilityPolicy.RELIABLE))

    def _on_state(self, msg: ArmState) -> None:
        with self._lock:
            self.states.append(msg)

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


def rail_seconds(states: list) -> float:
    """Seconds the carriage moved: between each /arm/state with ``rail_moving`` and the next state."""
    ts = sorted(states, key=lambda m: m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec)
    t = [m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec for m in ts]
    return float(sum(t[i + 1] - t[i] for i in range(len(ts) - 1) if ts[i].rail_moving))


def driver_rail_floor(params_file: Path, part: str) -> RailFloor | None:
    """The least carriage travel and time the part needs at a run's driver settings (None: no rail): the
    carriage ranges of the first and last rows of studs along the rail, by the driver's reach test."""
    from rm65_driver.driver.params import rail_axis, safety_checker
    from stud_common.rotations import transform_xyz_rpy
    from stud_perception.scene import surface_height, surface_normal
    from stud_perception.scene_file import load_scene

    values = {p.name: p.default for p in driver_params.PARAMS}
    values.update(yaml.safe_load(params_file.read_text())["/**"]["ros__parameters"])
    axis = rail_axis(values)
    if axis is None:
        return None
    weld, _limits = driver_params.job_config(values)
    reach = safety_checker(values, transform_xyz_rpy(values["hand_eye_xyz_m"], values["hand_eye_rpy_deg"])).reach_for(
        weld.standoff_m, weld.plunge_m)
    scene = load_scene(Path(__file__).resolve().parents[1] / "src" / "stud_perception" / PARTS[part].scene)
    xy = scene.studs_world_xy_m
    ends = np.flatnonzero((xy[:, 0] <= xy[:, 0].min() + 1e-6) | (xy[:, 0] >= xy[:, 0].max() - 1e-6))
    z = surface_height(scene, xy[ends, 0], xy[ends, 1])
    n = surface_normal(scene, xy[ends, 0], xy[ends, 1])
    ranges = [carriage_range(reach, np.array([*xy[i], zi]), ni, values["rail_mount_xyz_m"], axis.length_m)
              for i, zi, ni in zip(ends, z, n)]
    return rail_floor([r for r in ranges if r is not None], axis, values["rail_speed_pct"])


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
    target = TARGETS_S_PER_STUD.get(part, TARGET_S_PER_STUD)
    verdict = "met" if split.s_per_stud <= target else (
        f"missed by {split.s_per_stud - target:.2f} s ({3600.0 / target - split.studs_per_hour:.0f} studs/h)")
    print(f"  target <= {target:.1f} s/stud ({3600.0 / target:,.0f} studs/h): {verdict}", flush=True)
    floor = driver_floor(out / "params" / "arm_driver.yaml")
    rail = driver_rail_floor(out / "params" / "arm_driver.yaml", part)
    moved = rail_moves(node.states)
    rail_s = rail_seconds(node.states)
    if rail is not None:
        print(f"  rail: {moved['moves']} carriage moves, {moved['distance_m']:.2f} m, {rail_s:.1f} s moving "
              f"({rail_s / max(welded, 1):.2f} s/stud, inside the categories above); floor: the studs need >= "
              f"{rail.travel_m:.2f} m of travel, one move of {rail.move_s:.1f} s "
              f"({rail.move_s / max(welded, 1):.2f} s/stud); "
              f"floor with it {floor.as_sequenced_s + rail.move_s / max(welded, 1):.2f} s/stud as sequenced, "
              f"{floor.blended_s + rail.move_s / max(welded, 1):.2f} blended", flush=True)
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
                                 "retract": round(floor.retract_s, 3),
                                 **({"rail": round(rail.move_s / max(welded, 1), 3)} if rail is not None else {})},
            **({"rail": {"moves": moved["moves"], "distance_m": round(moved["distance_m"], 3),
                         "moving_s": round(rail_s, 2), "floor_travel_m": round(rail.travel_m, 3),
                         "floor_move_s": round(rail.move_s, 2)}} if rail is not None else {}),
            "target_s_per_stud": target}


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    extra = argv[argv.index("--") + 1:] if "--" in argv else []
    argv = argv[:argv.index("--")] if "--" in argv else argv
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--part", nargs="+", default=["dome", "shell"], choices=sorted(PARTS))
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
