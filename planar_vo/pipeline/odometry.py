"""`VisualOdometry`: frames in, 3D poses out (no ROS; driven by the node, replay and tests).

Per frame (see `VisualOdometry.process`):

1. checks: the stamp against the stream's time base (`planar_vo.pipeline.clock`), the camera
   model, an image of the camera's size that is not blank, nor the previous image again while
   the vehicle moves (a frozen camera: `VisualOdometry._frozen`);
2. affine correspondences from the current keyframe to this frame (`planar_vo.frontend`);
3. if the median parallax is below ``keyframe.stationary_parallax`` the vehicle stands still;
4. otherwise the ACs are undistorted and normalised, levelled by the mount tilt (configured or
   estimated online), and `planar_vo.pipeline.estimator.MotionEstimator` estimates the
   camera's relative pose since the keyframe: the 1AC vote in front, a general 5-DoF relative
   pose refined on all AC constraints out, with its covariance and an honest reliability flag;
5. the step length comes from the configured scale source (speed topic, the road at the
   known camera height with the road's normal calibrated online, a fixed speed) with a
   fallback (``hold``: the last metric speed, its uncertainty growing with the time since);
   without any metric scale the step is a unit step whose covariance says its length is
   unknown;
6. the camera pose is the keyframe's composed with the step, with its 6x6 covariance
   (`planar_vo.pipeline.motion`); the vehicle pose is the camera's through the configured
   mount (``base_link``), in 3D or flattened to x, y, yaw (``odometry.output``);
7. the frame becomes the new keyframe once its parallax reaches ``keyframe.min_parallax`` (or
   after ``keyframe.max_interval`` frames); every frame is still output;
8. calibrations that run alongside: the mount tilt from the refined motions
   (``mount.estimate_tilt``), the road normal from the road ACs (ground scale), the focal
   length from keyframe pairs the car turned between (``camera.estimate_focal``: queued, worked
   off a few steps per frame, adopted only with an honest uncertainty).

Every frame yields a `FrameResult`; a frame without an update carries a `DropReason`, and the
tracking state (tracking, lost, reinitialised) says where the chain stands.
"""

from __future__ import annotations

import copy
import logging
import math
import re
import threading
import time
from collections import deque

import numpy as np

from planar_vo.config import PlanarVoConfig
from planar_vo.core.camera import (
    CameraModel,
    field_of_view_for_focal,
    focal_for_field_of_view,
)
from planar_vo.core.conventions import (
    adjoint,
    invert,
    mount_transform,
    normal_from_tilt,
    planar_motion_from_pose,
    rotation_rpy,
    se3,
    se3_log,
    skew,
    so3_left_jacobian,
    so3_log,
    wrap_angle,
    yaw_of,
)
from planar_vo.core.correspondences import AffineCorrespondences
from planar_vo.core.robust.stats import MAD_TO_SIGMA, median
from planar_vo.errors import (
    CameraModelError,
    ConcurrencyError,
    ConfigError,
    ImageError,
    InputError,
    PlanarVoError,
    one_line,
)
from planar_vo.frontend import ACExtractor, leveling_rotation
from planar_vo.frontend.images import as_gray
from planar_vo.pipeline.calibration import (
    MountTiltEstimator,
    OnlineFocalCalibrator,
    RoadNormalCalibrator,
    TurnPairSelector,
    focal_pitch,
    pair_road_normal,
    prior_sigma_for_fov,
)
from planar_vo.pipeline.clock import (
    GAP_WATCH,
    FrameClock,
    Stamp,
    StampCheck,
    format_stamp,
    seconds_between,
    shift_stamp,
)
from planar_vo.pipeline.estimator import FrameEstimate, MotionEstimator
from planar_vo.pipeline.keyframes import Keyframe, KeyframeChain
from planar_vo.pipeline.motion import (
    compose,
    flatten,
    flatten_twist,
    ros_pose_covariance,
    ros_twist_covariance,
    to_base,
    yaw_rate_decay,
)
from planar_vo.pipeline.road_image import image_road_scale
from planar_vo.pipeline.scale import RoadScale, SpeedIntegrator, road_rays, road_scale
from planar_vo.pipeline.types import DropReason, FrameResult, TrackingState
from planar_vo.pipeline.window import RotationWindow

__all__ = ['VisualOdometry']

log = logging.getLogger(__name__)


class VisualOdometry:
    """Monocular visual odometry for a vehicle-mounted camera (1AC voting + general refinement).

    Args:
        config: the whole configuration (`PlanarVoConfig`); defaults if None.
        camera: the camera model, if known up front (else from `process` or the config's
            intrinsics; configured intrinsics get `CameraModel.check_plausible`, as a
            CameraInfo does). With ``camera.estimate_focal`` one given here is a
            `ConfigError`; one given to `process` (a CameraInfo that arrived) replaces the
            self-calibration from then on (a warning says so, once).

    One instance is one camera's state: not thread-safe (a second `process` call while one
    runs is a `ConcurrencyError`); instances in different threads are independent.

    Attributes:
        pose: ``T_odom_base`` after the last frame (4x4).
        camera_pose: ``T_world_camera`` after the last frame (world = the first camera frame).
        counters: frames processed per outcome (``'ok'`` and `DropReason` values).
        tilt_estimate: the last mount-tilt estimate (``mount.estimate_tilt``), else None.
    """

    def __init__(self, config: PlanarVoConfig | None = None,
                 camera: CameraModel | None = None) -> None:
        # Held while a `process` call runs (a second at once is refused; a review: a flag
        # set in `reset`, which a call may run, let a second call in).
        self._busy = threading.Lock()
        self.config = PlanarVoConfig() if config is None else config
        if not isinstance(self.config, PlanarVoConfig):      # (a user test: AttributeError)
            raise ConfigError(f'config: expected a PlanarVoConfig (PlanarVoConfig.from_dict '
                              f'builds one from a dict), got {type(config).__name__}')
        if camera is not None and not isinstance(camera, CameraModel):
            raise ConfigError(f'camera: expected a CameraModel or None, got '
                              f'{type(camera).__name__}')
        if camera is not None and self.config.camera.estimate_focal:
            # (a user test: the camera model was used and both options ignored without a word)
            raise ConfigError('camera: expected None with camera.estimate_focal (the focal '
                              'length is self-calibrated; a camera model gives it: turn '
                              'estimate_focal off to use one)')
        self._extractor = ACExtractor(self.config.frontend)
        self._estimator = MotionEstimator(self.config.estimator, self.config.voting)
        self._camera = camera
        # The model in use was configured: camera.fx, or the one given here (a user test: it
        # was named the CameraInfo's); a camera model passed with the frames is a CameraInfo's.
        self._camera_from_config = camera is not None
        self._size_matched = False                  # an image had the camera model's size
        self._camera_problem: str | None = None     # why the configured intrinsics are refused
        self._took_camera = False                   # a camera model replaced the calibration
        self._matched_camera: CameraModel | None = None     # the model frames were last tracked
        #                                                      with (a camera model's, given)
        self._warned_camera_size = False            # ... one of another size was refused
        self._warned_stray_camera = False           # ... one not of the tracked images' size
        self._new_size: tuple[int, int] | None = None   # an image size not yet confirmed
        self._image_size: tuple[int, int] | None = None  # the last image's (width, height)
        scale = self.config.scale
        self._speed = SpeedIntegrator(max_gap=scale.speed_max_gap)
        # Created at the first image (they need its size) when the focal length is unknown,
        # unless a first pass's is given (`start_from_first_pass`).
        self._focal: OnlineFocalCalibrator | None = None
        # Every image size's calibration (the current one among them; at most
        # _FOCAL_SIZES), so that images of a size seen before resume its calibration, and
        # those of a first pass not yet used (`start_from_first_pass`).
        self._calibrations: dict[tuple[int, int], OnlineFocalCalibrator] = {}
        self._first_pass: dict[tuple[int, int], OnlineFocalCalibrator] = {}
        self._focal_stride: int | None = None
        self._turns: TurnPairSelector | None = None
        self._in_use: CameraModel | None = camera
        self._frames = 0                            # frames processed (the focal's clock)
        mount = self.config.mount
        # base_link is where the user says the camera sits (REP-105): the configured mount.
        self._T_base_camera = mount_transform(mount.x, mount.y, mount.height, mount.roll,
                                              mount.pitch, mount.yaw)
        # The camera's tilt on the vehicle, estimated online from the refined motions (its
        # pitch and roll relative to the plane of motion), levels the ACs for the planar vote
        # and centres the planar prior once precise; the configured angles until then.
        self._tilt = (MountTiltEstimator(wobble_sigma=mount.tilt_wobble_std,
                                         max_pairs=mount.tilt_window,
                                         refit_every=mount.tilt_refit)
                      if mount.estimate_tilt else None)
        self.tilt_estimate = None
        self._level = (mount.pitch, mount.roll)
        self._level_estimated = False     # the levelling's pitch is the tilt estimate's
        self._estimator.R_lc = leveling_rotation(mount.pitch, mount.roll)
        self._road = (RoadNormalCalibrator(scale.ground_normal_acs, scale.ground_normal_frames,
                                           scale.ground_normal_refit)
                      if 'ground' in (scale.source, scale.fallback) else None)
        self._road_fit: tuple[float, float, float] | None = None
        self._keyframes = KeyframeChain()
        self._window = (RotationWindow(self.config.odometry.window_size)
                        if self.config.odometry.window_lags > 1 else None)
        self.counters: dict[str, int] = {}
        # Frames whose ground scale asked the front-end for more road ACs (`_road_acs`).
        self.road_top_ups = 0
        # Steps measured on the road's pixels (`_image_road_step`), its scans that found none
        # by reason (numbers as '#'), and the relative standard deviations of the recent steps
        # from road ACs (the pixels' steps state at least their median).
        self.image_road_steps = 0
        self.image_road_misses: dict[str, int] = {}
        self._told_faster = False       # warned that the vehicle outran ground_image_max_speed
        self._step_from = ''            # what measured the last ground step (`_scale`)
        self.image_road_examples: dict[str, str] = {}    # a miss's first message, by reason
        self._road_fed = False          # this frame's pair went to the road-normal calibration
        odometry = self.config.odometry
        self._clock = FrameClock(odometry.max_frame_gap, odometry.max_time_jump_back)
        # (yaw rate, its predicted variance) of the recent steps, for `_yaw_excess`; kept
        # across resets like the calibrations.
        self._yaw_rates: deque[tuple[float, float]] = deque(maxlen=self.config.estimator.history)
        # (direction of travel relative to the car, its predicted variance) of the recent steps,
        # for `_heading_excess`.
        self._headings: deque[tuple[float, float]] = deque(maxlen=self.config.estimator.history)
        self._norm: AffineCorrespondences | None = None   # the last pair's normalised ACs
        # Median AC displacement (pixels) per metre driven, of the last metric step: what the
        # stationary test's pixel threshold means as a speed (`_stationary`); kept across
        # resets, like the calibrations (the scene's depths do not reset).
        self._px_per_metre = math.nan
        self.reset()

    # -- state ---------------------------------------------------------------------------------

    def reset(self) -> None:
        """Pose back to the identity and a new keyframe chain from the next frame; the counters
        and the calibrations (tilt, focal length) are kept."""
        self._keyframes.clear()
        if self._window is not None:
            self._window.clear()
        self.camera_pose = np.eye(4)
        self._camera_cov = np.zeros((6, 6))
        self.pose = self._T_base_camera @ invert(self._T_base_camera)
        self._last_out: tuple[float, np.ndarray] | None = None   # stamp, camera pose
        # (the last output's stamp, the seconds since it that `_extrapolate` has grown the
        # covariance by, and the variances of its braking, persisting-turn yaw and offset terms
        # it added: a second restart from the same output adds only the rest)
        self._grown: tuple[float, ...] | None = None
        self._twist = np.zeros(6)
        self._twist_cov = np.eye(6) * _UNKNOWN
        # (end stamp, length in seconds, twist) of the last keyframe interval's mean twist.
        self._last_twist: tuple[float, float, np.ndarray] | None = None
        # the last few motion steps' (end, length, twist, scale source), and the gap whose frames
        # were found late
        self._recent_steps: deque[tuple] = deque(maxlen=GAP_WATCH + 2)
        self._late_gap: float | None = None
        self._held: tuple[float, float, float, float] | None = None   # speed, std, stamp, bias
        # (the road-AC steps' deviations for the pixels' floor are of this time base only: a
        # review, a looped bag's first pass came back as the second reached its stamps)
        self._road_relative_stds: deque[tuple[float, float]] = deque(maxlen=_ROAD_STD_HISTORY)
        # The last frame that reached tracking and its stamp, and why the run of frames
        # identical to it is a frozen camera's ('' while it is not; `_frozen`).
        self._previous_gray: np.ndarray | None = None
        self._previous_stamp: float | None = None
        self._previous_key: int | None = None   # its `_fingerprint`
        # The frames before it (newest last: image, stamp, fingerprint), to catch an older
        # image republished.
        self._older: deque[tuple[np.ndarray, float, int]] = deque(maxlen=_OLDER_FRAMES)
        self._frozen_why = ''
        self._frozen_run = 0                     # frozen frames in a row
        self._step_source = ''                   # the last motion step's scale source
        # The distance (m) standing frames may have moved unseen, until the next motion step.
        self._crept = 0.0
        # The position error (m, camera world frame) one standard deviation of the steps'
        # shared scale errors makes (`_road_step`): the same share of every step, so it grows
        # with the distance and stays out of the step covariances.
        self._bias = np.zeros(3)
        self._fresh_steps = 0                    # motion steps since start-up or the reset
        self._tilt_gain = np.zeros((6, 3))       # `Keyframe.tilt_gain` of the current pose
        self._focal_sums = np.zeros((9, 3))      # `Keyframe.focal_sums` of the current pose
        self._lost = self._miss_run = 0
        self._restart = ''          # why the next usable frame starts a new keyframe chain
        # The last frame, when it was lost against the keyframe (too few ACs or an unreliable
        # estimate): (image, stamp), for the next frame's `_bridge`; and the one this frame got.
        self._bridge_from: tuple[np.ndarray, float] | None = None
        self._bridge_source: tuple[np.ndarray, float] | None = None
        self._time_reset = False
        self._new_time_base = False
        self._state = TrackingState.INITIALISING
        self._clock.reset()
        self._estimator.reset()

    @property
    def tracking(self) -> TrackingState:
        """The tracking state after the last frame."""
        return self._state

    @property
    def camera(self) -> CameraModel | None:
        """The camera model in use (None until known; while the focal length is being
        self-calibrated, the model with the provisional or adopted focal length)."""
        return self._in_use

    @property
    def focal_calibrator(self) -> OnlineFocalCalibrator | None:
        """The online focal calibration (``camera.estimate_focal`` without intrinsics), else
        None (also once a camera model replaced it)."""
        return self._focal if self._camera is None else None

    @property
    def focal_calibrations(self) -> list[OnlineFocalCalibrator]:
        """The focal self-calibration of every image size seen (the current one last)."""
        return list(self._calibrations.values())

    def start_from_first_pass(self, *calibrators: OnlineFocalCalibrator) -> None:
        """Use the focal calibrations of a first pass over the same recording from the first
        frame on (``planar_vo replay --two-pass``; `focal_calibrations`, one per image size):
        its focal length (adopted or provisional) and its uncertainty, which enters the
        covariance as in the first pass; no pairs are added (they are the first pass's again).
        Each is used for the images of its size.

        Raises:
            ConfigError: without ``camera.estimate_focal``, or a calibrator whose first pass is
                not finished (`OnlineFocalCalibrator.finish_first_pass`).
            InputError: frames were processed already.
        """
        if not self.config.camera.estimate_focal:
            raise ConfigError('camera.estimate_focal: expected true to start from a first '
                              "pass's focal self-calibration")
        for calibrator in calibrators:
            if not (isinstance(calibrator, OnlineFocalCalibrator) and calibrator.first_pass):
                raise ConfigError('calibrator: expected an OnlineFocalCalibrator whose first '
                                  'pass is finished (finish_first_pass)')
        if self._frames:
            raise InputError(f'start_from_first_pass: expected no frame processed yet, got '
                             f'{self._frames}')
        self._first_pass = {(c.width, c.height): c for c in calibrators}

    @property
    def road_normal(self) -> tuple[float, float, float]:
        """The road normal's ``(pitch, roll, std)`` (radians) in the camera frame, as the
        ground scale uses it: calibrated online from the road ACs; before the first fit, the
        mount's tilt (configured or estimated) trusted to about a degree."""
        if self._road_fit is not None:
            return self._road_fit
        return (*self._level, _START_NORMAL_STD)

    def focal_status(self) -> str:
        """The focal length in use and where it comes from, one line: ``focal length 718.9 px
        (CameraInfo)``, ``(configured)``, or the self-calibration's ``focal length 712.3 +- 4.1
        px (self-calibrated at frame 143)`` / ``... (provisional, 2 of 4 blocks)``."""
        if self._focal is not None and self._camera is None:
            return self._focal.status()
        if self._unused_model():
            # (a user test: a CameraInfo of another size was named the source while every frame
            # was dropped for it)
            source = self._model_origin()
            origin = 'CameraInfo' if source == 'camera_info' else source
            return (f'focal length {self._in_use.fx:.1f} px ({origin}, not used: it is '
                    f'{self._in_use.width}x{self._in_use.height}, the images '
                    f'{self._image_size[0]}x{self._image_size[1]})')
        px, _, source = self.focal_length()
        if source == 'unknown':
            if self.config.camera.estimate_focal:     # (a user test: it said 'intrinsics')
                return 'focal length unknown (the self-calibration starts at the first image)'
            return 'focal length unknown (no frame with camera intrinsics yet)'
        origin = 'CameraInfo' if source == 'camera_info' else source
        return f'focal length {px:.1f} px ({origin})'

    def focal_carry(self) -> dict[str, float]:
        """The self-calibrated focal length as the settings that start this camera's next
        drive (or the node) from it, ``{'camera.nominal_fov': rad, 'camera.nominal_fov_std':
        rad}`` (with ``camera.estimate_focal``: the calibration goes on from there, and the
        odometry's covariance carries its uncertainty from the first frame); empty when not
        self-calibrating or before any turning pair was profiled."""
        if self._focal is None or self._camera is not None:
            return {}
        carried = self._focal.carry(self.config.camera.distortion_model == 'equidistant')
        if carried is None:
            return {}
        return {'camera.nominal_fov': round(carried[0], 4),
                'camera.nominal_fov_std': round(carried[1], 4)}

    def scale_status(self) -> str:
        """Where the steps' metric scale comes from, one line (a replay summary's): ``ground at
        the camera height 1.65 +- 0.01 m (mount.height)``, the speed topic, a fixed speed or
        none, with the fallback. The camera height sets every ground step, so its default is
        named as one (a user test: a replay without ``mount.height`` ran at 1.5 m unnoticed,
        t_rel 8 % instead of 2 %)."""
        cfg = self.config
        source = cfg.scale.source
        if source == 'ground':
            mount = cfg.mount
            given = ('mount.height' if mount.height != type(mount)().height else
                     'mount.height, the default: set the car\'s')
            line = (f'ground at the camera height {mount.height:g} +- {mount.height_std:g} m '
                    f'({given})')
        elif source == 'speed':
            line = f'speed topic (+- {cfg.scale.speed_std:g} m/s)'
        elif source == 'fixed':
            line = f'fixed speed {cfg.scale.fixed_speed:g} +- {cfg.scale.fixed_speed_std:g} m/s'
        else:
            line = 'none (unit steps: no metric scale)'
        pixels = (f"; too few road ACs: the road's pixels (steps up to "
                  f"scale.ground_image_max_speed {cfg.scale.ground_image_max_speed:g} m/s)"
                  if cfg.scale.ground_image else '')
        if source == 'ground':
            line += pixels
        if source != 'unit' and cfg.scale.fallback != source:
            line += f'; fallback {cfg.scale.fallback}'
            if cfg.scale.fallback == 'ground':
                line += pixels
        return line

    def focal_length(self) -> tuple[float, float, str]:
        """``(pixels, standard deviation, source)`` of the focal length `focal_status`
        describes (the one the next frame uses): source ``'unknown'`` (NaN, inf; also while
        the camera model is of another size than the images, whose frames are dropped),
        ``'camera_info'`` (a model passed with the frames), ``'configured'`` (standard
        deviation 0: ``camera.fx`` or the model given to the constructor), ``'provisional'`` or
        ``'self-calibrated'``."""
        if self._focal is not None and self._camera is None:
            cal = self._focal
            f = cal.provisional
            return (f, f * cal.relative_std,
                    'self-calibrated' if cal.adopted is not None else 'provisional')
        if self._in_use is None or self._unused_model():
            # (a user test: a CameraInfo of another size than the images was the status
            # values' focal_source while every frame was dropped for it)
            return float('nan'), float('inf'), 'unknown'
        return self._in_use.fx, 0.0, self._model_origin()

    def _model_origin(self) -> str:
        return 'configured' if self._camera_from_config else 'camera_info'

    def _unused_model(self) -> bool:
        """The camera model in use is of another size than the last image (whose frame was
        dropped for it)."""
        return (self._in_use is not None and not self._size_matched
                and self._image_size is not None and self._in_use.size != self._image_size)

    def add_speed(self, stamp: float, speed: float) -> None:
        """A speed sample (m/s) for ``scale.source = 'speed'`` (e.g. from wheel odometry)."""
        self._speed.add(float(stamp), float(speed))

    # -- the frame -----------------------------------------------------------------------------

    def process(self, image: np.ndarray, stamp: float, camera: CameraModel | None = None
                ) -> FrameResult:
        """Process one frame; never raises for bad input (the result says what went wrong).

        Args:
            image: 8-bit grey ``(H, W)`` or ``(H, W, 1)``, BGR ``(H, W, 3)`` or BGRA ``(H, W, 4)``
                image; or the `ImageError` its decoding raised (a driver's message the caller
                could not read): a ``bad_image`` frame like an unreadable array, which counts
                towards lost tracking when its stamp is new.
            stamp: its timestamp in seconds; a `Stamp` (integer nanoseconds, e.g.
                ``CameraFrame.stamp``) is judged exactly: 1 ns later is not a duplicate.
            camera: the camera model for this frame (e.g. from ``CameraInfo``); None keeps the
                last one.

        Raises:
            ConcurrencyError: another call on this instance is running (another thread): an
                instance is one camera's state, not thread-safe; give each thread its own, or
                serialise the calls (a user test: two threads sharing one got internal errors).
        """
        if not self._busy.acquire(blocking=False):
            raise ConcurrencyError('VisualOdometry.process: called while another call on this '
                                   'instance runs (from another thread): an instance is not '
                                   'thread-safe; give each thread its own instance, or '
                                   'serialise the calls with a lock')
        try:
            return self._process_frame(image, stamp, camera)
        finally:
            self._busy.release()

    def _process_frame(self, image, stamp, camera) -> FrameResult:
        """`process` (one call at a time)."""
        start = time.perf_counter()
        timings: dict[str, float] = {}
        # A frame lost against the keyframe is a bridge for this one only (`_bridge`).
        self._bridge_from, self._bridge_source = None, self._bridge_from
        try:
            seconds = stamp if isinstance(stamp, Stamp) else float(stamp)
        except (TypeError, ValueError):
            seconds = math.nan
        try:
            if not math.isfinite(seconds):
                result = self._drop(seconds, DropReason.BAD_STAMP,
                                    f'timestamp {_short(stamp)} is not a finite number')
            elif camera is not None and not isinstance(camera, CameraModel):
                result = self._drop(seconds, DropReason.NO_CAMERA_INFO,
                                    f'camera: expected a CameraModel or None, got '
                                    f'{type(camera).__name__}')
            else:
                result = self._process(image, seconds, camera, timings)
        except PlanarVoError as err:        # a bad input the checks did not anticipate
            result = self._drop(seconds, DropReason.PIPELINE_ERROR, str(err))
        except Exception as err:            # noqa: BLE001 - a bug must not stop the odometry
            log.exception('pipeline error at stamp %.6f', seconds)
            result = self._drop(seconds, DropReason.PIPELINE_ERROR,
                                f'{type(err).__name__}: {err}')
        if self._focal is not None and self._camera is None:
            t = time.perf_counter()
            try:
                self._focal.work(self.config.camera.focal_steps, self._frames)
            except Exception:               # noqa: BLE001 - a bug must not stop the odometry
                # (the frame's result stands; the pair is lost from the calibration)
                log.exception('focal self-calibration error at frame %d', self._frames)
            timings['focal'] = timings.get('focal', 0.0) + time.perf_counter() - t
        self._frames += 1
        timings['total'] = time.perf_counter() - start
        key = 'ok' if result.ok else result.reason.value
        self.counters[key] = self.counters.get(key, 0) + 1
        return _with_timings(result, timings)

    def _process(self, image, stamp: float, camera: CameraModel | None,
                 timings: dict[str, float]) -> FrameResult:
        # The image first: a frame refused as bad_image leaves the clock alone (its stamp
        # is not taken, so the same stamp sent again with a good image is not a duplicate).
        t = time.perf_counter()
        try:
            gray = _gray(image)
        except ImageError as err:
            last = self._clock.last
            if last is not None and seconds_between(stamp, last) > 0:
                # Time went by without an image: it counts towards lost tracking, as a blank
                # one does (a user test: after five undecodable frames the stale keyframe cost
                # five good ones more).
                return self._lost_frame(stamp, DropReason.BAD_IMAGE, str(err), 0)
            return self._drop(stamp, DropReason.BAD_IMAGE, str(err))
        last = self._clock.last
        check = self._clock.check(stamp)
        if check is StampCheck.DUPLICATE:
            return self._drop(stamp, DropReason.DUPLICATE_STAMP,
                              f'timestamp {format_stamp(stamp)} repeats the previous frame'
                              + (' (a stamp of 0: does the driver set the header stamps?)'
                                 if float(stamp) == 0.0 else ''))
        if check is StampCheck.TOO_CLOSE:
            usual = self._clock.usual_interval
            return self._drop(stamp, DropReason.DUPLICATE_STAMP,
                              f'timestamp {format_stamp(stamp)} is '
                              f'{1e3 * seconds_between(stamp, last):.3g} ms after the previous '
                              f'frame, under {1e3 * FrameClock.TOO_CLOSE_S:g} ms and a quarter of '
                              f'the usual {1e3 * usual:.3g} ms: a duplicated or mis-stamped '
                              f'frame')
        if check is StampCheck.INSIDE_GAP:
            # (a user test: 'after a gap' was said of a frame among the first, evenly stamped)
            after = ('one of the first frames, whose stamps are not yet known to be even' if
                     self._clock.inside_start else 'which came after a gap')
            return self._drop(stamp, DropReason.OUT_OF_ORDER,
                              f'timestamp {format_stamp(stamp)} is older than the previous '
                              f'{format_stamp(last)}, {after}: if the next frame is older '
                              f'too, that one was stamped ahead of its time')
        if check is StampCheck.OUT_OF_ORDER:
            return self._drop(stamp, DropReason.OUT_OF_ORDER,
                              f'timestamp {format_stamp(stamp)} is older than the previous '
                              f'{format_stamp(last)}')
        if check is StampCheck.FAR_BEHIND:
            return self._drop(stamp, DropReason.OUT_OF_ORDER,
                              f'timestamp {format_stamp(stamp)} is '
                              f'{_seconds(seconds_between(last, stamp))} s before the previous '
                              f'frame '
                              f'(more than odometry.max_time_jump_back); refused unless the '
                              f'next frame confirms the older time (a looped bag, a restarted '
                              f'clock)')
        if check is StampCheck.JUMP_AHEAD:
            return self._drop(stamp, DropReason.TIME_JUMP_AHEAD,
                              f'timestamp {format_stamp(stamp)} is '
                              f'{_seconds(seconds_between(stamp, last))} s after '
                              f'the previous frame (more than odometry.max_frame_gap); refused '
                              f'unless the next frame confirms the new time')
        if check is StampCheck.JUMP_BACK:
            log.warning('time jumped back %.3f s (looped bag or restarted clock): tracking '
                        'reset', -self._clock.jump)
            self.reset()
            self._clock.check(stamp)
            self._time_reset = True
        elif check is StampCheck.REWOUND:
            if not self._mis_stamp_fits(gray, self._in_use, self._clock.mis_stamped[0]):
                return self._drop(stamp, DropReason.OUT_OF_ORDER,
                                  f'timestamp {format_stamp(stamp)} is older than the previous '
                                  f'{format_stamp(last)}, which came after a gap, and does not '
                                  f'show it stamped ahead: a frame delivered late')
            self._clock.rewind()
            self._rewind(*self._clock.mis_stamped)
        elif check is StampCheck.NEW_TIME_BASE and self._fresh_steps == 0:
            # No motion was estimated on the old time base (a user test: one frame stamped
            # 1000 s early came first, became the origin, and the drive after it was held
            # there with a std of 1000 m): the odometry starts afresh on the new one.
            log.warning('time moved on by %.3f s before any motion was estimated: the '
                        'odometry starts afresh at the origin', self._clock.jump)
            self.reset()
            self._clock.check(stamp)
        elif check is StampCheck.NEW_TIME_BASE:
            log.warning('time moved on by %.3f s: tracking restarts, the pose held (the '
                        'motion across a new time base is unknown)', self._clock.jump)
            self._keyframes.clear()
            self._restart, self._new_time_base = 'the time base moved on', True
        self._image_size = (gray.shape[1], gray.shape[0])
        camera = self._resolve_camera(camera, gray.shape)
        if camera is None:
            c = self.config.camera
            if c.fx > 0 and self._camera_problem is not None:
                return self._drop(stamp, DropReason.NO_CAMERA_INFO,
                                  f'configured intrinsics (camera.fx, fy, cx, cy, distortion): '
                                  f'{self._camera_problem} (no camera model)')
            if c.fx > 0 or c.estimate_focal:
                # (unset, 0: the image centre, said so; a user test saw 'cy 0' for an unset cy)
                centre = [f'{value:g}' if value else f'{(size - 1) / 2.0:g}, the image centre'
                          for value, size in ((c.cx, gray.shape[1]), (c.cy, gray.shape[0]))]
                return self._drop(stamp, DropReason.NO_CAMERA_INFO,
                                  f'camera.cx, camera.cy ({centre[0]}; {centre[1]}) lie outside '
                                  f'the {gray.shape[1]}x{gray.shape[0]} image: no camera model')
            return self._drop(stamp, DropReason.NO_CAMERA_INFO,
                              'no camera intrinsics yet (no valid CameraInfo and camera.fx = 0; '
                              'or set camera.estimate_focal: true to self-calibrate)')
        if camera.size != (gray.shape[1], gray.shape[0]):
            if not self._size_matched:
                # No image has had this model's size: the intrinsics are another camera's or
                # another resolution's (a user test: counted as size changes of every frame).
                return self._drop(stamp, DropReason.NO_CAMERA_INFO,
                                  f'the camera model (CameraInfo) is {camera.width}x'
                                  f'{camera.height} but the image is {gray.shape[1]}x'
                                  f'{gray.shape[0]}: intrinsics of another camera or resolution')
            # A stray frame of another size: drop it, keep tracking (a new camera model with
            # the new size resets the keyframe in _resolve_camera; self-calibrating, a second
            # frame of the new size does).
            again = (' (self-calibrating: a second image of this size in a row starts a new '
                     'focal self-calibration)' if self._camera is None else '')
            return self._drop(stamp, DropReason.SIZE_CHANGED,
                              f'image is {gray.shape[1]}x{gray.shape[0]} but the camera model is '
                              f'{camera.width}x{camera.height}{again}')
        self._size_matched = True
        if self._camera is not None:
            self._matched_camera = camera
        if _is_blank(gray, self.config.odometry.min_contrast):
            # Nothing to track: the frame counts towards lost tracking (a tunnel, a covered
            # lens), but it never becomes a keyframe. It is another image: a run of repeated
            # ones ends (A, blank, A is one repeated frame, not a run of two).
            self._frozen_run = 0
            return self._lost_frame(stamp, DropReason.BLANK_IMAGE,
                                    'image is blank (black, saturated or without texture)', 0)
        key = _fingerprint(gray)
        frozen = self._frozen(gray, stamp, key)
        if self._previous_gray is not None:
            self._older.append((self._previous_gray, self._previous_stamp, self._previous_key))
        self._previous_gray, self._previous_stamp, self._previous_key = gray, stamp, key
        if frozen:
            # Like a blank frame: it counts towards lost tracking and never becomes a keyframe
            # (before, a republished image read as a stop: the pose held with a confident speed
            # of 0 while the car drove on). One repeated frame alone (a duplicated video frame)
            # adds nothing and loses nothing: the tracking state changes from the second on (a
            # review: each duplicate of a video flipped it to lost and back, a warning each).
            self._frozen_run += 1
            if self._frozen_run == 1:
                return self._drop(stamp, DropReason.FROZEN_IMAGE, frozen)
            if self._frozen_run == 2:
                self._lost += 1         # the run's first frame counts towards lost tracking now
            return self._lost_frame(stamp, DropReason.FROZEN_IMAGE, frozen, 0)
        self._frozen_run = 0
        timings['decode'] = time.perf_counter() - t
        keyframe = self._keyframes.current
        if keyframe is None:
            return self._start_chain(gray, stamp)

        t = time.perf_counter()
        acs = self._extractor.extract(keyframe.image, gray)
        timings['correspondences'] = time.perf_counter() - t
        bridged = None
        if len(acs) < self.config.odometry.min_correspondences:
            bridged = self._bridge(gray, stamp, camera, timings)
            if bridged is None and self._miss_run >= _OUTGROWN_MISSES and len(acs) \
                    and not self._restart:
                # The keyframe's last chance (`_lost_frame`) failed too, and this frame, like
                # the two before it, still sees some of the keyframe's scene: the frames have
                # moved away from it, and this one starts a new chain.
                self._keyframes.clear()
                self._restart = 'lost tracking'
                return self._start_chain(gray, stamp)
            if bridged is None:
                # (also with none: frames that moved away from the keyframe can go from some
                # to none at once, a review; a garbled one fails the next frame's bridge)
                self._bridge_from = (gray, stamp)
                return self._lost_frame(stamp, DropReason.TOO_FEW_CORRESPONDENCES,
                                        f'{len(acs)} correspondences (minimum '
                                        f'{self.config.odometry.min_correspondences})', len(acs))
        else:
            keyframe.matched = True
            parallax = median(np.linalg.norm(acs.p2 - acs.p1, axis=1))
            if parallax < self.config.keyframe.stationary_parallax:
                return self._stationary(keyframe, stamp, len(acs))
            t = time.perf_counter()
            est = self._estimate(acs, camera)
            timings['solve'] = time.perf_counter() - t
            if not est.reliable:
                bridged = self._bridge(gray, stamp, camera, timings)
                if bridged is None:
                    self._bridge_from = (gray, stamp)
                    return self._lost_frame(stamp, DropReason.UNRELIABLE,
                                            f'motion estimate flagged {est.flag!r} '
                                            f'({est.num_inliers} inliers of {len(acs)})',
                                            len(acs), est.num_inliers)
        if bridged is not None:
            keyframe, acs, est, parallax = bridged
        t = time.perf_counter()
        scale, var_scale, source, bias = self._scale(acs, camera, est, keyframe, stamp, gray)
        timings['scale'] = time.perf_counter() - t
        t = time.perf_counter()
        self.camera_pose, self._camera_cov, step_cov = compose(
            keyframe.pose, keyframe.covariance, est.R, est.t, est.basis,
            self._motion_covariance(est, seconds_between(stamp, keyframe.stamp)), scale, var_scale)
        self._bias = keyframe.bias + bias * (self.camera_pose[:3, 3] - keyframe.pose[:3, 3])
        distance = float(np.linalg.norm(self.camera_pose[:3, 3] - keyframe.pose[:3, 3]))
        if source in _METRIC_SOURCES and distance > 0.0:
            self._px_per_metre = parallax / distance
        if self._tilt is not None:
            self._tilt_gain = _tilt_gain(keyframe, self.camera_pose, est.R,
                                         self._estimator.R_lc)
        if self._focal is not None:
            # Road-scaled lengths scale with the focal length, so do speeds held from them.
            ground = source == 'ground' or (source == 'hold'
                                            and self.config.scale.source == 'ground')
            self._focal_sums = _focal_sums(
                keyframe.focal_sums, keyframe.pose[:3, :3], -so3_log(est.R),
                self.camera_pose[:3, 3] - keyframe.pose[:3, 3], camera.fx, ground)
            if self._camera is None:
                # The twist is one step's: the focal length's error is that step's alone there.
                step_cov = step_cov + _focal_step_covariance(
                    est.R, est.t, scale, ground, min(self._focal.relative_std, 1.0),
                    self._focal.pp_std / camera.fx)
        self._update_twist(keyframe, stamp, step_cov)
        self._step_source = source
        if self._last_twist is not None and self._last_twist[0] == stamp:
            self._recent_steps.append((*self._last_twist, source))
        self._twist_cov[:3, :3] += bias * bias * np.outer(self._twist[:3], self._twist[:3])
        new_keyframe = (parallax >= self.config.keyframe.min_parallax
                        or keyframe.age + 1 >= self.config.keyframe.max_interval)
        timings['integrate'] = time.perf_counter() - t
        if new_keyframe:
            if self._window is not None:
                t = time.perf_counter()
                self._windowed(keyframe, gray, camera, est)
                timings['window'] = time.perf_counter() - t
            self._keyframes.add(gray, stamp, self.camera_pose, self._camera_cov, self._bias,
                                self._tilt_gain, self._focal_sums).matched = False
        else:
            keyframe.age += 1
        self._lost = self._miss_run = 0
        R_lc = self._estimator.R_lc
        alpha, beta = planar_motion_from_pose(R_lc @ est.R @ R_lc.T, R_lc @ est.t)
        if new_keyframe and self._focal is not None and self._camera is None \
                and not self._focal.first_pass:
            t = time.perf_counter()
            self._offer_focal_pair(gray, camera, float(alpha))
            timings['focal'] = time.perf_counter() - t
        return self._result(stamp, True, keyframe=new_keyframe, scale_source=source,
                            scale_from=self._step_from if source == 'ground' else '',
                            num_correspondences=len(acs), num_inliers=est.num_inliers,
                            alpha=float(alpha), beta=float(beta),
                            message='' if bridged is None else
                            'tracked from the frame before, lost against the keyframe: a new '
                            'keyframe chain from it, its pose extrapolated')

    def _bridge(self, gray: np.ndarray, stamp: float, camera: CameraModel | None,
                timings: dict[str, float]):
        """This frame, lost against the keyframe, against the frame before it when that one
        was lost against the keyframe too (`_bridge_source`): a reliable motion between the two
        restarts the chain at the frame before, at the pose extrapolated to it, and this frame
        is tracked from there. Frames that moved away from the keyframe (a lost frame makes the
        next step twice as long, the one after three times) lost six frames and the chain for
        two frames missing in transport (a user test); a frame the two share a disturbance with
        (a truck across both, or a motion the car could not have made: `_plausible_bridge`)
        stays lost. Returns ``(keyframe, acs, estimate, parallax)``, or None (nothing
        changed: the estimate ran on a copy of the estimator)."""
        source, self._bridge_source = self._bridge_source, None
        keyframe = self._keyframes.current
        if source is None or camera is None or self._restart or keyframe is None or \
                source[0].shape != gray.shape:
            return None
        previous = self._keyframes.previous
        if not keyframe.matched and previous is not None and \
                keyframe.contrast < _DIM_KEYFRAME * previous.contrast:
            return None     # a dim keyframe nothing matched yet: the one before it takes over
        #                     (`_lost_frame`), exactly, without extrapolating
        before, when = source
        t = time.perf_counter()
        found = self._trial_motion(before, gray, camera, self.config.keyframe.stationary_parallax)
        timings['bridge'] = time.perf_counter() - t
        if found is None or not self._plausible_bridge(found[2], seconds_between(stamp, when)):
            return None
        acs, parallax, est, trial, norm = found
        self._estimator, self._norm = trial, norm       # (the copy's fit, kept with the motion)
        self._calibrate_tilt(est)
        self._keyframes.clear()
        if self._window is not None:
            self._window.clear()
        self._extrapolate(when)
        keyframe = self._keyframes.add(before, when, self.camera_pose, self._camera_cov,
                                       self._bias, self._tilt_gain, self._focal_sums)
        keyframe.matched = True
        self._last_out = (when, self.camera_pose.copy())
        return keyframe, acs, est, parallax

    def _plausible_bridge(self, est, dt: float) -> bool:
        """Whether a bridge's motion is one the vehicle could have made since its last step:
        the frames lost against the keyframe may be the ones a passing truck covers, whose
        motion a bridge would take for the car's (a review). The travel within
        `_BRIDGE_DIRECTION` of the last velocity's direction (when it moved at 0.5 m/s or
        more), the yaw within `_BRIDGE_YAW` of the last turn rate's over ``dt``."""
        alpha, moved = self._base_motion(est)
        velocity, rate = self._twist[:3], float(self._twist[5])
        speed = float(np.linalg.norm(velocity))
        if speed >= 0.5:
            cos = float(moved @ velocity) / max(float(np.linalg.norm(moved)) * speed, 1e-300)
            if cos < math.cos(_BRIDGE_DIRECTION):
                return False
        return abs(alpha - rate * max(dt, 0.0)) <= _BRIDGE_YAW

    def _trial_motion(self, before: np.ndarray, gray: np.ndarray, camera: CameraModel,
                      min_parallax: float):
        """The motion from image ``before`` to ``gray`` on a copy of the estimator (its own
        would take the motion, perhaps backwards, as the car's latest; its answer's direction
        is resolved by the cheirality of its inliers: the planar vote's alone put a car
        starting off on KITTI 05 backwards, a user test): ``(acs, parallax, estimate, the
        copy, the normalised ACs)``, or None with too few correspondences, a parallax below
        ``min_parallax`` or an unreliable estimate (`_bridge`, `_mis_stamp_fits`)."""
        acs = self._extractor.extract(before, gray)
        if len(acs) < self.config.odometry.min_correspondences:
            return None
        parallax = median(np.linalg.norm(acs.p2 - acs.p1, axis=1))
        if not parallax >= min_parallax:
            return None
        trial = copy.deepcopy(self._estimator)
        norm, level = self._levelled(acs, camera)
        est = trial.estimate(norm, level)
        return (acs, parallax, est, trial, norm) if est.reliable else None

    def _base_motion(self, est) -> tuple[float, np.ndarray]:
        """A relative pose's yaw (rad) and the camera's displacement direction, in base_link
        axes (``X2 = R X1 + t``: the centre moves by ``-R^T t``)."""
        T = self._T_base_camera[:3, :3]
        return float(yaw_of(T @ est.R.T @ T.T)), T @ (-est.R.T @ est.t)

    # -- steps ---------------------------------------------------------------------------------

    def _resolve_camera(self, camera: CameraModel | None, shape: tuple[int, int]
                        ) -> CameraModel | None:
        if camera is not None and self.config.camera.estimate_focal and self._camera is None:
            # The images' size: the calibration's (one stray image of another size does not
            # change it: a review), else this one's.
            height, width = shape if self._focal is None else (self._focal.height,
                                                               self._focal.width)
            if camera.size != (width, height):
                # A model of another resolution cannot replace the self-calibration of these
                # images (a review: every frame was then refused as no_camera_info): it goes on
                # until a model of their size comes.
                if not self._warned_camera_size:
                    log.warning('a camera model of %dx%d arrived for %dx%d images: the focal '
                                'self-calibration goes on until one of their size comes',
                                camera.width, camera.height, width, height)
                    self._warned_camera_size = True
                camera = None
            elif not self._took_camera:
                # A camera model (a CameraInfo that arrived late) replaces the self-calibration;
                # said once (a user test: it happened without a word).
                log.warning('a camera model arrived: it replaces the focal self-calibration '
                            '(camera.estimate_focal) from frame %d on', self._frames)
                self._took_camera = True
                in_use = self._in_use
                if in_use is not None and in_use.size == camera.size and in_use.fx != camera.fx:
                    # What the image measured through the provisional focal length is carried
                    # to the model's (a review: the levelling kept 3.2 deg where 4.0 was seen).
                    self._refocus(in_use.fx / camera.fx)
        matched = self._matched_camera
        if (camera is not None and camera.size != (shape[1], shape[0]) and matched is not None
                and matched.size == (shape[1], shape[0])):
            # The images keep the size of the model they were tracked with: one of another
            # size (a second camera's CameraInfo on the topic) is not theirs, and that one stays
            # in use (a user test: every frame was dropped until a matching one came again).
            if not self._warned_stray_camera:
                log.warning('a camera model of %dx%d arrived for %dx%d images: the last one of '
                            'their size stays in use', camera.width, camera.height, shape[1],
                            shape[0])
                self._warned_stray_camera = True
            camera = None
        if camera is not None:
            # Against the model the last frames were tracked with, and only for a model of the
            # images' size, which is used from this frame on (a user test: a stray CameraInfo of
            # another size, refused, restarted the chain when the right one came back).
            reference = self._matched_camera if self._matched_camera is not None else \
                self._camera
            if (reference is not None and camera != reference
                    and camera.size == (shape[1], shape[0])):
                shift = reference.pixel_shift(camera)
                if shift > _SAME_CAMERA_SHIFT and self._keyframes.current is not None:
                    # The keyframe's pixels do not mean what they did: restart the chain
                    # like lost tracking (the pose extrapolated over the frame interval, its
                    # covariance grown). A smaller change (a recalibration) keeps the chain.
                    log.debug('camera model changed (the image moves up to %.3g px): new '
                              'keyframe chain', shift)
                    self._keyframes.clear()
                    self._restart = 'a camera model change'
            if camera != self._camera:
                self._size_matched = False
            self._camera = camera
            self._camera_from_config = False
        if self._camera is None:
            c = self.config.camera
            height, width = shape
            cx, cy = (c.cx or (width - 1) / 2.0), (c.cy or (height - 1) / 2.0)
            if (c.fx > 0 or c.estimate_focal) and not (cx <= width - 1 and cy <= height - 1):
                return None                 # a principal point outside the image
            if c.fx > 0:
                model = CameraModel(
                    width, height, np.array([[c.fx, 0.0, cx], [0.0, c.fy or c.fx, cy],
                                             [0.0, 0.0, 1.0]]),
                    c.distortion_model, c.coefficients)
                try:
                    # The checks a CameraInfo gets (a user test: fx 1 px lost every frame as
                    # 'unreliable', 100000 px published NaN covariances).
                    model.check_plausible()
                except CameraModelError as err:
                    self._camera_problem = str(err)
                    return None
                self._camera, self._camera_problem = model, None
                self._camera_from_config = True
            elif c.estimate_focal:
                # Uncalibrated: the self-calibration's focal length, provisional (a prior at the
                # camera's stated field of view, else 53 degrees, combined with the pairs so
                # far) until adopted.
                if self._focal is not None and (self._focal.width, self._focal.height) == \
                        (width, height):
                    self._new_size = None
                elif (self._focal is not None and self._size_matched and self._in_use is not None
                      and self._new_size != (width, height)):
                    # One image of another size (a stray frame) is dropped as a size change,
                    # as with a camera model (`process`); a second one in a row is a new
                    # resolution (a review: one stray frame threw the calibration away, and the
                    # return to the old size the next one).
                    self._new_size = (width, height)
                    return self._in_use
                else:
                    self._new_size = None
                    if self._focal is not None:
                        # Another image size: its own calibration, and the keyframe's pixels do
                        # not mean what they did (a new chain, as for a new camera model); the
                        # focal sums' pixels become the new image's.
                        k = width / self._focal.width
                        self._focal_sums[[1, 3, 7]] *= k
                        self._focal_sums[[5, 8]] /= k
                        if self._keyframes.current is not None:
                            self._keyframes.clear()
                            self._restart = 'a camera model change'
                    self._focal_stride = None
                    self._focal = self._focal_calibration(width, height)
                    self._turns = TurnPairSelector(width)
                f = self._focal.provisional
                if self._in_use is not None:
                    # Angles measured through the old focal length keep their pixels: over the
                    # image width when the image size changed (a new calibration).
                    ratio = (self._in_use.fx / self._in_use.width) / (f / width)
                    if ratio != 1.0:
                        self._refocus(ratio)
                if self._in_use is None or self._in_use.size != (width, height) \
                        or self._in_use.fx != f:
                    self._in_use = CameraModel(
                        width, height, np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]]),
                        c.distortion_model, c.coefficients)
                return self._in_use
        self._in_use = self._camera
        return self._camera

    def _focal_calibration(self, width: int, height: int) -> OnlineFocalCalibrator:
        """The focal self-calibration of images of this size: a first pass's
        (`start_from_first_pass`), else this size's own from before (a user test: two stray
        frames in a row, and the drive's turn was lost when the old size came back), else a new
        one at the prior of ``camera.nominal_fov``; kept for the last `_FOCAL_SIZES` sizes."""
        c = self.config.camera
        size = (width, height)
        focal = self._first_pass.pop(size, None) or self._calibrations.pop(size, None)
        if focal is None:
            nominal = (focal_for_field_of_view(width, c.nominal_fov, c.distortion_model)
                       if c.nominal_fov > 0 else float(max(width, height)))
            focal = OnlineFocalCalibrator(
                width, height, nominal, pp_std=1.0 if c.cx and c.cy else None,
                prior_fov=field_of_view_for_focal(width, nominal, c.distortion_model),
                stated=c.nominal_fov > 0,
                prior_sigma=(prior_sigma_for_fov(c.nominal_fov, c.nominal_fov_std,
                                                 c.distortion_model == 'equidistant')
                             if c.nominal_fov_std > 0 else None),
                prior_fov_std=c.nominal_fov_std,
                tolerance=c.focal_tolerance, max_acs=c.focal_max_acs,
                max_queue=c.focal_queue, block_frames=c.focal_block_frames,
                min_blocks=c.focal_min_blocks, max_blocks=c.focal_max_blocks,
                config=self.config.voting)
        self._calibrations[size] = focal
        while len(self._calibrations) > _FOCAL_SIZES:
            del self._calibrations[next(iter(self._calibrations))]
        return focal

    def _refocus(self, ratio: float) -> None:
        """The focal length in use changed (self-calibration; ``ratio = f_old / f_new``, of the
        focal lengths over the image widths when the image size changed too): carry what was
        measured in the image through the old one to the new one: the mount tilt's pairs and
        the levelling from them (`MountTiltEstimator.refocus`), the road normal
        (`RoadNormalCalibrator.refocus`), the estimator's history (`MotionEstimator.refocus`).
        A configured mount pitch is an angle, not an image measurement: it stays."""
        if self._tilt is not None:
            self._tilt.refocus(ratio)
            if self.tilt_estimate is not None:
                self.tilt_estimate = self._tilt.latest
            if self._level_estimated:
                self._level = (focal_pitch(self._level[0], ratio), self._level[1])
                self._estimator.R_lc = leveling_rotation(*self._level)
        if self._road is not None:
            self._road.refocus(ratio)
            fit = self._road.latest
            if fit is not None and self._road_fit is not None:
                self._road_fit = (fit.pitch, fit.roll, math.hypot(fit.pitch_std, fit.roll_std))
        self._estimator.refocus(ratio)

    def _estimate(self, acs: AffineCorrespondences, camera: CameraModel) -> FrameEstimate:
        """The camera's relative pose since the keyframe (`MotionEstimator`)."""
        norm, level = self._levelled(acs, camera)
        est = self._estimator.estimate(norm, level)
        if est.reliable:
            self._calibrate_tilt(est)
        self._norm = norm
        return est

    def _levelled(self, acs: AffineCorrespondences, camera: CameraModel
                  ) -> tuple[AffineCorrespondences, AffineCorrespondences]:
        """The ACs normalised (undistorted, ``K^-1``) and the same levelled by ``R_lc``, item by
        item: a ray the levelling sends to infinity (only about 90 degrees off axis) is dropped
        from both."""
        norm = acs.normalized(camera)
        level, kept = norm.mapped_kept(self._estimator.R_lc)
        return (norm if kept.all() else norm.subset(kept)), level

    def _calibrate_tilt(self, est: FrameEstimate) -> None:
        """Feed a reliable relative pose to the mount-tilt estimate (``mount.estimate_tilt``);
        its pitch and roll level the vote and the prior once their standard deviations are
        below ``mount.tilt_tolerance`` (each angle on its own; the configured one until then).
        The estimator's measured non-planarity (the car's pitch and roll between frames) sets
        which rotations are large enough to show the motion plane's normal. Amortised: the
        estimator refits every ``mount.tilt_refit`` pairs."""
        if self._tilt is None:
            return
        cfg = self.config.mount
        self._tilt.add_motion(est.R, est.t)
        wobble = self._estimator.non_planarity
        if math.isfinite(wobble) and abs(wobble - self._tilt.wobble_sigma) > \
                _WOBBLE_CHANGE * self._tilt.wobble_sigma:
            self._tilt.wobble_sigma = wobble          # refits at the next update
        estimate = self._tilt.update()
        if estimate is None or estimate is self.tilt_estimate:
            return
        self.tilt_estimate = estimate
        self._level_estimated = estimate.pitch_std <= cfg.tilt_tolerance
        pitch = estimate.pitch if self._level_estimated else cfg.pitch
        roll = estimate.roll if estimate.roll_std <= cfg.tilt_tolerance else cfg.roll
        if (pitch, roll) == self._level:
            return
        first = self._level == (cfg.pitch, cfg.roll)
        self._level = (pitch, roll)
        self._estimator.R_lc = leveling_rotation(pitch, roll)
        (log.info if first else log.debug)(
            'mount tilt from %d pairs: pitch %.3f +- %.3f deg, roll %.3f +- %.3f deg; levelling '
            'with pitch %.3f, roll %.3f deg (base_link stays where mount.* puts it)',
            estimate.frames, np.rad2deg(estimate.pitch), np.rad2deg(estimate.pitch_std),
            np.rad2deg(estimate.roll), np.rad2deg(estimate.roll_std), np.rad2deg(pitch),
            np.rad2deg(roll))

    def _windowed(self, keyframe: Keyframe, gray: np.ndarray, camera: CameraModel,
                  est: FrameEstimate) -> None:
        """The new keyframe's orientation from the window (``odometry.window_lags > 1``): the
        pair from the previous keyframe (this frame's estimate), pairs from the kept keyframes
        before it (ACs against their images, refined from the composed prediction), then the
        window's joint solve (`planar_vo.pipeline.window`). Only the new keyframe's published
        orientation changes; its position follows the frame-to-frame chain."""
        window = self._window
        j = self._keyframes.next_index
        if keyframe.index not in window:
            window.clear()
            window.add_keyframe(keyframe.index, keyframe.pose[:3, :3])
        window.add_keyframe(j, self.camera_pose[:3, :3])
        window.add_pair(keyframe.index, j, est.R, est.cov[:3, :3])
        for lag in range(2, self.config.odometry.window_lags + 1):
            old = self._keyframes.find(j - lag)
            # (The frame's own reference after a dim keyframe's fallback: measured above.)
            if old is None or old is keyframe or old.index not in window:
                continue
            acs = self._extractor.extract(old.image, gray)
            if len(acs) < self.config.odometry.min_correspondences:
                continue
            C_old, C_new = window.orientation(old.index), window.orientation(j)
            R0 = C_new.T @ C_old
            c = C_old.T @ (self.camera_pose[:3, 3] - old.pose[:3, 3])   # in the old camera
            if not np.linalg.norm(c) > 0:
                continue
            pair = self._estimator.refine_from(acs.normalized(camera), R0, -R0 @ c)
            if pair.reliable:
                window.add_pair(old.index, j, pair.R, pair.cov[:3, :3])
        self.camera_pose[:3, :3] = window.solve()[j]

    def _motion_covariance(self, est: FrameEstimate, dt: float) -> np.ndarray:
        """The estimator's 5x5 covariance, widened by the rotation and heading errors the
        estimator's own covariance misses (`_yaw_excess`, `_heading_excess`, measured before
        this step; the step's yaw rate, heading and predicted variances then join their
        histories). Before they can be measured (`_EXCESS_MIN_STEPS`), the rotation and the
        heading are widened by the nominal AC accuracy (`_heading_nominal`). A self-calibrated
        focal length's error is shared by the steps: `_focal_covariance`, not here.

        The rotation's excess is measured on the yaw and added about all three axes: the
        errors the ACs share are not the yaw's alone. Measured against the ground truth (dev
        script rollz.py, shipped defaults, calibrated): per step the pitch and roll errors are
        0.024 and 0.022 deg rms on KITTI 05 (the yaw's 0.010), 0.024 and 0.030 on the KITTI 06
        excerpt (the yaw's 0.044), more than ten times what the estimator predicts
        (0.0011-0.0017). With the excess on the yaw only, the published roll was off by up to
        18 of its standard deviations on KITTI 05 (70 on the KITTI 06 excerpt); with it on all
        three axes by at most 1.41 (3.22), the pitch by at most 1.17 (1.04) (`planar_vo eval`,
        planar_vo/bench/results/covariance)."""
        cov = est.cov.copy()
        R_lc = self._estimator.R_lc
        yaw = float(so3_log(R_lc @ est.R @ R_lc.T)[1])
        # The first steps after start-up or a reset are widened by the nominal accuracy even
        # when the histories (kept across resets) could measure the excess: a reset restarts
        # the odometry as start-up does (a user test: after ~/reset the lateral error reached
        # 5 standard deviations within 20 m, where the chain from start-up stayed within 2.6).
        measured = self._fresh_steps >= _EXCESS_MIN_STEPS
        self._fresh_steps += 1
        if dt > 0:
            up = R_lc[1]                    # the level vertical in the camera frame
            if measured and len(self._yaw_rates) >= _EXCESS_MIN_STEPS:
                excess = self._yaw_excess() * dt * dt
            else:
                # Before the excess can be measured: the nominal accuracy of the ACs
                # (``voting.point_noise``) as an error shared by all of them, i.e. a rotation
                # of about that many radians (0.057 deg at the default; on KITTI 05 and 06 the
                # measured excess later is 0.010-0.044 deg per step: conservative, not zero).
                excess = self.config.voting.point_noise ** 2
            self._yaw_rates.append((yaw / dt, float(up @ cov[:3, :3] @ up) / (dt * dt)))
            cov[:3, :3] += excess * np.eye(3)
        # The heading of travel: the horizontal angle of the camera's motion (-t) in the level
        # frame; its gradient through the direction's tangent basis gives its variance.
        x, _, z = -(R_lc @ est.t)
        horizontal = x * x + z * z
        if horizontal > 0:
            g = (R_lc.T @ np.array([z, 0.0, -x]) / horizontal) @ -est.basis       # (2,)
            gg = float(g @ g)
            if gg > 0:
                excess = (self._heading_excess()
                          if measured and len(self._headings) >= _EXCESS_MIN_STEPS
                          else self._heading_nominal(est))
                # Along an arc the heading of travel turns by half the camera's yaw, which is
                # -yaw (``yaw`` rotates points, not the camera).
                self._headings.append((math.atan2(x, z) + 0.5 * yaw,
                                       float(g @ cov[3:5, 3:5] @ g)))
                v = g / gg                  # the direction change that moves the heading by 1
                cov[3:5, 3:5] += excess * np.outer(v, v)
        return cov

    def _yaw_excess(self) -> float:
        """Variance ((rad/s)^2) of the yaw-rate error that the estimator's covariance does not
        account for, measured online without ground truth: a car's yaw rate changes smoothly,
        so the change of the measured rate from one step to the next is mostly error (twice a
        step's variance), and its robust spread over the recent steps, less the variance the
        estimator predicted, is the excess (the rate changes of real turns only add to it:
        conservative). Why: the estimator's covariance describes white noise on the ACs, while
        real frames also carry errors shared by all ACs (KITTI 05 and the KITTI 06 excerpt,
        a dev script: a predicted yaw standard deviation of 0.0011-0.0017 deg per frame
        against 0.010-0.044 deg rms of error). Measured on the yaw only: the pitch and roll
        rates change with the suspension from frame to frame, which is motion, not error (their
        rate changes spread 0.065 deg per step on KITTI 05, three times their error); the
        excess is then added about all three axes (`_motion_covariance`)."""
        if len(self._yaw_rates) < _EXCESS_MIN_STEPS:
            return 0.0              # the caller uses the nominal accuracy until then
        h = np.array(self._yaw_rates)
        return _excess_variance(np.diff(h[:, 0]), h[:, 1], 0.5)

    def _heading_excess(self) -> float:
        """Variance (rad^2) of the heading-of-travel error that the estimator's covariance does
        not account for, measured online without ground truth like `_yaw_excess`: relative to
        the car, the camera moves in a direction that changes only with the curvature (the
        heading of travel less half the step's yaw), so the robust spread of that direction over
        the recent steps, less the variance the estimator predicted, is the excess (real
        changes only add to it). Why: the direction's error is what moves the position across
        the track (KITTI 05, a dev script: 0.40 deg rms per step against a predicted 0.04 deg,
        and at 20 m the cross-track error was 0.076 m against a standard deviation of
        0.007 m)."""
        if len(self._headings) < _EXCESS_MIN_STEPS:
            return 0.0
        h = np.array(self._headings)
        mean = math.atan2(float(np.sin(h[:, 0]).sum()), float(np.cos(h[:, 0]).sum()))
        return _excess_variance(wrap_angle(h[:, 0] - mean), h[:, 1])

    def _heading_nominal(self, est: FrameEstimate) -> float:
        """Variance (rad^2) of the heading-of-travel error before `_heading_excess` can be
        measured: the nominal accuracy of the ACs (``voting.point_noise``) as an error shared by
        all of them, like the yaw's, carried to the direction of travel. A rotation by ``d``
        moves every AC by ``d``, a turn of the direction of travel by ``e`` moves an AC at depth
        ``Z`` by about ``e b / Z`` (``b`` the baseline), so the shared error reads as the
        heading error ``e = d sum(b/Z) / sum((b/Z)^2)`` over the inliers that explains it best
        (least squares; ``b / Z = sin(parallax) / sin(angle at the first centre)`` in the
        triangle of the two camera centres and the point). On KITTI 05 that is about 1.5 deg
        per step for the first steps (KITTI 06: 0.6-0.9 deg) against the 0.40 deg rms measured
        later on KITTI 05: conservative, not zero (with zero, the cross-track error of the
        first two steps was more than 3 standard deviations)."""
        norm = self._norm
        if norm is None or len(norm) != len(est.inliers):
            return 0.0
        q1, q2 = norm.p1[est.inliers], norm.p2[est.inliers]
        d1 = np.column_stack([q1, np.ones(len(q1))]) @ est.R.T     # rays of frame 1, in frame 2
        d2 = np.column_stack([q2, np.ones(len(q2))])
        t = est.t / np.linalg.norm(est.t)
        n1 = np.linalg.norm(d1, axis=1)
        sin_centre = np.linalg.norm(np.cross(d1, t), axis=1) / n1
        n2 = np.linalg.norm(d2, axis=1)
        sin_parallax = np.linalg.norm(np.cross(d1, d2), axis=1) / (n1 * n2)
        # b / Z of each inlier away from the epipole (where both sines vanish).
        away = sin_centre > _EPIPOLE_SIN
        inverse = sin_parallax[away] / sin_centre[away]
        power = float(inverse @ inverse)
        if not power > 0:
            return 0.0
        # The heading error that explains a shared shift d best (least squares over the ACs).
        ratio = float(inverse.sum()) / power
        return (self.config.voting.point_noise * ratio) ** 2

    def _offer_focal_pair(self, gray: np.ndarray, camera: CameraModel, alpha: float) -> None:
        """At a new keyframe: when the car turned enough since an earlier kept keyframe
        (`TurnPairSelector`), the ACs between the two go to the focal calibration's queue
        (pixels from the principal point, levelled with the provisional focal length: the
        levelling shift ``f tan(pitch)`` is what the image measures, so this is consistent to
        first order).

        The ACs are extracted with the turn taken out of the flow: the earlier keyframe is
        warped by ``K R K^-1`` of the odometry's rotation between the two at the provisional
        focal length, and the ACs mapped back exactly (`ACExtractor.extract_warped`). Measured
        on KITTI 05 (the true principal point given; before `_refocus`): the frame's own ACs,
        found with the rotation in the flow, put the focal length 7.6 % short, the de-rotated
        ones 0.7 %; on the same turning pairs their affines disagree with the ground truth's
        motion by up to 0.011 on one side of the image (x > 200 px from the centre), against
        0.002 (README Findings). This costs a front-end run per turning pair (every other
        keyframe in a turn)."""
        current = self._keyframes.current
        partner = self._turns.step(current.index, alpha, camera.fx)
        old = self._keyframes.find(partner) if partner is not None else None
        if old is None:
            return
        R = current.pose[:3, :3].T @ old.pose[:3, :3]          # X_current = R X_old + t
        K = camera.K
        acs = self._extractor.extract_warped(old.image, gray, K @ R @ np.linalg.inv(K))
        if len(acs) < self.config.odometry.min_correspondences:
            return
        level = acs.normalized(camera).mapped(self._estimator.R_lc)
        f = camera.fx
        self._focal.offer(self._frames, level.p1 * f, level.p2 * f, level.A, level.weights,
                          block=self._focal_block())

    def _focal_block(self) -> int:
        """The focal calibration's block of the current frame: ``camera.focal_block_frames``
        frames at 10 Hz, as many more at a faster rate (the usual frame interval, fixed at the
        first turning pair), so that a block lasts about a second; a camera slower than 10 Hz
        keeps 10 frames a block, a longer one. (A user test: the same frames at 30 Hz made
        blocks of a third of a second, whose shared errors counted as independent, and stated
        2.5 % where 10 Hz stated 9.8 %.)"""
        if self._focal_stride is None:
            usual = self._clock.usual_interval
            if usual is None:
                return self._frames // self.config.camera.focal_block_frames
            # Nearest, halves up; a slower camera keeps 10 frames a block (longer blocks).
            self._focal_stride = max(1, math.floor(0.1 / usual + 0.5))
        return self._frames // (self.config.camera.focal_block_frames * self._focal_stride)

    def _scale(self, acs: AffineCorrespondences, camera: CameraModel, est: FrameEstimate,
               keyframe: Keyframe, stamp: float, gray: np.ndarray
               ) -> tuple[float, float, str, float]:
        """Step length (m), its variance, the source used (the configured source, then the
        fallback; a unit step of unknown length when no metric scale exists) and the standard
        deviation of the step's relative error shared with the other steps (`_road_step`; a
        held speed keeps that of its step). ``gray``: the current image (``keyframe``'s pair).
        """
        cfg = self.config.scale
        dt = seconds_between(stamp, keyframe.stamp)
        for source in (cfg.source, cfg.fallback):
            if source == 'speed':
                d = self._speed.distance(keyframe.stamp, stamp)
                if d is not None:
                    return self._metric(d, (cfg.speed_std * dt) ** 2, 0.0, 'speed', stamp, dt)
            elif source == 'ground':
                self._road_fed = False
                step = self._road_step(camera, est, self._norm)
                if step is None and cfg.ground_top_up:
                    more = self._road_acs(camera)
                    if more is not None and len(more):
                        self.road_top_ups += 1
                        # The road-normal calibration takes one frame pair once.
                        step = self._road_step(camera, est, more, feed=not self._road_fed)
                self._step_from = 'road ACs'
                if step is not None:
                    self._road_relative_stds.append((stamp, math.sqrt(step[1]) / step[0]))
                elif cfg.ground_image and dt > 0:
                    step = self._image_road_step(camera, est, keyframe.image, gray, dt, stamp)
                    self._step_from = 'road pixels'
                if step is not None:
                    # The camera height's relative error is shared by every step too, and
                    # independent of the road normal's: in quadrature per step (exact while
                    # the normal's share holds still, conservative where it changes).
                    mount = self.config.mount
                    shared = math.hypot(step[2], mount.height_std / mount.height)
                    return self._metric(step[0], step[1], shared, 'ground', stamp, dt)
            elif source == 'fixed':
                if cfg.fixed_speed > 0:
                    # One assumed speed for every step: its error is shared by all of them
                    # (the position's grows with the distance, as the camera height's; a user
                    # test: as independent step noise the covariance was overconfident).
                    return (cfg.fixed_speed * dt, 0.0, 'fixed',
                            cfg.fixed_speed_std / cfg.fixed_speed)
                return 0.0, (cfg.fixed_speed_std * dt) ** 2, 'fixed', 0.0
            elif source == 'hold' and self._held is not None:
                # The last metric speed, its uncertainty growing with the time since: a vehicle
                # changes its speed by about hold_acceleration_std m/s every second.
                speed, std, when, bias = self._held
                std = math.hypot(std, cfg.hold_acceleration_std * seconds_between(stamp, when))
                return speed * dt, (std * dt) ** 2, 'hold', bias
        return 1.0, _UNKNOWN, 'unit', 0.0

    def _image_road_step(self, camera: CameraModel, est: FrameEstimate, gray1: np.ndarray,
                         gray2: np.ndarray, dt: float, stamp: float
                         ) -> tuple[float, float, float] | None:
        """`_road_step` on the road's pixels (`image_road_scale`) where the road ACs are too
        few: the step scanned from 0 to ``scale.ground_image_max_speed`` times ``dt`` (twice
        the last measured speed instead when that is faster, with a warning), the blocks that
        matched measured as road ACs (the pair's own road normal and every
        variance term as there), none of them fed to the drive's road-normal calibration
        (measured: fed, they pulled it off, KITTI 06 at 3.6 m per frame 23 % long instead of
        5 %). Counts its answers in ``image_road_steps`` and its misses by reason in
        ``image_road_misses`` (the first of each reason logged).

        The step's standard deviation is at least the median relative one of the recent steps
        from road ACs (the last `_ROAD_STD_HISTORY` of them, those of the last
        `_ROAD_STD_SECONDS` of image time): the two share most of a frame's error (on KITTI
        05's first 120 frames, each step measured both ways, their errors against the ground
        truth correlate at 0.90), which the road ACs, reaching farther and so more sensitive to
        the road normal, state larger; on their own the blocks' stated deviations were 1.6-1.9
        times too small there (a user test: KITTI 05 at 4x speed, the position within 3.4 of
        its Mahalanobis distance 60 % of the time, 93 % without the blocks' steps)."""
        cfg = self.config.scale
        pitch, roll, _ = self.road_normal
        top = cfg.ground_image_max_speed
        if self._held is not None and self._held[0] > top:
            # The last measured speed beyond the configured top speed (a user test: 10 m/s
            # set, 36 driven, the scans failed and the first warning came a second later).
            if not self._told_faster:
                log.warning("the vehicle moved at %.1f m/s (its last measured step), faster "
                            "than scale.ground_image_max_speed %g m/s: the road's pixels are "
                            "searched up to twice its speed (raise the setting)",
                            self._held[0], top)
                self._told_faster = True
            top = 2.0 * self._held[0]

        def scan(speed: float):
            return image_road_scale(gray1, gray2, camera, est.R, est.t,
                                    normal_from_tilt(pitch, roll), self.config.mount.height,
                                    steps=(0.0, speed * dt), max_depth=cfg.ground_max_depth,
                                    lateral_std=cfg.ground_lateral_std or _LANE_WIDTH)

        found = scan(top)
        if found.reason.startswith(_LONGEST) and not self._held:
            # Nothing measured to widen the search by (a drive's start, a reset): once more
            # over twice the range (a review: a start above the setting never widened).
            wider = scan(2.0 * top)
            if wider.blocks:
                log.warning("the road's pixels found the step beyond scale.ground_image_max_"
                            "speed %g m/s (%.2f m in %.3f s): is the vehicle faster?", top,
                            wider.scale, dt)
                found, top = wider, 2.0 * top
        step = None
        if found.blocks:
            blocks = AffineCorrespondences(found.q1, found.q2, found.A, found.weights)
            step = self._road_step(camera, est, blocks, feed=False)
        if step is None:
            why = found.reason or 'its blocks measured no step as road ACs would'
            key = re.sub(r'\d[\d.]*', '#', why)
            if key not in self.image_road_misses:
                self.image_road_examples[key] = why
                # The longest step searched fitting best: the vehicle may be faster than the
                # configured top speed (a user test: 5 m/s set, 11.5 driven, nothing said).
                faster = why.startswith(_LONGEST)
                (log.warning if faster else log.info)(
                    "the road's pixels gave no step at %.3f s: %s (steps searched up to "
                    "%g m/s x %.3f s%s)", stamp, why, top, dt,
                    ': is the vehicle faster than scale.ground_image_max_speed?' if faster
                    else '')
            self.image_road_misses[key] = self.image_road_misses.get(key, 0) + 1
            return None
        self.image_road_steps += 1
        recent = [rel for when, rel in self._road_relative_stds
                  if 0.0 <= seconds_between(stamp, when) <= _ROAD_STD_SECONDS]
        if recent:
            floor = median(np.array(recent)) * step[0]
            step = (step[0], max(step[1], floor * floor), step[2])
        return step

    def _metric(self, distance: float, variance: float, bias: float, source: str,
                stamp: float, dt: float) -> tuple[float, float, str, float]:
        """Remember the speed of a metric step (for ``'hold'``) and return it."""
        if dt > 0:
            self._held = (distance / dt, math.sqrt(variance) / dt, stamp, bias)
        return distance, variance, source, bias

    def _road_acs(self, camera: CameraModel) -> AffineCorrespondences | None:
        """ACs of this frame pair on the road ahead (rays meeting the road within
        ``scale.ground_max_depth`` at the current road normal, `road_rays`), from the front-end
        without its per-frame budget's larger cells or from the road's own corners
        (`ACExtractor.extract_more`), normalised;
        None when the front-end cannot (``'asift'``)."""
        pitch, roll, _ = self.road_normal
        n = normal_from_tilt(pitch, roll)
        height, max_depth = self.config.mount.height, self.config.scale.ground_max_depth

        def select(points: np.ndarray) -> np.ndarray:
            q, _ = camera.pixel_to_normalized(points)
            ok = np.isfinite(q).all(axis=1)
            ok[ok] = road_rays(q[ok], n, height, max_depth)
            return ok

        more = self._extractor.extract_more(select)
        return None if more is None else more.normalized(camera)

    def _road_step(self, camera: CameraModel, est: FrameEstimate, norm: AffineCorrespondences,
                   feed: bool = True) -> tuple[float, float, float] | None:
        """The step length (m), its variance and its shared relative error from the road ACs
        at the camera height (`road_scale`: the refined general motion, the road normal in the
        camera frame), or None without enough road ACs. The variance adds the rotation's
        uncertainty (the estimator's covariance through the step's exact sensitivity to it) to
        the statistical, car-pitch and road-normal terms, all but one: the error of the
        drive's road normal (the part of it this pair's normal keeps) is the same for every
        step, so it is returned apart as the standard deviation of the step's relative error
        it causes, for the odometry to accumulate along the drive (steps 3 % short for 20 m
        are 3 % short at every step: KITTI 05, a dev script); `_scale` adds the camera
        height's (``mount.height_std``: every step is relative to it).

        Two passes: the first, with the current road normal, finds the road ACs; they refine the
        drive's road normal (`RoadNormalCalibrator`) and give this pair's own normal
        (`pair_road_normal`), shrunk towards the drive's by ``scale.ground_normal_std``; the
        second measures the step with that normal. So a pair's own road counts for its step:
        the first steps of a drive were otherwise measured with the mount's guess (KITTI 06:
        the first step 26 % long), and the car's pitch on its suspension moved every step
        (KITTI 05, frames 0-299, with the step length from the road against the ground truth:
        median error 3.9 % before, 2.6 % after; errors in units of the reported standard
        deviation, RMS 1.63 before, 1.10 after).

        ``norm``: the pair's normalised ACs; ``feed`` False keeps them from the drive's
        road-normal calibration (a top-up of a pair it already took: one pair counts once)."""
        cfg = self.config.scale

        def measure(pitch: float, roll: float, own_std: float) -> RoadScale:
            # own_std: the error of this pair's normal not shared with the other steps.
            return road_scale(norm.p1, norm.p2, norm.A, est.R, est.t,
                              normal_from_tilt(pitch, roll), self.config.mount.height,
                              point_sigma=cfg.ground_point_std / camera.fx,
                              weights=norm.weights,
                              sigma_normal=own_std,
                              max_depth=cfg.ground_max_depth,
                              affine_sigma=cfg.ground_affine_std, gate=cfg.ground_gate,
                              min_count=cfg.ground_min_correspondences,
                              lateral_std=cfg.ground_lateral_std, check=False)

        before = self.road_normal
        rs = measure(before[0], before[1], cfg.ground_normal_std)
        shared = before[2]      # the drive's normal error in this step's normal (rad)
        if self._road is not None and rs.count:
            if feed and self._road.add(norm.p1, norm.p2, est.R, est.t, rs.mask, norm.weights,
                                       check=False):
                self._road_fed = True
                fit = self._road.update(before[0], before[1])
                if fit is not None:
                    std = math.hypot(fit.pitch_std, fit.roll_std)
                    if math.isfinite(std):
                        self._road_fit = (fit.pitch, fit.roll, std)
            pitch, roll, normal_std = self.road_normal
            # This pair's road departs from the average road by the car's pitch on its
            # suspension and the road's camber and slope changes (``ground_normal_std``): its
            # own fit, shrunk towards the average by their precisions.
            one = pair_road_normal(norm.p1, norm.p2, est.R, est.t, rs.mask, norm.weights,
                                   pitch, roll, check=False)
            prior = cfg.ground_normal_std ** 2
            if one is not None and math.isfinite(one.pitch_std) and math.isfinite(one.roll_std):
                gain_p = prior / (prior + one.pitch_std ** 2)
                gain_r = prior / (prior + one.roll_std ** 2)
                pitch += gain_p * (one.pitch - pitch)
                roll += gain_r * (one.roll - roll)
                shared = (1.0 - min(gain_p, gain_r)) * normal_std
                rs = measure(pitch, roll, math.sqrt(gain_p * one.pitch_std ** 2
                                                    + gain_r * one.roll_std ** 2))
            elif (pitch, roll) != before[:2]:
                shared = normal_std
                rs = measure(pitch, roll, cfg.ground_normal_std)
        if not (math.isfinite(rs.scale) and rs.scale > 0):
            return None
        d = rs.d_rotation
        var = rs.std ** 2 + float(d @ est.cov[:3, :3] @ d)
        return rs.scale, var, shared * math.hypot(*rs.d_normal) / rs.scale

    def _frozen(self, gray: np.ndarray, stamp: float, key: int) -> str:
        """Why ``gray`` is a frozen camera's frame, or ``''``.

        A real sensor's noise differs from frame to frame: a frame identical to the previous
        one, pixel for pixel, is the same image again (a stalled driver republishing it, a
        duplicated frame of a raw or losslessly coded video), unless the vehicle stands (a
        simulator renders a standing vehicle's frames alike). Wheel speed samples that cover
        the time since the previous frame settle it, frame by frame (`_wheels_moved`); without
        them, the vehicle cannot stand right after a measured motion step too fast to have
        stopped since (`_moving`), and a run of identical frames that began so stays frozen.
        Without either evidence (no wheel speed, the run began at a stop) the frames go on as
        a stop."""
        previous = self._previous_gray
        if previous is None or key != self._previous_key or not np.array_equal(previous, gray):
            self._frozen_why = ''
            # An older frame again, the frames since it different, while moving: the camera
            # republished an old image (a user test: A B A at 10 m/s was a step back at -10
            # m/s). Standing, a simulator's scene may repeat (a blinking light).
            moving = (self._last_twist is not None
                      or self.config.odometry.repeated_images == 'frozen')
            for age, (older, when, older_key) in enumerate(reversed(self._older) if moving
                                                           else (), start=2):
                # ... and recently: the same images after a gap are a replay, not a stale
                # buffer (within the kept frames' usual time, half as much again).
                if older_key != key:
                    continue
                recent = 1.5 * (_OLDER_FRAMES + 1) * (self._clock.usual_interval or 0.1)
                if seconds_between(stamp, when) <= recent and np.array_equal(older, gray):
                    self._frozen_why = (f'image identical, pixel for pixel, to the frame {age} '
                                        f'frames before it, with other images between: a '
                                        f'camera republishing an old image')
                    break
            return self._frozen_why
        if self.config.odometry.repeated_images == 'frozen':
            self._frozen_why = ('image identical to the previous frame\'s, pixel for pixel '
                                '(odometry.repeated_images: frozen): a frozen camera or a '
                                'repeated frame')
            return self._frozen_why
        moved = self._wheels_moved(stamp)
        if moved is not None:
            self._frozen_why = moved
        elif not self._frozen_why:
            self._frozen_why = self._moving(stamp)
        elif self._frozen_why.startswith('image identical to the previous frame'):
            # The run goes on, judged at its first frame (a user test: every frame of the run
            # named that frame's interval as its own).
            return ('image identical to the previous frame\'s, pixel for pixel, in a run of '
                    'identical frames that began ' + self._frozen_why.split(
                        'pixel for pixel, ', 1)[1])
        return self._frozen_why

    def _wheels_moved(self, stamp: float) -> str | None:
        """From the wheel speed (`add_speed`), why the vehicle moved since the previous frame
        (``''``: it did not: the distance within three standard deviations, ``scale.speed_std``
        over the interval, of none), or None when no samples at or after ``stamp`` cover the
        interval (the speed is not extrapolated: a braking car's last sample is not the stop's
        speed; a review: late samples lost a whole stop as frozen)."""
        latest = self._speed.latest
        if latest is None or latest < stamp:
            return None
        d = self._speed.distance(self._previous_stamp, stamp)
        if d is None:
            return None
        if not d > 3.0 * self.config.scale.speed_std * seconds_between(stamp,
                                                                       self._previous_stamp):
            return ''
        return (f'image identical to the previous frame\'s, pixel for pixel, while the wheel '
                f'speed gives {d:.3g} m travelled since it: a frozen camera or a repeated frame')

    def _moving(self, stamp: float) -> str:
        """Why the vehicle cannot be standing at ``stamp``, the previous frame's image
        unchanged, or ``''``: the last motion step's velocity, measured (scale from the road,
        the wheels or a speed held from them; an assumed fixed speed says nothing), its mean
        over the step being the speed at the step's middle, less three standard deviations, is
        more than braking at ``odometry.max_deceleration`` takes off since that middle."""
        if self._last_twist is None or self._step_source not in ('ground', 'speed', 'hold'):
            return ''                   # standing, nothing measured, or no motion since a reset
        end, length, twist = self._last_twist
        v = float(np.linalg.norm(twist[:3]))
        if not v > 0.0:
            return ''
        u = twist[:3] / v
        std = math.sqrt(max(float(u @ self._twist_cov[:3, :3] @ u), 0.0))
        since = seconds_between(stamp, end) + 0.5 * length
        a = self.config.odometry.max_deceleration
        if not v - 3.0 * std > a * since:
            return ''
        return (f'image identical to the previous frame\'s, pixel for pixel, {since:.3g} s after '
                f'moving at {v:.3g} +- {std:.2g} m/s (the last step\'s mean), too fast to stop '
                f'since at odometry.max_deceleration {a:g} m/s^2: a frozen camera or a repeated '
                f'frame')

    def _stationary(self, keyframe: Keyframe, stamp: float, count: int) -> FrameResult:
        """The image has not moved: neither has the vehicle (no new keyframe, no drift). The
        keyframe's stamp follows, since nothing moved since it (a speed source then integrates
        from here, however long the stop)."""
        self.camera_pose = keyframe.pose.copy()
        self._camera_cov = keyframe.covariance.copy()
        self._bias = keyframe.bias.copy()
        self._tilt_gain = keyframe.tilt_gain.copy()
        self._focal_sums = keyframe.focal_sums.copy()
        self._last_twist = None         # the keyframe's stamp moves: a new interval begins
        since = keyframe.stamp
        keyframe.stamp = stamp
        keyframe.age += 1
        if self._held is not None:
            self._held = (0.0, self._held[1], stamp, self._held[3])
        # Standing means a median displacement below keyframe.stationary_parallax: the speed
        # that would make it, at the last metric step's pixels per metre, bounds the speed
        # (starting off, the first frames' 0.05-0.16 m/s pass for standing; rendered drive).
        # Before any metric step the threshold means no known speed: the speed of unknown
        # motion (odometry.lost_speed_std, as across a gap in tracking).
        # (Stamps 1 ns apart are distinct frames: the interval is exact and positive; a user
        # test's 1 ns repeat divided by a float difference of 0.)
        # (the displacement is the keyframe's: over the time since it or since the last
        # output, whichever is shorter; a user test: the first such frame after lost tracking
        # divided by the whole gap, a speed std of 4 mm/s)
        interval = (min(seconds_between(stamp, self._last_out[0]), seconds_between(stamp, since))
                    if self._last_out is not None else math.nan)
        crept = self.config.keyframe.stationary_parallax / self._px_per_metre
        self._crept = crept if math.isfinite(crept) else 0.0
        bound = crept / interval if interval > 0 else math.nan
        if not math.isfinite(bound):
            bound = self.config.odometry.lost_speed_std
        speed_var = max(bound, 1e-3) ** 2
        self._twist = np.zeros(6)
        self._twist_cov = np.diag([speed_var] * 3 + [1e-8] * 3)
        self._last_out = (stamp, self.camera_pose.copy())
        self._lost = self._miss_run = 0
        return self._result(stamp, True, keyframe=False, scale_source='stationary',
                            num_correspondences=count, alpha=0.0, beta=float('nan'))

    def _lost_frame(self, stamp: float, reason: DropReason, message: str, count: int,
                    inliers: int = 0) -> FrameResult:
        """No update from this frame. After ``odometry.max_lost_frames`` in a row the keyframe
        is dropped: the next usable frame starts a new keyframe chain (`_start_chain`). The
        failed frame itself never becomes the keyframe, since it may be the cause (a blank or
        garbled image would leave the next real frame without correspondences). A chain's first
        keyframe that the first two frames after it find too few correspondences with is
        dropped then: it is the garbled one. After two frames in a row with some but too few
        correspondences against any other keyframe (moving away from it), the next frame that
        finds some but too few too starts a new chain itself (`process`)."""
        if self._keyframes.current is None and not self._restart:
            return self._drop(stamp, reason, message, count, inliers)
        self._lost += 1
        keyframe = self._keyframes.current
        if keyframe is not None:
            keyframe.age += 1
        self._state = TrackingState.LOST
        miss = reason is DropReason.TOO_FEW_CORRESPONDENCES
        # Misses that still found some correspondences: the frame sees part of the keyframe's
        # scene (moving away from it), where a garbled one finds none.
        self._miss_run = self._miss_run + 1 if miss and count > 0 else 0
        if keyframe is not None and miss:
            keyframe.misses += 1
        # A keyframe that two frames in a row found no correspondences with is the garbled
        # one, not they (noise is not blank; a dim frame, an exposure glitch, matched the
        # keyframe before it but offers no texture to the next): no later frame would match it
        # either. (One such frame may be the garbled one itself: it is kept.) A chain's first
        # keyframe then starts a new chain; mid-chain, one far dimmer than the keyframe before
        # it gives way to that one (a user test: one dim frame cost six frames and a new
        # chain); any other is judged by lost tracking below.
        unmatched = (keyframe is not None and not keyframe.matched
                     and keyframe.misses >= _UNMATCHED_MISSES and not self._restart)
        previous = self._keyframes.previous
        if unmatched and previous is not None and \
                keyframe.contrast < _DIM_KEYFRAME * previous.contrast:
            self._keyframes.drop_current()
            if self._window is not None:
                self._window.clear()        # it held the dropped keyframe (a review)
            self._lost = self._miss_run = 0
            message += ('; the newest keyframe, far dimmer than the one before it, matched '
                        'nothing: tracking goes on against the one before it')
        elif unmatched and previous is None:
            self._keyframes.clear()
            self._restart = 'a first keyframe that no frame matched'
            message += ('; the new chain\'s first keyframe matched nothing: the next usable '
                        'frame starts a new keyframe chain')
        elif self._lost >= self.config.odometry.max_lost_frames and not self._restart:
            self._keyframes.clear()
            self._restart = 'lost tracking'
            message += '; tracking lost: the next usable frame starts a new keyframe chain'
        elif self._miss_run >= _OUTGROWN_MISSES and not self._restart:
            # Frames that move ever further from the keyframe find ever fewer correspondences
            # with it (a user test: after two lost frames 15, 10, 4, 4, 2 of them, six frames
            # without odometry). After two such misses in a row the next frame gets one try at
            # the keyframe (a frame that matches it keeps the chain: a review) and, if it too
            # finds some but too few, starts a new chain itself (`process`). Garbled frames
            # find none: they wait for odometry.max_lost_frames, and never become keyframes.
            message += ('; two frames in a row found too few correspondences with the keyframe: '
                        'the next one that finds some but too few too starts a new keyframe '
                        'chain (one that matches it keeps the chain; one that finds none, a '
                        'garbled frame, waits for odometry.max_lost_frames)')
        return self._drop(stamp, reason, message, count, inliers)

    def _start_chain(self, gray: np.ndarray, stamp: float) -> FrameResult:
        """The first keyframe of a chain: after start-up or a reset at the origin; after lost
        tracking at the pose extrapolated from the last output (`_extrapolate`)."""
        reason, message = DropReason.FIRST_FRAME, 'reference keyframe set'
        if self._restart and self._new_time_base:
            self._extrapolate(stamp, hold=True)
            reason, message = (DropReason.REINITIALISED,
                               'new keyframe chain after the time base moved on (pose held, '
                               'its covariance grown with the time since the last output)')
        elif self._restart:
            self._extrapolate(stamp)
            reason, message = (DropReason.REINITIALISED,
                               f'new keyframe chain after {self._restart} (pose extrapolated)')
        elif self._time_reset:
            reason, message = (DropReason.TIME_JUMP_BACK,
                               f'time jumped back to {format_stamp(stamp)}: tracking reset, '
                               f'pose at the origin, new keyframe chain')
        self._keyframes.add(gray, stamp, self.camera_pose, self._camera_cov,
                            self._bias, self._tilt_gain, self._focal_sums).matched = False
        self._state = (TrackingState.TRACKING if reason is DropReason.FIRST_FRAME
                       else TrackingState.REINITIALISED)
        self._restart = ''
        self._time_reset = self._new_time_base = False
        self._lost = self._miss_run = 0
        if self._last_out is None:
            self._last_out = (stamp, self.camera_pose.copy())
        # The frame is the chain's keyframe (a user test: the status said keyframe false
        # beside 'reference keyframe set').
        return self._result(stamp, False, reason=reason, message=message, keyframe=True)

    def _mis_stamp_fits(self, gray: np.ndarray, camera: CameraModel | None,
                        first: float) -> bool:
        """Whether the frames since the last gap, the first stamped ``first``, were stamped
        ahead of their time rather than the frames now coming inside the gap late: this one
        (``gray``) was then taken after the last of them and moved on from it as the step
        across the gap did (forward or back along base_link x; in a turn on the spot, the same
        sense of turn); a late one lies behind it (a review: judged by the speed, late frames
        of a car braking to a stop in the gap were taken for a mis-stamp). Only for a step
        across the gap whose length came from the image (the road, or unit steps): a time-based
        length (a speed topic, a fixed or held speed) was as long as the wrong interval says.
        Not when either motion is too small to tell; a frame found late settles its gap (no
        further front-end runs for the late frames after it)."""
        across = next((e for e in self._recent_steps if e[0] == first), None)
        previous = self._previous_gray
        if (across is None or across[3] not in ('ground', 'unit') or camera is None
                or previous is None or previous.shape != gray.shape or first == self._late_gap):
            return False
        found = self._trial_motion(previous, gray, camera, self.config.keyframe.min_parallax)
        if found is None:
            return False
        # The camera's displacement from the last frame to this one, in base_link.
        alpha, moved = self._base_motion(found[2])
        velocity, rate = across[2][:3], float(across[2][5])
        if abs(velocity[0]) > 0.5 * float(np.linalg.norm(velocity)) and \
                abs(moved[0]) > 0.5 * float(np.linalg.norm(moved)):
            on = moved[0] * velocity[0] > 0.0
        elif camera.fx * abs(alpha) >= self.config.keyframe.min_parallax and rate:
            on = alpha * rate > 0.0                  # a left turn: both positive
        else:
            return False
        if not on:
            self._late_gap = first
        return bool(on)

    def _rewind(self, first: float, ahead: float) -> None:
        """The frames since the last gap, from the one stamped ``first`` on, were stamped
        ``ahead`` seconds ahead of their time (`FrameClock.mis_stamped`): everything their
        stamps timed is moved back (the keyframes, the last output, the velocity of the steps
        that spanned the gap: their displacement over the shorter interval), and tracking goes
        on (a user test: a frame stamped 0.8 s ahead refused the 7 frames after it; 3 s ahead,
        the pose went back to the origin; two frames ahead lost 10 frames and left the pose 9 m
        short at 7 standard deviations)."""
        log.warning('the frames from the one stamped %s on were stamped %.3f s ahead of their '
                    'time (the frames after them are older): their stamps are moved back',
                    format_stamp(first), ahead)

        def back(stamp):
            return (shift_stamp(stamp, ahead) if stamp is not None
                    and seconds_between(stamp, first) >= 0.0 else stamp)

        def step(entry):
            """A twist entry ``(end, length, twist, ...)`` restamped, and its speed factor."""
            if entry is None or seconds_between(entry[0], first) < 0.0:
                return entry, 1.0
            spans = entry[1] > seconds_between(entry[0], first)      # began before the gap
            length = entry[1] - ahead if spans else entry[1]
            if not length > 0:
                return None, None
            k = entry[1] / length
            return (back(entry[0]), length, entry[2] * k, *entry[3:]), k

        self._keyframes.shift_stamps(first, ahead)
        if self._last_out is not None:
            self._last_out = (back(self._last_out[0]), self._last_out[1])
        old_end = self._last_twist[0] if self._last_twist is not None else None
        self._last_twist, k = step(self._last_twist)
        if k is None:
            self._twist, self._twist_cov = np.zeros(6), np.eye(6) * _UNKNOWN
        elif k != 1.0:
            self._twist, self._twist_cov = self._twist * k, self._twist_cov * (k * k)
        self._recent_steps = deque(
            (e for e in (step(e)[0] for e in self._recent_steps) if e is not None),
            maxlen=self._recent_steps.maxlen)
        if self._held is not None and seconds_between(self._held[2], first) >= 0.0:
            speed, std, when, bias = self._held
            factor = k if k is not None and when == old_end else 1.0
            self._held = (speed * factor, std * factor, back(when), bias)
        self._previous_stamp = back(self._previous_stamp)
        self._older = deque(((g, back(t), key) for g, t, key in self._older),
                            maxlen=self._older.maxlen)
        if self._grown is not None:
            self._grown = (back(self._grown[0]), *self._grown[1:])

    def _extrapolate(self, stamp: float, hold: bool = False) -> None:
        """The pose across a gap in tracking: the last velocity carried on (over the distance
        the wheel speed gives, when it covers the gap), its turn rate decaying (a long gap does
        not spin the pose) and the travel following that turn, and the covariance grown with
        the time of the gap (not with the frames in it): ``odometry.lost_speed_std`` and
        ``lost_turn_rate_std`` per second; without the wheels' distance, braking at up to
        ``odometry.max_deceleration``; in a turn, the yaw and the travel of the turn going on
        where the extrapolation lets it decay. With
        ``hold`` (the time base moved on: the stamps before and after belong to different
        clocks or a pause of unknown length, so the last velocity says nothing about the motion
        across it) the pose is held and only the covariance grows."""
        cfg = self.config.odometry
        last_stamp, last_pose = self._last_out if self._last_out else (stamp, self.camera_pose)
        dt = max(seconds_between(stamp, last_stamp), 0.0)
        T_bc = self._T_base_camera
        tau = cfg.turn_rate_time_constant
        wheels = None
        going_on = np.zeros(3)      # the travel if the turn rate persists, less the extrapolated
        if hold:
            self.camera_pose = last_pose.copy()
        else:
            rate = float(self._twist[5])
            yaw = yaw_rate_decay(rate, dt, tau)
            velocity = self._twist[:3]
            wheels = self._speed.distance(last_stamp, stamp) if dt > 0 else None
            if wheels is not None and not float(np.linalg.norm(velocity)) > 0:
                velocity = np.array([1.0, 0.0, 0.0])          # straight ahead from a standstill
            # Along the decaying turn (the heading turns as the yaw does; a review: the travel
            # went straight, a turn's whole sideways offset left out of the mean).
            travel, going_on = _arc_travels(velocity, rate, tau, dt)
            if wheels is not None:
                # The wheel speed measured the distance across the gap (a user test: a camera
                # stalled at a stop while the car drove off held the pose there, 10 m behind).
                factor = wheels / max(float(np.linalg.norm(velocity)) * dt, 1e-300)
                travel, going_on = travel * factor, going_on * factor
            step_base = se3(rotation_rpy(0.0, 0.0, yaw), travel)
            # (the persisting turn's offset in the extrapolated pose's own frame)
            going_on = rotation_rpy(0.0, 0.0, yaw)[:3, :3].T @ going_on
            self.camera_pose = last_pose @ (invert(T_bc) @ step_base @ T_bc)
            # The levelling's orientation error carried along tilts the extrapolated step too
            # (`_tilt_gain`; the step's own turn is assumed, not estimated about the levelled
            # vertical).
            G, H = self._tilt_gain[:3], self._tilt_gain[3:]
            step = self.camera_pose[:3, 3] - last_pose[:3, 3]
            self._tilt_gain = np.vstack([G, H - skew(step) @ G])
            # So does the focal length's, and the step itself was measured through it (its turn
            # and speed are the last ones'; `_focal_sums`).
            if self._focal is not None and self._in_use is not None:
                C = last_pose[:3, :3]
                self._focal_sums = _focal_sums(
                    self._focal_sums, C, so3_log(C.T @ self.camera_pose[:3, :3]), step,
                    self._in_use.fx, self.config.scale.source == 'ground')
        # The variance grows with the square of the time since the last output; a second
        # restart before the next output adds only what the first did not (a review: it added
        # the whole time again).
        again = self._grown is not None and self._grown[0] == last_stamp
        before, braked, turned, drifted = self._grown[1:] if again else (0.0, 0.0, 0.0, 0.0)
        share = max(dt * dt - before * before, 0.0)
        grow = np.diag([cfg.lost_turn_rate_std ** 2 * share] * 3
                       + [cfg.lost_speed_std ** 2 * share] * 3)
        if not hold:
            # The last velocity's own uncertainty, carried over the gap (twist order: linear,
            # angular); unknown before any motion was measured, and then so is the travel
            # across the gap (a user test: the node started while the car drove, lost the
            # second frame, and held the pose 36 m behind at 12 standard deviations). The turn
            # it adds is no less known than a uniform angle (a review: an unknown turn rate
            # times the camera's lever arm gave kilometres where the wheels had measured the
            # travel), axis by axis.
            if wheels is None:
                grow[3:, 3:] += share * self._twist_cov[:3, :3]
            turn = np.minimum(share * np.diag(self._twist_cov)[3:], _UNIFORM_ANGLE_STD ** 2)
            grow[:3, :3] += np.diag(turn)
        # The speed itself may have changed across the gap: braking at up to
        # odometry.max_deceleration (three standard deviations) falls short of the extrapolated
        # travel by a t^2 / 2, until the stop (v t - v^2 / (2 a) after it), along the last
        # velocity (a user test: a camera frozen for 3 s while the car braked, carried on at
        # its speed, ended 16 m ahead at 3.6 standard deviations). Not when the wheels measured
        # the travel, nor for a held pose.
        total = 0.0
        v = float(np.linalg.norm(self._twist[:3]))
        if not hold and wheels is None and v > 0.0:
            a = cfg.max_deceleration
            short = 0.5 * a * dt * dt if dt <= v / a else v * dt - v * v / (2.0 * a)
            total = (short / 3.0) ** 2
            u = self._twist[:3] / v
            grow[3:, 3:] += max(total - braked, 0.0) * np.outer(u, u)
        # The turn rate may persist where the extrapolation lets it decay: one standard
        # deviation is the yaw the persisting turn adds beyond the decayed one, about base z,
        # and the offset of its travel from the extrapolated one (a user test: a 3 s gap in a
        # 90-deg turn was 35 deg off at a yaw std of 8.9 deg).
        yaw_total = lateral_total = 0.0
        w = abs(float(self._twist[5]))
        if not hold and w > 0.0:
            yaw_total = (w * (dt - yaw_rate_decay(1.0, dt, tau))) ** 2
            grow[2, 2] += max(yaw_total - turned, 0.0)
            lateral_total = float(going_on @ going_on)
            if lateral_total > 0.0:
                grow[3:, 3:] += (max(lateral_total - drifted, 0.0) / lateral_total
                                 * np.outer(going_on, going_on))
        self._grown = (last_stamp, dt, max(total, braked), max(yaw_total, turned),
                       max(lateral_total, drifted))
        Ad = adjoint(invert(T_bc))
        cov = self._camera_cov + Ad @ grow @ Ad.T
        # No angle is less known than a uniform one (std pi / sqrt(3); a user test: a gap of
        # 100 s gave the held pose 287 deg of roll and pitch std): the rotation block is scaled
        # down axis by axis (rows and columns alike, so it stays a covariance).
        std = np.sqrt(np.maximum(np.diag(cov)[:3], 1e-300))
        scale = np.ones(6)
        scale[:3] = np.minimum(1.0, _UNIFORM_ANGLE_STD / std)
        self._camera_cov = cov * np.outer(scale, scale)

    def _update_twist(self, keyframe: Keyframe, stamp: float, step_cov: np.ndarray) -> None:
        """The body-frame velocity over the step since the keyframe, with its covariance: the
        constant body twist that moves the keyframe's base onto the current one (``log`` of
        the relative motion over ``dt``), so that a car turning at a steady rate has no lateral
        velocity (the chord over ``dt`` would give it ``v sin(yaw / 2)``).

        It is the mean over the keyframe interval ``T``, which lags the velocity at the frame
        by about ``T/2 dv/dt``: braking, by 0.2 m/s at 4.7 m/s^2 and one frame per keyframe,
        and after a stop the mean since the last keyframe before it halved over five frames
        while the car stood (the rendered drives: at 200 and more standard deviations; found by
        a user test). The change of the mean since the previous frame's, over the time between
        the two intervals' middles, measures the acceleration, so ``T/2`` times it enters the
        covariance (rank one, along the change); with a steady velocity only the means' noise
        does."""
        dt = seconds_between(stamp, keyframe.stamp)
        if dt > 0:
            T_bc = self._T_base_camera
            rel = T_bc @ invert(keyframe.pose) @ self.camera_pose @ invert(T_bc)
            xi = se3_log(rel)                                       # [phi, rho]
            self._twist = np.concatenate([xi[3:], xi[:3]]) / dt
            Ad = adjoint(T_bc)
            self._twist_cov = ros_twist_covariance(Ad @ step_cov @ Ad.T, dt)
            last = self._last_twist
            # The time between the intervals' middles, from the stamps' exact difference (a
            # float of absolute seconds holds about 0.2 us).
            between = (seconds_between(stamp, last[0]) - 0.5 * dt + 0.5 * last[1]
                       if last is not None else 0.0)
            if between > 0:
                # The means' change over the time between the intervals' middles is the
                # acceleration; the mean lags the velocity at the frame by half the interval.
                lag = 0.5 * dt * (self._twist - last[2]) / between
                self._twist_cov = self._twist_cov + np.outer(lag, lag)
            if self._crept > 0:
                # The first step after frames judged standing: they may have moved by up to
                # the distance the stationary threshold cannot exclude, which this step's
                # displacement holds but its interval (from the last of them) does not (a user
                # test: starting off, 0.254 m/s against 0.200 at 16 standard deviations).
                self._twist_cov[:3, :3] += (self._crept / dt) ** 2 * np.eye(3)
            self._last_twist = (stamp, dt, self._twist.copy())
        self._crept = 0.0
        self._last_out = (stamp, self.camera_pose.copy())

    # -- results -------------------------------------------------------------------------------

    def _result(self, stamp: float, ok: bool, **fields) -> FrameResult:
        if ok:
            self._state = TrackingState.TRACKING
        pose, cov_body = to_base(self.camera_pose, self._camera_cov + self._tilt_covariance()
                                 + self._focal_covariance(), self._T_base_camera)
        cov = ros_pose_covariance(pose, cov_body)
        bias = self._T_base_camera[:3, :3] @ self._bias       # odom frame
        cov[:3, :3] += np.outer(bias, bias)
        twist, twist_cov = self._twist.copy(), self._twist_cov.copy()
        odometry = self.config.odometry
        if odometry.output == 'flat':
            pose, cov = flatten(pose, cov, odometry.flat_z_std, odometry.flat_tilt_std)
            twist, twist_cov = flatten_twist(twist, twist_cov)
        self.pose = pose
        return FrameResult(stamp=stamp, ok=ok, pose=pose.copy(), pose_covariance=cov,
                           tracking=self._state, camera_pose=self.camera_pose.copy(),
                           twist=twist, twist_covariance=twist_cov, **fields)

    def _tilt_stds(self) -> tuple[float, float] | None:
        """The standard deviations (rad) of the levelling's pitch and roll (`_tilt_covariance`):
        the mount-tilt estimate's, with the offset of a configured angle still in use (its own
        standard deviation above ``mount.tilt_tolerance``) added; about a degree before the
        first estimate; None with ``mount.estimate_tilt`` off (the configured tilt is taken as
        exact)."""
        if self._tilt is None:
            return None
        estimate = self.tilt_estimate
        if estimate is None:
            return _START_NORMAL_STD, _START_NORMAL_STD
        return (math.hypot(estimate.pitch_std, estimate.pitch - self._level[0]),
                math.hypot(estimate.roll_std, estimate.roll - self._level[1]))

    def _tilt_covariance(self) -> np.ndarray:
        """The camera pose's body-frame covariance (``[phi, rho]``) from the levelling's
        uncertainty: the estimator takes the mount tilt it levels with as the vertical, and its
        planar prior pulls every relative rotation's axis towards it, so an error of that tilt
        tilts the axis of every turn alike (KITTI 05, a dev script: the roll error grew by
        0.38 deg per radian turned, the roll's estimate being uncertain by 0.36 deg). Shared by
        the steps, it makes orientation errors that grow with the angle turned (``2 sin(psi /
        2)`` times the tilt error after a turn by ``psi``) and position errors that grow with
        the distance driven after it (`_tilt_gain`), of the size of the levelling's current
        uncertainty (`_tilt_stds`: what is known now of the error the levelling has had; the
        levelling changes rarely and little)."""
        stds = self._tilt_stds()
        if stds is None or not self._tilt_gain.any():
            return np.zeros((6, 6))
        R_lc = self._estimator.R_lc
        # The vertical's displacement, level frame (x the pitch axis, y the vertical, z the roll
        # axis): a pitch error moves it along z, a roll error along x; then the camera frame.
        S_tilt = R_lc.T @ np.diag([stds[1] ** 2, 0.0, stds[0] ** 2]) @ R_lc
        R = self.camera_pose[:3, :3]
        gain = np.vstack([R.T @ self._tilt_gain[:3], R.T @ self._tilt_gain[3:]])  # to body
        return gain @ S_tilt @ gain.T

    def _focal_covariance(self) -> np.ndarray:
        """The camera pose's body-frame covariance (``[phi, rho]``) from a self-calibrated
        focal length (`_focal_sums`): every step was measured through the focal length then in
        use, ``f_i``, and the image fixes a rotation's pixel shift ``f tan(angle)`` and, for
        the ground scale, the road's depths times ``1 / f``: through the true ``f`` the step
        turns by ``f_i / f`` times its angle and goes ``f / f_i`` times as far. With the
        current estimate ``f = F (1 + e)`` (``e`` of standard deviation `relative_std`), the
        pose error is a known part (the steps measured through another focal length than
        ``F``, e.g. the wide prior's before the first turn) plus ``e`` times a gain, both
        shared by all steps (one focal length): rank-one terms, not step noise (KITTI 05
        self-calibrated, a dev script: the yaw error after the straight start was 5 standard
        deviations of a per-step term). The known part is a bias (what the calibration now
        says the earlier steps got wrong), folded into the covariance as its second moment:
        correcting the pose instead would make it jump (REP-105).

        The assumed principal point is uncertain too (`OnlineFocalCalibrator.pp_std`: 1 % of
        the width at the image centre): every step's direction is off sideways by the same
        ``d cx / f`` (a third rank-one term). Once a camera model arrives (CameraInfo), the
        steps before it keep their known part at its focal length; the uncertainties end."""
        if self._focal is None or self._in_use is None or not self._focal_sums.any():
            return np.zeros((6, 6))
        known, gain = _focal_error(self._focal_sums, self._in_use.fx)
        vectors = [known]
        if self._camera is None:
            vectors.append(gain * min(self._focal.relative_std, 1.0))
            vectors.append(np.concatenate([np.zeros(3), self._focal_sums[8]])
                           * self._focal.pp_std)
        R = self.camera_pose[:3, :3]
        body = np.zeros((len(vectors), 6))
        for row, v in zip(body, vectors):
            row[:3], row[3:] = R.T @ v[:3], R.T @ v[3:]
        return body.T @ body

    def _drop(self, stamp: float, reason: DropReason, message: str, count: int = 0,
              inliers: int = 0) -> FrameResult:
        return self._result(stamp, False, reason=reason, message=message,
                            num_correspondences=count, num_inliers=inliers)


def _tilt_gain(keyframe: Keyframe, pose: np.ndarray, R: np.ndarray, R_lc: np.ndarray
               ) -> np.ndarray:
    """`Keyframe.tilt_gain` of the pose ``pose`` reached from ``keyframe`` by the relative
    rotation ``R`` (``X2 = R X1 + t``) with the levelling ``R_lc``: the step turned by ``psi``
    about the levelled vertical, so an error ``d`` of the levelling's vertical (camera frame)
    adds the rotation ``psi R_kf J_l d`` (world frame) to the orientation; the keyframe's
    orientation error ``e`` moves the step ``s`` by ``e x s``."""
    R_kf = keyframe.pose[:3, :3]
    omega = -so3_log(R)                    # the step's rotation (R^T), camera frame
    psi = float(R_lc[1] @ omega)           # its turn about the levelled vertical
    # exp(omega + psi d) = exp(J_l(omega) psi d) exp(omega) to first order, so the world-frame
    # error is R_kf J_l psi d.
    G_kf, H_kf = keyframe.tilt_gain[:3], keyframe.tilt_gain[3:]
    step = pose[:3, 3] - keyframe.pose[:3, 3]
    return np.vstack([G_kf + psi * (R_kf @ so3_left_jacobian(omega)), H_kf - skew(step) @ G_kf])


def _focal_sums(sums: np.ndarray, C: np.ndarray, omega: np.ndarray, step: np.ndarray, f: float,
                ground: bool) -> np.ndarray:
    """`Keyframe.focal_sums` ``(9, 3)`` after one more step from a pose with orientation ``C``
    (camera to world) and sums ``sums``: its rotation ``omega`` (camera frame, ``C_new = C
    exp(omega)``) and displacement ``step`` (world frame) measured through the focal length
    ``f`` (pixels), its length from the road (``ground``) or not. Rows, world frame, summed over
    the steps: 0-1 the rotation ``phi`` about the camera's x and y axes (what the image
    measures through ``f``) and ``f phi``; 2-3 their lever arms (each sum so far crossed with
    the next step's displacement ``s``); 4-5 ``s`` and ``s / f`` over the road-scaled steps;
    6-7 the displacement's offset across the optical axis (the epipole's, also measured through
    ``f``, `_across`) and ``f`` times it; 8 its sideways move per pixel of the principal point
    (`_sideways` over ``f``). `_focal_error` turns rows 0-7 into the pose error at any true
    focal length."""
    S = sums.copy()
    # exp(omega + d) = exp(J_l(omega) d) exp(omega): its error d, world frame.
    phi = C @ so3_left_jacobian(omega) @ (omega * _IMAGE_PLANE_AXES)
    local = C.T @ step
    across = C @ _across(local)
    S[2] += np.cross(S[0], step)
    S[3] += np.cross(S[1], step)
    S[0] += phi
    S[1] += f * phi
    if ground:
        S[4] += step
        S[5] += step / f
    S[6] += across
    S[7] += f * across
    S[8] += C @ _sideways(local) / f
    return S


def _across(step: np.ndarray) -> np.ndarray:
    """How a displacement ``step`` (camera frame) measured through ``f_i`` moves per unit of
    ``f_i / f - 1``: its offset across the optical axis scales, its length does not (the
    direction is a unit vector; the length comes from the scale), so the change is that offset
    less its share along the step."""
    return _off_step(step * _IMAGE_PLANE_AXES, step)


def _sideways(step: np.ndarray) -> np.ndarray:
    """How a displacement ``step`` (camera frame) moves per unit of its direction's x offset
    (a principal point ``d`` pixels off moves it by ``d / f``): ``|s|`` times the camera's x
    axis, less its share along the step."""
    return float(np.linalg.norm(step)) * _off_step(np.array([1.0, 0.0, 0.0]), step)


def _off_step(v: np.ndarray, step: np.ndarray) -> np.ndarray:
    """``v`` less its component along ``step`` (zero for a zero step)."""
    length2 = float(step @ step)
    if not length2 > 0.0:
        return np.zeros(3)
    return v - step * float(step @ v) / length2


def _focal_error(sums: np.ndarray, f: float) -> tuple[np.ndarray, np.ndarray]:
    """The pose error ``[rotation; position]`` (world frame, 6) that steps measured through
    the focal lengths ``f_i`` (`_focal_sums`) have when the true one is ``f (1 + e)``:
    ``known + e gain``, returned as ``(known, gain)`` (the known part exact in the ratios
    ``f_i / f`` as far as the image fixes pixel shifts, the gain to first order in ``e``).
    Through the true focal length a step turns by ``f_i / f`` of its angle about the camera's
    x and y axes, moves across the optical axis by ``f_i / f`` of its offset and, scaled by
    the road, goes ``f / f_i`` as far; each rotation error turns every later step."""
    turn, turn_f, lever, lever_f, road, road_per_f, across, across_f = sums[:8]
    known = np.concatenate([turn - turn_f / f,
                            lever - lever_f / f + road - f * road_per_f + across - across_f / f])
    gain = np.concatenate([turn_f / f, lever_f / f - f * road_per_f + across_f / f])
    return known, gain


def _focal_step_covariance(R: np.ndarray, t: np.ndarray, s: float, ground: bool,
                           rel: float, pp_rel: float) -> np.ndarray:
    """The step's own covariance (``[phi, rho]``, as `compose`'s: ``T_true = T exp(xi)``) from
    a relative focal error ``e`` of standard deviation ``rel``, with the model of
    `_focal_sums`: through the true focal length the step turns by ``1 + e`` of its rotation
    about the camera's x and y axes (not about the optical axis), its displacement's offset
    across the optical axis (camera 1) is ``1 + e`` of the measured one (`_across`) and a
    road-scaled length ``s`` is ``1 + e`` of it; and from the principal point's error
    (``pp_rel``: its standard deviation over ``f``), the displacement's sideways move
    (`_sideways`). Checked against finite differences of the step (test_pipeline.py)."""
    omega = -so3_log(R)                                  # camera 2 = camera 1 exp(omega)
    d = -R.T @ (t / np.linalg.norm(t))                   # its direction, camera-1 frame
    phi = so3_left_jacobian(-omega) @ (omega * _IMAGE_PLANE_AXES)    # right Jacobian
    rho = s * R @ (_across(d) + (d if ground else 0.0))
    v = np.concatenate([phi, rho]) * rel
    u = np.concatenate([np.zeros(3), s * R @ _sideways(d)]) * pp_rel
    return np.outer(v, v) + np.outer(u, u)


# The rotation axes (camera x, y: pitch and yaw) whose angle the image measures as a pixel
# shift ``f tan(angle)``, i.e. through the focal length (`_focal_sums`).
_IMAGE_PLANE_AXES = np.array([1.0, 1.0, 0.0])
# Step lengths in metres (not unit steps).
_METRIC_SOURCES = frozenset({'ground', 'speed', 'fixed', 'hold'})
# Recent steps from road ACs whose relative standard deviations floor those from the road's
# pixels (`_image_road_step`): at most this many, of at most this many seconds before (a
# review: road-AC steps scarce at speed could otherwise reach back minutes, to slower driving
# whose relative deviations are smaller).
_ROAD_STD_HISTORY, _ROAD_STD_SECONDS = 50, 10.0
# `image_road_scale`'s reason when the longest step searched, or one beyond, fits best.
_LONGEST = 'the best step is the longest searched'
# The road's pixels are searched within a lane's width of the line of travel when
# scale.ground_lateral_std is 0 (road ACs weighed alike): blocks pass no test of being road.
_LANE_WIDTH = 3.5


# A new camera model that moves the image by at most this many pixels (`CameraModel.pixel_shift`)
# is a recalibration of the same camera: the keyframe chain goes on with it.
_SAME_CAMERA_SHIFT = 0.5
# Variance (m^2 or rad^2) that says "unknown": a unit step has no metric length.
_UNKNOWN = 1e6
# Frames with too few correspondences against a chain's first keyframe, before any frame matched
# it, that drop it (`_lost_frame`): one may be a garbled frame itself, two in a row implicate the
# keyframe.
_UNMATCHED_MISSES = 2
# Frames in a row with too few correspondences against any keyframe that start a new chain at
# the next usable frame (`_lost_frame`): the frames have moved away from it, or it is garbled.
_OUTGROWN_MISSES = 2
# A bridge's motion (`VisualOdometry._plausible_bridge`) against the last step's: its travel
# within this angle of the last velocity, its yaw within this of the last turn rate's over
# the interval (about a frame: a car's heading rate does not change by 50 deg/s within 0.1 s).
_BRIDGE_DIRECTION, _BRIDGE_YAW = math.radians(30.0), math.radians(5.0)
# A keyframe whose contrast is below this share of the one before it is a dim one (see
# `VisualOdometry._lost_frame`).
_DIM_KEYFRAME = 0.5
# ACs whose ray is within this sine (about 3 deg) of the epipole carry no depth for
# `_heading_nominal`.
_EPIPOLE_SIN = 0.05


def _seconds(value: float) -> str:
    """A duration for messages: ``0.0213``, ``4.9``, ``997`` (not ``1e+03``: a user test)."""
    return f'{value:.0f}' if abs(value) >= 100 else f'{value:.3g}'


# The standard deviation of an angle uniform on the circle: no angle is less known.
_UNIFORM_ANGLE_STD = math.pi / math.sqrt(3.0)
# Image sizes whose focal self-calibration is kept (a memory bound: each holds up to
# camera.focal_max_blocks profiles and its queue of pairs).
_FOCAL_SIZES = 4
# Frames before the previous one kept to catch an older image republished (A B A): 8 frames of
# 1241x376 are 3.7 MB.
_OLDER_FRAMES = 8
# Steps of history before the excess variances are measured (`_yaw_excess`, `_heading_excess`).
_EXCESS_MIN_STEPS = 10
# The road normal before its first fit is the mount's tilt (configured or estimated), trusted to
# about a degree (radians).
_START_NORMAL_STD = math.radians(1.0)
# The tilt estimator's wobble follows the measured non-planarity when it changed by more than
# this share (each change triggers a refit).
_WOBBLE_CHANGE = 0.2


def _excess_variance(values: np.ndarray, predicted: np.ndarray, share: float = 1.0) -> float:
    """``share`` times the squared robust spread (MAD) of ``values``, less the median of the
    ``predicted`` variances, at least 0 (`_yaw_excess`, `_heading_excess`)."""
    spread = MAD_TO_SIGMA * median(np.abs(values - median(values)))
    return max(share * spread * spread - median(predicted), 0.0)


def _with_timings(result: FrameResult, timings: dict[str, float]) -> FrameResult:
    result.timings.update(timings)
    return result


def _short(value, limit: int = 40) -> str:
    """``repr(value)`` on one line, cut to about ``limit`` characters (for drop reasons)."""
    text = one_line(repr(value))
    return text if len(text) <= limit else text[:limit - 3] + '...'


def _gray(image) -> np.ndarray:
    """8-bit grey image from grey or BGR input, or `ImageError` (the one given, see
    `VisualOdometry.process`)."""
    if isinstance(image, ImageError):
        raise image
    gray = as_gray('image', image)
    # The pipeline keeps it (the keyframe, the previous frames): a copy when it is the caller's
    # own writeable memory, which a capture loop refilling one buffer would change under it (a
    # read-only one, a message's bytes, cannot change).
    return gray.copy() if gray.flags.writeable and np.may_share_memory(gray, image) else gray


def _arc_travels(velocity: np.ndarray, rate: float, tau: float, dt: float, steps: int = 64
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The travel (m, the start's base frame) over ``dt`` seconds at the body velocity
    ``velocity`` (m/s) while the heading turns at ``rate`` (rad/s) decaying with the time
    constant ``tau`` (s) as `yaw_rate_decay` has it, and how much the travel at the undecaying
    rate differs from it (midpoint rule in ``steps`` steps; straight and 0 for ``rate`` 0)."""
    h = dt / steps
    s = (np.arange(steps) + 0.5) * h
    vx, vy, vz = (float(x) for x in velocity)

    def travel(psi: np.ndarray) -> np.ndarray:
        c, sn = np.cos(psi), np.sin(psi)
        return np.array([float(np.sum(c * vx - sn * vy)) * h,
                         float(np.sum(sn * vx + c * vy)) * h, vz * dt])

    decaying = travel(rate * tau * (1.0 - np.exp(-s / tau)))
    return decaying, travel(rate * s) - decaying


def _fingerprint(gray: np.ndarray) -> int:
    """A hash of a grey image's subsample (every 8th pixel) and size: equal images have equal
    fingerprints, and frames of a real camera differ there already, so the whole images are
    compared only when they match."""
    return hash((gray.shape, gray[::8, ::8].tobytes()))


def _is_blank(gray: np.ndarray, min_contrast: float) -> bool:
    """Black, saturated or flat: too little contrast for any correspondence (subsampled)."""
    sample = gray[::8, ::8]
    return float(sample.std()) < min_contrast
