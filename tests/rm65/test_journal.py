"""Weld journal: durable JSON lines, welded/uncertain sets, torn last line, operator decisions."""
from __future__ import annotations

import json
import os

import numpy as np
import pytest

from rm65_driver.journal import Journal, JournalError


def test_records_are_json_lines_and_survive_a_reload(tmp_path):
    path = tmp_path / "sub" / "weld.jsonl"
    with Journal(path) as j:
        j.started("S1", position=np.array([0.1, 0.2, 0.0]))
        j.welded("S1")
        j.skipped("S2", "inclination 7.0 deg > 5.0 deg limit")
        j.started("S3")
    lines = path.read_text().splitlines()
    assert [json.loads(x)["event"] for x in lines] == ["started", "welded", "skipped", "started"]
    assert json.loads(lines[0])["position"] == [0.1, 0.2, 0.0]
    j2 = Journal(path)
    assert j2.welded_ids == {"S1"}
    assert j2.uncertain_ids == {"S3"}
    assert j2.status("S2") == "skipped" and j2.status("S9") == "new"
    assert j2.warnings == []


def test_every_record_is_fsynced_before_returning(tmp_path, monkeypatch):
    synced = []
    real = os.fsync
    monkeypatch.setattr(os, "fsync", lambda fd: (synced.append(fd), real(fd)))
    j = Journal(tmp_path / "j.jsonl")
    before = len(synced)
    j.started("S1")
    assert len(synced) == before + 1
    assert (tmp_path / "j.jsonl").read_text().count("\n") == 1  # flushed, visible to another reader


def test_torn_last_line_is_ignored_with_a_warning_and_appends_start_clean(tmp_path):
    path = tmp_path / "j.jsonl"
    with Journal(path) as j:
        j.started("S1")
        j.welded("S1")
        j.started("S2")
    with open(path, "ab") as f:
        f.write(b'{"t":"2026-11-22T10:00:00","event":"wel')  # crash mid-write
    j = Journal(path)
    assert len(j.warnings) == 1 and "torn last line" in j.warnings[0]
    assert j.welded_ids == {"S1"} and j.uncertain_ids == {"S2"}
    j.resolve("S2", welded=False, note="checked by hand")
    j.close()
    j3 = Journal(path)
    assert j3.status("S2") == "not_welded"
    assert len(j3.warnings) == 1 and "invalid line" in j3.warnings[0]  # the old torn line, now mid-file


def test_resolving_uncertain_studs(tmp_path):
    j = Journal(tmp_path / "j.jsonl")
    j.started("A")
    j.started("B")
    j.resolve("A", welded=True, note="visual check: stud present")
    j.resolve("B", welded=False)
    assert j.welded_ids == {"A"} and j.uncertain_ids == set()
    assert j.status("B") == "not_welded"
    with pytest.raises(JournalError, match="not uncertain"):
        j.resolve("A", welded=True)
    with pytest.raises(JournalError, match="not uncertain"):
        j.resolve("never-seen", welded=False)
    assert j.last_record("A")["decision"] == "welded"


def test_skip_never_downgrades_a_welded_stud(tmp_path):
    j = Journal(tmp_path / "j.jsonl")
    j.started("S1")
    j.welded("S1")
    j.skipped("S1", "already welded")
    assert j.is_welded("S1")


def test_empty_and_blank_files(tmp_path):
    path = tmp_path / "j.jsonl"
    path.write_text("\n\n")
    j = Journal(path)
    assert j.welded_ids == set() and j.warnings == []
