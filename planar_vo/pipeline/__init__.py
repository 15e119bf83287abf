"""The visual-odometry pipeline: frames in, poses out, no ROS (driven by node, replay and tests)."""

from __future__ import annotations

from planar_vo.pipeline.clock import Stamp
from planar_vo.pipeline.odometry import VisualOdometry
from planar_vo.pipeline.types import DropReason, FrameResult, TrackingState

__all__ = ['DropReason', 'FrameResult', 'Stamp', 'TrackingState', 'VisualOdometry']
