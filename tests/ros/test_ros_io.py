"""ros_io's process set-up for nodes: the allocator keeps freed image-sized blocks (no page faults
on every frame's fresh arrays)."""
from __future__ import annotations

import subprocess
import sys

from rosproc import REPO

_PROBE = """
import sys
sys.path.insert(0, {src!r})
import numpy as np
from stud_perception import ros_io
ok = ros_io.keep_freed_memory() if {tune} else None

def rss_mb():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * 4096 / 2**20

before = rss_mb()
block = np.ones(20 * 2**20, dtype=np.uint8)  # a 20 MB frame-sized array, every page touched
del block
print(ok, rss_mb() - before)
"""


def _run(tune: bool) -> tuple[str, float]:
    code = _PROBE.format(src=str(REPO / "src" / "stud_perception"), tune=tune)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    ok, kept_mb = out.stdout.split()
    return ok, float(kept_mb)


def test_keep_freed_memory_keeps_a_freed_frame_in_the_process():
    ok, kept_mb = _run(tune=True)
    assert ok == "True"
    assert kept_mb >= 18  # freed, but kept for the next frame: no fresh pages to fault in
    _, default_kept_mb = _run(tune=False)
    assert default_kept_mb < 5  # glibc's default: unmapped on free, faulted in again next time
