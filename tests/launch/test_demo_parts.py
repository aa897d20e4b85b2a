"""The bundled girder (issue 35): its drawing and scene agree, they are what tools/make_demo_data.py writes,
the part is the issue's (6 m, 20-40 mm camber, 2-3 deg cross slope, rows of three every 150-250 mm,
reference marks along it, the board beside its start), and the arm on its rail reaches both of its ends;
the demo passes the rail's vars for it and nothing new for the dome."""
from __future__ import annotations

import importlib.util
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from rosproc import REPO
from stud_bringup import demo
from stud_bringup.demo_parts import GIRDER_RAIL_ERROR, PARTS
from stud_perception.scene_file import load_scene, scene_to_dict
from stud_perception.scene_solids import Girder
from stud_planner.drawing import read_layout

GIRDER = PARTS["girder"]
DXF = REPO / "src" / "stud_planner" / GIRDER.drawing
SCENE = REPO / "src" / "stud_perception" / GIRDER.scene


@pytest.fixture(scope="module")
def make_demo_data():
    spec = importlib.util.spec_from_file_location("make_demo_data", REPO / "tools" / "make_demo_data.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["make_demo_data"] = module
    spec.loader.exec_module(module)
    return module


def test_the_girders_drawing_and_scene_name_the_same_studs_and_marks_at_the_same_places():
    layout, scene = read_layout(DXF), load_scene(SCENE)
    assert sorted(s.id for s in layout.studs) == sorted(scene.stud_ids)
    by_id = dict(zip(scene.stud_ids, np.asarray(scene.studs_drawing_m)))
    for stud, xy in zip(layout.studs, layout.studs_xy_m()):
        np.testing.assert_allclose(xy, by_id[stud.id], atol=1e-9)
    np.testing.assert_allclose(layout.marks_xy_m(), scene.board.marks_drawing_m, atol=1e-9)
    assert layout.mark_diameter_m == pytest.approx(scene.board.mark_diameter_m)
    drawn = layout.reference_marks_xy_m()
    assert list(drawn) == list(scene.reference_marks_drawing_m)
    for label, xy in scene.reference_marks_drawing_m.items():
        np.testing.assert_allclose(drawn[label], xy, atol=1e-9)
    assert DXF.stat().st_size < 200_000 and SCENE.stat().st_size < 50_000  # small committed files


def test_the_bundled_girder_is_the_issues_part():
    scene = load_scene(SCENE)
    g = scene.component
    assert isinstance(g, Girder) and g.length_m == pytest.approx(6.0) and g.yaw_rad == 0.0  # along the rail
    assert 0.020 <= g.camber_m <= 0.040 and 2.0 <= math.degrees(g.cross_slope_rad) <= 3.0
    xy = scene.studs_world_xy_m
    assert 90 <= len(xy) <= 300
    rows = np.unique(np.round(xy[:, 0], 6))
    assert all(np.sum(np.isclose(xy[:, 0], x)) == 3 for x in rows)  # rows of three
    assert np.all((np.diff(rows) >= 0.150 - 1e-9) & (np.diff(rows) <= 0.250 + 1e-9))
    assert rows.min() - g.start_xy_m[0] < 0.25 and g.start_xy_m[0] + g.length_m - rows.max() < 0.25  # end to end
    marks = scene.reference_marks_world_m
    centre_y = g.start_xy_m[1]
    assert len(marks) >= 30 and (marks[:, 1] > centre_y).any() and (marks[:, 1] < centre_y).any()
    assert np.all(np.diff(marks[:, 0]) > 0) and marks[:, 0].max() - marks[:, 0].min() > 5.5  # along the whole part
    assert scene.stud_length_m == pytest.approx(0.05)  # M16x50, the cell's stud_length_mm (as the dome's)
    assert np.all(np.asarray(scene.studs_drawing_m) > 0)  # the drawing check's quadrant: no warning at load
    board = scene.marks_world_m
    assert board[:, 0].max() < g.start_xy_m[0]  # the board beside (before) its start, on the table
    assert np.all(board[:, 2] < 0.01)


def test_make_demo_data_writes_the_committed_girder(make_demo_data):
    committed = scene_to_dict(load_scene(SCENE))
    made = scene_to_dict(make_demo_data.girder_demo_scene())
    committed["studs"].pop("ids")
    made["studs"].pop("ids")
    assert json.dumps(made, sort_keys=True) == json.dumps(committed, sort_keys=True)


def test_the_arm_on_its_rail_reaches_both_ends_of_the_girder_with_their_studs(make_demo_data):
    """The first and the last camera station of the cell's plan, each with every stud it sees, from some
    carriage position: the driver's reach test with the base where the carriage puts it."""
    scene = load_scene(SCENE)
    mdd = make_demo_data
    seq = mdd._cell_settings(GIRDER)
    stations = mdd._stations(scene.studs_world_xy_m, seq, scene.board.thickness_m)
    limits = mdd.SafetyLimits(workspace_min_m=tuple(GIRDER.cell_vars["workspace_min_m"]),
                              workspace_max_m=tuple(GIRDER.cell_vars["workspace_max_m"]))
    reach = mdd._checker(limits).reach_for(mdd.STANDOFF_M)
    xy = scene.studs_world_xy_m
    z = mdd.surface_height(scene, xy[:, 0], xy[:, 1])
    n = mdd.surface_normal(scene, xy[:, 0], xy[:, 1])
    ends = (min(stations, key=lambda s: s.camera_xyz_w[0]), max(stations, key=lambda s: s.camera_xyz_w[0]))
    for s in ends:
        studs = [(np.array([*xy[i], z[i]]), n[i]) for i in s.stud_indices]
        assert studs and mdd.carriage_for(reach, GIRDER, np.asarray(s.camera_xyz_w), studs) is not None, s
    # the far end's studs are out of reach from the rail's start: the rail is what welds them
    far = [(np.array([*xy[i], z[i]]), n[i]) for i in ends[1].stud_indices]
    assert not any(reach.stud(p, nn, mdd.world_T_base(0.0, GIRDER.mount_xyz_m)).ok for p, nn in far)
    reg = np.asarray(seq["registration_station_xyz_m"], dtype=np.float64)
    assert mdd.carriage_for(reach, GIRDER, reg, []) is not None


def test_the_demo_rides_the_rail_with_an_error_for_the_girder_and_passes_nothing_new_for_the_dome():
    out = Path("/nonexistent/demo")  # only a name in the command
    girder = demo._cell_command(demo._parse_args(["--part", "girder"]), out)
    text = " ".join(girder)
    assert "rail_length_m=7.0" in text and "rail_mount_xyz_m=[0.0, 0.0, 0.2]" in text
    for name, value in GIRDER_RAIL_ERROR.items():
        assert f"{name}={value!r}" in text and value != 0.0
    assert "--with sensor_bag_record" in text and "arm_time_scale=0.2" in text
    # a user's --var comes last: it wins over the part's
    user = demo._cell_command(demo._parse_args(["--part", "girder", "--var", "true_rail_scale_ppm=0.0"]), out)
    assert user.index("true_rail_scale_ppm=0.0") > user.index("true_rail_scale_ppm=1000.0")
    dome = demo._cell_command(demo._parse_args([]), out)
    assert not any("rail" in a or "sensor_bag" in a or "camera_height" in a for a in dome)
    assert "arm_time_scale=0.25" in dome and demo._parse_args([]).max_z_error_mm is None
