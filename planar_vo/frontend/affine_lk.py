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
are products of the ``(N, S)`` sample arrays with a fixed matrix of offset monomials (one
``cv2.gemm`` for the Hessians, once; ``np.einsum`` on each patch's own row per iteration, so that
a patch's result does not depend on the other patches of its batch). The offset ``b`` is
eliminated by centring (its Schur complement), leaving a 6x6 system per patch whose inverse is
computed once by a vectorised Cholesky factorisation. There is no Python loop over patches.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np

__all__ = [
    'MAX_STEP',
    'AffineLKResult',
    'PatchRefinement',
    'Template',
    'patch_offsets',
    'prepare_template',
    'refine_affines',
    'refine_correspondences',
    'score_refinement',
    'singular_values_2x2',
    'smooth_for_refinement',
]

logger = logging.getLogger(__name__)

# Parameter order of the warp increment: [dtx, da00, da01, dty, da10, da11], matching the
# steepest-descent images [Gx, Gx ox, Gx oy, Gy, Gy ox, Gy oy] (gradient times 1, ox, oy).
_NPARAM = 6
_TINY = np.float32(1e-12)    # floor of a warped patch's sum of squares (a flat patch)


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

    Vectorised Cholesky ``H = L L^T``, then ``H^-1 = L^-T L^-1``; the loops run over the 6x6
    entries (not over the N matrices), so every numpy operation is N wide, and a batched LAPACK
    call (one small call per matrix) is avoided. Matrices that are not positive definite (no
    texture) come back NaN, flagged in the second output (``(N,)`` bool).
    """
    n = H.shape[0]
    L = np.zeros_like(H)
    inv_diag = np.empty((n,) + H.shape[2:])
    with np.errstate(invalid='ignore', divide='ignore'):
        for j in range(n):
            d = H[j, j] - (L[j, :j] * L[j, :j]).sum(axis=0)
            L[j, j] = np.sqrt(d)
            inv_diag[j] = 1.0 / L[j, j]
            if j + 1 < n:
                L[j + 1:, j] = (H[j + 1:, j] - np.einsum('ikn,kn->in', L[j + 1:, :j],
                                                         L[j, :j]) if j else H[j + 1:, j]) \
                    * inv_diag[j]
        # Forward substitution for M = L^-1 (lower triangular), one row at a time.
        M = np.zeros_like(H)
        for i in range(n):
            M[i, i] = inv_diag[i]
            if i:
                M[i, :i] = -np.einsum('kn,kjn->jn', L[i, :i], M[:i, :i]) * inv_diag[i]
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
        gradients: template gradients ``(Gx, Gy)`` at the samples, ``(N, 2, S)`` float32 (grey
            levels / pixel).
        hessian_inv: inverse Gauss-Newton Hessians in the layout ``(6, 6, N)`` (float64), in the
            parameter order ``(tx, a00, a01, ty, a10, a11)``.
        ok: patches with a positive-definite Hessian, ``(N,)`` bool.
        contrast: RMS of the centred template values, ``(N,)`` grey levels.
    """

    p1: np.ndarray
    offsets: np.ndarray
    values: np.ndarray
    gradients: np.ndarray
    hessian_inv: np.ndarray
    ok: np.ndarray
    contrast: np.ndarray

    def __len__(self) -> int:
        return int(self.p1.shape[0])

    def subset(self, index: np.ndarray) -> Template:
        """The template of the patches selected by a boolean mask or index array."""
        return Template(self.p1[index], self.offsets, self.values[index],
                        self.gradients[index], self.hessian_inv[:, :, index], self.ok[index],
                        self.contrast[index])


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


# Hessian entry (i, j) of SD = [Gx, Gx ox, Gx oy, Gy, Gy ox, Gy oy] as (gradient product,
# monomial): products 0 = Gx Gx, 1 = Gx Gy, 2 = Gy Gy; monomials as in `_monomials`.
_SD_GRAD = (0, 0, 0, 1, 1, 1)           # 0: Gx, 1: Gy
_SD_MONO = (0, 1, 2, 0, 1, 2)           # monomial index of the offset factor (1, ox or oy)
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


def prepare_template(image1: np.ndarray, p1: np.ndarray, offsets: np.ndarray) -> Template:
    """Gather template samples and precompute the inverse-compositional Hessians.

    Args:
        image1: image 1 as float32 ``(H, W)``, smoothed (see `refine_correspondences`).
        p1: integer patch centres ``(N, 2)`` whose patch, plus one pixel, lies inside the image.
        offsets: ``(S, 2)`` integer sample offsets (`patch_offsets`).

    Returns:
        A `Template`. Gradients are central differences of ``image1`` at the samples (they only
        set the descent direction: the iteration's fixed point is where the residual vanishes).
    """
    h, w = image1.shape
    p1 = np.asarray(p1, dtype=np.int64)
    n, s = p1.shape[0], offsets.shape[0]
    lin = (p1[:, 1] * w + p1[:, 0])[:, None] + (offsets[:, 1] * w + offsets[:, 0])[None, :]
    flat = image1.reshape(-1)
    values = np.take(flat, lin)
    gx = (np.take(flat, lin + 1) - np.take(flat, lin - 1)) * np.float32(0.5)
    gy = (np.take(flat, lin + w) - np.take(flat, lin - w)) * np.float32(0.5)
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
    contrast = np.sqrt(np.einsum('ns,ns->n', values, values).astype(np.float64) / max(s, 1))
    return Template(p1.astype(np.float64), offsets, values, np.stack([gx, gy], axis=1), Hinv,
                    ok, contrast)


@dataclass(frozen=True)
class AffineLKResult:
    """Refined warps and their quality.

    Attributes:
        p2: refined points in image 2, ``(N, 2)`` pixels.
        A: refined affines ``(N, 2, 2)``.
        residual: RMS photometric residual after the offset and gain are removed, ``(N,)``
            grey levels.
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


def _gauss_newton_step(T: np.ndarray, G: np.ndarray, Hinv: np.ndarray, image2: np.ndarray,
                       p2: np.ndarray, A: np.ndarray, mono: np.ndarray, radius: float,
                       energy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One inverse-compositional Gauss-Newton iteration for ``M`` patches (see `refine_affines`;
    ``G``: the template gradients ``(M, 2, S)``; ``Hinv``: inverse Hessians ``(6, 6, M)`` in the
    order of ``q`` below; ``mono``: ``(3, S)`` rows ``1, ox, oy``; ``energy``: the templates'
    sums of squares ``(M,)`` float32).

    Every operation works on each patch's own row (``np.einsum``'s loops; no BLAS or
    ``cv2.gemm``, whose rounding depends on the number of rows), so a patch's result does not
    depend on which other patches are refined with it: one batch or two halves on two threads
    give the same bits.

    Returns the updated ``p2 (M, 2)``, ``A (M, 2, 2)``, the step size ``(M,)`` (largest sample
    displacement of the increment, pixels) and the residual's sum of squares ``(M,)`` before the
    update.
    """
    # Warped sample positions x = p2 + A o: rows (p2_x, a00, a01) and (p2_y, a10, a11) of each
    # patch against the columns (1, ox, oy) of the offsets.
    m = T.shape[0]
    coeff = np.empty((2, m, 3), np.float32)
    coeff[:, :, 0] = p2.T
    coeff[:, :, 1:] = A.transpose(1, 0, 2)
    X = np.einsum('kmj,js->kms', coeff, mono)
    warped = cv2.remap(image2, X[0], X[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    warped -= np.einsum('ms->m', warped)[:, None] * np.float32(1.0 / T.shape[1])
    # Photometric gain: image 2 may be brighter or darker (auto-exposure, shadows), so the
    # warped patch is scaled to the template's contrast (the offset is already removed). The
    # fixed point is unchanged (T = g I2(W(x))), and an anti-correlated patch still leaves a
    # large residual (a least-squares gain would flip its sign and fit it).
    gain = np.sqrt(energy / np.maximum(np.einsum('ms,ms->m', warped, warped), _TINY))
    warped *= gain[:, None]
    r = np.subtract(T, warped, out=warped)
    # Gradient sum_x SD^T r: (Gx r, Gy r) against (1, ox, oy), q = (M, 6) in the order
    # (tx, a00, a01, ty, a10, a11); T and warped are centred, so the offset's Schur complement
    # (mean steepest-descent image times sum(r)) vanishes.
    q = np.einsum('mks,js->mkj', G * r[:, None, :], mono).reshape(m, 6).astype(np.float64)
    d = Hinv[:, 0] * -q[:, 0]                                       # (6, M), order of q
    for j in range(1, _NPARAM):
        d -= Hinv[:, j] * q[:, j]
    step = np.hypot(d[0], d[3]) + radius * np.sqrt(d[1] ** 2 + d[2] ** 2 + d[4] ** 2
                                                   + d[5] ** 2)
    # W <- W o W(d)^-1: A <- A (I + dA)^-1, p2 <- p2 - A_new dt.
    m00, m01, m10, m11 = 1.0 + d[1], d[2], d[4], 1.0 + d[5]
    with np.errstate(divide='ignore', invalid='ignore'):
        det = m00 * m11 - m01 * m10
        i00, i01, i10, i11 = m11 / det, -m01 / det, -m10 / det, m00 / det
    An = np.empty_like(A)
    An[:, :, 0] = A[:, :, 0] * i00[:, None] + A[:, :, 1] * i10[:, None]
    An[:, :, 1] = A[:, :, 0] * i01[:, None] + A[:, :, 1] * i11[:, None]
    p2n = p2 - An[:, :, 0] * d[0][:, None] - An[:, :, 1] * d[3][:, None]
    return p2n, An, step, np.einsum('ms,ms->m', r, r)


def refine_affines(template: Template, image2: np.ndarray, p2: np.ndarray, A: np.ndarray, *,
                   iterations: int = 3, max_iterations: int | None = None,
                   tolerance: float = 0.02, max_step: float = 0.25, noise_floor: float = 0.5,
                   max_divergence: float | None = None, give_up: float | None = None
                   ) -> AffineLKResult:
    """Refine the warps ``W(x) = p2 + A x`` of all template patches in image 2.

    Inverse-compositional Gauss-Newton (Baker and Matthews 2004): with residual
    ``r = T(x) - g I2(W(x))`` (both centred, ``g`` scaling the warped patch to the template's
    contrast), the increment is ``d = -H^-1 sum_x SD^T r`` and the warp
    is updated by composing with the inverse increment, ``W <- W o W(d)^-1``, i.e.
    ``A <- A (I + dA)^-1``, ``p2 <- p2 - A_new dt``.

    The first ``iterations`` iterations update every patch; later ones (up to
    ``max_iterations``) only the patches whose last step was above ``tolerance``, so slow
    patches (strong foreshortening, poor start) get more iterations without paying for all.

    Args:
        template: from `prepare_template`.
        image2: image 2 as float32 ``(H, W)``, smoothed like the template's image.
        p2: initial points ``(N, 2)``; A: initial affines ``(N, 2, 2)``.
        iterations: iterations on all patches (each one ``cv2.remap`` of all patches).
        max_iterations: total iterations for the unconverged ones (default ``iterations``).
        tolerance: a step (largest sample displacement of an update, pixels) below this ends a
            patch's iterations.
        max_step: the last step must be below this (pixels) for a patch to count as converged;
            the step is also added to the predicted errors.
        noise_floor: grey levels added in quadrature to the residual when predicting the
            standard errors (keeps noise-free rendered images from giving infinite weight).
        max_divergence: a patch whose update moves a sample by more than this (pixels; default
            the patch radius) has diverged: it is frozen and flagged.
        give_up: from the second iteration on, a patch whose RMS residual exceeds this many
            times its RMS contrast is dropped (flagged as diverged): it will not be accepted,
            so further iterations would be wasted. None keeps every patch.

    Returns:
        An `AffineLKResult`; the residual is the one measured at the start of each patch's last
        iteration (one more resampling would change little and cost a full iteration).
    """
    n, s = template.values.shape
    offsets = template.offsets
    radius = float(np.abs(offsets).max()) if s else 0.0
    max_divergence = radius if max_divergence is None else max_divergence
    max_iterations = iterations if max_iterations is None else max(max_iterations, iterations)
    mono = _monomials(offsets)[:, :3].T.copy()                     # (3, S): 1, ox, oy
    h, w = image2.shape
    p2 = np.asarray(p2, dtype=np.float64).copy()
    A = np.asarray(A, dtype=np.float64).copy()
    Hinv = template.hessian_inv
    last = np.full(n, np.inf)
    residual = np.full(n, np.inf)
    alive = template.ok.copy()
    active = np.flatnonzero(alive)
    energy = (template.contrast ** 2 * s).astype(np.float32)
    for it in range(max(max_iterations, 1)):
        if it >= iterations:
            active = active[last[active] >= tolerance]
        if active.size == 0:
            break
        if active.size == n:
            args = (template.values, template.gradients, Hinv, p2, A, energy)
        else:
            args = (template.values[active], template.gradients[active], Hinv[:, :, active],
                    p2[active], A[active], energy[active])
        T, G, Hi, p2_a, A_a, energy_a = args
        p2_new, A_new, step, rr = _gauss_newton_step(T, G, Hi, image2, p2_a, A_a, mono, radius,
                                                     energy_a)
        residual[active] = np.sqrt(rr.astype(np.float64) / max(s - _NPARAM - 1, 1))
        # A patch whose step explodes has lost its match: freeze it (and flag it) instead of
        # letting it wander off to huge coordinates, which also makes remap slow.
        good = np.isfinite(step) & (step < max_divergence)
        if give_up is not None and it >= 1:
            good &= residual[active] <= give_up * template.contrast[active]
        alive[active[~good]] = False
        last[active] = np.where(good, step, np.inf)
        keep = active[good]
        p2[keep], A[keep] = p2_new[good], A_new[good]
        active = keep
    # Gauss-Newton covariance residual^2 H^-1, plus the last step as an unconverged remainder.
    var = residual ** 2 + noise_floor ** 2
    remainder = np.where(np.isfinite(last), last, 0.0)
    sigma_A = np.sqrt(var * (Hinv[1, 1] + Hinv[2, 2] + Hinv[4, 4] + Hinv[5, 5])
                      + (remainder / max(radius, 1.0)) ** 2)
    sigma_p = np.sqrt(var * (Hinv[0, 0] + Hinv[3, 3]) + remainder ** 2)
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
# An accepted patch's last Gauss-Newton step moved no sample by more than this (pixels).
MAX_STEP = 0.25
# Gaussian pre-smoothing (pixels) of both images before the refinement.
PRESMOOTH_SIGMA = 1.0
_PRESMOOTH_KERNEL = cv2.getGaussianKernel(5, PRESMOOTH_SIGMA).astype(np.float32)
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


def smooth_for_refinement(gray: np.ndarray) -> np.ndarray:
    """The float32 image the refinement samples: Gaussian-smoothed by `PRESMOOTH_SIGMA`.

    Why: with samples every ``stride`` pixels, unsmoothed camera images alias and the
    Gauss-Newton steps oscillate (KITTI frame 10 -> 11: 13% of patches converged in 3 iterations
    unsmoothed, 43% with sigma = 1 px). Both images are smoothed alike, so the warp between them
    is unchanged up to the (small) non-commutation of blur and affine warp.
    """
    # A separable 5-tap filter from uint8 straight to float32: one pass, no rounding of the
    # smoothed values (about 7x faster than converting and then calling GaussianBlur).
    return cv2.sepFilter2D(gray, cv2.CV_32F, _PRESMOOTH_KERNEL, _PRESMOOTH_KERNEL,
                           borderType=cv2.BORDER_REFLECT_101)


def score_refinement(template: Template, result: AffineLKResult, max_residual: float
                     ) -> PatchRefinement:
    """Accept refined patches and weight them (`PatchRefinement`).

    Accepted: converged and inside (``result.ok``), an orientation-preserving affine with
    singular values in ``[0.25, 4]``, and an RMS residual at most ``max_residual`` times the
    patch's RMS contrast. Weight ``1 / (1 + (sigma_A / 0.02)^2 + (sigma_p / 0.1)^2)`` from the
    Gauss-Newton covariance (`refine_affines`).
    """
    contrast = template.contrast
    with np.errstate(divide='ignore', invalid='ignore'):
        residual = np.where(contrast > 0, result.residual / contrast, np.inf)
    smax, smin, det = singular_values_2x2(result.A)
    with np.errstate(invalid='ignore'):
        plausible = (det > 0) & (smin >= _SINGULAR_RANGE[0]) & (smax <= _SINGULAR_RANGE[1])
    ok = result.ok & plausible & (residual <= max_residual)
    weights = 1.0 / (1.0 + (result.sigma_A / SIGMA_A_REF) ** 2
                     + (result.sigma_p / SIGMA_P_REF) ** 2)
    return PatchRefinement(result.p2, result.A, np.where(ok, weights, 0.0), residual, ok)


def refine_correspondences(gray1: np.ndarray, gray2: np.ndarray, p1: np.ndarray,
                           p2: np.ndarray, A: np.ndarray, *, radius: int, stride: int,
                           iterations: int, max_iterations: int, max_step: float,
                           max_residual: float, levels: int = 1) -> PatchRefinement:
    """Refine ACs by affine Lucas-Kanade on image patches and score them.

    Args:
        gray1, gray2: 8-bit grey images of equal size.
        p1: integer patch centres ``(N, 2)``, divisible by ``2^(levels-1)``, with the patch
            inside image 1 at every level.
        p2, A: initial points ``(N, 2)`` and affines ``(N, 2, 2)`` in image 2.
        radius, stride: patch half-size and sample spacing in pixels (`patch_offsets`).
        iterations, max_iterations: Gauss-Newton iterations on all patches, and in total for
            the patches not yet converged (`refine_affines`); the coarse level uses
            ``iterations`` only.
        max_step: largest last step (pixels) of an accepted patch.
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
    p2_start, A_start = p2, A
    for level in range(levels - 1, -1, -1):
        f1, f2 = (smooth_for_refinement(g) for g in pyramid[level])
        scale = float(2 ** level)
        template = prepare_template(f1, p1 // (2 ** level), offsets)
        final = level == 0
        result = refine_affines(template, f2, p2 / scale, A, iterations=iterations,
                                max_iterations=max_iterations if final else iterations,
                                max_step=max_step if final else np.inf)
        if not final:
            p2, A = result.p2 * scale, result.A
            # Patches lost at the coarse level start the fine level from where they were.
            lost = ~np.isfinite(result.last_step)
            p2[lost], A[lost] = p2_start[lost], A_start[lost]
    return score_refinement(template, result, max_residual)
