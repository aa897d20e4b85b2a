"""The operator's rework decisions on studs that did not pass the post-weld inspection (ROS-free).

A stud that fails inspection is never welded again automatically (the weld journal knows it is
welded); what happens to it is a person's decision, recorded here: ``rework`` (a person repairs or
replaces it) or ``accept`` (it is fit as it stands, e.g. after a gauge check). Each decision is one
JSON line, appended with its time and who took it, in ``<output dir>/rework_decisions.jsonl``
(stud_inspection.operator_log)::

    {"time": "2025-05-01T10:12:03.120+00:00", "stamp": 1746094323.12, "stud_id": "S0004",
     "decision": "rework", "verdict": "fail", "note": "lean 8 deg, cut off and re-weld by hand",
     "operator": "A. Inspector"}

The newest line of a stud is its decision (:func:`latest_decisions`). The inspector node serves
``/inspection/record_rework`` with this module, publishes each record on ``/inspection/rework`` and
fills the QA record's ``rework`` column (docs/INSPECTION.md).
"""
from __future__ import annotations

import enum
import json
import os
from dataclasses import asdict, dataclass
from datetime import datetime, timezone
from pathlib import Path

from stud_inspection.inspection import Verdict
from stud_inspection.operator_log import OperatorError, append_line, complete_lines, operator_name

FILE_NAME = "rework_decisions.jsonl"
MAX_NOTE_CHARS = 2000


class ReworkDecision(str, enum.Enum):
    REWORK = "rework"
    ACCEPT = "accept"


#: Verdicts a person decides on; ``pass`` needs no decision and ``not_welded`` has nothing to rework.
NEEDS_DECISION = frozenset({Verdict.FAIL.value, Verdict.MISSING.value, Verdict.NOT_INSPECTED.value})


class ReworkError(ValueError):
    """A decision that cannot be recorded; the message says why."""


@dataclass(frozen=True)
class ReworkRecord:
    stud_id: str
    decision: str        # ReworkDecision value
    verdict: str         # the inspection verdict the decision was taken on
    note: str
    stamp: float         # s since the epoch
    operator: str = ""   # who decided ("" only in decisions recorded before operators signed them)

    @property
    def time(self) -> str:
        return datetime.fromtimestamp(self.stamp, timezone.utc).isoformat(timespec="milliseconds")

    def to_json(self) -> str:
        return json.dumps({"time": self.time, **asdict(self)}, ensure_ascii=False, allow_nan=False)

    def for_qa_record(self) -> dict:
        """What the QA record's row carries (qa_report's ``rework``, ``rework_note``, ``rework_operator``,
        ``rework_time``)."""
        return {"decision": self.decision, "note": self.note, "time": self.time, "operator": self.operator}


def make_record(stud_id: str, decision: str, note: str, verdict: str | None, stamp: float,
                operator: str | None = None) -> ReworkRecord:
    """A checked decision on ``stud_id``, whose last inspection ``verdict`` (None: never inspected),
    signed by ``operator`` (required when given: None only for callers that sign elsewhere)."""
    stud_id, note = stud_id.strip(), note.strip()
    if not stud_id:
        raise ReworkError("no stud_id given")
    if operator is not None:
        try:
            operator = operator_name(operator)
        except OperatorError as exc:
            raise ReworkError(str(exc)) from None
    try:
        decision = ReworkDecision(decision.strip().lower()).value
    except ValueError:
        raise ReworkError(f"decision {decision!r} is not one of "
                          f"{', '.join(d.value for d in ReworkDecision)}") from None
    if verdict is None:
        raise ReworkError(f"{stud_id} has not been inspected: nothing to decide")
    if verdict not in NEEDS_DECISION:
        raise ReworkError(f"{stud_id} is '{verdict}': only {', '.join(sorted(NEEDS_DECISION))} studs take a "
                          "rework decision")
    if len(note) > MAX_NOTE_CHARS:
        raise ReworkError(f"the note has {len(note)} characters; at most {MAX_NOTE_CHARS}")
    return ReworkRecord(stud_id, decision, verdict, note, stamp, operator or "")


def append_record(path: str | os.PathLike[str], record: ReworkRecord) -> Path:
    """Append ``record`` as one line (flushed and fsynced: a decision must survive a power cut)."""
    return append_line(path, record.to_json())


def latest_decisions(path: str | os.PathLike[str]) -> dict[str, ReworkRecord]:
    """The newest decision per stud id in the decisions file (none when it does not exist yet).

    A last line without its newline is an append cut short (a power cut): it is skipped. Any other
    line that is not a decision is a :class:`ReworkError` naming the file and the line."""
    path = Path(path)
    latest: dict[str, ReworkRecord] = {}
    try:
        for number, line in complete_lines(path):
            try:
                doc = json.loads(line)
                record = ReworkRecord(str(doc["stud_id"]), ReworkDecision(doc["decision"]).value, str(doc["verdict"]),
                                      str(doc.get("note", "")), float(doc["stamp"]), str(doc.get("operator", "")))
            except (ValueError, KeyError, TypeError) as exc:
                raise ReworkError(f"{path}:{number}: not a rework decision ({type(exc).__name__}: {exc}); expected "
                                  "one JSON object with stud_id, decision, verdict, note, stamp, operator") from None
            latest[record.stud_id] = record
    except (OSError, UnicodeDecodeError) as exc:
        raise ReworkError(f"{path}: cannot read the rework decisions ({exc})") from None
    return latest

