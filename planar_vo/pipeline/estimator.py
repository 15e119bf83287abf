"""`MotionEstimator`: one frame pair's relative pose, planar voting in front, general answer out.

For one pair of views (ACs in normalised coordinates of the camera, and the same ACs levelled by
the current mount tilt ``R_lc``, camera -> level camera):

1. `vote_planar_motion` (1AC + histogram voting) on the levelled ACs: the robust,
   deterministic, outlier-ratio-independent front (candidates, inliers, initial motion);
2. starting hypotheses: the vote lifted to the camera frame (``R_lc^T Ry(a) R_lc``,
   ``R_lc^T [cos b, 0, sin b]``) and the previous pair's motion (constant velocity), each scored
   by the MSAC cost ``sum_i w_i min(chi2_i, gate)`` over ALL ACs at the vote's coarse noise
   scales;
3. the best start is refined (`refine_general_motion`: 5 DoF, all three AC constraints,
   whitened by first-order noise propagation, Cauchy IRLS, inliers re-selected over all ACs
   every round, noise scales from the data, the soft planar prior); the other start too when
   it is a different motion and not clearly worse;
4. second hypotheses when the answer explains less than half of the ACs (and less than 0.8 of
   the recent typical share) or used all its rounds: graduated non-convexity from the best start,
   the same rotation with straight-ahead travel (the other side of the rotation-translation
   valley), and a vote on the ACs the answer leaves unexplained. Each is first refined on an
   even sample of at most ``_SCREEN_SIZE`` ACs (it only has to find its basin); one that lands
   on the first answer's motion confirms it and is dropped, one that lands elsewhere with a
   support that could matter is refined again on all ACs and competes. A first answer that
   settled before its last round at the nominal accuracy of ACs (``voting.point_noise``,
   ``affine_noise``) is in its basin and gets only the vote on the unexplained ACs, and that
   only when its inliers could matter: with random outliers (50-70 %, the estimator tests' 108
   pairs) the graduated and straight-ahead starts only ever confirmed such an answer, and found
   the right one exactly where the first answer had used all its rounds;
5. the answers compete on their support (MSAC gain over explaining nothing) at the tightest of
   their noise scales; an unconverged winner gets more rounds;
6. reliability: a competitor with at least ``ambiguity_ratio`` of the winner's support
   (``ambiguous``), not settled (``unconverged``), implausible noise scales (``noisy``: above
   4 x the recent median and the nominal accuracy ``voting.point_noise`` / ``affine_noise``), too
   few inliers or too small a share, an imprecise yaw (``imprecise``), a flat minimum
   (``flat``);
7. online state, from reliable pairs only: noise scales, inlier share, the non-planarity
   behind the prior (robust centre and spread of the recent motions' level pitch/roll and
   elevation of travel), the previous motion.

With ``model: planar`` the vote's planar motion is the answer (the paper's estimator), its
covariance completed by the measured non-planarity.

Nothing is tuned to a drive: the prior's sigma and mean, the noise scales, the typical inlier
share are measured online; the remaining thresholds are statistical (chi-square quantiles,
sigmas) or generic.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from planar_vo.core.conventions import rotation_y, so3_exp, so3_log, translation_direction
from planar_vo.core.correspondences import AffineCorrespondences
from planar_vo.core.robust import VotingConfig, vote_planar_motion
from planar_vo.core.robust.general import (
    CHI2_3_99,
    GATE,
    PRIOR_SIGMAS,
    PlanarPrior,
    ac_design,
    chi_square,
    chi_squares,
    essential,
    noise_scales,
    refine_general_motion,
    residual_variances,
    tangent_basis,
)
from planar_vo.core.robust.options import EstimatorConfig
from planar_vo.core.robust.stats import MAD_TO_SIGMA, median
from planar_vo.errors import ConfigError, InputError

__all__ = ['FrameEstimate', 'MotionEstimator', 'lift_planar']

# Answers further apart than this are different solutions.
_DISTINCT_ROTATION = math.radians(0.3)
_DISTINCT_DIRECTION = math.radians(5.0)
_SECOND_START_RATIO = 1.5     # a second start is refined if its MSAC cost is below this x best
# A well-posed answer is a sharp minimum: turning the rotation by _PERTURBATION about the
# vertical, or the direction of travel by 5 x that, raises the MSAC cost by at least
# _FLAT_RISE per inlier.
_PERTURBATION = math.radians(1.0)
_FLAT_RISE = 0.2
_HISTORY_MIN = 10             # frames before the measured history replaces the start values
_PRIOR_FLOOR = (math.radians(0.02), math.radians(0.1))
_RECHECK_SHARE, _RECHECK_RELATIVE, _GNC_INFLATION = 0.5, 0.8, 4.0
# The second hypotheses find their basins on an even sample of this many ACs, in at most this
# many selection rounds (step 4) ...
_SCREEN_SIZE = 300
_SCREEN_ROUNDS = 4
# ... and one whose support on the sample is below this share of the ambiguity ratio times
# the first answer's is dropped there.
_SCREEN_MARGIN = 0.5
# Noise scales above this many times the recent median flag the frame; before any history the
# generic caps of the voting (5 x its default noise levels) apply.
_MAX_SCALE_RATIO = 4.0
_MAX_SCALES = (5e-3, 0.1)


# The configurations are frozen: one default instance (and one screening variant per
# configuration) serves every estimator; validating them costs more than a fresh estimator's
# whole set-up otherwise.
_DEFAULT_ESTIMATOR = EstimatorConfig()
_DEFAULT_VOTING = VotingConfig()


@functools.lru_cache(maxsize=8)
def _screen_config(config: EstimatorConfig) -> EstimatorConfig:
    """``config`` with at most ``_SCREEN_ROUNDS`` selection rounds (for the screening)."""
    return dataclasses.replace(config, rounds=min(config.rounds, _SCREEN_ROUNDS))


def lift_planar(alpha: float, beta: float, R_lc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Planar motion of the level camera -> the camera-frame motion ``(R, t)``."""
    return (R_lc.T @ rotation_y(alpha) @ R_lc,
            R_lc.T @ translation_direction(beta))


def _rotation_distance(Ra: np.ndarray, Rb: np.ndarray) -> float:
    return float(np.linalg.norm(so3_log(Ra @ Rb.T)))


def _direction_distance(ta: np.ndarray, tb: np.ndarray) -> float:
    return math.acos(max(-1.0, min(1.0, float(ta @ tb))))


def _same_motion(Ra: np.ndarray, ta: np.ndarray, Rb: np.ndarray, tb: np.ndarray) -> bool:
    """Two answers closer than the distinctness thresholds are the same solution."""
    return (_rotation_distance(Ra, Rb) < _DISTINCT_ROTATION
            and _direction_distance(ta, tb) < _DISTINCT_DIRECTION)


@dataclass
class FrameEstimate:
    """The motion of one frame pair.

    Attributes:
        R (3, 3), t (3,): relative pose ``X2 = R X1 + t`` (camera frame, unit ``t``).
        cov: (5, 5) covariance of ``(w, d)``: ``R <- exp([w]x) R``, ``t <- normalise(t + B d)``.
        basis: (3, 2) tangent basis ``B`` of ``t`` for ``cov``.
        inliers: (N,) bool over the pair's ACs.
        reliable, flag: usable or not, and why not (``'no_vote'``, ``'too_few_inliers'``,
            ``'low_share'``, ``'imprecise'``, ``'ambiguous'``, ``'flat'``, ``'unconverged'``,
            ``'noisy'``).
        vote: ``(alpha, beta, reliable)`` of the planar vote (level frame).
        stats: diagnostics (start used, costs, scales, rounds, ``answers``: the answers that
            competed, ``screened``: second hypotheses screened on a sample, ...).
    """

    R: np.ndarray
    t: np.ndarray
    cov: np.ndarray
    basis: np.ndarray
    inliers: np.ndarray
    reliable: bool
    flag: str | None
    vote: tuple[float, float, bool]
    stats: dict = field(default_factory=dict)

    @property
    def num_inliers(self) -> int:
        return int(np.count_nonzero(self.inliers))


class MotionEstimator:
    """Frame pairs in, relative poses out, with the online state between pairs (module
    docstring).

    Args:
        config: `EstimatorConfig`.
        voting: `VotingConfig` of the planar vote.

    Raises:
        ConfigError: ``config`` or ``voting`` of another type.

    Attributes:
        R_lc: the levelling rotation (camera -> level camera) the pipeline keeps up to date.
    """

    def __init__(self, config: EstimatorConfig | None = None,
                 voting: VotingConfig | None = None) -> None:
        for name, value, kind in (('config', config, EstimatorConfig),
                                  ('voting', voting, VotingConfig)):
            if value is not None and not isinstance(value, kind):
                raise ConfigError(f'{name}: expected {kind.__name__} or None, got '
                                  f'{type(value).__name__}')
        self.config = _DEFAULT_ESTIMATOR if config is None else config
        self.voting = _DEFAULT_VOTING if voting is None else voting
        self.R_lc = np.eye(3)
        self._screen_config = _screen_config(self.config)
        self.reset()

    def reset(self) -> None:
        """Forget the previous motion and the measured history."""
        n = self.config.history
        self.previous: tuple[np.ndarray, np.ndarray] | None = None
        self._motions: deque[np.ndarray] = deque(maxlen=n)
        self._scales: deque[tuple[float, float]] = deque(maxlen=n)
        self._shares: deque[float] = deque(maxlen=n)

    def refocus(self, ratio: float) -> None:
        """Carry the history to a new focal length (``ratio = f_old / f_new``; the focal
        self-calibration changes the one in use): rotations keep the pixel shift of their part
        about the camera's x and y axes, directions their epipole (``M = diag(ratio, ratio,
        1)``), point noise scales their pixels; otherwise the planar prior's centre stays where
        the old focal length put it until half the history is replaced (a review: the
        elevation of travel 0.6 deg off for 50 frames)."""
        if ratio == 1.0:
            return
        scale = np.array([ratio, ratio, 1.0])
        for k, motion in enumerate(self._motions):
            c = motion[3:] * scale
            self._motions[k] = np.concatenate([motion[:3] * scale, c / np.linalg.norm(c)])
        for k, (sp, sa) in enumerate(self._scales):
            self._scales[k] = (sp * ratio, sa)
        if self.previous is not None:
            R, t = self.previous
            R = so3_exp(so3_log(R) * scale)
            t = t * scale
            self.previous = (R, t / np.linalg.norm(t))

    @property
    def scales(self) -> tuple[float, float] | None:
        """The noise scales (point, affine) of the last reliable pair, or None."""
        return self._scales[-1] if self._scales else None

    # -- the prior ------------------------------------------------------------------------------

    def prior(self) -> PlanarPrior | None:
        """The planar prior from the recent motions (robust centre and spread), or None."""
        if not self.config.use_prior:
            return None
        if len(self._motions) < _HISTORY_MIN:
            return PlanarPrior(self.R_lc, *PRIOR_SIGMAS, np.zeros(3))
        terms = self._level_terms()
        centre = _column_medians(terms)
        spread = np.abs(terms - centre)
        sigma_rot = max(MAD_TO_SIGMA * median(spread[:, :2].ravel()), _PRIOR_FLOOR[0])
        sigma_elev = max(MAD_TO_SIGMA * median(spread[:, 2]), _PRIOR_FLOOR[1])
        return PlanarPrior(self.R_lc, sigma_rot, sigma_elev, centre)

    @property
    def non_planarity(self) -> float:
        """The measured spread (rad) of the pairs' rotation about the level horizontal axes
        (the car's pitch and roll on its suspension and the road), NaN before enough pairs."""
        if len(self._motions) < _HISTORY_MIN:
            return float('nan')
        rotations = self._level_terms()[:, :2]
        spread = np.abs(rotations - _column_medians(rotations))
        return MAD_TO_SIGMA * median(spread.ravel())

    def _level_terms(self) -> np.ndarray:
        """``(K, 3)`` level pitch and roll rotation and elevation of travel of the history."""
        h = np.array(self._motions)                           # (K, 6): log R, direction c
        rho = h[:, :3] @ self.R_lc.T                          # log(R_lc R R_lc^T) = R_lc log R
        c = h[:, 3:] @ self.R_lc.T
        return np.column_stack([rho[:, 0], rho[:, 2], np.arcsin(np.clip(c[:, 1], -1.0, 1.0))])

    # -- one frame pair ---------------------------------------------------------------------------

    def estimate(self, acs: AffineCorrespondences, level: AffineCorrespondences
                 ) -> FrameEstimate:
        """The motion of one pair from its ACs in normalised camera coordinates (``acs``) and
        the same ACs levelled by `R_lc` (``level``, same order and length).

        Too few ACs (none at all included) give an unreliable estimate whose flag says why.

        Raises:
            InputError: either is not an `AffineCorrespondences`, their lengths differ, or a
                weight is negative.
        """
        for name, value in (('acs', acs), ('level', level)):
            if not isinstance(value, AffineCorrespondences):
                raise InputError(f'{name}: expected AffineCorrespondences, got '
                                 f'{type(value).__name__}')
        if len(acs) != len(level):      # (a user test: it gave 'no_vote', not why)
            raise InputError(f'level: expected the {len(acs)} ACs of acs levelled, got '
                             f'{len(level)}')
        for name, value in (('acs', acs), ('level', level)):
            # (AffineCorrespondences checks shapes and finiteness; the votes below skip their
            # own checks of the same arrays)
            if len(value) and not value.weights.min() >= 0:
                raise InputError(f'{name}: expected non-negative weights, got minimum '
                                 f'{value.weights.min()}')
        # (with model: planar the vote is the answer: the Sampson cost's own minimum; else the
        # general refinement follows from it)
        planar = self.config.model == 'planar'
        motion, vstats = vote_planar_motion(level.p1, level.p2, level.A, level.weights,
                                            self.voting, covariance=planar, check=False,
                                            sampson=planar)
        vote = (motion.alpha, motion.beta, bool(vstats.reliable))
        if self.config.model == 'planar':
            return self._planar(acs, motion, vstats, vote)
        limit = self.config.max_correspondences
        if 0 < limit < len(acs):
            # The vote saw every AC; the refinement needs only an even sample of them (its
            # cost grows with the count, its accuracy hardly beyond a few hundred). The inliers
            # are judged on every AC at the end.
            pick = np.linspace(0, len(acs) - 1, limit).astype(np.intp)
            result = self._refine(acs.subset(pick), level.subset(pick), motion, vstats, vote)
            if result.reliable or np.isfinite(result.R).all():
                chi2 = chi_square(ac_design(acs.p1, acs.p2, acs.A), acs.p1, acs.p2, acs.A,
                                  result.R, result.t, *self.scales_of(result))
                result.inliers = (chi2 <= CHI2_3_99) & (acs.weights > 0)
            else:
                result.inliers = np.zeros(len(acs), bool)
            return result
        return self._refine(acs, level, motion, vstats, vote)

    def refine_from(self, acs: AffineCorrespondences, R0: np.ndarray, t0: np.ndarray
                    ) -> FrameEstimate:
        """The motion of a longer-baseline pair refined from a predicted start (the composed
        shorter motions; no vote, no second hypotheses), judged like `estimate` plus
        ``'left_start'`` when the data moved it further from the prediction than two answers
        may differ and still be the same motion (the prediction was wrong, or the pair is).
        Without the planar prior (it describes one frame pair's wobble, not several); the
        online state gives the noise scales and is not updated."""
        q1, q2, A, w = acs.p1, acs.p2, acs.A, acs.weights
        n = len(acs)
        M = ac_design(q1, q2, A)
        sp, sa = self.scales if self.scales else (1e-3, 2e-2)
        t0 = np.asarray(t0, dtype=np.float64) / np.linalg.norm(t0)
        # Wider scales for the selection: the prediction carries the chained errors.
        chi2 = chi_square(M, q1, q2, A, R0, t0, _GNC_INFLATION * sp, _GNC_INFLATION * sa)
        active = (chi2 <= GATE) & (w > 0)
        vote = (math.nan, math.nan, False)
        if np.count_nonzero(active) < self.config.min_inliers:
            return self._failed(n, 'too_few_inliers', vote)
        best = refine_general_motion(q1, q2, A, w, R0, t0, active, _GNC_INFLATION * sp,
                                     _GNC_INFLATION * sa, prior=None,
                                     config=self.config, M=M, shrink=0.5, target=(sp, sa),
                                     extra_rounds=4)
        stats = {'start': 'prediction', 'point_scale': best.sp, 'affine_scale': best.sa,
                 'rounds': best.rounds}
        cost, _ = self._msac(M, acs, best.R, best.t, best.sp, best.sa)
        flag = self._judge(M, acs, best, cost, stats)
        if flag is None and not _same_motion(best.R, best.t, R0, t0):
            flag = 'left_start'
        return FrameEstimate(best.R, best.t, best.cov, best.basis, best.inliers, flag is None,
                             flag, vote, stats)

    @staticmethod
    def scales_of(result: FrameEstimate) -> tuple[float, float]:
        """The noise scales measured at an estimate (point, affine)."""
        return result.stats.get('point_scale', 1e-3), result.stats.get('affine_scale', 2e-2)

    def _refine(self, acs, level, motion, vstats, vote) -> FrameEstimate:
        """Steps 2-7 of the module docstring on the given ACs."""
        q1, q2, A, w = acs.p1, acs.p2, acs.A, acs.weights
        n = len(acs)
        M = ac_design(q1, q2, A)
        # Coarse noise scales for the starts (the planar model's accuracy): the vote's.
        sp = vstats.point_scale if math.isfinite(vstats.point_scale) else 1e-3
        sa = vstats.affine_scale if math.isfinite(vstats.affine_scale) else 2e-2
        starts = []
        if math.isfinite(motion.alpha) and math.isfinite(motion.beta):
            starts.append(('vote',) + lift_planar(motion.alpha, motion.beta, self.R_lc))
        if self.previous is not None:
            starts.append(('previous',) + self.previous)
        if not starts:
            return self._failed(n, 'no_vote', vote)
        scored = sorted((self._msac(M, acs, R0, t0, sp, sa) + (name, R0, t0)
                         for name, R0, t0 in starts), key=lambda item: item[0])
        prior = self.prior()
        sp0, sa0 = self.scales if self.scales else (sp, sa)
        answers = []
        for k, (cost0, chi2, name, R0, t0) in enumerate(scored):
            if k > 0 and answers:
                # Another start only when it is a different motion and not clearly worse.
                best = answers[0][1]
                if _same_motion(R0, t0, best.R, best.t):
                    continue
                if cost0 > _SECOND_START_RATIO * scored[0][0]:
                    continue
            active = (chi2 <= GATE) & (w > 0)
            if np.count_nonzero(active) < 5:
                continue
            answers.append((name, refine_general_motion(
                q1, q2, A, w, R0, t0, active, sp0, sa0, prior=prior, config=self.config, M=M)))
        if not answers:
            return self._failed(n, 'too_few_inliers', vote)
        first = answers[0][1]
        share = float(w[first.inliers].sum() / max(w.sum(), 1e-300))
        typical = (median(np.array(self._shares)) if len(self._shares) >= _HISTORY_MIN
                   else 1.0)
        unsettled = first.rounds >= self.config.rounds         # it used all its rounds
        if unsettled or share < min(_RECHECK_SHARE, _RECHECK_RELATIVE * typical):
            # A settled first answer at the nominal accuracy of ACs is in its basin: only
            # another coherent motion among the ACs it leaves unexplained could beat it.
            clean = (not unsettled and first.sp <= self.voting.point_noise
                     and first.sa <= self.voting.affine_noise)
            more, screened = self._second_hypotheses(acs, level, M, scored[0], first, prior,
                                                     (sp, sa), (sp0, sa0), revote_only=clean)
            answers += more
        else:
            screened = 0
        return self._decide(acs, M, answers, prior, vote, vstats, screened)

    def _second_hypotheses(self, acs, level, M, best_start, first, prior, coarse, start_scales,
                           revote_only: bool = False):
        """Other answers when the first explains too little or used all its rounds (module
        docstring, step 4): each screened on an even sample of the ACs, refined on all of them
        only when it found a motion other than the first answer's with a support that could
        matter. Returns the answers and the number of hypotheses screened."""
        q1, q2, A, w = acs.p1, acs.p2, acs.A, acs.weights
        n = len(acs)
        sp, sa = coarse
        starts = [] if revote_only else self._restarts(acs, M, best_start, first, coarse)
        # (c) Sequential consensus: a vote on the ACs the first answer leaves unexplained.
        # The vote runs on those ACs alone: the others would vote with weight 0, which changes
        # the answer only by rounding (the fits' sums in another order) but adds to its cost.
        unexplained = np.flatnonzero(w * ~first.inliers > 0)
        if unexplained.size >= self.config.min_inliers:
            w_rest = w[unexplained]
            m2, v2 = vote_planar_motion(level.p1[unexplained], level.p2[unexplained],
                                        level.A[unexplained], w_rest, self.voting,
                                        covariance=False, check=False, scan=False,
                                        sampson=False)
            # The revote's inliers, counted at its own coarse scales, overstate the support
            # its motion would keep at the first answer's: one below the screen's bar cannot
            # matter (with random outliers, 0.09 of the first answer's support typically and
            # 0.28 at most over the estimator tests' 108 pairs of 50-70 % outliers).
            weak = (float(w_rest[v2.inliers].sum())
                    < _SCREEN_MARGIN * self.config.ambiguity_ratio * float(w[first.inliers].sum()))
            if math.isfinite(m2.alpha) and math.isfinite(m2.beta) and not (revote_only and weak):
                R2, t2 = lift_planar(m2.alpha, m2.beta, self.R_lc)
                if not _same_motion(R2, t2, first.R, first.t):
                    sp2 = v2.point_scale if math.isfinite(v2.point_scale) else sp
                    sa2 = v2.affine_scale if math.isfinite(v2.affine_scale) else sa
                    starts.append(('revote', R2, t2, sp2, sa2, {}))
        answers, screened = [], 0
        if not starts:
            return answers, screened          # (the usual case of a settled first answer)
        pick = (np.linspace(0, n - 1, _SCREEN_SIZE).astype(np.intp) if n > _SCREEN_SIZE
                else np.arange(n))
        sample, Ms = acs.subset(pick), M[pick]
        qs1, qs2, As, ws = sample.p1, sample.p2, sample.A, sample.weights
        for label, R_s, t_s, sp_s, sa_s, schedule in starts:
            chi2 = chi_square(Ms, qs1, qs2, As, R_s, t_s, sp_s, sa_s)
            active = (chi2 <= GATE) & (ws > 0)
            if np.count_nonzero(active) < 5:
                continue
            scales = (sp_s, sa_s) if schedule else start_scales
            found = refine_general_motion(qs1, qs2, As, ws, R_s, t_s, active, *scales,
                                          prior=prior, config=self._screen_config, M=Ms,
                                          **schedule)
            screened += 1
            if _same_motion(found.R, found.t, first.R, first.t):
                continue                  # it confirms the first answer
            # A different motion that explains far less of the sample than the first answer
            # can neither win nor make the frame ambiguous (supports compared as in
            # `_decide`, at the tighter of the two answers' noise scales).
            sp_c, sa_c = min(first.sp, found.sp), min(first.sa, found.sa)
            zero = float(ws.sum()) * GATE
            gains = [zero - self._msac(Ms, sample, g.R, g.t, sp_c, sa_c)[0]
                     for g in (first, found)]
            if gains[1] < _SCREEN_MARGIN * self.config.ambiguity_ratio * gains[0]:
                continue
            chi2 = chi_square(M, q1, q2, A, found.R, found.t, found.sp, found.sa)
            active = (chi2 <= GATE) & (w > 0)
            if np.count_nonzero(active) >= 5:
                answers.append((label, refine_general_motion(
                    q1, q2, A, w, found.R, found.t, active, found.sp, found.sa,
                    prior=prior, config=self.config, M=M)))
        return answers, screened

    def _restarts(self, acs, M, best_start, first, coarse) -> list:
        """Second hypotheses (a) and (b) of `_second_hypotheses`: ``(label, R, t, sp, sa,
        schedule)``."""
        q1, q2, A, w = acs.p1, acs.p2, acs.A, acs.weights
        sp, sa = coarse
        _, chi2_0, _, R0, t0 = best_start
        # (a) Graduated non-convexity from the best start: scales several times those measured
        # at the start (inliers of a start ~1 deg off are not yet down-weighted), halved every
        # round down to the first answer's.
        active = (chi2_0 <= GATE) & (w > 0)
        E0 = essential(R0, t0)
        g0, h0 = residual_variances(E0, q1, q2, A)
        r0 = (M.reshape(-1, 9) @ E0.ravel()).reshape(len(acs), 3)
        spg, sag = noise_scales(r0, g0, h0, active)
        spg, sag = _GNC_INFLATION * max(spg, sp), _GNC_INFLATION * max(sag, sa)
        target = (min(first.sp, sp), min(first.sa, sa))
        annealed = {'shrink': 0.5, 'target': target}
        # (b) The same rotation with straight-ahead travel: a start on the other side of the
        # rotation-translation (bas-relief) valley.
        forward = -R0 @ (self.R_lc.T @ np.array([0.0, 0.0, 1.0]))
        return [('gnc', R0, t0, spg, sag, annealed), ('forward', R0, forward, spg, sag, annealed)]

    def _decide(self, acs, M, answers, prior, vote, vstats, screened=0) -> FrameEstimate:
        """The winning answer, its reliability, and the state update."""
        q1, q2, A, w = acs.p1, acs.p2, acs.A, acs.weights
        # Compete at common noise scales, the tightest of the answers' (a wrong answer inflates
        # its own scales to explain more ACs; at tight scales it explains few).
        sp_c = min(g.sp for _, g in answers)
        sa_c = min(g.sa for _, g in answers)
        final = sorted(((self._msac_of(M, acs, g, sp_c, sa_c), name, g) for name, g in answers),
                       key=lambda item: item[0])
        cost_best, name, best = final[0]
        if not best.converged:
            # More rounds from where the winner stopped (rare: slow linear convergence of the
            # fixed-whitening iteration in turns); flagged only if still not settled.
            more = refine_general_motion(q1, q2, A, w, best.R, best.t, best.chi2 <= GATE,
                                         best.sp, best.sa, prior=prior, config=self.config,
                                         M=M)
            more.iterations += best.iterations
            best = more
            cost_best = self._msac_of(M, acs, best, sp_c, sa_c)
        stats = {'start': name, 'msac': cost_best, 'point_scale': best.sp,
                 'affine_scale': best.sa, 'iterations': best.iterations, 'rounds': best.rounds,
                 'answers': len(final), 'screened': screened,
                 'vote_reliable': bool(vstats.reliable)}
        flag = None
        zero = float(w.sum()) * GATE                  # the MSAC cost of explaining nothing
        for cost_other, _, other in final[1:]:
            if not _same_motion(other.R, other.t, best.R, best.t):
                # Compare the supports (MSAC gains over explaining nothing): with many outliers
                # the costs are dominated by the outliers' constant and their ratio says little.
                ratio = (zero - cost_other) / max(zero - cost_best, 1e-300)
                stats['competitor_ratio'] = max(ratio, stats.get('competitor_ratio', 0.0))
                if ratio > self.config.ambiguity_ratio:
                    flag = 'ambiguous'
        flag = flag or self._judge(M, acs, best, cost_best, stats)
        if flag is None:
            self._update(best, stats['share'])
        return FrameEstimate(best.R, best.t, best.cov, best.basis, best.inliers, flag is None,
                             flag, vote, stats)

    def _judge(self, M, acs, best, cost_best, stats) -> str | None:
        """Reliability of the winning answer (None when reliable); see the module docstring."""
        cfg = self.config
        w = acs.weights
        if not best.converged:
            return 'unconverged'
        # A motion that 'fits' only with inflated noise scales explains the data by its noise
        # model, not by its geometry.
        if len(self._scales) >= _HISTORY_MIN:
            # Relative to the recent median, but never below the nominal accuracy of ACs
            # (``voting.point_noise``, ``voting.affine_noise``): a drive's easy stretches set a
            # median far below it, and the model errors of a sharp turn (an assumed principal
            # point, lens residuals) then flagged right answers.
            median_p, median_a = _column_medians(np.array(self._scales))
            cap_p = max(_MAX_SCALE_RATIO * median_p, self.voting.point_noise)
            cap_a = max(_MAX_SCALE_RATIO * median_a, self.voting.affine_noise)
        else:
            cap_p, cap_a = _MAX_SCALES
        if best.sp > cap_p or best.sa > cap_a:
            return 'noisy'
        stats['share'] = float(w[best.inliers].sum() / max(w.sum(), 1e-300))
        if int(best.inliers.sum()) < cfg.min_inliers:
            return 'too_few_inliers'
        if stats['share'] < cfg.min_inlier_share:
            return 'low_share'
        axis = self.R_lc.T @ np.array([0.0, 1.0, 0.0])          # the level vertical
        var_yaw = float(axis @ best.cov[:3, :3] @ axis)
        stats['yaw_std'] = math.sqrt(var_yaw) if np.isfinite(var_yaw) and var_yaw >= 0 \
            else math.inf
        if not stats['yaw_std'] <= cfg.max_yaw_std:
            return 'imprecise'
        support = max(float(w[best.inliers].sum()), 1e-300)
        perturbed = [(so3_exp(_PERTURBATION * axis) @ best.R, best.t),
                     (so3_exp(-_PERTURBATION * axis) @ best.R, best.t),
                     (best.R, _turn(best.t, best.basis[:, 0], 5 * _PERTURBATION)),
                     (best.R, _turn(best.t, best.basis[:, 1], 5 * _PERTURBATION))]
        chi2 = chi_squares(M, acs.p1, acs.p2, acs.A, perturbed, best.sp, best.sa)
        costs = [float(w @ c) for c in np.minimum(chi2, GATE)]     # as `_msac`'s
        stats['rise'] = min((cost - cost_best) / support for cost in costs)
        return 'flat' if stats['rise'] < _FLAT_RISE else None

    def _update(self, best, share: float) -> None:
        self._scales.append((best.sp, best.sa))
        self._shares.append(share)
        self.previous = (best.R, best.t)
        c = -best.R.T @ best.t
        self._motions.append(np.concatenate([so3_log(best.R), c / np.linalg.norm(c)]))

    # -- helpers -------------------------------------------------------------------------------

    @classmethod
    def _msac_of(cls, M, acs, answer, sp, sa) -> float:
        """`_msac` of a refined answer: at its own noise scales its chi-squares are those it
        carries (the same bits: the refinement's last round computed them at its motion)."""
        if sp == answer.sp and sa == answer.sa:
            return float(acs.weights @ np.minimum(answer.chi2, GATE))
        return cls._msac(M, acs, answer.R, answer.t, sp, sa)[0]

    @staticmethod
    def _msac(M, acs, R, t, sp, sa) -> tuple[float, np.ndarray]:
        chi2 = chi_square(M, acs.p1, acs.p2, acs.A, R, t, sp, sa)
        return float(acs.weights @ np.minimum(chi2, GATE)), chi2

    def _planar(self, acs, motion, vstats, vote) -> FrameEstimate:
        """The vote's planar motion as the answer (``model: planar``): its 2x2 covariance of
        ``(alpha, beta)`` in the level frame, completed by the non-planarity (pitch, roll and
        elevation of travel) the planar model ignores."""
        n = len(acs)
        if not vstats.reliable:
            return self._failed(n, vstats.flag or 'unreliable', vote)
        R, t = lift_planar(motion.alpha, motion.beta, self.R_lc)
        B = tangent_basis(t)
        sigma = self.non_planarity if math.isfinite(self.non_planarity) else PRIOR_SIGMAS[0]
        # Level frame: w = R_lc^T [pitch, yaw, roll]; the heading beta turns t about the level
        # vertical, the elevation tilts it out of the plane.
        cov_level = np.diag([sigma ** 2, vstats.covariance[0, 0], sigma ** 2])
        cov = np.zeros((5, 5))
        cov[:3, :3] = self.R_lc.T @ cov_level @ self.R_lc
        up = self.R_lc.T @ np.array([0.0, 1.0, 0.0])
        dt_dbeta = np.cross(up, t)                   # the heading turns t about the vertical
        dt_delev = np.cross(t, dt_dbeta)             # ... the elevation tilts it
        J = B.T @ np.column_stack([dt_dbeta, dt_delev])
        cov[3:, 3:] = J @ np.diag([vstats.covariance[1, 1], PRIOR_SIGMAS[1] ** 2]) @ J.T
        est = FrameEstimate(R, t, cov, B, vstats.inliers.copy(), True, None, vote,
                            {'start': 'vote', 'point_scale': vstats.point_scale,
                             'affine_scale': vstats.affine_scale})
        self.previous = (R, t)
        return est

    def _failed(self, n: int, flag: str, vote: tuple) -> FrameEstimate:
        return FrameEstimate(np.full((3, 3), np.nan), np.full(3, np.nan),
                             np.full((5, 5), np.inf), np.full((3, 2), np.nan),
                             np.zeros(n, bool), False, flag, vote, {})


def _column_medians(x: np.ndarray) -> np.ndarray:
    """``np.median(x, axis=0)`` of a (K, m) history, column by column by partial sorting (the
    same values; np.median's overhead is several times the work at these sizes)."""
    return np.array([median(x[:, k]) for k in range(x.shape[1])])


def _turn(t: np.ndarray, b: np.ndarray, angle: float) -> np.ndarray:
    """``t`` turned by ``angle`` towards the orthogonal unit vector ``b``."""
    return math.cos(angle) * t + math.sin(angle) * b
