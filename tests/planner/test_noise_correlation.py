"""The depth noise's correlation measured on a frame, and the normal's 1-sigma it widens.

A fit's own covariance assumes independent noise; a real camera's is correlated over a few pixels,
and then the normal is several times less certain than the residuals say. These tests check the
measurement against frames whose noise is known, and that the planner's lean check then stops a
stud whose normal is off by more than the budget allows (it did not before)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from stud_perception.depth_image import depth_m_to_mm, depth_mm_to_m
from stud_perception.scene_sensor import depth_noise
from stud_planner.matching.noise_correlation import NoiseCorrelation, measure_noise_correlation

H, W = 480, 640


def _surface(curvature_per_px2: float = 0.0) -> np.ndarray:
    """A tilted plane 0.5 m away (metres), bent by ``curvature_per_px2`` (m / px^2) about the centre."""
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    return 0.5 + 2e-4 * (u - W / 2) - 1e-4 * (v - H / 2) + curvature_per_px2 * ((u - W / 2) ** 2 + (v - H / 2) ** 2)


def _studs(n: int = 64) -> np.ndarray:
    rng = np.random.default_rng(3)
    return np.column_stack([rng.uniform(60, W - 60, n), rng.uniform(60, H - 60, n)])


def _vif_of_blur(s: float) -> float:
    """sum of the autocorrelation of white noise blurred by a Gaussian of sigma s px: 4 pi s^2."""
    return max(1.0, 4.0 * math.pi * s * s)


@pytest.mark.parametrize("s", [1.0, 2.0, 3.0])
def test_a_blurred_noise_has_the_inflation_of_its_blur(s):
    rng = np.random.default_rng(int(10 * s))
    depth = _surface() + depth_noise((H, W), 0.0005, s, rng)
    c = measure_noise_correlation(depth, _studs())
    assert c.measured
    assert c.sigma_m == pytest.approx(0.0005, rel=0.15)
    # The separable estimate, truncated where rho falls under the cutoff: within 35 % of the sum.
    assert 0.65 * _vif_of_blur(s) < float(c.inflation(1)) < 1.2 * _vif_of_blur(s)
    # Samples every 2nd pixel are less correlated with each other: about a quarter of the factor.
    assert float(c.inflation(2)) < 0.45 * float(c.inflation(1))


def test_independent_noise_on_a_curved_part_is_independent():
    """White noise, quantised to millimetres, on a strongly curved surface: the third differences
    leave the curvature out, and the factor stays near 1."""
    rng = np.random.default_rng(1)
    exact = _surface(curvature_per_px2=2e-7)  # 20 mm of sag over 320 px
    depth = depth_mm_to_m(depth_m_to_mm(exact + rng.normal(0.0, 0.0005, (H, W))))
    c = measure_noise_correlation(depth, _studs())
    assert c.measured
    assert float(c.inflation(1)) < 1.4
    assert c.sigma_m == pytest.approx(math.sqrt(0.0005**2 + 0.001**2 / 12), rel=0.15)  # noise + quantisation


def test_part_edges_and_holes_are_left_out():
    """A 50 mm step through half the segments and holes in the rest do not read as correlation."""
    rng = np.random.default_rng(2)
    depth = _surface() + rng.normal(0.0, 0.0005, (H, W))
    depth[:, W // 2:] += 0.05  # the part's edge: the floor beyond it
    depth[rng.random((H, W)) < 0.05] = np.nan
    c = measure_noise_correlation(depth, _studs())
    assert c.measured
    assert float(c.inflation(1)) < 1.4


def test_a_frame_without_noise_or_without_studs_is_taken_as_independent():
    assert not measure_noise_correlation(_surface(), _studs()).measured  # exact float depth: no noise
    assert not measure_noise_correlation(_surface(), np.empty((0, 2))).measured
    assert not measure_noise_correlation(np.full((H, W), np.nan), _studs()).measured
    off = measure_noise_correlation(_surface() + depth_noise((H, W), 5e-4, 2.0, np.random.default_rng(0)), _studs(),
                                    max_lag_px=0)
    assert not off.measured and float(off.inflation(1)) == 1.0
    assert NoiseCorrelation.independent(8).inflation(np.array([1, 2, 3])).tolist() == [1.0, 1.0, 1.0]


def test_correlated_noise_keeps_smooth_windows_on_the_fast_path(monkeypatch):
    """The fast path's gate is the frame's whole noise: against the 8x8 blocks' plane-fit RMS alone
    (blind to the noise's slow part), nearly every window of a correlated frame went to the robust
    pixel path, at twice the cost, for the same normals."""
    import stud_planner.matching.surface_pose as surface_pose
    from stud_perception.scene import demo_dome_scene, grid_stud_scene
    from stud_perception.scene_cameras import view_camera
    from stud_perception.scene_render import render
    from stud_planner.matching.view_targets import PlannerConfig, plan_view

    scene = grid_stud_scene(100, demo_dome_scene(), extent_m=(0.26, 0.2))
    c = scene.component.centre_xy_m
    cam = view_camera((c[0], c[1], 0.0), 0.5, yaw_rad=math.radians(35), tilt_rad=math.radians(8),
                      tilt_azimuth_rad=math.radians(60))
    view = render(scene, cam, seed=7, depth_noise_m=0.0005, hole_fraction=0.04, depth_noise_correlation_px=1.5)
    robust = []
    pixel_path = surface_pose._pixel_path_fits
    monkeypatch.setattr(surface_pose, "_pixel_path_fits",
                        lambda idx, *a, **k: robust.append(len(idx)) or pixel_path(idx, *a, **k))
    t = plan_view(list(scene.stud_ids), np.asarray(scene.studs_drawing_m), scene.M_local2world, view.depth_m, cam,
                  PlannerConfig(check_gun_clearance=False))
    fitted = int(t.poses.ok.sum())
    assert fitted >= 90
    assert sum(robust) <= 0.1 * fitted, (sum(robust), fitted)
    every_pixel = measure_noise_correlation(view.depth_m, t.matches.pixel_uv[t.matches.ok], beside_px=20)
    # sqrt of ~9-21 (4 pi 1.5^2 = 28 for the blur alone, less quantisation)
    assert 2.5 < every_pixel.correlation_px() < 6.0
    assert 1.5 < t.sigma_inflation() <= every_pixel.correlation_px()  # the windows sample every few pixels


@pytest.mark.parametrize("part", ["dome", "shell"])
def test_painted_stud_marks_do_not_hide_the_correlation(part):
    """The stud marks' dark paint returns no depth where the studs are: the correlation is measured
    along the normal windows' edges, not through the studs, and is still seen."""
    from pathlib import Path

    from stud_perception.scene_cameras import view_camera
    from stud_perception.scene_file import load_scene
    from stud_perception.scene_render import render
    from stud_planner.matching.view_targets import PlannerConfig, plan_view

    config = Path(__file__).resolve().parents[2] / "src" / "stud_perception" / "config"
    scene = load_scene(config / f"{part}_scene.json")
    c = scene.studs_world_xy_m.mean(axis=0)
    cam = view_camera((c[0], c[1], 0.0), 0.40)
    view = render(scene, cam, seed=3, depth_noise_m=0.0005, hole_fraction=0.02, mark_depth_dropout=True,
                  depth_noise_correlation_px=1.5)
    t = plan_view(list(scene.stud_ids), np.asarray(scene.studs_drawing_m), scene.M_local2world, view.depth_m, cam,
                  PlannerConfig(sample_step_max_loss=0.0))  # every pixel: the factor is the correlation's whole
    through_the_studs = measure_noise_correlation(view.depth_m, t.matches.pixel_uv[t.matches.ok], beside_px=0)
    assert not through_the_studs.measured  # the marks leave no long enough run of depth there
    assert t.sigma_inflation() > 2.5


@pytest.mark.parametrize("s, max_step", [(0.0, 1), (1.5, 4), (3.0, 4)])
def test_the_sample_step_costs_the_normal_at_most_the_loss_asked(s, max_step):
    """Correlated neighbours are redundant: a window sampled every few pixels loses almost nothing.
    Independent noise keeps every pixel, and 0 loss asked keeps every pixel."""
    rng = np.random.default_rng(21)
    depth = _surface() + depth_noise((H, W), 0.0005, s, rng)
    c = measure_noise_correlation(depth, _studs())
    step = c.redundant_step(0.05)
    assert 1 <= step <= max_step
    if s == 0.0:
        assert step == 1
    else:
        assert step >= 2  # a 1.5 px blur: rho(1) ~ 0.9
        loss = math.sqrt(step**2 * float(c.inflation(step)) / float(c.inflation(1)))
        assert loss <= 1.05
    assert c.redundant_step(0.0) == 1
    assert NoiseCorrelation.independent(16).redundant_step(0.05) == 1


@pytest.mark.parametrize("correlation_px", [0.0, 1.5])
def test_sampling_a_correlated_frame_sparsely_keeps_its_normals(correlation_px):
    """On issue 19's dome with a real camera's correlated noise the windows are sampled every few
    pixels -- a quarter of the samples or fewer -- for normals as accurate and a 1-sigma as honest as
    every pixel's. On independent noise nothing changes."""
    from stud_perception.scene import demo_dome_scene, grid_stud_scene
    from stud_perception.scene_cameras import view_camera
    from stud_perception.scene_render import render
    from stud_planner.matching.view_targets import PlannerConfig, plan_view

    scene = grid_stud_scene(100, demo_dome_scene(), extent_m=(0.26, 0.2))
    c = scene.component.centre_xy_m
    cam = view_camera((c[0], c[1], 0.0), 0.5, yaw_rad=math.radians(35), tilt_rad=math.radians(8),
                      tilt_azimuth_rad=math.radians(60))
    view = render(scene, cam, seed=11, depth_noise_m=0.0005, hole_fraction=0.04,
                  depth_noise_correlation_px=correlation_px)
    args = (list(scene.stud_ids), np.asarray(scene.studs_drawing_m), scene.M_local2world, view.depth_m, cam)
    every = plan_view(*args, PlannerConfig(check_gun_clearance=False, sample_step_max_loss=0.0))
    sparse = plan_view(*args, PlannerConfig(check_gun_clearance=False))
    if correlation_px == 0.0:
        np.testing.assert_array_equal(sparse.normal_w, every.normal_w)
        np.testing.assert_array_equal(sparse.normal_sigma_deg, every.normal_sigma_deg)
        return
    ok = every.poses.ok & sparse.poses.ok & view.stud_visible
    assert ok.sum() >= 90 and sparse.poses.ok.sum() >= every.poses.ok.sum() - 1
    assert np.median(sparse.poses.n_points[ok] / every.poses.n_points[ok]) <= 0.3

    def errors(t):
        return np.degrees(np.arccos(np.clip(np.sum(t.normal_w[ok] * view.stud_normals_w[ok], axis=1), -1, 1)))

    e_every, e_sparse = errors(every), errors(sparse)
    assert np.sqrt(np.mean(e_sparse**2)) <= 1.15 * np.sqrt(np.mean(e_every**2))
    # The 1-sigma follows the samples it has: the errors stay within the same few sigma.
    assert np.percentile(e_sparse / sparse.normal_sigma_deg[ok], 95) < 3.0
    assert np.max(e_sparse / sparse.normal_sigma_deg[ok]) < 4.5


def _correlated_dome_view(seed: int, correlation_px: float = 1.5, camera=None):
    from stud_perception.scene import demo_dome_scene, grid_stud_scene
    from stud_perception.scene_cameras import view_camera
    from stud_perception.scene_render import render

    scene = grid_stud_scene(100, demo_dome_scene(), extent_m=(0.26, 0.2))
    c = scene.component.centre_xy_m
    cam = camera or view_camera((c[0], c[1], 0.0), 0.5, yaw_rad=math.radians(35), tilt_rad=math.radians(8),
                                tilt_azimuth_rad=math.radians(60))
    view = render(scene, cam, seed=seed, depth_noise_m=0.0005, hole_fraction=0.04,
                  depth_noise_correlation_px=correlation_px)
    return scene, cam, view


def test_a_measurement_reused_on_the_next_frame_gives_what_measuring_it_there_gives():
    """The matcher node measures a frame's noise correlation after its targets are out and gives it
    to the same camera's next frame. Given the frame's own measurement, plan_view's result is the
    same to the bit; given the previous frame's, the sigmas are as wide and as honest as measured."""
    from stud_planner.matching.view_targets import PlannerConfig, plan_view, view_noise_correlation

    scene, cam, first = _correlated_dome_view(seed=21)
    _, _, second = _correlated_dome_view(seed=22)  # the next frame: the same camera, new noise
    cfg = PlannerConfig(check_gun_clearance=False)

    def plan(view, noise=None):
        return plan_view(list(scene.stud_ids), np.asarray(scene.studs_drawing_m), scene.M_local2world,
                         view.depth_m, cam, cfg, noise=noise)

    measured_first = plan(first)
    assert measured_first.poses.noise.measured and measured_first.sigma_inflation() > 1.5
    again = view_noise_correlation(measured_first, first.depth_m, cam)
    np.testing.assert_array_equal(again.rho_u, measured_first.poses.noise.rho_u)
    assert again.sigma_m == measured_first.poses.noise.sigma_m
    same = plan(first, noise=again)
    np.testing.assert_array_equal(same.normal_w, measured_first.normal_w)
    np.testing.assert_array_equal(same.normal_sigma_deg, measured_first.normal_sigma_deg)
    np.testing.assert_array_equal(same.status, measured_first.status)

    own, reused = plan(second), plan(second, noise=measured_first.poses.noise)
    ok = own.poses.ok & reused.poses.ok & second.stud_visible
    assert ok.sum() >= 90
    assert reused.sigma_inflation() == pytest.approx(own.sigma_inflation(), rel=0.1)
    err = np.degrees(np.arccos(np.clip(np.sum(reused.normal_w[ok] * second.stud_normals_w[ok], axis=1), -1, 1)))
    assert np.percentile(err / reused.normal_sigma_deg[ok], 95) < 3.0


def test_the_noise_memory_recalls_only_for_the_same_camera_at_the_same_pose_and_not_too_old():
    from stud_perception.scene_cameras import view_camera
    from stud_planner.matching.view_targets import NoiseMemory

    cam = view_camera((0.1, 0.05, 0.0), 0.5, yaw_rad=0.3)
    noise = NoiseCorrelation.independent(16)
    memory = NoiseMemory(max_age_s=2.0)
    assert memory.recall(cam, 0.0) is None  # nothing measured yet: the frame measures itself
    memory.remember(cam, noise, 10.0)
    assert memory.recall(cam, 11.9) is noise
    assert memory.recall(cam.with_pose(cam.R_wc, cam.t_wc + [0.0008, 0.0, 0.0]), 11.0) is noise  # settling jitter
    assert memory.recall(cam, 12.1) is None  # too old
    assert memory.recall(cam.with_pose(cam.R_wc, cam.t_wc + [0.0, 0.002, 0.0]), 11.0) is None  # moved
    turned = view_camera((0.1, 0.05, 0.0), 0.5, yaw_rad=0.3 + math.radians(0.2))
    assert memory.recall(turned.with_pose(turned.R_wc, cam.t_wc), 11.0) is None  # turned
    other_lens = type(cam)(K=cam.K * [[1.01], [1.01], [1.0]], width=cam.width, height=cam.height,
                           R_wc=cam.R_wc, t_wc=cam.t_wc)
    assert memory.recall(other_lens, 11.0) is None
    assert not memory.refresh_due(10.9) and memory.refresh_due(11.0)  # measured again from half its age
    off = NoiseMemory(max_age_s=0.0)
    off.remember(cam, noise, 10.0)
    assert off.recall(cam, 10.0) is None and not off.refresh_due(100.0)
