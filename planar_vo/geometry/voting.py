"""Robust planar motion from many affine correspondences: weighted histogram voting (and RANSAC).

One AC gives one motion candidate (`solve_1ac`), so robust estimation can be exhaustive and
deterministic (Hajder and Barath, section 3.4; Bujnak et al. 2009 for weighted voting):

1. every AC's candidate ``(alpha_i, beta_i)`` votes, with its weight, into a kernel-smoothed
   histogram on the circle for ``alpha``; the peak is refined below bin resolution by mean shift;
2. the ACs that agree on ``alpha`` vote for ``beta`` the same way;
3. inliers are selected by the whitened residual of all three AC constraints (epipolar + two
   affine) at the voted motion, with noise scales estimated robustly from the peak's members;
4. ``(alpha, beta)`` are refined by weighted Gauss-Newton on all inliers' constraints, giving a
   2x2 covariance from the normal equations.

Cost is linear in the number of ACs and independent of the outlier ratio. Degenerate or
ambiguous input gives a flagged result (``stats.reliable`` False, ``stats.flag`` says why), never
an exception and never a silently confident wrong answer. A 1AC-RANSAC with local optimisation
sits behind the same interface (``VotingConfig(method='ransac')``) for comparison.

The focal-length variant votes the 1ACf focal candidates (weighted by their conditioning) in
log-focal space first, then runs the calibrated estimator with that focal length and refines
``(alpha, beta, f)`` jointly on the inliers. `FocalCalibrator` accumulates 1ACf candidates over
many frames for online self-calibration.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planar_vo._checks import as_array, same_length
from planar_vo.config import VotingConfig
from planar_vo.errors import ConfigError, InputError
from planar_vo.geometry.minimal import (
    _ac_matrix,
    _ac_null_vectors,
    _check_ac,
    _cheirality_flip,
    solve_1ac,
    solve_1acf,
)
from planar_vo.geometry.planar import wrap_angle

__all__ = [
    'FocalCalibrator',
    'PlanarMotion',
    'VotingStats',
    'vote_planar_motion',
    'vote_planar_motion_focal',
]

TWO_PI = 2.0 * np.pi
# Numerical floors of the residual scales: on exact data the robust scales would be ~1e-17 and
# rounding alone would reject true inliers.
_POINT_SCALE_FLOOR = 1e-9
_AFFINE_SCALE_FLOOR = 1e-8
_MAD = 1.4826                     # sigma / median|x| for a normal
_HALF_NORMAL_Q25 = 0.31864        # lower quartile of |N(0, 1)|


@dataclass(frozen=True)
class PlanarMotion:
    """A planar motion estimate (``X2 = Ry(alpha) X1 + t``, ``t = [cos beta, 0, sin beta]``).

    Attributes:
        alpha, beta: radians, in ``(-pi, pi]``; NaN when nothing could be estimated.
        focal: focal length in pixels for the focal variant, else NaN.
    """

    alpha: float
    beta: float
    focal: float = float('nan')


@dataclass(frozen=True)
class VotingStats:
    """What the estimator saw, for callers that must judge the estimate.

    Attributes:
        inliers: bool mask over the input ACs, shape ``(N,)``.
        num_inliers: ``inliers.sum()``.
        num_candidates: ACs that gave a finite candidate.
        peak_sharpness: fraction of the total vote weight inside the alpha peak's window (1 for
            perfectly consistent data, small for noise).
        ambiguity: height of the best separate alpha peak relative to the winner, in ``[0, 1]``.
        residual_rms: RMS of the whitened constraint residuals over the inliers.
        covariance: 2x2 covariance of ``(alpha, beta)`` in rad^2 (infinite when unreliable).
        reliable: the estimate can be used.
        flag: why not, when not reliable: ``'too_few_candidates'``, ``'too_few_inliers'``,
            ``'unstable'`` (the refinement left the voted peak), ``'ambiguous'`` or
            ``'weak_peak'``.
        point_scale, affine_scale: robust noise scales of the epipolar (normalised
            coordinates) and affine residuals.
        iterations: RANSAC iterations (0 for voting).
        focal_std: standard deviation of the focal length (pixels; focal variant only).
    """

    inliers: np.ndarray
    num_inliers: int
    num_candidates: int
    peak_sharpness: float
    ambiguity: float
    residual_rms: float
    covariance: np.ndarray
    reliable: bool
    flag: str | None = None
    point_scale: float = float('nan')
    affine_scale: float = float('nan')
    iterations: int = 0
    focal_std: float = float('nan')


def _quantile(x: np.ndarray, q: float) -> float:
    """Lower ``q``-quantile of ``x`` by partial sorting (np.quantile's interpolation costs more
    than the whole selection here)."""
    k = int(q * (x.size - 1))
    return float(np.partition(x, k)[k])


# The peak's statistics (beta votes, mean shift, noise scales) need a sample of a peak, not all
# of it: above this many items a deterministic stride subsample is used. The final selection,
# refinement and covariance always use every AC.
_STAT_SAMPLE = 1500


def _thin(idx: np.ndarray, limit: int = _STAT_SAMPLE) -> np.ndarray:
    """Every k-th entry of ``idx`` so that at most about ``limit`` remain (deterministic)."""
    step = -(-idx.size // limit)
    return idx if step <= 1 else idx[::step]


def _wrap(x: np.ndarray) -> np.ndarray:
    """Angles to ``[-pi, pi)`` (the cheap form for internal use)."""
    return np.remainder(x + np.pi, TWO_PI) - np.pi


# ------------------------------------------------------------------------------------------------
# Circular histogram voting
# ------------------------------------------------------------------------------------------------

def _circular_kernel(bins: int, sigma_bins: float) -> np.ndarray:
    half = max(1, int(math.ceil(3.0 * sigma_bins)))
    half = min(half, bins // 2 - 1)
    x = np.arange(-half, half + 1, dtype=np.float64)
    k = np.exp(-0.5 * (x / sigma_bins) ** 2)
    return k / k.sum()


def _smoothed_histogram(angles: np.ndarray, weights: np.ndarray, bins: int,
                        kernel: np.ndarray) -> np.ndarray:
    """Histogram of angles on the circle (``bins`` bins over 2 pi), circularly smoothed."""
    idx = np.floor((angles + np.pi) * (bins / TWO_PI)).astype(np.intp) % bins
    hist = np.bincount(idx, weights=weights, minlength=bins)
    half = kernel.size // 2
    padded = np.concatenate([hist[-half:], hist, hist[:half]])
    return np.convolve(padded, kernel, mode='valid')


def _bin_center(i: int, bins: int) -> float:
    return (i + 0.5) * TWO_PI / bins - np.pi


def _mean_shift(angles: np.ndarray, weights: np.ndarray, start: float, bandwidth: float,
                iterations: int = 6) -> float:
    """Mode of the weighted angle density near ``start`` (Gaussian kernel, circular)."""
    # Work on offsets from the start inside a window (the kernel is negligible beyond it).
    d0 = np.remainder(angles - start + np.pi, TWO_PI) - np.pi
    near = _thin(np.flatnonzero(np.abs(d0) <= 4.0 * bandwidth))
    d0, weights = d0[near], weights[near]
    offset = 0.0
    for _ in range(iterations):
        d = d0 - offset
        k = weights * np.exp(-0.5 * (d / bandwidth) ** 2)
        total = float(k.sum())
        if total <= 0.0:
            break
        step = float(k @ d) / total
        offset += step
        if abs(step) < 1e-10:
            break
    return float(wrap_angle(start + offset))


def _peak(angles: np.ndarray, weights: np.ndarray, config: VotingConfig,
          exclusion: float) -> tuple[float, float, float, float]:
    """Voted mode of circular ``angles``.

    Returns:
        ``(mode, sharpness, ambiguity, bandwidth)``: the mean-shift mode, the fraction of the
        weight within the peak window, the best separate peak (more than ``exclusion`` radians
        away) relative to the winner, and the mean-shift bandwidth used.
    """
    bins = config.bins
    kernel = _circular_kernel(bins, config.kernel_bins)
    hist = _smoothed_histogram(angles, weights, bins, kernel)
    i = int(np.argmax(hist))
    top = hist[i]
    start = _bin_center(i, bins)
    # Second peak: the best local maximum of the histogram outside the exclusion zone.
    reach = int(math.ceil(exclusion * bins / TWO_PI))
    local_max = (hist >= np.roll(hist, 1)) & (hist >= np.roll(hist, -1))
    local_max[np.arange(i - reach, i + reach + 1) % bins] = False
    ambiguity = float(hist[local_max].max() / top) if local_max.any() and top > 0 else 0.0
    bandwidth = config.kernel_bins * TWO_PI / bins
    mode = _mean_shift(angles, weights, start, 2.0 * bandwidth)
    window = np.abs(np.remainder(angles - mode + np.pi, TWO_PI) - np.pi) <= 3.0 * bandwidth
    total = weights.sum()
    sharpness = float(weights[window].sum() / total) if total > 0 else 0.0
    return mode, sharpness, ambiguity, bandwidth


# ------------------------------------------------------------------------------------------------
# Residuals and refinement
# ------------------------------------------------------------------------------------------------

def _residual_terms(q1: np.ndarray, q2: np.ndarray, A: np.ndarray, B: np.ndarray,
                    theta: float, beta: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Residuals ``r = B x`` (N, 3) and their gradient norms w.r.t. points and affines.

    With ``x = [cos th, sin th, cos b, sin b]`` the rows are (minimal.py):

        r1 = -v2 c_t + u1 v2 s_t + v1 c_b - u2 v1 s_b
        r2 = -a3 c_t + (v2 + a3 u1) s_t - a1 v1 s_b
        r3 = -a4 c_t + a4 u1 s_t + c_b - (u2 + a2 v1) s_b

    First-order noise propagation: ``var(r_k) = sp^2 |d r_k / d points|^2 + sa^2 |d r_k / d A|^2``.
    """
    ct, st, cb, sb = math.cos(theta), math.sin(theta), math.cos(beta), math.sin(beta)
    x = np.array([ct, st, cb, sb])
    r = B @ x
    u1, v1, u2, v2 = q1[:, 0], q1[:, 1], q2[:, 0], q2[:, 1]
    a1, a2, a3, a4 = A[:, 0, 0], A[:, 0, 1], A[:, 1, 0], A[:, 1, 1]
    g = np.empty((q1.shape[0], 3))
    h = np.empty((q1.shape[0], 3))
    # Row 1 (epipolar): d/d(u1, v1, u2, v2) = (v2 s_t, c_b - u2 s_b, -v1 s_b, -c_t + u1 s_t).
    g[:, 0] = (v2 * st) ** 2 + (cb - u2 * sb) ** 2 + (v1 * sb) ** 2 + (u1 * st - ct) ** 2
    h[:, 0] = 0.0
    # Row 2: points (u1: a3 s_t, v1: -a1 s_b, v2: s_t); affine (a1: -v1 s_b, a3: -c_t + u1 s_t).
    g[:, 1] = (a3 * st) ** 2 + (a1 * sb) ** 2 + st * st
    h[:, 1] = (v1 * sb) ** 2 + (u1 * st - ct) ** 2
    # Row 3: points (u1: a4 s_t, v1: -a2 s_b, u2: -s_b); affine (a2: -v1 s_b, a4: -c_t + u1 s_t).
    g[:, 2] = (a4 * st) ** 2 + (a2 * sb) ** 2 + sb * sb
    h[:, 2] = h[:, 1]
    return r, g, h


def _whitened(r: np.ndarray, g: np.ndarray, h: np.ndarray, sp: float, sa: float) -> np.ndarray:
    """Residuals divided by their first-order standard deviations, shape ``(N, 3)``."""
    return r / np.sqrt(sp * sp * g + sa * sa * h + 1e-300)


def _robust_scales(r: np.ndarray, g: np.ndarray, h: np.ndarray, quantile: float = 0.25
                   ) -> tuple[float, float]:
    """Noise scales of points (normalised units) and affines from the peak's members' residuals.

    The members are the ACs whose candidates fell in the voted peak; with many outliers a good
    share of them are outliers too, so by default the scales come from the lower quartile of the
    normalised residuals (for ``|N(0, s^2)|`` the quartile is ``0.3186 s``), which tolerates up to
    three quarters of contamination; for clean inliers ``quantile=0.5`` (the median) is used.
    Epipolar rows see point noise only: ``e1 = r1 / |dr1/dp|``.
    Affine rows see ``sqrt(sp^2 g + sa^2 h)``; ``sa`` comes from ``r / sqrt(h)`` with the point
    share removed.
    """
    if r.shape[0] < 4:
        return _POINT_SCALE_FLOOR, _AFFINE_SCALE_FLOOR
    q = _HALF_NORMAL_Q25 if quantile == 0.25 else 1.0 / _MAD
    e1 = np.abs(r[:, 0]) / np.sqrt(g[:, 0] + 1e-300)
    sp = max(_quantile(e1, quantile) / q, _POINT_SCALE_FLOOR)
    ea = (np.abs(r[:, 1:]) / np.sqrt(h[:, 1:] + 1e-300)).ravel()
    raw = _quantile(ea, quantile) / q
    point_share = sp * sp * _quantile((g[:, 1:] / (h[:, 1:] + 1e-300)).ravel(), 0.5)
    sa = math.sqrt(max(raw * raw - point_share, 0.0))
    return sp, max(sa, _AFFINE_SCALE_FLOOR, 0.1 * raw)


def _minimize_form(M: np.ndarray, theta: float, beta: float, iterations: int = 20
                   ) -> tuple[float, float, np.ndarray, float]:
    """Gauss-Newton for ``min x^T M x``, ``x = [cos th, sin th, cos b, sin b]``.

    With the whitening fixed, the residual vector is ``Bw x`` and its Jacobian ``Bw D`` with
    ``D = dx/d(th, b) = [[-sin th, 0], [cos th, 0], [0, -sin b], [0, cos b]]``, so a step costs
    O(1): ``H = D^T M D``, ``g = D^T M x``. Converges quadratically from the voted estimate
    (4-5 steps); plain floats, since numpy's per-call overhead dominates at this size.

    Returns ``theta, beta``, ``H`` (2x2) and the objective value.
    """
    (m00, m01, m02, m03), (_, m11, m12, m13), (_, _, m22, m23), (_, _, _, m33) = M.tolist()
    h00 = h01 = h11 = f = float('nan')
    for _ in range(iterations):
        ct, st, cb, sb = math.cos(theta), math.sin(theta), math.cos(beta), math.sin(beta)
        # M x (M symmetric)
        y0 = m00 * ct + m01 * st + m02 * cb + m03 * sb
        y1 = m01 * ct + m11 * st + m12 * cb + m13 * sb
        y2 = m02 * ct + m12 * st + m22 * cb + m23 * sb
        y3 = m03 * ct + m13 * st + m23 * cb + m33 * sb
        f = ct * y0 + st * y1 + cb * y2 + sb * y3
        g0 = -st * y0 + ct * y1
        g1 = -sb * y2 + cb * y3
        h00 = st * st * m00 - 2.0 * st * ct * m01 + ct * ct * m11
        h11 = sb * sb * m22 - 2.0 * sb * cb * m23 + cb * cb * m33
        h01 = st * sb * m02 - st * cb * m03 - ct * sb * m12 + ct * cb * m13
        det = h00 * h11 - h01 * h01
        if not (det > 1e-300 * max(h00 * h11, 1e-300)):
            return theta, beta, np.full((2, 2), np.nan), f
        d_t = (h11 * g0 - h01 * g1) / det
        d_b = (h00 * g1 - h01 * g0) / det
        theta -= d_t
        beta -= d_b
        if abs(d_t) + abs(d_b) < 1e-12:
            break
    return theta, beta, np.array([[h00, h01], [h01, h11]]), f


def _to_alpha_beta_cov(cov_tb: np.ndarray) -> np.ndarray:
    """Covariance of ``(alpha, beta) = (theta - beta, beta)`` from that of ``(theta, beta)``."""
    if not np.all(np.isfinite(cov_tb)):
        return np.full((2, 2), np.inf)
    J = np.array([[1.0, -1.0], [0.0, 1.0]])
    return J @ cov_tb @ J.T


# ------------------------------------------------------------------------------------------------
# Public estimators
# ------------------------------------------------------------------------------------------------

def _check_inputs(q1, q2, A, weights, config):
    q1, q2, A = _check_ac('q1', q1, 'q2', q2, A)
    n = q1.shape[0]
    if weights is None:
        w = np.ones(n)
    else:
        w = as_array('weights', weights, (None,))
        same_length(q1=q1, weights=w)
        if np.any(w < 0):
            raise ConfigError(f'weights: expected non-negative values, got minimum {w.min()}')
    config = VotingConfig() if config is None else config
    if not isinstance(config, VotingConfig):
        raise ConfigError(f'config: expected VotingConfig, got {type(config).__name__}')
    return q1, q2, A, w, config


def _failed(n: int, flag: str, candidates: int = 0, sharpness: float = 0.0,
            ambiguity: float = 0.0) -> tuple[PlanarMotion, VotingStats]:
    return (PlanarMotion(float('nan'), float('nan')),
            VotingStats(np.zeros(n, bool), 0, candidates, sharpness, ambiguity, float('nan'),
                        np.full((2, 2), np.inf), False, flag))


def vote_planar_motion(q1: np.ndarray, q2: np.ndarray, A: np.ndarray,
                       weights: np.ndarray | None = None, config: VotingConfig | None = None,
                       *, clusters: np.ndarray | None = None
                       ) -> tuple[PlanarMotion, VotingStats]:
    """Robust planar motion from N affine correspondences (1AC + weighted histogram voting).

    Args:
        q1, q2: normalised image coordinates, shape ``(N, 2)``.
        A: local affines in normalised coordinates, shape ``(N, 2, 2)``.
        weights: per-AC quality (non-negative), shape ``(N,)``; None for equal weights.
        config: `VotingConfig` (``method='ransac'`` selects the RANSAC comparison).
        clusters: optional integer group per AC, shape ``(N,)``: ACs whose errors may be
            correlated (one surface, one segment). Default: cells of a
            ``config.covariance_grid`` grid over image 1, since neighbouring ACs share errors.
            Used only for the cluster-robust covariance.

    Returns:
        ``(motion, stats)``: a `PlanarMotion` and `VotingStats`. When ``stats.reliable`` is
        False, ``stats.flag`` says why; the angles may still be the best guess (or NaN).

    Raises:
        InputError: wrong shapes or non-finite values; ConfigError: bad weights or config.
    """
    q1, q2, A, w, config = _check_inputs(q1, q2, A, weights, config)
    if clusters is None:
        clusters = _spatial_clusters(q1, config)
    else:
        clusters = np.asarray(clusters)
        if clusters.shape != (q1.shape[0],) or not np.issubdtype(clusters.dtype, np.integer) \
                or (clusters.size and clusters.min() < 0):
            raise InputError(f'clusters: expected non-negative integers of shape '
                             f'({q1.shape[0]},), got {clusters.dtype} {clusters.shape}')
    if config.method == 'ransac':
        return _ransac(q1, q2, A, w, config, clusters)
    n = q1.shape[0]
    if config.refine_candidates:
        alpha_c, beta_c = solve_1ac(q1, q2, A, refine=True)
        signed = True
    else:
        # Alpha does not depend on the null vector's sign (flipping it adds pi to both angles),
        # so cheirality is resolved below only for the ACs that vote on beta.
        nv = _ac_null_vectors(q1, q2, A)
        theta_c = np.arctan2(nv[:, 1], nv[:, 0])
        beta_c = np.arctan2(nv[:, 3], nv[:, 2])
        alpha_c = _wrap(theta_c - beta_c)
        alpha_c[((nv[:, 0] == 0.0) & (nv[:, 1] == 0.0)) | ((nv[:, 2] == 0.0)
                                                           & (nv[:, 3] == 0.0))] = np.nan
        signed = False
    valid = np.isfinite(alpha_c) & (w > 0)
    num_candidates = int(np.count_nonzero(valid))
    if num_candidates < config.min_inliers:
        return _failed(n, 'too_few_candidates', num_candidates)
    valid_idx = np.flatnonzero(valid)
    a_v, w_v = alpha_c[valid_idx], w[valid_idx]

    exclusion = 6.0 * config.kernel_bins * TWO_PI / config.bins
    alpha0, sharpness, ambiguity, bw = _peak(a_v, w_v, config, exclusion)
    near_alpha = np.abs(_wrap(a_v - alpha0)) <= 3.0 * bw
    near_idx = _thin(valid_idx[near_alpha])
    b_near = beta_c[near_idx]
    if not signed:
        flip = _cheirality_flip(q1[near_idx], q2[near_idx], alpha_c[near_idx], b_near)
        b_near = _wrap(b_near + np.pi * flip)
    beta0, _, _, bw_b = _peak(b_near, w[near_idx], config, exclusion)

    # Residual terms at the voted motion: the peak's members (near both modes) calibrate the
    # noise scales, and the resulting whitening is kept for a first refinement (the vote is
    # within a degree, where the first-order standard deviations barely change).
    B = _ac_matrix(q1, q2, A)
    theta0 = alpha0 + beta0
    r, g, h = _residual_terms(q1, q2, A, B, theta0, beta0)
    beta_offsets = np.abs(_wrap(b_near - beta0))
    members = near_idx[beta_offsets <= 3.0 * bw_b]
    sp_cap = config.max_noise_factor * config.point_noise
    sa_cap = config.max_noise_factor * config.affine_noise
    sp, sa = _robust_scales(r[members], g[members], h[members])
    sp, sa = min(sp, sp_cap), min(sa, sa_cap)
    Bw = B / np.sqrt(sp * sp * g + sa * sa * h + 1e-300)[:, :, None]
    theta, beta, inliers, cov, rms = _select_and_refine(Bw, w, theta0, beta0, config, passes=1,
                                                        covariance=not config.refine)
    if config.refine and np.count_nonzero(inliers) >= max(config.min_inliers, 4):
        # Second round: noise scales from the inliers at the refined motion (clean, so the
        # median is the right statistic), then the same selection and refinement again.
        r, g, h = _residual_terms(q1, q2, A, B, theta, beta)
        sample = _thin(np.flatnonzero(inliers))
        sp, sa = _robust_scales(r[sample], g[sample], h[sample], quantile=0.5)
        sp, sa = min(sp, sp_cap), min(sa, sa_cap)
        Bw = B / np.sqrt(sp * sp * g + sa * sa * h + 1e-300)[:, :, None]
        theta, beta, inliers, cov, rms = _select_and_refine(Bw, w, theta, beta, config, clusters,
                                                            passes=3)
    elif config.refine:
        _, _, _, cov, rms = _select_and_refine(Bw, w, theta, beta, config, clusters, passes=1)
    motion = PlanarMotion(float(wrap_angle(theta - beta)), float(wrap_angle(beta)))
    num_inliers = int(np.count_nonzero(inliers))
    # The refined motion must stay in the voted peak: leaving it means the inliers' constraints
    # disagree with the votes they cast (a peak made of outliers, or a degenerate geometry).
    # Alpha candidates are sharp; beta candidates can spread widely (forward motion), so beta is
    # judged against the robust spread of the peak's own beta candidates.
    beta_spread = bw_b
    if beta_offsets.size:
        beta_spread = max(bw_b, _MAD * _quantile(beta_offsets, 0.5))
    drift = max(abs(float(wrap_angle(motion.alpha - alpha0))) / (3.0 * bw),
                abs(float(wrap_angle(motion.beta - beta0))) / (3.0 * beta_spread))
    flag = None
    if num_inliers < config.min_inliers:
        flag = 'too_few_inliers'
    elif drift > 1.0:
        flag = 'unstable'
    elif ambiguity >= config.ambiguity_ratio:
        flag = 'ambiguous'
    elif sharpness < config.min_sharpness:
        flag = 'weak_peak'
    cov_ab = _to_alpha_beta_cov(cov)
    if flag is not None:
        cov_ab = np.full((2, 2), np.inf)
    stats = VotingStats(inliers, num_inliers, num_candidates, sharpness, ambiguity, rms, cov_ab,
                        flag is None, flag, sp, sa)
    return motion, stats


def _spatial_clusters(q: np.ndarray, config: VotingConfig) -> np.ndarray:
    """Cluster id of each AC: its cell in a ``grid x grid`` partition of image-1 positions."""
    k = config.covariance_grid
    u, v = q[:, 0], q[:, 1]
    u0, v0 = float(u.min()), float(v.min())
    su = k / max(float(u.max()) - u0, 1e-12)
    sv = k / max(float(v.max()) - v0, 1e-12)
    iu = np.minimum(((u - u0) * su).astype(np.intp), k - 1)
    iv = np.minimum(((v - v0) * sv).astype(np.intp), k - 1)
    return iu * k + iv


def _fit_whitened(flat: np.ndarray, w3: np.ndarray, theta: float, beta: float
                  ) -> tuple[float, float, np.ndarray, float]:
    """Least squares over ``(theta, beta)`` of the whitened rows ``flat`` ``(3N, 4)`` with row
    weights ``w3`` ``(3N,)``; returns ``theta, beta``, the Gauss-Newton matrix ``H`` and the
    objective (see `_minimize_form`)."""
    M = (flat * w3[:, None]).T @ flat
    return _minimize_form(M, theta, beta)


def _covariance(flat: np.ndarray, w: np.ndarray, theta: float, beta: float, H: np.ndarray,
                f: float, clusters: np.ndarray | None) -> tuple[np.ndarray, float]:
    """Covariance of ``(theta, beta)`` at the solution of `_fit_whitened`, and the whitened RMS.

    Cluster-robust (a sandwich ``H^-1 (sum_c s_c s_c^T) H^-1`` with ``s_c`` the summed score
    ``J^T e`` of cluster ``c``; Liang and Zeger 1986): neighbouring ACs share errors (one
    surface, overlapping patches, one fitted homography), which the plain ``sigma^2 H^-1``
    ignores and which would make it overconfident. Never smaller than ``sigma^2 H^-1`` with the
    posterior variance factor. Neither depends on the scale of ``w``.
    """
    m = int(np.count_nonzero(w > 0))
    wsum = float(w.sum())
    rms = math.sqrt(max(f, 0.0) / (3.0 * wsum)) if wsum > 0 else float('nan')
    det = H[0, 0] * H[1, 1] - H[0, 1] ** 2
    if m < 2 or not np.all(np.isfinite(H)) or not det > 0:
        return np.full((2, 2), np.inf), rms
    Hinv = np.array([[H[1, 1], -H[0, 1]], [-H[0, 1], H[0, 0]]]) / det
    cov = max(f, 1e-300) / max(3 * m - 2, 1) * Hinv
    if clusters is not None:
        ct, st, cb, sb = math.cos(theta), math.sin(theta), math.cos(beta), math.sin(beta)
        # Per-row residual and its derivatives, contracted to per-AC scores J^T e.
        proj = flat @ np.array([[ct, -st, 0.0], [st, ct, 0.0], [cb, 0.0, -sb], [sb, 0.0, cb]])
        proj = proj.reshape(-1, 3, 3)                   # (N, row, [e, de/dtheta, de/dbeta])
        s0 = np.bincount(clusters, weights=w * (proj[:, :, 0] * proj[:, :, 1]).sum(axis=1))
        s1 = np.bincount(clusters, weights=w * (proj[:, :, 0] * proj[:, :, 2]).sum(axis=1))
        meat = np.array([[s0 @ s0, s0 @ s1], [s0 @ s1, s1 @ s1]])
        robust = Hinv @ meat @ Hinv
        if np.all(np.isfinite(robust)) and np.trace(robust) > np.trace(cov):
            cov = robust
    return cov, rms


def _select_and_refine(Bw: np.ndarray, w: np.ndarray, theta: float, beta: float,
                       config: VotingConfig, clusters: np.ndarray | None = None,
                       passes: int = 4, covariance: bool = True):
    """Inlier selection (chi-square of the whitened residuals) alternated with refitting, until
    the inlier set no longer changes (at most ``passes`` times); then, if asked, the
    covariance."""
    n = Bw.shape[0]
    flat = Bw.reshape(-1, 4)
    inliers = np.zeros(n, bool)
    H, f = np.full((2, 2), np.nan), float('nan')
    fitted = False
    for _ in range(passes if config.refine else 1):
        x = np.array([math.cos(theta), math.sin(theta), math.cos(beta), math.sin(beta)])
        e = (flat @ x).reshape(n, 3)
        selected = ((e * e).sum(axis=1) <= config.inlier_chi2) & (w > 0)
        if np.count_nonzero(selected) < 2:
            break
        if fitted and np.array_equal(selected, inliers):
            break                                   # the last fit already used this set
        inliers = selected
        t2, b2, H, f = _fit_whitened(flat, np.repeat(w * selected, 3), theta, beta)
        fitted = True
        if config.refine:
            theta, beta = t2, b2
    if not covariance or not np.count_nonzero(inliers):
        return theta, beta, inliers, np.full((2, 2), np.inf), float('nan')
    cov, rms = _covariance(flat, w * inliers, theta, beta, H, f, clusters)
    return theta, beta, inliers, cov, rms


def _ransac(q1, q2, A, w, config: VotingConfig, clusters: np.ndarray
            ) -> tuple[PlanarMotion, VotingStats]:
    """1AC-RANSAC with local optimisation (MSAC scoring), for comparison with voting.

    Each hypothesis is one AC's own candidate. Hypotheses are scored in vectorised batches by the
    truncated chi-square of all ACs' whitened residuals with the fixed noise levels
    ``config.point_noise`` and ``config.affine_noise``; every new best is refined on its inliers
    (local optimisation) and re-scored. The iteration count adapts to the inlier ratio.
    """
    n = q1.shape[0]
    alpha_c, beta_c = solve_1ac(q1, q2, A, refine=config.refine_candidates)
    valid = np.flatnonzero(np.isfinite(alpha_c) & (w > 0))
    if valid.size < config.min_inliers:
        return _failed(n, 'too_few_candidates', int(valid.size))
    B = _ac_matrix(q1, q2, A)
    sp, sa = config.point_noise, config.affine_noise
    rng = np.random.default_rng(config.seed)
    p = w[valid] / w[valid].sum()
    order = valid[rng.choice(valid.size, size=min(valid.size, config.ransac_iterations),
                             replace=False, p=p)]
    best = (np.inf, 0.0, 0.0)
    needed = config.ransac_iterations
    done = 0
    batch = 32

    def whiten(theta: float, beta: float) -> np.ndarray:
        _, g, h = _residual_terms(q1, q2, A, B, theta, beta)
        return B / np.sqrt(sp * sp * g + sa * sa * h + 1e-300)[:, :, None]

    def score(theta: float, beta: float) -> tuple[float, np.ndarray]:
        r, g, h = _residual_terms(q1, q2, A, B, theta, beta)
        chi2 = (_whitened(r, g, h, sp, sa) ** 2).sum(axis=1)
        return float((w * np.minimum(chi2, config.inlier_chi2)).sum()), chi2 <= config.inlier_chi2

    while done < min(needed, order.size):
        idx = order[done:done + batch]
        done += idx.size
        th = alpha_c[idx] + beta_c[idx]
        be = beta_c[idx]
        x = np.stack([np.cos(th), np.sin(th), np.cos(be), np.sin(be)])        # (4, H)
        r = np.einsum('nij,jh->nih', B, x)                                     # (N, 3, H)
        st, ct, sb = np.sin(th), np.cos(th), np.sin(be)
        cb = np.cos(be)
        u1, v1, u2, v2 = (q1[:, 0, None], q1[:, 1, None], q2[:, 0, None], q2[:, 1, None])
        a1, a2, a3, a4 = (A[:, 0, 0, None], A[:, 0, 1, None], A[:, 1, 0, None], A[:, 1, 1, None])
        var = np.empty_like(r)
        var[:, 0] = sp * sp * ((v2 * st) ** 2 + (cb - u2 * sb) ** 2 + (v1 * sb) ** 2
                               + (u1 * st - ct) ** 2)
        ha = (v1 * sb) ** 2 + (u1 * st - ct) ** 2
        var[:, 1] = sp * sp * ((a3 * st) ** 2 + (a1 * sb) ** 2 + st * st) + sa * sa * ha
        var[:, 2] = sp * sp * ((a4 * st) ** 2 + (a2 * sb) ** 2 + sb * sb) + sa * sa * ha
        chi2 = (r * r / (var + 1e-300)).sum(axis=1)                            # (N, H)
        scores = (w[:, None] * np.minimum(chi2, config.inlier_chi2)).sum(axis=0)
        k = int(np.argmin(scores))
        if scores[k] < best[0]:
            theta, beta = float(th[k]), float(be[k])
            inl = chi2[:, k] <= config.inlier_chi2
            if np.count_nonzero(inl) >= 2:                                      # local optimisation
                t2, b2, _, _ = _fit_whitened(whiten(theta, beta).reshape(-1, 4),
                                             np.repeat(w * inl, 3), theta, beta)
                s2, _ = score(t2, b2)
                if s2 <= scores[k]:
                    theta, beta, scores[k] = t2, b2, s2
            best = (float(scores[k]), theta, beta)
            _, inl_mask = score(theta, beta)
            ratio = max(float(w[inl_mask].sum() / w.sum()), 1e-9)
            if ratio >= 1.0:
                needed = done
            else:
                needed = min(config.ransac_iterations, int(math.ceil(
                    math.log(1.0 - config.ransac_confidence) / math.log(1.0 - ratio))))
    _, theta, beta = best
    theta, beta, inliers, cov, rms = _select_and_refine(whiten(theta, beta), w, theta, beta,
                                                        config, clusters)
    num_inliers = int(np.count_nonzero(inliers))
    sharpness = float(w[inliers].sum() / w.sum())
    flag = 'too_few_inliers' if num_inliers < config.min_inliers else None
    cov_ab = _to_alpha_beta_cov(cov) if flag is None else np.full((2, 2), np.inf)
    return (PlanarMotion(float(wrap_angle(theta - beta)), float(wrap_angle(beta))),
            VotingStats(inliers, num_inliers, int(valid.size), sharpness, 0.0, rms, cov_ab,
                        flag is None, flag, sp, sa, iterations=done))


# ------------------------------------------------------------------------------------------------
# Unknown focal length (1ACf)
# ------------------------------------------------------------------------------------------------

def _log_focal_modes(log_f: np.ndarray, weights: np.ndarray, lo: float, hi: float, bins: int,
                     count: int) -> list[float]:
    """The ``count`` highest local maxima of the smoothed log-focal histogram, refined by mean
    shift (per-AC 1ACf focal candidates are noisy, so the best start is not always the top)."""
    width = (hi - lo) / bins
    idx = np.clip(((log_f - lo) / width).astype(np.intp), 0, bins - 1)
    hist = np.convolve(np.bincount(idx, weights=weights, minlength=bins),
                       _circular_kernel(bins, 4.0), mode='same')
    peaks = np.flatnonzero((hist > 0) & (hist >= np.roll(hist, 1)) & (hist >= np.roll(hist, -1)))
    peaks = peaks[np.argsort(hist[peaks])[::-1]]
    modes: list[float] = []
    bandwidth = 4.0 * width
    for i in peaks:
        mode = lo + (i + 0.5) * width
        near = np.abs(log_f - mode) <= 4.0 * bandwidth
        x, wx = log_f[near], weights[near]
        for _ in range(8):
            k = wx * np.exp(-0.5 * ((x - mode) / bandwidth) ** 2)
            if k.sum() <= 0:
                break
            step = float(k @ (x - mode)) / float(k.sum())
            mode += step
            if abs(step) < 1e-10:
                break
        if all(abs(mode - m) > 2.0 * bandwidth for m in modes):
            modes.append(mode)
        if len(modes) == count:
            break
    return modes


def vote_planar_motion_focal(p1: np.ndarray, p2: np.ndarray, A: np.ndarray,
                             weights: np.ndarray | None = None,
                             config: VotingConfig | None = None, *,
                             focal_range: tuple[float, float] = (50.0, 20000.0),
                             min_conditioning: float = 2e-4, max_focal_rel_std: float = 0.05,
                             clusters: np.ndarray | None = None, starts: int = 3
                             ) -> tuple[PlanarMotion, VotingStats]:
    """Planar motion and the common focal length from N ACs (1ACf + voting).

    1. 1ACf candidates vote for ``log f`` with weights ``weight x conditioning`` (the
       conditioning ``|sin(alpha) sin(alpha + 2 beta)|`` vanishes when driving straight); per-AC
       candidates are noisy, so the ``starts`` best modes are each tried;
    2. for each, the calibrated estimator (`vote_planar_motion`) runs on ``p / f``; the start
       with the most inlier weight wins;
    3. ``(alpha, beta, f)`` are refined jointly on the inliers (Gauss-Newton), the calibrated
       voting re-selects inliers with the refined ``f``, and the joint refinement runs again.

    The focal length is observable only when the motion turns: the result is flagged
    ``'focal_unobservable'`` when the conditioning at the estimated motion is below
    ``min_conditioning`` or the focal standard deviation exceeds ``max_focal_rel_std`` of it.

    Args:
        p1, p2: pixel coordinates relative to the principal point, shape ``(N, 2)``.
        A: local affines in pixels, shape ``(N, 2, 2)``.
        weights, config, clusters: as for `vote_planar_motion`.
        focal_range: plausible focal lengths in pixels.
        min_conditioning, max_focal_rel_std: observability thresholds (see above).
        starts: number of focal modes tried.

    Returns:
        ``(motion, stats)`` with ``motion.focal`` and ``stats.focal_std`` (pixels).
    """
    p1, p2, A, w, config = _check_inputs(p1, p2, A, weights, config)
    lo, hi = float(focal_range[0]), float(focal_range[1])
    if not (0.0 < lo < hi and math.isfinite(hi)):
        raise ConfigError(f'focal_range: expected 0 < min < max, got {focal_range}')
    n = p1.shape[0]
    if clusters is None:
        clusters = _spatial_clusters(p1, config)
    _, _, f_c, cond = solve_1acf(p1, p2, A, return_weight=True)
    ok = np.isfinite(f_c) & (f_c >= lo) & (f_c <= hi) & (w > 0)
    if np.count_nonzero(ok) < config.min_inliers:
        return _failed(n, 'too_few_candidates', int(np.count_nonzero(ok)))
    modes = _log_focal_modes(np.log(f_c[ok]), (w * cond)[ok], math.log(lo), math.log(hi),
                             config.bins * 4, starts)
    best = None
    for log_f in modes:
        f0 = math.exp(log_f)
        motion, stats = vote_planar_motion(p1 / f0, p2 / f0, A, w, config, clusters=clusters)
        support = float(w[stats.inliers].sum())
        if np.isfinite(motion.alpha) and (best is None or support > best[0]):
            best = (support, f0, motion, stats)
    if best is None or best[3].num_inliers < 3:
        return _failed(n, 'too_few_inliers', int(np.count_nonzero(ok)))
    _, f, motion, stats = best
    cov3 = np.full((3, 3), np.inf)
    for _ in range(2):
        idx = np.flatnonzero(stats.inliers)
        theta, beta, log_f, cov3 = _refine_focal(
            p1[idx], p2[idx], A[idx], w[idx], clusters[idx], motion.alpha + motion.beta,
            motion.beta, math.log(f), stats.point_scale, stats.affine_scale, (lo, hi))
        f = math.exp(log_f)
        motion, stats = vote_planar_motion(p1 / f, p2 / f, A, w, config, clusters=clusters)
        if not np.isfinite(motion.alpha) or stats.num_inliers < 3:
            break
    theta, beta = motion.alpha + motion.beta, motion.beta
    focal_std = f * math.sqrt(cov3[2, 2]) if np.isfinite(cov3[2, 2]) else float('inf')
    conditioning = abs(math.sin(motion.alpha) * math.sin(motion.alpha + 2.0 * motion.beta))
    flag, reliable = stats.flag, stats.reliable
    if reliable and (conditioning < min_conditioning or not focal_std <= max_focal_rel_std * f):
        flag, reliable = 'focal_unobservable', False
    cov_ab = _to_alpha_beta_cov(cov3[:2, :2]) if reliable else np.full((2, 2), np.inf)
    stats = VotingStats(stats.inliers, stats.num_inliers, stats.num_candidates,
                        stats.peak_sharpness, stats.ambiguity, stats.residual_rms, cov_ab,
                        reliable, flag, stats.point_scale, stats.affine_scale,
                        stats.iterations, focal_std)
    return PlanarMotion(float(wrap_angle(theta - beta)), float(wrap_angle(beta)), f), stats


def _refine_focal(p1, p2, A, w, clusters, theta, beta, log_f, sp, sa, focal_range,
                  iterations: int = 10):
    """Gauss-Newton on ``(theta, beta, log f)`` over the whitened residuals (the focal derivative
    by central differences), with a cluster-robust covariance as in `_fit_whitened`.

    Point noise is fixed in pixels, so its normalised scale follows the focal length,
    ``sp(f) = sp f0 / f``; with a fixed normalised scale, growing ``f`` would shrink every
    residual and the refinement would run off to infinite focal length.
    """
    sp_px = sp * math.exp(log_f)

    def residuals(th: float, be: float, lf: float) -> np.ndarray:
        f = math.exp(lf)
        q1, q2 = p1 / f, p2 / f
        spf = sp_px / f
        r, g, h = _residual_terms(q1, q2, A, _ac_matrix(q1, q2, A), th, be)
        return (r / np.sqrt(spf * spf * g + sa * sa * h + 1e-300)).ravel()

    sw = np.repeat(np.sqrt(w), 3)
    eps = 1e-6
    lo, hi = math.log(focal_range[0]), math.log(focal_range[1])
    e = residuals(theta, beta, log_f) * sw
    cost = float(e @ e)
    for _ in range(iterations):
        J = _focal_jacobian(residuals, theta, beta, log_f, eps) * sw[:, None]
        H = J.T @ J
        if not np.all(np.isfinite(H)) or np.linalg.cond(H) > 1e14:
            break
        step = np.linalg.solve(H, J.T @ e)
        # Trust region: a weakly observable focal length must not jump (at most ~20 % a step);
        # halve the step while it raises the cost.
        step *= min(1.0, 0.2 / max(abs(step[2]), 1e-300), 0.05 / max(abs(step[:2]).max(), 1e-300))
        for _ in range(8):
            cand = (theta - step[0], beta - step[1], min(max(log_f - step[2], lo), hi))
            e_new = residuals(*cand) * sw
            cost_new = float(e_new @ e_new)
            if cost_new <= cost:
                break
            step *= 0.5
        else:
            break
        theta, beta, log_f = cand
        e, cost = e_new, cost_new
        if np.abs(step).sum() < 1e-12:
            break
    J = _focal_jacobian(residuals, theta, beta, log_f, eps) * sw[:, None]
    H = J.T @ J
    if not np.all(np.isfinite(H)) or np.linalg.cond(H) > 1e14:
        return theta, beta, log_f, np.full((3, 3), np.inf)
    Hinv = np.linalg.inv(H)
    cov = Hinv * max(cost, 1e-300) / max(e.size - 3, 1)
    scores = (J * e[:, None]).reshape(-1, 3, 3).sum(axis=1)                # per AC, (m, 3)
    per_cluster = np.stack([np.bincount(clusters, weights=scores[:, k]) for k in range(3)], 1)
    robust = Hinv @ (per_cluster.T @ per_cluster) @ Hinv
    if np.all(np.isfinite(robust)) and np.trace(robust) > np.trace(cov):
        cov = robust
    return theta, beta, log_f, cov


def _focal_jacobian(residuals, theta: float, beta: float, log_f: float, eps: float
                    ) -> np.ndarray:
    """Central-difference Jacobian of `residuals` w.r.t. ``(theta, beta, log f)``."""
    return np.stack([
        residuals(theta + eps, beta, log_f) - residuals(theta - eps, beta, log_f),
        residuals(theta, beta + eps, log_f) - residuals(theta, beta - eps, log_f),
        residuals(theta, beta, log_f + eps) - residuals(theta, beta, log_f - eps),
    ], axis=1) / (2.0 * eps)


class FocalCalibrator:
    """Online focal-length self-calibration from many frames (1ACf voting per frame).

    Every frame pair goes through `vote_planar_motion_focal`; a frame that does not reveal the
    focal length (straight driving: flagged ``'focal_unobservable'``, or unreliable) contributes
    nothing. Informative frames contribute their focal length with its standard deviation. The
    running estimate is the inverse-variance weighted median of the frames' focal lengths (robust
    to an occasional bad frame); its standard deviation is the larger of the combined
    inverse-variance one and the weighted spread between frames over ``sqrt(frames)``.

    Args:
        focal_range: plausible focal lengths in pixels.
        config: `VotingConfig` for the per-frame estimates.
    """

    def __init__(self, focal_range: tuple[float, float] = (50.0, 20000.0),
                 config: VotingConfig | None = None) -> None:
        if not (0.0 < focal_range[0] < focal_range[1]):
            raise ConfigError(f'focal_range: expected 0 < min < max, got {focal_range}')
        self.focal_range = (float(focal_range[0]), float(focal_range[1]))
        self.config = VotingConfig() if config is None else config
        self._focal: list[float] = []
        self._std: list[float] = []
        self.frames_seen = 0

    def add(self, p1: np.ndarray, p2: np.ndarray, A: np.ndarray,
            weights: np.ndarray | None = None) -> bool:
        """Add one frame pair's ACs (pixels relative to the principal point; A in pixels).

        Returns whether the frame was informative (it revealed the focal length).
        """
        self.frames_seen += 1
        if len(p1) < self.config.min_inliers:
            return False                    # nothing to learn from this pair
        motion, stats = vote_planar_motion_focal(p1, p2, A, weights, self.config,
                                                 focal_range=self.focal_range)
        if not stats.reliable or not math.isfinite(stats.focal_std):
            return False
        self._focal.append(motion.focal)
        self._std.append(stats.focal_std)
        return True

    @property
    def informative_frames(self) -> int:
        return len(self._focal)

    @property
    def estimate(self) -> float:
        """Current focal length in pixels (NaN before the first informative frame)."""
        if not self._focal:
            return float('nan')
        f, s = np.array(self._focal), np.array(self._std)
        return self._weighted_median(f, 1.0 / np.maximum(s, 1e-9) ** 2)

    @property
    def std(self) -> float:
        """Standard deviation of `estimate` in pixels (inf before the first informative frame)."""
        if not self._focal:
            return float('inf')
        f, s = np.array(self._focal), np.array(self._std)
        w = 1.0 / np.maximum(s, 1e-9) ** 2
        combined = 1.0 / math.sqrt(float(w.sum()))
        if f.size < 3:
            return combined
        m = self._weighted_median(f, w)
        spread = _MAD * self._weighted_median(np.abs(f - m), w) / math.sqrt(f.size)
        return max(combined, spread)

    @staticmethod
    def _weighted_median(x: np.ndarray, w: np.ndarray) -> float:
        order = np.argsort(x)
        c = np.cumsum(w[order])
        return float(x[order][np.searchsorted(c, 0.5 * c[-1])])
