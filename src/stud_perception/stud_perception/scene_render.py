"""The synthetic scene's renderer: one ray per pixel, shading, painted marks and the ground truth.

Rendering casts one ray per pixel through :class:`~stud_perception.camera_model.CameraModel`
(the one Eq. 1 implementation) and intersects it analytically with every solid, so the
noise-free depth, the surface of each pixel and the per-stud surface points and normals are
exact. Depth is the optical-frame z, quantised to millimetres in the 16UC1 image; the sensor's
imperfections (noise, holes, specular dropout) are :mod:`stud_perception.scene_sensor`'s.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from stud_perception.camera_model import CameraModel
from stud_perception.depth_image import depth_mm_to_m
from stud_perception.scene import (
    SURFACE_BOARD,
    SURFACE_COLLAR,
    SURFACE_COMPONENT,
    SURFACE_NONE,
    SURFACE_OBSTACLE,
    SURFACE_STUD,
    SURFACE_TABLE,
    SceneSpec,
    surface_height,
    surface_normal,
)
from stud_perception.scene_sensor import sensor_depth_mm, specular_mask
from stud_perception.scene_solids import Component, SceneError
from stud_perception.welded_studs import StudCollar, StudCylinder

# Appearance (8-bit grey levels before shading, BGR tints). Dark marks on a light board
# and a mid-grey table give the contrast the paper's Hough stage relies on.
_TABLE_GREY = 120.0
_BOARD_GREY = 228.0
_MARK_GREY = 22.0
_STEEL_GREY = 185.0
_STUD_MARK_GREY = 30.0
_STUD_GREY = 205.0  # bright steel of a welded stud
_COLLAR_GREY = 120.0  # its weld collar: darker, heat-tinted
_TINT_BGR = {
    SURFACE_TABLE: (0.92, 1.0, 1.06),
    SURFACE_BOARD: (1.0, 1.0, 1.0),
    SURFACE_COMPONENT: (1.04, 1.0, 0.97),
    SURFACE_OBSTACLE: (1.0, 0.98, 0.92),
    SURFACE_STUD: (0.98, 0.98, 1.02),
    SURFACE_COLLAR: (1.08, 0.96, 0.9),
}
# Lambertian shading with a light slightly off vertical, so curvature is visible in colour.
_LIGHT_DIR_W = np.array([0.25, 0.15, 1.0]) / np.linalg.norm([0.25, 0.15, 1.0])
_AMBIENT = 0.35
_WALL_SHADE = 0.55
# A stud counts as visible when the rendered depth at its pixel agrees with its own depth:
# larger than the nearest-pixel rounding error on steep surfaces, smaller than a board edge.
_VISIBLE_TOL_M = 0.002


# -- rendering ---------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class RenderedView:
    """One synthetic RGB-D frame with its ground truth.

    Images (H, W): ``color_bgr`` uint8 (H, W, 3); ``depth_mm`` uint16 16UC1 (0 = no depth);
    ``depth_exact_m`` float64 noise-free optical-frame z before quantisation and holes (NaN
    where the ray hits nothing); ``surface_id`` int8 (SURFACE_* constants); ``hole_mask`` bool
    (depth removed by the hole model). Per stud (N = len(scene.stud_ids)): ``studs_world_m``
    (N, 3) the surface point above the stud's world XY, ``stud_normals_w`` (N, 3) unit outward
    normals, ``stud_pixels_uv`` (N, 2) its projection, ``stud_visible`` (N,) in the image and
    not occluded. Marks: ``marks_world_m`` (3, 3) O, A, B and ``marks_pixels_uv`` (3, 2).
    :func:`~stud_perception.scene_cameras.distort_view` turns it into the raw images of a camera with lens distortion.
    """

    color_bgr: np.ndarray
    depth_mm: np.ndarray
    depth_exact_m: np.ndarray
    surface_id: np.ndarray
    hole_mask: np.ndarray
    camera: CameraModel
    scene: SceneSpec
    seed: int
    studs_world_m: np.ndarray
    stud_normals_w: np.ndarray
    stud_pixels_uv: np.ndarray
    stud_visible: np.ndarray
    marks_world_m: np.ndarray
    marks_pixels_uv: np.ndarray
    #: Lens distortion of the images (CameraInfo D and distortion_model); () for a pinhole view.
    distortion_d: tuple = ()
    distortion_model: str = "plumb_bob"
    #: The scene's reference marks (scene order; labels in ``scene.reference_marks``): world centres
    #: (K, 3) on the surface under them, and their projections (K, 2) (in the image or not).
    reference_marks_world_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    reference_marks_pixels_uv: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))

    @property
    def depth_m(self) -> np.ndarray:
        """The 16UC1 depth as float32 metres, NaN = no depth (what a matcher sees)."""
        return depth_mm_to_m(self.depth_mm)

    def exact_points_world(self) -> np.ndarray:
        """(H, W, 3) exact world point of every pixel's surface (NaN where nothing is hit)."""
        v, u = np.mgrid[0:self.camera.height, 0:self.camera.width]
        return self.camera.pixel_to_world(u, v, self.depth_exact_m)


def _image_window(camera: CameraModel, corners_w: np.ndarray):
    """Slices (rows, cols) of the image a world box can appear in, or None if it cannot."""
    u, v, z = camera.world_to_pixel(corners_w)
    if np.any(z <= 0):  # a corner behind the camera: the projection is unbounded
        return (slice(None), slice(None))
    u0, u1 = int(max(math.floor(u.min()) - 1, 0)), int(min(math.ceil(u.max()) + 2, camera.width))
    v0, v1 = int(max(math.floor(v.min()) - 1, 0)), int(min(math.ceil(v.max()) + 2, camera.height))
    if u0 >= u1 or v0 >= v1:
        return None
    return (slice(v0, v1), slice(u0, u1))


def _coverage(signed_dist_m: np.ndarray, pixel_m: np.ndarray) -> np.ndarray:
    """Area fraction of a pixel inside a shape from the signed distance of its centre.

    A one-pixel linear ramp is the box-filtered edge: it anti-aliases the marks so their
    image centroids are unbiased to well below 0.1 px, which the marker tests rely on.
    """
    return np.clip(0.5 - signed_dist_m / pixel_m, 0.0, 1.0)



def _patch_coverage(camera, centres_w, r_m, hit_x, hit_y, depth, px_m_per_depth, signed_distance):
    """(H, W) coverage of small painted shapes of radius ``r_m`` at world ``centres_w`` (K, 3), gathered
    in image patches around each: ``signed_distance(ex, ey, k)`` is the world-XY signed distance of
    hit points at offsets (ex, ey) from the centres ``k`` to the shape's edge (< 0 inside)."""
    h, w = depth.shape
    cover = np.zeros(h * w, dtype=np.float32)
    if len(centres_w) == 0:
        return cover.reshape(h, w)
    u, v, zc = camera.world_to_pixel(centres_w)
    with np.errstate(invalid="ignore", divide="ignore"):
        r_px = camera.fx * r_m / zc
    keep = camera.in_image(u, v, margin=-float(np.nanmax(r_px, initial=0.0)) - 2) & (zc > 0)
    if not keep.any():
        return cover.reshape(h, w)
    half = int(math.ceil(np.max(r_px[keep]) * 1.6)) + 2  # 1.6: tilted views stretch a mark
    offs = np.arange(-half, half + 1)
    dv, du = [a.ravel() for a in np.meshgrid(offs, offs, indexing="ij")]
    idx_keep = np.flatnonzero(keep)
    flat_x, flat_y, flat_d = hit_x.ravel(), hit_y.ravel(), depth.ravel()
    chunk = max(1, 2_000_000 // du.size)
    for s in range(0, idx_keep.size, chunk):
        k = idx_keep[s:s + chunk]
        cols = np.rint(u[k])[:, None].astype(np.int64) + du[None, :]
        rows = np.rint(v[k])[:, None].astype(np.int64) + dv[None, :]
        ok = (cols >= 0) & (cols < w) & (rows >= 0) & (rows < h)
        flat = np.where(ok, rows * w + cols, 0)
        ex = flat_x[flat] - centres_w[k, 0][:, None]
        ey = flat_y[flat] - centres_w[k, 1][:, None]
        cov = _coverage(signed_distance(ex, ey, k), flat_d[flat] * px_m_per_depth)
        cov = np.where(ok & np.isfinite(cov), cov, 0.0).astype(np.float32)
        np.maximum.at(cover, flat.ravel(), cov.ravel())
    return cover.reshape(h, w)


def _stud_mark_coverage(scene, camera, hit_x, hit_y, depth, px_m_per_depth):
    """(H, W) darkness coverage of the stud marks, gathered in small patches around each stud."""
    if scene.stud_mark_style == "none" or not scene.stud_ids:
        return np.zeros(depth.shape, dtype=np.float32)
    xy = scene.studs_world_xy_m
    z = surface_height(scene, xy[:, 0], xy[:, 1])
    r_m = scene.stud_mark_diameter_m / 2
    yaw = scene.drawing_to_world.yaw_rad
    cy, sy = math.cos(yaw), math.sin(yaw)

    def signed_distance(ex, ey, _k):
        if scene.stud_mark_style == "circle":
            return np.hypot(ex, ey) - r_m
        # cross with arms along the drawing axes, arm width a fifth of its length
        lx, ly = cy * ex + sy * ey, -sy * ex + cy * ey
        arm = r_m / 5
        return np.minimum(np.maximum(np.abs(lx) - r_m, np.abs(ly) - arm),
                          np.maximum(np.abs(ly) - r_m, np.abs(lx) - arm))

    return _patch_coverage(camera, np.column_stack([xy, z]), r_m, hit_x, hit_y, depth, px_m_per_depth,
                           signed_distance)


def _reference_mark_coverage(scene, camera, hits, px_m_per_depth):
    """(H, W) coverage of the reference marks: discs of the board marks' diameter painted on whatever
    top surface lies under them (part, table, board; not a wall or a welded stud)."""
    r_m = scene.board.mark_diameter_m / 2
    cover = _patch_coverage(camera, scene.reference_marks_world_m, r_m, hits.hit_x, hits.hit_y, hits.depth_exact,
                            px_m_per_depth, lambda ex, ey, _k: np.hypot(ex, ey) - r_m)
    cover[hits.wall | (hits.sid == SURFACE_STUD) | (hits.sid == SURFACE_NONE)] = 0.0
    return cover


def render(
    scene: SceneSpec,
    camera: CameraModel,
    seed: int = 0,
    depth_noise_m: float = 0.0,
    hole_fraction: float = 0.0,
    hole_blob_px: float = 6.0,
    color_noise: float = 0.0,
    mark_depth_dropout: bool = False,
    projector_offset_m: tuple[float, float, float] = (0.05, 0.0, 0.0),
    welded: tuple[StudCylinder, ...] = (),
    depth_noise_correlation_px: float = 0.0,
) -> RenderedView:
    """Ray-cast ``scene`` through ``camera`` into a colour + 16UC1 depth pair with ground truth.

    ``depth_noise_m``: std of Gaussian noise on the optical z before mm quantisation, correlated
    across pixels over ``depth_noise_correlation_px`` (the sigma of a Gaussian blur; 0: independent
    pixels; real structured-light cameras: a few pixels).
    ``hole_fraction``: fraction of pixels removed from the depth as random blobs of about
    ``hole_blob_px`` radius. ``color_noise``: std of Gaussian noise in grey levels.
    ``mark_depth_dropout``: structured light returns nothing from dark paint, so the marks
    and stud marks lose their depth too. ``projector_offset_m``: the structured-light
    projector's position in the optical frame; with the scene's ``specular_lobe_deg``, the
    component loses its depth where it mirrors the projector into the camera (a hole that moves
    with the viewpoint, unlike a dark mark). ``welded``: the studs standing on the part
    (stud_perception.welded_studs.welded_stud), seen like any other solid. Everything random is drawn from ``seed``, one
    independent stream per effect, so changing one effect leaves the others' pattern alone.
    """
    if not (0.0 <= hole_fraction < 1.0):
        raise SceneError(f"hole_fraction must be in [0, 1), got {hole_fraction}")
    if depth_noise_m < 0 or color_noise < 0 or hole_blob_px <= 0 or depth_noise_correlation_px < 0:
        raise SceneError(
            f"noise levels must be >= 0 and hole_blob_px > 0, got depth_noise_m={depth_noise_m}, "
            f"color_noise={color_noise}, hole_blob_px={hole_blob_px}, "
            f"depth_noise_correlation_px={depth_noise_correlation_px}"
        )
    rng_depth, rng_holes, rng_color = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(3))
    hits = _cast_rays(scene, camera, welded)
    grey, specular = _shade(scene, camera, hits, projector_offset_m)
    grey, mark_cover, stud_cover = _paint_marks(scene, camera, hits, grey)
    color_bgr = _colour(hits.sid, grey, color_noise, rng_color)
    dropout = (mark_cover > 0.5) | (stud_cover > 0.5) if mark_depth_dropout else None
    depth_mm, holes = sensor_depth_mm(hits.depth_exact, depth_noise_m, rng_depth, hole_fraction, hole_blob_px,
                                      rng_holes, dropout, specular, depth_noise_correlation_px)
    return _with_truth(scene, camera, hits, seed, color_bgr, depth_mm, holes)


@dataclass(frozen=True, eq=False)
class _Hits:
    """Every pixel's ray (unit optical z: ``t`` is the depth) and what it hits first."""

    o: np.ndarray             # (3,) the camera centre, world
    dx: np.ndarray            # (H, W) ray direction, world
    dy: np.ndarray
    dz: np.ndarray
    sid: np.ndarray           # (H, W) int8 SURFACE_* of the hit (SURFACE_NONE: nothing)
    wall: np.ndarray          # (H, W) the hit is on a vertical wall, not a top
    depth_exact: np.ndarray   # (H, W) optical z of the hit, NaN = nothing hit
    hit_x: np.ndarray         # (H, W) world x, y of the hit
    hit_y: np.ndarray


def _cast_rays(scene: SceneSpec, camera: CameraModel, welded: tuple[StudCylinder, ...]) -> _Hits:
    """Nearest hit over the plane, the board, the component, the obstacles and the welded studs; each
    solid is cast only over the image rectangle its bounding box projects to."""
    h, w = camera.height, camera.width
    v_pix, u_pix = np.mgrid[0:h, 0:w]
    d = camera.ray_directions_world(u_pix, v_pix)  # (H, W, 3), unit optical z: t is the depth
    dx, dy, dz = d[..., 0], d[..., 1], d[..., 2]
    o = camera.position_w
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(dz < 0, -o[2] / dz, np.inf)
    sid = np.where(np.isfinite(t), SURFACE_TABLE, SURFACE_NONE).astype(np.int8)
    wall = np.zeros((h, w), dtype=bool)
    solids: list[tuple[int, Component | StudCylinder | StudCollar]] = [(SURFACE_BOARD, scene.board_plate)]
    if scene.component is not None:
        solids.append((SURFACE_COMPONENT, scene.component))
    solids += [(SURFACE_OBSTACLE, ob) for ob in scene.obstacles]
    solids += [(SURFACE_STUD, stud) for stud in welded]
    solids += [(SURFACE_COLLAR, stud.collar) for stud in welded if stud.collar is not None]
    for surf, solid in solids:
        win = _image_window(camera, solid.bounding_box_w())
        if win is None:
            continue
        t_s, wall_s = solid.intersect(o, dx[win], dy[win], dz[win])
        closer = (t_s > 0) & (t_s < t[win])
        t[win] = np.where(closer, t_s, t[win])
        sid[win][closer] = surf
        wall[win] = np.where(closer, wall_s, wall[win])
    depth_exact = np.where(np.isfinite(t), t, np.nan)
    return _Hits(o=o, dx=dx, dy=dy, dz=dz, sid=sid, wall=wall, depth_exact=depth_exact,
                 hit_x=o[0] + depth_exact * dx, hit_y=o[1] + depth_exact * dy)


def _shade(scene: SceneSpec, camera: CameraModel, hits: _Hits, projector_offset_m) -> tuple[np.ndarray, np.ndarray]:
    """(grey (H, W) float32, specular (H, W) bool): Lambert on the top faces, a flat darker shade on
    walls (float32: colour only), and the component's pixels that mirror the projector."""
    h, w = hits.sid.shape
    sid, o = hits.sid, hits.o
    grey_lut = np.array([0.0, _TABLE_GREY, _BOARD_GREY, _STEEL_GREY, _STEEL_GREY, _STUD_GREY, _COLLAR_GREY],
                        dtype=np.float32)
    shade = np.full((h, w), _AMBIENT + (1 - _AMBIENT) * _LIGHT_DIR_W[2], dtype=np.float32)
    comp_top = (sid == SURFACE_COMPONENT) & ~hits.wall
    specular = np.zeros((h, w), dtype=bool)
    if comp_top.any() and scene.component is not None:
        n = scene.component.top_normal(hits.hit_x[comp_top], hits.hit_y[comp_top])
        shade[comp_top] = _AMBIENT + (1 - _AMBIENT) * np.clip(n @ _LIGHT_DIR_W, 0, 1)
        if scene.specular_lobe_deg > 0:
            p_hit = np.column_stack([hits.hit_x[comp_top], hits.hit_y[comp_top],
                                     o[2] + hits.depth_exact[comp_top] * hits.dz[comp_top]])
            projector = camera.R_wc @ np.asarray(projector_offset_m, dtype=np.float64) + o
            specular[comp_top] = specular_mask(n, p_hit, o, projector, scene.specular_lobe_deg)
    shade[hits.wall] = _WALL_SHADE
    return grey_lut[sid + 1] * shade, specular


def _paint_marks(scene: SceneSpec, camera: CameraModel, hits: _Hits, grey: np.ndarray):
    """(grey, mark coverage, stud-mark coverage): marks O, A, B on the board top, the reference marks on
    whatever lies under them and the stud marks on the part, anti-aliased from the exact hit points."""
    h, w = hits.sid.shape
    sid = hits.sid
    px_per_depth = 1.0 / camera.fx  # pixel footprint: metres per pixel per metre of depth
    on_board = (sid == SURFACE_BOARD) & ~hits.wall
    mark_cover = np.zeros((h, w), dtype=np.float32)
    if on_board.any():
        local = scene.drawing_to_world.apply_inverse(np.column_stack([hits.hit_x[on_board], hits.hit_y[on_board]]))
        marks = np.asarray(scene.board.marks_drawing_m)
        dist = np.min(np.hypot(local[:, 0, None] - marks[None, :, 0], local[:, 1, None] - marks[None, :, 1]), axis=1)
        mark_cover[on_board] = _coverage(dist - scene.board.mark_diameter_m / 2,
                                         hits.depth_exact[on_board] * px_per_depth)
    if scene.reference_marks:
        mark_cover = np.maximum(mark_cover, _reference_mark_coverage(scene, camera, hits, px_per_depth))
    grey = grey * (1 - mark_cover) + np.float32(_MARK_GREY) * mark_cover
    stud_cover = _stud_mark_coverage(scene, camera, hits.hit_x, hits.hit_y, hits.depth_exact, px_per_depth)
    stud_cover[(sid == SURFACE_STUD) | (sid == SURFACE_COLLAR)] = 0.0  # painted on the part, not on a stud
    grey = grey * (1 - stud_cover) + np.float32(_STUD_MARK_GREY) * stud_cover
    return grey, mark_cover, stud_cover


def _colour(sid: np.ndarray, grey: np.ndarray, color_noise: float, rng_color: np.random.Generator) -> np.ndarray:
    """(H, W, 3) uint8 BGR: the grey levels tinted per surface, with Gaussian noise of ``color_noise``."""
    tint_lut = np.ones((len(_TINT_BGR) + 1, 3), dtype=np.float32)  # SURFACE_NONE .. SURFACE_COLLAR
    for surf, bgr in _TINT_BGR.items():
        tint_lut[surf + 1] = bgr
    color = grey[..., None] * tint_lut[sid + 1]
    if color_noise > 0:
        color += rng_color.normal(0.0, color_noise, color.shape).astype(np.float32)
    return np.clip(np.rint(color), 0, 255).astype(np.uint8)


def _with_truth(scene: SceneSpec, camera: CameraModel, hits: _Hits, seed: int, color_bgr: np.ndarray,
                depth_mm: np.ndarray, holes: np.ndarray) -> RenderedView:
    """The view with its ground truth per stud (surface point, normal, pixel, visibility) and mark."""
    depth_exact = hits.depth_exact
    xy = scene.studs_world_xy_m
    z = surface_height(scene, xy[:, 0], xy[:, 1])
    studs_w = np.column_stack([xy, z])
    normals = surface_normal(scene, xy[:, 0], xy[:, 1])
    su, sv, sz = camera.world_to_pixel(studs_w)
    visible = camera.in_image(su, sv) & (sz > 0)
    vis_idx = np.flatnonzero(visible)
    if vis_idx.size:
        d_pix = depth_exact[np.rint(sv[vis_idx]).astype(int), np.rint(su[vis_idx]).astype(int)]
        visible[vis_idx] = np.abs(d_pix - sz[vis_idx]) < _VISIBLE_TOL_M
    marks_w = scene.marks_world_m
    mu, mv, _ = camera.world_to_pixel(marks_w)
    refs_w = scene.reference_marks_world_m
    ru, rv, _ = camera.world_to_pixel(refs_w)
    return RenderedView(
        color_bgr=color_bgr,
        depth_mm=depth_mm,
        depth_exact_m=depth_exact,
        surface_id=np.where(np.isfinite(depth_exact), hits.sid, SURFACE_NONE).astype(np.int8),
        hole_mask=holes,
        camera=camera,
        scene=scene,
        seed=int(seed),
        studs_world_m=studs_w,
        stud_normals_w=normals,
        stud_pixels_uv=np.column_stack([su, sv]),
        stud_visible=visible,
        marks_world_m=marks_w,
        marks_pixels_uv=np.column_stack([mu, mv]),
        reference_marks_world_m=refs_w,
        reference_marks_pixels_uv=np.column_stack([ru, rv]).reshape(-1, 2),
    )
