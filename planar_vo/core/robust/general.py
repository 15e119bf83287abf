"""General relative pose from affine correspondences: the refinement behind the planar vote.

Conventions (`planar_vo.core.conventions`): camera optical frames (x right, y down, z
forward), relative pose ``X2 = R X1 + t`` with ``|t| = 1``, essential matrix ``E = [t]x R``;
normalised coordinates ``q = K^-1 p`` and ``A`` the Jacobian of the image-1 -> image-2 map at
``q1`` in normalised units.

Constraints of one AC ``(q1, q2, A)`` on a general ``E`` (Barath et al. 2017), with
``h1 = [q1; 1]``, ``h2 = [q2; 1]``:

    r0 = h2^T E h1                                        (epipolar)
    r_{1+k} = (E^T h2)[k] + sum_{j<2} A[j, k] (E h1)[j]   (affine, k = 0, 1)

All three are linear in ``e = vec(E)`` (row-major): ``r = M e`` with ``M`` (N, 3, 9) per AC
(`ac_design`). First-order noise propagation with isotropic point noise ``sp`` (normalised
units, both images) and affine-element noise ``sa`` (`residual_variances`):

    var r0      = sp^2 (|(E^T h2)[:2]|^2 + |(E h1)[:2]|^2)
    var r_{1+k} = sp^2 (|E[:2, k]|^2 + |(A^T E[:2, :2])[k, :]|^2) + sa^2 |(E h1)[:2]|^2

(the planar specialisation is `planar_vo.core.robust.refine.residual_terms`). The whitened
residuals ``r / sqrt(var)`` are unitless; an inlier's sum of squares is chi-square(3).
Degenerate ACs (the horizon row, a plane seen edge-on) are whitened by their own small
gradients and constrain no motion, instead of counting as inliers of any motion.

`refine_general_motion` minimises the Cauchy-robust whitened residuals over 5 DoF (rotation:
``R <- exp([w]x) R``, 3; translation: ``t <- normalise(t + B d)`` with ``B`` (3, 2) an
orthonormal basis of the tangent plane, 2) plus an optional soft planar prior (`PlanarPrior`),
re-selecting the inliers over ALL ACs after every round and measuring the noise scales from the
data. The result carries the 5x5 covariance of ``(w, d)``.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from planar_vo.core.conventions import skew, so3_exp, so3_log
from planar_vo.core.robust.options import EstimatorConfig
from planar_vo.core.robust.refine import robust_scales, spatial_clusters
from planar_vo.core.robust.stats import CHI2_3_99

__all__ = [
    'CHI2_3_99',
    'GeneralMotion',
    'PRIOR_SIGMAS',
    'PlanarPrior',
    'ac_design',
    'chi_square',
    'chi_squares',
    'essential',
    'noise_scales',
    'refine_general_motion',
    'residual_variances',
    'tangent_basis',
]

# ACs whose chi-square exceeds GATE take no part in a Gauss-Newton step (far in the tails of
# chi-square(3), so that an active set chosen at a motion still a little off keeps its inliers).
GATE = 4.0 * CHI2_3_99
_IRLS_ITERATIONS = 2          # IRLS iterations per selection round
_STEP_TOLERANCE = 2e-6        # rad: a step below this ends an IRLS loop
_EYE5 = np.eye(5)
_EYE5.flags.writeable = False
_ROUND_TOLERANCE = 0.2        # a round that moves the motion by less sigma (Mahalanobis) ...
_MAX_SET_CHANGE = 0.03        # ... and changes the active set by at most this share: converged
_FINAL_TOLERANCE = 1.0        # out of rounds: a last move below one sigma still counts
_COVARIANCE_GRID = 6          # k x k image cells of the cluster-robust covariance
_SCALE_FLOORS = (1e-7, 1e-6)  # numerical floors of the point and affine noise scales
# The planar prior's sigmas (rad) before any motion is measured: rotation about the level
# horizontal axes and elevation of travel within a car's bumps.
PRIOR_SIGMAS = (math.radians(0.5), math.radians(2.0))


def essential(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``E = [t]x R`` (3, 3)."""
    return skew(t) @ R


def tangent_basis(t: np.ndarray) -> np.ndarray:
    """Orthonormal basis (3, 2) of the plane orthogonal to the unit vector ``t``.

    Deterministic: the first column is the component of the axis least aligned with ``t`` (for
    forward motion, ``t ~ -z``: the x axis) orthogonal to ``t``, the second ``t x b1``.
    """
    x, y, z = float(t[0]), float(t[1]), float(t[2])
    ax, ay, az = abs(x), abs(y), abs(z)
    if ax <= ay and ax <= az:
        b = (1.0 - x * x, -x * y, -x * z)
    elif ay <= az:
        b = (-y * x, 1.0 - y * y, -y * z)
    else:
        b = (-z * x, -z * y, 1.0 - z * z)
    nb = math.sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2])
    b1 = (b[0] / nb, b[1] / nb, b[2] / nb)
    # b2 = t x b1, in plain floats (numpy's per-call overhead dominates at this size)
    b2 = (y * b1[2] - z * b1[1], z * b1[0] - x * b1[2], x * b1[1] - y * b1[0])
    return np.array([[b1[0], b2[0]], [b1[1], b2[1]], [b1[2], b2[2]]])


# --------------------------------------------------------------------------------------------
# The AC constraints on a general essential matrix
# --------------------------------------------------------------------------------------------

def ac_design(q1: np.ndarray, q2: np.ndarray, A: np.ndarray) -> np.ndarray:
    """``M`` (N, 3, 9) with ``r = M vec(E)`` (row-major ``vec``) for each AC.

    Row 0: ``M[a, b] = h2[a] h1[b]``; row ``1+k``: ``M[a, b] = [b == k] h2[a] +
    [a < 2] A[a, k] h1[b]``.
    """
    n = q1.shape[0]
    h1 = np.column_stack([q1, np.ones(n)])
    h2 = np.column_stack([q2, np.ones(n)])
    M = np.zeros((n, 3, 3, 3))
    M[:, 0] = h2[:, :, None] * h1[:, None, :]
    for k in range(2):
        M[:, 1 + k, :2, :] = A[:, :, k, None] * h1[:, None, :]
        M[:, 1 + k, :, k] += h2
    return M.reshape(n, 3, 9)


def residual_variances(E: np.ndarray, q1: np.ndarray, q2: np.ndarray, A: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Unit-noise variance factors ``g`` (points) and ``h`` (affines), each (N, 3), such that
    ``var(r) = sp^2 g + sa^2 h`` to first order (module docstring)."""
    return _variance_terms(E.tolist(), q1, q2, A, (q1.shape[0],))


def _variance_terms(e, q1: np.ndarray, q2: np.ndarray, A: np.ndarray, shape: tuple
                    ) -> tuple[np.ndarray, np.ndarray]:
    """`residual_variances` for the entries ``e[i][j]`` of one essential matrix (floats:
    ``shape`` (N,)) or of K at once ((K, 1) columns: ``shape`` (K, N)); the same arithmetic
    either way, so each of the K results has the bits of a single call."""
    u1, v1, u2, v2 = q1[:, 0], q1[:, 1], q2[:, 0], q2[:, 1]
    (e00, e01, e02), (e10, e11, e12), (e20, e21, _) = e
    l1x = e00 * u1 + e01 * v1 + e02               # (E h1)[0]
    l1y = e10 * u1 + e11 * v1 + e12               # (E h1)[1]
    l2x = e00 * u2 + e10 * v2 + e20               # (E^T h2)[0]
    l2y = e01 * u2 + e11 * v2 + e21               # (E^T h2)[1]
    n1 = l1x * l1x + l1y * l1y
    a00, a01, a10, a11 = A[:, 0, 0], A[:, 0, 1], A[:, 1, 0], A[:, 1, 1]
    # (A^T E[:2, :2])[k, m] = A[0, k] E[0, m] + A[1, k] E[1, m]
    k00, k01 = a00 * e00 + a10 * e10, a00 * e01 + a10 * e11
    k10, k11 = a01 * e00 + a11 * e10, a01 * e01 + a11 * e11
    g = np.empty(shape + (3,))
    g[..., 0] = l2x * l2x + l2y * l2y + n1
    g[..., 1] = (e00 * e00 + e10 * e10) + k00 * k00 + k01 * k01
    g[..., 2] = (e01 * e01 + e11 * e11) + k10 * k10 + k11 * k11
    h = np.empty(shape + (3,))
    h[..., 0] = 0.0
    h[..., 1] = n1
    h[..., 2] = n1
    return g, h


def chi_square(M: np.ndarray, q1: np.ndarray, q2: np.ndarray, A: np.ndarray, R: np.ndarray,
               t: np.ndarray, sp: float, sa: float) -> np.ndarray:
    """Total chi-square (N,) of every AC's three whitened residuals at the motion ``(R, t)``."""
    E = essential(R, t)
    g, h = residual_variances(E, q1, q2, A)
    r = (M.reshape(-1, 9) @ E.ravel()).reshape(-1, 3)
    return _row_sums(r * r / (sp * sp * g + sa * sa * h + 1e-300))


def chi_squares(M: np.ndarray, q1: np.ndarray, q2: np.ndarray, A: np.ndarray,
                motions: list[tuple[np.ndarray, np.ndarray]], sp: float, sa: float
                ) -> np.ndarray:
    """`chi_square` (K, N) of K motions ``(R, t)`` at once: the same values (bit for bit) at a
    fraction of K calls' cost, numpy's per-call overhead being shared."""
    Es = np.array([essential(R, t) for R, t in motions])                 # (K, 3, 3)
    k = len(motions)
    g, h = _variance_terms([[Es[:, i, j, None] for j in range(3)] for i in range(3)],
                           q1, q2, A, (k, q1.shape[0]))
    Mf = M.reshape(-1, 9)
    r = np.empty_like(g)
    for i in range(k):
        r[i] = (Mf @ Es[i].ravel()).reshape(-1, 3)
    return _row_sums(r * r / (sp * sp * g + sa * sa * h + 1e-300))


def _row_sums(x: np.ndarray) -> np.ndarray:
    """``x.sum(axis=-1)`` of an (..., 3) array, the same bits in a fifth of the time (numpy's
    reduction over a short last axis is slow)."""
    return x[..., 0] + x[..., 1] + x[..., 2]


def noise_scales(r: np.ndarray, g: np.ndarray, h: np.ndarray, mask: np.ndarray,
                 quantile: float = 0.5) -> tuple[float, float]:
    """Robust point and affine noise scales from the residuals ``r`` (N, 3) of the ACs in
    ``mask`` at a motion (``g, h`` from `residual_variances`).

    ``sp`` from the epipolar rows (point noise only): ``Q_q(|r0| / sqrt(g0)) / Q_q(|N(0,1)|)``;
    ``sa`` from the affine rows, ``raw = Q_q(|r| / sqrt(h)) / Q_q(|N(0,1)|)``, with the point
    share ``sp^2 median(g / h)`` removed in quadrature (at least a tenth of ``raw``). The median
    (``quantile=0.5``) over an active set whose gate lies far in the tails does not shrink round
    after round; ``0.25`` tolerates up to 75 % contamination.
    """
    return robust_scales(r[mask], g[mask], h[mask], quantile, floors=_SCALE_FLOORS, min_count=5)


def _essential_jacobian(R: np.ndarray, t: np.ndarray, B: np.ndarray, with_e: bool = False
                        ) -> np.ndarray:
    """``d vec(E) / d(w, d)`` (9, 5) for ``R <- exp([w]x) R``, ``t <- t + B d``; with
    ``with_e`` a sixth column ``vec(E)`` (``E = [t]x R``).

    ``[t]x [e_k]x = e_k t^T - t_k I``, so ``dE/dw_k = e_k (t^T R) - t_k R``; ``dE/dd_m =
    [B_m]x R``. In plain floats: at this size numpy's per-call overhead would be the cost.
    """
    rows = R.tolist()
    tx, ty, tz = t.tolist()
    (x0, x1), (y0, y1), (z0, z1) = B.tolist()
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = rows
    tR = (tx * r00 + ty * r10 + tz * r20, tx * r01 + ty * r11 + tz * r21,
          tx * r02 + ty * r12 + tz * r22)
    # [b]x R row by row: (-z R1 + y R2, z R0 - x R2, -y R0 + x R1).
    S0 = [(-z0 * a + y0 * b, -z1 * a + y1 * b) for a, b in zip(rows[1], rows[2])]
    S1 = [(z0 * a - x0 * b, z1 * a - x1 * b) for a, b in zip(rows[0], rows[2])]
    S2 = [(-y0 * a + x0 * b, -y1 * a + x1 * b) for a, b in zip(rows[0], rows[1])]
    if with_e:
        # [t]x R row by row, as [b]x R above
        E = ([-tz * a + ty * b for a, b in zip(rows[1], rows[2])],
             [tz * a - tx * b for a, b in zip(rows[0], rows[2])],
             [-ty * a + tx * b for a, b in zip(rows[0], rows[1])])
    D = []
    for i, S in enumerate((S0, S1, S2)):
        for j in range(3):
            r = rows[i][j]
            w = [-r * tx, -r * ty, -r * tz]
            w[i] += tR[j]
            D.append(w + list(S[j]) + [E[i][j]] if with_e else w + list(S[j]))
    return np.array(D)


# --------------------------------------------------------------------------------------------
# The planar prior
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class PlanarPrior:
    """Soft planar-motion prior in the level camera frame.

    ``R_lc`` (3, 3) maps camera-optical to level-camera coordinates (the mount tilt). With the
    level relative rotation ``R_l = R_lc R R_lc^T``, ``rho = log(R_l)`` and the direction of
    travel ``c_l = -R_lc R^T t`` (unit), the prior residuals are

        (rho_x - mean[0]) / sigma_rot,  (rho_z - mean[1]) / sigma_rot,
        (asin(c_l,y) - mean[2]) / sigma_elev

    (x: the pitch axis, z: the roll axis, y: the vertical; ``asin(c_l,y)`` the elevation of
    travel). Sigmas in radians; ``inf`` switches a term off.
    """

    R_lc: np.ndarray = field(default_factory=lambda: np.eye(3))
    sigma_rot: float = PRIOR_SIGMAS[0]
    sigma_elev: float = PRIOR_SIGMAS[1]
    mean: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def level_terms(self, R: np.ndarray, t: np.ndarray) -> np.ndarray:
        """``[rho_x, rho_z, elevation]`` (radians) of a motion, without mean or scaling."""
        return np.array(self._terms(R, t)[0])

    def _terms(self, R: np.ndarray, t: np.ndarray
               ) -> tuple[tuple[float, float, float], list[list[float]], list[float]]:
        """`level_terms` with ``M = R_lc R^T`` and ``c = -M t``, in plain floats (3x3 numpy
        calls would cost more than the arithmetic)."""
        L = self._level_rows
        Rr = R.tolist()
        tx, ty, tz = t.tolist()
        # R_l = R_lc R R_lc^T = P R_lc^T with P = R_lc R; M = R_lc R^T.
        P = [[li[0] * Rr[0][j] + li[1] * Rr[1][j] + li[2] * Rr[2][j] for j in range(3)]
             for li in L]
        Rl = [[pi[0] * lj[0] + pi[1] * lj[1] + pi[2] * lj[2] for lj in L] for pi in P]
        M = [[li[0] * rj[0] + li[1] * rj[1] + li[2] * rj[2] for rj in Rr] for li in L]
        # so3_log of R_l (x and z components).
        wx, wy, wz = Rl[2][1] - Rl[1][2], Rl[0][2] - Rl[2][0], Rl[1][0] - Rl[0][1]
        s = 0.5 * math.sqrt(wx * wx + wy * wy + wz * wz)
        th = math.atan2(s, 0.5 * (Rl[0][0] + Rl[1][1] + Rl[2][2] - 1.0))
        k = 0.5 if th < 1e-8 else 0.5 * th / s
        c = [-(m[0] * tx + m[1] * ty + m[2] * tz) for m in M]
        elevation = math.asin(max(-1.0, min(1.0, c[1] / max(math.sqrt(
            c[0] * c[0] + c[1] * c[1] + c[2] * c[2]), 1e-300))))
        return (wx * k, wz * k, elevation), M, c

    def residuals(self, R: np.ndarray, t: np.ndarray, B: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
        """Whitened prior residuals (3,) and their Jacobian (3, 5) with respect to ``(w, d)``.

        ``d rho / d w ~ R_lc`` (small tilt: the log's Jacobian is about the identity);
        ``d c / d w = -R^T [t]x``, ``d c / d d = -R^T B`` (camera-1 frame), rotated by ``R_lc``.
        """
        terms, M, c = self._terms(R, t)
        i0, i1, i2 = self._inverse_sigma_floats
        m0, m1, m2 = self._mean_floats
        tx, ty, tz = t.tolist()
        (b00, b01), (b10, b11), (b20, b21) = B.tolist()
        # d(elevation) = dc_y / sqrt(1 - c_y^2) with dc_y = -M[1] [[t]x | B] column by column
        # (|c| = 1: its change c . dc = t^T [[t]x | B] vanishes for a unit t and its tangent
        # basis B).
        m = M[1]
        X = ((0.0, tz, -ty), (-tz, 0.0, tx), (ty, -tx, 0.0), (b00, b10, b20), (b01, b11, b21))
        norm = max(math.sqrt(max(1.0 - c[1] ** 2, 1e-12)), 1e-6)
        k2 = -i2 / norm
        L = self._level_rows
        J = np.array([[L[0][0] * i0, L[0][1] * i0, L[0][2] * i0, 0.0, 0.0],
                      [L[2][0] * i1, L[2][1] * i1, L[2][2] * i1, 0.0, 0.0],
                      [(m[0] * x[0] + m[1] * x[1] + m[2] * x[2]) * k2 for x in X]])
        res = np.array([(terms[0] - m0) * i0, (terms[1] - m1) * i1, (terms[2] - m2) * i2])
        return res, J

    @functools.cached_property
    def _level_rows(self) -> list[list[float]]:
        return np.asarray(self.R_lc, dtype=np.float64).tolist()

    @functools.cached_property
    def _inverse_sigma_floats(self) -> tuple[float, float, float]:
        return tuple(self._inverse_sigmas.tolist())

    @functools.cached_property
    def _mean_floats(self) -> tuple[float, float, float]:
        return tuple(np.broadcast_to(np.asarray(self.mean, dtype=np.float64), (3,)).tolist())

    @functools.cached_property
    def _inverse_sigmas(self) -> np.ndarray:
        s = np.array([self.sigma_rot, self.sigma_rot, self.sigma_elev])
        return np.where(np.isfinite(s), 1.0 / s, 0.0)


# --------------------------------------------------------------------------------------------
# The refinement
# --------------------------------------------------------------------------------------------

@dataclass
class GeneralMotion:
    """A general relative pose ``X2 = R X1 + t`` (``|t| = 1``) with its statistics.

    Attributes:
        R (3, 3), t (3,): the motion.
        cov: 5x5 covariance of the increments ``(w, d)`` (rotation vector, left increment;
            translation tangent coordinates in ``basis``), rad^2.
        basis: (3, 2) tangent basis of ``t`` the covariance refers to.
        inliers: (N,) bool, chi-square(3) at most its 99 % quantile at the final motion.
        sp, sa: the noise scales measured at the solution (normalised point units; affine
            elements).
        chi2: (N,) total chi-square at the solution.
        iterations, rounds: IRLS iterations and selection rounds used.
        converged: the last round moved the motion by less than a fraction of a sigma.
    """

    R: np.ndarray
    t: np.ndarray
    cov: np.ndarray
    basis: np.ndarray
    inliers: np.ndarray
    sp: float
    sa: float
    chi2: np.ndarray
    iterations: int
    rounds: int
    converged: bool


def _robust_weights(ew2: np.ndarray, c: float) -> np.ndarray:
    """Cauchy IRLS weights per row (N, 3): the epipolar row on its own chi-square, the affine
    pair on the mean of its two (an AC with a bad affine still gives its epipolar row)."""
    c2 = c * c
    w = np.empty_like(ew2)
    w[:, 0] = 1.0 / (1.0 + ew2[:, 0] / c2)
    w[:, 1] = 1.0 / (1.0 + 0.5 * (ew2[:, 1] + ew2[:, 2]) / c2)
    w[:, 2] = w[:, 1]
    return w


def _cheirality_sign(q1: np.ndarray, q2: np.ndarray, R: np.ndarray, t: np.ndarray,
                     mask: np.ndarray) -> float:
    """+1 if most ACs in ``mask`` lie in front of both cameras with ``t``, -1 with ``-t``.

    Depths of ``lam2 h2 = lam1 R h1 + t`` by least squares: with ``m = h2 x R h1``,
    ``lam1 = -(h2 x t) . m / |m|^2`` and ``lam2 = -((R h1) x t) . m / |m|^2``; only the signs
    matter (the positive ``|m|^2`` is dropped). Flipping ``t`` flips both.
    """
    idx = np.flatnonzero(mask)
    if idx.size == 0:
        return 1.0
    # Component by component (np.cross on (K, 3) arrays costs several times more).
    u1, v1 = q1[idx, 0], q1[idx, 1]
    u2, v2 = q2[idx, 0], q2[idx, 1]
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = R.tolist()
    tx, ty, tz = t.tolist()
    a = r00 * u1 + r01 * v1 + r02                 # R h1
    b = r10 * u1 + r11 * v1 + r12
    c = r20 * u1 + r21 * v1 + r22
    mx, my, mz = v2 * c - b, a - u2 * c, u2 * b - v2 * a              # m = h2 x R h1
    lam1 = (v2 * tz - ty) * mx + (tx - u2 * tz) * my + (u2 * ty - v2 * tx) * mz
    lam2 = (b * tz - c * ty) * mx + (c * tx - a * tz) * my + (a * ty - b * tx) * mz
    # lam = -(...) . m: the common minus sign flips both signs, so the vote is negated.
    return 1.0 if float(np.sign(lam1).sum() + np.sign(lam2).sum()) <= 0 else -1.0


def _minimize_form(G: np.ndarray, R: np.ndarray, t: np.ndarray, prior: PlanarPrior | None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One Gauss-Newton step for ``min vec(E)^T G vec(E) + |p(R, t)|^2`` (``E = [t]x R``).

    With ``G = L^T L`` the residual is ``L e`` and its Jacobian ``L D``, so a step costs O(1):
    ``X = [D | e]`` gives ``X^T G X = [[H, grad], [grad^T, f]]`` in one product, and the
    prior, linearised here (it is weak and smooth; the next IRLS iteration re-linearises it),
    adds ``Y^T Y`` with ``Y = [Jp | p0]``. Step halving keeps the cost from rising.
    Returns ``R, t``, the Gauss-Newton matrix ``H`` (5, 5) and the step taken ``(w, d)`` (5,)
    (zeros when none lowered the cost).
    """
    B = tangent_basis(t)
    X = _essential_jacobian(R, t, B, with_e=True)            # (9, 6): D and vec(E)
    S = X.T @ (G @ X)
    if prior is not None:
        p0, Jp = prior.residuals(R, t, B)
        Y = np.column_stack([Jp, p0])
        S += Y.T @ Y
    H, grad, f = S[:5, :5], S[:5, 5], float(S[5, 5])
    try:
        step = -np.linalg.solve(H + (1e-12 * float(np.trace(H))) * _EYE5, grad)
    except np.linalg.LinAlgError:
        return R, t, H, np.zeros(5)
    for _ in range(5):
        Rn = so3_exp(step[:3]) @ R
        tn = t + B @ step[3:]
        tn = tn / math.sqrt(float(tn @ tn))
        e = essential(Rn, tn).ravel()
        fn = float(e @ G @ e)
        if prior is not None:
            p = p0 + Jp @ step
            fn += float(p @ p)
        if fn <= f * (1.0 + 1e-12):
            return Rn, tn, H, step
        step = 0.5 * step
    return R, t, H, np.zeros(5)


def refine_general_motion(q1: np.ndarray, q2: np.ndarray, A: np.ndarray, weights: np.ndarray,
                          R0: np.ndarray, t0: np.ndarray, active0: np.ndarray, sp: float,
                          sa: float, *, prior: PlanarPrior | None = None,
                          config: EstimatorConfig | None = None, M: np.ndarray | None = None,
                          shrink: float = 0.0, target: tuple[float, float] | None = None,
                          extra_rounds: int = 0) -> GeneralMotion:
    """Robust 5-DoF refinement of a relative pose on all three constraints of every AC.

    Args:
        q1, q2: (N, 2) normalised points; A: (N, 2, 2) normalised affines (camera frame).
        weights: (N,) AC quality weights (front-end), >= 0.
        R0, t0: initial motion (e.g. the planar vote lifted to the camera frame).
        active0: (N,) bool, the initial active set (e.g. the ACs near the initial motion).
        sp, sa: initial noise scales (measured again from the data after each round).
        prior: the soft planar prior, or None.
        config: `EstimatorConfig` (``cauchy``, ``rounds``).
        M: precomputed `ac_design` (N, 3, 9), to share between hypotheses.
        shrink, target: graduated non-convexity: with ``shrink > 0`` the scales start at
            ``(sp, sa)`` and are multiplied by ``shrink`` every round down to ``target`` (a
            fixed schedule, so that a start far from the answer is pulled in before the loss
            becomes narrow), then follow the data.
        extra_rounds: rounds beyond ``config.rounds`` (for the second hypotheses).

    Returns:
        A `GeneralMotion`.

    Method: per selection round the whitening ``1 / sqrt(var)`` is computed at the current
    motion and held fixed; IRLS: the Cauchy weights give one 9x9 Gram matrix ``G = Mw^T W Mw``
    (the only O(N) work of an iteration) and ``e^T G e + |p|^2`` is minimised over the 5 DoF by
    an O(1) Gauss-Newton step (`_minimize_form`). Then the noise scales are measured again
    (`noise_scales`, the median over the active set) or annealed, and the active set
    (chi-square at most `GATE`) is re-selected over ALL ACs. Converged when a round moves the
    motion by less than `_ROUND_TOLERANCE` sigmas (Mahalanobis with the Gauss-Newton matrix)
    and the active set changes by at most `_MAX_SET_CHANGE`. Finally the sign of ``t`` is fixed
    by cheirality of the inliers and the covariance computed (the inverse Gauss-Newton matrix,
    or the cluster-robust sandwich when larger).
    """
    cfg = EstimatorConfig() if config is None else config
    M = ac_design(q1, q2, A) if M is None else M
    Mf = M.reshape(-1, 9)
    n = q1.shape[0]
    R, t = np.array(R0, dtype=np.float64), np.asarray(t0, dtype=np.float64)
    t = t / math.sqrt(float(t @ t))
    active = active0 & (weights > 0)
    iterations, rounds, converged, round_moved = 0, 0, False, math.inf
    annealing = shrink > 0.0 and target is not None
    g, h = residual_variances(essential(R, t), q1, q2, A)
    for rounds in range(1, cfg.rounds + extra_rounds + 1):
        # Whitening at the round's starting motion (g, h: computed there, at the end of the
        # previous round or before the first), held fixed for the round: ``inv_var`` the
        # inverse variances, ``base`` the AC weights over them; the IRLS sums run over the
        # active ACs only (the others would enter with weight 0).
        if np.all(active):
            Ma, ga, ha, wa = Mf, g, h, weights
        else:
            idx = np.flatnonzero(active)
            Ma, ga, ha, wa = M[idx].reshape(-1, 9), g[idx], h[idx], weights[idx]
        inv_var = 1.0 / (sp * sp * ga + sa * sa * ha + 1e-300)
        base = wa[:, None] * inv_var
        R_round, t_round = R, t
        H_gn = np.zeros((5, 5))
        for _ in range(_IRLS_ITERATIONS):
            iterations += 1
            r = (Ma @ essential(R, t).ravel()).reshape(-1, 3)
            W = (base * _robust_weights(r * r * inv_var, cfg.cauchy)).reshape(-1, 1)
            G = Ma.T @ (Ma * W)
            Rn, tn, H_gn, step = _minimize_form(G, R, t, prior)
            # (the rotation moved by the step's w: log(exp(w) R R^T) = w)
            moved = max(float(np.abs(step[:3]).max()), float(np.abs(tn - t).max()))
            R, t = Rn, tn
            if moved < _STEP_TOLERANCE:
                break
        # The round's step in units of its standard deviations (the Gauss-Newton matrix of
        # the whitened problem is the information matrix): converged when well below one
        # sigma, whatever the motion's own precision (turns, short baselines).
        step = np.concatenate([so3_log(R @ R_round.T), tangent_basis(t_round).T @ (t - t_round)])
        round_moved = math.sqrt(max(float(step @ H_gn @ step), 0.0))
        E = essential(R, t)
        g, h = residual_variances(E, q1, q2, A)
        r = (Mf @ E.ravel()).reshape(n, 3)
        if annealing:
            sp_new, sa_new = max(target[0], shrink * sp), max(target[1], shrink * sa)
            annealing = not (sp_new == target[0] and sa_new == target[1])
            settled = False
        else:
            sp_new, sa_new = noise_scales(r, g, h, active)
            settled = True
        chi2 = _row_sums(r * r / (sp_new * sp_new * g + sa_new * sa_new * h + 1e-300))
        new_active = (chi2 <= GATE) & (weights > 0)
        changed = int(np.count_nonzero(new_active != active))
        stable = changed <= _MAX_SET_CHANGE * max(int(np.count_nonzero(new_active)), 1)
        sp, sa, active = sp_new, sa_new, new_active
        if settled and stable and round_moved < _ROUND_TOLERANCE:
            converged = True
            break
    else:
        # Out of rounds: the fixed-whitening iteration converges linearly, slowly where the
        # whitening depends strongly on the motion (turns); a last step below one sigma is
        # accepted, a larger one means the answer is not settled.
        converged = round_moved < _FINAL_TOLERANCE
    # g, h, r: computed at the final (R, t) by the last round (there is at least one).
    return _finish(q1, q2, A, weights, M, R, t, g, h, r, active, sp, sa, prior, cfg, iterations,
                   rounds, converged)


def _finish(q1, q2, A, weights, M, R, t, g, h, r, active, sp, sa, prior, cfg, iterations, rounds,
            converged) -> GeneralMotion:
    """Inliers, the sign of ``t`` (cheirality) and the covariance at the solution, from the
    residuals ``r`` and their variance terms ``g, h`` at ``(R, t)``."""
    Mf = M.reshape(-1, 9)
    var = sp * sp * g + sa * sa * h + 1e-300
    ew2 = r * r / var
    chi2 = _row_sums(ew2)
    inliers = (chi2 <= CHI2_3_99) & (weights > 0)
    if _cheirality_sign(q1, q2, R, t, inliers) < 0:
        t = -t                            # E changes sign only: residuals and chi2 unchanged
    B = tangent_basis(t)
    D = _essential_jacobian(R, t, B)
    wac = weights * active
    W = wac[:, None] * _robust_weights(ew2, cfg.cauchy) / var
    H = D.T @ (Mf.T @ (Mf * W.reshape(-1, 1))) @ D
    if prior is not None:
        _, Jp = prior.residuals(R, t, B)
        H = H + Jp.T @ Jp
    try:
        cov = np.linalg.inv(H)
    except np.linalg.LinAlgError:
        cov = np.full((5, 5), np.inf)
    if np.all(np.isfinite(cov)):
        # Cluster-robust sandwich (Liang and Zeger 1986), as for the planar estimate:
        # neighbouring ACs share errors (one surface, overlapping patches), which H^-1 ignores.
        # Scores s_i = J_i^T W_i r_i per AC, summed per cell of a grid over image 1.
        # J_i = M_i D, so s_i = D^T (M_i^T W_i r_i): the 9-vectors first, D once.
        wr = W * r
        scores = np.einsum('nk,nkj->nj', wr, M) @ D
        cells = spatial_clusters(q1, _COVARIANCE_GRID)
        slots = (cells[:, None] * 5 + np.arange(5)).ravel()
        per = np.bincount(slots, weights=scores.ravel(),
                          minlength=5 * _COVARIANCE_GRID ** 2).reshape(-1, 5)
        robust = cov @ (per.T @ per) @ cov
        if np.all(np.isfinite(robust)) and np.trace(robust) > np.trace(cov):
            cov = robust
    return GeneralMotion(R, t, cov, B, inliers, sp, sa, chi2, iterations, rounds, converged)
