"""Runs stud_bringup.launcher.Launcher on a JSON description, as a process of its own (so a test can
send it signals): ``run_launcher.py SPEC.json``. SPEC: {"out_dir": ..., "options": {...},
"children": [{ChildSpec fields}, ...]}."""
from __future__ import annotations

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "src" / "stud_bringup"))
from stud_bringup.launcher import ChildSpec, Launcher  # noqa: E402

spec = json.loads(Path(sys.argv[1]).read_text())
launcher = Launcher([ChildSpec(**c) for c in spec["children"]], spec["out_dir"], **spec.get("options", {}))
sys.exit(launcher.run())
