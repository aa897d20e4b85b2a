"""Rotation conversions (pure numpy): quaternions (x, y, z, w) and roll-pitch-yaw.

Roll-pitch-yaw is the REP 103 fixed-axis convention, R = Rz(yaw) Ry(pitch) Rx(roll), the same
as RealMan's "ZYX intrinsic" Euler angles.
"""
from __future__ import annotations

import math

import numpy as np


def float3(values) -> tuple[float, float, float]:
    """Three numbers (a vector, a triple of angles) as a tuple of plain floats."""
    x, y, z = (float(v) for v in values)
    return x, y, z


def quaternion_to_matrix(x: float, y: float, z: float, w: float) -> np.ndarray:
    """Rotation matrix (3, 3) of the quaternion (x, y, z, w), normalised first; ValueError for a zero quaternion."""
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if n < 1e-9:
        raise ValueError("zero quaternion has no rotation")
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def matrix_to_quaternion(R: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) -> unit quaternions (..., 4) as (x, y, z, w), w >= 0.

    Shepperd's method: pick the largest of w, x, y, z to divide by, so it is stable everywhere.
    """
    R = np.asarray(R, dtype=np.float64)
    m00, m11, m22 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    tr = m00 + m11 + m22
    cand = np.stack([tr, m00, m11, m22], axis=-1)
    k = np.argmax(cand, axis=-1)
    q = np.empty(R.shape[:-2] + (4,))
    # Each branch only where it is chosen (most rotations take the first: w largest).
    branches = (
        lambda r, s: ((r[:, 2, 1] - r[:, 1, 2]) / s, (r[:, 0, 2] - r[:, 2, 0]) / s, (r[:, 1, 0] - r[:, 0, 1]) / s,
                      0.25 * s),
        lambda r, s: (0.25 * s, (r[:, 0, 1] + r[:, 1, 0]) / s, (r[:, 0, 2] + r[:, 2, 0]) / s,
                      (r[:, 2, 1] - r[:, 1, 2]) / s),
        lambda r, s: ((r[:, 0, 1] + r[:, 1, 0]) / s, 0.25 * s, (r[:, 1, 2] + r[:, 2, 1]) / s,
                      (r[:, 0, 2] - r[:, 2, 0]) / s),
        lambda r, s: ((r[:, 0, 2] + r[:, 2, 0]) / s, (r[:, 1, 2] + r[:, 2, 1]) / s, 0.25 * s,
                      (r[:, 1, 0] - r[:, 0, 1]) / s),
    )
    signs = ((1, 1, 1), (1, -1, -1), (-1, 1, -1), (-1, -1, 1))  # of m00, m11, m22 under the root
    Rf, kf, qf = R.reshape(-1, 3, 3), k.reshape(-1), q.reshape(-1, 4)
    with np.errstate(invalid="ignore", divide="ignore"):
        for b, (branch, (a0, a1, a2)) in enumerate(zip(branches, signs)):
            rows = np.flatnonzero(kf == b)
            if rows.size == 0:
                continue
            r = Rf[rows]
            s = np.sqrt(np.maximum(1.0 + a0 * r[:, 0, 0] + a1 * r[:, 1, 1] + a2 * r[:, 2, 2], 0.0)) * 2
            qf[rows] = np.stack(branch(r, s), axis=-1)
    q = np.where(q[..., 3:4] < 0, -q, q)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def rpy_to_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll), radians."""
    cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch),
                              math.cos(yaw), math.sin(yaw))
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])


def matrix_to_rpy(R: np.ndarray) -> tuple[float, float, float]:
    """Roll, pitch, yaw [rad] of a rotation matrix (3, 3), R = Rz(yaw) Ry(pitch) Rx(roll); roll 0 at gimbal lock."""
    R = np.asarray(R, dtype=np.float64)
    pitch = math.asin(max(-1.0, min(1.0, -R[2, 0])))
    if abs(R[2, 0]) < 1 - 1e-9:
        return math.atan2(R[2, 1], R[2, 2]), pitch, math.atan2(R[1, 0], R[0, 0])
    return 0.0, pitch, math.atan2(-R[0, 1], R[1, 1])  # gimbal lock: put everything in yaw


def frame_from_normal(normal_w: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3), columns (x, y, z): z = normal, x = world X projected onto the
    tangent plane (world Y when the normal is within ~0.06 deg of X), y = z cross x."""
    n = np.asarray(normal_w, dtype=np.float64)
    n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    ex = np.array([1.0, 0.0, 0.0])
    ey = np.array([0.0, 1.0, 0.0])
    x = ex - n[..., 0:1] * n
    norm = np.linalg.norm(x, axis=-1, keepdims=True)
    alt = ey - n[..., 1:2] * n
    x = np.where(norm > 1e-3, x, alt)
    x = x / np.linalg.norm(x, axis=-1, keepdims=True)
    y = np.cross(n, x)
    return np.stack([x, y, n], axis=-1)


# -- rigid transforms (4x4) -----------------------------------------------------------------------
def transform(R: np.ndarray, t) -> np.ndarray:
    """4x4 from a rotation (3, 3) and a translation (3,)."""
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, np.asarray(t, dtype=np.float64).reshape(3)
    return T



def transform_xyz_rpy(xyz_m, rpy_deg) -> np.ndarray:
    """4x4 from a translation (m) and roll-pitch-yaw (deg, R = Rz Ry Rx): the cell's hand-eye form."""
    return transform(rpy_to_matrix(*np.radians(np.asarray(rpy_deg, dtype=np.float64))), xyz_m)



def rigid_inverse(T: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms (..., 4, 4)."""
    R = np.swapaxes(T[..., :3, :3], -1, -2)
    out = np.zeros(T.shape)
    out[..., :3, :3] = R
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", R, T[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out
