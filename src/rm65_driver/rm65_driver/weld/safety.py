"""Checks run before any motion command is sent: reach, joint limits, workspace, gun tilt, speed.

The gun welds along the surface normal at any slope (the stud's 5 deg is its lean from that
normal, an error budget the planner checks). What the cell limits is how far the gun may tilt
from vertical, ``max_tool_tilt_deg``: a property of the cell (hose, cable, gun body), not of
the stud. The stud is round, so the rotation about its axis is free: it is searched for a
reachable solution nearest the current joints.

Every check returns a reason string a person can act on (``None``/``ok`` when it passes), and
nothing here talks to the controller: a rejected target is never sent.

Whether a stud can be welded at all is the reach verdict (:mod:`.reach`), the same function the
cell's planner applies, so a stud the plan accepted is never refused here; how the arm gets to it
from its current joints is :mod:`.reach_move`'s (the nearest solution, or a detour).

Frames: poses and targets here are in the arm's base frame, where the kinematics and the controller
work (the controller's work frame must be the base, which
:class:`~rm65_driver.weld.weld_sequence.WeldSequence` verifies); the tool is ``weld_tool``, given as
the flange -> tool transform ``tool_T`` (4x4, m). The cell's limits are in ``world``: ``world_T_base``
(4x4) places the base there -- the identity without a rail, :func:`stud_common.frames.world_T_base` on
one -- and the workspace box and the gun's tilt from vertical are checked in ``world``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from rm65_driver.kinematics.rm65 import SHOULDER_M, WORKING_RADIUS_M, DHModel, RM65Kinematics
from rm65_driver.weld.reach import Reach, ReachConfig
from rm65_driver.weld.reach_move import plan_move


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
    via: tuple[np.ndarray, ...] = ()  # joint waypoints before the approach (a detour), each (6,) rad

    @property
    def waypoints(self) -> tuple[np.ndarray, ...]:
        """The joint moves to the approach: the detour's waypoints, then the approach joints."""
        return (*self.via, self.q_approach)


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
    prefer_signs: tuple[int, ...] = (0, 0, 0, 0, 0, 0)   # the working branch (preferred_joint_signs)
    hand_eye_T: np.ndarray = field(default_factory=lambda: np.eye(4))  # camera in the weld-tool frame

    def __post_init__(self) -> None:
        self._reach: dict[tuple[float, float], Reach] = {}

    def reach_for(self, standoff_m: float, plunge_m: float = 0.0) -> Reach:
        """The reach test of this cell with these approach distances (the planner builds the same one
        from :attr:`Reach.config`, which the driver publishes)."""
        key = (float(standoff_m), float(plunge_m))
        if key not in self._reach:
            d6 = float(self.kin.dh.d[5])
            rm65 = DHModel.rm65(d6)
            if not all(np.array_equal(getattr(self.kin.dh, f), getattr(rm65, f))
                       for f in ("a", "alpha", "d", "offset")):
                raise ValueError("the reach test knows the RM65's DH table only")
            self._reach[key] = Reach(ReachConfig(
                standoff_m=key[0], plunge_m=key[1], tool_T=tuple(np.asarray(self.tool_T, float).ravel()),
                max_tool_tilt_deg=self.limits.max_tool_tilt_deg, yaw_step_deg=self.limits.yaw_step_deg,
                workspace_min_m=self.limits.workspace_min_m, workspace_max_m=self.limits.workspace_max_m,
                preferred_joint_signs=tuple(self.prefer_signs), d6_m=d6,
                joint_limits_deg=tuple(map(tuple, np.degrees(self.kin.limits_rad))),
                hand_eye_T=tuple(np.asarray(self.hand_eye_T, float).ravel())))
        return self._reach[key]

    @property
    def yaw_candidates_deg(self) -> np.ndarray:
        """Rotations about the stud's axis tried, from a fixed direction (away from the arm's axis): 0, +s, -s, ..."""
        return self.reach_for(1.0).yaw_candidates_deg

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
        pts = (np.atleast_2d(np.asarray(points_m, dtype=np.float64)) @ self.world_T_base[:3, :3].T
               + self.world_T_base[:3, 3])
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
        """Plan and check one stud (position and normal in the base frame; the verdict is taken in world
        with the base at :attr:`world_T_base`, as the planner takes it): the reach verdict
        (:meth:`Reach.stud`: gun tilt, approach pose on the normal at ``standoff_m`` and contact pose
        ``plunge_m`` beyond the surface in the workspace and reachable inside the joint limits for some
        rotation about the stud's axis, the straight descent and retract feasible) -- refused with its reason,
        prefixed ``unreachable:`` --, then
        the way there from ``q_current`` (:func:`~rm65_driver.weld.reach_move.plan_move`: the rotation and
        solution nearest the current joints whose joint move stays in the workspace, or a detour)."""
        reach = self.reach_for(standoff_m, plunge_m)
        B = self.world_T_base
        p_w = B[:3, :3] @ np.asarray(position_m, dtype=np.float64).reshape(3) + B[:3, 3]
        n_w = B[:3, :3] @ np.asarray(normal, dtype=np.float64).reshape(3)
        verdict = reach.stud(p_w, n_w, world_T_base=B)
        if not verdict.ok:
            return TargetCheck(False, f"unreachable: {verdict.reason}")
        move, why = plan_move(reach, verdict, q_current, world_T_base=B)
        if move is None:
            return TargetCheck(False, why)
        return TargetCheck(True, "", StudPlan(move.T_approach, move.T_contact, move.q_approach, move.q_contact,
                                              move.yaw_rad, move.via))
