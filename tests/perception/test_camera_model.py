"""The camera model: Eq. 1 both ways, its window form, and the checks on K and R."""
from __future__ import annotations

import numpy as np
import pytest

from stud_common.rotations import rpy_to_matrix
from stud_perception.camera_model import CameraModel, CameraModelError

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


def test_the_derived_forms_of_eq1_are_eq1(cam):
    """One pixel in plain floats, the ray linear in the pixel, a vertical line's pixel projective in its
    height, and pixels per metre: each what Eq. 1 itself gives."""
    rng = np.random.default_rng(5)
    u, v, z = rng.uniform(0, 1279, 40), rng.uniform(0, 959, 40), rng.uniform(0.3, 0.9, 40)
    P = cam.pixel_to_world(u, v, z)
    one = np.array([cam.pixel_to_world_one(float(a), float(b), float(c)) for a, b, c in zip(u, v, z)])
    np.testing.assert_array_equal(one, P)  # the same operations: the same values, to the bit
    base, per_u, per_v = cam.ray_basis_world()
    rays = base + u[:, None] * per_u + v[:, None] * per_v
    np.testing.assert_allclose(rays, cam.ray_directions_world(u, v), rtol=0, atol=1e-12)
    np.testing.assert_allclose(cam.t_wc + z[:, None] * rays, P, rtol=0, atol=1e-12)

    xy = P[:, :2]
    lines = cam.vertical_lines(xy)
    heights = P[:, 2] + rng.uniform(-0.05, 0.05, 40)
    lu, lv = lines.pixels_at(np.arange(40), heights)
    wu, wv, _ = cam.world_to_pixel(np.column_stack([xy, heights]))
    np.testing.assert_allclose(np.column_stack([lu, lv]), np.column_stack([wu, wv]), rtol=0, atol=1e-8)
    assert [lines.pixel_at_one(i, float(h)) for i, h in enumerate(heights)] == list(zip(lu.tolist(), lv.tolist()))
    lo, hi = cam.lines_in_view(lines, -1.0, 1.0)
    assert np.all((lo <= P[:, 2]) & (P[:, 2] <= hi))  # every line passes a pixel of the image at its point

    depth = rng.uniform(0.3, 0.9, 5)
    across = cam.pixels_across(0.02, depth)
    centre = np.column_stack([np.zeros(5), np.zeros(5), depth])  # on the optical axis, square to it
    ends = cam.R_wc @ np.array([0.02, 0.0, 0.0]) + (centre @ cam.R_wc.T + cam.t_wc)
    du = cam.world_to_pixel(ends)[0] - cam.world_to_pixel(centre @ cam.R_wc.T + cam.t_wc)[0]
    np.testing.assert_allclose(across, du, rtol=1e-12)
