"""Affine correspondences from images, and the local maps that make them ideal.

- `extract_acs` / `ACExtractor`: ACs between two images by DIS flow + affine Lucas-Kanade
  (``'flow'``, the default), KLT tracks (``'klt'``) or ASIFT (``'asift'``, slow).
- `undistort_acs`, `level_acs`, `correct_acs`: move ACs to an ideal, level pinhole camera
  (``A' = J(p2) A J(p1)^-1``).
- `MountTiltEstimator`: the camera's pitch and roll relative to the plane of motion, from many
  frame pairs.
"""

from __future__ import annotations

from planar_vo.frontend.correction import (
    correct_acs,
    level_acs,
    leveling_homography,
    leveling_rotation,
    undistort_acs,
)
from planar_vo.frontend.extract import METHODS, ACExtractor, extract_acs
from planar_vo.frontend.tilt import MountTiltEstimator, TiltEstimate

__all__ = [
    'METHODS',
    'ACExtractor',
    'MountTiltEstimator',
    'TiltEstimate',
    'correct_acs',
    'extract_acs',
    'level_acs',
    'leveling_homography',
    'leveling_rotation',
    'undistort_acs',
]
