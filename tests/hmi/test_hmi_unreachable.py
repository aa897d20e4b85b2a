"""The operator's stud table names the studs the cell cannot weld, with the reason /cell/status gives."""
from __future__ import annotations

from stud_hmi.model import CellInfo, CellState, CellView, Code

IDS = ["S0001", "S0002", "S0003"]
WHY = "unreachable: approach pose: no IK solution inside the joint limits (best residual 19.14 mm, 4.86 deg)"


def cell(unreachable=(), reasons=()):
    return CellInfo(int(CellState.WELDING), 1, 1, len(IDS), 0, 0, tuple(unreachable), "", tuple(reasons))


def test_a_stud_named_unreachable_shows_so_with_its_reason_and_an_alarm():
    v = CellView()
    v.set_layout(IDS, "/parts/dome.dxf")
    assert v.on_cell(cell(["S0002"], [WHY]), 10.0) is True
    rows = {r["stud_id"]: r for r in v.table.rows()}
    assert rows["S0002"]["status"] == "unreachable" and rows["S0002"]["reason"] == WHY
    assert rows["S0001"]["status"] == "not_seen" and rows["S0001"]["reason"] == ""
    assert v.table.counts() == {"not_seen": 2, "unreachable": 1}
    assert Code.UNREACHABLE in [a["code"] for a in v.alarms.message()["active"]]
    assert v.on_cell(cell(["S0002"], [WHY]), 11.0) is False   # nothing new: the table is not sent again
    assert v.progress(11.0)["unreachable"] == 1 and v.progress(11.0)["remaining"] == 2


def test_a_stud_welded_after_all_is_no_longer_shown_unreachable():
    v = CellView()
    v.set_layout(IDS, "/parts/dome.dxf")
    v.on_cell(cell(["S0003"], [WHY]), 10.0)
    v.table.job_result(["S0003"], [], [])
    row = {r["stud_id"]: r for r in v.table.rows()}["S0003"]
    assert row["weld"] == "welded" and row["status"] != "unreachable" and row["reason"] == ""
    assert v.on_cell(cell(), 12.0) is True
