"""The simulated controller's motion model: planning a commanded motion and moving along it.

Pure (no sockets, no threads): :func:`plan_motion` turns a ``movej`` / ``movej_p`` / ``movel``
request into a joint path (rad) and a simulated duration (s) -- or the controller's refusal code
(0x1002 joint limits, 0x1003 unreachable) -- and :class:`Motion` is one queued motion, advanced
by :class:`~rm65_sim.simulator.ArmSimulator`'s motion thread along a trapezoidal time law.

Timing: ``v`` % scales the speeds *and* the accelerations (RealMan's motion documentation). A
joint move lasts as long as the slowest joint needs at ``v`` % of its maximum speed and
acceleration, a linear move as long as the path needs at ``v`` % of the line (m/s, m/s^2) and
angular (rad/s, rad/s^2) limits and of the joints' own; every move starts and ends at rest
(:func:`~rm65_driver.kinematics.rm65.trapezoid_profile`), so a stop between two moves costs what it
costs a real arm.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from functools import cached_property
from typing import Any, Callable

import numpy as np

from rm65_driver.kinematics.rm65 import (
    RM65Kinematics,
    invert_transform,
    pose6_to_matrix,
    rotation_angle,
    trapezoid_profile,
)
from rm65_driver.protocol import messages as P

_log = logging.getLogger("rm65_sim.simulator")  # one logger for all parts of the simulator


@dataclass
class Motion:
    """One accepted motion in the controller's queue: joint waypoints, time law, injected faults."""

    kind: str  # "movej" | "movel" | "movej_p"
    path: np.ndarray  # (N, 6) joint waypoints, rad
    profile: SegmentProfile  # time law along the path: rest to rest (SegmentProfile.rest_to_rest) unless joined
    conn_id: int
    connect_next: bool = False  # sent with trajectory_connect=1: runs only once the next motion is queued
    line: LineSegment | None = None  # a movel's straight line (for joining it to the next one)
    elapsed_s: float = 0.0  # simulated seconds done
    stall_at: float | None = None  # fraction where it freezes, never arriving
    fail_at: float | None = None  # fraction where it aborts with trajectory_state false
    fail_code: int = 0
    drop_at: float | None = None  # fraction where the commanding connection is dropped
    released_at: float | None = None  # monotonic time the acknowledgement was on the wire

    @property
    def duration_s(self) -> float:  # simulated seconds (before time_scale)
        return self.profile.duration_s

    @property
    def released(self) -> bool:  # ack always precedes motion and arrival
        return self.released_at is not None

    def release(self) -> None:
        self.released_at = time.monotonic()

    def fraction(self) -> float:
        return 1.0 if self.duration_s <= 0 else min(1.0, self.elapsed_s / self.duration_s)

    def joints_at(self, fraction: float) -> np.ndarray:
        """The joints at ``fraction`` (0..1) of the move's *time*, along its time law."""
        s = self.profile.fraction_at(fraction * self.duration_s)
        n = len(self.path) - 1
        if n == 0:
            return self.path[0].copy()
        x = s * n
        i = min(int(x), n - 1)
        return self.path[i] + (x - i) * (self.path[i + 1] - self.path[i])


@dataclass(frozen=True)
class LineSegment:
    """A ``movel``'s straight line, as its time law sees it: ends (m, base), its own top speed and acceleration.

    ``speed`` / ``accel`` are what the binding limit (line, angle or joints) allows along the line:
    the standalone trapezoid's ``L / (T - t_a)`` and ``L / (t_a (T - t_a))``. For a line too short
    to cruise that speed is its peak from rest, below its cap: a junction taken at it is slower
    than a real controller might take it, never faster.
    """

    start: np.ndarray
    end: np.ndarray
    turns: bool  # the orientation changes along the line (by more than COLLINEAR_DEG)
    speed: float
    accel: float

    @property
    def length(self) -> float:
        return float(np.linalg.norm(self.end - self.start))

    @classmethod
    def timed(cls, start: np.ndarray, end: np.ndarray, turns: bool, duration_s: float, accel_s: float) -> LineSegment:
        """The line from ``start`` to ``end`` (m) whose rest-to-rest move lasts ``duration_s`` and
        accelerates for ``accel_s``: its speed and acceleration are what that trapezoid implies."""
        L = float(np.linalg.norm(np.asarray(end) - np.asarray(start)))
        cruise = max(duration_s - accel_s, 1e-9)
        return cls(start=start, end=end, turns=turns, speed=L / cruise, accel=L / max(accel_s * cruise, 1e-12))


#: Two lines join without a stop only if they continue each other within this angle.
COLLINEAR_DEG = 1.0


def junction_speed(a: LineSegment, b: LineSegment) -> float:
    """Speed (m/s) at which connected line ``a`` may hand over to ``b``: 0 unless ``b`` continues ``a``.

    A corner needs a blend radius (``r``) to be passed at speed; without one, and whenever the
    tool turns, the arm stops there as it does between unconnected moves. Along one line the arm
    needs only to slow to the lower of the two speeds (and to what each segment's length allows:
    ``a`` must reach it from rest, ``b`` must stop from it).
    """
    if a.turns or b.turns or a.length <= 1e-9 or b.length <= 1e-9:
        return 0.0
    da, db = (a.end - a.start) / a.length, (b.end - b.start) / b.length
    if float(da @ db) < np.cos(np.radians(COLLINEAR_DEG)) or float(np.linalg.norm(b.start - a.end)) > 1e-6:
        return 0.0
    return float(min(a.speed, b.speed, np.sqrt(2 * a.accel * a.length), np.sqrt(2 * b.accel * b.length)))


@dataclass(frozen=True)
class SegmentProfile:
    """Time law of a line of ``length`` m from speed ``u`` to ``w`` (m/s), at most ``speed``, accelerating at ``accel``.

    Speeds up to the peak, cruises, slows down to ``w``; ``u`` and ``w`` must be reachable from
    each other within the length (:func:`junction_speed` sees to it).
    """

    length: float
    u: float
    w: float
    speed: float
    accel: float

    @classmethod
    def rest_to_rest(cls, duration_s: float, accel_s: float) -> SegmentProfile:
        """The plain trapezoid of a move lasting ``duration_s`` that accelerates for ``accel_s``, along a unit path.

        ``accel_s`` outside (0, duration_s / 2] means a triangle; 0 would be a jump in speed.
        """
        T = max(float(duration_s), 1e-9)
        ta = accel_s if 0.0 < accel_s <= T / 2 else T / 2
        speed = 1.0 / (T - ta)
        return cls(1.0, 0.0, 0.0, speed, speed / ta)

    @property
    def peak(self) -> float:
        return self._phases[0]

    @cached_property
    def _phases(self) -> tuple[float, float, float, float]:  # asked at every tick of the motion thread
        a = self.accel
        vp = float(min(self.speed, np.sqrt(max(a * self.length + 0.5 * (self.u ** 2 + self.w ** 2), 0.0))))
        t1, t3 = max(vp - self.u, 0.0) / a, max(vp - self.w, 0.0) / a
        d1, d3 = (vp * vp - self.u ** 2) / (2 * a), (vp * vp - self.w ** 2) / (2 * a)
        t2 = max(self.length - d1 - d3, 0.0) / vp if vp > 0 else 0.0
        return vp, t1, t2, t3

    @property
    def duration_s(self) -> float:
        _, t1, t2, t3 = self._phases
        return t1 + t2 + t3

    def fraction_at(self, t: float) -> float:
        """Path fraction (0..1) covered after ``t`` s."""
        if self.length <= 0:
            return 1.0
        vp, t1, t2, t3 = self._phases
        a, u = self.accel, self.u
        t = min(max(t, 0.0), t1 + t2 + t3)
        if t <= t1:
            d = u * t + 0.5 * a * t * t
        elif t <= t1 + t2:
            d = (vp * vp - u * u) / (2 * a) + vp * (t - t1)
        else:
            r = t - t1 - t2
            d = (vp * vp - u * u) / (2 * a) + vp * t2 + vp * r - 0.5 * a * r * r
        return float(min(max(d / self.length, 0.0), 1.0))


@dataclass(frozen=True)
class MotionLimits:
    """The controller's Cartesian limits at 100 % (``v`` scales all of them); joints: the kinematics'."""

    line_speed_m_s: float = 0.5  # DOCS armConfig example (get_arm_max_line_speed)
    line_acc_m_s2: float = 1.6  # the SDK documentation's example; >= 3x the speed, as DOCS require
    angular_speed_rad_s: float = 3.0
    angular_acc_rad_s2: float = 10.0  # same >= 3x ratio


def plan_motion(kin: RM65Kinematics, name: str, msg: dict[str, Any], q_start: np.ndarray,
                frames: Callable[[], tuple[np.ndarray, np.ndarray]],
                limits: MotionLimits) -> tuple[np.ndarray | None, float, float, int]:
    """Joint path (N, 6 rad), duration and acceleration time (s) of motion command ``name``.

    Or (None, 0, 0, error code) for a refusal. ``frames()`` returns the active work frame (in
    base) and tool frame (in flange), 4x4 m; it is called only for the Cartesian commands. Raises
    ValueError on a malformed request.
    """
    v = int(msg["v"])
    if not 1 <= v <= 100:
        raise ValueError(f"v={v}")
    frac = v / 100.0
    if name == "movej":
        wire = finite_floats(msg["joint"], 6)
        if wire is None:
            return None, 0.0, 0.0, 0x1002  # no joint is at 1e300 degrees: out of its limits
        q_goal = P.joints_from_wire(wire)
        if not kin.within_limits(q_goal):
            return None, 0.0, 0.0, 0x1002
        path = np.vstack([q_start, q_goal])
        return (path, *kin.joint_move_profile(q_start, q_goal, frac), 0)
    wire = finite_floats(msg["pose"], 6)
    if wire is None or np.any(np.abs(wire[3:]) > 1e6):  # non-finite, or angles beyond +-1000 rad
        return None, 0.0, 0.0, 0x1003
    T_work, T_tool = frames()
    T_goal = T_work @ pose6_to_matrix(P.pose_from_wire(wire))  # tool in base
    if not within_reach(kin, T_goal, T_tool):
        return None, 0.0, 0.0, 0x1003
    if name == "movej_p":
        res = kin.ik(T_goal, q_start, tool=T_tool, restarts=6, max_iterations=100)
        if not res.success:
            return None, 0.0, 0.0, 0x1003
        path = np.vstack([q_start, res.q])
        return (path, *kin.joint_move_profile(q_start, res.q, frac), 0)
    # movel
    line, why = kin.linear_path(q_start, T_goal, tool=T_tool)
    if line is None:
        _log.info("simulator: movel refused: %s", why)
        return None, 0.0, 0.0, 0x1003
    T0 = kin.fk(q_start, T_tool)
    length = float(np.linalg.norm(T_goal[:3, 3] - T0[:3, 3]))
    angle = rotation_angle(T0, T_goal)
    # The joints along the line, as seconds at their full speed; the tightest acceleration to speed
    # ratio bounds how fast that measure may change its rate.
    dq = np.abs(np.diff(line, axis=0))
    joint_s = float(np.sum(np.max(dq / kin.max_speed_rad_s, axis=1)))
    joint_acc = float(np.min(kin.max_acc_rad_s2 / kin.max_speed_rad_s))
    T, t_a = trapezoid_profile([length, angle, joint_s],
                               frac * np.array([limits.line_speed_m_s, limits.angular_speed_rad_s, 1.0]),
                               frac * np.array([limits.line_acc_m_s2, limits.angular_acc_rad_s2, joint_acc]))
    return line, T, t_a, 0


def line_segment(kin: RM65Kinematics, path: np.ndarray, T_tool: np.ndarray, duration_s: float,
                 accel_s: float) -> LineSegment:
    """The straight line of a planned ``movel`` (joint ``path``), with the speed and acceleration its timing implies."""
    T0, T1 = kin.fk(path[0], T_tool), kin.fk(path[-1], T_tool)
    return LineSegment.timed(T0[:3, 3].copy(), T1[:3, 3].copy(), rotation_angle(T0, T1) > np.radians(COLLINEAR_DEG),
                             duration_s, accel_s)


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


def trajectory_msg(success: bool, connected: bool = False) -> dict[str, Any]:
    """The ``current_trajectory_state`` arrival message: ``success`` false for a motion stopped or aborted.

    ``connected``: the motion that ended hands over to the next one (``trajectory_connect`` 1);
    0 means every queued motion is done.
    """
    return {"state": P.TRAJECTORY_STATE, "trajectory_state": bool(success), "device": 0,
            "trajectory_connect": int(bool(connected))}

