"""Minimal solvers for planar relative motion: 1AC, 1ACf (the paper's) and the 2PC/3PC baselines.

All solvers are vectorised over N independent samples: one affine correspondence (AC) for 1AC and
1ACf, two or three point correspondences for 2PC and 3PC. Conventions are those of
`planar_vo.core.conventions`: ``X2 = Ry(alpha) X1 + t``, ``t = [cos beta, 0, sin beta]``.

Every solver builds rows of the linear system ``B x = 0`` in ``x = [cos(a+b), sin(a+b), cos b,
sin b]`` (Hajder and Barath, eqs. 2-4):

    epipolar:  [ -v2,  u1*v2,       v1,  -u2*v1      ]
    affine 1:  [ -a3,  v2 + a3*u1,  0,   -a1*v1      ]
    affine 2:  [ -a4,  a4*u1,       1,   -u2 - a2*v1 ]

with ``q = (u, v, 1)`` normalised coordinates and ``A = [[a1, a2], [a3, a4]]`` the Jacobian of the
image-1 -> image-2 mapping at ``q1``. A degenerate sample yields NaN, never an exception.
"""

from __future__ import annotations

import math

import numpy as np

from planar_vo.core.checks import as_array, same_length
from planar_vo.core.conventions import wrap_angle
from planar_vo.errors import InputError

__all__ = [
    'ac_residuals',
    'planar_ac_matrix',
    'solve_1ac',
    'solve_1acf',
    'solve_2pc',
    'solve_3pc',
]

# Below this conditioning (see `solve_1acf`) the focal length is not observable: alpha ~ 0 or
# sin^2(a+b) ~ sin^2(b). The relative error of f^2 is about (coordinate noise) / weight.
FOCAL_MIN_WEIGHT = 1e-6


# --------------------------------------------------------------------------------------------
# Input checks (once, at the public entry)
# --------------------------------------------------------------------------------------------

def _check_ac(name1: str, q1, name2: str, q2, A) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    q1 = as_array(name1, q1, (None, 2))
    q2 = as_array(name2, q2, (None, 2))
    A = as_array('A', A, (None, 2, 2))
    same_length(**{name1: q1, name2: q2, 'A': A})
    return q1, q2, A


def _check_points(q1, q2, k: int) -> tuple[np.ndarray, np.ndarray]:
    q1 = as_array('q1', q1, (None, k, 2))
    q2 = as_array('q2', q2, (None, k, 2))
    same_length(q1=q1, q2=q2)
    return q1, q2


# --------------------------------------------------------------------------------------------
# The linear system
# --------------------------------------------------------------------------------------------

def _epipolar_rows(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Epipolar rows ``[-v2, u1 v2, v1, -u2 v1]`` for points of shape ``(..., 2)``."""
    u1, v1 = q1[..., 0], q1[..., 1]
    u2, v2 = q2[..., 0], q2[..., 1]
    return np.stack([-v2, u1 * v2, v1, -u2 * v1], axis=-1)


def _ac_rows(q1: np.ndarray, q2: np.ndarray, A: np.ndarray, out: np.ndarray | None = None
             ) -> np.ndarray:
    """The rows of every AC's ``B`` (module docstring) transposed, ``(4, 3N)``: column
    ``3 i + k`` is AC ``i``'s row ``k``; written into ``out`` when given. The one builder of the
    AC constraints: `_ac_matrix` is a view of it, and the refinement keeps this layout."""
    u1, v1, u2, v2 = q1[:, 0], q1[:, 1], q2[:, 0], q2[:, 1]
    a1, a2, a3, a4 = A[:, 0, 0], A[:, 0, 1], A[:, 1, 0], A[:, 1, 1]
    rows = np.empty((4, 3 * q1.shape[0])) if out is None else out
    epi, aff1, aff2 = rows[:, 0::3], rows[:, 1::3], rows[:, 2::3]
    np.negative(v2, out=epi[0])                           # [-v2, u1 v2, v1, -u2 v1]
    np.multiply(u1, v2, out=epi[1])
    epi[2] = v1
    np.multiply(u2, v1, out=epi[3])
    np.negative(epi[3], out=epi[3])
    np.negative(a3, out=aff1[0])                          # [-a3, v2 + a3 u1, 0, -a1 v1]
    np.multiply(a3, u1, out=aff1[1])
    aff1[1] += v2
    aff1[2] = 0.0
    np.multiply(a1, v1, out=aff1[3])
    np.negative(aff1[3], out=aff1[3])
    np.negative(a4, out=aff2[0])                          # [-a4, a4 u1, 1, -u2 - a2 v1]
    np.multiply(a4, u1, out=aff2[1])
    aff2[2] = 1.0
    np.multiply(a2, v1, out=aff2[3])
    aff2[3] += u2
    np.negative(aff2[3], out=aff2[3])
    return rows


def _ac_matrix(q1: np.ndarray, q2: np.ndarray, A: np.ndarray) -> np.ndarray:
    """``B`` ``(N, 3, 4)`` of every AC: a view of `_ac_rows`."""
    return _ac_rows(q1, q2, A).T.reshape(-1, 3, 4)


def planar_ac_matrix(q1: np.ndarray, q2: np.ndarray, A: np.ndarray) -> np.ndarray:
    """The 3x4 coefficient matrix ``B`` of each AC (paper eq. 4), ``B x = 0``.

    Args:
        q1, q2: normalised image coordinates, shape ``(N, 2)``.
        A: local affine in normalised coordinates, shape ``(N, 2, 2)``.

    Returns:
        ``B``, shape ``(N, 3, 4)``: row 0 epipolar, rows 1-2 affine.
    """
    return np.ascontiguousarray(_ac_matrix(*_check_ac('q1', q1, 'q2', q2, A)))


def _det3(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Determinant of the 3x3 matrices with columns ``a, b, c`` (each ``(N, 3)``)."""
    return (a[:, 0] * (b[:, 1] * c[:, 2] - b[:, 2] * c[:, 1])
            - a[:, 1] * (b[:, 0] * c[:, 2] - b[:, 2] * c[:, 0])
            + a[:, 2] * (b[:, 0] * c[:, 1] - b[:, 1] * c[:, 0]))


def _null_vectors(B: np.ndarray) -> np.ndarray:
    """Null vector of each 3x4 matrix in closed form: its four signed 3x3 minors.

    ``n_j = (-1)^j det(B without column j)`` is the generalised cross product of the three rows:
    appending any row of ``B`` on top gives a singular 4x4 matrix whose cofactor expansion along
    that row is ``row . n = 0``. Shape ``(N, 3, 4) -> (N, 4)``; rank-deficient ``B`` gives zeros.
    """
    c0, c1, c2, c3 = B[..., 0], B[..., 1], B[..., 2], B[..., 3]
    return np.stack([_det3(c1, c2, c3), -_det3(c0, c2, c3),
                     _det3(c0, c1, c3), -_det3(c0, c1, c2)], axis=-1)


def _ac_null_vectors(q1: np.ndarray, q2: np.ndarray, A: np.ndarray) -> np.ndarray:
    """`_null_vectors` of the AC matrices, expanded symbolically (``B[1, 2] = 0``, ``B[2, 2] = 1``).

    Same signed minors as the generic version with the structure of ``B`` folded in and the
    shared 2x2 minors ``P, Q, S`` of rows 2-3 computed once: about a third of the operations.
    """
    u1, v1, u2, v2 = q1[:, 0], q1[:, 1], q2[:, 0], q2[:, 1]
    a1, a2, a3, a4 = A[:, 0, 0], A[:, 0, 1], A[:, 1, 0], A[:, 1, 1]
    b11, b12, b13, b14 = -v2, u1 * v2, v1, -u2 * v1
    b21, b22, b24 = -a3, v2 + a3 * u1, -a1 * v1
    b31, b32, b34 = -a4, a4 * u1, -u2 - a2 * v1
    P = b22 * b34 - b24 * b32
    Q = b21 * b34 - b24 * b31
    S = b21 * b32 - b22 * b31
    return np.stack([-b12 * b24 - b13 * P + b14 * b22,
                     b11 * b24 + b13 * Q - b14 * b21,
                     b11 * P - b12 * Q + b14 * S,
                     -b11 * b22 + b12 * b21 - b13 * S], axis=-1)


def _cheirality_flip(q1: np.ndarray, q2: np.ndarray, alpha: np.ndarray, beta: np.ndarray
                     ) -> np.ndarray:
    """True where ``t`` must be flipped for the points to lie in front of both cameras.

    With ``m = q2 x Ry(alpha) q1`` the depths of ``lambda2 q2 = lambda1 Ry q1 + t`` (least-squares
    rays) are ``lambda1 = -(q2 x t) . m / |m|^2`` and ``lambda2 = (t x Ry q1) . m / |m|^2``; only
    their signs matter, so the positive ``|m|^2`` is dropped. Points vote with the signs of both
    depths; an undecided vote (one depth each way) goes to the sign of the depth sum.

    Args:
        q1, q2: normalised points ``(N, 2)`` (one per motion) or ``(N, k, 2)`` (``k`` points
            voting for each of ``N`` motions).
        alpha, beta: the ``N`` motions (radians).
    """
    if q1.ndim == 3:
        alpha, beta = alpha[:, None], beta[:, None]
    u1, v1, u2, v2 = q1[..., 0], q1[..., 1], q2[..., 0], q2[..., 1]
    ca, sa, cb, sb = np.cos(alpha), np.sin(alpha), np.cos(beta), np.sin(beta)
    rx, rz = ca * u1 + sa, ca - sa * u1                     # Ry q1 = (rx, v1, rz)
    mx, my, mz = v2 * rz - v1, rx - u2 * rz, u2 * v1 - v2 * rx
    n1 = -(v2 * sb * mx + (cb - u2 * sb) * my - v2 * cb * mz)
    n2 = -sb * v1 * mx + (sb * rx - cb * rz) * my + cb * v1 * mz
    score = np.sign(n1) + np.sign(n2)
    tie = n1 + n2
    if q1.ndim == 3:
        score, tie = score.sum(axis=-1), tie.sum(axis=-1)
    return (score < 0) | ((score == 0) & (tie < 0))


def _solve_1ac_unchecked(q1: np.ndarray, q2: np.ndarray, A: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray]:
    """`solve_1ac` without input checks or refinement (for estimators that checked already)."""
    n = _ac_null_vectors(q1, q2, A)
    degenerate = ((n[:, 0] == 0.0) & (n[:, 1] == 0.0)) | ((n[:, 2] == 0.0) & (n[:, 3] == 0.0))
    theta = np.arctan2(n[:, 1], n[:, 0])
    beta = np.arctan2(n[:, 3], n[:, 2])
    alpha = theta - beta
    beta = np.where(_cheirality_flip(q1, q2, alpha, beta), beta + np.pi, beta)
    # (-pi, pi], as documented and as the refined path returns it (a user test: beta = pi
    # came out as -pi here, +pi refined)
    alpha, beta = wrap_angle(alpha), wrap_angle(beta)
    alpha[degenerate] = np.nan
    beta[degenerate] = np.nan
    return alpha, beta


# --------------------------------------------------------------------------------------------
# Angles, sign and refinement
# --------------------------------------------------------------------------------------------

def _angles_from_x(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``theta = a + b`` and ``b`` from ``x ~ [cos th, sin th, cos b, sin b]`` (halves need not
    be unit vectors)."""
    return np.arctan2(x[..., 1], x[..., 0]), np.arctan2(x[..., 3], x[..., 2])


def _fix_sign(q1: np.ndarray, q2: np.ndarray, theta: np.ndarray, beta: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    """Resolve the null vector's sign by cheirality: flipping it adds pi to both angles."""
    alpha = theta - beta
    beta = np.where(_cheirality_flip(q1, q2, alpha, beta), beta + np.pi, beta)
    return wrap_angle(alpha), wrap_angle(beta)


def _refine_constrained(B: np.ndarray, theta: np.ndarray, beta: np.ndarray, iterations: int
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Minimise ``|B x|^2`` subject to both halves of ``x`` being unit vectors.

    ``x = [cos th, sin th, cos b, sin b]`` parametrises the constraint set exactly, so a few
    vectorised Gauss-Newton steps on ``(th, b)`` from the closed-form null vector (already close)
    give the constrained least-squares solution (the optimum Guan et al., CVPR 2020, reach with
    Lagrange multipliers).
    """
    for _ in range(iterations):
        ct, st, cb, sb = np.cos(theta), np.sin(theta), np.cos(beta), np.sin(beta)
        r = B[..., 0] * ct[:, None] + B[..., 1] * st[:, None] + B[..., 2] * cb[:, None] \
            + B[..., 3] * sb[:, None]
        j0 = -B[..., 0] * st[:, None] + B[..., 1] * ct[:, None]
        j1 = -B[..., 2] * sb[:, None] + B[..., 3] * cb[:, None]
        h00 = np.einsum('ni,ni->n', j0, j0)
        h01 = np.einsum('ni,ni->n', j0, j1)
        h11 = np.einsum('ni,ni->n', j1, j1)
        g0 = np.einsum('ni,ni->n', j0, r)
        g1 = np.einsum('ni,ni->n', j1, r)
        det = h00 * h11 - h01 * h01
        ok = np.abs(det) > 1e-300
        det = np.where(ok, det, 1.0)
        theta = theta - np.where(ok, (h11 * g0 - h01 * g1) / det, 0.0)
        beta = beta - np.where(ok, (h00 * g1 - h01 * g0) / det, 0.0)
    return theta, beta


# --------------------------------------------------------------------------------------------
# 1AC: calibrated, one affine correspondence
# --------------------------------------------------------------------------------------------

def solve_1ac(q1: np.ndarray, q2: np.ndarray, A: np.ndarray, *, refine: bool = False,
              iterations: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Planar motion from each single affine correspondence (1AC; paper section 3.2).

    The null vector of the 3x4 system ``B x = 0`` comes in closed form (signed 3x3 minors);
    ``a + b = atan2(n2, n1)`` and ``b = atan2(n4, n3)``. Its sign is fixed per AC by cheirality of
    the AC's own point, so forward driving gives ``beta ~ -pi/2``.

    Args:
        q1, q2: normalised coordinates ``C^-1 p`` in views 1 and 2, shape ``(N, 2)``.
        A: local affine in normalised coordinates (``A_n = diag(1/fx2, 1/fy2) A_px diag(fx1,
            fy1)``), row-major ``[[a1, a2], [a3, a4]]``, shape ``(N, 2, 2)``.
        refine: also run the constrained least-squares refinement (both halves of ``x`` unit
            norm), which uses the AC's three constraints optimally when they are noisy.
        iterations: Gauss-Newton steps of the refinement.

    Returns:
        ``alpha, beta`` in radians, each shape ``(N,)``, wrapped to ``(-pi, pi]``. NaN where the
        AC is degenerate (rank-deficient ``B``).

    Raises:
        InputError: wrong shapes, non-finite values, no items, mismatched lengths, or
            ``iterations`` not a non-negative integer.
    """
    q1, q2, A = _check_ac('q1', q1, 'q2', q2, A)
    if not refine:
        return _solve_1ac_unchecked(q1, q2, A)
    if isinstance(iterations, bool) or not isinstance(iterations, (int, np.integer)) \
            or iterations < 0:
        # (a user test: 1.5 raised a bare TypeError, -1 was taken)
        raise InputError(f'iterations: expected a non-negative integer, got {iterations!r}')
    B = _ac_matrix(q1, q2, A)
    n = _ac_null_vectors(q1, q2, A)
    degenerate = (np.hypot(n[:, 0], n[:, 1]) == 0.0) | (np.hypot(n[:, 2], n[:, 3]) == 0.0)
    theta, beta = _angles_from_x(n)
    theta, beta = _refine_constrained(B, theta, beta, iterations)
    alpha, beta = _fix_sign(q1, q2, theta, beta)
    nan = np.full_like(alpha, np.nan)
    return np.where(degenerate, nan, alpha), np.where(degenerate, nan, beta)


# --------------------------------------------------------------------------------------------
# 1ACf: unknown common focal length, one affine correspondence
# --------------------------------------------------------------------------------------------

def solve_1acf(p1: np.ndarray, p2: np.ndarray, A: np.ndarray, *, return_weight: bool = False,
               min_weight: float = FOCAL_MIN_WEIGHT):
    """Planar motion and the common focal length from each single AC (1ACf; paper section 3.3).

    With pixel coordinates centred on the principal point and ``A`` in pixels, ``B`` has the same
    form and its null vector is ``n ~ [cos(a+b)/f, sin(a+b)/f^2, cos b/f, sin b/f^2]``, hence in
    closed form (the paper's 16 sign permutations reduce to this)

        f^2 = (n3^2 - n1^2) / (n2^2 - n4^2),  a + b = atan2(f n2, n1),  b = atan2(f n4, n3).

    Coordinates are divided by their RMS magnitude first (and ``f`` multiplied back), which keeps
    ``B`` well scaled in pixel units. The conditioning weight is
    ``w = |sin^2(a+b) - sin^2 b| = |sin(alpha) sin(alpha + 2 beta)|`` in ``[0, 1]``: the
    denominator of ``f^2`` for a unit-normalised ``x``, so the relative error of ``f^2`` grows like
    ``noise / w``. It vanishes for ``alpha = 0`` (driving straight does not reveal the focal
    length) and for ``alpha + 2 beta = 0 (mod pi)``. Items with ``w < min_weight`` or a
    non-positive ``f^2`` are NaN, never a confident wrong focal length.

    Args:
        p1, p2: pixel coordinates minus the principal point, shape ``(N, 2)``.
        A: local affine in pixels, shape ``(N, 2, 2)``.
        return_weight: also return the conditioning weight.
        min_weight: weights below this give NaN.

    Returns:
        ``alpha, beta, focal`` (radians, radians, pixels), each ``(N,)``; with
        ``return_weight=True`` also ``weight`` ``(N,)`` (0 where NaN).

    Raises:
        InputError: wrong shapes, non-finite values, no items, mismatched lengths, or
            ``min_weight`` not a finite number >= 0.
    """
    p1, p2, A = _check_ac('p1', p1, 'p2', p2, A)
    try:
        finite = math.isfinite(min_weight) and min_weight >= 0.0
    except TypeError:
        finite = False
    if isinstance(min_weight, bool) or not finite:
        # (a user test: 'x' raised numpy's UFuncTypeError, NaN made every output NaN)
        raise InputError(f'min_weight: expected a finite weight >= 0, got {min_weight!r}')
    scale = float(np.sqrt(np.mean(p1 ** 2) + np.mean(p2 ** 2))) or 1.0
    s1, s2 = p1 / scale, p2 / scale
    n = _null_vectors(_ac_matrix(s1, s2, A))
    n1, n2, n3, n4 = n[:, 0] ** 2, n[:, 1] ** 2, n[:, 2] ** 2, n[:, 3] ** 2
    with np.errstate(divide='ignore', invalid='ignore'):
        f2 = (n3 - n1) / (n2 - n4)
    positive = np.isfinite(f2) & (f2 > 0.0)
    f2 = np.where(positive, f2, 1.0)          # (the others are NaN below; 0 x inf warned)
    f = np.sqrt(f2)                                            # focal in scaled units
    x = np.stack([n[:, 0] * f, n[:, 1] * f2, n[:, 2] * f, n[:, 3] * f2], axis=-1)
    half1 = np.hypot(x[:, 0], x[:, 1])
    half2 = np.hypot(x[:, 2], x[:, 3])
    with np.errstate(divide='ignore', invalid='ignore'):
        weight = np.abs((x[:, 1] / half1) ** 2 - (x[:, 3] / half2) ** 2)
    valid = positive & (weight >= min_weight) & (half1 > 0.0) & (half2 > 0.0)
    theta, beta = _angles_from_x(x)
    alpha, beta = _fix_sign(s1 / f[:, None], s2 / f[:, None], theta, beta)
    focal = f * scale
    nan = np.nan
    out = (np.where(valid, alpha, nan), np.where(valid, beta, nan), np.where(valid, focal, nan))
    if return_weight:
        return out + (np.where(valid, weight, 0.0),)
    return out


# --------------------------------------------------------------------------------------------
# Point baselines: 3PC (linear) and 2PC (Choi and Kim 2018)
# --------------------------------------------------------------------------------------------

def solve_3pc(q1: np.ndarray, q2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Planar motion from three point correspondences, linearly (3PC; paper section 3.2).

    The three epipolar rows form a 3x4 system whose null vector (closed form, as in 1AC) gives
    the angles; each half of it is normalised separately, and the sign comes from the cheirality
    vote of the three points.

    Args:
        q1, q2: normalised coordinates, shape ``(N, 3, 2)``: N samples of three points.

    Returns:
        ``alpha, beta`` in radians, each ``(N,)``; NaN for degenerate samples.
    """
    q1, q2 = _check_points(q1, q2, 3)
    n = _null_vectors(_epipolar_rows(q1, q2))
    degenerate = (np.hypot(n[:, 0], n[:, 1]) == 0.0) | (np.hypot(n[:, 2], n[:, 3]) == 0.0)
    theta, beta = _angles_from_x(n)
    alpha, beta = _fix_sign(q1, q2, theta, beta)
    return np.where(degenerate, np.nan, alpha), np.where(degenerate, np.nan, beta)


def solve_2pc(q1: np.ndarray, q2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Planar motion from two point correspondences (2PC; Choi and Kim, 2018).

    The two epipolar rows leave a 2-D null space ``x = V c``; the constraint that both halves of
    ``x`` have equal norm is the quadratic form ``c^T (Vu^T Vu - Vw^T Vw) c = 0``, which in the
    eigenbasis of that symmetric 2x2 matrix (eigenvalues ``l1 < 0 < l2``) has the two solutions
    ``c ~ [sqrt(l2), +-sqrt(-l1)]`` up to scale. Each solution's sign is fixed by the cheirality
    vote of the two points. When noise makes both eigenvalues share a sign there is no exact
    solution; the closest one (eigenvector of the smaller eigenvalue magnitude) is returned once.

    Args:
        q1, q2: normalised coordinates, shape ``(N, 2, 2)``: N samples of two points.

    Returns:
        ``alpha, beta``, each shape ``(N, 2)``: up to two solutions per sample, NaN-padded.
    """
    q1, q2 = _check_points(q1, q2, 2)
    rows = _epipolar_rows(q1, q2)                                    # (N, 2, 4)
    _, s, vt = np.linalg.svd(rows, full_matrices=True)
    V = np.swapaxes(vt[:, 2:, :], 1, 2)                              # (N, 4, 2) null basis
    Vu, Vw = V[:, :2, :], V[:, 2:, :]
    D = np.einsum('nki,nkj->nij', Vu, Vu) - np.einsum('nki,nkj->nij', Vw, Vw)
    lam, E = np.linalg.eigh(D)                                       # ascending eigenvalues
    real = lam[:, 0] * lam[:, 1] <= 0.0
    a = np.sqrt(np.abs(lam[:, 1]))
    b = np.sqrt(np.abs(lam[:, 0]))
    closest = np.where(np.abs(lam[:, 0]) < np.abs(lam[:, 1]), 0, 1)
    c_fallback = np.take_along_axis(E, closest[:, None, None].repeat(2, 1), axis=2)[..., 0]
    degenerate = s[:, 1] <= 1e-12 * np.maximum(s[:, 0], 1e-300)     # rows not independent
    alphas, betas = [], []
    for sign in (1.0, -1.0):                                         # the two roots, not items
        exact = np.einsum('nij,nj->ni', E, np.stack([a, sign * b], -1))
        c = np.where(real[:, None], exact, c_fallback)
        theta, beta = _angles_from_x(np.einsum('nij,nj->ni', V, c))
        alpha, beta = _fix_sign(q1, q2, theta, beta)
        keep = (real | (sign > 0)) & ~degenerate
        alphas.append(np.where(keep, alpha, np.nan))
        betas.append(np.where(keep, beta, np.nan))
    return np.stack(alphas, -1), np.stack(betas, -1)


def ac_residuals(q1: np.ndarray, q2: np.ndarray, A: np.ndarray, alpha: np.ndarray | float,
                 beta: np.ndarray | float) -> np.ndarray:
    """Residuals ``B x(alpha, beta)`` of the three AC constraints for given motions.

    Args:
        q1, q2: normalised coordinates, shape ``(N, 2)``.
        A: normalised local affines, shape ``(N, 2, 2)``.
        alpha, beta: one motion (scalars) or one per AC (``(N,)``), radians.

    Returns:
        Shape ``(N, 3)``: epipolar residual, then the two affine residuals.
    """
    q1, q2, A = _check_ac('q1', q1, 'q2', q2, A)
    B = _ac_matrix(q1, q2, A)
    n = q1.shape[0]
    try:
        a = np.asarray(alpha, dtype=np.float64)
        b = np.asarray(beta, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise InputError(f'alpha, beta: expected angles in radians, got {err}') from None
    for name, value in (('alpha', a), ('beta', b)):
        # (a user test: (N+1,) angles raised numpy's broadcast ValueError)
        if value.shape not in ((), (n,)):
            raise InputError(f'{name}: expected one angle or one per AC, shape () or ({n},), '
                             f'got {value.shape}')
        if not np.all(np.isfinite(value)):
            # (a user test: NaN angles gave NaN residuals, where the solvers refuse NaN input)
            got = value if value.ndim == 0 else 'a non-finite one'
            raise InputError(f'{name}: expected finite angles, got {got}')
    x = np.stack(np.broadcast_arrays(np.cos(a + b), np.sin(a + b), np.cos(b), np.sin(b)), -1)
    return np.einsum('nij,...j->ni', B, x) if x.ndim == 1 else np.einsum('nij,nj->ni', B, x)
