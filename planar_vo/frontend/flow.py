"""Affine correspondences from dense optical flow (the ``'flow'`` method; the default).

1. DIS optical flow (Kroeger et al., ECCV 2016; ``cv2.DISOpticalFlow``) from image 1 to image 2,
   and, for the forward-backward check, from image 2 to image 1.
2. Candidate points on a regular grid: in each ``grid_step`` cell, the pixel with the most
   texture (smaller eigenvalue of the structure tensor), kept if above ``min_texture``. One
   candidate per cell keeps the ACs spread over the image.
3. Forward-backward consistency: ``|F(p1) + B(p1 + F(p1))|`` below ``fb_threshold`` pixels
   rejects occlusions and flow failures.
4. Initial affine: the Jacobian of the flow, ``A = I + dF/dp``, by central differences over
   half a patch.
5. Per-patch affine refinement (`planar_vo.frontend.affine_lk`): inverse-compositional affine
   Lucas-Kanade on all patches at once; its Gauss-Newton covariance gives the quality weights.
6. Ground re-seeding (``ground_reseed``): candidates of the lower image half that failed get a
   second start from a homography fitted to the accepted ACs there (the ground close to the
   car, where DIS fails).
"""

from __future__ import annotations

import logging
import time
from concurrent.futures import Future, ThreadPoolExecutor

import cv2
import numpy as np

from planar_vo.config import FrontendConfig
from planar_vo.correspondences import AffineCorrespondences
from planar_vo.geometry.camera import apply_homography, homography_jacobian
from planar_vo.frontend.affine_lk import (
    MAX_STEP,
    PatchRefinement,
    Template,
    patch_offsets,
    prepare_template,
    refine_affines,
    score_refinement,
    smooth_for_refinement,
)

__all__ = ['DIS_PRESETS', 'FlowExtractor', 'flow_jacobian', 'sample_field', 'texture_grid']

logger = logging.getLogger(__name__)

# Ground re-seeding (`FlowExtractor._reseed_ground`): agreement (pixels) and support of the fit.
_RESEED_FIT_PX = 1.0
_RESEED_MIN_INLIERS = 12
_RESEED_TRIM_ROUNDS = 3
_RESEED_MIN_DEFORMATION = 0.15        # |J_H - I|_F of the predicted local affine
_RESEED_MIN_DISAGREEMENT = 2.0        # pixels between the DIS flow and the prediction
_RESEED_MAX_FIT = 200                 # accepted ACs given to the homography fit
# Below this many patches the refinement runs on the calling thread only.
_PARALLEL_MIN_PATCHES = 256

DIS_PRESETS = {
    'ultrafast': cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST,
    'fast': cv2.DISOPTICAL_FLOW_PRESET_FAST,
    'medium': cv2.DISOPTICAL_FLOW_PRESET_MEDIUM,
}


def _structure_min_eig(gray: np.ndarray) -> np.ndarray:
    """Smaller eigenvalue of the 3x3-averaged structure tensor of the half-resolution image.

    Returned on the half-resolution grid, in (grey levels per full-resolution pixel)^2: the Sobel
    filter is 8x the derivative and a half-resolution pixel spans two pixels, hence ``/ 16``.
    """
    small = cv2.pyrDown(gray)
    gx, gy = cv2.spatialGradient(small)
    gx = gx.astype(np.float32) * np.float32(1.0 / 16.0)
    gy = gy.astype(np.float32) * np.float32(1.0 / 16.0)
    a = cv2.boxFilter(gx * gx, -1, (3, 3))
    b = cv2.boxFilter(gx * gy, -1, (3, 3))
    c = cv2.boxFilter(gy * gy, -1, (3, 3))
    return 0.5 * (a + c) - np.sqrt(0.25 * (a - c) ** 2 + b * b)


def texture_grid(gray: np.ndarray, step: int, margin: int, min_texture: float,
                 max_points: int) -> tuple[np.ndarray, np.ndarray]:
    """Well-spread textured points: the most textured pixel of each ``step x step`` cell.

    Args:
        gray: 8-bit grey image ``(H, W)``.
        step: cell size in pixels (rounded up to an even number: the search runs at half
            resolution); enlarged when the image has more than ``max_points`` cells.
        margin: pixels kept free along the borders.
        min_texture: smaller structure-tensor eigenvalue required, (grey levels / pixel)^2.
        max_points: cap on the number of cells.

    Returns:
        ``points`` ``(N, 2)`` int64 (even coordinates, full resolution) and their texture
        ``(N,)``, in row-major cell order.
    """
    h, w = gray.shape
    area = max(h - 2 * margin, 0) * max(w - 2 * margin, 0)
    step = max(int(step), int(np.ceil(np.sqrt(area / max(max_points, 1)))))
    half = max((step + 1) // 2, 1)
    eig = _structure_min_eig(gray)
    m = (margin + 1) // 2                              # half-resolution margin (even points)
    rows = (eig.shape[0] - 2 * m) // half
    cols = (eig.shape[1] - 2 * m) // half
    # Keep every point's full-resolution margin: 2 * (m + rows*half - 1) <= h - 1 - margin.
    while rows > 0 and 2 * (m + rows * half - 1) > h - 1 - margin:
        rows -= 1
    while cols > 0 and 2 * (m + cols * half - 1) > w - 1 - margin:
        cols -= 1
    if rows <= 0 or cols <= 0:
        return np.zeros((0, 2), np.int64), np.zeros(0)
    cells = eig[m:m + rows * half, m:m + cols * half].reshape(rows, half, cols, half)
    cells = cells.transpose(0, 2, 1, 3).reshape(rows, cols, half * half)
    best = cells.argmax(axis=-1)
    value = np.take_along_axis(cells, best[..., None], axis=-1)[..., 0]
    y = m + np.arange(rows)[:, None] * half + best // half
    x = m + np.arange(cols)[None, :] * half + best % half
    keep = value > min_texture
    points = 2 * np.stack([x[keep], y[keep]], axis=1).astype(np.int64)
    return points, value[keep].astype(np.float64)


def sample_field(field: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Bilinear samples of a 2-channel float32 field ``(H, W, 2)`` at points ``(N, 2)``."""
    if points.shape[0] == 0:
        return np.zeros((0, 2), np.float32)
    xy = points.astype(np.float32).reshape(-1, 1, 2)
    return cv2.remap(field, xy, None, cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE).reshape(-1, 2)


def flow_jacobian(flow: np.ndarray, points: np.ndarray, h: int) -> np.ndarray:
    """Local affines ``A = I + dF/dp`` of a flow field at integer points, by central differences.

    Args:
        flow: ``(H, W, 2)`` flow (image 1 -> image 2 displacement) in pixels.
        points: integer points ``(N, 2)``, at least ``h`` pixels from the border.
        h: half the difference baseline in pixels (DIS flow is smooth at its patch scale).

    Returns:
        ``A`` ``(N, 2, 2)`` with ``A[:, i, j] = d p2_i / d p1_j``.
    """
    x, y = points[:, 0], points[:, 1]
    dx = (flow[y, x + h] - flow[y, x - h]) / (2.0 * h)
    dy = (flow[y + h, x] - flow[y - h, x]) / (2.0 * h)
    return np.eye(2)[None] + np.stack([dx, dy], axis=-1).astype(np.float64)


def _homography_lsq(p1: np.ndarray, p2: np.ndarray) -> np.ndarray | None:
    """Least-squares homography ``p2 ~ H p1`` by the normalised DLT (Hartley and Zisserman 4.4).

    Solved through the 9x9 normal matrix (``cv2.mulTransposed`` and a 9x9 eigen-decomposition)
    rather than an SVD of the 2N x 9 system: a LAPACK SVD on a multi-threaded BLAS took 100 ms on
    a loaded 2-core machine. None when degenerate.
    """
    def similarity(p):
        c = p.mean(axis=0)
        d = float(np.mean(np.linalg.norm(p - c, axis=1)))
        s = np.sqrt(2.0) / max(d, 1e-12)
        return np.array([[s, 0.0, -s * c[0]], [0.0, s, -s * c[1]], [0.0, 0.0, 1.0]])

    T1, T2 = similarity(p1), similarity(p2)
    a = p1 @ T1[:2, :2].T + T1[:2, 2]
    b = p2 @ T2[:2, :2].T + T2[:2, 2]
    n = len(a)
    rows = np.zeros((2 * n, 9))
    rows[:n, 0:2], rows[:n, 2] = a, 1.0
    rows[:n, 6:8], rows[:n, 8] = -b[:, :1] * a, -b[:, 0]
    rows[n:, 3:5], rows[n:, 5] = a, 1.0
    rows[n:, 6:8], rows[n:, 8] = -b[:, 1:] * a, -b[:, 1]
    M = cv2.mulTransposed(rows, True)
    vals, vecs = np.linalg.eigh(M)
    if vals[1] <= 1e-12 * max(vals[-1], 1e-300):
        return None
    H = np.linalg.inv(T2) @ vecs[:, 0].reshape(3, 3) @ T1
    return H / H[2, 2] if abs(H[2, 2]) > 1e-12 else H


def _dominant_homography(p1: np.ndarray, p2: np.ndarray) -> np.ndarray | None:
    """Homography of the dominant plane among point pairs, by trimmed least squares.

    A least-squares fit (`_homography_lsq`) on all pairs, then refits on the pairs within
    ``max(3 x median, 1 px)`` of the previous fit. Cheaper than ``cv2.findHomography`` with
    RANSAC (3-4 ms for 200 pairs here) and enough when the plane holds most pairs, as the ground
    does in the lower half of a driving image. None if fewer than `_RESEED_MIN_INLIERS` pairs
    agree to within `_RESEED_FIT_PX`.
    """
    use = np.ones(len(p1), dtype=bool)
    H = None
    err = np.full(len(p1), np.inf)
    for _ in range(_RESEED_TRIM_ROUNDS):
        if np.count_nonzero(use) < _RESEED_MIN_INLIERS:
            return None
        H = _homography_lsq(p1[use], p2[use])
        if H is None:
            return None
        with np.errstate(divide='ignore', invalid='ignore'):
            err = np.linalg.norm(apply_homography(H, p1) - p2, axis=1)
        err = np.where(np.isfinite(err), err, np.inf)
        use = err <= max(3.0 * float(np.median(err[use])), 1.0)
    if H is None or np.count_nonzero(err <= _RESEED_FIT_PX) < _RESEED_MIN_INLIERS:
        return None
    return H


class FlowExtractor:
    """DIS-flow affine correspondences.

    Keeps the DIS instances between frames (creating one costs more than a flow computation)
    and a small thread pool: the two DIS flows run in worker threads (OpenCV releases the GIL)
    while the calling thread picks the candidates and prepares the refinement's templates,
    which need image 1 only, and the refinement runs in two halves on two threads. With
    ``cv2.setNumThreads(1)`` everything runs on the calling thread.

    Args:
        config: front-end configuration (`FrontendConfig`).
    """

    def __init__(self, config: FrontendConfig) -> None:
        self.config = config
        self._forward = cv2.DISOpticalFlow_create(DIS_PRESETS[config.dis_preset])
        self._backward = cv2.DISOpticalFlow_create(DIS_PRESETS[config.fb_preset])
        self._pool = ThreadPoolExecutor(max_workers=2, thread_name_prefix='planar_vo_dis')
        self.stats: dict[str, float] = {}

    def extract(self, gray1: np.ndarray, gray2: np.ndarray) -> AffineCorrespondences:
        """ACs from image 1 to image 2 (grey ``uint8``, same size), pixels; weights in ``[0, 1]``.

        Per-stage counts and times are left in ``self.stats`` (``candidates``,
        ``fb_consistent``, ``accepted``; ``seconds_candidates`` (grid and templates, overlapped
        with the flows), ``seconds_flow`` (waiting for the flows), ``seconds_refine``).
        """
        cfg = self.config
        stats: dict[str, float] = {}
        clock = [time.perf_counter()]

        def lap(name: str) -> None:
            now = time.perf_counter()
            stats[f'seconds_{name}'] = now - clock[0]
            clock[0] = now

        use_fb = cfg.fb_threshold > 0.0
        run = self._executor()
        forward = run(self._forward.calc, gray1, gray2, None)
        backward = run(self._backward.calc, gray2, gray1, None) if use_fb else None
        try:
            h_diff = max(cfg.patch_radius // 2, 1)
            margin = cfg.patch_radius + 1 + h_diff
            p1, texture = texture_grid(gray1, cfg.grid_step, margin, cfg.min_texture,
                                       cfg.max_correspondences)
            template = image2 = None
            if cfg.refine_affine and len(p1):
                template = prepare_template(smooth_for_refinement(gray1), p1,
                                            patch_offsets(cfg.patch_radius, cfg.patch_stride))
                image2 = smooth_for_refinement(gray2)
            stats['candidates'] = float(len(p1))
            lap('candidates')
            flow = forward.result()
            back = backward.result() if use_fb else None
        finally:
            # Never leave a flow running on these images after an error.
            forward.cancel()
            if backward is not None:
                backward.cancel()
        lap('flow')
        x, y = p1[:, 0], p1[:, 1]
        p2 = p1 + flow[y, x].astype(np.float64)
        if use_fb and len(p1):
            fb_error = np.linalg.norm(flow[y, x] + sample_field(back, p2), axis=1)
            keep = fb_error < cfg.fb_threshold
        else:
            fb_error = np.zeros(len(p1))
            keep = np.ones(len(p1), dtype=bool)
        stats['fb_consistent'] = float(np.count_nonzero(keep))
        A = flow_jacobian(flow, p1, h_diff)
        if template is not None:
            p2_flow = p2
            index = np.flatnonzero(keep)
            refined, lost = self._refine(template.subset(index), image2, p2[index], A[index])
            p2, A = p2.copy(), A.copy()
            accepted = np.zeros(len(p1), dtype=bool)
            weights = np.zeros(len(p1))
            accepted[index] = refined.ok
            p2[index], A[index], weights[index] = refined.p2, refined.A, refined.weights
            if cfg.ground_reseed:
                # Second chance where the flow failed: rejected by the FB check or diverged.
                failed = ~keep
                failed[index[lost]] = True
                self._reseed_ground(template, image2, p1, p2_flow, p2, A, weights, accepted,
                                    failed, stats)
            acs = AffineCorrespondences(p1[accepted].astype(np.float64), p2[accepted],
                                        A[accepted], weights[accepted])
        else:
            # Without refinement the flow Jacobian's quality is unknown: weight by texture and
            # forward-backward agreement only.
            scale = cfg.fb_threshold if use_fb else 1.0
            weights = texture / (texture + 4.0 * max(cfg.min_texture, 1.0)) \
                / (1.0 + (fb_error / scale) ** 2)
            acs = AffineCorrespondences(p1[keep].astype(np.float64), p2[keep], A[keep],
                                        weights[keep])
        stats['accepted'] = float(len(acs))
        lap('refine')
        self.stats = stats
        return acs

    def _executor(self):
        """``submit(fn, *args) -> future``: the thread pool, or inline calls when OpenCV is set to
        one thread (``cv2.setNumThreads(1)``): then everything runs on the calling thread, for
        single-core deployments and fair one-thread timing."""
        if cv2.getNumThreads() > 1:
            return self._pool.submit

        def inline(fn, *args):
            future: Future = Future()
            future.set_result(fn(*args))
            return future

        return inline

    def _refine(self, template: Template, image2: np.ndarray, p2: np.ndarray, A: np.ndarray,
                iterations: int | None = None) -> tuple[PatchRefinement, np.ndarray]:
        """`refine_affines` + `score_refinement`, in two halves on two threads when there are
        many patches (numpy and OpenCV release the GIL in the heavy calls).

        Returns the `PatchRefinement` and the mask of patches whose iteration diverged.
        """
        cfg = self.config
        iterations = cfg.lk_iterations if iterations is None else iterations
        max_iterations = max(cfg.lk_max_iterations, iterations)

        def work(index):
            sub = template.subset(index) if index is not None else template
            result = refine_affines(sub, image2, p2[index] if index is not None else p2,
                                    A[index] if index is not None else A, iterations=iterations,
                                    max_iterations=max_iterations, max_step=MAX_STEP)
            return score_refinement(sub, result, cfg.max_residual), ~np.isfinite(
                result.last_step)

        n = len(template)
        if n < _PARALLEL_MIN_PATCHES or cv2.getNumThreads() <= 1:
            return work(None)
        half = n // 2
        second = self._executor()(work, np.arange(half, n))
        a, lost_a = work(np.arange(half))
        b, lost_b = second.result()
        joined = PatchRefinement(*(np.concatenate([x, y]) for x, y in zip(
            (a.p2, a.A, a.weights, a.residual, a.ok), (b.p2, b.A, b.weights, b.residual, b.ok))))
        return joined, np.concatenate([lost_a, lost_b])

    def _reseed_ground(self, template: Template, image2: np.ndarray, p1: np.ndarray,
                       p2_flow: np.ndarray, p2: np.ndarray, A: np.ndarray, weights: np.ndarray,
                       accepted: np.ndarray, failed: np.ndarray, stats: dict[str, float]
                       ) -> None:
        """Second chance for the lower image half from a homography of its accepted ACs.

        Why: the ground close to a car-mounted camera moves fast and is strongly
        foreshortened, and there DIS fails (rendered 640x480 street at 1 m per frame: flow
        errors of 15-20 px beyond 3.5 m ahead, so all of it was rejected). The ground is the
        dominant plane of the lower half of the image: a homography fitted robustly to the ACs
        accepted there predicts the failed candidates of that half, and the patch refinement
        confirms or rejects each one as usual. Updates the arrays in place.
        """
        h, w = image2.shape
        lower = p1[:, 1] >= h / 2
        fit = accepted & lower
        retry = failed & ~accepted & lower
        stats['reseeded'] = 0.0
        if np.count_nonzero(fit) < _RESEED_MIN_INLIERS or not retry.any():
            return
        chosen = np.flatnonzero(fit)
        if chosen.size > _RESEED_MAX_FIT:
            # The fit's cost grows with the points; a spread subset fits the plane as well.
            chosen = chosen[np.linspace(0, chosen.size - 1, _RESEED_MAX_FIT).astype(int)]
        H = _dominant_homography(p1[chosen].astype(np.float64), p2[chosen])
        if H is None:
            return
        index = np.flatnonzero(retry)
        q = apply_homography(H, p1[index].astype(np.float64))
        J = homography_jacobian(H, p1[index].astype(np.float64))
        # Only where the predicted warp is strong (DIS's failure mode) and DIS disagrees with the
        # prediction: elsewhere the flow had a fair chance and the patch failed for other
        # reasons (occlusion, no texture, not on the ground), and retrying costs for nothing.
        strong = np.linalg.norm(J - np.eye(2), axis=(1, 2)) > _RESEED_MIN_DEFORMATION
        strong &= np.linalg.norm(q - p2_flow[index], axis=1) > _RESEED_MIN_DISAGREEMENT
        inside = strong & np.all(np.isfinite(q), axis=1) & (q[:, 0] >= 0) \
            & (q[:, 0] <= w - 1) & (q[:, 1] >= 0) & (q[:, 1] <= h - 1)
        index, q, J = index[inside], q[inside], J[inside]
        if index.size == 0:
            return
        refined, _ = self._refine(template.subset(index), image2, q, J)
        good = index[refined.ok]
        p2[good], A[good], weights[good] = (refined.p2[refined.ok], refined.A[refined.ok],
                                            refined.weights[refined.ok])
        accepted[good] = True
        stats['reseeded'] = float(good.size)
