"""A weld job's control and progress, shared by the thread that runs the job and the threads that
stop, pause or watch it (:class:`~rm65_driver.weld.weld_sequence.WeldSequence`'s ``cancel``,
``halt``, ``pause``, the driver's state publisher).

:class:`JobControl` holds the flags (cancel, halt and its reason, pause), the stop count the job's
motions are checked against, and the progress (stud, phase, done/total, job id) with the phase
callback; the waits between phases (a pause holds, a halt ends the job) are here too.
"""
from __future__ import annotations

import logging
import threading
import time

from rm65_driver.weld.weld_job import PhaseCallback, StudTarget
from stud_common.vocabulary import WeldPhase

_log = logging.getLogger("rm65_driver.weld.weld_sequence")  # the weld job's one logger, whichever part writes


class JobEnded(Exception):
    """The job stops here (cancel, halt, abort); ``message`` goes to the result."""


class JobControl:
    """Control flags and progress of the running (or last) weld job; thread-safe under :attr:`lock`."""

    def __init__(self, on_phase: PhaseCallback | None = None) -> None:
        self.on_phase = on_phase
        self.lock = threading.Lock()
        self.wake = threading.Condition(self.lock)
        self.cancelled = False
        self.halted = False
        self.halt_reason = ""
        self.paused = False
        self.epoch = 0  # client.stop_count when the job started
        self.running = False
        self.current_stud = ""
        self.phase: str = ""  # the running stud's WeldPhase; "" before the first and after the job
        self.done = 0
        self.total = 0
        self.job_id = ""  # of the running (or last) job; in every journal record it writes

    def wait_not_paused(self) -> None:
        with self.wake:
            while self.paused and not (self.halted or self.cancelled):
                self.wake.wait(0.1)

    def sleep(self, seconds: float, interruptible: bool) -> None:
        """Wait ``seconds``; a halt ends it early (a cancel does not: the weld completes)."""
        end = time.monotonic() + seconds
        with self.wake:
            while (left := end - time.monotonic()) > 0:
                if interruptible and self.halted:
                    return
                self.wake.wait(left)

    def check_halt(self) -> None:
        if self.halted:
            raise JobEnded(self.stop_message())

    def between_phases(self) -> None:
        self.wait_not_paused()
        self.check_halt()

    def stop_message(self) -> str:
        return f"halted: {self.halt_reason}" if self.halted else "cancelled"

    def finish_one(self, t: StudTarget, phase: WeldPhase) -> None:
        with self.lock:
            self.done += 1
        self.set_phase(t, phase)

    def set_phase(self, t: StudTarget, phase: WeldPhase) -> None:
        with self.lock:
            self.current_stud, self.phase = t.stud_id, phase
            done, total = self.done, self.total
        _log.info("stud %s: %s (%d/%d)", t.stud_id, phase, done, total)
        if self.on_phase is not None:
            try:
                self.on_phase(t.stud_id, phase, done, total)
            except Exception:
                _log.exception("phase callback failed")
