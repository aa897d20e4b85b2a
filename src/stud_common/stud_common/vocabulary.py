"""The cell's vocabulary, one place: a weld target's status (WeldTarget.STATUS_*), the cell job's
states (CellStatus.STATE_*) and the arm driver's modes (ArmState.MODE_*), as enums whose values are
the message constants (tested against the generated messages) and whose ``text`` is the lower-case
name the messages carry (``status_text``, ``state_text``) and the reports and the HMI show.

The words that travel as text are string enums whose values are that text: a stud's weld phase
(WeldJob feedback ``phase``), a stud's status in the weld journal, and the modes chosen by a
parameter (``stud_order``, ``on_disconnect``, the matcher's ``algorithm``: a parameter's choices are
:func:`choices` of its enum). A member *is* its text (``WeldPhase.WELD == "weld"``), so journal files,
messages and the HMI see the same words as before. No ROS import: the pure modules use it too."""
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


class WeldPhase(enum.StrEnum):
    """WeldJob feedback ``phase``: the step of one stud's weld cycle the arm driver is in."""

    APPROACH = "approach"   # to the standoff pose above the stud (and, with the fast approach, most of the way in)
    DESCEND = "descend"     # the slow final move to contact
    WELD = "weld"           # the trigger pulse
    DWELL = "dwell"         # the gun holds the stud while the weld sets
    RETRACT = "retract"     # back out along the normal; the weld is journalled by now
    SKIP = "skip"           # the stud was refused (safety, reach, a welded neighbour) or was already done


class JournalStatus(enum.StrEnum):
    """A stud's status in the arm driver's weld journal (rm65_driver.journal.records' rules)."""

    NEW = "new"                 # no record of it
    UNCERTAIN = "uncertain"     # started, never confirmed: the gun may or may not have fired
    WELDED = "welded"           # final: never welded again
    SKIPPED = "skipped"         # refused by a job; may be welded by a later one
    NOT_WELDED = "not_welded"   # an operator decided it was not welded: may be welded by a later job


class StudOrder(enum.StrEnum):
    """The arm driver's ``stud_order``: the order a weld job's studs are welded in."""

    TOUR = "tour"     # a short joint-space path from the current joints and back
    PATH = "path"     # a short path, no way back
    GIVEN = "given"   # the request's order


class OnDisconnect(enum.StrEnum):
    """The arm driver's ``on_disconnect``: what a job does after a connection loss mid-weld."""

    CONTINUE = "continue"   # go on with the next studs (the stud is uncertain: an operator decides)
    ABORT = "abort"         # end the job


class MatchAlgorithm(enum.StrEnum):
    """The matcher's ``algorithm`` (WeldTargetArray ``algorithm``)."""

    BATCH = "batch"   # ours
    FPM = "fpm"       # the paper's
    BFS = "bfs"       # the paper's baseline


def choices(vocabulary: type[enum.StrEnum]) -> tuple[str, ...]:
    """The texts of a string vocabulary, in its order: a parameter's or a CLI option's choices."""
    return tuple(member.value for member in vocabulary)
