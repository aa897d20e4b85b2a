"""Bend tests and signed decisions on the operator's page: the QA record's bend-test list reaches the
page, the operator -- named once per session -- enters each result, and it lands in the record.

The model (ROS-free), then the whole chain through real processes: a 400-stud job's QA record, the
inspector (which publishes its list and records results), the HMI node, and a browser's WebSocket."""
from __future__ import annotations

import json

import pytest

from stud_hmi.model import CellView

pytest.importorskip("rclpy")
pytest.importorskip("stud_welding_msgs.msg", reason="workspace not built/sourced (source ros2_ws/setup.bash)")

from hmi_testing import ctrl_c, free_port  # noqa: E402
from rosproc import ros2_run, wait_for  # noqa: E402
from stud_inspection import qa_codes  # noqa: E402
from stud_inspection.qa_report import empty_row, read_record, write_qa_report  # noqa: E402
from ws_client import WsClient  # noqa: E402


def test_the_bend_tests_to_do_come_first_and_a_result_needs_a_name_and_a_result():
    v = CellView()
    v.set_layout(["S0001", "S0002", "S0003"], "part.dxf")
    v.on_bend_tests([{"stud_id": "S0001", "reasons": ["pre-production"], "angle_deg": 30.0, "result": "pass",
                      "operator": "B. Welder"},
                     {"stud_id": "S0003", "reasons": ["lot sample"], "angle_deg": 30.0, "result": ""}], "iso14555")
    d = v.decisions(0.0)
    assert [t["stud_id"] for t in d["bend_tests"]] == ["S0003", "S0001"] and d["bend_code"] == "iso14555"
    rows = {r["stud_id"]: r for r in v.table.rows()}
    assert (rows["S0001"]["bend"], rows["S0003"]["bend"], rows["S0002"]["bend"]) == ("pass", "to do", "")
    ok = {"stud_id": "S0003", "result": "pass", "angle_deg": 31, "note": "", "operator": "A. Inspector"}
    assert v.check_command("record_bend_test", ok, 0.0) is None
    assert "no operator name" in v.check_command("record_bend_test", {**ok, "operator": "  "}, 0.0)
    assert "asks for it once per session" in v.check_command("record_rework", {"stud_id": "S0003",
                                                                               "decision": "rework"}, 0.0)
    assert "result must be one of ['pass', 'fail']" in v.check_command("record_bend_test", {**ok, "result": "ok"}, 0.0)
    assert "angle_deg must be a number" in v.check_command("record_bend_test", {**ok, "angle_deg": "30"}, 0.0)


def test_a_400_stud_jobs_bend_results_are_entered_on_the_page_and_land_in_the_record(ros_node, procs, tmp_path):
    rows = []
    for k in range(400):
        r = empty_row(f"S{k + 1:04d}", (k % 20 * 50.0, k // 20 * 50.0))
        r.update(verdict="pass", weld_seq=k + 1, station=1 + k // 100)
        rows.append(r)
    rows[150].update(verdict="fail", reasons=["lean 7.9 deg > 5 deg"])
    write_qa_report(tmp_path, {"id": "J400", "part": "deck"}, {"max_lean_deg": 5.0}, rows, [], [],
                    code=qa_codes.profile("gb50205").describe(), seed=4242)
    listed = [t["stud_id"] for t in read_record(tmp_path)["sampling"]["bend_tests"]]
    assert len(listed) >= 10 + 6 - 1  # the lot sample and the failure's neighbours (they may overlap once)

    port = free_port()
    procs.append(ros2_run("stud_planner", "inspector", tmp_path / "inspector.log",
                          {"qa_dir": str(tmp_path), "overlay_dir": str(tmp_path / "qa")}))
    hmi = ros2_run("stud_planner", "hmi", tmp_path / "hmi.log", {"port": port})
    procs.append(hmi)
    ws = None
    msgs: list[dict] = []

    def newest(pred):
        if ws is not None:
            msgs.extend(ws.poll(0.01))
        return next((m for m in reversed(msgs) if pred(m)), None)

    def bend_list(m):
        return m["type"] == "status" and len(m["decisions"]["bend_tests"]) == len(listed)

    wait_for(lambda: hmi.popen.poll() is None and "HMI on " in hmi.output(), 30, what=f"the hmi\n{hmi.output()}")
    ws = WsClient("127.0.0.1", port)
    wait_for(lambda: newest(bend_list), 40, spin=ros_node.spin,
             what="the record's bend-test list on the page\n" + "\n".join(p.output()[-1500:] for p in procs))
    status = newest(bend_list)
    assert {t["stud_id"] for t in status["decisions"]["bend_tests"]} == set(listed)
    assert status["decisions"]["bend_code"] == "gb50205"

    first, second = listed[0], listed[1]
    ws.send_json({"cmd": "record_bend_test", "id": 1, "stud_id": first, "result": "pass", "angle_deg": 30})
    wait_for(lambda: newest(lambda m: m["type"] == "reply" and m.get("id") == 1), 20, spin=ros_node.spin,
             what="the refusal")
    refused = newest(lambda m: m["type"] == "reply" and m.get("id") == 1)
    assert not refused["ok"] and "no operator name" in refused["error"]  # unsigned: refused on the page
    for cid, sid, result in ((2, first, "pass"), (3, second, "fail")):
        ws.send_json({"cmd": "record_bend_test", "id": cid, "stud_id": sid, "result": result, "angle_deg": 30,
                      "note": "by the book" if result == "pass" else "weld cracked", "operator": "A. Inspector"})
        wait_for(lambda c=cid: newest(lambda m: m["type"] == "reply" and m.get("id") == c), 30, spin=ros_node.spin,
                 what=f"the reply to {sid}'s result")
        reply = newest(lambda m, c=cid: m["type"] == "reply" and m.get("id") == c)
        assert reply["ok"] and "QA record updated" in reply["message"], reply
    doc = read_record(tmp_path)
    got = {r["stud_id"]: r for r in doc["studs"]}
    assert (got[first]["bend_test"]["result"], got[first]["bend_test"]["operator"]) == ("pass", "A. Inspector")
    assert got[second]["bend_test"]["result"] == "fail" and doc["sampling"]["counts"]["failed"] == 1
    # the failed bend test put its neighbours in weld order on the list, and the page shows it
    k = got[second]["weld_seq"]
    neighbours = {r["stud_id"] for r in doc["studs"] if r["weld_seq"] in {k - 3, k - 2, k - 1, k + 1, k + 2, k + 3}}
    assert all(f"welded next to {second} (bend test failed)" in got[s]["bend_test"]["reasons"] for s in neighbours)
    wait_for(lambda: newest(lambda m: m["type"] == "status" and any(
        t["stud_id"] == second and t["result"] == "fail" for t in m["decisions"]["bend_tests"])), 20,
        spin=ros_node.spin, what="the result on the page")
    page_list = newest(lambda m: m["type"] == "status")["decisions"]["bend_tests"]
    assert {t["stud_id"] for t in page_list} >= neighbours
    results = [json.loads(line) for line in (tmp_path / "qa" / "bend_tests.jsonl").read_text().splitlines()]
    assert [(r["stud_id"], r["result"], r["operator"]) for r in results] == [
        (first, "pass", "A. Inspector"), (second, "fail", "A. Inspector")]
    ws.close()
    assert ctrl_c(hmi) == 0
