"""Small robust statistics shared by the estimators and calibrators (numpy only)."""

from __future__ import annotations

import functools
import math

import numpy as np

__all__ = [
    'CHI2_3_99',
    'HALF_NORMAL_Q25',
    'MAD_TO_SIGMA',
    'few_cluster_factor',
    'lower_quantile',
    'median',
    'student_t_quantile',
    'thin',
    'weighted_median',
]

MAD_TO_SIGMA = 1.4826             # sigma / median|x| for a normal
CHI2_3_99 = 11.3449               # 99 % quantile of chi-square with 3 degrees of freedom
HALF_NORMAL_Q25 = 0.31864         # lower quartile of |N(0, 1)|

# The statistics of a vote's peak (beta votes, mean shift, noise scales) need a sample of a peak,
# not all of it: above this many items a deterministic stride subsample is used.
STAT_SAMPLE = 1500


def lower_quantile(x: np.ndarray, q: float) -> float:
    """Lower ``q``-quantile of ``x`` by partial sorting (np.quantile's interpolation costs more
    than the whole selection here)."""
    k = int(q * (x.size - 1))
    return float(np.partition(x, k)[k])


def median(x: np.ndarray) -> float:
    """``np.median`` of a 1-D array by partial sorting (np.median's overhead costs several times
    the selection at the sizes used here)."""
    k = x.size // 2
    if x.size % 2:
        return float(np.partition(x, k)[k])
    part = np.partition(x, (k - 1, k))
    return 0.5 * float(part[k - 1] + part[k])


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


def _student_t_mass(theta: float, nu: int) -> float:
    """``P(|T| <= sqrt(nu) tan(theta))`` for Student's t with integer ``nu`` degrees of freedom:
    the finite series of Abramowitz and Stegun 26.7.3 (odd ``nu``) and 26.7.4 (even ``nu``)."""
    c2 = math.cos(theta) ** 2
    if nu % 2:
        total, term = 0.0, math.cos(theta)
        for k in range(1, (nu - 1) // 2 + 1):          # cos + 2/3 cos^3 + (2 4)/(3 5) cos^5 ...
            total += term
            term *= c2 * (2 * k) / (2 * k + 1)
        return 2.0 / math.pi * (theta + math.sin(theta) * total)
    total, term = 0.0, 1.0
    for k in range(1, nu // 2 + 1):                     # 1 + 1/2 cos^2 + (1 3)/(2 4) cos^4 ...
        total += term
        term *= c2 * (2 * k - 1) / (2 * k)
    return math.sin(theta) * total


@functools.lru_cache(maxsize=256)
def student_t_quantile(p: float, nu: int) -> float:
    """Quantile of Student's t with ``nu`` (integer >= 1) degrees of freedom at ``p`` in
    ``(0, 1)``, by safeguarded Newton on the closed-form CDF (`_student_t_mass`; no scipy).
    Cached.

    In ``theta = atan(t / sqrt(nu))`` the mass has the derivative ``2 c cos(theta)^(nu - 1)``
    with ``c = Gamma((nu + 1) / 2) / (sqrt(pi) Gamma(nu / 2))``; Newton converges in a few
    steps where the bisection it replaced took 60 evaluations of the ``O(nu)`` series (a
    millisecond for each new ``nu`` of a growing cluster count). A step that leaves the
    bracket kept by the signs bisects it instead."""
    if not (0.0 < p < 1.0) or nu < 1:
        raise ValueError(f'student_t_quantile: expected 0 < p < 1 and nu >= 1, got {p}, {nu}')
    if p < 0.5:
        return -student_t_quantile(1.0 - p, nu)
    if p == 0.5:
        return 0.0                  # (the relative step test below never ends at theta = 0)
    target, lo, hi = 2.0 * p - 1.0, 0.0, 0.5 * math.pi
    log_c = math.lgamma(0.5 * (nu + 1)) - math.lgamma(0.5 * nu) - 0.5 * math.log(math.pi)
    # Start at the normal quantile (Abramowitz and Stegun 26.2.23, within 4.5e-4), which the
    # t quantile approaches from above as nu grows.
    r = math.sqrt(-2.0 * math.log(1.0 - p))
    z = r - (2.515517 + 0.802853 * r + 0.010328 * r * r) / (
        1.0 + 1.432788 * r + 0.189269 * r * r + 0.001308 * r ** 3)
    theta = math.atan(max(z, 1e-3) / math.sqrt(nu))
    for _ in range(200):
        excess = _student_t_mass(theta, nu) - target
        if excess < 0.0:
            lo = theta
        else:
            hi = theta
        slope = 2.0 * math.exp(log_c + (nu - 1) * math.log(math.cos(theta)))
        new = theta - excess / slope if slope > 0.0 else lo - 1.0
        if not lo < new < hi:
            new = 0.5 * (lo + hi)
        if abs(new - theta) <= 4.5e-16 * theta or hi - lo <= 4.5e-16 * hi:   # 2 ulp
            theta = new
            break
        theta = new
    return math.sqrt(nu) * math.tan(theta)


def few_cluster_factor(clusters: int, sigmas: float = 3.0) -> float:
    """Widening of a cluster-robust standard deviation from ``clusters`` clusters, so that
    ``sigmas`` of it cover what ``sigmas`` normal deviations would: ``t_q(G - 1) / z_q`` with
    ``q = Phi(sigmas)`` (the sandwich's variance has about ``G - 1`` degrees of freedom);
    inf below 2 clusters."""
    if clusters < 2:
        return float('inf')
    q = 0.5 * (1.0 + math.erf(sigmas / math.sqrt(2.0)))
    return student_t_quantile(q, int(clusters) - 1) / sigmas
