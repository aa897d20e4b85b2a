"""The simulated rail: the controller's expansion joint (device 4) carrying the arm's base.

:class:`SimRail` is a member of :class:`~rm65_sim.simulator.ArmSimulator` (it shares the
simulator's lock and change condition): the simulator hands it ``expand_set_pos``,
``expand_set_speed`` and ``expand_get_state``, advances it from its motion thread and stops it with
the arm's ``set_arm_stop`` / ``set_arm_slow_stop``.

Behaviour (RealMan's JSON protocol and what the official SDK 1.1.6 requires of a controller; what is
undocumented is chosen and said so):

* ``expand_set_pos``: a target outside the travel ``0 .. length`` (or a speed outside 1..100, a
  non-integer ``pos``, an axis that is moving, a controller without the axis) is refused at once
  with ``set_pos_state:false`` -- the only refusal channel RealMan documents. Accepted: the
  acknowledgement, then a trapezoidal move in (scaled) real time, ``v`` % scaling the axis's speed
  and acceleration alike, and **always** an arrival ``current_trajectory_state`` with ``device`` 4:
  ``trajectory_state`` true at the target, false when the move was stopped (the official SDK waits
  for ever otherwise). ``block``, which the SDK adds, is accepted and ignored.
* ``expand_set_speed``: a jog at ``speed`` % (-100..100), ramping at the scaled acceleration and
  halting at either end of the travel; 0 stops the axis at once (a position move so stopped
  reports ``trajectory_state`` false). No arrival message for a jog (none is documented).
* ``expand_get_state``: ``{"state":"expand_state","pos","current","err_flag","en_flag","mode",
  "joint_id"}``, every value a number (the keys the official SDK requires, docs/RM65_PROTOCOL.md §4.2); ``pos`` is the
  encoder's count -- the commanded position once a move has arrived: the controller does not know
  its rail's scale error. ``mode`` 2 / 4 during a position move toward + / -, 1 / 3 jogging, 0 still.
* The arm's ``set_arm_stop`` and ``set_arm_slow_stop`` stop the rail too (RealMan leaves open whether
  they do; a cell's stop must stop everything that moves). ``set_arm_pause`` does not pause it.
  Like the arm's stop, the simulated stop is immediate.

The truth: the carriage is where :func:`stud_common.frames.carriage_in_world` puts it with the
rail's :class:`~stud_common.frames.RailDeviation` (scale, offset, yaw per metre, sim-only), the
arm's base ``mount_xyz_m`` above it: :meth:`SimRail.true_base_in_world` (what the simulated
camera renders with and the demo measures the welds against). Nothing the controller reports
carries it.
"""
from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from rm65_driver.kinematics.rm65 import trapezoid_profile
from rm65_driver.protocol import messages as P
from rm65_driver.rail.axis import (
    DEVICE_EXPAND,
    EXPAND_SET_POS,
    EXPAND_SET_SPEED,
    RailAxis,
    RailMode,
    expand_state_message,
)
from rm65_sim.motion import SegmentProfile
from stud_common.frames import RailDeviation, world_T_base

_log = logging.getLogger("rm65_sim.simulator")  # one logger for all parts of the simulator


def rail_arrival(success: bool) -> dict[str, Any]:
    """The expansion joint's arrival message; ``trajectory_connect`` always sent (ROS1 requires it)."""
    return {"state": P.TRAJECTORY_STATE, "device": DEVICE_EXPAND, "trajectory_state": bool(success),
            "trajectory_connect": 0}


@dataclass
class RailMove:
    """One accepted position move: from ``start_m`` to ``target_m`` along a rest-to-rest trapezoid."""

    start_m: float
    target_m: float
    profile: SegmentProfile
    conn_id: int
    elapsed_s: float = 0.0  # simulated seconds done
    released_at: float | None = None  # monotonic time the acknowledgement was on the wire

    def release(self) -> None:
        self.released_at = time.monotonic()

    def position_at(self, t_s: float) -> float:
        return self.start_m + (self.target_m - self.start_m) * self.profile.fraction_at(t_s)


@dataclass
class SimRail:
    """The simulated expansion joint (see the module docstring). ``axis`` None: the controller has
    none (every expand command refused, the state reports it disabled)."""

    axis: RailAxis | None
    lock: threading.RLock
    changed: threading.Condition
    mount_xyz_m: Sequence[float] = (0.0, 0.0, 0.0)
    deviation: RailDeviation = field(default_factory=RailDeviation)
    min_motion_real_s: float = 0.01
    position_m: float = 0.0  # the encoder (m): where the drive believes the carriage is
    move: RailMove | None = None
    jog_speed_m_s: float = 0.0  # signed target speed of a jog (0: none)
    velocity_m_s: float = 0.0  # signed, during a jog
    arrivals: list[tuple[float, bool]] = field(default_factory=list)  # (monotonic time, success), tests

    # -- inspection -----------------------------------------------------------------------
    @property
    def moving(self) -> bool:
        with self.lock:
            return self.move is not None or self.jog_speed_m_s != 0.0 or self.velocity_m_s != 0.0

    @property
    def mode(self) -> RailMode:
        with self.lock:
            if self.move is not None:
                return RailMode.of_motion(self.move.target_m - self.move.start_m or 1.0, position_move=True)
            return RailMode.of_motion(self.velocity_m_s or self.jog_speed_m_s, position_move=False)

    def true_carriage_m(self) -> float:
        """How far the carriage really is from the rail's true zero, along the rail (m)."""
        with self.lock:
            return self.position_m * (1.0 + self.deviation.scale_ppm * 1e-6) + self.deviation.offset_m

    def true_base_in_world(self) -> np.ndarray:
        """Where the arm's base really is in ``world`` (4, 4).

        The rail's deviation applied (identity without a rail).
        """
        with self.lock:
            if self.axis is None:
                return np.eye(4)
            return world_T_base(self.position_m, self.mount_xyz_m, self.deviation)

    def set_position(self, position_m: float) -> None:
        """Teleport the carriage (test set-up only)."""
        with self.lock:
            self.position_m = float(position_m)
            self.changed.notify_all()

    # -- commands -------------------------------------------------------------------------
    def cmd_set_pos(self, conn_id: int, msg: dict[str, Any]) -> list[Any]:
        """``expand_set_pos``: the acknowledgement, and the callable that starts the move once it is sent."""
        refused = [{"command": EXPAND_SET_POS, "set_pos_state": False}]
        pos, speed = _wire_int(msg.get("pos")), _wire_int(msg.get("speed"))
        if self.axis is None:
            _log.info("simulator: expand_set_pos refused: this controller has no expansion joint")
            return refused
        if pos is None or speed is None or not 1 <= speed <= 100:
            _log.info("simulator: expand_set_pos refused: pos %r / speed %r", msg.get("pos"), msg.get("speed"))
            return refused
        if not 0 <= pos <= self.axis.max_counts:
            _log.info("simulator: expand_set_pos refused: pos %d outside 0..%d", pos, self.axis.max_counts)
            return refused
        with self.lock:
            if self.moving:
                _log.info("simulator: expand_set_pos refused: the rail is moving")
                return refused
            target = self.axis.to_m(pos)
            frac = speed / 100.0
            T, t_a = trapezoid_profile([target - self.position_m], [frac * self.axis.max_speed_m_s],
                                       [frac * self.axis.accel_m_s2])
            move = RailMove(self.position_m, target, SegmentProfile.rest_to_rest(max(T, 1e-6), t_a), conn_id)
            self.move = move
            self.changed.notify_all()
        return [{"command": EXPAND_SET_POS, "set_pos_state": True}, move.release]

    def cmd_set_speed(self, msg: dict[str, Any]) -> list[Any]:
        """``expand_set_speed``: jog, or stop with 0 (a stopped position move reports its failed arrival)."""
        speed = _wire_int(msg.get("speed"))
        if self.axis is None or speed is None or not -100 <= speed <= 100:
            return [{"command": EXPAND_SET_SPEED, "set_speed_state": False}]
        with self.lock:
            out: list[Any] = [{"command": EXPAND_SET_SPEED, "set_speed_state": True}]
            if speed == 0:
                out += self.stop()
            elif self.move is not None:
                _log.info("simulator: expand_set_speed %d refused during a position move", speed)
                return [{"command": EXPAND_SET_SPEED, "set_speed_state": False}]
            else:
                self.jog_speed_m_s = speed / 100.0 * self.axis.max_speed_m_s
            self.changed.notify_all()
        return out

    def cmd_get_state(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self.lock:
            if self.axis is None:
                return expand_state_message(0, RailMode.IDLE, enabled=False)
            return expand_state_message(self.axis.to_counts(self.position_m), self.mode,
                                        current_ma=800 if self.moving else 0)

    def stop(self) -> list[tuple[int, dict[str, Any]]]:
        """Halt now (the arm's stop, or a jog of 0): a position move ends with ``trajectory_state`` false."""
        with self.lock:
            out = []
            if self.move is not None:
                out.append((self.move.conn_id, rail_arrival(False)))
                self.arrivals.append((time.monotonic(), False))
                _log.info("simulator: rail stopped at %.4f m", self.position_m)
            self.move = None
            self.jog_speed_m_s = self.velocity_m_s = 0.0
            self.changed.notify_all()
        return out

    # -- motion ---------------------------------------------------------------------------
    def advance(self, dt_s: float, now: float) -> list[tuple[int, dict[str, Any]]]:
        """Move on by ``dt_s`` simulated seconds; returns the arrival messages to send (conn id, message)."""
        with self.lock:
            if self.axis is None or not self.moving:
                return []
            out = []
            m = self.move
            if m is not None:
                if m.released_at is None:
                    return []  # acknowledged, not on the wire yet
                m.elapsed_s += dt_s
                self.position_m = m.position_at(m.elapsed_s)
                if m.elapsed_s >= m.profile.duration_s and now - m.released_at >= self.min_motion_real_s:
                    self.position_m = m.target_m
                    self.move = None
                    self.arrivals.append((now, True))
                    out.append((m.conn_id, rail_arrival(True)))
            else:
                self._jog(dt_s)
            self.changed.notify_all()
            return out

    def _jog(self, dt_s: float) -> None:
        assert self.axis is not None
        target, v = self.jog_speed_m_s, self.velocity_m_s
        acc = abs(target) / self.axis.max_speed_m_s * self.axis.accel_m_s2  # v % scales the acceleration too
        step = acc * dt_s
        v = min(v + step, target) if v < target else max(v - step, target)
        x = self.position_m + v * dt_s
        if not 0.0 <= x <= self.axis.length_m:  # the travel's end: the drive's soft limit halts the jog
            x = min(max(x, 0.0), self.axis.length_m)
            v = target = 0.0
            _log.info("simulator: rail jog halted at the end of the travel (%.4f m)", x)
        self.position_m, self.velocity_m_s, self.jog_speed_m_s = x, v, target


def _wire_int(v: Any) -> int | None:
    """A JSON integer of the wire's int32 (2.0 accepted as a client might send it), else None (a bool, 1.5, "7")."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return None
    if not (math.isfinite(v) and float(v).is_integer() and abs(v) < 2**31):
        return None
    return int(v)
