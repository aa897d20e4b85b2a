"""The controller simulator's process ends on SIGTERM and SIGINT, with a client connected mid-motion.

A cell killed with SIGKILL mid-job leaves its children a SIGTERM (PR_SET_PDEATHSIG); once the
simulator outlived it (its launch test waited 60 s). Its signal handler set a threading.Event while
the main thread, in that Event's wait loop, could hold the Event's lock: the handler then waited
for a lock its own thread held, for ever. Now the stop signals are blocked in every thread and taken
synchronously (sigwait): no handler runs at all, which /proc shows."""
from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from rm65_driver.protocol import messages as P
from rm65_driver.protocol.arm_client import ArmClient

REPO = Path(__file__).resolve().parents[2]
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class SimulatorProcess:
    """``python -m rm65_sim.simulator`` on a free loopback port, from the source tree."""

    def __init__(self, tmp_path: Path):
        self.port = _free_port()
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([str(REPO / "src" / "rm65_driver"), str(REPO / "src" / "rm65_sim"),
                                             str(REPO / "src" / "stud_common"),
                                             env.get("PYTHONPATH", "")])
        self.log_path = tmp_path / f"simulator_{self.port}.log"
        self.log = open(self.log_path, "w")
        self.popen = subprocess.Popen([sys.executable, "-u", "-m", "rm65_sim.simulator", "--port", str(self.port),
                                       "--time-scale", "1.0"], stdout=self.log, stderr=subprocess.STDOUT, env=env,
                                      start_new_session=True)
        deadline = time.monotonic() + 30
        while "RM65 simulator on" not in self.log_path.read_text():
            assert self.popen.poll() is None and time.monotonic() < deadline, self.log_path.read_text()
            time.sleep(0.05)

    def threads_status(self) -> list[dict[str, str]]:
        out = []
        for task in Path(f"/proc/{self.popen.pid}/task").iterdir():
            fields = dict(line.split(":\t", 1) for line in (task / "status").read_text().splitlines() if ":\t" in line)
            out.append({k: v.strip() for k, v in fields.items()})
        return out

    def kill(self) -> None:
        if self.popen.poll() is None:
            os.killpg(self.popen.pid, signal.SIGKILL)
            self.popen.wait()
        self.log.close()


@pytest.fixture
def simulator(tmp_path):
    started: list[SimulatorProcess] = []

    def start() -> SimulatorProcess:
        started.append(SimulatorProcess(tmp_path))
        return started[-1]

    yield start
    for s in started:
        s.kill()


def _mid_motion_client(port: int) -> ArmClient:
    """A connected client whose joint move (1 % speed: tens of seconds) is running."""
    client = ArmClient("127.0.0.1", port, connect_timeout_s=2.0, reply_timeout_s=2.0)
    client.connect()
    client.command(P.movej(np.radians([30.0, -20.0, -80.0, 10.0, -40.0, 20.0]), 1))
    deadline = time.monotonic() + 10
    while client.current_trajectory() == "none":
        assert time.monotonic() < deadline, "the move never started"
        time.sleep(0.02)
    return client


@pytest.mark.parametrize("sig", STOP_SIGNALS, ids=lambda s: signal.Signals(s).name)
def test_the_simulator_exits_on_a_stop_signal_with_a_client_mid_motion(simulator, sig):
    for attempt in range(3):  # each time the signal meets its threads at another moment
        sim = simulator()
        client = _mid_motion_client(sim.port)
        try:
            os.kill(sim.popen.pid, sig)
            try:
                code = sim.popen.wait(timeout=15)
            except subprocess.TimeoutExpired:
                os.kill(sim.popen.pid, signal.SIGUSR1)  # its threads' stacks into the log
                time.sleep(0.5)
                raise AssertionError(f"attempt {attempt}: still running 15 s after {signal.Signals(sig).name}\n"
                                     f"{sim.log_path.read_text()[-4000:]}") from None
        finally:
            client.close()
        assert code == 0, sim.log_path.read_text()[-2000:]


def test_no_thread_of_the_simulator_runs_a_handler_for_the_stop_signals(simulator):
    """No thread catches SIGINT or SIGTERM, and the threads the simulator starts (accept, motion, one
    per connection) block them: they wait, pending, for the main thread's sigwait (which, while it
    waits, has the kernel unblock them for it alone), and no lock can keep that from returning."""
    sim = simulator()
    client = _mid_motion_client(sim.port)  # the connection's thread exists too
    try:
        status = sim.threads_status()
        bits = [1 << (sig - 1) for sig in STOP_SIGNALS]
        for s in status:
            caught = int(s["SigCgt"], 16)
            assert not any(caught & b for b in bits), f"thread {s['Pid']}: a handler for SIGINT or SIGTERM"
        blocking = [s for s in status if all(int(s["SigBlk"], 16) & b for b in bits)]
        assert len(blocking) >= 3, [(s["Pid"], s["SigBlk"]) for s in status]
    finally:
        client.close()


def test_the_simulator_cli_leaves_its_callers_signal_state_as_it_found_it():
    """``main`` blocks SIGINT/SIGTERM while it serves; called in-process (a test, an embedding program) and
    returning, it must put the mask and handlers back, or every child started afterwards inherits the
    blocked signals and never stops on Ctrl-C (``ros2 bag record`` later in the same pytest run did not)."""
    from rm65_sim.simulator import ArmSimulator, main

    before_mask = signal.pthread_sigmask(signal.SIG_BLOCK, set())
    before_handlers = {s: signal.getsignal(s) for s in STOP_SIGNALS}
    with ArmSimulator(port=0) as busy:
        assert main(["--port", str(busy.port)]) == 2  # cannot bind: returns at once
    assert signal.pthread_sigmask(signal.SIG_BLOCK, set()) == before_mask
    assert {s: signal.getsignal(s) for s in STOP_SIGNALS} == before_handlers
