"""One vocabulary: stud_common.vocabulary's enums are the message constants, name for name."""
from __future__ import annotations

import re
from pathlib import Path

from stud_welding_msgs.msg import ArmState, CellStatus, WeldTarget
from stud_welding_msgs.srv import ResolveStud

from stud_common.vocabulary import (
    VIEW_DEPENDENT,
    ArmMode,
    CellState,
    JournalStatus,
    MatchAlgorithm,
    OnDisconnect,
    StudOrder,
    TargetStatus,
    WeldPhase,
    choices,
)
from stud_planner.matching.matchers import MatchStatus
from stud_planner.matching.view_targets import STATUS_TEXT

MSGS = Path(__file__).resolve().parents[2] / "src" / "stud_welding_msgs"


def _documented_texts(interface: str, field: str) -> list[str]:
    """The texts a string field's comment lists in the interface file (``string phase  # "a", "b"``): a
    string field has no constants, its values are documented where it is declared."""
    line = next(ln for ln in (MSGS / interface).read_text().splitlines() if re.match(rf"string {field}\b", ln))
    return re.findall(r'"([^"]+)"', line.partition("#")[2])


def _constants(msg, prefix: str) -> dict:
    return {k[len(prefix):]: getattr(msg, k) for k in dir(msg) if k.startswith(prefix) and k.isupper()}


def test_the_enums_are_the_message_constants():
    assert {s.name: s.value for s in TargetStatus} == _constants(WeldTarget, "STATUS_")
    assert {s.name: s.value for s in CellState} == _constants(CellStatus, "STATE_")
    assert {m.name: m.value for m in ArmMode} == _constants(ArmState, "MODE_")


def test_the_matchers_statuses_and_the_texts_come_from_the_vocabulary():
    assert all(TargetStatus(m.value).name == m.name for m in MatchStatus)
    assert STATUS_TEXT == {int(s): s.name.lower() for s in TargetStatus}
    assert TargetStatus.OK not in VIEW_DEPENDENT and TargetStatus.GUN_BLOCKED not in VIEW_DEPENDENT
    assert TargetStatus.NORMAL_UNCERTAIN in VIEW_DEPENDENT  # shot again from another view, never welded blind


def test_the_string_vocabularies_are_the_texts_the_messages_document():
    assert choices(WeldPhase) == tuple(_documented_texts("action/WeldJob.action", "phase"))
    assert choices(MatchAlgorithm) == tuple(_documented_texts("msg/WeldTargetArray.msg", "algorithm"))
    # an operator's decision on an uncertain stud gives it the journal status of the same name
    decisions = _constants(ResolveStud.Request, "DECISION_")
    assert decisions and set(decisions) <= set(JournalStatus.__members__)


def test_a_member_is_its_text_wherever_text_is_expected():
    assert WeldPhase.WELD == "weld" and f"{WeldPhase.DWELL}" == "dwell"
    assert str(JournalStatus.NOT_WELDED) == "not_welded"
    assert {WeldPhase.APPROACH: 1}["approach"] == 1   # a lookup by the text a message carries
    assert choices(StudOrder) == ("tour", "path", "given") and choices(OnDisconnect) == ("continue", "abort")
    assert all(type(text) is str for text in choices(JournalStatus))   # parameter choices are plain text
