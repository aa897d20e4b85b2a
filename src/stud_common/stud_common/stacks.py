"""A process that will not stop can say where it is stuck.

``dump_stacks_on_signal()`` makes ``STACK_DUMP_SIGNAL`` (SIGUSR1) print the Python stack of every
thread to stderr, from a C-level handler: it works while the main thread waits inside rclpy or DDS,
where a Python signal handler would never run. The cell's launcher sends it to a child that has not
stopped within its SIGINT grace period, before escalating, so the launch log shows where teardown
waits. By hand: ``kill -USR1 <pid>``.
"""
from __future__ import annotations

import faulthandler
import signal
import sys

STACK_DUMP_SIGNAL = signal.SIGUSR1


def dump_stacks_on_signal() -> None:
    """Arm the stack dump for this process (idempotent). Without a usable stderr, nothing is armed."""
    try:
        faulthandler.register(STACK_DUMP_SIGNAL, file=sys.stderr, all_threads=True)
    except (AttributeError, ValueError, OSError):  # no fileno (stderr replaced or closed)
        pass
