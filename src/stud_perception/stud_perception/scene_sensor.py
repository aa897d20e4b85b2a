"""What the synthetic scene's RGB-D sensor does to the ideal view: depth noise (independent or
correlated across pixels), millimetre quantisation, holes, dark-paint and specular dropout.

A real structured-light or stereo camera's depth noise is not independent from pixel to pixel:
each depth comes from a correlation window or a phase over its neighbours, and drivers filter
spatially. :func:`depth_noise` makes such noise (white noise blurred by a Gaussian of
``correlation_px``, rescaled to the asked standard deviation); it is what makes a normal fitted to
a window of pixels less certain than its residuals say.

A structured-light camera returns no depth in random blobs (:func:`hole_mask`), from dark paint
and where shiny steel mirrors its projector into the camera (:func:`specular_mask`). Each random
effect draws from its own generator, so changing one leaves the others' pattern alone.
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from stud_perception.depth_image import depth_m_to_mm


def hole_mask(shape: tuple[int, int], fraction: float, blob_px: float, rng: np.random.Generator) -> np.ndarray:
    """Random elliptical blobs covering at least ``fraction`` of the image (deterministic per rng)."""
    mask = np.zeros(shape, dtype=np.uint8)
    if fraction <= 0:
        return mask.astype(bool)
    h, w = shape
    target = fraction * h * w
    mean_area = math.pi * blob_px * blob_px
    covered = 0
    while covered < target:
        # Add roughly half of what is missing per round, so the overshoot stays near one blob.
        n = max(1, int(0.5 * (target - covered) / mean_area))
        cx = rng.uniform(0, w, n)
        cy = rng.uniform(0, h, n)
        ax = rng.uniform(0.5, 1.5, (n, 2)) * blob_px
        ang = rng.uniform(0, 180, n)
        for i in range(n):  # cv2 draws one ellipse per call; n is small (tens to hundreds)
            cv2.ellipse(
                mask, (int(cx[i]), int(cy[i])), (max(1, int(round(ax[i, 0]))), max(1, int(round(ax[i, 1])))),
                float(ang[i]), 0, 360, 1, -1,
            )
        covered = int(np.count_nonzero(mask))
    return mask.astype(bool)



def specular_mask(normals_w: np.ndarray, points_w: np.ndarray, camera_w: np.ndarray, projector_w: np.ndarray,
                  lobe_deg: float) -> np.ndarray:
    """(N,) which surface points (N, 3) with unit normals (N, 3) mirror the projector at ``projector_w``
    into the camera at ``camera_w`` within ``lobe_deg`` (their half vector within the lobe of the normal)."""
    to_cam = camera_w - points_w
    to_proj = projector_w - points_w
    half = (to_cam / np.linalg.norm(to_cam, axis=1, keepdims=True)
            + to_proj / np.linalg.norm(to_proj, axis=1, keepdims=True))
    cos_half = np.einsum("ni,ni->n", normals_w, half) / np.linalg.norm(half, axis=1)
    return cos_half > math.cos(math.radians(lobe_deg))


#: The most depth noise (1-sigma, m) the simulated camera offers: the cell's working envelope. Beyond about
#: 2 mm at the cell's 0.3 m views the hand-eye cannot be vouched for to 0.5 mm / 0.15 deg: a calibration's
#: 24 poses leave it too uncertain for ``verify`` to tell such an error from noise with any number of views
#: (stud_perception.hand_eye_spread), and from about 3 mm its residual limits refuse it.
MAX_DEPTH_NOISE_M = 0.002


def depth_noise(shape: tuple[int, int], sigma_m: float, correlation_px: float, rng: np.random.Generator) -> np.ndarray:
    """Gaussian depth noise (H, W) of standard deviation ``sigma_m``, correlated over ``correlation_px``
    (the sigma of the Gaussian blur of white noise; 0: independent pixels)."""
    noise = rng.normal(0.0, 1.0, shape)
    if correlation_px > 0:
        noise = cv2.GaussianBlur(noise, (0, 0), correlation_px, borderType=cv2.BORDER_REFLECT)
        noise /= max(float(noise.std()), 1e-12)
    return sigma_m * noise


def sensor_depth_mm(depth_exact_m: np.ndarray, depth_noise_m: float, rng_depth: np.random.Generator,
                    hole_fraction: float, hole_blob_px: float, rng_holes: np.random.Generator,
                    dropout: np.ndarray | None, specular: np.ndarray,
                    noise_correlation_px: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """The 16UC1 depth (0 = no depth, REP 118) the sensor delivers of the exact optical z (NaN = no hit)
    and the mask of the depth removed by holes and specular dropout.

    Noise first (Gaussian, std ``depth_noise_m``, correlated over ``noise_correlation_px``:
    :func:`depth_noise`), then mm quantisation, then the holes: random blobs (:func:`hole_mask`),
    the ``dropout`` pixels (dark paint; None: none) and the ``specular`` ones.
    """
    depth_noisy = depth_exact_m
    if depth_noise_m > 0 and noise_correlation_px > 0:
        depth_noisy = depth_exact_m + depth_noise(depth_exact_m.shape, depth_noise_m, noise_correlation_px, rng_depth)
    elif depth_noise_m > 0:  # drawn directly, not through depth_noise: a seed keeps giving the same frames
        depth_noisy = depth_exact_m + rng_depth.normal(0.0, depth_noise_m, depth_exact_m.shape)
    depth_mm = depth_m_to_mm(depth_noisy)
    holes = hole_mask(depth_exact_m.shape, hole_fraction, hole_blob_px, rng_holes)
    depth_mm[holes] = 0
    if dropout is not None:
        depth_mm[dropout] = 0
    depth_mm[specular] = 0
    return depth_mm, holes | specular
