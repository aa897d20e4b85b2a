"""Fixtures for the rm65_driver tests: a loopback simulator and a connected client (from rm65_testing)."""
from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))  # rm65_testing helpers

from rm65_testing import client, sim  # noqa: E402,F401  (fixtures)
