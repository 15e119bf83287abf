"""Robust planar motion from many affine correspondences (numpy only).

- `vote_planar_motion`: every AC's 1AC candidate votes (`histogram`), inliers by all three AC
  constraints, least-squares refinement and a cluster-robust covariance (`refine`); RANSAC
  behind ``VotingConfig(method='ransac')`` for comparison (`ransac`).
- `vote_planar_motion_focal`: the same with an unknown common focal length (1ACf; `focal`);
  `pair_profile` / `combine_profiles`: a pair's profile cost over trial focal lengths and the
  minimiser of many pairs' (self-calibration over a drive); `shifted_profile`: a profile with
  the principal point moved, to first order.
- `VotingConfig`: every option of these estimators with its default (`options`).
"""

from __future__ import annotations

from planar_vo.core.robust.focal import (
    PairProfile,
    combine_profiles,
    pair_profile,
    shifted_profile,
    vote_planar_motion_focal,
)
from planar_vo.core.robust.options import VotingConfig
from planar_vo.core.robust.types import PlanarMotion, VotingStats
from planar_vo.core.robust.vote import vote_planar_motion

__all__ = [
    'PairProfile',
    'PlanarMotion',
    'VotingConfig',
    'VotingStats',
    'combine_profiles',
    'pair_profile',
    'shifted_profile',
    'vote_planar_motion',
    'vote_planar_motion_focal',
]
