"""Affine correspondences from ASIFT features (the ``'asift'`` method; the paper's source).

ASIFT (Morel and Yu, "ASIFT: a new framework for fully affine invariant image comparison", SIAM
J. Imaging Sciences 2009) runs SIFT on simulated views of each image: view ``i`` rotates the
image by ``phi_i`` and compresses its x axis by the tilt ``t_i``, i.e. maps image coordinates by
the linear part ``P_i = diag(1/t_i, 1) R(phi_i)``. ``cv2.AffineFeature`` returns each keypoint in
original image coordinates with ``class_id = i`` but keeps the SIFT scale ``s`` and angle
``theta`` of the simulated view, so the keypoint's local affine frame in the original image is

    F = P_i^-1 s R(theta)          (R(theta) = [[cos, -sin], [sin, cos]], y down, theta in degrees)

and a match between keypoints with frames ``F1`` and ``F2`` gives the AC ``A = F2 F1^-1`` (the
construction of Barath and Hajder's papers). The view parameters are set explicitly
(``setViewParams``) because the Python binding of ``getViewParams`` returns nothing.

Slow by design: about 1.6 s per image on this CPU (SIFT on 43 views), plus matching; use it for
offline comparison, not on a live camera.
"""

from __future__ import annotations

import logging

import cv2
import numpy as np

from planar_vo.config import FrontendConfig
from planar_vo.core.correspondences import AffineCorrespondences

__all__ = ['ASIFTExtractor', 'asift_views', 'keypoint_frames']

logger = logging.getLogger(__name__)


def asift_views(max_tilt: int = 5, tilt_step: float = float(np.sqrt(2.0)),
                rotate_step_base: float = 72.0) -> tuple[np.ndarray, np.ndarray]:
    """The standard ASIFT view sampling (Morel and Yu 2009, section 4.2).

    Tilts ``t = tilt_step^k`` for ``k = 0..max_tilt``; for each ``t > 1`` the rolls
    ``phi = j * rotate_step_base / t`` degrees in ``[0, 180)``; ``t = 1`` has the single roll 0.

    Returns:
        ``tilts, rolls`` (degrees), each ``(V,)``; 43 views with the defaults.
    """
    tilts, rolls = [1.0], [0.0]
    for k in range(1, max_tilt + 1):
        t = tilt_step ** k
        step = rotate_step_base / t
        count = int(np.ceil(180.0 / step - 1e-9))     # rolls j * step < 180
        tilts += [t] * count
        rolls += [j * step for j in range(count)]
    return np.array(tilts), np.array(rolls)


def keypoint_frames(keypoints, tilts: np.ndarray, rolls: np.ndarray) -> tuple[np.ndarray,
                                                                              np.ndarray]:
    """Points and local affine frames ``F = P_i^-1 s R(theta)`` of ASIFT keypoints.

    Args:
        keypoints: sequence of ``cv2.KeyPoint`` from ``cv2.AffineFeature`` (``class_id`` = view).
        tilts, rolls: the view parameters (`asift_views`), rolls in degrees.

    Returns:
        ``points`` ``(N, 2)`` and ``frames`` ``(N, 2, 2)`` in original image pixels.
    """
    n = len(keypoints)
    if n == 0:
        return np.zeros((0, 2)), np.zeros((0, 2, 2))
    data = np.array([(k.pt[0], k.pt[1], k.size, k.angle, k.class_id) for k in keypoints])
    view = data[:, 4].astype(np.int64)
    t = tilts[view]
    phi = np.deg2rad(rolls[view])
    theta = np.deg2rad(data[:, 3])
    # P^-1 = R(-phi) diag(t, 1).
    cp, sp = np.cos(phi), np.sin(phi)
    Pinv = np.stack([np.stack([cp * t, sp], -1), np.stack([-sp * t, cp], -1)], -2)
    ct, st = np.cos(theta), np.sin(theta)
    S = data[:, 2, None, None] * np.stack([np.stack([ct, -st], -1), np.stack([st, ct], -1)], -2)
    return data[:, :2], Pinv @ S


class ASIFTExtractor:
    """ASIFT affine correspondences (slow; faithful to the paper).

    Args:
        config: front-end configuration: ``match_ratio`` (Lowe's ratio test) and
            ``max_correspondences`` (the best matches by ratio are kept).
    """

    def __init__(self, config: FrontendConfig) -> None:
        self.config = config
        self.tilts, self.rolls = asift_views()
        self._detector = cv2.AffineFeature_create(cv2.SIFT_create())
        self._detector.setViewParams(self.tilts.astype(np.float32).tolist(),
                                     self.rolls.astype(np.float32).tolist())
        self._matcher = cv2.FlannBasedMatcher({'algorithm': 1, 'trees': 4}, {'checks': 64})
        self.stats: dict[str, float] = {}

    def extract(self, gray1: np.ndarray, gray2: np.ndarray) -> AffineCorrespondences:
        """ACs from image 1 to image 2 (grey ``uint8``, same size), pixels.

        Weights are ``1 - ratio / match_ratio`` in ``(0, 1]``: distinctive matches count more.
        Duplicates (the same point pair found in several simulated views) are merged, keeping
        the most distinctive.
        """
        kp1, d1 = self._detector.detectAndCompute(gray1, None)
        kp2, d2 = self._detector.detectAndCompute(gray2, None)
        self.stats = {'candidates': float(min(len(kp1), len(kp2))), 'accepted': 0.0}
        empty = AffineCorrespondences(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros((0, 2, 2)))
        if d1 is None or d2 is None or len(kp1) < 2 or len(kp2) < 2:
            return empty
        matches = self._matcher.knnMatch(d1, d2, k=2)
        pairs = np.array([(m[0].queryIdx, m[0].trainIdx, m[0].distance / max(m[1].distance,
                                                                             1e-12))
                          for m in matches if len(m) == 2])
        if len(pairs) == 0:
            return empty
        good = pairs[pairs[:, 2] < self.config.match_ratio]
        good = good[np.argsort(good[:, 2], kind='stable')]
        q, t = good[:, 0].astype(np.int64), good[:, 1].astype(np.int64)
        p1, F1 = keypoint_frames([kp1[i] for i in q], self.tilts, self.rolls)
        p2, F2 = keypoint_frames([kp2[i] for i in t], self.tilts, self.rolls)
        # Merge duplicates: same point pair to within half a pixel; the first (best ratio) wins.
        key = np.round(np.concatenate([p1, p2], axis=1) * 2.0).astype(np.int64)
        _, first = np.unique(key, axis=0, return_index=True)
        first = np.sort(first)[:self.config.max_correspondences]
        A = F2[first] @ np.linalg.inv(F1[first])
        weights = 1.0 - good[first, 2] / self.config.match_ratio
        self.stats['accepted'] = float(len(first))
        return AffineCorrespondences(p1[first], p2[first], A, weights)
