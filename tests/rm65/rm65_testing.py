"""Helpers shared by the rm65_driver and rm65_sim tests (imported as a plain module; tests/ is not a package):
the loopback simulator and client fixtures (each folder's conftest.py imports them), targets, journals."""
from __future__ import annotations

import random
import time
from typing import Callable

import numpy as np
import pytest

from rm65_driver.journal.writer import Journal
from rm65_driver.protocol.arm_client import ArmClient
from rm65_driver.weld.weld_job import StudTarget
from rm65_sim.config import SimulatorConfig
from rm65_sim.simulator import ArmSimulator

#: A "ready" pose in front of the arm, tool pointing down (0.289, 0, 0.183 m flange).
HOME_DEG = (0.0, -30.0, -100.0, 0.0, -50.0, 0.0)
#: Motions run 50x faster than real time in the tests.
FAST = 0.02


@pytest.fixture
def sim():
    s = ArmSimulator(host="127.0.0.1", port=0, config=SimulatorConfig(time_scale=FAST, initial_joints_deg=HOME_DEG))
    s.start()
    yield s
    s.stop()


@pytest.fixture
def client(sim):
    c = ArmClient("127.0.0.1", sim.port, connect_timeout_s=1.0, reply_timeout_s=1.0, backoff_s=(0.02, 0.2))
    c.connect()
    yield c
    c.close()


def dome_targets(center=(0.30, 0.0), radius_m: float = 2.0, z0: float = 0.03, rings=((0.0, 1), (0.05, 7), (0.10, 12))):
    """Studs on a shallow spherical cap (sphere radius ``radius_m``): normals tilt up to ~3 deg."""
    out = []
    k = 0
    for r, m in rings:
        for j in range(m):
            a = 2 * np.pi * j / m
            dx, dy = r * np.cos(a), r * np.sin(a)
            h = np.sqrt(radius_m**2 - dx * dx - dy * dy)
            out.append(StudTarget(f"S{k:04d}", [center[0] + dx, center[1] + dy, z0 + h - radius_m],
                                  np.array([dx, dy, h]) / radius_m))
            k += 1
    return out


def wait_for(predicate: Callable[[], bool], timeout: float = 5.0, period: float = 0.005) -> bool:
    """Poll ``predicate`` until true or ``timeout`` (s); returns its last value."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(period)
    return bool(predicate())


def welds_per_stud(sim: ArmSimulator, targets, io: int = 1, tol_m: float = 0.002) -> dict[str, int]:
    """Count the simulator's trigger rising edges at each stud's position (within ``tol_m``)."""
    counts = {t.stud_id: 0 for t in targets}
    P = np.array([t.position for t in targets])
    for e in sim.rising_edges(io):
        d = np.linalg.norm(P - e.position, axis=1)
        k = int(np.argmin(d))
        assert d[k] < tol_m, f"a trigger fired {d[k] * 1e3:.1f} mm away from the nearest stud"
        counts[targets[k].stud_id] += 1
    return counts


# -- weld journals (test_journal, test_journal_repair) ----------------------------------------------


def write_job(path, n=8, uncertain_last=False):
    """A journal of ``n`` welded studs S1..Sn (and a dangling 'started' Sx with ``uncertain_last``)."""
    with Journal(path) as j:
        for i in range(1, n + 1):
            j.started(f"S{i}", job="job-1", position=[0.1 * i, 0.0, 0.0])
            j.welded(f"S{i}", job="job-1")
        if uncertain_last:
            j.started("Sx", job="job-1")
    return path


def random_bytes(path):
    """Damage: ``path`` replaced by 4096 random bytes; returns what the damage report names."""
    rng = random.Random(14)
    path.write_bytes(bytes(rng.randrange(256) for _ in range(4096)))
    return "line"


def nul_block_over_one_stud(path):
    """Damage: NULs over S3's two records (lines 5 and 6) of a :func:`write_job` journal."""
    lines = path.read_bytes().split(b"\n")
    start = sum(len(x) + 1 for x in lines[:4])  # S3's started and welded: lines 5 and 6
    n = len(lines[4]) + len(lines[5]) + 1
    data = bytearray(path.read_bytes())
    data[start:start + n] = b"\0" * n
    path.write_bytes(bytes(data))
    return "line 5"
