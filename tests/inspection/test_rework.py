"""Rework decisions on studs that did not pass inspection: what is accepted, and the record written."""
from __future__ import annotations

import json

import pytest

from stud_inspection.rework import ReworkError, append_record, latest_decisions, make_record


def test_a_decision_on_a_failed_stud_is_appended_as_one_json_line_with_its_time(tmp_path):
    path = tmp_path / "out" / "rework_decisions.jsonl"
    append_record(path, make_record("S0004", "Rework", "  lean 8 deg ", "fail", stamp=1746094323.12,
                                    operator="  A.  Inspector "))
    append_record(path, make_record("S0004", "accept", "", "fail", stamp=1746094400.0, operator="B. Welder"))
    lines = [json.loads(line) for line in path.read_text().splitlines()]
    assert lines[0] == {"time": "2025-05-01T10:12:03.120+00:00", "stud_id": "S0004", "decision": "rework",
                        "verdict": "fail", "note": "lean 8 deg", "stamp": 1746094323.12, "operator": "A. Inspector"}
    assert (lines[1]["decision"], lines[1]["operator"]) == ("accept", "B. Welder")
    assert latest_decisions(path)["S0004"].for_qa_record() == {"decision": "accept", "note": "",
                                                               "time": "2025-05-01T10:13:20.000+00:00",
                                                               "operator": "B. Welder"}


@pytest.mark.parametrize("operator, why", [("", "no operator name"), ("   ", "no operator name"),
                                           ("x" * 101, "at most 100"), ("A.\x07B", "control characters")])
def test_a_decision_is_signed_by_a_named_operator(operator, why):
    with pytest.raises(ReworkError, match=why):
        make_record("S0004", "rework", "", "fail", stamp=0.0, operator=operator)


def test_decisions_written_before_operators_signed_them_still_read(tmp_path):
    path = tmp_path / "rework_decisions.jsonl"
    path.write_text('{"time": "x", "stud_id": "S0001", "decision": "accept", "verdict": "fail", "note": "", '
                    '"stamp": 5.0}\n')
    assert latest_decisions(path)["S0001"].operator == ""


@pytest.mark.parametrize("stud, decision, verdict, why", [
    ("", "rework", "fail", "no stud_id"),
    ("S0001", "weld", "fail", "not one of rework, accept"),
    ("S0001", "accept", "pass", "only fail, missing, not_inspected"),
    ("S0001", "accept", "not_welded", "only fail"),
    ("S0001", "rework", None, "has not been inspected"),
])
def test_decisions_that_make_no_sense_are_refused_with_the_reason(stud, decision, verdict, why):
    with pytest.raises(ReworkError, match=why):
        make_record(stud, decision, "", verdict, stamp=0.0)


def test_missing_and_not_inspected_studs_take_a_decision_too():
    assert make_record("S0002", "accept", "checked by gauge", "not_inspected", 0.0).verdict == "not_inspected"
    assert make_record("S0003", "rework", "", "missing", 0.0).decision == "rework"


def test_the_newest_line_of_a_stud_is_its_decision_and_a_torn_last_line_is_no_decision(tmp_path):
    path = tmp_path / "rework_decisions.jsonl"
    assert latest_decisions(path) == {}  # nothing decided yet
    append_record(path, make_record("S0004", "rework", "lean", "fail", stamp=10.0))
    append_record(path, make_record("S0007", "rework", "", "missing", stamp=11.0))
    append_record(path, make_record("S0004", "accept", "gauge ok", "fail", stamp=12.0))
    with open(path, "a") as f:  # a power cut in the middle of an append: never confirmed to the operator
        f.write('{"stud_id": "S0007", "decision": "acc')
    got = latest_decisions(path)
    assert {s: (r.decision, r.note) for s, r in got.items()} == {"S0004": ("accept", "gauge ok"),
                                                                 "S0007": ("rework", "")}


def test_a_damaged_decision_line_is_an_error_naming_the_file_and_line(tmp_path):
    path = tmp_path / "rework_decisions.jsonl"
    append_record(path, make_record("S0004", "rework", "", "fail", stamp=10.0))
    with open(path, "a") as f:
        f.write('{"stud_id": "S0005", "decision": "weld twice", "verdict": "fail", "stamp": 1}\n')
    with pytest.raises(ReworkError, match=r"rework_decisions.jsonl:2: not a rework decision"):
        latest_decisions(path)
