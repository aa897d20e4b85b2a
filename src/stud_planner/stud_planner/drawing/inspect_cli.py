"""``drawing_inspect FILE.dxf``: what the stud planner reads from a drawing, before anything moves.

Prints the DXF version, units, stud layers and count, the marks and the frame they define,
the rule that identified the marks and every warning. ``--json`` writes the layout
(:meth:`DrawingLayout.to_dict`), ``--png`` a preview (OpenCV): studs with ids, marks, and the
drawing frame's x (red) and y (green) axes.

Any failure -- a bad argument, a drawing the parser refuses, a file ezdxf chokes on, a drawing
that asks for more block expansion than its work budget allows (``--max-expanded-entities`` and
the other limits of :class:`~stud_planner.drawing.limits.DrawingLimits`) -- is one line
``drawing_inspect: error: <message>`` on stderr and exit code 2; never a traceback.
"""
from __future__ import annotations

import argparse
import logging
import math
import sys
from pathlib import Path
from typing import Sequence

import numpy as np

from stud_common.strict_json import write_json
from stud_planner.drawing import DrawingError, DrawingLayout, LayoutOptions, read_layout, units_to_metres
from stud_planner.drawing.limits import add_limit_arguments, cli_hint, limits_from_args

PROG = "drawing_inspect"


class _UsageError(Exception):
    pass


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):  # argparse would print the usage and exit; we want one line
        raise _UsageError(message)


def _unit(text: str) -> str:
    try:
        units_to_metres(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def _png_path(text: str) -> Path:
    path = Path(text)
    if path.suffix.lower() != ".png":
        raise argparse.ArgumentTypeError(f"{text}: the preview is a PNG, name it *.png")
    return path


def _build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog=PROG, description="Inspect a stud-layout DXF drawing (studs, marks O/A/B, frame).")
    p.add_argument("file", type=Path, help="the DXF drawing")
    p.add_argument("--png", type=_png_path, help="write a preview image (studs, ids, marks, frame axes)")
    p.add_argument("--json", type=Path, help="write the layout as JSON (drawing frame, metres)")
    # one value per option use (repeat it for more), so a file name after it is not swallowed
    p.add_argument("--stud-layers", action="extend", nargs=1, metavar="PATTERN",
                   help="stud layer name or fnmatch pattern, case-insensitive; repeat for more (default: STUDS)")
    p.add_argument("--mark-layer", action="extend", nargs=1, metavar="PATTERN",
                   help="layer of the mark circles O, A, B; repeat for more (default: MARKS)")
    p.add_argument("--units-if-unitless", default="mm", type=_unit,
                   help="unit of a drawing without $INSUNITS: mm, cm, m, in, ft ... (default: mm)")
    p.add_argument("--include-hidden-layers", action="store_true",
                   help="also read frozen or off layers (skipped by default, as CAD does not show them)")
    p.add_argument("--min-diameter-mm", type=float, help="ignore stud circles smaller than this")
    p.add_argument("--max-diameter-mm", type=float, help="ignore stud circles larger than this")
    p.add_argument("--min-spacing-mm", type=float,
                   help="warn about studs closer than this (default: 2.5 x the median stud diameter)")
    p.add_argument("--max-ids", type=int, default=400,
                   help="label stud ids in the preview only up to this many studs (default: 400)")
    add_limit_arguments(p)
    return p


def _z(v: float) -> float:
    """Print float noise (|v| < 5 nm) as 0 rather than -0.0000."""
    return 0.0 if abs(v) < 5e-9 else v


def _fmt_len(metres: float) -> str:
    return f"{metres * 1e3:.3f} mm" if abs(metres) < 10 else f"{metres:.4f} m"


def summary(layout: DrawingLayout) -> str:
    """Human-readable multi-line summary of ``layout``."""
    L = layout
    u = L.source_units
    lines = [
        f"file:         {L.source_file}",
        f"DXF version:  {L.dxf_version} ({L.dxf_release}), read with "
        + ("ezdxf.readfile" if L.read_mode == "read" else "ezdxf.recover (file was damaged)"),
        f"units:        {u}"
        + (" (assumed: the drawing is unitless)" if L.units_assumed else f" ($INSUNITS {L.insunits})")
        + f", {L.metres_per_unit:g} m per unit",
    ]
    counts = {lay: 0 for lay in L.stud_layers}
    for s in L.studs:
        counts[s.layer] += 1
    d = np.array([s.diameter_m for s in L.studs])
    lines.append("stud layers:  " + ", ".join(f"{lay} ({n})" for lay, n in counts.items()))
    lines.append(f"studs:        {len(L.studs)}, diameter {np.median(d) * 1e3:.2f} mm median "
                 f"({d.min() * 1e3:.2f} .. {d.max() * 1e3:.2f} mm), ids {L.studs[0].id} .. {L.studs[-1].id}")
    xmin, ymin, xmax, ymax = L.bbox_m
    lines.append(f"stud extent:  x {xmin:.4f} .. {xmax:.4f} m, y {ymin:.4f} .. {ymax:.4f} m (drawing frame)")
    rule = {"labels": "by their O/A/B labels", "geometry": "by geometry (right angle at O, B counter-clockwise from A)"}
    lines.append(f"marks:        found {rule.get(L.marks_rule, L.marks_rule)} [marks_rule={L.marks_rule}]")
    for m in L.marks.values():
        lines.append(f"  {m.name}  WCS ({m.wcs_x:.3f}, {m.wcs_y:.3f}) {u}  ->  "
                     f"drawing ({_z(m.x_m):.4f}, {_z(m.y_m):.4f}) m,"
                     f" diameter {m.diameter_m * 1e3:.2f} mm, layer {m.layer}")
    O, A = L.mark_o, L.mark_a
    heading = math.degrees(math.atan2(A.wcs_y - O.wcs_y, A.wcs_x - O.wcs_x))
    lines.append(f"frame:        origin O, x toward A (|OA| {_fmt_len(A.x_m)}, heading {heading:.2f} deg in WCS), "
                 f"y toward B (|OB| {_fmt_len(math.hypot(L.mark_b.x_m, L.mark_b.y_m))}), "
                 f"angle AOB {L.angle_aob_deg:.3f} deg, "
                 + ("MIRRORED w.r.t. the DXF" if L.mirrored else "right-handed"))
    if L.reference_marks:
        lines.append(f"reference marks: {len(L.reference_marks)} ({L.reference_marks[0].name} .. "
                     f"{L.reference_marks[-1].name}), drawing frame")
        lines += [f"  {m.name}  ({_z(m.x_m):.4f}, {_z(m.y_m):.4f}) m, diameter {m.diameter_m * 1e3:.2f} mm"
                  for m in L.reference_marks]
    if L.warnings:
        lines.append(f"warnings:     {len(L.warnings)}")
        lines += [f"  - {w}" for w in L.warnings]
    else:
        lines.append("warnings:     none")
    return "\n".join(lines)


def render_preview(layout: DrawingLayout, path: Path, size_px: int = 1600, max_ids: int = 400) -> None:
    """Write a PNG preview: studs (blue) with ids, marks and reference marks (red) with names, frame axes from O."""
    try:
        import cv2
    except ImportError as exc:
        raise DrawingError(f"{path}: --png needs OpenCV (cv2): {exc}") from exc
    studs = layout.studs_xy_m()
    all_marks = (*layout.marks.values(), *layout.reference_marks)
    marks = np.array([(m.x_m, m.y_m) for m in all_marks])
    pts = np.vstack([studs, marks, [[0.0, 0.0]]])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    pad = 0.08 * max(float(np.max(hi - lo)), 1e-6)
    lo, hi = lo - pad, hi + pad
    scale = (size_px - 1) / float(np.max(hi - lo))
    w, h = int(math.ceil((hi[0] - lo[0]) * scale)) + 1, int(math.ceil((hi[1] - lo[1]) * scale)) + 1
    band = 40  # title band above the drawing
    img = np.full((h + band, w, 3), 255, np.uint8)

    def px(xy) -> tuple[int, int]:  # drawing y up -> image rows down
        return int(round((xy[0] - lo[0]) * scale)), band + int(round((hi[1] - xy[1]) * scale))

    font, fs = cv2.FONT_HERSHEY_SIMPLEX, max(0.3, size_px / 3200)
    O = (layout.mark_o.x_m, layout.mark_o.y_m)
    axis_len = 0.5 * min(layout.mark_a.x_m, math.hypot(layout.mark_b.x_m, layout.mark_b.y_m))
    cv2.arrowedLine(img, px(O), px((axis_len, 0.0)), (0, 0, 220), 2, cv2.LINE_AA, tipLength=0.03)
    cv2.arrowedLine(img, px(O), px((0.0, axis_len)), (0, 160, 0), 2, cv2.LINE_AA, tipLength=0.03)
    cv2.putText(img, "x", px((axis_len, 0.0)), font, 2 * fs, (0, 0, 220), 2, cv2.LINE_AA)
    cv2.putText(img, "y", px((0.0, axis_len)), font, 2 * fs, (0, 160, 0), 2, cv2.LINE_AA)
    label_ids = len(layout.studs) <= max_ids
    for s in layout.studs:
        c = px((s.x_m, s.y_m))
        r = max(2, int(round(s.diameter_m / 2 * scale)))
        cv2.circle(img, c, r, (200, 90, 0), 1 if r > 3 else -1, cv2.LINE_AA)
        if label_ids:
            cv2.putText(img, s.id, (c[0] + r + 2, c[1] - r - 2), font, fs, (80, 40, 0), 1, cv2.LINE_AA)
    for m in all_marks:
        c = px((m.x_m, m.y_m))
        r = max(4, int(round(m.diameter_m / 2 * scale)))
        cv2.circle(img, c, r, (0, 0, 220), 2, cv2.LINE_AA)
        cv2.putText(img, m.name, (c[0] + r + 3, c[1] + r + 3), font, 2 * fs, (0, 0, 220), 2, cv2.LINE_AA)
    title = (f"{Path(layout.source_file).name}: {len(layout.studs)} studs, marks by {layout.marks_rule}, "
             f"{len(layout.warnings)} warnings")
    cv2.putText(img, title, (10, 24), font, 1.5 * fs, (0, 0, 0), 1, cv2.LINE_AA)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), img):
        raise DrawingError(f"{path}: cannot write the PNG preview")


def _run(argv: Sequence[str] | None) -> int:
    args = _build_parser().parse_args(argv)

    def mm(v):
        return None if v is None else v * 1e-3

    try:
        limits = limits_from_args(args)
    except ValueError as exc:
        raise _UsageError(str(exc)) from None

    options = LayoutOptions(
        stud_layers=args.stud_layers or ["STUDS"], mark_layer=args.mark_layer or ["MARKS"],
        units_if_unitless=args.units_if_unitless, min_diameter_m=mm(args.min_diameter_mm),
        max_diameter_m=mm(args.max_diameter_mm), min_spacing_m=mm(args.min_spacing_mm),
        include_hidden_layers=args.include_hidden_layers, limits=limits,
    )
    layout = read_layout(args.file, options)
    print(summary(layout))
    if args.json:
        try:
            write_json(args.json, layout.to_dict())
        except OSError as exc:
            raise DrawingError(f"{args.json}: cannot write JSON ({exc.strerror or exc})") from exc
        print(f"json:         {args.json}")
    if args.png:
        try:
            render_preview(layout, args.png, max_ids=args.max_ids)
        except OSError as exc:
            raise DrawingError(f"{args.png}: cannot write PNG ({exc.strerror or exc})") from exc
        print(f"png:          {args.png}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Console entry point; returns the exit code (0 ok, 2 error, 130 interrupted)."""
    # ezdxf logs oddities of weird files at WARNING; the CLI's contract is its own output only
    logging.getLogger("ezdxf").addHandler(logging.NullHandler())
    try:
        return _run(argv)
    except SystemExit as exc:  # --help / --version
        return int(exc.code or 0) if isinstance(exc.code, int) else 0
    except KeyboardInterrupt:
        return 130
    except (_UsageError, DrawingError) as exc:
        message = str(exc) + (cli_hint(exc) if isinstance(exc, DrawingError) else "")
    except Exception as exc:  # anything ezdxf or the file system throws at the boundary
        message = f"unexpected {type(exc).__name__}: {exc}"
    print(f"{PROG}: error: {' '.join(message.split())}", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
