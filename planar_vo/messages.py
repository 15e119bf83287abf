"""Duck-typed conversion between ROS messages and numpy (rclpy AND rosbags messages).

Nothing here imports rclpy or rosbags: functions read attributes (``msg.height``,
``msg.encoding``, ``msg.data``, ``stamp.sec``...) so the node and bag replay share one
implementation. Message byte buffers may be ``bytes``, ``array.array('B')`` (rclpy) or uint8
numpy arrays (rosbags).

Images come out as ``(H, W)`` uint8 grey by default, the input of the front-end:

- ``mono8``/``8UC1``: as stored.
- ``mono16``/``16UC1``: the 16-bit value shifted right by ``mono16_shift`` bits (default 8, the
  top byte of the full 16-bit range) and clipped to 255. The map is the same for every frame, so
  brightness constancy between frames (which optical flow relies on) is kept; a per-frame
  min/max stretch would break it. For 12-bit sensors stored in 16 bits use ``mono16_shift=4``.
- ``rgb8``, ``bgr8``, ``rgba8``, ``bgra8``: ITU-R BT.601 luma (OpenCV ``cvtColor``).

Stamps are handled as integer nanoseconds so that an output message can carry exactly its input
image's header stamp; ``float`` seconds (about 0.2 us resolution at 1.7e9 s) are for maths only.
"""

from __future__ import annotations

import math
from decimal import Decimal, InvalidOperation
from typing import Any

import cv2
import numpy as np

from planar_vo.errors import ImageError, InputError
from planar_vo.geometry.frames import quaternion_from_rotation, rotation_from_quaternion, se3

__all__ = [
    'IMAGE_ENCODINGS',
    'compressed_to_array',
    'covariance_to_list',
    'image_to_array',
    'ns_to_stamp_fields',
    'pose_from_message',
    'pose_to_position_quaternion',
    'seconds_to_ns',
    'seconds_to_stamp_fields',
    'speed_from_message',
    'stamp_to_ns',
    'stamp_to_seconds',
    'twist_to_fields',
]

# encoding -> (channels, bytes per channel, cv2 code to grey or None for single channel)
IMAGE_ENCODINGS: dict[str, tuple[int, int, int | None]] = {
    'mono8': (1, 1, None),
    '8UC1': (1, 1, None),
    'mono16': (1, 2, None),
    '16UC1': (1, 2, None),
    'rgb8': (3, 1, cv2.COLOR_RGB2GRAY),
    'bgr8': (3, 1, cv2.COLOR_BGR2GRAY),
    'rgba8': (4, 1, cv2.COLOR_RGBA2GRAY),
    'bgra8': (4, 1, cv2.COLOR_BGRA2GRAY),
}

_NS_PER_S = 1_000_000_000


def _buffer(data: Any) -> np.ndarray:
    """A flat uint8 view of a message byte buffer (bytes, array.array, numpy, list of ints)."""
    if isinstance(data, np.ndarray):
        return np.frombuffer(np.ascontiguousarray(data).data, dtype=np.uint8)
    try:
        return np.frombuffer(data, dtype=np.uint8)
    except TypeError:
        return np.asarray(data, dtype=np.uint8).reshape(-1)


def _mono16_to_8(img: np.ndarray, shift: int) -> np.ndarray:
    if not (isinstance(shift, (int, np.integer)) and 0 <= shift <= 8):
        raise InputError(f'mono16_shift: expected an integer in 0..8, got {shift!r}')
    return np.minimum(img >> np.uint16(shift), 255).astype(np.uint8)


def image_to_array(msg: Any, *, gray: bool = True, mono16_shift: int = 8) -> np.ndarray:
    """Pixels of a ``sensor_msgs/Image``.

    Honours ``step`` (row padding) and ``is_bigendian`` (16-bit encodings).

    Args:
        msg: any object with ``height``, ``width``, ``encoding``, ``is_bigendian``, ``step``,
            ``data`` (rclpy or rosbags message).
        gray: return ``(H, W)`` uint8 grey (see the module docstring for the conversions).
            ``False`` returns the pixels as stored: ``(H, W)`` for single-channel encodings,
            ``(H, W, C)`` in the encoding's channel order, native-endian uint8 or uint16.
        mono16_shift: right shift from 16-bit to 8-bit grey (0..8).

    Raises:
        ImageError: unsupported encoding, empty image, ``step`` too small for the width, or
            ``data`` shorter than ``height * step``.
    """
    encoding = str(msg.encoding)
    if encoding not in IMAGE_ENCODINGS:
        raise ImageError(f"image.encoding: expected one of {list(IMAGE_ENCODINGS)}, "
                         f"got '{encoding}'")
    channels, depth, code = IMAGE_ENCODINGS[encoding]
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    buf = _buffer(msg.data)
    if height <= 0 or width <= 0 or buf.size == 0:
        raise ImageError(f'image: expected a non-empty image, got {width}x{height} pixels and '
                         f'{buf.size} data bytes')
    row_bytes = width * channels * depth
    if step < row_bytes:
        raise ImageError(f'image.step: expected at least width * bytes per pixel = {width} * '
                         f'{channels * depth} = {row_bytes} for {encoding}, got {step}')
    if buf.size < height * step:
        raise ImageError(f'image.data: expected at least height * step = {height} * {step} = '
                         f'{height * step} bytes, got {buf.size}')
    rows = buf[:height * step].reshape(height, step)[:, :row_bytes]
    if depth == 2:
        dtype = np.dtype('>u2' if msg.is_bigendian else '<u2')
        img = np.ascontiguousarray(rows).view(dtype).astype(np.uint16)
    else:
        img = np.array(rows)                         # owned: never alias the message buffer
    img = img.reshape((height, width, channels) if channels > 1 else (height, width))
    if not gray:
        return img
    if depth == 2:
        return _mono16_to_8(img, mono16_shift)
    return cv2.cvtColor(img, code) if code is not None else img


def compressed_to_array(msg: Any, *, gray: bool = True, mono16_shift: int = 8) -> np.ndarray:
    """Pixels of a ``sensor_msgs/CompressedImage`` (JPEG or PNG, decoded by OpenCV).

    Args:
        msg: any object with ``format`` and ``data``. ``format`` must name ``jpeg``/``jpg`` or
            ``png`` (e.g. ``'jpeg'``, ``'bgr8; jpeg compressed bgr8'``).
        gray: return ``(H, W)`` uint8 grey; ``False`` returns what OpenCV decodes unchanged
            (``(H, W)`` grey, or ``(H, W, 3|4)`` in BGR(A) order; uint8 or uint16 for 16-bit PNG).
        mono16_shift: right shift from 16-bit to 8-bit grey for 16-bit PNGs.

    Raises:
        ImageError: unknown format or data OpenCV cannot decode.
    """
    fmt = str(msg.format).lower()
    if not any(name in fmt for name in ('jpeg', 'jpg', 'png')) or 'compresseddepth' in fmt:
        raise ImageError(f"compressed_image.format: expected 'jpeg' or 'png', got '{msg.format}'")
    buf = _buffer(msg.data)
    img = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED) if buf.size else None
    if img is None or img.size == 0:
        raise ImageError(f"compressed_image.data: expected decodable {msg.format} data, got "
                         f'{buf.size} bytes OpenCV cannot decode')
    if not gray:
        return img
    if img.dtype == np.uint16:
        img = _mono16_to_8(img, mono16_shift)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2GRAY if img.shape[2] == 4 else cv2.COLOR_BGR2GRAY)
    return img


# -- stamps -------------------------------------------------------------------------------------

def stamp_to_ns(stamp: Any) -> int:
    """Integer nanoseconds of a ``builtin_interfaces/Time`` (``sec``, ``nanosec``)."""
    return int(stamp.sec) * _NS_PER_S + int(stamp.nanosec)


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
        speed = math.sqrt(float(v.x) ** 2 + float(v.y) ** 2 + float(v.z) ** 2)
    except AttributeError as err:
        raise InputError(f'speed message: expected TwistStamped or Odometry fields, got '
                         f'{type(msg).__name__}') from err
    if not math.isfinite(speed):
        raise InputError(f'speed message: expected a finite velocity, got {speed}')
    return speed
