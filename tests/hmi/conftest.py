"""HMI tests: a WebSocket test client, the multi-process helpers of tests/ros, a free-port finder."""
from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))                   # ws_client
sys.path.insert(0, str(HERE.parent / "ros"))    # rosproc


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


@pytest.fixture()
def ros_node():
    """An rclpy context and a test node for one test; `spin()` spins it once briefly."""
    import rclpy
    from rclpy.node import Node

    rclpy.init()
    node = Node("hmi_test_probe")
    node.spin = lambda: rclpy.spin_once(node, timeout_sec=0.02)
    try:
        yield node
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


@pytest.fixture()
def procs():
    """Processes started by a test; all stopped (SIGINT, then SIGKILL) at its end."""
    started = []
    yield started
    for p in reversed(started):
        p.stop()
