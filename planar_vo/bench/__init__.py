"""Benchmarks behind ``planar_vo bench ...``, and the peers they compare against. Never imported
by the runtime (the pipeline and the node).

One module per benchmark (``paper``, ``speed``, ``frontend``, ``pipeline``, ``drives``,
``solvers``), each with ``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``, registered
in `planar_vo.cli.bench.BENCHES`. Shared pieces: `peers` (OpenCV and PoseLib estimators in
planar_vo's conventions), `odometry` (the peers' frame-to-frame odometry on real frames),
`metrics` (the paper's error measures), `methods` (the compared methods, '1AC + voting' among
them), `common` (reports, figures, dependencies). Optional
dependencies: ``pip install 'planar_vo[bench]'`` (poselib, matplotlib).
"""

from __future__ import annotations

from planar_vo.bench.common import BenchDependencyError
from planar_vo.bench.methods import METHODS, estimate_1ac_voting
from planar_vo.bench.metrics import (
    focal_error,
    rotation_error_deg,
    translation_error_deg,
)

__all__ = [
    'METHODS',
    'BenchDependencyError',
    'estimate_1ac_voting',
    'focal_error',
    'rotation_error_deg',
    'translation_error_deg',
]
