"""Estimate the camera's pitch and roll relative to the plane of motion from many frame pairs.

A vehicle moving on a plane moves its camera within that plane and turns it about the plane's
normal. In the camera frame of a tilted camera (relative pose ``X2 = R X1 + t``):

- the displacement ``c = -R^T t`` lies in the motion plane: ``n . c = 0``;
- the rotation axis of ``R`` is the plane normal: ``n x axis(R) = 0``.

`MountTiltEstimator` accumulates these constraints over frame pairs and fits the unit normal
``n`` (pointing down, the camera's y axis when level) as the eigenvector of the smallest
eigenvalue of

    M = sum_i w_i c_i c_i^T + sum_j v_j (I - a_j a_j^T),

by iteratively reweighted least squares with Cauchy weights (outlier frames: bumps, bad poses).
With the level camera of `planar_vo.frontend.correction.leveling_rotation`
(``R_lc = R_BO^T Ry(pitch) Rx(roll) R_BO``), the normal in camera coordinates is

    n = R_lc^T [0, 1, 0] = [sin(roll) cos(pitch), cos(roll) cos(pitch), sin(pitch)],

so ``pitch = asin(n_z)`` and ``roll = atan2(n_x, n_y)``. Driving straight constrains only the
pitch (``n`` is then only known to be perpendicular to the forward direction); the roll comes
from turns (rotation axes, sideways displacements). The reported standard deviations come from
the Fisher information of the fit, scaled by its residuals, so an unobservable roll shows as a
large ``roll_std``.

Real roads add a wobble to every relative rotation (the car's pitch and roll, 0.04-0.11 deg per
KITTI frame pair): rotations not clearly larger than it inform nothing about the axis
(`MountTiltEstimator`, ``wobble_sigma``), else straight driving locks the normal onto the
camera's x axis (a reported roll of 85-88 deg).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass

import numpy as np

from planar_vo.config.sections import MountConfig
from planar_vo.core.checks import as_array, as_rotation
from planar_vo.core.conventions import normal_from_tilt, normal_tilt_jacobian, tilt_from_normal
from planar_vo.core.robust.stats import MAD_TO_SIGMA
from planar_vo.errors import ConfigError, InputError

__all__ = ['MountTiltEstimator', 'TiltEstimate', 'check_focal_ratio', 'focal_pitch', 'refocused']

logger = logging.getLogger(__name__)

_IRLS_ITERATIONS = 8
_CAUCHY_SCALE = 2.5          # residuals (in units of their robust spread) at which weight = 1/2


@dataclass(frozen=True)
class TiltEstimate:
    """The camera's tilt relative to the plane of motion.

    Attributes:
        pitch, roll: radians, in the convention of `MountConfig` (positive pitch looks down).
        pitch_std, roll_std: standard deviations (radians); ``inf`` when not observable.
        normal: unit normal of the motion plane in camera coordinates (pointing down), ``(3,)``.
        frames: number of frame pairs used (with non-zero weight).
    """

    pitch: float
    roll: float
    pitch_std: float
    roll_std: float
    normal: np.ndarray
    frames: int

    def levelling_angles(self, max_std: float = np.deg2rad(0.5)) -> tuple[float, float]:
        """``(pitch, roll)`` to level with: an angle known no better than ``max_std`` (radians)
        is taken as 0, since levelling by a wrong angle does more harm than not levelling
        (KITTI 06 drives nearly straight: its roll is unobservable, std about 3 deg)."""
        return (self.pitch if self.pitch_std <= max_std else 0.0,
                self.roll if self.roll_std <= max_std else 0.0)


def _rotation_axis_angle(R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit axes ``(N, 3)`` and angles ``(N,)`` of rotations ``(N, 3, 3)`` (axis 0 when angle 0)."""
    w = np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], -1)
    s = 0.5 * np.linalg.norm(w, axis=1)
    c = 0.5 * (np.trace(R, axis1=1, axis2=2) - 1.0)
    angle = np.arctan2(s, c)
    with np.errstate(invalid='ignore', divide='ignore'):
        axis = np.where(s[:, None] > 0, w / (2.0 * s[:, None]), 0.0)
    return axis, angle


def focal_pitch(pitch: float, ratio: float) -> float:
    """The pitch (radians) of a normal measured with focal length ``f_old``, carried to
    ``f_new`` (``ratio = f_old / f_new``, the principal point unchanged).

    The image measures the horizon's offset ``f tan(pitch)``, not the angle: a normal
    ``n`` seen through ``K_old`` is ``M^-T n`` through ``K_new``, ``M = K_new^-1 K_old =
    diag(ratio, ratio, 1)``, which keeps the roll and gives ``tan(pitch') = ratio tan(pitch)``.
    """
    return math.atan(ratio * math.tan(pitch))


def check_focal_ratio(ratio: float) -> None:
    """Raise `InputError` unless ``ratio`` (``f_old / f_new`` of a ``refocus``) is positive."""
    if not (math.isfinite(ratio) and ratio > 0):
        raise InputError(f'ratio: expected a positive focal-length ratio, got {ratio}')


def refocused(estimate: TiltEstimate, ratio: float) -> TiltEstimate:
    """``estimate`` carried to a new focal length (`focal_pitch`; its pitch standard deviation
    through the same map's derivative)."""
    pitch = focal_pitch(estimate.pitch, ratio)
    slope = ratio * (1.0 + math.tan(estimate.pitch) ** 2) / (1.0 + math.tan(pitch) ** 2)
    return dataclasses.replace(estimate, pitch=pitch, pitch_std=estimate.pitch_std * slope,
                               normal=normal_from_tilt(pitch, estimate.roll))


class MountTiltEstimator:
    """Accumulates relative camera poses; reports pitch and roll of the camera w.r.t. the plane
    of motion (`TiltEstimate`).

    Pitch wobble. A car's relative rotation is a yaw about the normal plus a wobble: its pitch
    and roll on the suspension and the road's unevenness (KITTI: 0.04-0.11 deg per frame pair
    of the ground truth). When the rotation angle is comparable to the wobble, its axis is the
    wobble's, not the normal: fitted as an axis, straight driving turned the normal towards the
    camera's x axis (KITTI 05 pairs 0-99: roll 85-88 deg, pitch 0.15-0.40 deg, with
    ground-truth and five-point poses alike). So a rotation informs the axis only if its angle
    exceeds ``gate`` times ``wobble_sigma``, with the axis noise ``hypot(rotation_sigma,
    wobble_sigma) / angle``. The wobble is settable at any time (`wobble_sigma`): the odometry
    measures the real non-planarity of the drive; the default is only the start. With
    ``wobble_sigma = 0`` every rotation informs the axis (the model before the wobble).

    Bounded memory and cost: the last ``max_pairs`` pairs are kept (8 floats each); `update`
    refits after ``refit_every`` new pairs (or a new wobble) and returns the cached estimate
    otherwise, so its amortised cost is ``1 / refit_every`` of a fit over ``max_pairs``.

    Args:
        translation_sigma: expected angular error of a pair's translation direction (radians).
        rotation_sigma: expected error of a pair's rotation estimate (radians); the axis of a
            rotation by ``theta`` is known to about ``rotation_sigma / theta``.
        min_translation: pairs whose translation norm is below this (in the units passed to
            `add_motion`) contribute only their rotation; 0 uses every direction.
        prior_sigma: standard deviation (radians) of a prior that the camera is level; keeps
            the roll defined (near 0, with about this uncertainty) while the vehicle only drives
            straight. None: no prior (unobservable angles then report ``inf``).
        wobble_sigma: standard deviation (radians) of a pair's rotation about axes other than
            the normal (``mount.tilt_wobble_std``).
        gate: a rotation informs the axis only above ``gate * wobble_sigma`` (3: 99.7 % of the
            pure-wobble rotations about one axis fall below).
        max_pairs: pairs kept (the most recent; ``mount.tilt_window``).
        refit_every: new pairs between refits in `update` (``mount.tilt_refit``).
        systematic_sigma: standard deviation (radians) of what all pairs share and no number
            of pairs averages away (the front-end's systematic direction error: 0.02 deg on the
            rendered test drives), added to the fitted angles' standard deviations.

    Example:
        >>> est = MountTiltEstimator()
        >>> for R, t in poses:            # X2 = R X1 + t, camera frame
        ...     est.add_motion(R, t)
        ...     tilt = est.update()       # None before 2 pairs; refitted every 10 pairs
        >>> est.wobble_sigma = measured   # the odometry's non-planarity (rad), any time
    """

    def __init__(self, translation_sigma: float = np.deg2rad(1.0),
                 rotation_sigma: float = np.deg2rad(0.05), min_translation: float = 0.0,
                 prior_sigma: float | None = np.deg2rad(5.0), *,
                 wobble_sigma: float = MountConfig.tilt_wobble_std, gate: float = 3.0,
                 max_pairs: int = MountConfig.tilt_window,
                 refit_every: int = MountConfig.tilt_refit,
                 systematic_sigma: float = np.deg2rad(0.05)) -> None:
        if not (translation_sigma > 0 and rotation_sigma > 0):
            raise InputError(f'translation_sigma, rotation_sigma: expected positive angles, got '
                             f'{translation_sigma}, {rotation_sigma}')
        self.translation_sigma = float(translation_sigma)
        self.rotation_sigma = float(rotation_sigma)
        self.min_translation = float(min_translation)
        if prior_sigma is not None and not prior_sigma > 0:
            raise InputError(f'prior_sigma: expected a positive angle or None, got {prior_sigma}')
        self.prior_sigma = prior_sigma
        if not (gate > 0 and max_pairs >= 2 and refit_every >= 1):
            raise ConfigError(f'gate, max_pairs, refit_every: expected > 0, >= 2, >= 1, got '
                              f'{gate}, {max_pairs}, {refit_every}')
        self.gate = float(gate)
        if not (math.isfinite(systematic_sigma) and systematic_sigma >= 0):
            raise InputError(f'systematic_sigma: expected a non-negative angle, got '
                             f'{systematic_sigma}')
        self.systematic_sigma = float(systematic_sigma)
        self.max_pairs = int(max_pairs)
        self.refit_every = int(refit_every)
        self.wobble_sigma = wobble_sigma
        cap = self.max_pairs
        self._directions = np.zeros((cap, 3))   # unit displacement directions (0: none)
        self._axes = np.zeros((cap, 3))         # rotation axes
        self._angles = np.zeros(cap)            # rotation angles (rad)
        self._weights = np.zeros(cap)
        self._next = 0
        self._count = 0
        self._since_fit = 0
        self.fits = 0                           # fits run so far (cost accounting)
        self.latest: TiltEstimate | None = None

    @property
    def wobble_sigma(self) -> float:
        """Standard deviation (rad) of the per-pair rotation about axes other than the normal;
        setting it makes the next `update` refit."""
        return self._wobble

    @wobble_sigma.setter
    def wobble_sigma(self, value: float) -> None:
        if not (math.isfinite(value) and value >= 0.0):
            raise InputError(f'wobble_sigma: expected a non-negative angle (rad), got {value}')
        self._wobble = float(value)
        self._since_fit = self.refit_every      # the gate changed: refit at the next update

    def __len__(self) -> int:
        return self._count

    def add_motion(self, R: np.ndarray, t: np.ndarray, weight: float = 1.0) -> None:
        """Add one relative camera pose ``X2 = R X1 + t`` (camera optical frame).

        Args:
            R: rotation (3x3). t: translation (3,), any scale (its norm only gates
                ``min_translation``). weight: relative confidence of this pair.
        """
        R = as_rotation('R', R)
        t = as_array('t', t, (3,))
        if not (math.isfinite(weight) and weight >= 0.0):
            raise InputError(f'weight: expected a non-negative number, got {weight}')
        c = -R.T @ t
        norm = float(np.linalg.norm(c))
        k = self._next
        self._directions[k] = c / norm if norm > self.min_translation and norm > 0 else 0.0
        axis, angle = _rotation_axis_angle(R[None])
        self._axes[k], self._angles[k] = axis[0], angle[0]
        self._weights[k] = float(weight)
        self._next = (k + 1) % self.max_pairs
        self._count = min(self._count + 1, self.max_pairs)
        self._since_fit += 1

    def refocus(self, ratio: float) -> None:
        """Carry the stored pairs to a new focal length (``ratio = f_old / f_new``; the focal
        self-calibration changes the one in use).

        A pair's motion was estimated through the old focal length: its displacement direction
        is the epipole seen through ``K_old``, so through ``K_new`` it is ``M c`` with ``M =
        K_new^-1 K_old = diag(ratio, ratio, 1)``; its angle keeps the pixel shift of its part
        in the image plane (``f tan(angle)`` about the camera's x and y axes; a turn about the
        optical axis is the same through any focal length). Its axis is pulled by the
        estimator's planar prior towards the levelling, a normal, and moves like one
        (``M^-T a``, i.e. ``diag(1, 1, ratio)`` up to scale; a review measured per-pair fits
        through 1226 instead of 707 px at 0.58-0.82 of the true axis tilt, and on a rendered
        drive this map left the tilt 0.03 deg off where ``M a`` left it 0.17 deg off).
        Without this, pairs from a provisional focal length 1.7 times too long (KITTI 05
        before its first turn: pitch 0.56 instead of 0.98 deg) stay in the fit: it ended 0.19
        deg (2.9 sigma) short after the calibration. `latest` is carried along (`refocused`)
        and refitted at the next `update` (one fit more per change of the focal length, every
        few frames while it calibrates in a turn)."""
        check_focal_ratio(ratio)
        m = self._count
        if ratio == 1.0 or m == 0:
            return
        for vectors, scale in ((self._directions[:m], (ratio, ratio, 1.0)),
                               (self._axes[:m], (1.0, 1.0, ratio))):
            vectors *= np.array(scale)
            norms = np.linalg.norm(vectors, axis=1, keepdims=True)
            np.divide(vectors, norms, out=vectors, where=norms > 0)
        # Through the old focal length the rotation about the (new) axis a turned by
        # atan(|M^-1 a| tan(angle)): its image-plane part seen 1 / ratio as large.
        angles = self._angles[:m]
        seen = np.linalg.norm(self._axes[:m] * np.array([1.0 / ratio, 1.0 / ratio, 1.0]), axis=1)
        angles[:] = np.arctan2(np.sin(angles), np.where(seen > 0, seen, 1.0) * np.cos(angles))
        if self.latest is not None:
            self.latest = refocused(self.latest, ratio)
        self._since_fit = self.refit_every

    def update(self) -> TiltEstimate | None:
        """The estimate, refitted when ``refit_every`` pairs were added (or the wobble set)
        since the last fit; None before two pairs."""
        if self._count >= 2 and (self.latest is None or self._since_fit >= self.refit_every):
            self.latest = self.estimate()
        return self.latest

    def estimate(self) -> TiltEstimate:
        """Fit the motion-plane normal to all pairs so far (IRLS, Cauchy weights).

        Raises:
            InputError: fewer than two pairs with a usable translation or rotation.
        """
        if len(self) < 2:
            raise InputError(f'MountTiltEstimator: expected at least 2 frame pairs, got '
                             f'{len(self)}')
        self._since_fit = 0
        self.fits += 1
        m = self._count
        C, axis, angle = self._directions[:m], self._axes[:m], self._angles[:m]
        base = self._weights[:m]
        wt0 = base * np.any(C != 0, axis=1) / self.translation_sigma ** 2
        # The axis error is ~hypot(rotation_sigma, wobble) / angle: the information grows with
        # angle^2; rotations within the wobble carry the wobble's axis, not the normal.
        informs = angle > self.gate * self._wobble
        wr0 = base * informs * angle ** 2 / (self.rotation_sigma ** 2 + self._wobble ** 2)
        wt, wr = wt0.copy(), wr0.copy()
        eye = np.eye(3)
        down = np.array([0.0, 1.0, 0.0])
        # The level prior acts like one rotation about the camera's y axis.
        prior = 0.0 if self.prior_sigma is None else 1.0 / self.prior_sigma ** 2
        prior_M = prior * (eye - np.outer(down, down))
        n = down
        for _ in range(_IRLS_ITERATIONS):
            M = (C * wt[:, None]).T @ C + wr.sum() * eye - (axis * wr[:, None]).T @ axis \
                + prior_M
            vals, vecs = np.linalg.eigh(M)
            n = vecs[:, 0] * (1.0 if vecs[1, 0] >= 0 else -1.0)
            # Normalised residuals: translation-direction elevation and axis deviation.
            rt = (C @ n) * np.sqrt(wt0)
            rr = np.linalg.norm(np.cross(axis, n), axis=1) * np.sqrt(wr0)
            res = np.concatenate([rt[wt0 > 0], rr[wr0 > 0]])
            # Robust spread of the residuals (in units of the declared sigmas), at least 1:
            # residuals within the declared accuracy are never down-weighted.
            spread = max(MAD_TO_SIGMA * float(np.median(np.abs(res))) if res.size else 1.0, 1.0)
            wt = wt0 / (1.0 + (rt / (_CAUCHY_SCALE * spread)) ** 2)
            wr = wr0 / (1.0 + (rr / (_CAUCHY_SCALE * spread)) ** 2)
        pitch, roll = tilt_from_normal(n)
        Jn = normal_tilt_jacobian(pitch, roll)
        # Fisher information of the data in (pitch, roll).
        jt = C @ Jn                                             # (N, 2)
        axes_info = wr.sum() * eye - (axis * wr[:, None]).T @ axis   # sum wr (I - a a^T)
        info = (jt * wt[:, None]).T @ jt + Jn.T @ axes_info @ Jn
        chi2 = float(np.sum(wt * (C @ n) ** 2) + np.sum(wr * np.linalg.norm(
            np.cross(axis, n), axis=1) ** 2))
        used = int(np.count_nonzero((wt > 0) | (wr > 0)))
        dof = max(np.count_nonzero(wt) + 2 * np.count_nonzero(wr) - 2, 1)
        scale = max(chi2 / dof, 1e-30)
        # The data's variance factor (chi2 / dof) rescales the sigmas given at construction;
        # the prior keeps its own scale.
        info = info / scale + Jn.T @ prior_M @ Jn
        # Directions of (pitch, roll) with no information (e.g. the roll when only driving
        # straight) get an infinite standard deviation rather than a huge finite one.
        evals, evecs = np.linalg.eigh(info)
        observable = evals > 1e-9 * max(evals[-1], 1e-300)
        var = np.einsum('ak,k->a', evecs ** 2, np.where(observable, 1.0 / np.where(
            observable, evals, 1.0), 0.0))
        blind = np.any((np.abs(evecs) > 1e-6) & ~observable[None, :], axis=1)
        stds = np.where(blind, np.inf, np.sqrt(var + self.systematic_sigma ** 2))
        return TiltEstimate(pitch, roll, float(stds[0]), float(stds[1]), n, used)
