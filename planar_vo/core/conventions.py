"""Conventions, written once and used everywhere: the frames of a vehicle-mounted camera
(REP-103/105), rigid transforms, and the planar-motion parametrisation.

Frames:

- ``odom``: fixed world frame, z up, the ground plane is ``z = 0``.
- ``base_link``: the vehicle, x forward, y left, z up.
- ``camera`` (optical): x right, y down, z forward; placed in ``base_link`` by the mount.

Poses are 4x4 homogeneous matrices ``T_a_b`` mapping coordinates in frame ``b`` to frame ``a``
(``p_a = T_a_b p_b``), so ``T_a_c = T_a_b @ T_b_c``.

Planar motion between two views ``P1 = C1 [I | 0]`` and ``P2 = C2 [R | t]``, i.e.
``X2 = R X1 + t``, of a level camera (its y axis vertical):

    R = Ry(alpha) = [[cos a, 0, sin a], [0, 1, 0], [-sin a, 0, cos a]]
    t = [cos b, 0, sin b]                       (unit; monocular scale is unobservable)

The centre of camera 2 in frame 1 is ``-R^T t``. Forward driving gives ``t ~ [0, 0, -1]``
(``beta ~ -pi/2``). A positive ``alpha`` turns the optical axis towards the camera's -x, i.e. a
left turn: for a level camera ``alpha`` equals the vehicle's yaw change (REP-103, z up).

The essential matrix is ``E = [t]x R = [[0, -sin b, 0], [sin(a+b), 0, -cos(a+b)], [0, cos b, 0]]``
and the solvers' unknown vector is ``x = [cos(a+b), sin(a+b), cos b, sin b]``.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    'R_BASE_OPTICAL',
    'adjoint',
    'angle_difference',
    'camera_displacement',
    'camera_motion_to_base',
    'invert',
    'mount_transform',
    'normal_from_tilt',
    'normal_tilt_jacobian',
    'planar_essential',
    'planar_motion_from_pose',
    'planar_pose',
    'quaternion_from_rotation',
    'rotation_from_quaternion',
    'rotation_rpy',
    'rotation_y',
    'se3',
    'se3_exp',
    'se3_log',
    'skew',
    'so3_exp',
    'so3_left_jacobian',
    'so3_log',
    'tilt_from_normal',
    'translation_direction',
    'wrap_angle',
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


# --------------------------------------------------------------------------------------------
# Rotation vectors and twists (small motions, covariances)
# --------------------------------------------------------------------------------------------

def skew(v: np.ndarray) -> np.ndarray:
    """``[v]x`` (3, 3) with ``[v]x u = v x u`` for a 3-vector ``v``."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def so3_exp(w: np.ndarray) -> np.ndarray:
    """Rotation matrix ``exp([w]x)`` of the rotation vector ``w`` (3,) (Rodrigues:
    ``I + a [w]x + b [w]x^2`` with ``a = sin(th) / th``, ``b = (1 - cos(th)) / th^2``; the
    series limits ``a = 1``, ``b = 1/2`` below 1e-8 rad). Plain floats: at 3x3 numpy's
    per-call overhead would dominate."""
    x, y, z = float(w[0]), float(w[1]), float(w[2])
    th2 = x * x + y * y + z * z
    if th2 < 1e-16:
        a, b = 1.0, 0.5
    else:
        th = math.sqrt(th2)
        a, b = math.sin(th) / th, (1.0 - math.cos(th)) / th2
    xy, xz, yz = b * x * y, b * x * z, b * y * z
    return np.array([[1.0 - b * (y * y + z * z), xy - a * z, xz + a * y],
                     [xy + a * z, 1.0 - b * (x * x + z * z), yz - a * x],
                     [xz - a * y, yz + a * x, 1.0 - b * (x * x + y * y)]])


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation vector (3,) of ``R`` (angles below pi): ``so3_exp(so3_log(R)) = R``."""
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    s = 0.5 * math.sqrt(float(w @ w))
    c = 0.5 * (R[0, 0] + R[1, 1] + R[2, 2] - 1.0)
    th = math.atan2(s, c)
    return w * (0.5 if th < 1e-8 else 0.5 * th / s)


def so3_left_jacobian(phi: np.ndarray) -> np.ndarray:
    """SO(3)'s left Jacobian (3, 3) at the rotation vector ``phi``: ``exp(phi + d) =
    exp(J d) exp(phi)`` to first order in ``d``; also the ``V`` of `se3_exp`."""
    th = math.sqrt(float(phi @ phi))
    K = skew(phi)
    if th < 1e-9:
        return np.eye(3) + 0.5 * K
    return (np.eye(3) + (1.0 - math.cos(th)) / th ** 2 * K
            + (th - math.sin(th)) / th ** 3 * K @ K)


def se3_exp(xi: np.ndarray) -> np.ndarray:
    """``exp(xi^)`` (4, 4) of a twist ``xi = [phi, rho]`` (rotation vector, then translation)."""
    phi, rho = xi[:3], xi[3:]
    return se3(so3_exp(phi), so3_left_jacobian(phi) @ rho)


def se3_log(T: np.ndarray) -> np.ndarray:
    """The twist ``[phi, rho]`` (6,) of a rigid transform (inverse of `se3_exp`)."""
    phi = so3_log(T[:3, :3])
    th = math.sqrt(float(phi @ phi))
    K = skew(phi)
    if th < 1e-2:
        # The closed form's 1 - cos(th) cancels (it divided by zero at th near 1e-8): its
        # series, exact to rounding below 1e-2.
        b = 1.0 / 12.0 + th * th / 720.0 + th ** 4 / 30240.0
    else:
        b = (1.0 - th * math.sin(th) / (2.0 * (1.0 - math.cos(th)))) / th ** 2
    V_inv = np.eye(3) - 0.5 * K + b * K @ K
    return np.concatenate([phi, V_inv @ T[:3, 3]])


def adjoint(T: np.ndarray) -> np.ndarray:
    """Adjoint (6, 6) of ``T`` for twists ``[phi, rho]``: ``T exp(xi^) T^-1 = exp((Ad xi)^)``."""
    R, p = T[:3, :3], T[:3, 3]
    Ad = np.zeros((6, 6))
    Ad[:3, :3] = R
    Ad[3:, 3:] = R
    Ad[3:, :3] = skew(p) @ R
    return Ad


# --------------------------------------------------------------------------------------------
# Planar motion
# --------------------------------------------------------------------------------------------


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


# --------------------------------------------------------------------------------------------
# Tilt of a camera against a plane (the motion plane, the road)
# --------------------------------------------------------------------------------------------


def normal_from_tilt(pitch: float, roll: float) -> np.ndarray:
    """Unit normal ``(3,)`` (pointing down) of the plane under a camera pitched down by ``pitch``
    and rolled by ``roll`` (radians, the `MountConfig` sense), in camera-optical coordinates:

        n = [sin(roll) cos(pitch), cos(roll) cos(pitch), sin(pitch)],

    the level camera's y axis seen from the tilted camera (``R_lc^T [0, 1, 0]`` with the
    levelling rotation ``R_lc`` of `planar_vo.frontend.correction.leveling_rotation`).
    """
    sp, cp, sr, cr = np.sin(pitch), np.cos(pitch), np.sin(roll), np.cos(roll)
    return np.array([sr * cp, cr * cp, sp])


def normal_tilt_jacobian(pitch: float, roll: float) -> np.ndarray:
    """Jacobian ``(3, 2)`` of `normal_from_tilt` with respect to ``(pitch, roll)``."""
    sp, cp, sr, cr = np.sin(pitch), np.cos(pitch), np.sin(roll), np.cos(roll)
    return np.array([[-sr * sp, cr * cp], [-cr * sp, -sr * cp], [cp, 0.0]])


def tilt_from_normal(n: np.ndarray) -> tuple[float, float]:
    """``(pitch, roll)`` (radians) of a unit normal; the inverse of `normal_from_tilt`."""
    return float(np.arcsin(np.clip(n[2], -1.0, 1.0))), float(np.arctan2(n[0], n[1]))
