"""Rendered drives: the demo drive and frames along any trajectory, with exact ground truth."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from planar_vo.core.camera import CameraModel
from planar_vo.core.conventions import invert, yaw_of
from planar_vo.core.trajectory import Trajectory
from planar_vo.sim.renderer import render
from planar_vo.sim.trajectories import s_curve, stop_and_go, straight, turn
from planar_vo.sim.world import StreetWorld

__all__ = ['DriveFrame', 'body_twists', 'demo_drive', 'render_drive']


def demo_drive(rate: float = 10.0) -> Trajectory:
    """The demo drive (about 40 s, 250 m): a straight, a left turn, a straight with a full stop,
    a right turn, an S-curve and a last straight, at 6-10 m/s."""
    return straight(50.0, speed=10.0, rate=rate).then(
        turn(np.pi / 2, radius=25.0, speed=7.0, rate=rate),
        stop_and_go(30.0, speed=8.0, stop_duration=2.0, rate=rate),
        turn(-np.pi / 3, radius=30.0, speed=7.0, rate=rate),
        s_curve(60.0, speed=8.0, rate=rate),
        straight(30.0, speed=10.0, rate=rate),
    )


def body_twists(trajectory: Trajectory) -> np.ndarray:
    """Body-frame velocities ``(vx, vy, vz, wx, wy, wz)`` per frame, shape ``(N, 6)``.

    Central differences of the poses (one-sided at the ends), expressed in the frame's
    ``base_link``; exact for straights and constant turns sampled on their arc.
    """
    n = len(trajectory)
    out = np.zeros((n, 6))
    if n < 2:
        return out
    for i in range(n):
        a, b = max(i - 1, 0), min(i + 1, n - 1)
        rel = invert(trajectory.poses[a]) @ trajectory.poses[b]
        dt = trajectory.stamps[b] - trajectory.stamps[a]
        # The velocity at i, rotated from frame a into frame i.
        R_ai = invert(trajectory.poses[a])[:3, :3] @ trajectory.poses[i][:3, :3]
        v = R_ai.T @ rel[:3, 3] / dt
        out[i, :3] = v
        out[i, 5] = float(yaw_of(rel[:3, :3])) / dt
    return out


@dataclass(frozen=True)
class DriveFrame:
    """One rendered frame of a drive.

    Attributes:
        stamp: seconds. image: 8-bit grey ``(H, W)``. pose: ``T_odom_base`` (4x4).
        twist: body velocity ``(vx, vy, vz, wx, wy, wz)``.
    """

    stamp: float
    image: np.ndarray
    pose: np.ndarray
    twist: np.ndarray


def render_drive(trajectory: Trajectory, world: StreetWorld, camera: CameraModel,
                 T_base_camera: np.ndarray) -> Iterator[DriveFrame]:
    """Render every frame of ``trajectory`` through ``camera`` mounted by ``T_base_camera``."""
    twists = body_twists(trajectory)
    for stamp, pose, twist in zip(trajectory.stamps, trajectory.poses, twists):
        frame = render(world, camera, pose @ T_base_camera)
        yield DriveFrame(float(stamp), frame.image, pose, twist)
