"""Small robust statistics shared by the estimators and calibrators (numpy only)."""

from __future__ import annotations

import numpy as np

__all__ = ['MAD_TO_SIGMA', 'HALF_NORMAL_Q25', 'lower_quantile', 'thin', 'weighted_median']

MAD_TO_SIGMA = 1.4826             # sigma / median|x| for a normal
HALF_NORMAL_Q25 = 0.31864         # lower quartile of |N(0, 1)|

# The statistics of a vote's peak (beta votes, mean shift, noise scales) need a sample of a peak,
# not all of it: above this many items a deterministic stride subsample is used.
STAT_SAMPLE = 1500


def lower_quantile(x: np.ndarray, q: float) -> float:
    """Lower ``q``-quantile of ``x`` by partial sorting (np.quantile's interpolation costs more
    than the whole selection here)."""
    k = int(q * (x.size - 1))
    return float(np.partition(x, k)[k])


def thin(idx: np.ndarray, limit: int = STAT_SAMPLE) -> np.ndarray:
    """Every k-th entry of ``idx`` so that at most about ``limit`` remain (deterministic)."""
    step = -(-idx.size // limit)
    return idx if step <= 1 else idx[::step]


def weighted_median(x: np.ndarray, w: np.ndarray) -> float:
    """The weighted median of ``x`` (``(N,)``) with non-negative weights ``w`` (``(N,)``): the
    smallest value at which the cumulative weight reaches half the total."""
    order = np.argsort(x)
    c = np.cumsum(w[order])
    return float(x[order][np.searchsorted(c, 0.5 * c[-1])])
