"""The cell's state vocabulary, one place: the cell job's states (CellStatus.STATE_*) and the arm
driver's modes (ArmState.MODE_*), as enums whose values are the message constants (tested against
the generated messages) and whose ``text`` is the lower-case name the messages carry in
``state_text`` / the HMI shows. No ROS import: the pure cell job uses it too."""
from __future__ import annotations

import enum


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
