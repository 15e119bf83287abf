"""Affine correspondences from dense optical flow (the ``'flow'`` method; the default).

1. DIS optical flow (Kroeger et al., ECCV 2016; ``cv2.DISOpticalFlow``) from image 1 to image 2
   (preset ``dis_preset``; the refinement makes ``'ultrafast'`` as good as slower presets), on
   images shrunk to at most ``flow_max_width`` pixels wide, and, only when the forward-backward
   check is enabled, from image 2 to image 1.
2. Candidate points on a regular grid: in each ``grid_step`` cell, the pixel with the most
   texture (smaller eigenvalue of the structure tensor), kept if above ``min_texture``. One
   candidate per cell keeps the ACs spread over the image; the cells grow until at most
   ``max_correspondences`` of them have enough texture (the per-frame budget).
3. Optional forward-backward consistency (``fb_threshold > 0``; off by default):
   ``|F(p1) + B(p1 + F(p1))|`` below ``fb_threshold`` pixels. Measured on the rendered street
   and on KITTI, it rejected nothing the refinement's own tests (convergence, residual) did not,
   while the backward flow cost about half a DIS 'fast' flow.
4. Initial affine: the Jacobian of the flow, ``A = I + dF/dp``, by central differences over
   half a patch.
5. Per-patch affine refinement (`planar_vo.frontend.affine_lk`): inverse-compositional affine
   Lucas-Kanade on all patches at once; its Gauss-Newton covariance gives the quality weights.
6. Re-seeding (``reseed``): failed candidates get a second start from an accepted neighbour's
   affine (the ground close to the car, where DIS fails).

Cost: ``planar_vo bench frontend`` (`planar_vo/bench/results/frontend/frontend.md`) and, per
stage of the whole frame, ``planar_vo bench pipeline``.
"""

from __future__ import annotations

import logging
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np

from planar_vo.config import FrontendConfig
from planar_vo.core.correspondences import AffineCorrespondences
from planar_vo.errors import InputError
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

__all__ = [
    'DIS_PRESETS',
    'CandidateGrid',
    'FlowExtractor',
    'flow_candidates',
    'flow_downscale',
    'flow_jacobian',
    'neighbour_predictions',
    'sample_field',
    'shrink',
    'shrunk_points',
    'structure_texture',
    'texture_grid',
]

logger = logging.getLogger(__name__)

# Re-seeding (`FlowExtractor._reseed`): neighbour cells searched (edge-adjacent first),
# rounds of propagation (one: a second round gained little for its cost), and how different
# (pixels, Frobenius) a prediction must be from the flow's start to be worth a retry.
_NEIGHBOURS = ((0, -1), (0, 1), (-1, 0), (1, 0), (-1, -1), (-1, 1), (1, -1), (1, 1))
_RESEED_ROUNDS = 1
_RESEED_MIN_POINT_CHANGE = 1.0
_RESEED_MIN_AFFINE_CHANGE = 0.1
# After one update, patches with a residual above this many times max_residual are dropped.
_GIVE_UP = 2.0
# Below this many patches the refinement runs on the calling thread only.
_PARALLEL_MIN_PATCHES = 256

DIS_PRESETS = {
    'ultrafast': cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST,
    'fast': cv2.DISOPTICAL_FLOW_PRESET_FAST,
    'medium': cv2.DISOPTICAL_FLOW_PRESET_MEDIUM,
}


def structure_texture(gray: np.ndarray) -> np.ndarray:
    """Smaller eigenvalue of the 3x3-averaged structure tensor of the half-resolution image.

    Returned on the half-resolution grid, in (grey levels per full-resolution pixel)^2.
    ``cv2.cornerMinEigenVal`` (3x3 Sobel, 3x3 box) gives it for intensities in ``[0, 1]`` and
    8x the derivative; a half-resolution pixel spans two pixels: hence ``255^2 / 16``.
    """
    return cv2.cornerMinEigenVal(cv2.pyrDown(gray), 3, ksize=3) * np.float32(255.0 ** 2 / 16.0)


@dataclass(frozen=True)
class CandidateGrid:
    """Candidate points, one per grid cell (`texture_grid`).

    Attributes:
        points: ``(N, 2)`` int64 pixel coordinates (even, full resolution).
        texture: ``(N,)`` smaller structure-tensor eigenvalue, (grey levels / pixel)^2.
        cells: ``(N, 2)`` int64 ``(row, col)`` of each point's cell.
        shape: ``(rows, cols)`` of the grid.
    """

    points: np.ndarray
    texture: np.ndarray
    cells: np.ndarray
    shape: tuple[int, int]

    def __len__(self) -> int:
        return int(self.points.shape[0])


def texture_grid(gray: np.ndarray, step: int, margin: int, min_texture: float,
                 max_points: int, texture: np.ndarray | None = None) -> CandidateGrid:
    """Well-spread textured points: the most textured pixel of each ``step x step`` cell.

    Args:
        gray: 8-bit grey image ``(H, W)`` (only its shape is read when ``texture`` is given).
        step: cell size in pixels (rounded up to an even number: the search runs at half
            resolution); enlarged until at most ``max_points`` cells have enough texture.
        margin: pixels kept free along the borders.
        min_texture: smaller structure-tensor eigenvalue required, (grey levels / pixel)^2.
        max_points: cap on the number of points. The cells grow rather than the weakest
            points being dropped: the points stay spread over the image, the faint road
            included, and a richly textured scene costs no more per frame than a plain one.
        texture: the image's half-resolution texture map, when already computed
            (`structure_texture`); computed from ``gray`` when None.

    Returns:
        A `CandidateGrid` (cells without enough texture have no point), in row-major cell order.
    """
    h, w = gray.shape
    cap = max(int(max_points), 1)
    step = max(int(step), 1)
    if texture is None:
        eig = structure_texture(gray)
    else:
        eig = np.asarray(texture)
        half_shape = ((h + 1) // 2, (w + 1) // 2)           # cv2.pyrDown's
        if eig.shape != half_shape or not np.issubdtype(eig.dtype, np.floating):
            raise InputError(f'texture: expected the float texture map of the {w}x{h} image, '
                             f'shape {half_shape}, got {eig.dtype} {eig.shape}')
    half = max((step + 1) // 2, 1)
    rows, cols, m = _cell_layout(eig.shape, h, w, half, margin)
    if rows <= 0 or cols <= 0:
        empty = np.zeros((0, 2), np.int64)
        return CandidateGrid(empty, np.zeros(0), empty, (max(rows, 0), max(cols, 0)))
    while True:
        view = eig[m:m + rows * half, m:m + cols * half]
        # Each cell's maximum in two contiguous reductions (rows, then columns).
        peak = view.reshape(rows, half, cols * half).max(axis=1).reshape(rows, cols, half)
        count = int(np.count_nonzero(peak.max(axis=2) > min_texture))
        if count <= cap:
            break
        # Textured cells fall as 1 / step^2: one enlargement usually fits; then by 2 pixels;
        # halved back while the cells would not fit the image.
        grown = max(step + 2, int(np.ceil(step * np.sqrt(count / cap))))
        layout = _cell_layout(eig.shape, h, w, max((grown + 1) // 2, 1), margin)
        while (layout[0] <= 0 or layout[1] <= 0) and grown > step + 2:
            grown = max(step + 2, (step + grown) // 2)
            layout = _cell_layout(eig.shape, h, w, max((grown + 1) // 2, 1), margin)
        if layout[0] <= 0 or layout[1] <= 0:
            break               # no larger cell fits the image: the most textured cells below
        step, half, (rows, cols, m) = grown, max((grown + 1) // 2, 1), layout
    cells = view.reshape(rows, half, cols, half).transpose(0, 2, 1, 3).reshape(rows, cols,
                                                                               half * half)
    best = cells.argmax(axis=-1)
    value = np.take_along_axis(cells, best[..., None], axis=-1)[..., 0]
    y = m + np.arange(rows)[:, None] * half + best // half
    x = m + np.arange(cols)[None, :] * half + best % half
    keep = value > min_texture
    if count > cap:
        # Cells as large as the image allows still hold too many points: the cap's most
        # textured ones.
        order = np.argsort(-np.where(keep, value, -np.inf), axis=None, kind='stable')
        keep = np.zeros_like(keep)
        keep.ravel()[order[:cap]] = True
    points = 2 * np.stack([x[keep], y[keep]], axis=1).astype(np.int64)
    index = np.stack(np.nonzero(keep), axis=1).astype(np.int64)
    return CandidateGrid(points, value[keep].astype(np.float64), index, (rows, cols))


def _cell_layout(shape: tuple[int, int], h: int, w: int, half: int, margin: int
                 ) -> tuple[int, int, int]:
    """``(rows, cols, m)`` of the cells of ``half`` half-resolution pixels on the
    half-resolution map ``shape`` of an ``h x w`` image, ``m`` the half-resolution margin."""
    m = (margin + 1) // 2                              # half-resolution margin (even points)
    rows = (shape[0] - 2 * m) // half
    cols = (shape[1] - 2 * m) // half
    # Keep every point's full-resolution margin: 2 * (m + rows*half - 1) <= h - 1 - margin.
    while rows > 0 and 2 * (m + rows * half - 1) > h - 1 - margin:
        rows -= 1
    while cols > 0 and 2 * (m + cols * half - 1) > w - 1 - margin:
        cols -= 1
    return rows, cols, m


def _jacobian_baseline(config: FrontendConfig) -> int:
    """Half the central-difference baseline (pixels) of the flow Jacobian: half a patch."""
    return max(config.patch_radius // 2, 1)


def flow_candidates(gray: np.ndarray, config: FrontendConfig,
                    texture: np.ndarray | None = None) -> CandidateGrid:
    """The flow front-end's candidate points in image 1: `texture_grid` with the configured grid
    step, texture threshold and cap, and the border margin its patches and flow Jacobian need.

    Used by `FlowExtractor` and by benchmarks that sample a flow field where the front-end would
    (e.g. DIS-flow points for the five-point peers).
    """
    margin = config.patch_radius + 1 + _jacobian_baseline(config)
    return texture_grid(gray, config.grid_step, margin, config.min_texture,
                        config.max_correspondences, texture)


def sample_field(field: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Bilinear samples of a 2-channel float32 field ``(H, W, 2)`` at points ``(N, 2)``."""
    if points.shape[0] == 0:
        return np.zeros((0, 2), np.float32)
    xy = points.astype(np.float32).reshape(-1, 1, 2)
    return cv2.remap(field, xy, None, cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE).reshape(-1, 2)


def flow_jacobian(flow: np.ndarray, points: np.ndarray, h: int, scale: int = 1) -> np.ndarray:
    """Local affines ``A = I + dF/dp`` of a flow field at points, by central differences.

    Args:
        flow: ``(H, W, 2)`` flow (image 1 -> image 2 displacement) in pixels of the images it
            was computed on, which are the full-resolution images shrunk by ``scale``.
        points: integer full-resolution points ``(N, 2)``, at least ``h`` pixels from the
            border.
        h: half the difference baseline in full-resolution pixels (DIS flow is smooth at its
            patch scale); rounded to whole shrunk pixels when ``scale`` is above 1.
        scale: the shrink factor of the flow's images; above 1 the field is sampled
            bilinearly (`sample_field`) at `shrunk_points`.

    Returns:
        ``A`` ``(N, 2, 2)`` with ``A[:, i, j] = d p2_i / d p1_j``.
    """
    if scale == 1:
        w = flow.shape[1]
        flat = flow.reshape(-1, 2)
        lin = points[:, 1] * w + points[:, 0]
        dx = (np.take(flat, lin + h, axis=0) - np.take(flat, lin - h, axis=0)) / (2.0 * h)
        dy = (np.take(flat, lin + h * w, axis=0)
              - np.take(flat, lin - h * w, axis=0)) / (2.0 * h)
    else:
        # F(p) = scale * f(q(p)) with dq/dp = 1 / scale, so dF/dp = df/dq: differences of the
        # shrunk field over a whole number of shrunk pixels (about h / scale). The samples
        # either side then share their sub-pixel position, and `sample_field`'s quantised
        # bilinear weights cancel in the difference.
        q = shrunk_points(points, scale)
        step = max(int(round(h / scale)), 1)
        n = len(points)
        offsets = np.array([[step, 0.0], [-step, 0.0], [0.0, step], [0.0, -step]])
        f = sample_field(flow, (q[None, :, :] + offsets[:, None, :]).reshape(-1, 2))
        f = f.reshape(4, n, 2).astype(np.float64)
        dx = (f[0] - f[1]) / (2.0 * step)
        dy = (f[2] - f[3]) / (2.0 * step)
    A = np.empty((len(points), 2, 2))
    A[:, :, 0] = dx
    A[:, :, 1] = dy
    A[:, 0, 0] += 1.0
    A[:, 1, 1] += 1.0
    return A


def flow_downscale(width: int, max_width: int) -> int:
    """The integer factor that shrinks an image ``width`` pixels wide to at most ``max_width``
    (1 when it already fits or ``max_width`` is 0)."""
    if max_width <= 0 or width <= max_width:
        return 1
    return int(np.ceil(width / max_width))


def shrunk_points(points: np.ndarray, scale: int) -> np.ndarray:
    """Full-resolution pixel coordinates in an image shrunk by ``scale`` with area averaging
    (pixel centres: ``(p + 0.5) / scale - 0.5``)."""
    return (np.asarray(points, np.float64) + 0.5) / scale - 0.5


def shrink(gray: np.ndarray, scale: int) -> np.ndarray:
    """``gray`` shrunk by the integer ``scale`` (area averaging); itself for 1."""
    if scale == 1:
        return gray
    h, w = gray.shape[:2]
    return cv2.resize(gray, (max(w // scale, 1), max(h // scale, 1)),
                      interpolation=cv2.INTER_AREA)


def neighbour_predictions(grid: CandidateGrid, accepted: np.ndarray, retry: np.ndarray,
                          p2: np.ndarray, A: np.ndarray
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Predict candidates from an accepted neighbour: ``p2 = p2_n + A_n (p1 - p1_n)``, ``A = A_n``.

    The neighbour is the first accepted candidate among the 4 edge-adjacent cells, then the 4
    diagonal ones; the prediction is the neighbour's local affine extrapolated by one cell.

    Args:
        grid: the candidates.
        accepted, retry: ``(N,)`` bool: usable neighbours, candidates to predict.
        p2, A: current points ``(N, 2)`` and affines ``(N, 2, 2)`` (read for the neighbours).

    Returns:
        ``index`` (the retry candidates that have an accepted neighbour), their predicted points
        ``(M, 2)`` and affines ``(M, 2, 2)``.
    """
    rows, cols = grid.shape
    lookup = np.full((rows + 2, cols + 2), -1, dtype=np.int64)     # padded: no bounds checks
    ok = np.flatnonzero(accepted)
    lookup[grid.cells[ok, 0] + 1, grid.cells[ok, 1] + 1] = ok
    index = np.flatnonzero(retry)
    r, c = grid.cells[index, 0] + 1, grid.cells[index, 1] + 1
    neighbour = np.full(index.size, -1, dtype=np.int64)
    for dr, dc in _NEIGHBOURS:
        free = neighbour < 0
        neighbour[free] = lookup[r[free] + dr, c[free] + dc]
    found = neighbour >= 0
    index, neighbour = index[found], neighbour[found]
    offset = (grid.points[index] - grid.points[neighbour]).astype(np.float64)
    q = p2[neighbour] + np.einsum('nij,nj->ni', A[neighbour], offset)
    return index, q, A[neighbour].copy()


@dataclass(frozen=True)
class _PairState:
    """What `FlowExtractor.extract_more` reuses of the last pair: image 1's size and texture
    map (`structure_texture`), the flow scale, the forward and backward (or None) flows, image 2
    and image 1 smoothed for the refinement (None when not used). Arrays the extractor made
    itself: nothing of the caller's (who may refill its buffers) is kept."""

    shape: tuple[int, int]
    texture: np.ndarray
    scale: int
    flow: np.ndarray
    back: np.ndarray | None
    image2: np.ndarray | None
    smooth1: np.ndarray | None


class FlowExtractor:
    """DIS-flow affine correspondences.

    Keeps the DIS instances between frames (creating one costs more than a flow computation)
    and a small thread pool: the DIS flows run in worker threads (OpenCV releases the GIL)
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
        # A copy of image 2 of the last call and its derived images (shrunk for DIS, smoothed
        # for the refinement): a tracker's image 2 is usually its next image 1 (the new
        # keyframe).
        self._last: tuple[np.ndarray, int, np.ndarray, np.ndarray | None] | None = None
        self._pair: _PairState | None = None       # the last pair, for `extract_more`

    def _derived(self, gray: np.ndarray, scale: int
                 ) -> tuple[np.ndarray | None, np.ndarray | None]:
        """``gray`` shrunk by ``scale`` for DIS and `smooth_for_refinement`-ed, when ``gray``
        holds the pixels given as image 2 last time (None each otherwise). Compared by value,
        against a copy: a caller may refill one buffer frame after frame."""
        last = self._last
        if last is None or last[0].shape != gray.shape or not np.array_equal(last[0], gray):
            return None, None
        return (last[2] if last[1] == scale else None), last[3]

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

        self._pair = None
        use_fb = cfg.fb_threshold > 0.0
        run = self._executor()
        s = flow_downscale(gray1.shape[1], cfg.flow_max_width)
        small1, smooth1 = self._derived(gray1, s)
        small1 = shrink(gray1, s) if small1 is None else small1
        small2 = shrink(gray2, s)
        forward = run(self._forward.calc, small1, small2, None)
        backward = run(self._backward.calc, small2, small1, None) if use_fb else None
        try:
            texture = structure_texture(gray1)
            grid = flow_candidates(gray1, cfg, texture)
            p1 = grid.points
            template = image2 = None
            if cfg.refine_affine:
                image2 = smooth_for_refinement(gray2)
                smooth1 = smooth_for_refinement(gray1) if smooth1 is None else smooth1
                if len(p1):
                    template = prepare_template(
                        smooth1, p1, patch_offsets(cfg.patch_radius, cfg.patch_stride))
            self._last = (gray2.copy(), s, small2, image2)
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
        self._pair = _PairState(gray1.shape, texture, s, flow, back, image2, smooth1)
        acs = self._track(grid, template, stats)
        lap('refine')
        self.stats = stats
        return acs

    def extract_more(self, select) -> AffineCorrespondences | None:
        """More ACs on the image pair of the last `extract`, from its flows: candidates on the
        configured grid without the per-frame budget (``max_correspondences`` counts the
        selected ones only), those ``select`` keeps, evenly thinned to the budget.

        For a consumer that needs ACs in one region that the budget's larger cells left too
        sparse (the ground scale on the road close to a fast car); costs the candidate search
        and the refinement of the new points, not another flow.

        Args:
            select: ``select(points) -> (N,) bool`` for ``(N, 2)`` pixel points of image 1.

        Returns:
            The ACs (pixels; as `extract`, re-seeding among the selected points), or None before
            the first `extract`.
        """
        pair = self._pair
        if pair is None:
            return None
        cfg = self.config
        margin = cfg.patch_radius + 1 + _jacobian_baseline(cfg)
        grid = texture_grid(np.broadcast_to(np.uint8(0), pair.shape), cfg.grid_step, margin,
                            cfg.min_texture, pair.shape[0] * pair.shape[1], pair.texture)
        keep = np.asarray(select(grid.points.astype(np.float64)))
        if keep.dtype != bool or keep.shape != (len(grid.points),):
            raise InputError(f'select: expected a bool mask of shape ({len(grid.points)},), got '
                             f'{keep.dtype} {keep.shape}')
        index = np.flatnonzero(keep)
        cap = max(int(cfg.max_correspondences), 1)
        if index.size > cap:
            index = index[np.linspace(0, index.size - 1, cap).astype(np.intp)]
        grid = CandidateGrid(grid.points[index], grid.texture[index], grid.cells[index],
                             grid.shape)
        template = None
        if cfg.refine_affine and len(grid.points):
            template = prepare_template(pair.smooth1, grid.points,
                                        patch_offsets(cfg.patch_radius, cfg.patch_stride))
        stats: dict[str, float] = {'candidates': float(len(grid.points))}
        return self._track(grid, template, stats)

    def _track(self, grid: CandidateGrid, template: Template | None, stats: dict[str, float]
               ) -> AffineCorrespondences:
        """Steps 3-6 for the candidates ``grid`` on the stored pair (`_PairState`)."""
        cfg = self.config
        pair = self._pair
        flow, back, s, image2 = pair.flow, pair.back, pair.scale, pair.image2
        p1, texture = grid.points, grid.texture
        use_fb = back is not None
        if s == 1:
            forward_flow = flow[p1[:, 1], p1[:, 0]].astype(np.float64)
        else:
            forward_flow = s * sample_field(flow, shrunk_points(p1, s)).astype(np.float64)
        p2 = p1 + forward_flow
        if use_fb and len(p1):
            backward_flow = s * sample_field(back, shrunk_points(p2, s))
            fb_error = np.linalg.norm(forward_flow + backward_flow, axis=1)
            keep = fb_error < cfg.fb_threshold
        else:
            fb_error = np.zeros(len(p1))
            keep = np.ones(len(p1), dtype=bool)
        stats['fb_consistent'] = float(np.count_nonzero(keep))
        A = flow_jacobian(flow, p1, _jacobian_baseline(cfg), s)
        if template is not None:
            p2_flow, A_flow = p2, A
            index = np.flatnonzero(keep)
            refined = self._refine(template.subset(index), image2, p2[index], A[index])
            p2, A = p2.copy(), A.copy()
            accepted = np.zeros(len(p1), dtype=bool)
            weights = np.zeros(len(p1))
            accepted[index] = refined.ok
            p2[index], A[index], weights[index] = refined.p2, refined.A, refined.weights
            if cfg.reseed:
                self._reseed(grid, template, image2, p2_flow, A_flow, p2, A, weights, accepted,
                             stats)
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
                iterations: int | None = None) -> PatchRefinement:
        """`refine_affines` + `score_refinement`; many patches run in two halves on two threads
        unless OpenCV is set to one (numpy and OpenCV release the GIL in the heavy calls)."""
        cfg = self.config
        iterations = cfg.lk_iterations if iterations is None else iterations
        max_iterations = max(cfg.lk_max_iterations, iterations)

        def work(index):
            sub = template.subset(index) if index is not None else template
            result = refine_affines(sub, image2, p2[index] if index is not None else p2,
                                    A[index] if index is not None else A, iterations=iterations,
                                    max_iterations=max_iterations, max_step=MAX_STEP,
                                    give_up=_GIVE_UP * cfg.max_residual)
            return score_refinement(sub, result, cfg.max_residual)

        n = len(template)
        if n < _PARALLEL_MIN_PATCHES or cv2.getNumThreads() <= 1:
            return work(None)
        # Two halves on two threads. A patch's refinement does not depend on the other patches
        # of its batch (`refine_affines`), so the ACs are the same bits either way.
        half = n // 2
        second = self._pool.submit(work, np.arange(half, n))
        a = work(np.arange(half))
        b = second.result()
        return PatchRefinement(*(np.concatenate([x, y]) for x, y in zip(
            (a.p2, a.A, a.weights, a.residual, a.ok), (b.p2, b.A, b.weights, b.residual, b.ok))))

    def _reseed(self, grid: CandidateGrid, template: Template, image2: np.ndarray,
                p2_flow: np.ndarray, A_flow: np.ndarray, p2: np.ndarray, A: np.ndarray,
                weights: np.ndarray, accepted: np.ndarray, stats: dict[str, float]) -> None:
        """Second chances for failed candidates, started from an accepted neighbour's affine.

        Why: where the image moves fast and is strongly foreshortened, above all the ground close
        to a car-mounted camera, DIS fails (rendered 640x480 street at 1 m per frame: flow
        errors of 5 px on the near ground, 15-20 px beyond 3.5 m ahead), so the refinement
        starts outside its basin. An accepted neighbour one cell away, on the same surface,
        predicts the point to about a pixel (`neighbour_predictions`); the refinement then
        confirms or rejects each retry as usual. A few rounds let accepted ACs propagate into
        the failed region. Only predictions that differ from the flow's start are retried.
        Updates the arrays in place.
        """
        retried = 0
        tried = np.zeros(len(accepted), dtype=bool)
        for _ in range(_RESEED_ROUNDS):
            index, q, J = neighbour_predictions(grid, accepted, ~accepted & ~tried, p2, A)
            new = (np.linalg.norm(q - p2_flow[index], axis=1) > _RESEED_MIN_POINT_CHANGE) | (
                np.linalg.norm(J - A_flow[index], axis=(1, 2)) > _RESEED_MIN_AFFINE_CHANGE)
            index, q, J = index[new], q[new], J[new]
            if index.size == 0:
                break
            tried[index] = True
            refined = self._refine(template.subset(index), image2, q, J)
            good = index[refined.ok]
            p2[good], A[good], weights[good] = (refined.p2[refined.ok], refined.A[refined.ok],
                                                refined.weights[refined.ok])
            accepted[good] = True
            retried += good.size
            if good.size == 0:
                break
        stats['reseeded'] = float(retried)
