"""Registration along a long part on every visible mark (O, A, B and the reference marks), on rendered
views of the 6 m girder with depth noise, holes, dark-paint dropout and a tilted camera."""
from __future__ import annotations

import math

import numpy as np
import pytest

from stud_perception.mark_registration import MarkFitConfig, RegistrationTrail, associate_marks, register_view_on_marks
from stud_perception.markers import MarkDetection, MarkDetectorConfig, find_mark_candidates
from stud_perception.registration import RegistrationError, fit_marks, local_to_world
from stud_perception.scene import girder_scene
from stud_perception.scene_cameras import view_camera
from stud_perception.scene_render import render

SCENE = girder_scene()
TRUTH = SCENE.M_local2world
MARKS = {"O": (0.0, 0.0), "A": (0.13, 0.0), "B": (0.0, 0.1), **SCENE.reference_marks_drawing_m}
TOP_Z = 0.12 + 0.03  # the girder's crown: camera targets


def shoot(target_xy, seed: int = 1, tilt_deg: float = 8.0, believed=None):
    """A view of the scene from 0.5 m above ``target_xy`` (tilted, noisy, holey, dark paint without depth).
    ``believed``: a function (true camera) -> the camera the cell believes it used (rail error)."""
    cam = view_camera((*target_xy, TOP_Z), distance_m=0.5, tilt_rad=math.radians(tilt_deg),
                      tilt_azimuth_rad=math.radians(60.0))
    view = render(SCENE, cam, seed=seed, depth_noise_m=0.0005, depth_noise_correlation_px=2.0, hole_fraction=0.03,
                  color_noise=2.0, mark_depth_dropout=True)
    return view, (believed(cam) if believed is not None else cam)


def fully_in_view(view) -> set[str]:
    """Labels of the marks whose whole disc is in the image (from the ground truth)."""
    r_px = view.camera.fx * SCENE.board.mark_diameter_m / 2 / 0.45 + 3
    uv = np.vstack([view.marks_pixels_uv, view.reference_marks_pixels_uv])
    labels = ["O", "A", "B", *(m.label for m in SCENE.reference_marks)]
    inside = view.camera.in_image(uv[:, 0], uv[:, 1], margin=r_px)
    return {lb for lb, ok in zip(labels, inside) if ok}


def error_at_studs_mm(M: np.ndarray, view, M_truth: np.ndarray = TRUTH) -> float:
    """Largest distance (world XY) between where M and the truth put the studs within 0.35 m of the view's
    camera (those this station's carriage position welds), mm."""
    near = np.linalg.norm(SCENE.studs_world_xy_m - view.camera.position_w[:2], axis=1) < 0.35
    xy = np.asarray(SCENE.studs_drawing_m)[near]
    assert len(xy) >= 6
    return float(np.linalg.norm(local_to_world(M, xy) - local_to_world(M_truth, xy), axis=1).max() * 1e3)


def shifted(M: np.ndarray, dx_m: float, dyaw_rad: float = 0.0) -> np.ndarray:
    c, s = math.cos(dyaw_rad), math.sin(dyaw_rad)
    T = np.array([[c, -s, dx_m], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return T @ M


@pytest.fixture(scope="module")
def middle():
    """A station over the middle of the girder: two or three reference marks, no board."""
    return shoot((3.3, 0.0), seed=5)


def test_a_station_over_the_middle_registers_on_its_reference_marks_within_half_a_millimetre(middle):
    view, cam = middle
    seen = fully_in_view(view)
    assert 2 <= len(seen) <= 3 and not seen & {"O", "A", "B"}, seen
    prior = shifted(TRUTH, 0.006)  # an earlier station's registration, 6 mm off along the rail here
    result = register_view_on_marks(view.color_bgr, view.depth_m, cam, MARKS, MarkDetectorConfig(), prior=prior)
    assert result.ok, result.message
    reg = result.registration
    assert set(reg.labels_used) == seen  # the right marks, every one in view
    err = error_at_studs_mm(reg.M_local2world, view)
    assert err < 0.5, f"{err:.3f} mm"
    assert reg.residual_max_m < 0.5e-3 and len(reg.mark_residuals_m) == len(seen)
    assert np.isnan(reg.marks_world_m).all() and math.isnan(reg.angle_AOB_deg)  # O, A, B not seen
    # each mark's own height is measured: the cambered, sloped flange puts them at different z
    truth_w = SCENE.reference_marks_world_m[[int(lb[1:]) - 1 for lb in reg.labels_used]]
    np.testing.assert_allclose(reg.marks_used_world_m, truth_w, atol=1.0e-3)
    print(f"\nmiddle station: marks {', '.join(reg.labels_used)}, error at the studs in view {err:.3f} mm, "
          f"residual {reg.residual_m * 1e3:.3f} mm RMS / {reg.residual_max_m * 1e3:.3f} mm max")


@pytest.mark.parametrize("dx_m, dyaw_deg", [(-0.006, 0.0), (0.006, 0.05), (0.0, -0.2)])
def test_association_holds_with_a_prior_a_few_millimetres_off(middle, dx_m, dyaw_deg):
    view, cam = middle
    prior = shifted(TRUTH, dx_m, math.radians(dyaw_deg))
    result = register_view_on_marks(view.color_bgr, view.depth_m, cam, MARKS, MarkDetectorConfig(), prior=prior)
    assert result.ok, result.message
    assert set(result.registration.labels_used) == fully_in_view(view)
    assert error_at_studs_mm(result.registration.M_local2world, view) < 0.5


def test_a_prior_a_whole_mark_pitch_off_names_no_wrong_mark(middle):
    view, cam = middle
    result = register_view_on_marks(view.color_bgr, view.depth_m, cam, MARKS, MarkDetectorConfig(),
                                    prior=shifted(TRUTH, 0.2))  # the marks alternate sides: nothing within the gate
    assert not result.ok and "too few marks" in result.message


def test_swapped_marks_are_refused_by_their_residual(middle):
    view, cam = middle
    found = find_mark_candidates(view.color_bgr, view.depth_m, cam, MarkDetectorConfig())
    assert not isinstance(found, MarkDetection)
    labels = [lb for lb in MARKS if lb not in ("O", "A", "B")]
    drawing = np.array([MARKS[lb] for lb in labels])
    taken = associate_marks(found.world_m[:, :2], local_to_world(TRUTH, drawing), 0.03)
    used = np.flatnonzero(taken >= 0)
    assert len(used) >= 3
    names = [labels[m] for m in used]
    world = found.world_m[taken[used]]
    good = fit_marks(names, drawing[used], world, np.array([MARKS[k] for k in "OAB"]), max_residual_m=0.002)
    assert good.residual_max_m < 0.5e-3
    swapped = world.copy()
    swapped[[0, 1]] = swapped[[1, 0]]
    with pytest.raises(RegistrationError, match=r"mark M\d+ is .* mm from where the fit .*swapped.*refused"):
        fit_marks(names, drawing[used], swapped, np.array([MARKS[k] for k in "OAB"]), max_residual_m=0.002)


def test_without_a_prior_the_board_names_the_marks_and_the_fit_uses_them_all():
    view, cam = shoot((0.37, -0.2), seed=2)
    seen = fully_in_view(view)
    assert {"O", "A", "B", "M1"} <= seen
    result = register_view_on_marks(view.color_bgr, view.depth_m, cam, MARKS, MarkDetectorConfig())
    assert result.ok, result.message
    reg = result.registration
    assert set(reg.labels_used) == seen and reg.labels_used[:3] == ("O", "A", "B")
    assert error_at_studs_mm(reg.M_local2world, view) < 0.5
    assert np.isfinite(reg.marks_world_m).all() and abs(reg.angle_AOB_deg - 90.0) < 0.5
    np.testing.assert_allclose(reg.marks_world_m, SCENE.marks_world_m, atol=1.0e-3)


def test_without_a_prior_or_the_board_nothing_is_named(middle):
    view, cam = middle
    result = register_view_on_marks(view.color_bgr, view.depth_m, cam, MARKS, MarkDetectorConfig())
    assert not result.ok and "no prior registration" in result.message


def test_along_the_rail_every_station_cancels_the_rail_error_and_a_blind_one_says_how_far_it_extrapolated():
    """The cell believes the camera where the commanded carriage position puts it; the true carriage is off
    by a scale error, an offset and a yaw that grow along the rail. Each station's registration, made in
    the believed frame, must put the studs where the arm (off by the same error there) will hit them."""
    scale, offset, yaw_per_m = 1000e-6, 0.0005, 50e-6  # 1 mm/m, 0.5 mm, 50 urad/m

    def rail_error(x_m: float) -> tuple[float, float]:
        return scale * x_m + offset, yaw_per_m * x_m

    def believed(cam):  # the commanded carriage position: the true camera moved back by the rail's error
        dx, dyaw = rail_error(float(cam.position_w[0]))
        c, s = math.cos(-dyaw), math.sin(-dyaw)
        Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        return cam.with_pose(Rz @ cam.R_wc, Rz @ cam.position_w - np.array([dx, 0.0, 0.0]))

    def expected(cam_true, cam_believed):  # drawing -> the believed world: where the arm must be sent
        T_bt = np.eye(3)
        Rz = cam_believed.R_wc @ cam_true.R_wc.T
        T_bt[:2, :2] = Rz[:2, :2]
        T_bt[:2, 2] = (cam_believed.position_w - Rz @ cam_true.position_w)[:2]
        return T_bt @ TRUTH

    trail = RegistrationTrail()
    fit = MarkFitConfig()
    worst = 0.0
    for i, x in enumerate((0.37, 1.0, 2.0, 3.3, 4.5, 5.9)):
        view, cam = shoot((x, -0.2 if i == 0 else 0.0), seed=10 + i, believed=believed)
        result = trail.register(view.color_bgr, view.depth_m, cam, MARKS, MarkDetectorConfig(), fit)
        assert result.ok and not result.registration.extrapolated, (x, result.message)
        err = error_at_studs_mm(result.registration.M_local2world, view, expected(view.camera, cam))
        naive = error_at_studs_mm(trail.stations[0].registration.M_local2world, view, expected(view.camera, cam))
        worst = max(worst, err)
        assert err < 0.5, f"station at x = {x} m: {err:.3f} mm"
        print(f"\nstation x = {x:.2f} m: marks {', '.join(result.registration.labels_used)}, error {err:.3f} mm "
              f"(the start's registration would be {naive:.2f} mm off), residual "
              f"{result.registration.residual_max_m * 1e3:.3f} mm max")
    assert naive > 4.0  # without registering along the part the far end is millimetres off
    # A station past the last mark: too few marks, the nearest registration, and how far away it was made.
    view, cam = shoot((6.5, 0.0), seed=30, believed=believed, tilt_deg=0.0)
    result = trail.register(view.color_bgr, view.depth_m, cam, MARKS, MarkDetectorConfig(), fit)
    assert result.ok and result.registration.extrapolated
    nearest = trail.stations[-1]
    assert result.registration.M_local2world is nearest.registration.M_local2world
    assert result.registration.extrapolated_m == pytest.approx(
        np.linalg.norm(nearest.position_xy_m - cam.position_w[:2]))
    assert 0.5 < result.registration.extrapolated_m < 0.7
    assert f"extrapolated {result.registration.extrapolated_m:.3f} m" in result.message
    assert "marks not found" in result.message


def test_a_mark_off_its_drawing_position_is_refused_not_papered_over_by_the_trail(middle):
    trail = RegistrationTrail()
    start_view, start_cam = shoot((0.37, -0.2), seed=2)
    assert trail.register(start_view.color_bgr, start_view.depth_m, start_cam, MARKS).ok
    view, cam = middle
    bad = dict(MARKS)
    bad["M15"] = (MARKS["M15"][0] + 0.010, MARKS["M15"][1])  # the drawing and the paint disagree by 10 mm
    result = trail.register(view.color_bgr, view.depth_m, cam, bad)
    assert not result.ok and result.refused and result.registration is None
    assert "mark M15 is" in result.message and "refused" in result.message
    assert len(trail.stations) == 1
    # the same view with the drawing right registers, and joins the trail
    assert trail.register(view.color_bgr, view.depth_m, cam, MARKS).ok and len(trail.stations) == 2
