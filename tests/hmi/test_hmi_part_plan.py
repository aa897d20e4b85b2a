"""The plan of the part without ROS (stud_hmi.part_plan): each stud's state from the stud table, its
place from a registration, the view that fits a 6 m girder and a 0.3 m dome, the rail and the
carriage, the station being worked and the unreachable studs with their reasons."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from stud_common.vocabulary import CellState
from stud_hmi.model import StudTable, TargetInfo
from stud_hmi.part_plan import (
    MIN_MARKER_PX,
    NO_REASON,
    PartPlan,
    PlanState,
    RailConfig,
    StationInfo,
    fit_view,
    footprint_corners,
    in_footprint,
    plan_state,
)
from stud_hmi.server import to_json

NAN = math.nan


def target(sid, status="ok", xy=(NAN, NAN), view=0):
    code = {"ok": 0, "out_of_view": 1, "no_depth": 2, "normal_uncertain": 4, "unreachable": 5}[status]
    return TargetInfo(sid, status, code, (xy[0], xy[1], 0.1), NAN, 2.0, view)


def studs_of(msg) -> dict:
    return {s["stud_id"]: s for s in msg["studs"]}


def rotation(deg: float, t=(0.0, 0.0)) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, -s, t[0]], [s, c, t[1]], [0.0, 0.0, 1.0]])


# -- states ----------------------------------------------------------------------------------------------
def test_each_stud_takes_the_state_of_what_is_known_last_of_it():
    ids = [f"S{i}" for i in range(1, 12)]
    table = StudTable()
    table.set_layout(ids)
    table.update_view([target("S2", "ok"), target("S3", "no_depth"), target("S4", "normal_uncertain"),
                       target("S5", "out_of_view"), target("S6", "ok"), target("S7", "ok"), target("S8", "ok"),
                       target("S9", "ok"), target("S10", "unreachable"), target("S11", "ok")], view=0)
    table.job_result(welded=["S6", "S8", "S9"], skipped=["S11"], failed=["S7"])
    table.arm_progress("S2")                              # the arm is on S2 now
    table.inspected("S8", "pass")
    table.inspected("S9", "fail", ["lean 8.0 deg > 5.0"])
    rows = {r["stud_id"]: r for r in table.rows()}
    planned = {sid: plan_state(rows[sid], planned=True).value for sid in ids}
    assert planned == {"S1": "planned", "S2": "welding", "S3": "uncertain", "S4": "uncertain", "S5": "planned",
                       "S6": "welded", "S7": "failed", "S8": "qa_pass", "S9": "qa_fail", "S10": "unreachable",
                       "S11": "failed"}
    # before the job plans: not seen; the cell naming a stud unreachable; the journal's uncertain stud
    assert plan_state(rows["S1"]) == PlanState.NOT_SEEN and plan_state(rows["S5"]) == PlanState.NOT_SEEN
    assert plan_state(rows["S1"], planned=True, unreachable=True) == PlanState.UNREACHABLE
    assert plan_state(rows["S7"], journal_uncertain=True) == PlanState.UNCERTAIN
    # the operator accepting a failed stud, or a rework decision
    table.rework_decided("S9", "accept")
    assert plan_state({r["stud_id"]: r for r in table.rows()}["S9"]) == PlanState.QA_PASS


def test_the_legend_counts_every_state_in_one_order_and_a_new_weld_changes_one_count():
    plan = PartPlan()
    table = StudTable()
    ids = ["A", "B", "C"]
    plan.set_layout(ids, [(0.0, 0.0), (0.1, 0.0), (0.2, 0.0)])
    table.set_layout(ids)
    table.update_view([target("A"), target("B")])
    legend = {s["state"]: s["count"] for s in plan.message(table.rows())["states"]}
    assert list(legend) == [s.value for s in PlanState]
    assert legend["ok"] == 2 and legend["not_seen"] == 1 and sum(legend.values()) == 3
    table.job_result(welded=["A"], skipped=[], failed=[])
    legend = {s["state"]: s["count"] for s in plan.message(table.rows())["states"]}
    assert (legend["ok"], legend["welded"]) == (1, 1)
    assert [s.label for s in (PlanState.QA_PASS, PlanState.NOT_SEEN)] == ["QA pass", "not seen"]


# -- places --------------------------------------------------------------------------------------------
def test_studs_are_in_drawing_coordinates_until_a_valid_registration_puts_them_in_world():
    drawing = np.array([[0.0, 0.0], [0.5, 0.0], [0.5, 0.2]])
    plan = PartPlan()
    plan.set_layout(["S1", "S2", "S3"], drawing, [0.019] * 3, marks=[("O", (0.0, -0.1)), ("A", (0.6, -0.1))],
                    mark_diameter_m=0.03)
    msg = plan.message()
    assert msg["frame"] == "drawing" and msg["registered"] is False
    assert [s["xy_m"] for s in msg["studs"]] == drawing.tolist()
    assert msg["bounds_m"] == [0.0, -0.1, 0.6, 0.2]  # studs and marks: the part
    plan.set_registration(False, np.eye(3), "marks not found")
    assert plan.message()["frame"] == "drawing"

    M = rotation(30.0, (2.0, 0.5))  # the part 2 m along the rail, turned 30 deg
    plan.set_registration(True, M, "residual 0.2 mm")
    msg = plan.message()
    c, s = math.cos(math.radians(30.0)), math.sin(math.radians(30.0))
    expected = [[2.0 + c * x - s * y, 0.5 + s * x + c * y] for x, y in drawing]
    assert msg["frame"] == "world" and msg["registration"] == "residual 0.2 mm"
    assert np.allclose([st["xy_m"] for st in msg["studs"]], expected, atol=1e-5)
    assert np.allclose(msg["marks"][1]["xy_m"], [2.0 + c * 0.6 + s * 0.1, 0.5 + s * 0.6 - c * 0.1], atol=1e-5)
    # a later invalid registration keeps the part where it was
    plan.set_registration(False, np.eye(3), "board not seen")
    assert np.allclose([st["xy_m"] for st in plan.message()["studs"]], expected, atol=1e-5)

    # a stud a view matched is drawn where it was measured
    table = StudTable()
    table.set_layout(["S1", "S2", "S3"])
    table.update_view([target("S2", "ok", xy=(2.4337, 0.7512))])
    assert studs_of(plan.message(table.rows()))["S2"]["xy_m"] == [2.4337, 0.7512]
    assert np.allclose(studs_of(plan.message(table.rows()))["S3"]["xy_m"], expected[2], atol=1e-5)


def test_another_drawing_forgets_the_registration_but_a_first_drawing_after_it_keeps_it():
    plan = PartPlan()
    plan.set_registration(True, rotation(0.0, (1.0, 0.0)))
    plan.set_layout(["S1"], [(0.1, 0.0)])  # the latched layout arrived after the latched registration
    assert plan.message()["frame"] == "world" and plan.message()["studs"][0]["xy_m"] == [1.1, 0.0]
    plan.set_layout(["S1"], [(0.1, 0.0)])  # the same drawing again
    assert plan.registered
    plan.set_layout(["T1", "T2"], [(0.0, 0.0), (0.3, 0.0)])
    assert plan.message()["frame"] == "drawing" and plan.layout_revision == 3


def girder(rows=100, pitch_m=0.06, across_m=0.1) -> np.ndarray:
    """300 studs: three per row across a 6 m flange (a few hundred, as a bridge girder's)."""
    return np.array([[0.2 + i * pitch_m, 0.05 + j * across_m] for i in range(rows) for j in range(3)])


def dome(n=12, radius_m=0.12) -> np.ndarray:
    a = np.linspace(0.0, 2 * math.pi, n, endpoint=False)
    return np.vstack([[[0.0, 0.0]], np.c_[radius_m * np.cos(a), radius_m * np.sin(a)]])


@pytest.mark.parametrize("width_px,height_px", [(1200, 420), (800, 600)])
def test_the_fitted_view_shows_all_of_a_6_m_girder_readably_and_lets_a_dome_fill_it(width_px, height_px):
    margin = 24.0
    for xy, name in ((girder(), "girder"), (dome(), "dome")):
        plan = PartPlan(RailConfig(length_m=8.0, mount_xyz_m=(0.0, -0.4, 0.1)))
        plan.set_layout([f"S{i}" for i in range(len(xy))], xy, [0.019] * len(xy))
        plan.set_registration(True, rotation(0.0, (0.5, 0.0)))
        plan.on_arm(3.0, False)
        msg = plan.message()
        (cx, cy), scale = fit_view(msg["bounds_m"], width_px, height_px, margin)
        px = (np.array([s["xy_m"] for s in msg["studs"]]) - (cx, cy)) * scale + (width_px / 2, height_px / 2)
        assert px[:, 0].min() >= margin - 1e-6 and px[:, 0].max() <= width_px - margin + 1e-6, name
        assert px[:, 1].min() >= margin - 1e-6 and px[:, 1].max() <= height_px - margin + 1e-6, name
        span = px.max(axis=0) - px.min(axis=0)
        fills = max(span[0] / (width_px - 2 * margin), span[1] / (height_px - 2 * margin))
        assert fills == pytest.approx(1.0), name  # the part, not the 8 m rail, sets the view
        d = np.linalg.norm(px[:, None] - px[None, :], axis=2) + np.eye(len(px)) * 1e9
        if name == "girder":
            # all 6 m in view, every stud's marker clear of its neighbours' (zoom in to read more)
            assert len(xy) == 300 and d.min() > 2 * MIN_MARKER_PX + 1.0
        else:
            assert 0.019 * scale >= 20.0 and d.min() >= 40.0  # a stud is a disc, not a dot


def test_a_single_stud_does_not_zoom_without_bound():
    (cx, cy), scale = fit_view([1.0, 2.0, 1.0, 2.0], 1000, 500, margin_px=0.0, min_extent_m=0.05)
    assert (cx, cy, scale) == (1.0, 2.0, 10000.0)


# -- rail and carriage ----------------------------------------------------------------------------------
def test_without_a_rail_nothing_of_it_is_drawn():
    plan = PartPlan()
    plan.set_layout(["S1"], [(0.1, 0.1)])
    plan.on_arm(0.0, False)
    msg = plan.message()
    assert msg["rail"] is None and msg["carriage"] is None and plan.carriage() is None


def test_the_rail_and_the_carriage_with_the_arms_reach_around_its_base():
    plan = PartPlan(RailConfig(length_m=6.0, mount_xyz_m=(0.1, -0.35, 0.2), reach_m=0.61))
    assert plan.message()["rail"] == {"length_m": 6.0, "extent_m": [0.0, 6.0], "mount_xyz_m": [0.1, -0.35, 0.2],
                                      "reach_m": 0.61}
    assert plan.carriage() is None  # no /arm/state yet
    plan.on_arm(2.5, True)
    assert plan.carriage() == {"position_m": 2.5, "moving": True, "base_xy_m": [2.6, -0.35], "reach_m": 0.61}
    plan.changed = False
    plan.on_arm(2.75, False)
    assert plan.carriage()["position_m"] == 2.75 and not plan.changed  # the carriage travels with /arm/state


def test_a_rail_no_parameter_names_appears_once_the_carriage_is_seen_off_zero():
    plan = PartPlan()
    plan.set_layout(["S1", "S2"], [(0.0, 0.0), (0.4, 0.0)])
    plan.set_registration(True, rotation(0.0, (3.0, 0.0)))
    plan.on_arm(0.0, False)
    assert plan.message()["rail"] is None
    plan.changed = False
    plan.on_arm(1.2, True)
    assert plan.changed
    rail = plan.message()["rail"]
    assert rail["length_m"] is None and rail["extent_m"] == [0.0, 3.4]  # to the part's far end
    assert plan.carriage()["base_xy_m"] == [1.2, 0.0]


# -- station and unreachable ------------------------------------------------------------------------------
def test_footprint_corners_and_membership_follow_the_image_yaw():
    corners = footprint_corners((1.0, 0.0), math.radians(90.0), (0.4, 0.2))
    assert np.allclose(sorted(map(tuple, np.round(corners, 9))), [(0.9, -0.2), (0.9, 0.2), (1.1, -0.2), (1.1, 0.2)])
    inside = in_footprint(np.array([[1.0, 0.19], [1.09, 0.0], [1.15, 0.0], [1.0, 0.25]]), (1.0, 0.0),
                          math.radians(90.0), (0.4, 0.2))
    assert inside.tolist() == [True, True, False, False]


def test_the_station_being_worked_shows_its_footprint_and_the_studs_in_it():
    plan = PartPlan()
    xy = girder(rows=20)
    ids = [f"S{i}" for i in range(len(xy))]
    plan.set_layout(ids, xy)
    welding = StationInfo(int(CellState.WELDING), station=2, stations_total=5, camera_xyz_m=(0.5, 0.15, 0.5),
                          camera_yaw_rad=0.0, camera_footprint_m=(0.3, 0.25))
    plan.on_cell(welding)
    assert plan.message()["station"] is None  # the camera is in world: not over a plan in drawing coordinates
    plan.set_registration(True, np.eye(3))
    st = plan.message()["station"]
    assert (st["index"], st["total"], st["camera_xyz_m"], st["footprint_m"]) == (2, 5, [0.5, 0.15, 0.5], [0.3, 0.25])
    expected = [sid for sid, (x, y) in zip(ids, xy) if abs(x - 0.5) <= 0.15 and abs(y - 0.15) <= 0.125]
    assert st["stud_ids"] == expected and len(expected) == 15
    plan.on_cell(StationInfo(int(CellState.DONE), station=5, stations_total=5, camera_xyz_m=(0.5, 0.15, 0.5)))
    assert plan.message()["station"] is None
    plan.on_cell(StationInfo(int(CellState.MOVING), station=3, stations_total=5))  # a sequencer that does not say
    assert plan.message()["station"] is None


def test_unreachable_studs_are_listed_with_the_cells_reasons_until_welded_after_all():
    plan = PartPlan()
    ids = ["S1", "S2", "S3", "S4"]
    plan.set_layout(ids, [(0.0, 0.0), (0.1, 0.0), (0.2, 0.0), (0.3, 0.0)])
    table = StudTable()
    table.set_layout(ids)
    why = "unreachable: approach pose 0.66 m from the base, beyond the arm's 0.61 m"
    plan.on_cell(StationInfo(int(CellState.WELDING), 1, 2, unreachable=("S3", "S1"),
                             unreachable_reasons=(why, "unreachable: no camera station the arm reaches covers it")))
    table.update_view([target("S4", "unreachable", view=3)])
    msg = plan.message(table.rows())
    assert msg["unreachable"] == [
        {"stud_id": "S1", "reason": "unreachable: no camera station the arm reaches covers it"},
        {"stud_id": "S3", "reason": why},
        {"stud_id": "S4", "reason": "unreachable: its target (view 3) is out of the arm's reach"}]
    s3 = studs_of(msg)["S3"]
    assert s3["state"] == "unreachable" and s3["detail"].startswith("unreachable · " + why)
    assert studs_of(msg)["S2"]["state"] == "planned"
    table.job_result(welded=["S3"], skipped=[], failed=[])
    assert [u["stud_id"] for u in plan.message(table.rows())["unreachable"]] == ["S1", "S4"]
    # an older sequencer: ids without reasons
    plan.on_cell(StationInfo(int(CellState.WELDING), 1, 2, unreachable=("S2",)))
    assert plan.message(table.rows())["unreachable"][0] == {"stud_id": "S2", "reason": NO_REASON}


def test_the_plan_message_is_strict_json_with_a_stud_unmatched():
    plan = PartPlan(RailConfig(length_m=6.0))
    plan.set_layout(["S1", "S2"], [(0.0, 0.0), (0.1, 0.0)])
    plan.set_registration(True, np.eye(3))
    table = StudTable()
    table.set_layout(["S1", "S2"])
    table.update_view([target("S1", "no_depth")])
    plan.on_arm(1.0, False, uncertain=("S2",))
    msg = json.loads(to_json(plan.message(table.rows())))
    s = studs_of(msg)
    assert s["S1"]["xy_m"] == [0.0, 0.0] and s["S1"]["state"] == "uncertain"
    assert "target no depth (view 0)" in s["S1"]["detail"] and "x 0.0, y 0.0 mm (world)" in s["S1"]["detail"]
    assert s["S2"]["state"] == "uncertain" and "never confirmed" in s["S2"]["detail"]
    assert msg["carriage"]["position_m"] == 1.0
