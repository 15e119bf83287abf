"""Planar vehicle motion from camera motion, and the propagation of its covariance.

The estimators give the motion of the *level* camera between two views,
``X2 = Ry(alpha) X1 + s t(beta)`` (`planar_vo.core.conventions`), with ``s`` the metric step. The
vehicle's motion is ``T_base1_base2 = T_base_level T_level1_level2 T_base_level^-1``, with
``T_level1_level2 = [R^T | -R^T s t]`` the pose of view 2 in view 1. Everything below is in the
plane: a pose is ``(x, y, yaw)`` and a covariance 3x3 in that order.
"""

from __future__ import annotations

import math

import numpy as np

from planar_vo.core.conventions import (
    camera_motion_to_base,
    rotation_y,
    se3,
    translation_direction,
    yaw_of,
)

__all__ = [
    'base_step',
    'compose_covariance',
    'planar_delta',
    'ros_covariance',
    'step_covariance',
]


def base_step(alpha: float, beta: float, scale: float, T_base_level: np.ndarray) -> np.ndarray:
    """``T_base1_base2`` (4x4) of the vehicle for a level-camera motion and step length."""
    R = rotation_y(alpha)
    t = scale * translation_direction(beta)
    T_c1_c2 = se3(R.T, -R.T @ t)
    return camera_motion_to_base(T_c1_c2, T_base_level)


def planar_delta(T: np.ndarray) -> np.ndarray:
    """``(dx, dy, dyaw)`` of a (planar) rigid transform."""
    return np.array([T[0, 3], T[1, 3], float(yaw_of(T[:3, :3]))])


def step_covariance(alpha: float, beta: float, scale: float, cov_ab: np.ndarray,
                    var_scale: float, T_base_level: np.ndarray) -> np.ndarray:
    """Covariance 3x3 of ``planar_delta(base_step(...))`` from that of ``(alpha, beta, s)``.

    First-order propagation with a central-difference Jacobian (the map is smooth and cheap).
    """
    x0 = np.array([alpha, beta, scale])
    J = np.empty((3, 3))
    for k, h in enumerate((1e-6, 1e-6, max(1e-6, 1e-6 * abs(scale)))):
        d = np.zeros(3)
        d[k] = h
        J[:, k] = (planar_delta(base_step(*(x0 + d), T_base_level))
                   - planar_delta(base_step(*(x0 - d), T_base_level))) / (2 * h)
    C = np.zeros((3, 3))
    C[:2, :2] = cov_ab
    C[2, 2] = var_scale
    return J @ C @ J.T


def compose_covariance(pose: np.ndarray, cov_pose: np.ndarray, delta: np.ndarray,
                       cov_delta: np.ndarray) -> np.ndarray:
    """Covariance of ``(x, y, yaw)`` after composing a pose with a body-frame step ``delta``.

    ``x' = x + cos(th) dx - sin(th) dy``, ``y' = y + sin(th) dx + cos(th) dy``,
    ``th' = th + dth``; independent pose and step errors.
    """
    th = float(yaw_of(pose[:3, :3]))
    c, s = math.cos(th), math.sin(th)
    dx, dy = delta[0], delta[1]
    Jp = np.array([[1.0, 0.0, -s * dx - c * dy], [0.0, 1.0, c * dx - s * dy], [0.0, 0.0, 1.0]])
    Jd = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return Jp @ cov_pose @ Jp.T + Jd @ cov_delta @ Jd.T


def ros_covariance(cov3: np.ndarray, planar_variance: tuple[float, float, float]) -> np.ndarray:
    """6x6 covariance in REP-103 order ``(x, y, z, roll, pitch, yaw)`` from the planar 3x3.

    ``z``, roll and pitch are not estimated (planar motion); they get the variances of the
    planarity assumption, ``planar_variance = (var_z, var_roll, var_pitch)``.
    """
    C = np.zeros((6, 6))
    idx = [0, 1, 5]
    C[np.ix_(idx, idx)] = cov3
    C[2, 2], C[3, 3], C[4, 4] = planar_variance
    return C
