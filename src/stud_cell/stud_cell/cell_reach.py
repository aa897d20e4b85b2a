"""The cell's reach as the planner asks it: the arm driver's own test, never an approximation of it.

The arm driver publishes the configuration of its reach test (``/arm/reach_config``,
:class:`rm65_driver.weld.reach.ReachConfig`); :class:`CellReach` builds the same
:class:`~rm65_driver.weld.reach.Reach` from it and asks it what the driver will ask before it moves: can
the gun weld this stud (:meth:`CellReach.stud`), can the arm put the camera at this station
(:meth:`CellReach.cameras`). Inputs are brought into the form the driver receives them in -- a
stud's normal normalised as the driver's ``StudTarget`` does, a camera pose through the quaternion
of the ``/arm/move_to`` request -- so the two verdicts are the same numbers, not merely the same
rule.

Before any shot, a stud's height and normal are not known, but its place is (the registered
drawing) and so are bounds on both (the working plane, the part's height, the cell's gun-tilt
limit): :meth:`CellReach.surely_unreachable` names the studs the gun cannot reach whatever the part
turns out to be -- a bound that never names a stud the driver would weld.

``world_T_base`` (4x4): the arm base's pose in ``world`` (identity: the fixed arm). Pure numpy.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rm65_driver.kinematics.rm65 import SHOULDER_M, WORKING_RADIUS_M
from rm65_driver.weld.reach import PoseReach, Reach, ReachConfig, StudReach
from rm65_driver.weld.weld_job import StudTarget
from stud_common.rotations import matrix_to_quaternion, quaternion_to_matrix
from stud_perception.camera_model import nadir_rotation

#: Height steps (m) at which the prior bound samples the studs' possible heights.
_PRIOR_DZ_M = 0.005


def camera_pose_as_sent(xyz_w, yaw_rad: float) -> np.ndarray:
    """The nadir camera pose (4x4, world) at ``xyz_w`` with image yaw ``yaw_rad`` exactly as the
    driver reads it from the sequencer's ``/arm/move_to`` request (rotation through its quaternion)."""
    T = np.eye(4)
    T[:3, :3] = quaternion_to_matrix(*(float(v) for v in matrix_to_quaternion(nadir_rotation(yaw_rad))))
    T[:3, 3] = np.array([float(v) for v in np.asarray(xyz_w, dtype=np.float64).reshape(3)])
    return T


@dataclass
class CellReach:
    """The planner's questions to the driver's reach test (module docstring)."""

    reach: Reach
    world_T_base: np.ndarray | None = None

    @classmethod
    def from_config(cls, config: ReachConfig, world_T_base: np.ndarray | None = None) -> "CellReach":
        return cls(Reach(config), world_T_base)

    @property
    def config(self) -> ReachConfig:
        return self.reach.config

    def stud(self, position_w, normal_w) -> StudReach:
        """The driver's verdict on this stud (position m, outward normal, world)."""
        t = StudTarget("", position_w, normal_w)  # the driver normalises the normal so
        return self.reach.stud(t.position, t.normal, self.world_T_base)

    def cameras(self, poses) -> list[PoseReach]:
        """The driver's verdicts on nadir camera poses ``[(xyz_w, yaw_rad), ...]`` (one IK batch)."""
        if not len(poses):
            return []
        T = np.array([camera_pose_as_sent(xyz, yaw) for xyz, yaw in poses])
        return self.reach.cameras(T, self.world_T_base)

    def camera_ok(self, xyz_w, yaw_rad: float = 0.0) -> bool:
        return self.cameras([(xyz_w, yaw_rad)])[0].ok

    def surely_unreachable(self, xy_w, z_range_m: tuple[float, float], bases=None,
                           base_slack_m: float = 0.0) -> list[str]:
        """Per stud at world ``xy_w`` (N, 2) whose surface lies somewhere in ``z_range_m`` (world z)
        with a normal anywhere within the gun-tilt limit: why the gun cannot weld it whatever height
        and normal it turns out to have ("" when it may be weldable). A lower bound on the flange's
        distance from the shoulder at the approach pose, over every height and normal: beyond the
        reach sphere, the driver's verdict is "out of reach" for every one of them.

        ``bases`` (K, 4, 4): the arm's base at any of these poses in ``world`` (a rail's carriage
        positions; default: ``world_T_base``) -- the bound is the least over them, less
        ``base_slack_m`` (the bound moves by at most as much as the base does: sampled carriage
        positions ``h`` apart leave ``h / 2`` between them)."""
        c = self.config
        xy = np.asarray(xy_w, dtype=np.float64).reshape(-1, 2)
        z_lo, z_hi = (float(v) for v in z_range_m)
        zs = np.arange(z_lo, z_hi + _PRIOR_DZ_M, _PRIOR_DZ_M)
        if bases is None:
            bases = [np.eye(4) if self.world_T_base is None else self.world_T_base]
        B_inv = np.linalg.inv(np.asarray(bases, dtype=np.float64).reshape(-1, 4, 4))     # (K, 4, 4)
        axis = B_inv[:, :3, :3] @ np.array([0.0, 0.0, 1.0])  # world up, in each base frame (K, 3)
        tool = c.tool_matrix
        if np.allclose(tool[:3, :3], np.eye(3)):   # the flange is on the tool's axis but for t_xy
            lever, slack = c.standoff_m + float(tool[2, 3]), float(np.hypot(tool[0, 3], tool[1, 3]))
        else:                                      # |flange - tip| = |t| whatever the tool's rotation
            lever, slack = c.standoff_m, float(np.linalg.norm(tool[:3, 3]))
        theta = math.radians(c.max_tool_tilt_deg)
        out = []
        for x, y in xy:
            P_w = np.column_stack([np.full(len(zs), x), np.full(len(zs), y), zs, np.ones(len(zs))])
            P = np.einsum("kij,zj->kzi", B_inv, P_w)[..., :3]   # (K, Z, 3) in each base frame
            d = SHOULDER_M - P                               # surface point -> shoulder
            dn = np.linalg.norm(d, axis=-1)
            phi = np.arccos(np.clip(np.einsum("kzi,ki->kz", d, axis) / np.maximum(dn, 1e-12), -1.0, 1.0))
            gap = np.maximum(phi - theta, 0.0)               # the normal can lean toward d by theta at most
            dist = np.sqrt(np.maximum(lever ** 2 + dn ** 2 - 2 * lever * dn * np.cos(gap), 0.0))
            bound = float(dist.min()) - _PRIOR_DZ_M / 2 - slack - base_slack_m  # 1-Lipschitz in z: between the samples
            if bound > WORKING_RADIUS_M:
                out.append(f"approach pose out of reach at any height {z_lo:.3f}..{z_hi:.3f} m and gun tilt up to "
                           f"{c.max_tool_tilt_deg:g} deg (flange at least {bound:.3f} m from the shoulder > "
                           f"{WORKING_RADIUS_M:.3f} m)")
                continue
            lo, hi = np.asarray(c.workspace_min_m), np.asarray(c.workspace_max_m)   # world
            if x < lo[0] - c.plunge_m or x > hi[0] + c.plunge_m or y < lo[1] - c.plunge_m or y > hi[1] + c.plunge_m:
                # the contact lies within plunge_m of the surface point: out of the box at any height
                out.append(f"contact pose leaves the workspace box at ({x:.3f}, {y:.3f}) m "
                           f"(box {lo.tolist()}..{hi.tolist()} m)")
                continue
            out.append("")
        return out

__all__ = ["CellReach", "camera_pose_as_sent"]
