"""Cell sequencer: `ros2 run stud_planner cell_sequencer` runs a whole weld job.

1. registration station: the camera over the marking board (``/arm/move_to``, camera frame),
   ``/registration/trigger`` then one shot (``/camera/trigger``), wait for a valid
   ``/registration/result`` newer than the shot;
2. stations planned to cover every stud of ``/drawing/layout`` (station_planning.py); studs
   no reachable station covers are reported as unreachable;
3. per station: move, one shot, wait for the ``/weld_targets`` of that shot, weld its
   assigned usable targets through the ``/arm/weld_job`` action (``resume=true``: the arm
   driver's journal is the truth of what is welded, so a restarted job never welds twice).
   Should the driver crash mid-job and come back (``--respawn-driver``), its ``/arm/state``
   pauses and returns without a job: the station's targets are sent again (``weld_resends``),
   and the journal skips what is welded and holds back what the crash left uncertain.

Progress goes to ``/cell/status`` (CellStatus); ``/cell/start|pause|resume|stop`` (Trigger)
drive it (``auto_start`` starts at once). With ``report_file`` a JSON report of every stud
(the offline report's fields plus ``welded``) is written at the end; ``exit_when_done``
ends the process (exit 0 only when every stud was welded).
"""
from __future__ import annotations

import math
import threading
import time

import numpy as np
import rclpy
from rclpy.action import ActionClient
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node
from std_srvs.srv import Trigger
from stud_welding_msgs.action import WeldJob
from stud_welding_msgs.msg import ArmState, CellStatus, Registration, StudLayout, WeldTargetArray
from stud_welding_msgs.srv import MoveTo

from stud_perception import ros_io
from stud_perception.camera_model import nadir_rotation
from stud_perception.ros_io import Param
from stud_perception.strict_json import write_json
from stud_planner.msg_convert import layout_from_msg, registration_from_msg, target_report_entry
from stud_planner.station_planning import footprint_m, plan_stations, reshoot_station
from stud_planner.view_planning import STATUS_TEXT, VIEW_DEPENDENT_STATUSES

#: Status texts another view may cure: such studs are shot again before the cell gives up on them.
RESHOOT_STATUS_TEXTS = frozenset(STATUS_TEXT[s] for s in VIEW_DEPENDENT_STATUSES)


def _three(name):
    return lambda v: None if len(v) == 3 else f"{name} needs 3 numbers, got {list(v)}"


PARAMS = [
    Param("auto_start", False, "start the job as soon as the layout is there"),
    Param("exit_when_done", False, "end the process when the job ends (exit 0 only if every stud was welded)"),
    Param("report_file", "", "write a JSON report of every stud here at the end (empty: none)"),
    Param("registration_station_xyz_m", [0.225, -0.29, 0.285], "camera position over the marking board [m]",
          validate=_three("registration_station_xyz_m")),
    Param("camera_height_m", 0.40, "camera height of the stations above the working plane [m]", min=0.05, max=2.0),
    Param("camera_yaw_deg", 0.0, "image yaw of the stations [deg]", min=-360.0, max=360.0),
    Param("part_height_m", 0.15, "top of the part above the plane, for the footprint [m]", min=0.0, max=1.0),
    Param("fov_width_m", 0.46, "camera field-of-view width at fov_distance_m [m]", min=0.01, max=10.0),
    Param("fov_distance_m", 0.5, "distance of fov_width_m [m]", min=0.05, max=10.0),
    Param("image_aspect", 0.75, "image height / width", min=0.1, max=10.0),
    Param("overlap", 0.15, "footprint fraction kept free at the image border", min=0.0, max=0.85),
    Param("step_timeout_s", 60.0, "longest wait for a move, a shot, a registration or the targets [s]",
          min=1.0, max=3600.0),
    Param("weld_timeout_s", 1800.0, "longest wait for one station's weld job [s]", min=1.0, max=86400.0),
    Param("shot_retries", 3, "shots tried per station before giving up", min=1, max=20),
    Param("driver_lost_s", 1.5, "a gap this long in /arm/state during a weld job, after which the driver "
          "reports no job, means it was restarted and lost the job [s]", min=0.3, max=600.0),
    Param("weld_resends", 3, "times a station's weld job is sent again to a restarted driver (resume: its "
          "journal skips what is welded)", min=0, max=20),
    Param("reshoot_attempts", 2, "views taken again, from other directions, of a stud no view gave a usable "
          "target for (normal uncertain, no depth, ...) before giving up on it; it is never welded blind",
          min=0, max=8),
    Param("reshoot_offset_m", 0.08, "the re-shoot camera stands this far beside the stud [m]", min=0.0, max=0.5),
]

STATE_TEXT = {CellStatus.STATE_IDLE: "idle", CellStatus.STATE_REGISTERING: "registering",
              CellStatus.STATE_MOVING: "moving", CellStatus.STATE_SHOOTING: "shooting",
              CellStatus.STATE_MATCHING: "matching", CellStatus.STATE_WELDING: "welding",
              CellStatus.STATE_PAUSED: "paused", CellStatus.STATE_DONE: "done", CellStatus.STATE_FAILED: "failed"}


class JobAborted(Exception):
    """The job cannot go on (stop requested, a step failed): the message says why."""


class MoveRefused(JobAborted):
    """The arm driver refused a camera move (unreachable, e-stop): the message says why."""


class DriverLost(JobAborted):
    """The arm driver's action server vanished while a weld job ran (crash, restart)."""


class CellSequencer(Node):
    def __init__(self) -> None:
        super().__init__("cell_sequencer")
        self.p = ros_io.declare_params(self, PARAMS)
        cb = ReentrantCallbackGroup()
        self.layout: StudLayout | None = None
        self.registration: Registration | None = None
        self.targets: list[WeldTargetArray] = []
        self.arm_state: ArmState | None = None
        self._arm_state_time: float | None = None  # monotonic arrival of the last /arm/state
        self._state_gap = False  # /arm/state paused during the running weld job
        self.best: dict[str, tuple[float, object]] = {}  # stud id -> (distance from image centre, ok target)
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._paused = threading.Event()
        self._worker: threading.Thread | None = None
        self.exit_code: int | None = None
        self.status = CellStatus(state=CellStatus.STATE_IDLE, state_text="idle", message="waiting for start")
        self.stud_report: dict[str, dict] = {}
        self.pub_status = self.create_publisher(CellStatus, "/cell/status", ros_io.LATCHED_QOS)
        self.create_subscription(StudLayout, "/drawing/layout", self._on_layout, ros_io.LATCHED_QOS, callback_group=cb)
        self.create_subscription(Registration, "/registration/result", self._on_registration, ros_io.LATCHED_QOS,
                                 callback_group=cb)
        self.create_subscription(WeldTargetArray, "/weld_targets", self._on_targets, ros_io.RESULT_QOS,
                                 callback_group=cb)
        self.create_subscription(ArmState, "/arm/state", self._on_arm_state, ros_io.RESULT_QOS, callback_group=cb)
        self.cli_move = self.create_client(MoveTo, "/arm/move_to", callback_group=cb)
        self.cli_shot = self.create_client(Trigger, "/camera/trigger", callback_group=cb)
        self.cli_register = self.create_client(Trigger, "/registration/trigger", callback_group=cb)
        self.cli_arm = {name: self.create_client(Trigger, f"/arm/{name}", callback_group=cb)
                        for name in ("stop", "pause", "resume")}
        self.weld = ActionClient(self, WeldJob, "/arm/weld_job", callback_group=cb)
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

    def _on_arm_state(self, msg: ArmState) -> None:
        with self._cond:
            self.arm_state = msg
            self._arm_state_time = time.monotonic()
            self._cond.notify_all()

    def _tick(self) -> None:
        self.publish_status()
        self.diag.set(self.diag.ERROR if self.status.state == CellStatus.STATE_FAILED else self.diag.OK,
                      f"{self.status.state_text}: {self.status.message}")
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
        self._set(CellStatus.STATE_PAUSED, "paused by the operator")
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

    # -- plumbing -------------------------------------------------------------------------------
    def _set(self, state: int, message: str, **fields) -> None:
        self.status.state, self.status.state_text, self.status.message = state, STATE_TEXT[state], message
        for k, v in fields.items():
            setattr(self.status, k, v)
        self.publish_status()
        self.get_logger().info(f"[{STATE_TEXT[state]}] {message}")

    def publish_status(self) -> None:
        self.status.header.stamp = self.get_clock().now().to_msg()
        self.pub_status.publish(self.status)

    def _checkpoint(self) -> None:
        """Between steps: honour stop and pause."""
        while self._paused.is_set() and not self._stop.is_set():
            time.sleep(0.05)
        if self._stop.is_set():
            raise JobAborted("stopped by the operator")

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
                    raise DriverLost(f"no {what}")
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

    def _move_camera(self, xyz, yaw_rad: float) -> None:
        pose = ros_io.rt_to_pose(nadir_rotation(yaw_rad), np.asarray(xyz, dtype=float))
        reply = self._call(self.cli_move, MoveTo.Request(pose=pose, frame=MoveTo.Request.FRAME_CAMERA),
                           self.p["step_timeout_s"])
        if not reply.success:
            raise MoveRefused(f"camera move to {np.round(xyz, 3).tolist()} m refused: {reply.message}")
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

    def _shoot(self) -> int:
        """One triggered shot; returns the ROS time (ns) taken just before it."""
        deadline = time.monotonic() + self.p["step_timeout_s"]
        while True:  # a camera that has no (fresh) pose yet says so: ask again shortly
            t0 = self.get_clock().now().nanoseconds
            reply = self._call(self.cli_shot, Trigger.Request(), self.p["step_timeout_s"])
            if reply.success:
                return t0
            if time.monotonic() > deadline:
                raise JobAborted(f"camera shot failed: {reply.message}")
            self.get_logger().warn(f"camera refused the shot ({reply.message}); retrying",
                                   throttle_duration_sec=5.0)
            self._checkpoint()
            time.sleep(0.2)

    # -- the job --------------------------------------------------------------------------------
    def _run_job(self) -> None:
        try:
            self._job()
        except JobAborted as exc:
            self._finish(CellStatus.STATE_FAILED, str(exc))
        except Exception as exc:  # the job thread must always end with a state, never vanish
            self.get_logger().error(f"cell job crashed: {exc!r}")
            self._finish(CellStatus.STATE_FAILED, f"internal error: {exc!r}")

    def _job(self) -> None:
        p = self.p
        layout_msg = self._wait_for(lambda: self.layout, p["step_timeout_s"], "/drawing/layout")
        layout = layout_from_msg(layout_msg)
        self.stud_report = {sid: {"stud_id": sid, "drawing_xy_mm": [float(x * 1e3), float(y * 1e3)],
                                  "status": "not_planned", "welded": False}
                            for sid, (x, y) in zip(layout.ids, layout.xy_m)}
        self.status.studs_total = len(layout.ids)

        # 1. registration station
        self._set(CellStatus.STATE_REGISTERING, "camera to the registration station")
        self._checkpoint()
        self._move_camera(p["registration_station_xyz_m"], 0.0)
        registration = None
        for attempt in range(1, p["shot_retries"] + 1):
            self._checkpoint()
            self._call(self.cli_register, Trigger.Request(), p["step_timeout_s"])
            t0 = self._shoot()
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
        if registration is None or not registration.valid:
            raise JobAborted("no valid registration at the registration station"
                             + (f": {registration.message}" if registration is not None else ""))
        M = registration_from_msg(registration)
        studs_w = layout.xy_m @ M[:2, :2].T + M[:2, 2]

        # 2. stations
        fov = footprint_m(p["fov_width_m"], p["fov_distance_m"], p["image_aspect"], p["camera_height_m"],
                          p["part_height_m"])
        # the stations stand camera_height_m above the plane where the marks were measured
        plane_z = registration.mark_o.z if math.isfinite(registration.mark_o.z) else 0.0
        plan = plan_stations(studs_w, fov, p["camera_height_m"], overlap=p["overlap"],
                             yaw_rad=math.radians(p["camera_yaw_deg"]), plane_z_m=plane_z)
        for i in plan.unreachable:
            self.stud_report[layout.ids[i]]["status"] = "unreachable"
        self.status.unreachable = [layout.ids[i] for i in plan.unreachable]
        self.status.stations_total = len(plan.stations)
        self.get_logger().info(f"registered ({registration.message}); {len(plan.stations)} station(s) cover "
                               f"{plan.covered} of {len(layout.ids)} studs, {len(plan.unreachable)} unreachable")

        # 3. stations: move, shoot, match, weld
        for station in plan.stations:
            self.status.station = station.index
            self._run_station(station, layout.ids)
        self._weld_leftovers()
        self._reshoot(studs_w, layout.ids, plane_z)
        welded = sum(r["welded"] for r in self.stud_report.values())
        failed = len(layout.ids) - welded
        state = CellStatus.STATE_DONE
        self._finish(state, f"job done: {welded}/{len(layout.ids)} studs welded"
                     + (f", {failed} not welded (see report)" if failed else ""))

    def _run_station(self, station, ids: list[str]) -> None:
        p = self.p
        n = self.status.stations_total
        self._set(CellStatus.STATE_MOVING, f"station {station.index}/{n}: camera to "
                  f"{np.round(station.camera_xyz_w, 3).tolist()} m")
        self._checkpoint()
        self._move_camera(station.camera_xyz_w, station.yaw_rad)
        wanted = {ids[i] for i in station.stud_indices}
        view = self._shoot_view(f"station {station.index}/{n}")
        if view is None:
            raise JobAborted(f"station {station.index}: no weld targets for any of {p['shot_retries']} shots")
        self._remember_best(view)
        usable = []
        for t in view.targets:
            if t.stud_id not in wanted:
                continue
            report = self.stud_report[t.stud_id]
            report.pop("reason", None)
            report.update(target_report_entry(t, view.view_index))
            if t.status == t.STATUS_OK:
                usable.append(t)
        if not usable:
            self.get_logger().warn(f"station {station.index}: no usable target among {len(wanted)} assigned studs")
            return
        self._set(CellStatus.STATE_WELDING, f"station {station.index}/{n}: welding {len(usable)} stud(s)")
        self._weld(usable)

    def _shoot_view(self, what: str) -> WeldTargetArray | None:
        """Shoot (up to ``shot_retries`` times) and return the /weld_targets of the shot (None: none came)."""
        p = self.p
        for _attempt in range(p["shot_retries"]):
            self._checkpoint()
            self._set(CellStatus.STATE_SHOOTING, f"{what}: shot")
            t0 = self._shoot()
            self._set(CellStatus.STATE_MATCHING, f"{what}: matching")
            try:
                return self._wait_for(lambda: next((a for a in reversed(self.targets)
                                                    if ros_io.stamp_to_ns(a.header.stamp) >= t0), None),
                                      p["step_timeout_s"], "/weld_targets for the shot")
            except JobAborted:
                if self._stop.is_set():
                    raise
        return None

    def _remember_best(self, view: WeldTargetArray) -> None:
        """Keep, per stud, the usable target with the surest normal (smallest lean bound) over all
        views (targets are in `world`, so one matched from any station can be welded from anywhere)."""
        for t in view.targets:
            if t.status != t.STATUS_OK:
                continue
            score = float(t.lean_bound) if math.isfinite(t.lean_bound) else math.inf
            if t.stud_id not in self.best or score < self.best[t.stud_id][0]:
                self.best[t.stud_id] = (score, t, int(view.view_index))

    def _weld_leftovers(self) -> None:
        """Studs their own station did not give a usable target for, but another view did."""
        left = [sid for sid, r in self.stud_report.items() if not r["welded"] and sid in self.best]
        if not left:
            return
        self.get_logger().info(f"welding {len(left)} stud(s) matched on another station's view: {', '.join(left)}")
        targets = []
        for sid in left:
            _score, t, view = self.best[sid]
            self.stud_report[sid].update(target_report_entry(t, view))
            self.stud_report[sid].pop("reason", None)
            targets.append(t)
        self._set(CellStatus.STATE_WELDING, f"welding {len(left)} stud(s) from other views")
        self._weld(targets)

    def _reshoot(self, studs_w: np.ndarray, ids: list[str], plane_z: float) -> None:
        """Studs no view gave a usable target for, for a reason another view may cure (a normal too
        uncertain for the lean budget, a hole, a depth edge): shot again from other directions,
        ``reshoot_attempts`` times, and welded once a view makes them usable. Never welded blind."""
        p = self.p
        index = {sid: i for i, sid in enumerate(ids)}
        for attempt in range(p["reshoot_attempts"]):
            pending = [sid for sid, r in self.stud_report.items()
                       if not r["welded"] and r["status"] in RESHOOT_STATUS_TEXTS and sid not in self.best]
            if not pending:
                return
            for n, sid in enumerate(pending, 1):
                if self.stud_report[sid]["welded"] or sid in self.best:
                    continue  # a re-shoot of a neighbour made it usable
                station = reshoot_station(studs_w[index[sid]], attempt, p["reshoot_offset_m"], p["camera_height_m"],
                                          plane_z, math.radians(p["camera_yaw_deg"]), stud_index=index[sid])
                self._set(CellStatus.STATE_MOVING, f"re-shoot {attempt + 1}/{p['reshoot_attempts']} of {sid} "
                          f"({self.stud_report[sid]['status']}): camera to {np.round(station.camera_xyz_w, 3).tolist()} m")
                self._checkpoint()
                try:
                    self._move_camera(station.camera_xyz_w, station.yaw_rad)
                except MoveRefused as exc:
                    self.get_logger().warn(f"re-shoot of {sid} skipped: {exc}")
                    continue
                view = self._shoot_view(f"re-shoot of {sid}")
                if view is None:
                    continue
                self._remember_best(view)
                for t in view.targets:
                    r = self.stud_report.get(t.stud_id)
                    if r is not None and not r["welded"] and t.stud_id not in self.best and t.stud_id in pending:
                        r.pop("reason", None)
                        r.update(target_report_entry(t, view.view_index))
                usable = [self.best[s][1] for s in pending if s in self.best and not self.stud_report[s]["welded"]]
                if usable:
                    for t in usable:
                        self.stud_report[t.stud_id].update(target_report_entry(t, self.best[t.stud_id][2]))
                        self.stud_report[t.stud_id].pop("reason", None)
                    self._set(CellStatus.STATE_WELDING, f"welding {len(usable)} stud(s) usable after a re-shoot")
                    self._weld(usable)
        for sid, r in self.stud_report.items():
            if not r["welded"] and r["status"] in RESHOOT_STATUS_TEXTS and sid not in self.best and p["reshoot_attempts"]:
                r["reason"] = f"{r['status']} on every view, {p['reshoot_attempts']} re-shoot(s) included: not welded blind"

    def _weld(self, usable: list) -> None:
        """One station's weld job. Should the driver die mid-job, the same targets go again (resume)
        to its restarted self, whose journal skips what is welded and refuses what is uncertain."""
        p = self.p
        for attempt in range(p["weld_resends"] + 1):
            self._checkpoint()
            if not self.weld.wait_for_server(timeout_sec=min(p["step_timeout_s"], 10.0)):
                raise JobAborted("the arm driver's /arm/weld_job action is not available")
            try:
                result = self._weld_once(usable)
                break
            except DriverLost as exc:
                why = f"the arm driver lost the weld job ({exc}: restarted, or silent for {p['step_timeout_s']:g} s)"
                if attempt == p["weld_resends"]:
                    raise JobAborted(f"{why}; gave up after {attempt} resend(s) -- the driver's journal keeps what "
                                     "was welded: restart it and start the job again") from None
                self.get_logger().warn(f"{why}: sending the station's {len(usable)} target(s) again (resume: its "
                                       f"journal skips what is welded; resend {attempt + 1}/{p['weld_resends']})")
                # its /arm/state is back; give discovery a moment to match its action server as well
                # (a killed one can linger in the graph, so wait_for_server proves nothing)
                time.sleep(1.0)
        self._record_weld_result(result)

    def _weld_once(self, usable: list):
        p = self.p
        goal = self._wait_future(self.weld.send_goal_async(WeldJob.Goal(targets=usable, resume=True),
                                                           feedback_callback=self._on_feedback),
                                 p["step_timeout_s"], "/arm/weld_job goal")
        if not goal.accepted:
            raise JobAborted("the arm driver rejected the weld job (e-stop or another job running?)")
        self._state_gap = False
        return self._wait_future(goal.get_result_async(), p["weld_timeout_s"], "/arm/weld_job result",
                                 alive=self._driver_still_on_the_job).result

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

    def _record_weld_result(self, result) -> None:
        for sid in result.welded:
            if sid in self.stud_report:
                self.stud_report[sid]["welded"] = True
        for line in result.messages:
            sid, _, why = line.partition(": ")
            if sid in self.stud_report and not self.stud_report[sid]["welded"]:
                self.stud_report[sid]["weld_message"] = why
        self.status.studs_welded = sum(r["welded"] for r in self.stud_report.values())
        self.status.studs_failed = len(result.failed)
        if self._stop.is_set():
            raise JobAborted("stopped by the operator")

    def _on_feedback(self, fb) -> None:
        f = fb.feedback
        self.status.message = f"station {self.status.station}/{self.status.stations_total}: {f.stud_id} {f.phase} " \
                              f"({f.done}/{f.total})"

    def _finish(self, state: int, message: str) -> None:
        welded = sum(r["welded"] for r in self.stud_report.values())
        self._set(state, message, studs_welded=welded,
                  studs_failed=max(0, len(self.stud_report) - welded) if self.stud_report else 0)
        if self.p["report_file"]:
            # strict JSON: an unmatched stud's NaN position is null (RFC 8259 has no NaN)
            write_json(self.p["report_file"], {"state": STATE_TEXT[state], "message": message,
                                               "stations": int(self.status.stations_total),
                                               "unreachable": list(self.status.unreachable),
                                               "targets": list(self.stud_report.values())})
        all_welded = bool(self.stud_report) and welded == len(self.stud_report)
        self.exit_code = 0 if state == CellStatus.STATE_DONE and all_welded else 1


def main(args=None) -> int:
    rclpy.init(args=args)
    node = CellSequencer()
    executor = MultiThreadedExecutor(num_threads=4)
    executor.add_node(node)
    try:
        while rclpy.ok():
            executor.spin_once(timeout_sec=0.1)
            if node.p["exit_when_done"] and node.exit_code is not None:
                node.publish_status()
                time.sleep(0.3)  # let the last status go out
                return node.exit_code
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node._stop.set()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0 if node.exit_code in (None, 0) else node.exit_code


if __name__ == "__main__":
    raise SystemExit(main())
