"""`plan` on a long part's bag (issue 35): a few views of the bundled girder shot from the arm on its rail
with the rail's simulated error (tools/record_demo_bag.py --part girder), every view registered on the
marks it sees and matched with its own registration, so the far end's targets are where the studs are in
the world the cell believes at that carriage position -- one registration at the board would put them
millimetres off."""
from __future__ import annotations

import importlib.util
import sys

import numpy as np
import pytest

from rosproc import REPO
from stud_perception.registration import local_to_world
from stud_planner.drawing import read_layout
from stud_planner.offline_plan import plan

DXF = REPO / "src" / "stud_planner" / "data" / "girder_demo.dxf"
STATIONS = (0, 1, 17, 18)  # both ends of the girder, after the board's view


def record_demo_bag():
    spec = importlib.util.spec_from_file_location("record_demo_bag", REPO / "tools" / "record_demo_bag.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["record_demo_bag"] = module
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def girder_bag(tmp_path_factory):
    out = tmp_path_factory.mktemp("girder") / "girder_bag"
    truth = record_demo_bag().record_girder(out, list(STATIONS))
    return out, truth


def believed_truth(truth: dict, view: int) -> dict[str, np.ndarray]:
    """Each stud's true position in the world the cell believes at ``view``'s carriage position."""
    C_inv = np.linalg.inv(np.asarray(truth["views"][view]["true_world_correction"]))
    return {s["stud_id"]: C_inv[:3, :3] @ np.asarray(s["position_m"]) + C_inv[:3, 3] for s in truth["studs"]}


def test_every_girder_view_is_registered_on_its_own_marks_and_matched_with_it(girder_bag):
    bag, truth = girder_bag
    report = plan(DXF, bag)
    assert report["warnings"] == []
    regs = report["registrations"]
    assert [r["view"] for r in regs] == list(range(5))
    assert report["view_stamps_ns"] == [v["stamp_ns"] for v in truth["views"]]
    assert regs[0]["marks"] == ["O", "A", "B"]
    for r in regs[1:]:  # the stations see reference marks only (A as well at the girder's start), three or more
        assert len(r["marks"]) >= 3 and any(m.startswith("M") for m in r["marks"]), r
        assert r["extrapolated_m"] == 0.0 and r["residual_max_mm"] < 0.5, r
    seen = {sid for v in truth["views"][1:] for sid in v["visible"]}
    ok = {t["stud_id"]: t for t in report["targets"] if t["status"] == "ok"}
    assert seen <= set(ok) and len(ok) >= 20
    far_errors = []
    for sid, t in ok.items():
        expected = believed_truth(truth, t["view"])[sid]
        p = np.asarray(t["position_m"])
        assert np.linalg.norm(p[:2] - expected[:2]) < 0.5e-3 and abs(p[2] - expected[2]) < 1.0e-3, (sid, p - expected)
        if truth["views"][t["view"]]["carriage_m"] > 5.5:
            # the board's registration alone, 6 m back along the rail
            board = local_to_world(np.asarray(report["registration"]["M_local2world"]),
                                   np.asarray(t["drawing_xy_mm"]) * 1e-3).ravel()
            far_errors.append(np.linalg.norm(board - expected[:2]))
    assert far_errors and min(far_errors) > 0.004, far_errors


def test_a_drawing_without_reference_marks_is_still_registered_once():
    report = plan(REPO / "src" / "stud_planner" / "data" / "dome_demo.dxf", REPO / "bags" / "dome_demo")
    assert "registrations" not in report and len(report["view_stamps_ns"]) == report["views"] == 2
    assert report["registration"]["view"] == 0
    assert not read_layout(REPO / "src" / "stud_planner" / "data" / "dome_demo.dxf").reference_marks
