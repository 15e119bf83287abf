"""The road normal in the camera frame, from the road itself: its ACs must agree on one step.

For a road AC ``i`` of a frame pair with relative motion ``(R, t)`` (`planar_vo.pipeline.scale`),
the step length is ``s_i = h c_i / (n . Q1_i)`` with (`step_factors`)

    c_i = -((Q2 x R Q1) . (Q2 x t)) / |Q2 x t|^2,

which does not depend on the normal ``n`` or the height ``h``. So for the true normal all road
ACs of a frame give one ``s``:

    log c_i - log(n(pitch, roll) . Q1_i) = log(s_f / h)    for every road AC i of frame f.

A wrong pitch ``dp`` makes ``s_i`` drift like ``1 - dp / v_i`` across the road (near and far ACs
disagree), a wrong roll like ``1 - dr u_i / v_i``. `RoadNormalCalibrator` finds ``(pitch, roll)``
minimising the robust within-frame dispersion

    sum_f sum_i w_i rho(log c_i - log(n . Q1_i) - mu_f),   mu_f the frame's weighted mean,

by Gauss-Newton with Cauchy IRLS weights, the per-frame means profiled out. This is the road's
normal, which differs from the motion plane's (`MountTiltEstimator`) by the road's camber and
the car's stance (measured on KITTI 05: about 0.2 deg of pitch, 5 % of scale). The motion
``(R, t)`` should be a general one: a planar rotation leaves the pitch wobble in ``c_i`` and
biases the normal (KITTI 05 with the planar vote: pitch 2.04 instead of 1.26 deg).

Frames: camera optical (x right, y down, z forward); pitch and roll as in `MountConfig`
(`planar_vo.core.conventions.normal_from_tilt`).
"""

from __future__ import annotations

import math

import numpy as np

from planar_vo.config.sections import ScaleConfig
from planar_vo.core.checks import as_array, as_rotation, same_length
from planar_vo.core.conventions import normal_from_tilt, normal_tilt_jacobian
from planar_vo.core.robust.stats import MAD_TO_SIGMA, few_cluster_factor, median
from planar_vo.errors import ConfigError, InputError
from planar_vo.pipeline.calibration.tilt import TiltEstimate, check_focal_ratio, refocused
from planar_vo.pipeline.scale import step_factors

__all__ = ['RoadNormalCalibrator', 'pair_road_normal']

_CAUCHY_SCALE = 2.5       # residuals (in robust spreads) at which the IRLS weight is 1/2
_MIN_ROAD = 10            # road ACs a frame pair needs to be stored (a within-frame spread)


class RoadNormalCalibrator:
    """Online estimate of the road normal (pitch, roll) in the camera frame from road ACs.

    Feed every frame pair's road ACs (`add`, e.g. the mask of `road_scale`) and call `update`
    once per frame; use `latest` (a `TiltEstimate`) for the road normal of the next step.

    Memory: at most ``per_frame`` road ACs per frame pair (evenly picked) for the last
    ``max_frames`` pairs (a ring buffer): ``4 x per_frame x max_frames`` floats (384 KB by
    default). Cost: a fit is a few passes over the stored ACs (about 12,000); `update` refits
    only after ``refit_every`` new pairs once the buffer is full, and proportionally more often
    while it fills (after ``max(1, stored x refit_every / max_frames)`` new pairs), so the
    amortised cost per frame stays about that of ``1 / refit_every`` fits, and the first frames
    of a drive are not scaled with a level guess (measured on KITTI 05: the 0-pitch guess made
    the first 10 steps 22-29 % long). Each fit starts from the previous estimate.

    Standard deviations: a sandwich covariance with frame pairs as clusters (a frame's ACs share
    its rotation error), at least the model-based one, widened for few frames
    (`few_cluster_factor`). They describe the fit, not how far the road ahead departs from the
    average road (camber, the car's pitch; about 0.2 deg on KITTI): add that
    (``scale.ground_normal_std``) before using the normal for a single step.

    Args:
        per_frame: road ACs kept per frame pair.
        max_frames: frame pairs kept.
        refit_every: new pairs between refits once full.
        min_frames: pairs needed for an estimate.
    """

    def __init__(self, per_frame: int = ScaleConfig.ground_normal_acs,
                 max_frames: int = ScaleConfig.ground_normal_frames,
                 refit_every: int = ScaleConfig.ground_normal_refit,
                 min_frames: int = 1) -> None:
        if not (per_frame >= _MIN_ROAD and max_frames >= 2 and refit_every >= 1
                and 1 <= min_frames <= max_frames):
            raise ConfigError(f'RoadNormalCalibrator: expected per_frame >= {_MIN_ROAD}, '
                              f'max_frames >= 2, refit_every >= 1, 1 <= min_frames <= '
                              f'max_frames, got {per_frame}, {max_frames}, {refit_every}, '
                              f'{min_frames}')
        self.per_frame, self.max_frames = int(per_frame), int(max_frames)
        self.refit_every, self.min_frames = int(refit_every), int(min_frames)
        shape = (self.max_frames, self.per_frame)
        self._q = np.zeros(shape + (2,))        # normalised image-1 points of road ACs
        self._lc = np.zeros(shape)              # log c_i
        self._w = np.zeros(shape)               # weights (0: empty slot)
        self._next = 0                          # ring position of the next frame pair
        self._stored = 0
        self._since_fit = 0
        self.fits = 0                           # fits run so far (cost accounting)
        self.latest: TiltEstimate | None = None

    def __len__(self) -> int:
        return self._stored

    def add(self, q1: np.ndarray, q2: np.ndarray, R: np.ndarray, t: np.ndarray,
            road: np.ndarray, weights: np.ndarray | None = None, *, check: bool = True) -> bool:
        """Store one frame pair's road ACs.

        Args:
            q1, q2: normalised points of the camera (not levelled), ``(N, 2)``.
            R, t: the pair's relative rotation ``(3, 3)`` and translation direction ``(3,)``
                (any norm), ``X2 = R X1 + s t``.
            road: ``(N,)`` bool, the road ACs (e.g. `RoadScale.mask`).
            weights: per-AC quality ``(N,)``, non-negative.
            check: False skips the checks of the arguments (a caller whose arrays are checked
                already: the pipeline, at every frame).

        Returns:
            Whether the pair was stored (it needs at least 10 road ACs in front of both views).
        """
        if check:
            q1 = as_array('q1', q1, (None, 2), min_items=0)
            q2 = as_array('q2', q2, (None, 2), min_items=0)
            R = as_rotation('R', R)
            t = as_array('t', t, (3,))
            if not np.linalg.norm(t) > 0.0:
                raise InputError(f't: expected a non-zero direction, got {t.tolist()}')
            road = np.asarray(road)
            if road.dtype != bool or road.shape != (len(q1),):
                raise InputError(f'road: expected a bool mask of shape ({len(q1)},), got '
                                 f'{road.dtype} {road.shape}')
            w = np.ones(len(q1)) if weights is None else as_array('weights', weights, (None,),
                                                                  min_items=0)
            same_length(q1=q1, q2=q2, weights=w)
            if np.any(w < 0):
                raise InputError(f'weights: expected non-negative values, got minimum '
                                 f'{w.min()}')
        else:
            w = np.ones(len(q1)) if weights is None else weights
        idx = np.flatnonzero(road & (w > 0))
        if idx.size > self.per_frame:
            idx = idx[np.linspace(0, idx.size - 1, self.per_frame).astype(int)]
        c = step_factors(q1[idx], q2[idx], R, t / np.linalg.norm(t))
        front = c > 0                           # NaN or <= 0: not a road point in front
        idx, lc = idx[front], np.log(c[front])
        if idx.size < _MIN_ROAD:
            return False
        k, m = self._next, idx.size
        self._q[k, :m], self._lc[k, :m], self._w[k, :m] = q1[idx], lc, w[idx]
        self._q[k, m:], self._lc[k, m:], self._w[k, m:] = (0.0, 1.0), 0.0, 0.0   # empty slots
        self._next = (k + 1) % self.max_frames
        self._stored = min(self._stored + 1, self.max_frames)
        self._since_fit += 1
        return True

    def refocus(self, ratio: float) -> None:
        """Carry the stored road ACs to a new focal length (``ratio = f_old / f_new``; the
        focal self-calibration changes the one in use): their normalised points scale by
        ``ratio`` and their step factors stay, so every stored frame's residuals at the
        normal ``M^-T n`` equal those at ``n`` before (``M = diag(ratio, ratio, 1)``): the fit
        moves as `refocused` carries `latest`, so nothing is refitted.

        The step factors themselves came from motions estimated through the old focal length;
        in turns that biases the fit until the ring has turned over (a review: a rendered
        drive's road roll 0.68 +- 0.15 deg against 1.5 with them, 1.51 without). Dropping them
        instead left KITTI 05's fits to one or two frames each time the focal length moved in
        its turn, and one of them ran off to a roll of -50 deg: they stay."""
        check_focal_ratio(ratio)
        if ratio == 1.0 or self._stored == 0:
            return
        self._q[:self._stored] *= ratio
        if self.latest is not None:
            self.latest = refocused(self.latest, ratio)

    def update(self, pitch0: float = 0.0, roll0: float = 0.0) -> TiltEstimate | None:
        """Refit when due (see the class docstring), else keep `latest`; returns `latest`.

        ``pitch0, roll0`` (radians) start the very first fit (e.g. the motion-plane tilt);
        later fits start from the previous estimate."""
        due = min(max(1, self._stored * self.refit_every // self.max_frames), self.refit_every)
        if self._stored >= self.min_frames and (self.latest is None or self._since_fit >= due):
            if self.latest is None:
                fit = self.estimate(pitch0, roll0)
            else:
                # From the previous estimate the optimum moved by a fraction of a standard
                # deviation: 4 steps of the linearly converging IRLS (a factor of about 3
                # each) leave about 1 % of that move; the next refit continues from there.
                fit = self.estimate(self.latest.pitch, self.latest.roll, iterations=4)
            self.latest = fit or self.latest
        return self.latest

    def estimate(self, pitch0: float = 0.0, roll0: float = 0.0, iterations: int = 8
                 ) -> TiltEstimate | None:
        """Fit now from ``(pitch0, roll0)`` (radians): Gauss-Newton with Cauchy IRLS weights
        (see the module docstring), at most ``iterations`` steps, stopping once a step is below
        1 % of the model-based standard deviation (IRLS converges linearly; from the previous
        estimate that takes 2-4 steps). Returns None with fewer than ``min_frames`` pairs or a
        degenerate fit (e.g. all road ACs of every pair on one image row)."""
        if self._stored < self.min_frames:
            return None
        self._since_fit = 0
        self.fits += 1
        nf = self._stored                       # the ring fills rows 0.. first: these rows
        qx, qy = self._q[:nf, :, 0], self._q[:nf, :, 1]
        lc, w0 = self._lc[:nf], self._w[:nf]
        valid = w0 > 0
        p, r = float(pitch0), float(roll0)
        w = w0.copy()
        fitted = False
        for _ in range(iterations):
            n = normal_from_tilt(p, r)
            Jn = normal_tilt_jacobian(p, r)
            nq = qx * n[0] + qy * n[1] + n[2]
            front = valid & (nq > 0)            # a ray above the normal's horizon: not road
            nq = np.where(front, nq, 1.0)
            x = lc - np.log(nq)
            wf = w * front
            # Residuals after removing the weighted per-frame means, and their Jacobian
            # (per-frame sums along the rows; empty slots have weight 0).
            W = np.maximum(wf.sum(1), 1e-300)
            e = (x - ((wf * x).sum(1) / W)[:, None]) * front
            J = []
            for k in range(2):
                jk = -(qx * Jn[0, k] + qy * Jn[1, k] + Jn[2, k]) / nq
                J.append((jk - ((wf * jk).sum(1) / W)[:, None]) * front)
            spread = MAD_TO_SIGMA * median(np.abs(e[front])) + 1e-12 if front.any() else 1.0
            w = w0 * front / (1.0 + (e / (_CAUCHY_SCALE * spread)) ** 2)
            we = w * e
            # The 2x2 normal equations as dot products of the flattened arrays (two weighted
            # arrays instead of one per sum; the results in plain floats: numpy's per-call
            # overhead would cost more than the arithmetic).
            j0, j1 = J[0].ravel(), J[1].ravel()
            wj0, wj1 = w.ravel() * j0, w.ravel() * j1
            h00, h01, h11 = float(wj0 @ j0), float(wj0 @ j1), float(wj1 @ j1)
            fitted = True
            det = h00 * h11 - h01 ** 2
            if not det > 1e-12 * max(h00 * h11, 1e-300):
                return None
            i00, i01, i11 = h11 / det, -h01 / det, h00 / det
            wer = we.ravel()
            g0, g1 = float(wer @ j0), float(wer @ j1)
            s0, s1 = i00 * g0 + i01 * g1, i01 * g0 + i11 * g1
            p, r = p - s0, r - s1
            factor = float(wer @ e.ravel()) / max(float(w.sum()), 1e-300)
            if (abs(s0) <= max(1e-7, 0.01 * math.sqrt(max(i00 * factor, 0.0)))
                    and abs(s1) <= max(1e-7, 0.01 * math.sqrt(max(i11 * factor, 0.0)))):
                break
        if not fitted:
            return None
        # Sandwich covariance, frames as clusters, never below the model-based one (residual
        # variance times H^-1), widened for few frames (Student t with nf - 1 degrees of
        # freedom; a single frame gets the model-based one with the two-frame factor).
        Hinv = np.array([[i00, i01], [i01, i11]])
        model = Hinv * factor
        S = np.column_stack([(we * J[0]).sum(1), (we * J[1]).sum(1)])
        cov = Hinv @ (S.T @ S) @ Hinv * nf / (nf - 1) if nf > 1 else np.zeros((2, 2))
        cov = np.maximum(cov, model) * few_cluster_factor(max(nf, 2), 1.0) ** 2
        return TiltEstimate(p, r, math.sqrt(cov[0, 0]), math.sqrt(cov[1, 1]),
                            normal_from_tilt(p, r), int(nf))


def pair_road_normal(q1: np.ndarray, q2: np.ndarray, R: np.ndarray, t: np.ndarray,
                     road: np.ndarray, weights: np.ndarray | None, pitch0: float, roll0: float,
                     iterations: int = 4, *, check: bool = True) -> TiltEstimate | None:
    """The road normal from one frame pair's road ACs alone (all of them), by the same fit as
    `RoadNormalCalibrator` started from ``(pitch0, roll0)``, with its model-based standard
    deviations (one frame: no clusters to sandwich). None with fewer than 10 road ACs in
    front of both views or a degenerate fit. Arguments as in `RoadNormalCalibrator.add`."""
    count = int(np.count_nonzero(np.asarray(road, dtype=bool)))
    one = RoadNormalCalibrator(per_frame=max(count, _MIN_ROAD), max_frames=2)
    if not one.add(q1, q2, R, t, road, weights, check=check):
        return None
    return one.estimate(pitch0, roll0, iterations=iterations)
