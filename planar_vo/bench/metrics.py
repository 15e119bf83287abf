"""Error metrics of the paper's synthetic experiments (Hajder and Barath, section 4.2).

- Rotation error: the angle between ``R_est v`` and ``R_gt v`` with ``v = [1, 1, 1] / sqrt(3)``.
- Translation error: the angle between the estimated and the true translation vectors (sign
  included: a translation pointing backwards is 180 degrees off).
- Focal error: ``|f_est - f_gt| / f_gt``.

Angles are computed as ``atan2(|a x b|, a . b)``, which equals the paper's ``acos(a . b)`` for unit
vectors but keeps full precision near zero (``acos`` cannot resolve errors below about 1e-8 rad,
and the noise-free errors of the closed-form solvers are far smaller). Errors are in degrees.
"""

from __future__ import annotations

import numpy as np

from planar_vo.core.conventions import rotation_y, translation_direction

__all__ = [
    'ROTATION_PROBE',
    'focal_error',
    'planar_pose',
    'rotation_error_deg',
    'translation_error_deg',
    'vector_angle_deg',
]

ROTATION_PROBE = np.full(3, 1.0 / np.sqrt(3.0))


def vector_angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle in degrees between vectors ``a`` and ``b`` (shapes broadcast, ``(..., 3)``).

    NaN where either vector is zero or not finite.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    cross = np.linalg.norm(np.cross(a, b), axis=-1)
    dot = np.sum(a * b, axis=-1)
    with np.errstate(invalid='ignore'):
        bad = ~((np.linalg.norm(a, axis=-1) > 0) & (np.linalg.norm(b, axis=-1) > 0))
    return np.where(bad, np.nan, np.rad2deg(np.arctan2(cross, dot)))


def rotation_error_deg(R_est: np.ndarray, R_gt: np.ndarray) -> np.ndarray:
    """The paper's rotation error: angle between ``R_est v`` and ``R_gt v``, degrees.

    Args:
        R_est, R_gt: rotations ``(..., 3, 3)`` (shapes broadcast).

    Returns:
        Shape ``(...)``; NaN where ``R_est`` is NaN (a failed estimate).
    """
    v = ROTATION_PROBE
    return vector_angle_deg(np.asarray(R_est) @ v, np.asarray(R_gt) @ v)


def translation_error_deg(t_est: np.ndarray, t_gt: np.ndarray) -> np.ndarray:
    """Angle between translation vectors ``(..., 3)`` in degrees (any scale)."""
    return vector_angle_deg(t_est, t_gt)


def focal_error(f_est: np.ndarray, f_gt: float) -> np.ndarray:
    """Relative focal length error ``|f_est - f_gt| / f_gt``."""
    return np.abs(np.asarray(f_est, dtype=np.float64) - f_gt) / f_gt


def planar_pose(alpha: np.ndarray, beta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pose of planar motions: ``R = Ry(alpha)`` ``(..., 3, 3)``, ``t = [cos b, 0, sin b]``
    ``(..., 3)``."""
    return rotation_y(alpha), translation_direction(beta)
