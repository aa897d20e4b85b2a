"""The hand-eye calibration file (``hand_eye.yaml``): writing it (reading it: stud_common.hand_eye_in_use).

``hand_eye_calibrator`` writes it; the camera, shot and arm-driver nodes read it when their
``hand_eye_file`` parameter is set (``--var hand_eye_file=PATH``) instead of the typed
``hand_eye_xyz_m`` / ``hand_eye_rpy_deg``. The transform is the camera optical frame in the
weld-tool frame (``T_tool_cam``), metres and degrees, roll-pitch-yaw as everywhere in the cell
(R = Rz(yaw) Ry(pitch) Rx(roll)). Layout (docs/CALIBRATION.md has every field)::

    format: stud_welding/hand_eye 1
    date: '2025-01-31T10:12:00+00:00'
    accepted: true
    hand_eye: {frame: weld_tool, child_frame: camera_color_optical_frame,
               xyz_m: [...], rpy_deg: [...], quaternion_xyzw: [...]}
    residuals: {position_rms_mm, position_max_mm, rotation_rms_deg, rotation_max_deg,
                reprojection_rms_px, intrinsics}
    poses: {used, refused, no_marks, rotation_spread_deg: [a, b, c]}
    board_in_world: {xyz_m, rpy_deg}
    methods: {tsai: {xyz_m, rpy_deg, differs_mm, differs_deg}, ...}
    methods_agree: true
    problems: []   warnings: []   limits: {...}   shots: [...]

Reading it, and refusing a file that must not be used, is :mod:`stud_common.hand_eye_in_use`.
"""
from __future__ import annotations

import datetime as _dt
import math
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from stud_common.hand_eye_in_use import CHILD_FRAME, FORMAT, FRAME, HandEyeInUse
from stud_common.rotations import matrix_to_quaternion, matrix_to_rpy
from stud_perception.hand_eye import HandEyeCheck, HandEyeResult


# -- writing ----------------------------------------------------------------------------------------
def _r(values, digits: int) -> list[float]:
    return [round(float(v), digits) for v in np.ravel(values)]


def _pose(T: np.ndarray) -> dict:
    return {"xyz_m": _r(T[:3, 3], 7), "rpy_deg": _r(np.degrees(matrix_to_rpy(T[:3, :3])), 5)}


def _num(v: float, digits: int = 4):
    return round(float(v), digits) if math.isfinite(v) else None


def now_iso() -> str:
    """The current time, ISO 8601 with the UTC offset, to the second."""
    return _dt.datetime.now(_dt.timezone.utc).astimezone().replace(microsecond=0).isoformat()


def calibration_record(result: HandEyeResult, *, date: str | None = None, poses_refused: int = 0,
                       poses_failed: int = 0, aimed_from: int = 0, believed_xyz_m=None, believed_rpy_deg=None,
                       note: str = "") -> dict:
    """The file's content for a calibration ``result`` (plain data, YAML-ready). ``poses_refused``:
    views the arm driver refused (unreachable); ``poses_failed``: views whose shot showed no marks;
    ``aimed_from``: shots the last estimate the views were aimed through came from (0: every view
    went through the believed hand-eye)."""
    q = matrix_to_quaternion(result.T_tool_cam[:3, :3])
    intrinsics = ("ok" if not math.isfinite(result.reprojection_rms_px)
                  or result.reprojection_rms_px <= result.limits.max_reprojection_px else
                  f"need attention: reprojection RMS {result.reprojection_rms_px:.2f} px > "
                  f"{result.limits.max_reprojection_px:g} px")
    record: dict[str, Any] = {
        "format": FORMAT,
        "date": date or now_iso(),
        "accepted": result.accepted,
        "hand_eye": {"frame": FRAME, "child_frame": CHILD_FRAME, **_pose(result.T_tool_cam),
                     "quaternion_xyzw": _r(q, 9)},
        "residuals": {"position_rms_mm": _num(result.rms_mm), "position_max_mm": _num(result.max_mm),
                      "rotation_rms_deg": _num(result.rms_deg), "rotation_max_deg": _num(result.max_deg),
                      "reprojection_rms_px": _num(result.reprojection_rms_px, 3), "intrinsics": intrinsics},
        "poses": {"used": int(result.n_shots), "refused": int(poses_refused), "no_marks": int(poses_failed),
                  "views_aimed_from_shots": int(aimed_from),
                  "rotation_spread_deg": _r(result.rotation_spread_deg, 2)},
        "board_in_world": _pose(result.T_world_board),
        "methods": {name: {**_pose(T), "differs_mm": _num(result.method_differences[name][0]),
                           "differs_deg": _num(result.method_differences[name][1])}
                    for name, T in result.methods.items()},
        "methods_agree": result.methods_agree,
        "problems": list(result.problems),
        "warnings": list(result.warnings),
        "limits": result.limits.as_dict(),
        "shots": [{"residual_mm": _num(mm), "residual_deg": _num(deg), "oa_error_mm": _num(c.oa_error_mm),
                   "ob_error_mm": _num(c.ob_error_mm), "angle_error_deg": _num(c.angle_error_deg)}
                  for mm, deg, c in zip(result.shot_residual_mm, result.shot_residual_deg, result.mark_checks)],
    }
    if believed_xyz_m is not None and believed_rpy_deg is not None:
        record["believed_before"] = {"xyz_m": _r(believed_xyz_m, 7), "rpy_deg": _r(believed_rpy_deg, 5)}
    if note:
        record["note"] = note
    return record


def check_record(check: HandEyeCheck, in_use: HandEyeInUse, *, date: str | None = None) -> dict:
    """What ``verify`` writes (``hand_eye_check.yaml``): the residuals of the calibration in use."""
    return {"format": "stud_welding/hand_eye_check 1", "date": date or now_iso(), "passed": check.passed,
            "calibration": in_use.summary(),
            "residuals": {"position_rms_mm": _num(check.rms_mm), "position_max_mm": _num(check.max_mm),
                          "rotation_rms_deg": _num(check.rms_deg), "rotation_max_deg": _num(check.max_deg),
                          "reprojection_rms_px": _num(check.reprojection_rms_px, 3)},
            "hand_eye_from_shots": None if check.T_tool_cam_shots is None else {
                "difference_mm": _num(check.difference_mm), "difference_deg": _num(check.difference_deg),
                "transform": _pose(check.T_tool_cam_shots)},
            # the difference's limits, from the marks' noise the shots show and their number (hand_eye_spread.py)
            "limits_from_noise": None if check.spread is None else {
                "mark_noise_along_ray_mm": _num(check.spread.noise.along_m * 1e3, 5),
                "mark_noise_across_ray_mm": _num(check.spread.noise.across_m * 1e3, 5),
                "noise_bound_mm": _num(check.spread.bound_mm), "noise_bound_deg": _num(check.spread.bound_deg),
                "limit_mm": _num(check.spread.limit_mm), "limit_deg": _num(check.spread.limit_deg),
                "conclusive": check.spread.conclusive, "views": check.spread.views,
                "views_needed": check.spread.views_needed},
            "board_in_world": _pose(check.T_world_board), "problems": list(check.problems),
            "shots": [{"residual_mm": _num(mm), "residual_deg": _num(deg)}
                      for mm, deg in zip(check.shot_residual_mm, check.shot_residual_deg)]}


def write_yaml(path: str | Path, record: dict, header: str) -> Path:
    """Write ``record`` to ``path`` (folders made) atomically: a reader never sees half a file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text("".join(f"# {line}\n" for line in header.splitlines()) +
                   yaml.safe_dump(record, sort_keys=False, default_flow_style=None, width=110))
    tmp.replace(path)
    return path
