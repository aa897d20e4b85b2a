"""What a weld job is given and what it returns: the studs, the job's parameters, the result.

Pure data (no arm, no journal): :class:`StudTarget` (world frame, m), :class:`WeldParams`
(lengths m, times s, speeds % of the controller maximum; checked when built), :class:`JobResult`,
the callback types :class:`~rm65_driver.weld.weld_sequence.WeldSequence` reports through, and the job
ids every journal record of a job carries.
"""
from __future__ import annotations

import datetime as _dt
import math
import uuid
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from stud_common.vocabulary import OnDisconnect, StudOrder, WeldPhase, choices


@dataclass(frozen=True)
class StudTarget:
    """One stud to weld: ``position`` (3,) m on the surface and unit outward ``normal`` (3,), in ``world``
    as the cell sends it; the weld job works in the arm's base frame (the same without a rail;
    :func:`rm65_driver.rail.control.target_in_base` on one)."""

    stud_id: str
    position: np.ndarray
    normal: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "position", np.asarray(self.position, dtype=np.float64).reshape(3))
        n = np.asarray(self.normal, dtype=np.float64).reshape(3)
        norm = np.linalg.norm(n)
        object.__setattr__(self, "normal", n / norm if norm > 0 else n)


@dataclass(frozen=True)
class WeldParams:
    """Job parameters. Lengths m, times s, speeds % of the controller maximum.

    ``tool_offset_m``: flange -> weld-gun tip along the flange z axis (the ``weld_tool`` frame,
    set on the controller as tool frame ``tool_frame_name``). ``trigger_io``: controller DO 1..4
    (or tool-flange DO 1..2 with ``trigger_on_tool``); needs an external relay, see :mod:`.weld_sequence`.

    ``stud_length_m``: the welded stud's standing height. The gun holds the stud in its chuck and
    the ferrule at its base, so after the weld it must be pulled straight off the whole stud before
    it moves sideways (stud-gun makers: "pull the gun straight off the welded stud to prevent damage
    to the weld chuck"). The retract ends at the approach pose, ``standoff_m`` out along the normal,
    where the move to the next stud begins: ``standoff_m`` must be at least ``stud_length_m`` +
    ``stud_clearance_m``. 0: not known, not checked.

    ``min_stud_spacing_m``: the room the gun's foot needs around its axis beside a welded stud (the
    foot's radius, the stud head's and a margin: the gun's and the stud's, set by the cell). A stud
    whose foot would pass closer to a stud already welded (or uncertain), by this job or any the
    journal has seen, is refused (skipped, the neighbour named): :mod:`.welded_neighbours`. 0: not checked.
    """

    standoff_m: float = 0.05
    tool_offset_m: float = 0.15
    plunge_m: float = 0.0
    tool_payload_kg: float = 1.0
    tool_frame_name: str = "weld_gun"
    trigger_io: int = 1
    trigger_on_tool: bool = False
    set_io_mode: bool = True  # Gen-3 multiplexed IO must be switched to output first
    pulse_s: float = 0.2
    dwell_s: float = 0.5
    joint_speed_pct: int = 30
    linear_speed_pct: int = 10
    motion_timeout_s: float = 60.0
    # The fast approach: the last final_approach_m before the contact at linear_speed_pct (slow,
    # controlled), the rest of the standoff and the retract at approach_speed_pct. 0 (or not
    # shorter than the standoff): the whole standoff slow, the retract too.
    final_approach_m: float = 0.0
    approach_speed_pct: int = 10
    # The fast approach and the slow final move sent as one connected trajectory (trajectory_connect=1):
    # on their shared line the arm slows to the slow speed without stopping in between.
    connected_approach: bool = False
    stud_order: StudOrder = StudOrder.GIVEN
    reconnect_timeout_s: float = 10.0
    max_reconnects_per_stud: int = 3
    on_disconnect: OnDisconnect = OnDisconnect.CONTINUE
    require_base_work_frame: bool = True
    stud_length_m: float = 0.0
    stud_clearance_m: float = 0.01
    min_stud_spacing_m: float = 0.0

    def __post_init__(self) -> None:
        if self.stud_order not in choices(StudOrder):
            raise ValueError(f"stud_order={self.stud_order!r}: expected one of {', '.join(choices(StudOrder))}")
        if self.on_disconnect not in choices(OnDisconnect):
            raise ValueError(f"on_disconnect={self.on_disconnect!r}: expected 'continue' or 'abort'")
        # the modes arrive as text (ROS parameters, tests): held as the vocabulary's members
        object.__setattr__(self, "stud_order", StudOrder(self.stud_order))
        object.__setattr__(self, "on_disconnect", OnDisconnect(self.on_disconnect))
        for name in ("standoff_m", "tool_offset_m", "plunge_m", "tool_payload_kg", "pulse_s", "dwell_s",
                     "motion_timeout_s", "reconnect_timeout_s", "final_approach_m", "stud_length_m",
                     "stud_clearance_m", "min_stud_spacing_m"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"{name}={getattr(self, name)} must be a finite number")
            if getattr(self, name) < 0:
                raise ValueError(f"{name}={getattr(self, name)} must not be negative")
        if self.standoff_m <= 0:
            raise ValueError("standoff_m must be positive (the approach pose must be off the surface)")
        need = self.stud_length_m + self.stud_clearance_m
        if self.stud_length_m > 0 and self.standoff_m < need - 1e-9:
            raise ValueError(
                f"standoff_m={self.standoff_m:g} m does not pull the gun off the welded stud: the retract must "
                f"clear the stud's {self.stud_length_m * 1e3:g} mm standing height plus stud_clearance_m="
                f"{self.stud_clearance_m:g} m before the gun moves sideways; expected standoff_m >= {need:.4g} m")

    @property
    def fast_approach(self) -> bool:
        """A fast approach to a short standoff before the slow final move (see the fields)."""
        return 0.0 < self.final_approach_m < self.standoff_m

    @property
    def tool_T(self) -> np.ndarray:
        """Flange -> weld tool (4x4, m)."""
        T = np.eye(4)
        T[2, 3] = self.tool_offset_m
        return T


@dataclass
class JobResult:
    welded: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    failed: list[str] = field(default_factory=list)
    messages: list[str] = field(default_factory=list)
    success: bool = False
    message: str = ""
    job_id: str = ""


PhaseCallback = Callable[[str, WeldPhase, int, int], None]  # (stud_id, phase, done, total)
WeldedCallback = Callable[[str, np.ndarray], None]  # (stud_id, joints at the weld, rad): after the journal says welded


def new_job_id() -> str:
    """``<UTC time>-<6 hex>``: sorts by start time, unique across restarts and cells."""
    return f"{_dt.datetime.now(_dt.timezone.utc):%Y%m%dT%H%M%SZ}-{uuid.uuid4().hex[:6]}"

