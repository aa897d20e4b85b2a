"""Where a weld cell's cycle time goes: a timeline of cell states and weld phases, split per category.

Pure Python (no ROS): the benchmark (bench/bench_cycle_time.py) records, as they arrive, the
sequencer's ``/cell/status`` states and the driver's ``/arm/weld_job`` feedback phases; this module
turns that timeline into seconds per category and per stud.

Each event starts an interval that lasts until the next event. A cell event counts only when its
state differs from the cell's previous state (the sequencer re-publishes its status with new counts
while the state stays); a weld-phase event counts while the cell is welding. Categories:

* ``registration`` -- camera to the marking board, its shot and the registration;
* ``station_moves`` -- the camera to a station (or a re-shoot pose);
* ``shots`` -- a station's shot and the matching of its targets;
* ``inspection`` -- back to the station pose after its welds, the shot, the measurement;
* ``moves_between_studs``, ``approach`` -- the driver's ``approach`` phase: the joint move to the
  stud's clearance pose, and (when the driver reports it) the fast straight approach to the short
  standoff, split by the ``motion_s`` the journal's ``started`` record carries;
* ``descent`` (the slow controlled final move), ``weld``, ``dwell``, ``retract``, ``skip``;
* ``weld_overhead`` -- a weld job's time outside its phases (goal, first state read, result).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterable, Mapping

from stud_common.vocabulary import WeldPhase

#: Cell state text -> category (states not listed, e.g. idle, done, paused, count nowhere).
CELL_CATEGORY = {"registering": "registration", "moving": "station_moves", "shooting": "shots",
                 "matching": "shots", "inspecting": "inspection", "welding": "weld_overhead"}
#: Weld feedback phase -> category (``approach`` is split further, see the module docstring).
PHASE_CATEGORY: dict[str, str] = {
    WeldPhase.APPROACH: "approach", WeldPhase.DESCEND: "descent", WeldPhase.WELD: "weld", WeldPhase.DWELL: "dwell",
    WeldPhase.RETRACT: "retract", WeldPhase.SKIP: "skip"}
CATEGORIES = ("registration", "station_moves", "shots", "moves_between_studs", "approach", "descent", "weld",
              "dwell", "retract", "skip", "weld_overhead", "inspection")
END_STATES = ("done", "failed")


@dataclass(frozen=True)
class CycleEvent:
    """``t_s``: arrival time (s, any one clock); ``kind`` "cell" (``name`` = state text) or "weld"
    (``name`` = phase, ``stud_id`` its stud)."""

    t_s: float
    kind: str
    name: str
    stud_id: str = ""


@dataclass
class CycleSplit:
    seconds: dict[str, float] = field(default_factory=lambda: dict.fromkeys(CATEGORIES, 0.0))
    total_s: float = 0.0
    studs: int = 0

    @property
    def s_per_stud(self) -> float:
        return self.total_s / self.studs if self.studs else float("nan")

    @property
    def studs_per_hour(self) -> float:
        return 3600.0 / self.s_per_stud if self.studs else 0.0

    def per_stud(self, category: str) -> float:
        return self.seconds[category] / self.studs if self.studs else float("nan")


def split_cycle(events: Iterable[CycleEvent], studs: int,
                motion_s: Mapping[str, Mapping[str, float]] | None = None) -> CycleSplit:
    """Seconds per category from the job's first counted cell state (registration, usually) to the
    first ``done``/``failed`` cell state: an idle cell before its job starts is not cycle time (a
    listener that joins early hears the latched ``idle`` status first).

    ``studs``: studs welded (the per-stud denominator). ``motion_s``: per stud, the driver's measured
    motion durations (``{"move": s, "approach": s, ...}``); the ``approach`` phase of a stud is split
    into ``moves_between_studs`` (its ``move``) and ``approach`` (the rest). A stud without them (a
    driver whose approach phase is the joint move alone) counts wholly as a move between studs.
    """
    evs = sorted(events, key=lambda e: e.t_s)
    first = next((i for i, e in enumerate(evs) if e.kind == "cell" and e.name in CELL_CATEGORY), len(evs))
    evs = evs[first:]
    out = CycleSplit(studs=int(studs))
    motion_s = motion_s or {}
    cell_state = ""
    category = ""
    stud = ""
    t_prev = evs[0].t_s if evs else 0.0
    start = t_prev
    end = t_prev
    approach: dict[str, float] = {}  # per stud: its approach phase may be cut by re-published statuses
    for e in evs:
        dt = e.t_s - t_prev
        if category == "approach":
            approach[stud] = approach.get(stud, 0.0) + dt
        elif category:
            out.seconds[category] += dt
        t_prev = end = e.t_s
        if e.kind == "cell":
            if e.name == cell_state:
                continue
            cell_state = e.name
            if cell_state in END_STATES:
                category = ""
                break
            category, stud = CELL_CATEGORY.get(cell_state, ""), ""
        elif e.kind == "weld" and cell_state == "welding":
            category, stud = PHASE_CATEGORY.get(e.name, "weld_overhead"), e.stud_id
    for sid, dt in approach.items():
        measured = motion_s.get(sid)
        move = dt if measured is None else min(dt, float(measured.get("move", dt)))
        out.seconds["moves_between_studs"] += move
        out.seconds["approach"] += dt - move
    out.total_s = end - start
    return out


def motion_from_journal(records: Iterable[Mapping]) -> dict[str, dict[str, float]]:
    """Per stud, the ``motion_s`` of its last ``started`` record that has one (weld journal records)."""
    out: dict[str, dict[str, float]] = {}
    for rec in records:
        if rec.get("event") == "started" and isinstance(rec.get("motion_s"), Mapping):
            out[str(rec.get("stud"))] = {k: float(v) for k, v in rec["motion_s"].items()}
    return out


def format_split(split: CycleSplit, title: str) -> str:
    """A small table: seconds in total and per stud for every category, studs/hour and s/stud."""
    lines = [f"{title}: {split.studs} studs in {split.total_s:.1f} s -> {split.s_per_stud:.2f} s/stud, "
             f"{split.studs_per_hour:.0f} studs/h",
             f"  {'category':<22}{'total s':>9}{'s/stud':>9}"]
    for c in CATEGORIES:
        lines.append(f"  {c:<22}{split.seconds[c]:>9.2f}{split.per_stud(c):>9.3f}")
    rest = split.total_s - sum(split.seconds.values())
    lines.append(f"  {'(other: idle, paused)':<22}{rest:>9.2f}{rest / split.studs if split.studs else 0.0:>9.3f}")
    return "\n".join(lines)
