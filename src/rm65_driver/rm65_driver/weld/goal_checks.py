"""A weld goal's targets checked for consistency before anything moves: which one says where the gun goes.

A ``stud_welding_msgs/WeldTarget`` carries the weld direction twice: ``normal`` (the outward surface
normal) and ``pose.orientation`` (whose z axis is that normal; the gun points along -z, tool z =
-normal). **The normal is the authority**: the gun is welded along ``-normal``, as the matcher
computes it, and the orientation only has to agree with it. The rotation about the axis is free (the
stud is round: :class:`~rm65_driver.weld.safety.SafetyChecker` searches it), so only the orientation's z
axis is compared. A target is refused, named with the reason, never welded on a guess, when:

* its position is not finite;
* its normal is not a finite unit vector: ``| |n| - 1 |`` above ``normal_length_tol`` (zero, NaN, a
  normal of length 2 are no surface direction; a float32 round trip is 1e-7 off);
* its orientation is not a usable quaternion: not finite, or ``| |q| - 1 |`` above
  ``quaternion_norm_tol`` (zero, an unset or garbled quaternion). Within it the quaternion is
  normalised (float32 and rounded decimals);
* the orientation's z axis is more than ``axis_tol_deg`` from the normal: two producers disagree,
  or one of them is wrong, and the driver cannot know which.

Pure Python (numpy), no ROS: the driver node converts each message's fields and calls
:func:`check_target_fields`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rm65_driver.kinematics.rm65 import quat_xyzw_to_matrix
from rm65_driver.weld.weld_job import StudTarget


@dataclass(frozen=True)
class GoalTolerances:
    """How far a target's normal and orientation may be from consistent (module docstring)."""

    normal_length_tol: float = 1e-3      # | |normal| - 1 |
    quaternion_norm_tol: float = 1e-2    # | |q| - 1 |: within it normalised, beyond it refused
    axis_tol_deg: float = 1.0            # orientation z axis vs the normal

    def __post_init__(self) -> None:
        for name in ("normal_length_tol", "quaternion_norm_tol", "axis_tol_deg"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name}={value!r}: expected a positive finite number")


def _fmt(v: np.ndarray) -> str:
    return "(" + ", ".join(f"{x:.6g}" for x in v.tolist()) + ")"


def check_target_fields(stud_id: str, position, normal, quat_xyzw,
                        tol: GoalTolerances = GoalTolerances()) -> tuple[StudTarget | None, str]:
    """The :class:`StudTarget` to weld (the unit normal, the authority), or ``(None, reason)``: one line
    naming the field, its value and what was expected."""
    p = np.asarray(position, dtype=np.float64).reshape(3)
    n = np.asarray(normal, dtype=np.float64).reshape(3)
    q = np.asarray(quat_xyzw, dtype=np.float64).reshape(4)
    if not np.all(np.isfinite(p)):
        return None, f"position {_fmt(p)} is not finite"
    n_len = float(np.linalg.norm(n)) if np.all(np.isfinite(n)) else math.nan
    if not abs(n_len - 1.0) <= tol.normal_length_tol:  # NaN fails too
        return None, (f"normal {_fmt(n)} is not a unit vector (|n| = {n_len:.6g}; expected 1 within "
                      f"{tol.normal_length_tol:g}): no weld direction")
    q_len = float(np.linalg.norm(q)) if np.all(np.isfinite(q)) else math.nan
    if not abs(q_len - 1.0) <= tol.quaternion_norm_tol:
        return None, (f"pose orientation (x, y, z, w) {_fmt(q)} is not a unit quaternion (|q| = {q_len:.6g}; "
                      f"expected 1 within {tol.quaternion_norm_tol:g})")
    unit_n = n / n_len
    z_axis = quat_xyzw_to_matrix(q / q_len)[:, 2]  # the pose's z: the outward normal (tool z = -z)
    angle = math.degrees(math.acos(max(-1.0, min(1.0, float(z_axis @ unit_n)))))
    if angle > tol.axis_tol_deg:
        return None, (f"normal {_fmt(unit_n)} and the pose orientation's z axis {_fmt(z_axis)} are {angle:.2f} deg "
                      f"apart (> {tol.axis_tol_deg:g} deg): which way to weld is not clear")
    return StudTarget(stud_id, p, unit_n), ""
