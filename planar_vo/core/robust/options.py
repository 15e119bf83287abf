"""`VotingConfig`: every option of the robust estimators, with its default (one options struct,
PoseLib style); a section of the whole configuration (`planar_vo.config`)."""

from __future__ import annotations

import dataclasses
import typing

from planar_vo.core.options import Options, bounded

__all__ = ['EstimatorConfig', 'VotingConfig']


@dataclasses.dataclass(frozen=True)
class VotingConfig(Options):
    """Robust estimation of ``(alpha, beta)`` from per-AC candidates.

    Attributes:
        method: ``'histogram'`` (weighted kernel voting; deterministic, linear time) or
            ``'ransac'`` (1AC-RANSAC with local optimisation, for comparison).
        bins: histogram bins over the full circle for each angle.
        kernel_bins: standard deviation of the voting kernel, in bins.
        refine_candidates: refine each AC's candidate by constrained least squares before voting.
        inlier_chi2: inlier threshold on the sum of the three squared whitened AC residuals
            (chi-square with 3 degrees of freedom; 11.34 is its 99% quantile).
        min_inliers: fewer inliers than this flags the estimate as unreliable.
        ambiguity_ratio: a separate alpha peak at least this high relative to the winner flags
            the estimate as ambiguous.
        min_sharpness: minimum fraction of the vote weight in the winning alpha peak.
        refine: least-squares refinement of ``(alpha, beta)`` on all inliers' constraints.
        point_noise: point noise in normalised units (pixels / focal length): RANSAC's noise
            level; voting estimates the noise from the data, capped at ``max_noise_factor`` times
            this; the general estimator never flags noise scales up to this as implausible.
        affine_noise: affine noise (unitless): RANSAC's level, voting's cap and the estimator's
            floor, as above.
        max_noise_factor: cap of the data-driven noise scales relative to the two levels above.
        covariance_grid: ACs are grouped in a grid x grid partition of the image for the
            cluster-robust covariance (neighbouring ACs share errors).
        ransac_iterations: maximum RANSAC iterations.
        ransac_confidence: RANSAC confidence for the adaptive iteration count.
        seed: random seed of RANSAC (histogram voting is deterministic).
    """

    method: typing.Literal['histogram', 'ransac'] = 'histogram'
    # Bounds beyond any use keep memory bounded (a histogram, a grid of cells, RANSAC batches).
    bins: int = bounded(720, 36, 100000)
    kernel_bins: float = bounded(1.5, 0.0, 1000.0, low_open=True)
    refine_candidates: bool = False
    inlier_chi2: float = bounded(11.34, 0.0, 1e6, low_open=True)
    min_inliers: int = bounded(20, 1, 1000000)
    ambiguity_ratio: float = bounded(0.8, 0.0, 1.0, low_open=True)
    min_sharpness: float = bounded(0.05, 0.0, 1.0, high_open=True)
    refine: bool = True
    point_noise: float = bounded(1e-3, 0.0, 1.0, low_open=True)
    affine_noise: float = bounded(0.02, 0.0, 10.0, low_open=True)
    max_noise_factor: float = bounded(5.0, 1.0, 1e6)
    covariance_grid: int = bounded(6, 1, 1000)
    ransac_iterations: int = bounded(500, 1, 10000000)
    ransac_confidence: float = bounded(0.999, 0.0, 1.0, low_open=True, high_open=True)
    seed: int = bounded(0, 0, 2 ** 32 - 1)


@dataclasses.dataclass(frozen=True)
class EstimatorConfig(Options):
    """The general-motion estimator: planar voting in front, a general relative pose out.

    Attributes:
        model: ``'general'`` (the 1AC vote, then a 5-DoF relative pose refined on all three
            constraints of every AC, the planar motion a soft prior; for real roads) or
            ``'planar'`` (the vote's planar motion itself, the paper's estimator; for exactly
            planar motion).
        use_prior: apply the planar prior (pitch, roll and elevation of travel of the level
            camera near the recent motions' robust centre, with their measured spread).
        cauchy: Cauchy scale of the whitened residuals of the refinement.
        rounds: at most this many inlier re-selection rounds of the refinement.
        min_inliers: fewer inliers flag the frame (too_few_inliers).
        min_inlier_share: a smaller share of the AC weight among the inliers flags the frame.
        max_yaw_std: a larger yaw standard deviation (rad) flags the frame (imprecise).
        ambiguity_ratio: a different answer with at least this share of the winner's support
            flags the frame (ambiguous).
        history: frames of recent motions behind the prior, the noise scales and the typical
            inlier share (all measured online).
        max_correspondences: the refinement uses at most this many ACs, evenly picked (its
            cost grows with them, its accuracy barely beyond a few hundred); 0 uses all.
    """

    model: typing.Literal['general', 'planar'] = 'general'
    use_prior: bool = True
    cauchy: float = bounded(2.5, 0.0, 1e3, low_open=True)
    rounds: int = bounded(8, 1, 100)
    min_inliers: int = bounded(30, 5, 1000000)
    min_inlier_share: float = bounded(0.1, 0.0, 1.0, high_open=True)
    max_yaw_std: float = bounded(0.0035, 0.0, 3.2, low_open=True, expected='a positive angle (rad)')
    ambiguity_ratio: float = bounded(0.8, 0.0, 1.0, low_open=True)
    history: int = bounded(100, 10, 100000, expected='between 10 and 100000 frames')
    max_correspondences: int = bounded(0, 0, 1000000)

    def validate(self) -> None:
        self._require(self.max_correspondences == 0 or self.max_correspondences >= 50,
                      'max_correspondences', '0 (all) or at least 50')
