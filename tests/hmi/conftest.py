"""HMI tests: fixtures; helpers in hmi_testing.py, ws_client.py, fake_cell.py and tests/ros/rosproc.py."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))                   # ws_client, hmi_testing, fake_cell
sys.path.insert(0, str(HERE.parent / "ros"))    # rosproc


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
