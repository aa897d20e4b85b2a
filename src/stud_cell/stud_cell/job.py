"""The weld job of the cell, step by step, with no ROS in it (the sequencer node is its adapter).

1. registration: the camera over the marking board, a valid registration of a shot taken there; the
   registration station is where it looks first, and without one (``registration_station_xyz_m``
   empty) or when the marks are not seen there, the board is searched for (board_search.py);
2. stations planned to cover every stud (stations.py), each at a camera pose the driver's reach test
   accepts (station_reach.py); studs the drawing's place already rules out, and studs no reachable
   station sees, are named unreachable with the reason (cell_reach.py, unreachable.py);
3. per station: move, one shot, its targets; every target is checked with the driver's reach test
   before it is sent (a stud the arm cannot weld is named, never sent); weld the station's usable
   targets (``resume``: the arm driver's journal is the truth of what is welded, so a resent or
   restarted job never welds twice); then, with ``inspect``, shoot the same pose again and have every
   stud welded there measured and judged (post-weld inspection). A station the arm refuses anyway
   costs that station (its studs are reported), never the job;
4. studs their own station gave no usable target for, but another view did, are welded from that
   view's target (and inspected from that view's pose);
5. studs no view could use for a reason another view may cure (normal too uncertain, a hole) are
   shot again from other directions, ``reshoot_attempts`` times; never welded blind.

At the end -- also when the job stops early -- the job writes the weld report (``report_file``) and
the QA record (``qa_dir``: qa_report.json/.csv/.html, stud_inspection.qa_report): every drawing stud with
its verdict and place in the weld order, the code profile (``qa_code``, stud_inspection.qa_codes) and
the bend tests it asks for, drawn with the job's ``sample_seed`` (stud_inspection.sampling). A stud
that fails inspection is listed for the operator and never welded again: rework is a person's decision.

Everything the job needs of the cell comes through a :class:`CellPorts` object: the sequencer node
implements it over topics, services and the weld action; tests implement it in plain Python.
"""
from __future__ import annotations

import dataclasses
import math
import secrets
import time
from pathlib import Path

import numpy as np

from stud_cell.board_search import BoardSearchError, board_radius_m, search_area, search_plan
from stud_cell.cell_reach import CellReach
from stud_cell.station_reach import StationGeometry, reachable_stations
from stud_cell.stations import Station, StationPlan, footprint_m, plan_stations, reshoot_station
from stud_cell.unreachable import UnreachableStuds
from stud_common.strict_json import write_json
from stud_common.vocabulary import CellState, TargetStatus
from stud_inspection import bend, qa_codes, qa_report, rework
from stud_perception.registration import local_to_world
from stud_planner.matching.target_table import BestViewKey, choose_best

# The ports' names, re-exported: callers import the job's vocabulary from here. One statement kept
# in its compact wrapping (isort would spread its 24 names one per line).
from stud_cell.job_ports import (DONE, FAILED, IDLE, INSPECTING, MATCHING, MOVING, PAUSED,  # noqa: F401  # isort: skip
                                  REGISTERING, RESHOOT_STATUS_TEXTS, SHOOTING, WELDING, CellPorts, DriverLost,
                                  InspectionOutcome, InspectionUnavailable, JobAborted, JobConfig, Layout, MoveRefused,
                                  Registration, Target, View, WeldOutcome, table_targets)


class CellJob:
    """One weld job over ``ports``; :meth:`run` returns the end state and the exit code."""

    def __init__(self, ports: CellPorts, config: JobConfig, reach: CellReach | None = None) -> None:
        self.ports, self.c = ports, config
        self.reach = reach                         # the arm driver's reach test (None: not known)
        self.named = UnreachableStuds(reach, self._publish_unreachable, ports.warn)
        self.stud_report: dict[str, dict] = {}     # stud id -> weld-report entry
        self.qa: dict[str, dict] = {}              # stud id -> QA row (qa_report)
        self.best: dict[str, tuple[BestViewKey, Target, View]] = {}  # best usable target per stud, over all views
        self.views: dict[int, View] = {}
        self.stations_total = 0
        self.overlays: list[str] = []
        self.unexpected: list[dict] = []
        self.layout: Layout | None = None
        self.inspection_s: list[float] = []        # time per station's inspection (shot + measurement)
        self.state, self.message = IDLE, ""
        self._camera_at: tuple | None = None       # (xyz, yaw) the camera was last moved to
        self._station = 0                          # the station being worked (re-shoots count on after the plan)
        self._view_station: dict[int, int] = {}
        self._seen: set[str] = set()               # studs checked for reach on a view before their station
        self.weld_seq: dict[str, int] = {}         # stud id -> 1, 2, ... in the order the arm welded them
        self.sample_seed = int(config.sample_seed) or secrets.randbits(31)
        self._judged = False                       # an inspection reported the limits it judged with

    # -- the job ----------------------------------------------------------------------------------
    def run(self) -> tuple[CellState, int]:
        try:
            state, message = self._job()
        except JobAborted as exc:
            state, message = FAILED, str(exc)
        except Exception as exc:  # the job must always end with a state and its records, never vanish
            state, message = FAILED, f"internal error: {exc!r}"
        return state, self.finish(state, message)

    def _job(self) -> tuple[CellState, str]:
        ports = self.ports
        self.layout = layout = ports.wait_layout()
        for sid, (x, y) in zip(layout.ids, layout.xy_m):
            self.stud_report[sid] = {"stud_id": sid, "drawing_xy_mm": [float(x * 1e3), float(y * 1e3)],
                                     "status": "not_planned", "welded": False}
            self.qa[sid] = qa_report.empty_row(sid, (x * 1e3, y * 1e3))
        self._status(REGISTERING, "camera to the registration station", studs_total=len(layout.ids))
        registration = self._register(layout)
        studs_w = local_to_world(registration.m_local2world, layout.xy_m).reshape(-1, 2)
        plane_z = registration.plane_z_m if math.isfinite(registration.plane_z_m) else 0.0

        plan = self._plan(studs_w, plane_z, layout.ids)
        self.stations_total = len(plan.stations)
        ports.status(REGISTERING, f"registered ({registration.message})", unreachable=self.unreachable,
                     unreachable_reasons=[self.named.reasons[s] for s in self.unreachable],
                     stations_total=self.stations_total)
        ports.info(f"registered ({registration.message}); {len(plan.stations)} station(s) cover {plan.covered} of "
                   f"{len(layout.ids)} studs, {len(self.unreachable)} unreachable"
                   + "".join(f"\n  {sid}: {why}" for sid, why in self.named.reasons.items()))

        self._work(plan, studs_w, layout.ids, plane_z)
        welded = self.welded_count()
        failed = len(layout.ids) - welded
        return DONE, (f"job done: {welded}/{len(layout.ids)} studs welded"
                      + (f", {failed} not welded (see report)" if failed else "") + self._done_note())

    def _work(self, plan: StationPlan, studs_w: np.ndarray, ids: list[str], plane_z: float) -> None:
        """The stations in order, then the leftovers and the re-shoots (a rail's job: per carriage position)."""
        for station in plan.stations:
            self._run_station_or_skip(station, ids)
        self._weld_leftovers()
        self._reshoot(studs_w, ids, plane_z)
        self._reshoot_reasons()

    def _run_station_or_skip(self, station: Station, ids: list[str]) -> None:
        self._station = station.index
        try:
            self._run_station(station, ids)
        except MoveRefused as exc:  # a controller that disagrees: the station is lost, not the job
            self.ports.warn(f"station {station.index}: skipped, {exc}")
            for i in station.stud_indices:
                if not self.stud_report[ids[i]]["welded"] and ids[i] not in self.named.reasons:
                    self.named.name(ids[i], f"camera station {station.index} refused by the arm: {exc}")

    def _done_note(self) -> str:
        return ""

    # -- registration and the plan -----------------------------------------------------------------
    def _register(self, layout: Layout) -> Registration:
        """A valid registration: from the registration station when one is given, else (or when the
        marks are not seen there) from the board search's poses, one shot each (board_search.py)."""
        c, ports = self.c, self.ports
        looked: list[str] = []
        station = tuple(c.registration_station_xyz_m or ())  # a ROS parameter set to [] reads as None
        if station:
            ports.checkpoint()
            try:
                self._reach_pose(station, 0.0)
                self._move(station, 0.0)
                registration = ports.register()
                if registration.valid:
                    self._registered_at(station, 0.0, registration)
                    return registration
                looked.append(f"the registration station {np.round(station, 3).tolist()} m: {registration.message}")
            except MoveRefused as exc:
                looked.append(f"the registration station: {exc}")
            ports.warn(f"no valid registration at {looked[-1]}; searching for the marking board")
        try:
            area, max_shots = search_area(c.board_search_area_xy_m or (), c.board_search_max_shots, c.rail_length_m)
            search = search_plan(area, c.board_search_plane_z_m, c.board_search_heights_m,
                                 c.fov_width_m, c.fov_distance_m, c.image_aspect,
                                 board_radius_m(layout.marks_m, layout.mark_diameter_m or 0.02),
                                 None if self.reach is None else self._cameras_ok, max_shots)
        except BoardSearchError as exc:
            raise JobAborted(f"no valid registration ({'; '.join(looked) or 'no registration station'}): "
                             f"{exc}") from None
        last = ""
        for k, (xyz, yaw) in enumerate(self._search_order(search.poses), 1):
            self._status(REGISTERING, f"searching for the marking board: view {k}/{len(search.poses)} from "
                                      f"{np.round(xyz, 3).tolist()} m")
            ports.checkpoint()
            try:
                self._reach_pose(xyz, yaw)
                self._move(xyz, yaw)
            except MoveRefused as exc:
                last = str(exc)
                continue
            registration = ports.register(attempts=1)
            if registration.valid:
                self._registered_at(xyz, yaw, registration)
                ports.info(f"marking board found from the camera at {np.round(xyz, 3).tolist()} m (search view {k}); "
                           "set registration_station_xyz_m to look there first")
                return registration
            last = registration.message
        looked.append(search.describe() + (f" (last: {last})" if last else ""))
        raise JobAborted("no valid registration: the marks O, A, B were not found from " + "; nor from ".join(looked)
                         + ". Put the camera over the board with registration_station_xyz_m: [x, y, z] (cell.yaml "
                         "vars, world m), or set board_search_area_xy_m to where the board lies")

    def _reach_pose(self, xyz, yaw: float) -> None:
        """Before the camera goes to a registration pose (a rail: the carriage to where the arm reaches it)."""

    def _registered_at(self, xyz, yaw: float, registration: Registration) -> None:
        """A valid registration was made with the camera there."""

    def _search_order(self, poses) -> list:
        """The board search's poses in the order shot."""
        return list(poses)

    def _cameras_ok(self, poses) -> list[bool]:
        assert self.reach is not None
        return [v.ok for v in self.reach.cameras(poses)]

    def _surely_unreachable(self, studs_w: np.ndarray, z_range: tuple[float, float]) -> list[str]:
        assert self.reach is not None
        return self.reach.surely_unreachable(studs_w, z_range)

    def _plan(self, studs_w: np.ndarray, plane_z: float, ids: list[str]) -> StationPlan:
        """Stations for every stud not already ruled out; each at a pose the arm reaches."""
        c = self.c
        if self.reach is not None:  # the drawing's place and the plane rule these out, whatever the part
            for sid, why in zip(ids, self._surely_unreachable(studs_w, (plane_z, plane_z + c.part_height_m))):
                if why:
                    self.named.name(sid, why)
        todo = [i for i, sid in enumerate(ids) if sid not in self.named.reasons]
        fov = footprint_m(c.fov_width_m, c.fov_distance_m, c.image_aspect, c.camera_height_m, c.part_height_m)
        sub = plan_stations(studs_w[todo], fov, c.camera_height_m, overlap=c.overlap,
                            yaw_rad=math.radians(c.camera_yaw_deg), plane_z_m=plane_z, fewest=c.fewest_stations)
        plan = StationPlan(tuple(Station(s.index, s.camera_xyz_w, s.yaw_rad, tuple(todo[i] for i in s.stud_indices))
                                 for s in sub.stations), tuple(todo[i] for i in sub.unreachable))
        if self.reach is not None:
            geom = StationGeometry(c.fov_width_m, c.fov_distance_m, c.image_aspect, c.part_height_m, c.camera_height_m,
                                   plane_z, c.overlap, tuple(c.station_height_steps_m))
            plan, reasons = reachable_stations(plan, studs_w, geom, self._cameras_ok)
            for i, why in reasons.items():
                self.named.name(ids[i], why)
        for i in plan.unreachable:
            if ids[i] not in self.named.reasons:
                self.named.name(ids[i], "no camera station the arm reaches covers it")
        return plan

    @property
    def unreachable(self) -> list[str]:
        """The studs named unreachable so far (unreachable.py), in the order named."""
        return self.named.ids

    def _publish_unreachable(self) -> None:
        self.ports.status(self.state, self.message, unreachable=self.unreachable,
                          unreachable_reasons=[self.named.reasons[s] for s in self.unreachable])

    def _weldable(self, t: Target) -> bool:
        """The driver's reach test accepts this target (else the stud is named, and it is not sent)."""
        return not self.named.target_problem(t.stud_id, t.entry.get("position_m"), t.entry.get("normal"))

    # -- stations -------------------------------------------------------------------------------
    def _run_station(self, station, ids: list[str]) -> None:
        n = self.stations_total
        self._status(MOVING, f"station {station.index}/{n}: camera to {np.round(station.camera_xyz_w, 3).tolist()} m",
                     station=station.index)
        self.ports.checkpoint()
        self._move(station.camera_xyz_w, station.yaw_rad)
        wanted = {ids[i] for i in station.stud_indices}
        view = self._shoot_view(f"station {station.index}/{n}", station.camera_xyz_w, station.yaw_rad,
                                frozenset(wanted))
        if view is None:
            raise JobAborted(f"station {station.index}: no weld targets for any of its shots")
        usable = []
        for t in view.targets:
            if t.stud_id not in wanted:
                continue
            self._take_entry(t, view)
            if t.ok and self._weldable(t):
                usable.append(t)
        if not usable:
            self.ports.warn(f"station {station.index}: no usable target among {len(wanted)} assigned studs")
            return
        self._status(WELDING, f"station {station.index}/{n}: welding {len(usable)} stud(s)")
        self._weld_and_inspect([(t, view) for t in usable])

    def _shoot_view(self, what: str, xyz, yaw: float, own: frozenset = frozenset()) -> View | None:
        view = self.ports.shoot_view(what, xyz, yaw)
        if view is not None:
            self.views[view.index] = view
            self._view_station[view.index] = self._station
            self._remember_best(view)
            self._name_seen(view, own)
        return view

    def _name_seen(self, view: View, own: frozenset) -> None:
        """As soon as a shot gives a stud its height and normal, a stud the arm cannot weld is named --
        those of later stations too (``own``: this station's, checked on the target it sends)."""
        for t in view.targets:
            r = self.stud_report.get(t.stud_id)
            if t.ok and r is not None and not r["welded"] and t.stud_id not in own and t.stud_id not in self._seen:
                self._seen.add(t.stud_id)
                self._check_seen(t)

    def _check_seen(self, t: Target) -> None:
        """A stud of a later station seen on a view: named now when the arm cannot weld its target."""
        self._weldable(t)

    def _remember_best(self, view: View) -> None:
        """Keep, per stud, its best usable target over all views by the rule ``plan`` keeps its views by
        (target_table.choose_best: the smallest lean bound; targets are in `world`: one matched from any
        station can be welded from anywhere)."""
        for t in view.targets:
            if not t.ok or t.stud_id not in self.stud_report:
                continue
            key = BestViewKey(TargetStatus.OK, t.lean_bound_deg, t.centre_offset, view.index)
            if t.stud_id not in self.best or choose_best(self.best[t.stud_id][0], key):
                self.best[t.stud_id] = (key, t, view)

    def _take_entry(self, t: Target, view: View) -> None:
        report = self.stud_report[t.stud_id]
        report.pop("reason", None)
        report.update(t.entry)
        report["view"] = int(view.index)

    def _weld_leftovers(self) -> None:
        """Studs their own station gave no usable target for, but another view did."""
        left = [sid for sid, r in self.stud_report.items()
                if not r["welded"] and sid in self.best and self._due(sid) and self._weldable(self.best[sid][1])]
        if not left:
            return
        self.ports.info(f"welding {len(left)} stud(s) matched on another station's view: {', '.join(left)}")
        batch = []
        for sid in left:
            _score, t, view = self.best[sid]
            self._take_entry(t, view)
            batch.append((t, view))
        self._status(WELDING, f"welding {len(left)} stud(s) from other views")
        self._weld_and_inspect(batch)

    def _reshoot(self, studs_w: np.ndarray, ids: list[str], plane_z: float) -> None:
        """Studs no view gave a usable target for, for a reason another view may cure: shot again from
        other directions, ``reshoot_attempts`` times, welded once a view makes them usable."""
        c = self.c
        index = {sid: i for i, sid in enumerate(ids)}
        for attempt in range(c.reshoot_attempts):
            pending = [sid for sid, r in self.stud_report.items() if not r["welded"] and sid not in self.named.reasons
                       and r["status"] in RESHOOT_STATUS_TEXTS and sid not in self.best and self._due(sid, here=True)]
            if not pending:
                return
            for sid in pending:
                if self.stud_report[sid]["welded"] or sid in self.best:
                    continue  # a re-shoot of a neighbour made it usable
                self._station += 1
                station = self._reshoot_station(studs_w[index[sid]], attempt, plane_z, index[sid])
                if station is None:
                    self.ports.warn(f"re-shoot {attempt + 1} of {sid} skipped: "
                                    "no camera pose beside it the arm reaches")
                    continue
                self._status(MOVING, f"re-shoot {attempt + 1}/{c.reshoot_attempts} of {sid} "
                             f"({self.stud_report[sid]['status']}): camera to "
                             f"{np.round(station.camera_xyz_w, 3).tolist()} m")
                self.ports.checkpoint()
                try:
                    self._move(station.camera_xyz_w, station.yaw_rad)
                except MoveRefused as exc:
                    self.ports.warn(f"re-shoot of {sid} skipped: {exc}")
                    continue
                view = self._shoot_view(f"re-shoot of {sid}", station.camera_xyz_w, station.yaw_rad)
                if view is None:
                    continue
                for t in view.targets:
                    r = self.stud_report.get(t.stud_id)
                    if r is not None and not r["welded"] and t.stud_id not in self.best and t.stud_id in pending:
                        self._take_entry(t, view)
                batch = [self.best[s] for s in pending if s in self.best and not self.stud_report[s]["welded"]]
                if batch:
                    for _score, t, v in batch:
                        self._take_entry(t, v)
                    self._status(WELDING, f"welding {len(batch)} stud(s) usable after a re-shoot")
                    self._weld_and_inspect([(t, v) for _score, t, v in batch])

    def _due(self, stud_id: str, here: bool = False) -> bool:
        """The stud is to be welded now (a rail: at this carriage position -- ``here`` -- or, not welded
        at an earlier one, here too)."""
        return True

    def _reshoot_reasons(self) -> None:
        """At the end: why each stud no view could use, re-shoots included, was not welded."""
        c = self.c
        for sid, r in self.stud_report.items():
            if not r["welded"] and r["status"] in RESHOOT_STATUS_TEXTS and sid not in self.best and c.reshoot_attempts:
                r["reason"] = (f"{r['status']} on every view, {c.reshoot_attempts} re-shoot(s) included: "
                               "not welded blind")

    def _reshoot_station(self, stud_xy, attempt: int, plane_z: float, stud_index: int) -> Station | None:
        """The re-shoot's pose, turned further round the stud (and the camera higher) until the arm reaches it."""
        c = self.c
        for dh in c.station_height_steps_m:
            for turn in range(4):
                station = reshoot_station(stud_xy, attempt + turn, c.reshoot_offset_m, c.camera_height_m + dh,
                                          plane_z, math.radians(c.camera_yaw_deg), stud_index=stud_index)
                if self.reach is None or self.reach.camera_ok(station.camera_xyz_w, station.yaw_rad):
                    return station
        return None

    # -- welding and inspection --------------------------------------------------------------------
    def _weld_and_inspect(self, batch: list[tuple[Target, View]]) -> None:
        batch = [(t, v) for t, v in batch if self._weldable(t)]  # never send what the driver would refuse
        if not batch:
            return
        welded = self._weld([t for t, _v in batch])
        self._record_welded(welded)
        for t, view in batch:
            if t.stud_id in welded:
                row = self.qa[t.stud_id]
                row["planned"] = {"position_m": t.entry.get("position_m"), "normal": t.entry.get("normal")}
                row["station"] = self._view_station.get(view.index, self._station)
        if self.c.inspect and welded:
            self._inspect(batch, welded)

    def _record_welded(self, welded: set[str]) -> None:
        """Studs just welded (a rail: where the carriage stood)."""

    def _weld(self, targets: list[Target]) -> set[str]:
        """Weld ``targets``; returns the ids welded. Should the driver lose the job, the same targets go
        again (resume) to its restarted self, whose journal skips what is welded and refuses what is
        uncertain."""
        c = self.c
        self._camera_at = None  # the arm takes the camera along to the welds
        for attempt in range(c.weld_resends + 1):
            self.ports.checkpoint()
            try:
                outcome = self.ports.weld(targets)
                break
            except DriverLost as exc:
                why = f"the arm driver lost the weld job ({exc})"
                if attempt == c.weld_resends:
                    raise JobAborted(f"{why}; gave up after {attempt} resend(s) -- the driver's journal keeps what "
                                     "was welded: restart it and start the job again") from None
                self.ports.warn(f"{why}: sending the station's {len(targets)} target(s) again (resume: its journal "
                                f"skips what is welded; resend {attempt + 1}/{c.weld_resends})")
        sent = {t.stud_id for t in targets}
        welded = {sid for sid in outcome.welded if sid in sent}
        for sid in outcome.welded:  # in the order welded (the neighbours of a failure are the weld order's)
            if sid in sent:
                self.weld_seq.setdefault(sid, len(self.weld_seq) + 1)
        for sid in welded:
            self.stud_report[sid]["welded"] = True
        for line in outcome.messages:
            sid, _, why = line.partition(": ")
            if sid in self.stud_report and not self.stud_report[sid]["welded"]:
                self.stud_report[sid]["weld_message"] = why
        self.ports.status(self.state, self.message, studs_welded=self.welded_count(), studs_failed=len(outcome.failed))
        if self.ports.stopped():
            raise JobAborted("stopped by the operator")
        return welded

    def _inspect(self, batch: list[tuple[Target, View]], welded: set[str]) -> None:
        """Shoot each view's pose again after its welds and have the studs welded there judged."""
        by_view: dict[int, list[Target]] = {}
        for t, view in batch:
            by_view.setdefault(view.index, []).append(t)
        for index, targets in by_view.items():
            view = self.views[index]
            ids = [t.stud_id for t in targets if t.stud_id in welded]
            if not ids:
                continue
            t0 = time.monotonic()
            self._status(INSPECTING, f"station {self._station}: inspecting {len(ids)} welded stud(s)")
            try:
                self.ports.checkpoint()
                if self._camera_at != (tuple(view.camera_xyz_w), float(view.yaw_rad)):
                    self._move(view.camera_xyz_w, view.yaw_rad)  # back to where the targets were seen
                after_ns = self.ports.shoot(inspection=True)  # not a view to match: the inspector's alone
                outcome = self.ports.inspect(self._station, view, targets, ids, after_ns)
            except (InspectionUnavailable, MoveRefused) as exc:
                self.ports.warn(f"station {self._station}: {len(ids)} welded stud(s) not inspected: {exc}")
                for sid in ids:
                    self.qa[sid].update(verdict="not_inspected", reasons=[f"no inspection: {exc}"])
                continue
            for t, fields in zip(targets, outcome.rows):
                if t.stud_id in welded:
                    self.qa[t.stud_id].update(fields)
            self.unexpected += outcome.unexpected
            if outcome.limits:
                self.c = dataclasses.replace(self.c, qa_limits=dict(outcome.limits))
                self._judged = True
            if outcome.overlay_file:
                self.overlays.append(outcome.overlay_file)
            self.inspection_s.append(time.monotonic() - t0)
            counts = qa_report.summary_of([self.qa[sid] for sid in ids])
            self.ports.info(f"station {self._station}: inspection of {len(ids)} stud(s) in "
                            f"{self.inspection_s[-1]:.1f} s: " + ", ".join(f"{k} {v}" for k, v in counts.items() if v))

    # -- plumbing ----------------------------------------------------------------------------------
    def _move(self, xyz, yaw: float) -> None:
        self._camera_at = None
        self.ports.move_camera(xyz, yaw)
        self._camera_at = (tuple(xyz), float(yaw))

    def _status(self, state: CellState, message: str, **fields) -> None:
        self.state, self.message = state, message
        self.ports.status(state, message, **fields)

    def welded_count(self) -> int:
        return sum(r["welded"] for r in self.stud_report.values())

    def qa_rows(self, done: bool = True) -> list[dict]:
        """The QA rows in drawing order; a welded stud no inspection judged is ``not_inspected``. ``done``:
        the job went through its stations (else a stud no station reached says so)."""
        rows = []
        for sid, row in self.qa.items():
            row = dict(row, weld_seq=self.weld_seq.get(sid))
            if self.stud_report[sid]["welded"] and row["verdict"] == "not_welded":
                why = ("inspection is off (inspect:=false)" if not self.c.inspect
                       else "the job ended before its inspection")
                row.update(verdict="not_inspected", reasons=[why])
            elif not self.stud_report[sid]["welded"] and not row["reasons"]:
                r = self.stud_report[sid]
                why = r.get("reason") or r.get("weld_message") or r["status"]
                row["reasons"] = [why if done or r["status"] != "not_planned" else "the job ended before its station"]
            rows.append(row)
        return rows

    def _report_extras(self, qa: bool = False) -> dict:
        """Fields the weld report (and, ``qa``, the QA record's job) add (a rail: the carriage positions)."""
        return {}

    def _rework_decisions(self) -> dict[str, dict]:
        """Decisions the operator took during the job (on studs already inspected), for the QA record."""
        if not self.c.rework_file:
            return {}
        try:
            return {sid: r.for_qa_record() for sid, r in rework.latest_decisions(self.c.rework_file).items()}
        except rework.ReworkError as exc:
            self.ports.warn(f"QA record written without the rework decisions: {exc}")
            return {}

    def _bend_results(self) -> dict[str, dict]:
        """Bend-test results entered during the job, for the QA record."""
        if not self.c.bend_file:
            return {}
        try:
            return {sid: r.for_qa_record() for sid, r in bend.latest_results(self.c.bend_file).items()}
        except bend.BendError as exc:
            self.ports.warn(f"QA record written without the bend-test results: {exc}")
            return {}

    def _code(self) -> dict | None:
        """The record's code profile: the job's, with the limits the inspector judged with where they
        differ from it (its own overrides) marked as overridden."""
        c = self.c
        try:
            code = qa_codes.profile(c.qa_code, c.qa_overrides)
            judged = {n: float(c.qa_limits[n]) for n in qa_codes.LIMIT_NAMES
                      if self._judged and isinstance(c.qa_limits.get(n), (int, float))
                      and c.qa_limits[n] != code.value(n)}
            if self._judged and c.qa_limits.get("qa_code") not in (None, "", c.qa_code):
                self.ports.warn(f"the inspector judged by qa_code {c.qa_limits['qa_code']!r}, the cell samples by "
                                f"{c.qa_code!r}: the record lists the inspector's limits as overrides")
            return (qa_codes.profile(c.qa_code, {**c.qa_overrides, **judged}) if judged else code).describe()
        except qa_codes.CodeError as exc:
            self.ports.warn(f"QA record written without its code profile and bend tests: {exc}")
            return None

    def finish(self, state: CellState, message: str) -> int:
        """Write the weld report and the QA record (also after an early stop); the exit code: 0 only
        when the job is done and every stud welded."""
        welded = self.welded_count()
        self.named.apply(self.stud_report, self.qa)
        self._status(state, message, studs_welded=welded,
                     studs_failed=max(0, len(self.stud_report) - welded) if self.stud_report else 0,
                     unreachable=self.unreachable,
                     unreachable_reasons=[self.named.reasons[s] for s in self.unreachable])
        c = self.c
        if c.report_file:
            # strict JSON: an unmatched stud's NaN position is null (RFC 8259 has no NaN)
            write_json(c.report_file, {"state": state.text, "message": message, "stations": int(self.stations_total),
                                       "unreachable": list(self.unreachable),
                                       "unreachable_reasons": dict(self.named.reasons),
                                       "targets": list(self.stud_report.values()), **self._report_extras()})
        if c.qa_dir and self.qa:
            job = {"id": c.job_id, "part": c.part, "drawing": self.layout.source_file if self.layout else "",
                   "state": state.text, "message": message, **self._report_extras(qa=True)}
            with qa_report.locked(Path(c.qa_dir)):
                doc = qa_report.write_qa_report(Path(c.qa_dir), job, c.qa_limits, self.qa_rows(state == DONE),
                                                self.unexpected, [Path(f) for f in self.overlays],
                                                self._rework_decisions(), code=self._code(), seed=self.sample_seed,
                                                bends=self._bend_results())
            counts = ", ".join(f"{k} {v}" for k, v in doc["summary"].items() if v)
            bends = (doc.get("sampling") or {}).get("counts", {}).get("listed", 0)
            self.ports.info(f"QA record: {c.qa_dir}/qa_report.{{json,csv,html}} ({counts}; {bends} stud(s) to "
                            f"bend-test, {c.qa_code})")
        all_welded = bool(self.stud_report) and welded == len(self.stud_report)
        return 0 if state == DONE and all_welded else 1


__all__ = ["CellJob", "CellPorts", "CellState", "DriverLost", "InspectionOutcome", "InspectionUnavailable",
           "JobAborted", "JobConfig", "Layout", "MoveRefused", "RESHOOT_STATUS_TEXTS", "Registration", "Target", "View",
           "WeldOutcome"]
