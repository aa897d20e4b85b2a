"""strict_json: every JSON the project writes is RFC 8259 (no NaN/Infinity tokens; missing = null)."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from stud_common.strict_json import dumps, dumps_document, json_safe, write_json


def strict_loads(text: str):
    """json.loads that refuses the NaN/Infinity tokens Python's own json would accept."""
    def refuse(token):
        raise AssertionError(f"not RFC 8259 JSON: {token}")
    return json.loads(text, parse_constant=refuse)


DOC = {"a": math.nan, "b": [1.0, math.inf, -math.inf, np.float64("nan"), np.int64(3), np.bool_(True)],
       "c": (2, "x"), "d": None, "e": {"x": np.arange(3), "y": np.array([np.nan, 1.5])}, "p": Path("/tmp/r.json"),
       "rows": [{"k": 1}, {"k": math.nan}], "empty": []}
EXPECTED = {"a": None, "b": [1.0, None, None, None, 3, True], "c": [2, "x"], "d": None,
            "e": {"x": [0, 1, 2], "y": [None, 1.5]}, "p": "/tmp/r.json", "rows": [{"k": 1}, {"k": None}], "empty": []}


@pytest.mark.parametrize("encode", [dumps, lambda o: dumps(o, compact=True), dumps_document])
def test_non_finite_numbers_are_null_and_numpy_values_plain(encode):
    text = encode(DOC)
    assert "NaN" not in text and "Infinity" not in text
    assert strict_loads(text) == EXPECTED


def test_a_document_has_one_line_per_key_and_per_row():
    text = dumps_document({"drawing": "d.dxf", "targets": [{"stud_id": "S1"}, {"stud_id": "S2"}], "n": 2})
    assert text.splitlines() == ['{', ' "drawing": "d.dxf",', ' "targets": [', '  {"stud_id": "S1"},',
                                 '  {"stud_id": "S2"}', ' ],', ' "n": 2', '}']


def test_write_json_is_strict_atomic_and_makes_folders(tmp_path):
    path = write_json(tmp_path / "out" / "report.json", DOC)
    assert strict_loads(path.read_text()) == EXPECTED and path.read_text().endswith("\n")
    assert [p.name for p in path.parent.iterdir()] == ["report.json"]  # no temporary file left


def test_what_json_cannot_carry_is_an_error_not_a_file(tmp_path):
    with pytest.raises(TypeError):
        write_json(tmp_path / "x.json", {"obj": object()})
    assert not (tmp_path / "x.json").exists()
    assert json_safe({1: 2.5}) == {"1": 2.5}
