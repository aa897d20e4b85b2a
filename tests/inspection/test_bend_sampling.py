"""Which studs the inspector must bend-test (stud_inspection.sampling) and how the QA record carries them:
a 400-stud job's record lists a lot sample of >= 10 and >= 1 % spread over the part, drawn again from
the seed stored in it; the 3 + 3 neighbours in weld order of every failure (inspection or bend test);
the shift's pre-production test studs; under AWS D1.1 the studs without a full collar, bent away
from the gap; and every result entered, signed."""
from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest

from stud_inspection import bend, qa_codes
from stud_inspection.qa_report import CSV_FIELDS, apply_operator_entries, empty_row, read_record, write_qa_report
from stud_inspection.sampling import lot_sample, morton_order, plan_bend_tests


def part_of_400(pitch_mm=50.0):
    """A 20 x 20 grid of studs, welded row by row in a serpentine (the weld order is not the drawing's)."""
    rows = []
    for i in range(20):
        for j in range(20):
            rows.append(empty_row(f"S{i * 20 + j + 1:04d}", (j * pitch_mm, i * pitch_mm)))
    seq = 0
    for i in range(20):
        for j in (range(20) if i % 2 == 0 else range(19, -1, -1)):
            seq += 1
            rows[i * 20 + j].update(verdict="pass", weld_seq=seq, station=1)
    return rows


def by_id(rows):
    return {r["stud_id"]: r for r in rows}


def _write(tmp_path, rows, code="gb50205", seed=1234, **kw):
    return write_qa_report(tmp_path, {"id": "J400", "part": "deck"}, {"max_lean_deg": 5.0}, rows, [], [],
                           code=qa_codes.profile(code).describe(), seed=seed, **kw)


def _reasons(doc):
    return {t["stud_id"]: t["reasons"] for t in doc["sampling"]["bend_tests"]}


def test_a_400_stud_record_lists_a_lot_sample_of_10_spread_over_the_part_drawn_again_from_its_seed(tmp_path):
    rows = part_of_400()
    doc = _write(tmp_path, rows)
    sample = [sid for sid, why in _reasons(doc).items() if any(w.startswith("lot sample") for w in why)]
    assert len(sample) == 10 == max(10, math.ceil(0.01 * 400))  # GB 50205: >= 1 % and at least 10 per lot
    assert (doc["sampling"]["seed"] == 1234 and doc["sampling"]["lot_sample"] == 10
            and doc["code"]["profile"] == "gb50205")
    # spread over the part, whatever the seed: each quarter of the part holds at least 2 of the 10 (a random
    # draw leaves a quarter empty one time in 20), and the farthest stud from the sample is nearer than a
    # random draw's
    grid = np.array([r["drawing_xy_mm"] for r in rows])
    ids = [r["stud_id"] for r in rows]
    rng = np.random.default_rng(0)
    reach, reach_random = [], []
    for seed in range(40):
        xy = grid[[ids.index(s) for s in lot_sample(ids, grid, 10, seed)]]
        per_quarter = np.bincount((xy[:, 0] >= 500.0) * 2 + (xy[:, 1] >= 500.0), minlength=4)
        assert per_quarter.min() >= 2, (seed, per_quarter)
        reach.append(np.min(np.linalg.norm(grid[:, None] - xy[None], axis=2), axis=1).max())
        xr = grid[rng.choice(400, 10, replace=False)]
        reach_random.append(np.min(np.linalg.norm(grid[:, None] - xr[None], axis=2), axis=1).max())
    assert np.mean(reach) < 0.85 * np.mean(reach_random), (np.mean(reach), np.mean(reach_random))
    # anyone can draw it again from the record alone: the same seed and rows, the same sample
    again = read_record(tmp_path)
    rules = qa_codes.SamplingRules.from_dict(again["code"]["sampling"])
    redrawn = plan_bend_tests(again["studs"], rules, again["sampling"]["seed"])
    assert [t.stud_id for t in redrawn] == [t["stud_id"] for t in doc["sampling"]["bend_tests"]]
    other = plan_bend_tests(again["studs"], rules, 99)
    assert [t.stud_id for t in other] != [t.stud_id for t in redrawn]  # another seed, another sample
    # a larger lot: 1 %
    big = [empty_row(f"T{k:05d}", (k % 50 * 20.0, k // 50 * 20.0)) | {"verdict": "pass", "weld_seq": k + 1}
           for k in range(2500)]
    assert len(plan_bend_tests(big, rules, 5)) == 25


def test_the_3_and_3_neighbours_in_weld_order_of_every_failure_are_listed(tmp_path):
    rows = part_of_400()
    ids = by_id(rows)
    ids["S0025"].update(verdict="fail", reasons=["lean 8.2 deg > 5 deg"])  # row 2, welded right to left
    ids["S0200"].update(verdict="missing", reasons=["no stud stands at the weld point"])
    doc = _write(tmp_path, rows, code="iso14555")
    listed = _reasons(doc)
    order = sorted(rows, key=lambda r: r["weld_seq"])
    position = {r["stud_id"]: k for k, r in enumerate(order)}
    for failed, why in (("S0025", "fail"), ("S0200", "missing")):
        k = position[failed]
        neighbours = [r["stud_id"] for r in order[k - 3:k] + order[k + 1:k + 4]]
        for sid in neighbours:
            assert f"welded next to {failed} ({why})" in listed[sid], (failed, sid, listed.get(sid))
        assert failed not in listed  # a failure is reworked, not bent
    # S0025's neighbours in weld order are not its drawing neighbours: row 2 runs backwards
    assert {by_id(rows)[s]["weld_seq"] for s in listed if any("S0025" in w for w in listed[s])} == {
        ids["S0025"]["weld_seq"] + d for d in (-3, -2, -1, 1, 2, 3)}
    # EN ISO 14555's pre-production test: the shift's first 3 studs; no lot sample
    pre = [sid for sid, why in listed.items() if any(w.startswith("pre-production") for w in why)]
    assert pre == ["S0001", "S0002", "S0003"] and doc["sampling"]["lot_sample"] == 0
    assert all(t["angle_deg"] == 60.0 for t in doc["sampling"]["bend_tests"])


def test_a_failed_bend_test_puts_its_neighbours_on_the_list_and_results_are_signed(tmp_path):
    rows = part_of_400()
    doc = _write(tmp_path, rows)
    tested = next(t["stud_id"] for t in doc["sampling"]["bend_tests"])
    log = tmp_path / "qa" / bend.FILE_NAME
    with pytest.raises(bend.BendError, match="no operator name"):
        bend.make_record(tested, "fail", 30.0, "", "", "pass", 1.0)
    with pytest.raises(bend.BendError, match="'missing'"):
        bend.make_record(tested, "fail", 30.0, "", "A. Inspector", "missing", 1.0)
    with pytest.raises(bend.BendError, match="not one of pass, fail"):
        bend.make_record(tested, "cracked", 30.0, "", "A. Inspector", "pass", 1.0)
    bend.append_record(log, bend.make_record(tested, "FAIL", 30.0, "weld cracked", "A. Inspector", "pass", 1.0e9))
    results = {s: r.for_qa_record() for s, r in bend.latest_results(log).items()}
    after = apply_operator_entries(tmp_path, {}, results)
    k = by_id(rows)[tested]["weld_seq"]
    neighbours = {r["stud_id"] for r in rows if r["weld_seq"] in (k - 3, k - 2, k - 1, k + 1, k + 2, k + 3)}
    listed = _reasons(after)
    assert all(f"welded next to {tested} (bend test failed)" in listed[s] for s in neighbours)
    row = by_id(after["studs"])[tested]
    assert (row["bend_test"]["result"], row["bend_test"]["operator"], row["bend_test"]["note"]) == (
        "fail", "A. Inspector", "weld cracked")
    assert row["bend_test"]["time"].startswith("2001-09-09T01:46:40")
    assert after["sampling"]["counts"] == {"listed": len(listed), "passed": 0, "failed": 1,
                                           "pending": len(listed) - 1}
    # the lot sample is the same as before the result: drawn from the same seed and verdicts
    lot = lambda d: sorted(s for s, w in _reasons(d).items() if any(x.startswith("lot sample") for x in w))  # noqa: E731
    assert lot(after) == lot(doc)
    # the CSV: one row per stud, the bend test's columns filled, opens as a plain table
    with open(tmp_path / "qa_report.csv", newline="", encoding="utf-8") as f:
        table = list(csv.DictReader(f))
    assert len(table) == 400 and list(table[0]) == CSV_FIELDS
    got = {r["stud_id"]: r for r in table}
    assert (got[tested]["bend_result"], got[tested]["bend_operator"], got[tested]["bend_angle_deg"]) == (
        "fail", "A. Inspector", "30.0")
    assert all(got[s]["bend_test"] for s in neighbours) and got[tested]["weld_seq"] == str(k)


def test_under_aws_a_stud_without_a_full_collar_is_bent_15_deg_away_from_its_gap(tmp_path):
    rows = part_of_400()
    r = by_id(rows)["S0100"]
    r.update(verdict="fail", reasons=["collar 150 deg of the 260 deg seen: a 110 deg gap (360 deg of at least 1 mm "
                                      "required)"],
             measured={"position_m": [0.0, 0.0, 0.0], "axis": [0, 0, 1], "lean_deg": 0.5, "offset_mm": [0.1, 0.0],
                       "height_mm": 50.0, "collar_seen_deg": 260.0, "collar_coverage_deg": 150.0,
                       "collar_height_mm": 4.1, "collar_gap_deg": 110.0, "collar_gap_azimuth_deg": 60.0})
    doc = _write(tmp_path, rows, code="aws_d1_1")
    tests = {t["stud_id"]: t for t in doc["sampling"]["bend_tests"]}
    t = tests["S0100"]
    assert t["angle_deg"] == 15.0 and t["reasons"] == ["collar (flash) not 360 deg"]
    assert "toward azimuth -120 deg" in t["direction"]
    pre = [s for s, x in tests.items() if any(w.startswith("pre-production") for w in x["reasons"])]
    assert pre == ["S0001", "S0002"] and all(tests[s]["angle_deg"] == 30.0 for s in pre)
    # GB 50205: the same stud fails; no 15 deg test, its neighbours tested instead
    doc = _write(tmp_path, rows, code="gb50205")
    assert "S0100" not in _reasons(doc)


def test_the_sample_is_spread_by_the_z_curve_and_every_run_gives_one():
    xy = np.array([[x, y] for x in range(8) for y in range(8)], dtype=float)
    order = morton_order(xy)
    first_quarter = xy[order[:16]]
    assert np.ptp(first_quarter[:, 0]) == 3 and np.ptp(first_quarter[:, 1]) == 3  # a compact 4 x 4 patch
    ids = [f"S{k}" for k in range(64)]
    picked = lot_sample(ids, xy, 4, seed=3)
    quads = {(xy[ids.index(s)][0] >= 4, xy[ids.index(s)][1] >= 4) for s in picked}
    assert len(picked) == 4 and len(quads) == 4
    assert lot_sample(ids, xy, 4, seed=3) == picked and lot_sample(ids, xy, 0, seed=3) == []
    assert sorted(lot_sample(ids[:3], xy[:3], 10, seed=1)) == sorted(ids[:3])  # no more than there are


def test_decisions_in_the_record_say_who_and_when(tmp_path):
    rows = part_of_400()
    by_id(rows)["S0007"].update(verdict="fail", reasons=["offset 4.1 mm > 2 mm"])
    doc = _write(tmp_path, rows, decisions={"S0007": {"decision": "rework", "note": "cut off", "operator": "C. Chief",
                                                      "time": "2025-05-01T10:00:00.000+00:00"}})
    row = by_id(doc["studs"])["S0007"]
    assert (row["rework"], row["rework_note"], row["rework_operator"], row["rework_time"]) == (
        "rework", "cut off", "C. Chief", "2025-05-01T10:00:00.000+00:00")
    page = (tmp_path / "qa_report.html").read_text()
    assert "C. Chief" in page and "Inspector (name, signature)" in page and "GB 50205" in page
    assert json.loads((tmp_path / "qa_report.json").read_text())["studs"][6]["rework_operator"] == "C. Chief"
