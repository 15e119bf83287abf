"""Planar vehicle trajectories with exact poses and timestamps, for rendering test drives.

A trajectory is the pose ``T_odom_base`` (REP-103: base_link x forward, y left, z up; the ground
is ``z = 0`` in odom) sampled at a fixed frame rate. Each generator describes a path by the
vehicle heading as a function of signed arc length, ``theta(s)``, and the motion by ``s(t)``;
positions are ``p(s) = integral of (cos theta, sin theta) ds``. Between consecutive nodes of a fine
arc-length grid the path is the circular arc that joins their headings, so straights and constant
turns are exact and smooth paths are integrated to ~1e-10 m. Whatever the integration, the poses
ARE the ground truth: the renderer places the camera exactly there.

Positive yaw (and positive ``angle`` of `turn`) is a left turn. Reverse driving is ``s``
decreasing: the vehicle keeps its heading and moves along its -x axis.

Segments start at the origin with zero yaw at ``t = 0``; `concatenate` chains them, each starting
at the last pose and time of the previous one.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from planar_vo._checks import as_array
from planar_vo.errors import InputError
from planar_vo.geometry.frames import invert, mount_transform, planar_pose, yaw_of

__all__ = [
    'Trajectory',
    'concatenate',
    'reverse',
    's_curve',
    'stop_and_go',
    'straight',
    'turn',
]

logger = logging.getLogger(__name__)

# Fine arc-length step of the path integration (m): the chord-of-arc rule's error per step is
# O(ds^3 * dkappa/ds), negligible at this step for the curvatures used here.
_PATH_STEP = 0.05


@dataclass(frozen=True)
class Trajectory:
    """Vehicle poses at frame times.

    Attributes:
        stamps: frame times in seconds, shape ``(N,)``, strictly increasing.
        poses: ``T_odom_base`` of each frame, shape ``(N, 4, 4)``; planar (z = 0, no roll/pitch).
    """

    stamps: np.ndarray
    poses: np.ndarray

    def __post_init__(self) -> None:
        stamps = as_array('stamps', self.stamps, (None,))
        poses = as_array('poses', self.poses, (None, 4, 4))
        if len(stamps) != len(poses):
            raise InputError(f'stamps, poses: expected the same number of frames, got '
                             f'{len(stamps)} and {len(poses)}')
        if np.any(np.diff(stamps) <= 0.0):
            raise InputError('stamps: expected strictly increasing times, got a non-increasing '
                             'step')
        for name, value in (('stamps', stamps), ('poses', poses)):
            value.setflags(write=False)
            object.__setattr__(self, name, value)

    def __len__(self) -> int:
        return int(self.stamps.shape[0])

    @property
    def xy(self) -> np.ndarray:
        """Positions in odom, shape ``(N, 2)`` (m)."""
        return self.poses[:, :2, 3]

    @property
    def yaw(self) -> np.ndarray:
        """Headings in odom (rad, wrapped to ``(-pi, pi]``), shape ``(N,)``."""
        return yaw_of(self.poses[:, :3, :3])

    @property
    def rate(self) -> float:
        """Mean frame rate (Hz)."""
        return float((len(self) - 1) / (self.stamps[-1] - self.stamps[0])) if len(self) > 1 else 0.0

    def camera_poses(self, mount) -> np.ndarray:
        """``T_odom_camera = T_odom_base @ T_base_camera`` per frame, shape ``(N, 4, 4)``.

        Args:
            mount: ``T_base_camera`` (4x4, `planar_vo.geometry.frames.mount_transform`) or a
                `planar_vo.config.MountConfig` (anything with its x, y, height, roll, pitch,
                yaw).
        """
        if all(hasattr(mount, k) for k in ('x', 'y', 'height', 'roll', 'pitch', 'yaw')):
            mount = mount_transform(mount.x, mount.y, mount.height, mount.roll, mount.pitch,
                                    mount.yaw)
        T_bc = as_array('T_base_camera', mount, (4, 4))
        return self.poses @ T_bc

    def relative(self, i: int, j: int) -> np.ndarray:
        """Vehicle motion ``T_base_i_base_j`` between frames ``i`` and ``j``."""
        return invert(self.poses[i]) @ self.poses[j]

    def then(self, *others: Trajectory) -> Trajectory:
        """This trajectory followed by others (see `concatenate`)."""
        return concatenate(self, *others)

    def transformed(self, T: np.ndarray, time_offset: float = 0.0) -> Trajectory:
        """The trajectory moved rigidly, ``T @ poses``, with ``time_offset`` added to the stamps."""
        T = as_array('T', T, (4, 4))
        return Trajectory(self.stamps + time_offset, T @ self.poses)


def concatenate(*segments: Trajectory) -> Trajectory:
    """Chain segments: each starts at the previous segment's last pose and time.

    The first frame of every later segment coincides with the last frame of the one before (both
    are that segment's origin) and is dropped, so no frame is duplicated.
    """
    if not segments:
        raise InputError('segments: expected at least one Trajectory, got none')
    stamps, poses = [segments[0].stamps], [segments[0].poses]
    for seg in segments[1:]:
        if not isinstance(seg, Trajectory):
            raise InputError(f'segments: expected Trajectory objects, got {type(seg).__name__}')
        moved = seg.transformed(poses[-1][-1] @ invert(seg.poses[0]),
                                stamps[-1][-1] - seg.stamps[0])
        stamps.append(moved.stamps[1:])
        poses.append(moved.poses[1:])
    return Trajectory(np.concatenate(stamps), np.concatenate(poses))


# ------------------------------------------------------------------------------------------------
# Generators
# ------------------------------------------------------------------------------------------------

def _check_positive(**values: float) -> None:
    for name, value in values.items():
        if not (np.isfinite(value) and value > 0):
            raise InputError(f'{name}: expected a positive finite number, got {value!r}')


def _frame_count(duration: float, rate: float) -> int:
    return max(1, int(round(duration * rate)))


def _sample(s_of_t: Callable[[np.ndarray], np.ndarray],
            theta_of_s: Callable[[np.ndarray], np.ndarray],
            frames: int, rate: float) -> Trajectory:
    """Trajectory with ``frames + 1`` samples at ``t = k / rate`` from ``s(t)`` and ``theta(s)``.

    The path is integrated on a fine grid of arc length that contains every sample's ``s``, with
    the exact chord of the circular arc between consecutive nodes:
    ``dp = ds sinc(dtheta / 2) [cos(theta + dtheta / 2), sin(theta + dtheta / 2)]``.
    """
    t = np.arange(frames + 1) / rate
    s = np.asarray(s_of_t(t), dtype=np.float64)
    lo, hi = min(0.0, s.min()), max(0.0, s.max())
    grid = np.unique(np.concatenate([
        np.linspace(lo, hi, max(2, int(np.ceil((hi - lo) / _PATH_STEP)) + 1)), s, [0.0]]))
    theta = np.asarray(theta_of_s(grid), dtype=np.float64)
    ds = np.diff(grid)
    dth = np.diff(theta)
    mid = theta[:-1] + 0.5 * dth
    chord = ds * np.sinc(dth / (2.0 * np.pi))             # np.sinc(x) = sin(pi x) / (pi x)
    xy = np.concatenate([[[0.0, 0.0]], np.cumsum(
        np.stack([chord * np.cos(mid), chord * np.sin(mid)], -1), axis=0)])
    xy -= xy[np.searchsorted(grid, 0.0)]                  # s = 0 is the origin
    k = np.searchsorted(grid, s)
    return Trajectory(t, planar_pose(xy[k, 0], xy[k, 1], theta[k]))


def straight(distance: float = 50.0, speed: float = 10.0, rate: float = 10.0) -> Trajectory:
    """Drive ``distance`` metres straight ahead at constant speed (m/s), sampled at ``rate`` Hz.

    The duration is rounded to whole frames and the speed adjusted to cover exactly ``distance``.
    """
    _check_positive(distance=distance, speed=speed, rate=rate)
    n = _frame_count(distance / speed, rate)
    v = distance / (n / rate)
    return _sample(lambda t: v * t, np.zeros_like, n, rate)


def turn(angle: float = np.pi / 2, radius: float = 20.0, speed: float = 8.0,
         rate: float = 10.0) -> Trajectory:
    """Constant-curvature turn by ``angle`` (rad; positive = left, REP-103) of ``radius`` metres.

    The arc length is ``|angle| * radius``; duration rounded to whole frames as in `straight`.
    """
    _check_positive(radius=radius, speed=speed, rate=rate)
    if not (np.isfinite(angle) and angle != 0.0):
        raise InputError(f'angle: expected a non-zero finite angle (rad), got {angle!r}')
    length = abs(angle) * radius
    n = _frame_count(length / speed, rate)
    v = length / (n / rate)
    kappa = np.sign(angle) / radius
    return _sample(lambda t: v * t, lambda s: kappa * s, n, rate)


def s_curve(length: float = 60.0, max_heading: float = np.radians(25.0), speed: float = 8.0,
            rate: float = 10.0) -> Trajectory:
    """An S-curve (lane-change shape): heading ``theta(s) = max_heading sin^2(pi s / length)``.

    Starts and ends with zero heading and curvature; turns left first for ``max_heading > 0``.
    """
    _check_positive(length=length, speed=speed, rate=rate)
    if not (np.isfinite(max_heading) and 0.0 < abs(max_heading) < np.pi / 2):
        raise InputError(f'max_heading: expected 0 < |max_heading| < pi/2 rad, got {max_heading!r}')
    n = _frame_count(length / speed, rate)
    v = length / (n / rate)
    return _sample(lambda t: v * t,
                   lambda s: max_heading * np.sin(np.pi * s / length) ** 2, n, rate)


def reverse(distance: float = 10.0, speed: float = 2.0, rate: float = 10.0) -> Trajectory:
    """Back up ``distance`` metres in a straight line: the vehicle moves along its -x axis."""
    _check_positive(distance=distance, speed=speed, rate=rate)
    n = _frame_count(distance / speed, rate)
    v = distance / (n / rate)
    return _sample(lambda t: -v * t, np.zeros_like, n, rate)


def stop_and_go(distance: float = 20.0, speed: float = 8.0, stop_duration: float = 1.0,
                ramp_duration: float = 2.0, rate: float = 10.0) -> Trajectory:
    """Cruise, brake to a full stop, stand still, accelerate back to ``speed``, cruise.

    The speed follows a raised-cosine ramp of ``ramp_duration`` seconds down and up, so it is
    continuous; during the stop the poses are exactly identical. ``distance`` is covered at
    cruise speed before the braking and again after the acceleration.
    """
    _check_positive(distance=distance, speed=speed, stop_duration=stop_duration,
                    ramp_duration=ramp_duration, rate=rate)
    cruise = distance / speed
    # Phase boundaries (s): cruise, brake, stop, accelerate, cruise; distances covered by ramps
    # of the raised cosine are speed * ramp / 2.
    t1 = cruise
    t2 = t1 + ramp_duration
    t3 = t2 + stop_duration
    t4 = t3 + ramp_duration
    t5 = t4 + cruise
    d_ramp = speed * ramp_duration / 2.0
    n = _frame_count(t5, rate)
    scale = t5 / (n / rate)          # frame times map onto [0, t5]: whole frames, same distance

    def s_of_t(t_frames: np.ndarray) -> np.ndarray:
        t = t_frames * scale
        u_brake = np.clip((t - t1) / ramp_duration, 0.0, 1.0)
        u_acc = np.clip((t - t3) / ramp_duration, 0.0, 1.0)
        # Integral of v(u) = speed (1 + cos(pi u)) / 2 (braking) and speed (1 - cos(pi u)) / 2.
        brake = speed * ramp_duration * (u_brake + np.sin(np.pi * u_brake) / np.pi) / 2.0
        accel = speed * ramp_duration * (u_acc - np.sin(np.pi * u_acc) / np.pi) / 2.0
        return speed * np.minimum(t, t1) + brake + accel + speed * np.clip(t - t4, 0.0, None)

    traj = _sample(s_of_t, np.zeros_like, n, rate)
    logger.debug('stop_and_go: %d frames, %.1f m', len(traj), 2 * distance + 2 * d_ramp)
    return traj
