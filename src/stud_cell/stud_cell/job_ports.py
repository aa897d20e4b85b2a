"""What the weld job exchanges with the cell: its exceptions, data types, ports and settings.

:class:`CellPorts` is everything :class:`~stud_cell.job.CellJob` needs of the cell: the sequencer node
implements it over topics, services and the weld action, tests in plain Python. No ROS in here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from stud_common.vocabulary import VIEW_DEPENDENT, CellState
from stud_inspection import qa_codes
from stud_inspection.inspection import InspectionLimits
from stud_planner.matching.target_table import TargetTable

#: The job's states: CellState's members by their names (``cell_job.DONE is CellState.DONE``). The job keeps
#: and reports a CellState; its ``text`` (``"done"``) is only for the edges: CellStatus ``state_text``, the
#: weld report and the QA record, logs.
IDLE, REGISTERING, MOVING, SHOOTING, MATCHING, WELDING, INSPECTING, PAUSED, DONE, FAILED = (
    CellState.IDLE, CellState.REGISTERING, CellState.MOVING, CellState.SHOOTING, CellState.MATCHING,
    CellState.WELDING, CellState.INSPECTING, CellState.PAUSED, CellState.DONE, CellState.FAILED)


class JobAborted(Exception):
    """The job cannot go on (stop requested, a step failed): the message says why."""


class MoveRefused(JobAborted):
    """The arm refused a camera move (unreachable, e-stop): the message says why."""


class DriverLost(JobAborted):
    """The arm driver lost the weld job (crash, restart) while it ran."""


class InspectionUnavailable(Exception):
    """No inspection of a station could be had (no inspector, the view before the welds no longer
    kept, no shot after them): its studs are ``not_inspected`` with this message as the reason."""


@dataclass(frozen=True)
class Target:
    """One stud's weld target of a view: what the job decides on, and the arm's own target (opaque)."""

    stud_id: str
    ok: bool                  # usable: weld it
    status_text: str          # "ok", "normal_uncertain", "no_depth", ...
    lean_bound_deg: float     # how far the welded stud could lean from the normal, from its uncertainty
    entry: dict               # its weld-report fields (TargetTable.report_entries)
    payload: object = None    # what the arm driver welds (a WeldTarget message in the node)
    centre_offset: float = math.nan  # the match's distance from the image centre (target_table.centre_offset)


def table_targets(table: TargetTable, payloads=None) -> tuple[Target, ...]:
    """The job's targets of one view's :class:`TargetTable`; ``payloads`` (one per target): what the
    arm driver welds of each (None: nothing)."""
    entries = table.report_entries(with_stud=False)
    payloads = [None] * len(table.ids) if payloads is None else payloads
    return tuple(Target(stud_id=sid, ok=ok, status_text=entry["status"], lean_bound_deg=lean, entry=entry,
                        payload=payload, centre_offset=offset)
                 for sid, ok, lean, offset, entry, payload in zip(table.ids, table.ok.tolist(),
                                                                  table.lean_bound_deg.tolist(),
                                                                  table.centre_offset.tolist(), entries, payloads))


@dataclass(frozen=True)
class View:
    """One shot's targets, and where the camera stood for it."""

    index: int
    stamp_ns: int
    camera_xyz_w: tuple
    yaw_rad: float
    targets: tuple[Target, ...]


@dataclass(frozen=True)
class Registration:
    valid: bool
    message: str
    m_local2world: np.ndarray   # (3, 3), Eq. 2
    plane_z_m: float            # world z of the marks (the working plane)
    # Along a part with reference marks (Registration.msg): how well the marks fitted and how far it reached
    residual_m: float = math.nan            # RMS of the marks' fit
    residual_max_m: float = math.nan        # the largest mark's distance from the fit
    labels_used: tuple[str, ...] = ()       # the marks the fit used ("O", "A", "B", "M3", ...)
    extrapolated_m: float = 0.0             # > 0: too few marks in view, the nearest registration's, this far away


@dataclass(frozen=True)
class Layout:
    ids: list[str]
    xy_m: np.ndarray            # (N, 2) drawing frame
    source_file: str = ""
    marks_m: np.ndarray | None = None   # (3, 2) O, A, B, drawing frame (the board's size, for its search)
    mark_diameter_m: float = 0.0
    reference_marks_m: dict = field(default_factory=dict)   # "M1" -> (2,) drawing frame: marks along a long part


@dataclass(frozen=True)
class InspectionOutcome:
    """One view's post-weld inspection: QA fields per target sent (qa_report rows' ``verdict``,
    ``reasons``, ``measured``), objects standing where no stud was planned, the overlay image."""

    rows: list[dict]
    unexpected: list[dict] = field(default_factory=list)   # {"position_m": [x, y, z], "height_mm": h}
    overlay_file: str = ""
    limits: dict = field(default_factory=dict)             # what the studs were judged against


@dataclass(frozen=True)
class WeldOutcome:
    welded: tuple[str, ...]     # studs the journal holds as welded, of those sent, in the order welded
    failed: tuple[str, ...]
    messages: tuple[str, ...]   # "<stud id>: why"


class CellPorts(Protocol):
    """What the job needs of the cell. Every call may raise JobAborted (stop, time-out, refusal)."""

    def wait_layout(self) -> Layout: ...
    def move_camera(self, xyz_w, yaw_rad: float) -> None: ...             # MoveRefused: unreachable
    def register(self, attempts: int = 0) -> Registration: ...           # a registration shot (0: the cell's retries)
    def shoot_view(self, what: str, camera_xyz_w, yaw_rad: float) -> View | None: ...  # None: no targets came
    def shoot(self, inspection: bool = False) -> int: ...                # a shot (inspection: the
                                                                         # inspector's alone); its ROS time (ns)
    def weld(self, targets: list[Target]) -> WeldOutcome: ...            # DriverLost: the driver lost the job
    def inspect(self, station: int, view: View, targets: list[Target], welded_ids: list[str],
                after_ns: int) -> InspectionOutcome: ...                # InspectionUnavailable
    def status(self, state: CellState, message: str, **fields) -> None: ...
    def checkpoint(self) -> None: ...                                    # honours pause and stop
    # With a rail (JobConfig.rail_length_m > 0; rail_job.RailJob) -- a cell without one need not have these:
    def move_rail(self, position_m: float) -> float: ...                 # carriage there, the arm still; where it
                                                                         # arrived (m). MoveRefused: refused
    def rail_position_m(self) -> float: ...                              # where the carriage is (m)
    def stopped(self) -> bool: ...
    def info(self, text: str) -> None: ...
    def warn(self, text: str) -> None: ...


#: Status texts another view may cure: such studs are shot again before the job gives up on them.
RESHOOT_STATUS_TEXTS = frozenset(s.text for s in VIEW_DEPENDENT)


@dataclass(frozen=True)
class JobConfig:
    """The job's settings (the sequencer's parameters of the same names); frozen: a change is a new config
    (``dataclasses.replace``)."""

    registration_station_xyz_m: tuple = (0.225, -0.29, 0.285)   # (): no station, search the board
    board_search_area_xy_m: tuple = ()   # x_min, y_min, x_max, y_max (world); (): the arm's table along the rail
    board_search_plane_z_m: float = 0.0                           # the table the board lies on (world z)
    board_search_heights_m: tuple = (0.45, 0.425, 0.40, 0.375, 0.35, 0.325, 0.30, 0.275)  # camera above that table
    board_search_max_shots: int = 16
    station_height_steps_m: tuple = (0.0, 0.05, -0.05, 0.10)      # tried when a station is out of reach
    camera_height_m: float = 0.40
    camera_yaw_deg: float = 0.0
    part_height_m: float = 0.15
    fov_width_m: float = 0.46
    fov_distance_m: float = 0.5
    image_aspect: float = 0.75
    overlap: float = 0.15
    fewest_stations: bool = False  # station_planning: free footprints when they need fewer stations than the grid
    weld_resends: int = 3
    reshoot_attempts: int = 2
    reshoot_offset_m: float = 0.08
    inspect: bool = True
    report_file: str = ""
    qa_dir: str = ""
    rework_file: str = ""   # the operator's rework decisions (cell.rework), merged into the QA record
    bend_file: str = ""     # the bend-test results entered (stud_inspection.bend), merged into it too
    qa_code: str = qa_codes.DEFAULT_CODE   # the code profile the record's bend tests follow
    qa_overrides: dict = field(default_factory=dict)   # its values overridden for this job (qa_codes.profile)
    sample_seed: int = 0    # the lot sample's seed (0: a random one), stored in the record
    qa_limits: dict = field(default_factory=lambda: InspectionLimits().to_dict())  # the QA record's header
                                                    # (an inspection's own limits replace these)
    job_id: str = ""
    part: str = ""
    # The rail (rail_job.RailJob, rail_plan.py): the arm's base on a linear axis; 0: none, the arm fixed
    rail_length_m: float = 0.0
    rail_mount_xyz_m: tuple = (0.0, 0.0, 0.0)
    rail_coarse_step_m: float = 0.05     # carriage positions a station is reached from: sampled this far apart,
    rail_tolerance_m: float = 0.005      # the ends found to within this
    rail_stud_height_m: float = math.nan  # the studs' height above the plane the stops are planned for (NaN: half
                                          # part_height_m); their weld reach, normal up, is the plan's prior

    @classmethod
    def from_params(cls, p: dict) -> "JobConfig":
        names = cls.__dataclass_fields__
        return cls(**{k: v for k, v in p.items() if k in names})
