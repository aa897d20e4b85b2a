"""The camera model: Eq. 1 both ways, its window form, and the checks on K and R."""
from __future__ import annotations

import numpy as np
import pytest

from stud_perception.camera_model import CameraModel, CameraModelError
from stud_common.rotations import rpy_to_matrix

# A camera tilted and rolled away from nadir, with unequal focal lengths and an off-centre
# principal point: every term of Eq. 1 matters.
K = np.array([[905.0, 0.0, 652.3], [0.0, 898.5, 471.9], [0.0, 0.0, 1.0]])
R = rpy_to_matrix(np.radians(172.0), np.radians(-9.0), np.radians(33.0))
T = np.array([0.41, -0.12, 0.63])


@pytest.fixture()
def cam() -> CameraModel:
    return CameraModel(K=K, width=1280, height=960, R_wc=R, t_wc=T)


def test_eq1_matches_the_formula_and_round_trips(cam):
    rng = np.random.default_rng(3)
    u, v = rng.uniform(0, 1279, 50), rng.uniform(0, 959, 50)
    z = rng.uniform(0.3, 0.9, 50)
    P = cam.pixel_to_world(u, v, z)
    expected = (R @ (z * (np.linalg.inv(K) @ np.vstack([u, v, np.ones_like(u)])))).T + T
    np.testing.assert_allclose(P, expected, atol=1e-12)
    u2, v2, z2 = cam.world_to_pixel(P)
    np.testing.assert_allclose(np.column_stack([u2, v2, z2]), np.column_stack([u, v, z]), atol=1e-9)


def test_window_form_equals_eq1_per_pixel(cam):
    rng = np.random.default_rng(4)
    u0, v0 = rng.integers(20, 1260, 7), rng.integers(20, 940, 7)
    du, dv = rng.integers(-15, 16, (7, 30)), rng.integers(-15, 16, (7, 30))
    z = rng.uniform(0.3, 0.9, (7, 30))
    stud = rng.uniform(-0.2, 0.2, (7, 3))
    got = cam.window_to_world(u0, v0, du, dv, z)
    assert got.shape == (3, 7, 30)
    full = cam.pixel_to_world(u0[:, None] + du, v0[:, None] + dv, z)
    np.testing.assert_allclose(np.moveaxis(got, 0, -1), full, atol=1e-12)
    rel = cam.window_to_world(u0, v0, du, dv, z, minus_w=stud)
    np.testing.assert_allclose(np.moveaxis(rel, 0, -1), full - stud[:, None, :], atol=1e-12)
    out = np.empty((7, 3, 30)).transpose(1, 0, 2)  # written in place into a strided view
    assert cam.window_to_world(u0, v0, du, dv, z, out=out) is out
    np.testing.assert_allclose(out, got, atol=0)


@pytest.mark.parametrize("bad, match", [
    (dict(K=np.diag([0.0, 900.0, 1.0])), "non-positive focal length"),
    (dict(width=0), "must be positive"),
    (dict(R_wc=np.diag([1.0, 1.0, -1.0])), "not a proper rotation"),
    (dict(R_wc=2 * np.eye(3)), "not a proper rotation"),
])
def test_unusable_intrinsics_or_pose_are_rejected_with_the_value(bad, match):
    args = dict(K=K, width=1280, height=960, R_wc=R, t_wc=T) | bad
    with pytest.raises(CameraModelError, match=match):
        CameraModel(**args)
