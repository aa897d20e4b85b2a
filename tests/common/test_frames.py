"""The drawing frame in world from a registration: a rigid transform that maps drawing points as Eq. 2 does."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stud_common.frames import drawing_in_world


@settings(max_examples=100, deadline=None)
@given(st.floats(-math.pi, math.pi), st.floats(-1, 1), st.floats(-1, 1), st.floats(-0.2, 0.5),
       st.floats(-0.5, 0.5), st.floats(-0.5, 0.5))
def test_drawing_frame_maps_drawing_points_like_the_registration(yaw, tx, ty, z, x, y):
    c, s = math.cos(yaw), math.sin(yaw)
    M = np.array([[c, -s, tx], [s, c, ty], [0.0, 0.0, 1.0]])
    T = drawing_in_world(M, z)
    np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-12)
    world = T @ np.array([x, y, 0.0, 1.0])
    np.testing.assert_allclose(world[:2], (M @ np.array([x, y, 1.0]))[:2], atol=1e-12)
    assert world[2] == pytest.approx(z)


def test_a_slightly_sheared_fit_becomes_the_nearest_rotation():
    M = np.array([[1.0, -0.002, 0.1], [0.0, 1.0, 0.2], [0.0, 0.0, 1.0]])  # OA and OB 0.1 deg off square
    T = drawing_in_world(M, 0.0)
    assert math.degrees(math.atan2(T[1, 0], T[0, 0])) == pytest.approx(math.degrees(0.001), abs=1e-6)
    with pytest.raises(ValueError, match="non-finite"):
        drawing_in_world(np.full((3, 3), np.nan), 0.0)
