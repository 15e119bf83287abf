"""1AC-RANSAC with local optimisation: the sampling comparison for histogram voting
(``VotingConfig(method='ransac')``)."""

from __future__ import annotations

import math

import numpy as np

from planar_vo.core.conventions import wrap_angle
from planar_vo.core.robust import refine
from planar_vo.core.robust.options import VotingConfig
from planar_vo.core.robust.types import PlanarMotion, VotingStats, failed_estimate
from planar_vo.core.solvers import solve_1ac

__all__ = ['ransac_planar_motion']


def ransac_planar_motion(q1, q2, A, w, config: VotingConfig, clusters: np.ndarray
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
        return failed_estimate(n, 'too_few_candidates', int(valid.size))
    rows = refine.design_rows(q1, q2, A)
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
        _, g, h = refine.residual_terms(q1, q2, A, rows, theta, beta)
        return refine.whiten_rows(rows, g, h, sp, sa)

    def score(theta: float, beta: float) -> tuple[float, np.ndarray]:
        r, g, h = refine.residual_terms(q1, q2, A, rows, theta, beta)
        chi2 = (refine.whitened(r, g, h, sp, sa) ** 2).sum(axis=1)
        return float((w * np.minimum(chi2, config.inlier_chi2)).sum()), chi2 <= config.inlier_chi2

    while done < min(needed, order.size):
        idx = order[done:done + batch]
        done += idx.size
        th = alpha_c[idx] + beta_c[idx]
        be = beta_c[idx]
        x = np.stack([np.cos(th), np.sin(th), np.cos(be), np.sin(be)])        # (4, H)
        r = (rows.T @ x).reshape(n, 3, -1)                                     # (N, 3, H)
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
                t2, b2, _, _ = refine.fit_whitened(whiten(theta, beta),
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
    theta, beta, inliers, cov, rms = refine.select_and_refine(whiten(theta, beta), w, theta, beta,
                                                              config, clusters)
    num_inliers = int(np.count_nonzero(inliers))
    sharpness = float(w[inliers].sum() / w.sum())
    flag = 'too_few_inliers' if num_inliers < config.min_inliers else None
    cov_ab = refine.to_alpha_beta_cov(cov) if flag is None else np.full((2, 2), np.inf)
    return (PlanarMotion(float(wrap_angle(theta - beta)), float(wrap_angle(beta))),
            VotingStats(inliers, num_inliers, int(valid.size), sharpness, 0.0, rms, cov_ab,
                        flag is None, flag, sp, sa, iterations=done))
