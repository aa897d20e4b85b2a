"""The weld job along a rail (stud_cell.rail_job.RailJob) over a cell of plain Python whose rail is not
the straight, exact one the cell believes in (scale error, offset, a bend: stud_common.frames.RailDeviation)
and whose arm accepts exactly what the driver's reach test accepts with the base where the carriage is.
The registration node is mimicked honestly: a view registers on the marks truly in its footprint, in the
frame of the carriage position it was taken at; a view with too few marks gets the nearest earlier
registration (extrapolated), whose frame is another carriage position's. So a weld lands on the true stud
only when its target was matched with the registration of the carriage position it is welded at."""
from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from rm65_driver.weld.reach import Reach, ReachConfig
from stud_cell import job as cell_job
from stud_cell.cell_reach import CellReach
from stud_cell.job import JobConfig, MoveRefused
from stud_cell.rail_job import RailJob
from stud_common.frames import RailDeviation, true_world_correction, world_T_base
from stud_common.vocabulary import CellState
from stud_perception.scene import ReferenceMark, girder_scene, surface_height, surface_normal
from test_cell_job import FakeCell

HAND_EYE = np.eye(4)
HAND_EYE[:3, 3] = (0.05, 0.0, -0.10)
SIGNS = (0, 0, -1, 0, -1, 0)
DEVIATION = RailDeviation(scale_ppm=800.0, offset_m=0.003, yaw_urad_per_m=400.0)
MOUNT = (0.0, 0.0, 0.0)
REGISTRATION_STATION = (0.265, -0.30, 0.30)   # over girder_scene's board, beside the girder's start


def reach_for(rail_length_m: float) -> Reach:
    return Reach(ReachConfig(standoff_m=0.06, preferred_joint_signs=SIGNS, hand_eye_T=tuple(HAND_EYE.ravel()),
                             workspace_min_m=(-0.70, -0.70, -0.02), workspace_max_m=(rail_length_m + 0.70, 0.70, 1.10)))


def paired_marks_girder(length_m: float):
    """girder_scene with its reference marks in pairs across the flange (+-0.06 m) every 0.2 m between
    the stud rows: a view of the cell's camera over the flange holds a pair (girder_scene's alternating
    marks, 0.4 m apart on one side, it does not: too few for a registration there)."""
    scene = girder_scene(length_m=length_m)
    x0, y0 = 0.3, 0.0   # girder_scene's start_xy_m
    world = np.array([(x0 + u, y0 + v) for u in np.arange(0.2, length_m - 0.05, 0.2) for v in (-0.06, 0.06)])
    drawing = scene.drawing_to_world.apply_inverse(world)
    marks = tuple(ReferenceMark(f"M{k + 1}", (float(x), float(y))) for k, (x, y) in enumerate(drawing))
    return dataclasses.replace(scene, reference_marks=marks)


def planar(T: np.ndarray) -> np.ndarray:
    """The 3x3 homogeneous 2D part of a 4x4 transform (rotation about z and translation)."""
    return np.array([[T[0, 0], T[0, 1], T[0, 3]], [T[1, 0], T[1, 1], T[1, 3]], [0.0, 0.0, 1.0]])


class RailCell(FakeCell):
    """The girder scene ``scene`` on a rail ``rail_length_m`` long that truly deviates by ``DEVIATION``.
    ``normals``: stud id -> a true normal replacing the scene's."""

    def __init__(self, scene, rail_length_m: float, normals=None, start_m: float = 0.0, marks: bool = True):
        self.scene = scene
        ids = [f"S{k + 1:04d}" for k in range(len(scene.studs_drawing_m))]
        xy = scene.studs_world_xy_m
        super().__init__(dict(zip(ids, map(tuple, xy))))
        z = surface_height(scene, xy[:, 0], xy[:, 1])
        n = np.asarray(surface_normal(scene, xy[:, 0], xy[:, 1])).reshape(-1, 3)
        self.truth = {sid: (np.array([x, y, zz]), nn) for sid, (x, y), zz, nn in zip(ids, xy, z, n)}
        for sid, normal in (normals or {}).items():
            self.truth[sid] = (self.truth[sid][0], np.asarray(normal, float) / np.linalg.norm(normal))
        self.drawing = dict(zip(ids, np.asarray(scene.studs_drawing_m)))
        self.marks_w = {m.label: scene.drawing_to_world.apply(np.array([m.drawing_xy_m]))[0]
                        for m in scene.reference_marks} if marks else {}
        self.board_w = dict(zip("OAB", scene.drawing_to_world.apply(np.asarray(scene.board.marks_drawing_m))))
        yaw = scene.drawing_to_world.yaw_rad
        self.M_true = planar(np.array([[math.cos(yaw), -math.sin(yaw), 0, scene.drawing_to_world.x_m],
                                       [math.sin(yaw), math.cos(yaw), 0, scene.drawing_to_world.y_m],
                                       [0, 0, 1, 0], [0, 0, 0, 1]]))
        self.rail_length_m = rail_length_m
        self.reach = reach_for(rail_length_m)
        self.carriage = start_m
        self.events: list[tuple] = []          # ("rail", c) ("register", c, valid) ("weld", c, ids) in order
        self.registered: list[tuple[np.ndarray, float, np.ndarray]] = []   # (camera true xy, carriage, M)
        self.matcher_M: np.ndarray | None = None   # what the matcher has: the last registration published
        self.weld_errors: dict[str, float] = {}    # stud -> |where the gun truly welded - the true stud| (m)
        self.welded_at: dict[str, float] = {}
        self.unplanned_moves: list[tuple] = []

    def correction(self, c: float) -> np.ndarray:
        return true_world_correction(c, DEVIATION)

    def here(self) -> CellReach:
        return CellReach(self.reach, world_T_base(self.carriage, MOUNT))

    # -- CellPorts --
    def wait_layout(self):
        layout = super().wait_layout()
        refs = {m.label: np.asarray(m.drawing_xy_m) for m in self.scene.reference_marks} if self.marks_w else {}
        return cell_job.Layout(layout.ids, np.array([self.drawing[s] for s in layout.ids]), "girder.dxf",
                               np.asarray(self.scene.board.marks_drawing_m), self.scene.board.mark_diameter_m, refs)

    def rail_position_m(self):
        return self.carriage

    def move_rail(self, position_m):
        assert 0.0 <= position_m <= self.rail_length_m
        self.carriage = float(position_m)
        self.camera = None   # the camera rides on the carriage
        self.events.append(("rail", self.carriage))
        return self.carriage

    def move_camera(self, xyz, yaw):
        if not self.here().camera_ok(xyz, yaw):
            self.unplanned_moves.append((tuple(xyz), self.carriage))
            raise MoveRefused(f"camera move to {np.round(xyz, 3).tolist()} m refused: unreachable")
        super().move_camera(xyz, yaw)

    def _true_camera_xy(self) -> np.ndarray:
        xyz = np.array([*self.camera[0], 1.0])
        return (self.correction(self.carriage) @ xyz)[:2]

    def _half_footprint(self, top_z: float) -> np.ndarray:
        w = 0.46 * (self.camera[0][2] - top_z) / 0.5
        return np.array([w, 0.75 * w]) / 2

    def register(self, attempts=0):
        cam = self._true_camera_xy()
        marks = {**self.board_w, **self.marks_w}   # the board on the table, the reference marks on the part
        seen = [lb for lb, p in marks.items()
                if np.all(np.abs(p - cam) + 0.01 <= self._half_footprint(0.0 if lb in "OAB" else 0.13))]
        board = all(lb in seen for lb in "OAB")
        if len(seen) >= 2 and (board or self.registered):
            M = planar(np.linalg.inv(self.correction(self.carriage))) @ self.M_true   # believed world at this carriage
            self.registered.append((cam, self.carriage, M))
            reg = cell_job.Registration(True, f"{len(seen)} marks", M, 0.0, residual_m=0.0002, residual_max_m=0.0004,
                                        labels_used=tuple(seen))
        elif self.registered:   # the nearest earlier registration, in ITS carriage position's frame
            k = int(np.argmin([np.linalg.norm(c - cam) for c, _cc, _M in self.registered]))
            M, dist = self.registered[k][2], float(np.linalg.norm(self.registered[k][0] - cam))
            reg = cell_job.Registration(True, f"extrapolated {dist:.3f} m", M, 0.0, extrapolated_m=dist)
        else:
            reg = cell_job.Registration(False, "no dark circular marks found", np.eye(3), math.nan)
        self.events.append(("register", self.carriage, reg.valid))
        if reg.valid:
            self.matcher_M = reg.m_local2world
        return reg

    def shoot_view(self, what, xyz, yaw):
        assert self.camera is not None and np.allclose(self.camera[0], xyz), "shot away from the commanded pose"
        if self.matcher_M is None:
            return None
        self._view += 1
        self.shots.append(what)
        cam, half = self._true_camera_xy(), self._half_footprint(0.15)
        C_inv = np.linalg.inv(self.correction(self.carriage))
        targets = []
        for sid, (p, n) in self.truth.items():
            if np.all(np.abs(p[:2] - cam) <= half):
                xy = (self.matcher_M @ np.array([*self.drawing[sid], 1.0]))[:2]
                normal = C_inv[:3, :3] @ n
                targets.append(cell_job.Target(sid, True, "ok", 0.5, {"status": "ok", "position_m": [*xy, float(p[2])],
                                                                      "normal": normal.tolist()}, payload=sid))
        return cell_job.View(self._view, self.shoot(), tuple(xyz), yaw, tuple(targets))

    def weld(self, targets):
        here = self.here()
        for t in targets:
            verdict = here.stud(t.entry["position_m"], t.entry["normal"])
            assert verdict.ok, (f"{t.stud_id} sent with the carriage at {self.carriage}, "
                                f"the driver refuses: {verdict.reason}")
            landed = (self.correction(self.carriage) @ np.array([*t.entry["position_m"], 1.0]))[:3]
            self.weld_errors[t.stud_id] = float(np.linalg.norm(landed - self.truth[t.stud_id][0]))
            self.welded_at[t.stud_id] = self.carriage
        self.events.append(("weld", self.carriage, [t.stud_id for t in targets]))
        return super().weld(targets)

    def inspect(self, station, view, targets, welded_ids, after_ns):
        self.camera = (tuple(view.camera_xyz_w), view.yaw_rad)
        return super().inspect(station, view, targets, welded_ids, after_ns)


def run(cell, tmp_path, **config):
    config = {"registration_station_xyz_m": REGISTRATION_STATION, "rail_length_m": cell.rail_length_m,
              "rail_mount_xyz_m": MOUNT, "fewest_stations": True, **config}
    job = RailJob(cell, JobConfig(report_file=str(tmp_path / "weld_report.json"), qa_dir=str(tmp_path / "qa"),
                                  job_id="J1", part="girder", **config), reach=CellReach(cell.reach))
    state, code = job.run()
    report = json.loads((tmp_path / "weld_report.json").read_text())
    qa = json.loads((tmp_path / "qa" / "qa_report.json").read_text())
    return job, state, report, qa


@pytest.fixture(scope="module")
def girder_run(tmp_path_factory):
    scene = paired_marks_girder(2.4)   # 12 rows of 3 studs
    cell = RailCell(scene, rail_length_m=3.0)
    job, state, report, qa = run(cell, tmp_path_factory.mktemp("girder"))
    return cell, job, state, report, qa


def test_every_stud_of_a_girder_longer_than_the_arm_is_welded_once_on_the_true_stud(girder_run):
    cell, job, state, report, qa = girder_run
    assert state == CellState.DONE, cell.log
    assert sorted(cell.journal) == sorted(cell.studs) and len(cell.journal) == len(set(cell.journal))
    assert not cell.unplanned_moves
    # the rail's error at the far carriage positions is millimetres: had a target been welded with another
    # carriage position's registration, it would show here
    far = max(cell.welded_at.values())
    assert np.linalg.norm(cell.correction(far)[:3, 3] - cell.correction(0.0)[:3, 3]) > 0.002
    assert max(cell.weld_errors.values()) < 1e-6, cell.weld_errors


def test_the_carriage_moves_only_forward_and_each_position_registers_before_its_welds(girder_run):
    cell, job, state, report, qa = girder_run
    rail = [e[1] for e in cell.events if e[0] == "rail"]
    assert rail == sorted(rail) and len(set(rail)) == len(rail) >= 3
    last_rail, registered_here = None, False
    for e in cell.events:
        if e[0] == "rail":
            last_rail, registered_here = e[1], False
        elif e[0] == "register" and e[2] and e[1] == last_rail:
            registered_here = True
        elif e[0] == "weld" and last_rail is not None:
            assert e[1] == last_rail and registered_here, e
    # every stud welded at the carriage position it was matched at: the stops' own
    targets = {t["stud_id"]: t for t in report["targets"]}
    assert all(t["carriage_position_m"] == cell.welded_at[sid] for sid, t in targets.items())
    stops = report["rail"]["stops"]
    assert report["rail"]["moves"] == len(rail) and len(stops) == len(rail)
    assert [s["position_m"] for s in stops] == pytest.approx(rail)
    assert sum(s["welded"] for s in stops) == len(cell.studs)
    for s in stops:
        reg = s["registration"]
        assert reg["valid"] and reg["source"] == "reference marks" and reg["residual_max_m"] == 0.0004
        assert reg["labels_used"] and all(lb.startswith("M") or lb in "OAB" for lb in reg["labels_used"])
    assert qa["job"]["rail"]["moves"] == len(rail)
    assert all(r["carriage_stop"] in range(1, len(stops) + 1) for r in qa["studs"])
    assert f"{len(stops)} carriage position(s), {len(rail)} rail move(s)" in report["message"]


def test_every_target_sent_is_checked_with_the_base_where_the_carriage_stands(girder_run, tmp_path):
    """RailCell.weld asserts the driver's verdict at the carriage's position; a job that checked its
    targets with another carriage position's base would have sent one the driver refuses somewhere along
    the girder: checked here by re-asking every welded target at the position it was welded at and at
    the other stops."""
    cell, job, state, report, qa = girder_run
    positions = sorted({e[1] for e in cell.events if e[0] == "rail"})
    targets = {t["stud_id"]: t for t in report["targets"]}
    refused_elsewhere = 0
    for sid, t in targets.items():
        def reach_from(carriage_m: float):
            return CellReach(cell.reach, world_T_base(carriage_m, MOUNT)).stud(t["position_m"], t["normal"])

        assert reach_from(t["carriage_position_m"]).ok
        refused_elsewhere += sum(not reach_from(c).ok for c in positions if c != t["carriage_position_m"])
    assert refused_elsewhere > 0   # the base matters: the same target is refused from some other stop


def test_a_stud_beyond_the_rails_reach_is_named_before_any_motion_and_the_rest_welded(tmp_path):
    scene = paired_marks_girder(1.2)
    cell = RailCell(scene, rail_length_m=2.0)
    far = f"S{len(cell.studs) + 1:04d}"
    p = np.array([1.0, 1.3, 0.13])   # 1.3 m beside the rail
    cell.studs[far] = tuple(p[:2])
    cell.truth[far] = (p, np.array([0.0, 0.0, 1.0]))
    cell.drawing[far] = scene.drawing_to_world.apply_inverse(p[None, :2])[0]
    job, state, report, qa = run(cell, tmp_path)
    assert state == CellState.DONE, cell.log
    targets = {t["stud_id"]: t for t in report["targets"]}
    assert targets[far]["status"] == "unreachable" and "from any carriage position 0..2 m" in targets[far]["reason"]
    assert sorted(cell.journal) == sorted(set(cell.studs) - {far})
    assert max(cell.weld_errors.values()) < 1e-6


def test_a_stud_its_carriage_position_cannot_weld_is_deferred_to_a_later_one_and_welded_there(tmp_path):
    """A stud leaning 35 deg along the rail, in the first stop's stations: from there the arm cannot weld it
    (the driver's verdict on its target), from the next stop it can: it is welded there, with that stop's
    registration, and nothing the driver would refuse is ever sent (RailCell.weld)."""
    scene = paired_marks_girder(2.4)
    cell = RailCell(scene, rail_length_m=3.0)
    sid = min(cell.truth, key=lambda s: float(np.linalg.norm(cell.truth[s][0][:2] - (0.8, 0.1))))
    tilt = math.radians(35.0)
    cell = RailCell(scene, rail_length_m=3.0, normals={sid: (math.sin(tilt), 0.0, math.cos(tilt))})
    job, state, report, qa = run(cell, tmp_path)
    assert state == CellState.DONE and sorted(cell.journal) == sorted(cell.studs), cell.log
    stops = report["rail"]["stops"]
    planned = next(s for s in stops if sid in s["studs"])
    welded = next(s for s in stops if s["position_m"] == pytest.approx(cell.welded_at[sid]))
    assert welded["index"] > planned["index"] and sid in welded["deferred_in"]
    truth_p, truth_n = cell.truth[sid]
    assert not CellReach(cell.reach, world_T_base(planned["position_m"], MOUNT)).stud(truth_p, truth_n).ok
    assert any(f"{sid}: deferred to carriage position {welded['index']}/" in line for line in cell.log)
    assert cell.weld_errors[sid] < 1e-6 and max(cell.weld_errors.values()) < 1e-6


def test_the_board_is_searched_for_along_the_rail_the_carriage_moving_to_reach_each_view(tmp_path):
    """No registration station; the board lies beside a girder that starts 1.3 m along the rail, out of the
    arm's reach from where the carriage stands: the search's area is given there, the carriage brought to
    where the arm reaches each view, and the job goes on from there."""
    scene = dataclasses.replace(paired_marks_girder(1.0), drawing_to_world=girder_scene(
        length_m=1.0, start_xy_m=(1.6, 0.0)).drawing_to_world)
    cell = RailCell(scene, rail_length_m=2.5)
    board = np.array(list(cell.board_w.values()))
    assert board[:, 0].min() > 1.2 and not cell.here().camera_ok((*board.mean(axis=0), 0.35), 0.0)
    job, state, report, qa = run(cell, tmp_path, registration_station_xyz_m=(),
                                 board_search_area_xy_m=(1.2, -0.6, 1.9, -0.1))
    assert state == CellState.DONE, cell.log
    assert any("marking board found from the camera at" in line for line in cell.log)
    first = next(k for k, e in enumerate(cell.events) if e[0] == "register" and e[2])
    assert cell.events[0][0] == "rail" and cell.events[first][1] > 0.8   # moved before the board was seen
    rail = [e[1] for e in cell.events if e[0] == "rail"]
    assert rail[1:] == sorted(rail[1:]) or rail[1:] == sorted(rail[1:], reverse=True)
    assert sorted(cell.journal) == sorted(cell.studs) and max(cell.weld_errors.values()) < 1e-6
    assert not cell.unplanned_moves


def test_without_reference_marks_a_carriage_position_out_of_the_boards_reach_says_how_far_it_extrapolates(tmp_path):
    """A drawing without reference marks: the board registers the first carriage position; where the arm
    no longer reaches the board the registration carries over, and the report says by how far -- the rail's
    error there is not corrected (the welds land that much off: the cell cannot know better)."""
    cell = RailCell(paired_marks_girder(1.8), rail_length_m=2.5, marks=False)
    job, state, report, qa = run(cell, tmp_path)
    assert state == CellState.DONE, cell.log
    regs = [s["registration"] for s in report["rail"]["stops"]]
    carried = [r for r in regs if r["source"] == "carried over"]
    assert carried and all(r["extrapolated_m"] > 0.3 for r in carried)
    assert any("carries over" in line and "uncorrected" in line for line in cell.log)
    assert all(r["source"] in ("marking board", "carried over", "made at this carriage position") for r in regs)
    for stop in report["rail"]["stops"]:   # on the true studs where registered, off by the rail's error where not
        errors = [cell.weld_errors[sid] for sid, c in cell.welded_at.items() if c == stop["reached_m"]]
        if stop["registration"]["source"] == "carried over":
            # the encoder's scale error alone over the distance carried
            assert errors and min(errors) > 0.5 * DEVIATION.scale_ppm * 1e-6 * stop["registration"]["extrapolated_m"]
        else:
            assert max(errors, default=0.0) < 1e-6, stop


def test_without_a_rail_setting_the_job_refuses_to_be_a_rail_job():
    with pytest.raises(ValueError, match="RailJob needs a rail"):
        RailJob(FakeCell({}), JobConfig(rail_length_m=0.0))
