"""ros2_lite.stop_flag.StopFlag: what `ros2 bag play` and `record` stop on can be set from a SIGINT /
SIGTERM handler at any moment of the main thread's wait. A threading.Event could not: its set() takes
the lock its wait() holds between turns, and a handler interrupting that turn never returned."""
from __future__ import annotations

import os
import signal
import threading
import time

from ros2_lite.stop_flag import StopFlag


def test_a_handler_sets_the_flag_while_the_main_thread_waits_and_the_wait_ends():
    flag = StopFlag()
    previous = signal.signal(signal.SIGUSR2, lambda *_: flag.set())
    try:
        for _ in range(50):  # signals at many moments of the waits' turns
            flag = StopFlag()
            timer = threading.Timer(0.001 * (1 + _ % 7), os.kill, (os.getpid(), signal.SIGUSR2))
            timer.start()
            t0 = time.monotonic()
            assert flag.wait(30.0) is True
            assert time.monotonic() - t0 < 25.0  # ended by the signal, not by the 30 s
            timer.join()
    finally:
        signal.signal(signal.SIGUSR2, previous)


def test_wait_times_out_unset_and_returns_at_once_when_set():
    flag = StopFlag()
    assert flag.wait(0.05) is False and not flag.is_set()
    flag.set()
    assert flag.is_set() and flag.wait(10.0) is True
