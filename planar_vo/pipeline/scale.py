"""Metric scale for monocular motion.

A single camera observes the direction of translation only. Sources of the step length ``s``:

- `SpeedIntegrator`: a speed topic (wheel odometry, ``TwistStamped``) integrated over the
  interval between two frames, in memory bounded by a sample count (stops of any length);
- `road_scale`: road ACs at the known camera height ``h`` for a general relative motion
  ``(R, t)`` and an explicit road normal ``n`` in the camera frame (no levelling, no planar
  assumption), with a standard deviation that includes what all road ACs of a frame share
  (the relative rotation's pitch and roll, the road normal); the normal comes from
  `planar_vo.pipeline.calibration.RoadNormalCalibrator`;
- a fixed speed, or unit steps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planar_vo.config.sections import ScaleConfig
from planar_vo.core.checks import as_array, as_rotation, same_length
from planar_vo.core.conventions import (
    normal_tilt_jacobian,
    tilt_from_normal,
)
from planar_vo.core.robust.stats import MAD_TO_SIGMA, median, weighted_median
from planar_vo.core.robust.types import check_clusters
from planar_vo.errors import ConfigError, InputError

__all__ = [
    'RoadScale',
    'SpeedIntegrator',
    'road_rays',
    'road_scale',
    'step_factors',
]


class SpeedIntegrator:
    """Distance travelled between two times from speed samples (piecewise-linear speed).

    The samples are kept as knots ``(t_i, v_i, D_i)`` with ``D_i`` the distance travelled up to
    ``t_i`` (trapezoids), so a distance is ``D(t1) - D(t0)``. Memory is bounded by a number of
    knots, not by time: when ``max_samples`` are stored, the knots whose removal changes
    ``D(t)`` least are merged away (a quarter of them at once, so adding stays O(1) amortised).
    ``D`` at the kept knots stays exact; inside a merged interval ``D(t)`` follows the linear
    speed between its ends, scaled to the exact distance, and the interval remembers the error
    this introduced. A stop (speed 0 for minutes) or steady cruising merges at no error at all,
    so a query from a keyframe stamped before a stop of any length is still answered.

    Args:
        max_gap: longest interval (s) without samples that may be bridged (and extrapolated at
            either end); set it above the speed source's sample period (``scale.speed_max_gap``).
        max_samples: knots kept (at least 16).
    """

    def __init__(self, max_gap: float = ScaleConfig.speed_max_gap,
                 max_samples: int = 4096) -> None:
        if not (math.isfinite(max_gap) and max_gap > 0.0):
            raise ConfigError(f'max_gap: expected a positive duration in seconds, got {max_gap}')
        if not max_samples >= 16:
            raise ConfigError(f'max_samples: expected at least 16, got {max_samples}')
        self.max_gap = float(max_gap)
        self.max_samples = int(max_samples)
        cap = self.max_samples
        self._t = np.empty(cap)             # knot stamps (s), increasing
        self._v = np.empty(cap)             # speed at the knots (m/s)
        self._d = np.empty(cap)             # distance travelled up to the knot (m)
        self._err = np.zeros(cap)           # interval i -> i+1: error of D inside it (m)
        self._cov = np.zeros(cap, bool)     # interval i -> i+1: sampled without a longer gap
        self._n = 0
        self.ignored = 0                    # late samples inside merged history (not used)

    def __len__(self) -> int:
        return self._n

    @property
    def latest(self) -> float | None:
        """The stamp of the latest sample (s), or None before the first."""
        return float(self._t[self._n - 1]) if self._n else None

    def add(self, stamp: float, speed: float) -> None:
        """Add a speed sample (m/s, non-negative; the direction comes from vision).

        Samples may arrive out of order; a sample at an existing stamp replaces its speed. A
        late sample that falls inside history already merged away is counted in `ignored`.
        """
        stamp, speed = float(stamp), float(speed)
        if not (math.isfinite(stamp) and math.isfinite(speed)):
            raise InputError(f'speed sample: expected finite stamp and speed, got {stamp}, {speed}')
        speed = abs(speed)
        n = self._n
        t, v, d = self._t, self._v, self._d
        if n and stamp > t[n - 1]:
            if n == self.max_samples:
                self._thin()
                n = self._n
            dt = stamp - t[n - 1]
            t[n], v[n], d[n] = stamp, speed, d[n - 1] + 0.5 * (v[n - 1] + speed) * dt
            self._err[n - 1], self._cov[n - 1] = 0.0, dt <= self.max_gap
            self._n = n + 1
            return
        if n == 0:
            t[0], v[0], d[0] = stamp, speed, 0.0
            self._n = 1
            return
        i = int(np.searchsorted(t[:n], stamp))
        if i < n and t[i] == stamp:
            self._replace(i, speed)
        else:
            self._insert(i, stamp, speed)

    def _area(self, i: int) -> float:
        """Trapezoid distance of the interval ``i -> i+1`` from its end speeds."""
        return 0.5 * (self._v[i] + self._v[i + 1]) * (self._t[i + 1] - self._t[i])

    def _raw(self, i: int) -> bool:
        """Whether interval ``i -> i+1`` exists and was never merged (its D is a trapezoid)."""
        return 0 <= i < self._n - 1 and self._err[i] == 0.0 and \
            abs(self._d[i + 1] - self._d[i] - self._area(i)) <= 1e-9 * (1.0 + abs(self._d[i + 1]))

    def _replace(self, i: int, speed: float) -> None:
        n = self._n
        if (i > 0 and not self._raw(i - 1)) or (i < n - 1 and not self._raw(i)):
            self.ignored += 1
            return
        old_left = self._area(i - 1) if i > 0 else 0.0
        old_right = self._area(i) if i < n - 1 else 0.0
        self._v[i] = speed
        left = self._area(i - 1) if i > 0 else 0.0
        right = self._area(i) if i < n - 1 else 0.0
        self._d[i:n] += left - old_left
        self._d[i + 1:n] += right - old_right

    def _insert(self, i: int, stamp: float, speed: float) -> None:
        n = self._n
        if 0 < i < n and not self._raw(i - 1):
            self.ignored += 1
            return
        if n == self.max_samples:
            self._thin()
            self.add(stamp, speed)
            return
        t, v, d, err, cov = self._t, self._v, self._d, self._err, self._cov
        t[i + 1:n + 1], v[i + 1:n + 1], d[i + 1:n + 1] = t[i:n].copy(), v[i:n].copy(), d[i:n].copy()
        err[i + 1:n], cov[i + 1:n] = err[i:n - 1].copy(), cov[i:n - 1].copy()
        t[i], v[i] = stamp, speed
        self._n = n + 1
        if i == 0:                              # before the first knot
            d[0] = d[1] - self._area(0)
            err[0], cov[0] = 0.0, t[1] - t[0] <= self.max_gap
            return
        old = d[i + 1] - d[i - 1]
        d[i] = d[i - 1] + self._area(i - 1)
        d[i + 1:n + 1] += self._area(i - 1) + self._area(i) - old
        err[i - 1:i + 1] = 0.0
        cov[i - 1], cov[i] = t[i] - t[i - 1] <= self.max_gap, t[i + 1] - t[i] <= self.max_gap

    def _thin(self) -> None:
        """Merge away a quarter of the knots, those whose removal changes ``D(t)`` least (never
        two neighbours at once)."""
        n = self._n
        t, v, d = self._t[:n], self._v[:n], self._d[:n]
        i = np.arange(1, n - 1)
        # D at knot i as the merged interval i-1 -> i+1 would interpolate it, and the error.
        err = np.abs(d[i] - _interpolate(t[i], t[i - 1], t[i + 1], v[i - 1], v[i + 1],
                                         d[i - 1], d[i + 1])) \
            + self._err[i - 1] + self._err[i]
        chosen = np.zeros(n, bool)
        budget = n - (3 * self.max_samples) // 4
        for k in i[np.argsort(err, kind='stable')]:
            if budget == 0:
                break
            if not (chosen[k - 1] or chosen[k + 1]):
                chosen[k] = True
                budget -= 1
        keep = np.flatnonzero(~chosen)
        # Merged interval j (kept knots j -> j+1): error and coverage of the originals in it.
        err_new = np.zeros(keep.size)
        cov_new = np.ones(keep.size, bool)
        removed = np.flatnonzero(chosen)
        after = np.searchsorted(keep, removed) - 1      # the merged interval's left knot
        err_new[:-1] = self._err[keep[:-1]]
        cov_new[:-1] = self._cov[keep[:-1]]
        err_new[after] = err[removed - 1]
        cov_new[after] = self._cov[removed - 1] & self._cov[removed]
        m = keep.size
        self._t[:m], self._v[:m], self._d[:m] = t[keep], v[keep], d[keep]
        self._err[:m], self._cov[:m] = err_new, cov_new
        self._n = m

    def _distance_to(self, x: float) -> float:
        """``D(x)``: the knots' distance interpolated, or extrapolated at the end speeds."""
        n = self._n
        t, v, d = self._t, self._v, self._d
        if x <= t[0]:
            return float(d[0] - v[0] * (t[0] - x))
        if x >= t[n - 1]:
            return float(d[n - 1] + v[n - 1] * (x - t[n - 1]))
        j = int(np.searchsorted(t[:n], x, side='right')) - 1
        return float(_interpolate(x, t[j], t[j + 1], v[j], v[j + 1], d[j], d[j + 1]))

    def distance(self, t0: float, t1: float) -> float | None:
        """Metres travelled in ``[t0, t1]``, or None when the samples do not cover it (an
        interval without samples longer than ``max_gap`` inside, or an end farther than
        ``max_gap`` beyond the samples)."""
        n = self._n
        if not n or not t1 >= t0:
            return None
        t = self._t[:n]
        if t0 < t[0] - self.max_gap or t1 > t[-1] + self.max_gap:
            return None
        # Intervals j -> j+1 overlapping (t0, t1) must all be covered.
        lo = max(int(np.searchsorted(t, t0, side='right')) - 1, 0)
        hi = min(int(np.searchsorted(t, t1, side='left')), n - 1)
        if hi > lo and not np.all(self._cov[lo:hi]):
            return None
        return self._distance_to(t1) - self._distance_to(t0)


def _interpolate(x, ta, tb, va, vb, da, db):
    """``D(x)`` inside an interval ``[ta, tb]`` with end speeds ``va, vb`` and end distances
    ``da, db``: the shape of a linearly changing speed, scaled to the exact ``db - da`` (equal
    to the trapezoid for an interval that was never merged); linear in time when both speeds
    are 0. Works on scalars and arrays."""
    length = tb - ta
    x = x - ta
    shape = va * x + 0.5 * (vb - va) * x * x / length
    total = 0.5 * (va + vb) * length
    safe = np.where(total > 0.0, total, 1.0)
    return da + (db - da) * np.where(total > 0.0, shape / safe, x / length)


# --------------------------------------------------------------------------------------------
# Road scale: general motion, explicit road normal, honest standard deviation
# --------------------------------------------------------------------------------------------

# Cluster cell of the default cluster-robust variance (normalised units, ~35 px at f = 700):
# neighbouring ACs share a patch, the flow's smoothing and one surface, so their errors are
# correlated over about this distance.
_CLUSTER_CELL = 0.05


@dataclass(frozen=True)
class RoadScale:
    """The step length from road ACs (`road_scale`).

    Attributes:
        scale: step length in metres (NaN when fewer than ``min_count`` road ACs).
        std: its standard deviation in metres (inf without an estimate):
            ``hypot(std_stat, std_rot, std_normal)``.
        std_stat: cluster-robust statistical part (the road ACs' own noise).
        std_rot: part of the relative rotation's error about the camera x and z axes
            (``sigma_rot``), shared by every road AC of the frame.
        std_normal: part of the road normal's error (``sigma_normal`` in pitch and roll).
        count: road ACs used.
        mask: ``(N,)`` bool, the road ACs used.
        d_rotation: ``(3,)`` ds/d(omega) (m/rad) for ``R -> exp([omega]x) R``, a small rotation
            of view 2 about its x, y, z axes (to propagate a full rotation covariance
            ``d_rotation @ cov @ d_rotation``).
        d_normal: ``(2,)`` ds/d(pitch, roll) (m/rad) of the road normal (`normal_from_tilt`).
    """

    scale: float
    std: float
    std_stat: float
    std_rot: float
    std_normal: float
    count: int
    mask: np.ndarray
    d_rotation: np.ndarray
    d_normal: np.ndarray


def _robust_mean(s: np.ndarray, w: np.ndarray, clusters: np.ndarray
                 ) -> tuple[float, float, np.ndarray]:
    """Weighted mean of ``s`` after a 3-MAD clip around the weighted median, its
    cluster-robust standard deviation, and the kept mask.

    Cluster-robust variance of a weighted mean (Liang and Zeger 1986):
    ``sum_c (sum_{i in c} w_i (s_i - mean))^2 / W^2`` with the small-sample factor
    ``G / (G - 1)`` for ``G`` clusters.
    """
    med = weighted_median(s, w)
    dev = np.abs(s - med)
    keep = dev <= 3.0 * (MAD_TO_SIGMA * median(dev) + 1e-12)
    sk, wk, ck = s[keep], w[keep], clusters[keep]
    wsum = float(wk.sum())
    mean = float((wk * sk).sum() / wsum)
    e = np.bincount(ck, weights=wk * (sk - mean))
    g = np.count_nonzero(np.bincount(ck))
    var = float((e * e).sum()) / wsum ** 2 * (g / max(g - 1, 1))
    return mean, math.sqrt(var), keep


def _unit(name: str, x) -> np.ndarray:
    x = as_array(name, x, (3,))
    norm = float(np.linalg.norm(x))
    if not norm > 0.0:
        raise InputError(f'{name}: expected a non-zero direction, got {x.tolist()}')
    return x / norm


def _step_terms(u1, v1, u2, v2, R: np.ndarray, t: np.ndarray):
    """Per AC: ``R Q1`` (three ``(N,)`` arrays), ``b = Q2 x t`` (three arrays), ``|b|^2`` and
    ``c = -((Q2 x R Q1) . b) / |b|^2`` (NaN where ``b = 0``), for ``Q = [u, v, 1]``."""
    rx = R[0, 0] * u1 + R[0, 1] * v1 + R[0, 2]
    ry = R[1, 0] * u1 + R[1, 1] * v1 + R[1, 2]
    rz = R[2, 0] * u1 + R[2, 1] * v1 + R[2, 2]
    bx, by, bz = v2 * t[2] - t[1], t[0] - u2 * t[2], u2 * t[1] - v2 * t[0]
    bb = bx * bx + by * by + bz * bz
    ab = (v2 * rz - ry) * bx + (rx - u2 * rz) * by + (u2 * ry - v2 * rx) * bz
    with np.errstate(divide='ignore', invalid='ignore'):
        c = -ab / np.where(bb > 0.0, bb, np.nan)
    return (rx, ry, rz), (bx, by, bz), bb, c


def step_factors(q1: np.ndarray, q2: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``c_i`` ``(N,)`` with ``s_i = h c_i / (n . Q1_i)``: the step of `road_scale` without the
    road normal and the height (``q1, q2`` normalised ``(N, 2)``, ``R, t`` as there, ``t``
    unit); NaN where ``Q2 x t = 0``. `RoadNormalCalibrator` fits the normal to these."""
    return _step_terms(q1[:, 0], q1[:, 1], q2[:, 0], q2[:, 1], R, t)[3]


def _sensitivities(wn, lam, r, b, bb, u2, v2, s_i, q1, dn, n):
    """Exact derivatives of the weighted mean ``sum wn_i s_i`` (normalised weights) over the
    given road ACs: ds/d(omega) ``(3,)`` for ``R -> exp([omega]x) R`` and ds/d(pitch, roll)
    ``(2,)`` of the normal. ``ds_i/domega = -((Q2 x (e x R X1)) . b) / |b|^2`` with
    ``R X1 = lam R Q1``; ``ds_i/dtheta = -s_i (dn/dtheta . Q1) / (n . Q1)``."""
    Yx, Yy, Yz = lam * r[0], lam * r[1], lam * r[2]                # R X1
    bx, by, bz = b
    zero = np.zeros_like(Yx)
    d_rot = np.empty(3)
    # e x Y for e = x, y, z: (0, -Yz, Yy), (Yz, 0, -Yx), (-Yy, Yx, 0); then Q2 x (e x Y).
    for k, (ex, ey, ez) in enumerate(((zero, -Yz, Yy), (Yz, zero, -Yx), (-Yy, Yx, zero))):
        da_b = (v2 * ez - ey) * bx + (ex - u2 * ez) * by + (u2 * ey - v2 * ex) * bz
        d_rot[k] = -float((wn * da_b / bb).sum())
    J = normal_tilt_jacobian(*tilt_from_normal(n))
    Q1 = np.column_stack([q1, np.ones(len(q1))])
    d_normal = -(wn * s_i / dn) @ (Q1 @ J)
    return d_rot, np.asarray(d_normal, dtype=np.float64)


# Rays at least this far below the horizon (n . Q, about 1 deg) can meet the road.
_MIN_ELEVATION = 0.02


def road_rays(q: np.ndarray, n: np.ndarray, height: float,
              max_depth: float = ScaleConfig.ground_max_depth,
              min_elevation: float = _MIN_ELEVATION) -> np.ndarray:
    """``(N,)`` bool: the normalised points ``q`` ``(N, 2)`` whose rays meet the road
    ``n . X = height`` (``n`` pointing down, normalised here) below ``min_elevation`` and within
    ``max_depth`` metres along the ray: where `road_scale` can use an AC."""
    q = as_array('q', q, (None, 2), min_items=0)
    n = _unit('n', n)
    for name, value in (('height', height), ('max_depth', max_depth)):
        if not (math.isfinite(value) and value > 0):
            raise ConfigError(f'{name}: expected a positive number of metres, got {value}')
    if not math.isfinite(min_elevation):
        raise ConfigError(f'min_elevation: expected a finite number, got {min_elevation}')
    return _road_rays(q, n, height, max_depth, min_elevation)


def _road_rays(q: np.ndarray, n: np.ndarray, height: float, max_depth: float,
               min_elevation: float) -> np.ndarray:
    """`road_rays` on checked arguments (``n`` unit)."""
    dn = n[0] * q[:, 0] + n[1] * q[:, 1] + n[2]
    with np.errstate(divide='ignore'):
        depth = height / np.where(dn > 0, dn, np.inf) * np.sqrt(1.0 + (q * q).sum(axis=1))
    return (dn >= min_elevation) & (depth <= max_depth)


def road_scale(q1: np.ndarray, q2: np.ndarray, A: np.ndarray, R: np.ndarray, t: np.ndarray,
               n: np.ndarray, height: float, *, point_sigma: float,
               weights: np.ndarray | None = None, clusters: np.ndarray | None = None,
               sigma_rot: float = 0.0, sigma_normal: float = 0.0,
               max_depth: float = ScaleConfig.ground_max_depth,
               min_elevation: float = _MIN_ELEVATION,
               affine_sigma: float = ScaleConfig.ground_affine_std,
               gate: float = ScaleConfig.ground_gate,
               min_count: int = ScaleConfig.ground_min_correspondences,
               lateral_std: float = 0.0,
               s_prior: float | None = None, check: bool = True) -> RoadScale:
    """Step length from road ACs, for a general motion and an explicit road normal.

    Everything is in the frame of camera 1 (not levelled; the normal carries the tilt): the
    road is the plane ``n . X = h`` (``n`` unit, pointing down), the motion
    ``X2 = R X1 + s t`` with ``t`` the unit translation direction and ``s`` the step (metres).
    Per AC, in closed form: the ray of ``Q1 = [q1, 1]`` meets the road at
    ``X1 = h Q1 / (n . Q1)``; with ``a = Q2 x R X1`` and ``b = Q2 x t``, the least-squares
    step of ``Q2 x (R X1 + s t) = 0`` is

        s_i = -(a . b) / (b . b).

    Road test: at the consensus ``s``, an AC is road when the whitened RMS of its point
    residual (``|s_i - s| |b| / depth`` over ``point_sigma``) and of its affine's distance to
    the Jacobian of the road homography ``H = R + (s / h) t n^T`` (over ``affine_sigma``) is at
    most ``gate`` (run twice from the weighted median of all candidates, or ``s_prior``). The
    affine only *selects* road ACs: on KITTI the front-end's road affines are biased (the
    vertical foreshortening ``a4 - 1`` about 8 % low), so they do not measure ``s``.

    Estimate: the weighted mean of the road ACs' ``s_i`` after a 3-MAD clip; with
    ``lateral_std`` the weights are multiplied by ``exp(-x_i^2 / (2 lateral_std^2))``, ``x_i``
    the road point's distance from the line of travel (along ``n x t``): the height is known
    for the surface under the car, and the rest of the road (crown, gutters, curbs, sidewalks)
    may lie higher or lower. Variance:

        std^2 = std_stat^2 + sigma_rot^2 (ds/dw_x^2 + ds/dw_z^2)
                + sigma_normal^2 (ds/dpitch^2 + ds/droll^2),

    the cluster-robust variance of the mean plus what every road AC of the frame shares: a
    relative rotation about the camera x axis (the car's pitch between frames, 0.04-0.11 deg on
    KITTI) shifts every road ``v2`` at once and does not average out; the same for the roll
    and for the road normal. The sensitivities are exact derivatives of the mean over the same
    road ACs (``ds_i/dw = -((Q2 x (e x R X1)) . b) / (b . b)``,
    ``ds_i/dpitch = -s_i (dn/dpitch . Q1) / (n . Q1)``).

    Args:
        q1, q2: normalised points of the camera (not levelled), ``(N, 2)``.
        A: normalised affines, ``(N, 2, 2)``.
        R, t: relative rotation ``(3, 3)`` and translation direction ``(3,)`` (normalised
            here), ``X2 = R X1 + s t``.
        n: road normal in the camera-1 frame, pointing down, ``(3,)`` (normalised here); e.g.
            `normal_from_tilt` of `RoadNormalCalibrator`'s pitch and roll.
        height: camera height above the road (m).
        point_sigma: point noise of the road test in normalised units (the front-end's
            accuracy in pixels, ``scale.ground_point_std``, over the focal length).
        weights: per-AC quality ``(N,)`` (non-negative; 0 excludes).
        clusters: non-negative integer cell per AC ``(N,)`` for the cluster-robust variance
            (default: a grid of 0.05 normalised units).
        sigma_rot: std (rad) of the relative rotation about the camera x and z axes that ``R``
            may miss (about 0.1 deg for a planar motion on KITTI; the general estimator's own
            uncertainty otherwise).
        sigma_normal: std (rad) of the road normal's pitch and roll (the calibration's std
            combined with the car's pitch on its suspension).
        max_depth: road points farther along the ray (m) are not used: their parallax
            (~ h s / Z^2) is small against the rotation noise.
        min_elevation: ``n . Q1`` at least this (rays at least ~1 deg below the horizon).
        affine_sigma: affine noise (unitless) of the road test.
        gate: whitened RMS residual above which an AC is not road.
        min_count: fewer road ACs give no estimate (NaN).
        lateral_std: standard deviation (m) of the Gaussian weight of a road AC's lateral
            distance from the line of travel; 0 weighs all alike.
        s_prior: step (m) to start the road test from (e.g. the last step); None: the weighted
            median of all candidates.
        check: False skips the checks of the arguments (for a caller whose arrays are checked
            already, e.g. the pipeline at every frame: they cost about a third of the call);
            ``t`` and ``n`` are normalised either way.

    Returns:
        A `RoadScale`.

    Raises:
        InputError: arrays of the wrong shape or non-finite, ``R`` not a rotation, a zero
            ``t`` or ``n``, negative weights or sigmas, bad cluster labels.
        ConfigError: a non-positive height, noise scale, gate or depth, ``min_count < 1``.
    """
    if check:
        q1 = as_array('q1', q1, (None, 2), min_items=0)
        q2 = as_array('q2', q2, (None, 2), min_items=0)
        A = as_array('A', A, (None, 2, 2), min_items=0)
        count = same_length(q1=q1, q2=q2, A=A)
        R = as_rotation('R', R)
        t = _unit('t', t)
        n = _unit('n', n)
        w = np.ones(count) if weights is None else as_array('weights', weights, (None,),
                                                            min_items=0)
        same_length(q1=q1, weights=w)
        if np.any(w < 0):
            raise InputError(f'weights: expected non-negative values, got minimum {w.min()}')
        for name, value in (('sigma_rot', sigma_rot), ('sigma_normal', sigma_normal)):
            if not (math.isfinite(value) and value >= 0.0):
                raise InputError(f'{name}: expected a non-negative angle (rad), got {value}')
        for name, value in (('height', height), ('max_depth', max_depth),
                            ('point_sigma', point_sigma), ('affine_sigma', affine_sigma),
                            ('gate', gate)):
            if not (math.isfinite(value) and value > 0.0):
                raise ConfigError(f'{name}: expected a positive number, got {value}')
        if not (math.isfinite(lateral_std) and lateral_std >= 0.0):
            raise ConfigError(f'lateral_std: expected a non-negative distance (m), got '
                              f'{lateral_std}')
        if not (math.isfinite(min_elevation) and min_count >= 1):
            raise ConfigError(f'min_elevation, min_count: expected a finite number and at least '
                              f'1, got {min_elevation}, {min_count}')
        if s_prior is not None and not (math.isfinite(s_prior) and s_prior > 0.0):
            raise InputError(f's_prior: expected a positive step (m) or None, got {s_prior}')
    else:
        count = q1.shape[0]
        t = t / float(np.linalg.norm(t))
        n = n / float(np.linalg.norm(n))
        w = np.ones(count) if weights is None else weights
    if clusters is None:
        ij = np.floor(q1 / _CLUSTER_CELL).astype(np.int64) if count else np.zeros((0, 2), int)
        if count:
            ij -= ij.min(0)
        clusters = ij[:, 0] * (int(ij[:, 1].max(initial=0)) + 1) + ij[:, 1]
    labels = check_clusters(clusters, count)

    failed = RoadScale(float('nan'), float('inf'), float('inf'), 0.0, 0.0, 0,
                       np.zeros(count, bool), np.zeros(3), np.zeros(2))
    h = float(height)
    # Only rays that meet the road within max_depth count: the rest of the maths runs on those.
    below = np.flatnonzero(_road_rays(q1, n, h, max_depth, min_elevation) & (w > 0))
    if below.size < min_count:
        return failed
    dn = n[0] * q1[below, 0] + n[1] * q1[below, 1] + n[2]      # n . Q1
    u1, v1, u2, v2 = q1[below, 0], q1[below, 1], q2[below, 0], q2[below, 1]
    r, b, bb, c = _step_terms(u1, v1, u2, v2, R, t)
    lam = h / dn                                                # depth along Q1 (z of X1)
    s_i = lam * c
    depth = lam * np.sqrt(1.0 + u1 * u1 + v1 * v1)
    idx = np.flatnonzero(s_i > 0)
    if idx.size < min_count:
        return failed
    ws, labels = w[below], labels[below]
    # n x t: across the line of travel, in the road (numpy's cross costs more than the rest
    # of this block at this size; the same products in the same order).
    (n0, n1, n2), (t0, t1, t2) = n.tolist(), t.tolist()
    side = np.array([n1 * t2 - n2 * t1, n2 * t0 - n0 * t2, n0 * t1 - n1 * t0])
    side_norm = float(np.linalg.norm(side))
    if lateral_std > 0.0 and side_norm > 1e-6:
        # Lateral offset of the road point X1 = lam Q1 from the line of travel.
        x = lam * (side[0] * u1 + side[1] * v1 + side[2]) / side_norm
        ws = ws * np.exp(-0.5 * (x / lateral_std) ** 2)
    s0 = s_prior if s_prior is not None else _robust_mean(s_i[idx], ws[idx], labels[idx])[0]
    # Road test, twice: point residual |s_i - s0| |b| / depth (first order: ds_i/dq2 ~
    # depth / |b|) and the affine's distance to the road homography's Jacobian at s0.
    ep_scale = np.sqrt(bb[idx]) / (depth[idx] * point_sigma)
    uc, vc, Ac = u1[idx], v1[idx], A[below[idx]]
    for _ in range(2):
        H = R + (s0 / h) * np.outer(t, n)
        hx = H[0, 0] * uc + H[0, 1] * vc + H[0, 2]
        hy = H[1, 0] * uc + H[1, 1] * vc + H[1, 2]
        hz = H[2, 0] * uc + H[2, 1] * vc + H[2, 2]
        px, py = hx / hz, hy / hz
        ea2 = ((Ac[:, 0, 0] - (H[0, 0] - px * H[2, 0]) / hz) ** 2
               + (Ac[:, 0, 1] - (H[0, 1] - px * H[2, 1]) / hz) ** 2
               + (Ac[:, 1, 0] - (H[1, 0] - py * H[2, 0]) / hz) ** 2
               + (Ac[:, 1, 1] - (H[1, 1] - py * H[2, 1]) / hz) ** 2) / affine_sigma ** 2
        ep2 = ((s_i[idx] - s0) * ep_scale) ** 2
        road = idx[(ep2 + ea2 / 4.0) / 2.0 <= gate * gate]
        if road.size < min_count:
            return failed
        s0, _, keep = _robust_mean(s_i[road], ws[road], labels[road])
    sel = road[keep]
    scale, std_stat, keep = _robust_mean(s_i[sel], ws[sel], labels[sel])
    sel = sel[keep]
    mask = np.zeros(count, bool)
    mask[below[sel]] = True
    d_rot, d_normal = _sensitivities(ws[sel] / float(ws[sel].sum()), lam[sel],
                                     [x[sel] for x in r], [x[sel] for x in b], bb[sel],
                                     u2[sel], v2[sel], s_i[sel], q1[below[sel]], dn[sel], n)
    std_rot = sigma_rot * math.hypot(d_rot[0], d_rot[2])
    std_normal = sigma_normal * math.hypot(d_normal[0], d_normal[1])
    std = math.sqrt(std_stat ** 2 + std_rot ** 2 + std_normal ** 2)
    return RoadScale(scale, std, std_stat, std_rot, std_normal, int(sel.size), mask, d_rot,
                     d_normal)
