"""Online focal-length self-calibration from many frame pairs (1ACf voting per pair)."""

from __future__ import annotations

import math

import numpy as np

from planar_vo.core.robust import VotingConfig, vote_planar_motion_focal
from planar_vo.core.robust.stats import MAD_TO_SIGMA, weighted_median
from planar_vo.errors import ConfigError

__all__ = ['FocalCalibrator']


class FocalCalibrator:
    """Online focal-length self-calibration from many frames (1ACf voting per frame).

    Every frame pair goes through `vote_planar_motion_focal`; a frame that does not reveal the
    focal length (straight driving: flagged ``'focal_unobservable'``, or unreliable) contributes
    nothing. Informative frames contribute their focal length with its standard deviation. The
    running estimate is the inverse-variance weighted median of the frames' focal lengths (robust
    to an occasional bad frame); its standard deviation is the larger of the combined
    inverse-variance one and the weighted spread between frames over ``sqrt(frames)``.

    Args:
        focal_range: plausible focal lengths in pixels.
        config: `VotingConfig` for the per-frame estimates.
    """

    def __init__(self, focal_range: tuple[float, float] = (50.0, 20000.0),
                 config: VotingConfig | None = None) -> None:
        if not (0.0 < focal_range[0] < focal_range[1]):
            raise ConfigError(f'focal_range: expected 0 < min < max, got {focal_range}')
        self.focal_range = (float(focal_range[0]), float(focal_range[1]))
        self.config = VotingConfig() if config is None else config
        self._focal: list[float] = []
        self._std: list[float] = []
        self.frames_seen = 0

    def add(self, p1: np.ndarray, p2: np.ndarray, A: np.ndarray,
            weights: np.ndarray | None = None) -> bool:
        """Add one frame pair's ACs (pixels relative to the principal point; A in pixels).

        Returns whether the frame was informative (it revealed the focal length).
        """
        self.frames_seen += 1
        if len(p1) < self.config.min_inliers:
            return False                    # nothing to learn from this pair
        motion, stats = vote_planar_motion_focal(p1, p2, A, weights, self.config,
                                                 focal_range=self.focal_range)
        if not stats.reliable or not math.isfinite(stats.focal_std):
            return False
        self._focal.append(motion.focal)
        self._std.append(stats.focal_std)
        return True

    @property
    def informative_frames(self) -> int:
        return len(self._focal)

    @property
    def estimate(self) -> float:
        """Current focal length in pixels (NaN before the first informative frame)."""
        if not self._focal:
            return float('nan')
        f, s = np.array(self._focal), np.array(self._std)
        return weighted_median(f, 1.0 / np.maximum(s, 1e-9) ** 2)

    @property
    def std(self) -> float:
        """Standard deviation of `estimate` in pixels (inf before the first informative frame)."""
        if not self._focal:
            return float('inf')
        f, s = np.array(self._focal), np.array(self._std)
        w = 1.0 / np.maximum(s, 1e-9) ** 2
        combined = 1.0 / math.sqrt(float(w.sum()))
        if f.size < 3:
            return combined
        m = weighted_median(f, w)
        spread = MAD_TO_SIGMA * weighted_median(np.abs(f - m), w) / math.sqrt(f.size)
        return max(combined, spread)
