"""Cameras for synthetic views: a camera looking at a world point, the demo's camera, and the raw
images of a camera with lens distortion (:func:`distort_view`)."""
from __future__ import annotations

import dataclasses
import math
from functools import lru_cache

import cv2
import numpy as np

from stud_perception.camera_model import CameraModel, nadir_rotation
from stud_perception.scene import SURFACE_NONE
from stud_perception.scene_render import RenderedView

# -- cameras for synthetic views ----------------------------------------------------------------
DEMO_IMAGE_SIZE = (1280, 960)
DEMO_FOV_WIDTH_M = 0.46   # field of view width at DEMO_FOV_DISTANCE_M (paper: ~460 x 360 mm)
DEMO_FOV_DISTANCE_M = 0.5


@lru_cache(maxsize=4)
def _raw_to_pinhole_maps(K: tuple, D: tuple, fisheye: bool, w: int, h: int) -> tuple[np.ndarray, np.ndarray]:
    """For every raw pixel, the pinhole pixel on its ray (about a second for 1280x960: cached)."""
    K_arr, D_arr = np.array(K).reshape(3, 3), np.array(D)
    v, u = np.mgrid[0:h, 0:w]
    raw = np.stack([u, v], axis=-1).reshape(-1, 1, 2).astype(np.float64)
    if fisheye:
        ideal = cv2.fisheye.undistortPoints(raw, K_arr, D_arr.reshape(4, 1), P=K_arr)
    else:
        ideal = cv2.undistortPoints(raw, K_arr, D_arr, P=K_arr,
                                    criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-9))
    return (ideal[:, 0, 0].reshape(h, w).astype(np.float32), ideal[:, 0, 1].reshape(h, w).astype(np.float32))


def distort_view(view: RenderedView, d, model: str = "plumb_bob") -> RenderedView:
    """The raw images a camera with K = ``view.camera.K`` and lens distortion ``d`` (OpenCV order;
    ``model`` 'plumb_bob'/'rational_polynomial' or 'equidistant') delivers of the same scene: each
    raw pixel takes the pinhole view's value along its ray (colour bilinear, depth and labels
    nearest), and the truth's pixels move likewise. Pixels whose ray leaves the pinhole image get
    no depth. What :class:`stud_perception.rectify.Rectifier` undoes."""
    K = view.camera.K
    D = np.asarray(d, dtype=np.float64).ravel()
    fisheye = model == "equidistant"
    h, w = view.depth_mm.shape
    map_u, map_v = _raw_to_pinhole_maps(tuple(K.ravel().tolist()), tuple(D.tolist()), fisheye, w, h)
    ui, vi = np.rint(map_u).astype(np.int64), np.rint(map_v).astype(np.int64)
    inside = (ui >= 0) & (ui < w) & (vi >= 0) & (vi < h)
    ui, vi = np.clip(ui, 0, w - 1), np.clip(vi, 0, h - 1)

    def nearest(img, outside):
        return np.where(inside, img[vi, ui], outside).astype(img.dtype)

    def distort_pixels(uv):
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        if len(uv) == 0:
            return uv
        xn = np.column_stack([(uv[:, 0] - K[0, 2]) / K[0, 0], (uv[:, 1] - K[1, 2]) / K[1, 1]])
        if fisheye:
            return cv2.fisheye.distortPoints(xn.reshape(-1, 1, 2), K, D.reshape(4, 1)).reshape(-1, 2)
        pts = np.column_stack([xn, np.ones(len(xn))])
        return cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K, D)[0].reshape(-1, 2)

    return dataclasses.replace(
        view,
        color_bgr=cv2.remap(view.color_bgr, map_u, map_v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT),
        depth_mm=nearest(view.depth_mm, 0), depth_exact_m=nearest(view.depth_exact_m, np.nan),
        surface_id=nearest(view.surface_id, SURFACE_NONE), hole_mask=nearest(view.hole_mask, False),
        stud_pixels_uv=distort_pixels(view.stud_pixels_uv), marks_pixels_uv=distort_pixels(view.marks_pixels_uv),
        reference_marks_pixels_uv=distort_pixels(view.reference_marks_pixels_uv),
        distortion_d=tuple(D.tolist()), distortion_model=model)


def view_camera(
    target_w,
    distance_m: float = 0.5,
    yaw_rad: float = 0.0,
    tilt_rad: float = 0.0,
    tilt_azimuth_rad: float = 0.0,
    width: int = DEMO_IMAGE_SIZE[0],
    height: int = DEMO_IMAGE_SIZE[1],
    fov_width_m: float = DEMO_FOV_WIDTH_M,
    fov_distance_m: float = DEMO_FOV_DISTANCE_M,
) -> CameraModel:
    """A camera ``distance_m`` from world point ``target_w`` looking at it.

    The viewing direction is tilted ``tilt_rad`` from straight down, the camera leaning
    toward azimuth ``tilt_azimuth_rad`` (world, from +X); ``yaw_rad`` turns the image about
    the optical axis (0: a nadir camera has optical x along world +X).
    """
    up = np.array([
        math.sin(tilt_rad) * math.cos(tilt_azimuth_rad),
        math.sin(tilt_rad) * math.sin(tilt_azimuth_rad),
        math.cos(tilt_rad),
    ])
    # Rotation taking world +Z to `up` (Rodrigues about Z x up).
    axis = np.array([-up[1], up[0], 0.0])
    s = np.linalg.norm(axis)
    if s < 1e-12:
        R_tilt = np.eye(3)
    else:
        k = axis / s
        Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        R_tilt = np.eye(3) + math.sin(tilt_rad) * Kx + (1 - math.cos(tilt_rad)) * Kx @ Kx
    R_wc = R_tilt @ nadir_rotation(yaw_rad)
    t_wc = np.asarray(target_w, dtype=np.float64) + distance_m * up
    return CameraModel.from_fov(width, height, fov_width_m, fov_distance_m, R_wc=R_wc, t_wc=t_wc)


def demo_camera() -> CameraModel:
    """The demo's nadir 1280x960 camera, 0.5 m above the dome's apex, over the demo scene."""
    return CameraModel.from_fov(
        *DEMO_IMAGE_SIZE, DEMO_FOV_WIDTH_M, DEMO_FOV_DISTANCE_M, t_wc=np.array([-0.02, 0.0, 0.55])
    )

