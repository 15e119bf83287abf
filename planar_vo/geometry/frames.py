"""Rigid transforms and the frames of a vehicle-mounted camera (REP-103/105).

- ``odom``: fixed world frame, z up, the ground plane is ``z = 0``.
- ``base_link``: the vehicle, x forward, y left, z up.
- ``camera`` (optical): x right, y down, z forward; placed in ``base_link`` by the mount.

Poses are 4x4 homogeneous matrices ``T_a_b`` mapping coordinates in frame ``b`` to frame ``a``
(``p_a = T_a_b p_b``), so ``T_a_c = T_a_b @ T_b_c``.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    'R_BASE_OPTICAL',
    'camera_motion_to_base',
    'invert',
    'mount_transform',
    'planar_pose',
    'quaternion_from_rotation',
    'rotation_from_quaternion',
    'rotation_rpy',
    'se3',
    'yaw_of',
]

# Optical axes expressed in base_link: optical z (forward) -> base x, optical x (right) -> base -y,
# optical y (down) -> base -z.
R_BASE_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def se3(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Homogeneous ``(..., 4, 4)`` transforms from rotations ``(..., 3, 3)`` and translations."""
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    T = np.zeros(np.broadcast_shapes(R.shape[:-2], t.shape[:-1]) + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def invert(T: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms ``(..., 4, 4)``."""
    T = np.asarray(T, dtype=np.float64)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    return se3(Rt, -np.einsum('...ij,...j->...i', Rt, T[..., :3, 3]))


def rotation_rpy(roll: float | np.ndarray, pitch: float | np.ndarray,
                 yaw: float | np.ndarray) -> np.ndarray:
    """``Rz(yaw) Ry(pitch) Rx(roll)`` (fixed-axis roll, pitch, yaw; REP-103), ``(..., 3, 3)``."""
    r, p, y = (np.asarray(v, dtype=np.float64) for v in (roll, pitch, yaw))
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.stack([
        np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1),
        np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1),
        np.stack([-sp, cp * sr, cp * cr], -1),
    ], -2)


def yaw_of(R: np.ndarray) -> np.ndarray:
    """Yaw (rotation about z) of rotations ``(..., 3, 3)`` in a z-up frame, radians."""
    R = np.asarray(R, dtype=np.float64)
    return np.arctan2(R[..., 1, 0], R[..., 0, 0])


def planar_pose(x: float | np.ndarray, y: float | np.ndarray, yaw: float | np.ndarray,
                z: float | np.ndarray = 0.0) -> np.ndarray:
    """``T_odom_base`` of a vehicle at ``(x, y, z)`` heading ``yaw``; ``(..., 4, 4)``."""
    yaw = np.asarray(yaw, dtype=np.float64)
    zero = np.zeros_like(yaw)
    t = np.stack(np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float),
                                     np.asarray(z, float)), -1)
    return se3(rotation_rpy(zero, zero, yaw), t)


def mount_transform(x: float = 0.0, y: float = 0.0, height: float = 1.5, roll: float = 0.0,
                    pitch: float = 0.0, yaw: float = 0.0) -> np.ndarray:
    """``T_base_camera``: the optical frame placed in ``base_link`` (see `MountConfig`).

    The optical frame is first rotated into the base axes (`R_BASE_OPTICAL`), then by
    ``Rz(yaw) Ry(pitch) Rx(roll)`` about the base axes (positive pitch looks down, positive yaw
    looks left), and placed at ``(x, y, height)``.
    """
    return se3(rotation_rpy(roll, pitch, yaw) @ R_BASE_OPTICAL, np.array([x, y, height]))


def camera_motion_to_base(T_cam1_cam2: np.ndarray, T_base_camera: np.ndarray) -> np.ndarray:
    """Vehicle motion ``T_base1_base2`` from the camera motion ``T_cam1_cam2`` and the mount.

    The camera is rigidly mounted: ``T_base1_base2 = T_bc T_c1_c2 T_bc^-1``.
    """
    return T_base_camera @ T_cam1_cam2 @ invert(T_base_camera)


def quaternion_from_rotation(R: np.ndarray) -> np.ndarray:
    """Unit quaternions ``(..., 4)`` in ROS order ``(x, y, z, w)``, ``w >= 0``, from rotations."""
    R = np.asarray(R, dtype=np.float64)
    m00, m11, m22 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    # Four candidate magnitudes; take the largest for numerical stability (Shepperd's method).
    cand = np.stack([1.0 + m00 + m11 + m22, 1.0 + m00 - m11 - m22,
                     1.0 - m00 + m11 - m22, 1.0 - m00 - m11 + m22], -1)
    k = np.argmax(cand, axis=-1)
    s = np.sqrt(np.maximum(np.take_along_axis(cand, k[..., None], -1)[..., 0], 1e-300)) * 2.0
    q = np.empty(R.shape[:-2] + (4,))
    d10, d01 = R[..., 1, 0], R[..., 0, 1]
    d20, d02 = R[..., 2, 0], R[..., 0, 2]
    d21, d12 = R[..., 2, 1], R[..., 1, 2]
    options = [
        np.stack([(d21 - d12) / s, (d02 - d20) / s, (d10 - d01) / s, s / 4.0], -1),
        np.stack([s / 4.0, (d01 + d10) / s, (d02 + d20) / s, (d21 - d12) / s], -1),
        np.stack([(d01 + d10) / s, s / 4.0, (d12 + d21) / s, (d02 - d20) / s], -1),
        np.stack([(d02 + d20) / s, (d12 + d21) / s, s / 4.0, (d10 - d01) / s], -1),
    ]
    for i, opt in enumerate(options):
        q = np.where((k == i)[..., None], opt, q)
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., 3:4] < 0.0, -q, q)


def rotation_from_quaternion(q: np.ndarray) -> np.ndarray:
    """Rotations ``(..., 3, 3)`` from quaternions ``(..., 4)`` in ROS order ``(x, y, z, w)``."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], -2)
