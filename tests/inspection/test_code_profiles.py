"""The code profiles (stud_inspection.qa_codes): on the bundled dome and shell with one defect of each
kind injected -- lean, offset, missing, height, collar -- each is caught with its reason under every
code, and no clean stud fails; a scene that numbers its studs its own way gives the same verdicts. And
the table itself: cited, overridable per value, with errors that name what is wrong."""
from __future__ import annotations

import math

import numpy as np
import pytest

from stud_inspection import qa_codes
from stud_inspection.inspection import Verdict, inspect_studs
from stud_perception.welded_studs import WeldDefect
from welded_views import bundled, over, weld_and_shoot, with_defects

KINDS = ("lean", "offset", "missing", "height", "collar")


def _defects(ids):
    return {ids[1]: WeldDefect(lean_deg=8.0, lean_azimuth_deg=30.0), ids[2]: WeldDefect(offset_mm=(4.0, 0.0)),
            ids[3]: WeldDefect(missing=True), ids[4]: WeldDefect(height_mm=38.0),
            ids[5]: WeldDefect(collar_coverage_deg=250.0, collar_gap_azimuth_deg=0.0)}


@pytest.mark.parametrize("part", ["dome", "shell"])
def test_each_kind_of_defect_is_caught_with_its_reason_under_every_code_and_clean_studs_pass(part):
    scene = bundled(part)
    ids = list(scene.stud_ids)
    shots = weld_and_shoot(with_defects(scene, _defects(ids)), over(scene), ids)
    # the same part in a scene file that numbers its studs its own way: the welds (named by the drawing)
    # get the same defects, by where they are
    rename = {sid: f"{part}-{k:03d}" for k, sid in enumerate(reversed(ids))}
    renamed = weld_and_shoot(with_defects(scene, _defects(ids), rename), over(scene), ids)
    expected = dict(zip(ids[1:6], KINDS))
    for code in qa_codes.CODES:
        limits = qa_codes.profile(code).limits(nominal_length_mm=50.0)
        verdicts = []
        for s in (shots, renamed):
            ins = inspect_studs(s.planned_w, s.normals_w, s.ok, s.before_m, s.after_m, s.camera, limits)
            verdicts.append([(m.verdict, m.reasons) for m in ins.studs])
            got = dict(zip(ids, ins.studs))
            for sid, kind in expected.items():
                m = got[sid]
                if kind == "missing":
                    assert m.verdict is Verdict.MISSING, (code, sid, m)
                else:
                    assert m.verdict is Verdict.FAIL and any(kind in r for r in m.reasons), (code, kind, m)
                    others = {k for k in KINDS if k != kind and any(k in r for r in m.reasons)}
                    assert not others, (code, kind, m.reasons)  # the right reason, alone
            for sid in ids:
                if sid not in expected:
                    assert got[sid].verdict is Verdict.PASS, (code, sid, got[sid])
                    assert got[sid].collar is not None and abs(got[sid].collar.height_mm - 4.0) < 0.6
        assert verdicts[0] == verdicts[1], code  # the scene's own numbering changes nothing


def test_the_codes_differ_where_they_say_different_things():
    # EN ISO 13918 allows +1 mm over the design length, GB 50205 +2 mm: a stud 1.6 mm long fails one only
    scene = bundled("dome")
    ids = list(scene.stud_ids)
    shots = weld_and_shoot(with_defects(scene, {ids[0]: WeldDefect(height_mm=51.6)}), over(scene), ids)
    got = {}
    for code in ("gb50205", "iso14555"):
        limits = qa_codes.profile(code).limits(nominal_length_mm=50.0)
        got[code] = inspect_studs(shots.planned_w, shots.normals_w, shots.ok, shots.before_m, shots.after_m,
                                  shots.camera, limits).studs[0]
    assert got["gb50205"].verdict is Verdict.PASS, got["gb50205"]
    assert got["iso14555"].verdict is Verdict.FAIL and "expected 50 +1/-2 mm" in got["iso14555"].reasons[0]


def test_every_value_of_every_profile_has_a_source_and_the_record_says_which_profile():
    for code in qa_codes.CODES:
        p = qa_codes.profile(code)
        d = p.describe()
        assert d["profile"] == code and d["title"]
        for group, names in (("limits", qa_codes.LIMIT_NAMES), ("sampling", qa_codes.SAMPLING_NAMES)):
            assert set(d[group]) == set(names)
            assert all(e["source"] and not e["overridden"] and math.isfinite(e["value"]) for e in d[group].values())
    # the numbers the codes' summaries give (docs/INSPECTION.md cites them)
    gb, iso, aws = (qa_codes.profile(c) for c in ("gb50205", "iso14555", "aws_d1_1"))
    assert (gb.value("max_lean_deg"), gb.value("min_collar_height_mm"), gb.value("height_tol_mm")) == (5.0, 1.0, 2.0)
    assert (gb.sampling().lot_sample_fraction, gb.sampling().lot_sample_min, gb.sampling().bend_angle_deg) == (
        0.01, 10, 30.0)
    assert (iso.value("height_tol_mm"), iso.value("height_tol_below_mm")) == (1.0, 2.0)
    assert (iso.sampling().failure_neighbours, iso.sampling().preproduction_studs) == (3, 3)
    aws_rules = aws.sampling()
    assert (aws_rules.preproduction_studs, aws_rules.bend_angle_deg, aws_rules.missing_flash_bend_deg) == (
        2, 30.0, 15.0)
    assert all(qa_codes.profile(c).value("min_collar_coverage_deg") == 360.0 for c in qa_codes.CODES)


def test_a_value_is_overridden_for_a_job_and_the_record_says_so():
    p = qa_codes.profile("iso14555", {"max_lean_deg": 4.0, "lot_sample_min": 20, "failure_neighbours": -1,
                                      "bend_angle_deg": float("nan")})
    assert p.limits(nominal_length_mm=50.0).max_lean_deg == 4.0 and p.sampling().lot_sample_min == 20
    assert p.sampling().failure_neighbours == 3 and p.sampling().bend_angle_deg == 60.0  # -1 / NaN: the code's
    d = p.describe()
    assert d["limits"]["max_lean_deg"]["overridden"] and "the code's: 5" in d["limits"]["max_lean_deg"]["source"]
    assert d["sampling"]["lot_sample_min"]["overridden"] and not d["sampling"]["bend_angle_deg"]["overridden"]
    assert qa_codes.SamplingRules.from_dict(d["sampling"]) == p.sampling()  # the record alone gives the rules


@pytest.mark.parametrize("code, overrides, match", [
    ("en1090", {}, r"qa_code 'en1090': expected one of gb50205, iso14555, aws_d1_1"),
    ("gb50205", {"max_tilt_deg": 3.0}, r"override 'max_tilt_deg': expected one of max_lean_deg"),
    ("gb50205", {"lot_sample_fraction": 2.0}, r"lot_sample_fraction=2.0: expected a value in \[0, 1\]"),
])
def test_an_unknown_code_or_a_bad_override_is_an_error_naming_it(code, overrides, match):
    with pytest.raises(qa_codes.CodeError, match=match):
        qa_codes.profile(code, overrides)


def test_profiles_are_case_and_space_tolerant_and_their_limits_valid():
    assert qa_codes.profile(" GB50205 ").code == "gb50205"
    for code in qa_codes.CODES:
        lim = qa_codes.profile(code).limits(nominal_length_mm=150.0, stud_diameter_mm=19.0)
        assert lim.stud_diameter_mm == 19.0 and np.isfinite(lim.height_below_mm) and lim.checks_collar
