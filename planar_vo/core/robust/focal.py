"""Planar motion and the common focal length from many ACs: 1ACf candidates voted in log-focal
space, the calibrated estimator at the voted focal length, and a joint refinement."""

from __future__ import annotations

import math

import numpy as np

from planar_vo.core.conventions import wrap_angle
from planar_vo.core.robust import refine
from planar_vo.core.robust.histogram import circular_kernel
from planar_vo.core.robust.options import VotingConfig
from planar_vo.core.robust.types import (
    PlanarMotion,
    VotingStats,
    check_clusters,
    check_inputs,
    failed_estimate,
)
from planar_vo.core.robust.vote import vote_planar_motion
from planar_vo.core.solvers import _ac_matrix, solve_1acf
from planar_vo.errors import ConfigError

__all__ = ['vote_planar_motion_focal']


def _log_focal_modes(log_f: np.ndarray, weights: np.ndarray, lo: float, hi: float, bins: int,
                     count: int) -> list[float]:
    """The ``count`` highest local maxima of the smoothed log-focal histogram, refined by mean
    shift (per-AC 1ACf focal candidates are noisy, so the best start is not always the top)."""
    width = (hi - lo) / bins
    idx = np.clip(((log_f - lo) / width).astype(np.intp), 0, bins - 1)
    hist = np.convolve(np.bincount(idx, weights=weights, minlength=bins),
                       circular_kernel(bins, 4.0), mode='same')
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
    p1, p2, A, w, config = check_inputs(p1, p2, A, weights, config)
    lo, hi = float(focal_range[0]), float(focal_range[1])
    if not (0.0 < lo < hi and math.isfinite(hi)):
        raise ConfigError(f'focal_range: expected 0 < min < max, got {focal_range}')
    n = p1.shape[0]
    clusters = check_clusters(clusters, n)
    if clusters is None:
        clusters = refine.spatial_clusters(p1, config.covariance_grid)
    _, _, f_c, cond = solve_1acf(p1, p2, A, return_weight=True)
    ok = np.isfinite(f_c) & (f_c >= lo) & (f_c <= hi) & (w > 0)
    if np.count_nonzero(ok) < config.min_inliers:
        return failed_estimate(n, 'too_few_candidates', int(np.count_nonzero(ok)))
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
        return failed_estimate(n, 'too_few_inliers', int(np.count_nonzero(ok)))
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
    cov_ab = refine.to_alpha_beta_cov(cov3[:2, :2]) if reliable else np.full((2, 2), np.inf)
    stats = VotingStats(stats.inliers, stats.num_inliers, stats.num_candidates,
                        stats.peak_sharpness, stats.ambiguity, stats.residual_rms, cov_ab,
                        reliable, flag, stats.point_scale, stats.affine_scale,
                        stats.iterations, focal_std)
    return PlanarMotion(float(wrap_angle(theta - beta)), float(wrap_angle(beta)), f), stats


def _refine_focal(p1, p2, A, w, clusters, theta, beta, log_f, sp, sa, focal_range,
                  iterations: int = 10):
    """Gauss-Newton on ``(theta, beta, log f)`` over the whitened residuals (the focal derivative
    by central differences), with a cluster-robust covariance as in `fit_whitened`.

    Point noise is fixed in pixels, so its normalised scale follows the focal length,
    ``sp(f) = sp f0 / f``; with a fixed normalised scale, growing ``f`` would shrink every
    residual and the refinement would run off to infinite focal length.
    """
    sp_px = sp * math.exp(log_f)

    def residuals(th: float, be: float, lf: float) -> np.ndarray:
        f = math.exp(lf)
        q1, q2 = p1 / f, p2 / f
        spf = sp_px / f
        r, g, h = refine.residual_terms(q1, q2, A, _ac_matrix(q1, q2, A), th, be)
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
