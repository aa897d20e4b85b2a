"""The options of the controller simulator: one frozen configuration, changed with
:meth:`SimulatorConfig.with_changes` (as the drawing reader's ``LayoutOptions``), handed to
:class:`~rm65_sim.simulator.ArmSimulator` beside its address."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Sequence

from rm65_driver.rail.axis import RailAxis
from rm65_sim.motion import MotionLimits
from stud_common.frames import RailDeviation

__all__ = ["ERR_FORMATS", "SimulatorConfig"]

#: The arm state's error formats: the current firmware's list (what the SDK needs) and the older documented ones.
ERR_FORMATS = ("list", "scalar", "arm_sys")


@dataclass(frozen=True)
class SimulatorConfig:
    """How :class:`~rm65_sim.simulator.ArmSimulator` behaves, by concern.

    Time:
        time_scale: multiplies every motion's duration (0.02 makes tests 50x faster); the simulator's
            ``time_scale`` attribute starts at this value and may be changed while it runs.
        tick_s: the motion thread's period (s, wall clock).
        min_motion_real_s: floor on a motion's wall-clock duration, whatever ``time_scale`` (s): no real
            trajectory ends within milliseconds of its acknowledgement, and the official SDK's single-thread
            mode misses an arrival message that shares a TCP read with the ack.

    The arm:
        d6_m: the flange offset of the DH model (m).
        initial_joints_deg: the joints at start (deg).
        limits: the Cartesian limits at 100 % (:class:`~rm65_sim.motion.MotionLimits`).
        product_version: what ``get_robot_info`` reports.

    The controller's ways (what firmware versions differ in):
        err_format: ``"list"`` (current firmware, what the SDK needs), ``"scalar"`` or ``"arm_sys"``
            (older documented formats).
        pretty_replies: send pretty-printed replies.
        stop_reports_trajectory: a stop with motions queued sends the current one's connection a
            "trajectory failed" state message.
        strict_io_mode: ``set_DO_state`` is refused unless the IO was switched to output mode first
            (Gen-3 behaviour, [INFERRED]).
        keep_moving_on_disconnect: a dropped TCP connection does not stop a planned motion (what a
            controller executing its own trajectory does; [UNCERTAIN] on hardware).
        report_connected: a motion sent with ``trajectory_connect`` 1 reports its end with 1 (DOCS); False:
            with 0, as if every queued motion were done (the [UNCERTAIN] reading a client must survive).

    The rail (:mod:`.rail`):
        rail_axis: the expansion joint carrying the arm (None: no rail).
        rail_mount_xyz_m: the arm's base above the carriage (m).
        rail_deviation: the rail's true deviation (sim-only).
    """

    time_scale: float = 1.0
    tick_s: float = 0.002
    min_motion_real_s: float = 0.01
    d6_m: float = 0.144
    initial_joints_deg: Sequence[float] = (0.0, 0.0, 90.0, 0.0, 90.0, 0.0)
    limits: MotionLimits = field(default_factory=MotionLimits)
    product_version: str = "RM65-BI"
    err_format: str = "list"
    pretty_replies: bool = False
    stop_reports_trajectory: bool = True
    strict_io_mode: bool = True
    keep_moving_on_disconnect: bool = True
    report_connected: bool = True
    rail_axis: RailAxis | None = None
    rail_mount_xyz_m: Sequence[float] = (0.0, 0.0, 0.0)
    rail_deviation: RailDeviation = field(default_factory=RailDeviation)

    def __post_init__(self) -> None:
        if self.err_format not in ERR_FORMATS:
            raise ValueError(f"err_format {self.err_format!r}: expected list, scalar or arm_sys")
        # sequences (lists, arrays) are kept as tuples: the configuration stays immutable (and comparable)
        object.__setattr__(self, "initial_joints_deg", tuple(float(v) for v in self.initial_joints_deg))
        object.__setattr__(self, "rail_mount_xyz_m", tuple(float(v) for v in self.rail_mount_xyz_m))

    def with_changes(self, **changes: Any) -> "SimulatorConfig":
        """A copy with ``changes`` (field name -> value; an unknown name is a TypeError)."""
        return dataclasses.replace(self, **changes)
