"""The studs a job cannot weld, named with the reason before any motion toward them.

:class:`UnreachableStuds` keeps the job's list: studs named at planning (the drawing's place and the
registered plane already rule them out, or no reachable camera station sees them), studs whose
target -- height and normal from a shot -- the driver's reach test refuses (checked on the exact
target before it is sent: a target the driver would refuse is never sent), and studs of a station
the arm refused. A stud named on one view's target and found weldable on another's is taken off
the list; one welded after all is too. Each entry is ``"unreachable: <why>"``, as the weld report,
the QA record, ``/cell/status`` and the HMI show it.
"""
from __future__ import annotations

import math
from typing import Callable

import numpy as np

from stud_cell.cell_reach import CellReach

#: The prefix of every reason here (report status "unreachable").
PREFIX = "unreachable: "


def _usable(position_m, normal) -> bool:
    """A target the reach test can be asked about: position and normal given, all finite."""
    if position_m is None or normal is None:
        return False
    return all(math.isfinite(float(v)) for v in (*position_m, *normal))


class UnreachableStuds:
    """The named studs (id -> reason) and the reach verdicts on targets (cached by their values)."""

    def __init__(self, reach: CellReach | None, on_change: Callable[[], None] = lambda: None,
                 say: Callable[[str], None] = lambda text: None) -> None:
        self.reach = reach
        self.on_change = on_change
        self.say = say   # one line for the operator's log each time a stud is named or taken off
        self.reasons: dict[str, str] = {}
        self._verdicts: dict[tuple, str] = {}

    @property
    def ids(self) -> list[str]:
        return list(self.reasons)

    def name(self, stud_id: str, why: str) -> None:
        reason = why if why.startswith(PREFIX) else PREFIX + why
        if self.reasons.get(stud_id) != reason:
            self.reasons[stud_id] = reason
            self.say(f"{stud_id} will not be welded: {reason}")
            self.on_change()

    def withdraw(self, stud_id: str) -> None:
        if self.reasons.pop(stud_id, None) is not None:
            self.say(f"{stud_id} is weldable after all (another view's target): taken off the unreachable list")
            self.on_change()

    def verdict(self, position_m, normal, reach: CellReach | None = None) -> str:
        """Why the driver's reach test (``reach``, default the job's) refuses this target, as a reason
        (``"unreachable: ..."``; "" when it accepts it, or no test is known). Names nobody. Cached by
        the target's values and the arm base's pose (on a rail, each carriage position's own)."""
        reach = self.reach if reach is None else reach
        if reach is None or not _usable(position_m, normal):
            return ""
        p = tuple(float(v) for v in position_m)
        n = tuple(float(v) for v in normal)
        base = None if reach.world_T_base is None else tuple(float(v) for v in np.asarray(reach.world_T_base).ravel())
        key = (p, n, base)
        if key not in self._verdicts:
            verdict = reach.stud(p, n)
            self._verdicts[key] = "" if verdict.ok else PREFIX + verdict.reason
        return self._verdicts[key]

    def target_problem(self, stud_id: str, position_m, normal) -> str:
        """Why the driver would refuse this target ("" when it would weld it, or no reach test is
        known). Names the stud, or takes it off the list, accordingly."""
        why = self.verdict(position_m, normal)
        if why:
            self.name(stud_id, why)
        elif self.reach is not None and _usable(position_m, normal):
            self.withdraw(stud_id)
        return why

    def apply(self, stud_report: dict[str, dict], qa: dict[str, dict]) -> None:
        """Write the named studs' status and reason into the weld report's and the QA record's rows
        (a stud welded after all is no longer named)."""
        for sid in [s for s in self.reasons if stud_report.get(s, {}).get("welded")]:
            self.withdraw(sid)
        for sid, reason in self.reasons.items():
            if sid in stud_report:
                stud_report[sid]["status"] = "unreachable"
                stud_report[sid]["reason"] = reason
            if sid in qa:
                qa[sid]["reasons"] = [reason]


__all__ = ["PREFIX", "UnreachableStuds"]
