"""The weld journal's record format: events, the checksum, one record per line, and the status rules.

Records (one JSON object per line; ``t`` = UTC ISO time)::

    {"seq": 7, "event": "started", "stud": "S0001", "job": "20261122T100000-1a2b3c",
     "journal": "9f0c2d4e6a1b", "t": "...", "position": [...], ..., "crc": "5d1e0a7f"}

* ``seq``: 1, 2, 3 ... in file order (a missing, repeated or reordered line breaks the count);
* ``job``: the id :class:`~rm65_driver.weld.weld_sequence.WeldSequence` gives each job ("" for an
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

**Status rules** (one table, :data:`TRANSITIONS`; the statuses are
:class:`stud_common.vocabulary.JournalStatus`): *welded is final* -- nothing but a welded
stud's own records can follow, and none of them makes it weldable again. ``started`` ->
**uncertain** (the gun may or may not have fired) until ``welded`` or an operator's
``resolved``. ``skipped`` never changes an uncertain or welded stud (a later job that skips
it, say as "needs an operator decision", does not make it weldable). ``resolved: not_welded``
-> not_welded (may be welded by a later job); ``torn_tail`` / ``recovered`` make the studs they
list uncertain unless welded.

Pure: no files here (reading them is :mod:`.scan`, writing :mod:`.writer`).
"""
from __future__ import annotations

import json
import os
import re
import zlib
from pathlib import Path
from typing import Any, Callable

from stud_common.vocabulary import JournalStatus

STARTED, WELDED, SKIPPED, RESOLVED = "started", "welded", "skipped", "resolved"
TORN_TAIL, RECOVERED = "torn_tail", "recovered"
#: A ``resolved`` record's ``decision``: the status the operator gives the stud (ResolveStud.DECISION_*).
DECISION_WELDED, DECISION_NOT_WELDED = JournalStatus.WELDED.value, JournalStatus.NOT_WELDED.value
_STUD_EVENTS = frozenset({STARTED, WELDED, SKIPPED, RESOLVED})
_EVENTS = _STUD_EVENTS | {TORN_TAIL, RECOVERED}


MIRROR_SUFFIX = ".mirror"
_LEAD_KEYS = ("seq", "event", "stud")  # first on disk: a torn line still names its stud
_STUD_RE = re.compile(rb'"stud":"((?:[^"\\\x00-\x1f]|\\.){1,200})"')


class JournalError(RuntimeError):
    """The journal cannot be written or repaired, or a request contradicts it (e.g. resolving a
    stud that is not uncertain)."""


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


def plain_json(value: Any) -> Any:
    """``value`` as plain JSON types (numpy arrays/scalars to lists/floats); non-finite numbers refused."""
    try:
        return json.loads(json.dumps(value, default=_json_default, allow_nan=False))
    except (TypeError, ValueError) as exc:
        raise JournalError(f"journal record not written: {exc}") from exc


def _reject_constant(name: str) -> Any:
    raise ValueError(f"{name} is not valid JSON")


def parse_line(raw: bytes) -> tuple[dict[str, Any] | None, str]:
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


def excerpt(raw: bytes, n: int = 16) -> str:
    """The first ``n`` bytes of a damaged line, for a message (with its length if cut)."""
    return repr(raw[:n]) + (f"... ({len(raw)} bytes)" if len(raw) > n else "")


def studs_in(raw: bytes) -> tuple[str, ...]:
    """The stud ids that can still be read in a (possibly damaged) line, in order, each once."""
    out = []
    for m in _STUD_RE.finditer(raw):
        try:
            sid = json.loads(b'"' + m.group(1) + b'"')
        except ValueError:
            continue
        if sid not in out:
            out.append(sid)
    return tuple(out)


def _json_default(obj: Any) -> Any:
    tolist = getattr(obj, "tolist", None)
    if tolist is not None:  # numpy arrays / scalars
        return tolist()
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


# -- status rules ----------------------------------------------------------------------------


def _after_started(status: JournalStatus, rec: dict[str, Any]) -> JournalStatus:
    return status if status == JournalStatus.WELDED else JournalStatus.UNCERTAIN


def _after_skipped(status: JournalStatus, rec: dict[str, Any]) -> JournalStatus:
    # A skip never changes a welded or an uncertain stud: only an operator makes an uncertain one weldable.
    return status if status in (JournalStatus.WELDED, JournalStatus.UNCERTAIN) else JournalStatus.SKIPPED


def _after_resolved(status: JournalStatus, rec: dict[str, Any]) -> JournalStatus:
    if rec.get("decision") == DECISION_WELDED or status == JournalStatus.WELDED:
        return JournalStatus.WELDED
    return JournalStatus.NOT_WELDED


#: (status before, record) -> status after, per stud event. Welded is final in every row.
TRANSITIONS: dict[str, Callable[[JournalStatus, dict[str, Any]], JournalStatus]] = {
    STARTED: _after_started,
    WELDED: lambda status, rec: JournalStatus.WELDED,
    SKIPPED: _after_skipped,
    RESOLVED: _after_resolved,
}

