"""The job's time as the HMI shows it, ROS-free: the cell states in which a job is under way, and
the clock of the running job without its pauses, with the cycle per stud from the welds' times."""
from __future__ import annotations

from stud_common.vocabulary import CellState

# the cell's states: stud_common.vocabulary (tests check them against the messages)
#: A job is under way in these states (PAUSED is under way too, but does not move).
RUNNING_STATES = frozenset({CellState.REGISTERING, CellState.MOVING, CellState.SHOOTING, CellState.MATCHING,
                            CellState.WELDING, CellState.INSPECTING})
#: No job runs: a new one may start.
ENDED_STATES = frozenset({CellState.IDLE, CellState.DONE, CellState.FAILED})
#: The sequencer ends a job the operator stopped in FAILED with this message: not an alarm.
OPERATOR_STOP_TEXT = "stopped by the operator"


class JobClock:
    """Time of the running job without its pauses, and the cycle per stud from the welds' times."""

    def __init__(self) -> None:
        self.started: float | None = None
        self.ended: float | None = None
        self._paused_since: float | None = None
        self._paused_s = 0.0
        self._welds: list[float] = []  # active job time of each weld reported [s]

    def cell_state(self, state: int, now: float) -> None:
        under_way = state in RUNNING_STATES or state == CellState.PAUSED
        if under_way and (self.started is None or self.ended is not None):
            self.started, self.ended, self._paused_since, self._paused_s, self._welds = now, None, None, 0.0, []
        if self.started is None or self.ended is not None:
            return
        if state == CellState.PAUSED and self._paused_since is None:
            self._paused_since = now
        elif state != CellState.PAUSED and self._paused_since is not None:
            self._paused_s += now - self._paused_since
            self._paused_since = None
        if state in ENDED_STATES:
            self.ended = now

    @property
    def running(self) -> bool:
        return self.started is not None and self.ended is None

    def active_s(self, now: float) -> float | None:
        """Job time so far (or of the ended job) without pauses [s]; None before the first job."""
        if self.started is None:
            return None
        end = self.ended if self.ended is not None else now
        paused = self._paused_s + (end - self._paused_since if self._paused_since is not None else 0.0)
        return max(0.0, end - self.started - paused)

    def welded(self, now: float) -> None:
        if self.running:
            self._welds.append(self.active_s(now) or 0.0)

    @property
    def cycle_s(self) -> float | None:
        """Mean time per stud between the job's first and last weld (moves and shots between
        stations included, pauses not); None before the second weld."""
        w = self._welds
        return (w[-1] - w[0]) / (len(w) - 1) if len(w) >= 2 else None

    @property
    def last_cycle_s(self) -> float | None:
        w = self._welds
        return w[-1] - w[-2] if len(w) >= 2 else None
