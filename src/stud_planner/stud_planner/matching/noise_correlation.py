"""How far a depth frame's noise is correlated across pixels, and how much that widens a fit's error.

A least-squares fit's own covariance (the residual variance times the inverse normal matrix) holds
only if every sample's noise is independent. An RGB-D camera's is not: a structured-light or stereo
camera computes each pixel's depth from a correlation window or a phase over its neighbours, and
most drivers filter the depth spatially. A window of n pixels then holds far fewer than n
independent samples, and the fit's covariance understates the error of its slope -- the normal --
by the square root of the variance inflation factor

    VIF = sum over all lags (k, l) of rho(k, l),

rho the noise's autocorrelation (for a window much larger than the correlation length). Left out,
the reported 1-sigma can be many times smaller than the normal's true error, and a stud beyond the
lean budget passes (bench/RESULTS.md, *Correlated depth noise*).

The autocorrelation is measured on the frame, on rows and columns of pixels beside the studs (the
surface where it matters; not through them, where a painted stud mark may return no depth), by the
third-difference variogram

    T(k) = E[(d(x + 2k) - 3 d(x + k) + 3 d(x) - d(x - k))^2] = sigma^2 (20 - 30 rho(k) + 12 rho(2k) - 2 rho(3k)),

which a quadratic profile (the part's curvature along the row) leaves untouched: no surface model,
no mean to remove. With rho = 0 beyond ``max_lag_px``, sigma^2 = T(K) / 20 and rho(k) follows from
the largest lag down. Rows and columns give rho along u and v; rho(k, l) = rho_u(k) rho_v(l)
(exact for a Gaussian or box correlation kernel). The sum of the lags stops at the first rho under
:data:`RHO_CUTOFF` (the estimate's own noise would otherwise add up over the lags). A segment holding a
depth step (a part edge) is left out; pixels without depth are skipped.

Correlated samples are also redundant: where rho(1) is high, a window sampled every second or
third pixel holds nearly as many independent samples as one sampled at every pixel.
:meth:`NoiseCorrelation.redundant_step` picks the sample step that costs the normal at most a
given fraction of its 1-sigma, sigma(s) / sigma(1) = sqrt(s^2 VIF(s) / VIF(1)); on independent
noise that is every pixel (the ratios on the benchmark scenes: bench/RESULTS.md, *Correlated pixels
sampled sparsely*).

Limits: a correlation longer than about ``max_lag_px`` / 3 (Gaussian sigma) is underestimated, and
the factor is for windows much wider than the correlation; it is capped at the window's sample
count (perfectly correlated samples). Pure numpy; depth in metres, NaN = no depth.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: The sum of the autocorrelation over the lags stops at the first lag whose rho is under this.
RHO_CUTOFF = 0.05
#: Fewer third differences than this at a lag: the frame cannot tell, the noise is taken as independent.
MIN_DIFFERENCES = 200
#: Noise under this (m, 1-sigma) is none to speak of: an exact or noise-free frame.
MIN_NOISE_M = 1e-6
#: The largest sample step :meth:`NoiseCorrelation.redundant_step` returns (px).
MAX_SAMPLE_STEP = 4


@dataclass(frozen=True)
class NoiseCorrelation:
    """The depth noise's autocorrelation along image rows (``rho_u``) and columns (``rho_v``) at
    lags 0..K px, and its standard deviation ``sigma_m`` (NaN: not measured). ``measured`` is
    False where the frame could not tell; the noise is then taken as independent (rho = 0)."""

    rho_u: np.ndarray
    rho_v: np.ndarray
    sigma_m: float
    measured: bool

    @classmethod
    def independent(cls, max_lag_px: int = 0) -> "NoiseCorrelation":
        rho = np.zeros(max_lag_px + 1)
        rho[0] = 1.0
        return cls(rho, rho.copy(), float("nan"), False)

    def inflation(self, step_px) -> np.ndarray:
        """The variance inflation factor (>= 1) of a fit to samples every ``step_px`` pixels
        (int or int array) in both directions: sum_u(step) * sum_v(step)."""
        step = np.maximum(np.asarray(step_px, dtype=np.int64), 1)
        steps, inverse = np.unique(step, return_inverse=True)
        f = np.array([_lag_sum(self.rho_u, s) * _lag_sum(self.rho_v, s) for s in steps.tolist()])
        return f[inverse].reshape(step.shape)

    def redundant_step(self, max_loss: float, max_step: int = MAX_SAMPLE_STEP) -> int:
        """The largest sample step s <= ``max_step`` (px, both directions) whose fit's normal 1-sigma
        is at most ``1 + max_loss`` times that of a fit to every pixel: sqrt(s^2 VIF(s) / VIF(1)),
        the window's n / s^2 samples against its n. 1 for independent noise, for a frame whose noise
        was not measured, and for ``max_loss`` 0."""
        if not self.measured or not max_loss > 0:
            return 1
        steps = np.arange(1, max(int(max_step), 1) + 1)
        loss = np.sqrt(steps**2 * self.inflation(steps) / self.inflation(1))
        return int(steps[loss <= 1.0 + max_loss].max())

    def correlation_px(self) -> float:
        """The correlation's extent: the side of the square of independent samples, sqrt(VIF) px."""
        return float(np.sqrt(self.inflation(1)))


def _lag_sum(rho: np.ndarray, step: int) -> float:
    """1 + 2 sum_{m >= 1} rho(m step), up to the first rho under RHO_CUTOFF."""
    total = 1.0
    for r in rho[step::step].tolist():
        if r < RHO_CUTOFF:
            break
        total += 2.0 * r
    return total


def measure_noise_correlation(depth_m: np.ndarray, uv: np.ndarray, *, max_lag_px: int = 16,
                              max_segments: int = 64, step_m: float = 0.004,
                              beside_px: float | None = None) -> NoiseCorrelation:
    """The noise correlation of ``depth_m`` (H, W) metres, NaN or <= 0 = no depth, measured on the
    rows and the columns of 6 ``max_lag_px`` + 1 pixels centred on up to ``max_segments`` of the
    pixels ``uv`` (n, 2) (evenly chosen), ``beside_px`` (default ``max_lag_px`` / 2, at least 4) above
    and below, left and right of each; segments holding a depth jump over ``step_m`` are left out.
    ``max_lag_px`` 0: not measured (independent noise)."""
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    uv = uv[np.all(np.isfinite(uv), axis=1)]
    K = int(max_lag_px)
    if K <= 0 or uv.shape[0] == 0:
        return NoiseCorrelation.independent(max(K, 0))
    pick = np.unique(np.linspace(0, uv.shape[0] - 1, min(uv.shape[0], max_segments)).round().astype(np.int64))
    u0, v0 = np.rint(uv[pick, 0]).astype(np.int64), np.rint(uv[pick, 1]).astype(np.int64)
    off = np.arange(-3 * K, 3 * K + 1)
    # Rows and columns beside the stud, not through it: a painted stud mark (no depth from dark paint)
    # covers the stud's own place and often a cross along its row and column.
    side = max(4, int(round(beside_px)) if beside_px is not None and np.isfinite(beside_px) else K // 2)
    u_c, v_c = np.tile(u0, 2)[:, None], np.tile(v0, 2)[:, None]  # each stud twice: one side, then the other
    beside = np.repeat([-side, side], u0.size)[:, None]
    along_u = (u_c + off, np.broadcast_to(v_c + beside, (u_c.size, off.size)))  # rows above and below
    along_v = (np.broadcast_to(u_c + beside, (u_c.size, off.size)), v_c + off)  # columns left and right
    U, V = np.concatenate([along_u[0], along_v[0]]), np.concatenate([along_u[1], along_v[1]])
    lags = _lags(K)
    T, count = _third_differences(np.asarray(depth_m), U, V, lags, step_m, rows=u_c.size)
    if count.min() < MIN_DIFFERENCES:
        return NoiseCorrelation.independent(K)
    var = 0.5 * (T[0, -1] + T[1, -1]) / 20.0
    if not var > MIN_NOISE_M**2:
        return NoiseCorrelation.independent(K)
    return NoiseCorrelation(_rho_from_variogram(lags, T[0], var), _rho_from_variogram(lags, T[1], var),
                            float(np.sqrt(var)), True)


def _lags(K: int) -> np.ndarray:
    """The lags measured, up to K: every one to 4, then about 1.5x apart (rho is smooth)."""
    lags, k = [1, 2, 3, 4], 6
    while k < K:
        lags.append(k)
        k += k // 2
    return np.array(sorted({lag for lag in lags if lag < K} | {K}))


def _third_differences(depth: np.ndarray, U: np.ndarray, V: np.ndarray, lags: np.ndarray, step_m: float,
                       rows: int):
    """T(k) (2, len(lags)) at ``lags`` over the segments of pixels (U, V) (s, L), the first ``rows``
    of them along the image rows (u), the others along the columns (v); and the count (2, len(lags))
    of the differences each is the mean of."""
    H, W = depth.shape
    inside = (U >= 0) & (U < W) & (V >= 0) & (V < H)
    seg = depth[np.clip(V, 0, H - 1), np.clip(U, 0, W - 1)].astype(np.float64)
    seg[~inside | ~(seg > 0)] = np.nan  # NaN compares False: no depth
    # A jump between consecutive pixels with depth, across holes too (each compared with the last before it).
    last = np.maximum.accumulate(np.where(np.isnan(seg), 0, np.arange(seg.shape[1])), axis=1)
    filled = np.take_along_axis(seg, last, axis=1)
    with np.errstate(invalid="ignore"):
        jumps = np.abs(np.diff(filled, axis=1)) > step_m  # leading NaNs are no jump
    smooth = np.logical_not(np.any(jumps, axis=1))
    rows = int(np.count_nonzero(smooth[:rows]))  # the segments along u stay first
    seg = seg[smooth]
    T, count = np.full((2, lags.size), np.nan), np.zeros((2, lags.size), dtype=np.int64)
    if not 0 < rows < seg.shape[0]:
        return T, count
    L = seg.shape[1]
    for i, k in enumerate(lags.tolist()):
        d = seg[:, 3 * k:] - 3.0 * seg[:, 2 * k:L - k] + 3.0 * seg[:, k:L - 2 * k] - seg[:, :L - 3 * k]
        good = ~np.isnan(d)
        sq = np.square(d, out=d)
        sq[~good] = 0.0
        sums = np.add.reduceat(np.column_stack((sq.sum(axis=1), good.sum(axis=1))), [0, rows])
        count[:, i] = sums[:, 1]
        T[:, i] = sums[:, 0] / np.maximum(sums[:, 1], 1)
    return T, count


def _rho_from_variogram(lags: np.ndarray, T: np.ndarray, var: float) -> np.ndarray:
    """rho(0..K) from T(k) = var (20 - 30 rho(k) + 12 rho(2k) - 2 rho(3k)) at ``lags`` (K the last),
    rho = 0 beyond K and linear between the lags: from the largest lag down, each rho from the
    larger lags' already known."""
    K = int(lags[-1])
    known_k: list[int] = []  # ascending, as np.interp wants them
    known_rho: list[float] = []

    def rho_at(lag: int) -> float:
        return float(np.interp(lag, known_k, known_rho)) if lag <= K and known_k else 0.0

    for k, t in zip(lags[::-1].tolist(), T[::-1].tolist()):
        r = (20.0 - t / var + 12.0 * rho_at(2 * k) - 2.0 * rho_at(3 * k)) / 30.0
        known_k.insert(0, k)
        known_rho.insert(0, min(max(r, -1.0), 1.0))
    rho = np.interp(np.arange(K + 1), known_k, known_rho)
    rho[0] = 1.0
    return rho


__all__ = ["MAX_SAMPLE_STEP", "MIN_DIFFERENCES", "NoiseCorrelation", "RHO_CUTOFF", "measure_noise_correlation"]
