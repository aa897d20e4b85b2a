"""RM-65 kinematics: modified DH forward kinematics, damped-least-squares IK, pose helpers.

Units: radians and metres throughout (the controller's millidegrees / micrometres /
milliradians are converted in :mod:`rm65_driver.protocol.messages`, never here).

Model (docs/RM65_PROTOCOL.md §3.2, RealMan "RM65 ontology parameters"; identical to the values the
official SDK's ``rm_algo_get_dh()`` returns): modified (Craig) DH, per link
``T_i = RotX(alpha_{i-1}) · TransX(a_{i-1}) · RotZ(q_i + offset_i) · TransZ(d_i)``,
flange pose = ``T_1 · … · T_6`` in the base frame, no extra base rotation.

Orientation convention (docs/RM65_PROTOCOL.md §1.3): Euler ``[rx, ry, rz]`` are roll-pitch-yaw,
ZYX intrinsic, ``R = Rz(rz) · Ry(ry) · Rx(rx)``. Quaternions here are ROS order ``(x, y, z, w)``
(the RealMan SDK uses ``[w, x, y, z]``).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike

from stud_common.rotations import rpy_to_matrix

# --------------------------------------------------------------------------------------------
# Model data (docs/RM65_PROTOCOL.md §3.1 / §3.2)
# --------------------------------------------------------------------------------------------

#: d6 (flange distance, m) per RM65 variant (WEB-PARAM).
D6_BY_VARIANT: dict[str, float] = {
    "RM65-B": 0.144,
    "RM65-ZF": 0.153,
    "RM65-6F": 0.1725,
    "RM65-6FB": 0.1612,
    "RM65-B-V": 0.1668,
    "RM65-6FB-V": 0.184,
}

#: Joint range (deg), J1..J6 (WEB-PARAM / DOCS-PARAM).
JOINT_LIMITS_DEG = np.array(
    [[-178.0, 178.0], [-130.0, 130.0], [-135.0, 135.0], [-178.0, 178.0], [-128.0, 128.0], [-360.0, 360.0]]
)
#: Max joint speed (deg/s), J1..J6 (WEB-PARAM).
JOINT_MAX_SPEED_DEG_S = np.array([180.0, 180.0, 225.0, 225.0, 225.0, 225.0])
#: Max joint acceleration (deg/s^2), J1..J6: what the simulator answers to ``get_joint_max_acc``
#: (the SDK documentation's example value; a real arm's factory setting may differ: read it).
JOINT_MAX_ACC_DEG_S2 = np.array([600.0] * 6)

#: Shoulder point (m, base frame): J2 axis height; the reach sphere is centred here.
SHOULDER_M = np.array([0.0, 0.0, 0.2405])
#: Documented working radius of the RM65-B (m), flange reference point, from the shoulder.
WORKING_RADIUS_M = 0.610


@dataclass(frozen=True)
class DHModel:
    """Modified DH table; arrays of shape (6,). Lengths in m, angles in rad."""

    a: np.ndarray
    alpha: np.ndarray
    d: np.ndarray
    offset: np.ndarray

    @classmethod
    def rm65(cls, d6_m: float = D6_BY_VARIANT["RM65-B"]) -> "DHModel":
        """The RM65 table (docs/RM65_PROTOCOL.md §3.2) with the variant's flange distance ``d6_m``."""
        return cls(
            a=np.array([0.0, 0.0, 0.256, 0.0, 0.0, 0.0]),
            alpha=np.radians([0.0, 90.0, 0.0, 90.0, -90.0, 90.0]),
            d=np.array([0.2405, 0.0, 0.0, 0.210, 0.0, float(d6_m)]),
            offset=np.radians([0.0, 90.0, 90.0, 0.0, 0.0, 0.0]),
        )


# --------------------------------------------------------------------------------------------
# Rotation / pose helpers
# --------------------------------------------------------------------------------------------


def euler_zyx_to_matrix(rx: float, ry: float, rz: float) -> np.ndarray:
    """``Rz(rz) · Ry(ry) · Rx(rx)`` (3x3) — the RealMan ``[rx, ry, rz]`` convention, which is
    REP 103's roll-pitch-yaw (one implementation: stud_common.rotations)."""
    return rpy_to_matrix(rx, ry, rz)


def matrix_to_euler_zyx(R: np.ndarray) -> np.ndarray:
    """Inverse of :func:`euler_zyx_to_matrix`: ``[rx, ry, rz]`` (rad), ry in [-pi/2, pi/2].

    At gimbal lock (|ry| = pi/2) rx is set to 0 and the whole rotation about z goes to rz.
    """
    R = np.asarray(R, dtype=np.float64)
    sy = -R[2, 0]
    ry = np.arcsin(np.clip(sy, -1.0, 1.0))
    if abs(sy) < 1.0 - 1e-9:
        rx = np.arctan2(R[2, 1], R[2, 2])
        rz = np.arctan2(R[1, 0], R[0, 0])
    else:  # gimbal lock
        rx = 0.0
        rz = np.arctan2(-R[0, 1], R[1, 1])
    return np.array([rx, ry, rz])


def pose6_to_matrix(pose6) -> np.ndarray:
    """``[x, y, z (m), rx, ry, rz (rad)]`` -> 4x4 homogeneous transform."""
    p = np.asarray(pose6, dtype=np.float64).reshape(6)
    T = np.eye(4)
    T[:3, :3] = euler_zyx_to_matrix(*p[3:])
    T[:3, 3] = p[:3]
    return T


def matrix_to_pose6(T: np.ndarray) -> np.ndarray:
    """4x4 transform -> ``[x, y, z (m), rx, ry, rz (rad)]``."""
    T = np.asarray(T, dtype=np.float64)
    return np.concatenate([T[:3, 3], matrix_to_euler_zyx(T[:3, :3])])


def quat_xyzw_to_matrix(q) -> np.ndarray:
    """Unit quaternion ``(x, y, z, w)`` -> 3x3 rotation (normalised first)."""
    x, y, z, w = np.asarray(q, dtype=np.float64).reshape(4) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def matrix_to_quat_xyzw(R: np.ndarray) -> np.ndarray:
    """3x3 rotation (or batch ``(..., 3, 3)``) -> quaternion(s) ``(x, y, z, w)`` with w >= 0."""
    R = np.asarray(R, dtype=np.float64)
    m = R[..., :3, :3]
    tr = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
    # Shepperd's method, all four branches computed and the best-conditioned one picked.
    cand = np.stack(
        [
            np.stack([m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1],
                      1 + tr], -1),
            np.stack([1 + 2 * m[..., 0, 0] - tr, m[..., 0, 1] + m[..., 1, 0], m[..., 0, 2] + m[..., 2, 0],
                      m[..., 2, 1] - m[..., 1, 2]], -1),
            np.stack([m[..., 0, 1] + m[..., 1, 0], 1 + 2 * m[..., 1, 1] - tr, m[..., 1, 2] + m[..., 2, 1],
                      m[..., 0, 2] - m[..., 2, 0]], -1),
            np.stack([m[..., 0, 2] + m[..., 2, 0], m[..., 1, 2] + m[..., 2, 1], 1 + 2 * m[..., 2, 2] - tr,
                      m[..., 1, 0] - m[..., 0, 1]], -1),
        ],
        -2,
    )  # (..., 4, 4): branch, (x, y, z, w)
    diag = np.stack([tr, m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]], -1)
    best = np.argmax(diag, axis=-1)
    q = np.take_along_axis(cand, best[..., None, None], axis=-2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., 3:4] < 0, -q, q)


def pose_to_matrix(position, quat_xyzw) -> np.ndarray:
    """Position (m) + quaternion ``(x, y, z, w)`` -> 4x4."""
    T = np.eye(4)
    T[:3, :3] = quat_xyzw_to_matrix(quat_xyzw)
    T[:3, 3] = np.asarray(position, dtype=np.float64).reshape(3)
    return T


def rotation_vector(R: np.ndarray) -> np.ndarray:
    """Log map: rotation matrix (or batch) -> rotation vector axis·angle (rad), robust near pi."""
    q = matrix_to_quat_xyzw(R)
    v = q[..., :3]
    s = np.linalg.norm(v, axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(s, q[..., 3:4])
    scale = np.where(s > 1e-12, angle / np.maximum(s, 1e-300), 2.0)
    return v * scale


def rotation_angle(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """Angle (rad) of the relative rotation between two 3x3 rotations."""
    c = (np.trace(np.asarray(R_a)[:3, :3].T @ np.asarray(R_b)[:3, :3]) - 1.0) / 2.0
    return float(np.arccos(np.clip(c, -1.0, 1.0)))


def invert_transform(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4x4 transform."""
    T = np.asarray(T, dtype=np.float64)
    Ti = np.eye(4)
    Ti[:3, :3] = T[:3, :3].T
    Ti[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return Ti


def tool_pose_facing(position, normal, x_hint=(1.0, 0.0, 0.0), yaw: float = 0.0) -> np.ndarray:
    """4x4 tool pose at ``position`` whose z axis points *into* the surface (``-normal``).

    The x axis is ``x_hint`` projected on the plane normal to z (world y when x_hint is
    parallel to the normal), then rotated by ``yaw`` (rad) about z. A round stud does not
    care about yaw, so callers may try several to find a reachable one.
    """
    n = np.asarray(normal, dtype=np.float64).reshape(3)
    n = n / np.linalg.norm(n)
    z = -n
    hint = np.asarray(x_hint, dtype=np.float64).reshape(3)
    x = hint - np.dot(hint, z) * z
    if np.linalg.norm(x) < 1e-6:
        x = np.array([0.0, 1.0, 0.0]) - z[1] * z
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    if yaw:
        c, s = np.cos(yaw), np.sin(yaw)
        x, y = c * x + s * y, -s * x + c * y
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2] = x, y, z
    T[:3, 3] = np.asarray(position, dtype=np.float64).reshape(3)
    return T


# --------------------------------------------------------------------------------------------
# Kinematics
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class IKResult:
    """Outcome of :meth:`RM65Kinematics.ik`. ``q`` (6,) rad is the best candidate even on failure."""

    success: bool
    q: np.ndarray
    position_error_m: float
    rotation_error_rad: float
    iterations: int
    message: str = ""


def trapezoid_profile(lengths: ArrayLike, speeds: ArrayLike, accels: ArrayLike) -> tuple[float, float]:
    """(duration T, acceleration time t_a) (s) of the fastest synchronised trapezoidal move.

    Every component ``i`` (a joint, or a move's length and angle) covers ``lengths[i]`` along one
    shared time law -- accelerate for ``t_a``, cruise, decelerate for ``t_a`` -- so its peak speed
    is ``L_i / (T - t_a)`` and its acceleration ``L_i / (t_a (T - t_a))``. Both stay within
    ``speeds[i]`` and ``accels[i]`` iff ``T - t_a >= B = max L_i/v_i`` and ``t_a (T - t_a) >= A =
    max L_i/a_i``; the shortest such T is ``B + A/B`` (cruising), or ``2 sqrt(A)`` (a triangle,
    t_a = T/2) when ``B < sqrt(A)``. A single component: ``L/v + v/a``, or ``2 sqrt(L/a)``.
    """
    L = np.abs(np.asarray(lengths, dtype=np.float64))
    B = float(np.max(L / np.asarray(speeds, dtype=np.float64), initial=0.0))
    A = float(np.max(L / np.asarray(accels, dtype=np.float64), initial=0.0))
    if B <= 0.0:
        return 0.0, 0.0
    if B * B >= A:
        return B + A / B, A / B
    T = 2.0 * float(np.sqrt(A))
    return T, T / 2.0


@dataclass
class RM65Kinematics:
    """Forward/inverse kinematics of the RM65 flange (or a tool given as flange->tool 4x4).

    ``limits_rad`` (6, 2) are the joint ranges; ``max_speed_rad_s`` (6,) the joint speeds,
    ``max_acc_rad_s2`` (6,) their accelerations.
    """

    dh: DHModel = field(default_factory=DHModel.rm65)
    limits_rad: np.ndarray = field(default_factory=lambda: np.radians(JOINT_LIMITS_DEG))
    max_speed_rad_s: np.ndarray = field(default_factory=lambda: np.radians(JOINT_MAX_SPEED_DEG_S))
    max_acc_rad_s2: np.ndarray = field(default_factory=lambda: np.radians(JOINT_MAX_ACC_DEG_S2))

    # -- forward ----------------------------------------------------------------------------
    def link_transforms(self, q: np.ndarray) -> np.ndarray:
        """Cumulative base->frame_i transforms for joints ``q`` (..., 6): shape (..., 6, 4, 4)."""
        q = np.asarray(q, dtype=np.float64)
        batch = q.shape[:-1]
        th = q + self.dh.offset
        ct, st = np.cos(th), np.sin(th)
        ca, sa = np.cos(self.dh.alpha), np.sin(self.dh.alpha)
        A = np.zeros(batch + (6, 4, 4))
        A[..., 0, 0] = ct
        A[..., 0, 1] = -st
        A[..., 0, 3] = self.dh.a
        A[..., 1, 0] = st * ca
        A[..., 1, 1] = ct * ca
        A[..., 1, 2] = -sa
        A[..., 1, 3] = -sa * self.dh.d
        A[..., 2, 0] = st * sa
        A[..., 2, 1] = ct * sa
        A[..., 2, 2] = ca
        A[..., 2, 3] = ca * self.dh.d
        A[..., 3, 3] = 1.0
        out = np.empty_like(A)
        out[..., 0, :, :] = A[..., 0, :, :]
        for i in range(1, 6):
            out[..., i, :, :] = out[..., i - 1, :, :] @ A[..., i, :, :]
        return out

    def fk(self, q, tool: np.ndarray | None = None) -> np.ndarray:
        """Flange (or ``tool``) pose in the base frame: 4x4, or (N, 4, 4) for q of shape (N, 6)."""
        T = self.link_transforms(q)[..., 5, :, :]
        return T @ tool if tool is not None else T

    def jacobian(self, q, tool: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Geometric Jacobian (..., 6, 6) (rows: v, w in the base frame) and the end pose (..., 4, 4)."""
        frames = self.link_transforms(q)
        T_end = frames[..., 5, :, :] @ tool if tool is not None else frames[..., 5, :, :]
        z = frames[..., :, :3, 2]  # (..., 6, 3) joint axes
        p = frames[..., :, :3, 3]  # (..., 6, 3) joint origins
        p_end = T_end[..., None, :3, 3]
        Jv = np.cross(z, p_end - p)
        J = np.concatenate([Jv, z], axis=-1)  # (..., 6 joints, 6)
        return np.swapaxes(J, -1, -2), T_end

    # -- limits -----------------------------------------------------------------------------
    def within_limits(self, q, tol: float = 1e-9) -> bool:
        q = np.asarray(q, dtype=np.float64)
        return bool(np.all(q >= self.limits_rad[:, 0] - tol) and np.all(q <= self.limits_rad[:, 1] + tol))

    def limit_violations(self, q) -> list[str]:
        """Human-readable list of joints outside their range (empty when all inside)."""
        q = np.asarray(q, dtype=np.float64)
        out = []
        for i in range(6):
            lo, hi = self.limits_rad[i]
            if not lo - 1e-9 <= q[i] <= hi + 1e-9:
                out.append(
                    f"joint{i + 1}={np.degrees(q[i]):.2f} deg outside [{np.degrees(lo):.0f}, {np.degrees(hi):.0f}] deg"
                )
        return out

    @staticmethod
    def in_reach(position_flange_m) -> bool:
        """Coarse reach test: the flange point lies in the 610 mm sphere around the shoulder
        (docs/RM65_PROTOCOL.md §3.1).

        Necessary, not sufficient (the cylinder above/below the base and orientation are not
        checked): the IK is the real test.
        """
        return float(np.linalg.norm(np.asarray(position_flange_m) - SHOULDER_M)) <= WORKING_RADIUS_M

    def joint_move_profile(self, q_from, q_to, speed_fraction: float) -> tuple[float, float]:
        """(duration, acceleration time) (s) of a synchronised joint move (:func:`trapezoid_profile`).

        ``speed_fraction`` scales the joints' speeds and accelerations alike, as a RealMan
        controller's ``v`` does.
        """
        dq = np.abs(np.asarray(q_to, dtype=np.float64) - np.asarray(q_from, dtype=np.float64))
        f = max(speed_fraction, 1e-3)
        return trapezoid_profile(dq, self.max_speed_rad_s * f, self.max_acc_rad_s2 * f)

    # -- inverse ----------------------------------------------------------------------------
    def _seeds(self, q_seed: np.ndarray, restarts: int, rng_seed: int) -> np.ndarray:
        lo, hi = self.limits_rad[:, 0], self.limits_rad[:, 1]
        fixed = np.radians(
            [
                [0, 0, 90, 0, 90, 0],  # tool down, elbow forward
                [0, -30, 100, 0, 110, 0],
                [0, 30, 60, 0, 90, 0],
                [0, 0, -90, 0, -90, 0],  # mirrored (tool down, behind)
            ]
        )
        rng = np.random.default_rng(rng_seed)
        n_rand = max(0, restarts - len(fixed))
        rand = rng.uniform(lo * 0.8, hi * 0.8, size=(n_rand, 6))
        rand[:, 5] = rng.uniform(-np.pi, np.pi, size=n_rand)
        seeds = np.vstack([q_seed[None, :], fixed[: max(0, restarts)], rand])
        return np.clip(seeds, lo, hi)

    def ik(
        self,
        T_target: np.ndarray,
        q_seed=None,
        tool: np.ndarray | None = None,
        restarts: int = 8,
        max_iterations: int = 150,
        tol_position_m: float = 1e-6,
        tol_rotation_rad: float = 1e-5,
        damping: float = 0.02,
        rng_seed: int = 0,
        prefer_signs: Sequence[int] | None = None,
    ) -> IKResult:
        """Damped-least-squares IK for the flange (or ``tool``) pose ``T_target`` (4x4, base frame).

        All seeds iterate together as one numpy batch: ``q_seed`` (the current joints) plus
        ``restarts`` fixed and pseudo-random seeds. Joint limits are enforced by clipping at every
        step; of the converged solutions the one closest to ``q_seed`` wins (J6's ±360° range
        means q6 ± 2π can be the same pose: the copy nearest the seed is kept). Deterministic.

        ``prefer_signs`` (6,) of -1, 0, +1: the branch wanted (an industrial controller's
        configuration flags), e.g. J3 and J5 negative: ``[0, 0, -1, 0, -1, 0]`` (0: either sign).
        Solutions in that branch win over nearer ones; without one, the nearest is taken.
        """
        T_target = np.asarray(T_target, dtype=np.float64)
        lo, hi = self.limits_rad[:, 0], self.limits_rad[:, 1]
        q0 = np.zeros(6) if q_seed is None else np.asarray(q_seed, dtype=np.float64).reshape(6)
        q = self._seeds(np.clip(q0, lo, hi), restarts, rng_seed)
        p_t, R_t = T_target[:3, 3], T_target[:3, :3]
        lam2 = damping**2
        eye6 = np.eye(6)
        active = np.ones(len(q), dtype=bool)
        e_pos = e_rot = np.full(len(q), np.inf)  # (no iteration: nothing converged)
        it = 0
        first_converged = None
        in_branch = _branch_test(prefer_signs)
        for it in range(1, max_iterations + 1):
            J, T = self.jacobian(q, tool)
            e_p = p_t - T[:, :3, 3]
            e_r = rotation_vector(R_t @ np.swapaxes(T[:, :3, :3], -1, -2))
            e_pos = np.linalg.norm(e_p, axis=1)
            e_rot = np.linalg.norm(e_r, axis=1)
            done = (e_pos < tol_position_m) & (e_rot < tol_rotation_rad)
            active = ~done
            if done.any() and first_converged is None:
                first_converged = it
            # Stop when the seed from the current joints converged, when every seed did, or a
            # few iterations after the first one did (others get a short chance to be closer).
            seed_done = done[0] and in_branch(q[:1])[0]
            if seed_done or not active.any() or (first_converged is not None and it - first_converged >= 10):
                break
            e = np.concatenate([e_p, e_r], axis=1)[active]
            Ja = J[active]
            # Damping shrinks with the error: robust far away, Gauss-Newton-fast close to the goal
            # (also where the goal sits on a singular, fully stretched configuration).
            scale = np.minimum(1.0, np.linalg.norm(e, axis=1) / 0.01)[:, None, None]
            JJt = Ja @ np.swapaxes(Ja, -1, -2) + lam2 * scale**2 * eye6
            dq = np.einsum("nji,nj->ni", Ja, np.linalg.solve(JJt, e[..., None])[..., 0])
            step = np.linalg.norm(dq, axis=1, keepdims=True)
            dq *= np.minimum(1.0, 0.4 / np.maximum(step, 1e-12))
            q[active] = np.clip(q[active] + dq, lo, hi)
        converged = (e_pos < tol_position_m) & (e_rot < tol_rotation_rad)
        return _best_solution(q, q0, converged, e_pos, e_rot, it, in_branch, lo, hi)

    def linear_path(
        self, q_start, T_goal: np.ndarray, tool: np.ndarray | None = None, step_m: float = 0.005,
        step_rad: float = np.radians(2.0), max_joint_jump_rad: float = np.radians(10.0),
    ) -> tuple[np.ndarray | None, str]:
        """Joint waypoints (N, 6) of a straight-line tool move from FK(q_start) to ``T_goal``.

        Position is interpolated linearly and orientation by slerp; each waypoint is solved
        from the previous one (no restarts, so the branch is kept). Returns ``(None, reason)``
        when a waypoint has no solution inside the limits or the joints jump (singularity).
        """
        q_start = np.asarray(q_start, dtype=np.float64)
        T0 = self.fk(q_start, tool)
        dp = T_goal[:3, 3] - T0[:3, 3]
        rv = rotation_vector(T_goal[:3, :3] @ T0[:3, :3].T)
        n = int(max(1, np.ceil(np.linalg.norm(dp) / step_m), np.ceil(np.linalg.norm(rv) / step_rad)))
        path = [q_start]
        q = q_start
        for k in range(1, n + 1):
            s = k / n
            T = np.eye(4)
            T[:3, :3] = _rotvec_to_matrix(rv * s) @ T0[:3, :3]
            T[:3, 3] = T0[:3, 3] + dp * s
            res = self.ik(T, q, tool, restarts=0, max_iterations=60)
            if not res.success:
                return None, f"linear path point {k}/{n} unreachable: {res.message}"
            if np.max(np.abs(res.q - q)) > max_joint_jump_rad:
                return None, f"linear path point {k}/{n} passes near a singularity (joint jump)"
            q = res.q
            path.append(q)
        return np.array(path), ""


def _best_solution(q: np.ndarray, q0: np.ndarray, converged: np.ndarray, e_pos: np.ndarray, e_rot: np.ndarray,
                   iterations: int, in_branch, lo: np.ndarray, hi: np.ndarray) -> IKResult:
    """Of the IK seeds' end joints ``q`` (n, 6), the converged one in the preferred branch nearest ``q0``
    (any converged one when none is in it), or the least wrong with a reason; rad, m."""
    # Equivalent copies (q ± 2π) nearest the seed, where still inside the limits.
    for k in (-1, 1):
        alt = q + k * 2 * np.pi
        better = (np.abs(alt - q0) < np.abs(q - q0)) & (alt >= lo) & (alt <= hi)
        q = np.where(better, alt, q)
    dist = np.linalg.norm(q - q0, axis=1)
    wanted = converged & in_branch(q)
    if wanted.any():
        converged = wanted
    if converged.any():
        idx = int(np.flatnonzero(converged)[np.argmin(dist[converged])])
        return IKResult(True, q[idx].copy(), float(e_pos[idx]), float(e_rot[idx]), iterations)
    idx = int(np.argmin(e_pos + 0.1 * e_rot))
    return IKResult(
        False,
        q[idx].copy(),
        float(e_pos[idx]),
        float(e_rot[idx]),
        iterations,
        f"no IK solution inside the joint limits (best residual {e_pos[idx] * 1e3:.2f} mm, "
        f"{np.degrees(e_rot[idx]):.2f} deg)",
    )


def _branch_test(prefer_signs: Sequence[int] | None):
    """``test(q (N, 6)) -> (N,) bool``: the joints have the signs ``prefer_signs`` asks for (0: any)."""
    if prefer_signs is None:
        return lambda q: np.ones(len(q), dtype=bool)
    signs = np.asarray(prefer_signs, dtype=np.int64).reshape(6)
    if not np.all(np.isin(signs, (-1, 0, 1))):
        raise ValueError(f"prefer_signs must hold -1, 0 or 1 for each joint, got {signs.tolist()}")
    ask = signs != 0
    return lambda q: np.all(np.sign(q[:, ask]) == signs[ask], axis=1)


def _rotvec_to_matrix(rv: np.ndarray) -> np.ndarray:
    """Rodrigues' formula (3,) -> 3x3."""
    rv = np.asarray(rv, dtype=np.float64)
    angle = np.linalg.norm(rv)
    if angle < 1e-12:
        return np.eye(3)
    k = rv / angle
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K
