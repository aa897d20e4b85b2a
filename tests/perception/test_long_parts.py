"""Long parts in the synthetic scene: the cambered girder, reference marks, metre-scale components."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from stud_perception.depth_image import depth_mm_to_m
from stud_perception.scene import (
    SURFACE_COMPONENT,
    SURFACE_TABLE,
    ReferenceMark,
    SceneSpec,
    girder_scene,
    surface_height,
    surface_normal,
)
from stud_perception.scene_cameras import view_camera
from stud_perception.scene_file import scene_from_dict, scene_to_dict
from stud_perception.scene_render import render
from stud_perception.scene_solids import Cylinder, Dome, Girder, Plate, Pose2D, SceneError, Trough

GIRDER = Girder(start_xy_m=(0.3, 0.0), yaw_rad=0.0, length_m=6.0, width_m=0.4, camber_m=0.03,
                cross_slope_rad=math.radians(2.5), height_m=0.12)


def issue_z(g: Girder, u, v):
    """The issue's formula, written out independently of Girder."""
    L, c = g.length_m, g.camber_m
    R = (L * L / 4 + c * c) / (2 * c)
    return g.height_m - (R - c) + np.sqrt(R * R - (u - L / 2) ** 2) + v * math.tan(g.cross_slope_rad)


def same_solid(a, b) -> bool:
    """Equal kinds and sizes, angles to rounding (the file form holds degrees)."""
    fa, fb = dataclasses.astuple(a), dataclasses.astuple(b)
    return type(a) is type(b) and np.allclose(np.hstack(fa), np.hstack(fb), rtol=0, atol=1e-12)


def girder_world(g: Girder, u, v):
    c, s = math.cos(g.yaw_rad), math.sin(g.yaw_rad)
    return g.start_xy_m[0] + c * u - s * v, g.start_xy_m[1] + s * u + c * v


@pytest.mark.parametrize("yaw_deg", [0.0, 25.0])
def test_girder_top_follows_the_issue_formula_with_its_camber_and_slope(yaw_deg):
    g = Girder((0.3, -0.2), math.radians(yaw_deg), 6.0, 0.4, 0.03, math.radians(2.5), 0.12)
    u = np.linspace(1e-9, 6.0 - 1e-9, 61)  # the footprint's edges, inside by more than rounding
    v = np.linspace(-0.2 + 1e-9, 0.2 - 1e-9, 61)
    x, y = girder_world(g, u, v)
    z, inside = g.top_height(x, y)
    assert inside.all()
    np.testing.assert_allclose(z, issue_z(g, u, v), atol=1e-12)
    # the ends' centreline at height_m, the crown camber_m above them
    xe, ye = girder_world(g, np.array([1e-9, 3.0, 6.0 - 1e-9]), np.zeros(3))
    np.testing.assert_allclose(g.top_height(xe, ye)[0], [0.12, 0.15, 0.12], atol=1e-12)
    # outside the footprint: not the girder
    xo, yo = girder_world(g, np.array([-0.01, 6.01, 3.0]), np.array([0.0, 0.0, 0.21]))
    assert not g.top_height(xo, yo)[1].any()
    # normals: unit, the gradient's
    scene = SceneSpec(component=g)
    h = 1e-6
    gx = (surface_height(scene, x[1:-1] + h, y[1:-1]) - surface_height(scene, x[1:-1] - h, y[1:-1])) / (2 * h)
    gy = (surface_height(scene, x[1:-1], y[1:-1] + h) - surface_height(scene, x[1:-1], y[1:-1] - h)) / (2 * h)
    expect = np.column_stack([-gx, -gy, np.ones_like(gx)])
    expect /= np.linalg.norm(expect, axis=1, keepdims=True)
    np.testing.assert_allclose(surface_normal(scene, x[1:-1], y[1:-1]), expect, atol=1e-6)


def test_flat_girder_is_a_sloped_plate():
    g = Girder((0.0, 0.0), 0.0, 3.0, 0.5, 0.0, math.radians(3.0), 0.1)
    x = np.linspace(0.0, 3.0, 7)
    np.testing.assert_allclose(g.top_height(x, 0.2)[0], 0.1 + 0.2 * math.tan(math.radians(3.0)), atol=1e-15)
    view = render(SceneSpec(component=g), view_camera((1.5, 0.0, 0.1), 0.5, width=320, height=240))
    P = view.exact_points_world()[view.surface_id == SURFACE_COMPONENT]
    np.testing.assert_allclose(P[:, 2], 0.1 + P[:, 1] * math.tan(math.radians(3.0)), atol=1e-9)


@pytest.mark.parametrize("u_m", [0.15, 3.0, 5.85], ids=["start", "middle", "far_end"])
def test_girder_depth_matches_the_analytic_top_within_noise(u_m):
    scene = SceneSpec(component=GIRDER)
    x, y = girder_world(GIRDER, u_m, 0.0)
    cam = view_camera((x, y, 0.15), distance_m=0.5, tilt_rad=math.radians(10), tilt_azimuth_rad=math.radians(120))
    view = render(scene, cam, seed=4, depth_noise_m=0.0005, hole_fraction=0.02)
    top = (view.surface_id == SURFACE_COMPONENT) & (view.depth_mm > 0)
    P_exact = view.exact_points_world()[top]
    z_issue = issue_z(GIRDER, P_exact[:, 0] - GIRDER.start_xy_m[0], P_exact[:, 1] - GIRDER.start_xy_m[1])
    on_top = np.abs(P_exact[:, 2] - z_issue) < 1e-9
    assert on_top.mean() > 0.95  # the rest: the end wall the tilted view sees at the ends
    # the sensor's depth (noise 0.5 mm, mm quantisation) along each ray, against the exact one
    v, u = np.nonzero(top)
    d_err = depth_mm_to_m(view.depth_mm)[v, u] - view.depth_exact_m[v, u]
    assert abs(float(np.mean(d_err))) < 5e-5 and 0.4e-3 < float(np.std(d_err)) < 0.7e-3
    # lifted with Eq. 1, the sensor's points lie on the issue's surface within the noise
    P = cam.pixel_to_world(u, v, depth_mm_to_m(view.depth_mm)[v, u])[on_top]
    z_at = issue_z(GIRDER, P[:, 0] - GIRDER.start_xy_m[0], P[:, 1] - GIRDER.start_xy_m[1])
    assert np.percentile(np.abs(P[:, 2] - z_at), 99) < 2.0e-3


def test_girder_walls_are_vertical_and_under_the_top():
    scene = SceneSpec(component=GIRDER)
    cam = view_camera((0.3, -0.2, 0.0), distance_m=0.7, tilt_rad=math.radians(25), tilt_azimuth_rad=math.radians(225),
                      width=640, height=480)
    view = render(scene, cam)
    P = view.exact_points_world()[view.surface_id == SURFACE_COMPONENT]
    u, v = P[:, 0] - 0.3, P[:, 1]
    wall = np.abs(P[:, 2] - issue_z(GIRDER, u, v)) > 1e-9
    assert wall.sum() > 500 and (~wall).sum() > 500
    on_end, on_side = np.abs(u[wall]) < 1e-9, np.abs(np.abs(v[wall]) - 0.2) < 1e-9
    assert (on_end | on_side).all()
    assert ((P[wall, 2] >= -1e-12) & (P[wall, 2] <= issue_z(GIRDER, u[wall], v[wall]) + 1e-9)).all()


def _blob_centroid(view, uv, radius_px):
    """Darkness-weighted centroid of the dark disc around pixel ``uv``."""
    g = view.color_bgr.mean(axis=2)
    u0, v0 = np.rint(uv).astype(int)
    r = int(2 * radius_px)
    patch = g[v0 - r:v0 + r + 1, u0 - r:u0 + r + 1]
    bg = np.median(np.concatenate([patch[0], patch[-1], patch[:, 0], patch[:, -1]]))
    w = np.clip((bg - patch) / (bg - patch.min()), 0, 1)
    vv, uu = np.mgrid[v0 - r:v0 + r + 1, u0 - r:u0 + r + 1]
    return np.array([(w * uu).sum() / w.sum(), (w * vv).sum() / w.sum()])


def test_reference_marks_are_painted_where_the_drawing_puts_them_on_the_part_and_the_table():
    pose = Pose2D(0.1, -0.4, math.radians(5.0))
    on_part = pose.apply_inverse(np.array([[2.0, 0.03]]))[0]
    on_table = pose.apply_inverse(np.array([[2.1, -0.24]]))[0]
    scene = SceneSpec(component=GIRDER, drawing_to_world=pose,
                      reference_marks=(ReferenceMark("M1", on_part), ReferenceMark("M2", on_table)))
    cam = view_camera((2.05, -0.1, 0.1), distance_m=0.55, tilt_rad=math.radians(8))
    view = render(scene, cam, seed=1, mark_depth_dropout=True)
    world = scene.reference_marks_world_m
    np.testing.assert_allclose(world[:, :2], [[2.0, 0.03], [2.1, -0.24]], atol=1e-12)
    assert world[0, 2] == pytest.approx(issue_z(GIRDER, 2.0 - 0.3, 0.03)) and world[1, 2] == 0.0
    uv = view.reference_marks_pixels_uv
    assert cam.in_image(uv[:, 0], uv[:, 1], margin=40).all()
    ui, vi = np.rint(uv).astype(int).T
    assert list(view.surface_id[vi, ui]) == [SURFACE_COMPONENT, SURFACE_TABLE]
    assert (view.color_bgr[vi, ui] < 40).all()
    assert (view.depth_mm[vi, ui] == 0).all()  # dark paint: no depth, as the board's marks
    radius_px = cam.fx * scene.board.mark_diameter_m / 2 / 0.55
    for k in range(2):
        np.testing.assert_allclose(_blob_centroid(view, uv[k], radius_px), uv[k], atol=0.15)


def test_girder_scene_and_reference_marks_round_trip_through_the_file_form():
    scene = girder_scene()
    assert len(scene.stud_ids) >= 80 and len(scene.reference_marks) >= 25
    back = scene_from_dict(scene_to_dict(scene))
    assert same_solid(back.component, scene.component) and back.reference_marks == scene.reference_marks
    assert back.studs_drawing_m == scene.studs_drawing_m
    # studs and marks lie on the girder, clear of each other
    xy = scene.studs_world_xy_m
    assert scene.component.top_height(xy[:, 0], xy[:, 1])[1].all()
    marks = scene.reference_marks_world_m
    d = np.linalg.norm(marks[:, None, :2] - xy[None, :, :], axis=2)
    assert d.min() > 0.05


@pytest.mark.parametrize("component", [
    Dome((1.5, 0.0), base_radius_m=1.5, height_m=0.4),
    Cylinder((1.0, 0.0), radius_m=2.5, axis_yaw_rad=0.3, length_m=4.0, height_m=0.5),
    Trough((1.0, 0.0), radius_m=3.0, axis_yaw_rad=0.0, length_m=5.0, width_m=2.0, rim_height_m=0.6),
    Plate((2.0, 0.0), size_m=(6.0, 1.2), yaw_rad=0.1, height_m=0.3),
], ids=["dome", "cylinder", "trough", "plane"])
def test_existing_kinds_take_metre_scale_sizes(component):
    scene = scene_from_dict({"component": scene_to_dict(SceneSpec(component=component))["component"]})
    assert same_solid(scene.component, component)
    target = (*component.centre_xy_m, 0.0)
    cam = view_camera(target, distance_m=1.5, width=320, height=240)
    view = render(scene, cam)
    P = view.exact_points_world()[view.surface_id == SURFACE_COMPONENT]
    assert len(P) > 1000
    np.testing.assert_allclose(P[:, 2], surface_height(scene, P[:, 0], P[:, 1]), atol=1e-9)


@pytest.mark.parametrize("change, key", [
    ({"length_m": -1.0}, "length_m"),
    ({"width_m": 0.0}, "width_m"),
    ({"camber_m": -0.01}, "camber_m"),
    ({"camber_m": 4.0}, "camber_m"),
    ({"cross_slope_deg": 30.0, "height_m": 0.05}, "height_m"),
    ({"cross_slope_deg": 50.0}, "cross_slope_deg"),
    ({"length_m": "6 m"}, "length_m"),
    ({"yaw_deg": float("nan")}, "yaw_deg"),
    ({"start_xy_m": [0.0]}, "start_xy_m"),
    ({"lenght_m": 6.0}, "lenght_m"),
], ids=lambda x: str(x))
def test_bad_girder_sizes_name_the_key(change, key):
    d = scene_to_dict(SceneSpec(component=GIRDER))["component"]
    d.update(change)
    with pytest.raises(SceneError, match=key):
        scene_from_dict({"component": d})


def test_a_missing_girder_key_and_bad_reference_marks_are_named():
    d = scene_to_dict(SceneSpec(component=GIRDER))["component"]
    del d["width_m"]
    with pytest.raises(SceneError, match="misses key 'width_m'"):
        scene_from_dict({"component": d})
    with pytest.raises(SceneError, match="'M2' is used twice"):
        scene_from_dict({"reference_marks": [{"label": "M2", "drawing_xy_m": [0, 0]},
                                             {"label": "M2", "drawing_xy_m": [1, 0]}]})
    with pytest.raises(SceneError, match="drawing_xy_m"):
        scene_from_dict({"reference_marks": [{"label": "M1", "drawing_xy_m": [0.5]}]})
    with pytest.raises(SceneError, match="misses key 'drawing_xy_m'"):
        scene_from_dict({"reference_marks": [{"label": "M1"}]})
    with pytest.raises(SceneError, match="other than O, A, B"):
        scene_from_dict({"reference_marks": [{"label": "O", "drawing_xy_m": [0, 0]}]})
    with pytest.raises(SceneError, match="list"):
        scene_from_dict({"reference_marks": {"M1": [0, 0]}})
    with pytest.raises(SceneError, match="base_radius_m"):
        scene_from_dict({"component": {"kind": "dome", "centre_xy_m": [0, 0], "base_radius_m": "big",
                                       "height_m": 0.1}})
