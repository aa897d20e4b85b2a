"""The reach test: can the arm weld this stud, can it put the camera there -- one function for the
planner and the driver.

A stud is weldable when the gun can stand on its normal: the gun's tilt from vertical within
``max_tool_tilt_deg``; for some rotation about the stud's axis (every ``yaw_step_deg``, the stud is
round) the approach pose (``standoff_m`` out along the normal) and the contact pose (``plunge_m``
beyond the surface) have tool tip and flange inside the workspace box and the flange inside the
reach sphere, the approach pose has an inverse-kinematics solution inside the joint limits (the
``preferred_joint_signs`` branch first), and the straight descent from it to the contact -- the
retract is the same line back -- is solved point by point inside the limits without a joint jump.
The verdict (:meth:`Reach.stud`) depends on the stud, the cell's :class:`ReachConfig` and the arm
base's pose in ``world`` only -- never on where the arm happens to be: the rotations are counted
from a fixed direction (away from the arm's axis) and the IK starts from fixed seeds. So the cell
sequencer, planning a job, and the arm driver, before a weld, get the same answer from the same
inputs (how the driver gets from its current joints to a stud the verdict accepts is
:mod:`.reach_move`'s). A camera pose (:meth:`Reach.camera`) is reachable when the weld-tool pose
that puts the camera there (the hand-eye) passes the same box, sphere and IK tests.

One source of the configuration: the arm driver builds its :class:`ReachConfig` from its own
parameters (:func:`reach_config`) and publishes it (latched, JSON: :meth:`ReachConfig.to_json`); the
sequencer builds the same :class:`Reach` from that message. Whatever set the driver's parameters
(cell.yaml, ``--set``, ``ros2 param set``), the planner checks against what the driver checks.

Frames: stud positions, normals and camera poses are in ``world``; ``world_T_base`` (4x4, the arm
base's pose in ``world``, identity by default: a fixed arm; a carriage's pose on a rail)
maps them into the arm's base frame, where the kinematics and the plans (``T_approach``,
``T_contact``, joint solutions) are. The cell's limits are in ``world``: the workspace box (tool tip
and flange) and the gun's tilt from world +z. Lengths m, angles rad unless named ``_deg``. Pure
numpy, no ROS.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, fields
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike

from rm65_driver.kinematics.rm65 import (
    D6_BY_VARIANT,
    JOINT_LIMITS_DEG,
    SHOULDER_M,
    WORKING_RADIUS_M,
    DHModel,
    RM65Kinematics,
    rotation_vector,
    tool_pose_facing,
)
from stud_common.hand_eye_in_use import tool_in_world

_EYE16 = tuple(float(v) for v in np.eye(4).ravel())

#: The IK of the verdicts: damped least squares as RM65Kinematics.ik, its tolerances and damping; a
#: pose's seeds stop PATIENCE iterations after the first of them converged.
MAX_ITERATIONS = 150
PATIENCE = 10
TOL_POSITION_M = 1e-6
TOL_ROTATION_RAD = 1e-5
IK_DAMPING = 0.02


class ReachConfigError(ValueError):
    """A reach configuration that cannot be used (names the field and the value)."""


@dataclass(frozen=True)
class ReachConfig:
    """Everything the reach verdict depends on besides the stud and the base pose.

    ``tool_T`` (16,): flange -> weld-gun tip (row-major 4x4, m); ``hand_eye_T`` (16,): the camera's
    optical frame in the weld-tool frame (row-major 4x4); ``d6_m``: the arm variant's flange
    distance; ``joint_limits_deg`` (6 pairs); ``workspace_min_m`` / ``workspace_max_m``: the box
    tool tip and flange stay in, ``world``; ``preferred_joint_signs``: the working branch (-1, 0,
    +1 per joint; 0 either)."""

    standoff_m: float = 0.05
    plunge_m: float = 0.0
    tool_T: tuple[float, ...] = (1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.15, 0.0, 0.0, 0.0, 1.0)
    max_tool_tilt_deg: float = 60.0
    yaw_step_deg: float = 15.0
    workspace_min_m: tuple[float, float, float] = (-0.70, -0.70, -0.02)
    workspace_max_m: tuple[float, float, float] = (0.70, 0.70, 1.10)
    preferred_joint_signs: tuple[int, ...] = (0, 0, 0, 0, 0, 0)
    d6_m: float = D6_BY_VARIANT["RM65-B"]
    joint_limits_deg: tuple[tuple[float, float], ...] = tuple((float(lo), float(hi)) for lo, hi in JOINT_LIMITS_DEG)
    hand_eye_T: tuple[float, ...] = _EYE16

    def __post_init__(self) -> None:
        def floats(name: str, n: int) -> tuple:
            arr = np.asarray(getattr(self, name), dtype=np.float64).ravel()
            if arr.size != n or not np.all(np.isfinite(arr)):
                raise ReachConfigError(f"reach config {name}={getattr(self, name)!r}: expected {n} finite numbers")
            return tuple(float(v) for v in arr)

        for name, n in (("tool_T", 16), ("hand_eye_T", 16), ("workspace_min_m", 3), ("workspace_max_m", 3)):
            object.__setattr__(self, name, floats(name, n))
        lim = floats("joint_limits_deg", 12)
        object.__setattr__(self, "joint_limits_deg", tuple(zip(lim[0::2], lim[1::2])))
        signs = tuple(int(s) for s in np.asarray(self.preferred_joint_signs).ravel())
        if len(signs) != 6 or any(s not in (-1, 0, 1) for s in signs):
            raise ReachConfigError(f"reach config preferred_joint_signs={self.preferred_joint_signs!r}: "
                                   "expected 6 of -1, 0, 1")
        object.__setattr__(self, "preferred_joint_signs", signs)
        for name in ("standoff_m", "plunge_m", "max_tool_tilt_deg", "yaw_step_deg", "d6_m"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ReachConfigError(f"reach config {name}={value!r}: expected a finite number")
            object.__setattr__(self, name, float(value))
        if self.standoff_m <= 0 or self.plunge_m < 0 or self.d6_m <= 0:
            raise ReachConfigError(f"reach config standoff_m={self.standoff_m}, plunge_m={self.plunge_m}, "
                                   f"d6_m={self.d6_m}: expected standoff_m > 0, plunge_m >= 0, d6_m > 0")
        if not 0.0 <= self.max_tool_tilt_deg <= 90.0 or not 0.0 < self.yaw_step_deg <= 180.0:
            raise ReachConfigError(f"reach config max_tool_tilt_deg={self.max_tool_tilt_deg} (0..90) or "
                                   f"yaw_step_deg={self.yaw_step_deg} ((0, 180]) out of range")
        if any(a >= b for a, b in zip(self.workspace_min_m, self.workspace_max_m)):
            raise ReachConfigError(f"reach config workspace_min_m={list(self.workspace_min_m)} must be below "
                                   f"workspace_max_m={list(self.workspace_max_m)}")
        if any(lo >= hi for lo, hi in self.joint_limits_deg):
            raise ReachConfigError(f"reach config joint_limits_deg={self.joint_limits_deg}: expected min < max")

    # -- the one wire form -----------------------------------------------------------------------
    def to_dict(self) -> dict:
        return {f.name: (list(map(list, v)) if f.name == "joint_limits_deg" else
                         list(v) if isinstance(v, tuple) else v)
                for f in fields(self) for v in (getattr(self, f.name),)}

    def to_json(self) -> str:
        """Exact (floats as ``repr``): a :class:`Reach` built from it gives the driver's verdicts."""
        return json.dumps(self.to_dict(), sort_keys=True)

    @classmethod
    def from_dict(cls, d: dict) -> "ReachConfig":
        if not isinstance(d, dict):
            raise ReachConfigError(f"reach config must be a mapping, got {type(d).__name__}")
        known = {f.name for f in fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise ReachConfigError(f"unknown reach config key(s) {sorted(unknown)}; known: {sorted(known)}")
        try:
            return cls(**d)
        except (TypeError, ValueError) as exc:
            raise ReachConfigError(f"reach config: {exc}") from None

    @classmethod
    def from_json(cls, text: str) -> "ReachConfig":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ReachConfigError(f"reach config is not JSON: {exc}") from None
        return cls.from_dict(data)

    @property
    def tool_matrix(self) -> np.ndarray:
        return np.asarray(self.tool_T, dtype=np.float64).reshape(4, 4)

    @property
    def hand_eye_matrix(self) -> np.ndarray:
        return np.asarray(self.hand_eye_T, dtype=np.float64).reshape(4, 4)


def reach_config(weld_params, limits, preferred_joint_signs: Sequence[int], d6_m: float,
                 joint_limits_rad: np.ndarray, hand_eye_T: np.ndarray | None = None) -> ReachConfig:
    """The driver's :class:`ReachConfig` from its weld job's parameters (``WeldParams``: tool,
    standoff, plunge), its ``SafetyLimits`` (box, tilt, yaw step), its working branch, arm variant
    and joint limits (rad) and the hand-eye in use."""
    return ReachConfig(
        standoff_m=weld_params.standoff_m, plunge_m=weld_params.plunge_m,
        tool_T=tuple(np.asarray(weld_params.tool_T, dtype=np.float64).ravel()),
        max_tool_tilt_deg=limits.max_tool_tilt_deg, yaw_step_deg=limits.yaw_step_deg,
        workspace_min_m=tuple(limits.workspace_min_m), workspace_max_m=tuple(limits.workspace_max_m),
        preferred_joint_signs=tuple(preferred_joint_signs), d6_m=d6_m,
        joint_limits_deg=tuple(map(tuple, np.degrees(np.asarray(joint_limits_rad, dtype=np.float64)))),
        hand_eye_T=_EYE16 if hand_eye_T is None else tuple(np.asarray(hand_eye_T, dtype=np.float64).ravel()))


# -- verdicts -------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class ApproachOption:
    """One rotation about the stud's axis whose approach pose has an IK solution (base frame)."""

    yaw_rad: float
    T_approach: np.ndarray
    q_approach: np.ndarray
    in_branch: bool


@dataclass(frozen=True, eq=False)
class StudReach:
    """The verdict on one stud. When ``ok``: the plan it found (base frame: tool poses 4x4, joints
    rad; ``descent`` (N, 6) the straight line approach -> contact), and every rotation whose
    approach pose is solvable (``options``: the driver may take another one nearer its joints).
    ``reason`` names the pose and the test that failed."""

    ok: bool
    reason: str = ""
    yaw_rad: float = 0.0
    T_approach: np.ndarray | None = None
    T_contact: np.ndarray | None = None
    q_approach: np.ndarray | None = None
    q_contact: np.ndarray | None = None
    descent: np.ndarray | None = None
    options: tuple[ApproachOption, ...] = ()


@dataclass(frozen=True, eq=False)
class PoseReach:
    """The verdict on one weld-tool pose (a camera station): ``q`` (6,) rad, the branch-preferred
    solution from the fixed seeds, when ``ok``."""

    ok: bool
    reason: str = ""
    q: np.ndarray | None = None
    T_tool: np.ndarray | None = None


@dataclass
class Reach:
    """The reach test of one cell configuration (see the module docstring)."""

    config: ReachConfig = field(default_factory=ReachConfig)

    def __post_init__(self) -> None:
        c = self.config
        self.kin = RM65Kinematics(dh=DHModel.rm65(c.d6_m), limits_rad=np.radians(np.asarray(c.joint_limits_deg)))
        self.tool_T = c.tool_matrix
        self._tool_inv = np.linalg.inv(self.tool_T)
        self._box = (np.asarray(c.workspace_min_m), np.asarray(c.workspace_max_m))
        self._signs = np.asarray(c.preferred_joint_signs)

    # -- the rotations searched, the seeds ------------------------------------------------------
    @property
    def yaw_candidates_deg(self) -> np.ndarray:
        """Rotations about the stud's axis tried: 0, +s, -s, +2s, ... (one full turn)."""
        step = self.config.yaw_step_deg
        k = np.arange(1, int(np.floor(180.0 / step + 1e-9)) + 1)
        yaws = np.concatenate([[0.0], np.ravel(np.column_stack([k * step, -k * step]))])
        return yaws[np.abs(yaws) <= 180.0 + 1e-9][: int(round(360.0 / step))]

    def seeds(self, towards_b: np.ndarray) -> np.ndarray:
        """Fixed IK seeds (S, 6) for a target at ``towards_b`` (base frame): J1 turned toward it; the
        first is the reference posture (tool down in front, J3 and J5 negative) solutions are
        chosen nearest to."""
        a = math.degrees(math.atan2(float(towards_b[1]), float(towards_b[0])))
        deg = np.array([[a, -30, -100, 0, -50, 0], [a, 30, 100, 0, 50, 0], [a, 0, 90, 0, 90, 0],
                        [a, -30, 100, 0, 110, 0], [a, 30, 60, 0, 90, 0], [a, 0, -90, 0, -90, 0],
                        [a, -60, -60, 0, -60, 0], [a, 60, 60, 0, 60, 0], [a + 180, 30, 100, 0, 50, 0]],
                       dtype=np.float64)
        deg[:, 0] = (deg[:, 0] + 180.0) % 360.0 - 180.0
        lo, hi = self.kin.limits_rad[:, 0], self.kin.limits_rad[:, 1]
        return np.clip(np.radians(deg), lo, hi)

    # -- geometry checks ------------------------------------------------------------------------
    def _outside_box(self, points_w: np.ndarray) -> np.ndarray:
        lo, hi = self._box
        return np.any((points_w < lo - 1e-9) | (points_w > hi + 1e-9), axis=-1)

    def _box_text(self, p: np.ndarray, what: str) -> str:
        lo, hi = self._box
        return (f"{what} leaves the workspace box at ({p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f}) m "
                f"(box {lo.tolist()}..{hi.tolist()} m)")

    def position_problems(self, T_tools: np.ndarray, what: str, world_T_base: np.ndarray | None = None) -> list[str]:
        """Per tool pose (K, 4, 4; base frame): why tip or flange is outside the box (world) or the
        flange out of reach ("" if not)."""
        flanges = T_tools @ self._tool_inv
        tips, fl = T_tools[:, :3, 3], flanges[:, :3, 3]
        tips_w, fl_w = tips, fl
        if world_T_base is not None:
            B = np.asarray(world_T_base, dtype=np.float64)
            tips_w, fl_w = tips @ B[:3, :3].T + B[:3, 3], fl @ B[:3, :3].T + B[:3, 3]
        out = []
        for tip_w, f_w, f in zip(tips_w, fl_w, fl):
            if self._outside_box(tip_w[None])[0]:
                out.append(self._box_text(tip_w, what))
            elif self._outside_box(f_w[None])[0]:
                out.append(self._box_text(f_w, what))
            elif np.linalg.norm(f - SHOULDER_M) > WORKING_RADIUS_M:
                out.append(f"{what} out of reach (flange {np.linalg.norm(f - SHOULDER_M):.3f} m from the shoulder "
                           f"> {WORKING_RADIUS_M:.3f} m)")
            else:
                out.append("")
        return out

    def tilt_problem(self, normal_w: ArrayLike) -> str:
        n = np.asarray(normal_w, dtype=np.float64).reshape(3)
        norm = float(np.linalg.norm(n))
        if not math.isfinite(norm) or norm < 1e-9:
            return f"surface normal {n.tolist()} is not a usable direction"
        ang = math.degrees(math.acos(max(-1.0, min(1.0, n[2] / norm))))
        if ang > self.config.max_tool_tilt_deg:
            return (f"the gun would tilt {ang:.1f} deg from vertical > the cell's max_tool_tilt_deg "
                    f"{self.config.max_tool_tilt_deg:.1f} deg")
        return ""

    # -- IK -------------------------------------------------------------------------------------
    def solve(self, T_targets: np.ndarray, seeds: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every target (K, 4, 4; tool poses, base frame) from every seed (S, 6) or (K, S, 6):
        (q (K, S, 6), converged (K, S), residual (K, S) = position m + 0.1 x rotation rad).

        The damped least squares of :meth:`RM65Kinematics.ik`, all seeds of all targets in one
        numpy batch. A target's seeds stop once one of them has converged for ``PATIENCE``
        iterations (the others get a short chance to be nearer), or after ``MAX_ITERATIONS``. Each
        target's result depends on that target and its seeds only, never on the others solved
        with it, so one pose checked alone or among many gets the same answer."""
        T_targets = np.asarray(T_targets, dtype=np.float64).reshape(-1, 4, 4)
        K = len(T_targets)
        seeds = np.asarray(seeds, dtype=np.float64)
        Q0 = np.broadcast_to(seeds, (K,) + seeds.shape[-2:]) if seeds.ndim == 2 else seeds
        S = Q0.shape[1]
        lo, hi = self.kin.limits_rad[:, 0], self.kin.limits_rad[:, 1]
        q = np.clip(Q0.reshape(K * S, 6), lo, hi).copy()
        tidx = np.repeat(np.arange(K), S)
        p_t, R_t = T_targets[tidx, :3, 3], T_targets[tidx, :3, :3]
        e_pos = np.full(K * S, np.inf)
        e_rot = np.full(K * S, np.inf)
        converged = np.zeros(K * S, dtype=bool)
        first = np.full(K, -1)
        frozen = np.zeros(K, dtype=bool)
        lam2 = IK_DAMPING ** 2
        eye6 = np.eye(6)
        for it in range(1, MAX_ITERATIONS + 1):
            active = np.flatnonzero(~converged & ~frozen[tidx])
            if len(active) == 0:
                break
            J, T = self.kin.jacobian(q[active], self.tool_T)
            e_p = p_t[active] - T[:, :3, 3]
            e_r = rotation_vector(R_t[active] @ np.swapaxes(T[:, :3, :3], -1, -2))
            e_pos[active] = np.linalg.norm(e_p, axis=1)
            e_rot[active] = np.linalg.norm(e_r, axis=1)
            done = (e_pos[active] < TOL_POSITION_M) & (e_rot[active] < TOL_ROTATION_RAD)
            converged[active[done]] = True
            hit = np.unique(tidx[active[done]])
            first[hit[first[hit] < 0]] = it
            frozen |= (first >= 0) & (it - first >= PATIENCE)
            step = ~done & ~frozen[tidx[active]]
            if not step.any():
                continue
            idx = active[step]
            e = np.concatenate([e_p[step], e_r[step]], axis=1)
            Ja = J[step]
            scale = np.minimum(1.0, np.linalg.norm(e, axis=1) / 0.01)[:, None, None]
            JJt = Ja @ np.swapaxes(Ja, -1, -2) + lam2 * scale ** 2 * eye6
            dq = np.einsum("nji,nj->ni", Ja, np.linalg.solve(JJt, e[..., None])[..., 0])
            norm = np.linalg.norm(dq, axis=1, keepdims=True)
            dq *= np.minimum(1.0, 0.4 / np.maximum(norm, 1e-12))
            q[idx] = np.clip(q[idx] + dq, lo, hi)
        return q.reshape(K, S, 6), converged.reshape(K, S), (e_pos + 0.1 * e_rot).reshape(K, S)

    def _pick(self, q: np.ndarray, converged: np.ndarray,
              q_ref: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per target: the chosen solution (K, 6) -- converged, in the preferred branch if any is,
        nearest ``q_ref`` (J6's 2 pi copies taken nearest it) --, whether one exists (K,) and
        whether it is in the branch (K,)."""
        lo, hi = self.kin.limits_rad[:, 0], self.kin.limits_rad[:, 1]
        for k in (-1, 1):
            alt = q + k * 2 * np.pi
            better = (np.abs(alt - q_ref) < np.abs(q - q_ref)) & (alt >= lo) & (alt <= hi)
            q = np.where(better, alt, q)
        ask = self._signs != 0
        branch = np.all(np.sign(q[..., ask]) == self._signs[ask], axis=-1) if ask.any() else np.ones(q.shape[:2], bool)
        dist = np.linalg.norm(q - q_ref, axis=-1)
        wanted = converged & branch
        use = np.where(wanted.any(axis=1, keepdims=True), wanted, converged)
        cost = np.where(use, dist, np.inf)
        best = np.argmin(cost, axis=1)
        rows = np.arange(len(q))
        return q[rows, best], use[rows, best], branch[rows, best] & use[rows, best]

    # -- the verdicts ---------------------------------------------------------------------------
    def stud(self, position_w: ArrayLike, normal_w: ArrayLike, world_T_base: np.ndarray | None = None) -> StudReach:
        """Can the gun weld the stud at ``position_w`` with outward ``normal_w`` (world)? See the
        module docstring for the tests, in the order they are applied."""
        c = self.config
        p_w = np.asarray(position_w, dtype=np.float64).reshape(3)
        if not np.all(np.isfinite(p_w)):
            return StudReach(False, f"position {p_w.tolist()} is not finite")
        why = self.tilt_problem(normal_w)
        if why:
            return StudReach(False, why)
        n_w = np.asarray(normal_w, dtype=np.float64).reshape(3)
        n_w = n_w / np.linalg.norm(n_w)
        for point, what in ((p_w + c.standoff_m * n_w, "approach pose"), (p_w - c.plunge_m * n_w, "contact pose")):
            if self._outside_box(point[None])[0]:
                return StudReach(False, self._box_text(point, what))
        p, n = p_w, n_w
        if world_T_base is not None:
            B_inv = np.linalg.inv(np.asarray(world_T_base, dtype=np.float64))
            p, n = B_inv[:3, :3] @ p_w + B_inv[:3, 3], B_inv[:3, :3] @ n_w
        approach_tip, contact_tip = p + c.standoff_m * n, p - c.plunge_m * n
        radial = np.array([p[0], p[1], 0.0])
        x_hint = radial / np.linalg.norm(radial) if np.linalg.norm(radial) > 1e-6 else np.array([1.0, 0.0, 0.0])
        yaws = np.radians(self.yaw_candidates_deg)
        T_app = np.array([tool_pose_facing(approach_tip, n, x_hint=x_hint, yaw=float(y)) for y in yaws])
        T_con = np.array([tool_pose_facing(contact_tip, n, x_hint=x_hint, yaw=float(y)) for y in yaws])
        problems = self.position_problems(T_app, "approach pose", world_T_base)
        contact_problems = self.position_problems(T_con, "contact pose", world_T_base)
        keep = [i for i, why in enumerate(problems) if not why]
        if not keep:
            return StudReach(False, problems[0])
        seeds = self.seeds(approach_tip)
        q, conv, resid = self.solve(T_app[keep], seeds)
        q_app, solved, branch = self._pick(q, conv, seeds[0])
        if not solved.any():
            k = int(np.argmin(resid.min(axis=1)))
            best = resid[k]
            j = int(np.argmin(best))
            T_best = self.kin.fk(q[k, j], self.tool_T)
            pos_mm = 1e3 * float(np.linalg.norm(T_best[:3, 3] - T_app[keep[k]][:3, 3]))
            rot_deg = math.degrees(float(np.linalg.norm(rotation_vector(T_app[keep[k]][:3, :3] @ T_best[:3, :3].T))))
            return StudReach(False, f"approach pose: no IK solution inside the joint limits (best residual "
                                    f"{pos_mm:.2f} mm, {rot_deg:.2f} deg) at any of the {len(keep)} rotations about "
                                    "the stud's axis" + (f" the workspace allows (of {len(yaws)})"
                                                         if len(keep) < len(yaws) else ""))
        options = tuple(ApproachOption(float(yaws[keep[i]]), T_app[keep[i]], q_app[i], bool(branch[i]))
                        for i in range(len(keep)) if solved[i])
        index = {float(yaws[i]): i for i in range(len(yaws))}
        first_reason = ""
        # In the branch first, then the rotation order (0, +s, -s, ...): the first one the straight
        # descent works for is the plan.
        for opt in sorted(options, key=lambda o: not o.in_branch):
            i = index[opt.yaw_rad]
            why = contact_problems[i]
            if not why:
                path, why = self.kin.linear_path(opt.q_approach, T_con[i], tool=self.tool_T)
                if path is not None:
                    return StudReach(True, "", opt.yaw_rad, opt.T_approach, T_con[i], opt.q_approach, path[-1], path,
                                     options)
                why = f"descent: {why}"
            first_reason = first_reason or why
        return StudReach(False, first_reason, options=options)

    def tool_poses(self, T_tools_b: np.ndarray, world_T_base: np.ndarray | None = None) -> list[PoseReach]:
        """Verdicts on weld-tool poses (K, 4, 4), base frame: box (world), reach sphere, IK inside the
        limits from the fixed seeds (the branch first). Batched; each the same as alone."""
        T_tools_b = np.asarray(T_tools_b, dtype=np.float64).reshape(-1, 4, 4)
        problems = self.position_problems(T_tools_b, "tool pose", world_T_base)
        out: list[PoseReach] = [PoseReach(False, why) for why in problems]
        keep = [i for i, why in enumerate(problems) if not why]
        if keep:
            seeds = np.array([self.seeds(T[:3, 3]) for T in T_tools_b[keep]])
            q, conv, resid = self.solve(T_tools_b[keep], seeds)
            for j, i in enumerate(keep):
                qi, ok, _branch = self._pick(q[j:j + 1], conv[j:j + 1], seeds[j, 0])
                if ok[0]:
                    out[i] = PoseReach(True, "", qi[0], T_tools_b[i])
                else:
                    out[i] = PoseReach(False, f"tool pose: no IK solution inside the joint limits (best residual "
                                              f"{1e3 * float(resid[j].min()):.2f} mm-equivalent)")
        return out

    def cameras(self, T_cameras_w: np.ndarray, world_T_base: np.ndarray | None = None) -> list[PoseReach]:
        """Verdicts on camera poses (K, 4, 4; optical frame in ``world``): the weld-tool pose that
        puts the camera there through the hand-eye, :meth:`tool_poses`."""
        T = np.asarray(T_cameras_w, dtype=np.float64).reshape(-1, 4, 4)
        T_tools = np.array([tool_in_world(Ti, self.config.hand_eye_matrix) for Ti in T])
        if world_T_base is not None:
            T_tools = np.linalg.inv(np.asarray(world_T_base, dtype=np.float64)) @ T_tools
        return [PoseReach(r.ok, r.reason.replace("tool pose", "camera pose", 1), r.q, r.T_tool)
                for r in self.tool_poses(T_tools, world_T_base)]

    def camera(self, T_camera_w: np.ndarray, world_T_base: np.ndarray | None = None) -> PoseReach:
        return self.cameras(np.asarray(T_camera_w)[None], world_T_base)[0]


__all__ = ["ApproachOption", "PoseReach", "Reach", "ReachConfig", "ReachConfigError", "StudReach", "reach_config"]
