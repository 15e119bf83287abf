"""What the robust estimators return, and their shared input checks."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planar_vo.core.checks import as_array, same_length
from planar_vo.core.robust.options import VotingConfig
from planar_vo.core.solvers import _check_ac
from planar_vo.errors import ConfigError, InputError

__all__ = ['PlanarMotion', 'VotingStats', 'check_clusters', 'check_config', 'check_inputs',
           'failed_estimate']


@dataclass(frozen=True)
class PlanarMotion:
    """A planar motion estimate (``X2 = Ry(alpha) X1 + t``, ``t = [cos beta, 0, sin beta]``).

    Attributes:
        alpha, beta: radians, in ``(-pi, pi]``; NaN when nothing could be estimated.
        focal: focal length in pixels for the focal variant, else NaN.
    """

    alpha: float
    beta: float
    focal: float = float('nan')


@dataclass(frozen=True)
class VotingStats:
    """What the estimator saw, for callers that must judge the estimate.

    Attributes:
        inliers: bool mask over the input ACs, shape ``(N,)``.
        num_inliers: ``inliers.sum()``.
        num_candidates: ACs that gave a finite candidate.
        peak_sharpness: fraction of the total vote weight inside the alpha peak's window (1 for
            perfectly consistent data, small for noise).
        ambiguity: height of the best separate alpha peak relative to the winner, in ``[0, 1]``.
        residual_rms: RMS of the whitened constraint residuals over the inliers.
        covariance: 2x2 covariance of ``(alpha, beta)`` in rad^2 (infinite when unreliable).
        reliable: the estimate can be used.
        flag: why not, when not reliable: ``'too_few_candidates'``, ``'too_few_inliers'``,
            ``'unstable'`` (the refinement left the voted peak), ``'ambiguous'`` (a second
            alpha peak nearly as high, or another basin of the cost nearly as low),
            ``'weak_peak'`` or ``'no_parallax'`` (the points moved by the rotation alone: a
            camera that did not move or only turned, whose heading beta is not observed).
        point_scale, affine_scale: robust noise scales of the epipolar (normalised
            coordinates) and affine residuals.
        iterations: RANSAC iterations (0 for voting).
        focal_std: standard deviation of the focal length (pixels; focal variant only).
    """

    inliers: np.ndarray
    num_inliers: int
    num_candidates: int
    peak_sharpness: float
    ambiguity: float
    residual_rms: float
    covariance: np.ndarray
    reliable: bool
    flag: str | None = None
    point_scale: float = float('nan')
    affine_scale: float = float('nan')
    iterations: int = 0
    focal_std: float = float('nan')


_DEFAULT_CONFIG = VotingConfig()        # frozen: one instance serves every call without a config


def check_inputs(q1, q2, A, weights, config):
    """Checked ``q1, q2, A``, weights (ones when None) and config (defaults when None)."""
    q1, q2, A = _check_ac('q1', q1, 'q2', q2, A)
    n = q1.shape[0]
    if weights is None:
        w = np.ones(n)
    else:
        w = as_array('weights', weights, (None,))
        same_length(q1=q1, weights=w)
        if np.any(w < 0):
            raise InputError(f'weights: expected non-negative values, got minimum {w.min()}')
    return q1, q2, A, w, check_config(config)


def check_config(config) -> VotingConfig:
    """``config``, or the defaults when None; a `ConfigError` when it is not a `VotingConfig`."""
    config = _DEFAULT_CONFIG if config is None else config
    if not isinstance(config, VotingConfig):
        raise ConfigError(f'config: expected VotingConfig, got {type(config).__name__}')
    return config


def check_clusters(clusters, n: int) -> np.ndarray | None:
    """Checked cluster labels for ``n`` ACs, or None when not given.

    Labels only say which ACs belong together, so ids of ``n`` or more are renumbered
    ``0..K-1`` (order kept): the per-cluster sums (``np.bincount``) then stay of size at most
    ``n`` whatever the ids (a label of ``2**62`` would otherwise allocate exabytes).

    Raises:
        InputError: not an integer array of shape ``(n,)``, or a negative label.
    """
    if clusters is None:
        return None
    try:
        labels = np.asarray(clusters)
    except (TypeError, ValueError):
        labels = np.asarray(None)
    if labels.shape != (n,) or not np.issubdtype(labels.dtype, np.integer) \
            or (labels.size and labels.min() < 0):
        raise InputError(f'clusters: expected non-negative integers of shape ({n},), got '
                         f'{labels.dtype} {labels.shape}')
    if labels.size and labels.max() >= n:
        labels = np.unique(labels, return_inverse=True)[1].reshape(n)
    return labels


def failed_estimate(n: int, flag: str, candidates: int = 0, sharpness: float = 0.0,
                    ambiguity: float = 0.0) -> tuple[PlanarMotion, VotingStats]:
    return (PlanarMotion(float('nan'), float('nan')),
            VotingStats(np.zeros(n, bool), 0, candidates, sharpness, ambiguity, float('nan'),
                        np.full((2, 2), np.inf), False, flag))
