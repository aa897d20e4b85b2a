"""Cell sequencer: `ros2 run stud_planner cell_sequencer` runs a whole weld job.

The job's steps are stud_cell.job's (registration, stations, welds, post-weld inspection,
leftovers, re-shoots, the reports); this node is its adapter to the cell:

- camera moves: ``/arm/move_to`` (camera frame), then two ``/arm/state`` from after the move;
- registration: ``/registration/trigger``, one shot (``/camera/trigger``), a valid
  ``/registration/result`` newer than the shot (``shot_retries`` tries);
- a view: one shot and the ``/weld_targets`` of that shot;
- welds: the ``/arm/weld_job`` action (``resume=true``: the arm driver's journal is the truth of what
  is welded). Should the driver crash mid-job and come back (``--respawn-driver``), its
  ``/arm/state`` pauses and returns without a job: the job sends the targets again
  (``weld_resends``), and the journal skips what is welded and holds back what the crash left uncertain;
- inspection: a shot of the same pose after the welds (``/camera/trigger_inspection``: published on
  topics of its own, so the matcher never takes it for a view) and ``/inspection/inspect``.
- with a rail (``rail_length_m`` > 0, the arm driver's): the carriage through ``/arm/rail_move`` (the arm
  still; returns on arrival), then two ``/arm/state`` from after it at the new position; the job is
  stud_cell.rail_job's (carriage positions planned, a registration at each).

The reach test is the arm driver's own (``/arm/reach_config``, latched: stud_cell.cell_reach):
stations are planned at poses it accepts, and every target is checked before it is sent.

Progress goes to ``/cell/status`` (CellStatus, with the studs the cell cannot weld and why);
``/cell/start|pause|resume|stop`` (Trigger) drive it (``auto_start`` starts at once). With
``report_file`` a JSON report of every stud (the offline report's fields plus ``welded``) and with
``qa_dir`` the QA record are written at the end, also of a job stopped early; ``exit_when_done`` ends
the process (exit 0 only when every stud was welded).
"""
from __future__ import annotations

import dataclasses
import math
import threading
import time

import numpy as np
import rclpy
from rclpy.action import ActionClient
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo
from std_msgs.msg import String
from std_srvs.srv import Trigger
from stud_welding_msgs.action import WeldJob
from stud_welding_msgs.msg import ArmState, CellStatus, Registration, StudLayout, WeldRecord, WeldTargetArray
from stud_welding_msgs.srv import Inspect, MoveTo, RailMove

from rm65_driver.weld.reach import ReachConfig, ReachConfigError
from stud_cell import job as cell_job
from stud_cell.cell_reach import CellReach
from stud_cell.job import DriverLost, InspectionUnavailable, JobAborted, MoveRefused
from stud_cell.rail_job import RailJob
from stud_cell.sequencer_params import PARAMS
from stud_cell.stations import StationPlanningError, footprint_m
from stud_common import names, ros_io
from stud_common.executor_calls import ExecutorCalls
from stud_common.stacks import dump_stacks_on_signal
from stud_common.vocabulary import CellState
from stud_inspection.qa_params import SAMPLING_PARAMS, overrides
from stud_perception.camera_model import nadir_rotation
from stud_planner.msg_convert import (
    inspection_extras,
    inspection_rows,
    layout_from_msg,
    registration_from_msg,
    weld_target_table,
)

#: /arm/welds: every weld of the session, also for a sequencer started late.
WELDS_QOS = QoSProfile(depth=10000, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


class CellSequencer(Node):
    """The job's cell (cell_job.CellPorts) over ROS: topics, services and the weld action."""

    def __init__(self) -> None:
        super().__init__("cell_sequencer")
        self.p = ros_io.declare_params(self, PARAMS)
        cb = ReentrantCallbackGroup()
        self.layout: StudLayout | None = None
        self.registration: Registration | None = None
        self.targets: list[WeldTargetArray] = []
        self.arm_state: ArmState | None = None
        self.reach_config: str | None = None  # the arm driver's /arm/reach_config (JSON)
        self._arm_state_time: float | None = None  # monotonic arrival of the last /arm/state
        self._state_gap = False  # /arm/state paused during the running weld job
        self._lost_result = None  # the result future of a weld job the driver was believed to have lost
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._paused = threading.Event()
        self._worker: threading.Thread | None = None
        self.job: cell_job.CellJob | None = None
        self.exit_code: int | None = None
        self.cell_status = CellStatus(state=int(CellState.IDLE), state_text=CellState.IDLE.text,
                                      message="waiting for start")
        self.pub_status = self.create_publisher(CellStatus, names.CELL_STATUS, ros_io.LATCHED_QOS)
        self.create_subscription(StudLayout, names.DRAWING_LAYOUT, self._on_layout, ros_io.LATCHED_QOS,
                                 callback_group=cb)
        self.create_subscription(Registration, names.REGISTRATION_RESULT, self._on_registration, ros_io.LATCHED_QOS,
                                 callback_group=cb)
        self.create_subscription(WeldTargetArray, names.WELD_TARGETS, self._on_targets, ros_io.RESULT_QOS,
                                 callback_group=cb)
        self.create_subscription(ArmState, names.ARM_STATE, self._on_arm_state, ros_io.RESULT_QOS, callback_group=cb)
        self.create_subscription(String, names.ARM_REACH_CONFIG, self._on_reach_config, ros_io.LATCHED_QOS,
                                 callback_group=cb)
        # when each stud's weld was confirmed: the weld order of the QA record (the job's result lists
        # the studs in the order they were sent)
        self._weld_confirmed_ns: dict[str, int] = {}
        self.create_subscription(WeldRecord, names.ARM_WELDS, self._on_weld_record, WELDS_QOS, callback_group=cb)
        # The camera's principal point and size: how central each target's match is, the tie-break of the
        # best-view rule (target_table.choose_best). K: the raw images' camera, as the matcher models them.
        self._image: tuple[float, float, int, int] | None = None
        self.create_subscription(CameraInfo, names.CAMERA_INFO, self._on_camera_info, ros_io.SENSOR_QOS,
                                 callback_group=cb)
        self.cli_move = self.create_client(MoveTo, names.ARM_MOVE_TO, callback_group=cb)
        self.cli_rail = self.create_client(RailMove, names.ARM_RAIL_MOVE, callback_group=cb)
        self.cli_shot = self.create_client(Trigger, names.CAMERA_TRIGGER, callback_group=cb)
        self.cli_inspection_shot = self.create_client(Trigger, names.CAMERA_TRIGGER_INSPECTION, callback_group=cb)
        self.cli_register = self.create_client(Trigger, names.REGISTRATION_TRIGGER, callback_group=cb)
        self.cli_inspect = self.create_client(Inspect, names.INSPECTION_INSPECT, callback_group=cb)
        self.cli_arm = {name: self.create_client(Trigger, f"/arm/{name}", callback_group=cb)
                        for name in ("stop", "pause", "resume")}
        # The action client in a group of its own, its requests sent from inside that group (ExecutorCalls):
        # rclpy's action client is not thread-safe against the executor taking the response.
        action_group = MutuallyExclusiveCallbackGroup()
        self.weld_action = ActionClient(self, WeldJob, names.ARM_WELD_JOB, callback_group=action_group)
        self._in_action_group = ExecutorCalls(self, action_group)
        for name, handler in (("start", self._on_start), ("pause", self._on_pause), ("resume", self._on_resume),
                              ("stop", self._on_stop)):
            self.create_service(Trigger, f"/cell/{name}", handler, callback_group=cb)
        self.diag = ros_io.Diagnostics(self)
        self.create_timer(1.0, self._tick, callback_group=cb)
        self.get_logger().info("cell sequencer ready: /cell/start" + (" (auto_start)" if self.p["auto_start"] else ""))

    # -- inputs ---------------------------------------------------------------------------------
    def _on_layout(self, msg: StudLayout) -> None:
        with self._cond:
            self.layout = msg
            self._cond.notify_all()
        if self.p["auto_start"] and self._worker is None:
            self.start()

    def _on_registration(self, msg: Registration) -> None:
        with self._cond:
            self.registration = msg
            self._cond.notify_all()

    def _on_targets(self, msg: WeldTargetArray) -> None:
        with self._cond:
            self.targets.append(msg)
            del self.targets[:-5]
            self._cond.notify_all()

    def _on_weld_record(self, msg: WeldRecord) -> None:
        with self._cond:
            self._weld_confirmed_ns.setdefault(msg.stud_id, ros_io.stamp_to_ns(msg.header.stamp))

    def _on_camera_info(self, msg: CameraInfo) -> None:
        if msg.width > 0 and msg.height > 0:
            self._image = (float(msg.k[2]), float(msg.k[5]), int(msg.width), int(msg.height))

    def _on_arm_state(self, msg: ArmState) -> None:
        with self._cond:
            self.arm_state = msg
            self._arm_state_time = time.monotonic()
            self._cond.notify_all()

    def _on_reach_config(self, msg: String) -> None:
        with self._cond:
            self.reach_config = msg.data
            self._cond.notify_all()

    def cell_reach(self) -> CellReach | None:
        """The arm driver's reach test, from its /arm/reach_config (None, warned: not heard in time)."""
        try:
            text = self._wait_for(lambda: self.reach_config, self.p["reach_config_timeout_s"], names.ARM_REACH_CONFIG)
            return CellReach.from_config(ReachConfig.from_json(text))
        except JobAborted as exc:
            self.get_logger().warn(f"{exc}: planning without the arm's reach test (the driver refuses what it "
                                   "cannot do)")
        except ReachConfigError as exc:
            self.get_logger().error(f"{names.ARM_REACH_CONFIG} unusable ({exc}): planning without the arm's reach test")
        return None

    def _tick(self) -> None:
        self.publish_status()
        self.diag.set(self.diag.ERROR if self.cell_status.state == CellStatus.STATE_FAILED else self.diag.OK,
                      f"{self.cell_status.state_text}: {self.cell_status.message}")
        self.diag.publish()

    # -- services -------------------------------------------------------------------------------
    def start(self) -> tuple[bool, str]:
        if self._worker is not None and self._worker.is_alive():
            return False, "a job is already running"
        self._stop.clear()
        self._paused.clear()
        self._worker = threading.Thread(target=self._run_job, name="cell_job", daemon=True)
        self._worker.start()
        return True, "job started"

    def _on_start(self, _req, resp):
        resp.success, resp.message = self.start()
        return resp

    def _on_pause(self, _req, resp):
        self._paused.set()
        ok, msg = self._call_trigger(self.cli_arm["pause"], 5.0)
        self.status(cell_job.PAUSED, "paused by the operator")
        resp.success, resp.message = True, f"paused (arm: {msg})"
        return resp

    def _on_resume(self, _req, resp):
        ok, msg = self._call_trigger(self.cli_arm["resume"], 5.0)
        self._paused.clear()
        resp.success, resp.message = True, f"resumed (arm: {msg})"
        return resp

    def _on_stop(self, _req, resp):
        self._stop.set()
        self._paused.clear()
        ok, msg = self._call_trigger(self.cli_arm["stop"], 5.0)
        resp.success, resp.message = True, f"job stopping (arm: {msg})"
        return resp

    # -- the job --------------------------------------------------------------------------------
    def _run_job(self) -> None:
        p = self.p
        config = dataclasses.replace(cell_job.JobConfig.from_params(p), job_id=time.strftime("%Y%m%d-%H%M%S"),
                                     part=p["part_name"], qa_overrides=overrides(p, SAMPLING_PARAMS))
        job_class = RailJob if config.rail_length_m > 0 else cell_job.CellJob
        self.job = job_class(self, config, reach=self.cell_reach())
        _state, self.exit_code = self.job.run()

    # -- cell_job.CellPorts ---------------------------------------------------------------------
    def status(self, state: CellState, message: str, **fields) -> None:
        if "unreachable" in fields and "unreachable_reasons" not in fields:
            fields["unreachable_reasons"] = [self._unreachable_reason(sid) for sid in fields["unreachable"]]
        changed = (state, message) != (self.cell_status.state, self.cell_status.message)
        st = self.cell_status
        st.state, st.state_text, st.message = int(state), state.text, message
        for k, v in fields.items():
            setattr(self.cell_status, k, v)
        self.publish_status()
        if changed:
            self.get_logger().info(f"[{state.text}] {message}")

    def _unreachable_reason(self, stud_id: str) -> str:
        """Why the job cannot weld ``stud_id``: its QA row's reason, as the QA record says it."""
        reasons = self.job.qa.get(stud_id, {}).get("reasons") if self.job is not None else None
        return reasons[0] if reasons else "unreachable"

    def checkpoint(self) -> None:
        """Between steps: honour stop and pause."""
        while self._paused.is_set() and not self._stop.is_set():
            time.sleep(0.05)
        if self._stop.is_set():
            raise JobAborted("stopped by the operator")

    def stopped(self) -> bool:
        return self._stop.is_set()

    def info(self, text: str) -> None:
        self.get_logger().info(text)

    def warn(self, text: str) -> None:
        self.get_logger().warn(text)

    def wait_layout(self) -> cell_job.Layout:
        msg = self._wait_for(lambda: self.layout, self.p["step_timeout_s"], names.DRAWING_LAYOUT)
        layout = layout_from_msg(msg)
        return cell_job.Layout(ids=layout.ids, xy_m=layout.xy_m, source_file=layout.source_file, marks_m=layout.marks_m,
                               mark_diameter_m=layout.mark_diameter_m, reference_marks_m=layout.reference_marks_m)

    def move_camera(self, xyz, yaw_rad: float) -> None:
        pose = ros_io.rt_to_pose(nadir_rotation(yaw_rad), np.asarray(xyz, dtype=float))
        reply = self._call(self.cli_move, MoveTo.Request(pose=pose, frame=MoveTo.Request.FRAME_CAMERA),
                           self.p["step_timeout_s"])
        if not reply.success:
            text = f"camera move to {np.round(xyz, 3).tolist()} m refused: {reply.message}"
            if reply.message.startswith(("e-stop", "a weld job is running")):
                raise JobAborted(text)  # the arm refuses every move: not the pose (the job stops, as before)
            raise MoveRefused(text)     # this pose: the job skips what needed it and goes on
        self._camera_status(xyz, yaw_rad)
        # The camera's pose comes from /arm/state: shoot only once a state from after the move
        # is out (two, so the camera node has surely seen one), or the shot uses a stale pose.
        arrived = self.get_clock().now().nanoseconds
        seen: set[int] = set()

        def settled():
            st = self.arm_state
            if st is not None and ros_io.stamp_to_ns(st.header.stamp) > arrived and st.mode != ArmState.MODE_MOVING:
                seen.add(ros_io.stamp_to_ns(st.header.stamp))
            return len(seen) >= 2

        self._wait_for(settled, self.p["step_timeout_s"], "/arm/state after the move")

    def move_rail(self, position_m: float) -> float:
        """The carriage to ``position_m`` along the rail (the arm still); returns where it arrived (m),
        once two /arm/state from after the arrival show it there (the camera is posed from them)."""
        reply = self._call(self.cli_rail, RailMove.Request(position_m=float(position_m), speed_pct=0),
                           self.p["rail_move_timeout_s"])
        if not reply.success:
            text = f"carriage move to {position_m:.4f} m refused: {reply.message}"
            if reply.message.startswith(("e-stop", "a weld job is running")):
                raise JobAborted(text)
            raise MoveRefused(text)
        arrived, reached = self.get_clock().now().nanoseconds, float(reply.position_m)
        seen: set[int] = set()

        def settled():
            st = self.arm_state
            if (st is not None and ros_io.stamp_to_ns(st.header.stamp) > arrived and not st.rail_moving
                    and abs(st.rail_position_m - reached) <= 1e-6):
                seen.add(ros_io.stamp_to_ns(st.header.stamp))
            return len(seen) >= 2

        self._wait_for(settled, self.p["step_timeout_s"], f"/arm/state with the carriage at {reached:.4f} m")
        return reached

    def rail_position_m(self) -> float:
        st = self._wait_for(lambda: self.arm_state, self.p["step_timeout_s"], names.ARM_STATE)
        return float(st.rail_position_m)

    def _camera_status(self, xyz, yaw_rad: float) -> None:
        """Where the camera now looks, for /cell/status (the HMI's plan draws the footprint): the
        footprint on the part's top seen from the camera's height above the registered plane."""
        st, p = self.cell_status, self.p
        reg = self.registration
        plane_z = float(reg.mark_o.z) if reg is not None and reg.valid and math.isfinite(reg.mark_o.z) else 0.0
        try:
            fp = list(footprint_m(p["fov_width_m"], p["fov_distance_m"], p["image_aspect"], float(xyz[2]) - plane_z,
                                  p["part_height_m"]))
        except StationPlanningError:  # the camera not above the part's top: no footprint to draw
            fp = []
        st.camera_xyz_m, st.camera_yaw_rad, st.camera_footprint_m = [float(v) for v in xyz], float(yaw_rad), fp

    def shoot(self, inspection: bool = False) -> int:
        """One triggered shot; returns the ROS time (ns) taken just before it. With ``inspection``, a
        post-weld inspection shot (``/camera/trigger_inspection``); a camera without that service
        takes it on ``/camera/trigger``, and the matcher then matches it as one more view (said once)."""
        client = self.cli_shot
        if inspection:
            if self.cli_inspection_shot.wait_for_service(timeout_sec=2.0):
                client = self.cli_inspection_shot
            else:
                self.get_logger().warn(f"no {names.CAMERA_TRIGGER_INSPECTION}: the inspection shot is taken on "
                                       f"{names.CAMERA_TRIGGER}, and the matcher will match it as a view", once=True)
        deadline = time.monotonic() + self.p["step_timeout_s"]
        while True:  # a camera that has no (fresh) pose yet says so: ask again shortly
            t0 = self.get_clock().now().nanoseconds
            reply = self._call(client, Trigger.Request(), self.p["step_timeout_s"])
            if reply.success:
                return t0
            if time.monotonic() > deadline:
                raise JobAborted(f"camera shot failed: {reply.message}")
            self.get_logger().warn(f"camera refused the shot ({reply.message}); retrying",
                                   throttle_duration_sec=5.0)
            self.checkpoint()
            time.sleep(0.2)

    def register(self, attempts: int = 0) -> cell_job.Registration:
        p = self.p
        registration = None
        for attempt in range(1, (attempts or p["shot_retries"]) + 1):
            self.checkpoint()
            self._call(self.cli_register, Trigger.Request(), p["step_timeout_s"])
            t0 = self.shoot()
            try:
                registration = self._wait_for(
                    lambda: self.registration if (self.registration is not None
                                                  and ros_io.stamp_to_ns(self.registration.header.stamp) >= t0)
                    else None, p["step_timeout_s"], "registration result")
            except JobAborted:
                if self._stop.is_set():
                    raise
                continue
            if registration.valid:
                break
            self.get_logger().warn(f"registration attempt {attempt}: {registration.message}")
        if registration is None:
            return cell_job.Registration(False, f"no registration result for {attempts or p['shot_retries']} shot(s)",
                                         np.eye(3), math.nan)
        return cell_job.Registration(bool(registration.valid), registration.message,
                                     registration_from_msg(registration), float(registration.mark_o.z),
                                     residual_m=float(registration.residual),
                                     residual_max_m=float(registration.residual_max),
                                     labels_used=tuple(registration.labels_used),
                                     extrapolated_m=float(registration.extrapolated_distance))

    def shoot_view(self, what: str, camera_xyz_w, yaw_rad: float) -> cell_job.View | None:
        """Shoot (up to ``shot_retries`` times) and return the targets of the shot (None: none came)."""
        p = self.p
        for _attempt in range(p["shot_retries"]):
            self.checkpoint()
            self.status(cell_job.SHOOTING, f"{what}: shot")
            t0 = self.shoot()
            self.status(cell_job.MATCHING, f"{what}: matching")
            try:
                msg = self._wait_for(lambda: next((a for a in reversed(self.targets)
                                                   if ros_io.stamp_to_ns(a.header.stamp) >= t0), None),
                                     p["step_timeout_s"], "/weld_targets for the shot")
            except JobAborted:
                if self._stop.is_set():
                    raise
                continue
            targets = cell_job.table_targets(weld_target_table(msg, self._image), payloads=msg.targets)
            return cell_job.View(index=int(msg.view_index), stamp_ns=ros_io.stamp_to_ns(msg.header.stamp),
                                 camera_xyz_w=tuple(float(v) for v in camera_xyz_w), yaw_rad=float(yaw_rad),
                                 targets=targets)
        return None

    def weld(self, targets: list[cell_job.Target]) -> cell_job.WeldOutcome:
        """Send ``targets`` as one weld job and wait for its result. After a DriverLost the job sends
        them again: if the driver rejects that because a job is running, it was never lost (its state
        stream only stalled) and is still on the first job, whose result is then waited for; a job
        aborted here while the arm goes on welding would leave the studs it welds unrecorded."""
        p = self.p
        lost, self._lost_result = self._lost_result, None
        if lost is not None and lost.done():  # the "lost" job's result came after all
            return self._outcome(lost.result().result)
        if not self.weld_action.wait_for_server(timeout_sec=min(p["step_timeout_s"], 10.0)):
            raise JobAborted("the arm driver's /arm/weld_job action is not available")
        request = WeldJob.Goal(targets=[t.payload for t in targets], resume=True)
        sent = self._wait_future(self._in_action_group.call(
            lambda: self.weld_action.send_goal_async(request, feedback_callback=self._on_feedback)),
            p["step_timeout_s"], "/arm/weld_job goal sent")
        goal = self._wait_future(sent, p["step_timeout_s"], "/arm/weld_job goal")
        if goal.accepted:
            result = self._wait_future(self._in_action_group.call(goal.get_result_async), p["step_timeout_s"],
                                       "/arm/weld_job result request")
        elif lost is not None and not lost.done():
            self.get_logger().warn("the arm driver rejected the resent job: it is still on the job it was believed "
                                   "to have lost (its /arm/state only paused); waiting for that job's result")
            result = lost
        elif lost is not None:
            return self._outcome(lost.result().result)
        else:
            raise JobAborted("the arm driver rejected the weld job (e-stop or another job running?)")
        self._state_gap = False
        try:
            return self._outcome(self._wait_future(result, p["weld_timeout_s"], "/arm/weld_job result",
                                                   alive=self._driver_still_on_the_job).result)
        except DriverLost:
            self._lost_result = result
            # its /arm/state is back; give discovery a moment to match its action server as well
            # (a killed one can linger in the graph, so wait_for_server proves nothing)
            time.sleep(1.0)
            raise

    def _outcome(self, result: WeldJob.Result) -> cell_job.WeldOutcome:
        """The job's result, its welded studs in the order their welds were confirmed (/arm/welds; one
        not seen there yet keeps its place after them)."""
        with self._cond:
            confirmed = dict(self._weld_confirmed_ns)
        welded = sorted(result.welded, key=lambda sid: confirmed.get(sid, 1 << 62))
        return cell_job.WeldOutcome(welded=tuple(welded), failed=tuple(result.failed), messages=tuple(result.messages))

    def inspect(self, station: int, view: cell_job.View, targets: list[cell_job.Target], welded_ids: list[str],
                after_ns: int) -> cell_job.InspectionOutcome:
        if not self.cli_inspect.wait_for_service(timeout_sec=2.0):
            raise InspectionUnavailable("/inspection/inspect is not available (is the inspector running?)")
        req = Inspect.Request(before_stamp=ros_io.ns_to_stamp(view.stamp_ns),
                              after_not_before=ros_io.ns_to_stamp(after_ns), station=int(station),
                              targets=[t.payload for t in targets], welded_ids=list(welded_ids))
        try:
            reply = self._wait_future(self.cli_inspect.call_async(req), self.p["inspect_timeout_s"],
                                      names.INSPECTION_INSPECT)
        except JobAborted as exc:
            if self._stop.is_set():
                raise
            raise InspectionUnavailable(str(exc)) from None
        if not reply.success:
            raise InspectionUnavailable(reply.message)
        unexpected, limits = inspection_extras(reply.result)
        return cell_job.InspectionOutcome(rows=inspection_rows(reply.result), unexpected=unexpected,
                                          overlay_file=reply.result.overlay_file, limits=limits)

    # -- plumbing -------------------------------------------------------------------------------
    def publish_status(self) -> None:
        self.cell_status.header.stamp = self.get_clock().now().to_msg()
        self.pub_status.publish(self.cell_status)

    def _wait_future(self, future, timeout_s: float, what: str, alive=None):
        """The future's result; JobAborted on stop or time-out, DriverLost when ``alive()`` has been
        false for ``driver_lost_s``."""
        done = threading.Event()
        future.add_done_callback(lambda _f: done.set())
        deadline = time.monotonic() + timeout_s
        gone_since = None
        while not done.wait(0.05):
            if self._stop.is_set():
                raise JobAborted(f"stopped by the operator while waiting for {what}")
            now = time.monotonic()
            if now > deadline:
                raise JobAborted(f"no answer from {what} within {timeout_s:.0f} s")
            if alive is not None:
                gone_since = None if alive() else (gone_since or now)
                if gone_since is not None and now - gone_since >= self.p["driver_lost_s"]:
                    raise DriverLost(f"no {what}: restarted, or silent for {self.p['driver_lost_s']:g} s")
        return future.result()

    def _call(self, client, request, timeout_s: float):
        if not client.wait_for_service(timeout_sec=min(timeout_s, 10.0)):
            raise JobAborted(f"service {client.srv_name} is not available")
        return self._wait_future(client.call_async(request), timeout_s, client.srv_name)

    def _call_trigger(self, client, timeout_s: float) -> tuple[bool, str]:
        if not client.wait_for_service(timeout_sec=1.0):
            return False, f"{client.srv_name} not available"
        done = threading.Event()
        future = client.call_async(Trigger.Request())
        future.add_done_callback(lambda _f: done.set())
        if not done.wait(timeout_s):
            return False, f"{client.srv_name}: no reply"
        return future.result().success, future.result().message

    def _wait_for(self, predicate, timeout_s: float, what: str):
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while True:
                value = predicate()
                if value:
                    return value
                if self._stop.is_set():
                    raise JobAborted(f"stopped by the operator while waiting for {what}")
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise JobAborted(f"no {what} within {timeout_s:.0f} s")
                self._cond.wait(min(remaining, 0.1))

    def _driver_still_on_the_job(self) -> bool:
        """False once the driver looks restarted: its /arm/state stream paused for ``driver_lost_s``
        (a crash; the graph may show a killed server for many seconds more, so its presence there
        proves nothing) and came back with no job running, or has not come back within
        ``step_timeout_s``. A driver that only stalled comes back still on the job: keep waiting."""
        if self._arm_state_time is None:
            return True
        silent_s = time.monotonic() - self._arm_state_time
        if silent_s >= self.p["driver_lost_s"]:
            self._state_gap = True
            return silent_s < self.p["step_timeout_s"]
        if self._state_gap and self.arm_state is not None and self.arm_state.total > 0:
            self._state_gap = False  # the same driver, still welding this job
        return not self._state_gap

    def _on_feedback(self, fb) -> None:
        f = fb.feedback
        st = self.cell_status
        st.message = f"station {st.station}/{st.stations_total}: {f.stud_id} {f.phase} ({f.done}/{f.total})"


def main(args=None) -> int:
    """`ros2 run stud_cell cell_sequencer`: spin until Ctrl-C or (``exit_when_done``) the job's end: 0 if all welded."""
    dump_stacks_on_signal()
    ros_io.init_node_process(args)
    node = CellSequencer()
    executor = MultiThreadedExecutor(num_threads=4)
    executor.add_node(node)
    try:
        done = ros_io.spin_until_shutdown(executor, lambda: node.exit_code if node.p["exit_when_done"] else None)
        if done is not None:
            node.publish_status()
            time.sleep(0.3)  # let the last status go out
            return done
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node._stop.set()
        ros_io.drain_executor(executor)
        node.destroy_node()
        rclpy.try_shutdown()
    return 0 if node.exit_code in (None, 0) else node.exit_code


if __name__ == "__main__":
    raise SystemExit(main())
