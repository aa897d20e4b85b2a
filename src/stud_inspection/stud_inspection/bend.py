"""Bend-test results the inspector enters for the studs the QA record lists (stud_inspection.sampling).

A bend test is done by a person with a bending tool (or a tube over the stud): the stud is bent to
the code's angle and passes when neither the stud nor its weld cracks. The result -- ``pass`` or
``fail``, the angle actually bent, a note, who tested and when -- is one JSON line appended to
``<output dir>/qa/bend_tests.jsonl`` (stud_inspection.operator_log)::

    {"time": "2025-05-01T10:40:00.000+00:00", "stamp": 1746096000.0, "stud_id": "S0012",
     "result": "pass", "angle_deg": 30.0, "note": "", "operator": "A. Inspector"}

The newest line of a stud is its result (:func:`latest_results`). The inspector node serves
``/inspection/record_bend_test`` with this module and merges every result into the QA record; a
failed bend test puts the stud's neighbours in weld order on the list too. No ROS here.
"""
from __future__ import annotations

import enum
import json
import math
import os
from dataclasses import asdict, dataclass
from datetime import datetime, timezone
from pathlib import Path

from stud_inspection.operator_log import OperatorError, append_line, complete_lines, operator_name

FILE_NAME = "bend_tests.jsonl"
MAX_NOTE_CHARS = 2000


class BendResult(str, enum.Enum):
    PASS = "pass"
    FAIL = "fail"


#: Verdicts of studs that stand and can be bent (a missing stud or one never welded cannot).
BENDABLE = frozenset({"pass", "fail", "not_inspected"})


class BendError(ValueError):
    """A bend-test result that cannot be recorded; the message says why."""


@dataclass(frozen=True)
class BendRecord:
    stud_id: str
    result: str               # BendResult value
    angle_deg: float | None   # as bent (None: not said; the list's angle is the one asked)
    note: str
    operator: str
    stamp: float              # s since the epoch

    @property
    def time(self) -> str:
        return datetime.fromtimestamp(self.stamp, timezone.utc).isoformat(timespec="milliseconds")

    def to_json(self) -> str:
        return json.dumps({"time": self.time, **asdict(self)}, ensure_ascii=False, allow_nan=False)

    def for_qa_record(self) -> dict:
        """What the QA record's row carries in its ``bend_test``."""
        return {"result": self.result, "bent_deg": self.angle_deg, "note": self.note, "operator": self.operator,
                "time": self.time}


def make_record(stud_id: str, result: str, angle_deg: float | None, note: str, operator: str, verdict: str | None,
                stamp: float) -> BendRecord:
    """A checked bend-test result on ``stud_id``, whose inspection ``verdict`` (None: unknown: never
    welded or inspected in this job), signed by ``operator``."""
    stud_id, note = str(stud_id).strip(), str(note).strip()
    if not stud_id:
        raise BendError("no stud_id given")
    try:
        result = BendResult(str(result).strip().lower()).value
    except ValueError:
        raise BendError(f"result {result!r} is not one of {', '.join(r.value for r in BendResult)}") from None
    try:
        operator = operator_name(operator)
    except OperatorError as exc:
        raise BendError(str(exc)) from None
    if verdict is None:
        raise BendError(f"{stud_id} is not a welded stud of this job's QA record: nothing to bend")
    if verdict not in BENDABLE:
        raise BendError(f"{stud_id} is '{verdict}': only a stud that stands ({', '.join(sorted(BENDABLE))}) can be "
                        "bend-tested")
    if angle_deg is not None and not (math.isfinite(angle_deg) and 0 < angle_deg <= 180):
        angle_deg = None  # "not said" (a message's NaN or 0)
    if len(note) > MAX_NOTE_CHARS:
        raise BendError(f"the note has {len(note)} characters; at most {MAX_NOTE_CHARS}")
    return BendRecord(stud_id, result, None if angle_deg is None else float(angle_deg), note, operator, stamp)


def append_record(path: str | os.PathLike[str], record: BendRecord) -> Path:
    """Append ``record`` as one line (flushed and fsynced before the result is confirmed)."""
    return append_line(path, record.to_json())


def latest_results(path: str | os.PathLike[str]) -> dict[str, BendRecord]:
    """The newest bend-test result per stud in ``path`` (none when it does not exist yet); a damaged
    line is a :class:`BendError` naming the file and the line."""
    path = Path(path)
    latest: dict[str, BendRecord] = {}
    try:
        for number, line in complete_lines(path):
            try:
                doc = json.loads(line)
                angle = doc.get("angle_deg")
                record = BendRecord(str(doc["stud_id"]), BendResult(doc["result"]).value,
                                    None if angle is None else float(angle), str(doc.get("note", "")),
                                    str(doc["operator"]), float(doc["stamp"]))
            except (ValueError, KeyError, TypeError) as exc:
                raise BendError(f"{path}:{number}: not a bend-test result ({type(exc).__name__}: {exc}); expected one "
                                "JSON object with stud_id, result, angle_deg, note, operator, stamp") from None
            latest[record.stud_id] = record
    except (OSError, UnicodeDecodeError) as exc:
        raise BendError(f"{path}: cannot read the bend-test results ({exc})") from None
    return latest


__all__ = ["BENDABLE", "BendError", "BendRecord", "BendResult", "FILE_NAME", "append_record", "latest_results",
           "make_record"]
