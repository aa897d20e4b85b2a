"""Lens distortion: raw images -> the pinhole images Eq. 1 assumes (what image_proc's rectify does).

Eq. 1 is a pinhole model. A camera whose CameraInfo carries distortion coefficients (``D``)
publishes raw images in which a point away from the image centre sits at the wrong pixel for
that model: with k1 = -0.1 a stud 500 px from the centre of a 1280x960 image at 0.5 m is off by
several millimetres. :class:`Rectifier` remaps a raw view onto the ideal pinhole camera with the
same K, once per frame from maps computed once per calibration:

* depth with nearest-neighbour lookup: depth is the optical-frame z of the point on a pixel's
  ray, and rectifying only moves rays between pixels, so each value stays valid; blending two
  depths across an edge would invent a surface;
* colour bilinearly.

Supported ``distortion_model`` values (sensor_msgs/distortion_models.hpp): ``plumb_bob`` and
``rational_polynomial`` (OpenCV's k1 k2 p1 p2 [k3 [k4 k5 k6]]), ``equidistant`` (fisheye k1..k4).
Pixels whose ray falls outside the raw image become NaN depth / black colour.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import cv2
import numpy as np

PINHOLE_MODELS = ("plumb_bob", "rational_polynomial")
FISHEYE_MODELS = ("equidistant",)
#: OpenCV's accepted lengths of a pinhole distortion vector.
_PINHOLE_LENGTHS = (4, 5, 8, 12, 14)


class RectifyError(ValueError):
    """A distortion model or coefficient vector that cannot be used (with the offending value)."""


def has_distortion(D) -> bool:
    """Whether the distortion coefficients ``D`` (any shape) hold a non-zero one."""
    d = np.asarray(D, dtype=np.float64).ravel()
    return bool(d.size and np.any(d != 0))


@dataclass(frozen=True, eq=False)
class Rectifier:
    """Remaps raw (distorted) images of a ``width`` x ``height`` camera with intrinsics ``K`` and
    distortion ``D`` of ``model`` onto the pinhole camera with the same K."""

    K: np.ndarray
    D: np.ndarray
    model: str
    width: int
    height: int
    _maps: tuple[np.ndarray, np.ndarray] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=np.float64).reshape(3, 3)
        D = np.asarray(self.D, dtype=np.float64).ravel()
        size = (int(self.width), int(self.height))
        if self.model in PINHOLE_MODELS:
            if D.size not in _PINHOLE_LENGTHS:
                raise RectifyError(f"distortion model '{self.model}' with {D.size} coefficients; expected "
                                   f"{' or '.join(map(str, _PINHOLE_LENGTHS))} (k1 k2 p1 p2 [k3 [k4 k5 k6 ...]])")
            maps = cv2.initUndistortRectifyMap(K, D, np.eye(3), K, size, cv2.CV_32FC1)
        elif self.model in FISHEYE_MODELS:
            if D.size != 4:
                raise RectifyError(f"distortion model '{self.model}' with {D.size} coefficients; expected 4 (k1..k4)")
            maps = cv2.fisheye.initUndistortRectifyMap(K, D.reshape(4, 1), np.eye(3), K, size, cv2.CV_32FC1)
        else:
            raise RectifyError(f"distortion model '{self.model}' is not supported; expected one of "
                               f"{list(PINHOLE_MODELS + FISHEYE_MODELS)}, or images that are rectified already "
                               "(image_rect topics with images_rectified:=true, plan --images-rectified)")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "D", D)
        object.__setattr__(self, "_maps", maps)

    def _check(self, image: np.ndarray, what: str) -> None:
        if image.shape[:2] != (self.height, self.width):
            raise RectifyError(f"{what} image is {image.shape[1]}x{image.shape[0]}, the calibration "
                               f"{self.width}x{self.height}")

    def depth(self, depth_m: np.ndarray) -> np.ndarray:
        """float metres (H, W), NaN = no depth -> the same on the pinhole camera (nearest neighbour)."""
        self._check(depth_m, "depth")
        map_x, map_y = self._maps
        return cv2.remap(depth_m, map_x, map_y, interpolation=cv2.INTER_NEAREST,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=float("nan"))

    def color(self, bgr: np.ndarray) -> np.ndarray:
        """uint8 colour (H, W[, C]) -> the same on the pinhole camera (bilinear; black outside)."""
        self._check(bgr, "colour")
        return cv2.remap(bgr, *self._maps, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                         borderValue=0)


@lru_cache(maxsize=4)
def _cached(K: tuple, D: tuple, model: str, width: int, height: int) -> Rectifier:
    return Rectifier(np.array(K), np.array(D), model, width, height)


def rectifier_for(K, D, model: str, width: int, height: int) -> Rectifier | None:
    """The (cached: maps cost ~20 ms) rectifier of a calibration, or None if it has no distortion."""
    if not has_distortion(D):
        return None
    return _cached(tuple(np.asarray(K, dtype=np.float64).ravel().tolist()),
                   tuple(np.asarray(D, dtype=np.float64).ravel().tolist()), str(model), int(width), int(height))
