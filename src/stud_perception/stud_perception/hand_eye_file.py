"""The hand-eye calibration file (``hand_eye.yaml``): writing it, and the one loader every node uses.

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

A file is refused (:class:`HandEyeFileError`, one line naming the file, the field and the value)
when it cannot be read, misses a field, its rotation forms disagree, it was not accepted, or its
residuals or pose spread are beyond the reader's :class:`~stud_perception.hand_eye.HandEyeLimits`.
"""
from __future__ import annotations

import datetime as _dt
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from stud_perception.hand_eye import HandEyeCheck, HandEyeLimits, HandEyeResult, transform
from stud_perception.rotations import matrix_to_quaternion, matrix_to_rpy, quaternion_to_matrix, rpy_to_matrix

FORMAT = "stud_welding/hand_eye 1"
FRAME = "weld_tool"
CHILD_FRAME = "camera_color_optical_frame"


class HandEyeFileError(ValueError):
    """A calibration file that cannot be used: the message names the file, the field and the value."""


@dataclass(frozen=True)
class HandEyeInUse:
    """The hand-eye transform a node uses, and where it comes from.

    ``xyz_m`` (3,) and ``rpy_deg`` (3,): the optical frame in the weld-tool frame. ``source``:
    ``"parameters"`` (the typed values) or ``"file"``; ``path``, ``date`` and the residual figures
    only for a file (NaN otherwise)."""

    xyz_m: tuple[float, float, float]
    rpy_deg: tuple[float, float, float]
    source: str = "parameters"
    path: str = ""
    date: str = ""
    position_rms_mm: float = float("nan")
    position_max_mm: float = float("nan")
    rotation_rms_deg: float = float("nan")
    rotation_max_deg: float = float("nan")
    poses_used: int = 0
    rotation_spread_deg: tuple[float, ...] = ()
    reprojection_rms_px: float = float("nan")

    @property
    def T_tool_cam(self) -> np.ndarray:
        return transform(rpy_to_matrix(*np.radians(self.rpy_deg)), self.xyz_m)

    def summary(self) -> dict:
        """Plain data for /calibration/hand_eye (JSON): NaN figures become null."""
        def num(v):
            return None if isinstance(v, float) and not math.isfinite(v) else v

        return {"source": self.source, "path": self.path, "date": self.date or None,
                "xyz_m": list(self.xyz_m), "rpy_deg": list(self.rpy_deg),
                "quaternion_xyzw": [float(v) for v in matrix_to_quaternion(rpy_to_matrix(*np.radians(self.rpy_deg)))],
                "position_rms_mm": num(self.position_rms_mm), "position_max_mm": num(self.position_max_mm),
                "rotation_rms_deg": num(self.rotation_rms_deg), "rotation_max_deg": num(self.rotation_max_deg),
                "poses_used": self.poses_used, "rotation_spread_deg": list(self.rotation_spread_deg),
                "reprojection_rms_px": num(self.reprojection_rms_px)}


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
                       poses_failed: int = 0, believed_xyz_m=None, believed_rpy_deg=None, note: str = "") -> dict:
    """The file's content for a calibration ``result`` (plain data, YAML-ready). ``poses_refused``:
    views the arm driver refused (unreachable); ``poses_failed``: views whose shot showed no marks."""
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


# -- reading ------------------------------------------------------------------------------------------
def _field(data: dict, dotted: str, path: Path) -> Any:
    node: Any = data
    for key in dotted.split("."):
        if not isinstance(node, dict) or key not in node:
            raise HandEyeFileError(f"{path}: missing field {dotted}")
        node = node[key]
    return node


def _vector(data: dict, dotted: str, n: int, path: Path) -> np.ndarray:
    value = _field(data, dotted, path)
    try:
        arr = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        arr = np.zeros(0)
    if arr.shape != (n,) or not np.isfinite(arr).all():
        raise HandEyeFileError(f"{path}: {dotted} must be {n} finite numbers, got {value!r}")
    return arr


def _number(data: dict, dotted: str, path: Path) -> float:
    value = _field(data, dotted, path)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise HandEyeFileError(f"{path}: {dotted} must be a finite number, got {value!r}")
    return float(value)


def load_hand_eye_file(path: str | Path, limits: HandEyeLimits = HandEyeLimits()) -> HandEyeInUse:
    """Read and check a calibration file; :class:`HandEyeFileError` says why it cannot be used."""
    path = Path(path).expanduser()
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise HandEyeFileError(f"{path}: cannot read the calibration file: {exc.strerror or exc}") from None
    except yaml.YAMLError as exc:
        raise HandEyeFileError(f"{path}: not valid YAML: {' '.join(str(exc).split())}") from None
    if not isinstance(data, dict):
        raise HandEyeFileError(f"{path}: not a calibration file (a mapping with format: {FORMAT!r} expected)")
    if data.get("format") != FORMAT:
        raise HandEyeFileError(f"{path}: format is {data.get('format')!r}, expected {FORMAT!r}")
    for key, want in (("hand_eye.frame", FRAME), ("hand_eye.child_frame", CHILD_FRAME)):
        if _field(data, key, path) != want:
            raise HandEyeFileError(f"{path}: {key} is {_field(data, key, path)!r}, expected {want!r}")
    xyz = _vector(data, "hand_eye.xyz_m", 3, path)
    rpy = _vector(data, "hand_eye.rpy_deg", 3, path)
    q = _vector(data, "hand_eye.quaternion_xyzw", 4, path)
    if abs(np.linalg.norm(q) - 1.0) > 1e-3:
        raise HandEyeFileError(f"{path}: hand_eye.quaternion_xyzw {q.tolist()} is not a unit quaternion")
    R_rpy, R_q = rpy_to_matrix(*np.radians(rpy)), quaternion_to_matrix(*q)
    if math.degrees(math.acos(np.clip((np.trace(R_rpy.T @ R_q) - 1) / 2, -1, 1))) > 1e-3:
        raise HandEyeFileError(f"{path}: hand_eye.rpy_deg {rpy.tolist()} and quaternion_xyzw {q.tolist()} "
                               "are different rotations (edited by hand?)")
    if _field(data, "accepted", path) is not True:
        problems = data.get("problems") or []
        raise HandEyeFileError(f"{path}: accepted is {data.get('accepted')!r}: the calibration was refused"
                               + (f" ({problems[0]})" if problems else ""))
    date = _field(data, "date", path)
    figures = {k: _number(data, f"residuals.{k}", path)
               for k in ("position_rms_mm", "position_max_mm", "rotation_rms_deg", "rotation_max_deg")}
    used = _field(data, "poses.used", path)
    if isinstance(used, bool) or not isinstance(used, int):
        raise HandEyeFileError(f"{path}: poses.used must be a whole number, got {used!r}")
    spread = _vector(data, "poses.rotation_spread_deg", 3, path)
    reproj = data.get("residuals", {}).get("reprojection_rms_px")
    in_use = HandEyeInUse(
        xyz_m=tuple(float(v) for v in xyz), rpy_deg=tuple(float(v) for v in np.degrees(matrix_to_rpy(R_q))),
        source="file", path=str(path.resolve()), date=str(date), poses_used=used,
        rotation_spread_deg=tuple(float(v) for v in spread),
        reprojection_rms_px=float(reproj) if isinstance(reproj, (int, float)) else float("nan"), **figures)
    problems = limit_problems(in_use, limits)
    if problems:
        raise HandEyeFileError(f"{path}: refused: {problems[0]}" + (f" (and {len(problems) - 1} more)"
                                                                     if len(problems) > 1 else ""))
    return in_use


def limit_problems(cal: HandEyeInUse, limits: HandEyeLimits) -> list[str]:
    """A calibration's recorded figures against ``limits`` (empty: within them)."""
    problems = []
    if cal.poses_used < limits.min_poses:
        problems.append(f"poses.used {cal.poses_used}: too few poses, need at least {limits.min_poses}")
    spread = sorted(cal.rotation_spread_deg, reverse=True) + [0.0, 0.0]
    if spread[0] < limits.min_rotation_spread_deg:
        problems.append(f"poses.rotation_spread_deg {list(cal.rotation_spread_deg)}: rotations too small, need "
                        f"{limits.min_rotation_spread_deg:g} deg about two axes")
    elif spread[1] < limits.min_rotation_spread_deg:
        problems.append(f"poses.rotation_spread_deg {list(cal.rotation_spread_deg)}: rotations about one axis "
                        f"only, need {limits.min_rotation_spread_deg:g} deg about two axes")
    for name, value, limit, unit in (("position_rms_mm", cal.position_rms_mm, limits.max_rms_mm, "mm"),
                                     ("position_max_mm", cal.position_max_mm, limits.max_shot_mm, "mm"),
                                     ("rotation_rms_deg", cal.rotation_rms_deg, limits.max_rms_deg, "deg"),
                                     ("rotation_max_deg", cal.rotation_max_deg, limits.max_shot_deg, "deg")):
        if value > limit:
            problems.append(f"residuals.{name} {value:g} {unit} exceeds the limit {limit:g} {unit}")
    return problems


def resolve_hand_eye(hand_eye_file: str, xyz_m, rpy_deg, limits: HandEyeLimits = HandEyeLimits()) -> HandEyeInUse:
    """The hand-eye a node uses: the calibration file when one is given, else the typed values.
    The one place that decides (camera, shot and driver nodes all call it)."""
    if hand_eye_file:
        return load_hand_eye_file(hand_eye_file, limits)
    return HandEyeInUse(xyz_m=tuple(float(v) for v in xyz_m), rpy_deg=tuple(float(v) for v in rpy_deg))
