"""Whitened residuals of the planar AC constraints, their least-squares refinement and the
cluster-robust covariance.

The three constraints of an AC (epipolar and two affine, `planar_vo.core.solvers`) have
different noise: each is divided by its first-order standard deviation under point and affine
noise (`residual_terms`), with the noise scales estimated robustly from the data
(`robust_scales`). ``(alpha, beta)`` are then refined by weighted Gauss-Newton on the inliers'
whitened rows (`select_and_refine`), alternating with the chi-square inlier selection, and the
covariance is a cluster-robust sandwich (`cluster_covariance`).

Layout: the whitened rows are held transposed, ``(4, 3N)`` (`design_rows`, `whiten_rows`), so
that per-row weights broadcast along the contiguous axis and each fit is one matrix product
(numpy's element-wise loops over an inner axis of 4 cost about four times as much).

Large arrays: at thousands of ACs the rows are hundreds of kB. Blocks of that size that are
allocated and freed again and again are, in the C library's allocator, returned to the kernel
and faulted in afresh page by page; a vote that built several per call took about 150 page
faults per call at 4,000 ACs. So the rows are built and whitened in place and a caller can
hand in its buffers (``out``, ``scratch``): a vote then touches two such arrays and no new
pages.
"""

from __future__ import annotations

import math

import numpy as np

from planar_vo.core.robust.options import VotingConfig
from planar_vo.core.robust.stats import HALF_NORMAL_Q25, MAD_TO_SIGMA, lower_quantile
from planar_vo.core.solvers import _ac_rows

__all__ = [
    'cluster_covariance',
    'design_rows',
    'fit_whitened',
    'minimize_form',
    'residual_terms',
    'robust_scales',
    'select_and_refine',
    'spatial_clusters',
    'to_alpha_beta_cov',
    'whiten_rows',
    'whitened',
]

# Numerical floors of the residual scales: on exact data the robust scales would be ~1e-17 and
# rounding alone would reject true inliers.
_POINT_SCALE_FLOOR = 1e-9
_AFFINE_SCALE_FLOOR = 1e-8


def residual_terms(q1: np.ndarray, q2: np.ndarray, A: np.ndarray, rows: np.ndarray,
                   theta: float, beta: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Residuals ``r = B x`` (N, 3) and their gradient norms w.r.t. points and affines
    (``rows``: the ACs' `design_rows`).

    With ``x = [cos th, sin th, cos b, sin b]`` the rows are (minimal.py):

        r1 = -v2 c_t + u1 v2 s_t + v1 c_b - u2 v1 s_b
        r2 = -a3 c_t + (v2 + a3 u1) s_t - a1 v1 s_b
        r3 = -a4 c_t + a4 u1 s_t + c_b - (u2 + a2 v1) s_b

    First-order noise propagation: ``var(r_k) = sp^2 |d r_k / d points|^2 + sa^2 |d r_k / d A|^2``.
    """
    ct, st, cb, sb = math.cos(theta), math.sin(theta), math.cos(beta), math.sin(beta)
    x = np.array([ct, st, cb, sb])
    r = (x @ rows).reshape(-1, 3)                   # one matrix-vector product, not N small ones
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


def _variance(g: np.ndarray, h: np.ndarray, sp: float, sa: float) -> np.ndarray:
    """First-order residual variances ``sp^2 g + sa^2 h`` ``(N, 3)`` (kept off zero)."""
    var = g * (sp * sp)
    var += (sa * sa) * h
    var += 1e-300
    return var


def whitened(r: np.ndarray, g: np.ndarray, h: np.ndarray, sp: float, sa: float) -> np.ndarray:
    """Residuals divided by their first-order standard deviations, shape ``(N, 3)``."""
    return r / np.sqrt(_variance(g, h, sp, sa))


def design_rows(q1: np.ndarray, q2: np.ndarray, A: np.ndarray, out: np.ndarray | None = None
                ) -> np.ndarray:
    """The ACs' constraint rows transposed, ``(4, 3N)``: column ``3 i + k`` is AC ``i``'s row
    ``k`` (`planar_vo.core.solvers._ac_rows`), written into ``out`` when given (see the module
    docstring on large arrays)."""
    return _ac_rows(q1, q2, A, out)


def whiten_rows(rows: np.ndarray, g: np.ndarray, h: np.ndarray, sp: float, sa: float,
                out: np.ndarray | None = None) -> np.ndarray:
    """`design_rows` ``(4, 3N)`` divided by their first-order standard deviations (the
    whitening of `whitened`, applied to the rows instead of the residuals); into ``out`` when
    given (a buffer of the same shape, reused across calls: see the module docstring)."""
    return np.divide(rows, np.sqrt(_variance(g, h, sp, sa).ravel()), out=out)


def robust_scales(r: np.ndarray, g: np.ndarray, h: np.ndarray, quantile: float = 0.25, *,
                  floors: tuple[float, float] | None = None, min_count: int = 4
                  ) -> tuple[float, float]:
    """Noise scales of points (normalised units) and affines from the peak's members' residuals.

    The members are the ACs whose candidates fell in the voted peak; with many outliers a good
    share of them are outliers too, so by default the scales come from the lower quartile of the
    normalised residuals (for ``|N(0, s^2)|`` the quartile is ``0.3186 s``), which tolerates up to
    three quarters of contamination; for clean inliers ``quantile=0.5`` (the median) is used.
    Epipolar rows see point noise only: ``e1 = r1 / |dr1/dp|``.
    Affine rows see ``sqrt(sp^2 g + sa^2 h)``; ``sa`` comes from ``r / sqrt(h)`` with the point
    share removed. ``floors``: the smallest scales returned (default the voting's), also
    returned when there are fewer than ``min_count`` rows.
    """
    point_floor, affine_floor = floors or (_POINT_SCALE_FLOOR, _AFFINE_SCALE_FLOOR)
    if r.shape[0] < min_count:
        return point_floor, affine_floor
    q = HALF_NORMAL_Q25 if quantile == 0.25 else 1.0 / MAD_TO_SIGMA
    e1 = np.abs(r[:, 0]) / np.sqrt(g[:, 0] + 1e-300)
    sp = max(lower_quantile(e1, quantile) / q, point_floor)
    ea = (np.abs(r[:, 1:]) / np.sqrt(h[:, 1:] + 1e-300)).ravel()
    raw = lower_quantile(ea, quantile) / q
    point_share = sp * sp * lower_quantile((g[:, 1:] / (h[:, 1:] + 1e-300)).ravel(), 0.5)
    sa = math.sqrt(max(raw * raw - point_share, 0.0))
    return sp, max(sa, affine_floor, 0.1 * raw)


def minimize_form(M: np.ndarray, theta: float, beta: float, iterations: int = 20
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


def to_alpha_beta_cov(cov_tb: np.ndarray) -> np.ndarray:
    """Covariance of ``(alpha, beta) = (theta - beta, beta)`` from that of ``(theta, beta)``."""
    if not np.all(np.isfinite(cov_tb)):
        return np.full((2, 2), np.inf)
    J = np.array([[1.0, -1.0], [0.0, 1.0]])
    cov = J @ cov_tb @ J.T
    return 0.5 * (cov + cov.T)          # (symmetric to the last bit: a user test found it not)


def spatial_clusters(q: np.ndarray, k: int) -> np.ndarray:
    """Cluster id ``(N,)`` of each point ``(N, 2)``: its cell in a ``k x k`` partition of the
    points' bounding box (neighbouring ACs share errors: one surface, overlapping patches)."""
    u, v = q[:, 0], q[:, 1]
    u0, v0 = float(u.min()), float(v.min())
    su = k / max(float(u.max()) - u0, 1e-12)
    sv = k / max(float(v.max()) - v0, 1e-12)
    iu = np.minimum(((u - u0) * su).astype(np.intp), k - 1)
    iv = np.minimum(((v - v0) * sv).astype(np.intp), k - 1)
    return iu * k + iv


def fit_whitened(rows: np.ndarray, w3: np.ndarray, theta: float, beta: float,
                 scratch: np.ndarray | None = None) -> tuple[float, float, np.ndarray, float]:
    """Least squares over ``(theta, beta)`` of the whitened rows ``rows`` ``(4, 3N)``
    (`whiten_rows`) with row weights ``w3`` ``(3N,)``; returns ``theta, beta``, the
    Gauss-Newton matrix ``H`` and the objective (see `minimize_form`). ``scratch``: an
    optional buffer shaped like ``rows`` for the weighted rows."""
    M = np.multiply(rows, w3, out=scratch) @ rows.T
    return minimize_form(M, theta, beta)


def _per_ac(x: np.ndarray) -> np.ndarray:
    """Sums over each AC's three rows of a row vector ``(3N,)``: ``(N,)``."""
    return x[0::3] + x[1::3] + x[2::3]


def cluster_covariance(rows: np.ndarray, w: np.ndarray, theta: float, beta: float, H: np.ndarray,
                       f: float, clusters: np.ndarray | None, scratch: np.ndarray | None = None
                       ) -> tuple[np.ndarray, float]:
    """Covariance of ``(theta, beta)`` at the solution of `fit_whitened`, and the whitened RMS.

    Cluster-robust (a sandwich ``H^-1 (sum_c s_c s_c^T) H^-1`` with ``s_c`` the summed score
    ``J^T e`` of cluster ``c``; Liang and Zeger 1986): neighbouring ACs share errors (one
    surface, overlapping patches, one fitted homography), which the plain ``sigma^2 H^-1``
    ignores and which would make it overconfident. Never smaller than ``sigma^2 H^-1`` with the
    posterior variance factor. Neither depends on the scale of ``w``. ``scratch``: an optional
    buffer shaped like ``rows`` for the residuals and their derivatives.
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
        e, de_t, de_b = np.matmul(np.array([[ct, st, cb, sb], [-st, ct, 0.0, 0.0],
                                            [0.0, 0.0, -sb, cb]]), rows,
                                  out=None if scratch is None else scratch[:3])
        s0 = np.bincount(clusters, weights=w * _per_ac(e * de_t))
        s1 = np.bincount(clusters, weights=w * _per_ac(e * de_b))
        meat = np.array([[s0 @ s0, s0 @ s1], [s0 @ s1, s1 @ s1]])
        robust = Hinv @ meat @ Hinv
        if np.all(np.isfinite(robust)) and np.trace(robust) > np.trace(cov):
            cov = robust
    return cov, rms


def select_and_refine(rows: np.ndarray, w: np.ndarray, theta: float, beta: float,
                      config: VotingConfig, clusters: np.ndarray | None = None,
                      passes: int = 4, covariance: bool = True, scratch: np.ndarray | None = None):
    """Inlier selection (chi-square of the whitened residuals) alternated with refitting, until
    the inlier set no longer changes (at most ``passes`` times); then, if asked, the
    covariance. ``rows``: the whitened rows ``(4, 3N)`` (`whiten_rows`).

    ``scratch``: a buffer shaped like ``rows`` for the fits' weighted rows and the covariance
    (one is allocated when not given; see the module docstring on large arrays)."""
    n = w.shape[0]
    if scratch is None:
        scratch = np.empty_like(rows)
    inliers = np.zeros(n, bool)
    H, f = np.full((2, 2), np.nan), float('nan')
    fitted = False
    for _ in range(passes if config.refine else 1):
        x = np.array([math.cos(theta), math.sin(theta), math.cos(beta), math.sin(beta)])
        e = x @ rows
        selected = (_per_ac(e * e) <= config.inlier_chi2) & (w > 0)
        if np.count_nonzero(selected) < 2:
            break
        if fitted and np.array_equal(selected, inliers):
            break                                   # the last fit already used this set
        inliers = selected
        t2, b2, H, f = fit_whitened(rows, np.repeat(w * selected, 3), theta, beta, scratch)
        fitted = True
        if config.refine:
            theta, beta = t2, b2
    if not covariance or not np.count_nonzero(inliers):
        return theta, beta, inliers, np.full((2, 2), np.inf), float('nan')
    cov, rms = cluster_covariance(rows, w * inliers, theta, beta, H, f, clusters, scratch)
    return theta, beta, inliers, cov, rms


def sampson_refine(q1: np.ndarray, q2: np.ndarray, A: np.ndarray, w: np.ndarray,
                   theta: float, beta: float, sp: float, sa: float, iterations: int = 1,
                   max_sigmas: float = 10.0) -> tuple[float, float]:
    """Gauss-Newton on the Sampson cost itself, ``sum_i w_i sum_k r_ik^2 / var_ik(theta,
    beta)``, of the given ACs (the inliers) from ``(theta, beta)``: the whitening's own
    derivative included, which `select_and_refine` (the whitening held per round) leaves out.

    That refinement stops at a self-consistent point, biased at second order in the noise
    where the variances change with the motion (away from straight ahead): a library user test
    measured 3.2 and 3.7 standard deviations of bias in alpha and beta at 5 deg of yaw and beta
    -60 deg (1,600 ACs, 0.5 px, 0.005 affine noise); this minimum is unbiased there. From that
    point one step suffices (bias 0.00 and -0.11 standard deviations there; six: 0.00 and
    -0.08), hence one by default (about 0.3 ms on 1,600 ACs). A step that does not lower the
    cost is halved; the iteration ends when a step moves the motion by less than a hundredth of
    its standard deviation. A step of more than ``max_sigmas`` standard deviations is not
    taken: the start was not near a minimum of this cost, and a step that long can land in
    another basin (on the paper's protocol, 50 ACs on one plane: a correct answer 0.2 deg off
    stepped to one 14.5 deg off). Returns ``(theta, beta)``.
    """
    n = q1.shape[0]
    u1, v1, u2 = (np.ascontiguousarray(c) for c in (q1[:, 0], q1[:, 1], q2[:, 0]))
    vv1, vv2 = v1 * v1, q2[:, 1] * q2[:, 1]
    a1, a2, a3, a4 = (A[:, i, j] for i, j in ((0, 0), (0, 1), (1, 0), (1, 1)))
    # The rows kind-major (all epipolar rows, then the two affine ones): contiguous per kind.
    rows = np.ascontiguousarray(design_rows(q1, q2, A).reshape(4, n, 3).transpose(0, 2, 1)
                                ).reshape(4, 3 * n)
    sp2, sa2 = sp * sp, sa * sa
    # In units of the mean weight: the step's length in standard deviations (the trust region,
    # the stop) must not depend on the weights' scale (a review: weights of 10 let 4 of 6
    # biased answers through).
    mean_w = float(np.mean(w)) if w.size else 0.0
    if not mean_w > 0:
        return theta, beta
    w3 = np.tile(w / mean_w, 3)
    # The ACs' own parts of the variances (each a quadratic form in the motion's sines and
    # cosines): the point terms of the affine rows.
    p1, p2 = sp2 * (a3 * a3 + 1.0), sp2 * a1 * a1
    p3, p4 = sp2 * a4 * a4, sp2 * (a2 * a2 + 1.0)

    def evaluate(t: float, b: float, jacobian: bool = True):
        """The cost, the whitened residuals ``e`` (3N,) and (with ``jacobian``) their
        Gauss-Newton Jacobian (2, 3N)."""
        ct, st, cb, sb = math.cos(t), math.sin(t), math.cos(b), math.sin(b)
        r = np.array([ct, st, cb, sb]) @ rows
        lift = u1 * st - ct                             # (d/du1 of the epipolar row)
        side = cb - u2 * sb
        h = vv1 * (sb * sb) + lift * lift
        var = np.empty((3, n))
        var[0] = sp2 * (vv2 * (st * st) + side * side + h)
        var[1] = p1 * (st * st) + p2 * (sb * sb) + sa2 * h
        var[2] = p3 * (st * st) + p4 * (sb * sb) + sa2 * h
        var = var.reshape(-1)
        var += 1e-300
        sd = np.sqrt(var)
        e = r / sd
        if not jacobian:
            return float(w3 @ (e * e)), e, None
        h_t, h_b = 2.0 * lift * (u1 * ct + st), (2.0 * sb * cb) * vv1
        dvar = np.empty((2, 3, n))
        dvar[0, 0] = sp2 * ((2.0 * st * ct) * vv2 + h_t)
        dvar[1, 0] = sp2 * (-2.0 * side * (sb + u2 * cb) + h_b)
        dvar[0, 1] = (2.0 * st * ct) * p1 + sa2 * h_t
        dvar[1, 1] = (2.0 * sb * cb) * p2 + sa2 * h_b
        dvar[0, 2] = (2.0 * st * ct) * p3 + sa2 * h_t
        dvar[1, 2] = (2.0 * sb * cb) * p4 + sa2 * h_b
        dr = np.array([[-st, ct, 0.0, 0.0], [0.0, 0.0, -sb, cb]]) @ rows
        J = dr / sd - dvar.reshape(2, -1) * (0.5 * e / var)
        return float(w3 @ (e * e)), e, J

    f, e, J = evaluate(theta, beta)
    for k in range(iterations):
        H = (J * w3) @ J.T
        g = (J * w3) @ e
        det = H[0, 0] * H[1, 1] - H[0, 1] ** 2
        if not det > 0:
            break
        step = -np.array([H[1, 1] * g[0] - H[0, 1] * g[1], H[0, 0] * g[1] - H[0, 1] * g[0]]) / det
        if not float(step @ H @ step) <= max_sigmas * max_sigmas:
            break
        scale = 1.0
        while scale > 1e-3:
            f_new, _, _ = evaluate(theta + scale * step[0], beta + scale * step[1], False)
            if f_new < f:
                break
            scale *= 0.5
        if scale <= 1e-3:
            break
        theta, beta = theta + scale * float(step[0]), beta + scale * float(step[1])
        # (the step in standard deviations: H is the information of the whitened problem)
        if scale * scale * float(step @ H @ step) < 1e-4 or k == iterations - 1:
            break
        f, e, J = evaluate(theta, beta)
    return theta, beta
