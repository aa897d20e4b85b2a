"""Fixtures for the rm65_driver tests: a loopback simulator, a connected client, a dome of targets."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))  # rm65_testing helpers

from rm65_driver.arm_client import ArmClient  # noqa: E402
from rm65_driver.simulator import ArmSimulator  # noqa: E402
from rm65_testing import FAST, HOME_DEG  # noqa: E402


@pytest.fixture
def sim():
    s = ArmSimulator(host="127.0.0.1", port=0, time_scale=FAST, initial_joints_deg=HOME_DEG)
    s.start()
    yield s
    s.stop()


@pytest.fixture
def client(sim):
    c = ArmClient("127.0.0.1", sim.port, connect_timeout_s=1.0, reply_timeout_s=1.0, backoff_s=(0.02, 0.2))
    c.connect()
    yield c
    c.close()
