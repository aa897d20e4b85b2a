"""stud_bringup.launcher with small Python children (tests/launch/child.py), no ROS.

The launcher runs as a process of its own (run_launcher.py), so the tests send it real signals;
every child records its pid(s) and the signals it received in a state folder.
"""
from __future__ import annotations

import io
import json
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from launch_helpers import alive
from rosproc import wait_for
from stud_bringup.launcher import ChildSpec, Launcher, LaunchError, describe_returncode, group_members

HERE = Path(__file__).resolve().parent
CHILD = HERE / "child.py"
RUNNER = HERE / "run_launcher.py"


def child(name: str, state: Path, *flags: str, **spec) -> dict:
    return {"name": name, "argv": [sys.executable, str(CHILD), "--name", name, "--state-dir", str(state), *flags],
            **spec}


class LaunchRun:
    """The launcher as a real process; ``cleanup`` kills whatever a failed test left behind."""

    def __init__(self, tmp_path: Path, children: list[dict], **options):
        self.state = tmp_path / "state"
        self.out = tmp_path / "out"
        spec = tmp_path / "spec.json"
        spec.write_text(json.dumps({"out_dir": str(self.out), "children": children,
                                    "options": {"sigint_timeout_s": 5.0, "sigterm_timeout_s": 2.0, **options}}))
        self.stdout_path = tmp_path / "launcher.out"
        self._stdout = open(self.stdout_path, "w")
        self.popen = subprocess.Popen([sys.executable, "-u", str(RUNNER), str(spec)], stdout=self._stdout,
                                      stderr=subprocess.STDOUT, start_new_session=True)

    def output(self) -> str:
        return self.stdout_path.read_text()

    def pids(self, name: str) -> list[int]:
        path = self.state / f"{name}.pids"
        return [int(x) for x in path.read_text().split()] if path.exists() else []

    def signals(self, name: str) -> list[str]:
        path = self.state / f"{name}.signals"
        return [line.split()[1] for line in path.read_text().splitlines()] if path.exists() else []

    def grandchild(self, name: str) -> int:
        return int((self.state / f"{name}.grandchild").read_text())

    def wait_ready(self, *names: str, timeout_s: float = 15.0) -> None:
        wait_for(lambda: all(f"[{n}] {n} ready" in self.output() for n in names), timeout_s,
                 what=f"{names} ready\n{self.output()}")

    def wait(self, timeout_s: float = 20.0) -> int:
        try:
            return self.popen.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            raise AssertionError(f"launcher still running after {timeout_s} s\n{self.output()}") from None

    def all_pids(self) -> list[int]:
        pids = [int(x) for f in self.state.glob("*.pids") for x in f.read_text().split()]
        return pids + [int(f.read_text()) for f in self.state.glob("*.grandchild")]

    def cleanup(self) -> None:
        for pid in [self.popen.pid, *self.all_pids()]:
            if alive(pid):
                try:
                    os.kill(pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
        if self.popen.poll() is None:
            self.popen.wait()
        self._stdout.close()


@pytest.fixture()
def launch(tmp_path):
    runs = []

    def start(children, **options) -> LaunchRun:
        (tmp_path / "state").mkdir(exist_ok=True)
        run = LaunchRun(tmp_path, children, **options)
        runs.append(run)
        return run

    start.state = tmp_path / "state"
    yield start
    for run in runs:
        run.cleanup()


def test_ctrl_c_sends_sigint_to_every_child_and_leaves_no_process(launch):
    s = launch.state
    run = launch([child("camera", s), child("matcher", s, "--grandchild"), child("drawing", s, "--lines", "3")])
    run.wait_ready("camera", "matcher", "drawing")
    pids = {n: run.pids(n)[0] for n in ("camera", "matcher", "drawing")}
    grandchild = run.grandchild("matcher")
    assert all(alive(p) for p in [*pids.values(), grandchild])

    run.popen.send_signal(signal.SIGINT)
    assert run.wait() == 0, run.output()
    for name, pid in pids.items():
        assert run.signals(name) == ["SIGINT"], name
        assert not alive(pid), name
    assert not alive(grandchild)  # in matcher's process group: it got the SIGINT too
    out = run.output()
    assert "[drawing] drawing line 3 of 3" in out
    assert "SIGINT received" in out and "exit code 0" in out
    assert (run.out / "drawing.log").read_text().count("drawing line") == 3  # the per-child log file
    assert "stopping: SIGINT received" in (run.out / "launch.log").read_text()


def test_child_ignoring_sigint_and_sigterm_is_killed_after_the_grace_periods(launch):
    s = launch.state
    run = launch([child("stubborn", s, "--ignore-sigint", "--ignore-sigterm"), child("polite", s)],
                 sigint_timeout_s=1.0, sigterm_timeout_s=1.0)
    run.wait_ready("stubborn", "polite")
    stubborn, polite = run.pids("stubborn")[0], run.pids("polite")[0]
    run.popen.send_signal(signal.SIGINT)
    rc = run.wait()
    assert rc == 1, run.output()  # a child that had to be killed is not a clean stop
    assert run.signals("stubborn") == ["SIGINT", "SIGTERM"]
    assert run.signals("polite") == ["SIGINT"]
    assert not alive(stubborn) and not alive(polite)
    out = run.output()
    assert "stubborn still running: SIGTERM" in out and "stubborn still running: SIGKILL" in out
    assert "stopped by SIGKILL: signal SIGKILL" in out


def test_child_ignoring_only_sigint_is_stopped_by_sigterm(launch):
    s = launch.state
    run = launch([child("deaf", s, "--ignore-sigint")], sigint_timeout_s=0.5)
    run.wait_ready("deaf")
    pid = run.pids("deaf")[0]
    run.popen.send_signal(signal.SIGINT)
    assert run.wait() == 1
    assert run.signals("deaf") == ["SIGINT", "SIGTERM"] and not alive(pid)
    assert "did not stop on SIGINT within 0.5 s" in run.output()


def test_a_child_stuck_after_sigint_is_asked_for_its_stacks_before_sigterm(launch):
    """Where a node waits when it does not stop is in the launch log (stud_common.stacks), and the
    dump does not stop it: SIGTERM still follows."""
    s = launch.state
    run = launch([child("stuck", s, "--ignore-sigint", "--dump-stacks", stack_dump_signal=int(signal.SIGUSR1)),
                  child("plain", s, "--ignore-sigint")], sigint_timeout_s=0.5)
    run.wait_ready("stuck", "plain")
    run.popen.send_signal(signal.SIGINT)
    assert run.wait() == 1
    assert run.signals("stuck") == ["SIGINT", "SIGTERM"]  # alive after the dump, stopped by SIGTERM
    log = (run.out / "launch.log").read_text()
    assert "stuck did not stop on SIGINT within 0.5 s; its threads:" in log
    assert "stuck | " in log and "child.py" in log and "in main" in log  # the main thread's frames
    assert "plain did not stop on SIGINT within 0.5 s\n" in log  # no stack signal: not asked
    assert "plain | " not in log


def test_required_child_dying_stops_everything_with_its_exit_code_and_last_lines(launch):
    s = launch.state
    run = launch([child("registration", s, "--lines", "30", "--exit-after", "0.3", "--code", "3", required=True),
                  child("matcher", s, "--grandchild")], report_lines=5)
    rc = run.wait()
    assert rc == 1, run.output()
    matcher = run.pids("matcher")[0]
    assert run.signals("matcher") == ["SIGINT"] and not alive(matcher) and not alive(run.grandchild("matcher"))
    out = run.output()
    report = out[out.index("registration died (exit code 3"):]
    assert "last 5 lines:" in report
    assert "  | registration line 30 of 30" in report and "  | registration exiting with 3" in report
    assert "  | registration line 25 of 30" not in report  # only the last 5
    assert "stopping: required registration ended (exit code 3)" in out


def test_child_killed_by_a_signal_is_reported_by_signal_name(launch):
    s = launch.state
    run = launch([child("camera", s, required=True)])
    run.wait_ready("camera")
    os.kill(run.pids("camera")[0], signal.SIGKILL)
    assert run.wait() == 1
    assert "camera died (signal SIGKILL" in run.output()


def test_respawn_stops_after_max_respawns(launch):
    s = launch.state
    run = launch([child("driver", s, "--exit-after", "0.1", "--code", "1", respawn=True, max_respawns=2,
                        respawn_delay_s=0.1, required=True),
                  child("hmi", s)])
    rc = run.wait()
    assert rc == 1, run.output()
    assert len(run.pids("driver")) == 3  # the first start and two respawns
    out = run.output()
    assert "respawning driver in 0.1 s (1/2)" in out and "respawning driver in 0.1 s (2/2)" in out
    assert "driver: gave up after 2 respawns" in out
    assert not alive(run.pids("hmi")[0]) and run.signals("hmi") == ["SIGINT"]


def test_respawned_child_that_is_running_again_stops_cleanly(launch):
    s = launch.state
    run = launch([child("driver", s, respawn=True, max_respawns=1, respawn_delay_s=0.1)])
    run.wait_ready("driver")
    os.kill(run.pids("driver")[0], signal.SIGKILL)
    wait_for(lambda: len(run.pids("driver")) == 2 and run.output().count("[driver] driver ready") == 2, 10,
             what=f"respawn\n{run.output()}")
    run.popen.send_signal(signal.SIGINT)
    assert run.wait() == 0, run.output()  # the live instance stopped well: a clean Ctrl-C
    assert not any(alive(p) for p in run.pids("driver"))
    assert "respawned 1x" in run.output()


def test_sigterm_to_the_launcher_leaves_no_orphans(launch):
    s = launch.state
    run = launch([child("a", s, "--grandchild"), child("b", s, "--grandchild"), child("c", s)])
    run.wait_ready("a", "b", "c")
    everything = run.all_pids()
    assert len(everything) == 5
    run.popen.send_signal(signal.SIGTERM)
    assert run.wait() == 0, run.output()
    assert not [p for p in everything if alive(p)]
    assert run.signals("a") == ["SIGINT"]  # children are stopped with SIGINT first, as on Ctrl-C


@pytest.mark.skipif(not Path("/usr/bin/setpriv").exists() and not Path("/bin/setpriv").exists(),
                    reason="needs setpriv (util-linux) for PR_SET_PDEATHSIG")
def test_children_of_a_launcher_killed_with_sigkill_get_sigterm(launch):
    s = launch.state
    run = launch([child("a", s), child("b", s)])
    run.wait_ready("a", "b")
    pids = run.pids("a") + run.pids("b")
    run.popen.send_signal(signal.SIGKILL)  # no handler runs: the kernel's parent-death signal does it
    run.wait()
    wait_for(lambda: not any(alive(p) for p in pids), 10, what="children to end")
    assert run.signals("a") == ["SIGTERM"] and run.signals("b") == ["SIGTERM"]


def test_exit_on_child_finishing_ends_the_launch_with_0(launch):
    s = launch.state
    run = launch([child("sequencer", s, "--exit-after", "0.3", exit_on=True), child("matcher", s)])
    assert run.wait() == 0, run.output()
    assert run.signals("matcher") == ["SIGINT"] and not alive(run.pids("matcher")[0])
    assert "sequencer exited (exit code 0" in run.output() and "its job is done" in run.output()


def test_exit_on_child_failing_ends_the_launch_with_1(launch):
    s = launch.state
    run = launch([child("sequencer", s, "--exit-after", "0.3", "--code", "4", exit_on=True), child("matcher", s)])
    assert run.wait() == 1
    assert "sequencer died (exit code 4" in run.output()


def test_missing_executable_of_a_required_child_stops_the_launch(launch):
    s = launch.state
    run = launch([{"name": "ghost", "argv": ["/nonexistent/ghost_node"], "required": True}, child("matcher", s)])
    assert run.wait() == 1
    out = run.output()
    assert "ghost" in out and ("cannot start" in out or "No such file" in out)
    assert not any(alive(p) for p in run.pids("matcher"))


def test_wait_for_line_and_start_after_in_process(tmp_path):
    state = tmp_path / "state"
    state.mkdir()
    echo = io.StringIO()
    specs = [ChildSpec(**child("simulator", state, "--ready-delay", "0.5", ready_pattern=r"simulator ready")),
             ChildSpec(**child("driver", state, start_after="simulator"))]
    launcher = Launcher(specs, tmp_path / "out", echo=echo, sigint_timeout_s=5.0)
    codes = []
    thread = threading.Thread(target=lambda: codes.append(launcher.run()))
    thread.start()
    try:
        m = launcher.wait_for_line("driver", r"(\w+) ready", timeout_s=15)
        assert m is not None and m.group(1) == "driver", echo.getvalue()
        assert launcher.wait_for_line("simulator", "never printed", timeout_s=0.2) is None
        assert set(launcher.pids()) == {"simulator", "driver"}
        assert launcher.last_lines("simulator")[-1] == "simulator ready"
    finally:
        launcher.request_stop("test done")
        thread.join(20)
    assert codes == [0], echo.getvalue()
    out = echo.getvalue()
    assert out.index("[simulator] simulator ready") < out.index("started driver")
    assert launcher.outcomes["driver"].ok and launcher.outcomes["driver"].stopped_by == "SIGINT"


def test_bad_specs_are_refused():
    with pytest.raises(LaunchError, match="use letters"):
        ChildSpec(name="a b", argv=["true"])
    with pytest.raises(LaunchError, match="non-empty"):
        ChildSpec(name="a", argv=[])
    with pytest.raises(LaunchError, match="duplicate"):
        Launcher([ChildSpec("a", ["true"]), ChildSpec("a", ["true"])], "/tmp", echo=None)
    with pytest.raises(LaunchError, match="not in this launch"):
        Launcher([ChildSpec("a", ["true"], start_after="b")], "/tmp", echo=None)


def test_describe_returncode_and_group_members():
    assert describe_returncode(3) == "exit code 3"
    assert describe_returncode(-9) == "signal SIGKILL"
    assert describe_returncode(None) == "not started"
    assert os.getpid() in group_members(os.getpgid(0))
