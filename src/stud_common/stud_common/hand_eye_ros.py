"""The ROS side of the hand-eye transform, shared by every node that poses the camera from the arm.

The camera (sim), shot and arm-driver nodes, and the calibrator, declare :data:`PARAMS`:
``hand_eye_xyz_m`` / ``hand_eye_rpy_deg`` (the typed value), ``hand_eye_file`` (a calibration file
that replaces it, :mod:`stud_common.hand_eye_in_use`) and ``hand_eye_limits.*`` (what such a file
must meet: :class:`~stud_common.hand_eye_in_use.HandEyeLimits`). :func:`hand_eye_in_use` decides which
value a node uses (a refused file ends the node with exit code 2 and the reason), and
:class:`CalibrationTopic` publishes it on ``/calibration/hand_eye``: std_msgs/String with a JSON
object (:meth:`HandEyeInUse.summary`: source, path, date, xyz/rpy/quaternion, residuals), reliable
+ transient local so a late subscriber (the HMI) gets it.
"""
from __future__ import annotations

import json
from dataclasses import fields

from rclpy.node import Node
from std_msgs.msg import String

from stud_common import names, ros_io
from stud_common.hand_eye_in_use import HandEyeFileError, HandEyeInUse, HandEyeLimits, resolve_hand_eye
from stud_common.ros_io import Param, three_numbers

TOPIC = names.CALIBRATION_HAND_EYE
LIMITS_NS = "hand_eye_limits"


_LIMIT_TEXT = {
    "min_poses": ("usable shots a calibration needs", 3, 500),
    "min_rotation_spread_deg": ("the poses' orientations must span this about each of two axes [deg]", 1.0, 180.0),
    "max_rms_mm": ("largest RMS over shots of the marks' residual [mm]", 0.001, 100.0),
    "max_shot_mm": ("largest residual of any shot (RMS of its three marks) [mm]", 0.001, 100.0),
    "max_rms_deg": ("largest RMS over shots of the board orientation residual [deg]", 0.001, 90.0),
    "max_shot_deg": ("largest board orientation residual of any shot [deg]", 0.001, 90.0),
    "mark_distance_tol_mm": ("a shot's |OA|, |OB| may differ this much from the drawing's [mm]", 0.01, 50.0),
    "mark_angle_tol_deg": ("a shot's angle AOB may differ this much from the drawing's [deg]", 0.01, 45.0),
    "max_reprojection_px": ("above this reprojection RMS the intrinsics need attention (a warning) [px]", 0.01, 100.0),
    "methods_agree_mm": ("closed-form methods within this of the result agree (reported) [mm]", 0.001, 1000.0),
    "methods_agree_deg": ("closed-form methods within this of the result agree (reported) [deg]", 0.001, 180.0),
    "check_max_mm": ("the hand-eye error a check must catch: it fails when its shots' own hand-eye is farther "
                     "than this, less what the shots' noise explains, from the one checked [mm]",
                     0.001, 100.0),
    "check_max_deg": ("the same for the rotation [deg]", 0.001, 90.0),
}
_DEFAULTS = HandEyeLimits()
assert set(_LIMIT_TEXT) == {f.name for f in fields(HandEyeLimits)}, "describe every HandEyeLimits field"

#: The limit parameters, ``hand_eye_limits.<field>`` (defaults: HandEyeLimits()).
LIMIT_PARAMS = [Param(f"{LIMITS_NS}.{name}", getattr(_DEFAULTS, name), text, min=lo, max=hi)
                for name, (text, lo, hi) in _LIMIT_TEXT.items()]

#: Every node that poses the camera from the arm declares these.
PARAMS = [
    Param("hand_eye_xyz_m", [0.0, 0.0, 0.0], "optical frame origin in the weld-tool frame [m] (the typed "
          "hand-eye; hand_eye_file replaces it)", validate=three_numbers("hand_eye_xyz_m")),
    Param("hand_eye_rpy_deg", [0.0, 0.0, 0.0], "optical frame orientation in the weld-tool frame, roll-pitch-yaw "
          "[deg] (the typed hand-eye; hand_eye_file replaces it)", validate=three_numbers("hand_eye_rpy_deg")),
    Param("hand_eye_file", "", "hand-eye calibration file (hand_eye.yaml of `cell --mode calibrate`); empty: "
          "use hand_eye_xyz_m / hand_eye_rpy_deg", read_only=True),
    *LIMIT_PARAMS,
]


def limits_from(p: dict) -> HandEyeLimits:
    """HandEyeLimits from declared parameter values (:data:`LIMIT_PARAMS`)."""
    return HandEyeLimits(**{name: p[f"{LIMITS_NS}.{name}"] for name in _LIMIT_TEXT})


def hand_eye_in_use(node: Node, p: dict) -> HandEyeInUse:
    """The hand-eye this node uses (the file, or the typed value); a file that is refused ends the
    node: the reason on the log, exit code 2."""
    try:
        in_use = resolve_hand_eye(p["hand_eye_file"], p["hand_eye_xyz_m"], p["hand_eye_rpy_deg"], limits_from(p))
    except (HandEyeFileError, ValueError) as exc:
        node.get_logger().fatal(f"hand_eye_file: {exc}")
        raise SystemExit(2) from None
    if in_use.source == "file":
        node.get_logger().info(
            f"hand-eye from {in_use.path} ({in_use.date}): xyz {[round(v, 5) for v in in_use.xyz_m]} m, rpy "
            f"{[round(v, 3) for v in in_use.rpy_deg]} deg, residual RMS {in_use.position_rms_mm:.3f} mm / "
            f"{in_use.rotation_rms_deg:.3f} deg over {in_use.poses_used} poses")
    return in_use


class CalibrationTopic:
    """Publishes the hand-eye in use on ``/calibration/hand_eye`` (latched JSON, module docstring)."""

    def __init__(self, node: Node, in_use: HandEyeInUse, publisher_node: str = ""):
        self._pub = node.create_publisher(String, TOPIC, ros_io.LATCHED_QOS)
        self.publish(in_use, publisher_node or node.get_name())

    def publish(self, in_use: HandEyeInUse, publisher_node: str) -> None:
        self._pub.publish(String(data=json.dumps({**in_use.summary(), "node": publisher_node})))
