"""Depth conversions at the edge, the paper's hole rule and its fallbacks, safe sampling."""
from __future__ import annotations

import numpy as np
import pytest

from stud_perception.camera_model import CameraModel
from stud_perception.depth_image import (
    DepthImageError,
    FillRule,
    SampleStatus,
    depth_image_to_m,
    depth_m_to_mm,
    depth_mm_to_m,
    fill_depth_at,
    sample_depth_bilinear,
)


# -- conversions -------------------------------------------------------------------------------
def test_every_16uc1_value_round_trips_through_metres():
    mm = np.arange(65536, dtype=np.uint16).reshape(256, 256)
    m = depth_mm_to_m(mm)
    assert m.dtype == np.float32
    assert np.isnan(m[0, 0]) and np.isfinite(m.ravel()[1:]).all()
    np.testing.assert_array_equal(depth_m_to_mm(m), mm)


def test_metres_to_mm_rounds_and_marks_unrepresentable_depths_invalid():
    m = np.array([0.5004, 0.5006, np.nan, np.inf, -0.2, 0.0, 0.0004, 65.535, 65.6])
    np.testing.assert_array_equal(depth_m_to_mm(m), [500, 501, 0, 0, 0, 0, 0, 65535, 0])


def test_depth_mm_to_m_refuses_non_uint16():
    with pytest.raises(DepthImageError, match="uint16"):
        depth_mm_to_m(np.zeros((2, 2), dtype=np.float32))


def test_depth_image_to_m_accepts_both_ros_encodings():
    mm = np.array([[0, 750]], dtype=np.uint16)
    np.testing.assert_allclose(depth_image_to_m(mm, "16UC1"), [[np.nan, 0.75]])
    f = np.array([[0.0, 0.75, np.inf, -1.0]], dtype=np.float32)
    np.testing.assert_allclose(depth_image_to_m(f, "32FC1"), [[np.nan, 0.75, np.nan, np.nan]])
    with pytest.raises(DepthImageError, match="rgb8"):
        depth_image_to_m(mm, "rgb8")


# -- hole filling --------------------------------------------------------------------------------
def _flat(value=0.5, shape=(60, 80)):
    return np.full(shape, value, dtype=np.float32)


def test_valid_pixel_is_used_directly():
    d = _flat()
    d[10, 20] = 0.61
    r = fill_depth_at(d, 20.3, 9.8)  # nearest pixel (20, 10)
    assert r.rule == FillRule.DIRECT and r.depth_m == pytest.approx(0.61)
    assert r.window_px == 1 and r.n_used == 1


def test_single_hole_gets_mean_of_valid_depths_in_7x7_window():
    d = _flat(0.0)
    d[27:34, 37:44] = np.arange(49, dtype=np.float32).reshape(7, 7) / 100 + 0.4
    d[25, 40] = 9.0  # outside the 7x7 window: must not count
    d[30, 40] = np.nan  # the hole (window centre)
    d[28, 38] = np.nan  # another invalid pixel inside the window: skipped, not zero
    r = fill_depth_at(d, 40, 30)
    win = d[27:34, 37:44]
    assert r.rule == FillRule.MEAN_WINDOW
    assert r.n_used == 47 and r.window_px == 7
    assert r.depth_m == pytest.approx(np.nanmean(win), abs=1e-7)


def test_large_hole_with_grow_fallback_uses_mean_of_grown_window():
    d = _flat(0.5)
    d[20:33, 30:43] = np.nan  # 13x13 hole: the 7x7 and 11x11 windows hold nothing
    d[18, 36] = 0.54          # the 15x15 window reaches row 19..; this one is outside it
    r = fill_depth_at(d, 36, 26, fallback="grow")
    assert r.rule == FillRule.GROWN_WINDOW and r.window_px == 15
    assert r.depth_m == pytest.approx(0.5)
    none = fill_depth_at(d, 36, 26, fallback="none")
    assert none.rule == FillRule.NONE and np.isnan(none.depth_m)


def test_plane_fit_recovers_exact_depth_of_tilted_plane_in_large_hole():
    # Depth of a plane tilted 30 deg seen by a pinhole camera: 1/z is affine in (u, v).
    cam = CameraModel.from_fov(120, 90, 0.2, 0.5)
    v, u = np.mgrid[0:90, 0:120]
    n = np.array([np.sin(np.radians(30)), 0.0, -np.cos(np.radians(30))])  # optical frame
    ray = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u, float)], -1)
    depth = (-0.5 / (ray @ n)).astype(np.float64)  # plane n.P = -0.5
    holed = depth.copy()
    holed[35:56, 50:71] = np.nan  # 21x21 hole
    r = fill_depth_at(holed, [60.0, 60.4, 55.0], [45.0, 44.7, 40.0])
    assert (r.rule == FillRule.PLANE_FIT).all()
    truth = np.array([-0.5 / (np.array([(uu - cam.cx) / cam.fx, (vv - cam.cy) / cam.fy, 1.0]) @ n)
                      for uu, vv in [(60.0, 45.0), (60.4, 44.7), (55.0, 40.0)]])
    np.testing.assert_allclose(r.depth_m, truth, atol=1e-9)
    assert (r.spread_m < 1e-9).all()
    # The paper's mean of a one-sided window would be biased on this slope; the plane is not.
    mean_grow = fill_depth_at(holed, 55.0, 40.0, fallback="grow")
    assert abs(mean_grow.depth_m - truth[2]) > 1e-3


def test_plane_fit_refuses_samples_on_a_line_and_falls_back_to_mean_at_max_window():
    d = np.full((41, 41), np.nan, dtype=np.float32)
    d[20, :] = 0.5  # a single valid row: a plane through it is undetermined
    d[20, 20] = np.nan
    r = fill_depth_at(d, 20, 16, window=7, max_window=15)
    assert r.rule == FillRule.GROWN_WINDOW and r.window_px == 15
    assert r.depth_m == pytest.approx(0.5)


def test_no_valid_depth_or_query_outside_image_gives_none():
    d = np.full((30, 30), np.nan, dtype=np.float32)
    r = fill_depth_at(d, [15.0, -3.0, 31.0, np.nan], [15.0, 4.0, 4.0, 4.0])
    assert (r.rule == FillRule.NONE).all() and np.isnan(r.depth_m).all()
    assert (r.window_px == 0).all()


def test_fill_is_vectorised_and_keeps_query_shape():
    d = _flat(0.7)
    d[::3, ::3] = np.nan
    u = np.linspace(1, 78, 12).reshape(3, 4)
    v = np.linspace(1, 58, 12).reshape(3, 4)
    r = fill_depth_at(d, u, v)
    assert r.depth_m.shape == (3, 4) and r.rule.shape == (3, 4)
    np.testing.assert_allclose(r.depth_m, 0.7, rtol=1e-6)
    assert set(np.unique(r.rule)) <= {FillRule.DIRECT, FillRule.MEAN_WINDOW}


def test_fill_rejects_even_windows():
    with pytest.raises(DepthImageError, match="odd"):
        fill_depth_at(_flat(), 1, 1, window=6)


# -- bilinear sampling -----------------------------------------------------------------------------
def test_bilinear_is_exact_on_a_ramp_and_reaches_the_last_pixel():
    v, u = np.mgrid[0:20, 0:30]
    d = 0.5 + 0.001 * u + 0.002 * v
    uq = np.array([3.25, 29.0, 0.0, 12.5])
    vq = np.array([7.75, 19.0, 0.0, 19.0])
    s = sample_depth_bilinear(d, uq, vq)
    assert (s.status == SampleStatus.OK).all()
    np.testing.assert_allclose(s.depth_m, 0.5 + 0.001 * uq + 0.002 * vq, atol=1e-12)


def test_bilinear_refuses_invalid_neighbours_and_depth_steps():
    d = np.full((10, 10), 0.5)
    d[4, 5] = np.nan
    d[:, 8:] = 0.6  # a 100 mm step between columns 7 and 8
    s = sample_depth_bilinear(d, [4.5, 4.0, 7.5, 7.0, -0.1, 2.0], [4.5, 5.0, 2.0, 2.0, 2.0, 9.5], max_step_m=0.005)
    assert list(s.status) == [
        SampleStatus.INVALID_DEPTH,  # blends the NaN at (5, 4)
        SampleStatus.OK,             # exactly on pixel (4, 5): the NaN next to it has no weight
        SampleStatus.DISCONTINUITY,  # halfway across the step
        SampleStatus.OK,             # on the near side of the step, no weight across it
        SampleStatus.OUT_OF_IMAGE,
        SampleStatus.OUT_OF_IMAGE,   # beyond the last row centre
    ]
    assert np.isnan(s.depth_m[[0, 2, 4, 5]]).all()
    assert s.depth_m[1] == 0.5 and s.depth_m[3] == 0.5
