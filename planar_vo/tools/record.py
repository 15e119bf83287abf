"""Record a rendered drive (`planar_vo.sim`) as a ROS 2 bag with exact ground truth.

The bag has the topics of `planar_vo.io.camera_bag` (images, camera info,
``/ground_truth/odom`` and a ``/speed`` TwistStamped), so replay, the node and ``evo`` see a
rendered drive exactly as they would see a recorded one.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

from planar_vo.config import MountConfig
from planar_vo.core.camera import CameraModel
from planar_vo.core.conventions import mount_transform
from planar_vo.io.camera_bag import DEFAULT_START, CameraBagWriter
from planar_vo.ros.messages import seconds_to_ns

__all__ = ['RecordSummary', 'record_drive']


@dataclass(frozen=True)
class RecordSummary:
    """What `record_drive` wrote: path, frame count, camera, duration (s), distance (m)."""

    path: Path
    frames: int
    camera: CameraModel
    duration: float
    distance: float


def record_drive(out_path: str | Path, trajectory, *, camera: CameraModel,
                 mount: MountConfig | None = None, seed: int = 0, storage: str = 'mcap',
                 start: float = float(DEFAULT_START), progress: bool = False,
                 world=None) -> RecordSummary:
    """Render ``trajectory`` in a street world and write it as a bag (never overwrites).

    Args:
        out_path: bag directory to create.
        trajectory: a `planar_vo.core.Trajectory` (vehicle poses and stamps).
        camera: the camera model (its distortion is rendered and written to CameraInfo).
        mount: where the camera sits on the vehicle (default `MountConfig()`).
        seed: seed of the street world (ignored when ``world`` is given).
        storage: ``'mcap'`` or ``'sqlite3'``.
        start: seconds added to the trajectory's stamps.
        progress: progress bar on stderr.
        world: a `planar_vo.sim.StreetWorld` (default: built along the trajectory).
    """
    import numpy as np
    from tqdm import tqdm

    from planar_vo.sim import StreetWorld
    from planar_vo.sim.drive import render_drive

    mount = MountConfig() if mount is None else mount
    world = StreetWorld.along(trajectory, seed=seed) if world is None else world
    T_bc = mount_transform(mount.x, mount.y, mount.height, mount.roll, mount.pitch, mount.yaw)
    frames = render_drive(trajectory, world, camera, T_bc)
    with CameraBagWriter(out_path, storage=storage, ground_truth=True, speed=True) as writer:
        for frame in tqdm(frames, total=len(trajectory), desc='render', unit='frame',
                          file=sys.stderr, disable=not progress, leave=False):
            writer.write_frame(seconds_to_ns(start + frame.stamp), frame.image, camera,
                               pose=frame.pose, twist=frame.twist)
    xy = trajectory.xy
    return RecordSummary(Path(out_path), len(trajectory), camera,
                         float(trajectory.stamps[-1] - trajectory.stamps[0]),
                         float(np.linalg.norm(np.diff(xy, axis=0), axis=1).sum()))
