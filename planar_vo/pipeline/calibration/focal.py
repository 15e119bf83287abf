"""Online focal-length self-calibration from many frame pairs.

`OnlineFocalCalibrator` + `TurnPairSelector`: profile likelihoods of turning pairs
(`planar_vo.core.robust.focal.pair_profile`), summed per block, adopted only with an honest
uncertainty; bounded memory, cost amortised over the frames in a fixed number of work steps
per frame.

Why not a focal length per AC (the paper's 1ACf closed form, voted): for a car both parts of
``f^2 = (n3^2 - n1^2) / (n2^2 - n4^2)`` are of the order of the yaw squared and the denominator
is the difference of two nearly equal numbers, so zero-mean noise inflates it and biases the
focal length low (measured on KITTI 05 turns with the true principal point and ground-truth
inliers: median per-AC focal 351 px at 2.3 deg of yaw down to 93 px at lag 5, truth 707). The
profile uses the calibrated 1AC machinery, unbiased at any trial focal length.

The pairs' ACs are extracted with the turn taken out of the optical flow (the earlier keyframe
warped by the odometry's rotation, `ACExtractor.extract_warped`): the frame's own ACs, found
with the rotation in the flow, carry a small affine bias (up to 0.01 against the ground truth's
motion on KITTI 05's turn) that the profiles turn into a focal length 5-7 % shorter.
"""

from __future__ import annotations

import collections
import dataclasses
import logging
import math

import numpy as np

from planar_vo.config.sections import CameraConfig
from planar_vo.core.robust import VotingConfig
from planar_vo.core.robust.focal import combine_profiles, profile_steps, shifted_profile
from planar_vo.core.robust.stats import few_cluster_factor
from planar_vo.core.robust.types import check_inputs
from planar_vo.errors import ConfigError, InputError

__all__ = ['OnlineFocalCalibrator', 'TurnPairSelector', 'prior_sigma_for_fov']

log = logging.getLogger(__name__)


# --------------------------------------------------------------------------------------------
# Self-calibration from turning pairs: profiles, honest adoption, bounded and amortised cost
# --------------------------------------------------------------------------------------------

# The log-focal grid, relative to the image width: 0.25-2.5 x width covers fields of view of
# about 23-127 deg; 41 points are 5.9 % apart (the minimum is refined by a parabola between).
_GRID = (0.25, 2.5, 41)
# Prior of the provisional focal: log-normal at the nominal 53-deg field of view, sigma 0.45 in
# log units (fields of view of 30-120 deg within 2 sigma).
_PRIOR_SIGMA = 0.45
# Principal point: an assumed one (the image centre) is typically within 1-2 % of the width of
# the true one (KITTI: 0.9 %); the focal is sensitive to it (KITTI 05: 3-7 px of focal per px
# of cx, measured), so each pair's profile is also evaluated, to first order, with cx shifted by
# this share of the width (`shifted_profile`), and |df/dcx| pp_std enters the standard
# deviation.
_PP_STEP = 0.01
# Work per step of a pair's profile, in ACs times grid focal lengths: a pair of N ACs takes
# ``max(1, _STEP_WORK // N)`` grid points per step, so a step costs about the same whatever the
# pair's size (KITTI 05 turning pairs: 8 grid points of 1,100-1,350 ACs took 9 ms median, 16 ms
# at most; 21 of 267-468 ACs, 7.7 ms median, 10.7 ms at most) and small pairs take fewer steps: a
# pair of the budgeted front-end (about 400 ACs) is 4 steps (the vote, 2 chunks, the shifted
# profile), one every other frame at the default 2 steps per frame, which keeps pace with the
# turn (`TurnPairSelector` offers a pair every ``stride`` = 2 keyframes). With a fixed 8 grid
# points such pairs took 8 steps, the queue grew through the turn and the provisional focal
# length lagged it by up to 25 frames.
_STEP_WORK = 10_000


def prior_sigma_for_fov(fov: float, fov_std: float, fisheye: bool = False) -> float:
    """The log-focal standard deviation of a field of view known to ``fov_std`` (rad):
    rectilinear ``f = w / (2 tan(fov / 2))`` gives ``d ln f / d fov = -1 / sin(fov)``, an
    equidistant fisheye ``f = w / fov`` gives ``-1 / fov``; at least 0.1 % (a prior, not a
    calibration)."""
    gain = 1.0 / fov if fisheye else 1.0 / math.sin(fov)
    return max(fov_std * gain, 1e-3)


class TurnPairSelector:
    """Chooses the keyframe pairs that carry focal information (the car turned between them).

    Keeps the pixel rotation of the last ``max_lag`` keyframe steps (``f tan(alpha)``: what the
    image measures, the same whatever focal the yaw was estimated with). For a new keyframe it
    returns the most recent earlier keyframe whose accumulated pixel rotation to this one is at
    least ``min_shift`` (the 1ACf conditioning grows like ``alpha^2``: small turns carry
    nothing) and at most ``max_shift`` (the optical-flow front-end loses the correspondences
    beyond: measured on KITTI 05, no ACs at 190 px between frames), both as shares of the image
    width, and at least ``stride`` keyframes after the last selected pair (overlapping pairs
    repeat the same information). Pixels rather than degrees, because the degrees depend on the
    unknown focal: a provisional focal 1.7 times too long (KITTI with the nominal 53-deg guess)
    starved a 4-deg threshold. Memory: ``max_lag`` steps.

    Args:
        width: image width (pixels).
        min_shift, max_shift: accumulated pixel rotation as shares of the width.
        max_lag: keyframe steps remembered (the partner is at most ``max_lag - 1`` back).
        stride: keyframes between selected pairs at least.
    """

    def __init__(self, width: int, min_shift: float = 0.04, max_shift: float = 0.13,
                 max_lag: int = 5, stride: int = 2) -> None:
        if not (width > 0 and 0.0 < min_shift < max_shift and max_lag >= 2 and stride >= 1):
            raise ConfigError(f'TurnPairSelector: expected width > 0, 0 < min_shift < '
                              f'max_shift, max_lag >= 2, stride >= 1, got {width}, {min_shift},'
                              f' {max_shift}, {max_lag}, {stride}')
        self.min_px, self.max_px = min_shift * width, max_shift * width
        self.stride = int(stride)
        self._steps: collections.deque[tuple[int, float]] = collections.deque(
            maxlen=int(max_lag))
        self._last: int | None = None

    def step(self, frame: int, alpha: float, focal: float) -> int | None:
        """Record the keyframe step ending at keyframe ``frame`` (yaw ``alpha`` in radians,
        estimated at focal ``focal`` pixels); return the partner keyframe for a focal pair, or
        None."""
        if not (math.isfinite(alpha) and math.isfinite(focal) and focal > 0):
            raise InputError(f'TurnPairSelector.step: expected a finite yaw and a positive focal,'
                             f' got {alpha}, {focal}')
        self._steps.append((int(frame), focal * math.tan(alpha)))
        if self._last is not None and frame - self._last < self.stride:
            return None
        total = 0.0
        for k in range(len(self._steps) - 1, 0, -1):
            total += self._steps[k][1]
            if abs(total) > self.max_px:
                return None
            if abs(total) >= self.min_px:
                self._last = int(frame)
                return self._steps[k - 1][0]
        return None


@dataclasses.dataclass
class _Pair:
    """A queued turning pair: its ACs (at most ``max_acs``) and the frame it ends at."""

    frame: int
    p1: np.ndarray
    p2: np.ndarray
    A: np.ndarray
    w: np.ndarray
    block: int


class OnlineFocalCalibrator:
    """Online self-calibration of a common focal length from turning pairs, with an honest
    uncertainty and a bounded, amortised cost.

    Each informative pair (`TurnPairSelector`) is `offer`-ed: its ACs (at most ``max_acs``,
    evenly picked) wait in a queue of at most ``max_queue`` pairs. `work` turns them into
    profiles (`pair_profile`, the cost on a fixed log-focal grid, and `shifted_profile`, the
    same to first order with the principal point shifted by 1 % of the width) in small steps:
    about 60 ms per pair of 1,200 ACs (8 steps of about 9 ms; a pair of 400 ACs takes 4),
    far more than a frame may spend, so the pipeline calls ``work(camera.focal_steps)`` every
    frame and a pair is done a few frames later.

    Profiles are summed per block of ``block_frames`` frames (pairs within about a second share
    scenery and wobble: one cluster); at most ``max_blocks`` blocks are kept (the least
    informative dropped first): memory ``2 x 41 x max_blocks`` floats plus the queue. The
    estimate is the minimiser of the summed blocks (`combine_profiles`), its standard deviation
    the block-cluster sandwich (never below the curvature-only value) widened for few blocks
    (`few_cluster_factor`, so that ``|error| <= 3 std`` holds at 99.7 % despite few clusters)
    and combined with the principal-point term ``|df/dcx| pp_std``.

    The calibration is adopted only when at least ``min_blocks`` blocks contributed, the
    minimum is inside the grid, and the relative standard deviation is at most ``tolerance``.
    Until then `provisional` is the posterior mean (in log focal) of a prior at the nominal focal
    (53-deg field of view, sigma 0.45 in log units) and the calibration so far, from two blocks
    on (the fewest a sandwich can use; `few_cluster_factor` widens its one degree of freedom),
    and `relative_std` its uncertainty (for the odometry's covariance): during a first turn
    the odometry leaves the prior a block earlier than with three (KITTI 05 self-calibrated:
    yaw error 0.131 -> 0.068 deg per frame, a dev script). A drive without enough turning stays
    uncalibrated and says so (`status`).

    Measured on KITTI 05 (one 90-deg turn, principal point at the image centre; `planar_vo bench
    drives`): 671.5 +- 74.8 px (truth 707.1: -0.48 sigma), not adopted; with the principal
    point given 728.4 +- 49.1 px (+0.44 sigma). Before the odometry carried the mount tilt
    across changes of the focal length (`VisualOdometry._refocus`) it was 652.6 +- 68.4 and
    702.3 +- 44.9 px; on the frame's own ACs (before the pairs were de-rotated) 617.2 +- 78.3
    px; an earlier version's per-AC calibrator gave 603.7 +- 4.4 px there, adopted (-23
    sigma).

    Where the bias on the frame's own ACs came from (dev scripts on the 19 KITTI 05 pairs,
    before the de-rotation): about half is the
    principal point (with the true one configured: 649.8 px, -8 %); the rest follows each
    turning pair's own rotation axis, tilted 1-14 deg from the vertical by the car's roll and
    pitch in the turn (the pipeline's per-pair estimates of that tilt agree with the ground
    truth's within 1.6 deg). At the true focal length the ground-truth motion explains a
    pair's ACs far better than the best planar one (robust cost 121 against 630 on one pair).
    Tried and not kept, because none moved the estimate reliably towards the truth: only pairs
    tilted less than 3-5 deg (the same focal length); profiles about each pair's estimated
    tilted axis (+3 % or -14 %, depending on how the roll is carried to other trial focal
    lengths); first-order re-levelling (moves it the wrong way); more Lucas-Kanade iterations
    in the front-end (+0.5 %). Estimating the principal point along with the focal length:
    the summed cost of the turn's pairs (ground-truth de-rotation and levelling, fixed noise
    scales) varies by only 0.7 % over an assumed cx from -40 to +40 px of the true one, lowest
    at +40 px, while the focal length at its minimum moves by about 3 px per px: the pairs do not
    identify the principal point.

    Args:
        width, height: image size (pixels).
        nominal: provisional focal before any information (default ``max(width, height)``,
            a 53-deg field of view).
        prior_fov: the horizontal field of view (rad) of ``nominal`` through the lens, for the
            status (default: through a rectilinear lens).
        stated: whether the user stated it (``camera.nominal_fov``), else it is assumed.
        prior_sigma: the prior's standard deviation in log focal length (None: 0.45, wide;
            `prior_sigma_for_fov` from a stated field of view's standard deviation).
        prior_fov_std: that standard deviation (rad), for the status (0: not said).
        pp_std: standard deviation (pixels) of the horizontal principal point the caller
            assumed (default 1 % of the width, for the image centre; about 1 when cx, cy are
            configured).
        tolerance: adoption threshold on the relative standard deviation
            (``camera.focal_tolerance``).
        max_acs, max_queue, block_frames, min_blocks, max_blocks: ``camera.focal_*``.
        config: options of the calibrated votes.

    Example (per keyframe of the pipeline)::

        partner = selector.step(frame, alpha, calibrator.provisional)
        if partner is not None:               # ACs between keyframe `partner` and this one
            calibrator.offer(frame, p1, p2, A, w)   # pixels from the principal point, levelled
        calibrator.work(steps_per_frame, frame)
        focal = calibrator.provisional        # and calibrator.relative_std
    """

    def __init__(self, width: int, height: int, nominal: float | None = None,
                 pp_std: float | None = None, *, prior_fov: float | None = None,
                 stated: bool = False, prior_sigma: float | None = None,
                 prior_fov_std: float = 0.0,
                 tolerance: float = CameraConfig.focal_tolerance,
                 max_acs: int = CameraConfig.focal_max_acs,
                 max_queue: int = CameraConfig.focal_queue,
                 block_frames: int = CameraConfig.focal_block_frames,
                 min_blocks: int = CameraConfig.focal_min_blocks,
                 max_blocks: int = CameraConfig.focal_max_blocks,
                 config: VotingConfig | None = None) -> None:
        if not (width > 0 and height > 0):
            raise ConfigError(f'width, height: expected a positive image size, got {width}, '
                              f'{height}')
        CameraConfig(estimate_focal=True, focal_tolerance=tolerance, focal_max_acs=max_acs,
                     focal_queue=max_queue, focal_block_frames=block_frames,
                     focal_min_blocks=min_blocks, focal_max_blocks=max_blocks)   # validates them
        self.width, self.height = int(width), int(height)
        self.nominal = float(nominal) if nominal is not None else float(max(width, height))
        self.prior_fov = (float(prior_fov) if prior_fov is not None
                          else 2.0 * math.atan(0.5 * self.width / self.nominal))
        self.stated = bool(stated)
        self.prior_sigma = _PRIOR_SIGMA if prior_sigma is None else float(prior_sigma)
        self.prior_fov_std = float(prior_fov_std)
        if not (math.isfinite(self.prior_sigma) and self.prior_sigma > 0):
            raise ConfigError(f'prior_sigma: expected a positive standard deviation, got '
                              f'{prior_sigma}')
        if not (math.isfinite(self.nominal) and self.nominal > 0):
            raise ConfigError(f'nominal: expected a positive focal length, got {nominal}')
        self.pp_std = _PP_STEP * width if pp_std is None else float(pp_std)
        if not (math.isfinite(self.pp_std) and self.pp_std >= 0):
            raise ConfigError(f'pp_std: expected a non-negative number of pixels, got {pp_std}')
        self.pp_step = _PP_STEP * width
        lo, hi, n = _GRID
        self.log_grid = np.linspace(math.log(lo * width), math.log(hi * width), n)
        self.tolerance, self.max_acs, self.max_queue = float(tolerance), max_acs, max_queue
        self.block_frames, self.min_blocks = block_frames, min_blocks
        self.max_blocks = max_blocks
        self.config = VotingConfig() if config is None else config
        self._queue: collections.deque[_Pair] = collections.deque()
        self._job = None                    # the pair in progress: a generator of steps
        self._frame: int | None = None      # the frame of the current `work` call
        self._credit = 0.0                  # work steps granted and not yet run
        self._blocks: dict[int, np.ndarray] = {}
        self._shifted: dict[int, np.ndarray] = {}
        self._cache: tuple[float, float, dict] | None = None
        self.pairs = 0                      # pairs that contributed a profile
        self.rejected = 0                   # pairs whose vote was unreliable
        self.dropped = 0                    # pairs refused while the queue was full
        self.steps = 0                      # work steps run (cost accounting)
        self.adopted: float | None = None
        self.adopted_std: float | None = None
        self.adopted_at: int | None = None
        self.updated_at: int | None = None  # the last frame that changed the adopted value
        self.widened_at: int | None = None  # ... that widened its std beyond the tolerance
        self.revoked_at: int | None = None  # the frame an adopted value was last revoked at
        self.first_pass = False             # `finish_first_pass`: final, takes no more pairs

    # -- input and work ------------------------------------------------------------------------

    @property
    def blocks(self) -> int:
        """Blocks (clusters of pairs) holding profiles (at most ``max_blocks``)."""
        return len(self._blocks)

    @property
    def pending(self) -> int:
        """Pairs queued or in progress."""
        return len(self._queue) + (self._job is not None)

    def offer(self, frame: int, p1: np.ndarray, p2: np.ndarray, A: np.ndarray,
              weights: np.ndarray | None = None, *, block: int | None = None) -> bool:
        """Queue one turning pair ending at ``frame``.

        Args:
            frame: frame index (the pairs' blocks are ``frame // block_frames``).
            block: the pair's block instead (the caller's, e.g. in time: a 30 Hz camera's
                blocks hold three times the frames).
            p1, p2: pixels relative to the (assumed) principal point, levelled, ``(N, 2)``.
            A: pixel affines ``(N, 2, 2)``. weights: ``(N,)`` non-negative, or None.

        Returns:
            Whether it was queued: False with too few ACs (3 x ``config.min_inliers``) or a
            full queue (counted in `dropped`).
        """
        if self.first_pass:
            return False                     # (the same frames' pairs again: not counted twice)
        p1, p2, A, w, _ = check_inputs(p1, p2, A, weights, self.config)
        if len(p1) < 3 * self.config.min_inliers:
            return False
        if len(self._queue) >= self.max_queue:
            self.dropped += 1
            log.debug('focal calibration: queue full, pair at frame %d dropped', frame)
            return False
        if len(p1) > self.max_acs:
            pick = np.linspace(0, len(p1) - 1, self.max_acs).astype(int)
            p1, p2, A, w = p1[pick], p2[pick], A[pick], w[pick]
        block = int(frame) // self.block_frames if block is None else int(block)
        self._queue.append(_Pair(int(frame), p1.copy(), p2.copy(), A.copy(), w.copy(), block))
        return True

    def work(self, steps: float, frame: int | None = None) -> int:
        """Advance the queued profiles by ``steps`` work steps (a vote, a chunk of one profile's
        grid focal lengths sized by the pair's ACs, or the shifted profile: 5-15 ms each on
        KITTI pairs); returns the number of steps run.

        A fractional remainder carries over to the next call (``camera.focal_steps`` 0.5 runs a
        step every other frame); nothing is saved up while the queue is empty. Counted in steps,
        not seconds, so that the same frames give the same calibration on any machine and at
        any load (replays, fleet runs and the node agree).

        Args:
            steps: work steps this call may run (>= 0).
            frame: the current frame (`adopted_at` names it); default: the pair's frame.
        """
        if not (math.isfinite(steps) and steps >= 0):
            raise InputError(f'steps: expected a non-negative number of work steps, got {steps}')
        if self.first_pass:
            return 0
        self._frame = frame
        if self._job is None and not self._queue:
            self._credit = 0.0
            return 0
        self._credit += steps
        done = 0
        while (self._job is not None or self._queue) and self._credit >= 1.0:
            self._step()
            self._credit -= 1.0
            done += 1
        self.steps += done
        return done

    def finish_first_pass(self) -> None:
        """Profile every pair still waiting, then take no more: the calibration of a first pass
        over a whole recording (``planar_vo replay --two-pass``), which the second pass over
        the same frames uses from its first frame on and keeps (their pairs would count twice).
        `status` says so."""
        while self.pending:
            self.work(float(_STEP_WORK), self._frame)
        self.first_pass = True

    def _step(self) -> None:
        if self._job is None:
            self._job = self._pair_job(self._queue.popleft())
        try:
            next(self._job)
        except StopIteration:
            self._job = None

    def _pair_job(self, pair: _Pair):
        """The steps of one pair: its profile, then (one step) its profile with the principal
        point shifted (`shifted_profile`), the blocks and the adoption (at the frame of the
        `work` call that finishes it)."""
        f_ref = self.provisional
        prof = yield from profile_steps(pair.p1, pair.p2, pair.A, pair.w, self.log_grid, f_ref,
                                        self.config, chunk=max(1, _STEP_WORK // len(pair.p1)))
        if prof is None:
            self.rejected += 1
            return
        shifted = None
        if self.pp_std > 0:
            yield
            shifted = shifted_profile(pair.p1, pair.p2, pair.A, pair.w, self.log_grid, prof,
                                      self.pp_step)
        self._add(pair.block, prof.cost, shifted)
        self.update_adoption(pair.frame if self._frame is None else self._frame)

    def _add(self, b: int, cost: np.ndarray, shifted: np.ndarray | None) -> None:
        self._blocks[b] = self._blocks.get(b, 0.0) + cost
        if shifted is not None:
            self._shifted[b] = self._shifted.get(b, 0.0) + shifted
        self.pairs += 1
        if len(self._blocks) > self.max_blocks:
            # Drop the least informative block: the smallest curvature at its own minimum.
            def curvature(c: np.ndarray) -> float:
                k = int(np.clip(np.argmin(c), 1, len(c) - 2))
                return float(c[k - 1] - 2 * c[k] + c[k + 1])
            worst = min(self._blocks, key=lambda key: curvature(self._blocks[key]))
            del self._blocks[worst]
            self._shifted.pop(worst, None)
        self._cache = None

    # -- results -------------------------------------------------------------------------------

    def estimate(self) -> tuple[float, float, dict]:
        """``(focal, std, info)`` in pixels (NaN, inf before the first profile).

        ``std`` is reported so that ``|error| <= 3 std`` holds at the 99.7 % level despite few
        clusters: the block sandwich times ``few_cluster_factor(blocks, 3)``, combined with the
        principal-point term. ``info``: ``pairs``, ``blocks``, ``edge``, ``std_1sigma`` (with
        the 1-sigma factor, for the provisional posterior), ``df_dcx``, ``std_pp``."""
        if self._cache is not None:
            return self._cache
        if not self._blocks:
            return float('nan'), float('inf'), dict(pairs=0, blocks=0, edge=True)
        blocks = list(self._blocks.values())
        log_f, s, cinfo = combine_profiles(blocks, self.log_grid, 2)
        f = math.exp(log_f)
        B = len(blocks)
        info = dict(pairs=self.pairs, blocks=B, edge=cinfo['edge'], std_blocks_raw=f * s)
        std3 = f * s * few_cluster_factor(B, 3.0) if math.isfinite(s) else float('inf')
        std1 = f * s * few_cluster_factor(B, 1.0) if math.isfinite(s) else float('inf')
        info.update(std_blocks=std3)
        if self.pp_std > 0 and self._shifted:
            log_fs, _, _ = combine_profiles(list(self._shifted.values()), self.log_grid, 1)
            dfdc = (math.exp(log_fs) - f) / self.pp_step
            info.update(df_dcx=dfdc, std_pp=abs(dfdc) * self.pp_std)
            std3 = math.hypot(std3, abs(dfdc) * self.pp_std)
            std1 = math.hypot(std1, abs(dfdc) * self.pp_std)
        info.update(std_1sigma=std1)
        self._cache = (f, std3, info)
        return self._cache

    def _posterior(self) -> tuple[float, float]:
        """``(log f, std)`` of the prior (nominal focal, `prior_sigma`) combined with the
        calibration (1-sigma)."""
        m0, s0 = math.log(self.nominal), self.prior_sigma
        f, _, info = self.estimate()
        s1 = info.get('std_1sigma', float('inf')) / f if math.isfinite(f) else float('inf')
        if not (math.isfinite(s1) and s1 > 0) or info.get('edge', True):
            return m0, s0
        w0, w1 = 1.0 / s0 ** 2, 1.0 / s1 ** 2
        return (w0 * m0 + w1 * math.log(f)) / (w0 + w1), math.sqrt(1.0 / (w0 + w1))

    @property
    def provisional(self) -> float:
        """The focal length (pixels) to run with now: the adopted one, else the posterior mean
        of the nominal prior and the calibration so far."""
        if self.adopted is not None:
            return self.adopted
        return math.exp(self._posterior()[0])

    @property
    def relative_std(self) -> float:
        """Relative uncertainty of `provisional` (for the odometry covariance: the yaw error is
        about ``alpha x`` this): once adopted, the calibration's standard deviation as
        `estimate` reports it (sized so that the error stays within 3 of them despite few
        blocks: at 4 blocks about twice the 1-sigma value, conservative); before, the 1-sigma
        posterior of the prior and the calibration."""
        if self.adopted is not None:
            return self.adopted_std / self.adopted
        return math.exp(self._posterior()[1]) - 1.0

    def carry(self, fisheye: bool = False) -> tuple[float, float] | None:
        """The focal length in use and its uncertainty as the horizontal field of view (rad)
        and its standard deviation, ``camera.nominal_fov`` and ``nominal_fov_std`` of this
        camera's next drive or node (the inverse of `prior_sigma_for_fov`: ``sigma_fov =
        sigma_ln_f sin(fov)``, through an equidistant fisheye ``sigma_ln_f fov``); None before
        any turning pair was profiled (nothing learnt beyond the prior)."""
        if not self._blocks:
            return None
        f, rel = self.provisional, self.relative_std
        if not (math.isfinite(f) and f > 0 and math.isfinite(rel)):
            return None
        sigma = math.log1p(rel)
        fov = self.width / f if fisheye else 2.0 * math.atan(0.5 * self.width / f)
        gain = fov if fisheye else math.sin(fov)
        return fov, min(max(sigma * gain, 1e-4), 1.0)

    def update_adoption(self, frame: int) -> bool:
        """Adopt (or update the adopted) estimate when its uncertainty allows (see the class
        docstring); `adopted_at` is the frame of the adoption.

        An adopted value that the calibration no longer supports is revoked (`revoked_at`, a
        warning; provisional again): the estimate at the edge of its range, its standard
        deviation above twice the tolerance, or the adopted value off the estimate by more than
        that standard deviation (a review: blocks seen through another focal length moved the
        estimate to 770.7 +- 51.3 px while 616.4 +- 8.5 px stayed adopted). Between the
        tolerance and twice it the adopted value stays, with the estimate's standard deviation
        when that is larger."""
        f, s, info = self.estimate()
        ok = (math.isfinite(f) and info.get('blocks', 0) >= self.min_blocks
              and not info.get('edge', True) and s / f <= self.tolerance)
        if ok:
            if self.adopted_at is None:
                self.adopted_at = int(frame)
                log.debug('focal length self-calibrated at frame %d: %.1f +- %.1f px (%d pairs,'
                          ' %d blocks)', frame, f, s, self.pairs, info['blocks'])
            elif (f, s) != (self.adopted, self.adopted_std):
                self.updated_at = int(frame)
            self.adopted, self.adopted_std, self.widened_at = f, s, None
        elif self.adopted is not None:
            if (not math.isfinite(f) or info.get('edge', True) or s > 2.0 * self.tolerance * f
                    or abs(f - self.adopted) > s):
                log.warning('focal length self-calibration revoked at frame %d: the calibration '
                            'now gives %.1f +- %.1f px against the adopted %.1f +- %.1f px; '
                            'provisional again', frame, f, s, self.adopted, self.adopted_std)
                self.adopted = self.adopted_std = self.adopted_at = self.updated_at = None
                self.widened_at = None
                self.revoked_at = int(frame)
            elif s > self.adopted_std:
                # The value stays; only its uncertainty grows, and the status says so (a user
                # test: 'updated at frame 90' when only the +- had grown past the tolerance).
                self.adopted_std = s
                if self.widened_at is None:
                    self.widened_at = int(frame)
        return ok

    def status(self) -> str:
        """One line for logs and the status topic, e.g. ``focal length 712.3 +- 4.1 px
        (self-calibrated at frame 143)`` (``..., updated at frame 180)`` once a later block
        moved it) or ``focal length 1241.0 +- 702.3 px (provisional, 2 of 4 blocks)`` /
        ``(provisional, calibration 651.2 +- 9.9 %, adopted once below 2 %)`` / ``(provisional: no
        turn to calibrate from yet: an assumed 53-degree field of view, 0 of 4 blocks)``; after
        `finish_first_pass` ending in ``; from a first pass over the whole recording)``."""
        line = self._status()
        return line[:-1] + '; from a first pass over the whole recording)' if self.first_pass \
            else line

    def _status(self) -> str:
        if self.adopted is not None:
            updated = '' if self.updated_at is None else f', updated at frame {self.updated_at}'
            if self.widened_at is not None:
                updated += (f'; uncertain again since frame {self.widened_at}: '
                            f'{100.0 * self.adopted_std / self.adopted:.1f} % against the '
                            f'{100.0 * self.tolerance:g} % it was adopted at, revoked above '
                            f'{200.0 * self.tolerance:g} %')
            return (f'focal length {self.adopted:.1f} +- {self.adopted_std:.1f} px '
                    f'(self-calibrated at frame {self.adopted_at}{updated})')
        f = self.provisional
        blocks = len(self._blocks)
        if not blocks:
            known = (f' +- {math.degrees(self.prior_fov_std):.2g}'
                     if self.prior_fov_std else '')
            prior = (f"{'the stated' if self.stated else 'an assumed'} "
                     f'{math.degrees(self.prior_fov):.0f}{known}-degree field of view')
            why = (f"no turn to calibrate from{'' if self.first_pass else ' yet'}: {prior}, "
                   f'0 of {self.min_blocks} blocks')
        elif blocks < self.min_blocks:
            why = f'{blocks} of {self.min_blocks} blocks'
        else:
            estimate, std, info = self.estimate()
            why = ('the calibration at the edge of its range' if info.get('edge', True) else
                   f'calibration {estimate:.1f} +- {100.0 * std / estimate:.1f} %, adopted '
                   f'once below {100.0 * self.tolerance:g} %')
        if self.revoked_at is not None:
            why += f'; an adopted value revoked at frame {self.revoked_at}'
        return f'focal length {f:.1f} +- {f * self.relative_std:.1f} px (provisional, {why})'
