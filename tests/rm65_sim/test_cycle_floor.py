"""The floor under a stud's cycle time: priced by the simulator's own time law, never above what it runs."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from rm65_driver.kinematics.rm65 import RM65Kinematics, matrix_to_pose6
from rm65_driver.protocol import messages as P
from rm65_driver.weld.weld_job import WeldParams
from rm65_sim.cycle_floor import stud_time_floor
from rm65_sim.motion import Motion, MotionLimits, SegmentProfile, line_segment, plan_motion
from rm65_sim.simulator import ArmSimulator

#: The cell's settings (cell.yaml): 60 mm standoff, the last 10 mm at 10 %, the rest at 30 %, 0.2 s + 0.5 s.
CELL = WeldParams(standoff_m=0.06, final_approach_m=0.01, approach_speed_pct=30, linear_speed_pct=10, pulse_s=0.2,
                  dwell_s=0.5, connected_approach=True)


def _simulated_moves(standoff_m: float, final_m: float, fast_pct: int, slow_pct: int,
                     plunge_m: float) -> tuple[float, float]:
    """(approach, retract) seconds of the simulator planning the moves along a vertical normal at a
    reachable pose: the fast approach joined to the slow final move (to ``plunge_m`` beyond the
    surface), and the retract."""
    kin = RM65Kinematics()
    q_top = np.radians([0, 20, 70, 0, 90, 0])
    top = kin.fk(q_top)
    short, contact = top.copy(), top.copy()
    short[:3, 3] -= [0, 0, standoff_m - final_m]
    contact[:3, 3] -= [0, 0, standoff_m + plunge_m]
    frames = lambda: (np.eye(4), np.eye(4))  # noqa: E731
    p1, T1, a1, c1 = plan_motion(kin, "movel", P.movel(matrix_to_pose6(short), fast_pct), q_top, frames, MotionLimits())
    p2, T2, a2, c2 = plan_motion(kin, "movel", P.movel(matrix_to_pose6(contact), slow_pct), p1[-1], frames,
                                 MotionLimits())
    p3, T3, _, c3 = plan_motion(kin, "movel", P.movel(matrix_to_pose6(top), fast_pct), p2[-1], frames, MotionLimits())
    assert c1 == c2 == c3 == 0
    first = Motion("movel", p1, SegmentProfile.rest_to_rest(T1, a1), 0, connect_next=True,
                   line=line_segment(kin, p1, np.eye(4), T1, a1))
    second = Motion("movel", p2, SegmentProfile.rest_to_rest(T2, a2), 0, line=line_segment(kin, p2, np.eye(4), T2, a2))
    ArmSimulator._join(first, second)
    return first.duration_s + second.duration_s, T3


@pytest.mark.parametrize("standoff_m, final_m, fast_pct, slow_pct, plunge_m", [
    (0.06, 0.01, 30, 10, 0.0), (0.05, 0.01, 30, 10, 0.003), (0.08, 0.02, 20, 5, 0.0), (0.04, 0.005, 50, 20, 0.0)])
def test_the_floor_of_the_sequenced_moves_is_what_the_simulator_takes_for_them(standoff_m, final_m, fast_pct, slow_pct,
                                                                               plunge_m):
    floor = stud_time_floor(WeldParams(standoff_m=standoff_m, final_approach_m=final_m, approach_speed_pct=fast_pct,
                                       linear_speed_pct=slow_pct, pulse_s=0.2, dwell_s=0.5, connected_approach=True,
                                       plunge_m=plunge_m))
    approach_s, retract_s = _simulated_moves(standoff_m, final_m, fast_pct, slow_pct, plunge_m)
    # the joints do not bind along a short vertical line here: the line's own time law, to rounding
    assert floor.approach_s == pytest.approx(approach_s, rel=2e-3)
    assert floor.retract_s == pytest.approx(retract_s, rel=2e-3)
    assert floor.weld_s == pytest.approx(0.7)


def test_the_cells_settings_leave_a_stud_at_least_two_seconds_whatever_the_planner_does():
    floor = stud_time_floor(CELL)
    # the driver's stops: 0.71 s retract (60 mm at 0.15 m/s, 0.48 m/s^2), ~0.94 s approach, 0.7 s weld
    assert floor.retract_s == pytest.approx(0.06 / 0.15 + 0.15 / 0.48)
    assert 2.2 < floor.as_sequenced_s < 2.5
    # one stop a stud, every corner blended at full speed: still about 2 s before any move between studs
    assert floor.blended_s < floor.as_sequenced_s
    assert 1.9 < floor.blended_s < 2.1


def test_the_blended_floor_is_never_below_the_distance_at_full_speed():
    rng = np.random.default_rng(3)
    for _ in range(300):
        standoff = rng.uniform(0.01, 0.2)
        final = rng.uniform(0.0, standoff)
        fast, slow = int(rng.integers(5, 101)), int(rng.integers(1, 101))
        floor = stud_time_floor(WeldParams(standoff_m=standoff, final_approach_m=final, approach_speed_pct=fast,
                                           linear_speed_pct=slow, pulse_s=0.0, dwell_s=0.0, connected_approach=True))
        v_f, v_s = 0.5 * fast / 100, 0.5 * slow / 100
        assert floor.blended_s >= (2 * standoff - final) / v_f + final / v_s - 1e-9
        assert floor.blended_s <= floor.as_sequenced_s + 1e-9


def test_a_stop_between_the_fast_and_the_slow_move_costs_time():
    joined = stud_time_floor(CELL)
    apart = stud_time_floor(dataclasses.replace(CELL, connected_approach=False))
    assert apart.approach_s > joined.approach_s + 0.1
    assert apart.retract_s == joined.retract_s and apart.blended_s == joined.blended_s


def test_the_rail_floor_is_the_travel_between_the_first_and_last_studs_ranges_in_one_move():
    from rm65_driver.rail.axis import RailAxis
    from rm65_sim.cycle_floor import rail_floor

    axis = RailAxis(length_m=7.0, pos_unit_m=1e-6, max_speed_m_s=0.5, accel_m_s2=0.5)
    ranges = [(0.2, 0.9), (0.3, 1.0), (5.6, 6.3), (5.7, 6.4)]  # two studs near each end of a 6 m part
    floor = rail_floor(ranges, axis, 30)
    assert floor.travel_m == pytest.approx(5.7 - 0.9)
    # 4.8 m at 30 %: 0.15 m/s, 0.15 m/s^2 -> 1 s up, 31 s cruise, 1 s down
    assert floor.move_s == pytest.approx(4.8 / 0.15 + 1.0)
    # split in two moves it takes longer: one move is the floor
    assert floor.move_s < axis.move_time_s(2.4, 30) * 2
    # studs all reachable from one carriage position: no travel
    assert rail_floor([(0.2, 0.9), (0.5, 1.2)], axis, 30).move_s == 0.0


def test_a_studs_carriage_range_is_where_the_reach_test_welds_it_from():
    from rm65_driver.weld.safety import SafetyChecker, SafetyLimits
    from rm65_sim.cycle_floor import carriage_range
    from stud_common.frames import world_T_base

    tool = np.eye(4)
    tool[2, 3] = 0.15
    limits = SafetyLimits(workspace_min_m=(-0.7, -0.7, -0.02), workspace_max_m=(7.7, 0.7, 1.1))
    reach = SafetyChecker(RM65Kinematics(), limits, tool, prefer_signs=(0, 0, -1, 0, -1, 0)).reach_for(0.06)
    mount, stud, up = (0.0, 0.0, 0.2), np.array([3.0, 0.3, 0.15]), np.array([0.0, 0.0, 1.0])
    lo, hi = carriage_range(reach, stud, up, mount, 7.0, step_m=0.02)
    assert 2.5 < lo < 3.0 < hi < 3.5  # the arm reaches a patch a few decimetres along the rail
    for c, ok in ((lo, True), (hi, True), (lo - 0.02, False), (hi + 0.02, False)):
        assert reach.stud(stud, up, world_T_base(c, mount)).ok == ok, c
    assert carriage_range(reach, np.array([3.0, 0.9, 0.15]), up, mount, 7.0, step_m=0.05) is None  # too far across
