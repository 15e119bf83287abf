"""Peer estimators wrapped in planar_vo's conventions, for comparisons and benchmarks.

- `estimate_5pc_opencv`: OpenCV's five-point pipeline (``findEssentialMat`` with RANSAC, then
  ``recoverPose``), the estimator most monocular VO code uses.

Each returns the general pose and its projection onto planar motion ``(alpha, beta)``
(`planar_vo.geometry.planar_motion_from_pose`), so errors are measured the same way for all.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planar_vo._checks import as_array, same_length
from planar_vo.geometry.planar import planar_motion_from_pose

__all__ = ['PoseEstimate', 'estimate_5pc_opencv']


@dataclass(frozen=True)
class PoseEstimate:
    """A relative pose ``X2 = R X1 + t`` from a peer estimator.

    Attributes:
        alpha, beta: planar projection of the pose (radians); NaN if the estimator failed.
        R: rotation (3x3), t: unit translation (3,); NaN-filled on failure.
        inliers: bool mask over the input correspondences, shape ``(N,)``.
    """

    alpha: float
    beta: float
    R: np.ndarray
    t: np.ndarray
    inliers: np.ndarray

    @property
    def ok(self) -> bool:
        """Whether the estimator returned a pose."""
        return bool(np.isfinite(self.alpha) and np.isfinite(self.beta))


def _failed(n: int) -> PoseEstimate:
    return PoseEstimate(np.nan, np.nan, np.full((3, 3), np.nan), np.full(3, np.nan),
                        np.zeros(n, dtype=bool))


def estimate_5pc_opencv(q1: np.ndarray, q2: np.ndarray, *, threshold: float = 1e-3,
                        confidence: float = 0.999, max_iters: int = 1000,
                        ransac: bool = True) -> PoseEstimate:
    """OpenCV's five-point relative pose (``findEssentialMat`` + ``recoverPose``).

    Args:
        q1, q2: normalised image coordinates, shape ``(N, 2)``, ``N >= 5``.
        threshold: RANSAC inlier threshold in normalised units (pixels / focal length).
        confidence: RANSAC confidence.
        max_iters: RANSAC iteration cap.
        ransac: if False, use least median of squares (no threshold).

    Returns:
        A `PoseEstimate`; NaN angles (``ok`` False) when OpenCV finds no essential matrix.
    """
    import cv2

    q1 = as_array('q1', q1, (None, 2), min_items=5)
    q2 = as_array('q2', q2, (None, 2), min_items=5)
    n = same_length(q1=q1, q2=q2)
    method = cv2.RANSAC if ransac else cv2.LMEDS
    E, mask = cv2.findEssentialMat(q1, q2, np.eye(3), method=method, prob=confidence,
                                   threshold=threshold, maxIters=max_iters)
    if E is None or E.shape[0] < 3:
        return _failed(n)
    # With few points OpenCV may stack several candidate matrices; recoverPose takes the first.
    E = E[:3]
    mask = np.ones((n, 1), np.uint8) if mask is None else mask
    _, R, t, pose_mask = cv2.recoverPose(E, q1, q2, np.eye(3), mask=mask.copy())
    t = t.ravel()
    alpha, beta = planar_motion_from_pose(R, t)
    inliers = (pose_mask.ravel() > 0) if pose_mask is not None else mask.ravel() > 0
    return PoseEstimate(float(alpha), float(beta), R, t / np.linalg.norm(t), inliers)
