"""The arm driver's parameters: their declarations (range, type, choices) and what the weld job makes of them.

:data:`PARAMS` is declared by :class:`~rm65_driver.driver.driver_node.DriverNode` through
:func:`stud_common.ros_io.declare_params`, which checks each value and then all of them together
with :func:`job_config_problem` (at start-up: a bad value ends the node with exit code 2; at run
time: the change is refused). :func:`job_config` maps the values to the job's
:class:`~rm65_driver.weld.weld_job.WeldParams` and :class:`~rm65_driver.weld.safety.SafetyLimits`.
Units are in the names: ``_m`` metres, ``_s`` seconds, ``_hz``, ``_deg``, ``_pct`` % of the
controller maximum, ``_kg``; ``stud_length_mm`` is in millimetres, as the post-weld inspection's ``nominal_length_mm``
(the cell gives both the same value). No node here.
"""
from __future__ import annotations

import os

import numpy as np

from rm65_driver.kinematics.rm65 import D6_BY_VARIANT, DHModel, RM65Kinematics
from rm65_driver.protocol import messages as P
from rm65_driver.rail.axis import RailAxis, RailRequestError
from rm65_driver.weld.goal_checks import GoalTolerances
from rm65_driver.weld.safety import SafetyChecker, SafetyLimits
from rm65_driver.weld.weld_job import WeldParams
from stud_common import hand_eye_ros
from stud_common.ros_io import Param, three_numbers
from stud_common.vocabulary import OnDisconnect, StudOrder, choices


def default_journal() -> str:
    """``$ROS_HOME/stud_welding/weld_journal.jsonl`` (``~/.ros`` without ``ROS_HOME``): ``journal_file``'s default."""
    home = os.environ.get("ROS_HOME") or os.path.join(os.path.expanduser("~"), ".ros")
    return os.path.join(home, "stud_welding", "weld_journal.jsonl")


#: The weld job's and the safety limits' own defaults, which the parameters expose (one default each); the
#: approach and order below are the cell's, not the library's (final_approach_m, approach_speed_pct,
#: connected_approach, stud_order: WeldParams keeps plain rest-to-rest moves in the given order).
_WELD, _LIMITS = WeldParams(), SafetyLimits()

PARAMS = [
    Param("arm_ip", "127.0.0.1", "controller address; the real RM-65's factory address is 192.168.1.18 "
          "(default here: loopback, the simulator)", read_only=True),
    Param("tcp_port", P.DEFAULT_PORT, "controller JSON port (8080)", min=1, max=65535, read_only=True),
    Param("arm_variant", "RM65-B", "arm variant (sets the flange distance d6 of the kinematics)",
          choices=tuple(D6_BY_VARIANT), read_only=True),
    Param("connect_timeout_s", 2.0, "TCP connect timeout [s]", min=0.1, max=30.0),
    Param("reply_timeout_s", 1.0, "wait for a command's reply [s]", min=0.1, max=10.0),
    Param("state_rate_hz", 10.0, "arm state polling and /arm/state, /joint_states rate [Hz] "
          "(RealMan: poll no faster than every 20 ms)", min=0.5, max=50.0),
    Param("standoff_m", _WELD.standoff_m, "approach distance from the surface along the normal [m]",
          min=0.005, max=0.3),
    Param("stud_length_mm", 0.0, "the welded stud's standing height [mm, as the inspection's nominal_length_mm]: "
          "the gun is pulled straight off the whole stud before it moves sideways, so standoff_m must be at least "
          "this plus stud_clearance_m (refused otherwise); 0: not known, not checked", min=0.0, max=1000.0),
    Param("stud_clearance_m", _WELD.stud_clearance_m, "how far the gun's foot clears the welded stud's top at the "
          "end of the retract [m]", min=0.0, max=0.1),
    Param("min_stud_spacing_m", _WELD.min_stud_spacing_m, "the room the gun's foot needs around its axis beside a "
          "welded stud (foot radius + stud head radius + margin): a stud closer to one already welded is refused, "
          "the neighbour named; 0: not checked [m]", min=0.0, max=0.5),
    Param("tool_offset_m", _WELD.tool_offset_m, "flange -> weld-gun tip along the flange z axis (weld_tool frame) [m]",
          min=0.0, max=0.5),
    Param("plunge_m", _WELD.plunge_m, "how far beyond the surface the tip is commanded (gun spring travel) [m]",
          min=0.0, max=0.02),
    Param("tool_payload_kg", _WELD.tool_payload_kg, "weld gun mass for the controller's tool frame [kg]",
          min=0.0, max=5.0),
    Param("tool_frame_name", _WELD.tool_frame_name, "controller tool frame name (<= 10 characters)",
          validate=lambda v: None if 0 < len(v) <= 10 else f"tool_frame_name {v!r} must be 1..10 characters"),
    Param("trigger_io", _WELD.trigger_io, "digital output that triggers the weld gun (controller DO 1..4, "
          "tool DO 1..2); it sources 2 mA at most: use an external relay module", min=1, max=4),
    Param("trigger_on_tool", _WELD.trigger_on_tool, "trigger through the tool-flange DO instead of the controller DO"),
    Param("set_io_mode", _WELD.set_io_mode, "switch the trigger IO to output mode before a job (Gen-3 controllers)"),
    Param("pulse_s", _WELD.pulse_s, "trigger pulse length [s]", min=0.0, max=5.0),
    Param("dwell_s", _WELD.dwell_s, "hold still after the pulse while the gun completes the weld [s]",
          min=0.0, max=10.0),
    Param("joint_speed_pct", _WELD.joint_speed_pct, "joint-move speed [% of max]", min=1, max=100),
    Param("preferred_joint_signs", [0, 0, 0, 0, 0, 0], "the arm's working branch for /arm/move_to (camera "
          "stations, registration): the sign wanted of each joint J1..J6, -1 / +1, 0 = either; a solution in it "
          "wins over a nearer one in another (e.g. [0, 0, -1, 0, -1, 0]: J3 and J5 negative). All 0: the nearest",
          validate=lambda v: None if len(v) == 6 and all(x in (-1, 0, 1) for x in v)
          else f"preferred_joint_signs needs 6 of -1, 0, 1, got {list(v)}"),
    Param("linear_speed_pct", _WELD.linear_speed_pct, "linear-move speed [% of max]", min=1, max=100),
    Param("final_approach_m", 0.01, "the slow controlled final move: this last stretch before the contact at "
          "linear_speed_pct; the rest of the standoff and the retract at approach_speed_pct (0: the whole "
          "standoff slow) [m]", min=0.0, max=0.3),
    Param("approach_speed_pct", 30, "the fast straight approach to final_approach_m and the retract "
          "[% of max; within max_linear_speed_pct]", min=1, max=100),
    Param("connected_approach", True, "send the fast approach and the slow final move as one connected "
          "trajectory (trajectory_connect=1): on their shared line the arm slows to linear_speed_pct without a "
          "stop between them; false: two moves, each from rest to rest"),
    Param("stud_order", StudOrder.TOUR.value, "the order a job's studs are welded in: 'tour' (a short joint-space "
          "path from the current joints and back), 'path' (no way back) or 'given' (the request's)",
          choices=choices(StudOrder)),
    Param("max_joint_speed_pct", _LIMITS.max_joint_speed_pct, "speed cap for joint moves [%]", min=1, max=100),
    Param("max_linear_speed_pct", _LIMITS.max_linear_speed_pct, "speed cap for linear moves [%]", min=1, max=100),
    Param("workspace_min_m", list(_LIMITS.workspace_min_m), "workspace box lower corner, world [m]",
          validate=three_numbers("workspace_min_m")),
    Param("workspace_max_m", list(_LIMITS.workspace_max_m), "workspace box upper corner, world [m]",
          validate=three_numbers("workspace_max_m")),
    Param("max_tool_tilt_deg", _LIMITS.max_tool_tilt_deg, "how far this cell's gun may lean from vertical "
          "(hose, cable, gun body) -- a property of the cell: studs are welded along the surface normal at any "
          "slope up to it [deg]", min=0.0, max=90.0),
    Param("yaw_step_deg", _LIMITS.yaw_step_deg, "the free rotation about the stud's axis is searched in these "
          "steps for the reachable solution nearest the current joints [deg]", min=1.0, max=180.0),
    # A weld target's normal is the authority; its orientation must agree (weld/goal_checks.py)
    Param("target_normal_length_tol", 1e-3, "a weld target's normal must be a unit vector within this (| |n| - 1 |): "
          "a zero or NaN normal is refused, named", min=1e-9, max=0.1),
    Param("target_quaternion_norm_tol", 1e-2, "a weld target's orientation quaternion within this of unit length "
          "(| |q| - 1 |) is normalised, beyond it refused", min=1e-9, max=0.5),
    Param("target_axis_tol_deg", 1.0, "a weld target whose pose z axis is farther than this from its normal is "
          "refused: the two disagree on the weld direction [deg]", min=0.01, max=30.0),
    Param("motion_timeout_s", _WELD.motion_timeout_s, "a motion that has not arrived by then aborts the job [s]",
          min=1.0, max=600.0),
    Param("reconnect_timeout_s", _WELD.reconnect_timeout_s, "reconnection attempts before a job aborts [s]",
          min=0.5, max=300.0),
    Param("on_disconnect", _WELD.on_disconnect.value, "after a connection loss mid-weld: 'continue' with the next "
          "studs or 'abort'",
          choices=choices(OnDisconnect)),
    Param("journal_file", "", "weld journal (JSON lines); empty: $ROS_HOME/stud_welding/weld_journal.jsonl",
          read_only=True),
    Param("publish_camera_pose", False, "publish /camera/pose = weld-tool pose x hand-eye (an eye-in-hand camera)"),
    *hand_eye_ros.PARAMS,  # hand_eye_xyz_m / hand_eye_rpy_deg, or hand_eye_file (/arm/move_to FRAME_CAMERA)
    # The rail: a linear axis under the arm, the controller's expansion joint (device 4; rail.py). 0 m: none,
    # and the driver is what it is without one (world = the arm's base).
    Param("rail_length_m", 0.0, "the rail's travel [m]: world is then the rail's frame (x along it, origin at its "
          "zero) and the carriage moves 0..rail_length_m; 0: no rail, world = the arm's base", min=0.0, max=100.0,
          read_only=True),
    Param("rail_mount_xyz_m", [0.0, 0.0, 0.0], "the arm's base on the carriage (carriage -> base_link) [m]",
          validate=three_numbers("rail_mount_xyz_m"), read_only=True),
    Param("rail_speed_pct", 30, "rail moves: speed [% of the axis maximum]", min=1, max=100),
    Param("rail_max_speed_m_s", 0.5, "the axis's speed at 100 % (the drive's setting; for move-time estimates "
          "and timeouts) [m/s]", min=0.001, max=10.0),
    Param("rail_accel_m_s2", 0.5, "the axis's acceleration at 100 % (the drive's setting) [m/s^2]",
          min=0.001, max=50.0),
    Param("rail_pos_unit_m", 1e-6, "metres per count of the expansion joint's wire pos (RealMan's documents "
          "say 0.001 of the drive's unit: 1e-6 for a drive in mm)", min=1e-9, max=0.01, read_only=True),
]


def rail_axis(p: dict) -> RailAxis | None:
    """The rail the parameters describe (None: rail_length_m 0, no rail). Raises RailRequestError."""
    if not p["rail_length_m"] > 0:
        return None
    return RailAxis(p["rail_length_m"], p["rail_pos_unit_m"], p["rail_max_speed_m_s"], p["rail_accel_m_s2"])


def job_config(p: dict) -> tuple[WeldParams, SafetyLimits]:
    """The weld job's parameters and limits from the node's parameter values (raises ValueError)."""
    params = WeldParams(
        standoff_m=p["standoff_m"], tool_offset_m=p["tool_offset_m"], plunge_m=p["plunge_m"],
        tool_payload_kg=p["tool_payload_kg"], tool_frame_name=p["tool_frame_name"], trigger_io=p["trigger_io"],
        trigger_on_tool=p["trigger_on_tool"], set_io_mode=p["set_io_mode"], pulse_s=p["pulse_s"],
        dwell_s=p["dwell_s"], joint_speed_pct=p["joint_speed_pct"], linear_speed_pct=p["linear_speed_pct"],
        motion_timeout_s=p["motion_timeout_s"], reconnect_timeout_s=p["reconnect_timeout_s"],
        on_disconnect=p["on_disconnect"], final_approach_m=p["final_approach_m"],
        approach_speed_pct=p["approach_speed_pct"], stud_order=p["stud_order"],
        connected_approach=p["connected_approach"], stud_length_m=p["stud_length_mm"] * 1e-3,
        stud_clearance_m=p["stud_clearance_m"], min_stud_spacing_m=p["min_stud_spacing_m"])
    limits = SafetyLimits(
        workspace_min_m=tuple(p["workspace_min_m"]), workspace_max_m=tuple(p["workspace_max_m"]),
        max_tool_tilt_deg=p["max_tool_tilt_deg"], yaw_step_deg=p["yaw_step_deg"],
        max_joint_speed_pct=p["max_joint_speed_pct"], max_linear_speed_pct=p["max_linear_speed_pct"])
    return params, limits


def goal_tolerances(p: dict) -> GoalTolerances:
    """How consistent a weld goal's targets must be (:mod:`.goal_checks`), from the parameter values."""
    return GoalTolerances(normal_length_tol=p["target_normal_length_tol"],
                          quaternion_norm_tol=p["target_quaternion_norm_tol"], axis_tol_deg=p["target_axis_tol_deg"])


def safety_checker(p: dict, hand_eye_T: np.ndarray, kin: RM65Kinematics | None = None,
                   world_T_base: np.ndarray | None = None) -> SafetyChecker:
    """The checks of a weld job and of /arm/move_to from the parameter values and the hand-eye in
    use, with the arm's base at ``world_T_base`` (identity: no rail); its
    :meth:`~rm65_driver.weld.safety.SafetyChecker.reach_for` is the reach test the driver publishes."""
    params, limits = job_config(p)
    kin = kin if kin is not None else RM65Kinematics(dh=DHModel.rm65(D6_BY_VARIANT[p["arm_variant"]]))
    return SafetyChecker(kin, limits, params.tool_T, world_T_base=np.eye(4) if world_T_base is None else world_T_base,
                         prefer_signs=tuple(p["preferred_joint_signs"]), hand_eye_T=hand_eye_T)


def job_config_problem(p: dict) -> str | None:
    """Why the weld job would refuse these parameter values together (None: it accepts them)."""
    lo, hi = list(p["workspace_min_m"]), list(p["workspace_max_m"])
    if len(lo) == len(hi) == 3 and any(a >= b for a, b in zip(lo, hi)):
        return f"workspace_min_m={lo} must be below workspace_max_m={hi} on every axis (x, y, z)"
    try:
        job_config(p)
    except ValueError as exc:
        return f"combination refused by the weld job: {exc}"
    try:
        rail_axis(p)
    except RailRequestError as exc:
        return str(exc)
    return None
