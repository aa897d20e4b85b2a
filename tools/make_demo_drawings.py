#!/usr/bin/env python3
"""(Re)generate the sample stud-layout drawings in ``src/stud_planner/data/``.

    python tools/make_demo_drawings.py [--out DIR]

Writes ``flat_plate_demo.dxf``: a 600 x 400 mm flat plate, 4 x 3 studs of 19 mm on a 150 x
100 mm grid, marks O, A, B (30 mm circles, labelled) at three corners; mm, R2010, the drawing
frame rotated by 15 deg and shifted in the WCS so that the frame transform is exercised.
Only small files (< 50 kB) are committed. The demo dome drawing is written from the demo
scene through :func:`stud_planner.drawing.dxf_writer.write_scene_drawing` (same format), once that
scene exists.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Sequence

import numpy as np

REPO = Path(__file__).resolve().parents[1]
try:
    from stud_planner.drawing.dxf_writer import LayoutDxfOptions, write_scene_drawing
except ImportError:  # run from a checkout without the workspace sourced
    sys.path.insert(0, str(REPO / "src" / "stud_planner"))
    from stud_planner.drawing.dxf_writer import LayoutDxfOptions, write_scene_drawing

DATA_DIR = REPO / "src" / "stud_planner" / "data"
MAX_COMMITTED_BYTES = 50_000

# Flat plate: marks at the plate corners, studs on a grid inside (drawing frame, metres).
FLAT_PLATE_MARKS = {"O": (0.0, 0.0), "A": (0.6, 0.0), "B": (0.0, 0.4)}
FLAT_PLATE_STUDS = np.array([(0.075 + 0.15 * i, 0.1 + 0.1 * j) for j in range(3) for i in range(4)])


def write_flat_plate(path: str | Path) -> Path:
    return write_scene_drawing(path, FLAT_PLATE_STUDS, FLAT_PLATE_MARKS,
                               LayoutDxfOptions(rotation_deg=15.0, origin_wcs_m=(1.2, 0.8)))


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1].strip())
    parser.add_argument("--out", type=Path, default=DATA_DIR, help=f"output folder (default {DATA_DIR})")
    args = parser.parse_args(argv)
    for name, writer in (("flat_plate_demo.dxf", write_flat_plate),):
        path = writer(args.out / name)
        size = path.stat().st_size
        note = "" if size < MAX_COMMITTED_BYTES else f"  (> {MAX_COMMITTED_BYTES} bytes: do not commit)"
        print(f"{path}  {size} bytes{note}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
