"""HMI tests: helpers in hmi_testing.py, ws_client.py, fake_cell.py; ros_node/procs from tests/conftest.py."""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))  # ws_client, hmi_testing, fake_cell
