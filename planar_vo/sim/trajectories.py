"""Planar vehicle trajectories with exact poses and timestamps, for rendering test drives.

Each generator returns a `planar_vo.core.Trajectory`.

A trajectory is the pose ``T_odom_base`` (REP-103: base_link x forward, y left, z up; the ground
is ``z = 0`` in odom) sampled at a fixed frame rate. Each generator describes a path by the
vehicle heading as a function of signed arc length, ``theta(s)``, and the motion by ``s(t)``;
positions are ``p(s) = integral of (cos theta, sin theta) ds``. Between consecutive nodes of a fine
arc-length grid the path is the circular arc that joins their headings, so straights and constant
turns are exact and smooth paths are integrated to ~1e-10 m. Whatever the integration, the poses
ARE the ground truth: the renderer places the camera exactly there.

Positive yaw (and positive ``angle`` of `turn`) is a left turn. Reverse driving is ``s``
decreasing: the vehicle keeps its heading and moves along its -x axis.

Segments start at the origin with zero yaw at ``t = 0``; `Trajectory.then` chains them, each
starting at the last pose and time of the previous one.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import numpy as np

from planar_vo.core.conventions import planar_pose
from planar_vo.core.trajectory import Trajectory
from planar_vo.errors import InputError

__all__ = [
    'hard_stop',
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
    return Trajectory.from_poses(t, planar_pose(xy[k, 0], xy[k, 1], theta[k]))


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


def hard_stop(distance: float = 8.0, speed: float = 8.0, deceleration: float = 3.0,
              stop_duration: float = 1.5, rate: float = 30.0) -> Trajectory:
    """Cruise ``distance`` metres, brake at a constant ``deceleration`` (m/s^2) to a full stop
    and stand for ``stop_duration`` seconds: a simulator's brake, which does not ease off
    before the stop as a driver does (`stop_and_go`); the standing poses are exactly
    identical."""
    _check_positive(distance=distance, speed=speed, deceleration=deceleration,
                    stop_duration=stop_duration, rate=rate)
    cruise, braking = distance / speed, speed / deceleration
    n = _frame_count(cruise + braking + stop_duration, rate)

    def s_of_t(t: np.ndarray) -> np.ndarray:
        u = np.clip(t - cruise, 0.0, braking)
        return speed * np.minimum(t, cruise) + speed * u - 0.5 * deceleration * u * u

    return _sample(s_of_t, np.zeros_like, n, rate)


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
