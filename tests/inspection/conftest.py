"""Inspection tests: helpers in welded_views.py (rendered shots before and after the welds)."""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))  # welded_views
