"""Window moment sums: the summed-area table and the direct sums give the sums of the pixels themselves,
and the pose fit built on them hands the windows it cannot trust to the robust pixel path."""
from __future__ import annotations

import numpy as np
import pytest

from stud_planner.matching.surface_pose import SurfaceFitConfig, estimate_surface_poses
from stud_planner.matching.window_moments import BLOCK_PX, BlockMoments


def brute_force_sums(depth, y_ref, r0, r1, c0, c1):
    """float64 sums over the valid pixels of one window of blocks, about its centre, in pixels."""
    b = BLOCK_PX
    sub = depth[r0 * b:r1 * b, c0 * b:c1 * b].astype(np.float64)
    vv, uu = np.mgrid[r0 * b:min(r1 * b, depth.shape[0]), c0 * b:min(c1 * b, depth.shape[1])]
    uu = uu - ((c0 + c1) * b / 2.0 - 0.5)
    vv = vv - ((r0 + r1) * b / 2.0 - 0.5)
    ok = sub > 0
    # the inverse depths as the sums take them: float32 1/z - y_ref (a relative 1e-7 off float64)
    y = np.where(ok, np.float32(1.0) / np.where(ok, sub, 1.0).astype(np.float32) - np.float32(y_ref), 0.0)
    mw = np.array([[(ok * uu**p * vv**q).sum() if p + q <= 4 else 0.0 for q in range(5)] for p in range(5)])
    my = np.array([[(y * uu**p * vv**q).sum() if p + q <= 2 else 0.0 for q in range(3)] for p in range(3)])
    return mw, my, (y * y).sum()


@pytest.fixture
def holed_depth():
    rng = np.random.default_rng(3)
    vv, uu = np.mgrid[0:100, 0:132]  # not whole blocks: the last block row and column are padded
    depth = (0.45 + 1e-4 * uu - 5e-5 * vv + 1e-6 * (uu - 60.0) ** 2 + rng.normal(0, 5e-4, uu.shape)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.05] = np.nan
    depth[30:45, 70:90] = np.nan  # a large hole
    return depth


@pytest.mark.parametrize("use_table", [True, False])
def test_window_sums_are_the_sums_of_the_windows_pixels(holed_depth, use_table):
    y_ref = 2.2
    moments = BlockMoments(holed_depth, y_ref)
    rng = np.random.default_rng(4)
    r0 = rng.integers(0, moments.n_rows - 1, 40)
    c0 = rng.integers(0, moments.n_cols - 1, 40)
    r1 = np.minimum(r0 + rng.integers(1, 6, 40), moments.n_rows)
    c1 = np.minimum(c0 + rng.integers(1, 6, 40), moments.n_cols)
    got = moments.window_sums(r0, r1, c0, c1, use_table=use_table)
    for k in range(40):
        mw, my, yy = brute_force_sums(holed_depth, y_ref, r0[k], r1[k], c0[k], c1[k])
        scale_w = np.abs(mw).max()
        np.testing.assert_allclose(got.mw[k], mw, rtol=0, atol=1e-6 * scale_w)
        np.testing.assert_allclose(got.my[k], my, rtol=0, atol=1e-5 * np.abs(my).max() + 1e-9)
        np.testing.assert_allclose(got.yy[k], yy, rtol=1e-5)
        rows_in = min(r1[k] * BLOCK_PX, holed_depth.shape[0]) - r0[k] * BLOCK_PX
        cols_in = min(c1[k] * BLOCK_PX, holed_depth.shape[1]) - c0[k] * BLOCK_PX
        assert got.n_window[k] == rows_in * cols_in


@pytest.mark.parametrize("step", [2, 3])
def test_strided_window_sums_are_the_sums_of_every_step_th_pixel(holed_depth, step):
    """The direct sums sampled every ``step``-th row and column (a correlated frame's redundant
    pixels) are the sums of exactly those pixels, about the window's centre, and count them."""
    b, y_ref = BLOCK_PX, 2.2
    moments = BlockMoments(holed_depth, y_ref)
    rng = np.random.default_rng(5)
    r0 = rng.integers(0, moments.n_rows - 5, 30)  # whole windows inside the image: each box starts at
    c0 = rng.integers(0, moments.n_cols - 5, 30)  # its own window's first pixel
    r1, c1 = r0 + rng.integers(2, 6, 30), c0 + rng.integers(2, 6, 30)
    got = moments.window_sums(r0, r1, c0, c1, use_table=False, step=step)
    assert got.step == step
    for k in range(30):
        sampled = np.zeros_like(holed_depth)  # NaN: no depth, the pixels not sampled
        sampled[:] = np.nan
        rows, cols = slice(r0[k] * b, r1[k] * b, step), slice(c0[k] * b, c1[k] * b, step)
        sampled[rows, cols] = holed_depth[rows, cols]
        mw, my, yy = brute_force_sums(sampled, y_ref, r0[k], r1[k], c0[k], c1[k])
        np.testing.assert_allclose(got.mw[k], mw, rtol=0, atol=1e-6 * np.abs(mw).max())
        np.testing.assert_allclose(got.my[k], my, rtol=0, atol=1e-5 * np.abs(my).max() + 1e-9)
        np.testing.assert_allclose(got.yy[k], yy, rtol=1e-5)
        assert got.n_window[k] == len(range(r0[k] * b, r1[k] * b, step)) * len(range(c0[k] * b, c1[k] * b, step))
    # The table sums every pixel whatever the step asked: it says so.
    assert moments.window_sums(r0, r1, c0, c1, use_table=True, step=step).step == 1


@pytest.mark.parametrize("use_table", [True, False])
@pytest.mark.parametrize("no_depth", [0.0, -0.3, np.inf, -np.inf])
def test_every_spelling_of_no_depth_gives_the_sums_of_nan_holes(holed_depth, use_table, no_depth):
    # The class's contract: NaN or <= 0 is no depth (REP 118's +-inf too). A 0 once gave inf in
    # 1/z and inf * 0 = NaN in the sums of every window holding it.
    other = holed_depth.copy()
    other[np.isnan(holed_depth)] = no_depth
    r0, c0 = np.array([0, 3, 1]), np.array([0, 5, 8])
    r1, c1 = r0 + 4, c0 + 5
    want = BlockMoments(holed_depth, 2.2).window_sums(r0, r1, c0, c1, use_table=use_table)
    got = BlockMoments(other, 2.2).window_sums(r0, r1, c0, c1, use_table=use_table)
    for field in ("mw", "my", "yy"):
        np.testing.assert_array_equal(getattr(got, field), getattr(want, field))


def test_smooth_windows_take_the_plain_fit_and_a_step_goes_to_the_robust_path(scenes, cam_full):
    plane = scenes.Plane((0.0, 0.0, 0.02), (0.2, 0.1, 1.0))
    depth = scenes.render_depth(cam_full, plane, noise_m=0.0005, seed=21)
    xy = np.random.default_rng(21).uniform([-0.12, -0.08], [0.12, 0.08], (60, 2))
    P = np.column_stack([xy, plane.height(xy)])
    u, v, _ = cam_full.world_to_pixel(P)
    # a 6 mm step through the window of stud 0, 10 px from it: the plain fit's residual betrays it
    uu = np.arange(cam_full.width)
    depth[:, uu > u[0] + 10] -= 0.006
    poses = estimate_surface_poses(P, np.column_stack([u, v]), depth, cam_full, target_xy_w=xy)
    plain = estimate_surface_poses(P, np.column_stack([u, v]), depth, cam_full, SurfaceFitConfig(fast_fit=False),
                                   target_xy_w=xy)
    far = np.abs(u - u[0]) > 60  # windows the step does not reach
    assert np.all(poses.ok[far])
    assert np.all(poses.outlier_ratio[far] == 0.0)  # every valid pixel used: the plain fit
    # the stepped window is decided by the robust path, exactly as without the fast path
    assert poses.status[0] == plain.status[0]
    np.testing.assert_allclose(poses.fit_rms_m[0], plain.fit_rms_m[0], rtol=1e-9)
    np.testing.assert_allclose(poses.normal_w[0], plain.normal_w[0], rtol=0, atol=1e-12)
    assert poses.outlier_ratio[0] == plain.outlier_ratio[0]
    assert poses.fit_rms_m[0] > 2 * np.median(poses.fit_rms_m[far])  # rougher than the frame's noise
