"""The cell's vocabulary, one place: a weld target's status (WeldTarget.STATUS_*), the cell job's
states (CellStatus.STATE_*) and the arm driver's modes (ArmState.MODE_*), as enums whose values are
the message constants (tested against the generated messages) and whose ``text`` is the lower-case
name the messages carry (``status_text``, ``state_text``) and the reports and the HMI show. No ROS
import: the pure modules use it too."""
from __future__ import annotations

import enum


class TargetStatus(enum.IntEnum):
    """WeldTarget.STATUS_*: what a view made of one stud (matching, normal, reach, gun clearance)."""

    OK = 0
    OUT_OF_VIEW = 1
    NO_DEPTH = 2
    NOT_CONVERGED = 3
    NORMAL_UNCERTAIN = 4     # the normal's uncertainty could lean the stud beyond the budget
    UNREACHABLE = 5
    NO_NORMAL = 6
    DEPTH_DISCONTINUITY = 7
    GUN_BLOCKED = 8

    @property
    def text(self) -> str:
        return self.name.lower()


#: Statuses another view of the same stud may cure (a new shot, another station): the cell shoots
#: such studs again before giving up on them.
VIEW_DEPENDENT = frozenset({TargetStatus.OUT_OF_VIEW, TargetStatus.NO_DEPTH, TargetStatus.NOT_CONVERGED,
                            TargetStatus.NO_NORMAL, TargetStatus.NORMAL_UNCERTAIN, TargetStatus.DEPTH_DISCONTINUITY})


class CellState(enum.IntEnum):
    """CellStatus.STATE_* (the cell sequencer's job)."""

    IDLE = 0
    REGISTERING = 1
    MOVING = 2
    SHOOTING = 3
    MATCHING = 4
    WELDING = 5
    PAUSED = 6
    DONE = 7
    FAILED = 8
    INSPECTING = 9      # a station shot again after its welds, its studs judged

    @property
    def text(self) -> str:
        return self.name.lower()


class ArmMode(enum.IntEnum):
    """ArmState.MODE_* (the RM-65 driver)."""

    IDLE = 0
    MOVING = 1
    WELDING = 2
    PAUSED = 3
    FAULT = 4
    ESTOP = 5
    DISCONNECTED = 6

    @property
    def text(self) -> str:
        return self.name.lower()
