"""The limits of the hand-eye check (``verify``), from the noise and the number of views.

:func:`~stud_perception.hand_eye.check_hand_eye` solves the hand-eye ``X`` from its own ``n`` shots
and compares it with the one checked. For a correct ``X`` the two differ by noise alone; how much
follows from the marks' noise and the views, so the check's limits are derived, not fixed:

**The noise.** Each mark's 3D position (pixel + depth, Eq. 1) has noise ``sigma_along`` along its
viewing ray (the depth: the board plane fitted on a ring of pixels around the mark, about 5 % of the
camera's depth noise at the cell's 1.5 px noise correlation, 1-3 % for white noise, above a floor of
about 0.02 mm from the depth image's mm steps) and ``sigma_across`` across it (the sub-pixel centre:
about 0.001 mm at 0.3 m). Both are measured on the check's own shots: the residuals ``e`` of the
full fit (``X`` and the board free) hold noise only, whatever the hand-eye checked, and their sums
along and across the rays have expectations linear in the two variances (method of moments below:
what is reported). The limits use upper bounds: each sum taken as its own noise alone (the other's
share counted as its own) at the one-sided confidence ``NOISE_CONFIDENCE`` of a chi-square with the
degrees of freedom below (the coefficient of its own variance).

**The spread.** The fit is least squares on the marks with the ray weight ``rho`` (residual along the
ray x rho): ``W = P_c + rho^2 P_a`` per mark (``P_a = u u^T`` along the ray ``u``, ``P_c = I - P_a``).
Linearised about the solution, with ``J`` the Jacobian of the marks (3m x 12: ``X``'s rotation vector
and translation, then the board's), ``J_a = J^T P_a J``, ``J_c = J^T P_c J`` and ``H = J^T W J =
J_c + rho^2 J_a``::

    Cov(x) = H^-1 (rho^4 sigma_along^2 J_a + sigma_across^2 J_c) H^-1

    E[sum (u.e)^2]  = (m - 2 rho^2 tr(H^-1 J_a) + rho^4 tr(H^-1 J_a H^-1 J_a)) sigma_along^2
                      + tr(H^-1 J_c H^-1 J_a) sigma_across^2
    E[sum |P_c e|^2] = rho^4 tr(H^-1 J_a H^-1 J_c) sigma_along^2
                      + (2m - 2 tr(H^-1 J_c) + tr(H^-1 J_c H^-1 J_c)) sigma_across^2

with ``m = 3n`` marks. A calibration
checked against carries its own error: with ``n_ref`` shots of its own, about ``n / n_ref`` of the
check's, so the covariance is scaled by ``1 + n / n_ref``.

**The limits.** The translation difference ``|dt|`` of a correct ``X`` stays below
``b_mm = sqrt(chi2_3(1 - ALPHA) * lambda_max(Cov_t))`` with probability ``1 - ALPHA`` (likewise the
rotation, ``b_deg``). The check must catch an error of ``check_max_mm`` (``check_max_deg``): it fails
when the difference exceeds ``check_max_mm - b_mm``, which an error of ``check_max_mm`` does unless the
noise exceeds ``b_mm``, and a correct ``X`` does not unless the noise exceeds ``check_max_mm - b_mm``.
Both hold when ``b_mm <= check_max_mm / 2``: the check is **conclusive**. When it is not, no limit
separates a correct hand-eye from a wrong one at this noise with these views; the check fails as
inconclusive and says how many views would do: ``b^2 = K (1/n + 1/n_ref)`` (the check's share falls
with its views, the calibration's does not), so ``n_needed = 1 / ((check_max / 2)^2 / K - 1/n_ref)``
(the larger of translation and rotation, 5 % more), or none (0) when the calibration's own shots leave
it too uncertain to be vouched for at this noise: recalibrate with more poses.

Pure numpy (and the standard library's normal quantile).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

#: Probability that a correct hand-eye's check differs by more than the bound (per quantity).
ALPHA = 1e-3
#: Confidence of the upper bound taken on the measured noise (one-sided).
NOISE_CONFIDENCE = 0.99


def chi2_quantile(dof: float, p: float) -> float:
    """The ``p`` quantile of chi-square with ``dof`` degrees of freedom (Wilson-Hilferty; within 1 %
    for dof >= 3 at the tails used here)."""
    z = NormalDist().inv_cdf(p)
    k = max(float(dof), 1.0)
    return k * max(1.0 - 2.0 / (9.0 * k) + z * math.sqrt(2.0 / (9.0 * k)), 0.0) ** 3


@dataclass(frozen=True)
class MarkNoise:
    """The marks' noise (m, 1-sigma per component) along and across their viewing rays, as measured
    (``*_m``) and at the upper confidence bound used (``*_bound_m``)."""

    along_m: float
    across_m: float
    along_bound_m: float
    across_bound_m: float


@dataclass(frozen=True)
class CheckLimits:
    """What a correct hand-eye's check may differ by (``bound_*``: noise alone, at ``1 - ALPHA``), the
    pass limits (``limit_*`` = the error to catch minus the bound), whether they separate the two
    (``conclusive``), and the views that would (``views_needed``; the views taken when conclusive; 0:
    no number of views, the calibration checked is itself too uncertain at this noise)."""

    noise: MarkNoise
    bound_mm: float
    bound_deg: float
    limit_mm: float
    limit_deg: float
    conclusive: bool
    views: int
    views_needed: int

    def describe(self) -> str:
        return (f"noise alone moves it up to {self.bound_mm:.3f} mm / {self.bound_deg:.4f} deg with {self.views} views "
                f"(the marks' noise {self.noise.along_m * 1e3:.4f} mm along the ray, "
                f"{self.noise.across_m * 1e3:.4f} mm across)")


def _weights(rays: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Block-diagonal projectors as (m, 3, 3) stacks: along each ray and across it."""
    Pa = np.einsum("mi,mj->mij", rays, rays)
    return Pa, np.eye(3)[None] - Pa


def _blocks(J: np.ndarray, P: np.ndarray) -> np.ndarray:
    """J^T P J for block-diagonal P (m, 3, 3) and J (3m, p)."""
    Jm = J.reshape(P.shape[0], 3, -1)
    return np.einsum("mip,mij,mjq->pq", Jm, P, Jm)


def fit_statistics(J: np.ndarray, rays: np.ndarray, ray_weight: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(H^-1, J_a, J_c)`` of the weighted fit (module docstring); ``J`` (3m, p), ``rays`` (m, 3) unit."""
    Pa, Pc = _weights(rays)
    Ja, Jc = _blocks(J, Pa), _blocks(J, Pc)
    H = Jc + ray_weight ** 2 * Ja
    return np.linalg.pinv(H), Ja, Jc


def measure_mark_noise(residuals: np.ndarray, rays: np.ndarray, J: np.ndarray, ray_weight: float,
                       confidence: float = NOISE_CONFIDENCE) -> MarkNoise:
    """The marks' noise from the full fit's residuals (m, 3) (method of moments, module docstring)."""
    Hi, Ja, Jc = fit_statistics(J, rays, ray_weight)
    r2, r4 = ray_weight ** 2, ray_weight ** 4
    m = len(rays)
    along = np.einsum("mi,mi->m", residuals, rays)
    s_a = float(np.sum(along ** 2))
    s_c = float(np.sum(residuals ** 2)) - s_a
    A = np.array([[m - 2 * r2 * np.trace(Hi @ Ja) + r4 * np.trace(Hi @ Ja @ Hi @ Ja), np.trace(Hi @ Jc @ Hi @ Ja)],
                  [r4 * np.trace(Hi @ Ja @ Hi @ Jc), 2 * m - 2 * np.trace(Hi @ Jc) + np.trace(Hi @ Jc @ Hi @ Jc)]])
    var = np.linalg.lstsq(A, np.array([s_a, s_c]), rcond=None)[0]
    var_a, var_c = max(float(var[0]), 0.0), max(float(var[1]), 0.0)
    dof_a, dof_c = max(float(A[0, 0]), 1.0), max(float(A[1, 1]), 1.0)
    # The bounds: each sum as if it held its own noise only (the other's share, >= 0, counted as its
    # own: conservative), at the upper confidence bound of a chi-square with its degrees of freedom;
    # a nanometre at least, so that a noiseless synthetic check still gets finite, positive bounds.
    up_a = max(s_a, 1e-18 * dof_a) / chi2_quantile(dof_a, 1.0 - confidence)
    up_c = max(s_c, 1e-18 * dof_c) / chi2_quantile(dof_c, 1.0 - confidence)
    return MarkNoise(math.sqrt(var_a), math.sqrt(var_c), math.sqrt(up_a), math.sqrt(up_c))


def solution_covariance(J: np.ndarray, rays: np.ndarray, ray_weight: float, noise: MarkNoise) -> np.ndarray:
    """Cov(x) (p, p) of the weighted fit at the noise's upper bounds (module docstring)."""
    Hi, Ja, Jc = fit_statistics(J, rays, ray_weight)
    return Hi @ (ray_weight ** 4 * noise.along_bound_m ** 2 * Ja + noise.across_bound_m ** 2 * Jc) @ Hi


def check_limits(cov_x: np.ndarray, noise: MarkNoise, views: int, catch_mm: float, catch_deg: float,
                 reference_views: int = 0, alpha: float = ALPHA) -> CheckLimits:
    """The check's limits from ``cov_x`` (the first six parameters: ``X``'s rotation vector, rad, and
    translation, m) for errors of ``catch_mm`` / ``catch_deg`` (``check_max_mm`` / ``check_max_deg``).
    ``reference_views``: the shots of the calibration checked (0: not known, taken as exact)."""
    r = 1.0 / reference_views if reference_views > 0 else 0.0
    q = chi2_quantile(3, 1.0 - alpha)
    C = np.asarray(cov_x, dtype=np.float64)[:6, :6] * (1.0 + views * r)
    b_deg = math.degrees(math.sqrt(q * max(float(np.linalg.eigvalsh(C[:3, :3])[-1]), 0.0)))
    b_mm = 1e3 * math.sqrt(q * max(float(np.linalg.eigvalsh(C[3:, 3:])[-1]), 0.0))
    conclusive = b_mm <= catch_mm / 2 and b_deg <= catch_deg / 2
    needed = views
    if not conclusive:
        # b^2 = K (1/n + 1/n_ref): the check's share falls with its views, the calibration's does not
        inv_n = min((catch / 2) ** 2 / (b ** 2 / (1.0 / views + r)) - r
                    for b, catch in ((b_mm, catch_mm), (b_deg, catch_deg)))
        needed = max(views + 1, math.ceil(1.05 / inv_n)) if inv_n > 0 else 0
    return CheckLimits(noise, b_mm, b_deg, catch_mm - b_mm, catch_deg - b_deg, conclusive, views, needed)
