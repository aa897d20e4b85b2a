"""Planning with the arm driver's reach test: camera stations moved (higher, lower, slid, turned) or split
until the driver accepts them, the board searched for from reachable poses, and the bound that names a
stud before any shot never names one the driver would weld."""
from __future__ import annotations

import math

import numpy as np
import pytest

from rm65_driver.weld.reach import Reach, ReachConfig
from stud_cell.board_search import ARM_TABLE_XY_M, BoardSearchError, board_radius_m, search_area, search_plan
from stud_cell.cell_reach import CellReach, camera_pose_as_sent
from stud_cell.station_reach import StationGeometry, candidate_poses, reachable_stations
from stud_cell.stations import footprint_m, plan_stations

HAND_EYE = np.eye(4)
HAND_EYE[:3, 3] = (0.05, 0.0, -0.10)   # cell.yaml's
REACH = CellReach(Reach(ReachConfig(standoff_m=0.06, preferred_joint_signs=(0, 0, -1, 0, -1, 0),
                                    hand_eye_T=tuple(HAND_EYE.ravel()))))
GEOM = StationGeometry(0.46, 0.5, 0.75, part_height_m=0.15, camera_height_m=0.40, plane_z_m=0.005)
MARKS = np.array([[0.0, 0.0], [0.13, 0.0], [0.0, 0.10]])


def cameras_ok(poses):
    return [v.ok for v in REACH.cameras(poses)]


def _inside_inner_footprint(xyz, yaw, members_xy, geom) -> bool:
    half = geom.inner_half(xyz[2] - geom.plane_z_m) + 1e-6
    c, s = math.cos(yaw), math.sin(yaw)
    local = (np.asarray(members_xy) - np.asarray(xyz[:2])) @ np.array([[c, -s], [s, c]])
    return bool(np.all(np.abs(local) <= half))


def test_every_candidate_pose_holds_all_its_studs_and_the_nominal_one_comes_first():
    members = np.array([[0.40, 0.02], [0.44, -0.03], [0.47, 0.05]])
    nominal = np.array([0.43, 0.01])
    poses = candidate_poses(members, nominal, 0.0, GEOM)
    assert len(poses) > 10
    np.testing.assert_allclose(poses[0][0], [0.43, 0.01, 0.405])
    assert all(_inside_inner_footprint(xyz, yaw, members, GEOM) for xyz, yaw in poses)
    assert {round(xyz[2] - 0.005, 3) for xyz, _ in poses} <= {0.40, 0.45, 0.35, 0.50}
    assert {round(yaw % (2 * math.pi), 3) for _, yaw in poses} >= {0.0, round(math.pi, 3)}


def test_stations_the_arm_cannot_reach_are_moved_or_split_until_it_can_and_none_is_lost():
    # studs across the far edge of the RM-65's reach: the grid's nominal stations there are out of reach
    rng = np.random.default_rng(3)
    xy = rng.uniform((0.30, -0.12), (0.52, 0.12), (14, 2))
    fov = footprint_m(0.46, 0.5, 0.75, 0.40, 0.15)
    plan = plan_stations(xy, fov, 0.40, plane_z_m=0.005)
    nominal_ok = cameras_ok([(np.asarray(s.camera_xyz_w), s.yaw_rad) for s in plan.stations])
    assert not all(nominal_ok)
    placed, reasons = reachable_stations(plan, xy, GEOM, cameras_ok)
    assert all(cameras_ok([(np.asarray(s.camera_xyz_w), s.yaw_rad) for s in placed.stations]))
    seen = [i for s in placed.stations for i in s.stud_indices]
    assert sorted(seen + list(placed.unreachable)) == list(range(len(xy))) and len(set(seen)) == len(seen)
    for s in placed.stations:
        assert _inside_inner_footprint(s.camera_xyz_w, s.yaw_rad, xy[list(s.stud_indices)], GEOM)
    assert set(reasons) == set(placed.unreachable)
    assert all("no camera pose the arm reaches sees it" in why for why in reasons.values())
    assert len(seen) > len(xy) // 2


def test_a_stud_no_reachable_camera_sees_is_reported_with_the_reason():
    xy = np.array([[0.30, 0.0], [0.95, 0.0]])
    plan = plan_stations(xy, footprint_m(0.46, 0.5, 0.75, 0.40, 0.15), 0.40, plane_z_m=0.005)
    placed, reasons = reachable_stations(plan, xy, GEOM, cameras_ok)
    assert placed.unreachable == (1,) and [i for s in placed.stations for i in s.stud_indices] == [0]
    assert reasons[1].startswith("no camera pose the arm reaches sees it (")


def test_the_board_search_starts_at_the_highest_reachable_view_and_only_sends_reachable_poses():
    r = board_radius_m(MARKS, 0.02)
    assert r == pytest.approx(math.hypot(0.13, 0.10) / 2 + 0.01 + 0.005)   # a right triangle: AB is the diameter
    plan = search_plan((0.0, -0.55, 0.65, 0.55), 0.0, (0.45, 0.425, 0.40, 0.375, 0.35, 0.325, 0.30, 0.275),
                       0.46, 0.5, 0.75, r, cameras_ok, 12)
    assert 3 <= len(plan.poses) <= 12 and 0 < plan.covered < 1
    heights = [xyz[2] for xyz, _ in plan.poses]
    assert heights[0] == max(heights)
    assert all(cameras_ok([(np.asarray(xyz), yaw) for xyz, yaw in plan.poses]))
    assert "search pose(s) over x 0.00..0.65 m, y -0.55..0.55 m" in plan.describe()
    with pytest.raises(BoardSearchError, match=r"board_search_area_xy_m=\[0.5, 0.0, 0.2, 1.0\]"):
        search_plan((0.5, 0.0, 0.2, 1.0), 0.0, (0.4,), 0.46, 0.5, 0.75, r, cameras_ok, 5)


def test_without_a_search_area_the_arms_table_is_searched_stretched_along_the_rails_travel():
    assert search_area((), 16) == (ARM_TABLE_XY_M, 16)   # a fixed arm: its own table
    area, shots = search_area([], 16, rail_length_m=2.5)
    assert area == (0.0, -0.55, 3.15, 0.55) and shots == math.ceil(16 * 3.15 / 0.65)
    assert search_area((1.2, -0.6, 1.9, -0.1), 16, rail_length_m=2.5) == ((1.2, -0.6, 1.9, -0.1), 16)   # given: as is


def test_the_camera_pose_checked_is_the_one_the_driver_reads_from_the_move_request():
    T = camera_pose_as_sent((0.225, -0.29, 0.285), 0.3)
    assert np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3)) and T[2, 2] == pytest.approx(-1.0)
    assert REACH.camera_ok((0.225, -0.29, 0.285)) and not REACH.camera_ok((0.9, 0.0, 0.4))


def test_the_bound_before_any_shot_never_names_a_stud_the_driver_would_weld():
    """Studs drawn around the arm's reach edge, with heights and normals the bound does not know: every
    stud the bound names is refused by the driver's verdict for every height and normal tried."""
    rng = np.random.default_rng(11)
    r, a = rng.uniform(0.45, 0.95, 120), rng.uniform(-math.pi, math.pi, 120)   # around the reach's edge
    xy = np.column_stack([r * np.cos(a), r * np.sin(a)])
    named = REACH.surely_unreachable(xy, (0.0, 0.15))
    assert 20 < sum(bool(w) for w in named) < len(xy) - 20
    for (x, y), why in zip(xy, named):
        if why:
            assert why.startswith(("approach pose out of reach at any height", "contact pose leaves the workspace box"))
            tilt, az = math.radians(rng.uniform(0, 60)), rng.uniform(-math.pi, math.pi)
            n = [math.sin(tilt) * math.cos(az), math.sin(tilt) * math.sin(az), math.cos(tilt)]
            assert not REACH.stud([x, y, rng.uniform(0.0, 0.15)], n).ok
    # a stud the gun reaches (leaning toward the arm, on top of the part) is never named
    weldable = 0
    for (x, y), why in zip(xy, named):
        if np.hypot(x, y) < 0.62:
            az = math.atan2(-y, -x)
            n = [math.sin(0.6) * math.cos(az), math.sin(0.6) * math.sin(az), math.cos(0.6)]
            if REACH.stud([x, y, 0.15], n).ok:
                weldable += 1
                assert not why
    assert weldable > 3
