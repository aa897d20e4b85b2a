"""Lens distortion: raw images of a distorting lens, rectified, register and match as the pinhole
images would (and without rectification they do not); the maps undo scene_cameras.distort_view; models
and coefficient vectors that cannot be used are named."""
from __future__ import annotations

import numpy as np
import pytest

from stud_perception.markers import MarkDetectorConfig
from stud_perception.rectify import Rectifier, RectifyError, has_distortion, rectifier_for
from stud_perception.scene import demo_dome_scene
from stud_perception.scene_cameras import demo_camera, distort_view
from stud_perception.scene_render import render
from stud_perception.view_registration import register_view
from stud_planner.matching.view_targets import PlannerConfig, plan_view

# A wide-angle RGB lens's barrel distortion: about 50 px at the corners of the 1280x960 image.
PLUMB_BOB = (-0.2, 0.08, 0.001, -0.0008, 0.0)
FISHEYE = (-0.02, 0.004, 0.0, 0.0)


@pytest.fixture(scope="module")
def scene_and_view():
    scene = demo_dome_scene()
    # the demo view: marks and outer studs lie where this lens moves them by about 20 px
    return scene, render(scene, demo_camera(), seed=4)


def _plan(scene, color, depth, camera):
    reg = register_view(color, depth, camera, np.asarray(scene.board.marks_drawing_m))
    assert reg.ok, reg.message
    return reg, plan_view(list(scene.stud_ids), np.asarray(scene.studs_drawing_m), reg.registration.M_local2world,
                          depth, camera, PlannerConfig())


def _position_errors(view, targets):
    ok = targets.ok
    return np.abs(targets.position_w[ok] - view.studs_world_m[ok])


def test_rectified_raw_images_register_and_match_like_the_pinhole_view(scene_and_view):
    scene, view = scene_and_view
    raw = distort_view(view, PLUMB_BOB)
    shift = np.linalg.norm(raw.stud_pixels_uv - view.stud_pixels_uv, axis=1)
    assert shift.max() > 10  # px: the raw images are far from the pinhole ones, or this proves nothing
    rect = rectifier_for(view.camera.K, PLUMB_BOB, "plumb_bob", view.camera.width, view.camera.height)
    reg, targets = _plan(scene, rect.color(raw.color_bgr), rect.depth(raw.depth_m), view.camera)
    assert np.abs(reg.registration.M_local2world - scene.M_local2world).max() < 0.001
    assert targets.ok.sum() == len(scene.stud_ids)
    err = _position_errors(view, targets)
    assert err[:, :2].max() <= 0.001 and err[:, 2].max() <= 0.0015, err.max(axis=0)


def test_raw_images_taken_for_pinhole_ones_give_wrong_positions(scene_and_view):
    """Why rectification exists: without it the marks' distances disagree with the drawing (the
    registration refuses), and with the check loosened the weld points land millimetres off."""
    scene, view = scene_and_view
    raw = distort_view(view, PLUMB_BOB)
    marks = np.asarray(scene.board.marks_drawing_m)
    refused = register_view(raw.color_bgr, raw.depth_m, view.camera, marks)
    assert not refused.ok and "within 4.0 mm" in refused.message, refused.message
    reg = register_view(raw.color_bgr, raw.depth_m, view.camera, marks, MarkDetectorConfig(distance_tol_m=0.02))
    assert reg.ok, reg.message
    targets = plan_view(list(scene.stud_ids), np.asarray(scene.studs_drawing_m), reg.registration.M_local2world,
                        raw.depth_m, view.camera, PlannerConfig())
    assert np.linalg.norm(_position_errors(view, targets)[:, :2], axis=1).max() > 0.003


@pytest.mark.parametrize("d, model", [(PLUMB_BOB, "plumb_bob"), (PLUMB_BOB + (0.0, 0.0, 0.0), "rational_polynomial"),
                                      (FISHEYE, "equidistant")])
def test_rectify_undoes_the_lens(scene_and_view, d, model):
    _, view = scene_and_view
    raw = distort_view(view, d, model)
    rect = Rectifier(view.camera.K, d, model, view.camera.width, view.camera.height)
    back = rect.depth(raw.depth_m)
    both = np.isfinite(back) & np.isfinite(view.depth_m)
    assert both.mean() > 0.9
    diff = np.abs(back[both] - view.depth_m[both])
    # two nearest-neighbour resamplings move a value by at most ~1 px: off only across depth edges
    assert np.median(diff) < 1e-4 and (diff > 0.002).mean() < 0.01
    grey = lambda img: img.astype(np.float64).mean(axis=2)  # noqa: E731
    colour_diff = np.abs(grey(rect.color(raw.color_bgr)) - grey(view.color_bgr))
    assert np.median(colour_diff[both]) < 3


def test_no_distortion_needs_no_rectifier():
    K = demo_camera().K
    assert not has_distortion([0.0] * 5) and not has_distortion([])
    assert rectifier_for(K, [0.0] * 5, "plumb_bob", 1280, 960) is None
    assert rectifier_for(K, PLUMB_BOB, "plumb_bob", 1280, 960) is rectifier_for(K, PLUMB_BOB, "plumb_bob", 1280, 960)


@pytest.mark.parametrize("d, model, message", [
    (PLUMB_BOB, "kannala_brandt", r"distortion model 'kannala_brandt' is not supported; expected one of "
                                  r"\['plumb_bob', 'rational_polynomial', 'equidistant'\]"),
    ((0.1, 0.2, 0.0), "plumb_bob", r"'plumb_bob' with 3 coefficients; expected 4 or 5 or 8 or 12 or 14"),
    (PLUMB_BOB, "equidistant", r"'equidistant' with 5 coefficients; expected 4"),
])
def test_unusable_distortion_is_named(d, model, message):
    with pytest.raises(RectifyError, match=message):
        Rectifier(demo_camera().K, d, model, 1280, 960)


def test_an_image_of_another_size_is_refused():
    rect = Rectifier(demo_camera().K, PLUMB_BOB, "plumb_bob", 1280, 960)
    with pytest.raises(RectifyError, match=r"depth image is 640x480, the calibration 1280x960"):
        rect.depth(np.zeros((480, 640), np.float32))
