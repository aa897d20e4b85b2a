"""Weld journal: checksummed durable JSON lines and a mirror, welded/uncertain sets, torn tails vs.
corruption, failed appends, legacy files, operator decisions (operator repair: test_journal_repair.py)."""
from __future__ import annotations

import errno
import json
import os
import zlib
from pathlib import Path

import numpy as np
import pytest

from rm65_driver.journal.records import (
    DECISION_NOT_WELDED,
    DECISION_WELDED,
    TRANSITIONS,
    JournalError,
    encode_record,
    mirror_path,
)
from rm65_driver.journal.scan import JournalCorrupt
from rm65_driver.journal.writer import Journal
from rm65_testing import nul_block_over_one_stud, random_bytes, write_job
from stud_common.vocabulary import JournalStatus


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


def test_every_record_is_written_before_its_fsync_in_the_journal_and_its_mirror(tmp_path, monkeypatch):
    """At each fsync the new record must already be readable through another file descriptor:
    an fsync issued before the write (or before a flush) would make nothing durable."""
    path = tmp_path / "j.jsonl"
    j = Journal(path)
    seen = []
    real = os.fsync

    def spy(fd):
        target = os.readlink(f"/proc/self/fd/{fd}")
        if target.endswith((".jsonl", ".mirror")):
            with open(target, "rb") as other:  # another descriptor, another open file description
                seen.append((Path(target).name, other.read().splitlines()[-1:]))
        return real(fd)

    monkeypatch.setattr(os, "fsync", spy)
    j.started("S1", position=[0.1, 0.2, 0.0])
    j.welded("S1")
    names = [name for name, _ in seen]
    assert names == ["j.jsonl", "j.jsonl.mirror", "j.jsonl", "j.jsonl.mirror"]
    events = [json.loads(last[0])["event"] for _, last in seen]
    assert events == ["started", "started", "welded", "welded"]
    assert path.read_bytes() == mirror_path(path).read_bytes()


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


def test_the_journal_speaks_the_cells_vocabulary(tmp_path):
    j = Journal(tmp_path / "j.jsonl")
    assert j.status("never-seen") is JournalStatus.NEW
    j.started("A")
    j.resolve("A", welded=False)
    assert j.status("A") is JournalStatus.NOT_WELDED
    assert (DECISION_WELDED, DECISION_NOT_WELDED) == (JournalStatus.WELDED, JournalStatus.NOT_WELDED)
    for event, rule in TRANSITIONS.items():   # every rule, from every status, lands on a status of the vocabulary
        for before in JournalStatus:
            for decision in (DECISION_WELDED, DECISION_NOT_WELDED):
                assert isinstance(rule(before, {"decision": decision}), JournalStatus), event


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


# -- records, checksums, identity ----------------------------------------------------------------


def test_records_carry_seq_job_journal_id_and_a_crc32_of_their_canonical_json(tmp_path):
    path = write_job(tmp_path / "j.jsonl", n=2)
    recs = [json.loads(x) for x in path.read_text().splitlines()]
    assert [r["seq"] for r in recs] == [1, 2, 3, 4]
    assert {r["job"] for r in recs} == {"job-1"}
    assert len({r["journal"] for r in recs}) == 1 and recs[0]["journal"]
    for line, r in zip(path.read_text().splitlines(), recs):
        assert line.startswith('{"seq":')  # seq, event, stud first: a torn line still names its stud
        body = {k: v for k, v in r.items() if k != "crc"}
        canonical = json.dumps(body, sort_keys=True, separators=(",", ":"), ensure_ascii=True).encode()
        assert r["crc"] == f"{zlib.crc32(canonical):08x}"
    with Journal(path) as j:  # the id is the file's, across opens
        j.skipped("S9", "out of reach")
    assert json.loads(path.read_text().splitlines()[-1])["journal"] == recs[0]["journal"]


def test_a_record_that_is_not_finite_json_is_refused_before_anything_is_written(tmp_path):
    j = Journal(tmp_path / "j.jsonl")
    with pytest.raises(JournalError, match="not written"):
        j.started("S1", position=[float("nan"), 0.0, 0.0])
    assert (tmp_path / "j.jsonl").read_bytes() == b"" and j.status("S1") == "new"


# -- torn tail: tolerated, its stud uncertain ----------------------------------------------------


def test_a_torn_tail_naming_a_stud_makes_that_stud_uncertain(tmp_path):
    path = write_job(tmp_path / "j.jsonl", n=2)
    with open(path, "ab") as f:
        f.write(b'{"seq":5,"event":"skipped","stud":"S7","job":"jo')  # power cut mid-write
    j = Journal(path)
    assert j.uncertain_ids == {"S7"} and j.welded_ids == {"S1", "S2"}
    assert len(j.warnings) == 1 and "torn last line" in j.warnings[0] and "S7 now uncertain" in j.warnings[0]
    j.close()
    # the torn bytes stay as evidence, acknowledged by a torn_tail record; both copies agree
    lines = path.read_bytes().splitlines()
    assert lines[4].startswith(b'{"seq":5,"event":"skipped"') and json.loads(lines[5])["event"] == "torn_tail"
    assert path.read_bytes() == mirror_path(path).read_bytes()
    j2 = Journal(path)
    assert j2.uncertain_ids == {"S7"} and len(j2.warnings) == 1 and "acknowledged by line 6" in j2.warnings[0]


def test_a_torn_tail_without_a_stud_makes_the_last_open_started_uncertain(tmp_path):
    path = write_job(tmp_path / "j.jsonl", n=2)
    with open(path, "ab") as f:
        f.write(b'{"se')
    with Journal(path) as j:
        assert j.uncertain_ids == set() and "no stud affected" in j.warnings[0]
    path = write_job(tmp_path / "k.jsonl", n=2, uncertain_last=True)
    with open(path, "ab") as f:
        f.write(b'{"seq":6,"ev')
    with Journal(path) as j:
        assert j.uncertain_ids == {"Sx"}


def test_a_checksum_failing_last_line_with_its_newline_is_a_torn_tail_too(tmp_path):
    path = write_job(tmp_path / "j.jsonl", n=2)
    data = path.read_bytes()
    path.write_bytes(data[:-12] + b"0000000000\"}\n")  # the last record's crc scrambled
    mirror_path(path).write_bytes(data[: data.rindex(b"\n", 0, len(data) - 1) + 1])  # mirror one behind
    with Journal(path) as j:
        assert j.uncertain_ids == {"S2"} and j.welded_ids == {"S1"}


# -- corruption: file and line, nothing written --------------------------------------------------


def _crc_mismatch_in_the_middle(path):
    lines = path.read_text().splitlines(keepends=True)
    lines[2] = lines[2].replace('"event":"started"', '"event":"skipped"')
    path.write_text("".join(lines))
    return "line 3 (checksum mismatch"


def _unknown_event_in_the_middle(path):
    lines = path.read_text().splitlines(keepends=True)
    rec = json.loads(lines[2])
    rec["event"] = "forgotten"
    lines[2] = encode_record(rec).decode()  # a valid checksum, an event no driver writes
    path.write_text("".join(lines))
    return "line 3 (unknown event"


def _a_line_deleted(path):
    lines = path.read_text().splitlines(keepends=True)
    del lines[3]
    path.write_text("".join(lines))
    return "line 4 (record seq 5, expected 4"


def _legacy_record_after_checksummed_ones(path):
    lines = path.read_text().splitlines(keepends=True)
    lines.insert(4, json.dumps({"t": "x", "event": "skipped", "stud": "S3", "reason": "r"}) + "\n")
    path.write_text("".join(lines))
    return "line 5 (record without checksum"


@pytest.mark.parametrize("damage", [random_bytes, nul_block_over_one_stud, _crc_mismatch_in_the_middle,
                                    _unknown_event_in_the_middle, _a_line_deleted,
                                    _legacy_record_after_checksummed_ones])
def test_damage_other_than_a_torn_tail_is_corruption_naming_file_and_line(tmp_path, damage):
    path = write_job(tmp_path / "j.jsonl")
    where = damage(path)
    before = path.read_bytes(), mirror_path(path).read_bytes()
    with pytest.raises(JournalCorrupt) as exc:
        Journal(path)
    msg = str(exc.value)
    assert f"weld journal {path} is damaged" in msg and where in msg, msg
    assert exc.value.report.backup == mirror_path(path) and "is intact (16 records)" in msg
    assert (path.read_bytes(), mirror_path(path).read_bytes()) == before  # nothing written


def test_a_damaged_mirror_is_a_fault_offering_the_intact_journal(tmp_path):
    path = write_job(tmp_path / "j.jsonl")
    nul_block_over_one_stud(mirror_path(path))
    with pytest.raises(JournalCorrupt) as exc:
        Journal(path)
    assert f"its mirror {mirror_path(path)} is damaged: line 5 (not JSON" in str(exc.value)
    assert exc.value.report.backup == path


def test_a_journal_cut_cleanly_at_a_line_is_caught_by_its_mirror(tmp_path):
    path = write_job(tmp_path / "j.jsonl")
    lines = path.read_bytes().splitlines(keepends=True)
    path.write_bytes(b"".join(lines[:-4]))  # the last two studs' records gone, every line intact
    with pytest.raises(JournalCorrupt, match="the mirror has 4 record") as exc:
        Journal(path)
    assert exc.value.report.backup == mirror_path(path)
    path.unlink()
    with pytest.raises(JournalCorrupt, match="is missing but its mirror has 16"):
        Journal(path)


def test_a_mirror_one_record_behind_is_brought_level(tmp_path):
    path = write_job(tmp_path / "j.jsonl", n=2)
    data = path.read_bytes()
    mirror_path(path).write_bytes(data[: data.rindex(b"\n", 0, len(data) - 1) + 1])  # crash between the writes
    with Journal(path) as j:
        assert j.welded_ids == {"S1", "S2"} and "one record behind" in j.warnings[0]
    assert mirror_path(path).read_bytes() == path.read_bytes()


# -- failed appends -----------------------------------------------------------------------------


def test_a_failed_append_raises_leaves_complete_records_and_refuses_further_appends(tmp_path, monkeypatch):
    path = tmp_path / "j.jsonl"
    j = Journal(path)
    j.started("S1")
    j.welded("S1")
    real_write = os.write

    def disk_full(fd, data):
        if os.readlink(f"/proc/self/fd/{fd}").endswith(".mirror"):
            real_write(fd, bytes(data[:10]))  # part of the record made it, then the disk was full
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_write(fd, data)

    monkeypatch.setattr(os, "write", disk_full)
    with pytest.raises(JournalError, match=r"cannot write the weld journal .*j.jsonl.mirror: .*No space left"):
        j.started("S2")
    monkeypatch.setattr(os, "write", real_write)
    assert j.status("S2") == "new" and j.fault is not None
    with pytest.raises(JournalError, match="failed earlier"):
        j.welded("S2")
    j.close()
    assert path.read_text().count("\n") == 2 and path.read_bytes() == mirror_path(path).read_bytes()
    with Journal(path) as j2:
        assert j2.welded_ids == {"S1"} and not j2.warnings and j2.fault is None


def test_verify_notices_a_change_made_behind_the_journals_back(tmp_path):
    path = write_job(tmp_path / "j.jsonl", n=3)
    j = Journal(path)
    j.verify()
    nul_block_over_one_stud(path)
    with pytest.raises(JournalCorrupt, match="line 5"):
        j.verify()
    with pytest.raises(JournalError, match="failed earlier"):
        j.started("S9")
    j.close()


# -- legacy journals ----------------------------------------------------------------------------


def test_legacy_records_without_checksum_are_accepted_read_only_with_a_warning(tmp_path):
    path = tmp_path / "j.jsonl"
    legacy = "".join(json.dumps(r) + "\n" for r in (
        {"t": "x", "event": "started", "stud": "L1"}, {"t": "x", "event": "welded", "stud": "L1"},
        {"t": "x", "event": "started", "stud": "L2"}))
    path.write_text(legacy)
    j = Journal(path)
    assert any("3 legacy records without checksum" in w for w in j.warnings)
    assert j.welded_ids == {"L1"} and j.uncertain_ids == {"L2"}
    j.resolve("L2", welded=False)
    j.close()
    assert path.read_text().startswith(legacy)  # never rewritten
    new = json.loads(path.read_text().splitlines()[-1])
    assert new["seq"] == 4 and "crc" in new
    with Journal(path) as j2:
        assert j2.status("L2") == "not_welded"
    path.write_text(legacy.replace('"stud": "L2"}', '"stud": "L2"'))  # a broken legacy line mid-file
    path.write_text(path.read_text() + legacy)
    mirror_path(path).unlink()
    with pytest.raises(JournalCorrupt, match="line 3"):
        Journal(path)


# -- status rules -------------------------------------------------------------------------------


def test_a_skip_never_downgrades_an_uncertain_stud(tmp_path):
    path = tmp_path / "j.jsonl"
    with Journal(path) as j:
        j.started("S1")
        j.skipped("S1", "needs an operator decision")
        assert j.is_uncertain("S1")
    with Journal(path) as j:
        assert j.is_uncertain("S1")
        j.resolve("S1", welded=False)
        j.skipped("S1", "out of reach")
        assert j.status("S1") == "skipped"


def test_welded_is_final(tmp_path):
    path = tmp_path / "j.jsonl"
    with Journal(path) as j:
        j.started("S1")
        j.welded("S1")
        j.started("S1")  # a second attempt the sequence never makes: still welded
        assert j.is_welded("S1")
        with pytest.raises(JournalError, match="not uncertain"):
            j.resolve("S1", welded=False)
