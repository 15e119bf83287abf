"""`VotingConfig`: every option of the robust estimators, with its default (one options struct,
PoseLib style); a section of the whole configuration (`planar_vo.config`)."""

from __future__ import annotations

import dataclasses
import typing

from planar_vo.core.options import Options

__all__ = ['VotingConfig']


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
