"""Hand-eye calibrator: `ros2 run stud_planner hand_eye_calibrator` (``cell --mode calibrate|verify``).

``task:=calibrate``: finds the marking board from the registration station, then moves the arm
through ``/arm/move_to`` to the views of
:func:`~stud_cell.hand_eye_views.plan_calibration_views` (a view the driver refuses is skipped
and counted): the first through the believed hand-eye (camera frame), the rest, once a few shots
agree on one, through the estimate so far (tool frame;
:class:`~stud_cell.hand_eye_views.ViewAimer`, so a camera mounted degrees off its believed
pose still sees the board in the tilted views). At each view it waits for the arm to settle, takes
the weld-tool pose from ``/arm/state``, shoots (``/camera/trigger``), finds O, A, B (sub-pixel,
``markers.py``) and lifts them with Eq. 1 into the camera frame.
:func:`~stud_perception.hand_eye.calibrate_hand_eye` solves the camera-to-tool transform;
``<output_dir>/hand_eye.yaml`` gets the result, accepted or refused with the reasons
(:mod:`stud_perception.hand_eye_file`).

``task:=verify``: a few views (:func:`~stud_cell.hand_eye_views.plan_check_views`), the residual
of the hand-eye in use (``hand_eye_file`` or the typed value) with
:func:`~stud_perception.hand_eye.check_hand_eye`, whose limits follow from the noise the shots show and
their number: when that noise needs more views to tell a ``check_max_mm`` / ``check_max_deg`` error
from noise, the check views are shot again (up to ``max_verify_views``); prints PASS or FAIL and writes
``<output_dir>/hand_eye_check.yaml``.

Exit code (``exit_when_done``): 0 accepted / passed, 1 refused / failed or the procedure could not
run (the log says why), 2 bad parameters or calibration file.
"""
from __future__ import annotations

import functools
import threading
import time
from pathlib import Path

import numpy as np
from geometry_msgs.msg import PoseStamped
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image
from std_srvs.srv import Trigger
from stud_welding_msgs.msg import ArmState, StudLayout
from stud_welding_msgs.srv import MoveTo

from stud_cell.hand_eye_views import (
    CalibrationView,
    ViewAimer,
    ViewPlanError,
    board_centre_w,
    plan_calibration_views,
    plan_check_views,
    station_view,
)
from stud_common import hand_eye_ros, names, ros_io
from stud_common.hand_eye_in_use import camera_in_world
from stud_common.ros_io import Param, three_numbers
from stud_common.rotations import transform
from stud_perception import image_io
from stud_perception.hand_eye import (
    BoardShot,
    board_points_m,
    board_pose_from_marks,
    calibrate_hand_eye,
    check_with_enough_views,
)
from stud_perception.hand_eye_file import calibration_record, check_record, write_yaml
from stud_perception.hand_eye_solvers import HandEyeError, rotation_angle_deg
from stud_perception.markers import MarkDetectorConfig, detect_marks
from stud_perception.registration import layout_marks_m
from stud_perception.view_registration import config_for_layout


def _tilts(v) -> str | None:
    return None if v and all(0.0 < t <= 60.0 for t in v) else f"view_tilts_deg must be within (0, 60], got {list(v)}"


PARAMS = [
    ros_io.SENSOR_QOS_PARAM,
    Param("task", "calibrate", "'calibrate': solve and write hand_eye.yaml; 'verify': check the hand-eye in use",
          choices=("calibrate", "verify"), read_only=True),
    Param("output_dir", ".", "folder for hand_eye.yaml (calibrate) or hand_eye_check.yaml (verify)", read_only=True),
    Param("exit_when_done", True, "end the process when done (exit 0: accepted / passed, 1: not)"),
    Param("board_station_xyz_m", [0.225, -0.29, 0.285], "camera position over the marking board for the first, "
          "straight-down look that finds the board [m] (the sequencer's registration station)",
          validate=three_numbers("board_station_xyz_m")),
    Param("view_distance_m", 0.30, "camera distance from the board centre in the views [m]", min=0.1, max=1.5),
    Param("view_tilts_deg", [10.0, 20.0, 30.0], "calibration views' tilts from straight down [deg]",
          validate=_tilts),
    Param("views_per_tilt", 12, "calibration views' azimuths per tilt (those the arm cannot reach are skipped)",
          min=1, max=72),
    Param("view_yaw_span_deg", 30.0, "views turn about the optical axis by up to this [deg]", min=0.0, max=90.0),
    Param("max_poses", 24, "calibrate: stop after this many usable shots", min=3, max=500),
    Param("verify_poses", 4, "verify: tilted shots besides the straight-down one", min=1, max=50),
    Param("max_verify_views", 60, "verify: when the noise the first shots show needs more views to tell a "
          "check_max_mm / check_max_deg error from noise, the check views are shot again up to this many shots "
          "in all (beyond: FAIL, inconclusive)", min=2, max=1000),
    Param("verify_tilt_deg", 25.0, "verify: tilt of the check views [deg]", min=1.0, max=60.0),
    Param("step_timeout_s", 60.0, "longest wait for a move, a shot or a frame [s]", min=1.0, max=3600.0),
    Param("distance_tol_m", 0.004, "mark detection: allowed |measured - drawing| of |OA|, |OB|, |AB| [m]",
          min=1e-4, max=0.05),
    Param("depth_min_m", 0.15, "mark detection: nearest camera-to-board distance searched [m]", min=0.05, max=5.0),
    Param("depth_max_m", 1.2, "mark detection: farthest camera-to-board distance searched [m]", min=0.1, max=10.0),
    Param("min_contrast", 40.0, "mark detection: least grey-level difference of a mark", min=1.0, max=255.0),
    Param("sync_slop_s", 0.0, "stamps closer than this belong to one view [s] (0: equal stamps)", min=0.0, max=1.0),
    image_io.IMAGES_RECTIFIED_PARAM,
    *hand_eye_ros.PARAMS,
]


class Aborted(Exception):
    """The procedure cannot go on: the message says why."""


#: /arm/move_to refusals that are about the arm, not the view (MoveTo answers with a message only): an
#: unreachable view is skipped, but these stop the procedure, or it would skip every view.
_ARM_BUSY = ("e-stop engaged", "a weld job is running")


class HandEyeCalibrator(Node):
    def __init__(self) -> None:
        super().__init__("hand_eye_calibrator")
        self.p = ros_io.declare_params(self, PARAMS)
        self.limits = hand_eye_ros.limits_from(self.p)
        self.hand_eye = hand_eye_ros.hand_eye_in_use(self, self.p)
        cb = ReentrantCallbackGroup()
        self._cond = threading.Condition()
        self.layout: StudLayout | None = None
        self.arm_state: ArmState | None = None
        self.view: dict | None = None
        self.exit_code: int | None = None
        self.create_subscription(StudLayout, names.DRAWING_LAYOUT, self._keep("layout"), ros_io.LATCHED_QOS,
                                 callback_group=cb)
        self.create_subscription(ArmState, names.ARM_STATE, self._keep("arm_state"), ros_io.RESULT_QOS,
                                 callback_group=cb)
        self.sync = ros_io.StampSync(["color", "depth", "info", "pose"], self._keep("view"),
                                     slop_ns=int(self.p["sync_slop_s"] * 1e9),
                                     on_drop=ros_io.warn_dropped(self, "view"))
        for name, topic, typ in (("color", names.COLOR_IMAGE, Image), ("depth", names.DEPTH_IMAGE, Image),
                                 ("info", names.CAMERA_INFO, CameraInfo), ("pose", names.CAMERA_POSE, PoseStamped)):
            self.create_subscription(typ, topic, functools.partial(self._add, name),
                                     ros_io.sensor_qos(self.p["sensor_qos"]), callback_group=cb)
        self.cli_move = self.create_client(MoveTo, names.ARM_MOVE_TO, callback_group=cb)
        self.cli_shot = self.create_client(Trigger, names.CAMERA_TRIGGER, callback_group=cb)
        self.diag = ros_io.Diagnostics(self)
        self.create_timer(1.0, self.diag.publish, callback_group=cb)
        self._stop = threading.Event()
        self._worker = threading.Thread(target=self._run, name="hand_eye", daemon=True)
        self._worker.start()
        self.get_logger().info(f"hand-eye {self.p['task']}: waiting for /drawing/layout, /arm/move_to and "
                               "/camera/trigger")

    # -- inputs ---------------------------------------------------------------------------------
    def _keep(self, attr: str):
        def store(msg) -> None:
            with self._cond:
                setattr(self, attr, msg)
                self._cond.notify_all()
        return store

    def _add(self, name: str, msg) -> None:
        with self._cond:
            self.sync.add(name, msg)

    def _wait_for(self, predicate, what: str, timeout_s: float | None = None):
        timeout_s = self.p["step_timeout_s"] if timeout_s is None else timeout_s
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while not (value := predicate()):
                if self._stop.is_set():
                    raise Aborted(f"stopped while waiting for {what}")
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise Aborted(f"no {what} within {timeout_s:.0f} s")
                self._cond.wait(min(remaining, 0.1))
            return value

    def _call(self, client, request):
        if not client.wait_for_service(timeout_sec=min(self.p["step_timeout_s"], 10.0)):
            raise Aborted(f"service {client.srv_name} is not available")
        done = threading.Event()
        future = client.call_async(request)
        future.add_done_callback(lambda _f: done.set())
        if not done.wait(self.p["step_timeout_s"]):
            raise Aborted(f"no answer from {client.srv_name} within {self.p['step_timeout_s']:.0f} s")
        return future.result()

    # -- one view -------------------------------------------------------------------------------
    def _move(self, view: CalibrationView, T_world_tool: np.ndarray | None = None) -> str | None:
        """Camera to the view (or the weld tool to ``T_world_tool``, the view through an estimated
        hand-eye); the driver's refusal (unreachable, workspace) as text, None when there."""
        if T_world_tool is None:
            req = MoveTo.Request(pose=ros_io.rt_to_pose(view.R_world_cam, view.t_world_cam),
                                 frame=MoveTo.Request.FRAME_CAMERA)
        else:
            req = MoveTo.Request(pose=ros_io.rt_to_pose(T_world_tool[:3, :3], T_world_tool[:3, 3]),
                                 frame=MoveTo.Request.FRAME_TOOL)
        reply = self._call(self.cli_move, req)
        if not reply.success:
            return reply.message
        arrived = self.get_clock().now().nanoseconds
        seen: set[int] = set()

        def settled():  # two states from after the move, not moving: the camera node has one too
            st = self.arm_state
            if st is not None and ros_io.stamp_to_ns(st.header.stamp) > arrived and st.mode != ArmState.MODE_MOVING:
                seen.add(ros_io.stamp_to_ns(st.header.stamp))
            return len(seen) >= 2

        self._wait_for(settled, "/arm/state after the move")
        return None

    def _shoot(self, drawing_marks: np.ndarray, config: MarkDetectorConfig) -> tuple[BoardShot | None, str]:
        """One shot at the current pose: the board shot, or None and why not."""
        assert self.arm_state is not None  # _move_and_settle waited for it
        tool_R, tool_t = ros_io.pose_to_rt(self.arm_state.tool_pose)
        t0 = self.get_clock().now().nanoseconds
        deadline = time.monotonic() + self.p["step_timeout_s"]
        while not (reply := self._call(self.cli_shot, Trigger.Request())).success:
            if time.monotonic() > deadline:
                return None, f"camera refused the shot: {reply.message}"
            time.sleep(0.2)  # a camera waiting for a fresh pose says so: ask again shortly
        view = self._wait_for(lambda: self.view if self.view is not None and
                              ros_io.stamp_to_ns(self.view["color"].header.stamp) >= t0 else None, "frame of the shot")
        try:
            decoded = image_io.decode_view(view["info"], view["pose"].pose, view["depth"], view["color"],
                                           self.p["images_rectified"], image_io.view_topics(self))
            camera = decoded.camera
            det = detect_marks(decoded.color_bgr, decoded.depth_m, camera, drawing_marks, config)
        except (ros_io.MessageError, ValueError) as exc:
            return None, f"unusable frame: {exc}"
        if not det.ok:
            return None, f"marks not found ({det.status.value}): {det.message}"
        # Eq. 1 gave world points through /camera/pose (the believed pose: only the handedness check
        # needs it); the calibration wants them in the camera frame, which undoes that pose exactly.
        marks_cam = camera.world_to_camera(det.marks_world_m)
        return BoardShot(transform(tool_R, tool_t), marks_cam, det.marks_pixels_uv, camera.K), det.message

    def _shots(self, views: list[CalibrationView], wanted: int, drawing_marks, config,
               aimer: ViewAimer | None = None) -> tuple[list, int, int]:
        """Shots at ``views`` until ``wanted``; with an ``aimer``, at its views, re-aimed as shots come in."""
        shots: list[BoardShot] = []
        refused = failed = 0
        for i in range(len(views)):
            if len(shots) >= wanted or self._stop.is_set():
                break
            view = aimer.views[i] if aimer is not None else views[i]
            why = self._move(view, aimer.tool_pose(view) if aimer is not None else None)
            if why is not None and why.startswith(_ARM_BUSY):
                raise Aborted(f"the arm driver refused to move: {why}")
            if why is not None:
                refused += 1
                self.get_logger().info(f"{view.describe()}: refused by the arm driver ({why}); skipped")
                continue
            shot, message = self._shoot(drawing_marks, config)
            if shot is None:
                failed += 1
                self.get_logger().warn(f"{view.describe()}: {message}; skipped")
                continue
            shots.append(shot)
            self.diag.set(self.diag.OK, f"{len(shots)} shot(s)", refused=refused, failed=failed)
            self.get_logger().info(f"{view.describe()}: shot {len(shots)} ({message})")
            if aimer is not None and (line := aimer.update(shots, self.hand_eye.T_tool_cam)):
                self.get_logger().info(line)
        return shots, refused, failed

    # -- the procedure --------------------------------------------------------------------------
    def _run(self) -> None:
        try:
            self.exit_code = self._procedure()
        except (Aborted, HandEyeError, ViewPlanError) as exc:
            self.get_logger().error(f"hand-eye {self.p['task']} FAILED: {exc}")
            self.diag.set(self.diag.ERROR, str(exc))
            self.exit_code = 1
        except Exception as exc:  # the worker must end with an exit code, never vanish
            self.get_logger().error(f"hand-eye {self.p['task']} crashed: {exc!r}")
            self.exit_code = 1

    def _procedure(self) -> int:
        p = self.p
        layout = self._wait_for(lambda: self.layout, names.DRAWING_LAYOUT)
        drawing_marks = layout_marks_m(layout)
        config = config_for_layout(MarkDetectorConfig(depth_range_m=(p["depth_min_m"], p["depth_max_m"]),
                                                      distance_tol_m=p["distance_tol_m"],
                                                      min_contrast=p["min_contrast"]), layout.mark_diameter)
        self._wait_for(lambda: self.arm_state, names.ARM_STATE)
        # Find the board: straight down from the registration station.
        first, _, _ = self._shots([station_view(p["board_station_xyz_m"])], 1, drawing_marks, config)
        if not first:
            raise Aborted(f"the marking board was not found from board_station_xyz_m {p['board_station_xyz_m']} "
                          "(see the warning above)")
        target = self._board_centre_w(first[0], drawing_marks)
        self.get_logger().info(f"marking board found; views look at {np.round(target, 4).tolist()} m")
        if p["task"] == "calibrate":
            aimer = ViewAimer(lambda t: plan_calibration_views(t, p["view_distance_m"], tuple(p["view_tilts_deg"]),
                                                               p["views_per_tilt"], p["view_yaw_span_deg"]),
                              target, drawing_marks, self.limits)
            shots, refused, failed = self._shots(aimer.views, p["max_poses"], drawing_marks, config, aimer)
            return self._calibrate(shots, refused, failed, drawing_marks, aimer.aimed_from)
        views = plan_check_views(target, p["view_distance_m"], p["verify_tilt_deg"], 8, p["view_yaw_span_deg"])

        def shoot(k: int) -> list:  # the check views again, as often as needed
            return self._shots(views * (k // max(len(views), 1) + 2), k, drawing_marks, config)[0]

        def more(check, wanted: int) -> None:
            have = len(check.shot_residual_mm)
            needs = (f"needs {check.spread.views_needed} views to show" if check.spread.views_needed else
                     "may not show with any number of views by this estimate")
            self.get_logger().info(
                f"the check's {have} shots: {check.spread.describe()}; an error of {self.limits.check_max_mm:g} mm / "
                f"{self.limits.check_max_deg:g} deg {needs}: taking {wanted - have} more")

        check = check_with_enough_views(shoot, self.hand_eye.T_tool_cam, drawing_marks, self.limits,
                                        self.hand_eye.poses_used, p["verify_poses"] + 1, p["max_verify_views"], more)
        return self._verify(check)

    def _board_centre_w(self, shot: BoardShot, drawing_marks) -> np.ndarray:
        """World point the views look at, through the hand-eye in use (off by the hand-eye's error: the
        views only need the board in view, and a calibration re-aims them once its shots agree)."""
        T_cam_board = board_pose_from_marks(shot.marks_cam_m, board_points_m(drawing_marks))
        return board_centre_w(camera_in_world(shot.T_world_tool, self.hand_eye.T_tool_cam) @ T_cam_board, drawing_marks)

    def _calibrate(self, shots, refused: int, failed: int, drawing_marks, aimed_from: int = 0) -> int:
        if len(shots) < 3:
            raise Aborted(f"too few poses: {len(shots)} usable shot(s) ({refused} view(s) refused by the driver, "
                          f"{failed} without marks), need at least {self.limits.min_poses}")
        result = calibrate_hand_eye(shots, drawing_marks, self.limits)
        path = write_yaml(Path(self.p["output_dir"]) / "hand_eye.yaml",
                          calibration_record(result, poses_refused=refused, poses_failed=failed, aimed_from=aimed_from,
                                             believed_xyz_m=self.hand_eye.xyz_m,
                                             believed_rpy_deg=self.hand_eye.rpy_deg),
                          "hand-eye calibration (camera_color_optical_frame in weld_tool), written by "
                          "hand_eye_calibrator;\nuse it with: ros2 run stud_planner cell --mode sim|hardware "
                          f"--var hand_eye_file={Path(self.p['output_dir']).resolve() / 'hand_eye.yaml'}")
        log = self.get_logger()
        moved = result.T_tool_cam
        believed = self.hand_eye.T_tool_cam
        log.info("methods: " + ", ".join(f"{n} {mm:.3f} mm / {deg:.4f} deg" for n, (mm, deg) in
                                          result.method_differences.items())
                 + f" from the refined result: {'they agree' if result.methods_agree else 'they DISAGREE'}")
        log.info(f"hand-eye xyz {np.round(result.xyz_m, 5).tolist()} m, rpy {np.round(result.rpy_deg, 3).tolist()} "
                 f"deg; {1e3 * np.linalg.norm(moved[:3, 3] - believed[:3, 3]):.2f} mm / "
                 f"{float(rotation_angle_deg(moved[:3, :3], believed[:3, :3])):.3f} deg from the believed value")
        log.info(f"residuals over {result.n_shots} poses: {result.rms_mm:.3f} mm RMS (max {result.max_mm:.3f}), "
                 f"{result.rms_deg:.4f} deg RMS (max {result.max_deg:.4f}); reprojection RMS "
                 f"{result.reprojection_rms_px:.3f} px; rotations spread "
                 f"{np.round(result.rotation_spread_deg, 1).tolist()} deg")
        for w in result.warnings:
            log.warn(w)
        if not result.accepted:
            log.error(f"hand-eye calibration REFUSED ({path}): " + "; ".join(result.problems))
            self.diag.set(self.diag.ERROR, "refused: " + result.problems[0])
            return 1
        log.info(f"hand-eye calibration ACCEPTED: {path}")
        self.diag.set(self.diag.OK, f"accepted: {path}")
        return 0

    def _verify(self, check) -> int:
        shots = check.shot_residual_mm
        path = write_yaml(Path(self.p["output_dir"]) / "hand_eye_check.yaml", check_record(check, self.hand_eye),
                          "hand-eye check (cell --mode verify), written by hand_eye_calibrator")
        what = (f"{self.hand_eye.path} ({self.hand_eye.date})" if self.hand_eye.source == "file"
                else "the typed hand_eye_xyz_m / hand_eye_rpy_deg")
        lim = self.limits
        line = (f"{check.rms_mm:.3f} mm RMS (max {check.max_mm:.3f}, limit {lim.max_rms_mm:g} / {lim.max_shot_mm:g}), "
                f"{check.rms_deg:.4f} deg RMS (max {check.max_deg:.4f}) over {len(shots)} shots; ")
        spread = check.spread
        line += (f"their own hand-eye is {check.difference_mm:.3f} mm / {check.difference_deg:.4f} deg from it "
                 f"(limits {spread.limit_mm:.3f} mm / {spread.limit_deg:.4f} deg: {lim.check_max_mm:g} mm / "
                 f"{lim.check_max_deg:g} deg less what noise explains; {spread.describe()})" if spread is not None
                 else "their rotations do not determine a hand-eye of their own (about one axis), "
                      "only the residuals were checked")
        if check.passed:
            self.get_logger().info(f"hand-eye check PASS for {what}: {line}; {path}")
            return 0
        self.get_logger().error(f"hand-eye check FAIL for {what}: {line}: " + "; ".join(check.problems)
                                + f"; recalibrate: ros2 run stud_planner cell --mode calibrate; {path}")
        return 1

    def shutdown(self) -> None:
        self._stop.set()


def main(args=None) -> int:
    """`ros2 run stud_cell hand_eye_calibrator`: spin until Ctrl-C or (``exit_when_done``) the verdict: 0 accepted."""
    return ros_io.spin_node(HandEyeCalibrator, args, multithreaded=True,
                            until=lambda node: node.exit_code if node.p["exit_when_done"] else None)


if __name__ == "__main__":
    raise SystemExit(main())
