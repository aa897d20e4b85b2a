"""One vocabulary: stud_common.vocabulary's enums are the message constants, name for name."""
from __future__ import annotations

from stud_welding_msgs.msg import ArmState, CellStatus, WeldTarget

from stud_common.vocabulary import VIEW_DEPENDENT, ArmMode, CellState, TargetStatus
from stud_planner.matching.matchers import MatchStatus
from stud_planner.matching.view_targets import STATUS_TEXT


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
