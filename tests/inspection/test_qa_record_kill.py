"""A process killed while it writes the QA record leaves the previous record whole and readable: each
file is written to a temporary file, forced to disk and renamed into place (then the folder forced).

A child process re-writes a 400-stud record over and over, one more signed decision each time, as the
inspector does on each decision; it is killed (SIGKILL: no clean-up runs) at random moments, many of
them in the middle of a write -- its temporary files left behind show it. After every kill the record
reads as a whole record, the one before or after the write cut short. And, deterministically, a writer
killed at each step of a write: half-way through a file, a file written but not yet renamed."""
from __future__ import annotations

import csv
import json
import os
import random
import signal
import subprocess
import sys
import textwrap
import time

from rosproc import REPO
from stud_inspection import qa_codes
from stud_inspection.qa_report import JSON_NAME, empty_row, read_record, write_qa_report

WRITER = textwrap.dedent("""
    import os, signal, sys
    from pathlib import Path
    import stud_common.strict_json as sj
    from stud_inspection.qa_report import apply_operator_entries, locked, read_record
    out = Path(sys.argv[1])
    kill_at = sys.argv[2] if len(sys.argv) > 2 else ""  # "<file name>:half" or "<file name>:rename": die there
    if kill_at:
        target, when = kill_at.split(":")
        real_open, real_replace = open, os.replace

        class HalfWriter:
            def __init__(self, f):
                self.f = f
            def __enter__(self):
                return self
            def __exit__(self, *a):
                return self.f.__exit__(*a)
            def write(self, text):
                self.f.write(text[:len(text) // 2])
                self.f.flush()
                os.kill(os.getpid(), signal.SIGKILL)
            def __getattr__(self, name):
                return getattr(self.f, name)

        def kill_open(path, *a, **kw):
            f = real_open(path, *a, **kw)
            return HalfWriter(f) if when == "half" and Path(path).name.startswith("." + target) else f

        def kill_replace(src, dst):
            if when == "rename" and Path(dst).name == target:
                os.kill(os.getpid(), signal.SIGKILL)
            return real_replace(src, dst)

        sj.open = kill_open
        sj.os = type("os_kill", (), {"replace": staticmethod(kill_replace), "fsync": os.fsync, "open": os.open,
                                      "close": os.close, "O_RDONLY": os.O_RDONLY, "getpid": os.getpid,
                                      "PathLike": os.PathLike})
    rows = read_record(out)["studs"]
    k = sum(r["rework"] is not None for r in rows)
    while True:
        k += 1
        decisions = {r["stud_id"]: {"decision": "accept", "note": f"entry {k}", "operator": "A. Inspector",
                                    "time": "2025-05-01T10:00:00+00:00"} for r in rows[:k]}
        with locked(out):
            apply_operator_entries(out, decisions)
        print(k, flush=True)
""")


def _record(out):
    rows = []
    for k in range(400):
        r = empty_row(f"S{k + 1:04d}", (k % 20 * 50.0, k // 20 * 50.0))
        r.update(verdict="fail" if k % 7 == 0 else "pass", weld_seq=k + 1, station=1 + k // 50,
                 reasons=["lean 8.0 deg > 5 deg"] if k % 7 == 0 else [])
        rows.append(r)
    write_qa_report(out, {"id": "J400"}, {"max_lean_deg": 5.0}, rows, [], [],
                    code=qa_codes.profile("gb50205").describe(), seed=11)


def _whole(out) -> int:
    """The record in ``out`` read as a whole (JSON, CSV, HTML); the number of decisions in its JSON."""
    doc = read_record(out)
    assert doc is not None and len(doc["studs"]) == 400 and doc["sampling"]["seed"] == 11
    with open(out / "qa_report.csv", newline="", encoding="utf-8") as f:
        assert len(list(csv.reader(f))) == 401
    assert (out / "qa_report.html").read_text(encoding="utf-8").rstrip().endswith("</html>")
    return sum(r["rework"] is not None for r in doc["studs"])


def _env():
    return {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(REPO / "src" / p) for p in ("stud_common", "stud_perception", "stud_inspection")]
        + [os.environ.get("PYTHONPATH", "")])}


def test_a_writer_killed_at_each_step_of_a_write_leaves_the_previous_record_whole(tmp_path):
    """Killed half-way through writing a file, or with a file written but not yet in place: the record
    is the one before, whole; the next write goes through."""
    out = tmp_path / "job"
    _record(out)
    decided = _whole(out)
    for kill_at in ("qa_report.csv:half", "qa_report.html:half", "qa_report.json:half", "qa_report.json:rename",
                    "qa_report.html:rename"):
        child = subprocess.run([sys.executable, "-c", WRITER, str(out), kill_at], capture_output=True, text=True,
                               env=_env(), timeout=120)
        assert child.returncode == -signal.SIGKILL, (kill_at, child.stderr[-2000:])
        assert child.stdout == ""  # it died in its first write
        assert list(out.glob(".qa_report.*.tmp*")), kill_at  # the write cut short, left behind
        assert _whole(out) == decided, kill_at  # the record: the previous one, whole
    child = subprocess.Popen([sys.executable, "-c", WRITER, str(out)], stdout=subprocess.PIPE, text=True, env=_env())
    assert int(child.stdout.readline()) == decided + 1
    child.kill()
    child.wait()


def test_a_writer_killed_at_random_moments_always_leaves_a_whole_record(tmp_path):
    out = tmp_path / "job"
    _record(out)
    env = _env()
    rng = random.Random(37)
    mid_write = 0
    decided = 0
    for attempt in range(60):  # 12 kills, more until one has landed mid-write (a loaded machine's timing varies)
        if attempt >= 12 and mid_write:
            break
        child = subprocess.Popen([sys.executable, "-c", WRITER, str(out)], stdout=subprocess.PIPE, text=True, env=env)
        first = child.stdout.readline()  # one write done: the next ones are under way
        assert first.strip(), "the writer did not start"
        time.sleep(rng.uniform(0.0, 0.25))
        child.send_signal(signal.SIGKILL)
        done = [int(first)] + [int(line) for line in child.stdout.read().split()]
        child.wait()
        assert child.returncode == -signal.SIGKILL
        left = sorted(p.name for p in out.glob(".qa_report.*.tmp*"))
        mid_write += bool(left)
        n = _whole(out)  # whole, readable: the JSON is the last write done, or the one cut short if it got renamed
        assert n in (done[-1], done[-1] + 1), (n, done[-1], left)
        assert n >= decided  # never older than a write confirmed before
        decided = n
    assert mid_write >= 1, "no kill of 60 landed mid-write"
    # the next writer clears what the killed ones left behind
    write_qa_report(out, {"id": "J400"}, {}, read_record(out)["studs"], [], [])
    assert not list(out.glob(".qa_report.*.tmp*"))
    assert json.loads((out / JSON_NAME).read_text())["job"]["id"] == "J400"
