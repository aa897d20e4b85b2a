"""The weld journal: an append-only, checksummed JSON-lines record of what happened to every stud.

It is what makes a job resumable without ever welding a stud twice. Each state change is one
line, written (``os.write``) and then ``os.fsync``'ed -- to the journal and then to its mirror --
*before* the driver sends its next command, so after a crash or a power cut the files tell the
truth up to the last completed step.

Records (one JSON object per line; ``t`` = UTC ISO time)::

    {"seq": 7, "event": "started", "stud": "S0001", "job": "20261122T100000-1a2b3c",
     "journal": "9f0c2d4e6a1b", "t": "...", "position": [...], ..., "crc": "5d1e0a7f"}

* ``seq``: 1, 2, 3 ... in file order (a missing, repeated or reordered line breaks the count);
* ``job``: the id :class:`~rm65_driver.weld_sequence.WeldSequence` gives each job ("" for an
  operator's decision outside a job); ``journal``: the id of this journal, the same in every
  record (created with the file: lines of another cell's journal do not belong here);
* ``crc``: CRC32 (8 hex digits) of the record's *canonical* JSON without the ``crc`` field:
  ``json.dumps(record, sort_keys=True, separators=(",", ":"), ensure_ascii=True)``.
  On disk ``seq``, ``event`` and ``stud`` come first, so even a torn line names its stud.

Events: ``started`` (trigger about to fire), ``welded``, ``skipped`` (``reason``), ``resolved``
(``decision`` "welded" | "not_welded", ``note``), and two the journal writes itself:
``torn_tail`` (a torn last line was found at start-up: ``line``, ``torn_crc`` of its bytes,
``uncertain`` [stud ids]) and ``recovered`` (an operator resolved damage: ``action``,
``note``, ``damaged_lines``, ``moved_to``, ``uncertain`` [stud ids]).

**Status rules** (one table, :data:`_TRANSITIONS`): *welded is final* -- nothing but a welded
stud's own records can follow, and none of them makes it weldable again. ``started`` ->
**uncertain** (the gun may or may not have fired) until ``welded`` or an operator's
``resolved``. ``skipped`` never changes an uncertain or welded stud (a later job that skips
it, say as "needs an operator decision", does not make it weldable). ``resolved: not_welded``
-> not_welded (may be welded by a later job); ``torn_tail`` / ``recovered`` make the studs they
list uncertain unless welded.

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
  and line(s) and nothing is written. An operator resolves it with :func:`repair_journal`:
  ``accept_intact`` keeps the records before the first damage and marks every stud mentioned
  after it (in either file) uncertain; ``load_backup`` takes the intact copy. The damaged file
  is moved aside (``<name>.corrupt-<UTC time>``) and a clean journal and mirror are written.

**Mirror.** ``<journal>.mirror`` in the same directory receives every record right after the
journal (each fsynced), so one damaged file is not the only truth; on load the two are compared
and, after an interrupted append, the mirror is brought level with the journal.

**Failed appends** (disk full, I/O error) raise :class:`JournalError`; both files are cut back
to their last complete record where possible, and the journal refuses further appends (its
:attr:`Journal.fault` is set) until it is opened again: the job stops before its next motion.

**Legacy journals** (records without ``crc``, written by earlier driver versions) are accepted
as a *read-only prefix* with a warning ("legacy records without checksum"): their records count
(welded stays welded, started stays uncertain) but cannot be verified; new records appended after
them are checksummed, and a record without checksum after a checksummed one is damage.
"""
from __future__ import annotations

import datetime as _dt
import json
import logging
import os
import re
import threading
import uuid
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable

_log = logging.getLogger(__name__)

STARTED, WELDED, SKIPPED, RESOLVED = "started", "welded", "skipped", "resolved"
TORN_TAIL, RECOVERED = "torn_tail", "recovered"
DECISION_WELDED, DECISION_NOT_WELDED = "welded", "not_welded"
_STUD_EVENTS = frozenset({STARTED, WELDED, SKIPPED, RESOLVED})
_EVENTS = _STUD_EVENTS | {TORN_TAIL, RECOVERED}

#: Status names returned by :meth:`Journal.status`.
STATUS_NEW, STATUS_UNCERTAIN, STATUS_WELDED, STATUS_SKIPPED, STATUS_NOT_WELDED = (
    "new", "uncertain", "welded", "skipped", "not_welded")

#: Operator actions of :func:`repair_journal` (the ResolveJournal service's ACTION_* constants).
ACTION_ACCEPT_INTACT, ACTION_LOAD_BACKUP = "accept_intact", "load_backup"

MIRROR_SUFFIX = ".mirror"
_LEAD_KEYS = ("seq", "event", "stud")  # first on disk: a torn line still names its stud
_STUD_RE = re.compile(rb'"stud":"((?:[^"\\\x00-\x1f]|\\.){1,200})"')


class JournalError(RuntimeError):
    """The journal cannot be written or repaired, or a request contradicts it (e.g. resolving a
    stud that is not uncertain)."""


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


def mirror_path(path: str | os.PathLike[str]) -> Path:
    """The mirror of journal ``path``: ``<path>.mirror`` in the same directory."""
    p = Path(path)
    return p.with_name(p.name + MIRROR_SUFFIX)


# -- records ---------------------------------------------------------------------------------


def _canonical(rec: dict[str, Any]) -> bytes:
    return json.dumps(rec, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False).encode()


def record_crc(rec: dict[str, Any]) -> str:
    """CRC32 (8 lower-case hex digits) of the record's canonical JSON, without its ``crc`` field."""
    return f"{zlib.crc32(_canonical({k: v for k, v in rec.items() if k != 'crc'})):08x}"


def encode_record(rec: dict[str, Any]) -> bytes:
    """One journal line (with the trailing newline): lead keys first, ``crc`` last."""
    ordered = {k: rec[k] for k in _LEAD_KEYS if k in rec}
    ordered.update((k, v) for k, v in rec.items() if k not in ordered and k != "crc")
    ordered["crc"] = record_crc(ordered)
    return json.dumps(ordered, separators=(",", ":"), ensure_ascii=True, allow_nan=False).encode() + b"\n"


def _plain(value: Any) -> Any:
    """``value`` as plain JSON types (numpy arrays/scalars to lists/floats); non-finite numbers refused."""
    try:
        return json.loads(json.dumps(value, default=_json_default, allow_nan=False))
    except (TypeError, ValueError) as exc:
        raise JournalError(f"journal record not written: {exc}") from exc


def _reject_constant(name: str) -> Any:
    raise ValueError(f"{name} is not valid JSON")


def _parse_line(raw: bytes) -> tuple[dict[str, Any] | None, str]:
    """A line -> (record, "") or (None, why it is not one). Legacy records have no ``crc``."""
    try:
        rec = json.loads(raw.decode("utf-8"), parse_constant=_reject_constant)
    except UnicodeDecodeError:
        return None, "not UTF-8 text"
    except ValueError:
        return None, "not JSON"
    if not isinstance(rec, dict):
        return None, "not a JSON object"
    event = rec.get("event")
    if "crc" in rec:
        crc = rec["crc"]
        if not isinstance(crc, str) or crc != record_crc(rec):
            return None, f"checksum mismatch (crc {str(crc)[:12]!r}, computed {record_crc(rec)})"
        if event not in _EVENTS:
            return None, f"unknown event {str(event)[:40]!r}"
        if not isinstance(rec.get("seq"), int) or not isinstance(rec.get("journal"), str):
            return None, "record without seq/journal id"
    elif event not in _STUD_EVENTS:
        return None, f"unknown event {str(event)[:40]!r}"
    if event in _STUD_EVENTS and (not isinstance(rec.get("stud"), str) or not rec["stud"]):
        return None, "record without a stud id"
    if event == RESOLVED and rec.get("decision") not in (DECISION_WELDED, DECISION_NOT_WELDED):
        return None, f"unknown decision {str(rec.get('decision'))[:40]!r}"
    if event in (TORN_TAIL, RECOVERED) and not (isinstance(rec.get("uncertain"), list)
                                                and all(isinstance(s, str) for s in rec["uncertain"])):
        return None, f"{event} record without its list of uncertain studs"
    return rec, ""


def _excerpt(raw: bytes, n: int = 16) -> str:
    return repr(raw[:n]) + (f"... ({len(raw)} bytes)" if len(raw) > n else "")


def _studs_in(raw: bytes) -> tuple[str, ...]:
    out = []
    for m in _STUD_RE.finditer(raw):
        try:
            sid = json.loads(b'"' + m.group(1) + b'"')
        except ValueError:
            continue
        if sid not in out:
            out.append(sid)
    return tuple(out)


# -- status rules ----------------------------------------------------------------------------


def _after_started(status: str, rec: dict[str, Any]) -> str:
    return status if status == STATUS_WELDED else STATUS_UNCERTAIN


def _after_skipped(status: str, rec: dict[str, Any]) -> str:
    # A skip never changes a welded or an uncertain stud: only an operator makes an uncertain one weldable.
    return status if status in (STATUS_WELDED, STATUS_UNCERTAIN) else STATUS_SKIPPED


def _after_resolved(status: str, rec: dict[str, Any]) -> str:
    if rec.get("decision") == DECISION_WELDED or status == STATUS_WELDED:
        return STATUS_WELDED
    return STATUS_NOT_WELDED


#: (status before, record) -> status after, per stud event. Welded is final in every row.
_TRANSITIONS: dict[str, Callable[[str, dict[str, Any]], str]] = {
    STARTED: _after_started,
    WELDED: lambda status, rec: STATUS_WELDED,
    SKIPPED: _after_skipped,
    RESOLVED: _after_resolved,
}


# -- scanning --------------------------------------------------------------------------------


@dataclass
class _Line:
    no: int
    raw: bytes
    end: int  # byte offset just past this line's newline (or the end of the data)
    rec: dict[str, Any] | None = None
    why: str = ""


@dataclass
class _Scan:
    """One file, read and checked line by line (no decisions across the two files yet)."""

    path: Path
    exists: bool = False
    data: bytes = b""
    records: list[_Line] = field(default_factory=list)  # intact records, in order
    damage: list[Damage] = field(default_factory=list)  # not tolerated
    torn: _Line | None = None  # a tolerated torn last line
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
        return [_key(ln) for ln in self.records]


def _key(ln: _Line) -> tuple[Any, ...]:
    """A record's identity across the two copies: (seq, crc), or the raw line of a legacy record."""
    rec = ln.rec
    assert rec is not None
    return (rec["seq"], rec["crc"]) if "crc" in rec else (None, ln.raw)


def _scan(path: Path) -> _Scan:
    s = _Scan(path)
    try:
        s.data = path.read_bytes()
    except FileNotFoundError:
        return s
    s.exists = True
    data = s.data
    s.unterminated = bool(data) and not data.endswith(b"\n")
    lines: list[_Line] = []
    pos = 0
    for no, raw in enumerate(data.split(b"\n"), start=1):
        end = min(pos + len(raw) + 1, len(data))
        if raw.strip():
            lines.append(_Line(no, raw, end))
        pos = end
    for ln in lines:
        ln.rec, ln.why = _parse_line(ln.raw)

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
            s.damage.append(Damage(path, ln.no, f"{ln.why}: {_excerpt(ln.raw)}", _studs_in(ln.raw)))

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
                                       _studs_in(ln.raw)))
                continue
            s.legacy += 1
        else:
            if expected_seq is None:
                expected_seq = rec["seq"]
            if rec["seq"] != expected_seq:
                what = "missing" if rec["seq"] > expected_seq else "repeated or out of order"
                s.damage.append(Damage(path, ln.no, f"record seq {rec['seq']}, expected {expected_seq}: "
                                       f"records {what}", _studs_in(ln.raw)))
                expected_seq = max(expected_seq, rec["seq"] + 1)
                continue
            if not s.journal_id:
                s.journal_id = rec["journal"]
            elif rec["journal"] != s.journal_id:
                s.damage.append(Damage(path, ln.no, f"record of journal {rec['journal']!r}, not {s.journal_id!r}",
                                       _studs_in(ln.raw)))
                continue
        expected_seq = (expected_seq or 0) + 1
        s.records.append(ln)
    if s.damage and s.torn is not None:  # torn only means something in an otherwise intact file
        s.damage.append(Damage(path, s.torn.no, f"{s.torn.why}: {_excerpt(s.torn.raw)}", _studs_in(s.torn.raw)))
        s.torn = None
    s.damage.sort(key=lambda d: d.line)
    return s


def read_records(path: str | os.PathLike[str]) -> list[dict[str, Any]]:
    """The intact records of a journal file, in order, read only (for reports: the QA record, the
    demo's check of each weld's gun axis); a damaged line is left out, never guessed at."""
    return [ln.rec for ln in _scan(Path(path)).records if ln.rec is not None]


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


def _describe(s: _Scan, limit: int = 4) -> str:
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
class _Plan:
    """How a journal opens: the scan to replay, and the repairs to make first."""

    primary: _Scan
    mirror: _Scan
    warnings: list[str]
    torn_studs: tuple[str, ...] = ()  # made uncertain by the torn tail
    rewrite_mirror: bool = False


def _uncertain_from_torn(s: _Scan) -> tuple[str, ...]:
    assert s.torn is not None
    named = _studs_in(s.torn.raw)
    if named:
        return named
    status: dict[str, str] = {}
    last_started = ""
    for ln in s.records:
        rec = ln.rec
        assert rec is not None
        if rec["event"] in _TRANSITIONS:
            status[rec["stud"]] = _TRANSITIONS[rec["event"]](status.get(rec["stud"], STATUS_NEW), rec)
            if rec["event"] == STARTED:
                last_started = rec["stud"]
    return (last_started,) if last_started and status.get(last_started) == STATUS_UNCERTAIN else ()


def _report(p: _Scan, m: _Scan, extra: str = "", backup: Path | None = None, keep: int | None = None,
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


def _plan_open(path: Path) -> _Plan:
    """Scan journal and mirror and decide how to open them; raises :class:`JournalCorrupt`."""
    p, m = _scan(path), _scan(mirror_path(path))
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
    plan = _Plan(p, m, warnings)
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
            why = f"journal and mirror disagree from record {common + 1} (journal line {where_p}, mirror line {where_m})"
            backup = None
        dmg = [Damage(p.path, where_p if isinstance(where_p, int) else len(p.data.split(b"\n")), why)]
        raise _report(p, m, f"{p.path}: {why}", backup=backup, keep=common, damage=dmg)
    if p.legacy:
        warnings.append(f"{p.path}: {p.legacy} legacy records without checksum (an earlier driver version) "
                        "accepted unverified, read-only")
    if p.torn is not None:
        plan.torn_studs = _uncertain_from_torn(p)
        who = ", ".join(plan.torn_studs) + " now uncertain" if plan.torn_studs else "no stud affected"
        warnings.append(f"{p.path}:{p.torn.no}: torn last line (crash during a write?) ignored: "
                        f"{p.torn.raw[:80]!r} ({p.torn.why}); {who}")
    elif p.unterminated:
        warnings.append(f"{p.path}: the last record lacks its newline (an interrupted write); kept, newline added")
    plan.rewrite_mirror = m.data != p.data or m.exists != p.exists or p.torn is not None or p.unterminated
    return plan


# -- the journal -----------------------------------------------------------------------------


class Journal:
    """Append-only weld journal at ``path`` with its mirror (created with their directory if missing).

    Raises :class:`JournalCorrupt` when the files are damaged (see the module doc). Thread-safe.
    ``warnings`` lists what was tolerated while loading; :attr:`fault` is set once an append or
    :meth:`verify` failed (no more appends until the journal is opened again).
    """

    def __init__(self, path: str | os.PathLike[str], fsync: bool = True, journal_id: str | None = None):
        self.path = Path(path)
        self.mirror_path = mirror_path(self.path)
        self.fsync = fsync
        self.warnings: list[str] = []
        self.fault: JournalError | None = None
        self._lock = threading.Lock()
        self._status: dict[str, str] = {}
        self._last: dict[str, dict[str, Any]] = {}
        self._fds: list[int] = []
        self.path.parent.mkdir(parents=True, exist_ok=True)
        plan = _plan_open(self.path)
        self.warnings = plan.warnings
        for w in self.warnings:
            _log.warning("weld journal: %s", w)
        self.journal_id = plan.primary.journal_id or journal_id or uuid.uuid4().hex[:12]
        self._seq = len(plan.primary.records)
        for ln in plan.primary.records:
            self._apply(ln.rec)  # type: ignore[arg-type]
        new_file = not (plan.primary.exists and plan.mirror.exists)
        fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        self._fds = [fd]
        try:
            if plan.primary.unterminated:
                _write_all(fd, b"\n")  # the torn bytes stay as evidence; new records start clean
                self._sync(fd)
            if plan.rewrite_mirror:
                _atomic_write(self.mirror_path, self.path.read_bytes(), fsync)
            self._fds.append(os.open(self.mirror_path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644))
            if new_file and fsync:
                _fsync_dir(self.path.parent)
            if plan.primary.torn is not None:
                torn = plan.primary.torn
                self._append(TORN_TAIL, None, "", line=torn.no, torn_crc=f"{zlib.crc32(torn.raw):08x}",
                             uncertain=list(plan.torn_studs))
        except BaseException:
            self.close()
            raise
        self._snapshot = self._stat()

    # -- writing ---------------------------------------------------------------------------
    def _sync(self, fd: int) -> None:
        if self.fsync:
            os.fsync(fd)

    def _append(self, event: str, stud_id: str | None, job: str, **fields: Any) -> dict[str, Any]:
        with self._lock:
            if not self._fds:
                raise JournalError(f"journal {self.path} is closed")
            if self.fault is not None:
                raise JournalError(f"weld journal {self.path} not written: it failed earlier ({self.fault})")
            rec: dict[str, Any] = {"seq": self._seq + 1, "event": event}
            if stud_id is not None:
                rec["stud"] = str(stud_id)
            rec.update(job=str(job), journal=self.journal_id,
                       t=_dt.datetime.now(_dt.timezone.utc).isoformat(timespec="milliseconds"))
            rec.update(_plain(fields))
            line = encode_record(rec)
            rec["crc"] = record_crc(rec)
            sizes = [os.fstat(fd).st_size for fd in self._fds]
            target = self.path
            try:
                for fd, target in zip(self._fds, (self.path, self.mirror_path)):
                    _write_all(fd, line)
                    self._sync(fd)  # after the write: what is synced is the whole record
            except OSError as exc:
                self._cut_back(sizes)
                self.fault = JournalError(f"cannot write the weld journal {target}: {exc}")
                raise self.fault from exc
            self._seq += 1
            self._apply(rec)
            self._snapshot = self._stat()
        return rec

    def _cut_back(self, sizes: list[int]) -> None:
        """After a failed append: remove its partial bytes, so the files end on a complete record."""
        for fd, size, path in zip(self._fds, sizes, (self.path, self.mirror_path)):
            try:
                if os.fstat(fd).st_size != size:
                    os.ftruncate(fd, size)
                    self._sync(fd)
            except OSError as exc:
                _log.error("weld journal %s: could not remove a partial record: %s", path, exc)

    def started(self, stud_id: str, job: str = "", **info: Any) -> None:
        """The stud is at the surface and the trigger is about to fire (uncertain from now on)."""
        self._append(STARTED, stud_id, job, **info)

    def welded(self, stud_id: str, job: str = "", **info: Any) -> None:
        self._append(WELDED, stud_id, job, **info)

    def skipped(self, stud_id: str, reason: str, job: str = "", **info: Any) -> None:
        self._append(SKIPPED, stud_id, job, reason=reason, **info)

    def resolve(self, stud_id: str, welded: bool, note: str = "") -> None:
        """Operator decision on an uncertain stud: ``welded`` (never weld again) or not (may be welded)."""
        with self._lock:
            status = self._status.get(stud_id, STATUS_NEW)
        if status != STATUS_UNCERTAIN:
            raise JournalError(f"stud {stud_id!r} is {status}, not uncertain: nothing to resolve")
        self._append(RESOLVED, stud_id, "", decision=DECISION_WELDED if welded else DECISION_NOT_WELDED, note=note)

    def _apply(self, rec: dict[str, Any]) -> None:
        event = rec["event"]
        if event in _TRANSITIONS:
            stud = rec["stud"]
            self._status[stud] = _TRANSITIONS[event](self._status.get(stud, STATUS_NEW), rec)
            self._last[stud] = rec
        else:  # torn_tail / recovered: the studs they list are uncertain unless welded
            for stud in rec.get("uncertain", []):
                if self._status.get(stud) != STATUS_WELDED:
                    self._status[stud] = STATUS_UNCERTAIN
                    self._last[stud] = rec

    # -- checking --------------------------------------------------------------------------
    def _stat(self) -> tuple[tuple[int, int, int], ...]:
        out = []
        for p in (self.path, self.mirror_path):
            try:
                st = os.stat(p)
                out.append((st.st_ino, st.st_size, st.st_mtime_ns))
            except OSError:
                out.append((0, -1, 0))
        return tuple(out)

    def verify(self) -> None:
        """Check that nobody changed the files since our last write (cheap unless they did);
        raises :class:`JournalError` / :class:`JournalCorrupt` and sets :attr:`fault` if so."""
        with self._lock:
            if isinstance(self.fault, JournalCorrupt):
                raise self.fault
            if self.fault is not None:
                raise JournalError(f"the weld journal failed earlier ({self.fault}): nothing is written to it "
                                   "until it is opened again")
            if self._stat() == self._snapshot:
                return
            try:
                plan = _plan_open(self.path)
            except JournalCorrupt as exc:
                self.fault = exc
                raise
            if len(plan.primary.records) != self._seq or plan.rewrite_mirror:
                self.fault = JournalError(
                    f"weld journal {self.path} was changed by another writer: {len(plan.primary.records)} records "
                    f"on disk, {self._seq} written here; resolve with /arm/resolve_journal")
                raise self.fault
            self._snapshot = self._stat()

    def close(self) -> None:
        with self._lock:
            fds, self._fds = self._fds, []
        for fd in fds:
            try:
                os.close(fd)
            except OSError:
                pass

    def __enter__(self) -> "Journal":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # -- queries ---------------------------------------------------------------------------
    def status(self, stud_id: str) -> str:
        """``new``, ``uncertain``, ``welded``, ``skipped`` or ``not_welded``."""
        with self._lock:
            return self._status.get(stud_id, STATUS_NEW)

    def last_record(self, stud_id: str) -> dict[str, Any] | None:
        with self._lock:
            rec = self._last.get(stud_id)
            return dict(rec) if rec else None

    @property
    def record_count(self) -> int:
        with self._lock:
            return self._seq

    @property
    def welded_ids(self) -> set[str]:
        with self._lock:
            return {s for s, st in self._status.items() if st == STATUS_WELDED}

    @property
    def uncertain_ids(self) -> set[str]:
        with self._lock:
            return {s for s, st in self._status.items() if st == STATUS_UNCERTAIN}

    def is_welded(self, stud_id: str) -> bool:
        return self.status(stud_id) == STATUS_WELDED

    def is_uncertain(self, stud_id: str) -> bool:
        return self.status(stud_id) == STATUS_UNCERTAIN


# -- operator repair -------------------------------------------------------------------------


def repair_journal(path: str | os.PathLike[str], action: str, note: str = "", fsync: bool = True) -> str:
    """Resolve a corrupt journal (the driver's FAULT) by ``action``; returns what was done.

    ``accept_intact``: keep the journal's records before its first damage (or before the point
    where journal and mirror part), and make every stud mentioned after that point -- in either
    file, in intact records or in what can still be read of damaged lines -- uncertain unless the
    kept records show it welded. ``load_backup``: take the intact copy (the mirror, or the
    journal when only the mirror is damaged). Either way the old files are moved aside
    (``<name>.corrupt-<UTC time>``) and a clean journal and mirror are written, ending with a
    ``recovered`` record. Raises :class:`JournalError` when the action is not possible.
    """
    path = Path(path)
    if action not in (ACTION_ACCEPT_INTACT, ACTION_LOAD_BACKUP):
        raise JournalError(f"unknown journal action {action!r}: expected {ACTION_ACCEPT_INTACT!r} "
                           f"or {ACTION_LOAD_BACKUP!r}")
    try:
        _plan_open(path)
        return f"weld journal {path} is intact: nothing to repair"
    except JournalCorrupt as exc:
        report = exc.report
    p, m = _scan(path), _scan(mirror_path(path))
    if action == ACTION_LOAD_BACKUP:
        if report.backup is None:
            raise JournalError(f"no intact copy of {path} to load: {report.summary}")
        source = p if report.backup == p.path else m
        other = m if source is p else p
        kept = source.records
    else:
        source, other = p, m
        kept = p.records[:report.keep]
    keep_end = kept[-1].end if kept else 0
    content = source.data[:keep_end]
    if content and not content.endswith(b"\n"):
        content += b"\n"

    status: dict[str, str] = {}
    for ln in kept:
        rec = ln.rec
        assert rec is not None
        if rec["event"] in _TRANSITIONS:
            status[rec["stud"]] = _TRANSITIONS[rec["event"]](status.get(rec["stud"], STATUS_NEW), rec)
        else:
            for s in rec["uncertain"]:
                if status.get(s) != STATUS_WELDED:
                    status[s] = STATUS_UNCERTAIN
    known = {_key(ln) for ln in kept}
    mentioned: list[str] = []

    def mention(studs: Iterable[str]) -> None:
        mentioned.extend(s for s in studs if s not in mentioned)

    for scan in (source, other):
        for ln in scan.records:
            if _key(ln) not in known:
                rec = ln.rec
                assert rec is not None
                mention([rec["stud"]] if "stud" in rec else rec.get("uncertain", []))
        for d in scan.damage:
            mention(d.studs)
        if scan.torn is not None:
            mention(_studs_in(scan.torn.raw))
    if source.torn is not None and len(kept) == len(source.records):
        mention(_uncertain_from_torn(source))
    uncertain = [s for s in mentioned if status.get(s) != STATUS_WELDED]

    stamp = _dt.datetime.now(_dt.timezone.utc).strftime("%Y%m%dT%H%M%SZ")
    damaged = {d.path for d in report.damage}
    moved = []
    for scan in (p, m):
        if scan.exists:
            aside = _free_name(scan.path, f"{'corrupt' if scan.path in damaged else 'replaced'}-{stamp}")
            os.replace(scan.path, aside)
            moved.append(str(aside))
    journal_id = source.journal_id or other.journal_id or uuid.uuid4().hex[:12]
    rec: dict[str, Any] = {
        "seq": len(kept) + 1, "event": RECOVERED, "job": "", "journal": journal_id,
        "t": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="milliseconds"), "action": action,
        "note": note, "source": str(source.path),
        "damaged_lines": [f"{d.path.name}:{d.line}" for d in report.damage][:200], "moved_to": moved,
        "uncertain": uncertain}
    content += encode_record(_plain(rec))
    _atomic_write(path, content, fsync)
    _atomic_write(mirror_path(path), content, fsync)
    what = (f"kept {len(kept)} intact record(s) of {source.path}" if action == ACTION_ACCEPT_INTACT
            else f"loaded {source.path} ({len(kept)} records)")
    unc = f"; {len(uncertain)} stud(s) now uncertain: {', '.join(uncertain[:20])}" if uncertain else ""
    msg = f"{what}{unc}; the old files moved to {', '.join(moved)}"
    _log.warning("weld journal repaired (%s): %s", action, msg)
    return msg


# -- file helpers ----------------------------------------------------------------------------


def _free_name(path: Path, tag: str) -> Path:
    """``<path>.<tag>``, or ``<path>.<tag>.2`` ... if taken (two repairs within a second)."""
    out, n = path.with_name(f"{path.name}.{tag}"), 1
    while out.exists():
        n += 1
        out = path.with_name(f"{path.name}.{tag}.{n}")
    return out


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        n = os.write(fd, view)
        view = view[n:]


def _atomic_write(path: Path, data: bytes, fsync: bool = True) -> None:
    """Replace ``path`` by ``data`` (write a temporary file, fsync, rename, fsync the directory)."""
    tmp = path.with_name(path.name + ".tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    try:
        _write_all(fd, data)
        if fsync:
            os.fsync(fd)
    finally:
        os.close(fd)
    os.replace(tmp, path)
    if fsync:
        _fsync_dir(path.parent)


def _json_default(obj: Any) -> Any:
    tolist = getattr(obj, "tolist", None)
    if tolist is not None:  # numpy arrays / scalars
        return tolist()
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


def _fsync_dir(path: Path) -> None:
    """Make a newly created file's directory entry durable (POSIX)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
