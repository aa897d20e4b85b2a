"""The weld-target table and the best-view rule: `plan`'s report keeps its schema (the keys, their
order and their types, docs/INTERFACES.md), a stud keeps the view whose target is usable with the
smallest lean bound whatever order the views come in, and the tie-breaks are the documented ones."""
from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

from stud_common.vocabulary import TargetStatus
from stud_perception.scene import demo_dome_scene
from stud_perception.scene_cameras import view_camera
from stud_perception.scene_render import render
from stud_planner.matching.target_table import BestViewKey, TargetTable, choose_best
from stud_planner.matching.view_targets import PlannerConfig, plan_view

REPO = Path(__file__).resolve().parents[2]
#: The report's keys, in their order (docs/INTERFACES.md): the file's, and each target's. Fields are only ever
#: added at the end (view_stamps_ns: each view's stamp, for replay); a drawing with reference marks adds
#: "registrations" after them.
REPORT_KEYS = ["drawing", "bag", "algorithm", "registration", "views", "total_iterations", "match_time_s", "targets",
               "warnings", "view_stamps_ns"]
TARGET_KEYS = ["stud_id", "drawing_xy_mm", "status", "position_m", "normal", "pixel", "view", "iterations",
               "xy_error_mm", "inclination_deg", "normal_sigma_deg", "lean_bound_deg", "fill_ratio", "gun_clearance_mm"]


def _is_number_list(value, n: int) -> bool:
    return isinstance(value, list) and len(value) == n and all(isinstance(v, float) or v is None for v in value)


def test_plan_on_the_committed_bag_keeps_the_reports_schema():
    from stud_planner.offline_plan import plan

    report = plan(REPO / "src/stud_planner/data/dome_demo.dxf", REPO / "bags/dome_demo")
    assert list(report) == REPORT_KEYS
    assert list(report["registration"]) == ["M_local2world", "residual_mm", "view"]
    assert len(report["targets"]) == 9
    for t in report["targets"]:
        assert list(t) == TARGET_KEYS, t  # all usable: no reason
        assert isinstance(t["stud_id"], str) and t["status"] == "ok"
        assert _is_number_list(t["drawing_xy_mm"], 2) and _is_number_list(t["position_m"], 3)
        assert _is_number_list(t["normal"], 3) and _is_number_list(t["pixel"], 2)
        assert isinstance(t["view"], int) and isinstance(t["iterations"], int)
        assert all(isinstance(t[k], float) for k in TARGET_KEYS[8:])


@pytest.fixture(scope="module")
def five_views():
    """The dome from five cameras that overlap, miss studs and fail some (the lean budget is set
    where some usable targets of one view are uncertain on another)."""
    scene = demo_dome_scene()
    ids, xy = list(scene.stud_ids), np.asarray(scene.studs_drawing_m)
    apex = np.append(scene.studs_world_xy_m.mean(axis=0), 0.1)
    views = []
    for k, (dx, dy, tilt, az) in enumerate(((0.0, 0.0, 0.0, 0.0), (0.12, 0.0, 0.0, 0.0), (-0.05, 0.08, 0.35, 1.0),
                                            (0.2, -0.1, 0.0, 0.0), (0.0, 0.0, 0.2, 3.0))):
        cam = view_camera(apex + (dx, dy, 0.0), 0.5, tilt_rad=tilt, tilt_azimuth_rad=az, width=640, height=480)
        view = render(scene, cam, seed=k, depth_noise_m=0.0005 * (1 + 2 * (k % 2)), hole_fraction=0.02)
        views.append(plan_view(ids, xy, scene.M_local2world, view.depth_m, cam, PlannerConfig(lean_budget_deg=1.3),
                               view_index=k))
    statuses = {int(s) for t in views for s in t.status}
    assert {TargetStatus.OK, TargetStatus.OUT_OF_VIEW, TargetStatus.NORMAL_UNCERTAIN} <= statuses, statuses
    return ids, xy, views


def test_each_stud_keeps_its_usable_target_with_the_smallest_lean_bound_in_any_order(five_views):
    ids, xy, views = five_views
    reports = []
    for order in itertools.islice(itertools.permutations(range(len(views))), 0, None, 17):
        best = TargetTable.unseen(ids, xy)
        for k in order:
            best = best.merge(views[k])
        reports.append(best.report_entries())
        lean = np.array([np.where(t.ok, t.lean_bound_deg, np.inf) for t in views])  # (views, studs)
        usable = np.isfinite(lean).any(axis=0)
        np.testing.assert_array_equal(best.view_index[usable], np.argmin(lean, axis=0)[usable])
        np.testing.assert_array_equal(best.ok, usable)
        # a stud no view made usable keeps the first view that saw it, with its reason
        seen = np.array([t.status != TargetStatus.OUT_OF_VIEW for t in views])
        first = np.argmax(seen, axis=0)
        np.testing.assert_array_equal(best.view_index[~usable], np.where(seen.any(axis=0), first, -1)[~usable])
    assert all(r == reports[0] for r in reports[1:])
    # not a rule that the most central match would have met anyway
    central = np.argmin([np.where(t.ok, t.centre_offset, np.inf) for t in views], axis=0)
    assert np.any(central[usable] != np.argmin(lean, axis=0)[usable])


def _key(status=TargetStatus.OK, lean=1.0, centre=0.5, view=0) -> BestViewKey:
    return BestViewKey(np.array([status]), np.array([lean]), np.array([centre]), np.array([view]))


@pytest.mark.parametrize(("held", "offered", "takes"), [
    (_key(lean=1.0, centre=0.1, view=0), _key(lean=0.9, centre=0.8, view=1), True),    # surer normal, off-centre
    (_key(lean=0.9, centre=0.8, view=1), _key(lean=1.0, centre=0.1, view=0), False),
    (_key(lean=1.0, centre=0.5, view=0), _key(lean=1.0, centre=0.2, view=1), True),    # a tie: the more central
    (_key(lean=1.0, centre=0.5, view=1), _key(lean=1.0, centre=0.5, view=0), True),    # then the earlier view
    (_key(lean=1.0, centre=0.5, view=0), _key(lean=1.0, centre=0.5, view=1), False),
    (_key(lean=np.nan, view=0), _key(lean=9.0, view=1), True),                         # unknown bound: worst
    (_key(TargetStatus.NO_DEPTH, view=0), _key(lean=9.0, view=5), True),               # usable beats any other
    (_key(lean=9.0, view=5), _key(TargetStatus.NO_DEPTH, view=0), False),
    (_key(TargetStatus.NO_DEPTH, view=3), _key(TargetStatus.NORMAL_UNCERTAIN, view=1), True),  # earliest seen
    (_key(TargetStatus.NO_DEPTH, view=1), _key(TargetStatus.NORMAL_UNCERTAIN, view=3), False),
    (_key(TargetStatus.OUT_OF_VIEW, view=-1), _key(TargetStatus.NO_DEPTH, view=3), True),
    (_key(TargetStatus.OUT_OF_VIEW, view=-1), _key(TargetStatus.OUT_OF_VIEW, view=0), False),  # replaces nothing
])
def test_the_best_view_rule_and_its_tie_breaks(held, offered, takes):
    assert choose_best(held, offered).tolist() == [takes]
    scalar = BestViewKey(*(np.asarray(v[0]).item() for v in offered))  # the cell's: one target at a time
    assert bool(choose_best(BestViewKey(*(np.asarray(v[0]).item() for v in held)), scalar)) == takes


def test_tables_of_other_studs_do_not_merge(five_views):
    ids, xy, views = five_views
    with pytest.raises(ValueError, match="different studs"):
        TargetTable.unseen(ids[::-1], xy[::-1]).merge(views[0])
