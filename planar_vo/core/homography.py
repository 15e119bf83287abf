"""Homographies and their Jacobians: the exact local affines of plane-induced image maps.

A local affine ``A`` is the 2x2 Jacobian of the image-1 -> image-2 mapping at ``p1``. A scene
plane induces a homography between two views, and the Jacobian of that homography at ``p1`` is
the plane's exact AC; a rotation homography (levelling) acts on ACs by the chain rule
(`planar_vo.core.correspondences.AffineCorrespondences.transformed`).
"""

from __future__ import annotations

import numpy as np

from planar_vo.core.checks import as_array, same_length
from planar_vo.errors import InputError

__all__ = [
    'apply_homography',
    'fit_homography',
    'homography_jacobian',
    'plane_homography',
]


def apply_homography(H: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Map points ``(N, 2)`` by the homography ``H`` (3x3); points at infinity give inf/NaN."""
    h = p @ H[:, :2].T + H[:, 2]
    with np.errstate(divide='ignore', invalid='ignore'):
        return h[:, :2] / h[:, 2:3]


def homography_jacobian(H: np.ndarray, p: np.ndarray, *, with_points: bool = False
                        ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Jacobian of ``p -> pi(H [p; 1])`` at points ``p`` ``(N, 2)``; returns ``(N, 2, 2)``, or
    ``(p', J)`` with ``with_points`` (the mapped points ``(N, 2)`` come for free).

    With ``h = H [p; 1]`` and ``p' = h[:2] / h[2]``: ``J = (H[:2, :2] - p' H[2, :2]) / h[2]``.
    This is the exact local affine of a plane-induced homography.
    """
    H = np.asarray(H, dtype=np.float64)
    p = np.asarray(p, dtype=np.float64)
    h = p @ H[:, :2].T + H[:, 2]
    w = h[:, 2]
    p2 = h[:, :2] / w[:, None]
    J = (H[None, :2, :2] - p2[:, :, None] * H[None, 2:3, :2]) / w[:, None, None]
    return (p2, J) if with_points else J


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
