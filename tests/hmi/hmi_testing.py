"""Helpers of the HMI's process tests: a free port, Ctrl-C to a node started with `ros2 run`."""
from __future__ import annotations

import os
import signal
import socket
import subprocess


def free_port() -> int:
    """A TCP port that was free a moment ago (the kernel's pick for port 0)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def ctrl_c(proc, timeout_s: float = 10.0) -> int:
    """SIGINT to the process group, as a terminal's Ctrl-C (our `ros2` forwards only SIGTERM to
    its child: a Ctrl-C reaches the node directly); the exit code, -9 if it had to be killed."""
    os.killpg(proc.popen.pid, signal.SIGINT)
    try:
        return proc.popen.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        os.killpg(proc.popen.pid, signal.SIGKILL)
        return proc.popen.wait()
