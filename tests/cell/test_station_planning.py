"""Camera stations: every stud covered once, inside the footprint's inner part, at the right height."""
from __future__ import annotations

import math

import numpy as np
import pytest

from stud_cell.stations import StationPlanningError, footprint_m, plan_stations
from stud_perception.camera_model import CameraModel, nadir_rotation

#: The camera the footprint stands for: 640x480 (aspect 0.75), spanning 0.46 m at 0.5 m.
CAMERA = CameraModel.from_fov(640, 480, 0.46, 0.5)


def _in_footprint(station, xy: np.ndarray, fov, overlap: float) -> np.ndarray:
    c, s = math.cos(station.yaw_rad), math.sin(station.yaw_rad)
    local = (xy - np.asarray(station.camera_xyz_w[:2])) @ np.array([[c, -s], [s, c]])
    half = np.asarray(fov) * (1.0 - overlap) / 2 + 1e-9
    return np.all(np.abs(local) <= half, axis=1)


def _inner_part_of_image(station, xyz_w: np.ndarray, overlap: float) -> np.ndarray:
    """Each point projected by the camera model from the station (nadir, the station's yaw) lies
    in the inner part of the image (``overlap`` of it left at the border): the reference is the
    camera, not footprint_m, the function under test."""
    cam = CAMERA.with_pose(nadir_rotation(station.yaw_rad), np.asarray(station.camera_xyz_w, dtype=float))
    u, v, z = cam.world_to_pixel(xyz_w)
    half = (1.0 - overlap) * np.array([cam.width, cam.height]) / 2 * (1 + 1e-9)
    return (z > 0) & (np.abs(u - cam.cx) <= half[0]) & (np.abs(v - cam.cy) <= half[1])


@pytest.mark.parametrize("yaw_deg", [0.0, 35.0, -90.0])
@pytest.mark.parametrize("plane_z_m", [0.0, -0.62])
def test_every_stud_is_assigned_once_to_a_station_that_sees_it(yaw_deg, plane_z_m):
    rng = np.random.default_rng(5)
    xy = rng.uniform((-0.2, 0.1), (0.55, 0.4), (300, 2))
    fov = footprint_m(0.46, 0.5, 0.75, 0.3, 0.05)
    plan = plan_stations(xy, fov, 0.3, overlap=0.15, yaw_rad=math.radians(yaw_deg), plane_z_m=plane_z_m)
    assigned = np.concatenate([s.stud_indices for s in plan.stations])
    assert sorted(assigned.tolist()) == list(range(len(xy))) and plan.unreachable == ()
    part_top_w = plane_z_m + 0.05  # footprint_m(..., part_height_m=0.05): the studs stand on the part's top
    for st in plan.stations:
        assert _in_footprint(st, xy[list(st.stud_indices)], fov, 0.15).all()
        mine = np.column_stack([xy[list(st.stud_indices)], np.full(len(st.stud_indices), part_top_w)])
        assert _inner_part_of_image(st, mine, 0.15).all(), st.index
        # the world is the arm's base frame: the camera stands camera_height_m above the plane
        assert st.camera_xyz_w[2] == pytest.approx(plane_z_m + 0.3)


def test_unreachable_stations_report_their_studs():
    xy = np.array([[0.0, 0.0], [0.01, 0.0], [1.0, 0.0]])
    plan = plan_stations(xy, (0.2, 0.15), 0.3, camera_reachable=lambda p: p[0] < 0.5)
    assert plan.unreachable == (2,) and plan.covered == 2


@pytest.mark.parametrize("kwargs, match", [
    (dict(overlap=0.95), "overlap=0.95"),
    (dict(camera_height_m=0.0), "must be positive"),
])
def test_bad_settings_are_named(kwargs, match):
    args = dict(studs_xy_w=np.zeros((1, 2)), fov_m=(0.2, 0.15), camera_height_m=0.3) | kwargs
    with pytest.raises(StationPlanningError, match=match):
        plan_stations(**args)
    with pytest.raises(StationPlanningError, match="not above the part top"):
        footprint_m(0.46, 0.5, 0.75, 0.05, 0.05)


def test_a_reshoot_station_sees_the_stud_from_a_new_direction_each_attempt():
    from stud_cell.stations import reshoot_station

    stud = np.array([0.30, -0.05])
    seen = []
    for attempt in range(4):
        st = reshoot_station(stud, attempt, 0.08, 0.30, plane_z_m=0.005, stud_index=7)
        offset = np.asarray(st.camera_xyz_w[:2]) - stud
        assert np.linalg.norm(offset) == pytest.approx(0.08)
        assert st.camera_xyz_w[2] == pytest.approx(0.305) and st.stud_indices == (7,)
        seen.append(np.arctan2(offset[1], offset[0]))
    # four different sides of the stud, 90 deg apart: the viewing direction changes every time
    gaps = np.diff(np.unwrap(seen))
    np.testing.assert_allclose(gaps, np.radians(90.0))


def test_a_cluster_astride_the_grid_border_takes_one_station_not_two():
    # 0.2 x 0.15 m footprint, no overlap: the grid tiles the 0.41 m span with three tiles from -0.095 m,
    # which cut the cluster 0..0.2 m in two; two footprints placed freely see everything.
    xy = np.array([[0.0, 0.0], [0.1, 0.02], [0.2, 0.0], [0.31, 0.01], [0.41, 0.0]])
    grid = plan_stations(xy, (0.2, 0.15), 0.3, overlap=0.0, fewest=False)
    few = plan_stations(xy, (0.2, 0.15), 0.3, overlap=0.0, fewest=True)
    assert len(few.stations) < len(grid.stations)
    assigned = sorted(i for s in few.stations for i in s.stud_indices)
    assert assigned == list(range(len(xy))) and few.unreachable == ()
    for st in few.stations:
        assert _in_footprint(st, xy[list(st.stud_indices)], (0.2, 0.15), 0.0).all()


@pytest.mark.parametrize("seed", range(6))
def test_fewest_never_needs_more_stations_than_the_grid_and_each_stud_is_seen(seed):
    rng = np.random.default_rng(seed)
    xy = rng.uniform((-0.2, 0.1), (0.4, 0.4), (int(rng.integers(5, 60)), 2))
    fov = footprint_m(0.46, 0.5, 0.75, 0.3, 0.05)
    grid = plan_stations(xy, fov, 0.3, overlap=0.15, yaw_rad=0.3, fewest=False)
    few = plan_stations(xy, fov, 0.3, overlap=0.15, yaw_rad=0.3, fewest=True)
    assert len(few.stations) <= len(grid.stations)
    assert sorted(i for s in few.stations for i in s.stud_indices) == list(range(len(xy)))
    for st in few.stations:
        assert _in_footprint(st, xy[list(st.stud_indices)], fov, 0.15).all()


def test_fewest_skips_a_placement_the_arm_cannot_reach_and_reports_what_nothing_covers():
    xy = np.array([[0.0, 0.0], [0.19, 0.0], [0.5, 0.0], [0.69, 0.0], [2.0, 0.0]])
    plan = plan_stations(xy, (0.2, 0.15), 0.3, overlap=0.0, camera_reachable=lambda p: p[0] < 1.0,
                         fewest=True)
    assert plan.unreachable == (4,) and plan.covered == 4
