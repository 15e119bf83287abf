"""Affine correspondences from KLT tracks (the ``'klt'`` method).

Shi-Tomasi corners (``cv2.goodFeaturesToTrack``) are tracked by pyramidal Lucas-Kanade
(``cv2.calcOpticalFlowPyrLK``, Bouguet's implementation of Lucas and Kanade 1981), checked by
tracking back (forward-backward error below ``fb_threshold``), and each track's affine comes from
the batched affine Lucas-Kanade of `planar_vo.frontend.affine_lk`, started at ``A = I`` on a
two-level pyramid so that foreshortened ground patches still converge.
"""

from __future__ import annotations

import logging

import cv2
import numpy as np

from planar_vo.config import FrontendConfig
from planar_vo.core.correspondences import AffineCorrespondences
from planar_vo.frontend.affine_lk import MAX_STEP, refine_correspondences

__all__ = ['KLTExtractor']

logger = logging.getLogger(__name__)

_LK_WINDOW = (21, 21)
_LK_LEVELS = 3
_LK_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01)
# Shi-Tomasi quality relative to the best corner of the frame.
_CORNER_QUALITY = 0.01


class KLTExtractor:
    """KLT-track affine correspondences.

    Args:
        config: front-end configuration (`FrontendConfig`): ``max_correspondences`` corners at
            least ``grid_step`` pixels apart; ``patch_radius``, ``patch_stride``,
            ``lk_iterations`` and ``max_residual`` for the affine refinement; ``fb_threshold``.
    """

    _PYRAMID_LEVELS = 2

    def __init__(self, config: FrontendConfig) -> None:
        self.config = config
        self.stats: dict[str, float] = {}

    def extract(self, gray1: np.ndarray, gray2: np.ndarray) -> AffineCorrespondences:
        """ACs from image 1 to image 2 (grey ``uint8``, same size), pixels; weights in ``[0, 1]``.

        Weights are those of the affine refinement (`refine_correspondences`); with
        ``refine_affine`` off, ``A`` is the identity and the weights are 1.
        """
        cfg = self.config
        h, w = gray1.shape
        # At pyramid level 1 the patch (same radius in pixels) covers twice the distance.
        margin = 2 * (cfg.patch_radius + 1)
        mask = np.zeros_like(gray1)
        mask[margin:h - margin, margin:w - margin] = 255
        corners = cv2.goodFeaturesToTrack(gray1, cfg.max_correspondences, _CORNER_QUALITY,
                                          cfg.grid_step, mask=mask)
        empty = AffineCorrespondences(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros((0, 2, 2)))
        self.stats = {'candidates': 0.0, 'fb_consistent': 0.0, 'accepted': 0.0}
        if corners is None:
            return empty
        # Even integer centres: the half-resolution level then samples the same template grid.
        p1 = (2 * np.round(corners.reshape(-1, 2) / 2.0)).astype(np.int64)
        p1 = np.clip(p1, margin, [w - 1 - margin, h - 1 - margin])
        pts1 = p1.astype(np.float32).reshape(-1, 1, 2)
        pts2, status, _ = cv2.calcOpticalFlowPyrLK(gray1, gray2, pts1, None, winSize=_LK_WINDOW,
                                                   maxLevel=_LK_LEVELS, criteria=_LK_CRITERIA)
        ok = status.ravel() == 1
        self.stats['candidates'] = float(len(p1))
        if cfg.fb_threshold > 0.0 and ok.any():
            back, status_b, _ = cv2.calcOpticalFlowPyrLK(
                gray2, gray1, pts2, pts1.copy(), winSize=_LK_WINDOW, maxLevel=_LK_LEVELS,
                criteria=_LK_CRITERIA, flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
            fb = np.linalg.norm(back.reshape(-1, 2) - pts1.reshape(-1, 2), axis=1)
            ok &= (status_b.ravel() == 1) & (fb < cfg.fb_threshold)
        p1 = p1[ok]
        p2 = pts2.reshape(-1, 2)[ok].astype(np.float64)
        self.stats['fb_consistent'] = float(len(p1))
        if len(p1) == 0:
            return empty
        A = np.broadcast_to(np.eye(2), (len(p1), 2, 2)).copy()
        if cfg.refine_affine:
            refined = refine_correspondences(gray1, gray2, p1, p2, A, radius=cfg.patch_radius,
                                             stride=cfg.patch_stride,
                                             iterations=cfg.lk_iterations,
                                             max_iterations=cfg.lk_max_iterations,
                                             max_step=MAX_STEP,
                                             max_residual=cfg.max_residual,
                                             levels=self._PYRAMID_LEVELS)
            keep = refined.ok
            acs = AffineCorrespondences(p1[keep].astype(np.float64), refined.p2[keep],
                                        refined.A[keep], refined.weights[keep])
        else:
            acs = AffineCorrespondences(p1.astype(np.float64), p2, A)
        self.stats['accepted'] = float(len(acs))
        return acs
