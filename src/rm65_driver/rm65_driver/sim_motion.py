"""The simulated controller's motion model: planning a commanded motion and moving along it.

Pure (no sockets, no threads): :func:`plan_motion` turns a ``movej`` / ``movej_p`` / ``movel``
request into a joint path (rad) and a simulated duration (s) -- or the controller's refusal code
(0x1002 joint limits, 0x1003 unreachable) -- and :class:`Motion` is one queued motion, advanced
by :class:`~rm65_driver.simulator.ArmSimulator`'s motion thread along a smooth (cubic) time law.

Timing: a joint move lasts as long as the slowest joint needs at ``v`` % of its maximum speed, a
linear move as long as the path needs at ``v`` % of the line (m/s) and angular (rad/s) speeds.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from . import protocol as P
from .kinematics import RM65Kinematics, invert_transform, pose6_to_matrix, rotation_angle

_log = logging.getLogger("rm65_driver.simulator")  # one logger for all parts of the simulator


@dataclass
class Motion:
    """One accepted motion in the controller's queue: joint waypoints, timing, injected faults."""

    kind: str  # "movej" | "movel" | "movej_p"
    path: np.ndarray  # (N, 6) joint waypoints, rad
    duration_s: float  # simulated seconds (before time_scale)
    conn_id: int
    elapsed_s: float = 0.0  # simulated seconds done
    stall_at: float | None = None  # fraction where it freezes, never arriving
    fail_at: float | None = None  # fraction where it aborts with trajectory_state false
    fail_code: int = 0
    drop_at: float | None = None  # fraction where the commanding connection is dropped
    released_at: float | None = None  # monotonic time the acknowledgement was on the wire

    @property
    def released(self) -> bool:  # ack always precedes motion and arrival
        return self.released_at is not None

    def release(self) -> None:
        self.released_at = time.monotonic()

    def fraction(self) -> float:
        return 1.0 if self.duration_s <= 0 else min(1.0, self.elapsed_s / self.duration_s)

    def joints_at(self, fraction: float) -> np.ndarray:
        s = 3 * fraction**2 - 2 * fraction**3  # smooth start and stop
        n = len(self.path) - 1
        if n == 0:
            return self.path[0].copy()
        x = s * n
        i = min(int(x), n - 1)
        return self.path[i] + (x - i) * (self.path[i + 1] - self.path[i])


def plan_motion(kin: RM65Kinematics, name: str, msg: dict[str, Any], q_start: np.ndarray,
                frames: Callable[[], tuple[np.ndarray, np.ndarray]], max_line_speed_m_s: float,
                max_angular_speed_rad_s: float) -> tuple[np.ndarray | None, float, int]:
    """Joint path (N, 6 rad) and simulated duration (s) of motion command ``name``, or (None, 0, error code).

    ``frames()`` returns the active work frame (in base) and tool frame (in flange), 4x4 m; it is
    called only for the Cartesian commands. Raises ValueError on a malformed request.
    """
    v = int(msg["v"])
    if not 1 <= v <= 100:
        raise ValueError(f"v={v}")
    frac = v / 100.0
    if name == "movej":
        wire = finite_floats(msg["joint"], 6)
        if wire is None:
            return None, 0.0, 0x1002  # no joint is at 1e300 degrees: out of its limits
        q_goal = P.joints_from_wire(wire)
        if not kin.within_limits(q_goal):
            return None, 0.0, 0x1002
        path = np.vstack([q_start, q_goal])
        return path, kin.joint_move_time(q_start, q_goal, frac), 0
    wire = finite_floats(msg["pose"], 6)
    if wire is None or np.any(np.abs(wire[3:]) > 1e6):  # non-finite, or angles beyond +-1000 rad
        return None, 0.0, 0x1003
    T_work, T_tool = frames()
    T_goal = T_work @ pose6_to_matrix(P.pose_from_wire(wire))  # tool in base
    if not within_reach(kin, T_goal, T_tool):
        return None, 0.0, 0x1003
    if name == "movej_p":
        res = kin.ik(T_goal, q_start, tool=T_tool, restarts=6, max_iterations=100)
        if not res.success:
            return None, 0.0, 0x1003
        path = np.vstack([q_start, res.q])
        return path, kin.joint_move_time(q_start, res.q, frac), 0
    # movel
    line, why = kin.linear_path(q_start, T_goal, tool=T_tool)
    if line is None:
        _log.info("simulator: movel refused: %s", why)
        return None, 0.0, 0x1003
    T0 = kin.fk(q_start, T_tool)
    length = float(np.linalg.norm(T_goal[:3, 3] - T0[:3, 3]))
    angle = rotation_angle(T0, T_goal)
    dq = np.abs(np.diff(line, axis=0))
    joint_t = float(np.sum(np.max(dq / kin.max_speed_rad_s, axis=1))) / frac
    t = max(length / (max_line_speed_m_s * frac), angle / (max_angular_speed_rad_s * frac), joint_t)
    return line, t, 0


def within_reach(kin: RM65Kinematics, T_goal: np.ndarray, T_tool: np.ndarray) -> bool:
    """Cheap necessary condition, checked before the IK: the flange inside the working sphere."""
    dh = kin.dh
    reach = dh.a[2] + dh.d[3] + dh.d[5]  # upper arm + forearm + flange: 0.61 m for the RM65-B
    with np.errstate(all="ignore"):
        flange = (T_goal @ invert_transform(T_tool))[:3, 3]
        d = float(np.linalg.norm(flange - np.array([0.0, 0.0, dh.d[0]])))
    return bool(np.isfinite(d) and d <= reach + 1e-3)


def finite_floats(values: Any, n: int) -> np.ndarray | None:
    """``n`` wire numbers as floats, or None if any is not a finite number (NaN, 1e400, a 400-digit int)."""
    if not isinstance(values, (list, tuple)) or len(values) != n:
        raise ValueError(f"expected {n} numbers, got {values!r:.80}")
    try:
        out = np.array([float(v) for v in values], dtype=np.float64)
    except OverflowError:
        return None
    return out if np.all(np.isfinite(out)) and np.all(np.abs(out) < 1e15) else None


def trajectory_msg(success: bool) -> dict[str, Any]:
    """The ``current_trajectory_state`` arrival message: ``success`` false for a motion stopped or aborted."""
    return {"state": P.TRAJECTORY_STATE, "trajectory_state": bool(success), "device": 0, "trajectory_connect": 0}

