"""Planar motion conventions, written once and used everywhere (DESIGN.md section 1).

Camera optical frame: x right, y down, z forward. Two views ``P1 = C1 [I | 0]`` and
``P2 = C2 [R | t]``, i.e. ``X2 = R X1 + t``, with

    R = Ry(alpha) = [[cos a, 0, sin a], [0, 1, 0], [-sin a, 0, cos a]]
    t = [cos b, 0, sin b]                       (unit; monocular scale is unobservable)

The centre of camera 2 in frame 1 is ``-R^T t``. Forward driving gives ``t ~ [0, 0, -1]``
(``beta ~ -pi/2``). A positive ``alpha`` turns the optical axis towards the camera's -x, i.e. a
left turn: for a level camera ``alpha`` equals the vehicle's yaw change (REP-103, z up).

The essential matrix is ``E = [t]x R = [[0, -sin b, 0], [sin(a+b), 0, -cos(a+b)], [0, cos b, 0]]``
and the solvers' unknown vector is ``x = [cos(a+b), sin(a+b), cos b, sin b]``.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    'angle_difference',
    'camera_displacement',
    'planar_essential',
    'planar_motion_from_pose',
    'rotation_y',
    'translation_direction',
    'wrap_angle',
]


def wrap_angle(angle: np.ndarray | float) -> np.ndarray:
    """Wrap angles (radians) to ``(-pi, pi]``."""
    wrapped = np.remainder(np.asarray(angle, dtype=np.float64) + np.pi, 2.0 * np.pi) - np.pi
    return np.where(wrapped == -np.pi, np.pi, wrapped)


def angle_difference(a: np.ndarray | float, b: np.ndarray | float) -> np.ndarray:
    """Signed smallest difference ``a - b`` of angles (radians), in ``(-pi, pi]``."""
    return wrap_angle(np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64))


def rotation_y(alpha: np.ndarray | float) -> np.ndarray:
    """``Ry(alpha)`` for angles of shape ``S``; returns shape ``S + (3, 3)``."""
    a = np.asarray(alpha, dtype=np.float64)
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(a), np.ones_like(a)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1),
                     np.stack([-s, z, c], -1)], -2)


def translation_direction(beta: np.ndarray | float) -> np.ndarray:
    """Unit translation ``t = [cos b, 0, sin b]`` for angles of shape ``S``; shape ``S + (3,)``."""
    b = np.asarray(beta, dtype=np.float64)
    return np.stack([np.cos(b), np.zeros_like(b), np.sin(b)], -1)


def planar_essential(alpha: np.ndarray | float, beta: np.ndarray | float) -> np.ndarray:
    """Essential matrix ``[t]x Ry(alpha)`` of planar motion; shape ``S + (3, 3)``."""
    a = np.asarray(alpha, dtype=np.float64)
    b = np.asarray(beta, dtype=np.float64)
    z = np.zeros(np.broadcast(a, b).shape)
    sb, cb, sab, cab = np.sin(b) + z, np.cos(b) + z, np.sin(a + b) + z, np.cos(a + b) + z
    return np.stack([np.stack([z, -sb, z], -1), np.stack([sab, z, -cab], -1),
                     np.stack([z, cb, z], -1)], -2)


def camera_displacement(alpha: np.ndarray | float, beta: np.ndarray | float) -> np.ndarray:
    """Centre of camera 2 in camera-1 coordinates, ``-R^T t`` (unit length); shape ``S + (3,)``.

    For forward driving (``beta = -pi/2``) this is ``[0, 0, 1]``: the camera moved along its
    optical axis.
    """
    R = rotation_y(alpha)
    t = translation_direction(beta)
    return -np.einsum('...ji,...j->...i', R, t)


def planar_motion_from_pose(R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Project a general relative pose ``X2 = R X1 + t`` onto planar motion ``(alpha, beta)``.

    ``alpha`` is the rotation about the camera y axis closest to ``R`` (least squares over the
    x-z block) and ``beta`` the heading of ``t`` in the x-z plane. Used to compare general
    estimators (five-point) and ground truth with the planar solvers.

    Args:
        R: rotations, shape ``(..., 3, 3)``.
        t: translations, shape ``(..., 3)``; any scale.

    Returns:
        ``alpha, beta`` in radians, each of shape ``(...)``.
    """
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    alpha = np.arctan2(R[..., 0, 2] - R[..., 2, 0], R[..., 0, 0] + R[..., 2, 2])
    beta = np.arctan2(t[..., 2], t[..., 0])
    return alpha, beta
