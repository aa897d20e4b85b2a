"""Test-wide set-up: import our packages from the source tree, isolate DDS, and the rules for
what may be missing.

Pure-Python core modules are tested straight from ``src/<package>`` so a change is
tested without a rebuild; the generated message package comes from the built
workspace (``source ros2_ws/setup.bash``).

Missing prerequisites (:func:`require`): the shared test corpus (``../shared/data``: real CAD
files and rosbag2 bags) and Chromium for the HMI's browser test. On a developer's machine a test
that needs one skips, saying why; with ``CI=true`` (``.ci/run``) it *fails* with that reason, so a
CI run never turns dozens of tests into silent skips.

Property tests (hypothesis): profile ``dev`` (20 examples, random) by default, ``ci`` with
``CI=true`` -- derandomised (reproducible, no example database) and 100 examples for the tests
that leave ``max_examples`` to the profile (the matcher's and the normals' geometry properties).
``HYPOTHESIS_PROFILE`` picks one explicitly.
"""
from __future__ import annotations

import itertools
import os
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
for pkg in ("stud_common", "stud_bag", "stud_perception", "stud_planner", "stud_inspection", "stud_cell", "stud_hmi",
            "stud_bringup", "rm65_driver", "rm65_sim"):
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
from hypothesis import settings  # noqa: E402

CI = os.environ.get("CI", "").strip().lower() in ("1", "true", "yes")

settings.register_profile("dev", max_examples=20, deadline=None)
settings.register_profile("ci", max_examples=100, derandomize=True, database=None, deadline=None, print_blob=True)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE") or ("ci" if CI else "dev"))


def require(available: bool, what: str) -> None:
    """Skip the test (fail it under ``CI=true``) unless ``available``; ``what`` says what is missing."""
    if available:
        return
    if CI:
        pytest.fail(f"{what} -- CI=true: a missing prerequisite fails the run instead of skipping the test",
                    pytrace=False)
    pytest.skip(what)


@pytest.fixture()
def prerequisite():
    """:func:`require` for a test module (``prerequisite(available, "what is missing")``)."""
    return require


@pytest.fixture()
def require_shared_data():
    """``require_shared_data(path)``: the shared test corpus at ``path`` (under ../shared/data) is there."""
    def check(path: Path) -> Path:
        path = Path(path)
        require(path.exists(), f"shared test corpus {path} is not on this machine (expected next to the repository)")
        return path
    return check


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
