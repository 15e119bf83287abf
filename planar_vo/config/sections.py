"""The sections of the configuration: frozen dataclasses, validated once, mirroring
``config/planar_vo.yaml``.

The node maps ROS parameters onto it (dotted names such as ``voting.bins``), the CLI maps flags
and ``--config FILE`` onto it, and the library takes the section it needs. Values use SI units and
radians. Sections:

- `CameraConfig`: intrinsics when no ``CameraInfo`` is available, focal self-calibration.
- `MountConfig`: the ``base_link -> camera optical`` transform (height, pitch, roll, yaw, offset).
- `FrontendConfig`: how affine correspondences are extracted.
- `VotingConfig`: histogram voting, inlier selection and refinement.
- `EstimatorConfig`: the general-motion refinement behind the vote, and its reliability checks.
- `KeyframeConfig`, `ScaleConfig`: keyframe selection and the source of metric scale.
- `OdometryConfig`: frame checks and the planar-model covariance terms.
- `RosConfig`: topics, frames and publishing (used by the node only).
"""

from __future__ import annotations

import dataclasses
import math
import typing
from typing import Any

from planar_vo.core.camera import DISTORTION_MODELS, fits_distortion_model
from planar_vo.core.options import Options, bounded, finite, nest_dotted
from planar_vo.core.robust.options import EstimatorConfig, VotingConfig
from planar_vo.errors import ConfigError

__all__ = [
    'CameraConfig',
    'EstimatorConfig',
    'FrontendConfig',
    'KeyframeConfig',
    'MountConfig',
    'OdometryConfig',
    'PlanarVoConfig',
    'RosConfig',
    'ScaleConfig',
    'VotingConfig',
]


# Horizontal fields of view (rad) `camera.nominal_fov` may give, by lens: those of the focal
# lengths the self-calibration searches, 0.25-2.5 x the image width
# (`planar_vo.pipeline.calibration.focal`): through a rectilinear lens 22.6-126.9 deg, through an
# equidistant (fisheye) one 22.9-229.2 deg (`focal_for_field_of_view`).
NOMINAL_FOV_RANGE = {'rectilinear': (0.40, 2.20), 'equidistant': (0.40, 4.0)}


@dataclasses.dataclass(frozen=True)
class CameraConfig(Options):
    """Intrinsics used when no ``CameraInfo`` arrives (all zero: wait for ``CameraInfo``).

    Attributes:
        fx, fy, cx, cy: pinhole intrinsics in pixels; ``fx = 0`` means 'from CameraInfo' (or
            ``estimate_focal``), ``fy = 0`` 'the same as fx'; ``cx, cy = 0`` the image centre;
            a principal point outside the image is refused at the first image.
        distortion_model: ``'none'``, ``'plumb_bob'``, ``'rational_polynomial'`` or
            ``'equidistant'`` (ROS names).
        distortion: coefficients in the ROS order for that model; empty: all zero (for
            equidistant, the ideal fisheye).
        estimate_focal: self-calibrate the focal length online when ``fx`` is 0, instead of
            CameraInfo (the node does not subscribe to it, replay leaves a bag's unused):
            profile likelihoods of the focal length over frame pairs the car turned between
            (the principal point is assumed at ``(cx, cy)``, or the image centre when those
            are 0).
        nominal_fov: the camera's horizontal field of view (rad) as its specification states
            it (a dashcam's data sheet: 90 deg is 1.5708), where the self-calibration starts:
            its focal length (``width / (2 tan(fov / 2))``; through an ``equidistant`` fisheye
            lens ``width / fov``) is the prior's centre (log-normal, sigma 0.45) and the
            odometry's focal length until turning pairs move it; 0 (unknown): the focal length
            equals the image's larger side (53 deg across it through a rectilinear lens).
            Within the range the calibration searches: 0.40-2.20 rad (23-126 deg), with
            ``distortion_model: equidistant`` 0.40-4.0 rad (23-229 deg). Only with
            ``estimate_focal``. (The calibration profiles a fisheye's focal length to first
            order only: it rescales the undistorted points as a pinhole's.)
        nominal_fov_std: how well ``nominal_fov`` is known (rad, one standard deviation; 0:
            not said, the wide prior above). A measured or data-sheet value known to a degree
            (0.0175) keeps the focal length near it unless the turns' profiles say otherwise
            with more weight; give it only as tight as the value really is (KITTI's stated 90
            deg is 82 deg in truth).
        focal_tolerance: the calibration is adopted once its relative standard deviation
            (reported so that the error stays within 3 of them) is below this; until then a
            provisional focal length is used and its uncertainty enters the covariance. (This
            and the other ``focal_*`` settings only with ``estimate_focal``.)
        focal_steps: work steps of the focal calibration per frame while turning pairs wait
            (each a vote, a chunk of one pair's profile sized by its ACs, or its shifted
            profile, about 5-15 ms on KITTI frames; a pair of 400 ACs is 4 steps, of 1,200 ACs
            8); in steps rather than seconds, so that results do not depend on the machine's
            speed or load.
        focal_max_acs: ACs per turning pair kept for its focal profile (evenly picked), a
            memory bound; fewer cost less but lose information (800 instead of 1,300 widened
            the KITTI 05 standard deviation by a third).
        focal_queue: turning pairs waiting for their profile at most (memory bound; further
            pairs are dropped and counted while it is full).
        focal_block_frames: frames per block of the focal calibration at 10 Hz (pairs within
            about one second share scenery and pitch wobble: one cluster of its variance); a
            faster camera's blocks hold as many more frames (30 Hz: three times), so a block
            stays about a second long.
        focal_min_blocks: blocks (clusters) needed before a self-calibrated focal length may
            be adopted (fewer make the variance itself unreliable).
        focal_max_blocks: blocks kept (memory bound; the least informative is dropped).
        mono16_bits: significant bits of 16-bit grey images (``mono16``, ``16UC1``, 16-bit
            PNG): 16 for values filling the 16 bits, 12 for a 12-bit sensor whose values are
            stored as 0-4095 (10 likewise); they are shifted down by ``mono16_bits - 8`` to 8
            bits, a fixed mapping, so that brightness stays comparable between frames.
        rectified: the images are rectified (``image_rect``, image_proc's output): the camera
            model is CameraInfo's projection ``P`` (its fx, fy, cx, cy) without distortion, as
            image_geometry uses it for rectified images. False (raw images): ``K`` and ``D``.
            Only for a model from CameraInfo (not with ``fx`` or ``estimate_focal``).
    """

    fx: float = bounded(0.0, 0.0, expected='fx, fy >= 0 (0 = from CameraInfo)')
    fy: float = bounded(0.0, 0.0, expected='fx, fy >= 0 (0 = from CameraInfo)')
    cx: float = bounded(0.0, 0.0, expected='cx, cy >= 0 (0 = the image centre)')
    cy: float = bounded(0.0, 0.0, expected='cx, cy >= 0 (0 = the image centre)')
    distortion_model: typing.Literal['none', 'plumb_bob', 'rational_polynomial',
                                     'equidistant'] = 'none'
    distortion: tuple[float, ...] = ()
    estimate_focal: bool = False
    # The declared range (ros2 param describe) is the fisheye's; `validate` narrows it for a
    # rectilinear lens. Beyond it, most likely degrees: the text says how many radians 90 is.
    nominal_fov: float = bounded(0.0, 0.0, NOMINAL_FOV_RANGE['equidistant'][1],
                                 expected='0 (unknown) or a horizontal field of view in '
                                          'radians (90 deg is 1.5708): 0.4-2.2 rad, through a '
                                          'fisheye lens (distortion_model equidistant) up to 4 '
                                          'rad, 229 deg')
    nominal_fov_std: float = bounded(0.0, 0.0, 1.0,
                                     expected='0 (not said) or a standard deviation of the '
                                              'field of view of at most 1 rad')
    focal_tolerance: float = bounded(0.02, 0.0, 1.0, low_open=True, high_open=True)
    focal_steps: float = bounded(2.0, 0.0, 100.0, low_open=True,
                                 expected='work steps per frame in (0, 100]')
    focal_max_acs: int = bounded(2000, 50)
    focal_queue: int = bounded(16, 1)
    focal_block_frames: int = bounded(10, 1)
    focal_min_blocks: int = bounded(4, 2)
    focal_max_blocks: int = bounded(32, 2)
    mono16_bits: int = bounded(16, 8, 16, expected='an integer number of bits in 8..16')
    rectified: bool = False

    @property
    def coefficients(self) -> tuple[float, ...]:
        """``distortion``, the model's zeros when empty."""
        return self.distortion or (0.0,) * DISTORTION_MODELS[self.distortion_model]

    def validate(self) -> None:
        self._require(finite(*self.distortion), 'distortion', 'finite coefficients')
        count = DISTORTION_MODELS[self.distortion_model]
        # Empty: no distortion for any model (a user test: a fisheye's nominal_fov needed
        # distortion_model equidistant, which then refused the empty list, an undocumented
        # '[0, 0, 0, 0]' being the way out).
        self._require(not self.distortion
                      or fits_distortion_model(self.distortion_model, self.distortion),
                      'distortion',
                      f"{count} coefficients for distortion_model '{self.distortion_model}'"
                      + (' (or 4: k3 = 0)' if self.distortion_model == 'plumb_bob' else '')
                      + (' (more only if the extra ones are 0)' if self.distortion_model in
                         ('plumb_bob', 'rational_polynomial') else '')
                      + (', or none for no distortion' if count else ''))
        self._require(self.focal_max_blocks >= self.focal_min_blocks, 'focal_max_blocks',
                      'at least focal_min_blocks')
        self._require(self.fy == 0 or self.fx > 0, 'fy', '0 while fx is 0 (fy is used with fx '
                      'only; fx = 0 means the focal length comes from CameraInfo or '
                      'estimate_focal)')
        self._require(not (self.estimate_focal and self.fx > 0), 'estimate_focal',
                      f'false with fx configured ({self.fx:g} px: the focal length is known; '
                      f'fx = 0 self-calibrates it)')
        fisheye = self.distortion_model == 'equidistant'
        lo, hi = NOMINAL_FOV_RANGE['equidistant' if fisheye else 'rectilinear']
        fov = self.nominal_fov
        self._require(fov == 0 or lo <= fov <= hi, 'nominal_fov',
                      f'0 (unknown) or a horizontal field of view of {lo:g}-{hi:g} rad '
                      f'({math.degrees(lo):.0f}-{math.degrees(hi):.0f} deg, the range the focal '
                      f'calibration searches'
                      + (' through a fisheye lens' if fisheye else
                         '; wider: a fisheye lens, distortion_model equidistant' if fov > hi
                         else '')
                      + ')')
        self._require(self.nominal_fov == 0 or self.estimate_focal, 'nominal_fov',
                      '0 without estimate_focal (it is where the focal self-calibration starts)')
        # Options that would be ignored are refused, as nominal_fov above (a user test:
        # rectified with estimate_focal, and the calibration's settings without it, passed
        # without a word).
        self._require(not (self.rectified and (self.estimate_focal or self.fx > 0)),
                      'rectified', 'false when the camera model does not come from CameraInfo '
                      '(estimate_focal or fx configured): it says how a CameraInfo is read')
        defaults = {f.name: f.default for f in dataclasses.fields(self)}
        changed = [name for name in ('focal_tolerance', 'focal_steps', 'focal_max_acs',
                                     'focal_queue', 'focal_block_frames', 'focal_min_blocks',
                                     'focal_max_blocks')
                   if getattr(self, name) != defaults[name]]
        self._require(self.estimate_focal or not changed, changed[0] if changed else 'focal',
                      'its default without estimate_focal (a setting of the focal '
                      'self-calibration)')
        self._require(self.nominal_fov_std == 0 or self.nominal_fov > 0, 'nominal_fov_std',
                      '0 without nominal_fov (it says how well that is known)')


@dataclasses.dataclass(frozen=True)
class MountConfig(Options):
    """Pose of the camera optical frame in ``base_link`` (REP-103: x forward, y left, z up).

    The optical frame (x right, y down, z forward) is first rotated into ``base_link`` in the
    usual way (optical z along base x), then by ``roll``, ``pitch``, ``yaw`` (radians, about the
    base x, y, z axes; positive pitch looks down) and placed at ``(x, y, height)`` metres.

    Attributes:
        x, y, height: camera position in ``base_link`` (metres); ``height`` above the ground.
        height_std: how well ``height`` is known (metres, a standard deviation: a tape
            measure, the car's load and tyres); every step of the ground scale shares its
            relative error, so the position's covariance grows with the distance by it.
        roll, pitch, yaw: camera orientation offsets (radians).
        estimate_tilt: estimate pitch and roll online from the motion (real mounts are not
            level): the general relative poses are fitted with a motion plane, and its pitch
            and roll level the planar vote and the planar prior in place of the ones above
            (``base_link`` stays where these put it).
        tilt_tolerance: an estimated angle is used once its standard deviation is below this
            (radians); a less certain one is left at the configured value (levelling by a
            wrong angle does more harm than not levelling).
        tilt_wobble_std: initial standard deviation (rad) of a pair's rotation about axes other
            than the motion-plane normal (the car's pitch and roll on its suspension; KITTI:
            0.04-0.11 deg per frame pair); only rotations above 3 times this inform the tilt,
            and the odometry replaces it by the non-planarity it measures.
        tilt_window: frame pairs the tilt estimator keeps (the most recent; memory bound).
        tilt_refit: the tilt is refitted after this many new pairs (cost bound).
    """

    x: float = bounded(0.0, expected='a finite offset (m)')
    y: float = bounded(0.0, expected='a finite offset (m)')
    # 1 cm to 100 m: beyond, a slip of units (a user test: 1e-300 m ran, with a numpy warning,
    # into positions of 1e-299 m).
    height: float = bounded(1.5, 0.01, 100.0,
                            expected='a height above the ground of 0.01-100 m')
    height_std: float = bounded(0.01, 0.0, expected='a non-negative distance (m)')
    roll: float = bounded(0.0, -math.pi, math.pi, expected='an angle in [-pi, pi] rad')
    pitch: float = bounded(0.0, -math.pi, math.pi, expected='an angle in [-pi, pi] rad')
    yaw: float = bounded(0.0, -math.pi, math.pi, expected='an angle in [-pi, pi] rad')
    estimate_tilt: bool = True
    tilt_tolerance: float = bounded(0.0087, 0.0, low_open=True,
                                    expected='a positive angle (rad)')
    tilt_wobble_std: float = bounded(0.001745, 0.0, 0.1, high_open=True,
                                     expected='an angle in [0, 0.1) rad')
    tilt_window: int = bounded(1000, 10, expected='at least 10 pairs')
    tilt_refit: int = bounded(10, 1, expected='at least 1 pair')


@dataclasses.dataclass(frozen=True)
class FrontendConfig(Options):
    """Affine-correspondence extraction (`planar_vo.frontend`).

    Attributes:
        method: ``'flow'`` (DIS optical flow + per-patch affine refinement; the default),
            ``'klt'`` (KLT tracks refined by affine Lucas-Kanade) or ``'asift'`` (faithful to
            the paper, 4-11 s per frame pair on one core: `planar_vo bench frontend`).
        max_correspondences: cap on ACs per frame pair, the front-end's per-frame budget. For
            ``flow``, on the candidates: the grid's cells grow until at most this many have
            enough texture (the points stay spread over the image, the faint road included),
            so a richly textured scene costs no more per frame than a plain one. On KITTI
            05 and 06, budgets from 700 to 4000 gave per-frame yaw errors within 2 % and 3D
            rotation drift within 4 % of each other, with no trend: only the time per frame
            grew with the budget.
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
        flow_max_width: DIS flow runs on the images shrunk (area averaging) by the smallest
            integer factor that makes them at most this many pixels wide; 0 keeps the full
            resolution. The candidates, the flow Jacobian and the patch refinement stay at
            full resolution, so the refinement restores the accuracy: at 1241x376 (flow at
            620x188) the KITTI and rendered drives were as accurate as with the full-resolution
            flow, and replay was 5-11 % faster (two runs; README, Accuracy and speed).
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
    # cv2.remap takes at most 32767 rows: one row per patch.
    max_correspondences: int = bounded(700, 1, 30000)
    grid_step: int = bounded(10, 2, expected='at least 2 pixels')
    patch_radius: int = bounded(9, 2, expected='at least 2 pixels')
    patch_stride: int = bounded(3, 1, expected='between 1 and patch_radius pixels')
    lk_iterations: int = bounded(2, 1)
    lk_max_iterations: int = bounded(4, 1, expected='at least lk_iterations')
    dis_preset: typing.Literal['ultrafast', 'fast', 'medium'] = 'ultrafast'
    flow_max_width: int = bounded(800, 0, expected='a non-negative number of pixels (0: full '
                                                   'resolution)')
    fb_preset: typing.Literal['ultrafast', 'fast', 'medium'] = 'ultrafast'
    fb_threshold: float = bounded(0.0, 0.0,
                                  expected='a non-negative number of pixels (0 disables)')
    min_texture: float = bounded(1.5, 0.0, expected='a non-negative number')
    max_residual: float = bounded(0.3, 0.0, low_open=True, expected='a positive ratio')
    refine_affine: bool = True
    reseed: bool = True
    match_ratio: float = bounded(0.8, 0.0, 1.0, low_open=True)

    def validate(self) -> None:
        self._require(self.patch_stride <= self.patch_radius, 'patch_stride',
                      'between 1 and patch_radius pixels')
        self._require(self.lk_max_iterations >= self.lk_iterations, 'lk_max_iterations',
                      'at least lk_iterations')


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

    min_parallax: float = bounded(3.0, 0.0, expected='a non-negative pixel count')
    max_interval: int = bounded(10, 1, expected='at least 1 frame')
    stationary_parallax: float = bounded(0.25, 0.0, expected='a pixel count in [0, min_parallax]')

    def validate(self) -> None:
        self._require(self.stationary_parallax <= self.min_parallax, 'stationary_parallax',
                      'a pixel count in [0, min_parallax]')


@dataclasses.dataclass(frozen=True)
class ScaleConfig(Options):
    """Where metric scale comes from (monocular motion has none).

    Attributes:
        source: ``'speed'`` (a TwistStamped/Odometry topic, e.g. wheel odometry), ``'ground'``
            (road ACs at the known camera height ``mount.height``, with the road's normal in
            the camera frame calibrated online from the road ACs), ``'fixed'``
            (``fixed_speed``), or ``'unit'`` (unit steps between keyframes).
        fallback: source used while the primary gives nothing (``'ground'`` with no road ACs in
            view, ``'speed'`` before the first message): ``'hold'`` keeps the speed of the last
            metric step, its uncertainty growing with the time since (never a unit step passed
            off as metric), or ``'ground'``,
            ``'fixed'``, ``'unit'``.
        hold_acceleration_std: how fast the speed may change while ``'hold'`` keeps it
            (m/s per second): its standard deviation grows by this every second.
        speed_std: standard deviation of the speed source (m/s).
        speed_max_gap: longest interval (s) without speed samples that is bridged by
            interpolation; set it above the speed source's sample period (1.5 for 1 Hz).
        fixed_speed: metres per second for ``'fixed'``.
        fixed_speed_std: its assumed standard deviation (m/s), an error shared by every step
            (the position's grows with the distance).
        ground_min_correspondences: fewer road ACs give no ground scale.
        ground_max_depth: road points farther than this (m) are not used for the scale: their
            parallax (about h s / Z^2) is small against the rotation noise.
        ground_point_std: point noise (pixels) of the road test (the front-end's accuracy).
        ground_affine_std: affine noise (unitless) of the road test.
        ground_gate: whitened RMS residual (points and affine) above which an AC is not road.
        ground_lateral_std: road ACs count for the step with a Gaussian weight of their lateral
            distance (m) from the car's line of travel, this standard deviation; 0 weighs all
            alike. The camera height is the height above the surface the car stands on; a
            road's crown and gutters, curbs, parking strips and sidewalks lie at other heights
            (KITTI 06 excerpt: steps from road ACs more than 3 m to the right 8.5 % long, those
            within 1 m of the line of travel 1 % short). The default is a lane's width.
        ground_normal_std: standard deviation (rad) of the road ahead's normal against the
            calibrated one in a single frame (car pitch on its suspension, slope changes;
            measured on KITTI about 0.2 deg); added to the calibration's own.
        ground_normal_frames: frame pairs of road ACs kept by the road-normal calibration.
        ground_normal_acs: road ACs kept per frame pair for it (evenly picked).
        ground_normal_refit: the road normal is refitted after this many new frame pairs.
        ground_top_up: when a frame's ACs hold too few road ACs for the ground scale, the
            front-end adds ACs on the road within ``ground_max_depth`` (at most
            ``frontend.max_correspondences`` more): the flow front-end from the same flows, on
            its grid without the per-frame budget's larger cells
            (`FlowExtractor.extract_more`), the KLT front-end from corners detected on the
            road alone (`KLTExtractor.extract_more`); not ASIFT. A fast car sees little near
            road, and the budget's cells (or the frame's stronger corners) leave few
            candidates on it.
        ground_image: when the road ACs (topped up or not) are still too few, the step is
            found from the road's pixels (`planar_vo.pipeline.road_image`): the road
            homography's one unknown, the step, scanned by correlating blocks of the road
            ahead within ``ground_lateral_std`` of the line of travel (a lane's width, 3.5 m,
            when that is 0); the blocks' matches
            then measure the step as road ACs would. The flow loses the near road at motorway
            speeds (KITTI 06 at 3.6 m per frame: 0-23 road ACs a frame), its pixels remain.
        ground_image_max_speed: the vehicle's top speed (m/s): the longest step the road's
            pixels are searched for is this times the frames' interval (when the longest
            step searched fits best, a warning asks whether the vehicle is faster; a measured
            speed above it widens the search to twice that speed, with a warning).
    """

    source: typing.Literal['speed', 'ground', 'fixed', 'unit'] = 'ground'
    fallback: typing.Literal['hold', 'ground', 'fixed', 'unit'] = 'hold'
    hold_acceleration_std: float = bounded(1.0, 0.0, 1e3, low_open=True, high_open=True,
                                           expected='a positive rate of change of speed (m/s^2)')
    speed_std: float = bounded(0.1, 0.0, low_open=True, expected='a positive speed in m/s')
    speed_max_gap: float = bounded(0.5, 0.0, 1e6, low_open=True, high_open=True,
                                   expected='a positive duration in seconds')
    fixed_speed: float = bounded(10.0, 0.0, expected='a non-negative speed in m/s')
    fixed_speed_std: float = bounded(3.0, 0.0, low_open=True, expected='a positive speed in m/s')
    ground_min_correspondences: int = bounded(10, 1)
    ground_max_depth: float = bounded(30.0, 0.0, low_open=True, expected='a positive number')
    ground_point_std: float = bounded(1.0, 0.0, low_open=True, expected='a positive number')
    ground_affine_std: float = bounded(0.03, 0.0, low_open=True, expected='a positive number')
    ground_gate: float = bounded(3.0, 0.0, low_open=True, expected='a positive number')
    ground_lateral_std: float = bounded(
        3.5, 0.0, expected='a non-negative distance in m (0: no lateral weighting)')
    ground_normal_std: float = bounded(0.00349, 0.0, 0.1, high_open=True,
                                       expected='an angle in [0, 0.1) rad')
    ground_normal_frames: int = bounded(200, 2)
    ground_normal_acs: int = bounded(60, 10)
    ground_normal_refit: int = bounded(10, 1)
    ground_top_up: bool = True
    ground_image: bool = True
    ground_image_max_speed: float = bounded(70.0, 0.0, 1e3, low_open=True,
                                            expected='a positive speed in m/s, at most 1000')


@dataclasses.dataclass(frozen=True)
class OdometryConfig(Options):
    """Frame checks and the parts of the pose that planar motion does not estimate.

    Attributes:
        min_correspondences: fewer ACs than this drop the frame (too_few_correspondences).
        min_contrast: grey-level standard deviation below which a frame is blank.
        max_lost_frames: after this many frames in a row without an update, tracking is
            restarted at the next usable frame (the pose is extrapolated and its covariance
            grows); after two frames in a row with some but too few correspondences with the
            keyframe (they moved away from it), the next frame that finds some but too few too
            starts the new chain itself.
        max_frame_gap: the longest plausible interval between consecutive frames (s): a frame
            stamped further ahead is refused as a clock glitch unless the next frame confirms
            the new time, which then restarts tracking.
        max_time_jump_back: a stamp further back than this (s) is refused unless the next
            frame confirms the older time, which then resets tracking (a looped bag, a
            restarted clock); a smaller step back is a frame out of order.
        output: ``'3d'`` (the full pose: the vehicle follows hills, with roll and pitch) or
            ``'flat'`` (x, y and yaw; z, roll and pitch zero, and their rates in the twist:
            for ground robots).
        flat_z_std, flat_tilt_std: with ``output: flat``, the standard deviations (m, rad)
            of the flat-world assumption given to the dropped z and roll/pitch (their
            estimates' variances and squares are added: the zero is off by that much).
        lost_speed_std, lost_turn_rate_std: while tracking is lost the pose is extrapolated
            at the last velocity (over the wheel speed's distance when there is one, straight
            ahead from a standstill); its standard deviation grows by this much speed (m/s) and
            turn rate (rad/s) per second of the gap, and, without the wheels' distance, along
            the last velocity by a third of what braking at ``max_deceleration`` would fall
            short of the extrapolated travel (a t^2 / 2 until the stop). The last velocity's
            own uncertainty is carried over the gap too: before any motion was measured it is
            unknown, and so is the travel across such a gap (the pose held, its covariance
            huge).
        turn_rate_time_constant: the extrapolated turn rate decays with this time constant
            (s): a long gap does not spin the pose; the travel follows the decaying turn, the
            yaw's standard deviation grows by the turn the decay leaves out (the rate going
            on), the position's by the offset of the travel if the turn went on.
        repeated_images: an image identical to the previous one, pixel for pixel, is
            ``'auto'``: a stop when the vehicle could have stopped (below; a simulator renders
            a standing vehicle's frames alike), else a frozen camera's; ``'frozen'``: always a
            frozen camera's (a real camera, whose noise never repeats an image: catches a
            freeze at low speed, or while the speed is uncertain, e.g. the focal length still
            being calibrated, which ``'auto'`` takes for a stop). An image identical to one of
            the 8 frames before the previous one, within their usual time, is a republished old
            image, with ``'auto'`` after a motion step (a simulator's scene may repeat while the
            vehicle stands).
        max_deceleration: the hardest braking of the vehicle (m/s^2; about 1 g for a car on
            dry asphalt). A real sensor's noise differs from frame to frame, so a frame
            identical to the one before it, pixel for pixel, shows a vehicle that stands (a
            simulator renders those alike) only if it could have stopped: while wheel speed
            samples up to the frame say it moved since the previous frame, or when the last
            measured motion step's velocity (the mean over its interval, the speed at its
            middle), less three standard deviations, exceeds this deceleration times the time
            since that middle, the frame
            is a frozen camera's (a stalled driver republishing its last image, a duplicated
            frame of a raw or losslessly coded video; a lossy codec's duplicates differ and
            read as a stop), counted as ``frozen_image`` and lost for tracking, and so are the
            identical frames after it. A higher value judges fewer frames frozen and widens
            the pose's covariance across lost frames more (see ``lost_speed_std``).
        window_lags: keyframe pairs measured per new keyframe: 1 tracks frame to frame; D > 1
            also matches each new keyframe against the D - 1 kept keyframes before the
            previous one (a front-end run and a refinement each) and solves the orientations of
            the last ``window_size`` keyframes jointly, causally (published poses are never
            revised; `planar_vo.pipeline.window`). It helps where the estimator's own noise
            dominates the drift, and costs time per lag.
        window_size: keyframes whose orientations the window solves (the oldest held).
    """

    min_correspondences: int = bounded(30, 1)
    min_contrast: float = bounded(2.0, 0.0, expected='a non-negative grey level')
    max_lost_frames: int = bounded(5, 1)
    max_frame_gap: float = bounded(10.0, 0.0, 1e9, low_open=True, high_open=True,
                                   expected='a positive duration in seconds')
    max_time_jump_back: float = bounded(1.0, 0.0, 1e9, high_open=True,
                                        expected='a non-negative duration in seconds')
    output: typing.Literal['3d', 'flat'] = '3d'
    flat_z_std: float = bounded(0.05, 0.0, 1e6, low_open=True, high_open=True,
                                expected='a positive length (m)')
    flat_tilt_std: float = bounded(0.02, 0.0, 10.0, low_open=True, high_open=True,
                                   expected='a positive angle (rad)')
    lost_speed_std: float = bounded(1.0, 0.0, 1e3, low_open=True, high_open=True,
                                    expected='a positive speed (m/s)')
    lost_turn_rate_std: float = bounded(0.05, 0.0, 10.0, low_open=True, high_open=True,
                                        expected='a positive turn rate (rad/s)')
    turn_rate_time_constant: float = bounded(2.0, 0.0, 1e4, low_open=True, high_open=True,
                                             expected='a positive duration (s)')
    repeated_images: typing.Literal['auto', 'frozen'] = 'auto'
    max_deceleration: float = bounded(10.0, 0.0, 1e4, low_open=True, high_open=True,
                                      expected='a deceleration (m/s^2) between 0 and 1e4')
    window_lags: int = bounded(1, 1, 5)
    window_size: int = bounded(6, 2, 50)


@dataclasses.dataclass(frozen=True)
class RosConfig(Options):
    """ROS interface of the node.

    Attributes:
        odom_frame, base_frame: REP-105 frame ids of the published pose.
        publish_tf: broadcast ``odom -> base_frame`` (needs ``tf2_ros``).
        image_transport: ``'raw'`` (``image``) or ``'compressed'`` (``image/compressed``).
        speed_topic_type: ``'twist'`` (``geometry_msgs/TwistStamped``) or ``'odometry'``.
        path_max_length: poses kept in the published ``nav_msgs/Path`` (the oldest are
            dropped): bounds its memory and its publishing cost (about 10 us per pose).
        path_spacing: a pose joins the path once it is this far (m) from the last one kept (0:
            every odometry pose); the path always ends at the latest pose.
        path_period: the path is published at most once per this many seconds of image time
            (0: with every odometry message); with the two above this bounds its cost per
            frame (500 poses once per second: about 0.5 ms per frame at 10 Hz).
        warn_period: seconds between repeats of the same warning.
        diagnostics_period: seconds between ``/diagnostics`` messages.
        image_timeout: warn when no image has arrived for this many seconds.
    """

    odom_frame: str = 'odom'
    base_frame: str = 'base_link'
    publish_tf: bool = True
    image_transport: typing.Literal['raw', 'compressed'] = 'raw'
    speed_topic_type: typing.Literal['twist', 'odometry'] = 'twist'
    path_max_length: int = bounded(500, 1, 1_000_000)
    path_spacing: float = bounded(1.0, 0.0, expected='a non-negative distance (m)')
    path_period: float = bounded(1.0, 0.0, expected='a non-negative number of seconds')
    warn_period: float = bounded(5.0, 0.0, expected='a non-negative number of seconds')
    # Bounded both ways (a user test: 1e-6 s kept a core busy; 1e10 s overflowed rclpy's
    # timer, which crashed the node on a run-time change).
    diagnostics_period: float = bounded(1.0, 0.05, 3600.0,
                                        expected='a period of 0.05-3600 seconds')
    image_timeout: float = bounded(5.0, 0.1, 86400.0,
                                   expected='a timeout of 0.1-86400 seconds (a day)')

    def validate(self) -> None:
        # tf2 refuses frame ids with a leading slash; whitespace makes ids that look equal
        # differ.
        for name in ('odom_frame', 'base_frame'):
            frame = getattr(self, name)
            self._require(bool(frame) and not frame.startswith('/')
                          and not any(c.isspace() for c in frame), name,
                          'a frame id without a leading slash or whitespace, e.g. odom')
        self._require(self.odom_frame != self.base_frame, 'base_frame', 'a frame id other than '
                      'odom_frame')


@dataclasses.dataclass(frozen=True)
class PlanarVoConfig(Options):
    """The whole configuration (``config/planar_vo.yaml``)."""

    camera: CameraConfig = dataclasses.field(default_factory=CameraConfig)
    mount: MountConfig = dataclasses.field(default_factory=MountConfig)
    frontend: FrontendConfig = dataclasses.field(default_factory=FrontendConfig)
    voting: VotingConfig = dataclasses.field(default_factory=VotingConfig)
    estimator: EstimatorConfig = dataclasses.field(default_factory=EstimatorConfig)
    keyframe: KeyframeConfig = dataclasses.field(default_factory=KeyframeConfig)
    scale: ScaleConfig = dataclasses.field(default_factory=ScaleConfig)
    odometry: OdometryConfig = dataclasses.field(default_factory=OdometryConfig)
    ros: RosConfig = dataclasses.field(default_factory=RosConfig)

    @classmethod
    def from_flat(cls, flat: typing.Mapping[str, Any]) -> PlanarVoConfig:
        """Build from dotted keys (``{'voting.bins': 720}``), the form of ROS parameters."""
        if not isinstance(flat, typing.Mapping):
            raise ConfigError(f'config: expected a mapping of dotted keys, got '
                              f'{type(flat).__name__}')
        return cls.from_dict(nest_dotted(dict(flat)))
