"""The one-command demo: `ros2 run stud_planner demo [--part dome|shell|girder] [--out DIR]` (`bash demo.sh`).

Runs the whole weld cell in simulation on a bundled curved part -- the dome (slopes over 20 deg at
its outer studs), a tank-shell section (a horizontal cylinder) or a 6 m bridge girder welded from a rail
(``stud_bringup.demo_parts``) -- (`ros2 run stud_planner cell --mode sim`, the sequencer starting the job
by itself and ending the launch when done):
registration over the marking board, camera stations, matching, simulated welding of every
stud through the RM-65 controller simulator over TCP, with the topics recorded to an MCAP bag.
Then it scores the result against the scene's exact truth and prints a summary: the weld points
and normals against the truth, the steepest slope welded, and for every stud the gun's axis at the
weld -- forward kinematics of the joints the controller reported there (the weld journal) --
against the true normal; and the post-weld inspection's QA summary (every welded stud measured by
the camera and judged: lean, offset, standing height). Left in the output folder:
``weld_report.json`` (per stud: status, position, normal, welded), the QA record
``qa_report.json``/``.csv``/``.html`` (with ``qa/*.png``, each station's inspection overlay),
``summary.json``, ``overlays/*.png`` (the matcher's overlays), ``cell_bag/`` (rosbag2 MCAP, opens in
Foxglove), ``weld_journal.jsonl`` and every node's log. Exit code 0 only if every stud was welded
within the accuracy limits and passed its inspection, and the matcher matched no post-weld inspection
shot (the last ``/weld_targets`` is what it saw before the welds: no welded stud ``gun_blocked``).

The simulated camera is not mounted exactly where the cell believes: it renders through the cell's
hand-eye moved by :data:`CALIBRATION_RESIDUAL`, the error a good calibration leaves, so the weld
points carry what a calibrated real cell's carry (``--var true_hand_eye_*`` or ``hand_eye_*`` set up
a case of one's own instead).

The girder rides a rail whose simulated truth differs from the straight, exact one the cell believes
in (``demo_parts.GIRDER_RAIL_ERROR``): there the weld points and gun axes are judged where the gun
truly was (``demo_score.welds_from_journal``: the rail's true pose times the forward kinematics of the
journal's joints), at both ends of the part too, and the summary adds the registration residual per
station and the carriage positions (from the cell bag), the rail moves and the studs per hour. Its run
also records the camera's views (``sensor_bag/``: every station's shot with its pose in world, the
carriage in it) for ``--mode replay`` and ``plan`` (``tools/replay_check.py`` compares them).
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

from stud_bringup.demo_parts import PARTS, DemoPart
from stud_bringup.demo_score import accuracy_at_ends, cell_bag_summary, gun_axes_at_weld, score, welds_from_journal  # noqa: F401
from stud_common import names
from stud_common.frames import RailDeviation
from stud_common.strict_json import write_json

#: How far the simulated camera's true mount lies from the hand-eye the cell works with: (x, y, z) m
#: and (roll, pitch, yaw) deg in the weld tool's frame, 0.24 mm and 0.05 deg. The order a good
#: hand-eye calibration leaves on a real arm (the daily check accepts up to 0.5 mm / 0.15 deg); with
#: none the camera would sit exactly where the cell believes and every weld point would flatter us.
CALIBRATION_RESIDUAL = ((0.0002, -0.0001, 0.0001), (0.03, -0.02, 0.03))
#: ``--var`` names with which a user sets up a hand-eye case of their own (no residual added then).
_HAND_EYE_VARS = ("hand_eye_xyz_m", "hand_eye_rpy_deg", "hand_eye_file", "true_hand_eye_xyz_m",
                  "true_hand_eye_rpy_deg")


def sets_hand_eye(user_vars: list[str]) -> bool:
    """Whether ``user_vars`` (``NAME=VALUE``) set up a hand-eye case of their own."""
    return any(v.split("=", 1)[0].strip() in _HAND_EYE_VARS for v in user_vars)


def calibration_residual_vars(user_vars: list[str]) -> list[str]:
    """``--var`` arguments putting the simulated camera :data:`CALIBRATION_RESIDUAL` off the cell's
    typed hand-eye (cell.yaml's ``hand_eye_xyz_m`` / ``hand_eye_rpy_deg``); none when ``user_vars``
    set a hand-eye of their own."""
    from stud_bringup.launch import default_config_path, load_config
    from stud_common.rotations import matrix_to_rpy, transform_xyz_rpy

    if sets_hand_eye(user_vars):
        return []
    typed = load_config(default_config_path())["vars"]
    T = transform_xyz_rpy(typed["hand_eye_xyz_m"], typed["hand_eye_rpy_deg"]) @ transform_xyz_rpy(*CALIBRATION_RESIDUAL)
    xyz = [round(float(x), 7) for x in T[:3, 3]]
    rpy = [round(float(np.degrees(a)), 6) for a in matrix_to_rpy(T[:3, :3])]
    return ["--var", f"true_hand_eye_xyz_m={xyz}", "--var", f"true_hand_eye_rpy_deg={rpy}"]


def calibration_residual_size() -> tuple[float, float]:
    """(mm, deg): the translation and rotation angle of :data:`CALIBRATION_RESIDUAL`."""
    from stud_common.rotations import rpy_to_matrix
    from stud_perception.hand_eye_solvers import rotation_angle_deg

    R = rpy_to_matrix(*np.radians(CALIBRATION_RESIDUAL[1]))
    return 1e3 * float(np.linalg.norm(CALIBRATION_RESIDUAL[0])), float(rotation_angle_deg(R, np.eye(3)))


def share_file(package: str, relative: str) -> Path:
    """The installed file ``relative`` in ``package``'s share directory (ament index)."""
    from ament_index_python.packages import get_package_share_directory

    return Path(get_package_share_directory(package)) / relative


def export_overlays(bag_dir: Path, out_dir: Path) -> int:
    """The matcher's overlay images from the recorded bag as PNG files."""
    import cv2

    from stud_bag import open_bag
    from stud_perception import image_io

    if not bag_dir.exists():
        return 0
    out_dir.mkdir(parents=True, exist_ok=True)
    n = 0
    with open_bag(bag_dir) as bag:
        for item in bag.messages([names.WELD_TARGET_OVERLAY]):
            n += 1
            cv2.imwrite(str(out_dir / f"overlay_{n:02d}.png"), image_io.color_to_bgr(item.message()))
    return n


def last_weld_targets(bag_dir: Path) -> dict | None:
    """What the recorded bag says of the matcher's views: the last ``/weld_targets`` (its view index and
    the count per status) and how many ``/weld_targets`` carry the stamp of an ``/inspection/result``'s
    shot (a post-weld shot matched as a view: none, as the inspection shots have topics of their own)."""
    from stud_bag import open_bag

    if not bag_dir.exists():
        return None
    last, target_stamps, inspection_stamps = None, set(), set()
    with open_bag(bag_dir) as bag:
        for item in bag.messages([names.WELD_TARGETS, names.INSPECTION_RESULT]):
            msg = item.message()
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            if item.topic == names.INSPECTION_RESULT:
                inspection_stamps.add(stamp)
                continue
            target_stamps.add(stamp)
            counts: dict[str, int] = {}
            for t in msg.targets:
                counts[t.status_text] = counts.get(t.status_text, 0) + 1
            last = {"view": int(msg.view_index), "counts": counts,
                    "gun_blocked": sorted(t.stud_id for t in msg.targets if t.status_text == "gun_blocked")}
    if last is None:
        return None
    return {**last, "inspection_shots_matched": len(target_stamps & inspection_stamps)}


def _parse_args(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="demo", description="Run the simulated weld cell on a bundled curved part.")
    ap.add_argument("--part", choices=sorted(PARTS), default="dome",
                    help="; ".join(f"{name}: {part.description}" for name, part in PARTS.items()))
    ap.add_argument("--out", type=Path, default=Path("out") / "demo",
                    help="output folder (default: out/demo)")
    ap.add_argument("--no-hmi", action="store_true", help="do not start the web HMI")
    ap.add_argument("--time-scale", type=float, default=None,
                    help="arm simulator motion time factor (1 = real time; default: the part's, 0.25 for the dome)")
    ap.add_argument("--max-xy-error-mm", type=float, default=None,
                    help="accuracy limit on the weld points (default 1.0)")
    ap.add_argument("--max-z-error-mm", type=float, default=None,
                    help="limit on the weld points' height (default: the girder's 1.0; none for the dome and shell)")
    ap.add_argument("--max-normal-error-deg", type=float, default=None,
                    help="accuracy limit on the normals (default 1.0)")
    ap.add_argument("--max-gun-axis-error-deg", type=float, default=None,
                    help="limit on the gun's axis at each weld (forward kinematics) against the true normal "
                         "(default 1.5, the girder's 1.0)")
    ap.add_argument("--var", dest="vars", action="append", default=[], metavar="NAME=VALUE",
                    help="passed on to `cell` (a ${NAME} of cell.yaml), e.g. hand_eye_file=PATH or "
                         "'true_hand_eye_xyz_m=[0.056, -0.004, -0.097]' (docs/CALIBRATION.md)")
    ap.add_argument("--arm-port", type=int, default=8080, help="TCP port of the arm simulator (default: 8080)")
    ap.add_argument("--hmi-port", type=int, default=8090, help="port of the operator page (default: 8090)")
    args = ap.parse_args(argv)
    part = PARTS[args.part]
    for name in ("time_scale", "max_xy_error_mm", "max_z_error_mm", "max_normal_error_deg", "max_gun_axis_error_deg"):
        if getattr(args, name) is None:
            setattr(args, name, getattr(part, name))
    return args


def _clear_previous_run(out: Path) -> None:
    """A demo starts a new job: a new journal (and its mirror, else the driver would see the journal missing)."""
    if not out.exists():
        return
    for stale in ("weld_journal.jsonl", "weld_journal.jsonl.mirror", "weld_report.json", "summary.json",
                  "qa_report.json", "qa_report.csv", "qa_report.html"):
        (out / stale).unlink(missing_ok=True)
    import shutil

    for folder in ("cell_bag", "sensor_bag", "overlays", "qa"):
        shutil.rmtree(out / folder, ignore_errors=True)


def _cell_command(args: argparse.Namespace, out: Path) -> list[str]:
    """`ros2 run stud_planner cell --mode sim ...` for this demo (the sequencer starts and ends the job)."""
    part = PARTS[args.part]
    cmd = ["ros2", "run", "stud_planner", "cell", "--mode", "sim", "--out", str(out),
           "--set", "cell_sequencer.auto_start=true", "--set", "cell_sequencer.exit_when_done=true",
           "--var", f"arm_time_scale={args.time_scale}", "--var", f"arm_port={args.arm_port}",
           "--var", f"hmi_port={args.hmi_port}", "--var", f"part={args.part}", "--with", "bag_record",
           "--var", f"drawing={share_file('stud_planner', part.drawing)}",
           "--var", f"scene={share_file('stud_perception', part.scene)}"]
    if part.record_sensors:
        cmd += ["--with", "sensor_bag_record"]
    cmd += part.var_args()
    cmd += calibration_residual_vars(args.vars)
    for var in args.vars:
        cmd += ["--var", var]
    if args.no_hmi:
        cmd.append("--no-hmi")
    return cmd


def run_params(out: Path, node: str) -> dict:
    """The ROS parameters a node of this run had (``<out>/params/<node>.yaml``, the launcher writes it); {}
    when the file is missing."""
    import yaml

    f = out / "params" / f"{node}.yaml"
    if not f.exists():
        return {}
    return (yaml.safe_load(f.read_text()) or {}).get("/**", {}).get("ros__parameters", {}) or {}


def rail_of_run(out: Path, part: DemoPart, user_vars: list[str]) -> tuple[float, tuple[float, ...], RailDeviation]:
    """(rail length m, the base's mount on the carriage, the simulated rail's true deviation) of a run: the
    driver's and the camera's parameters of the run when written, else the part's and the user's vars."""
    import yaml

    driver, camera = run_params(out, "arm_driver"), run_params(out, "camera")
    given = {**part.cell_vars, **part.sim_vars,
             **{k.strip(): yaml.safe_load(v) for k, v in (u.split("=", 1) for u in user_vars if "=" in u)}}

    def value(name: str, params: dict, default):
        return params.get(name, given.get(name, default))

    length = float(value("rail_length_m", driver, 0.0))
    mount = (tuple(float(v) for v in value("rail_mount_xyz_m", driver, (0.0, 0.0, 0.0))) if length > 0
             else (0.0, 0.0, 0.0))
    deviation = RailDeviation(float(value("true_rail_scale_ppm", camera, 0.0)),
                              float(value("true_rail_offset_m", camera, 0.0)),
                              float(value("true_rail_yaw_urad_per_m", camera, 0.0))) if length > 0 else RailDeviation()
    return length, mount, deviation


def _welded_once(journal_file: Path) -> dict[str, int]:
    """Welded events per stud in the journal (every stud once, in a good run)."""
    from rm65_driver.journal.scan import read_records

    counts: dict[str, int] = {}
    if journal_file.exists():
        for rec in read_records(journal_file):
            if rec.get("event") == "welded":
                counts[str(rec["stud"])] = counts.get(str(rec["stud"]), 0) + 1
    return counts


def _evaluate(args: argparse.Namespace, out: Path, report: dict, code: int, elapsed: float) -> dict:
    """The run judged: ``summary`` (``summary.json`` without ``per_stud``) and what the printout
    needs (``acc`` with the per-stud rows, ``qa`` the QA record or None, ``qa_file``, ``elapsed_s``)."""
    part = PARTS[args.part]
    driver = run_params(out, "arm_driver")
    rail_m, mount, deviation = rail_of_run(out, part, args.vars)
    welds = welds_from_journal(out / "weld_journal.jsonl", float(driver.get("tool_offset_m", 0.15)), mount, deviation)
    acc = score(report, share_file("stud_perception", part.scene), welds=welds,
                plunge_m=float(driver.get("plunge_m", 0.0)))
    overlays = export_overlays(out / "cell_bag", out / "overlays")
    welded = sum(bool(t.get("welded")) for t in report["targets"])
    total = len(report["targets"])
    qa_file = out / "qa_report.json"
    qa = json.loads(qa_file.read_text()) if qa_file.exists() else None
    qa_counts = qa["summary"] if qa else {}
    last = last_weld_targets(out / "cell_bag")
    welded_ids = {t["stud_id"] for t in report["targets"] if t.get("welded")}
    matched_clean = (last is not None and last["inspection_shots_matched"] == 0
                     and not welded_ids & set(last["gun_blocked"]))
    per_stud = _welded_once(out / "weld_journal.jsonl")
    welded_once = set(per_stud) == welded_ids and all(n == 1 for n in per_stud.values())
    qa_ok = qa_counts.get("pass") == welded
    ok = (code == 0 and welded == total and welded_once and (qa_ok or not part.qa_must_pass) and matched_clean
          and acc["max_xy_error_mm"] <= args.max_xy_error_mm
          and (args.max_z_error_mm is None or acc["max_z_error_mm"] <= args.max_z_error_mm)
          and acc["max_normal_error_deg"] <= args.max_normal_error_deg and acc["gun_axes_checked"] == welded
          and acc["max_gun_axis_error_deg"] <= args.max_gun_axis_error_deg)
    summary = {"ok": ok, "part": args.part, "cell_exit_code": code, "studs_total": total, "studs_welded": welded,
               "welded_once": welded_once, "stations": report.get("stations"),
               "unreachable": report.get("unreachable", []),
               "unreachable_reasons": report.get("unreachable_reasons", {}),
               "time_s": round(elapsed, 1), "accuracy": {k: v for k, v in acc.items() if k != "studs"},
               "overlays": overlays, "qa_summary": qa_counts, "last_weld_targets": last,
               "qa_code": (qa.get("code") or {}).get("profile") if qa else None, "qa_all_pass": qa_ok,
               "qa_must_pass": part.qa_must_pass,
               "bend_tests": ((qa.get("sampling") or {}).get("counts") if qa else None)}
    if rail_m > 0:
        job = cell_bag_summary(out / "cell_bag")
        summary["rail"] = {"length_m": rail_m, "mount_xyz_m": list(mount), "true_scale_ppm": deviation.scale_ppm,
                           "true_offset_m": deviation.offset_m, "true_yaw_urad_per_m": deviation.yaw_urad_per_m,
                           **job["rail"]}
        summary["accuracy_at_ends"] = accuracy_at_ends(acc["studs"])
        summary["registrations"] = job["registrations"]
        summary["registrations_invalid"] = job["registrations_invalid"]
        summary["job_s"] = job["job_s"]
        summary["studs_per_hour"] = 3600.0 * welded / job["job_s"] if job["job_s"] else None
        summary["time_scale"] = args.time_scale
    return {"summary": summary, "acc": acc, "qa": qa, "qa_file": qa_file, "elapsed_s": elapsed}


#: Per-stud lines of the summary's gun-axis table: every stud of a bundled part up to this many, else the worst.
PER_STUD_LINES = 20


def _print_rail(summary: dict) -> None:
    """The summary's lines of a part welded from a rail: the rail and its simulated error, the accuracy at
    both ends of the part, the registration at each carriage position, the rail moves, the studs per hour."""
    rail = summary["rail"]
    print(f"   rail                {rail['length_m']:g} m, the arm's base {rail['mount_xyz_m']} m on the carriage; "
          f"simulated error {rail['true_scale_ppm']:g} ppm scale, {1e3 * rail['true_offset_m']:.2f} mm at zero, "
          f"{rail['true_yaw_urad_per_m']:g} urad/m bend (sim-only truth: the weld points above are where the gun "
          "truly was)")
    for name, end in summary["accuracy_at_ends"].items():
        print(f"   {name.replace('_', ' '):<20}x {end['x_m'][0]:.2f}-{end['x_m'][1]:.2f} m, {end['studs']} studs: max "
              f"{end['max_xy_error_mm']:.2f} mm XY, {end['max_z_error_mm']:.2f} mm Z, gun axis "
              f"{end['max_gun_axis_error_deg']:.2f} deg")
    regs = summary["registrations"]
    extrapolated = sum(r["extrapolated_m"] > 0 for r in regs)
    print(f"   registrations       {len(regs)} valid ({extrapolated} extrapolated, "
          f"{summary['registrations_invalid']} refused): per carriage position, each view's marks and residual "
          f"(RMS / largest mark, mm)")
    by_carriage: dict[str, list[str]] = {}
    for r in regs:
        where = f"{r['carriage_m']:.3f} m" if r["carriage_m"] is not None else "?"
        note = f", extrapolated {r['extrapolated_m']:.3f} m" if r["extrapolated_m"] > 0 else ""
        marks = ", ".join(r["marks"]) if len(r["marks"]) <= 3 else f"{r['marks'][0]}..{r['marks'][-1]}"
        by_carriage.setdefault(where, []).append(
            f"{len(r['marks'])} ({marks}) {r['residual_mm']:.3f} / {r['residual_max_mm']:.3f}{note}")
    for where, views in by_carriage.items():
        print(f"     carriage {where:>9}  " + "; ".join(views))
    print(f"   rail moves          {rail['moves']} moves, {rail['distance_m']:.2f} m travelled")
    rate = summary.get("studs_per_hour")
    print("   throughput          "
          + (f"{summary['studs_welded']} studs in {summary['job_s']:.0f} s of job: {rate:.0f} studs/h "
             f"at {summary['time_scale']:g}x motion time (real time: bench/bench_cycle_time.py "
             f"--part {summary['part']})" if rate else "the job's span is not in the cell bag"))


def _print_summary(args: argparse.Namespace, out: Path, report: dict, result: dict) -> None:
    summary, acc, qa = result["summary"], result["acc"], result["qa"]
    welded, total, overlays = summary["studs_welded"], summary["studs_total"], summary["overlays"]
    print()
    print("=" * 72)
    print(f" weld-cell demo ({args.part}): {'PASSED' if summary['ok'] else 'FAILED'}")
    print(f"   studs welded        {welded}/{total} over {report.get('stations')} camera station(s)"
          + (f", {len(report['unreachable'])} the arm cannot weld (named before any motion toward them):"
             if report.get("unreachable") else ""))
    for sid, why in (report.get("unreachable_reasons") or {sid: "" for sid in report.get("unreachable", [])}).items():
        print(f"     {sid:>8}  {why}")
    print("   camera mount        " + (
        "{:.2f} mm / {:.3f} deg off the hand-eye the cell uses (a calibration's residual, simulated)".format(
            *calibration_residual_size()) if not sets_hand_eye(args.vars) else "as set by --var"))
    print(f"   weld-point error    max {acc['max_xy_error_mm']:.2f} mm XY (mean {acc['mean_xy_error_mm']:.2f}), "
          f"max {acc['max_z_error_mm']:.2f} mm Z   [paper: 7.1 mm XY, 2.09 mm Z]")
    print(f"   normal error        max {acc['max_normal_error_deg']:.2f} deg; steepest slope welded "
          f"{acc['steepest_welded_slope_deg']:.1f} deg (the gun follows the normal)")
    print(f"   gun axis at weld    max {acc['max_gun_axis_error_deg']:.2f} deg from the true normal "
          f"(forward kinematics of the controller's joints, {acc['gun_axes_checked']} welds)")
    rows = [r for r in acc["studs"] if "gun_axis_error_deg" in r]
    if len(rows) > PER_STUD_LINES:  # a long part: its worst studs (summary.json has every one)
        rows = sorted(rows, key=lambda r: -max(r["xy_error_m"] * 1e3, r["z_error_m"] * 1e3, r["gun_axis_error_deg"]))
        print(f"     the {PER_STUD_LINES} worst of {len(acc['studs'])} (summary.json per_stud has every one):")
        rows = rows[:PER_STUD_LINES]
    for r in rows:
        print(f"     {r['stud_id']:>8}  slope {r['slope_deg']:5.1f} deg   gun axis {r['gun_axis_error_deg']:.2f} deg   "
              f"point {1e3 * r['xy_error_m']:.2f} mm XY, {1e3 * r['z_error_m']:.2f} mm Z")
    if "rail" in summary:
        _print_rail(summary)
    if qa:
        lim = qa["limits"]
        qa_counts = summary["qa_summary"]
        print("   QA (post-weld)      " + ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in qa_counts.items() if v)
              + f"  [lean <= {lim['max_lean_deg']:g} deg, base within {lim['position_tol_mm']:g} mm, "
              f"height {lim['nominal_length_mm']:g} +- {lim['height_tol_mm']:g} mm]")
        if not summary["qa_must_pass"]:
            print("                       (reported; this part's pass conditions are every stud welded once and the "
                  "weld points and the gun's axis against the truth)")
        for r in qa["studs"]:
            if r["verdict"] != "pass":
                print(f"     {r['stud_id']:>8}  {r['verdict']}: {'; '.join(r['reasons'])}")
        bends = summary.get("bend_tests")
        if qa.get("code"):
            print(f"   QA code             {qa['code']['title']}: collar {lim.get('min_collar_coverage_deg', 0):g} deg "
                  f">= {lim.get('min_collar_height_mm', 0):g} mm; {bends['listed'] if bends else 0} stud(s) to "
                  f"bend-test (seed {qa['sampling']['seed']}): qa_report.html")
    else:
        print(f"   QA (post-weld)      no QA record ({result['qa_file']} missing)")
    last = summary.get("last_weld_targets")
    if last is None:
        print("   last /weld_targets  none recorded")
    else:
        print(f"   last /weld_targets  view {last['view']}: "
              + ", ".join(f"{k} {v}" for k, v in sorted(last['counts'].items()))
              + f"; inspection shots matched as views: {last['inspection_shots_matched']}"
              + (f"; gun_blocked: {', '.join(last['gun_blocked'])}" if last["gun_blocked"] else ""))
    print(f"   time                {result['elapsed_s']:.0f} s "
          f"(arm simulator at {args.time_scale:g}x real motion time)")
    print(f"   output              {out}/  (weld_report.json, qa_report.json/.csv/.html, summary.json, "
          f"overlays/ [{overlays}], qa/, cell_bag/, " + ("sensor_bag/, " if PARTS[args.part].record_sensors else "")
          + "logs)")
    print("=" * 72)


def main(argv: list[str] | None = None) -> int:
    """Run the demo cell on the chosen part and score it; returns 0 if every check passed, else 1."""
    args = _parse_args(argv)
    out = args.out.resolve()
    _clear_previous_run(out)
    out.mkdir(parents=True, exist_ok=True)
    cmd = _cell_command(args, out)
    # Another cell on this machine with the same domain would mix with ours: say which one we use.
    print(f"demo: ROS_DOMAIN_ID={os.environ.get('ROS_DOMAIN_ID', '0')} (set ROS_DOMAIN_ID to run beside another "
          "cell; `ros2 topic list` in a shell with the same value sees this one)", flush=True)
    if not args.no_hmi:
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
    result = _evaluate(args, out, report, code, elapsed)
    write_json(out / "summary.json", {**result["summary"], "per_stud": result["acc"]["studs"]})
    _print_summary(args, out, report, result)
    return 0 if result["summary"]["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
