"""The weld collar (flash): the sim renders it (height, width, coverage, the gap where the defect says),
the inspection measures it per pixel between the shots before and after -- a gap caught on whatever
side it is, a collar too low caught, a collar the camera cannot see enough of never passed -- and the
scene's defects reach the studs welded where the scene's studs are, whatever either calls them."""
from __future__ import annotations

import math

import numpy as np
import pytest

from stud_common.rotations import frame_from_normal
from stud_inspection.inspection import InspectionLimits, Verdict, inspect_studs
from stud_perception.scene_file import scene_from_dict, scene_to_dict
from stud_perception.scene_solids import SceneError
from stud_perception.welded_studs import DefectsByPosition, StudCollar, WeldDefect, welded_stud
from welded_views import bundled, over, weld_and_shoot, with_defects

LIMITS = InspectionLimits(nominal_length_mm=50.0)


def _inspect(shots, limits=LIMITS):
    return inspect_studs(shots.planned_w, shots.normals_w, shots.ok, shots.before_m, shots.after_m, shots.camera,
                         limits).studs


def test_a_collar_is_a_ring_of_its_height_and_width_with_its_gap_where_asked():
    up = np.array([0.0, 0.0, 1.0])
    c = StudCollar(np.zeros(3), up, 0.008, 0.003, 0.004, coverage_deg=250.0, gap_azimuth_deg=90.0)
    o = np.array([0.0, 0.0, 0.3])
    for az_deg, rho, hit in ((0.0, 0.0095, True), (180.0, 0.0095, True), (90.0, 0.0095, False),
                             (90.0 + 60.0, 0.0095, True), (90.0 + 50.0, 0.0095, False), (0.0, 0.012, False),
                             (0.0, 0.007, False)):
        x, y = rho * math.cos(math.radians(az_deg)), rho * math.sin(math.radians(az_deg))
        d = np.array([x, y, -0.3])
        d /= np.linalg.norm(d)
        t, wall = c.intersect(o, *(np.array([v]) for v in d))
        assert np.isfinite(t[0]) == hit, (az_deg, rho)
        if hit:
            assert abs((o + t[0] * d)[2] - 0.004) < 1e-9 and not wall[0]  # the flat top, 4 mm up
    # seen from aside, the outer wall
    t, wall = c.intersect(np.array([0.3, 0.0, 0.002]), np.array([-1.0]), np.array([0.0]), np.array([0.0]))
    assert abs(t[0] - (0.3 - 0.011)) < 1e-9 and wall[0]


def _gap_sectors_seen(collar, gap_az_deg: float, margin_deg: float = 10.0) -> int:
    """How many of the sectors the collar measurement saw lie inside the true gap (by ``margin_deg``)."""
    k = len(collar.sector_heights_mm)
    centres = (np.arange(k) + 0.5) * 360.0 / k - 180.0
    inside = np.abs((centres - gap_az_deg + 180.0) % 360.0 - 180.0) <= 55.0 - margin_deg
    return int(np.sum(inside & np.isfinite(collar.sector_heights_mm)))


@pytest.mark.parametrize("part", ["dome", "shell"])
def test_a_one_sided_collar_is_caught_whenever_its_gap_is_in_view(part):
    """The camera cannot see the collar behind a stud it sees from aside (100-130 deg of it on the bundled
    parts' slopes): a 110 deg gap wholly behind the stud is not seen, and the record says how much of each
    collar was (collar_seen_deg). Whenever 20 deg of the gap are in view, the stud fails for its collar."""
    scene = bundled(part)
    ids = list(scene.stud_ids)
    in_view = 0
    for az in (0.0, 60.0, 180.0, -120.0):
        defects = {sid: WeldDefect(collar_coverage_deg=250.0, collar_gap_azimuth_deg=az) for sid in ids}
        for sid, m in zip(ids, _inspect(weld_and_shoot(with_defects(scene, defects), over(scene), ids, seed=2))):
            c = m.collar
            assert c.seen_deg >= 230.0 and c.covered_deg <= 260.0, (az, sid, c)  # never more than is there
            if _gap_sectors_seen(c, az) >= 2:
                in_view += 1
                assert m.verdict is Verdict.FAIL and "collar" in m.reasons[0], (az, sid, m)
            elif m.verdict is Verdict.PASS:
                assert c.seen_deg <= 360.0 - 80.0, (az, sid, c)  # passed only with the gap out of view
    assert in_view >= 3 * len(ids)  # most gaps show: the check is not vacuous


def test_the_collar_is_measured_around_a_stud_seen_along_its_axis_and_its_gap_located():
    scene = bundled("dome")
    ids = list(scene.stud_ids)
    apex = ids[0]  # S0005 on the dome's top: the camera looks down its axis
    shots = weld_and_shoot(with_defects(scene, {apex: WeldDefect(collar_coverage_deg=250.0,
                                                                 collar_gap_azimuth_deg=60.0)}), over(scene), ids)
    m = _inspect(shots)[0]
    c = m.collar
    assert c.seen_deg >= 340.0 and abs(c.covered_deg - 250.0) <= 20.0 and abs(c.gap_deg - 110.0) <= 20.0, c
    assert abs((c.gap_azimuth_deg - 60.0 + 180.0) % 360.0 - 180.0) <= 15.0, c
    assert abs(c.height_mm - 4.0) < 0.6 and m.verdict is Verdict.FAIL


def test_a_collar_too_low_is_caught_and_a_collar_seen_too_little_is_never_passed():
    scene = bundled("shell")
    ids = list(scene.stud_ids)
    shots = weld_and_shoot(with_defects(scene, {ids[2]: WeldDefect(collar_height_mm=0.5)}), over(scene), ids)
    got = dict(zip(ids, _inspect(shots)))
    # (a 0.5 mm collar reads 1 mm here and there: the depth's millimetre steps and its noise; it fails either way)
    assert got[ids[2]].verdict is Verdict.FAIL and "collar" in got[ids[2]].reasons[0], got[ids[2]]
    assert got[ids[2]].collar.covered_deg <= 0.5 * got[ids[2]].collar.seen_deg
    assert all(got[s].verdict is Verdict.PASS for s in ids if s != ids[2])
    # the shell's studs are seen from aside: about 250 deg of each collar is in view. Asking for more before
    # judging it leaves them not inspected -- with the reason -- never passed
    strict = InspectionLimits(nominal_length_mm=50.0, min_collar_seen_deg=300.0)
    for sid, m in zip(ids, _inspect(shots, strict)):
        if sid != ids[2]:
            assert m.verdict is Verdict.NOT_INSPECTED and m.reasons[0].startswith("collar: only"), (sid, m)
            assert m.lean_deg is not None  # what was measured is still reported
    # no collar check asked: the collar is not measured, the studs pass on the rest
    off = InspectionLimits(nominal_length_mm=50.0, min_collar_coverage_deg=0.0)
    got = dict(zip(ids, _inspect(shots, off)))
    assert got[ids[2]].verdict is Verdict.PASS and got[ids[2]].collar is None


def test_a_welded_stud_stands_in_its_collar_and_a_missing_one_leaves_none():
    n = np.array([0.0, math.sin(math.radians(20.0)), math.cos(math.radians(20.0))])
    s = welded_stud("S1", np.zeros(3), -n, WeldDefect(lean_deg=8.0, offset_mm=(3.0, 0.0)), length_m=0.05)
    assert s.collar is not None and np.allclose(s.collar.up_w, n) and np.allclose(s.collar.centre_w, s.base_w)
    assert np.allclose(s.base_w, 3e-3 * frame_from_normal(n)[:, 0])
    assert welded_stud("S1", np.zeros(3), -n, WeldDefect(missing=True)) is None
    assert welded_stud("S1", np.zeros(3), -n, collar_height_m=0.0).collar is None


def test_defects_are_attached_by_position_and_a_defect_never_welded_is_named():
    xy = np.array([[0.0, 0.0], [0.05, 0.0], [0.10, 0.0]])
    m = DefectsByPosition(xy, ("a", "b", "c"), {"b": WeldDefect(missing=True), "c": WeldDefect(lean_deg=9.0)})
    assert m.reach_m == pytest.approx(0.025)
    assert m.nearest([0.051, 0.002, 0.03]) == ("b", pytest.approx(math.hypot(0.001, 0.002)))
    assert m.nearest([0.075, 0.03, 0.0])[0] is None  # beside the row: nearer no stud than half their spacing
    assert m.never_welded(["a", "b"]) == ["c"] and m.never_welded(["c", "b"]) == []
    assert WeldDefect(lean_deg=9.0, collar_coverage_deg=250.0).kinds() == ["lean 9 deg", "collar 250 deg"]


def test_a_scene_file_carries_its_collars_and_collar_defects_validated():
    d = scene_to_dict(bundled("dome"))
    assert (d["collar_height_mm"], d["collar_width_mm"]) == (4.0, 3.0)
    d.update(collar_height_mm=5.0, collar_width_mm=2.5)
    sid = d["studs"]["ids"][0]
    d["weld_defects"] = {sid: {"collar_coverage_deg": 250.0, "collar_gap_azimuth_deg": 45.0}}
    scene = scene_from_dict(d)
    assert (scene.collar_height_m, scene.collar_width_m) == (0.005, 0.0025)
    assert scene.weld_defects[sid] == WeldDefect(collar_coverage_deg=250.0, collar_gap_azimuth_deg=45.0)
    assert scene_to_dict(scene)["weld_defects"][sid] == {"collar_coverage_deg": 250.0, "collar_gap_azimuth_deg": 45.0}
    d["weld_defects"] = {sid: {"collar_coverage_deg": 400.0}}
    with pytest.raises(SceneError, match=rf"weld_defects\['{sid}'\].collar_coverage_deg=400.0"):
        scene_from_dict(d)
    d["weld_defects"] = {}
    d["collar_height_mm"] = 80.0
    with pytest.raises(SceneError, match="collar_height_mm=80"):
        scene_from_dict(d)
