"""The QA record: strict JSON, a CSV with the same rows and a self-contained HTML page."""
from __future__ import annotations

import csv
import json

import cv2
import numpy as np
import pytest

from stud_inspection.qa_report import CSV_FIELDS, apply_rework, empty_row, locked, write_qa_report


def test_the_three_files_carry_the_same_rows(tmp_path):
    rows = [empty_row("S0001", (10.0, 20.0)), empty_row("S0002", (30.0, 20.0)), empty_row("S0003", (50.0, 20.0))]
    rows[0].update(verdict="pass", station=1, planned={"position_m": [0.1, 0.2, 0.05], "normal": [0, 0, 1]},
                   measured={"position_m": [0.1001, 0.2, 0.05], "axis": [0, 0, 1], "lean_deg": 0.3,
                             "offset_mm": [0.1, 0.0], "height_mm": 50.1})
    rows[1].update(verdict="fail", station=1, reasons=["lean 8.1 deg > 5 deg"], rework="grind off and re-weld (A.B.)",
                   planned={"position_m": [0.13, 0.2, float("nan")], "normal": [0, 0, 1]})
    overlay = tmp_path / "inspection_station_01.png"
    cv2.imwrite(str(overlay), np.full((20, 30, 3), 128, np.uint8))
    doc = write_qa_report(tmp_path, {"id": "J7", "part": "dome", "drawing": "dome.dxf", "state": "done"},
                          {"max_lean_deg": 5.0, "position_tol_mm": 2.0, "nominal_length_mm": 50.0,
                           "height_tol_mm": 2.0, "stud_diameter_mm": 16.0}, rows,
                          [{"position_m": [0.2, 0.1, 0.06], "height_mm": 30.0}], [overlay, tmp_path / "gone.png"])
    text = (tmp_path / "qa_report.json").read_text()
    assert "NaN" not in text
    data = json.loads(text)
    assert data == json.loads(json.dumps(doc, allow_nan=False))
    assert data["summary"] == {"pass": 1, "fail": 1, "missing": 0, "not_inspected": 0, "not_welded": 1}
    assert [r["stud_id"] for r in data["studs"]] == ["S0001", "S0002", "S0003"]
    assert data["studs"][1]["planned"]["position_m"][2] is None and data["studs"][2]["measured"] is None
    assert data["job"]["date"] and data["limits"]["max_lean_deg"] == 5.0
    with open(tmp_path / "qa_report.csv") as f:
        table = list(csv.reader(f))
    assert table[0] == CSV_FIELDS and [r[0] for r in table[1:]] == ["S0001", "S0002", "S0003"]
    assert table[2][3] == "fail" and table[2][4] == "lean 8.1 deg > 5 deg"
    page = (tmp_path / "qa_report.html").read_text()
    assert page.count("<tr class=") == 3 and "J7" in page and "grind off" in page
    assert page.count("data:image/png;base64,") == 1  # the overlay embedded, the missing file left out
    assert "5&deg;" in page or "5°" in page


def _limits():
    return {"max_lean_deg": 5.0, "position_tol_mm": 2.0, "nominal_length_mm": 50.0, "height_tol_mm": 2.0,
            "stud_diameter_mm": 16.0}


def test_a_decision_after_the_job_rewrites_the_rework_column_of_all_three_files(tmp_path):
    rows = [empty_row("S0001", (10.0, 20.0)), empty_row("S0002", (30.0, 20.0))]
    rows[1].update(verdict="fail", reasons=["lean 8.1 deg > 5 deg"])
    overlay = tmp_path / "qa" / "inspection_station_01.png"
    overlay.parent.mkdir()
    cv2.imwrite(str(overlay), np.full((20, 30, 3), 128, np.uint8))
    before = write_qa_report(tmp_path, {"id": "J7"}, _limits(), rows, [], [overlay],
                             decisions={"S0001": {"decision": "accept", "note": ""}})
    assert before["overlays"] == ["qa/inspection_station_01.png"]  # relative: the folder can be moved
    assert [r["rework"] for r in before["studs"]] == ["accept", None]
    with locked(tmp_path):
        after = apply_rework(tmp_path, {"S0002": {"decision": "rework", "note": "cut off, re-weld by hand"}})
    data = json.loads((tmp_path / "qa_report.json").read_text())
    assert data == after and data["summary"] == before["summary"] and data["job"] == before["job"]
    assert [(r["rework"], r["rework_note"]) for r in data["studs"]] == [("accept", None),
                                                                         ("rework", "cut off, re-weld by hand")]
    with open(tmp_path / "qa_report.csv") as f:
        table = list(csv.DictReader(f))
    assert [(r["rework"], r["rework_note"]) for r in table] == [("accept", ""), ("rework", "cut off, re-weld by hand")]
    page = (tmp_path / "qa_report.html").read_text()
    assert "rework: cut off, re-weld by hand" in page and page.count("data:image/png;base64,") == 1


def test_no_record_yet_is_none_and_a_foreign_file_an_error_naming_it(tmp_path):
    assert apply_rework(tmp_path, {"S0001": {"decision": "rework"}}) is None
    (tmp_path / "qa_report.json").write_text('{"weld": 1}')
    with pytest.raises(ValueError, match=r"qa_report.json: not a QA record"):
        apply_rework(tmp_path, {"S0001": {"decision": "rework"}})
