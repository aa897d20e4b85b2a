"""Reading a weld journal and its mirror back: each file line by line, then the two against each other.

**Damage.** Loading tells two things apart:

* a *torn final line* -- what a crash in the middle of a write leaves: the last line has no
  newline or is an incomplete / checksum-failing record with nothing after it. It is tolerated:
  the stud it names (or, if it names none, the stud of the last ``started`` without an outcome)
  becomes uncertain, and a ``torn_tail`` record acknowledges the torn bytes, which stay in the
  file as evidence (a later load recognises them by that record). A final record that is
  complete and verified but only lacks its newline is kept.
* *anything else* -- unparseable bytes (random data, a block of NULs) anywhere but the tail,
  a checksum mismatch in the middle, a record of an unknown event or of another journal, a
  missing or repeated ``seq``, or journal and mirror that disagree beyond what one interrupted
  append explains -- makes the journal **corrupt**: :class:`JournalCorrupt` names the file(s)
  and line(s) and nothing is written. An operator resolves it with :func:`~rm65_driver.journal.repair.repair_journal`:
  ``accept_intact`` keeps the records before the first damage and marks every stud mentioned
  after it (in either file) uncertain; ``load_backup`` takes the intact copy. The damaged file
  is moved aside (``<name>.corrupt-<UTC time>``) and a clean journal and mirror are written.

**Legacy journals** (records without ``crc``, written by earlier driver versions) are accepted
as a *read-only prefix* with a warning ("legacy records without checksum"): their records count
(welded stays welded, started stays uncertain) but cannot be verified; new records appended after
them are checksummed, and a record without checksum after a checksummed one is damage.

:func:`plan_open` is what :class:`~rm65_driver.journal.writer.Journal` and the repair run first: it scans
both files and decides how to open them, or raises :class:`JournalCorrupt` with a
:class:`DamageReport` (file, lines, what an operator can do). Reads only, never writes.
"""
from __future__ import annotations

import os
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

from rm65_driver.journal.records import (
    STARTED,
    TORN_TAIL,
    TRANSITIONS,
    JournalError,
    excerpt,
    mirror_path,
    parse_line,
    studs_in,
)
from stud_common.vocabulary import JournalStatus


@dataclass(frozen=True)
class Damage:
    """One damaged line (``line`` 1-based) of ``path``, why, and the stud ids it still shows."""

    path: Path
    line: int
    reason: str
    studs: tuple[str, ...] = ()


@dataclass(frozen=True)
class DamageReport:
    """What is wrong with a journal and its mirror, and what an operator can do about it.

    ``damage``: every damaged line, in either file; ``backup``: the copy that is intact (to load
    with ``load_backup``), if exactly one is; ``keep``: how many of the journal's records
    ``accept_intact`` keeps.
    """

    journal: Path
    mirror: Path
    damage: tuple[Damage, ...]
    backup: Path | None
    keep: int
    summary: str

    @property
    def lines(self) -> list[tuple[str, int]]:
        return [(str(d.path), d.line) for d in self.damage]


class JournalCorrupt(JournalError):
    """The journal is damaged beyond a torn last line; ``report`` says where and what can be done."""

    def __init__(self, report: DamageReport):
        self.report = report
        super().__init__(report.summary)


# -- scanning --------------------------------------------------------------------------------


@dataclass
class ScanLine:
    no: int
    raw: bytes
    end: int  # byte offset just past this line's newline (or the end of the data)
    rec: dict[str, Any] | None = None
    why: str = ""


@dataclass
class FileScan:
    """One file, read and checked line by line (no decisions across the two files yet)."""

    path: Path
    exists: bool = False
    data: bytes = b""
    records: list[ScanLine] = field(default_factory=list)  # intact records, in order
    damage: list[Damage] = field(default_factory=list)  # not tolerated
    torn: ScanLine | None = None  # a tolerated torn last line
    unterminated: bool = False  # no newline at the very end
    legacy: int = 0
    journal_id: str = ""
    notes: list[str] = field(default_factory=list)  # tolerated things worth a warning

    @property
    def damaged(self) -> bool:
        return bool(self.damage)

    def first_damage_line(self) -> int | None:
        return min((d.line for d in self.damage), default=None)

    def keys(self) -> list[tuple[Any, ...]]:
        """What two copies must agree on, record by record."""
        return [record_key(ln) for ln in self.records]


def record_key(ln: ScanLine) -> tuple[Any, ...]:
    """A record's identity across the two copies: (seq, crc), or the raw line of a legacy record."""
    rec = ln.rec
    assert rec is not None
    return (rec["seq"], rec["crc"]) if "crc" in rec else (None, ln.raw)


def scan_file(path: Path) -> FileScan:
    """A journal file checked line by line: intact records, damage, a tolerated torn tail (``exists``: file found)."""
    s = FileScan(path)
    try:
        s.data = path.read_bytes()
    except FileNotFoundError:
        return s
    s.exists = True
    data = s.data
    s.unterminated = bool(data) and not data.endswith(b"\n")
    lines: list[ScanLine] = []
    pos = 0
    for no, raw in enumerate(data.split(b"\n"), start=1):
        end = min(pos + len(raw) + 1, len(data))
        if raw.strip():
            lines.append(ScanLine(no, raw, end))
        pos = end
    for ln in lines:
        ln.rec, ln.why = parse_line(ln.raw)

    bad = [ln for ln in lines if ln.rec is None]
    acknowledged: set[int] = set()
    for i, ln in enumerate(lines[:-1]):
        nxt = lines[i + 1]
        if (ln.rec is None and nxt.rec is not None and nxt.rec.get("event") == TORN_TAIL
                and nxt.rec.get("line") == ln.no and nxt.rec.get("torn_crc") == f"{zlib.crc32(ln.raw):08x}"):
            acknowledged.add(ln.no)
            s.notes.append(f"{path}:{ln.no}: invalid line (the torn tail of an earlier crash, "
                           f"acknowledged by line {nxt.no}) ignored")
    if lines and lines[-1].rec is None:
        s.torn = lines[-1]
    for ln in bad:
        if ln.no not in acknowledged and ln is not s.torn:
            s.damage.append(Damage(path, ln.no, f"{ln.why}: {excerpt(ln.raw)}", studs_in(ln.raw)))

    expected_seq: int | None = 1
    for ln in lines:
        rec = ln.rec
        if rec is None:
            if ln.no not in acknowledged:
                expected_seq = None  # what the damaged line held is unknown: no gap to report after it
            continue
        if "crc" not in rec:
            if s.records and "crc" in s.records[-1].rec:  # type: ignore[operator]
                s.damage.append(Damage(path, ln.no, "record without checksum after checksummed ones",
                                       studs_in(ln.raw)))
                continue
            s.legacy += 1
        else:
            if expected_seq is None:
                expected_seq = rec["seq"]
            if rec["seq"] != expected_seq:
                what = "missing" if rec["seq"] > expected_seq else "repeated or out of order"
                s.damage.append(Damage(path, ln.no, f"record seq {rec['seq']}, expected {expected_seq}: "
                                       f"records {what}", studs_in(ln.raw)))
                expected_seq = max(expected_seq, rec["seq"] + 1)
                continue
            if not s.journal_id:
                s.journal_id = rec["journal"]
            elif rec["journal"] != s.journal_id:
                s.damage.append(Damage(path, ln.no, f"record of journal {rec['journal']!r}, not {s.journal_id!r}",
                                       studs_in(ln.raw)))
                continue
        expected_seq = (expected_seq or 0) + 1
        s.records.append(ln)
    if s.damage and s.torn is not None:  # torn only means something in an otherwise intact file
        s.damage.append(Damage(path, s.torn.no, f"{s.torn.why}: {excerpt(s.torn.raw)}", studs_in(s.torn.raw)))
        s.torn = None
    s.damage.sort(key=lambda d: d.line)
    return s


def read_records(path: str | os.PathLike[str]) -> list[dict[str, Any]]:
    """The intact records of a journal file, in order, read only (for reports: the QA record, the
    demo's check of each weld's gun axis); a damaged line is left out, never guessed at."""
    return [ln.rec for ln in scan_file(Path(path)).records if ln.rec is not None]


def _line_ranges(nos: Iterable[int]) -> str:
    nos = sorted(set(nos))
    out, i = [], 0
    while i < len(nos):
        j = i
        while j + 1 < len(nos) and nos[j + 1] == nos[j] + 1:
            j += 1
        out.append(str(nos[i]) if i == j else f"{nos[i]}-{nos[j]}")
        i = j + 1
    return ",".join(out)


def _describe(s: FileScan, limit: int = 4) -> str:
    """"lines 1-17 (not JSON ...), 20 (checksum mismatch ...)" for a damaged file."""
    groups: list[tuple[list[int], str]] = []
    for d in s.damage:
        if groups and d.line == groups[-1][0][-1] + 1 or (groups and d.line == groups[-1][0][-1]):
            groups[-1][0].append(d.line)
        else:
            groups.append(([d.line], d.reason))
    parts = [f"line{'s' if len(set(nos)) > 1 else ''} {_line_ranges(nos)} ({why})" for nos, why in groups[:limit]]
    if len(groups) > limit:
        parts.append(f"and {len(groups) - limit} more damaged place(s)")
    return ", ".join(parts)


# -- deciding what the two files say ---------------------------------------------------------


@dataclass
class OpenPlan:
    """How a journal opens: the scan to replay, and the repairs to make first."""

    primary: FileScan
    mirror: FileScan
    warnings: list[str]
    torn_studs: tuple[str, ...] = ()  # made uncertain by the torn tail
    rewrite_mirror: bool = False


def uncertain_from_torn(s: FileScan) -> tuple[str, ...]:
    """The studs a torn last line leaves uncertain: those it names, else the last stud started if still uncertain."""
    assert s.torn is not None
    named = studs_in(s.torn.raw)
    if named:
        return named
    status: dict[str, JournalStatus] = {}
    last_started = ""
    for ln in s.records:
        rec = ln.rec
        assert rec is not None
        if rec["event"] in TRANSITIONS:
            status[rec["stud"]] = TRANSITIONS[rec["event"]](status.get(rec["stud"], JournalStatus.NEW), rec)
            if rec["event"] == STARTED:
                last_started = rec["stud"]
    return (last_started,) if last_started and status.get(last_started) == JournalStatus.UNCERTAIN else ()


def _report(p: FileScan, m: FileScan, extra: str = "", backup: Path | None = None, keep: int | None = None,
            damage: Iterable[Damage] = ()) -> JournalCorrupt:
    damage = tuple(p.damage) + tuple(m.damage) + tuple(damage)
    parts = []
    if p.damaged:
        parts.append(f"weld journal {p.path} is damaged: {_describe(p)}")
    if m.damaged:
        parts.append(f"its mirror {m.path} is damaged: {_describe(m)}")
    if extra:
        parts.append(extra)
    if backup is None and p.exists and not p.damaged and m.damaged:
        backup = p.path
    if backup is None and m.exists and not m.damaged and p.damaged and m.records:
        backup = m.path
    if keep is None:
        first = p.first_damage_line()
        keep = sum(1 for ln in p.records if first is None or ln.no < first)
    if backup is not None:
        n = len((p if backup == p.path else m).records)
        parts.append(f"{backup} is intact ({n} records): load it with /arm/resolve_journal ACTION_LOAD_BACKUP")
    parts.append(f"ACTION_ACCEPT_INTACT keeps the journal's first {keep} record(s) and marks every stud "
                 "mentioned after them uncertain")
    return JournalCorrupt(DamageReport(p.path, m.path, damage, backup, keep, "; ".join(parts)))


def plan_open(path: Path) -> OpenPlan:
    """Scan journal and mirror and decide how to open them; raises :class:`JournalCorrupt`."""
    p, m = scan_file(path), scan_file(mirror_path(path))
    warnings = [*p.notes]
    if p.damaged or m.damaged:
        raise _report(p, m)
    if not p.exists and m.exists and m.records:
        raise _report(p, m, f"the weld journal {p.path} is missing but its mirror has {len(m.records)} record(s)",
                      backup=m.path, keep=0)
    if p.exists and p.journal_id and m.journal_id and p.journal_id != m.journal_id:
        raise _report(p, m, f"journal {p.journal_id!r} and mirror {m.journal_id!r} are different journals",
                      keep=len(p.records))
    pk, mk = p.keys(), m.keys()
    plan = OpenPlan(p, m, warnings)
    if pk == mk:
        pass
    elif len(pk) == len(mk) + 1 and pk[:-1] == mk:
        if m.exists:
            warnings.append(f"{m.path}: one record behind the journal (an interrupted append); brought level")
        elif p.records:
            warnings.append(f"{m.path}: missing; created from the journal")
    elif not m.exists and p.records:
        warnings.append(f"{m.path}: missing; created from the journal ({len(pk)} records)")
    else:
        common = 0
        while common < min(len(pk), len(mk)) and pk[common] == mk[common]:
            common += 1
        where_p = p.records[common].no if common < len(p.records) else "its end"
        where_m = m.records[common].no if common < len(m.records) else "its end"
        if mk[:len(pk)] == pk:
            why = f"the mirror has {len(mk) - len(pk)} record(s) more than the journal (from mirror line {where_m})"
            backup = m.path
        elif pk[:len(mk)] == mk:
            why = f"the journal has {len(pk) - len(mk)} record(s) more than its mirror (from journal line {where_p})"
            backup = p.path
        else:
            why = (f"journal and mirror disagree from record {common + 1} "
                   f"(journal line {where_p}, mirror line {where_m})")
            backup = None
        dmg = [Damage(p.path, where_p if isinstance(where_p, int) else len(p.data.split(b"\n")), why)]
        raise _report(p, m, f"{p.path}: {why}", backup=backup, keep=common, damage=dmg)
    if p.legacy:
        warnings.append(f"{p.path}: {p.legacy} legacy records without checksum (an earlier driver version) "
                        "accepted unverified, read-only")
    if p.torn is not None:
        plan.torn_studs = uncertain_from_torn(p)
        who = ", ".join(plan.torn_studs) + " now uncertain" if plan.torn_studs else "no stud affected"
        warnings.append(f"{p.path}:{p.torn.no}: torn last line (crash during a write?) ignored: "
                        f"{p.torn.raw[:80]!r} ({p.torn.why}); {who}")
    elif p.unterminated:
        warnings.append(f"{p.path}: the last record lacks its newline (an interrupted write); kept, newline added")
    plan.rewrite_mirror = m.data != p.data or m.exists != p.exists or p.torn is not None or p.unterminated
    return plan

