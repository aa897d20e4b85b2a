"""Checks run before any motion command is sent: reach, joint limits, workspace, gun tilt, speed.

The gun welds along the surface normal at any slope (the stud's 5 deg is its lean from that
normal, an error budget the planner checks). What the cell limits is how far the gun may tilt
from vertical, ``max_tool_tilt_deg``: a property of the cell (hose, cable, gun body), not of
the stud. The stud is round, so the rotation about its axis is free: it is searched for a
reachable solution nearest the current joints.

Every check returns a reason string a person can act on (``None``/``ok`` when it passes), and
nothing here talks to the controller: a rejected target is never sent.

Frames: poses and targets here are in the arm's base frame, where the kinematics and the controller
work (the controller's work frame must be the base, which :class:`~rm65_driver.weld.weld_sequence.WeldSequence`
verifies); the tool is ``weld_tool``, given as the flange -> tool transform ``tool_T`` (4x4, m).
The cell's limits are in ``world``: ``world_T_base`` (4x4) places the base there -- the identity
without a rail, :func:`stud_common.frames.world_T_base` on one -- and the workspace box and the gun's
tilt from vertical are checked in ``world``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from rm65_driver.kinematics.rm65 import SHOULDER_M, WORKING_RADIUS_M, RM65Kinematics, tool_pose_facing


@dataclass(frozen=True)
class SafetyLimits:
    """Limits; lengths in m (world frame), angles in deg, speeds in % of the controller maximum.

    ``max_tool_tilt_deg``: how far the gun may lean from vertical (gun pointing straight down)
    in this cell; a stud whose normal is tilted more than that from world +z is refused.
    ``workspace_min_m``/``workspace_max_m`` bound the weld-tool tip (and the flange) everywhere
    along every planned path. ``yaw_step_deg``: the rotation about the stud's axis is searched
    in these steps.
    """

    workspace_min_m: tuple[float, float, float] = (-0.70, -0.70, -0.02)
    workspace_max_m: tuple[float, float, float] = (0.70, 0.70, 1.10)
    max_tool_tilt_deg: float = 60.0
    yaw_step_deg: float = 15.0
    max_joint_speed_pct: int = 50
    max_linear_speed_pct: int = 30

    def __post_init__(self) -> None:
        lo, hi = np.asarray(self.workspace_min_m, float), np.asarray(self.workspace_max_m, float)
        if lo.shape != (3,) or hi.shape != (3,) or not np.all(np.isfinite(lo) & np.isfinite(hi)) or np.any(lo >= hi):
            raise ValueError(f"workspace box min {self.workspace_min_m} must be below max {self.workspace_max_m}")
        if not 0.0 <= self.max_tool_tilt_deg <= 90.0:
            raise ValueError(f"max_tool_tilt_deg={self.max_tool_tilt_deg} outside 0..90")
        if not 0.0 < self.yaw_step_deg <= 180.0:
            raise ValueError(f"yaw_step_deg={self.yaw_step_deg} outside (0, 180]")
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
    world_T_base: np.ndarray = field(default_factory=lambda: np.eye(4))  # the arm's base in world (the rail)

    @property
    def yaw_candidates_deg(self) -> np.ndarray:
        """Rotations about the stud's axis tried, from the current wrist yaw outward: 0, +s, -s, ..."""
        step = self.limits.yaw_step_deg
        k = np.arange(1, int(np.floor(180.0 / step + 1e-9)) + 1)
        yaws = np.concatenate([[0.0], np.ravel(np.column_stack([k * step, -k * step]))])
        return yaws[np.abs(yaws) <= 180.0 + 1e-9][: int(round(360.0 / step))]

    # -- single checks -------------------------------------------------------------------
    def check_speed(self, v_pct: int, linear: bool) -> str | None:
        cap = self.limits.max_linear_speed_pct if linear else self.limits.max_joint_speed_pct
        kind = "linear" if linear else "joint"
        if not 1 <= int(v_pct) <= cap:
            return f"{kind} speed {v_pct} % outside 1..{cap} % (speed cap)"
        return None

    def check_tool_tilt(self, normal: ArrayLike) -> str | None:
        """The gun, along -normal (base frame), leans from vertical by the normal's angle to world +z."""
        n = self.world_T_base[:3, :3] @ np.asarray(normal, dtype=np.float64)
        norm = np.linalg.norm(n)
        if not np.isfinite(norm) or norm < 1e-9:
            return f"surface normal {n.tolist()} is not a usable direction"
        ang = float(np.degrees(np.arccos(np.clip(n[2] / norm, -1.0, 1.0))))
        if ang > self.limits.max_tool_tilt_deg:
            return (f"the gun would tilt {ang:.1f} deg from vertical > the cell's max_tool_tilt_deg "
                    f"{self.limits.max_tool_tilt_deg:.1f} deg")
        return None

    def check_points(self, points_m: np.ndarray, what: str) -> str | None:
        """All points (N, 3, base frame) inside the workspace box (world)?"""
        pts = np.atleast_2d(np.asarray(points_m, dtype=np.float64)) @ self.world_T_base[:3, :3].T + self.world_T_base[:3, 3]
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
    def check_target(self, position_m: ArrayLike, normal: ArrayLike, standoff_m: float,
                     q_current: np.ndarray, plunge_m: float = 0.0) -> TargetCheck:
        """Plan and check one stud: gun tilt, approach pose on the normal at ``standoff_m``, contact
        pose (``plunge_m`` beyond the surface), both in the workspace and reachable inside the
        joint limits, the straight descent (and so the retract, the same line back) feasible, the
        joint move from ``q_current`` inside the workspace.

        The rotation about the stud's axis is free: every ``yaw_step_deg`` is tried, and of the
        reachable ones the plan whose approach joints are nearest ``q_current`` is taken. Only
        when no rotation works is the stud refused, with the first reason met."""
        p = np.asarray(position_m, dtype=np.float64).reshape(3)
        if not np.all(np.isfinite(p)):
            return TargetCheck(False, f"position {p.tolist()} is not finite")
        reason = self.check_tool_tilt(normal)
        if reason:
            return TargetCheck(False, reason)
        n = np.asarray(normal, dtype=np.float64)
        n = n / np.linalg.norm(n)
        q_current = np.asarray(q_current, dtype=np.float64)
        x_hint = (self.kin.fk(q_current) @ self.tool_T)[:3, 0]  # yaw 0: keep the wrist's current yaw
        # The tip's positions do not depend on the yaw about the tool axis: check them once (the
        # flange's do, when the gun is mounted off the flange axis: checked per yaw below).
        for point, what in ((p + standoff_m * n, "approach pose"), (p - plunge_m * n, "contact pose")):
            reason = self.check_points(point, what)
            if reason:
                return TargetCheck(False, reason)
        # Approach solutions for every yaw, each seeded from its neighbour's (a yaw step is mostly
        # a step of the wrist), then the full plan for the nearest first.
        candidates: list[tuple[float, float, np.ndarray, np.ndarray]] = []
        first_reason = ""
        seed = q_current
        for yaw_deg in self.yaw_candidates_deg:
            yaw = float(np.radians(yaw_deg))
            T_approach = tool_pose_facing(p + standoff_m * n, n, x_hint=x_hint, yaw=yaw)
            q_app, why = self.check_pose(T_approach, seed if candidates else q_current, "approach pose")
            if q_app is None:
                first_reason = first_reason or why
                continue
            seed = q_app
            candidates.append((float(np.linalg.norm(q_app - q_current)), yaw, T_approach, q_app))
        for _dist, yaw, T_approach, q_app in sorted(candidates, key=lambda c: c[0]):
            T_contact = tool_pose_facing(p - plunge_m * n, n, x_hint=x_hint, yaw=yaw)
            q_con, why = self.check_pose(T_contact, q_app, "contact pose")
            if q_con is not None:
                why = (self.check_linear(q_app, T_contact, "descent")
                       or self.check_joint_path(q_current, q_app, "approach move") or "")
                if not why:
                    return TargetCheck(True, "", StudPlan(T_approach, T_contact, q_app, q_con, yaw))
            first_reason = first_reason or why
        return TargetCheck(False, first_reason or "no rotation about the stud's axis is reachable")
