"""Weighted voting on the circle: kernel-smoothed histograms, their peaks, mean shift.

One AC gives one candidate angle, so the robust estimate of an angle is the mode of the weighted
candidates (Hajder and Barath, section 3.4; Bujnak et al. 2009 for weighted voting): a histogram
over the full circle, circularly smoothed by a Gaussian kernel, its highest bin refined below bin
resolution by mean shift, and the best separate peak reported as an ambiguity.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from planar_vo.core.conventions import wrap_angle
from planar_vo.core.robust.options import VotingConfig
from planar_vo.core.robust.stats import thin

__all__ = ['TWO_PI', 'circular_kernel', 'peak', 'wrap']

TWO_PI = 2.0 * np.pi


def wrap(x: np.ndarray) -> np.ndarray:
    """Angles to ``[-pi, pi)`` (the cheap form for internal use)."""
    return np.remainder(x + np.pi, TWO_PI) - np.pi


@functools.lru_cache(maxsize=16)
def circular_kernel(bins: int, sigma_bins: float) -> np.ndarray:
    """Normalised Gaussian kernel of standard deviation ``sigma_bins`` bins, cut at 3 sigma (at
    most half the circle); cached and read-only."""
    half = max(1, int(math.ceil(3.0 * sigma_bins)))
    half = min(half, bins // 2 - 1)
    x = np.arange(-half, half + 1, dtype=np.float64)
    k = np.exp(-0.5 * (x / sigma_bins) ** 2)
    k /= k.sum()
    k.flags.writeable = False
    return k


def _smoothed_histogram(angles: np.ndarray, weights: np.ndarray, bins: int,
                        kernel: np.ndarray) -> np.ndarray:
    """Histogram of angles on the circle (``bins`` bins over 2 pi), circularly smoothed."""
    idx = np.floor((angles + np.pi) * (bins / TWO_PI)).astype(np.intp) % bins
    hist = np.bincount(idx, weights=weights, minlength=bins)
    half = kernel.size // 2
    padded = np.concatenate([hist[-half:], hist, hist[:half]])
    return np.convolve(padded, kernel, mode='valid')


def _bin_center(i: int, bins: int) -> float:
    return (i + 0.5) * TWO_PI / bins - np.pi


def _mean_shift(angles: np.ndarray, weights: np.ndarray, start: float, bandwidth: float,
                iterations: int = 6) -> tuple[float, np.ndarray]:
    """Mode of the weighted angle density near ``start`` (Gaussian kernel, circular), and every
    angle's offset from it on the circle (``(N,)``; within about ``pi`` of the mode)."""
    # Work on offsets from the start inside a window (the kernel is negligible beyond it).
    offsets = np.remainder(angles - start + np.pi, TWO_PI) - np.pi
    near = thin(np.flatnonzero(np.abs(offsets) <= 4.0 * bandwidth))
    d0, weights = offsets[near], weights[near]
    offset = 0.0
    for _ in range(iterations):
        d = d0 - offset
        k = weights * np.exp(-0.5 * (d / bandwidth) ** 2)
        total = float(k.sum())
        if total <= 0.0:
            break
        step = float(k @ d) / total
        offset += step
        if abs(step) < 1e-10:
            break
    # The mode moved by a few bandwidths at most, so offsets near the mode need no re-wrapping.
    offsets -= offset
    return float(wrap_angle(start + offset)), offsets


def peak(angles: np.ndarray, weights: np.ndarray, config: VotingConfig,
         exclusion: float) -> tuple[float, float, float, float, np.ndarray]:
    """Voted mode of circular ``angles``.

    Returns:
        ``(mode, sharpness, ambiguity, bandwidth, offsets)``: the mean-shift mode, the fraction
        of the weight within the peak window (3 bandwidths), the best separate peak (more than
        ``exclusion`` radians away) relative to the winner, the mean-shift bandwidth used, and
        each angle's signed offset from the mode (exact near the mode; used to select the
        peak's members).
    """
    bins = config.bins
    kernel = circular_kernel(bins, config.kernel_bins)
    hist = _smoothed_histogram(angles, weights, bins, kernel)
    i = int(np.argmax(hist))
    top = hist[i]
    start = _bin_center(i, bins)
    # Second peak: the best local maximum of the histogram outside the exclusion zone.
    reach = int(math.ceil(exclusion * bins / TWO_PI))
    ring = np.concatenate([hist[-1:], hist, hist[:1]])          # neighbours on the circle
    local_max = (hist >= ring[:-2]) & (hist >= ring[2:])
    local_max[np.arange(i - reach, i + reach + 1) % bins] = False
    ambiguity = float(hist[local_max].max() / top) if local_max.any() and top > 0 else 0.0
    bandwidth = config.kernel_bins * TWO_PI / bins
    mode, offsets = _mean_shift(angles, weights, start, 2.0 * bandwidth)
    total = weights.sum()
    sharpness = (float(weights[np.abs(offsets) <= 3.0 * bandwidth].sum() / total) if total > 0
                 else 0.0)
    return mode, sharpness, ambiguity, bandwidth, offsets
