"""hmi_model without ROS: what the stud table and the last-errors list say."""
from __future__ import annotations

import json
import math

from stud_planner.hmi_model import ErrorLog, StudTable, TargetInfo
from stud_planner.hmi_server import to_json

NAN = math.nan


def target(sid, status="ok", view=0, x=0.1, incl=2.0):
    code = {"ok": 0, "out_of_view": 1, "no_depth": 2}[status]
    pos = (x, 0.2, 0.05) if status == "ok" else (NAN, NAN, NAN)
    return TargetInfo(sid, status, code, pos, 0.0003 if status == "ok" else NAN, incl if status == "ok" else NAN, view)


def rows_by_id(table):
    return {r["stud_id"]: r for r in table.rows()}


def test_rows_convert_to_mm_and_nan_becomes_null_in_json():
    t = StudTable()
    t.update_view([target("S0001"), target("S0002", "no_depth")], view=0, algorithm="batch")
    msg = json.loads(to_json(t.message()))
    r1, r2 = msg["rows"]
    assert r1["position_mm"] == [100.0, 200.0, 50.0] and abs(r1["xy_error_mm"] - 0.3) < 1e-9
    assert r1["inclination_deg"] == 2.0 and r1["status"] == "ok" and r1["welded"] is False
    assert r2["position_mm"] == [None, None, None] and r2["xy_error_mm"] is None and r2["inclination_deg"] is None
    assert msg["counts"] == {"ok": 1, "no_depth": 1} and msg["total"] == 2 and msg["view"] == 0


def test_layout_lists_every_stud_in_drawing_order_before_any_view():
    t = StudTable()
    t.set_layout(["S0003", "S0001", "S0002"])
    t.update_view([target("S0002"), target("S0009")])
    assert [r["stud_id"] for r in t.rows()] == ["S0003", "S0001", "S0002", "S0009"]
    assert rows_by_id(t)["S0003"]["status"] == "not_seen"


def test_a_first_layout_arriving_after_a_view_orders_the_table_without_losing_the_view():
    t = StudTable()
    t.update_view([target("S0002"), target("S0001", "no_depth")], view=0)
    t.job_result(welded=["S0002"], skipped=[], failed=[])
    t.set_layout(["S0001", "S0002", "S0003"])
    rows = t.rows()
    assert [(r["stud_id"], r["status"], r["weld"]) for r in rows] == [
        ("S0001", "no_depth", ""), ("S0002", "ok", "welded"), ("S0003", "not_seen", "")]


def test_a_stud_out_of_a_later_view_keeps_its_earlier_match_but_a_new_match_replaces_it():
    t = StudTable()
    t.update_view([target("S0001", view=0, x=0.1), target("S0002", "out_of_view", view=0)], view=0)
    t.update_view([target("S0001", "out_of_view", view=1), target("S0002", view=1)], view=1)
    rows = rows_by_id(t)
    assert rows["S0001"]["status"] == "ok" and rows["S0001"]["view"] == 0
    assert rows["S0002"]["status"] == "ok" and rows["S0002"]["view"] == 1
    t.update_view([target("S0001", view=2, x=0.2)], view=2)
    assert rows_by_id(t)["S0001"]["position_mm"][0] == 200.0


def test_weld_state_follows_feedback_arm_state_and_the_job_result():
    t = StudTable()
    t.set_layout(["S0001", "S0002", "S0003", "S0004"])
    t.update_view([target(s) for s in ("S0001", "S0002", "S0003", "S0004")])
    assert t.arm_progress("S0001") and not t.arm_progress("S0001")
    assert rows_by_id(t)["S0001"]["weld"] == "active"
    t.weld_feedback("S0001", "weld")
    assert rows_by_id(t)["S0001"]["phase"] == "weld" and not rows_by_id(t)["S0001"]["welded"]
    t.weld_feedback("S0001", "retract")  # the driver retracts only after a confirmed weld
    t.weld_feedback("S0002", "approach")
    rows = rows_by_id(t)
    assert rows["S0001"]["welded"] and rows["S0001"]["weld"] == "welded"
    assert rows["S0002"]["weld"] == "active"
    t.update_view([target("S0001", view=5)])  # a new view does not forget a weld
    assert rows_by_id(t)["S0001"]["welded"]
    t.job_result(welded=["S0001"], skipped=["S0003"], failed=["S0002"])
    rows = rows_by_id(t)
    assert [rows[s]["weld"] for s in ("S0001", "S0002", "S0003", "S0004")] == ["welded", "failed", "skipped", ""]
    assert t.message()["welded"] == 1
    t.set_layout(["S0001"])  # another drawing starts afresh
    assert rows_by_id(t)["S0001"]["weld"] == ""


def test_error_log_counts_repeats_marks_cleared_errors_and_keeps_the_newest():
    log = ErrorLog(max_items=3)
    log.update("matcher", 1, "waiting for inputs", now=1.0)
    log.update("rm65_driver", 2, "controller not connected", now=2.0)
    log.update("rm65_driver", 2, "controller not connected", now=3.0)
    log.update("camera", 0, "ok", now=3.0)
    items = log.message()["items"]
    assert [(i["name"], i["count"], i["level"], i["active"]) for i in items] == [
        ("rm65_driver", 2, "error", True), ("matcher", 1, "warn", True)]
    assert items[0]["first"] == 2.0 and items[0]["last"] == 3.0
    log.changed = False
    log.update("matcher", 0, "view 3: 12/12 ok", now=4.0)
    assert log.changed and [i["active"] for i in log.message()["items"]] == [True, False]
    for k in range(3):
        log.update("x", 2, f"e{k}", now=5.0 + k)
    assert [i["message"] for i in log.message()["items"]] == ["e2", "e1", "e0"]
