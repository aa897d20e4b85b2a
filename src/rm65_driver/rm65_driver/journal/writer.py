"""The weld journal: an append-only, checksummed JSON-lines record of what happened to every stud.

It is what makes a job resumable without ever welding a stud twice. Each state change is one
line, written (``os.write``) and then ``os.fsync``'ed -- to the journal and then to its mirror --
*before* the driver sends its next command, so after a crash or a power cut the files tell the
truth up to the last completed step.

The parts: the record format, its checksum and the status rules (:mod:`.records`);
reading the files back, telling a torn last line from corruption, and the damage report
(:mod:`.scan`); the operator's repair (:mod:`.repair`); durable writes
(:mod:`.files`). This module is the writer, :class:`Journal`.

**Mirror.** ``<journal>.mirror`` in the same directory receives every record right after the
journal (each fsynced), so one damaged file is not the only truth; on load the two are compared
and, after an interrupted append, the mirror is brought level with the journal.

**Failed appends** (disk full, I/O error) raise :class:`JournalError`; both files are cut back
to their last complete record where possible, and the journal refuses further appends (its
:attr:`Journal.fault` is set) until it is opened again: the job stops before its next motion.
"""
from __future__ import annotations

import datetime as _dt
import logging
import os
import threading
import uuid
import zlib
from pathlib import Path
from typing import Any

from rm65_driver.journal.files import atomic_write, fsync_dir, write_all
from rm65_driver.journal.records import (
    DECISION_NOT_WELDED,
    DECISION_WELDED,
    RESOLVED,
    SKIPPED,
    STARTED,
    TORN_TAIL,
    TRANSITIONS,
    WELDED,
    JournalError,
    encode_record,
    mirror_path,
    plain_json,
    record_crc,
)
from rm65_driver.journal.scan import JournalCorrupt, plan_open
from stud_common.vocabulary import JournalStatus

_log = logging.getLogger(__name__)


# -- the journal -----------------------------------------------------------------------------


class Journal:
    """Append-only weld journal at ``path`` with its mirror (created with their directory if missing).

    Raises :class:`JournalCorrupt` when the files are damaged (see :mod:`.scan`). Thread-safe.
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
        self._status: dict[str, JournalStatus] = {}
        self._last: dict[str, dict[str, Any]] = {}
        self._where: dict[str, tuple[tuple[float, ...], tuple[float, ...]]] = {}  # last started: point, normal
        self._fds: list[int] = []
        self.path.parent.mkdir(parents=True, exist_ok=True)
        plan = plan_open(self.path)
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
                write_all(fd, b"\n")  # the torn bytes stay as evidence; new records start clean
                self._sync(fd)
            if plan.rewrite_mirror:
                atomic_write(self.mirror_path, self.path.read_bytes(), fsync)
            self._fds.append(os.open(self.mirror_path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644))
            if new_file and fsync:
                fsync_dir(self.path.parent)
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
            rec.update(plain_json(fields))
            line = encode_record(rec)
            rec["crc"] = record_crc(rec)
            sizes = [os.fstat(fd).st_size for fd in self._fds]
            target = self.path
            try:
                for fd, target in zip(self._fds, (self.path, self.mirror_path)):
                    write_all(fd, line)
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
            status = self._status.get(stud_id, JournalStatus.NEW)
        if status != JournalStatus.UNCERTAIN:
            raise JournalError(f"stud {stud_id!r} is {status}, not uncertain: nothing to resolve")
        self._append(RESOLVED, stud_id, "", decision=DECISION_WELDED if welded else DECISION_NOT_WELDED, note=note)

    def _apply(self, rec: dict[str, Any]) -> None:
        event = rec["event"]
        if event in TRANSITIONS:
            stud = rec["stud"]
            self._status[stud] = TRANSITIONS[event](self._status.get(stud, JournalStatus.NEW), rec)
            self._last[stud] = rec
            if event == STARTED and rec.get("position") is not None and rec.get("normal") is not None:
                self._where[stud] = (tuple(rec["position"]), tuple(rec["normal"]))
        else:  # torn_tail / recovered: the studs they list are uncertain unless welded
            for stud in rec.get("uncertain", []):
                if self._status.get(stud) != JournalStatus.WELDED:
                    self._status[stud] = JournalStatus.UNCERTAIN
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
                plan = plan_open(self.path)
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
    def status(self, stud_id: str) -> JournalStatus:
        """``new``, ``uncertain``, ``welded``, ``skipped`` or ``not_welded``."""
        with self._lock:
            return self._status.get(stud_id, JournalStatus.NEW)

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
            return {s for s, st in self._status.items() if st == JournalStatus.WELDED}

    @property
    def uncertain_ids(self) -> set[str]:
        with self._lock:
            return {s for s, st in self._status.items() if st == JournalStatus.UNCERTAIN}

    def standing_studs(self) -> list[tuple[str, tuple[float, ...], tuple[float, ...]]]:
        """The studs that stand on the part now: welded, or uncertain (one may stand there), each with
        the weld point and normal (world, m) of its last ``started`` record -- from every job this
        journal has seen, not only the running one. A stud whose record has neither (a journal
        written before they were recorded) is left out."""
        with self._lock:
            return [(sid, *self._where[sid]) for sid, st in self._status.items()
                    if st in (JournalStatus.WELDED, JournalStatus.UNCERTAIN) and sid in self._where]

    def is_welded(self, stud_id: str) -> bool:
        return self.status(stud_id) == JournalStatus.WELDED

    def is_uncertain(self, stud_id: str) -> bool:
        return self.status(stud_id) == JournalStatus.UNCERTAIN
