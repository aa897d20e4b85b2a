"""The weld journal: an append-only JSON-lines record of what happened to every stud.

It is what makes a job resumable without ever welding a stud twice. Each state change is one
line, written with ``flush`` + ``os.fsync`` *before* the driver sends its next command, so
after a crash or a power cut the file tells the truth up to the last completed step.

Records (one JSON object per line, ``t`` = UTC ISO time)::

    {"t": ..., "event": "started",  "stud": "S0001", ...}   # trigger about to fire: uncertain until "welded"
    {"t": ..., "event": "welded",   "stud": "S0001"}
    {"t": ..., "event": "skipped",  "stud": "S0002", "reason": "inclination 7.2 deg > 5.0 deg"}
    {"t": ..., "event": "resolved", "stud": "S0003", "decision": "welded" | "not_welded", "note": "..."}

A stud's status is decided by its last record: ``started`` -> **uncertain** (the gun may or
may not have fired: e.g. the connection dropped mid-stud) until an operator resolves it;
``welded`` or ``resolved: welded`` -> welded (never weld again); ``skipped`` or
``resolved: not_welded`` -> may be (re)tried by a later job.

A crash in the middle of a write leaves a torn last line: loading ignores it with a warning,
and the next append starts on a fresh line. Lines that are not valid records elsewhere are
also skipped with a warning (never silently).
"""
from __future__ import annotations

import datetime as _dt
import json
import logging
import os
import threading
from pathlib import Path
from typing import Any

_log = logging.getLogger(__name__)

STARTED, WELDED, SKIPPED, RESOLVED = "started", "welded", "skipped", "resolved"
DECISION_WELDED, DECISION_NOT_WELDED = "welded", "not_welded"
_EVENTS = {STARTED, WELDED, SKIPPED, RESOLVED}

#: Status names returned by :meth:`Journal.status`.
STATUS_NEW, STATUS_UNCERTAIN, STATUS_WELDED, STATUS_SKIPPED, STATUS_NOT_WELDED = (
    "new", "uncertain", "welded", "skipped", "not_welded")


class JournalError(RuntimeError):
    """The journal cannot be written, or a request contradicts it (e.g. resolving a stud that is not uncertain)."""


class Journal:
    """Append-only weld journal at ``path`` (created with its directory if missing).

    Thread-safe. ``warnings`` lists what was tolerated while loading (torn/invalid lines).
    """

    def __init__(self, path: str | os.PathLike[str], fsync: bool = True):
        self.path = Path(path)
        self.fsync = fsync
        self.warnings: list[str] = []
        self._lock = threading.Lock()
        self._status: dict[str, str] = {}
        self._last: dict[str, dict[str, Any]] = {}
        self.path.parent.mkdir(parents=True, exist_ok=True)
        needs_newline = self._load()
        new_file = not self.path.exists()
        self._file = open(self.path, "a", encoding="utf-8")
        if needs_newline:
            self._file.write("\n")  # the torn line stays as evidence; new records start clean
            self._sync()
        if new_file and fsync:
            _fsync_dir(self.path.parent)

    # -- loading ---------------------------------------------------------------------------
    def _load(self) -> bool:
        """Replay the file; return True when it does not end with a newline (torn last line)."""
        if not self.path.exists():
            return False
        data = self.path.read_bytes()
        if not data:
            return False
        torn = not data.endswith(b"\n")
        lines = data.split(b"\n")
        if not torn:
            lines = lines[:-1]
        for no, raw in enumerate(lines, start=1):
            if not raw.strip():
                continue
            last_line = no == len(lines)
            try:
                rec = json.loads(raw.decode("utf-8"))
                if not isinstance(rec, dict) or rec.get("event") not in _EVENTS or not isinstance(rec.get("stud"), str):
                    raise ValueError("not a journal record")
            except (UnicodeDecodeError, ValueError) as exc:
                what = "torn last line (crash during a write?)" if last_line and torn else "invalid line"
                msg = f"{self.path}:{no}: {what} ignored: {raw[:80]!r} ({exc})"
                self.warnings.append(msg)
                _log.warning("weld journal: %s", msg)
                continue
            self._apply(rec)
        return torn

    def _apply(self, rec: dict[str, Any]) -> None:
        stud, event = rec["stud"], rec["event"]
        if event == STARTED:
            status = STATUS_UNCERTAIN
        elif event == WELDED:
            status = STATUS_WELDED
        elif event == SKIPPED:
            # A skip never downgrades a welded or uncertain stud (a later job may skip it as "already welded").
            status = self._status.get(stud, STATUS_NEW)
            if status not in (STATUS_WELDED, STATUS_UNCERTAIN):
                status = STATUS_SKIPPED
        else:
            status = STATUS_WELDED if rec.get("decision") == DECISION_WELDED else STATUS_NOT_WELDED
        self._status[stud] = status
        self._last[stud] = rec

    # -- writing ---------------------------------------------------------------------------
    def _sync(self) -> None:
        self._file.flush()
        if self.fsync:
            os.fsync(self._file.fileno())

    def _append(self, event: str, stud_id: str, **fields: Any) -> dict[str, Any]:
        rec = {"t": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="milliseconds"), "event": event,
               "stud": str(stud_id), **fields}
        line = json.dumps(rec, separators=(",", ":"), default=_json_default) + "\n"
        with self._lock:
            if self._file.closed:
                raise JournalError(f"journal {self.path} is closed")
            try:
                self._file.write(line)
                self._sync()
            except OSError as exc:
                raise JournalError(f"cannot write the weld journal {self.path}: {exc}") from exc
            self._apply(rec)
        return rec

    def started(self, stud_id: str, **info: Any) -> None:
        """The stud is at the surface and the trigger is about to fire (uncertain from now on)."""
        self._append(STARTED, stud_id, **info)

    def welded(self, stud_id: str, **info: Any) -> None:
        self._append(WELDED, stud_id, **info)

    def skipped(self, stud_id: str, reason: str, **info: Any) -> None:
        self._append(SKIPPED, stud_id, reason=reason, **info)

    def resolve(self, stud_id: str, welded: bool, note: str = "") -> None:
        """Operator decision on an uncertain stud: ``welded`` (never weld again) or not (may be welded)."""
        with self._lock:
            status = self._status.get(stud_id, STATUS_NEW)
        if status != STATUS_UNCERTAIN:
            raise JournalError(f"stud {stud_id!r} is {status}, not uncertain: nothing to resolve")
        self._append(RESOLVED, stud_id, decision=DECISION_WELDED if welded else DECISION_NOT_WELDED, note=note)

    def close(self) -> None:
        with self._lock:
            if not self._file.closed:
                self._file.close()

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
