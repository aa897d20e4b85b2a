"""Operator repair of a corrupt weld journal (journal_repair): load the intact copy, or keep the
records before the damage and mark every stud mentioned after it uncertain."""
from __future__ import annotations

import json

import pytest

from rm65_driver.journal.records import JournalError, mirror_path
from rm65_driver.journal.repair import ACTION_ACCEPT_INTACT, ACTION_LOAD_BACKUP, repair_journal
from rm65_driver.journal.scan import JournalCorrupt
from rm65_driver.journal.writer import Journal
from rm65_testing import nul_block_over_one_stud, random_bytes, write_job


def test_load_backup_restores_the_mirror_and_moves_the_damaged_file_aside(tmp_path):
    path = write_job(tmp_path / "j.jsonl", uncertain_last=True)
    random_bytes(path)
    with pytest.raises(JournalError, match="unknown journal action"):
        repair_journal(path, "fix_it")
    msg = repair_journal(path, ACTION_LOAD_BACKUP, note="disk checked")
    assert "loaded" in msg and ".corrupt-" in msg
    [aside] = tmp_path.glob("j.jsonl.corrupt-*")
    assert len(aside.read_bytes()) == 4096
    with Journal(path) as j:
        assert j.welded_ids == {f"S{i}" for i in range(1, 9)} and j.uncertain_ids == {"Sx"} and not j.warnings
        last = json.loads(path.read_text().splitlines()[-1])
        assert last["event"] == "recovered" and last["action"] == "load_backup" and last["note"] == "disk checked"
    assert "intact: nothing to repair" in repair_journal(path, ACTION_LOAD_BACKUP)


def test_accept_intact_keeps_the_records_before_the_damage_and_marks_later_studs_uncertain(tmp_path):
    path = write_job(tmp_path / "j.jsonl")
    with Journal(path) as j:
        j.skipped("S1", "already welded")  # after the damage below, but S1 is welded before it: stays welded
        j.skipped("S20", "unreachable")
    nul_block_over_one_stud(path)
    random_bytes(mirror_path(path))  # no intact copy left
    with pytest.raises(JournalCorrupt) as exc:
        Journal(path)
    assert exc.value.report.backup is None and "first 4 record(s)" in str(exc.value)
    with pytest.raises(JournalError, match="no intact copy"):
        repair_journal(path, ACTION_LOAD_BACKUP)
    msg = repair_journal(path, ACTION_ACCEPT_INTACT, note="checked the plate")
    assert "kept 4 intact record(s)" in msg
    with Journal(path) as j:
        assert j.welded_ids == {"S1", "S2"}
        # S3 was under the NUL block: nothing names it any more (the operator is told 'first 4 records')
        assert j.uncertain_ids == {"S4", "S5", "S6", "S7", "S8", "S20"}
        assert j.status("S3") == "new"
    assert len(list(tmp_path.glob("j.jsonl*.corrupt-*"))) == 2


def test_accept_intact_uses_what_the_mirror_still_knows(tmp_path):
    path = write_job(tmp_path / "j.jsonl")
    random_bytes(path)  # the whole journal gone; the mirror intact
    repair_journal(path, ACTION_ACCEPT_INTACT)
    with Journal(path) as j:
        assert j.welded_ids == set() and j.uncertain_ids == {f"S{i}" for i in range(1, 9)}
