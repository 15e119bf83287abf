"""Geometry of planar motion: conventions, minimal solvers and robust estimation (numpy only).

Conventions (see `planar_vo.geometry.planar`): camera optical frame x right, y down, z forward;
``X2 = Ry(alpha) X1 + t``, ``t = [cos beta, 0, sin beta]``.
"""

from __future__ import annotations

from planar_vo.geometry.minimal import (
    ac_residuals,
    planar_ac_matrix,
    solve_1ac,
    solve_1acf,
    solve_2pc,
    solve_3pc,
)
from planar_vo.geometry.voting import (
    FocalCalibrator,
    PlanarMotion,
    VotingStats,
    vote_planar_motion,
    vote_planar_motion_focal,
)
from planar_vo.geometry.planar import (
    angle_difference,
    camera_displacement,
    planar_essential,
    planar_motion_from_pose,
    rotation_y,
    translation_direction,
    wrap_angle,
)

__all__ = [
    'FocalCalibrator',
    'PlanarMotion',
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
