"""Fixtures for the rm65_sim tests: a loopback simulator and a connected client (tests/rm65/rm65_testing.py)."""
from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "rm65"))  # rm65_testing helpers, shared with rm65_driver

from rm65_testing import client, sim  # noqa: E402,F401  (fixtures)
