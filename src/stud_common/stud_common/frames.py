"""The cell's coordinate frames (REP 103/105: metres, radians, right-handed) and their pure math.

One vocabulary for every node that stamps or publishes a frame (docs/FRAMES.md has the tree):

* ``world`` -- the cell's fixed frame, z up (REP 105's ``map``/``odom`` role: nothing moves it).
  Without a rail it is the RM-65 base frame; with a rail (``rail_length_m`` > 0) it is the rail's
  frame: x along the rail, z up, origin at the rail's zero.
* ``carriage`` -- with a rail only: the carriage, ``world`` moved ``rail_joint`` metres along x.
* ``base_link`` -- the arm's base: coincident with ``world`` without a rail (a fixed URDF joint, so an
  arm mounted elsewhere is one origin to change); ``rail_mount_xyz_m`` from ``carriage`` with one.
* ``link1`` ... ``link6``, ``rm65_flange`` -- the arm's links (modified-DH frames) and its flange.
* ``weld_tool`` -- the weld-gun tip: ``rm65_flange`` moved by the tool offset along flange z.
* ``camera_color_optical_frame`` -- the eye-in-hand camera, z forward, x right, y down (REP 103's
  optical convention), placed on ``weld_tool`` by the hand-eye calibration.
* ``drawing`` -- the drawing's frame: origin at mark O, x toward A, y toward B, z up; placed in
  ``world`` by the registration.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

WORLD = "world"
CARRIAGE = "carriage"
BASE_LINK = "base_link"
FLANGE = "rm65_flange"
WELD_TOOL = "weld_tool"
CAMERA_OPTICAL = "camera_color_optical_frame"
DRAWING = "drawing"
RAIL_JOINT = "rail_joint"  # the prismatic joint world -> carriage (metres along world x)


def drawing_in_world(M_local2world: np.ndarray, plane_z_m: float) -> np.ndarray:
    """The ``drawing`` frame in ``world`` (4, 4) from a registration.

    ``M_local2world`` (3, 3) is the planar registration (Eq. 2: drawing x, y -> world x, y; rotation
    block orthonormal, translation in metres); ``plane_z_m`` the world height of the drawing's plane
    (the measured height of mark O, where the drawing's origin is). The 2x2 block is projected on
    the nearest rotation (the registration is rigid up to rounding), so the result is a proper
    rigid transform whatever the fit left in it.
    """
    M = np.asarray(M_local2world, dtype=np.float64).reshape(3, 3)
    if not np.all(np.isfinite(M)) or not math.isfinite(plane_z_m):
        raise ValueError("registration has non-finite values: no drawing frame")
    yaw = math.atan2(M[1, 0] - M[0, 1], M[0, 0] + M[1, 1])  # angle of the nearest rotation
    c, s = math.cos(yaw), math.sin(yaw)
    T = np.eye(4)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:3, 3] = [M[0, 2], M[1, 2], plane_z_m]
    return T


@dataclass(frozen=True)
class RailDeviation:
    """How a real rail differs from the straight, exact one the cell believes in (sim-only truth).

    ``scale_ppm``: the carriage travels (1 + scale_ppm 1e-6) m per metre the encoder counts;
    ``offset_m``: where the encoder's zero really is, along the rail; ``yaw_urad_per_m``: the rail
    bends in the horizontal plane, the carriage's heading turning this much per metre travelled (a
    constant curvature: heading k s, lateral drift k s^2 / 2 after s metres). The cell never knows
    these; the simulator and the simulated camera place the arm with them. Zero: the believed rail.
    """

    scale_ppm: float = 0.0
    offset_m: float = 0.0
    yaw_urad_per_m: float = 0.0

    def __post_init__(self) -> None:
        for name in ("scale_ppm", "offset_m", "yaw_urad_per_m"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"rail deviation {name}={getattr(self, name)} is not a finite number")


def carriage_in_world(carriage_m: float, deviation: RailDeviation = RailDeviation()) -> np.ndarray:
    """The ``carriage`` frame in ``world`` (4, 4) at rail position ``carriage_m`` (m, the encoder's value).

    Believed (no ``deviation``): a translation of ``carriage_m`` along world x. With a :class:`RailDeviation`:
    the carriage ``s = carriage_m (1 + scale) + offset`` metres along a rail of constant curvature
    ``k`` (yaw per metre) that starts at the origin heading along x: heading ``k s`` about z, position
    ``(sin(k s) / k, (1 - cos(k s)) / k, 0)``.
    """
    c = float(carriage_m)
    if not math.isfinite(c):
        raise ValueError(f"carriage position {carriage_m} m is not a finite number")
    s = c * (1.0 + deviation.scale_ppm * 1e-6) + deviation.offset_m
    k = deviation.yaw_urad_per_m * 1e-6
    heading = k * s
    # sin(ks)/k and (1 - cos(ks))/k = 2 sin^2(ks/2)/k, through sinc: exact and smooth as k -> 0
    along = s * float(np.sinc(heading / math.pi))
    across = 0.5 * heading * s * float(np.sinc(heading / (2.0 * math.pi))) ** 2
    T = np.eye(4)
    T[:2, :2] = [[math.cos(heading), -math.sin(heading)], [math.sin(heading), math.cos(heading)]]
    T[:3, 3] = [along, across, 0.0]
    return T


def world_T_base(carriage_m: float, mount_xyz_m: ArrayLike = (0.0, 0.0, 0.0),
                 deviation: RailDeviation = RailDeviation()) -> np.ndarray:
    """The arm's ``base_link`` in ``world`` (4, 4) with the carriage at ``carriage_m`` (m).

    The one conversion between the world (the rail's frame) and the arm's base frame, where the
    arm's kinematics and the controller work: ``carriage_in_world(carriage_m, deviation)`` times the
    carriage -> base mount (``mount_xyz_m``, a translation). A driver uses the position it
    commanded (the encoder's) and no ``deviation``: the rail's true error is what registration on the
    part's reference marks corrects. Without a rail (0 m, zero mount) it is the identity.
    """
    mount = np.asarray(mount_xyz_m, dtype=np.float64).reshape(3)
    if not np.all(np.isfinite(mount)):
        raise ValueError(f"rail mount {mount.tolist()} m is not 3 finite numbers")
    M = np.eye(4)
    M[:3, 3] = mount
    return carriage_in_world(carriage_m, deviation) @ M


def true_world_correction(carriage_m: float, deviation: RailDeviation) -> np.ndarray:
    """What the rail's ``deviation`` does to every pose the cell computes in ``world`` (4, 4), sim-only.

    A pose the driver reports in ``world`` (its forward kinematics on the believed, straight rail)
    is truly at ``true_world_correction(c, deviation) @ pose``: ``carriage_in_world(c, deviation) @
    carriage_in_world(c)^-1`` -- the mount cancels. The identity for a zero deviation.
    """
    return carriage_in_world(carriage_m, deviation) @ np.linalg.inv(carriage_in_world(carriage_m))
