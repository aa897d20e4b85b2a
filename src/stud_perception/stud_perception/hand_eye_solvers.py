"""Closed-form hand-eye solvers of ``A X = X B`` and the rotation helpers the calibration shares
(pure numpy, no ROS).

``A = T_tool_i^-1 T_tool_j`` is the tool's motion between two shots and ``B = T_cam_board_i
T_cam_board_j^-1`` the board's, seen by the camera; ``X = T_tool_cam`` (names as in
:mod:`stud_perception.hand_eye`, which refines the estimates on the marks). Methods: Tsai-Lenz,
Park-Martin, Andreff, and OpenCV's ``calibrateHandEye`` as a cross-check when the installed OpenCV
has it (the pinned 5.0 wheel does not). :class:`HandEyeError` is the calibration's one error.
"""
from __future__ import annotations

import math

import numpy as np

from stud_common.rotations import matrix_to_quaternion, rigid_inverse, transform

__all__ = ["HandEyeError", "METHODS", "project_so3", "rotation_angle_deg", "rotation_exp", "rotation_log", "skew",
           "solve_ax_xb"]


class HandEyeError(ValueError):
    """Shots from which no hand-eye transform can be computed at all (the message says why)."""



def rotation_log(R: np.ndarray) -> np.ndarray:
    """Rotation vectors (..., 3), radians, of rotations (..., 3, 3) (through quaternions: stable near pi)."""
    q = matrix_to_quaternion(R)
    s = np.linalg.norm(q[..., :3], axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(s, q[..., 3:4])
    return np.where(s > 1e-12, q[..., :3] * angle / np.maximum(s, 1e-300), 2.0 * q[..., :3])


def rotation_exp(w: np.ndarray) -> np.ndarray:
    """Rotation (3, 3) of a rotation vector (3,), radians (Rodrigues)."""
    angle = float(np.linalg.norm(w))
    if angle < 1e-12:
        return np.eye(3) + skew(w)
    k = skew(np.asarray(w) / angle)
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


def skew(v) -> np.ndarray:
    """The cross-product matrix (3, 3) of a 3-vector v: ``skew(v) @ w == np.cross(v, w)``."""
    x, y, z = np.asarray(v, dtype=np.float64).reshape(3)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def project_so3(M: np.ndarray) -> np.ndarray:
    """The rotation closest to M (3, 3) (Frobenius norm)."""
    U, _, Vt = np.linalg.svd(M)
    return U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt


def rotation_angle_deg(R_a: np.ndarray, R_b: np.ndarray) -> np.ndarray:
    """Angle (deg) of ``R_a^T R_b`` for rotations (..., 3, 3)."""
    c = (np.einsum("...ij,...ij->...", R_a, R_b) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))



# -- closed form: A X = X B -----------------------------------------------------------------------------
def _motion_pairs(T_world_tool: np.ndarray, T_cam_board: np.ndarray, min_angle_deg: float = 2.0):
    """(A, B) motions (M, 4, 4) of every pair of shots whose tool rotates by at least ``min_angle_deg``."""
    n = len(T_world_tool)
    i, j = np.triu_indices(n, k=1)
    A = rigid_inverse(T_world_tool[i]) @ T_world_tool[j]
    B = T_cam_board[i] @ rigid_inverse(T_cam_board[j])
    keep = np.linalg.norm(rotation_log(A[:, :3, :3]), axis=1) > math.radians(min_angle_deg)
    if keep.sum() < 2:
        raise HandEyeError("fewer than two motions between the shots rotate the tool: the hand-eye "
                           "rotation is undetermined")
    return A[keep], B[keep]


def _translation_ls(A: np.ndarray, B: np.ndarray, R_X: np.ndarray) -> np.ndarray:
    """t_X from (R_A - I) t_X = R_X t_B - t_A, least squares over the motions."""
    M = (A[:, :3, :3] - np.eye(3)).reshape(-1, 3)
    b = (np.einsum("ij,mj->mi", R_X, B[:, :3, 3]) - A[:, :3, 3]).reshape(-1)
    return np.linalg.lstsq(M, b, rcond=None)[0]


def _tsai(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Tsai & Lenz (1989): rotation from modified Rodrigues vectors, then the translation."""
    def rodrigues_mod(R):
        w = rotation_log(R)
        angle = np.linalg.norm(w, axis=1, keepdims=True)
        return 2.0 * np.sin(angle / 2.0) * w / np.maximum(angle, 1e-300)

    Pg, Pc = rodrigues_mod(A[:, :3, :3]), rodrigues_mod(B[:, :3, :3])
    M = np.concatenate([skew(s) for s in Pg + Pc])
    p_prime = np.linalg.lstsq(M, (Pc - Pg).reshape(-1), rcond=None)[0]
    p = 2.0 * p_prime / math.sqrt(1.0 + p_prime @ p_prime)
    n2 = p @ p
    R = (1.0 - n2 / 2.0) * np.eye(3) + 0.5 * (np.outer(p, p) + math.sqrt(max(4.0 - n2, 0.0)) * skew(p))
    R = project_so3(R)
    return transform(R, _translation_ls(A, B, R))


def _park(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Park & Martin (1994): R_X = (M^T M)^(-1/2) M^T with M = sum beta alpha^T (log maps)."""
    alpha, beta = rotation_log(A[:, :3, :3]), rotation_log(B[:, :3, :3])
    M = beta.T @ alpha  # sum_i beta_i alpha_i^T
    w, V = np.linalg.eigh(M.T @ M)
    if w.min() <= 1e-12 * max(w.max(), 1e-300):
        raise HandEyeError("the tool's rotations are all about one axis: the hand-eye rotation is undetermined")
    R = project_so3(V @ np.diag(w ** -0.5) @ V.T @ M.T)
    return transform(R, _translation_ls(A, B, R))


def _andreff(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Andreff et al. (2001), linear: R_A R_X = R_X R_B as (R_A (x) I - I (x) R_B^T) vec(R_X) = 0."""
    rows = [np.kron(a[:3, :3], np.eye(3)) - np.kron(np.eye(3), b[:3, :3].T) for a, b in zip(A, B)]
    _, _, Vt = np.linalg.svd(np.concatenate(rows))
    R = Vt[-1].reshape(3, 3)  # row-major vec
    R = project_so3(R * np.sign(np.linalg.det(R)))
    return transform(R, _translation_ls(A, B, R))


def _opencv_methods() -> dict:
    """OpenCV's calibrateHandEye methods, when this OpenCV has the function (5.0's Python wheel has not)."""
    try:
        import cv2
    except ImportError:
        return {}
    if not hasattr(cv2, "calibrateHandEye"):
        return {}

    def method(flag):
        def solve(T_world_tool, T_cam_board):
            R, t = cv2.calibrateHandEye(list(T_world_tool[:, :3, :3]), list(T_world_tool[:, :3, 3]),
                                        list(T_cam_board[:, :3, :3]), list(T_cam_board[:, :3, 3]), method=flag)
            return transform(np.asarray(R), np.asarray(t).reshape(3))
        return solve

    names = {"opencv_tsai": "CALIB_HAND_EYE_TSAI", "opencv_park": "CALIB_HAND_EYE_PARK",
             "opencv_horaud": "CALIB_HAND_EYE_HORAUD", "opencv_andreff": "CALIB_HAND_EYE_ANDREFF",
             "opencv_daniilidis": "CALIB_HAND_EYE_DANIILIDIS"}
    return {name: method(getattr(cv2, flag)) for name, flag in names.items() if hasattr(cv2, flag)}


#: The closed-form methods on motion pairs (A, B) -> X.
METHODS = {"tsai": _tsai, "park": _park, "andreff": _andreff}


def solve_ax_xb(T_world_tool: np.ndarray, T_cam_board: np.ndarray) -> dict[str, np.ndarray]:
    """``X = T_tool_cam`` by every closed-form method: name -> (4, 4). Inputs (N, 4, 4). A method
    that fails numerically is left out; :class:`HandEyeError` when none can work."""
    T_world_tool = np.asarray(T_world_tool, dtype=np.float64)
    T_cam_board = np.asarray(T_cam_board, dtype=np.float64)
    A, B = _motion_pairs(T_world_tool, T_cam_board)
    out = {}
    for name, solve in METHODS.items():
        try:
            X = solve(A, B)
        except (HandEyeError, np.linalg.LinAlgError):
            continue
        if np.isfinite(X).all():
            out[name] = X
    for name, solve in _opencv_methods().items():
        try:
            X = solve(T_world_tool, T_cam_board)
        except Exception:  # noqa: BLE001 -- a cross-check only; our own methods decide
            continue
        if np.isfinite(X).all():
            out[name] = X
    if not out:
        raise HandEyeError("no closed-form method found a hand-eye transform (degenerate motions)")
    return out
