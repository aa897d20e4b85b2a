"""A stop request a signal handler may set: a flag, no lock.

``threading.Event.set`` takes the lock its ``wait`` holds for a few bytecodes of every turn. A signal
handler runs in the main thread between two bytecodes, so one that calls ``set`` while the main thread
is inside ``wait`` waits for a lock its own thread holds: for ever (a process that outlived its
SIGTERM; the cell's arm simulator did, and ``ros2 bag play`` could). :class:`StopFlag` is set by a
plain assignment and waited for in short sleeps, which a signal ends early.
"""
from __future__ import annotations

import time

#: Longest sleep of :meth:`StopFlag.wait` between two looks at the flag (s).
POLL_S = 0.02


class StopFlag:
    """``set`` / ``is_set`` / ``wait(timeout)`` as ``threading.Event``, safe to set from a signal handler."""

    def __init__(self) -> None:
        self._set = False

    def set(self) -> None:
        self._set = True

    def is_set(self) -> bool:
        return self._set

    def wait(self, timeout_s: float) -> bool:
        """True once set; False after ``timeout_s`` (at most :data:`POLL_S` late)."""
        end = time.monotonic() + timeout_s
        while not self._set:
            left = end - time.monotonic()
            if left <= 0:
                return False
            time.sleep(min(left, POLL_S))
        return True
