"""Trajectory evaluation: TUM and bag I/O, association, Umeyama alignment, ATE/RPE, plots.

numpy only, except `plots` (matplotlib, imported when a plot is drawn) and bag reading (through
`planar_vo.bag`, imported when a bag is read).
"""

from __future__ import annotations

from planar_vo.evaluation.align import Alignment, align_trajectory, umeyama
from planar_vo.evaluation.metrics import (
    Evaluation,
    evaluate,
    rpe_by_distance,
    rpe_per_frame,
    statistics,
    yaw_heading_errors,
)
from planar_vo.evaluation.plots import save_plots
from planar_vo.evaluation.trajectory import (
    Trajectory,
    associate,
    load_trajectory,
    read_bag_trajectory,
    read_tum,
    write_tum,
)

__all__ = [
    'Alignment',
    'Evaluation',
    'Trajectory',
    'align_trajectory',
    'associate',
    'evaluate',
    'load_trajectory',
    'read_bag_trajectory',
    'read_tum',
    'rpe_by_distance',
    'rpe_per_frame',
    'save_plots',
    'statistics',
    'umeyama',
    'write_tum',
    'yaw_heading_errors',
]
