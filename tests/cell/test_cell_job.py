"""The cell's weld job (stud_cell.job) over a cell made of plain Python: a camera that sees the
studs inside its footprint, an arm driver with a journal (a stud it holds as welded is never welded
again, whatever is sent), an inspector judging by a table of defects. What is checked is the job's
logic: every stud welded once, inspected after its station, the QA record written even after a stop,
a failed stud never welded again, views that cannot be used shot again."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from stud_cell import job as cell_job
from stud_cell.job import CellJob, DriverLost, InspectionOutcome, InspectionUnavailable, JobAborted, JobConfig
from stud_cell.stations import footprint_m
from stud_common.vocabulary import CellState
from stud_inspection.rework import append_record, make_record


class FakeCell:
    """``studs``: id -> world XY. ``status_of(stud_id, camera_xy)``: the matcher's status text of that
    stud seen from there ("ok" by default). ``verdict_of``: id -> the inspection's verdict and reasons."""

    def __init__(self, studs: dict, status_of=None, verdict_of=None, inspector=True, stop_after_welds=None,
                 lose_driver_once=False):
        self.studs = studs
        self.status_of = status_of or (lambda sid, cam: "ok")
        self.verdict_of = verdict_of or {}
        self.inspector = inspector
        self.stop_after_welds = stop_after_welds
        self.lose_driver_once = lose_driver_once
        self.camera = None
        self.journal: list[str] = []           # every stud the arm welded, in order (a real double weld shows twice)
        self.weld_calls: list[list[str]] = []
        self.inspections: list[dict] = []
        self.moves: list[tuple] = []
        self.shots: list[str] = []
        self.states: list[CellState] = []
        self.log: list[str] = []
        self._stop = False
        self._view = 0
        self._clock = 1_000
        self.last_shot_was_inspection = False
        c = JobConfig()
        self.fov = footprint_m(c.fov_width_m, c.fov_distance_m, c.image_aspect, c.camera_height_m, c.part_height_m)

    # -- CellPorts --
    def wait_layout(self):
        ids = list(self.studs)
        return cell_job.Layout(ids=ids, xy_m=np.array([self.studs[s] for s in ids]).reshape(-1, 2),
                               source_file="part.dxf")

    def move_camera(self, xyz, yaw):
        self.camera = (tuple(float(v) for v in xyz), float(yaw))
        self.moves.append(self.camera)

    def register(self, attempts=0):
        return cell_job.Registration(True, "3 marks", np.eye(3), 0.0)   # drawing frame = world

    def shoot(self, inspection=False):
        self._clock += 1_000
        self.last_shot_was_inspection = inspection
        return self._clock

    def shoot_view(self, what, xyz, yaw):
        assert self.camera is not None and np.allclose(self.camera[0], xyz), "shot away from the commanded pose"
        self._view += 1
        self.shots.append(what)
        cx, cy = xyz[0], xyz[1]
        targets = []
        for sid, (x, y) in self.studs.items():
            if abs(x - cx) <= self.fov[0] / 2 and abs(y - cy) <= self.fov[1] / 2:
                st = self.status_of(sid, (cx, cy))
                targets.append(cell_job.Target(sid, st == "ok", st, 0.5 if st == "ok" else math.inf,
                                               {"status": st, "position_m": [x, y, 0.0], "normal": [0.0, 0.0, 1.0]},
                                               payload=sid))
        return cell_job.View(self._view, self.shoot(), tuple(xyz), yaw, tuple(targets))

    def weld(self, targets):
        self.camera = None  # the camera rides on the arm to the welds
        ids = [t.payload for t in targets]
        self.weld_calls.append(ids)
        done = []
        for n, sid in enumerate(ids):
            if sid not in self.journal:          # the journal: resume skips what is welded
                self.journal.append(sid)
            done.append(sid)
            if self.lose_driver_once and n == 0:
                self.lose_driver_once = False
                raise DriverLost("no /arm/weld_job result")
        if self.stop_after_welds is not None and len(self.journal) >= self.stop_after_welds:
            self._stop = True
        return cell_job.WeldOutcome(tuple(done), (), ())

    def inspect(self, station, view, targets, welded_ids, after_ns):
        if not self.inspector:
            raise InspectionUnavailable("/inspection/inspect is not available")
        assert self.camera is not None and self.camera[0] == tuple(view.camera_xyz_w), \
            "inspected from another pose than the targets' view"
        assert after_ns > view.stamp_ns
        assert self.last_shot_was_inspection, "the shot after the welds must be an inspection shot, not a view to match"
        self.inspections.append({"station": station, "ids": list(welded_ids)})
        rows = []
        for t in targets:
            verdict, reasons = self.verdict_of.get(t.stud_id, ("pass", []))
            if t.stud_id not in welded_ids:
                verdict, reasons = "not_welded", []
            rows.append({"verdict": verdict, "reasons": list(reasons),
                         "measured": None if verdict in ("missing", "not_welded") else
                         {"position_m": t.entry["position_m"], "axis": [0.0, 0.0, 1.0], "lean_deg": 0.3,
                          "offset_mm": [0.1, 0.0], "height_mm": 49.8}})
        return InspectionOutcome(rows, [], "", {"max_lean_deg": 5.0, "position_tol_mm": 2.0, "nominal_length_mm": 50.0,
                                                "height_tol_mm": 2.0, "stud_diameter_mm": 16.0})

    def status(self, state, message, **fields):
        self.states.append(state)

    def checkpoint(self):
        if self._stop:
            raise JobAborted("stopped by the operator")

    def stopped(self):
        return self._stop

    def info(self, text):
        self.log.append(text)

    def warn(self, text):
        self.log.append("WARN " + text)


def grid(nx=6, ny=4, pitch=0.1):
    return {f"S{i * ny + j + 1:04d}": (0.1 + i * pitch, -0.15 + j * pitch) for i in range(nx) for j in range(ny)}


def run(cell, tmp_path, **config):
    job = CellJob(cell, JobConfig(report_file=str(tmp_path / "weld_report.json"), qa_dir=str(tmp_path / "qa"),
                                  job_id="J1", part="plate", **config))
    state, code = job.run()
    qa = json.loads((tmp_path / "qa" / "qa_report.json").read_text())
    return job, state, code, qa


def test_a_clean_job_welds_every_stud_once_and_inspects_each_station_after_its_welds(tmp_path):
    cell = FakeCell(grid())
    job, state, code, qa = run(cell, tmp_path)
    assert (state, code) == (CellState.DONE, 0), cell.log
    assert sorted(cell.journal) == sorted(cell.studs) and len(cell.journal) == len(set(cell.journal))
    inspected = [sid for i in cell.inspections for sid in i["ids"]]
    assert sorted(inspected) == sorted(cell.studs)
    assert len(cell.inspections) == job.stations_total > 1
    assert [r["stud_id"] for r in qa["studs"]] == list(cell.studs)  # drawing order
    assert qa["summary"]["pass"] == len(cell.studs) and qa["job"]["part"] == "plate"
    assert qa["limits"]["nominal_length_mm"] == 50.0
    assert all(r["planned"]["normal"] == [0.0, 0.0, 1.0] and r["measured"]["height_mm"] == 49.8 for r in qa["studs"])
    assert {(tmp_path / "qa" / f"qa_report.{ext}").exists() for ext in ("json", "csv", "html")} == {True}
    # the inspection states come after each station's welds
    assert cell.states.index(CellState.INSPECTING) > cell.states.index(CellState.WELDING)


def test_every_defect_is_reported_with_its_reason_and_a_failed_stud_is_never_welded_again(tmp_path):
    defects = {"S0004": ("fail", ["lean 8.1 deg > 5 deg"]), "S0007": ("fail", ["offset 4.0 mm > 2 mm"]),
               "S0011": ("missing", ["nothing stands at the planned point"]),
               "S0013": ("fail", ["height 38.0 mm: 50 +- 2 mm"])}
    cell = FakeCell(grid(), verdict_of=defects)
    job, state, code, qa = run(cell, tmp_path)
    rows = {r["stud_id"]: r for r in qa["studs"]}
    for sid, (verdict, reasons) in defects.items():
        assert rows[sid]["verdict"] == verdict and rows[sid]["reasons"] == reasons
    assert qa["summary"]["pass"] == len(cell.studs) - 4 and qa["summary"]["fail"] == 3 and qa["summary"]["missing"] == 1
    assert all(cell.journal.count(sid) == 1 for sid in defects)
    assert sum(ids.count(sid) for ids in cell.weld_calls for sid in defects) == 4   # each sent once, never again


def test_decisions_taken_during_the_job_are_in_its_qa_record_and_a_damaged_file_costs_only_them(tmp_path):
    decisions = tmp_path / "qa" / "qa" / "rework_decisions.jsonl"   # the inspector's, beside its overlays
    append_record(decisions, make_record("S0004", "rework", "cut off", "fail", stamp=10.0))
    cell = FakeCell(grid(), verdict_of={"S0004": ("fail", ["lean 8.1 deg > 5 deg"])})
    job, state, code, qa = run(cell, tmp_path, rework_file=str(decisions))
    rows = {r["stud_id"]: r for r in qa["studs"]}
    assert (rows["S0004"]["rework"], rows["S0004"]["rework_note"]) == ("rework", "cut off")
    assert sum(r["rework"] is not None for r in qa["studs"]) == 1
    with open(decisions, "a") as f:
        f.write("not json\n")
    job, state, code, qa = run(FakeCell(grid()), tmp_path, rework_file=str(decisions))
    assert state == CellState.DONE and qa["summary"]["pass"] == len(grid())   # the record is written all the same
    assert any("without the rework decisions" in line and "rework_decisions.jsonl:2" in line for line in job.ports.log)


def test_a_job_stopped_early_still_writes_the_qa_record_and_the_rest_are_not_welded(tmp_path):
    cell = FakeCell(grid(), stop_after_welds=3)
    job, state, code, qa = run(cell, tmp_path)
    assert state == CellState.FAILED and code == 1 and "stopped" in qa["job"]["message"]
    rows = {r["stud_id"]: r for r in qa["studs"]}
    welded = set(cell.journal)
    assert welded and len(welded) < len(cell.studs)
    assert {sid for sid, r in rows.items() if r["verdict"] == "not_welded"} == set(cell.studs) - welded
    # the station welded when the stop came was never inspected: not a pass; those before it were
    last = set(cell.weld_calls[-1])
    assert all(rows[sid]["verdict"] == "not_inspected" and "ended before" in rows[sid]["reasons"][0] for sid in last)
    assert all(rows[sid]["verdict"] == "pass" for sid in welded - last) and welded - last
    assert all("ended before its station" in r["reasons"][0] for r in rows.values() if r["verdict"] == "not_welded")
    assert json.loads((tmp_path / "weld_report.json").read_text())["state"] == "failed"


def test_without_an_inspector_welded_studs_are_not_inspected_with_the_reason_never_passed(tmp_path):
    cell = FakeCell(grid(3, 2), inspector=False)
    job, state, code, qa = run(cell, tmp_path)
    assert (state, code) == (CellState.DONE, 0)
    assert qa["summary"]["not_inspected"] == len(cell.studs) and qa["summary"]["pass"] == 0
    assert all("not available" in r["reasons"][0] for r in qa["studs"])


def test_inspection_off_says_so(tmp_path):
    cell = FakeCell(grid(3, 2))
    job, state, code, qa = run(cell, tmp_path, inspect=False)
    assert not cell.inspections and qa["summary"]["not_inspected"] == len(cell.studs)
    assert all("inspection is off" in r["reasons"][0] for r in qa["studs"])


def test_a_driver_that_loses_the_job_gets_it_again_and_its_journal_welds_nothing_twice(tmp_path):
    cell = FakeCell(grid(3, 2), lose_driver_once=True)
    job, state, code, qa = run(cell, tmp_path)
    assert (state, code) == (CellState.DONE, 0)
    assert len(cell.weld_calls) > job.stations_total             # a resend happened
    assert sorted(cell.journal) == sorted(cell.studs) and len(cell.journal) == len(set(cell.journal))


def test_a_stud_its_station_cannot_use_is_welded_from_another_view_and_inspected_from_that_views_pose(tmp_path):
    studs = grid()
    first_cam = {}

    def status_of(sid, cam):  # S0010's own station sees it in a hole; any other view is fine
        first_cam.setdefault(sid, cam)
        return "no_depth" if sid == "S0010" and cam == first_cam[sid] else "ok"

    cell = FakeCell(studs, status_of=status_of)
    job, state, code, qa = run(cell, tmp_path)
    assert (state, code) == (CellState.DONE, 0), cell.log
    assert cell.journal.count("S0010") == 1
    rows = {r["stud_id"]: r for r in qa["studs"]}
    assert rows["S0010"]["verdict"] == "pass"


def test_a_stud_no_view_can_use_is_shot_again_and_never_welded_blind(tmp_path):
    cell = FakeCell(grid(3, 2), status_of=lambda sid, cam: "normal_uncertain" if sid == "S0003" else "ok")
    job, state, code, qa = run(cell, tmp_path, reshoot_attempts=2)
    assert state == CellState.DONE and code == 1                    # not every stud welded
    assert "S0003" not in cell.journal
    assert [w for w in cell.shots if w.startswith("re-shoot")] == ["re-shoot of S0003"] * 2
    rows = {r["stud_id"]: r for r in qa["studs"]}
    assert rows["S0003"]["verdict"] == "not_welded" and "not welded blind" in rows["S0003"]["reasons"][0]
    assert json.loads((tmp_path / "weld_report.json").read_text())["targets"][2]["welded"] is False


def test_an_invalid_registration_ends_the_job_with_the_reason_and_the_records(tmp_path):
    cell = FakeCell(grid(2, 2))
    cell.register = lambda attempts=0: cell_job.Registration(False, "mark B not found", np.eye(3), math.nan)
    job, state, code, qa = run(cell, tmp_path)
    assert state == CellState.FAILED and "mark B not found" in qa["job"]["message"]
    assert qa["summary"]["not_welded"] == 4 and not cell.journal


@pytest.mark.parametrize("bad", [{"weld": "boom"}])
def test_an_internal_error_ends_the_job_with_a_state_not_a_vanished_thread(tmp_path, bad):
    cell = FakeCell(grid(2, 2))

    def weld(_targets):
        raise RuntimeError(bad["weld"])

    cell.weld = weld
    job, state, code, qa = run(cell, tmp_path)
    assert state == CellState.FAILED and "boom" in qa["job"]["message"] and code == 1


def test_fewest_stations_covers_the_plate_with_fewer_stations_and_welds_every_stud_once(tmp_path):
    grid_job, *_ = run(FakeCell(grid()), tmp_path / "grid")
    cell = FakeCell(grid())
    job, state, code, qa = run(cell, tmp_path / "few", fewest_stations=True)
    assert (state, code) == (CellState.DONE, 0)
    assert job.stations_total < grid_job.stations_total
    assert sorted(cell.journal) == sorted(cell.studs) and qa["summary"]["pass"] == len(cell.studs)


class ViewsOfADome(FakeCell):
    """The dome's studs, seen unusable from their own station (a hole over each), and the same studs
    usable on the views taken at two far studs' stations: ``far_views`` maps each far stud to the
    (index, targets) of the view its station's shot gives besides it."""

    def __init__(self, studs: dict, far_views: dict):
        super().__init__(studs, status_of=lambda sid, cam: "ok" if sid in far_views else "no_depth")
        self.far_views = far_views

    def shoot_view(self, what, xyz, yaw):
        view = super().shoot_view(what, xyz, yaw)
        for far, (index, targets) in self.far_views.items():
            if any(t.stud_id == far for t in view.targets):
                return cell_job.View(index, view.stamp_ns, view.camera_xyz_w, view.yaw_rad, view.targets + targets)
        return cell_job.View(100 + view.index, view.stamp_ns, view.camera_xyz_w, view.yaw_rad, view.targets)


@pytest.mark.parametrize("tied", [False, True], ids=["rendered", "equal_lean_bounds"])
def test_plan_and_the_cell_keep_the_same_view_of_a_stud_two_views_saw(tmp_path, tied):
    """Two rendered views of the dome: `plan` merges them into its report, the cell gets them as
    WeldTargetArray messages from far stations and welds the dome's studs from its best view of each."""
    import dataclasses

    from rclpy.serialization import deserialize_message
    from stud_welding_msgs.msg import WeldTargetArray

    from stud_perception.scene import demo_dome_scene
    from stud_perception.scene_cameras import view_camera
    from stud_perception.scene_render import render
    from stud_planner.matching.target_cdr import weld_target_array_cdr
    from stud_planner.matching.target_table import TargetTable
    from stud_planner.matching.view_targets import plan_view
    from stud_planner.msg_convert import weld_target_table

    scene = demo_dome_scene()
    ids, xy = list(scene.stud_ids), np.asarray(scene.studs_drawing_m)
    apex = np.append(scene.studs_world_xy_m.mean(axis=0), 0.1)
    views, cameras = [], []
    for index, (dx, dy, tilt, noise) in ((1, (0.0, 0.0, 0.0, 0.0005)), (2, (-0.05, 0.08, 0.35, 0.0005))):
        cam = view_camera(apex + (dx, dy, 0.0), 0.5, tilt_rad=tilt, tilt_azimuth_rad=1.0, width=640, height=480)
        depth = render(scene, cam, seed=index, depth_noise_m=noise).depth_m
        views.append(plan_view(ids, xy, scene.M_local2world, depth, cam, view_index=index))
        cameras.append(cam)
    if tied:  # noise-free depth puts both at the floor: the more central match must decide
        views[1] = dataclasses.replace(views[1], lean_bound_deg=views[0].lean_bound_deg.copy())
    assert views[0].ok.all() and views[1].ok.all()

    best = TargetTable.unseen(ids, xy)
    for t in views:  # what `plan` does with its views
        best = best.merge(t)
    planned = {e["stud_id"]: e for e in best.report_entries()}
    assert {e["view"] for e in planned.values()} == {1, 2}  # each view is the best of some studs

    far_views = {}
    for far, t, cam in zip(("F1", "F2"), views, cameras):  # the matcher's message, read as the sequencer does
        msg = deserialize_message(weld_target_array_cdr(t, int(t.view_index[0]), 1, 0), WeldTargetArray)
        table = weld_target_table(msg, (cam.cx, cam.cy, cam.width, cam.height))
        far_views[far] = (int(msg.view_index), cell_job.table_targets(table, payloads=table.ids))
    studs = {sid: tuple(p) for sid, p in zip(ids, xy)} | {"F1": (xy[:, 0].max() + 0.6, 0.0),
                                                           "F2": (xy[:, 0].max() + 1.2, 0.0)}
    cell = ViewsOfADome(studs, far_views)
    job, state, code, qa = run(cell, tmp_path)
    assert (state, code) == (CellState.DONE, 0), cell.log
    welded = {e["stud_id"]: e for e in json.loads((tmp_path / "weld_report.json").read_text())["targets"]}
    for sid in ids:
        assert welded[sid]["welded"] and welded[sid]["view"] == planned[sid]["view"], sid
        assert welded[sid]["position_m"] == planned[sid]["position_m"], sid
