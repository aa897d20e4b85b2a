"""The hand-eye transform a node uses (the camera optical frame in the weld-tool frame): the typed
values or a calibration file (``hand_eye.yaml``, written by stud_perception.hand_eye_file), and the
limits such a file must meet. The one loader every node that poses the camera uses (camera, shot, arm
driver, state publisher, pose_rebase), so it sits in the lowest package.

A file is refused (:class:`HandEyeFileError`, one line naming the file, the field and the value)
when it cannot be read, misses a field, its rotation forms disagree, it was not accepted, or its
residuals or pose spread are beyond the reader's :class:`HandEyeLimits`. The transform is in metres
and degrees, roll-pitch-yaw as everywhere in the cell (R = Rz(yaw) Ry(pitch) Rx(roll)).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from stud_common.rotations import (
    float3,
    matrix_to_quaternion,
    matrix_to_rpy,
    quaternion_to_matrix,
    rigid_inverse,
    rpy_to_matrix,
    transform,
)

FORMAT = "stud_welding/hand_eye 1"
FRAME = "weld_tool"
CHILD_FRAME = "camera_color_optical_frame"


@dataclass(frozen=True)
class HandEyeLimits:
    """What a calibration must meet to be used (and what ``verify`` checks).

    ``min_poses``: usable shots. ``min_rotation_spread_deg``: the poses' orientations must span
    at least this about each of two axes (:func:`rotation_spread_deg`; rotations about one axis
    leave part of ``X`` undetermined). ``max_rms_mm`` / ``max_shot_mm``: RMS over shots and the
    worst shot of the marks' residual (each shot: RMS of its three marks). ``max_rms_deg`` /
    ``max_shot_deg``: the same for the board orientation. ``mark_distance_tol_mm`` /
    ``mark_angle_tol_deg``: a shot's measured |OA|, |OB| and angle AOB against the drawing's.
    ``max_reprojection_px``: above it the intrinsics need attention (a warning, not a refusal).
    ``methods_agree_mm`` / ``methods_agree_deg``: closed-form methods within this of the refined
    result agree (reported, not a refusal). ``check_max_mm`` / ``check_max_deg``: the hand-eye error a check
    (``verify``) must catch: its own shots' hand-eye farther than this from the one checked fails it,
    whatever the noise; its pass limits are these less what the noise its shots show explains
    (stud_perception.hand_eye_spread), and it takes as many views as that noise needs.
    """

    min_poses: int = 12
    min_rotation_spread_deg: float = 30.0
    max_rms_mm: float = 0.5
    max_shot_mm: float = 1.0
    max_rms_deg: float = 0.2
    max_shot_deg: float = 0.5
    mark_distance_tol_mm: float = 1.5
    mark_angle_tol_deg: float = 1.0
    max_reprojection_px: float = 0.5
    methods_agree_mm: float = 2.0
    methods_agree_deg: float = 0.3
    check_max_mm: float = 0.5
    check_max_deg: float = 0.15

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0:
                raise ValueError(f"hand-eye limit {f.name} must be a positive number, got {value!r}")
        if self.min_poses < 3:
            raise ValueError(f"hand-eye limit min_poses must be at least 3, got {self.min_poses}")

    def as_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}



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


# -- reading ------------------------------------------------------------------------------------------
def camera_in_world(T_world_tool: np.ndarray, T_tool_cam: np.ndarray) -> np.ndarray:
    """The camera's optical frame in ``world`` (4x4): the ``weld_tool`` pose in world times the
    hand-eye (the optical frame in ``weld_tool``). The one place this product is written: the
    camera and shot nodes, the arm driver and the calibrator pose the camera with it."""
    return np.asarray(T_world_tool, dtype=np.float64) @ np.asarray(T_tool_cam, dtype=np.float64)


def tool_in_world(T_world_cam: np.ndarray, T_tool_cam: np.ndarray) -> np.ndarray:
    """The inverse question: the ``weld_tool`` pose (4x4) that puts the camera at ``T_world_cam``."""
    return np.asarray(T_world_cam, dtype=np.float64) @ rigid_inverse(np.asarray(T_tool_cam, dtype=np.float64))


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
        xyz_m=float3(xyz), rpy_deg=float3(np.degrees(matrix_to_rpy(R_q))),
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
    return HandEyeInUse(xyz_m=float3(xyz_m), rpy_deg=float3(rpy_deg))
