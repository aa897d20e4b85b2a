"""Post-weld inspection: every defect caught with its reason, no clean stud rejected, the lean and the
offset measured to 1 deg / 0.5 mm of the truth on sloped parts, a stud the camera cannot see never
passing, and something standing where no stud was planned reported.

Scenes are rendered with their welded studs (stud_perception.welded_studs), before and after the
welds from the same camera pose, with a structured-light camera's noise, quantisation and holes.
"""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stud_common.rotations import frame_from_normal
from stud_inspection.inspection import InspectionLimits, Verdict, inspect_studs
from stud_perception.scene import SceneSpec, surface_height, surface_normal
from stud_perception.scene_cameras import view_camera
from stud_perception.scene_file import load_scene
from stud_perception.scene_render import render
from stud_perception.scene_solids import Cylinder, Plate, Pose2D
from stud_perception.welded_studs import StudCylinder, WeldDefect, parse_weld_defects, welded_stud
from stud_planner.matching.view_targets import plan_view

CONFIG = Path(__file__).resolve().parents[2] / "src" / "stud_perception" / "config"
LENGTH_M = 0.05  # short studs: the RM-65 holds its camera low, and a 150 mm stud would reach into it


def truth_of(scene):
    xy = scene.studs_world_xy_m
    return np.column_stack([xy, surface_height(scene, xy[:, 0], xy[:, 1])]), surface_normal(scene, xy[:, 0], xy[:, 1])


def job(scene, camera, defects=None, extra=(), seed=0, noise_m=0.0005, holes=0.01, correlation_px=0.0):
    """Plan on the shot before, weld every stud where planned along the planned normal (defects
    applied), shoot after (depth noise correlated over ``correlation_px``); returns (targets, studs
    as welded or None, inspection)."""
    before = render(scene, camera, seed=seed, depth_noise_m=noise_m, hole_fraction=holes,
                    depth_noise_correlation_px=correlation_px)
    t = plan_view(list(scene.stud_ids), np.asarray(scene.studs_drawing_m), scene.M_local2world, before.depth_m,
                  camera)
    assert np.all(t.ok[before.stud_visible]), t.counts()
    defects = defects or {}
    studs = [welded_stud(sid, p, -n, defects.get(sid), length_m=scene.stud_length_m)
             for sid, p, n in zip(scene.stud_ids, t.position_w, t.normal_w)]
    after = render(scene, camera, seed=seed + 1, depth_noise_m=noise_m, hole_fraction=holes,
                   welded=tuple(s for s in studs if s is not None) + tuple(extra),
                   depth_noise_correlation_px=correlation_px)
    limits = InspectionLimits(nominal_length_mm=scene.stud_length_m * 1e3)
    return t, studs, inspect_studs(t.position_w, t.normal_w, t.ok, before.depth_m, after.depth_m, camera, limits)


def over(scene, distance=0.40):
    xy = scene.studs_world_xy_m.mean(axis=0)
    return view_camera((xy[0], xy[1], 0.0), distance + 0.005)


@pytest.mark.parametrize("part", ["dome", "shell"])
def test_each_defect_is_caught_with_its_reason_and_clean_studs_pass(part):
    scene = dataclasses.replace(load_scene(CONFIG / f"{part}_scene.json"), stud_length_m=LENGTH_M)
    ids = scene.stud_ids
    defects = {ids[1]: WeldDefect(lean_deg=8.0, lean_azimuth_deg=30.0), ids[2]: WeldDefect(offset_mm=(4.0, 0.0)),
               ids[3]: WeldDefect(missing=True), ids[4]: WeldDefect(height_mm=LENGTH_M * 1e3 - 12.0)}
    _t, _studs, ins = job(scene, over(scene))
    verdicts = {sid: m for sid, m in zip(ids, ins.studs)}
    _t, _studs, ins = job(scene, over(scene), defects)
    got = dict(zip(ids, ins.studs))
    assert got[ids[1]].verdict is Verdict.FAIL and any("lean" in r for r in got[ids[1]].reasons)
    assert got[ids[2]].verdict is Verdict.FAIL and any("offset" in r for r in got[ids[2]].reasons)
    assert got[ids[3]].verdict is Verdict.MISSING
    assert got[ids[4]].verdict is Verdict.FAIL and any("height" in r for r in got[ids[4]].reasons)
    # zero false accepts, zero false rejects: every other stud passes, with or without the defects nearby
    for sid in ids[5:] + ids[:1]:
        assert got[sid].verdict is Verdict.PASS, (sid, got[sid])
        assert verdicts[sid].verdict is Verdict.PASS, (sid, verdicts[sid])
    assert ins.unexpected == ()


def test_a_clean_job_of_25_studs_on_a_curved_part_has_no_false_reject():
    pose = Pose2D(-0.30, -0.25, 0.0)
    world = np.array([[x, y] for x in np.linspace(-0.07, 0.07, 5) for y in np.linspace(-0.08, 0.08, 5)])
    scene = SceneSpec(component=Cylinder((0.0, 0.0), 0.20, 0.0, 0.25, 0.12), drawing_to_world=pose,
                      studs_drawing_m=tuple(map(tuple, pose.apply_inverse(world))), stud_length_m=LENGTH_M)
    for seed in (0, 2):
        _t, _studs, ins = job(scene, view_camera((0.0, 0.0, 0.0), 0.45), seed=seed)
        assert [m.verdict for m in ins.studs] == [Verdict.PASS] * 25, [(m.verdict.value, m.reasons) for m in ins.studs]


@settings(max_examples=12, deadline=None, derandomize=True)
@given(slope=st.floats(0.0, 30.0), azimuth=st.floats(-180.0, 180.0), lean=st.floats(0.0, 10.0),
       lean_az=st.floats(-180.0, 180.0), dx=st.floats(-5.0, 5.0), dy=st.floats(-5.0, 5.0))
def test_lean_and_offset_are_measured_to_1_deg_and_half_a_mm_on_0_to_30_deg_slopes(slope, azimuth, lean, lean_az,
                                                                                      dx, dy):
    pose = Pose2D(-0.30, -0.25, 0.0)
    scene = SceneSpec(component=Plate((0.0, 0.0), (0.2, 0.2), math.radians(azimuth), 0.08, math.radians(slope)),
                      drawing_to_world=pose, studs_drawing_m=(tuple(pose.apply_inverse(np.zeros((1, 2)))[0]),),
                      stud_length_m=LENGTH_M)
    defect = WeldDefect(lean_deg=lean, lean_azimuth_deg=lean_az, offset_mm=(dx, dy))
    t, studs, ins = job(scene, view_camera((0.0, 0.0, 0.08), 0.35), {scene.stud_ids[0]: defect})
    m, stud = ins.studs[0], studs[0]
    assert m.position_m is not None, m
    n = t.normal_w[0]
    true_lean = math.degrees(math.acos(np.clip(stud.axis_w @ n, -1, 1)))
    true_offset = (stud.base_w - t.position_w[0]) @ frame_from_normal(n)[:, :2] * 1e3
    assert abs(m.lean_deg - true_lean) <= 1.0
    assert np.linalg.norm(np.asarray(m.offset_mm) - true_offset) <= 0.5
    assert abs(m.height_mm - LENGTH_M * 1e3) <= 1.0
    # the verdict follows the limits (5 deg, 2 mm), away from the limits by more than the measurement's error
    if abs(true_lean - 5.0) > 1.0 and abs(np.hypot(*true_offset) - 2.0) > 0.5:
        expect_fail = true_lean > 5.0 or np.hypot(*true_offset) > 2.0
        assert (m.verdict is Verdict.FAIL) == expect_fail, (m, true_lean, true_offset)


def test_a_stud_hidden_behind_another_is_not_inspected_never_passed():
    # seen from a low angle, a 50 mm stud stands between the camera and a short one behind it
    pose = Pose2D(-0.30, -0.25, 0.0)
    world = np.array([[0.0, 0.0], [0.02, 0.0]])
    scene = SceneSpec(component=Plate((0.0, 0.0), (0.2, 0.2), 0.0, 0.05), drawing_to_world=pose,
                      studs_drawing_m=tuple(map(tuple, pose.apply_inverse(world))), stud_length_m=LENGTH_M)
    camera = view_camera((0.01, 0.0, 0.05), 0.35, tilt_rad=math.radians(55.0), tilt_azimuth_rad=math.pi)
    far = scene.stud_ids[1]
    _t, _studs, ins = job(scene, camera, {far: WeldDefect(height_mm=30.0)})
    near_m, far_m = ins.studs
    assert near_m.verdict is Verdict.PASS
    assert far_m.verdict is Verdict.NOT_INSPECTED, far_m
    assert far_m.reasons and ("hidden" in far_m.reasons[0] or "partly seen" in far_m.reasons[0])


def test_something_standing_where_no_stud_was_planned_is_reported():
    scene = dataclasses.replace(load_scene(CONFIG / "dome_scene.json"), stud_length_m=LENGTH_M)
    centre = scene.component.centre_xy_m
    xy = np.array([centre[0] - 0.03, centre[1] + 0.03])  # between the apex and the ring, no stud planned
    z = float(surface_height(scene, xy[:1], xy[1:])[0])
    n = surface_normal(scene, xy[:1], xy[1:]).reshape(3)
    stray = StudCylinder("stray", np.array([xy[0], xy[1], z]), n, 0.04, 0.006)
    _t, _studs, ins = job(scene, over(scene), extra=(stray,))
    assert all(m.verdict is Verdict.PASS for m in ins.studs)
    assert len(ins.unexpected) == 1
    obj = ins.unexpected[0]
    assert np.linalg.norm(np.asarray(obj.position_m)[:2] - xy) < 0.015 and 30.0 < obj.height_mm < 50.0


def test_not_welded_studs_are_reported_as_such():
    scene = dataclasses.replace(load_scene(CONFIG / "dome_scene.json"), stud_length_m=LENGTH_M)
    camera = over(scene)
    before = render(scene, camera, seed=0, depth_noise_m=0.0005)
    P, N = truth_of(scene)
    ins = inspect_studs(P, N, np.zeros(len(P), bool), before.depth_m, before.depth_m, camera)
    assert [m.verdict for m in ins.studs] == [Verdict.NOT_WELDED] * len(P) and ins.unexpected == ()


@pytest.mark.parametrize("bad, match", [
    ({"S9999": {"missing": True}}, "not a stud of the scene"),
    ({"S0001": {"lean_deg": "8"}}, r"lean_deg='8': expected a finite number"),
    ({"S0001": {"lean_deg": 80.0}}, r"expected a number in \[0.0, 60.0\]"),
    ({"S0001": {"offset_mm": [1.0]}}, "expected two numbers"),
    ({"S0001": {"missing": "yes"}}, "expected true or false"),
    ({"S0001": {"tilt": 3}}, r"unknown field\(s\) \['tilt'\]"),
    ([1, 2], "must be a mapping"),
])
def test_weld_defects_are_validated_with_errors_naming_stud_and_field(bad, match):
    from stud_perception.welded_studs import WeldDefectError

    with pytest.raises(WeldDefectError, match=match):
        parse_weld_defects(bad, ("S0001", "S0002"))


@pytest.mark.parametrize("part", ["dome", "shell"])
def test_correlated_depth_noise_leaves_the_lean_and_the_base_measured_to_a_fraction_of_the_limits(part):
    """A real camera's depth noise is correlated over a few pixels. The cap alone (a 16 mm disc) then
    tilts the measured axis by up to 2 deg, and the base, a stud length down that axis, moves by up
    to 1.8 mm: against a 2 mm tolerance, a false reject waiting to happen. With the side fitted too,
    clean studs stay well inside both limits and a 4 mm offset is measured as 4 mm."""
    scene = dataclasses.replace(load_scene(CONFIG / f"{part}_scene.json"), stud_length_m=LENGTH_M)
    ids = scene.stud_ids
    offsets, leans = [], []
    for seed in (0, 2, 4):
        _t, _studs, ins = job(scene, over(scene), {ids[2]: WeldDefect(offset_mm=(4.0, 0.0))}, seed=seed,
                              correlation_px=1.5)
        got = dict(zip(ids, ins.studs))
        assert got[ids[2]].verdict is Verdict.FAIL
        assert abs(float(np.hypot(*got[ids[2]].offset_mm)) - 4.0) <= 0.5
        for sid in ids[:2] + ids[3:]:
            assert got[sid].verdict is Verdict.PASS, (sid, got[sid])
            offsets.append(float(np.hypot(*got[sid].offset_mm)))
            leans.append(got[sid].lean_deg)
    assert max(offsets) <= 0.75 and max(leans) <= 1.0, (max(offsets), max(leans))
