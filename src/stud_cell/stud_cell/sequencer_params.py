"""The cell sequencer's ROS parameters: the job's settings (:class:`~stud_cell.job_ports.JobConfig`, whose
defaults they expose), the waits of the adapter and the QA code's choices."""
from __future__ import annotations

import math

from stud_cell.job_ports import JobConfig
from stud_common.ros_io import Param, three_numbers
from stud_inspection.qa_params import QA_CODE_PARAM, SAMPLING_PARAMS

_JOB = JobConfig()  # the job's defaults are its own; the parameters expose them
PARAMS = [
    Param("auto_start", False, "start the job as soon as the layout is there"),
    Param("exit_when_done", False, "end the process when the job ends (exit 0 only if every stud was welded)"),
    Param("report_file", "", "write a JSON report of every stud here at the end (empty: none)"),
    Param("registration_station_xyz_m", list(_JOB.registration_station_xyz_m),
          "camera position over the marking board, where the registration looks first [m]; [] (none): the board "
          "is searched for over board_search_area_xy_m", validate=lambda v: None if v is None or len(v) in (0, 3)
          else f"registration_station_xyz_m needs 3 numbers (x, y, z) or [] (search for the board), got {list(v)}"),
    Param("board_search_area_xy_m", list(_JOB.board_search_area_xy_m), "where the board may lie: [x_min, y_min, "
          "x_max, y_max] in world [m], searched when the registration station shows no marks; [] (default): the "
          "arm's table, x 0..0.65 m and y -0.55..0.55 m, stretched along the rail's travel",
          validate=lambda v: None if v is None or len(v) == 0 or (len(v) == 4 and v[2] > v[0] and v[3] > v[1])
          else f"board_search_area_xy_m needs [x_min, y_min, x_max, y_max] with max > min, or [], got {list(v)}"),
    Param("board_search_plane_z_m", _JOB.board_search_plane_z_m, "world height of the table the board lies on [m]",
          min=-2.0, max=2.0),
    Param("board_search_heights_m", list(_JOB.board_search_heights_m), "camera heights above that table the search "
          "tries, the highest the arm reaches at each place is used [m]",
          validate=lambda v: None if len(v) > 0 and min(v) > 0 else f"board_search_heights_m needs positive heights, "
          f"got {list(v)}"),
    Param("board_search_max_shots", _JOB.board_search_max_shots, "views the board search takes at most (with the "
          "default area: per 0.65 m of it along the rail)", min=1, max=200),
    Param("station_height_steps_m", list(_JOB.station_height_steps_m), "camera height changes tried, in order, "
          "for a station the arm cannot reach (it is also slid within its studs' room and its image turned) [m]",
          validate=lambda v: None if len(v) > 0 else "station_height_steps_m needs at least one value (0.0)"),
    Param("reach_config_timeout_s", 10.0, "wait this long at the job's start for the arm driver's "
          "/arm/reach_config; without it the job plans without the reach test (warned) [s]", min=0.0, max=600.0),
    Param("camera_height_m", _JOB.camera_height_m, "camera height of the stations above the working plane [m]",
          min=0.05, max=2.0),
    Param("camera_yaw_deg", _JOB.camera_yaw_deg, "image yaw of the stations [deg]", min=-360.0, max=360.0),
    Param("part_height_m", _JOB.part_height_m, "top of the part above the plane, for the footprint [m]",
          min=0.0, max=1.0),
    Param("fov_width_m", _JOB.fov_width_m, "camera field-of-view width at fov_distance_m [m]", min=0.01, max=10.0),
    Param("fov_distance_m", _JOB.fov_distance_m, "distance of fov_width_m [m]", min=0.05, max=10.0),
    Param("image_aspect", _JOB.image_aspect, "image height / width", min=0.1, max=10.0),
    Param("overlap", _JOB.overlap, "footprint fraction kept free at the image border", min=0.0, max=0.85),
    # On in the cell (fewer stations: fewer camera moves, shots and inspections); the job's own default
    # keeps the grid tiling.
    Param("fewest_stations", True, "place the stations' footprints freely when that needs fewer stations than "
          "the grid tiling"),
    Param("step_timeout_s", 60.0, "longest wait for a move, a shot, a registration or the targets [s]",
          min=1.0, max=3600.0),
    Param("weld_timeout_s", 1800.0, "longest wait for one station's weld job [s]", min=1.0, max=86400.0),
    Param("shot_retries", 3, "shots tried per station before giving up", min=1, max=20),
    Param("driver_lost_s", 1.5, "a gap this long in /arm/state during a weld job, after which the driver "
          "reports no job, means it was restarted and lost the job [s]", min=0.3, max=600.0),
    Param("weld_resends", _JOB.weld_resends, "times a station's weld job is sent again to a restarted driver "
          "(resume: its journal skips what is welded)", min=0, max=20),
    Param("reshoot_attempts", _JOB.reshoot_attempts, "views taken again, from other directions, of a stud no view "
          "gave a usable target for (normal uncertain, no depth, ...) before giving up on it; it is never welded "
          "blind", min=0, max=8),
    Param("reshoot_offset_m", _JOB.reshoot_offset_m, "the re-shoot camera stands this far beside the stud [m]",
          min=0.0, max=0.5),
    Param("inspect", _JOB.inspect, "after a station's welds, shoot it again and have /inspection/inspect measure "
          "and judge every stud welded there (false: no post-weld inspection; the QA record says not_inspected)"),
    Param("inspect_timeout_s", 60.0, "longest wait for one station's inspection [s]", min=1.0, max=3600.0),
    Param("qa_dir", "", "write the QA record (qa_report.json, .csv, .html) into this folder at the end (empty: none)"),
    Param("part_name", "", "the part's name, for the QA record"),
    Param("rework_file", "", "the inspector's rework decisions file (JSON lines): decisions taken during the job "
          "go into the QA record's rework column (empty: none)"),
    Param("bend_file", "", "the inspector's bend-test results file (JSON lines): results entered during the job go "
          "into the QA record (empty: none)"),
    QA_CODE_PARAM,
    *SAMPLING_PARAMS,
    Param("sample_seed", 0, "the seed of the lot's bend-test sample, stored in the QA record (0: a random one)",
          min=0, max=2**31 - 1),
    # The rail (stud_cell.rail_job, rail_plan): pass the arm driver's values (cell.yaml does)
    Param("rail_length_m", _JOB.rail_length_m, "the rail's travel, as the arm driver's rail_length_m [m]: > 0, the "
          "job plans the fewest carriage positions along it and registers at each; 0: no rail, the arm fixed",
          min=0.0, max=100.0),
    Param("rail_mount_xyz_m", list(_JOB.rail_mount_xyz_m), "the arm's base on the carriage, as the arm driver's "
          "rail_mount_xyz_m [m]", validate=three_numbers("rail_mount_xyz_m")),
    Param("rail_coarse_step_m", _JOB.rail_coarse_step_m, "the carriage positions a camera station is reached from "
          "are sampled this far apart, then bisected [m]", min=0.005, max=0.5),
    Param("rail_tolerance_m", _JOB.rail_tolerance_m, "... to within this [m]", min=0.0005, max=0.5),
    Param("rail_stud_height_m", _JOB.rail_stud_height_m, "the studs' height above the working plane the carriage "
          "positions are planned for: where the arm welds a stud there, normal up, is the plan's prior [m]; NaN: "
          "half part_height_m", nan_means="half part_height_m",
          validate=lambda v: None if math.isnan(v) or 0.0 <= v <= 2.0
          else f"rail_stud_height_m={v}: expected 0.0 .. 2.0 m, or NaN (half part_height_m)"),
    Param("rail_move_timeout_s", 300.0, "longest wait for the carriage to arrive at a carriage position [s]",
          min=1.0, max=3600.0),
]
