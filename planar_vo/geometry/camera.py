"""Pinhole-camera helpers for affine correspondences: normalisation, homographies, Jacobians.

A local affine ``A`` is the 2x2 Jacobian of the image-1 -> image-2 mapping at ``p1``. Any smooth
map applied to the images (normalisation by ``C^-1``, undistortion, a levelling homography) acts
on ACs by the chain rule: ``p' = g2(p2)``, ``A' = J_g2(p2) A J_g1(p1)^-1``.
"""

from __future__ import annotations

import numpy as np

from planar_vo._checks import as_array, same_length
from planar_vo.errors import CameraModelError, InputError

__all__ = [
    'apply_homography',
    'fit_homography',
    'homography_jacobian',
    'intrinsic_matrix',
    'normalize_affines',
    'normalize_points',
    'plane_homography',
    'transform_acs',
]


def intrinsic_matrix(fx: float, fy: float | None = None, cx: float = 0.0, cy: float = 0.0
                     ) -> np.ndarray:
    """The 3x3 upper-triangular intrinsics ``C`` (no skew); ``fy`` defaults to ``fx``."""
    fy = fx if fy is None else fy
    if not (np.isfinite([fx, fy, cx, cy]).all() and fx > 0 and fy > 0):
        raise CameraModelError(f'intrinsics: expected finite fx > 0 and fy > 0, got fx={fx}, '
                               f'fy={fy}, cx={cx}, cy={cy}')
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def _check_K(K) -> np.ndarray:
    K = as_array('K', K, (3, 3))
    if K[0, 0] <= 0 or K[1, 1] <= 0 or K[1, 0] != 0 or np.any(K[2] != (0.0, 0.0, 1.0)):
        raise CameraModelError(f'K: expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy '
                               f'> 0, got {K.tolist()}')
    return K


def normalize_points(K: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Normalised coordinates ``q = C^-1 p`` of pixels ``p`` ``(N, 2)``; returns ``(N, 2)``."""
    K = _check_K(K)
    p = as_array('p', p, (None, 2), min_items=0)
    v = (p[:, 1] - K[1, 2]) / K[1, 1]
    u = (p[:, 0] - K[0, 2] - K[0, 1] * v) / K[0, 0]
    return np.stack([u, v], axis=-1)


def normalize_affines(K1: np.ndarray, K2: np.ndarray, A: np.ndarray) -> np.ndarray:
    """Affines in normalised coordinates, ``A_n = L2^-1 A L1`` with ``L`` the 2x2 block of ``C``.

    For zero skew this is ``diag(1/fx2, 1/fy2) A diag(fx1, fy1)`` (DESIGN.md section 2).
    """
    K1, K2 = _check_K(K1), _check_K(K2)
    A = as_array('A', A, (None, 2, 2), min_items=0)
    return np.linalg.inv(K2[:2, :2]) @ A @ K1[:2, :2]


def apply_homography(H: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Map points ``(N, 2)`` by the homography ``H`` (3x3); points at infinity give inf/NaN."""
    h = p @ H[:, :2].T + H[:, 2]
    with np.errstate(divide='ignore', invalid='ignore'):
        return h[:, :2] / h[:, 2:3]


def homography_jacobian(H: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Jacobian of ``p -> pi(H [p; 1])`` at points ``p`` ``(N, 2)``; returns ``(N, 2, 2)``.

    With ``h = H [p; 1]`` and ``p' = h[:2] / h[2]``: ``J = (H[:2, :2] - p' H[2, :2]) / h[2]``.
    This is the exact local affine of a plane-induced homography.
    """
    H = np.asarray(H, dtype=np.float64)
    p = np.asarray(p, dtype=np.float64)
    h = p @ H[:, :2].T + H[:, 2]
    w = h[:, 2]
    p2 = h[:, :2] / w[:, None]
    return (H[None, :2, :2] - p2[:, :, None] * H[None, 2:3, :2]) / w[:, None, None]


def plane_homography(K1: np.ndarray, K2: np.ndarray, R: np.ndarray, t: np.ndarray,
                     normal: np.ndarray, distance: float) -> np.ndarray:
    """Homography induced by the plane ``normal . X1 = distance`` (frame 1) between two views.

    With ``X2 = R X1 + t``: ``X2 = (R + t normal^T / distance) X1``, so
    ``H = C2 (R + t n^T / d) C1^-1``.
    """
    M = np.asarray(R, float) + np.outer(np.asarray(t, float), np.asarray(normal, float)) / distance
    return np.asarray(K2, float) @ M @ np.linalg.inv(np.asarray(K1, float))


def fit_homography(p1: np.ndarray, p2: np.ndarray) -> np.ndarray:
    """Least-squares homography ``p2 ~ H p1`` by the normalised DLT (Hartley and Zisserman 4.4).

    Args:
        p1, p2: at least four point pairs, shape ``(N, 2)``.

    Returns:
        ``H`` (3x3) with ``H[2, 2] = 1`` where possible.
    """
    p1 = as_array('p1', p1, (None, 2), min_items=4)
    p2 = as_array('p2', p2, (None, 2), min_items=4)
    same_length(p1=p1, p2=p2)

    def similarity(p: np.ndarray) -> np.ndarray:
        c = p.mean(axis=0)
        s = np.sqrt(2.0) / max(np.mean(np.linalg.norm(p - c, axis=1)), 1e-12)
        return np.array([[s, 0.0, -s * c[0]], [0.0, s, -s * c[1]], [0.0, 0.0, 1.0]])

    T1, T2 = similarity(p1), similarity(p2)
    a = apply_homography(T1, p1)
    b = apply_homography(T2, p2)
    n = a.shape[0]
    one, zero = np.ones(n), np.zeros((n, 3))
    ah = np.column_stack([a, one])
    rows_x = np.column_stack([ah, zero, -b[:, :1] * ah])
    rows_y = np.column_stack([zero, ah, -b[:, 1:] * ah])
    _, s, vt = np.linalg.svd(np.vstack([rows_x, rows_y]))
    if s[-2] <= 1e-12 * s[0]:
        raise InputError('p1, p2: points are degenerate (collinear or repeated); '
                         'the homography is not determined')
    H = np.linalg.inv(T2) @ vt[-1].reshape(3, 3) @ T1
    return H / H[2, 2] if abs(H[2, 2]) > 1e-12 else H


def transform_acs(p1: np.ndarray, p2: np.ndarray, A: np.ndarray, map1, map2
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Push ACs through per-image point maps: ``p' = g(p)``, ``A' = J_g2(p2) A J_g1(p1)^-1``.

    Args:
        p1, p2: points ``(N, 2)``; A: affines ``(N, 2, 2)``.
        map1, map2: callables ``p -> (g(p), J_g(p))`` returning ``(N, 2)`` and ``(N, 2, 2)``.

    Returns:
        ``p1', p2', A'`` of the same shapes.
    """
    g1, J1 = map1(p1)
    g2, J2 = map2(p2)
    return g1, g2, J2 @ A @ np.linalg.inv(J1)
