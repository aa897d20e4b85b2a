"""The least time a stud can take at a cell's settings: the floor under its cycle time.

Whatever order the studs are welded in, whatever the stations, each stud costs at least its moves
along the normal at their speeds and the weld itself. This module prices them with the arm
simulator's own time law (:mod:`.motion`: ``v`` % scales the line's speed *and* acceleration,
every move from rest to rest unless the controller joins two collinear lines), so that a measured
cycle time can be set against what no planner could beat at the same settings:

* ``as_sequenced_s`` -- the stops :mod:`~rm65_driver.weld.weld_sequence` makes: the fast approach and the slow final
  move (one connected trajectory with ``connected_approach``, else two moves), the trigger pulse,
  the dwell, the retract (a ``movel`` from rest to rest over the standoff). The joint move to the
  next stud is taken as nothing (the next stud at the same place) and the job's own time
  (registration, station moves, shots, inspection) as nothing;
* ``blended_s`` -- an ideal controller that blends every corner at full speed: one stop a stud, at
  the contact. The gun goes up the standoff (it must clear the welded stud before it moves
  sideways: the driver's ``stud_length_mm`` + ``stud_clearance_m``) and down again at the fast
  speed, slowing only to the slow speed for the final stretch: no real controller does better.

Both are lower bounds under the controller's limits given (:class:`.motion.MotionLimits`: the
documentation's example values unless the arm's own are read); a measured figure above them is
what the moves between studs and the per-job work cost.

A part longer than the arm's reach adds the carriage's travel along the rail (:func:`rail_floor`):
each stud is weldable only from a range of carriage positions (the driver's reach test,
:func:`carriage_range`), so the carriage must travel at least from where the first stud can be
welded to where the last one can -- ``max(lo) - min(hi)`` over the studs' ranges -- and however that
travel is split, it takes no less than one rest-to-rest move over it at the rail's speed
(:meth:`rm65_driver.rail.axis.RailAxis.move_time_s`, the time law the simulated expansion joint
moves by: ``v`` % scales the speed and the acceleration alike). Pure Python; no ROS.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

import numpy as np

from rm65_driver.kinematics.rm65 import trapezoid_profile
from rm65_driver.rail.axis import RailAxis
from rm65_driver.weld.weld_job import WeldParams
from rm65_sim.motion import LineSegment, MotionLimits, SegmentProfile, junction_speed


@dataclass(frozen=True)
class StudTimeFloor:
    """Seconds a stud takes at least (see the module docstring); the parts of ``as_sequenced_s``."""

    approach_s: float  # the fast approach and the slow final move, from rest at the clearance to rest at the contact
    weld_s: float  # trigger pulse + dwell
    retract_s: float  # the contact to the clearance, rest to rest
    blended_s: float  # one stop a stud: up the standoff and down again with every corner blended, + weld_s

    @property
    def as_sequenced_s(self) -> float:
        return self.approach_s + self.weld_s + self.retract_s


def _line(length_m: float, speed_pct: float, limits: MotionLimits, start_m: float = 0.0) -> LineSegment:
    """A straight ``movel`` down the z axis from height ``start_m`` over ``length_m`` at ``speed_pct`` %,
    timed as the simulator times one (:func:`.motion.plan_motion`, :func:`.motion.line_segment`);
    the joints not binding."""
    frac = speed_pct / 100.0
    T, t_a = trapezoid_profile([length_m], [frac * limits.line_speed_m_s], [frac * limits.line_acc_m_s2])
    return LineSegment.timed(np.array([0.0, 0.0, start_m]), np.array([0.0, 0.0, start_m - length_m]), False, T, t_a)


def _rest_to_rest_s(line: LineSegment) -> float:
    return SegmentProfile(line.length, 0.0, 0.0, line.speed, line.accel).duration_s


def stud_time_floor(params: WeldParams, limits: MotionLimits = MotionLimits()) -> StudTimeFloor:
    """The floor of one stud's time with the weld job's ``params`` on a controller with ``limits``:
    the standoff (and the plunge beyond the surface) at ``approach_speed_pct`` but the last
    ``final_approach_m`` at ``linear_speed_pct`` (all of it slow without a fast approach), joined
    with ``connected_approach``, ``pulse_s`` + ``dwell_s``, the retract back over the same line."""
    p = params
    travel = p.standoff_m + p.plunge_m  # the clearance pose to the contact pose, along the normal
    last = p.final_approach_m + p.plunge_m if p.fast_approach else travel  # the slow stretch
    fast_pct = p.approach_speed_pct if p.fast_approach else p.linear_speed_pct
    slow = _line(last, p.linear_speed_pct, limits, start_m=last)
    if p.fast_approach:
        quick = _line(travel - last, p.approach_speed_pct, limits, start_m=travel)
        w = junction_speed(quick, slow) if p.connected_approach else 0.0
        approach_s = (SegmentProfile(quick.length, 0.0, w, quick.speed, quick.accel).duration_s
                      + SegmentProfile(slow.length, w, 0.0, slow.speed, slow.accel).duration_s)
    else:
        approach_s = _rest_to_rest_s(slow)
    retract_s = _rest_to_rest_s(_line(travel, fast_pct, limits))
    weld_s = p.pulse_s + p.dwell_s
    # One stop: from the contact up and down again (the way up and the fast part of the way down,
    # unfolded onto one line) at the fast speed, handed over at the slow speed itself (not the peak
    # the simulator's slow move reaches from rest: an ideal controller), then the slow stretch.
    v_f, a_f = (fast_pct / 100.0 * x for x in (limits.line_speed_m_s, limits.line_acc_m_s2))
    v_s, a_s = (p.linear_speed_pct / 100.0 * x for x in (limits.line_speed_m_s, limits.line_acc_m_s2))
    if p.fast_approach:
        up_down = 2.0 * travel - last
        w = min(v_s, v_f, float(np.sqrt(2.0 * a_s * last)), float(np.sqrt(2.0 * a_f * up_down)))
        blended = (SegmentProfile(up_down, 0.0, w, v_f, a_f).duration_s
                   + SegmentProfile(last, w, 0.0, v_s, a_s).duration_s)
    else:
        blended = SegmentProfile(2.0 * travel, 0.0, 0.0, v_s, a_s).duration_s
    return StudTimeFloor(approach_s=approach_s, weld_s=weld_s, retract_s=retract_s, blended_s=blended + weld_s)


def carriage_range(reach, position_w, normal_w, mount_xyz_m, rail_length_m: float,
                   step_m: float = 0.01) -> tuple[float, float] | None:
    """(lowest, highest) carriage position (m, sampled every ``step_m`` along the rail) from which
    ``reach`` (:class:`rm65_driver.weld.reach.Reach`) welds the stud at ``position_w`` with
    ``normal_w`` (world); None when no position on the rail does."""
    from stud_common.frames import world_T_base

    p = np.asarray(position_w, dtype=np.float64)
    centre = float(p[0]) - float(np.asarray(mount_xyz_m, dtype=np.float64)[0])
    cs = np.arange(max(0.0, centre - 1.0), min(rail_length_m, centre + 1.0) + 1e-9, step_m)
    ok = [c for c in cs if reach.stud(p, normal_w, world_T_base(float(c), mount_xyz_m)).ok]
    return (float(min(ok)), float(max(ok))) if ok else None


@dataclass(frozen=True)
class RailFloor:
    """The least carriage travel a part needs (m) and the least time it takes (s), whatever the plan."""

    travel_m: float
    move_s: float


def rail_floor(ranges: Iterable[tuple[float, float]], axis: RailAxis, speed_pct: float) -> RailFloor:
    """From the studs' carriage ranges (:func:`carriage_range`; the first and last studs along the rail
    decide it): the carriage travels at least ``max(lo) - min(hi)``, in no less than one move's time
    on ``axis`` at ``speed_pct`` %."""
    r = list(ranges)
    travel = max(0.0, max(lo for lo, _ in r) - min(hi for _, hi in r)) if r else 0.0
    return RailFloor(travel, axis.move_time_s(travel, speed_pct) if travel > 0 else 0.0)


__all__ = ["RailFloor", "StudTimeFloor", "carriage_range", "rail_floor", "stud_time_floor"]
