"""hmi_model without ROS: what the stud table, the alarms, the banner, the buttons, the progress
and the operator's decisions say."""
from __future__ import annotations

import json
import math

import pytest

from stud_hmi.model import (
    ALARMS,
    ArmInfo,
    ArmMode,
    CellInfo,
    CellState,
    CellView,
    Code,
    StudTable,
    TargetInfo,
    Timeouts,
)
from stud_hmi.server import to_json

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



# -- helpers ----------------------------------------------------------------------------------------
IDS = [f"S{i:04d}" for i in range(1, 11)]


def arm(mode=ArmMode.IDLE, connected=True, stud="", message="", errors=(), uncertain=()):
    return ArmInfo(int(mode), connected, stud, message, tuple(errors), tuple(uncertain))


def cell(state=CellState.IDLE, welded=0, message="", unreachable=(), station=0):
    return CellInfo(int(state), station, 3, len(IDS), welded, 0, tuple(unreachable), message)


def ready_view(now=100.0) -> CellView:
    v = CellView()
    v.set_layout(IDS, "/parts/dome.dxf", part_name="")
    v.on_arm(arm(), now)
    v.on_cell(cell(), now)
    return v


def codes(v: CellView) -> list[str]:
    return [a["code"] for a in v.alarms.message()["active"]]


# -- alarms -----------------------------------------------------------------------------------------
def test_a_repeated_diagnostic_is_one_alarm_that_keeps_its_ack_and_clears_when_the_node_reports_ok():
    v = ready_view()
    for k in range(657):  # the drawing node repeats its status every second
        v.on_diagnostic("drawing", 1, "2 studs closer than 5 mm", now=101.0 + k)
    msg = v.alarms.message()
    assert [(a["code"], a["severity"], a["source"], a["acked"]) for a in msg["active"]] == [
        (Code.NODE_WARN, "warning", "drawing", False)]
    assert msg["unacked"] == 1 and msg["active"][0]["raised"] == 101.0 and "count" not in msg["active"][0]
    assert v.acknowledge(msg["active"][0]["key"], now=800.0) == 1
    v.on_diagnostic("drawing", 1, "2 studs closer than 5 mm", now=801.0)
    msg = v.alarms.message()
    assert msg["unacked"] == 0 and msg["active"][0]["acked"] and msg["active"][0]["acked_at"] == 800.0
    v.on_diagnostic("drawing", 0, "12 studs, 0 warnings", now=802.0)  # another drawing, no warning
    msg = v.alarms.message()
    assert msg["active"] == [] and msg["history"][0]["cleared"] == 802.0 and msg["history"][0]["code"] == "A201"


def test_a_diagnostic_no_longer_repeated_clears_but_the_arm_and_cell_are_alarmed_from_their_topics():
    v = CellView(Timeouts(arm_s=2.0, cell_s=5.0, diagnostics_s=10.0))
    v.on_diagnostic("matcher", 2, "unusable view: depth is 8UC1", now=0.0)
    v.on_diagnostic("rm65_driver", 1, "uncertain studs need an operator decision", now=0.0)
    v.on_diagnostic("cell_sequencer", 2, "failed: no shot", now=0.0)
    assert codes(v) == [Code.NODE_ERROR]  # not a second alarm for what /arm/state and /cell/status say
    v.tick(now=5.0)
    assert codes(v) == [Code.NODE_ERROR]
    v.tick(now=10.5)
    assert codes(v) == []


def test_uncertain_studs_alarm_only_when_the_driver_lists_them_and_clear_once_decided():
    v = ready_view()
    v.on_arm(arm(ArmMode.WELDING, stud="S0001"), 101.0)  # welding S0001: the driver lists no uncertain stud
    assert codes(v) == []
    v.on_arm(arm(uncertain=["S0004"]), 102.0)
    assert codes(v) == [Code.UNCERTAIN] and "S0004" in v.alarms.message()["active"][0]["text"]
    assert v.decisions(102.0)["uncertain"] == ["S0004"] and v.decisions(102.0)["uncertain_enabled"]
    v.on_arm(arm(), 103.0)
    assert codes(v) == [] and v.decisions(103.0)["uncertain"] == []


def test_a_job_the_operator_stopped_is_no_alarm_a_failed_one_is_until_the_next_start():
    v = ready_view()
    v.on_cell(cell(CellState.FAILED, message="stopped by the operator while waiting for /weld_targets"), 101.0)
    assert codes(v) == []
    v.on_cell(cell(CellState.FAILED, message="no /weld_targets within 60 s"), 102.0)
    assert codes(v) == [Code.CELL_FAILED]
    v.on_cell(cell(CellState.REGISTERING), 103.0)
    assert codes(v) == [] and v.alarms.message()["history"][0]["code"] == Code.CELL_FAILED


def test_alarms_sort_by_severity_and_every_code_has_a_definition():
    v = ready_view()
    v.on_diagnostic("matcher", 1, "registration is stale", now=101.0)
    v.on_arm(arm(ArmMode.ESTOP, message="e-stop engaged (/arm/estop service)"), 102.0)
    v.on_registration(False, math.nan, "marks not found", 103.0)
    active = v.alarms.message()["active"]
    assert [a["severity"] for a in active] == ["critical", "warning", "warning"]
    assert active[0]["code"] == Code.ESTOP and "refuses every motion" in active[0]["text"]
    assert {getattr(Code, k) for k in dir(Code) if not k.startswith("_")} == set(ALARMS)
    assert v.acknowledge("all", 104.0) == 3 and v.alarms.message()["unacked"] == 0


def test_silent_arm_driver_and_sequencer_raise_alarms_and_clear_when_they_speak_again():
    v = ready_view(now=100.0)
    v.tick(101.0)
    assert codes(v) == []
    v.tick(103.0)
    assert codes(v) == [Code.ARM_LOST]
    v.tick(106.0)
    assert set(codes(v)) == {Code.ARM_LOST, Code.CELL_LOST}
    assert not v.controls(106.0)["start"]["enabled"]
    v.on_arm(arm(), 106.5)
    v.on_cell(cell(), 106.5)
    assert codes(v) == [] and v.controls(106.6)["start"]["enabled"]


def test_hand_eye_calibrations_that_differ_between_nodes_raise_an_alarm():
    v = ready_view()
    cal = {"source": "file", "path": "/cal/hand_eye.yaml", "date": "2025-04-30", "xyz_m": [0.0, 0.05, 0.02],
           "rpy_deg": [0.0, 0.0, 90.0], "position_rms_mm": 0.31}
    v.on_hand_eye("rm65_driver", cal, 101.0)
    v.on_hand_eye("camera", dict(cal), 101.0)
    c = v.calibration()
    assert c["agree"] and c["nodes"] == ["camera", "rm65_driver"] and codes(v) == []
    assert c["text"] == ("file hand_eye.yaml (2025-04-30, residual 0.31 mm): "
                         "xyz [0.0, 50.0, 20.0] mm, rpy [0.00, 0.00, 90.00]°")
    v.on_hand_eye("camera", {"source": "typed", "xyz_m": [0.0, 0.0, 0.0], "rpy_deg": [0.0, 0.0, 0.0]}, 102.0)
    assert not v.calibration()["agree"] and codes(v) == [Code.HAND_EYE]


# -- the safety banner --------------------------------------------------------------------------------
def test_the_safety_banner_shows_a_latched_estop_and_an_arm_fault_and_nothing_else():
    v = ready_view()
    assert v.safety(100.0) is None
    v.on_arm(arm(ArmMode.ESTOP, message="e-stop engaged (/arm/estop service)"), 101.0)
    banner = v.safety(101.0)
    assert banner["kind"] == "estop" and banner["title"] == "E-STOP LATCHED" and banner["stale_s"] is None
    assert "release the latch at the cell" in banner["text"]
    assert "last known state" in v.safety(110.0)["text"]  # the driver went silent: still shown, and said so
    v.on_arm(arm(ArmMode.FAULT, message="weld journal FAULT: line 7 damaged"), 111.0)
    assert v.safety(111.0)["kind"] == "fault" and "line 7 damaged" in v.safety(111.0)["text"]
    v.on_arm(arm(ArmMode.FAULT, errors=["joint 3 over temperature"]), 112.0)
    assert "joint 3 over temperature" in v.safety(112.0)["text"]
    v.on_arm(arm(ArmMode.DISCONNECTED, connected=False), 113.0)
    assert v.safety(113.0) is None and codes(v) == [Code.ARM_DISCONNECTED]


# -- which buttons are valid --------------------------------------------------------------------------
def enabled(v: CellView, now: float = 100.5) -> set[str]:
    return {k for k, c in v.controls(now).items() if c["enabled"]}


@pytest.mark.parametrize("state, mode, expected", [
    (CellState.IDLE, ArmMode.IDLE, {"start", "estop"}),
    (CellState.DONE, ArmMode.IDLE, {"start", "estop"}),
    (CellState.FAILED, ArmMode.IDLE, {"start", "estop"}),
    (CellState.REGISTERING, ArmMode.MOVING, {"pause", "stop", "estop"}),
    (CellState.WELDING, ArmMode.WELDING, {"pause", "stop", "estop"}),
    (CellState.PAUSED, ArmMode.PAUSED, {"resume", "stop", "estop"}),
    (CellState.IDLE, ArmMode.ESTOP, {"estop"}),
    (CellState.PAUSED, ArmMode.ESTOP, {"stop", "estop"}),
    (CellState.IDLE, ArmMode.FAULT, {"estop"}),
    (CellState.IDLE, ArmMode.DISCONNECTED, {"estop"}),
])
def test_each_button_is_enabled_only_when_its_action_is_valid(state, mode, expected):
    v = ready_view()
    v.on_cell(cell(state), 100.0)
    v.on_arm(arm(mode, connected=mode != ArmMode.DISCONNECTED), 100.0)
    assert enabled(v) == expected
    why = v.controls(100.5)
    assert all(c["why"] for c in why.values())
    if mode == ArmMode.ESTOP and state == CellState.IDLE:
        assert why["start"]["why"] == "e-stop latched"


def test_without_the_sequencer_or_the_drawing_start_is_disabled_and_says_why():
    v = CellView()
    assert enabled(v) == {"stop", "estop"}  # nothing known: stopping is always offered
    assert "cell sequencer" in v.controls(0.0)["start"]["why"]
    v.on_cell(cell(), 0.0)
    v.on_arm(arm(), 0.0)
    assert v.controls(0.5)["start"] == {"enabled": False, "why": "no drawing loaded (/drawing/layout)"}
    assert v.check_command("start", {}, 0.5) == "no drawing loaded (/drawing/layout)"
    assert v.check_command("stop", {}, 0.5) is None and v.check_command("estop", {}, 0.5) is None


def test_commands_for_decisions_are_checked_against_what_is_pending():
    v = ready_view()
    v.on_arm(arm(uncertain=["S0004"]), 101.0)
    assert v.check_command("resolve_stud", {"stud_id": "S0004", "decision": "welded"}, 101.0) is None
    assert v.check_command("resolve_stud", {"stud_id": "S0004", "decision": "weld_again"}, 101.0) is None
    assert "not an uncertain stud" in v.check_command("resolve_stud", {"stud_id": "S0005", "decision": "welded"}, 101.0)
    assert "decision must be" in v.check_command("resolve_stud", {"stud_id": "S0004", "decision": "maybe"}, 101.0)
    v.on_arm(arm(ArmMode.FAULT, message="journal damaged", uncertain=["S0004"]), 102.0)
    assert "resolve the journal first" in v.check_command("resolve_stud", {"stud_id": "S0004", "decision": "welded"},
                                                          102.0)
    assert "unknown command" in v.check_command("weld_all", {}, 102.0)


# -- progress, cycle time, time to the end -------------------------------------------------------------
def test_progress_counts_studs_not_stations():
    v = ready_view()
    v.on_cell(cell(CellState.WELDING, welded=2, station=2), 101.0)  # the sequencer counts per finished station
    for sid in IDS[:6]:
        v.weld_feedback(sid, "approach", 101.0)
        v.weld_feedback(sid, "retract", 101.5)
    p = v.progress(102.0)
    assert (p["welded"], p["total"], p["remaining"], p["station"]) == (6, 10, 4, 2)
    assert p["percent"] == pytest.approx(60.0)
    v.on_cell(cell(CellState.WELDING, welded=7), 102.0)  # it may know more (studs welded before the HMI started)
    assert v.progress(102.0)["welded"] == 7


def test_cycle_time_and_time_to_the_end_leave_out_pauses():
    v = ready_view(now=0.0)
    v.on_cell(cell(CellState.REGISTERING), 0.0)
    assert v.progress(5.0)["cycle_s"] is None and v.progress(5.0)["eta_s"] is None
    v.on_cell(cell(CellState.WELDING), 10.0)
    for k, sid in enumerate(IDS[:3]):  # welds at 20, 24, 28 s
        v.weld_feedback(sid, "retract", 20.0 + 4.0 * k)
    p = v.progress(28.0)
    assert p["cycle_s"] == pytest.approx(4.0) and p["last_cycle_s"] == pytest.approx(4.0)
    assert p["eta_s"] == pytest.approx(7 * 4.0) and p["elapsed_s"] == pytest.approx(28.0) and p["running"]
    v.on_cell(cell(CellState.PAUSED), 29.0)
    v.on_cell(cell(CellState.WELDING), 129.0)  # 100 s paused
    v.weld_feedback(IDS[3], "retract", 132.0)  # 4 s of job time after the last weld
    p = v.progress(132.0)
    assert p["cycle_s"] == pytest.approx(4.0) and p["elapsed_s"] == pytest.approx(32.0)
    assert p["eta_s"] == pytest.approx(6 * 4.0)
    v.job_result(welded=IDS[:4], skipped=[], failed=IDS[4:])
    v.on_cell(cell(CellState.DONE, welded=4), 140.0)
    p = v.progress(500.0)
    assert not p["running"] and p["elapsed_s"] == pytest.approx(40.0) and p["eta_s"] == 0.0
    assert (p["welded"], p["failed"], p["remaining"]) == (4, 6, 0)


# -- part, drawing, inspection and rework ----------------------------------------------------------------
def test_part_and_drawing_name_come_from_the_layout():
    v = CellView()
    v.set_layout(IDS, "/data/parts/dome_part.dxf", part_name="", warnings=["2 studs closer than 5 mm"])
    assert v.part == {"part": "dome_part", "drawing": "dome_part.dxf", "drawing_file": "/data/parts/dome_part.dxf",
                      "studs": 10, "warnings": ["2 studs closer than 5 mm"]}
    v.set_layout(IDS, "/data/parts/dome_part.dxf", part_name="Bracket 7-114")
    assert v.part["part"] == "Bracket 7-114"


def test_inspection_verdicts_fill_the_table_and_failed_studs_wait_for_a_rework_decision():
    v = ready_view()
    v.on_inspection([("S0001", "pass", ()), ("S0002", "fail", ("lean 8.0 deg > 5.0",)), ("S0003", "missing", ()),
                     ("S0004", "not_welded", ())], 101.0)
    rows = rows_by_id(v.table)
    assert (rows["S0001"]["inspection"], rows["S0002"]["inspection"], rows["S0004"]["inspection"]) == (
        "pass", "fail", "not_welded")
    assert rows["S0002"]["inspection_reasons"] == ["lean 8.0 deg > 5.0"] and rows["S0005"]["inspection"] == ""
    assert [r["stud_id"] for r in v.decisions(101.0)["rework"]] == ["S0002", "S0003"]
    assert codes(v) == [Code.REWORK]
    v.on_rework("S0002", "rework", 102.0)
    assert rows_by_id(v.table)["S0002"]["rework"] == "rework" and codes(v) == [Code.REWORK]
    v.on_rework("S0003", "accept", 103.0)
    assert v.decisions(103.0)["rework"] == [] and codes(v) == []


def test_status_message_is_strict_json():
    v = ready_view()
    v.on_registration(True, 0.4, "ok", 100.0)
    msg = json.loads(to_json(v.status_message(100.5)))
    assert msg["type"] == "status" and msg["safety"] is None and msg["part"]["part"] == "dome"
    assert msg["controls"]["start"]["enabled"] and msg["progress"]["total"] == 10
