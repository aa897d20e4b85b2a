"""Every topic, service and action name of the cell, in one place (the interface contract:
docs/INTERFACES.md). Nodes use these absolute names; a deployment remaps them with
``--ros-args -r /camera/pose:=/other``, so the constants never need editing.

Frames are in :mod:`stud_common.frames`, message constants in :mod:`stud_common.vocabulary`.
"""
from __future__ import annotations

# -- camera (the RGB-D sensor, real or simulated; depth registered to colour) ---------------------
COLOR_IMAGE = "/camera/color/image_raw"
DEPTH_IMAGE = "/camera/depth/image_raw"
CAMERA_INFO = "/camera/color/camera_info"
CAMERA_POSE = "/camera/pose"                       # optical frame in `world` at the images' stamp
CAMERA_POSE_RECORDED = "/camera/pose_recorded"     # replay: the bag's pose, re-posed by pose_rebase
CAMERA_TRIGGER = "/camera/trigger"                 # std_srvs/Trigger: one shot

# -- the post-weld inspection's shots: the same camera and the same four messages on topics of their own
#    (the matcher never takes a shot of welded studs for a view to plan welds on; docs/INTERFACES.md)
CAMERA_TRIGGER_INSPECTION = "/camera/trigger_inspection"   # std_srvs/Trigger: one inspection shot
INSPECTION_COLOR_IMAGE = "/camera/inspection/color/image_raw"
INSPECTION_DEPTH_IMAGE = "/camera/inspection/depth/image_raw"
INSPECTION_CAMERA_INFO = "/camera/inspection/color/camera_info"
INSPECTION_CAMERA_POSE = "/camera/inspection/pose"

# -- drawing, registration, matching ---------------------------------------------------------------
DRAWING_LAYOUT = "/drawing/layout"
DRAWING_POSES = "/drawing/poses"
DRAWING_LOAD = "/drawing/load"
REGISTRATION_RESULT = "/registration/result"
REGISTRATION_OVERLAY = "/registration/overlay"
REGISTRATION_TRIGGER = "/registration/trigger"
WELD_TARGETS = "/weld_targets"
WELD_TARGET_POSES = "/weld_targets/poses"
WELD_TARGET_MARKERS = "/weld_targets/markers"
WELD_TARGET_OVERLAY = "/weld_targets/overlay"
WELD_TARGET_OVERLAY_COMPRESSED = "/weld_targets/overlay/compressed"   # the same as JPEG

# -- arm (RM-65 driver) ----------------------------------------------------------------------------
ARM_STATE = "/arm/state"
ARM_WELDS = "/arm/welds"
ARM_WELD_JOB = "/arm/weld_job"                     # action stud_welding_msgs/action/WeldJob
ARM_MOVE_TO = "/arm/move_to"
ARM_RAIL_MOVE = "/arm/rail_move"                   # stud_welding_msgs/srv/RailMove: the carriage along the rail
ARM_STOP = "/arm/stop"
ARM_PAUSE = "/arm/pause"
ARM_RESUME = "/arm/resume"
ARM_ESTOP = "/arm/estop"
ARM_RESOLVE_STUD = "/arm/resolve_stud"
ARM_RESOLVE_JOURNAL = "/arm/resolve_journal"
ARM_REACH_CONFIG = "/arm/reach_config"             # std_msgs/String, JSON: rm65_driver.weld.reach.ReachConfig
JOINT_STATES = "/joint_states"
ROBOT_DESCRIPTION = "/robot_description"

# -- cell, inspection, calibration -----------------------------------------------------------------
CELL_STATUS = "/cell/status"
CELL_START = "/cell/start"
CELL_STOP = "/cell/stop"
CELL_PAUSE = "/cell/pause"
CELL_RESUME = "/cell/resume"
INSPECTION_INSPECT = "/inspection/inspect"
INSPECTION_RESULT = "/inspection/result"
INSPECTION_RECORD_REWORK = "/inspection/record_rework"
INSPECTION_REWORK = "/inspection/rework"
INSPECTION_RECORD_BEND_TEST = "/inspection/record_bend_test"
INSPECTION_BEND_TESTS = "/inspection/bend_tests"
CALIBRATION_HAND_EYE = "/calibration/hand_eye"

def shot_topics(inspection: bool = False) -> dict[str, str]:
    """The four topics of one shot, by stream name ("color", "depth", "info", "pose"): a matching view's,
    or with ``inspection`` a post-weld inspection shot's."""
    if inspection:
        return {"color": INSPECTION_COLOR_IMAGE, "depth": INSPECTION_DEPTH_IMAGE, "info": INSPECTION_CAMERA_INFO,
                "pose": INSPECTION_CAMERA_POSE}
    return {"color": COLOR_IMAGE, "depth": DEPTH_IMAGE, "info": CAMERA_INFO, "pose": CAMERA_POSE}


# -- ROS-wide --------------------------------------------------------------------------------------
DIAGNOSTICS = "/diagnostics"
TF = "/tf"
TF_STATIC = "/tf_static"
