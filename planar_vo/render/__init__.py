"""A seeded, textured street world rendered through a `CameraModel`, with exact ground truth.

Used by front-end, pipeline and node tests and by the demo drive:

    traj = straight(40.0).then(turn(np.pi / 2, radius=20.0), stop_and_go())
    world = StreetWorld.along(traj, seed=1)
    poses = traj.camera_poses(mount_transform(height=1.5))
    frame = render(world, camera, poses[0])                  # frame.image, .plane, .depth
    acs, valid = exact_acs(world, poses[0], poses[1], camera, pixels)
    alpha, beta, scale = relative_planar_motion(poses[0], poses[1])
"""

from __future__ import annotations

from planar_vo.render.ground_truth import (
    backproject,
    cast_rays,
    exact_acs,
    relative_planar_motion,
)
from planar_vo.render.renderer import RenderedFrame, render
from planar_vo.render.trajectory import (
    Trajectory,
    concatenate,
    reverse,
    s_curve,
    stop_and_go,
    straight,
    turn,
)
from planar_vo.render.world import FACADE_KIND, GROUND_KIND, OBSTACLE_KIND, StreetWorld

__all__ = [
    'FACADE_KIND',
    'GROUND_KIND',
    'OBSTACLE_KIND',
    'RenderedFrame',
    'StreetWorld',
    'Trajectory',
    'backproject',
    'cast_rays',
    'concatenate',
    'exact_acs',
    'relative_planar_motion',
    'render',
    'reverse',
    's_curve',
    'stop_and_go',
    'straight',
    'turn',
]
