"""The rail: a linear axis carrying the arm's base, driven as the controller's *expansion joint* (device 4).

RealMan controllers drive one external axis themselves, as the *lift* (device 3: a vertical column,
heights in whole millimetres, 0-2600 mm) or the *expansion joint* (device 4: a general axis, any
range, positions in thousandths of its native unit). A horizontal rail is what the expansion joint
is for, and a rail metres long needs finer steps than the lift's millimetre, so this is the
expansion joint (``expand_set_pos`` / ``expand_set_speed`` / ``expand_get_state`` of RealMan's JSON
protocol v3.5.5+, as the official SDK 1.1.6 sends and parses them). The two are either/or on one
controller.

Units. The wire's ``pos`` is an integer count whose size RealMan's documents disagree on (0.001 deg
in the ROS 2 message and the state docs, "200 mm" in a C demo): for a linear drive it is 0.001 of
the drive's native unit. So it is a parameter, :attr:`RailAxis.pos_unit_m` (metres per count;
1e-6, a micrometre, for a drive configured in mm) and converted here, never elsewhere. Speeds are
percent of the axis maximum (1-100 for a position move, -100..100 for a jog), as on the wire;
:attr:`RailAxis.max_speed_m_s` and :attr:`RailAxis.accel_m_s2` say what 100 % is. ``v`` % scales
the speed and the acceleration alike, as RealMan documents for the arm's own moves.

Pure: the axis model (range, units, time law), the requests and the parsing of the replies; no
sockets (:class:`~rm65_driver.protocol.arm_client.ArmClient` sends them), no ROS.
"""
from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Any

from rm65_driver.kinematics.rm65 import trapezoid_profile
from rm65_driver.protocol.messages import ProtocolError

#: ``device`` of the expansion joint's arrival messages (0 arm, 1 gripper, 2 hand, 3 lift, 4 expansion joint).
DEVICE_EXPAND = 4

EXPAND_SET_POS = "expand_set_pos"
EXPAND_SET_SPEED = "expand_set_speed"
EXPAND_GET_STATE = "expand_get_state"
EXPAND_STATE = "expand_state"  # the state tag of expand_get_state's reply
# The acknowledgements' result keys (set_pos_state, set_speed_state) are in protocol.RESULT_KEY.

#: Keys of expand_get_state's reply the official SDK 1.1.6 requires (it fails with -3 without one).
STATE_KEYS = ("pos", "current", "err_flag", "mode")


class RailMode(enum.IntEnum):
    """``mode`` of the expansion joint's (and the lift's) state (docs/RM65_PROTOCOL.md §4.1)."""

    IDLE = 0
    SPEED_POSITIVE = 1      # jog (expand_set_speed) toward +
    POSITION_POSITIVE = 2   # position move (expand_set_pos) toward +
    SPEED_NEGATIVE = 3
    POSITION_NEGATIVE = 4

    @classmethod
    def of_motion(cls, direction: float, position_move: bool) -> RailMode:
        if direction == 0:
            return cls.IDLE
        if position_move:
            return cls.POSITION_POSITIVE if direction > 0 else cls.POSITION_NEGATIVE
        return cls.SPEED_POSITIVE if direction > 0 else cls.SPEED_NEGATIVE


class RailRequestError(ValueError):
    """A rail request this axis cannot take: the message names the value and the range."""


@dataclass(frozen=True)
class RailAxis:
    """The rail as the controller drives it: travel ``0 .. length_m`` (m), ``pos_unit_m`` metres per
    wire count, ``max_speed_m_s`` and ``accel_m_s2`` at 100 %."""

    length_m: float
    pos_unit_m: float = 1e-6
    max_speed_m_s: float = 0.5
    accel_m_s2: float = 0.5

    def __post_init__(self) -> None:
        checks = (("length_m", self.length_m > 0), ("pos_unit_m", self.pos_unit_m > 0),
                  ("max_speed_m_s", self.max_speed_m_s > 0), ("accel_m_s2", self.accel_m_s2 > 0))
        for name, ok in checks:
            value = getattr(self, name)
            if not (math.isfinite(value) and ok):
                raise RailRequestError(f"rail {name}={value}: expected a finite number > 0")
        if self.max_counts > 2**31 - 1:
            raise RailRequestError(f"rail of {self.length_m} m at {self.pos_unit_m} m per count needs "
                            f"{self.max_counts} counts: beyond the wire's int32 pos")

    @property
    def max_counts(self) -> int:
        """The far end of the travel, in wire counts."""
        return int(round(self.length_m / self.pos_unit_m))

    def to_counts(self, position_m: float) -> int:
        """Metres along the rail -> wire count (rounded to the nearest count)."""
        return int(round(float(position_m) / self.pos_unit_m))

    def to_m(self, counts: float) -> float:
        """Wire count -> metres along the rail."""
        return float(counts) * self.pos_unit_m

    def check_position(self, position_m: float) -> int:
        """The wire count of a target ``position_m`` (m), or :class:`RailRequestError` outside the travel."""
        if not math.isfinite(position_m):
            raise RailRequestError(f"rail position {position_m} m is not a finite number")
        counts = self.to_counts(position_m)
        if not 0 <= counts <= self.max_counts:
            raise RailRequestError(f"rail position {position_m:.4f} m is outside the travel 0..{self.length_m:g} m")
        return counts

    def move_time_s(self, distance_m: float, speed_pct: float) -> float:
        """Seconds a position move over ``distance_m`` takes at ``speed_pct`` %, rest to rest (trapezoid)."""
        frac = float(speed_pct) / 100.0
        T, _ = trapezoid_profile([abs(distance_m)], [frac * self.max_speed_m_s], [frac * self.accel_m_s2])
        return T


def check_speed_pct(speed_pct: int, jog: bool = False) -> int:
    """A position move's speed 1..100 %, or a jog's -100..100 %; :class:`RailRequestError` otherwise."""
    v = int(speed_pct)
    lo = -100 if jog else 1
    if v != speed_pct or not lo <= v <= 100:
        raise RailRequestError(f"rail speed {speed_pct} %: expected an integer in {lo}..100")
    return v


# --------------------------------------------------------------------------------------------
# requests
# --------------------------------------------------------------------------------------------


def expand_set_pos(counts: int, speed_pct: int, block: bool | None = None) -> dict[str, Any]:
    """Position move to ``counts`` at ``speed_pct`` % (1..100). ``block`` is what the official SDK
    adds (a controller ignores it; the arrival message ends the move either way)."""
    msg: dict[str, Any] = {"command": EXPAND_SET_POS, "pos": int(counts), "speed": check_speed_pct(speed_pct)}
    if block is not None:
        msg["block"] = bool(block)
    return msg


def expand_set_speed(speed_pct: int) -> dict[str, Any]:
    """Jog at ``speed_pct`` % (-100..100; 0 stops the axis: the documented way to stop it)."""
    return {"command": EXPAND_SET_SPEED, "speed": check_speed_pct(speed_pct, jog=True)}


def expand_get_state() -> dict[str, Any]:
    """Query the expansion joint's state: ``pos`` in counts, current, flags, mode (docs/RM65_PROTOCOL.md §4.2)."""
    return {"command": EXPAND_GET_STATE}


# --------------------------------------------------------------------------------------------
# replies
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RailReading:
    """``expand_get_state``'s reply: ``pos`` (wire counts, the drive's encoder), ``current`` (mA),
    ``err_flag`` (joint error bits), ``mode`` (:class:`RailMode`), ``enabled``."""

    pos: int
    current_ma: int
    err_flag: int
    mode: RailMode
    enabled: bool = True

    @property
    def moving(self) -> bool:
        return self.mode != RailMode.IDLE


def parse_expand_state(msg: dict[str, Any]) -> RailReading:
    """Parse an ``expand_state`` reply (numbers, or the doc example's numeric strings)."""
    if msg.get("state") != EXPAND_STATE:
        raise ProtocolError(f"not an {EXPAND_STATE} reply: {str(msg)[:200]}")
    missing = [k for k in STATE_KEYS if k not in msg]
    if missing:
        raise ProtocolError(f"{EXPAND_STATE} reply lacks {missing}: {str(msg)[:200]}")
    try:
        values = {k: int(float(msg[k])) for k in STATE_KEYS}
        mode = RailMode(values["mode"])
        enabled = bool(int(float(msg.get("en_flag", 1))))
    except (TypeError, ValueError) as exc:
        raise ProtocolError(f"{EXPAND_STATE} reply has a bad value ({exc}): {str(msg)[:200]}") from None
    return RailReading(values["pos"], values["current"], values["err_flag"], mode, enabled)


def expand_state_message(pos: int, mode: RailMode, current_ma: int = 0, err_flag: int = 0,
                         enabled: bool = True, joint_id: int = 1) -> dict[str, Any]:
    """The ``expand_get_state`` reply a controller sends, every value numeric (ROS1 parses numbers only)."""
    return {"state": EXPAND_STATE, "pos": int(pos), "current": int(current_ma), "err_flag": int(err_flag),
            "en_flag": int(bool(enabled)), "mode": int(mode), "joint_id": int(joint_id)}

