"""The sections of the configuration: frozen dataclasses, validated once, mirroring
``config/planar_vo.yaml``.

The node maps ROS parameters onto it (dotted names such as ``voting.bins``), the CLI maps flags
and ``--config FILE`` onto it, and the library takes the section it needs. Values use SI units and
radians. Sections:

- `CameraConfig`: intrinsics when no ``CameraInfo`` is available, focal self-calibration.
- `MountConfig`: the ``base_link -> camera optical`` transform (height, pitch, roll, yaw, offset).
- `FrontendConfig`: how affine correspondences are extracted.
- `VotingConfig`: histogram voting, inlier selection and refinement.
- `KeyframeConfig`, `ScaleConfig`: keyframe selection and the source of metric scale.
- `OdometryConfig`: frame checks and the planar-model covariance terms.
- `RosConfig`: topics, frames and publishing (used by the node only).
"""

from __future__ import annotations

import dataclasses
import math
import typing
from typing import Any

from planar_vo.core.options import Options, finite
from planar_vo.core.robust.options import VotingConfig
from planar_vo.errors import ConfigError

__all__ = [
    'CameraConfig',
    'FrontendConfig',
    'KeyframeConfig',
    'MountConfig',
    'OdometryConfig',
    'PlanarVoConfig',
    'RosConfig',
    'ScaleConfig',
    'VotingConfig',
]


@dataclasses.dataclass(frozen=True)
class CameraConfig(Options):
    """Intrinsics used when no ``CameraInfo`` arrives (all zero: wait for ``CameraInfo``).

    Attributes:
        fx, fy, cx, cy: pinhole intrinsics in pixels; ``fx = 0`` means 'from CameraInfo'.
        distortion_model: ``'none'``, ``'plumb_bob'`` or ``'equidistant'`` (ROS names).
        distortion: coefficients in the ROS order for that model.
        estimate_focal: self-calibrate the focal length online with 1ACf voting (the
            principal point is assumed at ``(cx, cy)``, or the image centre when those are 0).
        focal_tolerance: the calibration is used once its relative standard deviation is below
            this; until then a provisional focal length is used.
        focal_budget: share of the average per-frame processing time that the focal
            self-calibration may add on average (its per-pair profiles, about 100 ms each, are
            queued and worked off in steps of about 10 ms within this budget).
        focal_max_acs: ACs per turning pair kept for its focal profile (evenly picked), a
            memory bound; fewer cost less but lose information (800 instead of 1,300 widened
            the KITTI 05 standard deviation by a third).
        focal_queue: turning pairs waiting for their profile at most (memory bound; further
            pairs are dropped and counted while it is full).
        focal_block_frames: frames per block of the focal calibration (pairs within about one
            second share scenery and pitch wobble: one cluster of its variance); about the
            frame rate.
        focal_min_blocks: blocks (clusters) needed before a self-calibrated focal length may
            be adopted (fewer make the variance itself unreliable).
        focal_max_blocks: blocks kept (memory bound; the least informative is dropped).
    """

    fx: float = 0.0
    fy: float = 0.0
    cx: float = 0.0
    cy: float = 0.0
    distortion_model: typing.Literal['none', 'plumb_bob', 'equidistant'] = 'none'
    distortion: tuple[float, ...] = ()
    estimate_focal: bool = False
    focal_tolerance: float = 0.02
    focal_budget: float = 0.1
    focal_max_acs: int = 2000
    focal_queue: int = 16
    focal_block_frames: int = 10
    focal_min_blocks: int = 4
    focal_max_blocks: int = 32

    def validate(self) -> None:
        self._require(finite(self.fx, self.fy, self.cx, self.cy), 'fx', 'finite intrinsics')
        self._require(self.fx >= 0.0 and self.fy >= 0.0, 'fx', 'fx, fy >= 0 (0 = from CameraInfo)')
        self._require(finite(*self.distortion), 'distortion', 'finite coefficients')
        self._require(0.0 < self.focal_tolerance < 1.0, 'focal_tolerance', 'in (0, 1)')
        self._require(0.0 < self.focal_budget <= 1.0, 'focal_budget', 'a share in (0, 1]')
        self._require(self.focal_max_acs >= 50, 'focal_max_acs', 'at least 50')
        self._require(self.focal_queue >= 1, 'focal_queue', 'at least 1')
        self._require(self.focal_block_frames >= 1, 'focal_block_frames', 'at least 1')
        self._require(self.focal_min_blocks >= 2, 'focal_min_blocks', 'at least 2')
        self._require(self.focal_max_blocks >= self.focal_min_blocks, 'focal_max_blocks',
                      'at least focal_min_blocks')


@dataclasses.dataclass(frozen=True)
class MountConfig(Options):
    """Pose of the camera optical frame in ``base_link`` (REP-103: x forward, y left, z up).

    The optical frame (x right, y down, z forward) is first rotated into ``base_link`` in the
    usual way (optical z along base x), then by ``roll``, ``pitch``, ``yaw`` (radians, about the
    base x, y, z axes; positive pitch looks down) and placed at ``(x, y, height)`` metres.

    Attributes:
        x, y, height: camera position in ``base_link`` (metres); ``height`` above the ground.
        roll, pitch, yaw: camera orientation offsets (radians).
        estimate_tilt: estimate pitch and roll online from the motion (real mounts are not
            level): general poses of keyframe pairs are fitted with a motion plane, and its
            pitch and roll replace the ones above once precise.
        tilt_tolerance: the estimated tilt is adopted once the pitch standard deviation is
            below this (radians).
        tilt_max_pairs: frame pairs used for the tilt estimate (the five-point solver runs on
            each, so this bounds the extra cost).
        tilt_wobble_std: initial standard deviation (rad) of a pair's rotation about axes other
            than the motion-plane normal (the car's pitch and roll on its suspension; KITTI:
            0.04-0.11 deg per frame pair); only rotations above 3 times this inform the tilt,
            and the odometry replaces it by the non-planarity it measures.
        tilt_window: frame pairs the tilt estimator keeps (the most recent; memory bound).
        tilt_refit: the tilt is refitted after this many new pairs (cost bound).
    """

    x: float = 0.0
    y: float = 0.0
    height: float = 1.5
    roll: float = 0.0
    pitch: float = 0.0
    yaw: float = 0.0
    estimate_tilt: bool = False
    tilt_tolerance: float = 0.002
    tilt_max_pairs: int = 100
    tilt_wobble_std: float = 0.001745
    tilt_window: int = 1000
    tilt_refit: int = 10

    def validate(self) -> None:
        self._require(finite(self.x, self.y, self.height, self.roll, self.pitch, self.yaw),
                      'height', 'finite values')
        self._require(self.height > 0.0, 'height', 'a positive height above the ground (m)')
        for name in ('roll', 'pitch', 'yaw'):
            self._require(abs(getattr(self, name)) <= math.pi, name, 'an angle in [-pi, pi] rad')
        self._require(self.tilt_tolerance > 0.0, 'tilt_tolerance', 'a positive angle (rad)')
        self._require(self.tilt_max_pairs >= 10, 'tilt_max_pairs', 'at least 10')
        self._require(0.0 <= self.tilt_wobble_std < 0.1 and finite(self.tilt_wobble_std),
                      'tilt_wobble_std', 'an angle in [0, 0.1) rad')
        self._require(self.tilt_window >= 10, 'tilt_window', 'at least 10 pairs')
        self._require(self.tilt_refit >= 1, 'tilt_refit', 'at least 1 pair')


@dataclasses.dataclass(frozen=True)
class FrontendConfig(Options):
    """Affine-correspondence extraction (`planar_vo.frontend`).

    Attributes:
        method: ``'flow'`` (DIS optical flow + per-patch affine refinement; the default),
            ``'klt'`` (KLT tracks refined by affine Lucas-Kanade) or ``'asift'`` (faithful to
            the paper, about 2 s per frame pair).
        max_correspondences: cap on ACs per frame pair.
        grid_step: spacing in pixels of the candidate grid (one candidate per cell) for
            ``flow``, minimum corner distance for ``klt``.
        patch_radius: half-size in pixels of the patch an affine is fitted on.
        patch_stride: spacing in pixels of the samples within a patch (the images are
            smoothed first; a 7x7 grid over a radius of 9 px gave more accurate affines than
            15x15 samples over 7 px, at a fifth of the cost).
        lk_iterations: Gauss-Newton iterations of the affine Lucas-Kanade refinement on all
            patches.
        lk_max_iterations: further iterations, up to this total, only on the patches that have
            not converged yet.
        dis_preset: DIS optical-flow preset of the forward flow, ``'ultrafast'``, ``'fast'`` or
            ``'medium'`` (the refinement makes the preset matter little: on KITTI the accepted
            ACs agree with the ground-truth motion equally well for all three).
        fb_preset: DIS preset of the backward flow used only for the forward-backward check.
        fb_threshold: maximum forward-backward flow error in pixels; 0 (the default) disables
            the check and the backward flow: after the patch refinement, whose convergence and
            residual tests reject the same candidates, it changed neither the accuracy nor the
            number of ACs (rendered street, KITTI) but cost a second DIS flow.
        min_texture: minimum smaller eigenvalue of the local structure tensor, in (grey levels
            per pixel)^2 of the 8-bit image.
        max_residual: maximum RMS photometric residual of a refined patch, relative to the
            patch's RMS contrast (0 identical, 1 uncorrelated).
        refine_affine: refine each affine on its patch (needed on the foreshortened ground).
        reseed: give failed candidates a second start from an accepted neighbour's affine (the
            near ground, where DIS fails).
        match_ratio: Lowe's ratio test threshold for ``asift`` descriptor matching.
    """

    method: typing.Literal['flow', 'klt', 'asift'] = 'flow'
    max_correspondences: int = 4000
    grid_step: int = 10
    patch_radius: int = 9
    patch_stride: int = 3
    lk_iterations: int = 2
    lk_max_iterations: int = 4
    dis_preset: typing.Literal['ultrafast', 'fast', 'medium'] = 'ultrafast'
    fb_preset: typing.Literal['ultrafast', 'fast', 'medium'] = 'ultrafast'
    fb_threshold: float = 0.0
    min_texture: float = 1.5
    max_residual: float = 0.3
    refine_affine: bool = True
    reseed: bool = True
    match_ratio: float = 0.8

    def validate(self) -> None:
        # cv2.remap takes at most 32767 rows: one row per patch.
        self._require(1 <= self.max_correspondences <= 30000, 'max_correspondences',
                      'between 1 and 30000')
        self._require(self.grid_step >= 2, 'grid_step', 'at least 2 pixels')
        self._require(self.patch_radius >= 2, 'patch_radius', 'at least 2 pixels')
        self._require(1 <= self.patch_stride <= self.patch_radius, 'patch_stride',
                      'between 1 and patch_radius pixels')
        self._require(self.lk_iterations >= 1, 'lk_iterations', 'at least 1')
        self._require(self.lk_max_iterations >= self.lk_iterations, 'lk_max_iterations',
                      'at least lk_iterations')
        self._require(self.fb_threshold >= 0.0 and finite(self.fb_threshold), 'fb_threshold',
                      'a non-negative number of pixels (0 disables)')
        self._require(self.min_texture >= 0.0 and finite(self.min_texture), 'min_texture',
                      'a non-negative number')
        self._require(self.max_residual > 0.0, 'max_residual', 'a positive ratio')
        self._require(0.0 < self.match_ratio <= 1.0, 'match_ratio', 'in (0, 1]')


@dataclasses.dataclass(frozen=True)
class KeyframeConfig(Options):
    """Keyframe selection by parallax: small baselines carry little information.

    Attributes:
        min_parallax: median AC displacement (pixels) from the keyframe that makes a frame the
            new keyframe.
        max_interval: a frame becomes the keyframe after at most this many frames.
        stationary_parallax: below this median displacement (pixels) the vehicle is standing
            still: zero motion is output and no keyframe is made.
    """

    min_parallax: float = 3.0
    max_interval: int = 10
    stationary_parallax: float = 0.25

    def validate(self) -> None:
        self._require(self.min_parallax >= 0.0, 'min_parallax', 'a non-negative pixel count')
        self._require(self.max_interval >= 1, 'max_interval', 'at least 1 frame')
        self._require(0.0 <= self.stationary_parallax <= self.min_parallax, 'stationary_parallax',
                      'a pixel count in [0, min_parallax]')


@dataclasses.dataclass(frozen=True)
class ScaleConfig(Options):
    """Where metric scale comes from (monocular motion has none).

    Attributes:
        source: ``'speed'`` (a TwistStamped/Odometry topic, e.g. wheel odometry), ``'ground'``
            (road ACs at the known camera height ``mount.height``), ``'fixed'``
            (``fixed_speed``), or ``'unit'`` (unit steps between keyframes).
        fallback: source used while the primary gives nothing (``'ground'`` with no road ACs in
            view, ``'speed'`` before the first message): ``'hold'`` keeps the speed of the last
            metric step (for up to ``hold_seconds``, then unit steps), or ``'ground'``,
            ``'fixed'``, ``'unit'``.
        hold_seconds: how long ``'hold'`` may keep the last metric speed.
        speed_std: standard deviation of the speed source (m/s).
        speed_max_gap: longest interval (s) without speed samples that is bridged by
            interpolation; set it above the speed source's sample period (1.5 for 1 Hz).
        fixed_speed: metres per second for ``'fixed'``.
        fixed_speed_std: its assumed standard deviation (m/s).
        ground_affine_tolerance: a road AC's affine must match the ground homography within
            this relative Frobenius distance.
        ground_min_correspondences: fewer road ACs give no ground scale.
        ground_max_depth: road points farther than this (m) are not used for the scale: their
            parallax (about h s / Z^2) is small against the rotation noise.
        ground_point_std: point noise (pixels) of the road test (the front-end's accuracy).
        ground_affine_std: affine noise (unitless) of the road test.
        ground_gate: whitened RMS residual (points and affine) above which an AC is not road.
        ground_normal_std: standard deviation (rad) of the road ahead's normal against the
            calibrated one in a single frame (car pitch on its suspension, slope changes;
            measured on KITTI about 0.2 deg); added to the calibration's own.
        ground_normal_frames: frame pairs of road ACs kept by the road-normal calibration.
        ground_normal_acs: road ACs kept per frame pair for it (evenly picked).
        ground_normal_refit: the road normal is refitted after this many new frame pairs.
    """

    source: typing.Literal['speed', 'ground', 'fixed', 'unit'] = 'ground'
    fallback: typing.Literal['hold', 'ground', 'fixed', 'unit'] = 'hold'
    hold_seconds: float = 2.0
    speed_std: float = 0.1
    speed_max_gap: float = 0.5
    fixed_speed: float = 10.0
    fixed_speed_std: float = 3.0
    ground_affine_tolerance: float = 0.05
    ground_min_correspondences: int = 10
    ground_max_depth: float = 30.0
    ground_point_std: float = 1.0
    ground_affine_std: float = 0.03
    ground_gate: float = 3.0
    ground_normal_std: float = 0.00349
    ground_normal_frames: int = 200
    ground_normal_acs: int = 60
    ground_normal_refit: int = 10

    def validate(self) -> None:
        self._require(self.hold_seconds >= 0.0, 'hold_seconds', 'a non-negative duration (s)')
        self._require(self.speed_std > 0.0 and finite(self.speed_std), 'speed_std',
                      'a positive speed in m/s')
        self._require(self.fixed_speed >= 0.0 and finite(self.fixed_speed), 'fixed_speed',
                      'a non-negative speed in m/s')
        self._require(self.fixed_speed_std > 0.0, 'fixed_speed_std', 'a positive speed in m/s')
        self._require(self.ground_affine_tolerance > 0.0, 'ground_affine_tolerance',
                      'a positive number')
        self._require(self.ground_min_correspondences >= 1, 'ground_min_correspondences',
                      'at least 1')
        self._require(0.0 < self.speed_max_gap < 1e6, 'speed_max_gap',
                      'a positive duration in seconds')
        for name in ('ground_max_depth', 'ground_point_std', 'ground_affine_std', 'ground_gate'):
            value = getattr(self, name)
            self._require(value > 0.0 and finite(value), name, 'a positive number')
        self._require(0.0 <= self.ground_normal_std < 0.1 and finite(self.ground_normal_std),
                      'ground_normal_std', 'an angle in [0, 0.1) rad')
        self._require(self.ground_normal_frames >= 2, 'ground_normal_frames', 'at least 2')
        self._require(self.ground_normal_acs >= 10, 'ground_normal_acs', 'at least 10')
        self._require(self.ground_normal_refit >= 1, 'ground_normal_refit', 'at least 1')


@dataclasses.dataclass(frozen=True)
class OdometryConfig(Options):
    """Frame checks and the parts of the pose that planar motion does not estimate.

    Attributes:
        min_correspondences: fewer ACs than this drop the frame (too_few_correspondences).
        min_contrast: grey-level standard deviation below which a frame is blank.
        max_lost_frames: after this many frames in a row without an update, tracking is
            restarted at the next usable frame (the pose is extrapolated and its covariance
            grows).
        max_frame_gap: the longest plausible interval between consecutive frames (s): a frame
            stamped further ahead is refused as a clock glitch unless the next frame confirms
            the new time, which then restarts tracking.
        max_time_jump_back: a stamp further back than this (s) resets tracking (a looped bag, a
            restarted clock); a smaller step back is a frame out of order.
        planar_z_std: standard deviation of height changes (m) the planar model ignores.
        planar_tilt_std: standard deviation of roll and pitch (rad) the planar model ignores.
    """

    min_correspondences: int = 30
    min_contrast: float = 2.0
    max_lost_frames: int = 5
    max_frame_gap: float = 10.0
    max_time_jump_back: float = 1.0
    planar_z_std: float = 0.05
    planar_tilt_std: float = 0.02

    def validate(self) -> None:
        self._require(self.min_correspondences >= 1, 'min_correspondences', 'at least 1')
        self._require(self.min_contrast >= 0.0, 'min_contrast', 'a non-negative grey level')
        self._require(self.max_lost_frames >= 1, 'max_lost_frames', 'at least 1')
        self._require(0.0 < self.max_frame_gap < 1e9, 'max_frame_gap',
                      'a positive duration in seconds')
        self._require(0.0 <= self.max_time_jump_back < 1e9, 'max_time_jump_back',
                      'a non-negative duration in seconds')
        self._require(self.planar_z_std > 0.0, 'planar_z_std', 'a positive length')
        self._require(self.planar_tilt_std > 0.0, 'planar_tilt_std', 'a positive angle')


@dataclasses.dataclass(frozen=True)
class RosConfig(Options):
    """ROS interface of the node.

    Attributes:
        odom_frame, base_frame: REP-105 frame ids of the published pose.
        publish_tf: broadcast ``odom -> base_frame`` (needs ``tf2_ros``).
        image_transport: ``'raw'`` (``image``) or ``'compressed'`` (``image/compressed``).
        speed_topic_type: ``'twist'`` (``geometry_msgs/TwistStamped``) or ``'odometry'``.
        path_max_length: poses kept in the published ``nav_msgs/Path`` (0: unlimited).
        warn_period: seconds between repeats of the same warning.
    """

    odom_frame: str = 'odom'
    base_frame: str = 'base_link'
    publish_tf: bool = True
    image_transport: typing.Literal['raw', 'compressed'] = 'raw'
    speed_topic_type: typing.Literal['twist', 'odometry'] = 'twist'
    path_max_length: int = 10000
    warn_period: float = 5.0

    def validate(self) -> None:
        self._require(bool(self.odom_frame.strip()), 'odom_frame', 'a non-empty frame id')
        self._require(bool(self.base_frame.strip()), 'base_frame', 'a non-empty frame id')
        self._require(self.odom_frame != self.base_frame, 'base_frame', 'a frame id other than '
                      'odom_frame')
        self._require(self.path_max_length >= 0, 'path_max_length', 'a non-negative count')
        self._require(self.warn_period >= 0.0, 'warn_period', 'a non-negative number of seconds')


@dataclasses.dataclass(frozen=True)
class PlanarVoConfig(Options):
    """The whole configuration (``config/planar_vo.yaml``)."""

    camera: CameraConfig = dataclasses.field(default_factory=CameraConfig)
    mount: MountConfig = dataclasses.field(default_factory=MountConfig)
    frontend: FrontendConfig = dataclasses.field(default_factory=FrontendConfig)
    voting: VotingConfig = dataclasses.field(default_factory=VotingConfig)
    keyframe: KeyframeConfig = dataclasses.field(default_factory=KeyframeConfig)
    scale: ScaleConfig = dataclasses.field(default_factory=ScaleConfig)
    odometry: OdometryConfig = dataclasses.field(default_factory=OdometryConfig)
    ros: RosConfig = dataclasses.field(default_factory=RosConfig)

    @classmethod
    def from_flat(cls, flat: typing.Mapping[str, Any]) -> PlanarVoConfig:
        """Build from dotted keys (``{'voting.bins': 720}``), the form of ROS parameters."""
        nested: dict[str, Any] = {}
        for key, value in flat.items():
            node = nested
            *parents, leaf = key.split('.')
            for part in parents:
                node = node.setdefault(part, {})
                if not isinstance(node, dict):
                    raise ConfigError(f'{key}: {part} is a value, not a section')
            node[leaf] = value
        return cls.from_dict(nested)
