"""Set-up for the tool tests: import ros2_lite from the source tree and the multi-process helpers."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parents[1]
for path in (TESTS / "ros", TESTS.parent / "tools" / "ros2_lite"):  # rosproc helpers, ros2_lite
    if str(path) not in sys.path:
        sys.path.insert(0, str(path))

SHARED_BAGS = (TESTS.parents[1] / "shared" / "data" / "bags").resolve()


@pytest.fixture()
def shared_bag(prerequisite):
    """Path of a bag recorded by the real rosbag2 (shared test corpus); skips when it is absent
    (fails under CI=true: tests/conftest.py)."""
    def get(name: str) -> Path:
        path = SHARED_BAGS / name
        prerequisite((path / "metadata.yaml").is_file(), f"shared rosbag2 test bag {path} is not on this machine")
        return path
    return get
