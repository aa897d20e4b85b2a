"""Hand-eye calibration of the eye-in-hand camera on the marking board (pure numpy, no ROS).

Frames and names: ``T_a_b`` is the 4x4 pose of frame ``b`` in frame ``a`` (``p_a = T_a_b p_b``),
metres. ``world`` is the RM-65 base, ``tool`` the weld-tool frame of ``ArmState.tool_pose``,
``cam`` the optical frame ``camera_color_optical_frame``, ``board`` the drawing frame on the
board's top (origin at mark O, the drawing's x and y, z = x cross y, up out of the board).

The unknowns are the hand-eye transform ``X = T_tool_cam`` (what the cell's ``hand_eye_xyz_m`` /
``hand_eye_rpy_deg`` are) and the board's pose ``T_world_board``. Every shot gives the arm's
``T_world_tool_i`` and the marks O, A, B measured in ``cam`` (pixel + depth, Eq. 1). Three marks
are a full board pose per shot, ``T_cam_board_i``, so the classical ``A X = X B`` applies with
``A = T_tool_i^-1 T_tool_j`` (the tool's motion) and ``B = T_cam_board_i T_cam_board_j^-1``:

1. closed-form estimates by several methods (Tsai-Lenz, Park-Martin, Andreff; OpenCV's
   ``calibrateHandEye`` as well when the installed OpenCV has it -- the pinned 5.0 wheel does not),
   and whether they agree (:mod:`stud_perception.hand_eye_solvers`, with :class:`HandEyeError`);
2. a least-squares refinement of ``X`` and ``T_world_board`` together on the 3D mark positions
   (Levenberg-Marquardt over all shots), which is what the result is;
3. residuals per shot (marks in mm, board orientation in degrees), the spread of the poses
   used, the intrinsics' reprojection RMS, and the checks against :class:`HandEyeLimits`: too
   few poses, rotations too small or about one axis only, a shot whose marks disagree with the
   drawing, residuals too large. A result with problems is not ``accepted``.

:func:`check_hand_eye` measures the residual of a given ``X`` on a few new shots (the board pose
is fitted, ``X`` is held): the daily verification.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from stud_common.hand_eye_in_use import HandEyeLimits
from stud_common.rotations import matrix_to_quaternion, matrix_to_rpy, rigid_inverse, transform
from stud_perception.hand_eye_solvers import (
    HandEyeError,
    project_so3,
    rotation_angle_deg,
    rotation_exp,
    rotation_log,
    solve_ax_xb,
)
from stud_perception.hand_eye_spread import CheckLimits, check_limits, measure_mark_noise, solution_covariance

__all__ = ["BoardShot", "MarkCheck", "HandEyeResult", "HandEyeCheck",
           "board_points_m", "board_pose_from_marks", "check_marks", "rotation_spread_deg", "pose_set_problems",
           "calibrate_hand_eye", "check_hand_eye", "check_with_enough_views", "rebase_camera_pose"]


@dataclass(frozen=True, eq=False)
class BoardShot:
    """One shot of the board: the arm's ``T_world_tool`` (4, 4) when the image was taken, the marks
    O, A, B in the optical frame ``marks_cam_m`` (3, 3), metres, and optionally their sub-pixel
    image centres ``marks_uv_px`` (3, 2) with the intrinsics ``K`` (3, 3) of those pixels (for the
    reprojection RMS)."""

    T_world_tool: np.ndarray
    marks_cam_m: np.ndarray
    marks_uv_px: np.ndarray | None = None
    K: np.ndarray | None = None

    def __post_init__(self) -> None:
        T = np.asarray(self.T_world_tool, dtype=np.float64)
        P = np.asarray(self.marks_cam_m, dtype=np.float64)
        if T.shape != (4, 4) or not np.isfinite(T).all():
            raise HandEyeError(f"T_world_tool must be a finite 4x4 transform, got shape {T.shape}")
        if P.shape != (3, 3) or not np.isfinite(P).all():
            raise HandEyeError(f"marks_cam_m must be finite O, A, B (3, 3), got shape {P.shape}")
        object.__setattr__(self, "T_world_tool", T)
        object.__setattr__(self, "marks_cam_m", P)
        if self.marks_uv_px is not None:
            object.__setattr__(self, "marks_uv_px", np.asarray(self.marks_uv_px, dtype=np.float64).reshape(3, 2))
        if self.K is not None:
            object.__setattr__(self, "K", np.asarray(self.K, dtype=np.float64).reshape(3, 3))


# -- small geometry ---------------------------------------------------------------------------------
def rebase_camera_pose(T_world_cam: np.ndarray, T_tool_cam_recorded: np.ndarray,
                       T_tool_cam_in_use: np.ndarray) -> np.ndarray:
    """A camera pose made with one hand-eye, re-made with another: the tool pose it came from
    (``T_world_cam @ inv(T_tool_cam_recorded)``) times the hand-eye in use. All 4x4 rigid transforms."""
    return (np.asarray(T_world_cam, dtype=np.float64)
            @ rigid_inverse(np.asarray(T_tool_cam_recorded, dtype=np.float64))
            @ np.asarray(T_tool_cam_in_use, dtype=np.float64))


# -- per shot -----------------------------------------------------------------------------------------
def board_points_m(drawing_marks_m) -> np.ndarray:
    """(3, 3) marks O, A, B in the board frame: the drawing's (x, y) on the board top, z = 0."""
    D = np.asarray(drawing_marks_m, dtype=np.float64)
    if D.shape != (3, 2) or not np.isfinite(D).all():
        raise HandEyeError(f"drawing marks must be finite O, A, B (3, 2), got shape {D.shape}")
    return np.column_stack([D, np.zeros(3)])


def _kabsch(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """T with ``dst ~ T src`` (least squares), points (N, 3)."""
    cs, cd = src.mean(axis=0), dst.mean(axis=0)
    H = (src - cs).T @ (dst - cd)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return transform(R, cd - R @ cs)


def board_pose_from_marks(marks_cam_m: np.ndarray, board_pts_m: np.ndarray) -> np.ndarray:
    """``T_cam_board`` (4, 4) from the measured O, A, B (3, 3) in ``cam`` and the same marks in the
    board frame (:func:`board_points_m`): three non-collinear points fix a full pose."""
    return _kabsch(board_pts_m, marks_cam_m)


@dataclass(frozen=True)
class MarkCheck:
    """A shot's marks against the drawing: measured minus drawing |OA|, |OB| (mm) and angle AOB (deg)."""

    oa_error_mm: float
    ob_error_mm: float
    angle_error_deg: float

    def problem(self, limits: HandEyeLimits) -> str | None:
        bad = []
        if abs(self.oa_error_mm) > limits.mark_distance_tol_mm:
            bad.append(f"|OA| off by {self.oa_error_mm:+.2f} mm")
        if abs(self.ob_error_mm) > limits.mark_distance_tol_mm:
            bad.append(f"|OB| off by {self.ob_error_mm:+.2f} mm")
        if abs(self.angle_error_deg) > limits.mark_angle_tol_deg:
            bad.append(f"angle AOB off by {self.angle_error_deg:+.2f} deg")
        return None if not bad else (
            f"marks disagree with the drawing ({', '.join(bad)}; tolerance {limits.mark_distance_tol_mm:g} mm, "
            f"{limits.mark_angle_tol_deg:g} deg)")


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(math.atan2(float(np.linalg.norm(np.cross(a, b))), float(a @ b)))


def check_marks(marks_m: np.ndarray, drawing_marks_m) -> MarkCheck:
    """|OA|, |OB| and angle AOB of measured marks (3, 3), any frame, against the drawing's (3, 2)."""
    P = np.asarray(marks_m, dtype=np.float64)
    D = board_points_m(drawing_marks_m)
    return MarkCheck(
        oa_error_mm=1e3 * float(np.linalg.norm(P[1] - P[0]) - np.linalg.norm(D[1] - D[0])),
        ob_error_mm=1e3 * float(np.linalg.norm(P[2] - P[0]) - np.linalg.norm(D[2] - D[0])),
        angle_error_deg=_angle_deg(P[1] - P[0], P[2] - P[0]) - _angle_deg(D[1] - D[0], D[2] - D[0]))


# -- the pose set -------------------------------------------------------------------------------------
def rotation_spread_deg(R_world_tool: np.ndarray) -> np.ndarray:
    """How far the orientations (N, 3, 3) spread, about their three principal axes: (3,) degrees,
    largest first.

    Each orientation's rotation vector relative to the set's mean orientation; the extents
    (max - min) of those vectors along their principal directions. Tilting the camera both ways
    about one axis by 15 deg spreads 30 deg about that axis and 0 about the others.
    """
    R = np.asarray(R_world_tool, dtype=np.float64)
    if len(R) < 2:
        return np.zeros(3)
    R_mean = project_so3(R.sum(axis=0))
    r = np.degrees(rotation_log(R @ R_mean.T))
    r = r - r.mean(axis=0)
    _, _, Vt = np.linalg.svd(r, full_matrices=False)
    proj = r @ Vt.T
    spread = np.zeros(3)
    spread[:proj.shape[1]] = np.ptp(proj, axis=0)
    return np.sort(spread)[::-1]


def pose_set_problems(R_world_tool: np.ndarray, limits: HandEyeLimits) -> list[str]:
    """Why a set of tool orientations (N, 3, 3) cannot give a trustworthy calibration (empty: it can)."""
    n = len(R_world_tool)
    problems = []
    if n < limits.min_poses:
        problems.append(f"too few poses: {n} usable shot(s), need at least {limits.min_poses}")
    spread = rotation_spread_deg(R_world_tool) if n >= 2 else np.zeros(3)
    need = limits.min_rotation_spread_deg
    if spread[0] < need:
        problems.append(f"rotations too small: the poses' orientations span {spread[0]:.1f} deg, need {need:g} deg "
                        "about two axes")
    elif spread[1] < need:
        problems.append(f"rotations about one axis only: {spread[0]:.1f} deg about one axis but {spread[1]:.1f} deg "
                        f"about any other, need {need:g} deg about two axes")
    return problems

# -- least squares on the marks --------------------------------------------------------------------------
def _predict(X: np.ndarray, T_world_board: np.ndarray, T_world_tool: np.ndarray, board_pts: np.ndarray):
    """Marks predicted in ``cam`` (N, 3, 3) and the predicted ``T_cam_board`` (N, 4, 4)."""
    T_cam_board = rigid_inverse(T_world_tool @ X) @ T_world_board
    P = np.einsum("nij,kj->nki", T_cam_board[:, :3, :3], board_pts) + T_cam_board[:, None, :3, 3]
    return P, T_cam_board


def _perturb(T: np.ndarray, d: np.ndarray) -> np.ndarray:
    """T moved by d = (rotation vector (3,), translation (3,)): R <- exp(w) R, t <- t + v."""
    return transform(rotation_exp(d[:3]) @ T[:3, :3], T[:3, 3] + d[3:])


def _refine(X: np.ndarray, T_world_board: np.ndarray, T_world_tool: np.ndarray, marks: np.ndarray,
            board_pts: np.ndarray, solve_x: bool = True, ray_weight: float = 1.0,
            iterations: int = 50) -> tuple[np.ndarray, np.ndarray]:
    """Levenberg-Marquardt on the marks' 3D residuals in ``cam`` (metres): ``X`` and ``T_world_board``
    (or the board alone when ``solve_x`` is false). The problem is tiny (12 unknowns), so the
    Jacobian is by central differences."""
    n_free = 12 if solve_x else 6

    def unpack(x):
        return (_perturb(X, x[:6]) if solve_x else X), _perturb(T_world_board, x[-6:])

    # The residual along each mark's viewing ray (its depth) counts ``ray_weight`` as much as across
    # it: structured-light depth is several times noisier than the sub-pixel centre.
    rays = marks / np.linalg.norm(marks, axis=2, keepdims=True)

    def residual(x):
        Xi, Bi = unpack(x)
        e = _predict(Xi, Bi, T_world_tool, board_pts)[0] - marks
        along = np.sum(e * rays, axis=2, keepdims=True)
        return (e - (1.0 - ray_weight) * along * rays).ravel()

    lam = 1e-3
    r = residual(np.zeros(n_free))
    cost = cost_old = float(r @ r)
    eps = 1e-7
    for _ in range(iterations):
        J = np.empty((r.size, n_free))
        for k in range(n_free):
            d = np.zeros(n_free)
            d[k] = eps
            J[:, k] = (residual(d) - residual(-d)) / (2 * eps)
        H, g = J.T @ J, J.T @ r
        improved = False
        while lam < 1e8:
            step = -np.linalg.solve(H + lam * np.diag(np.diag(H) + 1e-12), g)
            r_new = residual(step)
            if r_new @ r_new < cost:
                X, T_world_board = unpack(step)
                r, cost_old, cost = r_new, cost, float(r_new @ r_new)
                lam = max(lam / 10, 1e-9)
                improved = True
                break
            lam *= 10
        if not improved or (cost_old - cost) < 1e-14 * max(cost_old, 1e-30) or np.linalg.norm(step) < 1e-12:
            break
    return X, T_world_board


def _mean_pose(T: np.ndarray) -> np.ndarray:
    return transform(project_so3(T[:, :3, :3].sum(axis=0)), T[:, :3, 3].mean(axis=0))


# -- results ----------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class _Residuals:
    shot_mm: np.ndarray       # (N,) RMS of each shot's three marks
    shot_deg: np.ndarray      # (N,) board orientation, predicted vs measured
    reprojection_px: float    # RMS over every mark with pixels and K (NaN without)


def _residuals(X, T_world_board, shots, board_pts) -> _Residuals:
    T_world_tool = np.stack([s.T_world_tool for s in shots])
    marks = np.stack([s.marks_cam_m for s in shots])
    P, T_cb_pred = _predict(X, T_world_board, T_world_tool, board_pts)
    shot_mm = 1e3 * np.sqrt(np.mean(np.sum((P - marks) ** 2, axis=2), axis=1))
    T_cb_meas = np.stack([board_pose_from_marks(s.marks_cam_m, board_pts) for s in shots])
    shot_deg = rotation_angle_deg(T_cb_pred[:, :3, :3], T_cb_meas[:, :3, :3])
    err2 = []
    for s, p in zip(shots, P):
        if s.marks_uv_px is None or s.K is None:
            continue
        uvw = p @ s.K.T
        err2.append(np.sum((uvw[:, :2] / uvw[:, 2:3] - s.marks_uv_px) ** 2, axis=1))
    reproj = float(np.sqrt(np.mean(np.concatenate(err2)))) if err2 else float("nan")
    return _Residuals(shot_mm, shot_deg, reproj)


def _rms(a: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(a)))) if len(a) else float("nan")


def _residual_problems(res: _Residuals, limits: HandEyeLimits, orientation_rms: bool = True) -> list[str]:
    """Residuals beyond the limits. ``orientation_rms``: also the RMS of the board orientation residual
    (a calibration's many shots; a check of a few tests the hand-eye they give instead)."""
    problems = []
    rms_mm, rms_deg = _rms(res.shot_mm), _rms(res.shot_deg)
    worst = int(np.argmax(res.shot_mm))
    worst_deg = int(np.argmax(res.shot_deg))
    if rms_mm > limits.max_rms_mm:
        problems.append(f"residual RMS {rms_mm:.3f} mm exceeds {limits.max_rms_mm:g} mm")
    if res.shot_mm[worst] > limits.max_shot_mm:
        problems.append(f"shot {worst + 1}: residual {res.shot_mm[worst]:.3f} mm exceeds {limits.max_shot_mm:g} mm")
    if orientation_rms and rms_deg > limits.max_rms_deg:
        problems.append(f"orientation residual RMS {rms_deg:.3f} deg exceeds {limits.max_rms_deg:g} deg")
    if res.shot_deg[worst_deg] > limits.max_shot_deg:
        problems.append(f"shot {worst_deg + 1}: orientation residual {res.shot_deg[worst_deg]:.3f} deg exceeds "
                        f"{limits.max_shot_deg:g} deg")
    return problems


def _difference(T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    """(translation mm, rotation deg) between two transforms."""
    return (1e3 * float(np.linalg.norm(T_a[:3, 3] - T_b[:3, 3])),
            float(rotation_angle_deg(T_a[:3, :3], T_b[:3, :3])))


@dataclass(frozen=True, eq=False)
class HandEyeResult:
    """A hand-eye calibration. ``T_tool_cam`` (4, 4): the result (refined); ``T_world_board`` (4, 4):
    the board; ``methods``: closed-form estimates, name -> (4, 4), and ``method_differences``:
    name -> (mm, deg) from the refined result; ``shot_residual_mm`` / ``shot_residual_deg`` (N,);
    ``reprojection_rms_px`` (NaN without pixels); ``rotation_spread_deg`` (3,); ``problems``:
    why it must not be used (empty: ``accepted``); ``warnings``: what needs attention anyway."""

    T_tool_cam: np.ndarray
    T_world_board: np.ndarray
    methods: dict
    method_differences: dict
    shot_residual_mm: np.ndarray
    shot_residual_deg: np.ndarray
    reprojection_rms_px: float
    rotation_spread_deg: np.ndarray
    n_shots: int
    limits: HandEyeLimits
    problems: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()
    mark_checks: tuple[MarkCheck, ...] = field(default=())

    @property
    def accepted(self) -> bool:
        return not self.problems

    @property
    def methods_agree(self) -> bool:
        return all(mm <= self.limits.methods_agree_mm and deg <= self.limits.methods_agree_deg
                   for mm, deg in self.method_differences.values())

    @property
    def xyz_m(self) -> np.ndarray:
        return self.T_tool_cam[:3, 3].copy()

    @property
    def rpy_deg(self) -> np.ndarray:
        return np.degrees(matrix_to_rpy(self.T_tool_cam[:3, :3]))

    @property
    def quaternion_xyzw(self) -> np.ndarray:
        return matrix_to_quaternion(self.T_tool_cam[:3, :3])

    @property
    def rms_mm(self) -> float:
        return _rms(self.shot_residual_mm)

    @property
    def max_mm(self) -> float:
        return float(np.max(self.shot_residual_mm))

    @property
    def rms_deg(self) -> float:
        return _rms(self.shot_residual_deg)

    @property
    def max_deg(self) -> float:
        return float(np.max(self.shot_residual_deg))


def _shot_problems(shots, drawing_marks_m, limits) -> tuple[list[str], list[MarkCheck]]:
    checks = [check_marks(s.marks_cam_m, drawing_marks_m) for s in shots]
    problems = [f"shot {i + 1}: {p}" for i, c in enumerate(checks) if (p := c.problem(limits))]
    return problems, checks


#: Weight of a mark's residual along its viewing ray (its depth) relative to across it in the least
#: squares: the board depth behind a mark (about 0.004 mm RMS along the ray after the ring's plane
#: fit, at 0.5 mm depth noise) is several times noisier than the sub-pixel centre (about 0.001 mm
#: across it at 0.3 m), measured on rendered calibration shots.
RAY_WEIGHT = 0.2

#: A check solves the hand-eye from its own shots only when their orientations spread this much about
#: two axes (``rotation_spread_deg``); the cell's check views spread 30-60 deg.
CHECK_MIN_SPREAD_DEG = 15.0


def calibrate_hand_eye(shots: list[BoardShot], drawing_marks_m, limits: HandEyeLimits = HandEyeLimits(),
                       ray_weight: float = RAY_WEIGHT) -> HandEyeResult:
    """Solve ``X = T_tool_cam`` and ``T_world_board`` from board shots (module docstring).

    Always returns a result when one can be computed (its ``problems`` say whether it may be
    used); :class:`HandEyeError` when none can (fewer than three shots, degenerate motions)."""
    shots = list(shots)
    if len(shots) < 3:
        raise HandEyeError(f"too few poses: {len(shots)} usable shot(s), need at least {limits.min_poses}")
    board_pts = board_points_m(drawing_marks_m)
    problems, checks = _shot_problems(shots, drawing_marks_m, limits)
    T_world_tool = np.stack([s.T_world_tool for s in shots])
    problems += pose_set_problems(T_world_tool[:, :3, :3], limits)
    T_cam_board = np.stack([board_pose_from_marks(s.marks_cam_m, board_pts) for s in shots])
    methods = solve_ax_xb(T_world_tool, T_cam_board)
    # Start from the closed-form estimate that fits the marks best, then refine X and the board together.
    marks = np.stack([s.marks_cam_m for s in shots])

    def fit(X):
        T_wb = _mean_pose(T_world_tool @ X @ T_cam_board)
        return float(np.sum((_predict(X, T_wb, T_world_tool, board_pts)[0] - marks) ** 2)), T_wb

    start = min(methods, key=lambda name: fit(methods[name])[0])
    X, T_world_board = _refine(methods[start], fit(methods[start])[1], T_world_tool, marks, board_pts,
                                 ray_weight=ray_weight)
    res = _residuals(X, T_world_board, shots, board_pts)
    problems += _residual_problems(res, limits)
    warnings = []
    if np.isfinite(res.reprojection_px) and res.reprojection_px > limits.max_reprojection_px:
        warnings.append(f"the camera intrinsics need attention: the marks reproject with an RMS of "
                        f"{res.reprojection_px:.2f} px (above {limits.max_reprojection_px:g} px)")
    diffs = {name: _difference(T, X) for name, T in methods.items()}
    disagree = [f"{n} {mm:.2f} mm / {deg:.3f} deg" for n, (mm, deg) in diffs.items()
                if mm > limits.methods_agree_mm or deg > limits.methods_agree_deg]
    if disagree:
        warnings.append("closed-form methods disagree with the refined result: " + ", ".join(disagree))
    return HandEyeResult(
        T_tool_cam=X, T_world_board=T_world_board, methods=methods, method_differences=diffs,
        shot_residual_mm=res.shot_mm, shot_residual_deg=res.shot_deg, reprojection_rms_px=res.reprojection_px,
        rotation_spread_deg=rotation_spread_deg(T_world_tool[:, :3, :3]), n_shots=len(shots), limits=limits,
        problems=tuple(problems), warnings=tuple(warnings), mark_checks=tuple(checks))


@dataclass(frozen=True, eq=False)
class HandEyeCheck:
    """:func:`check_hand_eye`: the residuals of a given hand-eye on new shots and whether they pass."""

    shot_residual_mm: np.ndarray
    shot_residual_deg: np.ndarray
    reprojection_rms_px: float
    T_world_board: np.ndarray
    problems: tuple[str, ...]
    #: The hand-eye the check's own shots give (solved from them alone), and how far the one checked
    #: is from it: (mm, deg). None / NaN when the shots' rotations cannot determine it.
    T_tool_cam_shots: np.ndarray | None = None
    difference_mm: float = float("nan")
    difference_deg: float = float("nan")
    #: The limits the difference was held to, from the marks' noise the shots show and their number
    #: (:mod:`stud_perception.hand_eye_spread`); None when the difference was not tested.
    spread: CheckLimits | None = None

    @property
    def passed(self) -> bool:
        return not self.problems

    @property
    def rms_mm(self) -> float:
        return _rms(self.shot_residual_mm)

    @property
    def max_mm(self) -> float:
        return float(np.max(self.shot_residual_mm))

    @property
    def rms_deg(self) -> float:
        return _rms(self.shot_residual_deg)

    @property
    def max_deg(self) -> float:
        return float(np.max(self.shot_residual_deg))


def _mark_jacobian(X: np.ndarray, T_world_board: np.ndarray, T_world_tool: np.ndarray, board_pts: np.ndarray,
                   eps: float = 1e-7) -> np.ndarray:
    """d(marks predicted in ``cam``) / d(X's rotation vector and translation, the board's): (3m, 12)."""
    def marks(d):
        return _predict(_perturb(X, d[:6]), _perturb(T_world_board, d[6:]), T_world_tool, board_pts)[0].ravel()

    J = np.empty((3 * 3 * len(T_world_tool), 12))
    for k in range(12):
        d = np.zeros(12)
        d[k] = eps
        J[:, k] = (marks(d) - marks(-d)) / (2 * eps)
    return J


def check_spread(X_shots: np.ndarray, T_world_board: np.ndarray, T_world_tool: np.ndarray, marks: np.ndarray,
                 board_pts: np.ndarray, limits: HandEyeLimits, reference_views: int = 0) -> CheckLimits:
    """The limits of a check whose own shots give ``X_shots`` and the board ``T_world_board`` (the full
    fit): the marks' noise measured on its residuals, the spread of ``X_shots`` it implies, and the limits
    that catch an error of ``check_max_mm`` / ``check_max_deg`` (:mod:`stud_perception.hand_eye_spread`)."""
    J = _mark_jacobian(X_shots, T_world_board, T_world_tool, board_pts)
    m = marks.reshape(-1, 3)
    rays = m / np.linalg.norm(m, axis=1, keepdims=True)
    residuals = _predict(X_shots, T_world_board, T_world_tool, board_pts)[0].reshape(-1, 3) - m
    noise = measure_mark_noise(residuals, rays, J, RAY_WEIGHT)
    cov = solution_covariance(J, rays, RAY_WEIGHT, noise)
    return check_limits(cov, noise, len(T_world_tool), limits.check_max_mm, limits.check_max_deg, reference_views)


def check_hand_eye(shots: list[BoardShot], T_tool_cam: np.ndarray, drawing_marks_m,
                   limits: HandEyeLimits = HandEyeLimits(), reference_views: int = 0) -> HandEyeCheck:
    """How well ``T_tool_cam`` explains a few shots of the board. Two tests:

    * the residuals: the board pose is fitted (it may have been moved since the calibration), the
      hand-eye is held; a wrong hand-eye makes the shots disagree about where the board is. The
      marks' residuals (``max_rms_mm``, ``max_shot_mm``) and each shot's board orientation
      (``max_shot_deg``) are checked.
    * the difference: the hand-eye is solved from the check's shots alone and compared with the one
      checked. This sees what the residuals hardly show: a rotation about the optical axis moves
      marks near the image centre little, and the few views' orientation residuals carry it at a
      fraction of its size, under the three marks' noise. Its limits follow from the marks' noise
      the shots show and their number (:func:`check_spread`): an error of ``check_max_mm`` /
      ``check_max_deg`` fails, a correct hand-eye passes, each but with probability ``ALPHA``; when
      the noise is too large for the views to tell the two apart the check fails as inconclusive and
      ``spread.views_needed`` says how many views would do. ``reference_views``: the shots of the
      calibration checked (its own error counts; 0: taken as exact). It needs rotations about two
      axes (``CHECK_MIN_SPREAD_DEG``); with fewer, it is skipped.

    Needs two shots at least (more, at different tilts, see more)."""
    shots = list(shots)
    if len(shots) < 2:
        raise HandEyeError(f"a check needs at least 2 shots, got {len(shots)}")
    board_pts = board_points_m(drawing_marks_m)
    problems, _ = _shot_problems(shots, drawing_marks_m, limits)
    T_world_tool = np.stack([s.T_world_tool for s in shots])
    marks = np.stack([s.marks_cam_m for s in shots])
    X = np.asarray(T_tool_cam, dtype=np.float64)
    T_cam_board = np.stack([board_pose_from_marks(s.marks_cam_m, board_pts) for s in shots])
    _, T_world_board = _refine(X, _mean_pose(T_world_tool @ X @ T_cam_board), T_world_tool, marks, board_pts,
                               solve_x=False, ray_weight=RAY_WEIGHT)
    res = _residuals(X, T_world_board, shots, board_pts)
    problems += _residual_problems(res, limits, orientation_rms=False)
    X_shots, mm, deg, spread = None, float("nan"), float("nan"), None
    if len(shots) >= 3 and rotation_spread_deg(T_world_tool[:, :3, :3])[1] >= CHECK_MIN_SPREAD_DEG:
        X_shots, T_world_board_shots = _refine(X, T_world_board, T_world_tool, marks, board_pts, ray_weight=RAY_WEIGHT)
        mm, deg = _difference(X, X_shots)
        spread = check_spread(X_shots, T_world_board_shots, T_world_tool, marks, board_pts, limits, reference_views)
        if not spread.conclusive:
            remedy = (f"take at least {spread.views_needed} views" if spread.views_needed else
                      f"no number of views will do: the calibration's own {reference_views} shots leave it "
                      "too uncertain at this noise; recalibrate with more poses")
            problems.append(f"inconclusive: {spread.describe()}, so an error of {limits.check_max_mm:g} mm / "
                            f"{limits.check_max_deg:g} deg could hide in it; {remedy}")
        elif mm > spread.limit_mm or deg > spread.limit_deg:
            problems.append(f"the check's shots put the hand-eye {mm:.2f} mm / {deg:.3f} deg from the one checked "
                            f"(limits {spread.limit_mm:.2f} mm / {spread.limit_deg:.3f} deg: the "
                            f"{limits.check_max_mm:g} mm / {limits.check_max_deg:g} deg to catch, less what noise "
                            f"explains)")
    return HandEyeCheck(res.shot_mm, res.shot_deg, res.reprojection_px, T_world_board, tuple(problems),
                        X_shots, mm, deg, spread)


def check_with_enough_views(shoot: Callable[[int], list[BoardShot]], T_tool_cam: np.ndarray, drawing_marks_m,
                            limits: HandEyeLimits = HandEyeLimits(), reference_views: int = 0, first_views: int = 5,
                            max_views: int = 60, on_more: Callable[[HandEyeCheck, int], None] | None = None,
                            rounds: int = 4) -> HandEyeCheck:
    """``verify``'s procedure: ``shoot(k)`` takes ``k`` more shots (fewer when views fail) of the check
    views, again as often as asked. It starts with ``first_views``; while the noise the shots show needs
    more views to tell a ``check_max`` error from noise (``spread.views_needed``), it takes more, up to
    ``max_views`` in all (the measured noise settles as shots come in: a few rounds). ``on_more(check,
    wanted)`` hears of each round. Returns the last check (inconclusive, and so failed, when even
    ``max_views`` would not do)."""
    shots = list(shoot(first_views))
    check = check_hand_eye(shots, T_tool_cam, drawing_marks_m, limits, reference_views)
    for _ in range(rounds):
        spread = check.spread
        if spread is None or spread.conclusive or len(shots) >= max_views:
            break
        # none would do by this estimate: take all there may be, the noise is measured better with them
        wanted = min(spread.views_needed or max_views, max_views)
        if on_more is not None:
            on_more(check, wanted)
        more = list(shoot(wanted - len(shots)))
        if not more:
            break
        shots += more
        check = check_hand_eye(shots, T_tool_cam, drawing_marks_m, limits, reference_views)
    return check
