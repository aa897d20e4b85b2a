"""The driver's side of the rail: reading the carriage, moving it, and the world <-> base conversion.

Pure Python on top of :class:`~rm65_driver.protocol.arm_client.ArmClient` (no ROS), as the weld job is.
:class:`RailControl` knows the axis (:class:`~rm65_driver.rail.axis.RailAxis`, None: no rail) and the
carriage -> base mount; it reads ``expand_get_state``, sends ``expand_set_pos`` and waits for the
device-4 arrival, and stops the axis with ``expand_set_speed`` 0 -- RealMan's documented way;
whether the arm's ``set_arm_stop`` stops it too is undocumented, so the driver sends both.

Frames: the arm's kinematics and the controller work in the arm's base frame; the cell's targets
come in ``world``, the rail's frame. The conversion is
:func:`stud_common.frames.world_T_base` with the carriage position the controller reports -- the
encoder's, which is the commanded one once a move arrived. The rail's true error (scale, offset,
yaw) is not the driver's to correct: registration on the part's reference marks does.
Without a rail every transform is the identity and nothing is ever sent to the axis.
"""
from __future__ import annotations

import threading
from typing import Sequence

import numpy as np

from rm65_driver.protocol.arm_client import ArmClient, ArmCommandError
from rm65_driver.protocol.messages import ProtocolError
from rm65_driver.rail.axis import (
    DEVICE_EXPAND,
    RailAxis,
    RailReading,
    expand_get_state,
    expand_set_pos,
    expand_set_speed,
    parse_expand_state,
)
from rm65_driver.weld.weld_job import StudTarget
from stud_common.frames import world_T_base


class RailControl:
    """The carriage as the driver sees and moves it (see the module docstring)."""

    def __init__(self, client: ArmClient, axis: RailAxis | None, mount_xyz_m: Sequence[float] = (0.0, 0.0, 0.0)):
        self.client = client
        self.axis = axis
        self.mount_xyz_m = tuple(float(v) for v in mount_xyz_m)
        self._lock = threading.Lock()
        self._last: RailReading | None = None

    @property
    def present(self) -> bool:
        return self.axis is not None

    # -- state ----------------------------------------------------------------------------
    def read(self) -> RailReading | None:
        """Ask the controller for the axis's state (None without a rail). Raises ArmError."""
        if self.axis is None:
            return None
        try:
            reading = parse_expand_state(self.client.request(expand_get_state()))
        except ProtocolError as exc:
            raise ArmCommandError("expand_get_state", 0, str(exc)) from exc
        with self._lock:
            self._last = reading
        return reading

    @property
    def last(self) -> RailReading | None:
        with self._lock:
            return self._last

    @property
    def position_m(self) -> float:
        """The carriage's last known position along the rail (m; 0 without a rail or a reading)."""
        last = self.last
        return 0.0 if last is None or self.axis is None else self.axis.to_m(last.pos)

    @property
    def moving(self) -> bool:
        last = self.last
        return last is not None and last.moving

    def world_T_base(self, carriage_m: float | None = None) -> np.ndarray:
        """The arm's base in ``world`` (4, 4) with the carriage at ``carriage_m`` (default: its last known
        position); the identity without a rail."""
        if self.axis is None:
            return np.eye(4)
        return world_T_base(self.position_m if carriage_m is None else carriage_m, self.mount_xyz_m)

    # -- motion ---------------------------------------------------------------------------
    def move(self, position_m: float, speed_pct: int, timeout_s: float, stop_count: int | None = None) -> float:
        """Move the carriage to ``position_m`` (m) at ``speed_pct`` %, wait for its arrival, return the
        position the controller then reports (m). Raises RailRequestError (no rail, outside the travel),
        ArmError (refused, stopped, timed out, link lost)."""
        if self.axis is None:
            raise ArmCommandError("expand_set_pos", 0, "this driver has no rail (rail_length_m is 0)")
        counts = self.axis.check_position(position_m)
        distance = abs(position_m - self.position_m)
        self.client.move_axis_and_wait(expand_set_pos(counts, speed_pct), DEVICE_EXPAND,
                                       timeout_s=self.axis.move_time_s(distance, speed_pct) + timeout_s,
                                       stop_count=stop_count)
        reading = self.read()
        assert reading is not None
        return self.axis.to_m(reading.pos)

    def stop(self) -> None:
        """Stop the axis now (``expand_set_speed`` 0); nothing without a rail. Raises ArmError."""
        if self.axis is not None:
            self.client.command(expand_set_speed(0))


def target_in_base(target: StudTarget, world_T_base_: np.ndarray) -> StudTarget:
    """A stud target given in ``world`` -> the same stud in the arm's base frame.

    ``world_T_base_`` (4, 4): the base in world.
    """
    B = np.linalg.inv(world_T_base_)
    return StudTarget(target.stud_id, B[:3, :3] @ target.position + B[:3, 3], B[:3, :3] @ target.normal)
