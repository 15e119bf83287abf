"""The step length from the road's pixels where too few road ACs measure it.

(``scale.ground_image``.) With the motion's rotation ``R`` and direction ``t``
(`MotionEstimator`), the road normal ``n`` and the camera height ``h`` known, the road's image
motion between two frames is the homography ``H(s) = R + (s / h) t n^T`` (`road_scale`'s model)
of the step length ``s`` alone. A fast car leaves the optical flow few road ACs (the near road
moves by a hundred pixels and more and stretches between frames; README Findings), but its
pixels still say ``s``:

1. Blocks of road ahead in image 2 (whole blocks whose rays meet the road within
   ``max_depth`` and within ``lateral_std`` of the line of travel; at most 128, evenly
   picked), image 1 sampled where ``H(s)^-1`` maps their pixels, on images shrunk to at most
   320 pixels wide and smoothed (a distorted camera's images undistorted first).
2. Coarse: the blocks' mean normalised cross-correlation, scanned over ``s`` across the given
   range and a quarter of it beyond, in steps that move the blocks by about a shrunk pixel each
   (5 to 200 steps, none where no block stays in image 1); its best ``s`` must be inside the
   range and clearly better than the typical ``s`` more than 4 steps from it
   (``min_contrast``).
3. Fine: at the next resolution (half the shrink, at least full resolution), each block's own
   correlation over two coarse steps either side in steps four times finer, its peak (a
   parabola through the best three) its step ``s_b`` when it correlates at least
   ``min_ncc``.
4. The blocks' weighted mean (weight: how far a block moves in the image per metre of step,
   squared, times the lateral weight of `road_scale`) after a 3-MAD clip of the blocks'
   disagreement in pixels, its standard deviation from their scatter. Each block is a
   correspondence ``(H(s_b)^-1 q2_b, q2_b)`` of the road: a point's match moves along its
   epipolar line as ``s`` does, so it holds whatever road normal was assumed, and the pipeline
   measures the step from the blocks as from road ACs (`VisualOdometry._image_road_step`: the
   pair's own road normal, every variance term).

Measured through the pipeline (dev script, the scan run on every frame beside the road ACs,
its own motion and road normal, each step against the ground truth's): KITTI 05's first 120
frames -1.1 % mean and 3.6 % RMS error (the road ACs -0.3 % and 4.6 %); every 3rd frame of KITTI
05 -0.3 % and 5.7 % (6.7 %), every 4th -0.4 % and 6.1 % (7.7 %); the KITTI 06 excerpt +2.0 %
and 2.8 % (+1.9 % and 3.3 %), every 3rd frame of it (3.6 m per frame, road ACs for 2 of 16
steps) +4.5 % and 6.2 %. The answer does not depend on the range searched (two KITTI 05 pairs,
ranges from 5 to 310 m: 3.804 and 3.678 m each time). A scan costs about 10 ms at KITTI size.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from planar_vo.core.camera import CameraModel
from planar_vo.core.checks import as_array, as_rotation
from planar_vo.core.robust.stats import MAD_TO_SIGMA, median, weighted_median
from planar_vo.errors import ConfigError, InputError
from planar_vo.pipeline.scale import _sensitivities, _step_terms

__all__ = ['ImageRoadScale', 'image_road_scale', 'pixels_note']

# Working widths: the coarse scan's images at most this wide, the fine stage's at twice it.
_COARSE_WIDTH = 320
# Block side in samples at either stage (a block is this many shrunk pixels square).
_BLOCK = 8
# Smoothing (shrunk pixels) of both images before sampling: widens the correlation's basin.
_BLUR = 1.0
# Rays at least this far below the horizon (n . Q) at every corner of a block.
_MIN_ELEVATION = 0.02
# The fine stage: this many coarse steps either side of the coarse answer, this many fine
# steps to each.
_FINE_SPAN, _FINE_SPLIT = 2, 4
# At least and at most this many steps in the coarse scan, and at most this many blocks in
# either scan; the scan goes this share of the range beyond it (a best step there: none); the
# contrast is judged against the steps more than this many from the best.
_MIN_STEPS, _MAX_STEPS = 5, 200
_MARGIN = 0.25
_NEAR = 4
_MAX_BLOCKS = 128
# The fastest block's track over the range, sampled at this many steps to space the scan.
_TRACK = 512


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
            ok &= (depth <= max_depth) & (np.abs(lateral) <= lateral_std)
        keep = np.flatnonzero(ok)
        if keep.size > _MAX_BLOCKS:
            # Evenly over the road (row-major order): a tall image or a camera pitched down
            # sees many more blocks, and a scan's cost grows with them.
            keep = keep[np.linspace(0, keep.size - 1, _MAX_BLOCKS).astype(np.intp)]
        self.corner = np.column_stack([gx[keep], gy[keep]])  # top-left (full pixels)
        self.size = size
        self.q2 = q[keep]                                   # block centres, normalised
        self.weight = np.exp(-0.5 * (lateral[keep] / lateral_std) ** 2)

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
        """Normalised points of image 2 ``(..., 2)`` -> pixels of image 1 under ``H(s)`` (NaN
        behind camera 1): for every step ``(S,)`` ``(S, ..., 2)``, or with ``each`` one step
        per point (``(B,)`` steps, ``(B, 2)`` points) ``(B, 2)``."""
        M = self.camera.K @ self.inverses(steps)                 # K H(s)^-1 (undistorted)
        Q = np.concatenate([q2, np.ones(q2.shape[:-1] + (1,))], axis=-1)
        if each:
            P = (M @ Q[:, :, None])[:, :, 0]
        else:
            P = (Q.reshape(-1, 3) @ M.transpose(0, 2, 1)).reshape((len(M),) + Q.shape)
        with np.errstate(invalid='ignore', divide='ignore'):
            p = P[..., :2] / P[..., 2:]
        p[P[..., 2] <= 0] = np.nan                                # behind camera 1
        return p


@functools.lru_cache(maxsize=4)
def _undistortion(width: int, height: int, K: tuple, model: str, D: tuple
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Maps for `cv2.remap` from a distorted camera's image to the undistorted one of the same
    size and intrinsics (OpenCV's, whose models are ROS's: ``plumb_bob`` and
    ``rational_polynomial`` its standard one, ``equidistant`` its fisheye one; read-only
    float32, a few cameras kept)."""
    Km = np.array(K, dtype=np.float64).reshape(3, 3)
    if model == 'equidistant':
        mx, my = cv2.fisheye.initUndistortRectifyMap(Km, np.array(D[:4]), np.eye(3), Km,
                                                     (width, height), cv2.CV_32FC1)
    else:
        mx, my = cv2.initUndistortRectifyMap(Km, np.array(D), np.eye(3), Km, (width, height),
                                             cv2.CV_32FC1)
    mx.flags.writeable = my.flags.writeable = False
    return mx, my


def _undistorted(camera: CameraModel, *images: np.ndarray) -> tuple[CameraModel, list]:
    """An undistorted camera of the same size and intrinsics, and the images seen by it
    (unchanged without distortion)."""
    if not camera.is_distorted:
        return camera, list(images)
    K = tuple(float(x) for x in camera.K.ravel())
    mx, my = _undistortion(camera.width, camera.height, K, camera.distortion_model,
                           tuple(float(x) for x in camera.D))
    pinhole = CameraModel(camera.width, camera.height, camera.K)
    return pinhole, [cv2.remap(image, mx, my, cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_CONSTANT, borderValue=0)
                     for image in images]


def _correlations(image1: np.ndarray, values2: np.ndarray, pixels1: np.ndarray,
                  factor: int) -> np.ndarray:
    """Normalised cross-correlation ``(S, B)`` of each block's samples of image 2
    (``values2`` ``(B, m)``) with image 1 (shrunk by ``factor``) at ``pixels1`` ``(S, B, m, 2)``
    (full-resolution pixels); NaN where a sample falls outside image 1."""
    S, B, m, _ = pixels1.shape
    xy = _shrunk(pixels1, factor).reshape(1, -1, 2)
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
                     min_contrast: float = 0.1) -> ImageRoadScale:
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
            distance ``x`` (m) from the line of travel, none beyond ``lateral_std`` (positive;
            unlike road ACs, blocks pass no test of being road: the kerbs, parked cars and
            verges beside the road made the steps 12 % long on KITTI 05 with blocks out to
            three lane widths).
        min_blocks: fewer blocks give no answer.
        min_ncc: a block counts when its correlation peaks at least this high.
        min_contrast: the coarse scan's best mean cost (1 - correlation) must lie this far
            below its median over the steps scanned more than 4 steps from it (on KITTI 05,
            129 pairs at 1x, 3x and 4x speed, a review: right answers at least 0.111 below the
            median over the whole scan; false peaks of a range short of the true step, before
            the scan went beyond the range, up to 0.088).

    Returns:
        An `ImageRoadScale` (``reason`` set and ``scale`` NaN without an answer).

    Raises:
        InputError: images not 8-bit grey of the camera's size, ``camera`` not a
            `CameraModel`, ``R`` not a rotation, ``t`` or ``n`` not a non-zero 3-vector.
        ConfigError: a non-positive ``height``, ``max_depth`` or ``lateral_std``, or
            ``min_blocks`` below 1.
    """
    camera, R, t, n, height = _checked(gray1, gray2, camera, R, t, n, height, max_depth,
                                       lateral_std, min_blocks)
    low, high = (float(x) for x in steps)
    if not (math.isfinite(high) and high > max(low, 0.0) and low >= 0.0):
        return _failed(f'no range of steps ({low}, {high})')
    camera, (gray1, gray2) = _undistorted(camera, gray1, gray2)
    coarse = max(1, math.ceil(camera.size[0] / _COARSE_WIDTH))
    fine = max(1, coarse // 2)
    road = _Road(camera, R, t, n, height, max_depth, lateral_std, coarse)
    if len(road.q2) < min_blocks:
        return _failed(f'{len(road.q2)} road blocks in view')
    # -- coarse scan over the range and a margin beyond it (`_MARGIN`): steps that move the
    # fastest block by a shrunk pixel -----------------------------------------------------------
    grid = _scan_steps(road, low, high + _MARGIN * (high - low), coarse)
    if not len(grid):
        return _failed('no road block stays in image 1 over the range of steps')
    if np.count_nonzero(grid <= high) < _MIN_STEPS:
        return _failed(f'the range of steps ({low:.3g}, {high:.3g} m) moves the road by less than '
                       f'{_MIN_STEPS} pixels')
    shrunk = functools.lru_cache(maxsize=None)(lambda i, f: _shrink((gray1, gray2)[i], f))

    def correlations(steps: np.ndarray, factor: int, spacing: int) -> np.ndarray:
        # The blocks' samples every `spacing` full pixels, on the images shrunk by `factor`
        # (made once per factor: at full resolution both stages use the same).
        p2, q2 = road.samples(spacing)
        return _correlations(shrunk(0, factor), _sample(shrunk(1, factor), p2, factor),
                             road.to_image1(q2, steps), factor)

    ncc = correlations(grid, coarse, 2 * coarse)
    # A block whose samples leave image 1 or meet no texture there (the far road near the
    # horizon, where long steps take them) says nothing at that step: no correlation.
    seen = np.isfinite(ncc).any(axis=0)
    if seen.sum() < min_blocks:
        return _failed(f'{int(seen.sum())} road blocks seen in both images')
    cost = (1.0 - np.nan_to_num(ncc[:, seen], nan=0.0)).mean(axis=1)
    k = int(np.argmin(cost))
    # The typical cost away from the best step (more than `_NEAR` steps from it: a tight range
    # holds mostly steps near the peak, whose costs would make a right answer look unclear, a
    # review: 19 of 50 KITTI 05 pairs at a 12 m/s top speed).
    far = np.abs(np.arange(len(grid)) - k) > _NEAR
    contrast = float(median(cost[far] if np.count_nonzero(far) >= _NEAR else cost) - cost[k])
    if contrast < min_contrast:
        return _failed(f'no clear best step (contrast {contrast:.3f})', contrast)
    if k == 0:
        return _failed(f'the best step is the shortest searched ({grid[k]:.3g} m of '
                       f'{low:.3g}-{high:.3g} m)', contrast)
    if grid[k] > high:
        # (in the margin: a step beyond the range fits best; without the margin its best
        # match inside the range could pass as the answer, a review)
        return _failed(f'the best step is the longest searched or beyond ({grid[k]:.3g} m, '
                       f'the range {low:.3g}-{high:.3g} m)', contrast)
    # -- fine: each block around it, at the next resolution ----------------------------------
    span = grid[max(k - _FINE_SPAN, 0)], grid[min(k + _FINE_SPAN, len(grid) - 1)]
    fine_grid = np.linspace(span[0], span[1], 2 * _FINE_SPAN * _FINE_SPLIT + 1)
    ncc = correlations(fine_grid, fine, coarse)
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
    s_b = fine_grid[best[idx]] + np.clip(offset, -0.5, 0.5) * (fine_grid[1] - fine_grid[0])
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


def _checked(gray1, gray2, camera, R, t, n, height, max_depth, lateral_std, min_blocks):
    """The arguments of `image_road_scale` checked (``t``, ``n`` unit, ``height`` a float)."""
    if not isinstance(camera, CameraModel):
        raise InputError(f'camera: expected a CameraModel, got {type(camera).__name__}')
    for name, image in (('gray1', gray1), ('gray2', gray2)):
        shape = getattr(image, 'shape', None)
        if shape != (camera.height, camera.width) or getattr(image, 'dtype', None) != np.uint8:
            raise InputError(f'{name}: expected an 8-bit grey image of the camera\'s size '
                             f'{camera.width}x{camera.height}, got '
                             f'{getattr(image, "dtype", type(image).__name__)} {shape}')
    R = as_rotation('R', R)
    unit = []
    for name, value in (('t', t), ('n', n)):
        v = as_array(name, value, (3,))
        norm = float(np.linalg.norm(v))
        if not norm > 0.0:
            raise InputError(f'{name}: expected a non-zero direction, got {v.tolist()}')
        unit.append(v / norm)
    for name, value in (('height', height), ('max_depth', max_depth),
                        ('lateral_std', lateral_std)):
        if not (isinstance(value, (int, float, np.floating, np.integer))
                and math.isfinite(value) and value > 0):
            raise ConfigError(f'{name}: expected a positive number, got {value!r}')
    if not (isinstance(min_blocks, (int, np.integer)) and min_blocks >= 1):
        raise ConfigError(f'min_blocks: expected an integer of at least 1, got {min_blocks!r}')
    return camera, R, unit[0], unit[1], float(height)


def _scan_steps(road: _Road, low: float, high: float, coarse: int) -> np.ndarray:
    """The coarse scan's steps from ``low`` to ``high`` (both included, positive only): spaced
    so that the blocks' image motion from each step to the next is at most one shrunk pixel
    (the fastest block still in image 1 at each point of the range: the image motion per metre
    falls as the step grows for a camera looking ahead, and rises as the road leaves the view
    for one looking back), between `_MIN_STEPS` and `_MAX_STEPS` steps."""
    dense = np.linspace(low, high, _TRACK)
    tracks = road.to_image1(road.q2, dense)                                  # (T, B, 2)
    width, rows = road.camera.size
    with np.errstate(invalid='ignore'):
        inside = ((tracks[..., 0] >= 0) & (tracks[..., 0] <= width - 1)
                  & (tracks[..., 1] >= 0) & (tracks[..., 1] <= rows - 1))
        moves = np.linalg.norm(np.diff(tracks, axis=0), axis=-1)           # (T-1, B)
    both = inside[1:] & inside[:-1]
    moves[~both | ~np.isfinite(moves)] = 0.0
    seen = np.flatnonzero(both.any(axis=1))
    if not seen.size:
        return np.zeros(0)
    # (up to the last step any block is seen at: beyond it the road has left image 1)
    dense, moves = dense[:seen[-1] + 2], moves[:seen[-1] + 1]
    arc = np.concatenate([[0.0], np.cumsum(moves.max(axis=1))]) / coarse
    if not arc[-1] > 0:
        return np.zeros(0)
    count = int(np.clip(math.ceil(arc[-1] - 1e-9), _MIN_STEPS - 1, _MAX_STEPS - 1))
    grid = np.interp(np.linspace(0.0, arc[-1], count + 1), arc, dense)     # ends included
    return grid[grid > 0]


def _sample(image: np.ndarray, pixels: np.ndarray, factor: int) -> np.ndarray:
    """``image`` (shrunk by ``factor``) at full-resolution ``pixels`` ``(B, m, 2)``: ``(B, m)``."""
    return _remap(image, _shrunk(pixels, factor).reshape(-1, 2)).reshape(pixels.shape[:2])


def _shrunk(pixels: np.ndarray, factor: int) -> np.ndarray:
    """Full-resolution pixel coordinates in an image shrunk by ``factor`` (`_shrink`'s
    INTER_AREA: pixel centres), float32 for `cv2.remap`."""
    return ((pixels + 0.5) / factor - 0.5).astype(np.float32)


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


def pixels_note(steps: int, misses: dict[str, int],
                examples: dict[str, str] | None = None) -> str:
    """``'; N ground steps from the road's pixels; M scans of the road's pixels found no step,
    most often (K): reason'`` for summaries (`VisualOdometry.image_road_steps`,
    ``image_road_misses`` and, to show a reason as it was first said rather than its key,
    ``image_road_examples``), each part only when there is any; empty if neither."""
    note = ''
    if steps:
        note += f"; {steps} ground step{'s' if steps > 1 else ''} from the road's pixels"
    total = sum(misses.values())
    if total:
        key, count = max(misses.items(), key=lambda item: item[1])
        why = (examples or {}).get(key, key)
        note += (f"; {total} scan{'s' if total > 1 else ''} of the road's pixels found no step"
                 + (f', most often ({count}):' if len(misses) > 1 else ':') + f' {why}')
    return note
