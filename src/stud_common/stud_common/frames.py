"""The cell's coordinate frames (REP 103/105: metres, radians, right-handed) and their pure math.

One vocabulary for every node that stamps or publishes a frame (docs/FRAMES.md has the tree):

* ``world`` -- the RM-65 base frame, z up; the cell's fixed frame (REP 105's ``map``/``odom`` role:
  nothing moves it).
* ``base_link`` -- the arm's base, coincident with ``world`` (a fixed URDF joint, so an arm mounted
  elsewhere is one origin to change).
* ``link1`` ... ``link6``, ``rm65_flange`` -- the arm's links (modified-DH frames) and its flange.
* ``weld_tool`` -- the weld-gun tip: ``rm65_flange`` moved by the tool offset along flange z.
* ``camera_color_optical_frame`` -- the eye-in-hand camera, z forward, x right, y down (REP 103's
  optical convention), placed on ``weld_tool`` by the hand-eye calibration.
* ``drawing`` -- the drawing's frame: origin at mark O, x toward A, y toward B, z up; placed in
  ``world`` by the registration.
"""
from __future__ import annotations

import math

import numpy as np

WORLD = "world"
BASE_LINK = "base_link"
FLANGE = "rm65_flange"
WELD_TOOL = "weld_tool"
CAMERA_OPTICAL = "camera_color_optical_frame"
DRAWING = "drawing"


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
