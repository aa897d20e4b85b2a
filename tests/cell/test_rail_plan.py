"""Carriage positions along the rail (stud_cell.rail_plan), with the arm driver's own reach test: every
station reached from its stop (the exact test at that carriage position), the fewest stops, visited in
one direction, a station no carriage position reaches named with its studs; the bands searched in the
base frame agree with the exact test at the carriage positions they stand for."""
from __future__ import annotations

import math

import numpy as np
import pytest

from rm65_driver.weld.reach import Reach, ReachConfig
from stud_cell.job import JobConfig
from stud_cell.rail_plan import Rail, RailPlanConfig, RailPlanError, RailReach, intersect, plan_rail
from stud_cell.stations import Station, footprint_m, plan_stations
from stud_perception.scene import girder_scene

HAND_EYE = np.eye(4)
HAND_EYE[:3, 3] = (0.05, 0.0, -0.10)
SIGNS = (0, 0, -1, 0, -1, 0)


def reach_for(rail_length_m: float) -> Reach:
    """The cell's reach test, its workspace box spanning the rail (as cell.yaml asks on a rail)."""
    return Reach(ReachConfig(standoff_m=0.06, preferred_joint_signs=SIGNS, hand_eye_T=tuple(HAND_EYE.ravel()),
                             workspace_min_m=(-0.70, -0.70, -0.02), workspace_max_m=(rail_length_m + 0.70, 0.70, 1.10)))


def girder_stations(length_m=6.0):
    """The issue's girder (girder_scene: rows of 3 studs every 0.2 m along x) and the job's stations over it."""
    xy = girder_scene(length_m=length_m).studs_world_xy_m
    c = JobConfig()
    fov = footprint_m(c.fov_width_m, c.fov_distance_m, c.image_aspect, c.camera_height_m, c.part_height_m)
    return xy, plan_stations(xy, fov, c.camera_height_m, overlap=c.overlap, plane_z_m=0.0, fewest=True).stations


@pytest.fixture(scope="module")
def girder_plan():
    xy, stations = girder_stations()
    rail_reach = RailReach(reach_for(6.0), Rail(6.0))
    plan = plan_rail(stations, xy, rail_reach, prior_z_m=0.15, start_m=0.0)
    print(f"\n6 m girder: {len(xy)} studs, {len(stations)} stations -> {len(plan.stops)} carriage positions, "
          f"planned in {plan.planning_s:.1f} s ({plan.reach_checks} reach checks)")
    return xy, stations, rail_reach, plan


def test_a_6_m_girder_gets_carriage_positions_in_one_direction_each_station_reached_from_its_own(girder_plan):
    xy, stations, rail_reach, plan = girder_plan
    assert not plan.unreachable and sorted(s.stud_indices for s in plan.stations) == sorted(s.stud_indices
                                                                                          for s in stations)
    positions = [s.position_m for s in plan.stops]
    assert positions == sorted(positions) and len(set(positions)) == len(positions)   # forward only, never back
    assert all(0.0 <= p <= 6.0 for p in positions)
    for stop in plan.stops:   # the exact test, with the base where the driver will have it
        exact = rail_reach.at(stop.position_m).cameras([(s.camera_xyz_w, s.yaw_rad) for s in stop.stations])
        assert all(v.ok for v in exact), (stop.index, [v.reason for v in exact])
        assert stop.window_m[0] <= stop.position_m <= stop.window_m[1]
    # the stations numbered in the order they are worked
    assert [s.index for s in plan.stations] == list(range(1, len(stations) + 1))
    # a stop's stations column by column along the rail, serpentine across
    for stop in plan.stops:
        xs = [s.camera_xyz_w[0] for s in stop.stations]
        assert xs == sorted(xs)


def test_the_stops_are_the_fewest_the_stations_reach_allows(girder_plan):
    """Interval stabbing is optimal: the stations that closed each stop (their interval ends there) are
    reached from pairwise disjoint carriage ranges, so no plan has fewer stops than there are of them."""
    xy, stations, rail_reach, plan = girder_plan
    by_index = {s.stud_indices: s for s in stations}
    intervals = {}
    for stop in plan.stops:
        for st in stop.stations:
            orig = by_index[st.stud_indices]
            cam = rail_reach.camera_intervals([(orig.camera_xyz_w, orig.yaw_rad)])[0]
            prior = (0.0, 6.0),
            for j in orig.stud_indices:
                prior = intersect(prior, rail_reach.stud_prior_intervals(xy[[j]], 0.15)[0])
            intervals[st.index] = intersect(cam, prior) or cam
    closers = []
    for stop in plan.stops:   # the station whose reach ends first among the stop's: it fixed the stop
        closers.append(min(stop.stations, key=lambda st: max(hi for lo, hi in intervals[st.index]
                                                             if lo <= stop.window_m[1] + 1e-9)))
    for a, b in zip(closers, closers[1:]):
        assert not intersect(intervals[a.index], intervals[b.index]), (a.index, b.index)
    assert len(plan.stops) <= math.ceil(6.4 / 0.45)   # the RM-65's camera band is about half a metre wide


def test_a_station_no_carriage_position_reaches_is_named_with_its_studs_and_the_rest_planned():
    xy = np.array([[0.6, 0.0], [0.8, 0.0], [1.0, 1.5]])   # the last 1.5 m beside the rail
    stations = [Station(1, (0.6, 0.0, 0.40), 0.0, (0,)), Station(2, (0.8, 0.0, 0.40), 0.0, (1,)),
                Station(3, (1.0, 1.5, 0.40), 0.0, (2,))]
    plan = plan_rail(stations, xy, RailReach(reach_for(2.0), Rail(2.0)), prior_z_m=0.15, start_m=0.0)
    assert set(plan.unreachable) == {3} and "no carriage position along the rail 0..2 m" in plan.unreachable[3]
    assert set(plan.unreachable_studs) == {2} and "[1.0, 1.5, 0.4]" in plan.unreachable_studs[2]
    assert sorted(i for s in plan.stations for i in s.stud_indices) == [0, 1]
    assert len(plan.stops) == 1   # 0.2 m apart: one carriage position reaches both


def test_the_stops_start_at_the_end_nearer_the_carriage_and_go_one_way():
    xy, stations = girder_stations(length_m=2.0)
    rail_reach = RailReach(reach_for(2.5), Rail(2.5))
    forward = plan_rail(stations, xy, rail_reach, prior_z_m=0.15, start_m=0.0)
    backward = plan_rail(stations, xy, rail_reach, prior_z_m=0.15, start_m=2.5)
    assert len(forward.stops) == len(backward.stops) >= 2
    assert [s.position_m for s in backward.stops] == [s.position_m for s in reversed(forward.stops)]
    for stop in backward.stops:
        xs = [s.camera_xyz_w[0] for s in stop.stations]
        assert xs == sorted(xs, reverse=True)


def test_the_base_frame_bands_agree_with_the_exact_test_at_the_carriage_positions():
    """The searched band says where a pose is reached from; the exact test with the base at a carriage
    position inside it accepts the pose, and one clearly outside it refuses."""
    rail_reach = RailReach(reach_for(3.0), Rail(3.0, (0.0, 0.0, 0.05)), RailPlanConfig(coarse_step_m=0.05))
    for pose in [((1.5, 0.1, 0.40), 0.0), ((1.5, -0.2, 0.35), math.pi), ((2.9, 0.0, 0.40), 0.0)]:
        intervals = rail_reach.camera_intervals([pose])[0]
        assert intervals
        for lo, hi in intervals:
            for c in (lo, (lo + hi) / 2, hi):
                assert rail_reach.at(c).camera_ok(*pose), (pose, c)
        outside = [c for c in np.arange(0.0, 3.0, 0.05) if all(c < lo - 0.03 or c > hi + 0.03 for lo, hi in intervals)]
        assert outside and not any(rail_reach.at(c).camera_ok(*pose) for c in outside), pose


def test_bad_rail_settings_are_one_line_errors():
    with pytest.raises(RailPlanError, match="rail_length_m=0.0: expected a rail longer than 0 m"):
        Rail(0.0)
    with pytest.raises(RailPlanError, match="rail_mount_xyz_m"):
        Rail(2.0, (0.0, math.nan, 0.0))
    with pytest.raises(RailPlanError, match="tolerance_m=0.1"):
        RailPlanConfig(coarse_step_m=0.05, tolerance_m=0.1)
