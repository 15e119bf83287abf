"""Keyframes: the reference views the frames are tracked against.

A frame becomes the new keyframe once its parallax to the current one reaches
``keyframe.min_parallax`` (or after ``keyframe.max_interval`` frames): small baselines carry
little information, and a slow or stopped vehicle does not accumulate noise. The last few
keyframes are kept (bounded) for the calibrations that pair the current view with an older one
(the focal length needs a turn between the views).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

from planar_vo.pipeline.clock import seconds_between, shift_stamp

__all__ = ['Keyframe', 'KeyframeChain']


@dataclass
class Keyframe:
    """One reference view.

    Attributes:
        image: 8-bit grey ``(H, W)``.
        stamp: seconds; moved forward while the vehicle stands still (no motion since).
        pose: ``T_world_camera`` (4, 4), world = the first camera frame of the chain.
        covariance: 6x6 right-perturbation covariance of ``pose`` (``[phi, rho]``).
        index: running number of the keyframe in the chain.
        bias: ``(3,)`` the position error (m, world frame) one standard deviation of the
            steps' shared scale errors makes (`VisualOdometry._road_step`).
        tilt_gain: ``(6, 3)`` how an error of the levelling's vertical (the mount tilt the
            estimator takes as vertical; a direction error in the camera frame) has moved its
            orientation (rows 0-2, world frame) and position (rows 3-5)
            (`VisualOdometry._tilt_covariance`).
        focal_sums: ``(9, 3)`` sums along the chain (world frame) that give the pose error a
            self-calibrated focal length made (`VisualOdometry._focal_covariance`).
        age: frames tracked against it so far.
        matched: a later frame found correspondences with it; False until one does (a
            keyframe that two frames in a row cannot match is dropped: see
            `VisualOdometry._lost_frame`).
        misses: frames since it that found too few correspondences with it.
        contrast: its grey-level standard deviation (subsampled): a keyframe far dimmer than
            the one before it (an exposure glitch) is why frames cannot match it.
    """

    image: np.ndarray
    stamp: float
    pose: np.ndarray
    covariance: np.ndarray
    index: int
    bias: np.ndarray = field(default_factory=lambda: np.zeros(3))
    tilt_gain: np.ndarray = field(default_factory=lambda: np.zeros((6, 3)))
    focal_sums: np.ndarray = field(default_factory=lambda: np.zeros((9, 3)))
    age: int = 0
    matched: bool = True
    misses: int = 0
    contrast: float = 0.0


class KeyframeChain:
    """The current keyframe and the few before it (at most ``keep``).

    Args:
        keep: keyframes kept (the current one included).
    """

    def __init__(self, keep: int = 6) -> None:
        self._frames: deque[Keyframe] = deque(maxlen=max(1, int(keep)))
        self._count = 0

    def __len__(self) -> int:
        return len(self._frames)

    @property
    def current(self) -> Keyframe | None:
        """The keyframe frames are tracked against (None after `clear`)."""
        return self._frames[-1] if self._frames else None

    def add(self, image: np.ndarray, stamp: float, pose: np.ndarray,
            covariance: np.ndarray, bias: np.ndarray | None = None,
            tilt_gain: np.ndarray | None = None,
            focal_sums: np.ndarray | None = None) -> Keyframe:
        """Make a view the new keyframe."""
        frame = Keyframe(image, stamp, pose.copy(), covariance.copy(), self._count,
                         np.zeros(3) if bias is None else np.array(bias, dtype=np.float64),
                         np.zeros((6, 3)) if tilt_gain is None else
                         np.array(tilt_gain, dtype=np.float64),
                         np.zeros((9, 3)) if focal_sums is None else
                         np.array(focal_sums, dtype=np.float64))
        frame.contrast = float(image[::8, ::8].std())
        self._count += 1
        self._frames.append(frame)
        return frame

    @property
    def next_index(self) -> int:
        """The running number the next keyframe will get."""
        return self._count

    def find(self, index: int) -> Keyframe | None:
        """The kept keyframe with this running number, or None."""
        for frame in self._frames:
            if frame.index == index:
                return frame
        return None

    @property
    def previous(self) -> Keyframe | None:
        """The keyframe before the current one, if kept."""
        return self._frames[-2] if len(self._frames) >= 2 else None

    def drop_current(self) -> None:
        """Go back to the keyframe before the current one (`previous`, which must exist)."""
        if len(self._frames) < 2:
            raise ValueError('drop_current: no keyframe before the current one')
        self._frames.pop()

    def shift_stamps(self, first: float, seconds: float) -> None:
        """Move the stamps of the keyframes stamped at or after ``first`` back by ``seconds``
        (they were stamped ahead of their time)."""
        for frame in self._frames:
            if seconds_between(frame.stamp, first) >= 0.0:
                frame.stamp = shift_stamp(frame.stamp, seconds)

    def clear(self) -> None:
        """Drop every keyframe (the next usable frame starts a new chain)."""
        self._frames.clear()
