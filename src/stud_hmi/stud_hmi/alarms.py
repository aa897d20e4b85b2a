"""The HMI's alarms, ROS-free: codes with a severity and a title (docs/HMI.md lists each with its
cause and what to do), and the list that raises, acknowledges and clears them (the ``alarms`` message)."""
from __future__ import annotations

import enum
from dataclasses import dataclass

from stud_common import names


class Severity(enum.IntEnum):
    WARNING = 1    # needs the operator's attention; the job goes on
    ERROR = 2      # the job stops, or cannot start
    CRITICAL = 3   # safety: the arm is stopped and will not move

    @property
    def text(self) -> str:
        return self.name.lower()


@dataclass(frozen=True)
class AlarmDef:
    code: str
    severity: Severity
    title: str


class Code:
    """Alarm codes (docs/HMI.md lists each with its cause and what to do)."""

    ESTOP, ARM_FAULT, ARM_DISCONNECTED, ARM_LOST, UNCERTAIN = "A100", "A101", "A102", "A103", "A104"
    CELL_FAILED, CELL_LOST, UNREACHABLE = "A110", "A111", "A112"
    REGISTRATION = "A120"
    REWORK = "A130"
    HAND_EYE = "A140"
    NODE_WARN, NODE_ERROR, NODE_STALE = "A201", "A202", "A203"


ALARMS: dict[str, AlarmDef] = {d.code: d for d in (
    AlarmDef(Code.ESTOP, Severity.CRITICAL, "e-stop latched"),
    AlarmDef(Code.ARM_FAULT, Severity.CRITICAL, "arm in FAULT"),
    AlarmDef(Code.ARM_DISCONNECTED, Severity.ERROR, "arm controller not connected"),
    AlarmDef(Code.ARM_LOST, Severity.ERROR, "no arm state"),
    AlarmDef(Code.UNCERTAIN, Severity.WARNING, "uncertain studs need a decision"),
    AlarmDef(Code.CELL_FAILED, Severity.ERROR, "cell job failed"),
    AlarmDef(Code.CELL_LOST, Severity.ERROR, "no cell status"),
    AlarmDef(Code.UNREACHABLE, Severity.WARNING, "studs the arm cannot weld (named with the reason)"),
    AlarmDef(Code.REGISTRATION, Severity.WARNING, "registration not valid"),
    AlarmDef(Code.REWORK, Severity.WARNING, "studs need a rework decision"),
    AlarmDef(Code.HAND_EYE, Severity.ERROR, "nodes use different hand-eye calibrations"),
    AlarmDef(Code.NODE_WARN, Severity.WARNING, "node warning"),
    AlarmDef(Code.NODE_ERROR, Severity.ERROR, "node error"),
    AlarmDef(Code.NODE_STALE, Severity.ERROR, "node stale"),
)}
#: /diagnostics level -> the alarm it raises
DIAG_CODE = {1: Code.NODE_WARN, 2: Code.NODE_ERROR, 3: Code.NODE_STALE}
#: Nodes whose health the HMI reads from a topic of their own, with more detail than their
#: /diagnostics: their diagnostics raise no second alarm for the same cause.
STATE_SOURCES = {"rm65_driver": names.ARM_STATE, "cell_sequencer": names.CELL_STATUS}


@dataclass
class Alarm:
    code: str
    source: str
    text: str
    raised: float                 # s since the epoch
    acked: float | None = None
    cleared: float | None = None

    @property
    def key(self) -> str:
        return f"{self.code}@{self.source}"

    @property
    def severity(self) -> Severity:
        return ALARMS[self.code].severity

    def to_dict(self) -> dict:
        d = ALARMS[self.code]
        return {"key": self.key, "code": self.code, "severity": d.severity.text, "title": d.title,
                "source": self.source, "text": self.text, "raised": self.raised, "acked": self.acked is not None,
                "acked_at": self.acked, "cleared": self.cleared}


class AlarmList:
    """Alarms with a code and a severity: raised while their cause is there, acknowledged by the
    operator, cleared (moved to the history) when the cause is gone -- acknowledged or not.

    Each input (a *scope*: the arm, the cell, one node's diagnostics, ...) reports the complete set
    of alarms it causes now; what it reported before and not now has cleared. A cause that stays
    is one alarm however often it is reported (no repeat counts), and its acknowledgement stays.
    """

    def __init__(self, history: int = 50) -> None:
        self.history_size = history
        self._active: dict[str, Alarm] = {}
        self._history: list[Alarm] = []
        self._scopes: dict[str, set[str]] = {}
        self.changed = False

    def update(self, scope: str, causes: dict[tuple[str, str], str], now: float) -> None:
        """``causes``: (code, source) -> text, everything ``scope`` raises now."""
        keys = set()
        for (code, source), text in causes.items():
            alarm = Alarm(code, source, text, now)
            keys.add(alarm.key)
            old = self._active.get(alarm.key)
            if old is None:
                self._active[alarm.key] = alarm
                self.changed = True
            elif old.text != text:
                old.text = text
                self.changed = True
        for key in self._scopes.get(scope, set()) - keys:
            self._clear(key, now)
        self._scopes[scope] = keys

    def _clear(self, key: str, now: float) -> None:
        alarm = self._active.pop(key, None)
        if alarm is None:
            return
        alarm.cleared = now
        self._history.insert(0, alarm)
        del self._history[self.history_size:]
        self.changed = True

    def acknowledge(self, key: str, now: float) -> int:
        """Acknowledge one active alarm by its ``key`` ("A100@rm65_driver"), or all with "all";
        returns how many were acknowledged."""
        n = 0
        for alarm in self._active.values():
            if (key == "all" or alarm.key == key) and alarm.acked is None:
                alarm.acked = now
                n += 1
        self.changed = self.changed or n > 0
        return n

    def active(self) -> list[Alarm]:
        """Most severe first, then newest first."""
        return sorted(self._active.values(), key=lambda a: (-a.severity, -a.raised))

    def message(self) -> dict:
        """The ``alarms`` WebSocket message (docs/HMI.md)."""
        active = self.active()
        return {"type": "alarms", "active": [a.to_dict() for a in active],
                "history": [a.to_dict() for a in self._history],
                "unacked": sum(a.acked is None for a in active),
                "highest": active[0].severity.text if active else ""}
