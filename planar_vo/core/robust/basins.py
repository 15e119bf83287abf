"""Other basins of the planar AC cost: a scan of the yaw around a refined estimate.

The refinement (`planar_vo.core.robust.refine.select_and_refine`) holds each round's whitening
fixed at the round's starting motion and stops at a self-consistent point: a motion whose own
noise scales and whitening make it the least-squares answer. Where the whitening depends
strongly on the motion (a few ACs on one plane, large yaw, sideways travel: the paper's general
protocol) that point can lie in the wrong basin of the cost, and the 1AC candidates that chose
the start are biased the same way (their median 4-12 deg off at 1 px on one plane, the vote and
its refinement with them, reported with a standard deviation of 0.1-0.4 deg; a library user
test, then dev scripts). The scan finds such a point: along a grid of yaws around the estimate,
each with its best heading, the robust Sampson cost (the whitening evaluated at every grid
motion, not held) of an even sample of the estimate's inliers.

`other_basin` returns the lowest local minimum of that profile other than the estimate, and how
much lower than the estimate's its cost is (also when the estimate's own descent leads there:
the start was on a slope), and the same for the best minimum beyond the estimate's basin
(`cost_change`, `polish`: the comparison and the Sampson minimum for a switch). Cost: the
headings from one Gram matrix, the costs of 21 motions in one vectorised evaluation, on at most
256 ACs (about 0.3 ms).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from planar_vo.core.robust import refine
from planar_vo.core.robust.stats import thin

__all__ = ['OtherBasin', 'cost_change', 'other_basin', 'polish', 'sampson_costs']

# The yaw grid: +-20 deg around the estimate in 2-deg steps (the wrong basins seen on the paper's
# protocol lay 1-13 deg from the truth; a basin there is 2-6 deg wide at 1 px of noise).
_SPAN, _STEP = math.radians(20.0), math.radians(2.0)
# ACs of the scan (an even sample of the estimate's inliers).
_SAMPLE = 256


@dataclasses.dataclass(frozen=True)
class OtherBasin:
    """The lowest local minimum of the yaw profile other than the estimate: its grid motion and
    its cost minus the estimate's (chi-square units of the mean AC weight; negative: lower),
    and the same for the lowest minimum outside the estimate's basin (``rival_change``; inf:
    none), the one that makes the estimate ambiguous."""

    theta: float
    beta: float
    cost_change: float
    rival_change: float


def sampson_costs(q1: np.ndarray, q2: np.ndarray, A: np.ndarray, rows: np.ndarray,
                  theta: np.ndarray, beta: np.ndarray, sp: float, sa: float,
                  w: np.ndarray | None, gate: float, epipolar_only: bool = False
                  ) -> np.ndarray:
    """Robust cost ``sum_i w_i min(chi2_i, gate)`` of each of K motions ``(theta, beta)``
    ``(K,)`` (``chi2_i``: AC ``i``'s three residuals whitened at that motion, as
    `refine.residual_terms` does for one; ``epipolar_only``: its epipolar residual alone);
    ``rows``: the ACs' `refine.design_rows`. ``(K,)``; with ``w`` None each AC's chi-square
    instead, ``(K, N)``."""
    theta = np.asarray(theta, dtype=np.float64)
    beta = np.asarray(beta, dtype=np.float64)
    x = np.stack([np.cos(theta), np.sin(theta), np.cos(beta), np.sin(beta)], axis=1)
    r = (x @ rows).reshape(theta.shape[0], -1, 3)                            # (K, N, 3)
    r *= r
    inv = _inverse_variances(q1, q2, A, x, sp, sa, epipolar_only)
    chi2 = r[..., 0] * inv[0]
    if not epipolar_only:
        chi2 += r[..., 1] * inv[1]
        chi2 += r[..., 2] * inv[2]
    return chi2 if w is None else np.minimum(chi2, gate) @ w


def _best_headings(alphas: np.ndarray, M: np.ndarray) -> np.ndarray:
    """For each yaw, the heading ``beta`` minimising ``x^T M_k x`` with ``x = [cos(alpha +
    beta), sin(alpha + beta), cos beta, sin beta] = Q(alpha) [cos beta, sin beta]``: the
    eigenvector of the smallest eigenvalue of ``Q^T M Q`` (2x2); ``M`` the whitened rows'
    weighted Gram matrix ``(4, 4)``."""
    ca, sa = np.cos(alphas), np.sin(alphas)
    Q = np.zeros((alphas.size, 4, 2))
    Q[:, 0, 0], Q[:, 0, 1], Q[:, 1, 0], Q[:, 1, 1] = ca, -sa, sa, ca
    Q[:, 2, 0] = Q[:, 3, 1] = 1.0
    S = np.swapaxes(Q, 1, 2) @ M @ Q
    a, b, c = S[:, 0, 0], S[:, 0, 1], S[:, 1, 1]
    lam = 0.5 * (a + c) - np.sqrt(0.25 * (a - c) ** 2 + b * b)
    # (b, lam - a) is that eigenvector; when b vanishes the smaller diagonal entry's axis.
    flat = np.abs(b) <= 1e-300
    return np.where(flat, np.where(a <= c, 0.0, 0.5 * np.pi), np.arctan2(lam - a, b))


def _inverse_variances(q1: np.ndarray, q2: np.ndarray, A: np.ndarray, x: np.ndarray,
                       sp: float, sa: float, epipolar_only: bool = False) -> np.ndarray:
    """The inverse first-order variances of the ACs' three residuals at each of K motions
    ``x = [cos theta, sin theta, cos beta, sin beta]`` ``(K, 4)``, ``(3, K, N)`` (only the
    first with ``epipolar_only``): the terms of `refine.residual_terms`, each a sum of
    products of the motion's ``st^2, sb^2, cb sb, st ct, ct^2, cb^2`` with the AC's own
    coefficients, so all K motions are one small matrix product (``d/du1`` of the epipolar
    row ``(u1 st - ct)^2 = u1^2 st^2 - 2 u1 st ct + ct^2`` and so on)."""
    u1, v1, u2, v2 = q1[:, 0], q1[:, 1], q2[:, 0], q2[:, 1]
    ct, st, cb, sb = x.T
    C = np.stack([st * st, sb * sb, -2.0 * cb * sb, -2.0 * st * ct, ct * ct, cb * cb], 1)
    sp2, sa2 = sp * sp, sa * sa
    uu, vv = u1 * u1, v1 * v1
    F = np.zeros((1 if epipolar_only else 3, 6, u1.size))
    # Epipolar: (v2 st)^2 + (cb - u2 sb)^2 + (v1 sb)^2 + (u1 st - ct)^2, point noise only.
    F[0] = np.stack([v2 * v2 + uu, u2 * u2 + vv, u2, u1, np.ones_like(u1), np.ones_like(u1)])
    F[0] *= sp2
    if not epipolar_only:
        a1, a2, a3, a4 = A[:, 0, 0], A[:, 0, 1], A[:, 1, 0], A[:, 1, 1]
        # Affine rows: their affine noise sa^2 ((v1 sb)^2 + (u1 st - ct)^2) in both, and the
        # point noise sp^2 ((a3 st)^2 + (a1 sb)^2 + st^2), sp^2 ((a4 st)^2 + (a2 sb)^2 + sb^2).
        F[1, 0], F[1, 1] = sp2 * (a3 * a3 + 1.0), sp2 * (a1 * a1)
        F[2, 0], F[2, 1] = sp2 * (a4 * a4), sp2 * (a2 * a2 + 1.0)
        F[1:, 0] += sa2 * uu
        F[1:, 1] += sa2 * vv
        F[1:, 3] += sa2 * u1
        F[1:, 4] += sa2
    var = C @ F
    var += 1e-300
    return np.reciprocal(var, out=var)


def other_basin(q1: np.ndarray, q2: np.ndarray, A: np.ndarray, w: np.ndarray,
                inliers: np.ndarray, theta: float, beta: float, sp: float, sa: float,
                gate: float) -> OtherBasin | None:
    """The lowest other local minimum of the yaw profile (see the module docstring), or None
    when the profile has none.

    Args:
        q1, q2, A, w: the ACs (normalised) and their weights.
        inliers: the estimate's inliers (the scan uses an even sample of at most 256).
        theta, beta: the estimate (``theta = alpha + beta``).
        sp, sa: its noise scales (the whitening of every grid motion).
        gate: the robust cost's cap per AC (the inlier chi-square).
    """
    idx = thin(np.flatnonzero(inliers & (w > 0)), _SAMPLE)
    if idx.size < 3:
        return None
    q1, q2, A = q1[idx], q2[idx], A[idx]
    ws = w[idx] / float(np.mean(w[idx]))               # chi-square units of the mean AC
    rows = refine.design_rows(q1, q2, A)
    alpha = theta - beta
    steps = np.arange(-round(_SPAN / _STEP), round(_SPAN / _STEP) + 1)
    alphas = alpha + _STEP * steps
    # Headings with the estimate's whitening (a second pass with each grid motion's own did
    # about as well on the paper's protocol, 10 against 11 wrong of 96, at twice the cost),
    # costs with their own.
    _, g, h = refine.residual_terms(q1, q2, A, rows, theta, beta)
    whitened = refine.whiten_rows(rows, g, h, sp, sa)        # (a copy: the costs use rows)
    betas = _best_headings(alphas, (whitened * np.repeat(ws, 3)) @ whitened.T)
    # (and the estimate itself, last: the grid's centre is its yaw with the best heading)
    both = sampson_costs(q1, q2, A, rows, np.append(alphas + betas, theta),
                         np.append(betas, beta), sp, sa, ws, gate)
    costs = both[:-1]
    centre = int(np.flatnonzero(steps == 0)[0])
    costs[centre] = min(costs[centre], float(both[-1]))
    # The estimate's basin: the slopes rising from the minimum its descent of the profile
    # reaches. Every other local minimum is a candidate; one outside that basin is a rival.
    own = centre
    while True:
        nxt = min((k for k in (own - 1, own + 1) if 0 <= k < costs.size), key=costs.__getitem__)
        if costs[nxt] >= costs[own]:
            break
        own = nxt
    lo, hi = own, own
    while lo > 0 and costs[lo - 1] >= costs[lo]:
        lo -= 1
    while hi < costs.size - 1 and costs[hi + 1] >= costs[hi]:
        hi += 1
    minima = [k for k in range(costs.size) if k != centre
              and (k == 0 or costs[k] <= costs[k - 1])
              and (k == costs.size - 1 or costs[k] <= costs[k + 1])]
    if not minima:
        return None
    k = min(minima, key=costs.__getitem__)
    rivals = [costs[j] for j in minima if not lo <= j <= hi]
    return OtherBasin(float(alphas[k] + betas[k]), float(betas[k]),
                      float(costs[k] - costs[centre]),
                      float(min(rivals) - costs[centre]) if rivals else math.inf)


def cost_change(q1: np.ndarray, q2: np.ndarray, A: np.ndarray, w: np.ndarray,
                mask: np.ndarray, first: tuple[float, float, float, float],
                second: tuple[float, float, float, float], gate: float
                ) -> tuple[float, float, int]:
    """The robust cost of motion ``second`` minus that of ``first`` (each ``(theta, beta, sp,
    sa)``) on an even sample of the ACs in ``mask`` (at most 256), both whitened at their own
    motion with the smaller of their noise scales (the better fit's), in chi-square units of
    the mean AC weight (see `other_basin`): all three residuals, the epipolar one alone (the
    points' own evidence: affines derived from one fitted surface may fit the other
    decomposition of its homography better, by its fit's error; a check of the scan's first
    version: a correct straight-ahead answer left for one 17 deg off), and the number of ACs
    compared."""
    idx = thin(np.flatnonzero(mask & (w > 0)), _SAMPLE)
    if idx.size == 0:
        return 0.0, 0.0, 0
    q1, q2, A = q1[idx], q2[idx], A[idx]
    ws = w[idx] / float(np.mean(w[idx]))
    rows = refine.design_rows(q1, q2, A)
    sp, sa = min(first[2], second[2]), min(first[3], second[3])
    theta, beta = np.array([first[0], second[0]]), np.array([first[1], second[1]])
    c = sampson_costs(q1, q2, A, rows, theta, beta, sp, sa, ws, gate)
    e = sampson_costs(q1, q2, A, rows, theta, beta, sp, sa, ws, gate, epipolar_only=True)
    return float(c[1] - c[0]), float(e[1] - e[0]), int(idx.size)


def polish(q1: np.ndarray, q2: np.ndarray, A: np.ndarray, w: np.ndarray, mask: np.ndarray,
           theta: float, beta: float, sp: float, sa: float, gate: float,
           iterations: int = 20) -> tuple[float, float]:
    """Newton's method on the Sampson cost itself (the whitening evaluated at every motion,
    not held as `refine.select_and_refine` holds it) of the ACs in ``mask`` within ``gate`` at
    the start, from ``(theta, beta)``; derivatives by central differences, the Hessian's
    eigenvalues kept positive, steps halved until the cost falls. Returns ``(theta, beta)``.
    """
    idx = np.flatnonzero(mask & (w > 0))
    if idx.size < 3:
        return theta, beta
    q1, q2, A, ws = q1[idx], q2[idx], A[idx], w[idx] / float(np.mean(w[idx]))
    rows = refine.design_rows(q1, q2, A)
    # The ACs within the gate at the start, with their whole chi-square (a smooth cost).
    keep = sampson_costs(q1, q2, A, rows, np.array([theta]), np.array([beta]), sp, sa, None,
                         gate)[0] <= gate
    if np.count_nonzero(keep) < 3:
        return theta, beta
    q1, q2, A, ws = q1[keep], q2[keep], A[keep], ws[keep]
    rows = refine.design_rows(q1, q2, A)
    d = 1e-5
    dt = np.array([0.0, d, -d, 0.0, 0.0, d])
    db = np.array([0.0, 0.0, 0.0, d, -d, d])
    for _ in range(iterations):
        c = sampson_costs(q1, q2, A, rows, theta + dt, beta + db, sp, sa, ws, math.inf)
        f = c[0]
        grad = np.array([c[1] - c[2], c[3] - c[4]]) / (2.0 * d)
        htt, hbb = (c[1] - 2.0 * f + c[2]) / d ** 2, (c[3] - 2.0 * f + c[4]) / d ** 2
        htb = (c[5] - c[1] - c[3] + f) / d ** 2
        lam, V = np.linalg.eigh(np.array([[htt, htb], [htb, hbb]]))
        lam = np.maximum(np.abs(lam), 1e-6 * max(float(np.abs(lam).max()), 1e-12))
        step = -(V @ ((V.T @ grad) / lam))
        scale = 1.0
        while scale > 1e-3:
            cand = sampson_costs(q1, q2, A, rows, np.array([theta + scale * step[0]]),
                                 np.array([beta + scale * step[1]]), sp, sa, ws, math.inf)[0]
            if cand < f:
                break
            scale *= 0.5
        if scale <= 1e-3:
            break
        theta, beta = theta + scale * step[0], beta + scale * step[1]
        if scale * float(np.abs(step).max()) < 1e-10:
            break
    return theta, beta
