"""The calibration's views: all look at the board centre from the set distance, start straight down, and
spread the camera's orientation about three axes; bad settings are named."""
from __future__ import annotations

import numpy as np
import pytest

from stud_cell.hand_eye_views import ViewPlanError, plan_calibration_views, plan_check_views, station_view
from stud_perception.hand_eye import rotation_spread_deg

TARGET = np.array([0.367, -0.158, 0.005])


@pytest.mark.parametrize("views", [plan_calibration_views(TARGET), plan_check_views(TARGET)])
def test_every_view_looks_at_the_target_from_the_distance(views):
    for v in views:
        axis = v.R_world_cam[:, 2]  # optical z
        to_target = TARGET - v.t_world_cam
        assert np.linalg.norm(to_target) == pytest.approx(0.30)
        assert np.linalg.norm(np.cross(axis, to_target / np.linalg.norm(to_target))) < 1e-9 and axis @ to_target > 0
        assert np.degrees(np.arccos(-axis[2])) == pytest.approx(v.tilt_deg, abs=1e-6)
    assert views[0].tilt_deg == 0.0 and views[0].yaw_deg == 0.0


def test_calibration_views_spread_about_three_axes():
    views = plan_calibration_views(TARGET)
    assert len(views) == 3 + 3 * 12
    spread = rotation_spread_deg(np.stack([v.R_world_cam for v in views]))
    assert spread[2] >= 45.0, spread
    assert len({(v.tilt_deg, round(v.azimuth_deg, 6)) for v in views[3:]}) == 36


def test_station_view_is_straight_down_from_the_station():
    v = station_view([0.345, -0.175, 0.28])
    assert np.allclose(v.t_world_cam, [0.345, -0.175, 0.28])
    assert np.allclose(v.R_world_cam[:, 2], [0.0, 0.0, -1.0]) and np.allclose(v.R_world_cam[:, 0], [1.0, 0.0, 0.0])


@pytest.mark.parametrize("kwargs, message", [
    ({"distance_m": 0.01}, "distance_m must be within 0.05..2.0 m, got 0.01"),
    ({"tilts_deg": (10.0, 75.0)}, "tilts_deg must be within (0, 60] deg, got [10.0, 75.0]"),
    ({"views_per_tilt": 0}, "views per tilt must be at least 1, got 0"),
    ({"yaw_span_deg": 120.0}, "yaw_span_deg must be within 0..90 deg, got 120.0"),
])
def test_bad_settings_are_named(kwargs, message):
    with pytest.raises(ViewPlanError) as info:
        plan_calibration_views(TARGET, **kwargs)
    assert message in str(info.value)
