"""Metric scale for monocular planar motion (DESIGN.md section 5).

A single camera observes the direction of translation only. Sources of the step length ``s``:

- `SpeedIntegrator`: a speed topic (wheel odometry, ``TwistStamped``) integrated over the
  interval between two frames;
- `ground_plane_scale`: ACs on the road at the known camera height ``h``. In the level camera
  frame of the reference view (y down), the ground is ``Y = h``; a ground point seen at ``q1``
  lies at ``X1 = (h / v1) q1``, and its image in view 2, ``q2 ~ R X1 + s t``, gives ``s`` in closed
  form. Its affine must match the ground homography ``H = R + (s / h) t n^T`` (``n = [0, 1, 0]``),
  which separates road ACs from facades and obstacles;
- a fixed speed, or unit steps.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

import numpy as np

from planar_vo.core.conventions import rotation_y, translation_direction
from planar_vo.core.robust.stats import MAD_TO_SIGMA, weighted_median
from planar_vo.errors import InputError

__all__ = ['GroundScale', 'SpeedIntegrator', 'ground_plane_scale']


class SpeedIntegrator:
    """Distance travelled between two times from speed samples (piecewise-linear speed).

    Args:
        max_gap: longest interval (seconds) without samples that may be bridged.
        keep: seconds of history kept.
    """

    def __init__(self, max_gap: float = 0.5, keep: float = 30.0) -> None:
        self.max_gap = float(max_gap)
        self.keep = float(keep)
        self._t: list[float] = []
        self._v: list[float] = []

    def __len__(self) -> int:
        return len(self._t)

    def add(self, stamp: float, speed: float) -> None:
        """Add a speed sample (m/s, non-negative; the direction comes from vision)."""
        if not (math.isfinite(stamp) and math.isfinite(speed)):
            raise InputError(f'speed sample: expected finite stamp and speed, got {stamp}, {speed}')
        speed = abs(float(speed))
        i = bisect.bisect_left(self._t, stamp)
        if i < len(self._t) and self._t[i] == stamp:
            self._v[i] = speed
        else:
            self._t.insert(i, float(stamp))
            self._v.insert(i, speed)
        while self._t and self._t[0] < self._t[-1] - self.keep:
            self._t.pop(0)
            self._v.pop(0)

    def distance(self, t0: float, t1: float) -> float | None:
        """Metres travelled in ``[t0, t1]``, or None when the samples do not cover it."""
        if not self._t or t1 < t0:
            return None
        t = np.asarray(self._t)
        v = np.asarray(self._v)
        if t0 < t[0] - self.max_gap or t1 > t[-1] + self.max_gap:
            return None
        inside = (t > t0) & (t < t1)
        knots = np.concatenate([[t0], t[inside], [t1]])
        if np.any(np.diff(knots) > self.max_gap) and t.size > 1:
            return None
        speeds = np.interp(knots, t, v)
        return float(np.sum(0.5 * (speeds[1:] + speeds[:-1]) * np.diff(knots)))


@dataclass(frozen=True)
class GroundScale:
    """The ground-plane scale estimate.

    Attributes:
        scale: step length in metres (NaN when no road ACs were found).
        std: its standard deviation in metres.
        count: road ACs used.
    """

    scale: float
    std: float
    count: int


def ground_plane_scale(q1: np.ndarray, q2: np.ndarray, A: np.ndarray, alpha: float, beta: float,
                       height: float, *, weights: np.ndarray | None = None,
                       min_v: float = 0.05, max_depth: float = 40.0, affine_tol: float = 0.05,
                       min_count: int = 10) -> GroundScale:
    """Step length from road ACs at camera height ``height`` (level, normalised coordinates).

    Args:
        q1, q2: normalised coordinates of a level camera (y down), ``(N, 2)``.
        A: normalised affines, ``(N, 2, 2)``.
        alpha, beta: the motion between the views (radians).
        height: camera height above the road (metres).
        weights: optional per-AC weights (e.g. the voting inlier mask).
        min_v: only points at least this far below the horizon (normalised) are candidates.
        max_depth: only candidates closer than this (metres) are used: far road points carry
            little parallax.
        affine_tol: maximum Frobenius distance between the measured affine and the one the
            ground homography predicts, relative to ``|A|``.
        min_count: fewer road ACs give NaN.

    Returns:
        A `GroundScale`; ``std`` is a robust spread over ``sqrt(count / 10)``: neighbouring road
        ACs share errors, so about one in ten counts as independent.
    """
    w = np.ones(len(q1)) if weights is None else np.asarray(weights, dtype=np.float64)
    v1 = q1[:, 1]
    depth = height / np.where(v1 > 0, v1, np.inf) * np.sqrt(1.0 + q1[:, 0] ** 2 + v1 ** 2)
    cand = (v1 >= min_v) & (depth <= max_depth) & (w > 0)
    if np.count_nonzero(cand) < min_count:
        return GroundScale(float('nan'), float('inf'), 0)
    q1c, q2c, Ac, wc = q1[cand], q2[cand], A[cand], w[cand]
    R = rotation_y(alpha)
    t = translation_direction(beta)
    X1 = np.column_stack([q1c, np.ones(len(q1c))]) * (height / q1c[:, 1])[:, None]
    RX = X1 @ R.T
    h2 = np.column_stack([q2c, np.ones(len(q2c))])
    a = np.cross(h2, RX)
    b = np.cross(h2, t)
    bb = np.einsum('ni,ni->n', b, b)
    s = -np.einsum('ni,ni->n', a, b) / np.where(bb > 0, bb, np.inf)
    # The affine the road homography predicts at q1: H = R + (s / h) t n^T, n = [0, 1, 0].
    H = np.broadcast_to(R, (len(s), 3, 3)).copy()
    H[:, :, 1] += (s / height)[:, None] * t[None, :]
    hq = np.einsum('nij,nj->ni', H, np.column_stack([q1c, np.ones(len(q1c))]))
    q2p = hq[:, :2] / hq[:, 2:3]
    Jp = (H[:, :2, :2] - q2p[:, :, None] * H[:, 2:3, :2]) / hq[:, 2, None, None]
    err = np.linalg.norm(Jp - Ac, axis=(1, 2)) / np.linalg.norm(Ac, axis=(1, 2))
    road = (err <= affine_tol) & np.isfinite(s) & (s > 0)
    if np.count_nonzero(road) < min_count:
        return GroundScale(float('nan'), float('inf'), int(np.count_nonzero(road)))
    s, wr = s[road], wc[road]
    median = weighted_median(s, wr)
    # A second, tighter pass around the median rejects the occasional non-road AC that matched.
    close = np.abs(s - median) <= 3.0 * MAD_TO_SIGMA * np.median(np.abs(s - median)) + 1e-12
    s, wr = s[close], wr[close]
    scale = float(np.average(s, weights=wr))
    spread = MAD_TO_SIGMA * float(np.median(np.abs(s - scale)))
    std = spread / math.sqrt(max(len(s) / 10.0, 1.0))
    return GroundScale(scale, std, int(len(s)))
