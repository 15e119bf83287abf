"""Planar motion and the common focal length from many ACs.

- `vote_planar_motion_focal`: 1ACf candidates voted in log-focal space, the calibrated estimator
  at the voted focal length, and a joint refinement (one frame pair);
- `pair_profile` / `combine_profiles`: the profile cost of a pair's focal length on a grid, and
  the minimiser of many pairs' summed profiles with a cluster-robust standard deviation
  (self-calibration over a drive without the low bias of per-AC focal lengths);
- `shifted_profile`: the same pair's profile with the principal point moved, to first order
  (the focal length's sensitivity to an assumed principal point, at a fraction of a profile's
  cost).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from planar_vo.core.conventions import wrap_angle
from planar_vo.core.robust import refine
from planar_vo.core.robust.histogram import circular_kernel
from planar_vo.core.robust.options import VotingConfig
from planar_vo.core.robust.stats import CHI2_3_99
from planar_vo.core.robust.types import (
    PlanarMotion,
    VotingStats,
    check_clusters,
    check_inputs,
    failed_estimate,
)
from planar_vo.core.robust.vote import vote_planar_motion
from planar_vo.core.solvers import solve_1acf
from planar_vo.errors import ConfigError

__all__ = [
    'PairProfile',
    'combine_profiles',
    'pair_profile',
    'profile_steps',
    'shifted_profile',
    'vote_planar_motion_focal',
]


def _log_focal_modes(log_f: np.ndarray, weights: np.ndarray, lo: float, hi: float, bins: int,
                     count: int) -> list[float]:
    """The ``count`` highest local maxima of the smoothed log-focal histogram, refined by mean
    shift (per-AC 1ACf focal candidates are noisy, so the best start is not always the top)."""
    width = (hi - lo) / bins
    idx = np.clip(((log_f - lo) / width).astype(np.intp), 0, bins - 1)
    hist = np.convolve(np.bincount(idx, weights=weights, minlength=bins),
                       circular_kernel(bins, 4.0), mode='same')
    # (the log-focal axis is not circular: its ends have one neighbour each; a review)
    line = np.concatenate([[-np.inf], hist, [-np.inf]])
    peaks = np.flatnonzero((hist > 0) & (hist >= line[:-2]) & (hist >= line[2:]))
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
        p1, p2: pixel coordinates relative to the principal point, shape ``(N, 2)`` (not
            normalised ones: their candidates, about 1 px, fall below ``focal_range`` and the
            result is ``'too_few_candidates'``).
        A: local affines in pixels, shape ``(N, 2, 2)``.
        weights, config, clusters: as for `vote_planar_motion`.
        focal_range: plausible focal lengths in pixels, ``(min, max)``.
        min_conditioning, max_focal_rel_std: observability thresholds (see above).
        starts: number of focal modes tried.

    Returns:
        ``(motion, stats)`` with ``motion.focal`` and ``stats.focal_std`` (pixels).
    """
    p1, p2, A, w, config = check_inputs(p1, p2, A, weights, config)
    # (a user test: ('a', 'b'), (600,) and None raised ValueError, IndexError, TypeError)
    try:
        lo, hi = (float(v) for v in focal_range)
    except (TypeError, ValueError):
        lo = hi = math.nan
    if not (0.0 < lo < hi and math.isfinite(hi)):
        raise ConfigError(f'focal_range: expected (min, max) pixels with 0 < min < max, got '
                          f'{focal_range!r}')
    if isinstance(starts, bool) or not isinstance(starts, (int, np.integer)) or starts < 1:
        raise ConfigError(f'starts: expected a positive integer number of focal modes, got '
                          f'{starts!r}')
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
        motion, stats = vote_planar_motion(p1 / f0, p2 / f0, A, w, config, clusters=clusters,
                                           sampson=False)
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
        # (the answer's motion: the Sampson cost's minimum at the refined focal length)
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
        r, g, h = refine.residual_terms(q1, q2, A, refine.design_rows(q1, q2, A), th, be)
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


# --------------------------------------------------------------------------------------------
# Profile likelihood of the focal length (self-calibration without a per-AC focal)
# --------------------------------------------------------------------------------------------
#
# The per-AC 1ACf closed form f^2 = (n3^2 - n1^2) / (n2^2 - n4^2) divides two second-order small
# quantities (for a car both are ~alpha^2, the denominator a difference of two nearly equal O(1)
# numbers), so zero-mean noise inflates it and the per-AC focal lengths are biased low (measured
# on KITTI 05 turn pairs with the true principal point, levelled, on ground-truth inliers: per-AC
# median 93-351 px, truth 707). The calibrated 1AC machinery is unbiased at any trial focal, so
# a pair's information on f is its profile cost on a grid of focal lengths instead.


@dataclass(frozen=True)
class PairProfile:
    """One frame pair's profile cost on a log-focal grid (`pair_profile`).

    Attributes:
        cost: ``(G,)`` robust cost at each grid focal (lower is better).
        alpha, beta: ``(G,)`` the planar motion (radians) minimising it at each grid focal.
        yaw: ``|alpha|`` at the pair's own best grid focal (radians).
        point_std: point noise (pixels) and affine_std: affine noise (unitless) used.
    """

    cost: np.ndarray
    alpha: np.ndarray
    beta: np.ndarray
    yaw: float
    point_std: float
    affine_std: float


class _ProfileData:
    """What every trial focal shares for one pair: ``B(f) = B0 + B1 / f + B2 / f^2`` of the AC
    matrix of ``q = p / f`` (`planar_vo.core.solvers.planar_ac_matrix`; pixel affines do not
    change with a common focal) as rows ``(3N, 4)`` (row kind major: all epipolar rows, then the
    two affine rows), and the outer products of its parts grouped by the power of ``1 / f``
    they carry, ``(5, 3N, 16)``: the weighted normal matrix at any focal is then a few small
    matrix products instead of a pass over ``B``."""

    def __init__(self, p1: np.ndarray, p2: np.ndarray, A: np.ndarray, w: np.ndarray) -> None:
        U1, V1, U2, V2 = p1[:, 0], p1[:, 1], p2[:, 0], p2[:, 1]
        a1, a2, a3, a4 = A[:, 0, 0], A[:, 0, 1], A[:, 1, 0], A[:, 1, 1]
        z = np.zeros_like(U1)
        B0 = np.stack([np.stack([z, z, z, z], -1), np.stack([-a3, z, z, z], -1),
                       np.stack([-a4, z, z + 1.0, z], -1)])
        B1 = np.stack([np.stack([-V2, z, V1, z], -1),
                       np.stack([z, V2 + a3 * U1, z, -a1 * V1], -1),
                       np.stack([z, a4 * U1, z, -U2 - a2 * V1], -1)])
        B2 = np.stack([np.stack([z, U1 * V2, z, -U2 * V1], -1), np.stack([z, z, z, z], -1),
                       np.stack([z, z, z, z], -1)])
        self._parts = [B.reshape(-1, 4) for B in (B0, B1, B2)]
        self.parts_t = [np.ascontiguousarray(P.T) for P in self._parts]         # (4, 3N)
        self.U1, self.V1, self.U2 = U1, V1, U2
        self.sq = dict(V1=V1 * V1, V2=V2 * V2, a1=a1 * a1, a2=a2 * a2, a3=a3 * a3, a4=a4 * a4)
        self.w = w
        self.n = len(w)

    @functools.cached_property
    def products(self) -> np.ndarray:
        """``(3N, 80)``: the parts' outer products, built on first use (`normal_matrices`
        needs them; the costs alone, as in `shifted_profile`, do not)."""
        parts = self._parts
        outer = [[np.einsum('ri,rj->rij', Ba, Bb).reshape(-1, 16) for Bb in parts]
                 for Ba in parts]
        return np.concatenate([outer[0][0], outer[0][1] + outer[1][0],
                               outer[1][1] + outer[0][2] + outer[2][0],
                               outer[1][2] + outer[2][1], outer[2][2]], 1)

    def robust_cost(self, k: np.ndarray, theta: np.ndarray, beta: np.ndarray,
                    point_std: float, affine_std: float) -> np.ndarray:
        """``sum_i w_i c log(1 + chi2_i / c)`` ``(G,)`` at the given focal lengths ``1 / k`` and
        angles (see `_profile_costs`)."""
        chi2, _ = self.whitened_chi2(k, theta, beta, point_std, affine_std)
        return np.sum(self.w[None] * CHI2_3_99 * np.log1p(chi2 / CHI2_3_99), axis=1)

    def whitened_chi2(self, k: np.ndarray, theta: np.ndarray, beta: np.ndarray,
                      point_std: float, affine_std: float) -> tuple[np.ndarray, np.ndarray]:
        """Sum over the three rows of the squared residuals (`refine.residual_terms`) over
        their first-order variances ``point_std^2 k^2 g + affine_std^2 h``, ``(G, N)``, and the
        variances ``(3, G, N)``, at ``G`` trial focal lengths ``1 / k`` with angles
        ``theta, beta`` (each ``(G,)``)."""
        x = np.stack([np.cos(theta), np.sin(theta), np.cos(beta), np.sin(beta)], 1)  # (G, 4)
        kk = k[:, None]
        r0, r1, r2 = (x @ part for part in self.parts_t)                            # (G, 3N)
        r = (r0 + r1 * kk + r2 * (kk * kk)).reshape(-1, 3, self.n)
        ct, st = x[:, 0:1], x[:, 1:2]
        cb, sb = x[:, 2:3], x[:, 3:4]
        st2, sb2, kk2 = st * st, sb * sb, kk * kk
        sq = self.sq
        e = kk * self.U1 * st - ct
        g0 = kk2 * (sq['V2'] * st2 + sq['V1'] * sb2) + (cb - kk * self.U2 * sb) ** 2 + e * e
        h1 = kk2 * sq['V1'] * sb2 + e * e
        g1 = (sq['a3'] + 1.0) * st2 + sq['a1'] * sb2
        g2 = sq['a4'] * st2 + (sq['a2'] + 1.0) * sb2
        sp2 = (point_std * k)[:, None] ** 2
        sa2h = affine_std * affine_std * h1
        var = np.stack([sp2 * g0 + 1e-300, sp2 * g1 + sa2h + 1e-300, sp2 * g2 + sa2h + 1e-300])
        chi2 = r[:, 0] ** 2 / var[0] + r[:, 1] ** 2 / var[1] + r[:, 2] ** 2 / var[2]
        return chi2, var

    def normal_matrices(self, k: np.ndarray, c: np.ndarray) -> np.ndarray:
        """``M_g = sum_rows c_row B_row(f_g) B_row(f_g)^T`` ``(G, 4, 4)`` for row weights ``c``
        ``(3, G, N)``."""
        c = c.transpose(1, 0, 2).reshape(k.size, -1)
        powers = k[:, None] ** np.arange(5)                                       # (G, 5)
        M = np.einsum('gp,gpm->gm', powers, (c @ self.products).reshape(k.size, 5, 16))
        return M.reshape(-1, 4, 4)


def _minimize_forms(M: np.ndarray, theta: np.ndarray, beta: np.ndarray, iterations: int = 20
                    ) -> tuple[np.ndarray, np.ndarray]:
    """`refine.minimize_form` for ``(G, 4, 4)`` forms at once (each stops on its own: on a
    degenerate Hessian, unchanged from there, or after a step below 1e-12)."""
    theta, beta = theta.copy(), beta.copy()
    active = np.ones(theta.shape, bool)
    m = [[M[:, i, j] for j in range(4)] for i in range(4)]
    for _ in range(iterations):
        if not active.any():
            break
        ct, st, cb, sb = np.cos(theta), np.sin(theta), np.cos(beta), np.sin(beta)
        y = [m[i][0] * ct + m[i][1] * st + m[i][2] * cb + m[i][3] * sb for i in range(4)]
        g0 = -st * y[0] + ct * y[1]
        g1 = -sb * y[2] + cb * y[3]
        h00 = st * st * m[0][0] - 2.0 * st * ct * m[0][1] + ct * ct * m[1][1]
        h11 = sb * sb * m[2][2] - 2.0 * sb * cb * m[2][3] + cb * cb * m[3][3]
        h01 = st * sb * m[0][2] - st * cb * m[0][3] - ct * sb * m[1][2] + ct * cb * m[1][3]
        det = h00 * h11 - h01 * h01
        with np.errstate(invalid='ignore'):
            active &= det > 1e-300 * np.maximum(h00 * h11, 1e-300)
        safe = np.where(active, det, 1.0)
        d_t = np.where(active, (h11 * g0 - h01 * g1) / safe, 0.0)
        d_b = np.where(active, (h00 * g1 - h01 * g0) / safe, 0.0)
        theta -= d_t
        beta -= d_b
        active &= np.abs(d_t) + np.abs(d_b) >= 1e-12
    return theta, beta


def _profile_costs(data: _ProfileData, focals: np.ndarray, point_std: float, affine_std: float,
                   theta: np.ndarray, beta: np.ndarray, iterations: int = 8
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Robust cost, alpha and beta ``(G,)`` at ``G`` trial focal lengths (all at once).

    At each focal ``f``: ``q = p / f``, the residuals of the three AC rows whitened by their
    first-order standard deviations with the point noise fixed in pixels (``point_std / f``
    normalised) and the affine noise unitless, so costs compare across ``f``; the cost is
    ``sum_i w_i c log(1 + chi2_i / c)`` (Cauchy, ``c`` = `CHI2_3_99`, the chi-square(3) 99 %
    quantile: smooth in the motion, an outlier costs about the same at every ``f``), minimised
    over ``(theta, beta)`` by ``iterations`` IRLS steps from the given start (each a
    Gauss-Newton solve of the weighted form, `refine.minimize_form`; a grid point stops on its
    own when its motion stops moving).
    """
    inv = 1.0 / focals
    theta, beta = theta.copy(), beta.copy()
    active = np.arange(focals.size)
    for _ in range(iterations):
        if active.size == 0:
            break
        k = inv[active]
        chi2, var = data.whitened_chi2(k, theta[active], beta[active], point_std, affine_std)
        irls = data.w[None] / (1.0 + chi2 / CHI2_3_99)
        M = data.normal_matrices(k, irls[None] / var)
        t2, b2 = _minimize_forms(M, theta[active], beta[active])
        ok = np.isfinite(t2) & np.isfinite(b2)
        moved = np.abs(t2 - theta[active]) + np.abs(b2 - beta[active])
        theta[active] = np.where(ok, t2, theta[active])
        beta[active] = np.where(ok, b2, beta[active])
        active = active[ok & (moved >= 1e-9)]
    cost = data.robust_cost(inv, theta, beta, point_std, affine_std)
    return cost, theta - beta, beta


def profile_steps(p1: np.ndarray, p2: np.ndarray, A: np.ndarray, w: np.ndarray,
                  log_f_grid: np.ndarray, f_ref: float, config: VotingConfig | None = None,
                  noise: tuple[float, float] | None = None, chunk: int = 8):
    """`pair_profile` as a generator of small steps (the vote, then ``chunk`` grid points at a
    time): ``yield`` after each step, the `PairProfile` (or None) as its return value. A caller
    with a time budget advances it with ``next`` (`OnlineFocalCalibrator.work`)."""
    config = VotingConfig() if config is None else config
    motion, stats = vote_planar_motion(p1 / f_ref, p2 / f_ref, A, w, config, sampson=False)
    if not stats.reliable:
        return None
    sp_px, sa = (stats.point_scale * f_ref, stats.affine_scale) if noise is None else noise
    yield
    focals = np.exp(log_f_grid)
    # Start at every grid focal from the voted motion mapped along the data's valley: the image
    # pins down the pixel rotation f tan(alpha) and the epipole f cot(beta), not alpha and f
    # separately, so alpha(f) = atan(f_ref tan(alpha_ref) / f) and
    # beta(f) = atan2(sin beta_ref, cos beta_ref f_ref / f). (Continuation from neighbour to
    # neighbour instead drifts into another basin when f_ref is far off; measured.)
    a0 = np.arctan(f_ref * math.tan(motion.alpha) / focals)
    b0 = np.arctan2(math.sin(motion.beta), math.cos(motion.beta) * f_ref / focals)
    data = _ProfileData(p1, p2, A, w)
    G = focals.size
    cost, alpha, beta = np.empty(G), np.empty(G), np.empty(G)
    for lo in range(0, G, chunk):
        sl = slice(lo, min(lo + chunk, G))
        cost[sl], alpha[sl], beta[sl] = _profile_costs(data, focals[sl], sp_px, sa,
                                                       a0[sl] + b0[sl], b0[sl])
        if sl.stop < G:
            yield
    bad = ~np.isfinite(cost)
    if bad.any():
        cost[bad] = cost[~bad].max() if (~bad).any() else 0.0
    best = int(np.argmin(cost))
    return PairProfile(cost, alpha, beta, abs(float(alpha[best])), float(sp_px), float(sa))


def shifted_profile(p1: np.ndarray, p2: np.ndarray, A: np.ndarray, w: np.ndarray,
                    log_f_grid: np.ndarray, profile: PairProfile, shift: float,
                    step: float = 0.1) -> np.ndarray:
    """The pair's profile cost ``(G,)`` with the principal point moved right by ``shift`` pixels
    (the points moved left by it), to first order in the shift:

        C_shift(f) = C(f) + shift dC(f)/dcx,

    with ``dC/dcx`` by the envelope theorem: ``C(f)`` is a minimum over the motion, so its
    derivative is the cost's partial derivative at the minimising motion ``(alpha(f),
    beta(f))`` of ``profile``, here by central differences of ``+-step`` pixels.

    Why not a second profile on the moved points: that costs as much as the profile itself
    (on KITTI 05 turning pairs 30-73 ms, this 4-14 ms), and the reweighting that minimises it
    converges slowly from the pair's own motion (two steps gave the summed profiles' focal
    sensitivity to cx 36 % low). On the 19 turning pairs of KITTI 05 (principal point at the
    image centre) this gives -4.03 px of focal per px of cx, two whole profiles of 8 reweighting
    steps -4.69 and of 40 steps -3.50 (a dev script): within the approximation the
    ``|df/dcx| pp_std`` term of the standard deviation is anyway.

    Args:
        p1, p2, A, w: the pair as given to `pair_profile` (pixels from the principal point).
        log_f_grid: the profile's grid. profile: its `PairProfile` (its motion and noise).
        shift: pixels the principal point moves along x.
        step: half the central difference (pixels).
    """
    if not (math.isfinite(shift) and math.isfinite(step) and step > 0):
        raise ConfigError(f'shift, step: expected finite pixels and step > 0, got {shift}, '
                          f'{step}')
    k = np.exp(-np.asarray(log_f_grid, dtype=np.float64))
    theta = profile.alpha + profile.beta
    moved = np.array([step, 0.0])
    up, down = (_ProfileData(p1 - s * moved, p2 - s * moved, A, w).robust_cost(
        k, theta, profile.beta, profile.point_std, profile.affine_std) for s in (1.0, -1.0))
    slope = (up - down) / (2.0 * step)
    slope[~np.isfinite(slope)] = 0.0
    return profile.cost + shift * slope


def pair_profile(p1: np.ndarray, p2: np.ndarray, A: np.ndarray, weights: np.ndarray | None,
                 log_f_grid: np.ndarray, f_ref: float, config: VotingConfig | None = None,
                 noise: tuple[float, float] | None = None) -> PairProfile | None:
    """Profile cost of one frame pair's focal length on a log-focal grid:

        C(f) = min_{alpha, beta} sum_i w_i c log(1 + chi2_i(f, alpha, beta) / c),

    ``chi2_i`` the whitened residual of AC i's three rows on ``q = p / f`` (`_profile_costs`).
    The calibrated vote at ``f_ref`` gives the motion (mapped along the data's valley to every
    grid focal as the start) and, unless ``noise`` is given, the noise scales; an unreliable
    vote gives None. Exact ACs of a turning pair have their minimum at the true focal (up to
    the grid step); straight driving gives a flat profile.

    Args:
        p1, p2: pixels relative to the principal point (levelled), ``(N, 2)``.
        A: pixel affines ``(N, 2, 2)``. weights: ``(N,)`` non-negative, or None.
        log_f_grid: ``(G,)`` log focal lengths (pixels), increasing.
        f_ref: focal length (pixels) of the vote (the provisional or current estimate).
        config: the vote's options.
        noise: ``(point std in pixels, affine std)`` instead of the vote's robust scales.

    Returns:
        A `PairProfile`, or None when the vote at ``f_ref`` is unreliable.
    """
    p1, p2, A, w, config = check_inputs(p1, p2, A, weights, config)
    grid = np.asarray(log_f_grid, dtype=np.float64)
    if grid.ndim != 1 or grid.size < 3 or not np.all(np.diff(grid) > 0):
        raise ConfigError(f'log_f_grid: expected at least 3 increasing values, got {grid}')
    if not (math.isfinite(f_ref) and f_ref > 0):
        raise ConfigError(f'f_ref: expected a positive focal length in pixels, got {f_ref}')
    steps = profile_steps(p1, p2, A, w, grid, f_ref, config, noise)
    while True:
        try:
            next(steps)
        except StopIteration as done:
            return done.value


def combine_profiles(profiles: list[np.ndarray] | np.ndarray, log_f_grid: np.ndarray,
                     min_pairs: int = 3) -> tuple[float, float, dict]:
    """Minimiser of the summed profiles and its sandwich standard deviation (log focal).

    The profiles (one per cluster: a pair, or a block of pairs sharing scenery and wobble) are
    summed; the minimum is refined by a parabola through the grid neighbours, and

        var(log f) = sum_k C_k'(x)^2 / C''(x)^2 * K / (K - 1),

    never below the curvature-only ``2 / C''`` of a chi-square cost (a sandwich with the
    profiles as clusters: the spread of their own minima enters through the slopes).

    Returns:
        ``(log_f, std, info)``; ``std`` is inf with fewer than ``min_pairs`` (or 2) profiles, a
        minimum on the grid's edge, or a non-positive curvature. ``info``: ``pairs``, ``edge``,
        ``curvature``, ``slopes``.
    """
    P = np.atleast_2d(np.asarray(profiles, dtype=np.float64))
    grid = np.asarray(log_f_grid, dtype=np.float64)
    C = P.sum(axis=0)
    k = int(np.argmin(C))
    info = dict(pairs=len(P), edge=k in (0, len(C) - 1))
    if info['edge']:
        return float(grid[k]), float('inf'), info
    x0, x1 = grid[k - 1], grid[k]
    c0, c1, c2 = C[k - 1:k + 2]
    step = x1 - x0
    curv = (c0 - 2 * c1 + c2) / step ** 2
    shift = -(c2 - c0) / (2 * step) / curv if curv > 0 else 0.0
    x = x1 + float(np.clip(shift, -step, step))
    d = np.gradient(P, grid, axis=1)
    slopes = np.array([np.interp(x, grid, dk) for dk in d])
    info.update(curvature=float(curv), slopes=slopes)
    if not curv > 0 or len(P) < max(min_pairs, 2):
        return x, float('inf'), info
    var = float(np.sum((slopes / curv) ** 2)) * len(P) / (len(P) - 1)
    return x, math.sqrt(max(var, 2.0 / curv)), info
