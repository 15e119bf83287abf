"""The step length from the road's pixels where too few road ACs measure it.

(``scale.ground_image``.) With the motion's rotation ``R`` and direction ``t``
(`MotionEstimator`), the road normal ``n`` and the camera height ``h`` known, the road's image
motion between two frames is the homography ``H(s) = R + (s / h) t n^T`` (`road_scale`'s model)
of the step length ``s`` alone. A fast car leaves the optical flow few road ACs (the near road
moves by a hundred pixels and more and stretches between frames; README Findings), but its
pixels still say ``s``:

1. Blocks of road ahead in image 2 (whole blocks whose rays meet the road within
   ``max_depth`` and within ``lateral_std`` of the line of travel), image 1 sampled where
   ``H(s)^-1`` maps their pixels, on images shrunk to about 320 pixels wide and smoothed.
2. Coarse: the blocks' mean normalised cross-correlation, scanned over ``s`` across the given
   range in steps that move the fastest block by a shrunk pixel; its best ``s`` must be inside
   the range and clearly better than the typical ``s`` (``min_contrast``).
3. Fine: at twice that resolution, each block's own correlation over four times finer steps
   around it, its peak (a parabola through the best three) its step ``s_b`` when it correlates
   at least ``min_ncc``.
4. The blocks' weighted mean (weight: how far a block moves in the image per metre of step,
   squared, times the lateral weight of `road_scale`) after a 3-MAD clip of the blocks'
   disagreement in pixels, its standard deviation from their scatter. Each block is a
   correspondence ``(H(s_b)^-1 q2_b, q2_b)`` of the road: a point's match moves along its
   epipolar line as ``s`` does, so it holds whatever road normal was assumed, and the pipeline
   measures the step from the blocks as from road ACs (`VisualOdometry._image_road_step`: the
   pair's own road normal, every variance term).

Measured through the pipeline (dev script, the scan run on every frame beside the road ACs,
its own motion and road normal, each step against the ground truth's): KITTI 05's first 120
frames -1.0 % mean and 3.6 % RMS error (the road ACs -0.3 % and 4.6 %); every 3rd frame of KITTI
05 -0.3 % and 5.3 % (6.8 %); the KITTI 06 excerpt +2.4 % and 3.1 % (+1.9 % and 3.3 %), every
3rd frame of it (3.6 m per frame, road ACs for 2 of 16 steps) +5.3 % and 6.2 %. Errors over
the stated standard deviations have an RMS of 1.1-1.8 (the road ACs' 0.7-1.3): the pipeline
uses the blocks only where the road ACs are too few. A scan costs 8.6-11.9 ms (median; its
length grows with the range of steps).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from planar_vo.core.camera import CameraModel
from planar_vo.core.robust.stats import MAD_TO_SIGMA, median, weighted_median
from planar_vo.pipeline.scale import _sensitivities, _step_terms

__all__ = ['ImageRoadScale', 'image_road_scale']

# Working widths: the coarse scan's images at most this wide, the fine stage's at twice it.
_COARSE_WIDTH = 320
# Block side in samples at either stage (a block is this many shrunk pixels square).
_BLOCK = 8
# Smoothing (shrunk pixels) of both images before sampling: widens the correlation's basin.
_BLUR = 1.0
# Rays at least this far below the horizon (n . Q) at every corner of a block.
_MIN_ELEVATION = 0.02
# The fine stage: one coarse step either side of the coarse answer, in this many steps each.
_FINE_SPLIT = 4
# At most this many steps in the coarse scan.
_MAX_STEPS = 200


@dataclass(frozen=True)
class ImageRoadScale:
    """The step length from the road's pixels (`image_road_scale`).

    Attributes:
        scale: step length in metres (NaN without an answer: ``reason`` says why).
        std: its statistical standard deviation (m): the blocks' scatter (inf without).
        blocks: blocks that measured it.
        d_rotation: ``(3,)`` ds/d(omega) (m/rad), `RoadScale`'s sense.
        d_normal: ``(2,)`` ds/d(pitch, roll) (m/rad) of the road normal.
        contrast: the coarse scan's typical minus best mean correlation cost.
        reason: ``''``, or why there is no answer.
        q1, q2: ``(G, 2)`` the blocks as road correspondences, normalised: ``q2`` a block's
            centre in image 2, ``q1 = H(s_b)^-1 q2`` where it matched (the point's depth,
            whatever the road normal assumed: the scan moves it along its epipolar line).
        A: ``(G, 2, 2)`` the road homography's Jacobian at each (their affines).
        weights: ``(G,)`` the blocks' precisions (their image motion per metre of step,
            squared; the largest 1), without the lateral weight.
    """

    scale: float
    std: float
    blocks: int
    d_rotation: np.ndarray
    d_normal: np.ndarray
    contrast: float
    reason: str = ''
    q1: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    q2: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    A: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 2)))
    weights: np.ndarray = field(default_factory=lambda: np.zeros(0))


def _failed(reason: str, contrast: float = 0.0) -> ImageRoadScale:
    return ImageRoadScale(math.nan, math.inf, 0, np.zeros(3), np.zeros(2), contrast, reason)


def _shrink(gray: np.ndarray, factor: int) -> np.ndarray:
    small = gray if factor == 1 else cv2.resize(
        gray, (gray.shape[1] // factor, gray.shape[0] // factor), interpolation=cv2.INTER_AREA)
    return cv2.GaussianBlur(small.astype(np.float32), (0, 0), _BLUR)


class _Road:
    """The road blocks of image 2 and the mapping of their samples into image 1."""

    def __init__(self, camera: CameraModel, R, t, n, height, max_depth, lateral_std, coarse):
        self.camera, self.R, self.t, self.n, self.h = camera, R, t, n, height
        size = _BLOCK * coarse                              # block side (full pixels)
        width, rows = camera.size
        n2 = R @ n                                          # the road normal in camera 2
        side = np.cross(n2, t)
        side /= max(float(np.linalg.norm(side)), 1e-12)
        x0 = np.arange(0, width - size + 1, size, dtype=np.float64)
        y0 = np.arange(0, rows - size + 1, size, dtype=np.float64)
        gx, gy = np.meshgrid(x0, y0)
        gx, gy = gx.ravel(), gy.ravel()
        ok = np.ones(gx.size, bool)
        for dx, dy in ((0, 0), (size - 1, 0), (0, size - 1), (size - 1, size - 1)):
            q, _ = camera.pixel_to_normalized(np.column_stack([gx + dx, gy + dy]))
            with np.errstate(invalid='ignore'):
                ok &= np.isfinite(q).all(axis=1) & (q @ n2[:2] + n2[2] >= _MIN_ELEVATION)
        centre = np.column_stack([gx, gy]) + (size - 1) / 2.0
        q, _ = camera.pixel_to_normalized(centre)
        with np.errstate(invalid='ignore', divide='ignore'):
            lam = height / (q @ n2[:2] + n2[2])
            X = lam[:, None] * np.column_stack([q, np.ones(len(q))])
            depth = np.linalg.norm(X, axis=1)
            lateral = X @ side
            ok &= (depth <= max_depth) & (np.abs(lateral) <= lateral_std
                                          if lateral_std > 0 else True)
        self.corner = np.column_stack([gx[ok], gy[ok]])     # top-left (full pixels)
        self.size = size
        self.q2 = q[ok]                                     # block centres, normalised
        self.weight = (np.exp(-0.5 * (lateral[ok] / lateral_std) ** 2) if lateral_std > 0
                       else np.ones(int(ok.sum())))

    def samples(self, spacing: int) -> tuple[np.ndarray, np.ndarray]:
        """Per block, sample pixels every ``spacing`` full pixels (full-resolution
        coordinates, centred in the block) ``(B, m, 2)`` and their normalised coordinates."""
        per = max(1, self.size // spacing)
        k = (np.arange(per) + 0.5) * (self.size / per) - 0.5
        ox, oy = np.meshgrid(k, k)
        offsets = np.column_stack([ox.ravel(), oy.ravel()])
        p = self.corner[:, None, :] + offsets[None]
        q, _ = self.camera.pixel_to_normalized(p.reshape(-1, 2))
        return p, q.reshape(p.shape)

    def inverses(self, steps: np.ndarray) -> np.ndarray:
        """``H(s)^-1`` ``(S, 3, 3)`` for the steps ``(S,)`` (Sherman-Morrison)."""
        a = np.asarray(steps, dtype=np.float64) / self.h
        RT = self.R.T
        u, v = RT @ self.t, self.n @ RT
        gain = a / (1.0 + a * float(self.n @ u))
        return RT[None] - gain[:, None, None] * np.outer(u, v)[None]

    def to_image1(self, q2: np.ndarray, steps: np.ndarray, each: bool = False) -> np.ndarray:
        """Normalised points of image 2 ``(..., 2)`` -> pixels of image 1 under ``H(s)``: for
        every step ``(S,)`` ``(S, ..., 2)``, or with ``each`` one step per point
        (``(B,)`` steps, ``(B, 2)`` points) ``(B, 2)``."""
        Hinv = self.inverses(steps)
        Q = np.concatenate([q2, np.ones(q2.shape[:-1] + (1,))], axis=-1)
        if each:
            Q1 = (Hinv @ Q[:, :, None])[:, :, 0]
        else:
            Q1 = (Q.reshape(-1, 3) @ Hinv.transpose(0, 2, 1)).reshape(
                (len(Hinv),) + Q.shape)
        with np.errstate(invalid='ignore', divide='ignore'):
            q1 = Q1[..., :2] / Q1[..., 2:]
        q1[Q1[..., 2] <= 0] = np.nan                        # behind camera 1
        return _pixels(self.camera, q1)


def _pixels(camera: CameraModel, q: np.ndarray) -> np.ndarray:
    """Normalised ``(..., 2)`` -> pixels (``camera.normalized_to_pixel`` without its Jacobian
    for an undistorted camera)."""
    if camera.is_distorted:
        return camera.normalized_to_pixel(q.reshape(-1, 2))[0].reshape(q.shape)
    K = camera.K
    return q @ K[:2, :2].T + K[:2, 2]


def _correlations(image1: np.ndarray, values2: np.ndarray, pixels1: np.ndarray,
                  factor: int) -> np.ndarray:
    """Normalised cross-correlation ``(S, B)`` of each block's samples of image 2
    (``values2`` ``(B, m)``) with image 1 (shrunk by ``factor``) at ``pixels1`` ``(S, B, m, 2)``
    (full-resolution pixels); NaN where a sample falls outside image 1."""
    S, B, m, _ = pixels1.shape
    xy = ((pixels1 + 0.5) / factor - 0.5).astype(np.float32).reshape(1, -1, 2)
    rows, cols = image1.shape
    with np.errstate(invalid='ignore'):
        inside = ((xy[..., 0] >= 0) & (xy[..., 0] <= cols - 1) & (xy[..., 1] >= 0)
                  & (xy[..., 1] <= rows - 1)).reshape(S, B, m)
    w = _remap(image1, np.nan_to_num(xy[0], nan=-1.0)).reshape(S, B, m)
    g = values2 - values2.mean(axis=1, keepdims=True)
    g /= np.maximum(np.sqrt((g * g).sum(axis=1, keepdims=True)), 1e-9)
    w -= w.mean(axis=2, keepdims=True)
    norm = np.sqrt((w * w).sum(axis=2))
    ncc = np.einsum('sbm,bm->sb', w, g) / np.maximum(norm, 1e-9)
    ncc[~inside.all(axis=2) | (norm < 1e-6)] = np.nan
    return ncc


def image_road_scale(gray1: np.ndarray, gray2: np.ndarray, camera: CameraModel,
                     R: np.ndarray, t: np.ndarray, n: np.ndarray, height: float, *,
                     steps: tuple[float, float], max_depth: float = 30.0,
                     lateral_std: float = 3.5, min_blocks: int = 8, min_ncc: float = 0.5,
                     min_contrast: float = 0.05) -> ImageRoadScale:
    """The step length ``s`` (m) of ``X2 = R X1 + s t`` from the road's pixels (module
    docstring).

    Args:
        gray1, gray2: 8-bit grey images of camera 1 and 2, ``camera``'s size.
        camera: the camera model (distortion included).
        R, t: relative rotation and translation direction (camera 1 -> 2; ``t`` normalised
            here).
        n: road normal in camera 1 (pointing down; normalised here); ``height``: camera
            height (m).
        steps: ``(low, high)``, the range of plausible steps (m) the scan covers: e.g. from 0
            to the vehicle's top speed times the frames' interval, or around a known speed's.
        max_depth: road farther along the ray (m) is not used.
        lateral_std: blocks weighted by ``exp(-x^2 / (2 lateral_std^2))`` of their lateral
            distance ``x`` (m) from the line of travel, none beyond ``lateral_std`` (unlike
            road ACs, blocks pass no test of being road: the kerbs, parked cars and verges
            beside the road made the steps 12 % long on KITTI 05 with blocks out to three
            lane widths); 0: all alike, no limit.
        min_blocks: fewer blocks give no answer.
        min_ncc: a block counts when its correlation peaks at least this high.
        min_contrast: the coarse scan's best mean cost (1 - correlation) must lie this far
            below its median over the range.

    Returns:
        An `ImageRoadScale` (``reason`` set and ``scale`` NaN without an answer).
    """
    t = np.asarray(t, dtype=np.float64) / float(np.linalg.norm(t))
    n = np.asarray(n, dtype=np.float64) / float(np.linalg.norm(n))
    low, high = (float(x) for x in steps)
    if not (math.isfinite(high) and high > max(low, 0.0) and low >= 0.0):
        return _failed(f'no range of steps ({low}, {high})')
    coarse = max(1, int(round(camera.size[0] / _COARSE_WIDTH)))
    fine = max(1, coarse // 2)
    road = _Road(camera, R, t, n, float(height), max_depth, lateral_std, coarse)
    if len(road.q2) < min_blocks:
        return _failed(f'{len(road.q2)} road blocks in view')
    # -- coarse scan over the range: steps that move the fastest block by a shrunk pixel ------
    ends = road.to_image1(road.q2, np.array([low, high]))
    with np.errstate(invalid='ignore'):
        travel = np.nanmax(np.linalg.norm(ends[1] - ends[0], axis=-1)) / coarse
    if not (math.isfinite(travel) and travel > 0):
        return _failed('the road does not move')
    count = int(min(max(math.ceil(travel), 8), _MAX_STEPS))
    delta = (high - low) / count
    grid = low + delta * np.arange(count + 1)
    grid = grid[grid > 0]
    p2, q2 = road.samples(2 * coarse)
    small1 = _shrink(gray1, coarse)
    ncc = _correlations(small1, _sample(_shrink(gray2, coarse), p2, coarse),
                        road.to_image1(q2, grid), coarse)
    complete = np.isfinite(ncc).all(axis=0)
    if complete.sum() < min_blocks:
        return _failed(f'{int(complete.sum())} road blocks seen in both images')
    cost = (1.0 - ncc[:, complete]).mean(axis=1)
    k = int(np.argmin(cost))
    contrast = float(median(cost) - cost[k])
    if (k == 0 and grid[0] > 0) or k == len(grid) - 1:
        return _failed('the best step lies at the end of the range', contrast)
    if contrast < min_contrast:
        return _failed(f'no clear best step (contrast {contrast:.3f})', contrast)
    # -- fine: each block around it, at twice the resolution ----------------------------------
    split = _FINE_SPLIT
    fine_grid = grid[k] + delta / split * np.arange(-split, split + 1)
    fine_grid = fine_grid[fine_grid > 0]
    p2, q2 = road.samples(coarse)
    ncc = _correlations(_shrink(gray1, fine), _sample(_shrink(gray2, fine), p2, fine),
                        road.to_image1(q2, fine_grid), fine)
    best = np.argmax(np.nan_to_num(ncc, nan=-2.0), axis=0)
    cols = np.arange(ncc.shape[1])
    peak = ncc[best, cols]
    good = ((best > 0) & (best < len(fine_grid) - 1) & (peak >= min_ncc)
            & np.isfinite(ncc).all(axis=0))
    idx = np.flatnonzero(good)
    if idx.size < min_blocks:
        return _failed(f'{idx.size} road blocks correlate', contrast)
    y0, y1, y2 = ncc[best[idx] - 1, idx], peak[idx], ncc[best[idx] + 1, idx]
    curv = y0 - 2.0 * y1 + y2
    offset = np.where(curv < 0, 0.5 * (y0 - y2) / np.where(curv < 0, curv, -1.0), 0.0)
    s_b = fine_grid[best[idx]] + np.clip(offset, -0.5, 0.5) * (delta / split)
    # -- the step: blocks as road correspondences ---------------------------------------------
    centre = road.q2[idx]
    eps = 1e-3 * high
    ahead = road.to_image1(centre, s_b + eps, each=True)
    speed = np.linalg.norm(ahead - road.to_image1(centre, s_b - eps, each=True),
                           axis=1) / (2.0 * eps)                     # pixels per metre
    w = road.weight[idx] * speed ** 2
    z = (s_b - weighted_median(s_b, w)) * speed
    keep = np.abs(z) <= 3.0 * (MAD_TO_SIGMA * median(np.abs(z)) + 1e-12)
    if keep.sum() < min_blocks:
        return _failed(f'{int(keep.sum())} road blocks agree', contrast)
    s_b, w, centre = s_b[keep], w[keep], centre[keep]
    W = float(w.sum())
    scale = float((w * s_b).sum() / W)
    G = s_b.size
    std = math.sqrt(float(((w * (s_b - scale)) ** 2).sum()) / W ** 2 * G / max(G - 1, 1))
    # Each block as a correspondence of the road: q1 = H(s_b)^-1 q2 (normalised).
    Q1 = (road.inverses(s_b) @ np.column_stack([centre, np.ones(G)])[:, :, None])[:, :, 0]
    q1 = Q1[:, :2] / Q1[:, 2:]
    u1, v1, u2, v2 = q1[:, 0], q1[:, 1], centre[:, 0], centre[:, 1]
    r, b, bb, _ = _step_terms(u1, v1, u2, v2, R, t)
    dn = n[0] * u1 + n[1] * v1 + n[2]
    d_rot, d_normal = _sensitivities(w / W, height / dn, r, b, bb, u2, v2, s_b, q1, dn, n)
    # The road homography's Jacobian at each block (the affine of its correspondence).
    H = np.linalg.inv(road.inverses(s_b))
    Q1 = np.column_stack([q1, np.ones(G)])
    hz = np.einsum('bj,bj->b', H[:, 2], Q1)
    A = (H[:, :2, :2] - centre[:, :, None] * H[:, 2:3, :2]) / hz[:, None, None]
    precision = speed[keep] ** 2
    return ImageRoadScale(scale, std, G, d_rot, d_normal, contrast, '', q1, centre, A,
                          precision / precision.max())


def _sample(image: np.ndarray, pixels: np.ndarray, factor: int) -> np.ndarray:
    """``image`` (shrunk by ``factor``) at full-resolution ``pixels`` ``(B, m, 2)``: ``(B, m)``."""
    xy = ((pixels + 0.5) / factor - 0.5).astype(np.float32).reshape(-1, 2)
    return _remap(image, xy).reshape(pixels.shape[:2])


# cv2.remap takes maps of fewer than 32767 columns and rows: points in rows of this many.
_ROW = 4096


def _remap(image: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """``image`` bilinearly at the points ``xy`` ``(N, 2)`` (float32; border replicated)."""
    count = xy.shape[0]
    rows = max(1, -(-count // _ROW))
    grid = np.full((rows * _ROW, 2), -1.0, np.float32)
    grid[:count] = xy
    grid = grid.reshape(rows, _ROW, 2)
    v = cv2.remap(image, grid[..., 0], grid[..., 1], cv2.INTER_LINEAR,
                  borderMode=cv2.BORDER_REPLICATE)
    return v.reshape(-1)[:count].astype(np.float64)
