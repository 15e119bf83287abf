"""Simulated data with exact ground truth: the paper's synthetic protocol (`synthetic`) and a
seeded, textured street world rendered through a `CameraModel` (the rest).

For front-end, pipeline and node tests and the demo drive (numpy and OpenCV only)::

    drive = straight(40.0).then(turn(np.pi / 2, radius=20.0), stop_and_go())
    world = StreetWorld.along(drive, seed=1)          # street built around the drive
    poses = drive.camera_poses(mount_transform(height=1.5))    # T_odom_camera per frame
    frame = render(world, camera, poses[k])           # .image uint8, .plane, .kind, .depth
    acs, valid = exact_acs(world, poses[k], poses[k + 1], camera, pixels)
    alpha, beta, scale = relative_planar_motion(poses[k], poses[k + 1])

- Trajectories (`trajectories`): generators of `planar_vo.core.Trajectory` (``T_odom_base``,
  REP-103); positive yaw turns left.
- World (`world`): ground ``z = 0``, building boxes along both sides, parked cars; procedural,
  non-repeating two-layer textures (`textures`).
- Rendering (`renderer`): per-pixel rays through the camera model (distortion exact),
  anisotropic trilinear mip-mapping (no aliasing on the far ground), optional lens blur.
- Ground truth (`ground_truth`): ``p2`` and ``A = dp2/dp1`` exactly (plane homography chained
  with the distortion Jacobians), with visibility; the true motion in planar_vo's convention.
  Note: under planar motion, ACs on vertical planes (facades) make the 1AC system rank 2; only
  non-vertical surfaces (the ground) determine ``(alpha, beta)`` from a single AC.
"""

from __future__ import annotations

from planar_vo.core.trajectory import Trajectory, concatenate
from planar_vo.sim.ground_truth import backproject, cast_rays, exact_acs, relative_planar_motion
from planar_vo.sim.renderer import RenderedFrame, render
from planar_vo.sim.trajectories import hard_stop, reverse, s_curve, stop_and_go, straight, turn
from planar_vo.sim.world import FACADE_KIND, GROUND_KIND, OBSTACLE_KIND, StreetWorld

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
    'hard_stop',
    'relative_planar_motion',
    'render',
    'reverse',
    's_curve',
    'stop_and_go',
    'straight',
    'turn',
]
