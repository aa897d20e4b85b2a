"""Synthetic scene renderer: exact ground truth, determinism, speed, file form."""
from __future__ import annotations

import json
import math
import time

import numpy as np
import pytest

from stud_perception.camera_model import CameraModel
from stud_perception.depth_image import depth_mm_to_m
from stud_perception.scene import (
    SURFACE_BOARD,
    SURFACE_COMPONENT,
    SURFACE_TABLE,
    SceneSpec,
    demo_dome_scene,
    grid_stud_scene,
    surface_height,
    surface_normal,
)
from stud_perception.scene_cameras import demo_camera, view_camera
from stud_perception.scene_file import load_scene, scene_from_dict, scene_to_dict
from stud_perception.scene_render import render
from stud_perception.scene_solids import Cylinder, Dome, Plate, Pose2D, SceneError


@pytest.fixture(scope="module")
def demo_view():
    return render(demo_dome_scene(), demo_camera(), seed=3)


def test_demo_scene_matches_the_paper_set_up(demo_view):
    scene = demo_dome_scene()
    assert len(scene.stud_ids) == 17
    assert demo_view.color_bgr.shape == (960, 1280, 3) and demo_view.depth_mm.dtype == np.uint16
    assert demo_view.stud_visible.all()
    # All three marks and the whole board are in the image.
    cam = demo_view.camera
    assert cam.in_image(demo_view.marks_pixels_uv[:, 0], demo_view.marks_pixels_uv[:, 1], margin=30).all()
    o, a, b = scene.marks_world_m
    assert 0.1 <= np.linalg.norm(a - o) <= 0.15 and 0.1 <= np.linalg.norm(b - o) <= 0.15
    # Normals: upright at the apex, steeper at the outer studs.
    incl = np.degrees(np.arccos(demo_view.stud_normals_w[:, 2]))
    assert incl[0] == pytest.approx(0.0, abs=1e-9) and 10 < incl.max() < 20
    # Marks are dark on a light board.
    u, v = np.rint(demo_view.marks_pixels_uv).astype(int).T
    assert (demo_view.color_bgr[v, u] < 40).all()


def test_render_1280x960_is_fast():
    scene, cam = demo_dome_scene(), demo_camera()
    render(scene, cam, seed=0)  # warm-up
    t0 = time.perf_counter()
    render(scene, cam, seed=1, depth_noise_m=0.0005, hole_fraction=0.02)
    elapsed = time.perf_counter() - t0
    assert elapsed < 1.5, f"render took {elapsed:.2f} s"  # ~0.3 s on 2 cores; slack for a busy machine


def test_stud_depth_back_projects_to_true_point_within_quantisation(demo_view):
    cam = demo_view.camera
    uv = demo_view.stud_pixels_uv
    ui, vi = np.rint(uv).astype(int).T
    # Exact depth at the nearest pixel: only the sub-pixel offset on the slope separates them.
    _, _, z_true = cam.world_to_pixel(demo_view.studs_world_m)
    np.testing.assert_allclose(demo_view.depth_exact_m[vi, ui], z_true, atol=1e-4)
    # The 16UC1 depth, lifted with Eq. 1 at the stud's own projection: within the 0.5 mm
    # quantisation (stretched along the ray) plus the slope over half a pixel.
    z_mm = depth_mm_to_m(demo_view.depth_mm)[vi, ui]
    P = cam.pixel_to_world(uv[:, 0], uv[:, 1], z_mm)
    err = np.linalg.norm(P - demo_view.studs_world_m, axis=1)
    assert err.max() < 0.7e-3


def test_exact_pixels_lie_on_their_surfaces(demo_view):
    scene = demo_dome_scene()
    P = demo_view.exact_points_world()
    sid = demo_view.surface_id
    dome = scene.component
    on_dome = P[sid == SURFACE_COMPONENT]
    np.testing.assert_allclose(np.linalg.norm(on_dome - dome.sphere_centre_w, axis=1), dome.sphere_radius_m, atol=1e-9)
    assert (on_dome[:, 2] >= -1e-12).all()
    np.testing.assert_allclose(P[sid == SURFACE_TABLE][:, 2], 0.0, atol=1e-9)
    board_z = P[sid == SURFACE_BOARD][:, 2]
    # Board pixels are its top (z = thickness) or, at the rim, its side wall (0 < z < thickness).
    assert np.mean(np.abs(board_z - scene.board.thickness_m) < 1e-9) > 0.99
    assert ((board_z > -1e-9) & (board_z < scene.board.thickness_m + 1e-9)).all()


def test_dome_normals_are_unit_and_match_the_height_gradient():
    scene = demo_dome_scene()
    rng = np.random.default_rng(0)
    c = np.asarray(scene.component.centre_xy_m)
    r = 0.19 * np.sqrt(rng.uniform(0, 1, 200))
    a = rng.uniform(0, 2 * np.pi, 200)
    x, y = c[0] + r * np.cos(a), c[1] + r * np.sin(a)
    n = surface_normal(scene, x, y)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)
    h = 1e-6
    gx = (surface_height(scene, x + h, y) - surface_height(scene, x - h, y)) / (2 * h)
    gy = (surface_height(scene, x, y + h) - surface_height(scene, x, y - h)) / (2 * h)
    expect = np.column_stack([-gx, -gy, np.ones_like(gx)])
    expect /= np.linalg.norm(expect, axis=1, keepdims=True)
    np.testing.assert_allclose(n, expect, atol=1e-6)
    # Analytic: the normal of a sphere points away from its centre.
    p = np.column_stack([x, y, surface_height(scene, x, y)])
    np.testing.assert_allclose(n, (p - scene.component.sphere_centre_w) / scene.component.sphere_radius_m, atol=1e-12)


@pytest.mark.parametrize(
    "component",
    [
        Cylinder(centre_xy_m=(0.05, 0.0), radius_m=0.3, axis_yaw_rad=0.5, length_m=0.2, height_m=0.06),
        Plate(centre_xy_m=(0.05, 0.0), size_m=(0.2, 0.16), yaw_rad=-0.4, height_m=0.05, tilt_rad=0.2),
    ],
    ids=["cylinder", "tilted_plane"],
)
def test_normals_of_other_components_match_the_height_gradient(component):
    scene = SceneSpec(component=component, drawing_to_world=Pose2D(-0.4, 0.0, 0.0))
    rng = np.random.default_rng(1)
    x, y = rng.uniform(0.0, 0.1, 100), rng.uniform(-0.05, 0.05, 100)
    assert component.top_height(x, y)[1].all()
    h = 1e-6
    gx = (surface_height(scene, x + h, y) - surface_height(scene, x - h, y)) / (2 * h)
    gy = (surface_height(scene, x, y + h) - surface_height(scene, x, y - h)) / (2 * h)
    expect = np.column_stack([-gx, -gy, np.ones_like(gx)])
    expect /= np.linalg.norm(expect, axis=1, keepdims=True)
    np.testing.assert_allclose(surface_normal(scene, x, y), expect, atol=1e-6)


def test_surface_queries_are_vectorised_over_any_shape():
    scene = demo_dome_scene()
    x = np.linspace(-0.3, 0.3, 12).reshape(3, 4)
    assert surface_height(scene, x, 0.0).shape == (3, 4)
    assert surface_normal(scene, x, 0.0).shape == (3, 4, 3)
    o = scene.marks_world_m[0]
    assert surface_height(scene, o[0], o[1]) == pytest.approx(scene.board.thickness_m)


@pytest.mark.parametrize(
    "component",
    [
        Cylinder(centre_xy_m=(0.05, 0.0), radius_m=0.3, axis_yaw_rad=math.radians(30), length_m=0.2, height_m=0.06),
        Plate(centre_xy_m=(0.05, 0.0), size_m=(0.2, 0.16), yaw_rad=math.radians(-20), height_m=0.05,
              tilt_rad=math.radians(12)),
    ],
    ids=["cylinder", "tilted_plane"],
)
def test_other_components_render_exactly_from_a_tilted_view(component):
    scene = SceneSpec(component=component, drawing_to_world=Pose2D(-0.2, -0.05, 0.3),
                      studs_drawing_m=((0.25, 0.0), (0.22, 0.05)))
    cam = view_camera((0.0, 0.0, 0.0), distance_m=0.55, yaw_rad=0.4, tilt_rad=math.radians(15),
                      tilt_azimuth_rad=math.radians(200), width=320, height=240)
    view = render(scene, cam, seed=0)
    P = view.exact_points_world()[view.surface_id == SURFACE_COMPONENT]
    assert len(P) > 1000
    z_top = surface_height(scene, P[:, 0], P[:, 1])
    on_top = np.abs(P[:, 2] - z_top) < 1e-9
    assert on_top.mean() > 0.95  # the rest are the walls/end faces the tilted view sees
    # Wall points lie on the footprint's rim, under the top: nudged 1 um inward they are inside.
    wall = P[~on_top]
    towards_centre = np.asarray(component.centre_xy_m) - wall[:, :2]
    inner = wall[:, :2] + 1e-6 * towards_centre / np.linalg.norm(towards_centre, axis=1, keepdims=True)
    z_in, inside = component.top_height(inner[:, 0], inner[:, 1])
    outer = wall[:, :2] - 1e-6 * towards_centre / np.linalg.norm(towards_centre, axis=1, keepdims=True)
    _, inside_out = component.top_height(outer[:, 0], outer[:, 1])
    assert inside.all() and not inside_out.any()
    assert (wall[:, 2] <= z_in + 1e-9).all()
    # Ground-truth normals are unit and tilted as the part is.
    assert component.top_height(view.studs_world_m[:, 0], view.studs_world_m[:, 1])[1].all()
    assert view.stud_visible.all()
    n = surface_normal(scene, view.studs_world_m[:, 0], view.studs_world_m[:, 1])
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0)
    if isinstance(component, Plate):
        np.testing.assert_allclose(np.degrees(np.arccos(n[:, 2])), 12.0, atol=1e-9)


def test_rendering_is_deterministic_per_seed_and_holes_reach_the_fraction():
    scene, cam = demo_dome_scene(), demo_camera()
    a = render(scene, cam, seed=7, depth_noise_m=0.0005, hole_fraction=0.03, color_noise=2.0)
    b = render(scene, cam, seed=7, depth_noise_m=0.0005, hole_fraction=0.03, color_noise=2.0)
    c = render(scene, cam, seed=8, depth_noise_m=0.0005, hole_fraction=0.03, color_noise=2.0)
    np.testing.assert_array_equal(a.depth_mm, b.depth_mm)
    np.testing.assert_array_equal(a.color_bgr, b.color_bgr)
    assert not np.array_equal(a.hole_mask, c.hole_mask)
    assert 0.03 <= a.hole_mask.mean() < 0.032
    assert (a.depth_mm[a.hole_mask] == 0).all()
    # Noise is centred on the exact depth with the requested spread.
    ok = ~a.hole_mask & np.isfinite(a.depth_exact_m)
    diff = a.depth_mm[ok] / 1000.0 - a.depth_exact_m[ok]
    assert abs(diff.mean()) < 2e-5 and 0.0005 < diff.std() < 0.0006


def test_mark_depth_dropout_removes_depth_on_dark_paint():
    view = render(demo_dome_scene(), demo_camera(), seed=0, mark_depth_dropout=True)
    u, v = np.rint(view.marks_pixels_uv).astype(int).T
    assert (view.depth_mm[v, u] == 0).all()
    su, sv = np.rint(view.stud_pixels_uv).astype(int).T
    assert (view.depth_mm[sv, su] == 0).all()


def test_grid_factory_scales_to_ten_thousand_studs():
    scene = grid_stud_scene(10_000)
    assert len(scene.stud_ids) == 10_000 and len(set(scene.stud_ids)) == 10_000
    view = render(scene, demo_camera(), seed=0)
    assert view.stud_visible.all()
    assert np.isfinite(view.studs_world_m).all()


def test_scene_dict_round_trip_and_json_file(tmp_path):
    scene = demo_dome_scene()
    d = scene_to_dict(scene)
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(d))
    back = load_scene(path)
    np.testing.assert_allclose(back.M_local2world, scene.M_local2world, atol=1e-12)
    assert back.component == scene.component and back.board == scene.board
    assert back.studs_drawing_m == scene.studs_drawing_m and back.stud_ids == scene.stud_ids


def test_yaml_scene_file_with_a_cylinder(tmp_path):
    yaml = pytest.importorskip("yaml")
    path = tmp_path / "scene.yaml"
    path.write_text(yaml.safe_dump({
        "component": {"kind": "cylinder", "centre_xy_m": [0.1, 0.0], "radius_m": 0.4, "axis_yaw_deg": 90,
                      "length_m": 0.3, "height_m": 0.05},
        "drawing_to_world": {"x_m": -0.2, "y_m": 0.0, "yaw_deg": 0},
        "studs": {"xy_m": [[0.3, 0.0]], "ids": ["A1"], "mark_style": "cross"},
    }))
    scene = load_scene(path)
    assert isinstance(scene.component, Cylinder) and scene.stud_ids == ("A1",)
    assert scene.component.axis_yaw_rad == pytest.approx(math.pi / 2)
    assert surface_height(scene, 0.1, 0.0) == pytest.approx(0.05)


def test_bad_scene_descriptions_say_what_is_wrong():
    with pytest.raises(SceneError, match="radiu"):
        scene_from_dict({"component": {"kind": "dome", "centre_xy_m": [0, 0], "base_radius": 0.2, "height_m": 0.05}})
    with pytest.raises(SceneError, match="kind 'sphere'"):
        scene_from_dict({"component": {"kind": "sphere"}})
    with pytest.raises(SceneError, match="height_m <= base_radius_m"):
        Dome(centre_xy_m=(0, 0), base_radius_m=0.1, height_m=0.2)
    with pytest.raises(SceneError, match="below the working plane"):
        Plate(centre_xy_m=(0, 0), size_m=(0.2, 0.2), yaw_rad=0.0, height_m=0.01, tilt_rad=math.radians(20))


def test_view_camera_looks_at_its_target():
    target = np.array([0.1, -0.05, 0.02])
    cam = view_camera(target, distance_m=0.5, yaw_rad=2.0, tilt_rad=math.radians(15), tilt_azimuth_rad=1.0)
    u, v, z = cam.world_to_pixel(target)
    assert u == pytest.approx(cam.cx) and v == pytest.approx(cam.cy) and z == pytest.approx(0.5)
    optical_z_w = cam.R_wc[:, 2]
    assert np.degrees(np.arccos(-optical_z_w[2])) == pytest.approx(15.0)
    assert isinstance(cam, CameraModel)
