"""Online calibration of what a user may not know: the camera's tilt on the vehicle (pitch and
roll relative to the plane of motion), the road's normal in the camera frame (for the
ground-plane scale), and the focal length (1ACf self-calibration)."""

from __future__ import annotations

from planar_vo.pipeline.calibration.focal import (
    OnlineFocalCalibrator,
    TurnPairSelector,
    prior_sigma_for_fov,
)
from planar_vo.pipeline.calibration.road import RoadNormalCalibrator, pair_road_normal
from planar_vo.pipeline.calibration.tilt import MountTiltEstimator, TiltEstimate, focal_pitch

__all__ = [
    'MountTiltEstimator',
    'OnlineFocalCalibrator',
    'RoadNormalCalibrator',
    'TiltEstimate',
    'TurnPairSelector',
    'focal_pitch',
    'pair_road_normal',
    'prior_sigma_for_fov',
]
