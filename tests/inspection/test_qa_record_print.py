"""The QA record's page prints: headless Chromium renders qa_report.html to PDF on A4, and the demo's
record -- the bundled dome's 9 studs, its inspection overlay, the code, the bend-test list and the
signature block -- fits on two pages. A 400-stud job's page lists the studs that need attention and
says where the rest are. Skipped without Chromium (set CHROMIUM=/path), failed under CI=true."""
from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np
import pytest

import chromium_pdf
from chromium_pdf import find_chromium
from stud_inspection import qa_codes
from stud_inspection.inspection import InspectionLimits, draw_inspection_overlay, inspect_studs
from stud_inspection.qa_report import empty_row, write_qa_report
from stud_perception.scene_render import render
from stud_perception.welded_studs import WeldDefect
from welded_views import bundled, over, weld_and_shoot, with_defects

CHROMIUM = find_chromium()


@pytest.fixture(autouse=True)
def _chromium(prerequisite):
    prerequisite(CHROMIUM is not None, "no Chromium binary found (apt-get install chromium, or set CHROMIUM=/path)")


def print_to_pdf(page: Path, tmp_path: Path) -> tuple[int, bytes]:
    assert CHROMIUM is not None
    return chromium_pdf.print_to_pdf(CHROMIUM, page, tmp_path)


def _demo_record(out: Path) -> dict:
    """The demo's QA record, made as the cell makes it: the bundled dome welded (one stud leaning), the
    inspection of the shot after the welds, its overlay, a signed decision."""
    scene = bundled("dome")
    ids = list(scene.stud_ids)
    scene_d = with_defects(scene, {ids[3]: WeldDefect(lean_deg=8.0)})
    camera = over(scene)
    shots = weld_and_shoot(scene_d, camera, ids)
    limits = qa_codes.profile("gb50205").limits(nominal_length_mm=50.0)
    ins = inspect_studs(shots.planned_w, shots.normals_w, shots.ok, shots.before_m, shots.after_m, camera, limits)
    colour = render(scene_d, camera, welded=tuple(s for s in shots.studs if s is not None)).color_bgr
    overlay = out / "qa" / "inspection_station_01.png"
    overlay.parent.mkdir(parents=True)
    cv2.imwrite(str(overlay), draw_inspection_overlay(colour, ids, shots.planned_w, ins, camera))
    rows = []
    for k, (sid, xy, m, p, n) in enumerate(zip(ids, np.asarray(scene.studs_drawing_m) * 1e3, ins.studs,
                                               shots.planned_w, shots.normals_w)):
        rows.append({**empty_row(sid, xy), "verdict": m.verdict.value, "reasons": list(m.reasons), "station": 1,
                     "weld_seq": k + 1, "planned": {"position_m": list(p), "normal": list(n)},
                     "measured": m.measured_dict()})
    assert [r["verdict"] for r in rows].count("fail") == 1
    return write_qa_report(out, {"id": "20250501-101500", "part": "dome", "drawing": "dome_demo.dxf", "state": "done",
                                 "message": "job done: 9/9 studs welded"}, limits.to_dict(), rows, [], [overlay],
                           decisions={ids[3]: {"decision": "rework", "note": "lean 8 deg by gauge: cut off, re-weld",
                                               "operator": "A. Inspector", "time": "2025-05-01T10:20:00+00:00"}},
                           code=qa_codes.profile("gb50205").describe(), seed=20250501,
                           bends={ids[0]: {"result": "pass", "bent_deg": 30.0, "note": "", "operator": "B. Welder",
                                           "time": "2025-05-01T10:30:00+00:00"}})


def test_the_demos_record_prints_on_two_a4_pages_or_fewer(tmp_path):
    doc = _demo_record(tmp_path / "demo")
    page = tmp_path / "demo" / "qa_report.html"
    text = page.read_text()
    for must in ("GB 50205", "dome_demo.dxf", "Bend tests", "Inspector (name, signature)", "A. Inspector", "B. Welder",
                 "<svg class='map'", "data:image/png;base64,"):
        assert must in text, must
    assert doc["sampling"]["counts"]["listed"] == 8  # the 8 that passed (fewer than 10: all), the failure reworked
    pages, pdf = print_to_pdf(page, tmp_path)
    assert 1 <= pages <= 2, pages
    assert b"/MediaBox [0 0 594.95996 841.91998]" in pdf or re.search(rb"/MediaBox\s*\[0 0 59[45](\.\d+)? 84[12]", pdf)


def test_a_400_stud_jobs_page_lists_the_studs_that_need_attention_and_prints(tmp_path):
    rows = [{**empty_row(f"S{k + 1:04d}", (k % 20 * 50.0, k // 20 * 50.0)), "verdict": "pass", "weld_seq": k + 1}
            for k in range(400)]
    rows[17].update(verdict="fail", reasons=["offset 4.2 mm > 2 mm"])
    write_qa_report(tmp_path, {"id": "J400"}, InspectionLimits(nominal_length_mm=150.0).to_dict(), rows, [], [],
                    code=qa_codes.profile("gb50205").describe(), seed=3)
    text = (tmp_path / "qa_report.html").read_text()
    shown = text.count("<tr class=")
    assert 10 + 1 <= shown <= 10 + 1 + 6  # the failure, its neighbours, the lot sample (some may coincide)
    assert f"{shown} of 400 studs shown" in text and "qa_report.csv" in text
    pages, _pdf = print_to_pdf(tmp_path / "qa_report.html", tmp_path)
    assert pages <= 3, pages
