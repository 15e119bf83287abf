"""What the visual-odometry pipeline returns for every input frame (no ROS types).

Every frame yields a `FrameResult`: either an odometry update (``ok``) or a reason why not, from
`DropReason`, so nothing is silently lost; the node and replay count and log those reasons. The
first frame after start-up or a reset (``VisualOdometry.reset``, the node's ``~/reset``) has no
motion to report, but its pose is the origin itself: it yields odometry too
(`FrameResult.has_odometry`). A time jump back also restarts at the origin, but stays a counted
drop (``time_jump_back``, warned about) that publishes nothing.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

import numpy as np

__all__ = ['DropReason', 'FrameResult', 'TrackingState', 'unit_note']


class DropReason(str, enum.Enum):
    """Why a frame produced no odometry update (stable keys for counters and logs); all but
    ``first_frame`` (the origin's odometry, `FrameResult.has_odometry`) are frames without
    odometry."""

    FIRST_FRAME = 'first_frame'            # initialises the pipeline; nothing to compare with yet
    #                                        (its pose, the origin, is still published)
    REINITIALISED = 'reinitialised'        # a new keyframe chain after lost tracking, a new
    #                                        time base or a camera model change
    TIME_JUMP_AHEAD = 'time_jump_ahead'    # stamped implausibly far ahead (a clock glitch)
    TIME_JUMP_BACK = 'time_jump_back'      # stamped far back (looped bag, clock restart): reset
    NO_CAMERA_INFO = 'no_camera_info'      # no usable intrinsics yet (none, refused, or of
    #                                        another image size), no focal self-calibration
    BAD_IMAGE = 'bad_image'                # undecodable, unsupported encoding, wrong size
    BAD_STAMP = 'bad_stamp'                # the stamp is no time: not a finite number, or a ROS
    #                                        stamp out of range (negative, nanosec of a second
    #                                        or more, beyond 2038)
    BLANK_IMAGE = 'blank_image'            # black, saturated or textureless
    FROZEN_IMAGE = 'frozen_image'          # the previous frame again, pixel for pixel, while
    #                                        moving (a stalled camera republishing its image)
    SIZE_CHANGED = 'size_changed'          # image size differs from the camera model
    DUPLICATE_STAMP = 'duplicate_stamp'    # same timestamp as the previous frame, or far sooner
    #                                        after it than the usual interval (mis-stamped)
    OUT_OF_ORDER = 'out_of_order'          # older than the previous frame
    TOO_FEW_CORRESPONDENCES = 'too_few_correspondences'
    UNRELIABLE = 'unreliable'              # estimator flagged the motion (ambiguous, few inliers)
    PIPELINE_ERROR = 'pipeline_error'      # an unexpected exception inside the pipeline


class TrackingState(str, enum.Enum):
    """The pipeline's tracking state after a frame (stable keys for status and logs)."""

    INITIALISING = 'initialising'          # no keyframe yet (first frame, no camera model)
    TRACKING = 'tracking'                  # frames are tracked against the keyframe chain
    LOST = 'lost'                          # the last frame(s) could not be tracked
    REINITIALISED = 'reinitialised'        # a new keyframe chain started at this frame


@dataclass(frozen=True)
class FrameResult:
    """The outcome of one input frame.

    Attributes:
        stamp: image timestamp in seconds.
        ok: the pose was updated from this frame.
        reason: why not (None when ``ok``).
        message: human-readable detail for logs.
        keyframe: this frame became the new reference keyframe.
        pose: ``T_odom_base`` (4x4) after this frame (the last known pose when not ``ok``); in 3D,
            or flat (x, y, yaw) with ``odometry.output: flat``.
        pose_covariance: 6x6 covariance of the pose, REP-103 order (x, y, z, roll, pitch, yaw):
            position in ``odom`` and small rotations about its axes.
        twist: body-frame velocity ``(vx, vy, vz, wx, wy, wz)`` in ``base_link``.
        twist_covariance: 6x6 covariance of ``twist``.
        scale_source: where the step length came from: ``'speed'``, ``'ground'``, ``'fixed'``,
            ``'hold'`` (the last metric speed, its uncertainty growing), ``'stationary'``, or
            ``'unit'`` (no metric scale: a unit step whose covariance says it is unknown).
        scale_from: for a ``'ground'`` step, what measured it: ``'road ACs'`` or ``"road
            pixels"`` (`scale.ground_image`); empty otherwise.
        num_correspondences, num_inliers: ACs extracted and accepted.
        alpha, beta: the camera motion since the reference keyframe (radians; NaN if none).
        timings: seconds spent per stage (``'decode'``, ``'correspondences'``, ``'solve'``, ...).
        tracking: the tracking state after this frame.
        camera_pose: ``T_world_camera`` (4x4) after this frame, world = the camera frame at the
            start of the trajectory (the KITTI convention of camera poses).
    """

    stamp: float
    ok: bool
    pose: np.ndarray
    pose_covariance: np.ndarray
    twist: np.ndarray = field(default_factory=lambda: np.zeros(6))
    twist_covariance: np.ndarray = field(default_factory=lambda: np.eye(6) * 1e6)
    reason: DropReason | None = None
    message: str = ''
    keyframe: bool = False
    scale_source: str = 'unit'
    scale_from: str = ''
    num_correspondences: int = 0
    num_inliers: int = 0
    alpha: float = float('nan')
    beta: float = float('nan')
    timings: dict[str, float] = field(default_factory=dict)
    tracking: TrackingState = TrackingState.INITIALISING
    camera_pose: np.ndarray = field(default_factory=lambda: np.eye(4))

    @property
    def has_odometry(self) -> bool:
        """The frame yields an odometry message: an update (``ok``), or the first frame after
        start-up or a reset (``first_frame``), whose pose is the origin that sets ``odom``
        (covariance zero by definition, but for a flat output's assumed z and tilt; twist
        unknown). A consumer then has ``odom -> base_link`` from the first image on, and an
        evaluation matches every frame."""
        return self.ok or self.reason is DropReason.FIRST_FRAME


def unit_note(sources: dict[str, int]) -> str:
    """``'N of M without a metric length: their positions are in steps, not metres'`` for the
    step lengths by source (``FrameResult.scale_source`` counts), or ``''`` with no unit step
    (a user test: 'unit 50' alone read like a success)."""
    unit = sources.get('unit', 0)
    if not unit:
        return ''
    return (f'{unit} of {sum(sources.values())} without a metric length: their positions are '
            f'in steps, not metres')
