"""Duck-typed conversion between ROS messages and numpy (rclpy AND rosbags messages).

Nothing here imports rclpy or rosbags: functions read attributes (``msg.height``,
``msg.encoding``, ``msg.data``, ``stamp.sec``...) so the node and bag replay share one
implementation. Message byte buffers may be ``bytes``, ``array.array('B')`` (rclpy) or uint8
numpy arrays (rosbags).

Images come out as ``(H, W)`` uint8 grey by default, the input of the front-end (the pixel
conversions are `planar_vo.frontend.images`'). `odometry_message` builds ``nav_msgs/Odometry``
for rclpy (the node) and rosbags (bag writing) alike, from the message classes it is given.

Stamps are handled as integer nanoseconds so that an output message can carry exactly its input
image's header stamp; ``float`` seconds (about 0.2 us resolution at 1.7e9 s) are for maths only.
"""

from __future__ import annotations

import math
from decimal import Decimal, InvalidOperation
from typing import Any

import numpy as np

from planar_vo.core.conventions import quaternion_from_rotation, rotation_from_quaternion, se3
from planar_vo.errors import InputError
from planar_vo.frontend.images import decode_compressed, decode_raw

__all__ = [
    'MAX_SPEED',
    'compressed_to_array',
    'covariance_to_list',
    'image_to_array',
    'odometry_message',
    'ns_to_stamp_fields',
    'pose_from_message',
    'pose_to_position_quaternion',
    'seconds_to_ns',
    'seconds_to_stamp_fields',
    'speed_from_message',
    'stamp_problem',
    'stamp_to_ns',
    'stamp_to_seconds',
    'twist_to_fields',
]

_NS_PER_S = 1_000_000_000


def image_to_array(msg: Any, *, gray: bool = True, mono16_shift: int = 8) -> np.ndarray:
    """Pixels of a ``sensor_msgs/Image`` (`planar_vo.frontend.images.decode_raw`).

    Args:
        msg: any object with ``height``, ``width``, ``encoding``, ``is_bigendian``, ``step``,
            ``data`` (rclpy or rosbags message).
        gray, mono16_shift: see `decode_raw`.

    Raises:
        ImageError: unsupported encoding, empty image, inconsistent ``step`` or ``data``.
    """
    return decode_raw(msg.data, msg.encoding, msg.height, msg.width, msg.step,
                      bool(msg.is_bigendian), gray=gray, mono16_shift=mono16_shift)


def compressed_to_array(msg: Any, *, gray: bool = True, mono16_shift: int = 8) -> np.ndarray:
    """Pixels of a ``sensor_msgs/CompressedImage`` (JPEG or PNG;
    `planar_vo.frontend.images.decode_compressed`).

    Raises:
        ImageError: unknown format or data that cannot be decoded.
    """
    return decode_compressed(msg.data, str(msg.format), gray=gray, mono16_shift=mono16_shift)


# -- stamps -------------------------------------------------------------------------------------

def stamp_to_ns(stamp: Any) -> int:
    """Integer nanoseconds of a ``builtin_interfaces/Time`` (``sec``, ``nanosec``)."""
    return int(stamp.sec) * _NS_PER_S + int(stamp.nanosec)


def stamp_problem(stamp: Any) -> str | None:
    """Why a ``builtin_interfaces/Time`` is no ROS time (negative, ``nanosec`` of a second or
    more, beyond 2038: int32 seconds), or None."""
    sec, nanosec = int(stamp.sec), int(stamp.nanosec)
    if 0 <= sec < 2 ** 31 and 0 <= nanosec < _NS_PER_S:
        return None
    return (f'header stamp sec {sec}, nanosec {nanosec} is not a ROS time (0 <= nanosec < 1e9, '
            f'from 1970 to 2038)')


def stamp_to_seconds(stamp: Any) -> float:
    """Seconds (float, correctly rounded from the exact integer nanoseconds) of a stamp."""
    return stamp_to_ns(stamp) / _NS_PER_S


def ns_to_stamp_fields(ns: int) -> tuple[int, int]:
    """``(sec, nanosec)`` of integer nanoseconds, ``0 <= nanosec < 1e9`` (exact)."""
    return divmod(int(ns), _NS_PER_S)


def seconds_to_ns(t: float | int | str | Decimal) -> int:
    """Nearest integer nanoseconds of seconds given as a number or a decimal string.

    Floats go through their shortest decimal representation (``repr``), so ``0.1`` is exactly
    100,000,000 ns rather than the binary float's 100,000,000.0000000055.
    """
    try:
        value = t if isinstance(t, Decimal) else Decimal(t if isinstance(t, str) else repr(t))
        if not value.is_finite():
            raise InvalidOperation
    except (InvalidOperation, ValueError, TypeError) as err:
        raise InputError(f'stamp: expected finite seconds, got {t!r}') from err
    return int((value * _NS_PER_S).to_integral_value())


def seconds_to_stamp_fields(t: float | int | str | Decimal) -> tuple[int, int]:
    """``(sec, nanosec)`` of seconds, rounded to the nearest nanosecond (see `seconds_to_ns`)."""
    return ns_to_stamp_fields(seconds_to_ns(t))


# -- odometry fields ----------------------------------------------------------------------------

def pose_to_position_quaternion(T: np.ndarray) -> tuple[tuple[float, float, float],
                                                        tuple[float, float, float, float]]:
    """``((x, y, z), (qx, qy, qz, qw))`` of a 4x4 pose, quaternion in ROS order with ``qw >= 0``."""
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise InputError(f'pose: expected a finite 4x4 matrix, got shape {T.shape}')
    q = quaternion_from_rotation(T[:3, :3])
    return tuple(float(v) for v in T[:3, 3]), tuple(float(v) for v in q)


def covariance_to_list(C: np.ndarray) -> list[float]:
    """The 36 row-major floats of a 6x6 covariance (``PoseWithCovariance.covariance``)."""
    C = np.asarray(C, dtype=np.float64)
    if C.shape != (6, 6):
        raise InputError(f'covariance: expected shape (6, 6), got {C.shape}')
    return [float(v) for v in C.reshape(36)]


def twist_to_fields(twist: np.ndarray) -> tuple[tuple[float, float, float],
                                                tuple[float, float, float]]:
    """``((vx, vy, vz), (wx, wy, wz))`` of a body twist ``(6,)`` (m/s, rad/s, in base_link)."""
    twist = np.asarray(twist, dtype=np.float64)
    if twist.shape != (6,):
        raise InputError(f'twist: expected shape (6,), got {twist.shape}')
    return (tuple(float(v) for v in twist[:3]), tuple(float(v) for v in twist[3:]))


ODOMETRY_TYPES = (
    'nav_msgs/msg/Odometry', 'std_msgs/msg/Header', 'builtin_interfaces/msg/Time',
    'geometry_msgs/msg/PoseWithCovariance', 'geometry_msgs/msg/Pose', 'geometry_msgs/msg/Point',
    'geometry_msgs/msg/Quaternion', 'geometry_msgs/msg/TwistWithCovariance',
    'geometry_msgs/msg/Twist', 'geometry_msgs/msg/Vector3',
)


def odometry_message(types: Any, stamp_ns: int, pose: np.ndarray, *, odom_frame: str,
                     base_frame: str, pose_covariance: np.ndarray | None = None,
                     twist: np.ndarray | None = None,
                     twist_covariance: np.ndarray | None = None) -> Any:
    """A ``nav_msgs/Odometry`` from plain values, for any message library.

    Args:
        types: mapping from the ROS type names in `ODOMETRY_TYPES` (``'nav_msgs/msg/Odometry'``,
            ...) to message classes that take their fields as keyword arguments: rclpy's
            generated classes or a rosbags typestore's ``types``.
        stamp_ns: ``header.stamp`` in integer nanoseconds.
        pose: ``T_odom_base`` (4x4, finite).
        odom_frame, base_frame: ``header.frame_id`` and ``child_frame_id``.
        pose_covariance, twist_covariance: 6x6 (default zeros), REP-103 order.
        twist: body velocity ``(vx, vy, vz, wx, wy, wz)`` in `base_frame` (default zeros).

    Raises:
        InputError: a non-finite pose or a wrongly shaped covariance or twist.
    """
    geo = 'geometry_msgs/msg/'
    zeros = np.zeros((6, 6))
    (px, py, pz), (qx, qy, qz, qw) = pose_to_position_quaternion(pose)
    (vx, vy, vz), (wx, wy, wz) = twist_to_fields(np.zeros(6) if twist is None else twist)
    sec, nanosec = ns_to_stamp_fields(stamp_ns)
    return types['nav_msgs/msg/Odometry'](
        header=types['std_msgs/msg/Header'](
            stamp=types['builtin_interfaces/msg/Time'](sec=sec, nanosec=nanosec),
            frame_id=odom_frame),
        child_frame_id=base_frame,
        pose=types[geo + 'PoseWithCovariance'](
            pose=types[geo + 'Pose'](
                position=types[geo + 'Point'](x=px, y=py, z=pz),
                orientation=types[geo + 'Quaternion'](x=qx, y=qy, z=qz, w=qw)),
            covariance=np.array(covariance_to_list(
                zeros if pose_covariance is None else pose_covariance))),
        twist=types[geo + 'TwistWithCovariance'](
            twist=types[geo + 'Twist'](linear=types[geo + 'Vector3'](x=vx, y=vy, z=vz),
                                       angular=types[geo + 'Vector3'](x=wx, y=wy, z=wz)),
            covariance=np.array(covariance_to_list(
                zeros if twist_covariance is None else twist_covariance))),
    )


# -- incoming poses and speeds ------------------------------------------------------------------

def pose_from_message(msg: Any) -> np.ndarray:
    """4x4 pose of a ``nav_msgs/Odometry``, ``geometry_msgs/PoseStamped``,
    ``PoseWithCovarianceStamped`` or ``Pose`` (duck-typed, the first that fits)."""
    pose = msg
    for _ in range(2):                               # Odometry.pose.pose, PoseStamped.pose
        if hasattr(pose, 'pose') and not hasattr(pose, 'position'):
            pose = pose.pose
    try:
        p, o = pose.position, pose.orientation
        t = np.array([p.x, p.y, p.z], dtype=np.float64)
        q = np.array([o.x, o.y, o.z, o.w], dtype=np.float64)
    except AttributeError as err:
        raise InputError(f'pose message: expected Odometry, PoseStamped or Pose fields, got '
                         f'{type(msg).__name__}') from err
    norm = float(np.linalg.norm(q))
    if not (np.all(np.isfinite(t)) and math.isfinite(norm) and norm > 0.0):
        raise InputError(f'pose message: expected a finite position and a non-zero quaternion, '
                         f'got position {t.tolist()} quaternion {q.tolist()}')
    return se3(rotation_from_quaternion(q / norm), t)


# A speed above this (m/s, 3,600 km/h) is no ground vehicle's: the message is refused.
MAX_SPEED = 1000.0


def speed_from_message(msg: Any) -> float:
    """Vehicle speed (m/s, non-negative) of a ``geometry_msgs/TwistStamped``, ``Twist`` or
    ``nav_msgs/Odometry``: the norm of the linear velocity.

    The norm, not ``linear.x``, because speed sources differ in frame (wheel odometry in
    base_link, GNSS velocity in a world frame); the direction of motion comes from vision.
    """
    twist = msg
    for _ in range(2):                               # Odometry.twist.twist, TwistStamped.twist
        if hasattr(twist, 'twist') and not hasattr(twist, 'linear'):
            twist = twist.twist
    try:
        v = twist.linear
        components = (float(v.x), float(v.y), float(v.z))
    except AttributeError as err:
        raise InputError(f'speed message: expected TwistStamped or Odometry fields, got '
                         f'{type(msg).__name__}') from err
    except (TypeError, ValueError) as err:
        raise InputError(f'speed message: expected numbers in linear.x, y, z: {err}') from err
    speed = math.hypot(*components)                  # no overflow where the squares would
    if not (math.isfinite(speed) and speed <= MAX_SPEED):
        raise InputError(f'speed message: expected a finite velocity of at most {MAX_SPEED:g} '
                         f'm/s, got {speed:.6g} m/s')
    return speed
