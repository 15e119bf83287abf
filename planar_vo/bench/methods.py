"""The methods compared in the paper benchmark, and how each produces its estimates per run.

Every run is one `planar_vo.sim.synthetic.paper_trial` (50 ACs sharing one motion). Two kinds:

- ``minimal``: the solver alone, as in the paper's Fig. 3. Each run draws ``samples`` random
  minimal samples (the first ``m`` indices of a random permutation of the 50 correspondences,
  the same permutations for every method); every sample gives one estimate. Solvers with
  several roots keep the root nearest to the truth (smallest rotation + translation error; for
  focal problems smallest focal error), the usual way of scoring minimal solvers. A sample
  without any root counts as a failure (reported as 'solved').
- ``robust``: an estimator on all 50 correspondences, once per run (no outliers in this
  protocol, so these show what using all the data buys). Its inlier threshold is
  `peer_threshold_px` of the noise level (an oracle threshold).

`estimate_1ac_voting` runs the paper's own robust estimator (1AC + histogram voting,
``planar_vo.core.vote_planar_motion``) on all 50 ACs of a run.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from planar_vo.bench import peers
from planar_vo.bench.metrics import planar_pose
from planar_vo.core import solve_1ac, solve_1acf, solve_2pc, solve_3pc
from planar_vo.sim.synthetic import SyntheticACs

__all__ = [
    'Candidates',
    'Method',
    'METHODS',
    'estimate_1ac_voting',
    'peer_threshold_px',
]


def estimate_1ac_voting(q1: np.ndarray, q2: np.ndarray, A: np.ndarray) -> tuple[float, float]:
    """'1AC + voting', the paper's robust estimator, on all ACs of one image pair.

    `planar_vo.core.vote_planar_motion` on normalised coordinates ``(N, 2)`` and affines
    ``(N, 2, 2)``; returns ``(alpha, beta)`` in radians (NaN when it found nothing). Both
    benchmarks (paper and speed) time and score '1AC + voting' through this function.
    """
    from planar_vo.core import vote_planar_motion

    motion, _ = vote_planar_motion(q1, q2, A)
    return float(motion.alpha), float(motion.beta)


def peer_threshold_px(sigma: float) -> float:
    """Inlier threshold (pixels) given to the robust peers: twice the noise, at least 0.1 px."""
    return max(2.0 * sigma, 0.1)


@dataclass(frozen=True)
class Candidates:
    """Estimates of one run: ``S`` samples with up to ``M`` roots each, NaN-padded.

    Attributes:
        R: rotations ``(S, M, 3, 3)``; t: translations ``(S, M, 3)``;
        focal: focal lengths in pixels ``(S, M)``, or None for calibrated methods.
    """

    R: np.ndarray
    t: np.ndarray
    focal: np.ndarray | None = None


@dataclass(frozen=True)
class Method:
    """A compared method.

    Attributes:
        name: label in tables and plots.
        kind: ``'minimal'`` (one estimate per random minimal sample) or ``'robust'`` (one per run).
        problem: ``'calibrated'`` (alpha, beta) or ``'focal'`` (alpha, beta and the focal length).
        sample_size: correspondences per sample (robust: all, recorded as 0).
        solve: ``(trial, samples, sigma) -> Candidates``; ``samples`` is ``(S, n)`` permutations.
        source: where the implementation comes from (for the report).
    """

    name: str
    kind: str
    problem: str
    sample_size: int
    solve: Callable[[SyntheticACs, np.ndarray, float], Candidates]
    source: str


def _one(alpha: np.ndarray, beta: np.ndarray, focal: np.ndarray | None = None) -> Candidates:
    """Candidates from per-sample planar angles ``(S,)`` or ``(S, M)``."""
    alpha, beta = np.atleast_1d(alpha), np.atleast_1d(beta)
    if alpha.ndim == 1:
        alpha, beta = alpha[:, None], beta[:, None]
        focal = None if focal is None else np.atleast_1d(focal)[:, None]
    R, t = planar_pose(alpha, beta)
    return Candidates(R, t, focal)


def _pose(est: peers.PoseEstimate, with_focal: bool = False) -> Candidates:
    return Candidates(est.R[None, None], est.t[None, None],
                      np.array([[est.focal]]) if with_focal else None)


def _1ac(refine: bool):
    def solve(trial: SyntheticACs, samples: np.ndarray, sigma: float) -> Candidates:
        i = samples[:, 0]
        n = trial.normalized.subset(i)
        return _one(*solve_1ac(n.p1, n.p2, n.A, refine=refine))
    return solve


def _1acf(trial: SyntheticACs, samples: np.ndarray, sigma: float) -> Candidates:
    i = samples[:, 0]
    c1, c2 = trial.centered
    alpha, beta, focal = solve_1acf(c1[i], c2[i], trial.acs.A[i])
    return _one(alpha, beta, focal)


def _points(solver, m: int):
    def solve(trial: SyntheticACs, samples: np.ndarray, sigma: float) -> Candidates:
        i = samples[:, :m]
        return _one(*solver(trial.normalized.p1[i], trial.normalized.p2[i]))
    return solve


def _5pc_minimal(trial: SyntheticACs, samples: np.ndarray, sigma: float) -> Candidates:
    i = samples[:, :5]
    return Candidates(*peers.solve_5pc_poselib(trial.normalized.p1[i], trial.normalized.p2[i]))


def _6pc_minimal(trial: SyntheticACs, samples: np.ndarray, sigma: float) -> Candidates:
    i = samples[:, :6]
    c1, c2 = trial.centered
    return Candidates(*peers.solve_6pc_focal_poselib(c1[i], c2[i]))


def _5pc_opencv(trial: SyntheticACs, samples: np.ndarray, sigma: float) -> Candidates:
    thr = peer_threshold_px(sigma) / trial.focal
    n = trial.normalized
    return _pose(peers.estimate_5pc_opencv(n.p1, n.p2, threshold=thr))


def _5pc_poselib(trial: SyntheticACs, samples: np.ndarray, sigma: float) -> Candidates:
    thr = peer_threshold_px(sigma) / trial.focal
    n = trial.normalized
    return _pose(peers.estimate_5pc_poselib(n.p1, n.p2, threshold=thr))


def _6pc_poselib(trial: SyntheticACs, samples: np.ndarray, sigma: float) -> Candidates:
    c1, c2 = trial.centered
    est = peers.estimate_6pc_focal_poselib(c1, c2, threshold=peer_threshold_px(sigma))
    return _pose(est, with_focal=True)


def _1ac_voting(trial: SyntheticACs, samples: np.ndarray, sigma: float) -> Candidates:
    n = trial.normalized
    return _one(*estimate_1ac_voting(n.p1, n.p2, n.A))


METHODS: tuple[Method, ...] = (
    Method('1AC', 'minimal', 'calibrated', 1, _1ac(False), 'planar_vo solve_1ac'),
    Method('1AC+LS', 'minimal', 'calibrated', 1, _1ac(True),
           'planar_vo solve_1ac(refine=True): constrained least squares of the AC\'s 3 rows'),
    Method('2PC', 'minimal', 'calibrated', 2, _points(solve_2pc, 2),
           'planar_vo solve_2pc (Choi and Kim 2018)'),
    Method('2PC (PoseLib)', 'minimal', 'calibrated', 2,
           _points(peers.solve_2pc_poselib, 2), 'PoseLib relpose_upright_planar_2pt'),
    Method('3PC', 'minimal', 'calibrated', 3, _points(solve_3pc, 3), 'planar_vo solve_3pc'),
    Method('5PC (PoseLib)', 'minimal', 'calibrated', 5, _5pc_minimal,
           'PoseLib relpose_5pt (Nister); the paper\'s 5PC'),
    Method('5PC RANSAC (OpenCV)', 'robust', 'calibrated', 0, _5pc_opencv,
           'OpenCV findEssentialMat (RANSAC, p=0.999) + recoverPose'),
    Method('5PC RANSAC (PoseLib)', 'robust', 'calibrated', 0, _5pc_poselib,
           'PoseLib estimate_relative_pose (RANSAC + LO + bundle, p=0.999)'),
    Method('1AC+voting', 'robust', 'calibrated', 0, _1ac_voting,
           'planar_vo vote_planar_motion (histogram voting + refinement)'),
    Method('1ACf', 'minimal', 'focal', 1, _1acf, 'planar_vo solve_1acf'),
    Method('6PC (PoseLib)', 'minimal', 'focal', 6, _6pc_minimal,
           'PoseLib shared_focal_relpose_6pt'),
    Method('6PC RANSAC (PoseLib)', 'robust', 'focal', 0, _6pc_poselib,
           'PoseLib estimate_shared_focal_relative_pose (p=0.999)'),
)
