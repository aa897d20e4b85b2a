"""Shared by every matcher: the result types, the input checks, the heights searched and the in-view interval.

:mod:`stud_planner.matching.matchers` is the public face (it re-exports all of this); the paper's
baselines live in :mod:`stud_planner.matching.paper_baselines`, ours in ``matchers``. Frames and
units as there: ``targets_xy_w`` (N, 2) metres in `world`, ``depth_m`` (H, W) float32 metres of
optical-frame z, NaN = invalid, indexed ``[v, u]``.
"""
from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from typing import Iterator

import numpy as np

from stud_common.vocabulary import TargetStatus
from stud_perception.camera_model import CameraModel
from stud_perception.depth_image import FillRule

#: Margin (m) added around the heights the depth image shows (:func:`observed_z_range`).
Z_RANGE_MARGIN_M = 0.05


def depth_samples(depth_m: np.ndarray, stride: int = 16) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every ``stride``-th pixel of a depth image: u (1, w), v (h, 1) and depth (h, w), NaN where invalid."""
    sub = depth_m[::stride, ::stride]
    sub = np.where(sub > 0, sub, np.nan)  # NaN stays NaN
    u = np.arange(0, depth_m.shape[1], stride, dtype=np.float64)[None, :]
    v = np.arange(0, depth_m.shape[0], stride, dtype=np.float64)[:, None]
    return u, v, sub


def observed_z_range(depth_m: np.ndarray, camera: CameraModel, stride: int = 16,
                     margin_m: float = Z_RANGE_MARGIN_M) -> tuple[float, float, float]:
    """(z_min, z_max, z_median) in world metres of the surfaces this depth image shows.

    The heights a stud's weld point may have: the range searched along its vertical line, and the
    range over which "out of view" is decided (perspective makes any vertical line enter the image
    far enough below the plane, so the range must be finite). Taken from the view itself -- Eq. 1
    on every ``stride``-th pixel with depth, plus ``margin_m`` -- so it holds wherever the world
    frame is: a robot base on a pedestal puts the part well below z = 0, a floor-mounted one above.
    An image without any depth gives a range around the camera's own height.
    """
    return z_range_of(observed_heights(depth_m, camera, stride), camera, margin_m)


def observed_heights(depth_m: np.ndarray, camera: CameraModel, stride: int = 16) -> tuple[float, float, float] | None:
    """(lowest, highest, median) world z of Eq. 1 on every ``stride``-th pixel with depth; None if none."""
    u, v, sub = depth_samples(depth_m, stride)
    zw = camera.pixel_to_world(u, v, sub)[..., 2]
    zw = zw[np.isfinite(zw)]
    if zw.size == 0:
        return None
    return float(zw.min()), float(zw.max()), float(np.median(zw))


def z_range_of(heights: tuple[float, float, float] | None, camera: CameraModel,
               margin_m: float = Z_RANGE_MARGIN_M) -> tuple[float, float, float]:
    """:func:`observed_z_range` from :func:`observed_heights` (one pass over the image for several margins)."""
    if heights is None:
        z = float(camera.position_w[2])
        return z - 10.0, z + 10.0, z
    return heights[0] - margin_m, heights[1] + margin_m, heights[2]


class MatchStatus(IntEnum):
    """Per-stud outcome of the matching: the matcher's subset of stud_common.vocabulary.TargetStatus."""

    OK = TargetStatus.OK
    OUT_OF_VIEW = TargetStatus.OUT_OF_VIEW
    NO_DEPTH = TargetStatus.NO_DEPTH
    NOT_CONVERGED = TargetStatus.NOT_CONVERGED
    DEPTH_DISCONTINUITY = TargetStatus.DEPTH_DISCONTINUITY


class MatchingError(ValueError):
    """Inputs a matcher cannot work with (shapes, sizes), with the offending value."""


@dataclass(frozen=True)
class MatchResult:
    """One stud's match. ``point_w`` (3,) metres in `world` is Eq. 1 of ``pixel_uv`` with the depth
    used there; ``xy_residual_m`` = |point_w[:2] - target|; NaN fields when nothing was found."""

    pixel_uv: tuple[float, float]
    point_w: np.ndarray
    iterations: int
    xy_residual_m: float
    status: MatchStatus
    hole_rule: FillRule

    @property
    def ok(self) -> bool:
        return self.status == MatchStatus.OK


@dataclass(frozen=True)
class MatchResults:
    """Matches of N studs of one frame, struct-of-arrays; ``results[i]`` is a :class:`MatchResult`.

    - ``pixel_uv`` (N, 2) float64 px, sub-pixel for the batch matcher, NaN if none;
    - ``point_w`` (N, 3) float64 m, `world`;
    - ``iterations`` (N,) int64: depth look-ups (batch) or pixels evaluated (BFS/FPM, the paper's count);
    - ``xy_residual_m`` (N,) float64 m;
    - ``status`` (N,) int8 :class:`MatchStatus`; ``hole_rule`` (N,) int8 :class:`FillRule`;
    - ``algorithm``: "bfs", "fpm" or "batch".
    """

    algorithm: str
    pixel_uv: np.ndarray
    point_w: np.ndarray
    iterations: np.ndarray
    xy_residual_m: np.ndarray
    status: np.ndarray
    hole_rule: np.ndarray

    def __post_init__(self) -> None:
        for name in ("pixel_uv", "point_w", "iterations", "xy_residual_m", "status", "hole_rule"):
            getattr(self, name).setflags(write=False)

    def __len__(self) -> int:
        return int(self.status.shape[0])

    def __getitem__(self, i: int) -> MatchResult:
        return MatchResult(
            pixel_uv=(float(self.pixel_uv[i, 0]), float(self.pixel_uv[i, 1])),
            point_w=self.point_w[i].copy(),
            iterations=int(self.iterations[i]),
            xy_residual_m=float(self.xy_residual_m[i]),
            status=MatchStatus(int(self.status[i])),
            hole_rule=FillRule(int(self.hole_rule[i])),
        )

    def __iter__(self) -> Iterator[MatchResult]:
        return (self[i] for i in range(len(self)))

    @property
    def ok(self) -> np.ndarray:
        """(N,) bool: usable matches."""
        return self.status == MatchStatus.OK

    @property
    def total_iterations(self) -> int:
        return int(self.iterations.sum())


# ---------------------------------------------------------------------------------------------
# Input checks and small geometry helpers (no Eq. 1 here: that is CameraModel's)
# ---------------------------------------------------------------------------------------------
def check_inputs(targets_xy_w, depth_m, camera: CameraModel) -> tuple[np.ndarray, np.ndarray]:
    """A matcher's inputs as (targets (N, 2) float64, depth (H, W) float); MatchingError naming what does not fit."""
    xy = np.asarray(targets_xy_w, dtype=np.float64)
    if xy.ndim == 1 and xy.shape == (2,):
        xy = xy[None, :]
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise MatchingError(f"targets_xy_w must have shape (N, 2), got {xy.shape}")
    depth = np.asarray(depth_m)
    if depth.shape != (camera.height, camera.width):
        raise MatchingError(
            f"depth image shape {depth.shape} does not match the camera's {camera.height}x{camera.width} (HxW)"
        )
    if not np.issubdtype(depth.dtype, np.floating):
        raise MatchingError(f"depth_m must be float metres with NaN = invalid, got dtype {depth.dtype}")
    return xy, depth


def empty_results(algorithm: str, n: int) -> dict:
    """The arrays of :class:`MatchResults` for ``n`` studs before a matcher fills them: nothing found yet."""
    return dict(
        algorithm=algorithm,
        pixel_uv=np.full((n, 2), np.nan),
        point_w=np.full((n, 3), np.nan),
        iterations=np.zeros(n, dtype=np.int64),
        xy_residual_m=np.full(n, np.nan),
        status=np.full(n, MatchStatus.NOT_CONVERGED, dtype=np.int8),
        hole_rule=np.full(n, FillRule.NONE, dtype=np.int8),
    )


def line_in_view_z_interval(
    camera: CameraModel, targets_xy_w: np.ndarray, z_min_m: float, z_max_m: float, min_depth_m: float = 1e-3
) -> tuple[np.ndarray, np.ndarray]:
    """Heights z in [z_min_m, z_max_m] at which the vertical line (x_w, y_w, z) projects inside the image:
    (lo, hi), each (N,); lo > hi means never in view (:meth:`CameraModel.lines_in_view`, exact)."""
    return camera.lines_in_view(camera.vertical_lines(targets_xy_w), z_min_m, z_max_m, min_depth_m)
