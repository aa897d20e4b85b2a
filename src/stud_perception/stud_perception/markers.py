"""Detection of the marking board's marks O, A, B in an RGB-D frame, lifted to world (Eq. 1).

Pipeline (paper Sec. on registration, made robust):

1. Hough circles (``HOUGH_GRADIENT_ALT``, falling back to ``HOUGH_GRADIENT``) with a radius
   range derived from the mark diameter, the working depth range and the focal length.
   Circles whose centres lie within a radius of a stronger one are one mark (ALT can split an
   elliptical mark in two) and are merged before deciding whether to fall back.
2. Sub-pixel centre per candidate: the darkness-weighted centroid of the dark blob (weights
   are the pixel's fraction of mark paint, from the blob's own dark and surround levels). A
   tilted circle images as an ellipse; the centroid is its centre, unlike the integer-edge
   Hough centre (~0.5 px bias). The blob's size must match the size its depth predicts.
   A mark near the image border is measured in a patch clipped to the image; a blob that
   touches the border is cut by it (biased centroid), dropped, and counted in the message.
3. Depth from the board around the mark, not the mark: dark paint often returns no
   structured-light depth, so the mark discs are masked and the board plane is fitted over the
   ring of board around each disc (hundreds of depths, one robust pass against a board edge or
   a step in the ring; :func:`_ring_plane_depth`). Where the ring holds too few depths,
   :func:`~stud_perception.depth_image.fill_depth_at` grows its window into the board instead;
   the rule used is reported per mark.
4. The triple whose pairwise 3D distances match the drawing's |OA|, |OB|, |AB|, labelled by
   the distances and checked for handedness (sign of OA x OB seen from above). Stud marks on
   the part are dark circles too; the distances reject them.

A bad frame is not an exception: :class:`MarkDetection` carries a status and a message.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum

import cv2
import numpy as np

from stud_perception.camera_model import CameraModel
from stud_perception.depth_image import FillRule, fill_depth_at


class MarkStatus(str, Enum):
    """Outcome of :func:`detect_marks` (lower-case values, as in reports)."""

    OK = "ok"
    NO_CANDIDATES = "no_candidates"          # fewer than three mark-like circles
    NO_DEPTH = "no_depth"                    # candidates without board depth around them
    NO_MATCHING_TRIPLE = "no_matching_triple"  # no three candidates at the drawing's distances
    MIRRORED = "mirrored"                    # distances match, handedness does not
    AMBIGUOUS = "ambiguous"                  # more than one triple matches


@dataclass(frozen=True)
class MarkDetectorConfig:
    """Tunables of :func:`detect_marks` (metres, pixels, 8-bit grey levels).

    ``depth_range_m``: camera-to-board depths to search (sets the Hough radius range).
    ``distance_tol_m``: allowed |measured - drawing| for |OA|, |OB|, |AB|.
    ``radius_tol``: allowed relative difference between a blob's radius and the radius its
    depth predicts (tilt shrinks the mean radius by sqrt(cos tilt): 0.97 at 15 deg).
    ``min_contrast``: least grey-level difference between a mark and its surround.
    ``max_candidates``: candidates kept for the triple search (strongest first).
    """

    mark_diameter_m: float = 0.02
    depth_range_m: tuple[float, float] = (0.25, 1.2)
    distance_tol_m: float = 0.004
    radius_tol: float = 0.3
    min_contrast: float = 40.0
    max_candidates: int = 40

    def __post_init__(self) -> None:
        lo, hi = self.depth_range_m
        if not (0 < lo < hi):
            raise ValueError(f"depth_range_m must be 0 < near < far, got {self.depth_range_m}")
        if self.mark_diameter_m <= 0 or self.distance_tol_m <= 0 or not (0 < self.radius_tol < 1):
            raise ValueError(
                f"mark_diameter_m and distance_tol_m must be > 0 and radius_tol in (0, 1), got "
                f"{self.mark_diameter_m}, {self.distance_tol_m}, {self.radius_tol}"
            )


@dataclass(frozen=True, eq=False)
class MarkDetection:
    """Result of :func:`detect_marks`.

    ``marks_world_m`` (3, 3) and ``marks_pixels_uv`` (3, 2): O, A, B (NaN unless OK).
    ``depth_rules`` (3,): :class:`~stud_perception.depth_image.FillRule` codes of the depth
    behind each mark. ``distance_error_m``: largest |measured - drawing| of the best triple
    (NaN when no triple could be formed). ``candidates_uv`` (K, 2), ``candidates_radius_px``
    (K,), ``candidates_world_m`` (K, 3) (NaN without depth): every mark-like circle seen.
    """

    status: MarkStatus
    message: str
    marks_world_m: np.ndarray
    marks_pixels_uv: np.ndarray
    depth_rules: np.ndarray
    distance_error_m: float
    candidates_uv: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    candidates_radius_px: np.ndarray = field(default_factory=lambda: np.zeros(0))
    candidates_world_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    @property
    def ok(self) -> bool:
        return self.status is MarkStatus.OK


# -- stage 1: Hough ---------------------------------------------------------------------------------
def _is_new_circle(c, kept) -> bool:
    """Circle ``c`` = (u, v, r) is none of ``kept``: its centre is at least the smaller radius away
    from each (min, not max: a spurious large circle must not swallow a real mark beside it)."""
    return all(math.hypot(c[0] - k[0], c[1] - k[1]) >= min(c[2], k[2]) for k in kept)


def _merge_close_circles(found: np.ndarray | None) -> np.ndarray:
    """(K, 3) distinct circles of a cv2.HoughCircles result: those whose centre lies within a
    radius of a stronger one are dropped.

    ``HOUGH_GRADIENT_ALT`` can return two circles for one elliptical mark (fx != fy, or a tilted
    board); counted twice they would hide that a mark is missing. Input and output are
    strongest first.
    """
    kept: list[np.ndarray] = []
    for c in (() if found is None else found[0].astype(np.float64)):
        if _is_new_circle(c, kept):
            kept.append(c)
    return np.array(kept).reshape(-1, 3)


def _hough_candidates(gray: np.ndarray, r_min: int, r_max: int) -> np.ndarray:
    """(K, 3) distinct circles (u, v, r) in pixels, ALT first; the classic method when ALT finds < 3."""
    blurred = cv2.GaussianBlur(gray, (5, 5), 1.0)
    min_dist = max(2.0 * r_min, 4.0)
    found = cv2.HoughCircles(
        blurred, cv2.HOUGH_GRADIENT_ALT, dp=1.5, minDist=min_dist, param1=300, param2=0.8,
        minRadius=r_min, maxRadius=r_max,
    )
    circles = _merge_close_circles(found)
    if len(circles) < 3:
        # Classic gradient Hough: accumulator threshold a quarter of the smallest circumference.
        found = cv2.HoughCircles(
            blurred, cv2.HOUGH_GRADIENT, dp=1.0, minDist=min_dist, param1=100,
            param2=max(10.0, 0.25 * 2 * math.pi * r_min), minRadius=r_min, maxRadius=r_max,
        )
        circles = _merge_close_circles(found)
    return circles


# -- stage 2: sub-pixel centre ------------------------------------------------------------------------
class _Rejected(Enum):
    """Why :func:`_refine_centre` found no mark at a Hough circle."""

    NOT_A_MARK = "not_a_mark"      # too little contrast, or no closed dark disc around the centre
    CUT_BY_BORDER = "cut_by_border"  # the dark blob reaches the image border: its centroid would be biased


def _refine_centre(gray: np.ndarray, u0: float, v0: float, r: float, min_contrast: float):
    """Darkness-weighted centroid of the dark blob near (u0, v0).

    Returns (u, v, r_eq_px, r_major_px, contrast), or a :class:`_Rejected` reason when the blob
    is not a closed dark disc or touches the image border (a partial mark gives a biased centre).
    The patch is clipped to the image, so a whole mark close to the border is still measured.
    """
    h, w = gray.shape
    half = int(math.ceil(1.8 * r)) + 2
    uc0, vc0 = int(round(u0)), int(round(v0))
    c0, r0 = max(uc0 - half, 0), max(vc0 - half, 0)
    c1, r1 = min(uc0 + half + 1, w), min(vc0 + half + 1, h)
    if c1 - c0 < 3 or r1 - r0 < 3:
        return _Rejected.NOT_A_MARK
    patch = gray[r0:r1, c0:c1].astype(np.float64)
    yy, xx = np.mgrid[r0:r1, c0:c1].astype(np.float64)
    dist = np.hypot(xx - u0, yy - v0)
    ring = patch[(dist > 1.35 * r) & (dist < 1.75 * r)]
    centre = patch[dist < 0.5 * r]
    if ring.size == 0 or centre.size == 0:
        return _Rejected.NOT_A_MARK
    bg = float(np.median(ring))
    fg = float(np.median(centre))
    contrast = bg - fg
    if contrast < min_contrast:
        return _Rejected.NOT_A_MARK
    # The connected dark region at the centre must be closed within the patch, away from the image border.
    dark = (patch < 0.5 * (bg + fg)).astype(np.uint8)
    n_lab, labels = cv2.connectedComponents(dark, connectivity=8)
    core = labels[dist < 0.5 * r]
    core = core[core > 0]
    if core.size == 0:
        return _Rejected.NOT_A_MARK
    blob = labels == np.bincount(core).argmax()
    edges = (blob[0, :].any(), blob[-1, :].any(), blob[:, 0].any(), blob[:, -1].any())
    at_border = (r0 == 0, r1 == h, c0 == 0, c1 == w)
    if any(e and b for e, b in zip(edges, at_border)):
        return _Rejected.CUT_BY_BORDER
    if any(edges):
        return _Rejected.NOT_A_MARK
    # Weights: fraction of paint per pixel, over the blob grown by two pixels (its anti-aliased rim).
    support = cv2.dilate(blob.astype(np.uint8), np.ones((3, 3), np.uint8), iterations=2).astype(bool)
    wgt = np.where(support, np.clip((bg - patch) / contrast, 0.0, 1.0), 0.0)
    m0 = wgt.sum()
    uc = float((wgt * xx).sum() / m0)
    vc = float((wgt * yy).sum() / m0)
    cu, cv_ = xx - uc, yy - vc
    cuv = (wgt * cu * cv_).sum()
    cov = np.array([[(wgt * cu * cu).sum(), cuv], [cuv, (wgt * cv_ * cv_).sum()]]) / m0
    # A uniform ellipse with semi-axes a, b has variances a^2/4 and b^2/4 along its axes.
    r_major = 2.0 * math.sqrt(max(np.linalg.eigvalsh(cov)[1], 0.0))
    return uc, vc, math.sqrt(m0 / math.pi), r_major, contrast


def _perspective_bias_px(camera: CameraModel, centres_w: np.ndarray, normal_w: np.ndarray, radius_m: float):
    """(K, 2) offset of the imaged disc's centroid from the projected disc centre.

    Perspective images a circle as an ellipse whose centre is not the image of the circle's
    centre (the near half is magnified more): ~0.1 px for our marks at 15 deg tilt. Computed
    from the disc's exact projection, a polygon of 128 circle points (shoelace centroid).
    """
    e1 = np.cross(normal_w, [1.0, 0.0, 0.0] if abs(normal_w[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal_w, e1)
    phi = np.linspace(0.0, 2 * np.pi, 128, endpoint=False)
    ring = centres_w[:, None, :] + radius_m * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2)
    u, v, _ = camera.world_to_pixel(ring)
    un, vn = np.roll(u, -1, axis=1), np.roll(v, -1, axis=1)
    cross = u * vn - un * v
    area = cross.sum(axis=1) / 2
    cu = ((u + un) * cross).sum(axis=1) / (6 * area)
    cv_ = ((v + vn) * cross).sum(axis=1) / (6 * area)
    pu, pv, _ = camera.world_to_pixel(centres_w)
    return np.column_stack([cu - pu, cv_ - pv])


# -- stage 4: the triple ---------------------------------------------------------------------------
def _best_triples(P: np.ndarray, expected: np.ndarray, turn_sign: float):
    """Score every ordered triple (i, j, k) as (O, A, B).

    Returns (err (T,), idx (T, 3), handed_ok (T,)) with err the largest |distance - drawing|.
    """
    k = len(P)
    i, j, m = np.meshgrid(np.arange(k), np.arange(k), np.arange(k), indexing="ij")
    sel = (i != j) & (i != m) & (j != m)
    idx = np.column_stack([i[sel], j[sel], m[sel]])
    D = np.linalg.norm(P[:, None, :] - P[None, :, :], axis=2)
    err = np.max(
        np.abs(np.column_stack([D[idx[:, 0], idx[:, 1]], D[idx[:, 0], idx[:, 2]], D[idx[:, 1], idx[:, 2]]]) - expected),
        axis=1,
    )
    oa = P[idx[:, 1], :2] - P[idx[:, 0], :2]
    ob = P[idx[:, 2], :2] - P[idx[:, 0], :2]
    turn = oa[:, 0] * ob[:, 1] - oa[:, 1] * ob[:, 0]
    return err, idx, np.sign(turn) == turn_sign


def _failure(status: MarkStatus, message: str, cand_uv, cand_r, cand_w, distance_error_m=float("nan")):
    return MarkDetection(
        status=status, message=message,
        marks_world_m=np.full((3, 3), np.nan),
        marks_pixels_uv=np.full((3, 2), np.nan),
        depth_rules=np.full(3, FillRule.NONE, dtype=np.int8),
        distance_error_m=float(distance_error_m),
        candidates_uv=cand_uv,
        candidates_radius_px=cand_r,
        candidates_world_m=cand_w,
    )


def detect_marks(
    color_bgr: np.ndarray,
    depth_m: np.ndarray,
    camera: CameraModel,
    drawing_marks_m,
    config: MarkDetectorConfig = MarkDetectorConfig(),
) -> MarkDetection:
    """Find marks O, A, B in a colour image (H, W, 3 BGR, or H, W grey) with registered depth.

    ``depth_m``: float metres, NaN = no depth (convert 16UC1 with
    :func:`~stud_perception.depth_image.depth_mm_to_m` first). ``drawing_marks_m``: (3, 2) O, A, B
    in the drawing frame, metres. World points follow Eq. 1 through ``camera``.
    """
    gray, depth_m = _checked_inputs(color_bgr, depth_m, camera)
    D = np.asarray(drawing_marks_m, dtype=np.float64)
    expected = np.array([np.linalg.norm(D[1] - D[0]), np.linalg.norm(D[2] - D[0]), np.linalg.norm(D[2] - D[1])])
    oa, ob = D[1] - D[0], D[2] - D[0]
    turn_sign = float(np.sign(oa[0] * ob[1] - oa[1] * ob[0]))
    found = _find_candidates(gray, camera, config)  # stages 1 and 2
    if isinstance(found, MarkDetection):
        return found
    refined, border_note = found
    lifted = _lift_candidates(np.array(refined), depth_m, camera, config, border_note)  # stage 3
    if isinstance(lifted, MarkDetection):
        return lifted
    picked = _identify_triple(lifted, expected, turn_sign, config.distance_tol_m, border_note)  # stage 4
    if isinstance(picked, MarkDetection):
        return picked
    sel, err_best = picked
    marks_uv, marks_w = _corrected_marks(lifted, sel, camera, config.mark_diameter_m / 2)  # stage 5
    return MarkDetection(
        status=MarkStatus.OK,
        message=f"marks found, largest distance error {err_best * 1000:.2f} mm",
        marks_world_m=marks_w,
        marks_pixels_uv=marks_uv,
        depth_rules=lifted.rules[sel].astype(np.int8),
        distance_error_m=float(err_best),
        candidates_uv=lifted.uv,
        candidates_radius_px=lifted.r_eq,
        candidates_world_m=lifted.world,
    )


def _checked_inputs(color_bgr: np.ndarray, depth_m, camera: CameraModel) -> tuple[np.ndarray, np.ndarray]:
    """(grey image, float depth) of :func:`detect_marks`'s inputs; ValueError for a wrong type or size."""
    depth_m = np.asarray(depth_m)
    if not np.issubdtype(depth_m.dtype, np.floating):
        raise ValueError(f"depth must be float metres with NaN = no depth, got dtype {depth_m.dtype}; "
                         "convert 16UC1 images with depth_mm_to_m")
    gray = color_bgr if color_bgr.ndim == 2 else cv2.cvtColor(color_bgr, cv2.COLOR_BGR2GRAY)
    if gray.shape != depth_m.shape or gray.shape != (camera.height, camera.width):
        raise ValueError(
            f"colour {gray.shape}, depth {depth_m.shape} and camera ({camera.height}, {camera.width}) sizes differ"
        )
    return gray, depth_m


def _find_candidates(gray: np.ndarray, camera: CameraModel, config: MarkDetectorConfig):
    """Stages 1 and 2: (refined candidates [(u, v, r_eq, r_major, contrast)], note on the marks the image
    border cuts), or the NO_CANDIDATES :class:`MarkDetection` when no mark-like blob is found."""
    # 1. Hough over the radius range the depth range allows (tilted marks image smaller).
    r_m = config.mark_diameter_m / 2
    near, far = config.depth_range_m
    r_min = max(3, int(math.floor(0.7 * camera.fx * r_m / far)))
    r_max = int(math.ceil(1.2 * camera.fx * r_m / near))
    circles = _hough_candidates(gray, r_min, r_max)

    # 2. Sub-pixel centres, duplicates merged (strongest Hough response first).
    refined: list[tuple[float, float, float, float]] = []
    cut_by_border: list[tuple[float, float, float]] = []  # Hough circles of marks the border cuts
    for u0, v0, r in circles:
        res = _refine_centre(gray, u0, v0, r, config.min_contrast)
        if res is _Rejected.CUT_BY_BORDER:
            if _is_new_circle((u0, v0, r), cut_by_border):
                cut_by_border.append((u0, v0, r))
            continue
        if isinstance(res, _Rejected):
            continue
        if any(math.hypot(res[0] - q[0], res[1] - q[1]) < 0.5 * q[2] for q in refined):
            continue
        refined.append(res)
        if len(refined) >= config.max_candidates:
            break
    border_note = (
        f"; {len(cut_by_border)} dark circle(s) cut by the image border were left out "
        "(move the camera so all three marks are fully in view)"
        if cut_by_border else ""
    )
    if not refined:
        return _failure(
            MarkStatus.NO_CANDIDATES,
            f"no dark circular marks found (Hough radius {r_min}-{r_max} px){border_note}",
            np.zeros((0, 2)), np.zeros(0), np.zeros((0, 3)),
        )
    return refined, border_note


@dataclass(frozen=True, eq=False)
class _Lifted:
    """Mark-sized candidates with their board depth (stage 3), and what re-lifting them needs."""

    uv: np.ndarray          # (K, 2) sub-pixel centres
    r_eq: np.ndarray        # (K,) equivalent-disc radius, px
    world: np.ndarray       # (K, 3) lifted with the board depth (NaN without)
    rules: np.ndarray       # (K,) FillRule of that depth
    has_depth: np.ndarray   # (K,) bool
    masked: np.ndarray      # the depth image with the mark discs removed
    reach_px: np.ndarray    # (K,) radius of each masked disc, px
    max_window: int         # fill_depth_at's window limits for this mark size
    grow_step_px: int

    def board_depth(self, uv: np.ndarray, sel) -> tuple[np.ndarray, np.ndarray]:
        """(depth (M,) m, FillRule (M,)) of the board at pixels ``uv`` (M, 2) around candidates ``sel``."""
        return _board_depth(self.masked, uv, self.reach_px[sel], self.max_window, self.grow_step_px)


#: The board under a mark: the ring from the masked disc's edge out to this many times its radius,
#: and the fewest valid depths a ring fit needs (below it, fill_depth_at's growing window decides).
RING_OUTER = 1.6
RING_MIN_POINTS = 64
#: Depths farther than this from the ring's first plane (or 3 robust sigmas, if larger) are not the
#: board: the board's edge, the table below it, a part or a hand in the ring. Above twice the depth's
#: 1 mm quantisation: on a board square to the camera the depths take two or three values only (the
#: robust sigma is 0), and a 1 mm cut dropped some of the +-1 mm ones and not the others (0.2 mm bias).
RING_STEP_M = 0.002


def _ring_plane_depth(masked: np.ndarray, u: float, v: float, reach_px: float) -> float:
    """Board depth (m) at the sub-pixel (u, v): the plane through the valid depths of the ring
    ``reach_px`` .. ``RING_OUTER * reach_px`` around it (inverse depth affine in the pixel, exact on a
    plane at any tilt), refitted twice without the depths that are not on it. NaN when the ring (or
    what is left of it) holds fewer than ``RING_MIN_POINTS`` depths or they do not surround the pixel.

    A plane through the ring's hundreds of depths, not the first few the growing window meets: at
    0.5 mm depth noise the few gave the board depth under a mark to 0.1-0.3 mm, and 0.9 mm at worst
    over 18 calibration shots, enough to turn the board 0.5 deg in one shot."""
    h, w = masked.shape
    R = RING_OUTER * reach_px
    u0, u1, v0, v1 = max(int(u - R), 0), min(int(u + R) + 2, w), max(int(v - R), 0), min(int(v + R) + 2, h)
    if u1 <= u0 or v1 <= v0:
        return float("nan")
    patch = masked[v0:v1, u0:u1]
    dv, du = np.mgrid[v0:v1, u0:u1]
    du, dv = du - u, dv - v
    with np.errstate(invalid="ignore"):
        sel = (du * du + dv * dv <= R * R) & (patch > 0)  # the disc itself is NaN in ``masked``
    z = patch[sel].astype(np.float64)
    A = np.column_stack([np.ones(z.size), du[sel], dv[sel]])
    keep = np.ones(z.size, dtype=bool)
    for _ in range(3):  # all depths, then twice without those off the plane (a step tilts the first fit)
        if keep.sum() < RING_MIN_POINTS:
            return float("nan")
        Ak = A[keep]
        # the depths must surround the pixel: a sliver of ring at an image border extrapolates
        spread = np.linalg.eigvalsh(np.cov(Ak[:, 1:].T))[0]
        if spread < (0.25 * reach_px) ** 2:
            return float("nan")
        p = np.linalg.lstsq(Ak, 1.0 / z[keep], rcond=None)[0]
        with np.errstate(divide="ignore"):
            res = z - 1.0 / (A @ p)
        sigma = 1.4826 * float(np.median(np.abs(res[keep])))
        keep = np.abs(res) <= max(3.0 * sigma, RING_STEP_M)
    return float(1.0 / p[0]) if p[0] > 0 else float("nan")


def _board_depth(masked: np.ndarray, uv: np.ndarray, reach_px: np.ndarray, max_window: int,
                 grow_step_px: int) -> tuple[np.ndarray, np.ndarray]:
    """Board depth at each of ``uv`` (M, 2): the ring's plane, else fill_depth_at's growing window."""
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    z = np.array([_ring_plane_depth(masked, u, v, r) if np.isfinite(u) and np.isfinite(v) else np.nan
                  for (u, v), r in zip(uv, np.broadcast_to(reach_px, len(uv)))])
    rules = np.where(np.isfinite(z), int(FillRule.PLANE_FIT), int(FillRule.NONE)).astype(np.int8)
    rest = ~np.isfinite(z)
    if rest.any():
        filled = fill_depth_at(masked, uv[rest, 0], uv[rest, 1], window=7, max_window=max_window, fallback="plane",
                               grow_step_px=grow_step_px)
        z[rest], rules[rest] = filled.depth_m, filled.rule
    return z, rules


def _lift_candidates(cand: np.ndarray, depth_m: np.ndarray, camera: CameraModel, config: MarkDetectorConfig,
                     border_note: str, need: int = 3):
    """Stage 3: depth of the board around each candidate (the mark discs masked, the window grown into
    the board), candidates too small or large for their depth dropped. A :class:`_Lifted`, or the
    NO_CANDIDATES / NO_DEPTH :class:`MarkDetection` when fewer than ``need`` remain."""
    uv, r_eq, r_major = cand[:, :2], cand[:, 2], cand[:, 3]
    r_m = config.mark_diameter_m / 2
    masked = np.array(depth_m, dtype=np.float32, copy=True)
    disc = np.zeros(masked.shape, dtype=np.uint8)
    reach_px = np.ceil(1.2 * r_major + 2).astype(np.int64)
    for (u, v), rr in zip(uv, reach_px):
        cv2.circle(disc, (int(round(u)), int(round(v))), int(rr), 1, -1)
    masked[disc.astype(bool)] = np.nan
    reach = int(reach_px.max())
    max_window = 2 * int(math.ceil(1.5 * reach)) + 1
    grow_step_px = max(2, 2 * (reach // 8))
    z, rules = _board_depth(masked, uv, reach_px, max_window, grow_step_px)
    world = camera.pixel_to_world(uv[:, 0], uv[:, 1], z)
    # The blob must be as large as a mark at that depth: drops stud marks and other dark dots early.
    with np.errstate(invalid="ignore", divide="ignore"):
        r_expected = camera.fx * r_m / z
        size_ok = np.abs(r_eq / r_expected - 1.0) <= config.radius_tol
    has_depth = np.isfinite(z)
    keep = size_ok | ~has_depth
    uv, r_eq, world, rules, reach_px = uv[keep], r_eq[keep], world[keep], rules[keep], reach_px[keep]
    has_depth = has_depth[keep]
    n_nodepth = int((~has_depth).sum())
    if len(uv) < need:
        return _failure(
            MarkStatus.NO_CANDIDATES,
            f"{len(uv)} mark-sized circle(s) found, need {need} (mark diameter {config.mark_diameter_m * 1000:.0f} mm)"
            f"{border_note}",
            uv, r_eq, world,
        )
    if np.count_nonzero(has_depth) < need:
        return _failure(
            MarkStatus.NO_DEPTH,
            f"{n_nodepth} of {len(uv)} mark candidates have no depth on the board around them{border_note}",
            uv, r_eq, world,
        )
    return _Lifted(uv, r_eq, world, rules, has_depth, masked, reach_px, max_window, grow_step_px)


def _identify_triple(lifted: _Lifted, expected: np.ndarray, turn_sign: float, tol: float, border_note: str):
    """Stage 4: the one triple of candidates with depth at the drawing's distances |OA|, |OB|, |AB| and
    with its handedness: (candidate indices (3,) O, A, B, its largest distance error), or the
    MIRRORED / NO_DEPTH / NO_MATCHING_TRIPLE / AMBIGUOUS :class:`MarkDetection`."""
    cand_info = (lifted.uv, lifted.r_eq, lifted.world)
    idx_depth = np.flatnonzero(lifted.has_depth)
    n_nodepth = int((~lifted.has_depth).sum())
    err, trip, handed = _best_triples(lifted.world[idx_depth], expected, turn_sign)
    best = int(np.argmin(np.where(handed, err, np.inf))) if handed.any() else -1
    if best < 0 or err[best] > tol:
        mirrored = ~handed & (err <= tol)
        if mirrored.any():
            return _failure(
                MarkStatus.MIRRORED,
                "three marks match the drawing's distances but are mirrored (OA x OB has the wrong sign): "
                "is the board upside down or mirrored?",
                *cand_info, distance_error_m=float(err[mirrored].min()),
            )
        best_any = float(err.min())
        status = MarkStatus.NO_DEPTH if n_nodepth else MarkStatus.NO_MATCHING_TRIPLE
        extra = f"; {n_nodepth} candidate(s) without depth were left out" if n_nodepth else ""
        return _failure(
            status,
            f"no three of {idx_depth.size} candidates match |OA|, |OB|, |AB| = "
            f"{', '.join(f'{e * 1000:.1f}' for e in expected)} mm within {tol * 1000:.1f} mm "
            f"(best error {best_any * 1000:.1f} mm){extra}{border_note}",
            *cand_info, distance_error_m=best_any,
        )
    same_marks = (np.sort(trip, axis=1) == np.sort(trip[best])).all(axis=1)
    rivals = handed & (err <= tol) & ~same_marks
    if rivals.any():
        return _failure(
            MarkStatus.AMBIGUOUS,
            f"{int(rivals.sum()) + 1} different triples match the drawing's distances within {tol * 1000:.1f} mm: "
            "reduce distance_tol_m or clear dark circles of the mark size from the view",
            *cand_info, distance_error_m=float(err[best]),
        )
    return idx_depth[trip[best]], err[best]


def _corrected_marks(lifted: _Lifted, sel: np.ndarray, camera: CameraModel, r_m: float,
                     normal: np.ndarray | None = None):
    """Stage 5: (marks_uv (M, 2), marks_w (M, 3)) with the perspective offset of the imaged centres
    removed, using the surface normal ``normal`` (world; default: the plane the first three marks
    span), and lifted again (Eq. 1) with the board depth at the corrected pixels."""
    uv, world = lifted.uv, lifted.world
    marks_uv = uv[sel]
    if normal is None:
        normal = np.cross(world[sel[1]] - world[sel[0]], world[sel[2]] - world[sel[0]])
        normal /= np.linalg.norm(normal)
    marks_w = world[sel]
    for _ in range(2):
        marks_uv = uv[sel] - _perspective_bias_px(camera, marks_w, normal, r_m)
        z_marks, _ = lifted.board_depth(marks_uv, sel)
        marks_w = camera.pixel_to_world(marks_uv[:, 0], marks_uv[:, 1], z_marks)
    if not np.isfinite(marks_w).all():  # cannot happen unless the correction left the board
        marks_uv, marks_w = uv[sel], world[sel]
    return marks_uv, marks_w


# -- every mark of a view (registration along a part: stud_perception.mark_registration) ---------------
@dataclass(frozen=True, eq=False)
class MarkCandidates:
    """Every mark-sized dark disc of a view with the depth of the surface around it (stages 1-3 of
    :func:`detect_marks`), before any is named: ``uv`` (K, 2) sub-pixel centres, ``radius_px`` (K,),
    ``world_m`` (K, 3) lifted with Eq. 1 (NaN rows without depth), ``has_depth`` (K,); ``note`` says
    what was left out (marks cut by the image border)."""

    uv: np.ndarray
    radius_px: np.ndarray
    world_m: np.ndarray
    has_depth: np.ndarray
    note: str
    _lifted: _Lifted

    def __len__(self) -> int:
        return int(self.uv.shape[0])

    def corrected(self, idx, camera: CameraModel, radius_m: float, normal_w=None) -> tuple[np.ndarray, np.ndarray]:
        """(uv (M, 2), world (M, 3)) of candidates ``idx`` with the perspective offset of the imaged disc
        centres removed (stage 5) for discs of ``radius_m`` on a surface of unit normal ``normal_w``
        (default: the plane of the first three)."""
        idx = np.asarray(idx, dtype=np.int64)
        n = None if normal_w is None else np.asarray(normal_w, dtype=np.float64)
        return _corrected_marks(self._lifted, idx, camera, radius_m, n)

    def board_triple(self, drawing_marks_m, tol_m: float) -> tuple[np.ndarray, float] | MarkDetection:
        """Stage 4: (candidate indices (3,) of O, A, B, largest distance error) -- the one triple at the
        drawing's |OA|, |OB|, |AB| with its handedness -- or the failed :class:`MarkDetection`."""
        D = np.asarray(drawing_marks_m, dtype=np.float64)
        expected = np.array([np.linalg.norm(D[1] - D[0]), np.linalg.norm(D[2] - D[0]), np.linalg.norm(D[2] - D[1])])
        oa, ob = D[1] - D[0], D[2] - D[0]
        turn_sign = float(np.sign(oa[0] * ob[1] - oa[1] * ob[0]))
        if np.count_nonzero(self.has_depth) < 3:
            return _failure(MarkStatus.NO_CANDIDATES, f"{int(np.count_nonzero(self.has_depth))} mark candidate(s) "
                            f"with depth, need 3 for O, A, B{self.note}", self.uv, self.radius_px, self.world_m)
        return _identify_triple(self._lifted, expected, turn_sign, tol_m, self.note)


def find_mark_candidates(color_bgr: np.ndarray, depth_m: np.ndarray, camera: CameraModel,
                         config: MarkDetectorConfig = MarkDetectorConfig()) -> MarkCandidates | MarkDetection:
    """Stages 1-3 of :func:`detect_marks` on a view: every dark disc of the mark size, lifted with the
    depth around it. A failed :class:`MarkDetection` (NO_CANDIDATES / NO_DEPTH) when none is usable."""
    gray, depth_m = _checked_inputs(color_bgr, depth_m, camera)
    found = _find_candidates(gray, camera, config)
    if isinstance(found, MarkDetection):
        return found
    refined, border_note = found
    lifted = _lift_candidates(np.array(refined), depth_m, camera, config, border_note, need=1)
    if isinstance(lifted, MarkDetection):
        return lifted
    return MarkCandidates(lifted.uv, lifted.r_eq, lifted.world, lifted.has_depth, border_note, lifted)
