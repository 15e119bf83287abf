"""`VisualOdometry`: frames in, 3D poses out (no ROS; driven by the node, replay and tests).

Per frame (see `VisualOdometry.process`):

1. checks: the stamp against the stream's time base (`planar_vo.pipeline.clock`), the camera
   model, an image of the camera's size that is not blank;
2. affine correspondences from the current keyframe to this frame (`planar_vo.frontend`);
3. if the median parallax is below ``keyframe.stationary_parallax`` the vehicle stands still;
4. otherwise the ACs are undistorted and normalised, levelled by the mount tilt (configured or
   estimated online), and `planar_vo.pipeline.estimator.MotionEstimator` estimates the
   camera's relative pose since the keyframe: the 1AC vote in front, a general 5-DoF relative
   pose refined on all AC constraints out, with its covariance and an honest reliability flag;
5. the step length comes from the configured scale source (speed topic, the road at the
   known camera height, a fixed speed) with a fallback (``hold``: the last metric speed, its
   uncertainty growing with the time since); without any metric scale the step is a unit step
   whose covariance says its length is unknown;
6. the camera pose is the keyframe's composed with the step, with its 6x6 covariance
   (`planar_vo.pipeline.motion`); the vehicle pose is the camera's through the configured
   mount (``base_link``), in 3D or flattened to x, y, yaw (``odometry.output``);
7. the frame becomes the new keyframe once its parallax reaches ``keyframe.min_parallax`` (or
   after ``keyframe.max_interval`` frames); every frame is still output.

Every frame yields a `FrameResult`; a frame without an update carries a `DropReason`, and the
tracking state (tracking, lost, reinitialised) says where the chain stands.
"""

from __future__ import annotations

import logging
import math
import time

import numpy as np

from planar_vo.config import PlanarVoConfig
from planar_vo.core.camera import CameraModel
from planar_vo.core.conventions import (
    adjoint,
    invert,
    mount_transform,
    planar_motion_from_pose,
    rotation_rpy,
    se3,
    so3_log,
)
from planar_vo.core.correspondences import AffineCorrespondences
from planar_vo.core.homography import apply_homography
from planar_vo.errors import ImageError, PlanarVoError
from planar_vo.frontend import ACExtractor, leveling_rotation, undistort_acs
from planar_vo.frontend.images import as_gray
from planar_vo.pipeline.calibration import FocalCalibrator, MountTiltEstimator
from planar_vo.pipeline.clock import FrameClock, StampCheck
from planar_vo.pipeline.estimator import FrameEstimate, MotionEstimator
from planar_vo.pipeline.keyframes import Keyframe, KeyframeChain
from planar_vo.pipeline.motion import (
    compose,
    flatten,
    ros_pose_covariance,
    ros_twist_covariance,
    to_base,
    yaw_rate_decay,
)
from planar_vo.pipeline.scale import SpeedIntegrator, ground_plane_scale
from planar_vo.pipeline.types import DropReason, FrameResult, TrackingState

__all__ = ['VisualOdometry']

log = logging.getLogger(__name__)


class VisualOdometry:
    """Monocular visual odometry for a vehicle-mounted camera (1AC voting + general refinement).

    Args:
        config: the whole configuration (`PlanarVoConfig`); defaults if None.
        camera: the camera model, if known up front (else from `process` or the config's
            intrinsics).

    Attributes:
        pose: ``T_odom_base`` after the last frame (4x4).
        camera_pose: ``T_world_camera`` after the last frame (world = the first camera frame).
        counters: frames processed per outcome (``'ok'`` and `DropReason` values).
        tilt_estimate: the last mount-tilt estimate (``mount.estimate_tilt``), else None.
    """

    def __init__(self, config: PlanarVoConfig | None = None,
                 camera: CameraModel | None = None) -> None:
        self.config = PlanarVoConfig() if config is None else config
        self._extractor = ACExtractor(self.config.frontend)
        self._estimator = MotionEstimator(self.config.estimator, self.config.voting)
        self._camera = camera
        self._speed = SpeedIntegrator()
        self._calibrator = FocalCalibrator() if self.config.camera.estimate_focal else None
        mount = self.config.mount
        # base_link is where the user says the camera sits (REP-105): the configured mount.
        self._T_base_camera = mount_transform(mount.x, mount.y, mount.height, mount.roll,
                                              mount.pitch, mount.yaw)
        # The camera's tilt on the vehicle, estimated online from the refined motions (its
        # pitch and roll relative to the plane of motion), levels the ACs for the planar vote
        # and centres the planar prior once precise; the configured angles until then.
        self._tilt = MountTiltEstimator() if mount.estimate_tilt else None
        self.tilt_estimate = None
        self._estimator.R_lc = leveling_rotation(mount.pitch, mount.roll)
        self._keyframes = KeyframeChain()
        self.counters: dict[str, int] = {}
        odometry = self.config.odometry
        self._clock = FrameClock(odometry.max_frame_gap, odometry.max_time_jump_back)
        self.reset()

    # -- state ---------------------------------------------------------------------------------

    def reset(self) -> None:
        """Pose back to the identity and a new keyframe chain from the next frame; the counters
        and the calibrations (tilt, focal length) are kept."""
        self._keyframes.clear()
        self.camera_pose = np.eye(4)
        self._camera_cov = np.zeros((6, 6))
        self.pose = self._T_base_camera @ invert(self._T_base_camera)
        self._last_out: tuple[float, np.ndarray] | None = None   # stamp, camera pose
        self._twist = np.zeros(6)
        self._twist_cov = np.eye(6) * _UNKNOWN
        self._held: tuple[float, float, float] | None = None      # speed, std, stamp
        self._lost = 0
        self._restart = False
        self._time_reset = False
        self._state = TrackingState.INITIALISING
        self._clock.reset()
        self._estimator.reset()

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
            self._keyframes.clear()
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
            # Nothing to track: the frame counts towards lost tracking (a tunnel, a covered
            # lens), but it never becomes a keyframe.
            return self._lost_frame(stamp, DropReason.BLANK_IMAGE,
                                    'image is blank (black, saturated or without texture)', 0)
        timings['decode'] = time.perf_counter() - t
        keyframe = self._keyframes.current
        if keyframe is None:
            return self._start_chain(gray, stamp)

        t = time.perf_counter()
        acs = self._extractor.extract(keyframe.image, gray)
        timings['correspondences'] = time.perf_counter() - t
        if len(acs) < self.config.odometry.min_correspondences:
            return self._lost_frame(stamp, DropReason.TOO_FEW_CORRESPONDENCES,
                                    f'{len(acs)} correspondences (minimum '
                                    f'{self.config.odometry.min_correspondences})', len(acs))
        parallax = float(np.median(np.linalg.norm(acs.p2 - acs.p1, axis=1)))
        if parallax < self.config.keyframe.stationary_parallax:
            return self._stationary(keyframe, stamp, len(acs))

        t = time.perf_counter()
        est = self._estimate(acs, camera)
        timings['solve'] = time.perf_counter() - t
        if not est.reliable:
            return self._lost_frame(stamp, DropReason.UNRELIABLE,
                                    f'motion estimate flagged {est.flag!r} '
                                    f'({est.num_inliers} inliers of {len(acs)})', len(acs),
                                    est.num_inliers)
        t = time.perf_counter()
        scale, var_scale, source = self._scale(acs, camera, est, keyframe, stamp)
        timings['scale'] = time.perf_counter() - t
        t = time.perf_counter()
        self.camera_pose, self._camera_cov, step_cov = compose(
            keyframe.pose, keyframe.covariance, est.R, est.t, est.basis,
            self._motion_covariance(est), scale, var_scale)
        self._update_twist(keyframe, stamp, step_cov)
        new_keyframe = (parallax >= self.config.keyframe.min_parallax
                        or keyframe.age + 1 >= self.config.keyframe.max_interval)
        if new_keyframe:
            self._keyframes.add(gray, stamp, self.camera_pose, self._camera_cov)
        else:
            keyframe.age += 1
        self._lost = 0
        timings['integrate'] = time.perf_counter() - t
        alpha, beta = planar_motion_from_pose(self._estimator.R_lc @ est.R @ self._estimator.R_lc.T,
                                              self._estimator.R_lc @ est.t)
        return self._result(stamp, True, keyframe=new_keyframe, scale_source=source,
                            num_correspondences=len(acs), num_inliers=est.num_inliers,
                            alpha=float(alpha), beta=float(beta))

    # -- steps ---------------------------------------------------------------------------------

    def _resolve_camera(self, camera: CameraModel | None, shape: tuple[int, int]
                        ) -> CameraModel | None:
        if camera is not None:
            if self._camera is not None and camera != self._camera:
                log.info('camera model changed; starting a new keyframe')
                self._keyframes.clear()
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

    def _estimate(self, acs: AffineCorrespondences, camera: CameraModel) -> FrameEstimate:
        """The camera's relative pose since the keyframe (`MotionEstimator`)."""
        if self._camera is None and self._calibrator is not None:
            ideal = undistort_acs(acs, camera)
            c = camera.K[:2, 2]
            self._calibrator.add(ideal.p1 - c, ideal.p2 - c, ideal.A, ideal.weights)
        norm = acs.normalized(camera)                 # undistorted, K^-1
        level = norm.mapped(self._estimator.R_lc)
        if len(level) != len(norm):
            # A ray the levelling rotation sends behind the camera (only beyond 90 degrees off
            # axis): drop it from both, so that the two sets stay item by item the same.
            keep = np.isfinite(apply_homography(self._estimator.R_lc, norm.p1)).all(1) & \
                np.isfinite(apply_homography(self._estimator.R_lc, norm.p2)).all(1)
            norm = norm.subset(keep)
            level = norm.mapped(self._estimator.R_lc)
        est = self._estimator.estimate(norm, level)
        if est.reliable:
            self._calibrate_tilt(est)
        self._norm = norm
        return est

    def _calibrate_tilt(self, est: FrameEstimate) -> None:
        """Feed a reliable relative pose to the mount-tilt estimate; adopt its pitch (and roll,
        once observable) when precise (``mount.tilt_tolerance``). Amortised: the fit runs every
        tenth pair, for at most ``mount.tilt_max_pairs`` pairs."""
        cfg = self.config.mount
        if self._tilt is None or len(self._tilt) >= cfg.tilt_max_pairs:
            return
        self._tilt.add_motion(est.R, est.t)
        if len(self._tilt) < 10 or len(self._tilt) % 10:
            return
        estimate = self._tilt.estimate()
        if estimate.pitch_std > cfg.tilt_tolerance:
            return
        roll = estimate.roll if estimate.roll_std <= cfg.tilt_tolerance else cfg.roll
        self.tilt_estimate = estimate
        self._estimator.R_lc = leveling_rotation(estimate.pitch, roll)
        log.info('mount tilt estimated from %d pairs: pitch %.3f +- %.3f deg, roll %.3f +- '
                 '%.3f deg (%s); base_link stays where mount.* puts it', estimate.frames,
                 np.rad2deg(estimate.pitch), np.rad2deg(estimate.pitch_std),
                 np.rad2deg(estimate.roll), np.rad2deg(estimate.roll_std),
                 'used' if roll == estimate.roll else 'roll not observable yet: configured roll')

    def _motion_covariance(self, est: FrameEstimate) -> np.ndarray:
        """The estimator's 5x5 covariance, widened by the focal length's uncertainty while it
        is provisional (an error of ``e`` relative scales every angle by about ``1 + e``)."""
        cov = est.cov
        if self._camera is None and self._calibrator is not None:
            f = self._calibrator.estimate
            rel = self._calibrator.std / f if math.isfinite(f) else 1.0
            angle = float(np.linalg.norm(so3_log(est.R)))
            cov = cov.copy()
            cov[:3, :3] += np.eye(3) * (angle * min(rel, 1.0)) ** 2
        return cov

    def _scale(self, acs: AffineCorrespondences, camera: CameraModel, est: FrameEstimate,
               keyframe: Keyframe, stamp: float) -> tuple[float, float, str]:
        """Step length (m), its variance and the source used: the configured source, then the
        fallback; a unit step of unknown length when no metric scale exists."""
        cfg = self.config.scale
        dt = stamp - keyframe.stamp
        for source in (cfg.source, cfg.fallback):
            if source == 'speed':
                d = self._speed.distance(keyframe.stamp, stamp)
                if d is not None:
                    return self._metric(d, (cfg.speed_std * dt) ** 2, 'speed', stamp, dt)
            elif source == 'ground':
                norm = self._norm
                R_l = self._estimator.R_lc @ est.R @ self._estimator.R_lc.T
                alpha, beta = planar_motion_from_pose(R_l, self._estimator.R_lc @ est.t)
                level = norm.mapped(self._estimator.R_lc)
                g = ground_plane_scale(level.p1, level.p2, level.A, float(alpha), float(beta),
                                       self.config.mount.height, weights=est.inliers,
                                       affine_tol=cfg.ground_affine_tolerance,
                                       min_count=cfg.ground_min_correspondences)
                if math.isfinite(g.scale):
                    return self._metric(g.scale, g.std ** 2, 'ground', stamp, dt)
            elif source == 'fixed':
                return cfg.fixed_speed * dt, (cfg.fixed_speed_std * dt) ** 2, 'fixed'
            elif source == 'hold' and self._held is not None:
                # The last metric speed, its uncertainty growing with the time since: a vehicle
                # changes its speed by about hold_acceleration_std m/s every second.
                speed, std, when = self._held
                std = math.hypot(std, cfg.hold_acceleration_std * (stamp - when))
                return speed * dt, (std * dt) ** 2, 'hold'
        return 1.0, _UNKNOWN, 'unit'

    def _metric(self, distance: float, variance: float, source: str, stamp: float, dt: float
                ) -> tuple[float, float, str]:
        """Remember the speed of a metric step (for ``'hold'``) and return it."""
        if dt > 0:
            self._held = (distance / dt, math.sqrt(variance) / dt, stamp)
        return distance, variance, source

    def _stationary(self, keyframe: Keyframe, stamp: float, count: int) -> FrameResult:
        """The image has not moved: neither has the vehicle (no new keyframe, no drift). The
        keyframe's stamp follows, since nothing moved since it (a speed source then integrates
        from here, however long the stop)."""
        self.camera_pose = keyframe.pose.copy()
        self._camera_cov = keyframe.covariance.copy()
        keyframe.stamp = stamp
        keyframe.age += 1
        if self._held is not None:
            self._held = (0.0, self._held[1], stamp)
        self._twist = np.zeros(6)
        self._twist_cov = np.diag([1e-6] * 3 + [1e-8] * 3)
        self._last_out = (stamp, self.camera_pose.copy())
        self._lost = 0
        return self._result(stamp, True, keyframe=False, scale_source='stationary',
                            num_correspondences=count, alpha=0.0, beta=float('nan'))

    def _lost_frame(self, stamp: float, reason: DropReason, message: str, count: int,
                    inliers: int = 0) -> FrameResult:
        """No update from this frame. After ``odometry.max_lost_frames`` in a row the keyframe
        is dropped: the next usable frame starts a new keyframe chain (`_restart_chain`). The
        failed frame itself never becomes the keyframe, since it may be the cause (a blank or
        garbled image would leave the next real frame without correspondences)."""
        if self._keyframes.current is None and not self._restart:
            return self._drop(stamp, reason, message, count, inliers)
        self._lost += 1
        keyframe = self._keyframes.current
        if keyframe is not None:
            keyframe.age += 1
        self._state = TrackingState.LOST
        if self._lost >= self.config.odometry.max_lost_frames and not self._restart:
            self._keyframes.clear()
            self._restart = True
            message += '; tracking lost: the next usable frame starts a new keyframe chain'
        return self._drop(stamp, reason, message, count, inliers)

    def _start_chain(self, gray: np.ndarray, stamp: float) -> FrameResult:
        """The first keyframe of a chain: after start-up or a reset at the origin; after lost
        tracking at the pose extrapolated from the last output (`_extrapolate`)."""
        reason, message = DropReason.FIRST_FRAME, 'reference keyframe set'
        if self._restart:
            self._extrapolate(stamp)
            reason, message = (DropReason.REINITIALISED,
                               'new keyframe chain after lost tracking (pose extrapolated)')
        elif self._time_reset:
            reason, message = (DropReason.TIME_JUMP_BACK,
                               f'time jumped back to {stamp:.9f}: tracking reset, pose at the '
                               f'origin, new keyframe chain')
        self._keyframes.add(gray, stamp, self.camera_pose, self._camera_cov)
        self._state = (TrackingState.TRACKING if reason is DropReason.FIRST_FRAME
                       else TrackingState.REINITIALISED)
        self._restart = self._time_reset = False
        self._lost = 0
        if self._last_out is None:
            self._last_out = (stamp, self.camera_pose.copy())
        return self._drop(stamp, reason, message)

    def _extrapolate(self, stamp: float) -> None:
        """The pose across a gap in tracking: the last velocity carried on, its turn rate
        decaying (a long gap does not spin the pose), and the covariance grown with the time
        of the gap (not with the frames in it)."""
        cfg = self.config.odometry
        last_stamp, last_pose = self._last_out if self._last_out else (stamp, self.camera_pose)
        dt = max(stamp - last_stamp, 0.0)
        T_bc = self._T_base_camera
        v, w = self._twist[:3], self._twist[3:]
        yaw = yaw_rate_decay(float(w[2]), dt, cfg.turn_rate_time_constant)
        step_base = se3(rotation_rpy(0.0, 0.0, yaw), v * dt)
        self.camera_pose = last_pose @ (invert(T_bc) @ step_base @ T_bc)
        grow = np.diag([(cfg.lost_turn_rate_std * dt) ** 2] * 3
                       + [(cfg.lost_speed_std * dt) ** 2] * 3)
        Ad = adjoint(invert(T_bc))
        self._camera_cov = self._camera_cov + Ad @ grow @ Ad.T

    def _update_twist(self, keyframe: Keyframe, stamp: float, step_cov: np.ndarray) -> None:
        """The body-frame velocity over the step since the keyframe, with its covariance."""
        dt = stamp - keyframe.stamp
        if dt > 0:
            T_bc = self._T_base_camera
            rel = T_bc @ invert(keyframe.pose) @ self.camera_pose @ invert(T_bc)
            self._twist = np.concatenate([rel[:3, 3], so3_log(rel[:3, :3])]) / dt
            Ad = adjoint(T_bc)
            self._twist_cov = ros_twist_covariance(Ad @ step_cov @ Ad.T, dt)
        self._last_out = (stamp, self.camera_pose.copy())

    # -- results -------------------------------------------------------------------------------

    def _result(self, stamp: float, ok: bool, **fields) -> FrameResult:
        if ok:
            self._state = TrackingState.TRACKING
        pose, cov_body = to_base(self.camera_pose, self._camera_cov, self._T_base_camera)
        cov = ros_pose_covariance(pose, cov_body)
        odometry = self.config.odometry
        if odometry.output == 'flat':
            pose, cov = flatten(pose, cov, odometry.flat_z_std, odometry.flat_tilt_std)
        self.pose = pose
        return FrameResult(stamp=stamp, ok=ok, pose=pose.copy(), pose_covariance=cov,
                           tracking=self._state, camera_pose=self.camera_pose.copy(),
                           twist=self._twist.copy(), twist_covariance=self._twist_cov.copy(),
                           **fields)

    def _drop(self, stamp: float, reason: DropReason, message: str, count: int = 0,
              inliers: int = 0) -> FrameResult:
        return self._result(stamp, False, reason=reason, message=message,
                            num_correspondences=count, num_inliers=inliers)


# Variance (m^2 or rad^2) that says "unknown": a unit step has no metric length.
_UNKNOWN = 1e6


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
