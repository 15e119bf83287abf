"""The geometry of planar motion, numpy only (no OpenCV, ROS or configuration files).

- `conventions`: frames (REP-103/105), rigid transforms and the planar-motion parametrisation,
  written once: camera optical frame x right, y down, z forward; ``X2 = Ry(alpha) X1 + t``,
  ``t = [cos beta, 0, sin beta]``.
- `camera`: the camera model (pinhole, ``plumb_bob``, ``rational_polynomial``,
  ``equidistant``) and normalisation;
  `homography`: plane-induced maps and their Jacobians (exact ACs).
- `correspondences`: `AffineCorrespondences`, the one AC container.
- `solvers`: the minimal solvers 1AC, 1ACf (the paper's), 2PC and 3PC.
- `robust`: voting, refinement, covariance, RANSAC, unknown focal length.
- `trajectory`: `Trajectory`, stamped poses (estimates, ground truth, rendered drives).
"""

from __future__ import annotations

from planar_vo.core.camera import CameraModel
from planar_vo.core.conventions import (
    angle_difference,
    camera_displacement,
    planar_essential,
    planar_motion_from_pose,
    rotation_y,
    translation_direction,
    wrap_angle,
)
from planar_vo.core.correspondences import AffineCorrespondences
from planar_vo.core.robust import (
    PlanarMotion,
    VotingConfig,
    VotingStats,
    vote_planar_motion,
    vote_planar_motion_focal,
)
from planar_vo.core.solvers import (
    ac_residuals,
    planar_ac_matrix,
    solve_1ac,
    solve_1acf,
    solve_2pc,
    solve_3pc,
)
from planar_vo.core.trajectory import Trajectory

__all__ = [
    'AffineCorrespondences',
    'CameraModel',
    'PlanarMotion',
    'Trajectory',
    'VotingConfig',
    'VotingStats',
    'ac_residuals',
    'angle_difference',
    'camera_displacement',
    'planar_ac_matrix',
    'planar_essential',
    'planar_motion_from_pose',
    'rotation_y',
    'solve_1ac',
    'solve_1acf',
    'solve_2pc',
    'solve_3pc',
    'translation_direction',
    'vote_planar_motion',
    'vote_planar_motion_focal',
    'wrap_angle',
]
