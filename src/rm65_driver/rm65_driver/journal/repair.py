"""Operator repair of a corrupt weld journal (the driver's FAULT, ``/arm/resolve_journal``).

Two actions: ``accept_intact`` keeps the journal's records before its first damage (or before the
point where journal and mirror part) and makes every stud mentioned after that point -- in either
file, in intact records or in what can still be read of damaged lines -- uncertain unless the kept
records show it welded; ``load_backup`` takes the intact copy (the mirror, or the journal when
only the mirror is damaged). Either way the old files are moved aside
(``<name>.corrupt-<UTC time>``, or ``.replaced-...`` for an intact one that is rewritten) and a
clean journal and mirror are written, ending with a ``recovered`` record.
"""
from __future__ import annotations

import datetime as _dt
import logging
import os
import uuid
from pathlib import Path
from typing import Any, Iterable

from rm65_driver.journal.files import atomic_write, free_name
from rm65_driver.journal.records import (
    RECOVERED,
    TRANSITIONS,
    JournalError,
    encode_record,
    mirror_path,
    plain_json,
    studs_in,
)
from rm65_driver.journal.scan import (
    DamageReport,
    FileScan,
    JournalCorrupt,
    ScanLine,
    plan_open,
    record_key,
    scan_file,
    uncertain_from_torn,
)
from stud_common.vocabulary import JournalStatus

_log = logging.getLogger("rm65_driver.journal.writer")  # the journal's one logger, whichever part writes

#: Operator actions of :func:`repair_journal` (the ResolveJournal service's ACTION_* constants).
ACTION_ACCEPT_INTACT, ACTION_LOAD_BACKUP = "accept_intact", "load_backup"


def repair_journal(path: str | os.PathLike[str], action: str, note: str = "", fsync: bool = True) -> str:
    """Resolve a corrupt journal (the driver's FAULT) by ``action``; returns what was done.

    ``accept_intact`` or ``load_backup`` (see the module doc). Raises :class:`JournalError` when
    the action is not possible; a journal that is intact is left alone.
    """
    path = Path(path)
    if action not in (ACTION_ACCEPT_INTACT, ACTION_LOAD_BACKUP):
        raise JournalError(f"unknown journal action {action!r}: expected {ACTION_ACCEPT_INTACT!r} "
                           f"or {ACTION_LOAD_BACKUP!r}")
    try:
        plan_open(path)
        return f"weld journal {path} is intact: nothing to repair"
    except JournalCorrupt as exc:
        report = exc.report
    p, m = scan_file(path), scan_file(mirror_path(path))
    source, other, kept = _what_to_keep(p, m, report, action)
    keep_end = kept[-1].end if kept else 0
    content = source.data[:keep_end]
    if content and not content.endswith(b"\n"):
        content += b"\n"
    uncertain = _uncertain_after(kept, source, other)

    stamp = _dt.datetime.now(_dt.timezone.utc).strftime("%Y%m%dT%H%M%SZ")
    damaged = {d.path for d in report.damage}
    moved = []
    for scan in (p, m):
        if scan.exists:
            aside = free_name(scan.path, f"{'corrupt' if scan.path in damaged else 'replaced'}-{stamp}")
            os.replace(scan.path, aside)
            moved.append(str(aside))
    journal_id = source.journal_id or other.journal_id or uuid.uuid4().hex[:12]
    rec: dict[str, Any] = {
        "seq": len(kept) + 1, "event": RECOVERED, "job": "", "journal": journal_id,
        "t": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="milliseconds"), "action": action,
        "note": note, "source": str(source.path),
        "damaged_lines": [f"{d.path.name}:{d.line}" for d in report.damage][:200], "moved_to": moved,
        "uncertain": uncertain}
    content += encode_record(plain_json(rec))
    atomic_write(path, content, fsync)
    atomic_write(mirror_path(path), content, fsync)
    what = (f"kept {len(kept)} intact record(s) of {source.path}" if action == ACTION_ACCEPT_INTACT
            else f"loaded {source.path} ({len(kept)} records)")
    unc = f"; {len(uncertain)} stud(s) now uncertain: {', '.join(uncertain[:20])}" if uncertain else ""
    msg = f"{what}{unc}; the old files moved to {', '.join(moved)}"
    _log.warning("weld journal repaired (%s): %s", action, msg)
    return msg


def _what_to_keep(p: FileScan, m: FileScan, report: DamageReport,
                  action: str) -> tuple[FileScan, FileScan, list[ScanLine]]:
    """(the copy to keep records of, the other copy, the records kept) for ``action``."""
    if action == ACTION_LOAD_BACKUP:
        if report.backup is None:
            raise JournalError(f"no intact copy of {p.path} to load: {report.summary}")
        source = p if report.backup == p.path else m
        other = m if source is p else p
        return source, other, source.records
    return p, m, p.records[:report.keep]


def _kept_status(kept: list[ScanLine]) -> dict[str, JournalStatus]:
    """Each stud's status after the kept records (the status rules of :mod:`.records`)."""
    status: dict[str, JournalStatus] = {}
    for ln in kept:
        rec = ln.rec
        assert rec is not None
        if rec["event"] in TRANSITIONS:
            status[rec["stud"]] = TRANSITIONS[rec["event"]](status.get(rec["stud"], JournalStatus.NEW), rec)
        else:
            for s in rec["uncertain"]:
                if status.get(s) != JournalStatus.WELDED:
                    status[s] = JournalStatus.UNCERTAIN
    return status


def _uncertain_after(kept: list[ScanLine], source: FileScan, other: FileScan) -> list[str]:
    """The studs mentioned after the kept records, in either copy, that the kept ones do not show welded."""
    status = _kept_status(kept)
    known = {record_key(ln) for ln in kept}
    mentioned: list[str] = []

    def mention(studs: Iterable[str]) -> None:
        mentioned.extend(s for s in studs if s not in mentioned)

    for scan in (source, other):
        for ln in scan.records:
            if record_key(ln) not in known:
                rec = ln.rec
                assert rec is not None
                mention([rec["stud"]] if "stud" in rec else rec.get("uncertain", []))
        for d in scan.damage:
            mention(d.studs)
        if scan.torn is not None:
            mention(studs_in(scan.torn.raw))
    if source.torn is not None and len(kept) == len(source.records):
        mention(uncertain_from_torn(source))
    return [s for s in mentioned if status.get(s) != JournalStatus.WELDED]
