#!/usr/bin/env python3
"""Measurement: the planner's reach verdict against the driver's weld check, on many random studs (not a test).

Draws ``--poses`` stud poses around the arm (seeded: distance from its axis 0.05-0.68 m, any direction,
height -0.03..0.35 m, normal up to 35 deg from vertical in any direction) and, for each, an arm pose
anywhere in the workspace (random joints whose tool tip and flange lie inside the workspace box, above
the table). The planner's verdict comes from a CellReach built from the JSON the driver publishes on
/arm/reach_config; the driver's from its weld check (``SafetyChecker.check_target``) from that arm
pose, with the cell's configuration (cell.yaml: standoff, working branch, hand-eye). Prints how many
agree (every one must), how many studs are weldable, how many of those the driver reached through a
detour, and the time per verdict. ``tests/cell/test_reach_planner_equals_driver.py`` is the test.

Usage (after ``bash tools/setup.sh && source ros2_ws/setup.bash``)::

    python bench/bench_reach_agreement.py [--poses 3000] [--seed 1]
"""
from __future__ import annotations

import argparse
import sys
import time
from collections import Counter

import numpy as np

from rm65_driver.driver.params import PARAMS, safety_checker
from rm65_driver.weld.reach import ReachConfig
from stud_bringup.launch import default_config_path, load_config
from stud_cell.cell_reach import CellReach
from stud_common.hand_eye_in_use import resolve_hand_eye


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, default=3000)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    cell = load_config(default_config_path())
    v, node = cell["vars"], cell["nodes"]["arm_driver"]["params"]
    p = {prm.name: prm.default for prm in PARAMS}
    p.update(standoff_m=v["standoff_m"], stud_length_mm=v["stud_length_mm"], min_stud_spacing_m=v["min_stud_spacing_m"],
             preferred_joint_signs=node["preferred_joint_signs"])
    driver = safety_checker(p, resolve_hand_eye("", v["hand_eye_xyz_m"], v["hand_eye_rpy_deg"]).T_tool_cam)
    planner = CellReach.from_config(
        ReachConfig.from_json(driver.reach_for(p["standoff_m"], p["plunge_m"]).config.to_json()))
    kin = driver.kin
    rng = np.random.default_rng(args.seed)
    lo, hi = kin.limits_rad[:, 0], kin.limits_rad[:, 1]
    box_lo, box_hi = np.asarray(driver.limits.workspace_min_m), np.asarray(driver.limits.workspace_max_m)
    counts: Counter = Counter()
    disagreements = []
    t_planner = t_driver = 0.0
    for k in range(args.poses):
        while True:
            q = rng.uniform(lo, hi)
            F = kin.fk(q)
            tip = (F @ driver.tool_T)[:3, 3]
            if np.all((tip > box_lo) & (tip < box_hi) & (F[:3, 3] > box_lo) & (F[:3, 3] < box_hi)) and tip[2] > 0.05:
                break
        r, a, z = rng.uniform(0.05, 0.68), rng.uniform(-np.pi, np.pi), rng.uniform(-0.03, 0.35)
        tilt, az = np.radians(rng.uniform(0.0, 35.0)), rng.uniform(-np.pi, np.pi)
        pos = np.array([r * np.cos(a), r * np.sin(a), z])
        n = np.array([np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), np.cos(tilt)])
        t0 = time.perf_counter()
        pv = planner.stud(pos, n)
        t1 = time.perf_counter()
        dv = driver.check_target(pos, n, p["standoff_m"], q, p["plunge_m"])
        t2 = time.perf_counter()
        t_planner, t_driver = t_planner + t1 - t0, t_driver + t2 - t1
        counts["agree" if pv.ok == dv.ok else "disagree"] += 1
        counts["weldable" if pv.ok else "refused"] += 1
        if dv.ok and dv.plan is not None and dv.plan.via:
            counts["detour"] += 1
        if pv.ok != dv.ok:
            disagreements.append((pos.round(4).tolist(), n.round(4).tolist(), pv.reason, dv.reason))
        if (k + 1) % 500 == 0:
            print(f"  {k + 1} poses: {dict(counts)}", flush=True)
    n = args.poses
    print(f"{n} random stud poses (seed {args.seed}): planner == driver for {counts['agree']}/{n}; "
          f"{counts['weldable']} weldable ({counts['detour']} reached through a detour from the random arm pose), "
          f"{counts['refused']} refused; {1e3 * t_planner / n:.0f} ms per planner verdict, "
          f"{1e3 * t_driver / n:.0f} ms per driver check (verdict + its way there)")
    for d in disagreements:
        print("DISAGREE", d)
    return 0 if not disagreements else 1


if __name__ == "__main__":
    sys.exit(main())
