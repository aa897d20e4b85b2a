#!/usr/bin/env python3
"""Benchmark: how fast a stop reaches the RM-65 controller (this is a benchmark, not a test).

The unit tests check that a stop gets through while a motion is awaited and another request
hangs (tests/rm65/test_arm_client.py); how *fast* it gets through is measured here, because a
wall-clock limit inside a unit test fails at random on a shared 2-core machine.

``ArmClient.stop()`` -> the ``set_arm_stop`` command decoded by the controller simulator over
loopback TCP, while another thread waits on a long real-time joint motion: median, p90 and max
over ``--stops`` stops (target: max <= 100 ms).

Usage::

    python bench/bench_arm_latency.py [--stops 50]
"""
from __future__ import annotations

import argparse
import sys
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
for _pkg in ("stud_common", "rm65_driver", "rm65_sim"):  # run from a checkout, no build needed
    _path = str(REPO / "src" / _pkg)
    if _path not in sys.path:
        sys.path.insert(0, _path)

import numpy as np  # noqa: E402

from rm65_driver.protocol.arm_client import ArmClient, ArmStopped  # noqa: E402
from rm65_sim.config import SimulatorConfig
from rm65_sim.simulator import ArmSimulator  # noqa: E402

HOME_DEG = (0.0, -30.0, -100.0, 0.0, -50.0, 0.0)
TARGET_S = 0.100


def _wait(cond, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.0005)
    return True


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stops", type=int, default=50)
    args = parser.parse_args(argv)
    sim = ArmSimulator(host="127.0.0.1", port=0, config=SimulatorConfig(time_scale=1.0, initial_joints_deg=HOME_DEG))
    sim.start()
    client = ArmClient("127.0.0.1", sim.port, connect_timeout_s=1.0, reply_timeout_s=1.0, backoff_s=(0.02, 0.2))
    client.connect()
    latencies = []
    try:
        for k in range(args.stops):
            done = threading.Event()

            def mover():
                try:
                    client.move_joints_and_wait(np.radians([90 if k % 2 == 0 else -90, -30, -100, 0, -50, 0]), 5,
                                                timeout_s=30, stop_count=client.stop_count)
                except ArmStopped:
                    pass
                finally:
                    done.set()

            thread = threading.Thread(target=mover)
            thread.start()
            if not _wait(lambda: sim.moving, 5.0):
                print("the simulator never started moving", file=sys.stderr)
                return 1
            before = len(sim.commands_named("set_arm_stop"))
            t0 = time.monotonic()
            client.stop(wait_reply=False)
            if not _wait(lambda: len(sim.commands_named("set_arm_stop")) > before, 5.0):
                print(f"stop {k}: not decoded at the controller within 5 s", file=sys.stderr)
                return 1
            latencies.append(sim.commands_named("set_arm_stop")[-1].t - t0)
            done.wait(10.0)
            thread.join(10.0)
    finally:
        client.close()
        sim.stop()
    lat = np.array(latencies) * 1e3
    print(f"stop latency, ArmClient.stop() -> decoded at the controller simulator, {len(lat)} stops during a "
          f"real-time motion: median {np.median(lat):.2f} ms, p90 {np.percentile(lat, 90):.2f} ms, "
          f"max {lat.max():.2f} ms (target max <= {TARGET_S * 1e3:.0f} ms: "
          f"{'met' if lat.max() <= TARGET_S * 1e3 else 'MISSED'})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
