"""Batched inverse-compositional affine Lucas-Kanade: refine thousands of local affines at once.

Each affine correspondence ``(p1, p2, A)`` says that the patch of image 1 around ``p1`` appears in
image 2 under the warp ``W(x) = p2 + A x`` (``x`` = offset from ``p1``, pixels). The refinement
minimises, per patch, ``sum_x (T(x) - I2(W(x)) - b)^2`` over the six warp parameters and an
intensity offset ``b``, by the inverse-compositional algorithm (Baker and Matthews, "Lucas-Kanade
20 years on", IJCV 2004, section 3.2): the steepest-descent images and the Gauss-Newton Hessian
come from the template (image 1) alone, so they are computed once, and each iteration is one
bilinear resampling of image 2 plus small matrix products.

All patches are processed together: one ``np.take`` gathers every template sample, one
``cv2.remap`` samples every warped patch per iteration, and the per-patch sums (Hessian, gradient)
are matrix products of the ``(N, S)`` sample arrays with a fixed ``(S, k)`` matrix of offset
monomials, which BLAS does in one call. The offset ``b`` is eliminated by centring (its Schur
complement), leaving a 6x6 system per patch whose inverse is computed once by a vectorised
Cholesky factorisation. There is no Python loop over patches.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np

__all__ = [
    'AffineLKResult',
    'PatchRefinement',
    'Template',
    'image_gradients',
    'patch_offsets',
    'prepare_template',
    'refine_affines',
    'refine_correspondences',
    'singular_values_2x2',
]

logger = logging.getLogger(__name__)

# Parameter order of the warp increment: [da00, da01, da10, da11, dtx, dty], matching the
# steepest-descent images [Gx ox, Gx oy, Gy ox, Gy oy, Gx, Gy].
_NPARAM = 6


def patch_offsets(radius: int, stride: int) -> np.ndarray:
    """Integer sample offsets of a square patch, ``(S, 2)`` as ``(dx, dy)``, row-major.

    ``radius`` is the half-size in pixels and ``stride`` the sample spacing: a stride above 1
    keeps the patch's extent (the lever arm that determines ``A``) at a fraction of the cost.
    """
    if (2 * radius) % stride == 0:     # e.g. radius 7, stride 2: -7, -5, ..., 7
        r = np.arange(-radius, radius + 1, stride)
    else:                              # symmetric about the centre, within the radius
        r = stride * np.arange(-(radius // stride), radius // stride + 1)
    oy, ox = np.meshgrid(r, r, indexing='ij')
    return np.stack([ox.ravel(), oy.ravel()], axis=1).astype(np.int64)


def _cholesky_inverse(H: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of symmetric positive-definite matrices given as ``(n, n, N)`` (last axis batch).

    Vectorised Cholesky ``H = L L^T``, then ``H^-1 = L^-T L^-1``; a loop over the 6x6 entries
    (not over the N matrices) keeps every numpy operation N wide. Matrices that are not
    positive definite (no texture) come back NaN, flagged in the second output (``(N,)`` bool).
    """
    n = H.shape[0]
    L = np.zeros_like(H)
    with np.errstate(invalid='ignore', divide='ignore'):
        for j in range(n):
            d = H[j, j] - np.einsum('kn,kn->n', L[j, :j], L[j, :j])
            L[j, j] = np.sqrt(d)
            for i in range(j + 1, n):
                L[i, j] = (H[i, j] - np.einsum('kn,kn->n', L[i, :j], L[j, :j])) / L[j, j]
        # Forward substitution for M = L^-1 (lower triangular).
        M = np.zeros_like(H)
        for i in range(n):
            M[i, i] = 1.0 / L[i, i]
            for j in range(i):
                M[i, j] = -np.einsum('kn,kn->n', L[i, j:i], M[j:i, j]) / L[i, i]
    inv = np.einsum('kin,kjn->ijn', M, M)
    ok = np.all(np.isfinite(inv), axis=(0, 1))
    return inv, ok


@dataclass(frozen=True)
class Template:
    """Everything the refinement needs from image 1, computed once per set of patches.

    Attributes:
        p1: patch centres in image 1, ``(N, 2)`` pixels.
        offsets: sample offsets ``(S, 2)`` (pixels, relative to ``p1``).
        values: centred template intensities ``T - mean(T)``, ``(N, S)`` float32.
        gx, gy: template gradients at the samples, ``(N, S)`` float32 (grey levels / pixel).
        hessian_inv: inverse Gauss-Newton Hessians in the layout ``(6, 6, N)`` (float64).
        hessian_min_eig: smallest eigenvalue estimate of each Hessian's translation block,
            ``(N,)``, a texture measure (grey^2 / pixel^2 summed over the patch).
        sd_mean: mean steepest-descent image per patch ``(N, 6)`` (to centre gradients).
        ok: patches with a positive-definite Hessian, ``(N,)`` bool.
    """

    p1: np.ndarray
    offsets: np.ndarray
    values: np.ndarray
    gx: np.ndarray
    gy: np.ndarray
    hessian_inv: np.ndarray
    hessian_min_eig: np.ndarray
    sd_mean: np.ndarray
    ok: np.ndarray

    def __len__(self) -> int:
        return int(self.p1.shape[0])


def _gemm(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a @ b`` for 2-D float32 arrays by OpenCV.

    Why not numpy: these products are tall and thin ((N*k, S) by (S, 6)); multi-threaded
    OpenBLAS splits them across threads and, when other processes load the cores, its threads'
    busy-waiting made one product 100x slower (16 ms instead of 0.16 ms, measured on 2 cores).
    ``cv2.gemm`` stays fast either way.
    """
    if a.shape[0] == 0:
        return np.zeros((0, b.shape[1]), np.float32)
    return cv2.gemm(np.ascontiguousarray(a), np.ascontiguousarray(b), 1.0, None, 0.0)


def _monomials(offsets: np.ndarray) -> np.ndarray:
    """``(S, 6)`` float32 columns ``1, ox, oy, ox^2, ox oy, oy^2`` of the sample offsets."""
    ox = offsets[:, 0].astype(np.float32)
    oy = offsets[:, 1].astype(np.float32)
    return np.stack([np.ones_like(ox), ox, oy, ox * ox, ox * oy, oy * oy], axis=1)


# Hessian entry (i, j) of SD = [Gx ox, Gx oy, Gy ox, Gy oy, Gx, Gy] as (gradient product,
# monomial): products 0 = Gx Gx, 1 = Gx Gy, 2 = Gy Gy; monomials as in `_monomials`.
_SD_GRAD = (0, 0, 1, 1, 0, 1)           # 0: Gx, 1: Gy
_SD_MONO = (1, 2, 1, 2, 0, 0)           # monomial index of the offset factor (ox, oy or 1)
_MONO_PRODUCT = {(0, 0): 0, (0, 1): 1, (0, 2): 2, (1, 1): 3, (1, 2): 4, (2, 2): 5}


def _hessian_index() -> np.ndarray:
    """Flat indices into the ``(3 products x 6 monomials)`` moment table for the 6x6 Hessian."""
    idx = np.empty((_NPARAM, _NPARAM), dtype=np.int64)
    for i in range(_NPARAM):
        for j in range(_NPARAM):
            gi, gj = sorted((_SD_GRAD[i], _SD_GRAD[j]))
            product = gi + gj                       # (0,0)->0, (0,1)->1, (1,1)->2
            mi, mj = sorted((_SD_MONO[i], _SD_MONO[j]))
            idx[i, j] = product * 6 + _MONO_PRODUCT[(mi, mj)]
    return idx


_HESSIAN_INDEX = _hessian_index()


def prepare_template(image1: np.ndarray, grad_x: np.ndarray, grad_y: np.ndarray,
                     p1: np.ndarray, offsets: np.ndarray, *, grad_scale: float = 1.0
                     ) -> Template:
    """Gather template samples and precompute the inverse-compositional Hessians.

    Args:
        image1: image 1 as float32 ``(H, W)``.
        grad_x, grad_y: its gradients times ``1 / grad_scale`` (e.g. the int16 output of
            ``cv2.spatialGradient``, a Sobel filter, with ``grad_scale = 1/8``), ``(H, W)``.
            Their accuracy only affects the speed of convergence: the fixed point of the
            iteration is where the residual vanishes.
        p1: integer patch centres ``(N, 2)`` whose whole patch lies inside the image.
        offsets: ``(S, 2)`` integer sample offsets (`patch_offsets`).

    Returns:
        A `Template`.
    """
    h, w = image1.shape
    p1 = np.asarray(p1, dtype=np.int64)
    n, s = p1.shape[0], offsets.shape[0]
    lin = (p1[:, 1] * w + p1[:, 0])[:, None] + (offsets[:, 1] * w + offsets[:, 0])[None, :]
    values = np.take(image1, lin).astype(np.float32, copy=False)
    gx = np.take(grad_x, lin).astype(np.float32)
    gy = np.take(grad_y, lin).astype(np.float32)
    if grad_scale != 1.0:
        gx *= np.float32(grad_scale)
        gy *= np.float32(grad_scale)
    values = values - values.mean(axis=1, keepdims=True)
    mono = _monomials(offsets)
    products = np.stack([gx * gx, gx * gy, gy * gy, gx, gy], axis=1).reshape(-1, s)
    moments = _gemm(products, mono).reshape(n, 5, 6).astype(np.float64)
    H = moments[:, :3].reshape(n, 18)[:, _HESSIAN_INDEX]            # (N, 6, 6)
    # Sum of each steepest-descent image: Gx/Gy times (ox, oy, 1).
    gsum = moments[:, 3:5]
    sd_sum = gsum[:, _SD_GRAD, _SD_MONO]                             # (N, 6)
    # Eliminate the intensity offset: Schur complement = Hessian of centred steepest descent.
    H -= sd_sum[:, :, None] * sd_sum[:, None, :] / s
    Hinv, ok = _cholesky_inverse(np.ascontiguousarray(H.transpose(1, 2, 0)))
    # Texture of the translation block (2x2 [[sum gx^2, sum gx gy], [., sum gy^2]]), centred.
    a, b, c = H[:, 4, 4], H[:, 4, 5], H[:, 5, 5]
    min_eig = 0.5 * (a + c) - np.sqrt(0.25 * (a - c) ** 2 + b * b)
    return Template(p1.astype(np.float64), offsets, values, gx, gy, Hinv, min_eig,
                    (sd_sum / s).astype(np.float32), ok)


@dataclass(frozen=True)
class AffineLKResult:
    """Refined warps and their quality.

    Attributes:
        p2: refined points in image 2, ``(N, 2)`` pixels.
        A: refined affines ``(N, 2, 2)``.
        residual: RMS photometric residual after the offset is removed, ``(N,)`` grey levels.
        sigma_A: predicted standard error of ``A`` (Frobenius), ``(N,)``, from
            ``residual^2 H^-1`` (the Gauss-Newton covariance).
        sigma_p: predicted standard error of ``p2`` (pixels), ``(N,)``.
        last_step: size of the last update (pixels at the patch rim), ``(N,)``; large values mean
            the iteration had not converged.
        inside: the final warped patch lies inside image 2, ``(N,)`` bool.
        ok: finite, converged, inside, with a positive-definite Hessian, ``(N,)`` bool.
    """

    p2: np.ndarray
    A: np.ndarray
    residual: np.ndarray
    sigma_A: np.ndarray
    sigma_p: np.ndarray
    last_step: np.ndarray
    inside: np.ndarray
    ok: np.ndarray


def refine_affines(template: Template, image2: np.ndarray, p2: np.ndarray, A: np.ndarray, *,
                   iterations: int = 3, noise_floor: float = 0.5,
                   max_step: float = 0.05, max_divergence: float | None = None
                   ) -> AffineLKResult:
    """Refine the warps ``W(x) = p2 + A x`` of all template patches in image 2.

    Inverse-compositional Gauss-Newton (Baker and Matthews 2004): with residual
    ``r = T(x) - I2(W(x))`` (both centred), the increment is ``d = -H^-1 sum_x SD^T r`` and the warp
    is updated by composing with the inverse increment, ``W <- W o W(d)^-1``, i.e.
    ``A <- A (I + dA)^-1``, ``p2 <- p2 - A_new dt``.

    Args:
        template: from `prepare_template`.
        image2: image 2 as float32 ``(H, W)``.
        p2: initial points ``(N, 2)``; A: initial affines ``(N, 2, 2)``.
        iterations: Gauss-Newton iterations (each one ``cv2.remap`` of all patches).
        noise_floor: grey levels added in quadrature to the residual when predicting the
            standard errors (keeps quantisation-free rendered images from giving infinite weight).
        max_step: the last update, measured as the largest sample displacement it causes within
            the patch (pixels), must be below this for a patch to count as converged.
        max_divergence: a patch whose update moves a sample by more than this (pixels; default
            the patch radius) has diverged: it is frozen and flagged.

    Returns:
        An `AffineLKResult`; the residual is the one measured at the start of the last iteration
        (the final update is below ``max_step`` for accepted patches, so one more resampling
        would change it very little and would cost a full iteration).
    """
    n, s = template.values.shape
    offsets = template.offsets
    radius = float(np.abs(offsets).max()) if s else 0.0
    max_divergence = radius if max_divergence is None else max_divergence
    mono = _monomials(offsets)[:, :3].T.copy()                     # (3, S): 1, ox, oy
    mono_t = mono.T.copy()                                          # (S, 3)
    h, w = image2.shape
    p2 = np.asarray(p2, dtype=np.float64).copy()
    A = np.asarray(A, dtype=np.float64).copy()
    Hinv = template.hessian_inv
    T, Gx, Gy = template.values, template.gx, template.gy
    last = np.full(n, np.inf)
    alive = template.ok.copy()
    r = np.zeros((n, s), np.float32)
    coeff = np.empty((2 * n, 3), np.float32)
    for _ in range(max(iterations, 1)):
        # Warped sample positions: one (2N, 3) @ (3, S) product gives the x rows then the y rows.
        coeff[:n, 0], coeff[:n, 1], coeff[:n, 2] = p2[:, 0], A[:, 0, 0], A[:, 0, 1]
        coeff[n:, 0], coeff[n:, 1], coeff[n:, 2] = p2[:, 1], A[:, 1, 0], A[:, 1, 1]
        X = _gemm(coeff, mono)
        warped = cv2.remap(image2, X[:n], X[n:], cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_REPLICATE)
        warped -= warped.mean(axis=1, keepdims=True)
        np.subtract(T, warped, out=r)
        # Gradient sum_x SD^T r: (Gx r, Gy r) against (1, ox, oy); T and warped are centred, so
        # the offset's Schur complement only removes sd_mean * sum(r) = 0 here.
        q = _gemm(np.stack([Gx * r, Gy * r], axis=1).reshape(-1, s), mono_t).reshape(n, 2, 3)
        g = np.stack([q[:, 0, 1], q[:, 0, 2], q[:, 1, 1], q[:, 1, 2], q[:, 0, 0], q[:, 1, 0]])
        d = -np.einsum('ijn,jn->in', Hinv, g.astype(np.float64))    # (6, N)
        # Largest displacement the increment causes within the patch (pixels).
        step = np.hypot(d[4], d[5]) + radius * np.sqrt(d[0] ** 2 + d[1] ** 2 + d[2] ** 2
                                                        + d[3] ** 2)
        # A patch whose step explodes has lost its match: freeze it (and flag it) instead of
        # letting it wander off to huge coordinates, which also makes remap slow.
        alive &= np.isfinite(step) & (step < max_divergence)
        d[:, ~alive] = 0.0
        last = np.where(alive, step, np.inf)
        m00, m01, m10, m11 = 1.0 + d[0], d[1], d[2], 1.0 + d[3]
        det = m00 * m11 - m01 * m10
        i00, i01, i10, i11 = m11 / det, -m01 / det, -m10 / det, m00 / det
        a00 = A[:, 0, 0] * i00 + A[:, 0, 1] * i10
        a01 = A[:, 0, 0] * i01 + A[:, 0, 1] * i11
        a10 = A[:, 1, 0] * i00 + A[:, 1, 1] * i10
        a11 = A[:, 1, 0] * i01 + A[:, 1, 1] * i11
        A[:, 0, 0], A[:, 0, 1], A[:, 1, 0], A[:, 1, 1] = a00, a01, a10, a11
        p2[:, 0] -= a00 * d[4] + a01 * d[5]
        p2[:, 1] -= a10 * d[4] + a11 * d[5]
    residual = np.sqrt(np.einsum('ns,ns->n', r, r).astype(np.float64) / max(s - _NPARAM - 1, 1))
    var = residual ** 2 + noise_floor ** 2
    sigma_A = np.sqrt(var * (Hinv[0, 0] + Hinv[1, 1] + Hinv[2, 2] + Hinv[3, 3]))
    sigma_p = np.sqrt(var * (Hinv[4, 4] + Hinv[5, 5]))
    # The warped patch must stay inside image 2 (else BORDER_REPLICATE was sampled): its
    # half-extent along x is radius * (|a00| + |a01|), along y radius * (|a10| + |a11|).
    ex = radius * (np.abs(A[:, 0, 0]) + np.abs(A[:, 0, 1]))
    ey = radius * (np.abs(A[:, 1, 0]) + np.abs(A[:, 1, 1]))
    with np.errstate(invalid='ignore'):
        inside = ((p2[:, 0] - ex >= 0) & (p2[:, 0] + ex <= w - 1) & (p2[:, 1] - ey >= 0)
                  & (p2[:, 1] + ey <= h - 1))
    ok = alive & inside & (last < max_step)
    return AffineLKResult(p2, A, residual, sigma_A, sigma_p, last, inside, ok)


# --------------------------------------------------------------------------------------------
# Patch refinement as used by the front-end methods: pyramid, acceptance and quality weights
# --------------------------------------------------------------------------------------------

# Quality weight w = 1 / (1 + (sigma_A / SIGMA_A_REF)^2 + (sigma_p / SIGMA_P_REF)^2): an AC whose
# predicted affine error equals SIGMA_A_REF (Frobenius) gets weight 1/2.
SIGMA_A_REF = 0.02
SIGMA_P_REF = 0.1
# Accepted local affines are orientation-preserving with singular values in this range.
_SINGULAR_RANGE = (0.25, 4.0)


@dataclass(frozen=True)
class PatchRefinement:
    """Refined correspondences of `refine_correspondences`, one row per input patch.

    Attributes:
        p2: refined points ``(N, 2)``; A: refined affines ``(N, 2, 2)`` (pixels).
        weights: quality in ``(0, 1]``, ``1 / (1 + (sigma_A/0.02)^2 + (sigma_p/0.1 px)^2)``.
        residual: RMS photometric residual relative to the patch's RMS contrast ``(N,)``.
        ok: accepted (converged, inside, small residual, plausible affine) ``(N,)`` bool.
    """

    p2: np.ndarray
    A: np.ndarray
    weights: np.ndarray
    residual: np.ndarray
    ok: np.ndarray


def singular_values_2x2(A: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Largest and smallest singular values and the determinant of 2x2 matrices ``(N, 2, 2)``.

    Closed form: with ``E = (a + d)/2``, ``F = (a - d)/2``, ``G = (c + b)/2``, ``H = (c - b)/2``,
    ``s = sqrt(E^2 + H^2) +- sqrt(F^2 + G^2)`` (no batched LAPACK call).
    """
    a, b, c, d = A[:, 0, 0], A[:, 0, 1], A[:, 1, 0], A[:, 1, 1]
    q = np.hypot(0.5 * (a + d), 0.5 * (c - b))
    r = np.hypot(0.5 * (a - d), 0.5 * (c + b))
    return q + r, np.abs(q - r), a * d - b * c


def image_gradients(gray: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Sobel gradients of an 8-bit image as int16 and the scale to grey levels per pixel."""
    gx, gy = cv2.spatialGradient(gray)
    return gx, gy, 1.0 / 8.0


def refine_correspondences(gray1: np.ndarray, gray2: np.ndarray, p1: np.ndarray,
                           p2: np.ndarray, A: np.ndarray, *, radius: int, stride: int,
                           iterations: int, max_residual: float, levels: int = 1
                           ) -> PatchRefinement:
    """Refine ACs by affine Lucas-Kanade on image patches and score them.

    Args:
        gray1, gray2: 8-bit grey images of equal size.
        p1: integer patch centres ``(N, 2)``, divisible by ``2^(levels-1)``, with the patch
            inside image 1 at every level.
        p2, A: initial points ``(N, 2)`` and affines ``(N, 2, 2)`` in image 2.
        radius, stride: patch half-size and sample spacing in pixels (`patch_offsets`).
        iterations: Gauss-Newton iterations per pyramid level.
        max_residual: largest accepted RMS residual relative to the patch's RMS contrast.
        levels: pyramid levels; ``2`` first refines on half-resolution images, where the same
            patch covers twice the area, which widens the convergence basin (for ACs starting
            from ``A = I``).

    Returns:
        A `PatchRefinement`.
    """
    p1 = np.asarray(p1, dtype=np.int64)
    p2 = np.asarray(p2, dtype=np.float64)
    A = np.asarray(A, dtype=np.float64)
    offsets = patch_offsets(radius, stride)
    pyramid = [(gray1, gray2)]
    for _ in range(levels - 1):
        pyramid.append((cv2.pyrDown(pyramid[-1][0]), cv2.pyrDown(pyramid[-1][1])))
    alive = np.ones(p1.shape[0], dtype=bool)
    for level in range(levels - 1, -1, -1):
        g1, g2 = pyramid[level]
        scale = float(2 ** level)
        gx, gy, gscale = image_gradients(g1)
        template = prepare_template(g1.astype(np.float32), gx, gy, p1 // (2 ** level), offsets,
                                    grad_scale=gscale)
        final = level == 0
        result = refine_affines(template, g2.astype(np.float32), p2 / scale, A,
                                iterations=iterations,
                                max_step=0.1 if final else np.inf)
        p2, A = result.p2 * scale, result.A
        alive &= result.ok if final else np.isfinite(result.last_step)
    contrast = np.sqrt(np.mean(template.values.astype(np.float64) ** 2, axis=1))
    with np.errstate(divide='ignore', invalid='ignore'):
        residual = np.where(contrast > 0, result.residual / contrast, np.inf)
    smax, smin, det = singular_values_2x2(A)
    with np.errstate(invalid='ignore'):
        plausible = (det > 0) & (smin >= _SINGULAR_RANGE[0]) & (smax <= _SINGULAR_RANGE[1])
    ok = alive & plausible & (residual <= max_residual)
    weights = 1.0 / (1.0 + (result.sigma_A / SIGMA_A_REF) ** 2
                     + (result.sigma_p / SIGMA_P_REF) ** 2)
    return PatchRefinement(p2, A, np.where(ok, weights, 0.0), residual, ok)
