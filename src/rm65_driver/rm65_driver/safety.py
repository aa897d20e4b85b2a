"""Checks run before any motion command is sent: reach, joint limits, workspace, inclination, speed.

Every check returns a reason string a person can act on (``None``/``ok`` when it passes), and
nothing here talks to the controller: a rejected target is never sent.

Frames: ``world`` is the arm base frame (the controller's work frame must be the base, which
:class:`~rm65_driver.weld_sequence.WeldSequence` verifies); the tool is ``weld_tool``, given as
the flange -> tool transform ``tool_T`` (4x4, m).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from .kinematics import SHOULDER_M, WORKING_RADIUS_M, RM65Kinematics, tool_pose_facing


@dataclass(frozen=True)
class SafetyLimits:
    """Limits; lengths in m (world frame), angles in deg, speeds in % of the controller maximum.

    ``stud_axis`` is the direction studs must be welded along (unit vector, world; the plate
    normal, +z by default); a target whose surface normal is tilted more than
    ``max_inclination_deg`` from it is refused. ``workspace_min_m``/``workspace_max_m`` bound
    the weld-tool tip (and the flange) everywhere along every planned path.
    """

    workspace_min_m: tuple[float, float, float] = (-0.70, -0.70, -0.02)
    workspace_max_m: tuple[float, float, float] = (0.70, 0.70, 1.10)
    max_inclination_deg: float = 5.0
    stud_axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    max_joint_speed_pct: int = 50
    max_linear_speed_pct: int = 30

    def __post_init__(self) -> None:
        lo, hi = np.asarray(self.workspace_min_m, float), np.asarray(self.workspace_max_m, float)
        if lo.shape != (3,) or hi.shape != (3,) or np.any(lo >= hi):
            raise ValueError(f"workspace box min {self.workspace_min_m} must be below max {self.workspace_max_m}")
        if not 0.0 <= self.max_inclination_deg <= 90.0:
            raise ValueError(f"max_inclination_deg={self.max_inclination_deg} outside 0..90")
        if np.linalg.norm(self.stud_axis) < 1e-9:
            raise ValueError("stud_axis must be a non-zero vector")
        for name in ("max_joint_speed_pct", "max_linear_speed_pct"):
            if not 1 <= getattr(self, name) <= 100:
                raise ValueError(f"{name}={getattr(self, name)} outside 1..100 %")


@dataclass(frozen=True)
class StudPlan:
    """Checked poses for one stud: tool poses (4x4, world) and their joint solutions (6,) rad."""

    T_approach: np.ndarray
    T_contact: np.ndarray
    q_approach: np.ndarray
    q_contact: np.ndarray
    yaw_rad: float


@dataclass(frozen=True)
class TargetCheck:
    ok: bool
    reason: str = ""
    plan: StudPlan | None = None


@dataclass
class SafetyChecker:
    """Applies :class:`SafetyLimits` with the arm's kinematics and the weld tool ``tool_T``."""

    kin: RM65Kinematics
    limits: SafetyLimits = field(default_factory=SafetyLimits)
    tool_T: np.ndarray = field(default_factory=lambda: np.eye(4))
    yaw_candidates_deg: Sequence[float] = (0.0, 90.0, -90.0, 180.0, 45.0, -45.0, 135.0, -135.0)

    # -- single checks -------------------------------------------------------------------
    def check_speed(self, v_pct: int, linear: bool) -> str | None:
        cap = self.limits.max_linear_speed_pct if linear else self.limits.max_joint_speed_pct
        kind = "linear" if linear else "joint"
        if not 1 <= int(v_pct) <= cap:
            return f"{kind} speed {v_pct} % outside 1..{cap} % (speed cap)"
        return None

    def check_inclination(self, normal: Sequence[float]) -> str | None:
        n = np.asarray(normal, dtype=np.float64)
        norm = np.linalg.norm(n)
        if not np.isfinite(norm) or norm < 1e-9:
            return f"surface normal {n.tolist()} is not a usable direction"
        axis = np.asarray(self.limits.stud_axis, dtype=np.float64)
        cosang = np.dot(n / norm, axis / np.linalg.norm(axis))
        ang = float(np.degrees(np.arccos(np.clip(cosang, -1.0, 1.0))))
        if ang > self.limits.max_inclination_deg:
            return f"inclination {ang:.1f} deg > {self.limits.max_inclination_deg:.1f} deg limit"
        return None

    def check_points(self, points_m: np.ndarray, what: str) -> str | None:
        """All points (N, 3) inside the workspace box?"""
        pts = np.atleast_2d(np.asarray(points_m, dtype=np.float64))
        lo, hi = np.asarray(self.limits.workspace_min_m), np.asarray(self.limits.workspace_max_m)
        bad = np.any((pts < lo - 1e-9) | (pts > hi + 1e-9), axis=1)
        if bad.any():
            p = pts[int(np.argmax(bad))]
            return (f"{what} leaves the workspace box at ({p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f}) m "
                    f"(box {lo.tolist()}..{hi.tolist()} m)")
        return None

    def check_position(self, T_tool: np.ndarray, what: str) -> str | None:
        """Tool tip and flange inside the workspace box and the flange inside the reach sphere."""
        flange = T_tool @ np.linalg.inv(self.tool_T)
        reason = self.check_points(np.vstack([T_tool[:3, 3], flange[:3, 3]]), what)
        if reason:
            return reason
        if not self.kin.in_reach(flange[:3, 3]):
            d = np.linalg.norm(flange[:3, 3] - SHOULDER_M)
            return f"{what} out of reach (flange {d:.3f} m from the shoulder > {WORKING_RADIUS_M:.3f} m)"
        return None

    def check_pose(self, T_tool: np.ndarray, q_seed: np.ndarray, what: str) -> tuple[np.ndarray | None, str]:
        """Workspace, reach and IK within the joint limits; returns (q, "") or (None, reason)."""
        reason = self.check_position(T_tool, what)
        if reason:
            return None, reason
        res = self.kin.ik(T_tool, q_seed, tool=self.tool_T)
        if not res.success:
            return None, f"{what} unreachable: {res.message}"
        return res.q, ""

    def check_joint_path(self, q_from: np.ndarray, q_to: np.ndarray, what: str, samples: int = 16) -> str | None:
        """The tool tip and flange stay in the workspace along a joint-interpolated move."""
        s = np.linspace(0.0, 1.0, samples)[1:, None]
        Q = np.asarray(q_from) + s * (np.asarray(q_to) - np.asarray(q_from))
        flanges = self.kin.fk(Q)
        tips = flanges @ self.tool_T
        return self.check_points(np.vstack([tips[:, :3, 3], flanges[:, :3, 3]]), what)

    def check_linear(self, q_from: np.ndarray, T_goal: np.ndarray, what: str) -> str | None:
        path, why = self.kin.linear_path(q_from, T_goal, tool=self.tool_T)
        if path is None:
            return f"{what}: {why}"
        return None

    # -- a whole stud --------------------------------------------------------------------
    def check_target(self, position_m: Sequence[float], normal: Sequence[float], standoff_m: float,
                     q_current: np.ndarray, plunge_m: float = 0.0) -> TargetCheck:
        """Plan and check one stud: inclination, approach pose on the normal at ``standoff_m``,
        contact pose (``plunge_m`` beyond the surface), both in the workspace and reachable inside
        the joint limits, the straight descent feasible, the joint move from ``q_current`` inside
        the workspace. Tries several tool yaws (a round stud does not care)."""
        p = np.asarray(position_m, dtype=np.float64).reshape(3)
        if not np.all(np.isfinite(p)):
            return TargetCheck(False, f"position {p.tolist()} is not finite")
        reason = self.check_inclination(normal)
        if reason:
            return TargetCheck(False, reason)
        n = np.asarray(normal, dtype=np.float64)
        n = n / np.linalg.norm(n)
        q_current = np.asarray(q_current, dtype=np.float64)
        x_hint = (self.kin.fk(q_current) @ self.tool_T)[:3, 0]  # keep the wrist's current yaw
        # Positions do not depend on the yaw about the tool axis: check them once.
        for T, what in ((tool_pose_facing(p + standoff_m * n, n), "approach pose"),
                        (tool_pose_facing(p - plunge_m * n, n), "contact pose")):
            reason = self.check_position(T, what)
            if reason:
                return TargetCheck(False, reason)
        first_reason = ""
        for yaw_deg in self.yaw_candidates_deg:
            yaw = float(np.radians(yaw_deg))
            T_contact = tool_pose_facing(p - plunge_m * n, n, x_hint=x_hint, yaw=yaw)
            T_approach = tool_pose_facing(p + standoff_m * n, n, x_hint=x_hint, yaw=yaw)
            q_app, why = self.check_pose(T_approach, q_current, "approach pose")
            if q_app is not None:
                q_con, why = self.check_pose(T_contact, q_app, "contact pose")
                if q_con is not None:
                    why = (self.check_linear(q_app, T_contact, "descent")
                           or self.check_joint_path(q_current, q_app, "approach move") or "")
                    if not why:
                        return TargetCheck(True, "", StudPlan(T_approach, T_contact, q_app, q_con, yaw))
            first_reason = first_reason or why
        return TargetCheck(False, first_reason)
