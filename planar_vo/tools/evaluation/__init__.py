"""Trajectory evaluation: association, alignment, ATE/RPE and yaw errors, plots, reports.

The metrics (`align`, `metrics`) are numpy only and take `planar_vo.core.Trajectory` objects;
file I/O is separate: `files` (TUM files and pose topics of bags, through `planar_vo.io`),
`plots` (matplotlib, imported when a plot is drawn) and `report` (``metrics.json`` and PNGs).
"""

from __future__ import annotations

from planar_vo.tools.evaluation.align import Alignment, align_trajectory, umeyama
from planar_vo.tools.evaluation.files import (
    associate,
    load_trajectory,
    read_bag_odometry,
    read_bag_trajectory,
    read_tum,
    write_tum,
)
from planar_vo.tools.evaluation.metrics import (
    Evaluation,
    covariance_consistency,
    evaluate,
    flatten_se2,
    kitti_drift,
    rpe_by_distance,
    rpe_per_frame,
    statistics,
    yaw_heading_errors,
)
from planar_vo.tools.evaluation.plots import save_plots
from planar_vo.tools.evaluation.report import write_report

__all__ = [
    'Alignment',
    'Evaluation',
    'align_trajectory',
    'associate',
    'covariance_consistency',
    'evaluate',
    'flatten_se2',
    'kitti_drift',
    'load_trajectory',
    'read_bag_odometry',
    'read_bag_trajectory',
    'read_tum',
    'rpe_by_distance',
    'rpe_per_frame',
    'save_plots',
    'statistics',
    'umeyama',
    'write_report',
    'write_tum',
    'yaw_heading_errors',
]
