"""`VotingConfig`: every option of the robust estimators, with its default (one options struct,
PoseLib style); a section of the whole configuration (`planar_vo.config`)."""

from __future__ import annotations

import dataclasses
import typing

from planar_vo.core.options import Options

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
            this.
        affine_noise: affine noise (unitless): RANSAC's level and voting's cap, as above.
        max_noise_factor: cap of the data-driven noise scales relative to the two levels above.
        covariance_grid: ACs are grouped in a grid x grid partition of the image for the
            cluster-robust covariance (neighbouring ACs share errors).
        ransac_iterations: maximum RANSAC iterations.
        ransac_confidence: RANSAC confidence for the adaptive iteration count.
        seed: random seed of RANSAC (histogram voting is deterministic).
    """

    method: typing.Literal['histogram', 'ransac'] = 'histogram'
    bins: int = 720
    kernel_bins: float = 1.5
    refine_candidates: bool = False
    inlier_chi2: float = 11.34
    min_inliers: int = 20
    ambiguity_ratio: float = 0.8
    min_sharpness: float = 0.05
    refine: bool = True
    point_noise: float = 1e-3
    affine_noise: float = 0.02
    max_noise_factor: float = 5.0
    covariance_grid: int = 6
    ransac_iterations: int = 500
    ransac_confidence: float = 0.999
    seed: int = 0

    def validate(self) -> None:
        self._require(self.bins >= 36, 'bins', 'at least 36')
        self._require(self.kernel_bins > 0.0, 'kernel_bins', 'a positive width in bins')
        self._require(self.inlier_chi2 > 0.0, 'inlier_chi2', 'a positive number')
        self._require(self.min_inliers >= 1, 'min_inliers', 'at least 1')
        self._require(0.0 < self.ambiguity_ratio <= 1.0, 'ambiguity_ratio', 'in (0, 1]')
        self._require(0.0 <= self.min_sharpness < 1.0, 'min_sharpness', 'in [0, 1)')
        self._require(self.point_noise > 0.0, 'point_noise', 'a positive number')
        self._require(self.affine_noise > 0.0, 'affine_noise', 'a positive number')
        self._require(self.max_noise_factor >= 1.0, 'max_noise_factor', 'at least 1')
        self._require(self.covariance_grid >= 1, 'covariance_grid', 'at least 1')
        self._require(self.ransac_iterations >= 1, 'ransac_iterations', 'at least 1')
        self._require(0.0 < self.ransac_confidence < 1.0, 'ransac_confidence', 'in (0, 1)')


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
    cauchy: float = 2.5
    rounds: int = 8
    min_inliers: int = 30
    min_inlier_share: float = 0.1
    max_yaw_std: float = 0.0035
    ambiguity_ratio: float = 0.8
    history: int = 100
    max_correspondences: int = 0

    def validate(self) -> None:
        self._require(self.cauchy > 0.0, 'cauchy', 'a positive number')
        self._require(1 <= self.rounds <= 100, 'rounds', 'between 1 and 100')
        self._require(self.min_inliers >= 5, 'min_inliers', 'at least 5')
        self._require(0.0 <= self.min_inlier_share < 1.0, 'min_inlier_share', 'in [0, 1)')
        self._require(self.max_yaw_std > 0.0, 'max_yaw_std', 'a positive angle (rad)')
        self._require(0.0 < self.ambiguity_ratio <= 1.0, 'ambiguity_ratio', 'in (0, 1]')
        self._require(10 <= self.history <= 100000, 'history', 'between 10 and 100000 frames')
        self._require(self.max_correspondences == 0 or self.max_correspondences >= 50,
                      'max_correspondences', '0 (all) or at least 50')
