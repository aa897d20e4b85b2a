"""Helpers for multi-process ROS tests: start our executables as real processes, wait on conditions."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable

REPO = Path(__file__).resolve().parents[2]


def wait_for(condition: Callable[[], bool], timeout_s: float, spin: Callable[[], None] | None = None,
              what: str = "condition") -> None:
    """Spin (or sleep briefly) until ``condition()`` holds; AssertionError after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s:.0f} s waiting for {what}")
        if spin is not None:
            spin()
        else:
            time.sleep(0.02)


class Proc:
    """A child process (a node, `ros2 run ...`) whose output is kept for failure messages."""

    def __init__(self, cmd: list[str], log_path: Path, env: dict | None = None):
        self.cmd = cmd
        self.log_path = log_path
        self._log = open(log_path, "w")
        self.popen = subprocess.Popen(cmd, stdout=self._log, stderr=subprocess.STDOUT,
                                      env={**os.environ, **(env or {})}, start_new_session=True)

    def output(self) -> str:
        self._log.flush()
        return self.log_path.read_text(errors="replace")

    def stop(self, timeout_s: float = 10.0) -> int:
        if self.popen.poll() is None:
            # Ctrl-C reaches a terminal's whole foreground group: do the same to our session's
            # group, so `ros2 run`'s child gets SIGINT too (ros2 run itself just waits, as ros2cli does).
            try:
                os.killpg(self.popen.pid, signal.SIGINT)
            except ProcessLookupError:
                pass
            try:
                self.popen.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                os.killpg(self.popen.pid, signal.SIGKILL)
                self.popen.wait()
        self._log.close()
        return self.popen.returncode


def python_proc(script_or_module: str, args: list[str], log_path: Path, module: bool = False, **kw) -> Proc:
    cmd = [sys.executable, "-u"] + (["-m", script_or_module] if module else [script_or_module]) + args
    return Proc(cmd, log_path, **kw)


def ros2_run(package: str, executable: str, log_path: Path, params: dict | None = None,
             extra: list[str] | None = None) -> Proc:
    """`ros2 run package executable --ros-args -p k:=v ...` as a real process."""
    args = list(extra or [])
    if params:
        args += ["--ros-args"] + [a for k, v in params.items() for a in ("-p", f"{k}:={_param_text(v)}")]
    return Proc(["ros2", "run", package, executable, *args], log_path)


def _param_text(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (list, tuple)):
        return "[" + ",".join(_param_text(v) for v in value) + "]"
    if isinstance(value, str):
        return value if value else "''"
    return repr(value)
