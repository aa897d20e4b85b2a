"""Test-wide set-up: import our packages from the source tree, isolate DDS.

Pure-Python core modules are tested straight from ``src/<package>`` so a change is
tested without a rebuild; the generated message package comes from the built
workspace (``source ros2_ws/setup.bash``).
"""
from __future__ import annotations

import itertools
import os
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
for pkg in ("stud_perception", "stud_planner", "rm65_driver"):
    path = str(REPO / "src" / pkg)
    if path not in sys.path:
        sys.path.insert(0, path)

SHARED_DATA = (REPO.parent / "shared" / "data").resolve()

# Keep DDS traffic on loopback, and give every test a domain of its own (below): a node still
# shutting down from one test must not answer the next, and two runs on one machine (or a
# developer's running cell) must not see each other.
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
_DOMAIN_BASE = int(os.environ.get("ROS_DOMAIN_ID", str(os.getpid())))
_domains = itertools.count()

# Multi-process ROS tests share these (tests/ros/rosproc.py has the process helpers).
sys.path.insert(0, str(REPO / "tests" / "ros"))

import pytest  # noqa: E402


@pytest.fixture(autouse=True)
def _own_dds_domain(monkeypatch):
    """A fresh ROS_DOMAIN_ID (10..99; 0..101 are safe on Linux) for each test and its child processes."""
    monkeypatch.setenv("ROS_DOMAIN_ID", str(10 + (_DOMAIN_BASE + next(_domains)) % 90))


@pytest.fixture()
def ros_node():
    """An rclpy context and a probe node for one test; ``node.spin()`` spins it once briefly."""
    import rclpy
    from rclpy.node import Node

    rclpy.init()
    node = Node("pytest_probe")
    node.spin = lambda: rclpy.spin_once(node, timeout_sec=0.02)
    try:
        yield node
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


@pytest.fixture()
def procs():
    """Processes (rosproc.Proc) started by a test; all stopped (SIGINT to the group, then SIGKILL) at its end."""
    started = []
    yield started
    for p in reversed(started):
        p.stop()
