import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))  # child.py / run_launcher.py helpers
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "ros"))  # rosproc: wait_for, REPO

from test_cell_ros import cell_run  # noqa: E402,F401  (the fixture, for every test module here)
