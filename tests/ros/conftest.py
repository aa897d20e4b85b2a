import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))  # rosproc helpers


@pytest.fixture()
def ros_node():
    """An rclpy context and a test node for one test; `spin()` spins it once briefly."""
    import rclpy
    from rclpy.node import Node

    rclpy.init()
    node = Node("pytest_probe")
    node.spin = lambda: rclpy.spin_once(node, timeout_sec=0.05)
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
