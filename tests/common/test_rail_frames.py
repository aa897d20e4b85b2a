"""World -> carriage -> base: the believed rail is a translation along x; a deviated one follows its curve."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stud_common.frames import RailDeviation, carriage_in_world, true_world_correction, world_T_base


def test_without_a_rail_the_base_is_the_world():
    np.testing.assert_array_equal(world_T_base(0.0), np.eye(4))


@settings(max_examples=50, deadline=None)
@given(st.floats(0.0, 20.0), st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3))
def test_the_believed_base_is_the_carriage_position_along_x_plus_the_mount(c, mount):
    T = world_T_base(c, mount)
    np.testing.assert_array_equal(T[:3, :3], np.eye(3))
    np.testing.assert_allclose(T[:3, 3], np.array(mount) + [c, 0.0, 0.0], atol=1e-12)


def test_a_curved_rail_is_the_integral_of_its_heading():
    dev = RailDeviation(scale_ppm=-300.0, offset_m=0.01, yaw_urad_per_m=2000.0)  # exaggerated, to see the curve
    c = 6.0
    s = c * (1 - 300e-6) + 0.01
    u = np.linspace(0.0, s, 200_001)
    heading = 2000e-6 * u
    x, y = np.trapezoid(np.cos(heading), u), np.trapezoid(np.sin(heading), u)
    T = carriage_in_world(c, dev)
    np.testing.assert_allclose(T[:3, 3], [x, y, 0.0], atol=1e-9)
    assert math.atan2(T[1, 0], T[0, 0]) == pytest.approx(2000e-6 * s)


def test_a_tiny_curvature_is_continuous_with_none():
    a = carriage_in_world(4.0, RailDeviation(yaw_urad_per_m=1e-9))
    np.testing.assert_allclose(a, carriage_in_world(4.0), atol=1e-14)


def test_the_mount_turns_with_the_carriage():
    dev = RailDeviation(yaw_urad_per_m=100.0)
    T = world_T_base(3.0, (0.0, 0.5, 0.2), dev)
    C = carriage_in_world(3.0, dev)
    np.testing.assert_allclose(T[:3, 3], C[:3, 3] + C[:3, :3] @ [0.0, 0.5, 0.2], atol=1e-15)


@pytest.mark.parametrize("bad", [dict(scale_ppm=math.nan), dict(offset_m=math.inf)])
def test_a_non_finite_deviation_is_refused(bad):
    with pytest.raises(ValueError, match="not a finite number"):
        RailDeviation(**bad)
    with pytest.raises(ValueError, match="not 3 finite numbers"):
        world_T_base(1.0, (0.0, math.nan, 0.0))


def test_the_true_world_correction_moves_a_believed_pose_onto_the_deviated_rail():
    dev = RailDeviation(scale_ppm=500.0, offset_m=-0.003, yaw_urad_per_m=80.0)
    mount, c = (0.1, 0.05, 0.3), 4.2
    pose_in_base = np.eye(4)
    pose_in_base[:3, 3] = [0.3, -0.1, 0.05]
    believed = world_T_base(c, mount) @ pose_in_base
    np.testing.assert_allclose(true_world_correction(c, dev) @ believed, world_T_base(c, mount, dev) @ pose_in_base,
                               atol=1e-12)
    np.testing.assert_array_equal(true_world_correction(c, RailDeviation()), np.eye(4))
