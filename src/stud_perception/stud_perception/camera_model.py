"""Pinhole camera model and the paper's Eq. 1 (pixel + depth -> world), vectorised.

Frames (REP 103/105): the optical frame `camera_color_optical_frame` has z forward,
x right, y down; `world` is the RM-65 base frame with z up. Depth is registered to
colour, so one K serves both images. All lengths are metres; depth is the optical-frame
z coordinate (not the ray length), as RGB-D drivers publish it (REP 118).

This is the only place Eq. 1 lives: every matcher, the registration and the scene
renderer call :meth:`CameraModel.pixel_to_world` / :meth:`CameraModel.world_to_pixel`, and the
hot paths its derived forms: the windowed form (:meth:`CameraModel.window_to_world`), one pixel in
plain floats (:meth:`CameraModel.pixel_to_world_one`), the ray as linear in the pixel
(:meth:`CameraModel.ray_basis_world`), a vertical world line's image, projective in its height
(:meth:`CameraModel.vertical_lines`), and pixels per metre (:meth:`CameraModel.pixels_across`).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np


class CameraModelError(ValueError):
    """Camera intrinsics or pose that cannot be used (with the offending value)."""


@dataclass(frozen=True)
class CameraModel:
    """Intrinsics K (3x3, pixels) and the optical frame's pose in `world`.

    ``R_wc`` (3x3, orthonormal) and ``t_wc`` (3,, metres) map optical-frame points to
    world: ``P_w = R_wc @ P_c + t_wc``. ``width``/``height`` are the image size in pixels.
    """

    K: np.ndarray
    width: int
    height: int
    R_wc: np.ndarray
    t_wc: np.ndarray

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=np.float64).reshape(3, 3)
        R = np.asarray(self.R_wc, dtype=np.float64).reshape(3, 3)
        t = np.asarray(self.t_wc, dtype=np.float64).reshape(3)
        if not (K[0, 0] > 0 and K[1, 1] > 0):
            raise CameraModelError(f"camera K has non-positive focal length fx={K[0, 0]}, fy={K[1, 1]}")
        if self.width <= 0 or self.height <= 0:
            raise CameraModelError(f"camera image size {self.width}x{self.height} must be positive")
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise CameraModelError("camera rotation R_wc is not a proper rotation matrix")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "R_wc", R)
        object.__setattr__(self, "t_wc", t)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    # -- construction ---------------------------------------------------------------
    @classmethod
    def from_fov(
        cls,
        width: int,
        height: int,
        fov_width_m: float,
        distance_m: float,
        R_wc: np.ndarray | None = None,
        t_wc: np.ndarray | None = None,
    ) -> "CameraModel":
        """Square-pixel camera whose image spans ``fov_width_m`` at ``distance_m``.

        Default pose: looking straight down (nadir) from ``distance_m`` above the world
        origin, optical x along world +X, optical y along world -Y, optical z along world -Z.
        """
        f = width * distance_m / fov_width_m
        K = np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])
        if R_wc is None:
            R_wc = nadir_rotation()
        if t_wc is None:
            t_wc = np.array([0.0, 0.0, distance_m])
        return cls(K=K, width=width, height=height, R_wc=R_wc, t_wc=t_wc)

    def with_pose(self, R_wc: np.ndarray, t_wc: np.ndarray) -> "CameraModel":
        return CameraModel(K=self.K, width=self.width, height=self.height, R_wc=R_wc, t_wc=t_wc)

    # -- properties -----------------------------------------------------------------
    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    @property
    def position_w(self) -> np.ndarray:
        """Optical centre in world (metres)."""
        return self.t_wc

    # -- Eq. 1 --------------------------------------------------------------------------
    def pixel_to_camera(self, u, v, depth_m) -> np.ndarray:
        """Pixel (u, v) with depth z (metres) -> optical-frame point, shape (..., 3)."""
        u = np.asarray(u, dtype=np.float64)
        v = np.asarray(v, dtype=np.float64)
        z = np.asarray(depth_m, dtype=np.float64)
        x = (u - self.cx) / self.fx * z
        y = (v - self.cy) / self.fy * z
        return np.stack(np.broadcast_arrays(x, y, z), axis=-1)

    def pixel_to_world(self, u, v, depth_m) -> np.ndarray:
        """Paper Eq. 1: ``P_w = R_wc (z K^-1 [u v 1]^T) + t_wc``; shape (..., 3), metres.

        Invalid depth (NaN) propagates as NaN.
        """
        u, v, z = np.broadcast_arrays(np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64),
                                      np.asarray(depth_m, dtype=np.float64))
        x = (u - self.cx) * (z / self.fx)
        y = (v - self.cy) * (z / self.fy)
        return _rotate_translate(self.R_wc, (x, y, z), self.t_wc)

    def window_to_world(self, u0, v0, du, dv, depth_m, minus_w=None, out=None) -> np.ndarray:
        """Eq. 1 on pixel windows: pixels (u0 + du, v0 + dv) with their depth -> world points,
        component-major: (3, n, M) -- x, y, z each one contiguous (n, M) block.

        ``u0``, ``v0`` (n,) are the windows' centres, ``du``, ``dv``, ``depth_m`` (n, M) the
        offsets and depths; ``minus_w`` (n, 3), if given, is subtracted per window (points
        relative to a stud); ``out`` (3, n, M) may be a view into the caller's array. The same
        values as :meth:`pixel_to_world`, factored for speed: ``R_wc K^-1 [u v 1]`` is linear in
        (u, v), so it is the centre's ray plus ``du`` and ``dv`` times the ray's change per pixel.
        """
        base = self.ray_directions_world(np.asarray(u0, dtype=np.float64), np.asarray(v0, dtype=np.float64))
        origin = np.broadcast_to(self.t_wc, base.shape) if minus_w is None else self.t_wc - np.asarray(minus_w)
        _base, per_u, per_v = self.ray_basis_world()
        z = np.asarray(depth_m, dtype=np.float64)
        out = np.empty((3,) + z.shape) if out is None else out
        tmp = np.empty(z.shape)
        for i in range(3):
            o = out[i]
            np.multiply(du, per_u[i], out=o)
            np.multiply(dv, per_v[i], out=tmp)
            o += tmp
            o += base[:, i, None]
            o *= z
            o += origin[:, i, None]
        return out

    def pixel_to_world_one(self, u: float, v: float, depth_m: float) -> tuple[float, float, float]:
        """:meth:`pixel_to_world` of one pixel in plain floats, for per-stud loops where numpy's call
        cost dominates: the same operations in the same order, so the same values."""
        fx, fy, cx, cy, ((r00, r01, r02, t0), (r10, r11, r12, t1), (r20, r21, r22, t2)) = self._floats
        x = (u - cx) * (depth_m / fx)
        y = (v - cy) * (depth_m / fy)
        return (r00 * x + r01 * y + r02 * depth_m + t0, r10 * x + r11 * y + r12 * depth_m + t1,
                r20 * x + r21 * y + r22 * depth_m + t2)

    @cached_property
    def _floats(self) -> tuple:
        """fx, fy, cx, cy and the rows (R_wc[i], t_wc[i]) as Python floats (:meth:`pixel_to_world_one`)."""
        rows = tuple((*(float(r) for r in self.R_wc[i]), float(self.t_wc[i])) for i in range(3))
        return self.fx, self.fy, self.cx, self.cy, rows

    def ray_basis_world(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Eq. 1's ray as linear in the pixel: ``R_wc K^-1 [u v 1] = base + u per_u + v per_v`` (world,
        per metre of depth); returns (base, per_u, per_v), each (3,). ``base`` is pixel (0, 0)'s ray."""
        per_u, per_v = self.R_wc[:, 0] / self.fx, self.R_wc[:, 1] / self.fy
        return self.R_wc[:, 2] - self.cx * per_u - self.cy * per_v, per_u, per_v

    def pixels_across(self, length_m, depth_m) -> np.ndarray:
        """How many pixels (along image x) ``length_m`` spans, square to the optical axis at optical
        depth ``depth_m`` (floored at 1 um): pixels per metre there times the length."""
        return length_m * self.fx / np.maximum(depth_m, 1e-6)

    def vertical_lines(self, xy_w) -> "VerticalLines":
        """The images of the vertical world lines (x_w, y_w, z) through ``xy_w`` (N, 2): see :class:`VerticalLines`."""
        xy = np.asarray(xy_w, dtype=np.float64).reshape(-1, 2)
        n = xy.shape[0]
        A = self.world_to_camera(np.column_stack([xy, np.zeros(n)]))
        B = self.world_to_camera(np.column_stack([xy, np.ones(n)])) - A
        fx, fy, cx, cy = self.fx, self.fy, self.cx, self.cy
        return VerticalLines(A, B, a_u=fx * A[:, 0] + cx * A[:, 2], b_u=fx * B[:, 0] + cx * B[:, 2],
                             a_v=fy * A[:, 1] + cy * A[:, 2], b_v=fy * B[:, 1] + cy * B[:, 2], a_z=A[:, 2].copy(),
                             b_z=B[:, 2].copy())

    def lines_in_view(self, lines: "VerticalLines", z_min_m: float, z_max_m: float,
                      min_depth_m: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
        """Heights z in [z_min_m, z_max_m] at which each line's pixel is inside the image and at least
        ``min_depth_m`` in front of the camera: (lo, hi), each (N,); lo > hi: never in view.

        View-frustum clipping, exact: each bound ``0 <= u <= W-1``, ``0 <= v <= H-1``, ``z_c >= min_depth_m``
        is linear in z on the line P_c(z) = A + z B."""
        A, B = lines.A, lines.B
        fx, fy, cx, cy = self.fx, self.fy, self.cx, self.cy
        W1, H1 = self.width - 1, self.height - 1
        # (alpha + beta z) >= 0 for each constraint; u = fx x/z + cx >= 0 <=> fx x + cx z >= 0, etc.
        alpha = np.stack([fx * A[:, 0] + cx * A[:, 2],  # u >= 0
                          -(fx * A[:, 0] + (cx - W1) * A[:, 2]),  # u <= W-1
                          fy * A[:, 1] + cy * A[:, 2],  # v >= 0
                          -(fy * A[:, 1] + (cy - H1) * A[:, 2]),  # v <= H-1
                          A[:, 2] - min_depth_m])  # in front of the camera
        beta = np.stack([fx * B[:, 0] + cx * B[:, 2], -(fx * B[:, 0] + (cx - W1) * B[:, 2]),
                         fy * B[:, 1] + cy * B[:, 2], -(fy * B[:, 1] + (cy - H1) * B[:, 2]), B[:, 2]])
        with np.errstate(divide="ignore", invalid="ignore"):
            root = -alpha / beta
            lo = np.maximum(float(z_min_m), np.max(np.where(beta > 0, root, -np.inf), axis=0))
            hi = np.minimum(float(z_max_m), np.min(np.where(beta < 0, root, np.inf), axis=0))
            lo[np.any((beta == 0) & (alpha < 0), axis=0)] = np.inf  # a bound the line never meets
        # Shrink by a hair so rounding never puts an iterate a femtometre outside the image.
        span = hi - lo
        pad = np.where(span > 0, np.minimum(1e-9, 0.25 * span), 0.0)
        return lo + pad, hi - pad

    def world_to_camera(self, P_w) -> np.ndarray:
        P_w = np.asarray(P_w, dtype=np.float64)
        d = [P_w[..., i] - self.t_wc[i] for i in range(3)]
        return _rotate_translate(self.R_wc.T, d, np.zeros(3))

    def world_to_pixel(self, P_w) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """World points (..., 3) -> (u, v, z_cam). Points behind the camera give NaN u, v."""
        P_c = self.world_to_camera(P_w)
        z = P_c[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            safe = np.where(z > 0, z, np.nan)
            u = self.fx * P_c[..., 0] / safe + self.cx
            v = self.fy * P_c[..., 1] / safe + self.cy
        return u, v, z

    def ray_directions_world(self, u, v) -> np.ndarray:
        """World direction of the ray through pixel (u, v) per metre of depth (not unit)."""
        return self.pixel_to_camera(u, v, 1.0) @ self.R_wc.T

    def in_image(self, u, v, margin: float = 0.0) -> np.ndarray:
        u = np.asarray(u)
        v = np.asarray(v)
        return (
            np.isfinite(u) & np.isfinite(v)
            & (u >= margin) & (v >= margin)
            & (u <= self.width - 1 - margin) & (v <= self.height - 1 - margin)
        )


@dataclass(frozen=True, eq=False)
class VerticalLines:
    """The images of N vertical world lines (x_w, y_w, z) (:meth:`CameraModel.vertical_lines`).

    On each, the optical-frame point is affine in the height, ``P_c(z) = A + z B`` (A, B (N, 3)), so
    its pixel is projective in z: ``u = (a_u + b_u z) / (a_z + b_z z)``, the same for v, with
    ``a_z + b_z z`` the optical depth (the coefficients (N,) each)."""

    A: np.ndarray
    B: np.ndarray
    a_u: np.ndarray
    b_u: np.ndarray
    a_v: np.ndarray
    b_v: np.ndarray
    a_z: np.ndarray
    b_z: np.ndarray

    def pixels_at(self, idx: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(u, v) of lines ``idx`` at heights ``z`` (each (n,)), where they are in front of the camera."""
        inv_zc = 1.0 / (self.a_z[idx] + self.b_z[idx] * z)
        return (self.a_u[idx] + self.b_u[idx] * z) * inv_zc, (self.a_v[idx] + self.b_v[idx] * z) * inv_zc

    def pixel_at_one(self, i: int, z: float) -> tuple[float, float]:
        """:meth:`pixels_at` of one line in plain floats (the same operations, the same values)."""
        inv_zc = 1.0 / (self.a_z[i] + self.b_z[i] * z)
        return float((self.a_u[i] + self.b_u[i] * z) * inv_zc), float((self.a_v[i] + self.b_v[i] * z) * inv_zc)


def _rotate_translate(R: np.ndarray, xyz, t: np.ndarray) -> np.ndarray:
    """``R @ [x y z]^T + t`` for component arrays x, y, z of one shape -> (..., 3).

    Written out per component: for many points this is several times faster than a matmul of an
    (..., 3) stack with a 3x3 matrix, which numpy does not hand to BLAS as one call."""
    x, y, z = xyz
    out = np.empty(np.shape(x) + (3,))
    for i in range(3):
        out[..., i] = R[i, 0] * x + R[i, 1] * y + R[i, 2] * z + t[i]
    return out


def nadir_rotation(yaw_rad: float = 0.0) -> np.ndarray:
    """R_wc of a camera looking straight down (optical z = world -Z), rotated by yaw about world Z.

    With yaw 0, optical x is world +X and optical y is world -Y.
    """
    base = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return Rz @ base

