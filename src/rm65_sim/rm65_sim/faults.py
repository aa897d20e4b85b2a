"""Fault injection for the controller simulator (tests): drops, refusals, controller errors, stalls.

:class:`FaultInjection` is a part of :class:`~rm65_sim.simulator.ArmSimulator`: each call
queues a :class:`Fault` (or sets the connection refusal count) under the simulator's lock; the
command handling, the motion thread and the accept loop take them from there
(:meth:`FaultInjection._take_fault`).
"""
from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any, Sequence


@dataclass
class Fault:
    """One pending injected fault: fires on the ``remaining``-th matching command (None: any)."""

    command: str | None
    remaining: int
    action: str
    code: int = 0
    fraction: float = 0.5

    def matches(self, name: str) -> bool:
        return self.command is None or self.command == name


class FaultInjection:
    """The fault-injection methods of :class:`~rm65_sim.simulator.ArmSimulator` (state lives there)."""

    _lock: threading.RLock
    _faults: list[Fault]
    _refuse: int  # connections still to refuse; -1: all
    _errors: list[int]
    _conns: dict[int, Any]

    def drop_connections(self) -> None:
        """Close every client connection now (as a cable pull would look to the client)."""
        with self._lock:
            conns = list(self._conns.values())
        for c in conns:
            c.close()

    def drop_after_commands(self, n: int, command: str | None = None) -> None:
        """Close the connection right after replying to the ``n``-th (matching) command from now."""
        with self._lock:
            self._faults.append(Fault(command, int(n), "drop_after"))

    def drop_mid_motion(self, nth: int = 1, fraction: float = 0.5, command: str | None = None) -> None:
        """Drop the commanding connection when the ``nth`` (matching) motion reaches ``fraction``."""
        with self._lock:
            self._faults.append(Fault(command, int(nth), "drop_mid_motion", fraction=fraction))

    def refuse_connections(self, count: int | None = None) -> None:
        """Accept and immediately close the next ``count`` connection attempts (None: all, until
        :meth:`accept_connections`)."""
        with self._lock:
            self._refuse = -1 if count is None else int(count)

    def accept_connections(self) -> None:
        with self._lock:
            self._refuse = 0

    def fail_next(self, command: str, code: int, mode: str = "reject", nth: int = 1, fraction: float = 0.5) -> None:
        """Make the ``nth`` ``command`` from now fail with controller error ``code``.

        ``mode``: ``"reject"`` — the acknowledgement carries ``false`` and the state shows
        ``code``; ``"trajectory"`` (motions) — accepted, then at ``fraction`` the motion aborts
        with ``trajectory_state:false`` and ``code`` (e.g. 0x100D collision); ``"no_reply"`` — the
        command is swallowed.
        """
        if mode not in ("reject", "trajectory", "no_reply"):
            raise ValueError(f"mode {mode!r}")
        with self._lock:
            self._faults.append(Fault(command, int(nth), mode, code=int(code), fraction=fraction))

    def stall_next_motion(self, fraction: float = 0.5, command: str | None = None) -> None:
        """The next (matching) motion freezes at ``fraction`` and never reports arrival."""
        with self._lock:
            self._faults.append(Fault(command, 1, "stall", fraction=fraction))

    def set_error(self, code: int) -> None:
        """Raise a controller error (shown in the state until cleared or the next motion)."""
        with self._lock:
            self._errors.append(int(code))

    def clear_faults(self) -> None:
        with self._lock:
            self._faults.clear()
            self._refuse = 0

    def _take_fault(self, name: str, actions: Sequence[str]) -> Fault | None:
        """Count ``name`` against the pending faults of the given actions; return one that fires."""
        fired = None
        for f in list(self._faults):
            if f.action in actions and f.matches(name):
                f.remaining -= 1
                if f.remaining <= 0:
                    self._faults.remove(f)
                    if fired is None:
                        fired = f
        return fired
