"""The weld job along a rail: the arm's base on a linear axis, a part longer than its reach (issue 35).

:class:`RailJob` is :class:`~stud_cell.job.CellJob` with the carriage (``JobConfig.rail_length_m`` > 0):

1. **Registration** as on a fixed arm -- the registration station, else the board search -- with the
   carriage moved first to where the arm reaches the pose (the search's area may lie anywhere along
   the rail; its views are shot moving the carriage one way).
2. **The plan.** Stations over every stud as on a fixed arm, each at a pose the arm reaches from some
   carriage position; then the fewest carriage positions covering them, in one direction along the
   rail (rail_plan.py). A stud no carriage position can weld, whatever its height and normal, is
   named before any motion (:meth:`~stud_cell.rail_plan.RailReach.surely_unreachable`).
3. **Per carriage position ("stop"), in order:** the carriage moves with the arm still
   (``CellPorts.move_rail``); a registration shot at the stop's first station and a valid
   registration from after the move (on the part's reference marks when the drawing has them: the
   registration node fits every mark in view, or takes the nearest registration and says how far it
   extrapolated; without reference marks, on the marking board when the arm reaches it from here,
   else the last registration carries over, its distance reported); then its stations -- shot,
   targets each checked with the reach test at THIS carriage position before it is sent, weld,
   inspect --, the leftovers and re-shoots of this stop, before the carriage moves on. A target is
   welded at the carriage position it was matched at: its registration absorbed the rail's error
   there, another position's would not.
4. **A stud this stop cannot weld** but a later stop can (the exact test on its target, at the later
   carriage position) is deferred there -- and shot there if none of that stop's views sees it --; else
   it is named unreachable with the reason. The carriage never goes back.

The weld report gains ``rail`` (the stops: position, stations, studs, welded, the registration's
residual, marks used and extrapolated distance; the rail moves; the planning time) and per stud
``carriage_stop`` / ``carriage_position_m`` (where it was welded, or is planned); the QA record's job
gains the same ``rail`` and its rows ``carriage_stop``.
"""
from __future__ import annotations

import math

import numpy as np

from stud_cell.cell_reach import CellReach
from stud_cell.job import (
    MATCHING,
    MOVING,
    REGISTERING,
    WELDING,
    CellJob,
    CellPorts,
    JobAborted,
    JobConfig,
    Layout,
    MoveRefused,
    Registration,
    Target,
    View,
)
from stud_cell.rail_plan import CarriageStop, Rail, RailPlan, RailPlanConfig, RailReach, plan_rail, registration_views
from stud_cell.station_reach import StationGeometry
from stud_cell.stations import Station, StationPlan, reshoot_station
from stud_perception.registration import local_to_world

#: Carriage positions closer than this are the same (m): no move, no new registration.
SAME_POSITION_M = 1e-6


def _nan_to_none(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


class RailJob(CellJob):
    """One weld job along the rail (module docstring)."""

    def __init__(self, ports: CellPorts, config: JobConfig, reach: CellReach | None = None) -> None:
        super().__init__(ports, config, reach)
        if not config.rail_length_m > 0:
            raise ValueError(f"RailJob needs a rail: rail_length_m={config.rail_length_m}")
        self.rail: RailReach | None = None
        self.rail_plan: RailPlan | None = None
        self.carriage_m: float | None = None       # where the carriage is (the controller's, m)
        self.rail_moves = 0
        self._visit: list[CarriageStop] = []       # the stops in the order visited (planned, and extra ones)
        self._records: dict[int, dict] = {}        # stop index -> its record in the reports
        self._direction = 1                        # the way the carriage goes along the rail (+1: increasing x)
        self._stop: CarriageStop | None = None     # the stop being worked
        self._studs_w = np.zeros((0, 2))
        self._ids: list[str] = []
        self._index: dict[str, int] = {}
        self._stud_stop: dict[str, int] = {}       # stud id -> the stop it is welded at (planned, or deferred to)
        self._registration: Registration | None = None
        self._reg_carriage: float | None = None    # the carriage position of the last valid registration
        self._board_pose: tuple | None = None      # (xyz, yaw) the marking board was registered from
        self._seen_here: set[str] = set()          # studs on a view of this stop
        self._plane_z = 0.0                        # the registered working plane (world z)

    # -- the carriage ------------------------------------------------------------------------------
    def _set_carriage(self, position_m: float) -> None:
        assert self.rail is not None
        self.carriage_m = float(position_m)
        self.reach = self.rail.at(self.carriage_m)   # the reach test as the driver applies it from here
        self.named.reach = self.reach

    def _move_rail(self, position_m: float, why: str) -> None:
        if self.carriage_m is not None and abs(position_m - self.carriage_m) <= SAME_POSITION_M:
            return
        self._status(MOVING, f"carriage to {position_m:.3f} m ({why})")
        self.ports.checkpoint()
        self._camera_at = None  # the camera rides along
        reached = self.ports.move_rail(position_m)
        self.rail_moves += 1
        self._set_carriage(reached)

    # -- registration ------------------------------------------------------------------------------
    def _register(self, layout: Layout) -> Registration:
        if self.reach is None:
            raise JobAborted("on a rail the job plans carriage positions with the arm driver's reach test, and no "
                             "/arm/reach_config came: is the arm driver running?")
        c = self.c
        self.rail = RailReach(self.reach.reach, Rail(float(c.rail_length_m), tuple(c.rail_mount_xyz_m)),
                              RailPlanConfig(coarse_step_m=c.rail_coarse_step_m, tolerance_m=c.rail_tolerance_m))
        self._set_carriage(self.ports.rail_position_m())
        return super()._register(layout)

    def _reach_pose(self, xyz, yaw: float) -> None:
        assert self.rail is not None and self.carriage_m is not None
        if self.reach is not None and self.reach.camera_ok(xyz, yaw):
            return
        position = self.rail.carriage_for((tuple(xyz), yaw), self.carriage_m)
        if position is None:
            raise MoveRefused(f"no carriage position along the rail 0..{self.c.rail_length_m:g} m lets the arm hold "
                              f"the camera at {np.round(xyz, 3).tolist()} m")
        self._move_rail(position, f"to reach {np.round(xyz, 3).tolist()} m")

    def _registered_at(self, xyz, yaw: float, registration: Registration) -> None:
        self._registration, self._reg_carriage = registration, self.carriage_m
        self._board_pose = (tuple(float(v) for v in xyz), float(yaw))

    def _search_order(self, poses) -> list:
        """The views the arm reaches from where the carriage stands first (the search's order), then the
        others by the carriage position nearest that reaches them, moving one way."""
        assert self.rail is not None and self.reach is not None and self.carriage_m is not None
        now = self.carriage_m
        here = [p for p, v in zip(poses, self.reach.cameras(list(poses))) if v.ok]
        rest = [p for p in poses if p not in here]
        at = {}
        for pose, intervals in zip(rest, self.rail.camera_intervals(list(rest))):
            at[pose] = min((min(max(now, lo), hi) for lo, hi in intervals), key=lambda v: abs(v - now), default=now)
        ahead = sorted((p for p in rest if at[p] >= now), key=lambda p: at[p])
        behind = sorted((p for p in rest if at[p] < now), key=lambda p: -at[p])
        if behind and (not ahead or abs(at[behind[-1]] - now) < abs(at[ahead[-1]] - now)):
            ahead, behind = behind, ahead   # the shorter way first
        return here + ahead + behind

    def _cameras_ok(self, poses) -> list[bool]:
        assert self.rail is not None
        return self.rail.cameras_somewhere(list(poses))

    def _surely_unreachable(self, studs_w: np.ndarray, z_range: tuple[float, float]) -> list[str]:
        assert self.rail is not None
        return self.rail.surely_unreachable(studs_w, z_range)

    # -- the stops ---------------------------------------------------------------------------------
    def _work(self, plan: StationPlan, studs_w: np.ndarray, ids: list[str], plane_z: float) -> None:
        assert self.rail is not None and self.carriage_m is not None
        c = self.c
        self._plane_z, self._studs_w, self._ids = plane_z, studs_w, ids
        self._index = {sid: i for i, sid in enumerate(ids)}
        height = c.rail_stud_height_m if math.isfinite(c.rail_stud_height_m) else c.part_height_m / 2
        rp = plan_rail(plan.stations, studs_w, self.rail, plane_z + height, start_m=self.carriage_m)
        self.rail_plan = rp
        for i, why in rp.unreachable_studs.items():
            self.named.name(ids[i], why)
        self.stations_total = len(rp.stations)
        self._visit = list(rp.stops)
        if len(rp.stops) >= 2:
            self._direction = 1 if rp.stops[-1].position_m >= rp.stops[0].position_m else -1
        for stop in rp.stops:
            for i in stop.stud_indices:
                self._stud_stop[ids[i]] = stop.index
            self._records[stop.index] = self._new_record(stop)
        self.ports.status(self.state, self.message, stations_total=self.stations_total)
        self.ports.info(f"{len(rp.stops)} carriage position(s) along the rail for {len(rp.stations)} station(s): "
                        + ", ".join(f"{s.position_m:.3f}" for s in rp.stops) + f" m; planned in {rp.planning_s:.1f} s "
                        f"({rp.reach_checks} reach checks)"
                        + (f"; stations {list(rp.prior_ignored)} placed by the camera's reach alone (their studs' "
                           "prior left no carriage position)" if rp.prior_ignored else ""))
        k = 0
        while k < len(self._visit):   # extra stops may join ahead while the job goes
            self._run_stop(self._visit[k], studs_w, ids, plane_z)
            k += 1
        self._reshoot_reasons()

    def _new_record(self, stop: CarriageStop, extra: bool = False) -> dict:
        return {"index": stop.index, "position_m": stop.position_m, "window_m": list(stop.window_m), "reached_m": None,
                "stations": [st.index for st in stop.stations],
                "studs": [self._ids[i] for i in stop.stud_indices], "deferred_in": [], "extra": extra,
                "registration": None, "welded": 0, "error": ""}

    def _rank(self, stop_index: int) -> int:
        """Where a stop comes in the visiting order (0-based)."""
        return next(k for k, s in enumerate(self._visit) if s.index == stop_index)

    def _where(self, stop: CarriageStop) -> str:
        return f"carriage position {self._rank(stop.index) + 1}/{len(self._visit)} at {stop.position_m:.3f} m"

    def _run_stop(self, stop: CarriageStop, studs_w: np.ndarray, ids: list[str], plane_z: float) -> None:
        self._stop = stop
        record = self._records[stop.index]
        try:
            self._move_rail(stop.position_m, self._where(stop))
        except MoveRefused as exc:
            self._lose_stop(stop, record, f"the carriage move was refused: {exc}")
            return
        record["reached_m"] = self.carriage_m
        self.best.clear()   # targets of another carriage position are in its registration, not this one's
        self._seen_here = set()
        problem = self._register_stop(stop, record)
        if problem:
            self._lose_stop(stop, record, problem)
            return
        for station in stop.stations:
            self._run_station_or_skip(station, ids)
        self._weld_leftovers()
        self._reshoot(studs_w, ids, plane_z)
        self._catch_up(stop, studs_w, ids, plane_z)
        record["welded"] = sum(1 for r in self.stud_report.values() if r.get("carriage_stop") == stop.index
                               and r["welded"])

    def _lose_stop(self, stop: CarriageStop, record: dict, why: str) -> None:
        """The stop cannot be worked: its studs are named with the reason (the carriage does not come back)."""
        record["error"] = why
        self.ports.warn(f"{self._where(stop)}: skipped, {why}")
        for sid, k in self._stud_stop.items():
            if k == stop.index and not self.stud_report[sid]["welded"] and sid not in self.named.reasons:
                self.named.name(sid, f"{self._where(stop)}: {why}")

    def _register_stop(self, stop: CarriageStop, record: dict) -> str:
        """A valid registration with the carriage here (module docstring, 3); "" or why there is none."""
        assert self.layout is not None and self.carriage_m is not None and self.reach is not None
        if self.layout.reference_marks_m:
            pose, source = self._mark_view(stop), "reference marks"
        elif self._reg_carriage is not None and abs(self.carriage_m - self._reg_carriage) <= SAME_POSITION_M:
            record["registration"] = self._registration_record(self._registration, "made at this carriage position")
            return ""
        elif self._board_pose is not None and self.reach.camera_ok(*self._board_pose):
            pose, source = self._board_pose, "marking board"
        else:
            assert self._reg_carriage is not None
            distance = abs(self.carriage_m - self._reg_carriage)
            self.ports.warn(f"{self._where(stop)}: the drawing has no reference marks and the marking board is out of "
                            f"reach from here: the registration made with the carriage at {self._reg_carriage:.3f} m "
                            f"carries over, {distance:.3f} m of the rail's error uncorrected")
            record["registration"] = {**self._registration_record(self._registration, "carried over"),
                                      "extrapolated_m": distance}
            return ""
        self._status(REGISTERING, f"{self._where(stop)}: registering on the {source} in view")
        try:
            self._move(*pose)
        except MoveRefused as exc:
            return f"the registration view was refused: {exc}"
        registration = self.ports.register()
        record["registration"] = self._registration_record(registration, source)
        if not registration.valid:
            return f"no valid registration on the {source}: {registration.message}"
        self._registration, self._reg_carriage = registration, self.carriage_m
        self.ports.info(f"{self._where(stop)}: registered ({registration.message})")
        return ""

    def _mark_view(self, stop: CarriageStop) -> tuple:
        """Where the stop registers on the reference marks: the pose the arm reaches from here that holds
        the most marks (where the last registration puts them; two at least fix the drawing), nearest its
        first station -- or that station's pose, where the registration node takes the nearest registration."""
        assert self.layout is not None and self._registration is not None and self.reach is not None
        c = self.c
        refs = np.array(list(self.layout.reference_marks_m.values()), dtype=np.float64).reshape(-1, 2)
        marks_w = local_to_world(self._registration.m_local2world, refs).reshape(-1, 2)
        geom = StationGeometry(c.fov_width_m, c.fov_distance_m, c.image_aspect, c.part_height_m, c.camera_height_m,
                               self._plane_z, c.overlap, tuple(c.station_height_steps_m))
        first = (stop.stations[0].camera_xyz_w, stop.stations[0].yaw_rad)
        views = [v for v in registration_views(marks_w, stop.stations, geom, self.layout.mark_diameter_m / 2 + 0.005)
                 if v[1] >= 2]
        for k in range(0, len(views), 64):   # in batches: the first reachable of the best is taken
            batch = views[k:k + 64]
            for (pose, _count), verdict in zip(batch, self.reach.cameras([p for p, _n in batch])):
                if verdict.ok:
                    return pose
        return first

    @staticmethod
    def _registration_record(reg: Registration | None, source: str) -> dict:
        if reg is None:
            return {"valid": False, "source": source, "message": "no registration"}
        return {"valid": bool(reg.valid), "source": source, "message": reg.message,
                "residual_m": _nan_to_none(reg.residual_m), "residual_max_m": _nan_to_none(reg.residual_max_m),
                "labels_used": list(reg.labels_used), "extrapolated_m": float(reg.extrapolated_m)}

    # -- what each stud waits for ------------------------------------------------------------------
    def _due(self, stud_id: str, here: bool = False) -> bool:
        k = self._stud_stop.get(stud_id)
        if k is None or self._stop is None:
            return False
        rank, now = self._rank(k), self._rank(self._stop.index)
        return rank == now if here else rank <= now

    def _verdict_at(self, t_or_entry, stop: CarriageStop) -> str:
        entry = t_or_entry.entry if isinstance(t_or_entry, Target) else t_or_entry
        assert self.rail is not None
        return self.named.verdict(entry.get("position_m"), entry.get("normal"), self.rail.at(stop.position_m))

    def _defer_or_name(self, t: Target, why: str, after: CarriageStop) -> None:
        """A stud ``why`` the stop ``after`` cannot weld: deferred to the first stop visited after it that
        can, else to an extra carriage position ahead, else named."""
        sid = t.stud_id
        later = next((s for s in self._visit[self._rank(after.index) + 1:] if not self._verdict_at(t, s)), None)
        if later is None:
            later = self._extra_stop(t, after)
        if later is None:
            self.named.name(sid, f"{why} (with the carriage at {after.position_m:.3f} m; no carriage position further "
                                 "along the rail reaches it either)")
            return
        self.named.withdraw(sid)
        if self._stud_stop.get(sid) != later.index:
            self._stud_stop[sid] = later.index
            self._records[later.index]["deferred_in"].append(sid)
            self.ports.info(f"{sid}: deferred to {self._where(later)} ({why.removeprefix('unreachable: ')} from "
                            f"{after.position_m:.3f} m)")

    def _extra_stop(self, t: Target, after: CarriageStop) -> CarriageStop | None:
        """A carriage position further along the rail than ``after`` -- not planned -- from which the arm
        welds ``t`` and holds the camera over it: a new stop, visited in its place along the travel."""
        assert self.rail is not None
        sid = t.stud_id
        i = self._index[sid]
        rail, step = self.rail.rail, self.rail.config.coarse_step_m
        x = float(self._studs_w[i][0]) - rail.mount_xyz_m[0]
        d, span = self._direction, self.rail.config.reach_span_m
        cs = [c for c in np.arange(0.0, rail.length_m + 1e-9, step)
              if d * (c - after.position_m) > 0.5 * step and abs(x - c) <= span]
        poses = self._poses_seeing(sid, self._studs_w[i], i, self._plane_z)
        for c in sorted(cs, key=lambda v: abs(v - after.position_m)):
            c = float(c)
            if self.named.verdict(t.entry.get("position_m"), t.entry.get("normal"), self.rail.at(c)):
                continue
            ok = [p for p, v in zip(poses, self.rail.at(c).cameras(poses)) if v.ok]
            if not ok:
                continue
            self.stations_total += 1
            station = Station(self.stations_total, tuple(ok[0][0]), float(ok[0][1]), (i,))
            index = max(s.index for s in self._visit) + 1
            stop = CarriageStop(index, c, (c, c), (station,))
            rank = self._rank(after.index) + 1
            while rank < len(self._visit) and d * (self._visit[rank].position_m - c) < 0:
                rank += 1
            self._visit.insert(rank, stop)
            self._records[index] = self._new_record(stop, extra=True)
            self.ports.info(f"{sid}: no planned carriage position welds it: an extra one at {c:.3f} m")
            self.ports.status(self.state, self.message, stations_total=self.stations_total)
            return stop
        return None

    def _weldable(self, t: Target) -> bool:
        """The reach test at THIS carriage position accepts the target; else the stud is deferred to a
        later stop that can weld it, or named."""
        why = self.named.verdict(t.entry.get("position_m"), t.entry.get("normal"))
        if not why:
            if self.reach is not None and t.entry.get("position_m") is not None:
                self.named.withdraw(t.stud_id)
            return True
        assert self._stop is not None
        self._defer_or_name(t, why, self._stop)
        return False

    def _check_seen(self, t: Target) -> None:
        """A stud of a later stop, seen from here: checked at its own stop (then the later ones)."""
        k = self._stud_stop.get(t.stud_id)
        if k is None or self._stop is None or self._rank(k) <= self._rank(self._stop.index):
            return   # this stop's own and earlier ones' are checked on the target they are sent with
        own = self._visit[self._rank(k)]
        why = self._verdict_at(t, own)
        if why:
            self._defer_or_name(t, why, own)

    def _shoot_view(self, what: str, xyz, yaw: float, own: frozenset = frozenset()) -> View | None:
        view = super()._shoot_view(what, xyz, yaw, own)
        if view is not None:
            self._seen_here |= {t.stud_id for t in view.targets}
        return view

    def _record_welded(self, welded: set[str]) -> None:
        assert self._stop is not None
        for sid in welded:
            self.stud_report[sid].update(carriage_stop=self._stop.index, carriage_position_m=self.carriage_m)
            self.qa[sid].update(carriage_stop=self._stop.index, carriage_position_m=self.carriage_m)

    # -- studs deferred here that no view of this stop saw -----------------------------------------
    def _poses_seeing(self, sid: str, stud_xy, stud_index: int, plane_z: float) -> list[tuple]:
        """Camera poses that hold the stud: its planned station's, then the re-shoot poses round it."""
        c = self.c
        poses = [(st.camera_xyz_w, st.yaw_rad) for stop in self._visit for st in stop.stations
                 if stud_index in st.stud_indices]
        for dh in c.station_height_steps_m:
            for turn in range(4):
                st = reshoot_station(stud_xy, turn, c.reshoot_offset_m, c.camera_height_m + dh, plane_z,
                                     math.radians(c.camera_yaw_deg), stud_index=stud_index)
                poses.append((st.camera_xyz_w, st.yaw_rad))
        return poses

    def _catch_up(self, stop: CarriageStop, studs_w: np.ndarray, ids: list[str], plane_z: float) -> None:
        """Studs deferred to this stop that none of its views saw: a view from here that holds them."""
        assert self.rail is not None and self.reach is not None
        index = {sid: i for i, sid in enumerate(ids)}
        for sid in [s for s, k in self._stud_stop.items() if k == stop.index]:
            r = self.stud_report[sid]
            if r["welded"] or sid in self.named.reasons or sid in self._seen_here:
                continue
            poses = self._poses_seeing(sid, studs_w[index[sid]], index[sid], plane_z)
            ok = [p for p, v in zip(poses, self.reach.cameras(poses)) if v.ok]
            if not ok:   # a later stop whose arm holds a view of it and welds its last target
                later = next((s for s in self._visit[self._rank(stop.index) + 1:]
                              if not self._verdict_at(r, s)
                              and any(v.ok for v in self.rail.at(s.position_m).cameras(poses))),
                             None)
                if later is None:
                    self.named.name(sid, f"no camera pose the arm reaches from {self._where(stop)} or a later one "
                                         "sees it")
                else:
                    self._stud_stop[sid] = later.index
                    self._records[later.index]["deferred_in"].append(sid)
                    self.ports.info(f"{sid}: deferred to {self._where(later)} (no view of it from here)")
                continue
            xyz, yaw = ok[0]
            self._station += 1
            self._status(MOVING, f"{self._where(stop)}: view of {sid} (deferred here): camera to "
                                 f"{np.round(xyz, 3).tolist()} m")
            self.ports.checkpoint()
            try:
                self._move(xyz, yaw)
            except MoveRefused as exc:
                self.ports.warn(f"view of {sid} skipped: {exc}")
                continue
            self._status(MATCHING, f"{self._where(stop)}: view of {sid}")
            view = self._shoot_view(f"view of {sid}", xyz, yaw)
            if view is None:
                continue
            due = [t for t in view.targets if self._due(t.stud_id) and not self.stud_report[t.stud_id]["welded"]
                   and t.stud_id not in self.named.reasons]
            for t in due:
                self._take_entry(t, view)
            batch = [(t, view) for t in due if t.ok]
            if batch:
                self._status(WELDING, f"{self._where(stop)}: welding {len(batch)} stud(s) from the view of {sid}")
                self._weld_and_inspect(batch)

    # -- the reports -------------------------------------------------------------------------------
    @property
    def stops(self) -> list[dict]:
        """Per carriage position, in the order visited: its record in the reports."""
        return [self._records[s.index] for s in self._visit]

    def _done_note(self) -> str:
        return f"; {len(self._visit)} carriage position(s), {self.rail_moves} rail move(s)"

    def _report_extras(self, qa: bool = False) -> dict:
        rp = self.rail_plan
        for sid, k in self._stud_stop.items():   # where each stud not welded was planned
            if not self.stud_report[sid]["welded"]:
                self.stud_report[sid].setdefault("carriage_stop", k)
        return {"rail": {"length_m": float(self.c.rail_length_m),
                         "mount_xyz_m": [float(v) for v in self.c.rail_mount_xyz_m],
                         "moves": int(self.rail_moves), "planning_s": None if rp is None else float(rp.planning_s),
                         "reach_checks": None if rp is None else int(rp.reach_checks),
                         "unreachable_stations": {} if rp is None else {str(k): v for k, v in rp.unreachable.items()},
                         "stops": self.stops}}


__all__ = ["RailJob"]
