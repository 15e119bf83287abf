"""Affine correspondences from KLT tracks (the ``'klt'`` method).

Shi-Tomasi corners (``cv2.goodFeaturesToTrack``) are tracked by pyramidal Lucas-Kanade
(``cv2.calcOpticalFlowPyrLK``, Bouguet's implementation of Lucas and Kanade 1981), checked by
tracking back (forward-backward error below ``fb_threshold``), and each track's affine comes from
the batched affine Lucas-Kanade of `planar_vo.frontend.affine_lk`, started at ``A = I`` on a
two-level pyramid so that foreshortened ground patches still converge. `KLTExtractor.extract_more`
adds corners in one region of the last pair (the road ahead, for the ground scale).
"""

from __future__ import annotations

import logging

import cv2
import numpy as np

from planar_vo.config import FrontendConfig
from planar_vo.core.correspondences import AffineCorrespondences
from planar_vo.errors import InputError
from planar_vo.frontend.affine_lk import MAX_STEP, refine_correspondences

__all__ = ['KLTExtractor']

logger = logging.getLogger(__name__)

_LK_WINDOW = (21, 21)
_LK_LEVELS = 3
_LK_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01)
# Shi-Tomasi quality relative to the best corner of the frame (or of the region, `extract_more`).
_CORNER_QUALITY = 0.01
# `extract_more`: the region is sampled on cells of this many pixels.
_REGION_CELL = 8


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
        self._pair: tuple[np.ndarray, np.ndarray] | None = None    # for `extract_more`

    def extract(self, gray1: np.ndarray, gray2: np.ndarray) -> AffineCorrespondences:
        """ACs from image 1 to image 2 (grey ``uint8``, same size), pixels; weights in ``[0, 1]``.

        Weights are those of the affine refinement (`refine_correspondences`); with
        ``refine_affine`` off, ``A`` is the identity and the weights are 1.
        """
        self._pair = None
        self.stats = {'candidates': 0.0, 'fb_consistent': 0.0, 'accepted': 0.0}
        acs = self._track(gray1, gray2, self._corners(gray1, self._inner(gray1.shape)))
        self._pair = (gray1, gray2)
        return acs

    def extract_more(self, select) -> AffineCorrespondences | None:
        """More ACs on the image pair of the last `extract`, in the region ``select`` keeps:
        corners detected there alone (their quality relative to the best corner of the region,
        so a faint road ahead gets corners that the frame's strongest ones outranked), up to
        ``max_correspondences``, tracked and refined as in `extract`.

        For a consumer that needs ACs in one region that the frame's corners left too sparse
        (the ground scale on the road close to a fast car).

        Args:
            select: ``select(points) -> (N,) bool`` for ``(N, 2)`` pixel points of image 1.

        Returns:
            The ACs (pixels), or None before the first `extract`.
        """
        if self._pair is None:
            return None
        gray1, gray2 = self._pair
        h, w = gray1.shape
        # The region as a mask: ``select`` on the centres of _REGION_CELL-pixel cells.
        ys = np.minimum(np.arange(-(-h // _REGION_CELL)) * _REGION_CELL + _REGION_CELL // 2, h - 1)
        xs = np.minimum(np.arange(-(-w // _REGION_CELL)) * _REGION_CELL + _REGION_CELL // 2, w - 1)
        gx, gy = np.meshgrid(xs, ys)
        centres = np.column_stack([gx.ravel(), gy.ravel()]).astype(np.float64)
        keep = np.asarray(select(centres))
        if keep.dtype != bool or keep.shape != (len(centres),):
            raise InputError(f'select: expected a bool mask of shape ({len(centres)},), got '
                             f'{keep.dtype} {keep.shape}')
        cells = keep.reshape(len(ys), len(xs)).astype(np.uint8) * np.uint8(255)
        region = np.repeat(np.repeat(cells, _REGION_CELL, axis=0), _REGION_CELL, axis=1)[:h, :w]
        self.stats = {'candidates': 0.0, 'fb_consistent': 0.0, 'accepted': 0.0}
        return self._track(gray1, gray2, self._corners(gray1, self._inner(gray1.shape) & region))

    @property
    def _margin(self) -> int:
        """Pixels a corner keeps from the border: at pyramid level 1 the patch (same radius in
        pixels) covers twice the distance."""
        return 2 * (self.config.patch_radius + 1)

    def _inner(self, shape: tuple[int, int]) -> np.ndarray:
        """The ``uint8`` mask (255 inside) of corners whose patch fits at pyramid level 1."""
        h, w = shape
        margin = self._margin
        mask = np.zeros(shape, np.uint8)
        mask[margin:h - margin, margin:w - margin] = 255
        return mask

    def _corners(self, gray1: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """At most ``max_correspondences`` Shi-Tomasi corners inside ``mask``, at least
        ``grid_step`` apart, as even integer pixels ``(N, 2)``."""
        cfg = self.config
        if not mask.any():
            return np.zeros((0, 2), np.int64)
        corners = cv2.goodFeaturesToTrack(gray1, cfg.max_correspondences, _CORNER_QUALITY,
                                          cfg.grid_step, mask=mask)
        if corners is None:
            return np.zeros((0, 2), np.int64)
        h, w = gray1.shape
        margin = self._margin
        # Even integer centres: the half-resolution level then samples the same template grid.
        p1 = (2 * np.round(corners.reshape(-1, 2) / 2.0)).astype(np.int64)
        return np.clip(p1, margin, [w - 1 - margin, h - 1 - margin])

    def _track(self, gray1: np.ndarray, gray2: np.ndarray, p1: np.ndarray
               ) -> AffineCorrespondences:
        """Track corners ``p1`` of image 1 into image 2, check them backwards and refine their
        affines; counts in ``self.stats``."""
        cfg = self.config
        empty = AffineCorrespondences(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros((0, 2, 2)))
        if len(p1) == 0:
            return empty
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
