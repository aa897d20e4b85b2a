"""Drawing -> world registration: Eq. 3 from three marks, rigid least squares, refusals."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stud_perception.registration import (
    RegistrationError,
    fit_rigid_2d,
    local_to_world,
    registration_from_marks,
    world_to_local,
)

DRAWING = np.array([[0.0, 0.0], [0.13, 0.0], [0.0, 0.10]])


def _pose(yaw_rad, tx, ty):
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return np.array([[c, -s, tx], [s, c, ty], [0.0, 0.0, 1.0]])


@settings(max_examples=25, deadline=None)
@given(
    yaw=st.floats(-math.pi, math.pi),
    tx=st.floats(-1.0, 1.0),
    ty=st.floats(-1.0, 1.0),
    method=st.sampled_from(["eq3", "least_squares"]),
)
def test_registration_recovers_a_known_transform_exactly(yaw, tx, ty, method):
    M_true = _pose(yaw, tx, ty)
    world = local_to_world(M_true, DRAWING)
    reg = registration_from_marks(*np.column_stack([world, np.full(3, 0.005)]), drawing_marks=DRAWING, method=method)
    np.testing.assert_allclose(reg.M_local2world, M_true, atol=1e-12)
    assert reg.residual_m < 1e-12
    assert reg.angle_AOB_deg == pytest.approx(90.0)
    np.testing.assert_allclose(reg.distance_errors_m, 0.0, atol=1e-12)
    assert math.isclose(math.cos(reg.yaw_rad - yaw), 1.0, abs_tol=1e-12)


def test_without_a_drawing_the_frame_is_o_x_toward_a_y_toward_b():
    O, A, B = np.array([0.2, 0.1]), np.array([0.2, 0.25]), np.array([0.08, 0.1])
    reg = registration_from_marks(O, A, B)
    np.testing.assert_allclose(reg.M_local2world, _pose(math.pi / 2, 0.2, 0.1), atol=1e-12)
    np.testing.assert_allclose(reg.marks_drawing_m, [[0, 0], [0.15, 0], [0, 0.12]], atol=1e-12)
    assert np.isnan(reg.distance_errors_m).all()


def test_eq3_shares_a_non_perpendicular_error_between_both_axes():
    # B measured 1 deg off perpendicular: the closest rotation turns the frame by half of it,
    # where a Gram-Schmidt on OA would keep the whole degree in the y axis.
    off = math.radians(1.0)
    O, A, B = np.zeros(2), np.array([0.13, 0.0]), 0.10 * np.array([-math.sin(off), math.cos(off)])
    reg = registration_from_marks(O, A, B, drawing_marks=DRAWING)
    assert math.degrees(reg.yaw_rad) == pytest.approx(0.5, abs=1e-9)
    np.testing.assert_allclose(reg.M_local2world[:2, :2] @ reg.M_local2world[:2, :2].T, np.eye(2), atol=1e-12)
    assert reg.residual_m > 0 and reg.angle_AOB_deg == pytest.approx(91.0)


def test_drawing_marks_anywhere_in_the_drawing_frame():
    D = local_to_world(_pose(0.7, 0.5, -0.3), DRAWING)  # a drawing whose O is not its origin
    M_true = _pose(-2.0, 0.1, 0.4)
    reg = registration_from_marks(*local_to_world(M_true, D), drawing_marks=D)
    np.testing.assert_allclose(reg.M_local2world, M_true, atol=1e-12)


def test_noisy_marks_give_a_residual_and_a_close_transform():
    rng = np.random.default_rng(1)
    M_true = _pose(0.3, 0.2, -0.1)
    world = local_to_world(M_true, DRAWING) + rng.normal(0, 0.0003, (3, 2))
    for method in ("eq3", "least_squares"):
        reg = registration_from_marks(*world, drawing_marks=DRAWING, method=method)
        assert 0 < reg.residual_m < 0.001
        assert np.abs(reg.to_world(DRAWING) - local_to_world(M_true, DRAWING)).max() < 0.001
    assert reg.scale_error == pytest.approx(np.max(np.abs(reg.distance_errors_m) / [0.13, 0.10, math.hypot(0.13, 0.1)]))


def test_coincident_marks_are_refused_by_name():
    with pytest.raises(RegistrationError, match="marks O and A coincide"):
        registration_from_marks([0, 0], [0.001, 0], [0, 0.1])


def test_collinear_marks_are_refused_with_the_angle():
    with pytest.raises(RegistrationError, match=r"collinear \(angle AOB = 177\.\d deg"):
        registration_from_marks([0, 0], [0.13, 0], [-0.1, 0.005])


def test_mirrored_board_is_refused():
    with pytest.raises(RegistrationError, match="mirrored"):
        registration_from_marks([0, 0], [0.13, 0], [0, -0.10], drawing_marks=DRAWING)
    with pytest.raises(RegistrationError, match="mirrored"):
        registration_from_marks([0, 0], [0.13, 0], [0, -0.10])


def test_distances_disagreeing_with_the_drawing_name_the_values_in_mm():
    with pytest.raises(RegistrationError, match=r"\|OA\| measured 140\.0 mm vs 130\.0 mm"):
        registration_from_marks([0, 0], [0.14, 0], [0, 0.10], drawing_marks=DRAWING)
    # A mark lifted with a 30 mm depth error is caught in 3D even though XY agree.
    with pytest.raises(RegistrationError, match=r"\|OB\| measured 104\.4 mm"):
        registration_from_marks([0, 0, 0.005], [0.13, 0, 0.005], [0, 0.10, 0.035], drawing_marks=DRAWING)
    # Within tolerance: accepted, with the error reported.
    reg = registration_from_marks([0, 0], [0.132, 0], [0, 0.10], drawing_marks=DRAWING, tol_m=0.003)
    assert reg.distance_errors_m[0] == pytest.approx(0.002)


def test_degenerate_drawing_is_refused():
    with pytest.raises(RegistrationError, match="drawing marks O, A, B are nearly collinear"):
        registration_from_marks([0, 0], [0.13, 0], [0, 0.1], drawing_marks=[[0, 0], [0.1, 0], [0.2, 0]])


def test_rigid_fit_recovers_transform_and_reports_rms():
    rng = np.random.default_rng(0)
    local = rng.uniform(-0.5, 0.5, (40, 2))
    M_true = _pose(2.5, -0.3, 0.8)
    fit = fit_rigid_2d(local, local_to_world(M_true, local))
    np.testing.assert_allclose(fit.M_local2world, M_true, atol=1e-12)
    assert fit.rms_m < 1e-12
    noise = rng.normal(0, 0.001, (40, 2))
    fit = fit_rigid_2d(local, local_to_world(M_true, local) + noise)
    assert fit.residuals_m.shape == (40,)
    assert fit.rms_m == pytest.approx(math.sqrt(np.mean(np.sum(noise**2, axis=1))), rel=0.1)


def test_rigid_fit_never_returns_a_reflection():
    local = np.array([[0, 0], [0.2, 0], [0, 0.1], [0.15, 0.12]])
    mirrored = local * [1, -1]
    fit = fit_rigid_2d(local, mirrored)
    assert np.linalg.det(fit.M_local2world[:2, :2]) == pytest.approx(1.0)
    assert fit.rms_m > 0.03
    with pytest.raises(RegistrationError, match="exceeds 1.00 mm"):
        fit_rigid_2d(local, mirrored, max_rms_m=0.001)


def test_rigid_fit_refuses_degenerate_input():
    with pytest.raises(RegistrationError, match="at least 2"):
        fit_rigid_2d([[0.0, 0.0]], [[1.0, 1.0]])
    with pytest.raises(RegistrationError, match="coincide"):
        fit_rigid_2d([[0.1, 0.1], [0.1, 0.1]], [[0, 0], [1, 1]])
    with pytest.raises(RegistrationError, match="NaN"):
        fit_rigid_2d([[0, 0], [1, np.nan]], [[0, 0], [1, 1]])


def test_local_world_transforms_are_vectorised_inverses():
    M = _pose(-1.1, 0.4, 0.2)
    xy = np.random.default_rng(2).uniform(-1, 1, (5, 4, 2))
    w = local_to_world(M, xy)
    assert w.shape == (5, 4, 2)
    np.testing.assert_allclose(world_to_local(M, w), xy, atol=1e-12)
