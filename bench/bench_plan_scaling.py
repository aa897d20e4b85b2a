#!/usr/bin/env python3
"""Benchmark: offline ``plan`` on a bridge-sized drawing (this is a benchmark, not a test).

A bridge carries about 250,000 shear studs. This script writes drawings of 10k, 50k and 250k
studs into a temporary folder (never into the repository): the demo drawing's marks O, A, B
and 17 studs, plus a 100 mm grid of 19 mm studs around them, through
:mod:`stud_planner.drawing.dxf_writer` (an R2010 mm drawing as CAD writes it). Each size then runs in a
fresh process, as a user runs it:

* ``parse``: :func:`stud_planner.drawing.read_layout` (ezdxf load + circles + ids + checks);
* ``plan``: :func:`offline_plan.plan` over ``bags/dome_demo`` (3 views: registration, matching,
  the best view per stud; parses the drawing again inside, as the command does);
* ``write``: the JSON report (strict JSON, as ``plan --out`` writes it);
* ``cli``: the whole ``plan --drawing D --bag B --out R`` command, wall clock, in a new process
  (imports included), and its peak resident memory (``ru_maxrss``).

It prints the figures per size, the time per stud and the ratio of the per-stud cost against the
smallest size (1.0 = linear; below 1 while the fixed cost -- imports, the bag, registration -- still
weighs), the marginal cost per added stud between sizes (equal = linear), and the targets: 250k parsed
and planned in <= 20 s, peak memory <= 1.5 GB. Exit code 1 when a target is missed (0 with
``--no-check``).

Usage::

    python bench/bench_plan_scaling.py              # 10k, 50k, 250k (about a minute, most of it writing DXFs)
    python bench/bench_plan_scaling.py --sizes 1000 5000 --no-check   # quick
    python bench/bench_plan_scaling.py --profile 250000               # cProfile of plan at that size
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
for _pkg in ("stud_common", "stud_bag", "stud_perception", "stud_planner"):  # run from a checkout, no build needed
    _path = str(REPO / "src" / _pkg)
    if _path not in sys.path:
        sys.path.insert(0, _path)

DEMO_DRAWING = REPO / "src" / "stud_planner" / "data" / "dome_demo.dxf"
DEMO_BAG = REPO / "bags" / "dome_demo"
TARGET_S = 20.0
TARGET_RSS_MB = 1536.0
GRID_M = 0.1


def write_drawing(path: Path, n_studs: int) -> Path:
    """The demo drawing's marks and studs plus a grid around them: ``n_studs`` studs in all."""
    import numpy as np

    from stud_planner.drawing import read_layout
    from stud_planner.drawing.dxf_writer import LayoutDxfOptions, write_scene_drawing

    demo = read_layout(DEMO_DRAWING)
    marks = {k: (m.x_m, m.y_m) for k, m in demo.marks.items()}
    own = demo.studs_xy_m()
    extra = n_studs - len(own)
    side = int(np.ceil(np.sqrt(extra)))
    # a square grid centred on the demo studs, offset by half a pitch so no grid stud duplicates one
    centre = own.mean(axis=0)
    k = np.arange(side) - side // 2
    gx, gy = np.meshgrid(k * GRID_M + GRID_M / 2, k * GRID_M + GRID_M / 2)
    grid = np.column_stack([gx.ravel(), gy.ravel()]) + centre
    near = np.min(np.hypot(*(grid[:, None, :] - own[None, :, :]).transpose(2, 0, 1)), axis=1) < 0.03 \
        if side <= 2000 else np.zeros(len(grid), bool)
    grid = grid[~near][:extra]
    studs = np.vstack([own, grid])
    return write_scene_drawing(path, studs, marks,
                               LayoutDxfOptions(stud_diameter_m=0.019, mark_diameter_m=demo.mark_diameter_m))


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def measure_in_process(drawing: Path, report: Path) -> dict:
    """Run in a child: parse, plan, write; seconds and peak RSS (MB)."""
    from stud_common.strict_json import write_json
    from stud_planner import offline_plan
    from stud_planner.drawing import read_layout

    t0 = time.perf_counter()
    layout = read_layout(drawing)
    t1 = time.perf_counter()
    result = offline_plan.plan(drawing, DEMO_BAG, quiet=True)
    t2 = time.perf_counter()
    write_json(report, result)
    t3 = time.perf_counter()
    counts: dict[str, int] = {}
    for t in result["targets"]:
        counts[t["status"]] = counts.get(t["status"], 0) + 1
    return {"studs": len(layout.studs), "parse_s": t1 - t0, "plan_s": t2 - t1, "write_s": t3 - t2,
            "rss_mb": _rss_mb(), "counts": counts}


def _child(args) -> int:
    out = measure_in_process(Path(args.child[0]), Path(args.child[1]))
    print(json.dumps(out))
    return 0


def _run_child(drawing: Path, report: Path) -> dict:
    done = subprocess.run([sys.executable, __file__, "--child", str(drawing), str(report)],
                          capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise SystemExit(f"benchmark child failed: {done.stderr.strip().splitlines()[-1:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def _run_cli(drawing: Path, report: Path) -> tuple[float, float]:
    """Wall clock and peak RSS (MB) of ``plan --drawing D --bag B --out R --quiet`` in a new process."""
    code = ("import sys; from stud_planner.offline_plan import main; sys.exit(main(sys.argv[1:]))")
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    t0 = time.perf_counter()
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO / "src" / "stud_planner"),
                                                       str(REPO / "src" / "stud_perception"),
                                                       str(REPO / "src" / "stud_bag"),
                                                       str(REPO / "src" / "stud_common"),
                                                       os.environ.get("PYTHONPATH", "")]))
    done = subprocess.run([sys.executable, "-c", code, "--drawing", str(drawing), "--bag", str(DEMO_BAG),
                           "--out", str(report), "--quiet"], capture_output=True, text=True, env=env, check=False)
    wall = time.perf_counter() - t0
    if done.returncode != 0:
        raise SystemExit(f"plan failed: {done.stderr.strip()}")
    after = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    return wall, max(after, before) / 1024.0  # ru_maxrss of children: the largest child so far


def _profile(n: int, tmp: Path) -> int:
    import cProfile
    import pstats

    from stud_planner import offline_plan

    drawing = write_drawing(tmp / f"studs_{n}.dxf", n)
    prof = cProfile.Profile()
    prof.enable()
    offline_plan.plan(drawing, DEMO_BAG, quiet=True)
    prof.disable()
    pstats.Stats(prof).sort_stats("cumulative").print_stats(30)
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[10_000, 50_000, 250_000])
    parser.add_argument("--no-check", action="store_true", help="print only; exit 0 even if a target is missed")
    parser.add_argument("--profile", type=int, metavar="N", help="cProfile plan() on an N-stud drawing instead")
    parser.add_argument("--child", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        return _child(args)
    with tempfile.TemporaryDirectory(prefix="bench_plan_") as tmp_name:
        tmp = Path(tmp_name)
        if args.profile:
            return _profile(args.profile, tmp)
        rows = []
        for n in sorted(args.sizes):
            t0 = time.perf_counter()
            drawing = write_drawing(tmp / f"studs_{n}.dxf", n)
            made = time.perf_counter() - t0
            m = _run_child(drawing, tmp / f"report_{n}.json")
            wall, rss = _run_cli(drawing, tmp / f"report_cli_{n}.json")
            m.update(cli_s=wall, cli_rss_mb=rss, dxf_mb=drawing.stat().st_size / 1e6, made_s=made)
            rows.append(m)
            print(f"{m['studs']:>8,} studs ({m['dxf_mb']:.0f} MB DXF, written in {made:.0f} s): parse "
                  f"{m['parse_s']:.2f} s, plan {m['plan_s']:.2f} s, write {m['write_s']:.2f} s, "
                  f"parse+plan {m['parse_s'] + m['plan_s']:.2f} s, peak RSS {m['rss_mb']:.0f} MB; "
                  f"plan command {wall:.2f} s, peak RSS {rss:.0f} MB; statuses {m['counts']}", flush=True)
        base = rows[0]
        print("\nper stud (plan command, and parse + plan in one process), ratio to the smallest size "
              "(1.0 = linear):")
        for m in rows:
            per_cli = m["cli_s"] / m["studs"] * 1e6
            per_in = (m["parse_s"] + m["plan_s"]) / m["studs"] * 1e6
            ratio_cli = per_cli / (base["cli_s"] / base["studs"] * 1e6)
            ratio_in = per_in / ((base["parse_s"] + base["plan_s"]) / base["studs"] * 1e6)
            print(f"  {m['studs']:>8,}: {per_cli:6.1f} us/stud (x{ratio_cli:.2f}), "
                  f"{per_in:6.1f} us/stud (x{ratio_in:.2f})")
        if len(rows) > 1:
            print("marginal cost per added stud (removes the fixed cost: imports, the bag, registration):")
            for a, b in zip(rows, rows[1:]):
                dn = b["studs"] - a["studs"]
                cli_us = (b['cli_s'] - a['cli_s']) / dn * 1e6
                inproc_us = (b['parse_s'] + b['plan_s'] - a['parse_s'] - a['plan_s']) / dn * 1e6
                print(f"  {a['studs']:>8,} -> {b['studs']:>8,}: plan command {cli_us:6.1f} "
                      f"us/stud, parse + plan {inproc_us:6.1f} "
                      "us/stud")
        big = rows[-1]
        ok_time = big["cli_s"] <= TARGET_S
        ok_rss = max(big["cli_rss_mb"], big["rss_mb"]) <= TARGET_RSS_MB
        print(f"\ntargets at {big['studs']:,} studs: plan command {big['cli_s']:.1f} s (<= {TARGET_S:g} s: "
              f"{'met' if ok_time else 'MISSED'}), peak RSS {max(big['cli_rss_mb'], big['rss_mb']):.0f} MB "
              f"(<= {TARGET_RSS_MB:.0f} MB: {'met' if ok_rss else 'MISSED'})")
        return 0 if args.no_check or (ok_time and ok_rss) else 1


if __name__ == "__main__":
    sys.exit(main())
