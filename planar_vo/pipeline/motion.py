"""Integration of relative camera motions into a 3D pose with covariance, and its ROS form.

Conventions (`planar_vo.core.conventions`):

- poses ``T`` (4, 4) map body to world (``p_w = T p_b``); uncertainty as a RIGHT perturbation
  ``T = T_hat exp(xi^)`` with ``xi = [phi, rho]`` (rotation, translation; body axes), covariance
  6x6 in that order;
- a relative motion from `planar_vo.pipeline.estimator.MotionEstimator`: ``X2 = R X1 + t``
  (camera frames, unit ``t``) with the 5x5 covariance of ``(w, d)``: ``R <- exp([w]x) R``,
  ``t <- normalise(t + B d)``; the step length ``s`` (metres) with its variance.

`compose` gives the camera pose ``T_w2 = T_w1 T_12`` with ``T_12 = [R^T | -s R^T t]`` and
``Sigma_2 = Ad(T_12^-1) Sigma_1 Ad(T_12^-1)^T + J Sigma_m J^T`` (first order; ``J`` is the
Jacobian of ``xi_12`` with respect to ``(w, d, s)``). `to_base` moves a
pose and its covariance to ``base_link`` through the mount; `ros_pose_covariance` turns the
body-frame covariance into the 6x6 of ``nav_msgs/Odometry`` (REP-103 order x, y, z, roll,
pitch, yaw; position and small rotations in the parent frame); `flatten` gives the 2D output
(x, y, yaw; z, roll and pitch zero) for ground robots that want it.
"""

from __future__ import annotations

import math

import numpy as np

from planar_vo.core.conventions import (
    adjoint,
    invert,
    planar_pose,
    se3,
    skew,
    yaw_of,
)

__all__ = [
    'compose',
    'flatten',
    'relative_pose',
    'ros_pose_covariance',
    'ros_twist_covariance',
    'to_base',
    'yaw_rate_decay',
]


def relative_pose(R: np.ndarray, t: np.ndarray, s: float) -> np.ndarray:
    """``T_12`` (the pose of camera 2 in camera 1) of ``X2 = R X1 + t`` (unit ``t``) and the
    step length ``s``."""
    return se3(R.T, -s * (R.T @ t))


def compose(T1: np.ndarray, S1: np.ndarray, R: np.ndarray, t: np.ndarray, B: np.ndarray,
            cov5: np.ndarray, s: float, var_s: float
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The camera pose and its 6x6 covariance after one relative motion (module docstring),
    and the covariance of the step alone (in the frame of camera 2).

    Args:
        T1 (4, 4), S1 (6, 6): the pose of camera 1 and its covariance.
        R (3, 3), t (3,), B (3, 2), cov5 (5, 5): the motion, its tangent basis and the
            covariance of ``(w, d)``.
        s, var_s: the step length (m) and its variance (m^2).
    """
    T12 = relative_pose(R, t, s)
    # xi_12 of the perturbed step, to first order (R <- exp([w]x) R, t <- t + B d, s <- s + ds):
    # phi = -w, rho = -s [t]x w - s B d - t ds.
    J = np.zeros((6, 6))
    J[:3, :3] = -np.eye(3)
    J[3:, :3] = -s * skew(t)
    J[3:, 3:5] = -s * B
    J[3:, 5] = -t
    Sm = np.zeros((6, 6))
    Sm[:5, :5] = cov5
    Sm[5, 5] = var_s
    Ad = adjoint(invert(T12))
    step = J @ Sm @ J.T
    return T1 @ T12, Ad @ S1 @ Ad.T + step, step


_IDENTITY = np.eye(4)


def to_base(T_wc: np.ndarray, S_c: np.ndarray, T_bc: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
    """Camera pose (world = the first camera frame) -> base pose (world = the first base frame,
    ``odom``): ``T_ob = T_bc T_wc T_bc^-1``; the camera's right perturbation maps to the base
    by ``xi_b = Ad(T_bc) xi_c``. The origin maps to the origin exactly (the products would
    leave rounding of 1e-17 m in a pose that is the identity by definition)."""
    Ad = adjoint(T_bc)
    T_ob = np.eye(4) if np.array_equal(T_wc, _IDENTITY) else T_bc @ T_wc @ invert(T_bc)
    return T_ob, Ad @ S_c @ Ad.T


def ros_pose_covariance(T: np.ndarray, S: np.ndarray) -> np.ndarray:
    """The 6x6 pose covariance of ``nav_msgs/Odometry`` from a body-frame one ``[phi, rho]``.

    To first order the position error in the parent frame is ``R rho`` and the orientation
    error a small rotation ``R phi`` about the parent's axes (roll, pitch, yaw for small
    errors); REP-103 order ``(x, y, z, roll, pitch, yaw)``.
    """
    R = T[:3, :3]
    J = np.zeros((6, 6))
    J[:3, 3:] = R
    J[3:, :3] = R
    return J @ S @ J.T


def ros_twist_covariance(S_step: np.ndarray, dt: float) -> np.ndarray:
    """The 6x6 twist covariance ``(vx, vy, vz, wx, wy, wz)`` in the body frame of a step whose
    body-frame covariance is ``S_step`` (``[phi, rho]``) over ``dt`` seconds."""
    C = np.zeros((6, 6))
    C[:3, :3] = S_step[3:, 3:]
    C[3:, 3:] = S_step[:3, :3]
    C[:3, 3:] = S_step[3:, :3]
    C[3:, :3] = S_step[:3, 3:]
    return C / (dt * dt)


def flatten(T: np.ndarray, C_ros: np.ndarray, z_std: float, tilt_std: float
            ) -> tuple[np.ndarray, np.ndarray]:
    """The 2D output: ``(x, y, yaw)`` of a pose kept, z, roll and pitch set to zero, with the
    ROS covariance ``C_ros`` reduced accordingly (x, y, yaw rows and columns kept, the rest
    uncorrelated). z, roll and pitch get the variances of the flat-world assumption ``z_std``,
    ``tilt_std``, plus, as the twist's dropped rates (`flatten_twist`), their own variance and
    the square of the value dropped: the zero is off by that much (a user test: on KITTI 06's
    climb the z error was 14 times its standard deviation of 5 cm)."""
    flat = planar_pose(T[0, 3], T[1, 3], float(yaw_of(T[:3, :3])))
    keep = [0, 1, 5]
    C = np.zeros((6, 6))
    C[np.ix_(keep, keep)] = C_ros[np.ix_(keep, keep)]
    R = T[:3, :3]
    roll = math.atan2(float(R[2, 1]), float(R[2, 2]))           # ROS: fixed x, y, z axes
    pitch = math.asin(max(-1.0, min(1.0, -float(R[2, 0]))))
    C[2, 2] = z_std ** 2 + float(T[2, 3]) ** 2 + C_ros[2, 2]
    C[3, 3] = tilt_std ** 2 + roll ** 2 + C_ros[3, 3]
    C[4, 4] = tilt_std ** 2 + pitch ** 2 + C_ros[4, 4]
    return flat, C


def flatten_twist(twist: np.ndarray, C_twist: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The 2D output's twist ``[vx, vy, vz, wx, wy, wz]``: vz and the roll and pitch rates set
    to zero, each with its variance plus the square of the value dropped (the zero is off by
    that much); the x, y, yaw block of ``C_twist`` kept, the rest uncorrelated."""
    flat = np.zeros(6)
    keep, drop = [0, 1, 5], [2, 3, 4]
    flat[keep] = twist[keep]
    C = np.zeros((6, 6))
    C[np.ix_(keep, keep)] = C_twist[np.ix_(keep, keep)]
    C[drop, drop] = C_twist[drop, drop] + twist[drop] ** 2
    return flat, C


def yaw_rate_decay(rate: float, dt: float, time_constant: float) -> float:
    """The yaw (rad) a rate ``rate`` (rad/s) decaying exponentially with ``time_constant`` (s)
    turns in ``dt`` seconds: ``rate tau (1 - exp(-dt / tau))``, bounded by ``rate tau`` however
    long the gap (no spin in a long tunnel)."""
    return rate * time_constant * (1.0 - math.exp(-dt / time_constant))
