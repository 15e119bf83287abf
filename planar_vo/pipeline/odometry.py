"""`VisualOdometry`: frames in, planar poses out (no ROS; driven by the node, replay and tests).

Per frame (see `VisualOdometry.process`):

1. checks: timestamp order, camera model, image decodable and of the camera's size, not blank;
2. affine correspondences from the current keyframe to this frame (`planar_vo.frontend`);
3. if the median parallax is below ``keyframe.stationary_parallax`` the vehicle is standing still;
4. otherwise the ACs are undistorted, levelled by the mount's pitch and roll (so that the
   camera's y axis is vertical) and normalised; `vote_planar_motion` estimates the motion of the
   level camera since the keyframe;
5. the step length comes from the configured scale source (speed topic, ground plane, fixed
   speed, unit steps) with a fallback; the vehicle pose is the keyframe pose composed with the
   step (`planar_vo.pipeline.motion`), and its covariance is propagated from the estimator's;
6. the frame becomes the new keyframe once its parallax reaches ``keyframe.min_parallax`` (or
   after ``keyframe.max_interval`` frames): slow or stopped vehicles do not accumulate noise,
   and every frame is still output.

Every frame yields a `FrameResult`; a frame without an update carries a `DropReason`.
"""

from __future__ import annotations

import logging
import math
import time

import numpy as np

from planar_vo.config import PlanarVoConfig
from planar_vo.core.camera import CameraModel
from planar_vo.core.conventions import R_BASE_OPTICAL, invert, rotation_rpy, se3
from planar_vo.core.correspondences import AffineCorrespondences
from planar_vo.core.robust import vote_planar_motion
from planar_vo.errors import ImageError, PlanarVoError
from planar_vo.frontend import ACExtractor, leveling_rotation, undistort_acs
from planar_vo.frontend.images import as_gray
from planar_vo.pipeline.calibration import FocalCalibrator, MountTiltEstimator
from planar_vo.pipeline.clock import FrameClock, StampCheck
from planar_vo.pipeline.motion import (
    base_step,
    compose_covariance,
    planar_delta,
    ros_covariance,
    step_covariance,
)
from planar_vo.pipeline.scale import SpeedIntegrator, ground_plane_scale
from planar_vo.pipeline.types import DropReason, FrameResult, TrackingState

__all__ = ['VisualOdometry']

log = logging.getLogger(__name__)

_LOST_VARIANCE = (1.0, 1.0, math.radians(5.0) ** 2)   # x, y, yaw added when tracking is lost


class VisualOdometry:
    """Monocular planar visual odometry (Hajder and Barath 1AC + voting).

    Args:
        config: the whole configuration (`PlanarVoConfig`); defaults if None.
        camera: the camera model, if known up front (else from `process` or the config's
            intrinsics).

    Attributes:
        pose: ``T_odom_base`` after the last frame (4x4).
        counters: frames processed per outcome (``'ok'`` and `DropReason` values).
    """

    def __init__(self, config: PlanarVoConfig | None = None,
                 camera: CameraModel | None = None) -> None:
        self.config = PlanarVoConfig() if config is None else config
        self._extractor = ACExtractor(self.config.frontend)
        self._camera = camera
        self._speed = SpeedIntegrator()
        self._calibrator = FocalCalibrator() if self.config.camera.estimate_focal else None
        mount = self.config.mount
        self._set_tilt(mount.pitch, mount.roll)
        # Mount-tilt estimation: general poses of keyframe pairs (five-point) feed it during a
        # calibration phase; its pitch and roll then replace the configured ones.
        self._tilt = None
        if mount.estimate_tilt:
            self._tilt = MountTiltEstimator()
        self.tilt_estimate = None
        self.counters: dict[str, int] = {}
        odometry = self.config.odometry
        self._clock = FrameClock(odometry.max_frame_gap, odometry.max_time_jump_back)
        self.reset()

    # -- state ---------------------------------------------------------------------------------

    def _set_tilt(self, pitch: float, roll: float) -> None:
        """Levelling for a camera pitched and rolled by ``pitch``, ``roll`` (MountConfig sense)."""
        mount = self.config.mount
        # The level camera: the camera's centre, optical axes rotated by the mount's yaw only.
        self._T_base_level = se3(rotation_rpy(0.0, 0.0, mount.yaw) @ R_BASE_OPTICAL,
                                 np.array([mount.x, mount.y, mount.height]))
        # Levelling rotation, level <- camera, applied to the ideal normalised rays.
        self._R_level_camera = leveling_rotation(pitch, roll)
        self._level = not np.allclose(self._R_level_camera, np.eye(3), atol=1e-12)

    def _calibrate_tilt(self, q1: np.ndarray, q2: np.ndarray) -> None:
        """Feed one pair to the mount-tilt estimator; adopt its estimate when precise."""
        cfg = self.config.mount
        if self._tilt is None or len(self._tilt) >= cfg.tilt_max_pairs:
            return
        step = max(1, len(q1) // 400)             # the five-point needs a few hundred points
        if not self._tilt.add_acs(q1[::step], q2[::step]) or len(self._tilt) % 10:
            return
        estimate = self._tilt.estimate()
        if estimate.pitch_std <= cfg.tilt_tolerance:
            # Each angle is adopted only when it is precise: driving straight reveals the pitch
            # (translations lie in the plane) but hardly the roll (that needs turns).
            self.tilt_estimate = estimate
            roll = estimate.roll if estimate.roll_std <= cfg.tilt_tolerance else cfg.roll
            self._set_tilt(estimate.pitch, roll)
            log.info('mount tilt estimated from %d pairs: pitch %.3f +- %.3f deg, roll %.3f +- '
                     '%.3f deg (%s)', estimate.frames, np.rad2deg(estimate.pitch),
                     np.rad2deg(estimate.pitch_std), np.rad2deg(estimate.roll),
                     np.rad2deg(estimate.roll_std),
                     'used' if roll == estimate.roll else 'not precise yet: configured roll kept')

    def reset(self) -> None:
        """Pose back to the identity and a new keyframe chain from the next frame; the counters
        and the calibrations (tilt, focal length) are kept."""
        self.pose = np.eye(4)
        self._cov = np.zeros((3, 3))
        self._keyframe: np.ndarray | None = None
        self._kf_pose = np.eye(4)
        self._kf_cov = np.zeros((3, 3))
        self._kf_stamp = float('nan')
        self._kf_age = 0
        self._lost = 0
        self._restart = False
        self._time_reset = False
        self._state = TrackingState.INITIALISING
        self._clock.reset()
        self._last_out_stamp: float | None = None
        self._last_out_pose = np.eye(4)
        self._twist = np.zeros(6)
        self._twist_cov = np.eye(6) * 1e6
        self._held_speed = (float('nan'), float('inf'), float('-inf'))   # m/s, std, stamp

    @property
    def tracking(self) -> TrackingState:
        """The tracking state after the last frame."""
        return self._state

    @property
    def camera(self) -> CameraModel | None:
        """The camera model in use (None until known)."""
        return self._camera

    @property
    def focal_calibrator(self) -> FocalCalibrator | None:
        """The online focal calibration (``camera.estimate_focal``), else None."""
        return self._calibrator

    def add_speed(self, stamp: float, speed: float) -> None:
        """A speed sample (m/s) for ``scale.source = 'speed'`` (e.g. from wheel odometry)."""
        self._speed.add(float(stamp), float(speed))

    # -- the frame -----------------------------------------------------------------------------

    def process(self, image: np.ndarray, stamp: float, camera: CameraModel | None = None
                ) -> FrameResult:
        """Process one frame; never raises for bad input (the result says what went wrong).

        Args:
            image: 8-bit grey ``(H, W)`` or BGR ``(H, W, 3)`` image.
            stamp: its timestamp in seconds.
            camera: the camera model for this frame (e.g. from ``CameraInfo``); None keeps the
                last one.
        """
        start = time.perf_counter()
        timings: dict[str, float] = {}
        try:
            result = self._process(image, float(stamp), camera, timings)
        except PlanarVoError as err:        # a bad input the checks did not anticipate
            result = self._drop(float(stamp), DropReason.PIPELINE_ERROR, str(err))
        except Exception as err:            # noqa: BLE001 - a bug must not stop the odometry
            log.exception('pipeline error at stamp %.6f', stamp)
            result = self._drop(float(stamp), DropReason.PIPELINE_ERROR,
                                f'{type(err).__name__}: {err}')
        timings['total'] = time.perf_counter() - start
        key = 'ok' if result.ok else result.reason.value
        self.counters[key] = self.counters.get(key, 0) + 1
        return _with_timings(result, timings)

    def _process(self, image, stamp: float, camera: CameraModel | None,
                 timings: dict[str, float]) -> FrameResult:
        if not math.isfinite(stamp):
            return self._drop(stamp, DropReason.BAD_IMAGE, f'timestamp {stamp} is not finite')
        last = self._clock.last
        check = self._clock.check(stamp)
        if check is StampCheck.DUPLICATE:
            return self._drop(stamp, DropReason.DUPLICATE_STAMP,
                              f'timestamp {stamp:.9f} repeats the previous frame')
        if check is StampCheck.OUT_OF_ORDER:
            return self._drop(stamp, DropReason.OUT_OF_ORDER,
                              f'timestamp {stamp:.9f} is older than the previous {last:.9f}')
        if check is StampCheck.JUMP_AHEAD:
            return self._drop(stamp, DropReason.TIME_JUMP_AHEAD,
                              f'timestamp {stamp:.9f} is {stamp - last:.3g} s after the previous '
                              f'frame (more than odometry.max_frame_gap); refused unless the '
                              f'next frame confirms the new time')
        if check is StampCheck.JUMP_BACK:
            log.warning('time jumped back %.3f s (looped bag or restarted clock): tracking '
                        'reset', last - stamp)
            self.reset()
            self._clock.check(stamp)
            self._time_reset = True
        elif check is StampCheck.NEW_TIME_BASE:
            log.warning('time moved on by %.3f s: tracking restarts', stamp - last)
            self._keyframe = None
            self._restart = True
        t = time.perf_counter()
        try:
            gray = _gray(image)
        except ImageError as err:
            return self._drop(stamp, DropReason.BAD_IMAGE, str(err))
        camera = self._resolve_camera(camera, gray.shape)
        if camera is None:
            return self._drop(stamp, DropReason.NO_CAMERA_INFO,
                              'no camera intrinsics yet (no CameraInfo and camera.fx = 0)')
        if camera.size != (gray.shape[1], gray.shape[0]):
            # A stray frame of another size: drop it, keep tracking (a new camera model with
            # the new size resets the keyframe in _resolve_camera).
            return self._drop(stamp, DropReason.SIZE_CHANGED,
                              f'image is {gray.shape[1]}x{gray.shape[0]} but the camera model is '
                              f'{camera.width}x{camera.height}')
        if _is_blank(gray, self.config.odometry.min_contrast):
            return self._drop(stamp, DropReason.BLANK_IMAGE,
                              'image is blank (black, saturated or without texture)')
        timings['decode'] = time.perf_counter() - t
        if self._keyframe is None and self._restart:
            return self._restart_chain(gray, stamp)
        if self._keyframe is None:
            self._new_keyframe(gray, stamp)
            self._last_out_stamp, self._last_out_pose = stamp, self.pose.copy()
            if self._time_reset:
                self._time_reset = False
                self._state = TrackingState.REINITIALISED
                return self._drop(stamp, DropReason.TIME_JUMP_BACK,
                                  f'time jumped back to {stamp:.9f}: tracking reset, pose at '
                                  f'the origin, new keyframe chain')
            self._state = TrackingState.TRACKING
            return self._drop(stamp, DropReason.FIRST_FRAME, 'reference keyframe set')

        t = time.perf_counter()
        acs = self._extractor.extract(self._keyframe, gray)
        timings['correspondences'] = time.perf_counter() - t
        if len(acs) < self.config.odometry.min_correspondences:
            return self._lost_frame(stamp, DropReason.TOO_FEW_CORRESPONDENCES,
                                    f'{len(acs)} correspondences (minimum '
                                    f'{self.config.odometry.min_correspondences})', len(acs))
        parallax = float(np.median(np.linalg.norm(acs.p2 - acs.p1, axis=1)))
        if parallax < self.config.keyframe.stationary_parallax:
            return self._stationary(stamp, len(acs))

        t = time.perf_counter()
        motion, stats, scale_info = self._estimate(acs, camera, stamp)
        timings['solve'] = time.perf_counter() - t
        if not stats.reliable:
            return self._lost_frame(stamp, DropReason.UNRELIABLE,
                                    f'motion estimate flagged {stats.flag!r} '
                                    f'({stats.num_inliers} inliers of {len(acs)})', len(acs),
                                    stats.num_inliers)
        t = time.perf_counter()
        scale, var_scale, source = scale_info
        step = base_step(motion.alpha, motion.beta, scale, self._T_base_level)
        delta = planar_delta(step)
        cov_step = step_covariance(motion.alpha, motion.beta, scale, stats.covariance,
                                   var_scale, self._T_base_level)
        self.pose = self._kf_pose @ step
        self._cov = compose_covariance(self._kf_pose, self._kf_cov, delta, cov_step)
        self._update_twist(stamp, cov_step)
        keyframe = (parallax >= self.config.keyframe.min_parallax
                    or self._kf_age + 1 >= self.config.keyframe.max_interval)
        if keyframe:
            self._new_keyframe(gray, stamp)
        else:
            self._kf_age += 1
        self._lost = 0
        timings['integrate'] = time.perf_counter() - t
        return self._result(stamp, True, keyframe=keyframe, scale_source=source,
                            num_correspondences=len(acs), num_inliers=stats.num_inliers,
                            alpha=motion.alpha, beta=motion.beta)

    # -- steps ---------------------------------------------------------------------------------

    def _resolve_camera(self, camera: CameraModel | None, shape: tuple[int, int]
                        ) -> CameraModel | None:
        if camera is not None:
            if self._camera is not None and camera != self._camera:
                log.info('camera model changed; starting a new keyframe')
                self._keyframe = None
            self._camera = camera
        if self._camera is None:
            c = self.config.camera
            height, width = shape
            if c.fx > 0:
                self._camera = CameraModel(
                    width, height, np.array([[c.fx, 0.0, c.cx or (width - 1) / 2.0],
                                             [0.0, c.fy or c.fx, c.cy or (height - 1) / 2.0],
                                             [0.0, 0.0, 1.0]]),
                    c.distortion_model, c.distortion)
            elif self._calibrator is not None:
                # Uncalibrated: a provisional focal length (the calibration's running estimate,
                # else a nominal 53-degree field of view) until the calibration converges.
                cx, cy = (c.cx or (width - 1) / 2.0), (c.cy or (height - 1) / 2.0)
                f = self._calibrator.estimate
                converged = math.isfinite(f) and self._calibrator.std < \
                    self.config.camera.focal_tolerance * f
                f = f if math.isfinite(f) else float(max(width, height))
                model = CameraModel(width, height,
                                    np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]]))
                if converged:
                    self._camera = model
                    log.info('focal length self-calibrated: %.1f +- %.1f px', f,
                             self._calibrator.std)
                return model
        return self._camera

    def _estimate(self, acs: AffineCorrespondences, camera: CameraModel, stamp: float):
        """Motion of the level camera since the keyframe, with its scale."""
        if self._camera is None and self._calibrator is not None:
            ideal = undistort_acs(acs, camera)
            c = camera.K[:2, 2]
            self._calibrator.add(ideal.p1 - c, ideal.p2 - c, ideal.A, ideal.weights)
        norm = acs.normalized(camera)                 # undistorted, K^-1
        if self._tilt is not None:
            self._calibrate_tilt(norm.p1, norm.p2)
        if self._level:
            norm = norm.mapped(self._R_level_camera)
        motion, stats = vote_planar_motion(norm.p1, norm.p2, norm.A, norm.weights,
                                           self.config.voting)
        if not stats.reliable:
            return motion, stats, (float('nan'), float('inf'), '')
        return motion, stats, self._scale(norm.p1, norm.p2, norm.A, motion, stats, stamp)

    def _scale(self, q1, q2, An, motion, stats, stamp: float) -> tuple[float, float, str]:
        """Step length (m), its variance and the source used, with the configured fallback."""
        cfg = self.config.scale
        dt = stamp - self._kf_stamp
        for source in (cfg.source, cfg.fallback, 'unit'):
            if source == 'speed':
                d = self._speed.distance(self._kf_stamp, stamp)
                if d is not None:
                    return self._metric(d, (cfg.speed_std * dt) ** 2, 'speed', stamp, dt)
            elif source == 'ground':
                g = ground_plane_scale(q1, q2, An, motion.alpha, motion.beta,
                                       self.config.mount.height, weights=stats.inliers,
                                       affine_tol=cfg.ground_affine_tolerance,
                                       min_count=cfg.ground_min_correspondences)
                if math.isfinite(g.scale):
                    return self._metric(g.scale, g.std ** 2, 'ground', stamp, dt)
            elif source == 'fixed':
                d = cfg.fixed_speed * dt
                return d, (cfg.fixed_speed_std * dt) ** 2, 'fixed'
            elif source == 'hold':
                speed, std, when = self._held_speed
                if math.isfinite(speed) and stamp - when <= cfg.hold_seconds:
                    # Constant speed since the last metric step; its error grows with the gap.
                    grow = 0.2 * speed * (stamp - when)
                    return speed * dt, (std * dt) ** 2 + (grow * dt) ** 2, 'hold'
            else:
                return 1.0, 1.0, 'unit'
        return 1.0, 1.0, 'unit'

    def _metric(self, distance: float, variance: float, source: str, stamp: float, dt: float
                ) -> tuple[float, float, str]:
        """Remember the speed of a metric step (for ``'hold'``) and return it."""
        if dt > 0:
            self._held_speed = (distance / dt, math.sqrt(variance) / dt, stamp)
        return distance, variance, source

    def _stationary(self, stamp: float, count: int) -> FrameResult:
        """The image has not moved: neither has the vehicle (no new keyframe, no drift)."""
        self.pose = self._kf_pose.copy()
        self._cov = self._kf_cov.copy()
        self._update_twist(stamp, np.diag([1e-6, 1e-6, 1e-8]))
        self._lost = 0
        self._kf_age += 1
        return self._result(stamp, True, keyframe=False, scale_source='stationary',
                            num_correspondences=count, alpha=0.0, beta=float('nan'))

    def _lost_frame(self, stamp: float, reason: DropReason, message: str, count: int,
                    inliers: int = 0) -> FrameResult:
        """No update from this frame. After ``odometry.max_lost_frames`` in a row the keyframe
        is dropped: the next usable frame starts a new keyframe chain (`_restart_chain`). The
        failed frame itself never becomes the keyframe, since it may be the cause (a blank or
        garbled image would leave the next real frame without correspondences)."""
        self._lost += 1
        self._kf_age += 1
        self._state = TrackingState.LOST
        if self._lost >= self.config.odometry.max_lost_frames:
            self._keyframe = None
            self._restart = True
            self._lost = 0
            message += '; tracking lost: the next usable frame starts a new keyframe chain'
        return self._drop(stamp, reason, message, count, inliers)

    def _restart_chain(self, gray: np.ndarray, stamp: float) -> FrameResult:
        """A new keyframe chain after lost tracking: the pose is extrapolated to this frame at
        the last velocity, with its covariance inflated."""
        dt = stamp - (self._last_out_stamp if self._last_out_stamp is not None else stamp)
        v, w = self._twist[:2], self._twist[5]
        guess = se3(rotation_rpy(0.0, 0.0, w * dt), np.array([v[0] * dt, v[1] * dt, 0.0]))
        self.pose = self._last_out_pose @ guess
        self._cov = self._cov + np.diag(_LOST_VARIANCE)
        self._new_keyframe(gray, stamp)
        self._restart = False
        self._state = TrackingState.REINITIALISED
        return self._drop(stamp, DropReason.REINITIALISED,
                          'new keyframe chain after lost tracking (pose extrapolated)')

    def _new_keyframe(self, gray: np.ndarray, stamp: float) -> None:
        self._keyframe = gray
        self._kf_pose = self.pose.copy()
        self._kf_cov = self._cov.copy()
        self._kf_stamp = stamp
        self._kf_age = 0

    def _update_twist(self, stamp: float, cov_step: np.ndarray) -> None:
        if self._last_out_stamp is not None and stamp > self._last_out_stamp:
            dt = stamp - self._last_out_stamp
            d = planar_delta(invert(self._last_out_pose) @ self.pose)
            self._twist = np.array([d[0] / dt, d[1] / dt, 0.0, 0.0, 0.0, d[2] / dt])
            tc = np.zeros((6, 6))
            idx = [0, 1, 5]
            tc[np.ix_(idx, idx)] = cov_step / (dt * dt)
            tc[2, 2], tc[3, 3], tc[4, 4] = (v / (dt * dt) for v in self._planar_variance())
            self._twist_cov = tc
        self._last_out_stamp, self._last_out_pose = stamp, self.pose.copy()

    def _planar_variance(self) -> tuple[float, float, float]:
        o = self.config.odometry
        return o.planar_z_std ** 2, o.planar_tilt_std ** 2, o.planar_tilt_std ** 2

    # -- results -------------------------------------------------------------------------------

    def _result(self, stamp: float, ok: bool, **fields) -> FrameResult:
        if ok:
            self._state = TrackingState.TRACKING
        return FrameResult(stamp=stamp, ok=ok, pose=self.pose.copy(), tracking=self._state,
                           pose_covariance=ros_covariance(self._cov, self._planar_variance()),
                           twist=self._twist.copy(), twist_covariance=self._twist_cov.copy(),
                           **fields)

    def _drop(self, stamp: float, reason: DropReason, message: str, count: int = 0,
              inliers: int = 0) -> FrameResult:
        return self._result(stamp, False, reason=reason, message=message,
                            num_correspondences=count, num_inliers=inliers)


def _with_timings(result: FrameResult, timings: dict[str, float]) -> FrameResult:
    result.timings.update(timings)
    return result


def _gray(image) -> np.ndarray:
    """8-bit grey image from grey or BGR input, or `ImageError`."""
    return as_gray('image', image)


def _is_blank(gray: np.ndarray, min_contrast: float) -> bool:
    """Black, saturated or flat: too little contrast for any correspondence (subsampled)."""
    sample = gray[::8, ::8]
    return float(sample.std()) < min_contrast
