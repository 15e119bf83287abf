"""Affine correspondences from images, and the local maps that make them ideal.

- `extract_acs` / `ACExtractor`: ACs between two images by DIS flow + affine Lucas-Kanade
  (``'flow'``, the default), KLT tracks (``'klt'``) or ASIFT (``'asift'``, slow).
- `undistort_acs`, `level_acs`, `correct_acs`, `leveling_rotation`: move ACs to an ideal, level
  pinhole camera (``A' = J(p2) A J(p1)^-1``).
- `images`: the one place that decodes pixels (raw ROS encodings, JPEG/PNG) into 8-bit grey.

The only subpackage that uses OpenCV on images.
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

__all__ = [
    'METHODS',
    'ACExtractor',
    'correct_acs',
    'extract_acs',
    'level_acs',
    'leveling_homography',
    'leveling_rotation',
    'undistort_acs',
]
