"""A new weld journal's directory entries are durable: after the journal and its mirror are created,
their directory is fsync'ed before the journal is used. Without it a power cut can lose the files
themselves (the records inside are fsync'ed, their names in the directory are not), and a restarted
driver would find no journal and weld every stud again. Watched like the per-record fsync
(test_journal.py): os.fsync spied on, the descriptor's target read from /proc."""
from __future__ import annotations

import os
from pathlib import Path

from rm65_driver.journal.records import mirror_path
from rm65_driver.journal.writer import Journal


def _spy_fsync(monkeypatch) -> list[tuple[str, bool, set[str]]]:
    """Every os.fsync: (target path, is a directory, the directory's entries then, for a directory)."""
    calls = []
    real = os.fsync

    def spy(fd):
        target = os.readlink(f"/proc/self/fd/{fd}")
        is_dir = os.path.isdir(target)
        calls.append((target, is_dir, set(os.listdir(target)) if is_dir else set()))
        return real(fd)

    monkeypatch.setattr(os, "fsync", spy)
    return calls


def test_a_new_journal_fsyncs_its_directory_once_both_files_exist(tmp_path, monkeypatch):
    calls = _spy_fsync(monkeypatch)
    path = tmp_path / "weld_journal.jsonl"
    with Journal(path) as journal:
        dir_syncs = [entries for target, is_dir, entries in calls if is_dir and Path(target) == tmp_path]
        assert dir_syncs, f"no fsync of {tmp_path} after creating the journal: {calls}"
        assert {path.name, mirror_path(path).name} <= dir_syncs[-1], dir_syncs  # both names made durable
        journal.started("S1")  # and it is usable
    assert path.exists() and mirror_path(path).exists()


def test_the_directory_is_fsynced_before_the_first_record(tmp_path, monkeypatch):
    calls = _spy_fsync(monkeypatch)
    path = tmp_path / "weld_journal.jsonl"
    with Journal(path) as journal:
        journal.started("S1")
    order = [("dir" if is_dir else Path(target).name) for target, is_dir, _ in calls]
    assert "dir" in order and order.index("dir") < order.index(path.name), order

