"""Robust planar motion from many affine correspondences: weighted histogram voting (and RANSAC).

One AC gives one motion candidate (`solve_1ac`), so robust estimation can be exhaustive and
deterministic (Hajder and Barath, section 3.4; Bujnak et al. 2009 for weighted voting):

1. every AC's candidate ``(alpha_i, beta_i)`` votes, with its weight, into a kernel-smoothed
   histogram on the circle for ``alpha``; the peak is refined below bin resolution by mean shift;
2. the ACs that agree on ``alpha`` vote for ``beta`` the same way;
3. inliers are selected by the whitened residual of all three AC constraints (epipolar + two
   affine) at the voted motion, with noise scales estimated robustly from the peak's members;
4. ``(alpha, beta)`` are refined by weighted Gauss-Newton on all inliers' constraints, giving a
   2x2 covariance from the normal equations, the whitening held per round; then a step on the
   Sampson cost itself (`refine.sampson_refine`, the whitening's derivative included: the held
   whitening's fixed point is biased at second order in the noise, 3 standard deviations at 5
   deg of yaw and beta -60 deg with 1,600 ACs at 0.5 px, a library user test; on the paper's
   general protocol the median error of the reliable answers halves, 0.175 to 0.082 deg);
5. the yaw around the answer is scanned for another basin of the cost (`basins`): the
   refinement holds its whitening fixed per round, and where the whitening depends strongly on
   the motion (few ACs on one plane, large yaw, sideways travel) it can settle, self-consistent
   and confident, in the wrong basin its biased 1AC candidates started it in. A basin clearly
   lower (a likelihood ratio of 100) is taken at the Sampson cost's own minimum when the
   points agree (their epipolar residuals alone lower by that and a standard deviation more:
   one plane's two homography decompositions explain its points alike); otherwise, or within
   the margin, the estimate is flagged ``'ambiguous'``. On the paper's protocol (general motion,
   50 ACs on one plane, 1 px and 0.02 affine noise; 100 seeded trials, the voting tests) 3 of 42
   reliable answers were more than 1 deg off, against 11 of 48 without the scan; straight ahead
   no answer got worse (300 trials); on KITTI 05 and 06 and the car-like street pairs it
   changed no answer (375 and 35 votes).

Cost is linear in the number of ACs and independent of the outlier ratio. Degenerate or
ambiguous input gives a flagged result (``stats.reliable`` False, ``stats.flag`` says why), never
an exception and never a silently confident wrong answer. A 1AC-RANSAC with local optimisation
sits behind the same interface (``VotingConfig(method='ransac')``) for comparison.

The pieces: `planar_vo.core.robust.histogram` (voting), `planar_vo.core.robust.refine`
(whitening, refinement, covariance), `planar_vo.core.robust.ransac` (the comparison) and
`planar_vo.core.robust.focal` (the unknown-focal variant).
"""

from __future__ import annotations

import math

import numpy as np

from planar_vo.core.conventions import wrap_angle
from planar_vo.core.robust import basins, histogram, refine
from planar_vo.core.robust.options import VotingConfig
from planar_vo.core.robust.ransac import ransac_planar_motion
from planar_vo.core.robust.stats import MAD_TO_SIGMA, STAT_SAMPLE, lower_quantile, thin
from planar_vo.core.robust.types import (
    PlanarMotion,
    VotingStats,
    check_clusters,
    check_config,
    check_inputs,
    failed_estimate,
)
from planar_vo.core.solvers import _ac_null_vectors, _cheirality_flip, solve_1ac

__all__ = ['PlanarMotion', 'VotingStats', 'vote_planar_motion']


def vote_planar_motion(q1: np.ndarray, q2: np.ndarray, A: np.ndarray,
                       weights: np.ndarray | None = None, config: VotingConfig | None = None,
                       *, clusters: np.ndarray | None = None, covariance: bool = True,
                       check: bool = True, scan: bool = True, sampson: bool = True
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
        covariance: False skips the covariance of the histogram method's refinement
            (``stats.covariance`` infinite, ``stats.residual_rms`` NaN; with
            ``config.refine`` False the single selection still gives both) for a caller that
            uses only the motion, the inliers and the noise scales; everything else is the
            same.
        check: False skips the checks of ``q1, q2, A`` and the weights (a caller whose arrays
            are checked already: `AffineCorrespondences` with non-negative weights, the
            pipeline's estimator at every frame); the config is checked either way.
        scan: False skips the search for another basin of the cost after the refinement
            (`planar_vo.core.robust.basins`, about 0.2-0.4 ms) for a caller that screens and
            refines the answer itself (the pipeline's revote of the ACs its first answer leaves
            unexplained).
        sampson: False skips the last refinement on the Sampson cost itself
            (`refine.sampson_refine`: unbiased where the refinement with the whitening held per
            round is biased at second order in the noise; about 0.2 ms per 1,000 inliers) for a
            caller whose own refinement follows (the pipeline's general motion, the focal
            profiles).

    Returns:
        ``(motion, stats)``: a `PlanarMotion` and `VotingStats`. When ``stats.reliable`` is
        False, ``stats.flag`` says why; the angles may still be the best guess (or NaN).

    Raises:
        InputError: wrong shapes, non-finite or negative values; ConfigError: a bad config.
    """
    if check:
        q1, q2, A, w, config = check_inputs(q1, q2, A, weights, config)
    else:
        w = np.ones(q1.shape[0]) if weights is None else weights
        config = check_config(config)
    clusters = check_clusters(clusters, q1.shape[0])
    if clusters is None and (covariance or config.method == 'ransac'):
        clusters = refine.spatial_clusters(q1, config.covariance_grid)
    if config.method == 'ransac':
        return ransac_planar_motion(q1, q2, A, w, config, clusters)
    n = q1.shape[0]
    nv = None
    if config.refine_candidates:
        alpha_c, beta_c = solve_1ac(q1, q2, A, refine=True)
    else:
        # The null vector n ~ [cos th, sin th, cos b, sin b] gives alpha = th - b directly, by
        # one arctan2 of the angle difference (the two pairs' norms are positive factors).
        # Alpha does not depend on the null vector's sign (flipping it adds pi to both angles),
        # so beta and its cheirality are resolved below only for the ACs that vote on beta.
        nv = _ac_null_vectors(q1, q2, A)
        n0, n1, n2, n3 = nv.T
        alpha_c = np.arctan2(n1 * n2 - n0 * n3, n0 * n2 + n1 * n3)
        alpha_c[((n0 == 0.0) & (n1 == 0.0)) | ((n2 == 0.0) & (n3 == 0.0))] = np.nan
    valid = np.isfinite(alpha_c) & (w > 0)
    num_candidates = int(np.count_nonzero(valid))
    if num_candidates < config.min_inliers:
        return failed_estimate(n, 'too_few_candidates', num_candidates)
    valid_idx = np.flatnonzero(valid)
    a_v, w_v = alpha_c[valid_idx], w[valid_idx]

    exclusion = 6.0 * config.kernel_bins * histogram.TWO_PI / config.bins
    alpha0, sharpness, ambiguity, bw, offsets = histogram.peak(a_v, w_v, config, exclusion)
    near_alpha = np.abs(offsets) <= 3.0 * bw
    near_idx = thin(valid_idx[near_alpha])
    if nv is None:
        b_near = beta_c[near_idx]
    else:
        b_near = np.arctan2(nv[near_idx, 3], nv[near_idx, 2])
        flip = _cheirality_flip(q1[near_idx], q2[near_idx], alpha_c[near_idx], b_near)
        b_near = histogram.wrap(b_near + np.pi * flip)
    beta0, _, _, bw_b, beta_offsets = histogram.peak(b_near, w[near_idx], config, exclusion)
    beta_offsets = np.abs(beta_offsets)

    members = near_idx[beta_offsets <= 3.0 * bw_b]
    theta, beta, inliers, cov, rms, sp, sa, twice = _two_rounds(
        q1, q2, A, w, alpha0 + beta0, beta0, members, config, clusters, covariance)
    refined = PlanarMotion(float(wrap_angle(theta - beta)), float(wrap_angle(beta)))
    if twice and sampson:
        # The minimum of the Sampson cost itself (the rounds hold their whitening: a biased
        # fixed point); the inliers and the covariance stay those of the last round, a few
        # standard deviations at most away.
        idx = np.flatnonzero(inliers & (w > 0))
        theta, beta = refine.sampson_refine(q1[idx], q2[idx], A[idx], w[idx], theta, beta,
                                            sp, sa)
    # Another basin of the cost (`basins`): a start in the wrong one ends at a self-consistent
    # wrong motion. From a clearly lower one the Sampson cost's own minimum is taken if it
    # stays lower; a rival within the margin either way makes the estimate ambiguous.
    switched = basin_ambiguous = False
    if twice and scan:
        alt = basins.other_basin(q1, q2, A, w, inliers, theta, beta, sp, sa, config.inlier_chi2)
        if alt is not None and alt.cost_change < -_BASIN_MARGIN:
            start = basins.polish(q1, q2, A, w, inliers, alt.theta, alt.beta, sp, sa,
                                  config.inlier_chi2)
            new = _settle(q1, q2, A, w, *start, thin(np.flatnonzero(inliers)), config, clusters,
                          covariance)
            change, points, compared = basins.cost_change(
                q1, q2, A, w, inliers | new[2], (theta, beta, sp, sa), new[:2] + new[5:],
                config.inlier_chi2)
            # Taken only when the points agree: their epipolar residuals alone lower by the
            # margin and a standard deviation of the difference of two equally good fits'
            # chi-squares over the ACs compared (2 sqrt(N)). Both motions explain one plane's
            # points alike (one homography, two decompositions), and the affines fitted to it
            # can favour either: then the two are ambiguous.
            if np.count_nonzero(new[2]) >= config.min_inliers and \
                    change < -_BASIN_MARGIN and \
                    points < -(_BASIN_MARGIN + 2.0 * math.sqrt(compared)):
                theta, beta, inliers, cov, rms, sp, sa = new
                switched = True
            else:
                basin_ambiguous = change <= _BASIN_MARGIN
        elif alt is not None:
            basin_ambiguous = alt.rival_change <= _BASIN_MARGIN
    motion = PlanarMotion(float(wrap_angle(theta - beta)), float(wrap_angle(beta)))
    num_inliers = int(np.count_nonzero(inliers))
    # The refined motion must stay in the voted peak: leaving it means the inliers' constraints
    # disagree with the votes they cast (a peak made of outliers, or a degenerate geometry).
    # Alpha candidates are sharp; beta candidates can spread widely (forward motion), so beta is
    # judged against the robust spread of the peak's own beta candidates. (Judged before the
    # Sampson step: the 1AC candidates share the bias it removes.)
    beta_spread = bw_b
    if beta_offsets.size:
        beta_spread = max(bw_b, MAD_TO_SIGMA * lower_quantile(beta_offsets, 0.5))
    drift = max(abs(float(wrap_angle(refined.alpha - alpha0))) / (3.0 * bw),
                abs(float(wrap_angle(refined.beta - beta0))) / (3.0 * beta_spread))
    flag = None
    if num_inliers < config.min_inliers:
        flag = 'too_few_inliers'
    elif drift > 1.0 and not switched:
        flag = 'unstable'
    elif ambiguity >= config.ambiguity_ratio or basin_ambiguous:
        flag = 'ambiguous'
    elif sharpness < config.min_sharpness:
        flag = 'weak_peak'
    elif _no_parallax(q1, q2, inliers, motion.alpha, sp):
        flag = 'no_parallax'
    cov_ab = refine.to_alpha_beta_cov(cov)
    if flag is not None:
        cov_ab = np.full((2, 2), np.inf)
    stats = VotingStats(inliers, num_inliers, num_candidates, sharpness, ambiguity, rms, cov_ab,
                        flag is None, flag, sp, sa)
    return motion, stats


# A basin of the cost this much lower (chi-square units of the mean AC: a likelihood ratio of
# 100) is taken; within it either way the estimate is ambiguous.
_BASIN_MARGIN = 2.0 * math.log(100.0)


def _noise_caps(config: VotingConfig) -> tuple[float, float]:
    """The most the data-driven point and affine noise scales may be (``max_noise_factor``
    times the nominal levels)."""
    return (config.max_noise_factor * config.point_noise,
            config.max_noise_factor * config.affine_noise)


def _two_rounds(q1, q2, A, w, theta0, beta0, members, config, clusters, covariance):
    """Selection and refinement from ``(theta0, beta0)``: noise scales from ``members`` (the
    lower quartile: a share of them may be outliers) and one refinement, then, with
    ``config.refine`` and enough inliers, scales from the inliers (the median) and up to three
    more (above `_FIRST_ROUND_SAMPLE` ACs the first round runs on an even sample of them:
    `_sampled_first_round`). Returns ``theta, beta, inliers, cov, rms, sp, sa`` and whether the
    second round ran."""
    sp_cap, sa_cap = _noise_caps(config)
    sampled = _sampled_first_round(q1, q2, A, w, theta0, beta0, members, config)
    if sampled is not None:
        theta, beta, sp, sa = sampled
        twice, scratch, wrows, sample = True, None, None, None
    else:
        # The whitened rows are rebuilt in the same buffer for the second round: with one
        # scratch buffer for the fits, two arrays of the rows' size serve every step below
        # (see `refine.select_and_refine` on why).
        wrows, scratch, (theta, beta, inliers, cov, rms), sp, sa = _first_round(
            q1, q2, A, w, theta0, beta0, members, config, covariance=not config.refine,
            keep=True)
        twice = config.refine and np.count_nonzero(inliers) >= max(config.min_inliers, 4)
        sample = thin(np.flatnonzero(inliers))
    if twice:
        # Second round: noise scales from the inliers at the refined motion (clean, so the
        # median is the right statistic), then the same selection and refinement again.
        rows = refine.design_rows(q1, q2, A, out=wrows)
        r, g, h = refine.residual_terms(q1, q2, A, rows, theta, beta)
        if sample is None:
            # (after a sampled first round: its inliers among all the ACs, at its motion)
            chi2 = np.sum(refine.whitened(r, g, h, sp, sa) ** 2, axis=1)
            sample = thin(np.flatnonzero((chi2 <= config.inlier_chi2) & (w > 0)))
            scratch = np.empty_like(rows)
        sp, sa = refine.robust_scales(r[sample], g[sample], h[sample], quantile=0.5)
        sp, sa = min(sp, sp_cap), min(sa, sa_cap)
        wrows = refine.whiten_rows(rows, g, h, sp, sa, out=rows)
        theta, beta, inliers, cov, rms = refine.select_and_refine(
            wrows, w, theta, beta, config, clusters, passes=3, covariance=covariance,
            scratch=scratch)
    elif config.refine and covariance:
        _, _, _, cov, rms = refine.select_and_refine(wrows, w, theta, beta, config, clusters,
                                                     passes=1, scratch=scratch)
    return theta, beta, inliers, cov, rms, sp, sa, twice


def _sampled_first_round(q1, q2, A, w, theta0, beta0, members, config):
    """The first round of `_two_rounds` on an even sample of the ACs when there are more than
    `_FIRST_ROUND_SAMPLE` (its motion only starts the second round, which selects and refines
    on all of them, and its inliers only give the second round's noise scales, from a sample
    anyway): ``theta, beta`` and its noise scales, or None (too few ACs to sample, or too few
    members or inliers in the sample: the whole first round runs)."""
    n = q1.shape[0]
    if not config.refine or n <= _FIRST_ROUND_SAMPLE:
        return None
    sub = thin(np.arange(n), _FIRST_ROUND_SAMPLE)
    in_sub = np.zeros(n, bool)
    in_sub[sub] = True
    at = np.cumsum(in_sub) - 1                       # position in the sample of a sampled AC
    own = at[members[in_sub[members]]]
    if own.size < max(config.min_inliers, 4):
        return None
    _, _, (theta, beta, inliers, _, _), sp, sa = _first_round(
        q1[sub], q2[sub], A[sub], w[sub], theta0, beta0, own, config, covariance=False)
    if np.count_nonzero(inliers) < max(config.min_inliers, 4):
        return None
    return theta, beta, sp, sa


def _first_round(q1, q2, A, w, theta0, beta0, members, config, *, covariance, keep=False):
    """The first round of `_two_rounds` on the given ACs: the residual terms at the start,
    noise scales from ``members`` (near both modes of the vote: the lower quartile, capped)
    and, with that whitening kept (the vote is within a degree, where the first-order
    standard deviations barely change), one selection and refinement. Returns the whitened
    rows, a scratch buffer of their shape (``keep``; else None), `refine.select_and_refine`'s
    ``(theta, beta, inliers, cov, rms)`` and the scales ``sp, sa``."""
    rows = refine.design_rows(q1, q2, A)
    r, g, h = refine.residual_terms(q1, q2, A, rows, theta0, beta0)
    sp_cap, sa_cap = _noise_caps(config)
    sp, sa = refine.robust_scales(r[members], g[members], h[members])
    sp, sa = min(sp, sp_cap), min(sa, sa_cap)
    wrows = refine.whiten_rows(rows, g, h, sp, sa, out=rows)       # (in place)
    scratch = np.empty_like(rows) if keep else None
    fit = refine.select_and_refine(wrows, w, theta0, beta0, config, passes=1,
                                   covariance=covariance, scratch=scratch)
    return wrows, scratch, fit, sp, sa


# Above this many ACs the first round of `_two_rounds` runs on an even sample of about as many
# (4,000 ACs of the speed benchmark: about 0.1 ms less; as accurate, a test).
_FIRST_ROUND_SAMPLE = STAT_SAMPLE


def _settle(q1, q2, A, w, theta, beta, members, config, clusters, covariance):
    """Inliers, noise scales and covariance at ``(theta, beta)`` itself (the Sampson cost's
    minimum, `basins.polish`; no refinement moves it): scales from ``members`` (the lower
    quartile), inliers, scales from them (the median), inliers again. Returns ``theta, beta,
    inliers, cov, rms, sp, sa``."""
    rows = refine.design_rows(q1, q2, A)
    r, g, h = refine.residual_terms(q1, q2, A, rows, theta, beta)
    sp_cap, sa_cap = _noise_caps(config)
    sp, sa = refine.robust_scales(r[members], g[members], h[members])
    inliers = np.zeros(w.shape[0], bool)
    for quantile in (0.25, 0.5):
        if quantile == 0.5:
            sample = thin(np.flatnonzero(inliers))
            sp, sa = refine.robust_scales(r[sample], g[sample], h[sample], quantile=0.5)
        sp, sa = min(sp, sp_cap), min(sa, sa_cap)
        chi2 = np.sum(refine.whitened(r, g, h, sp, sa) ** 2, axis=1)
        inliers = (chi2 <= config.inlier_chi2) & (w > 0)
    # The cost is the same for -t (x changes sign): the inliers' points in front of both
    # cameras decide (the vote's candidates were resolved so).
    idx = np.flatnonzero(inliers)
    if idx.size and _cheirality_flip(q1[idx][None], q2[idx][None], np.array([theta - beta]),
                                     np.array([beta]))[0]:
        theta, beta = theta + math.pi, beta + math.pi
    cov, rms = np.full((2, 2), np.inf), float('nan')
    if covariance and np.count_nonzero(inliers) >= 2:
        wrows = refine.whiten_rows(rows, g, h, sp, sa, out=rows)
        weights = w * inliers
        M = (wrows * np.repeat(weights, 3)) @ wrows.T
        _, _, H, f = refine.minimize_form(M, theta, beta, iterations=1)   # (H, f at the start)
        cov, rms = refine.cluster_covariance(wrows, weights, theta, beta, H, f, clusters)
    return theta, beta, inliers, cov, rms, sp, sa


# Nine in ten of the inliers' points move by the rotation alone within this many point noise
# scales: no parallax, the translation's direction (beta) is not observed. (Noise alone puts
# 90 % of them within 2.15 scales; a moving car's near points, a tenth of them at least, show
# more: its median point is often a distant one.)
_PARALLAX_QUANTILE, _PARALLAX_SCALES = 0.9, 4.0


def _no_parallax(q1: np.ndarray, q2: np.ndarray, inliers: np.ndarray, alpha: float,
                 sp: float) -> bool:
    """Whether the inliers' second points are where the rotation ``Ry(alpha)`` alone puts the
    first ones, within `_PARALLAX_SCALES` point noise scales (at the `_PARALLAX_QUANTILE`): a
    camera that did not move (or only turned) fits every heading, and the vote's beta is then
    noise, however sharp its peak (a user test: a standing camera's vote was reliable with a
    confident arbitrary heading)."""
    idx = thin(np.flatnonzero(inliers))            # (a quantile: an even sample will do)
    if idx.size == 0 or not (math.isfinite(alpha) and math.isfinite(sp)):
        return False
    c, s = math.cos(alpha), math.sin(alpha)
    u, v = q1[idx, 0], q1[idx, 1]
    z = -s * u + c                                   # Ry(alpha) [u, v, 1]: (c u + s, v, z)
    ok = z > 1e-9
    if not np.any(ok):
        return False
    du = q2[idx[ok], 0] - (c * u[ok] + s) / z[ok]
    dv = q2[idx[ok], 1] - v[ok] / z[ok]
    shift = np.hypot(du, dv)
    return lower_quantile(shift, _PARALLAX_QUANTILE) <= _PARALLAX_SCALES * sp
