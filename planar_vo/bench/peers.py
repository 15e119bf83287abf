"""Peer estimators wrapped in planar_vo's conventions, for comparisons and benchmarks.

Robust estimators (all correspondences in, one pose out, a `PoseEstimate`):

- `estimate_5pc_opencv`: OpenCV's five-point pipeline (``findEssentialMat`` with RANSAC, then
  ``recoverPose``), the estimator most monocular VO code uses.
- `estimate_5pc_poselib`: PoseLib's ``estimate_relative_pose`` (five-point RANSAC with local
  optimisation and a final bundle refinement) on normalised coordinates (identity cameras).
- `estimate_2pc_ransac`: a planar two-point RANSAC; the minimal solver is PoseLib's upright planar
  two-point solver (``relpose_upright_planar_2pt``, called once per sample from Python) or
  planar_vo's `solve_2pc` (vectorised over a batch of samples).
- `estimate_6pc_focal_poselib`: PoseLib's ``estimate_shared_focal_relative_pose`` (six-point
  shared-focal RANSAC and refinement), pixel coordinates relative to the principal point.

Minimal solvers (one call per sample, every root returned, NaN-padded), for solver accuracy and
timing: `solve_2pc_poselib`, `solve_5pc_poselib`, `solve_6pc_focal_poselib`.

Each robust estimator returns the general pose and its projection onto planar motion
``(alpha, beta)`` (`planar_vo.core.planar_motion_from_pose`), so errors are measured the same
way for all. PoseLib's pose convention ``x_cam2 = R x_cam1 + t`` equals ours (checked on exact
data in test/test_bench.py), and its upright solvers use the same ``Ry`` and x-z translation.
PoseLib is an optional dependency (``pip install 'planar_vo[bench]'``), imported inside the
functions that need it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from planar_vo.core.checks import as_array, same_length
from planar_vo.core.conventions import planar_motion_from_pose, rotation_y, translation_direction
from planar_vo.core.solvers import _cheirality_flip, solve_2pc
from planar_vo.errors import InputError

__all__ = [
    'PoseEstimate',
    'estimate_2pc_ransac',
    'estimate_5pc_opencv',
    'estimate_5pc_poselib',
    'estimate_6pc_focal_poselib',
    'planar_sampson_errors',
    'ransac_iterations',
    'solve_2pc_poselib',
    'solve_5pc_poselib',
    'solve_6pc_focal_poselib',
]

# Roots a minimal solver can return at most: the NaN-padded width of the solve_* outputs.
MAX_ROOTS = {'2pc': 2, '5pc': 10, '6pc': 15}
TWO_PC_SOLVERS = ('poselib', 'planar_vo')


@dataclass(frozen=True)
class PoseEstimate:
    """A relative pose ``X2 = R X1 + t`` from a peer estimator.

    Attributes:
        alpha, beta: planar projection of the pose (radians); NaN if the estimator failed.
        R: rotation (3x3), t: unit translation (3,); NaN-filled on failure.
        inliers: bool mask over the input correspondences, shape ``(N,)``.
        focal: estimated focal length in pixels (shared-focal estimators), else NaN.
        iterations: RANSAC iterations run (-1 where the peer does not report it).
    """

    alpha: float
    beta: float
    R: np.ndarray
    t: np.ndarray
    inliers: np.ndarray
    focal: float = math.nan
    iterations: int = field(default=-1)

    @property
    def ok(self) -> bool:
        """Whether the estimator returned a pose."""
        return bool(np.isfinite(self.alpha) and np.isfinite(self.beta))


def _failed(n: int) -> PoseEstimate:
    return PoseEstimate(np.nan, np.nan, np.full((3, 3), np.nan), np.full(3, np.nan),
                        np.zeros(n, dtype=bool))


def _pose_estimate(R: np.ndarray, t: np.ndarray, inliers: np.ndarray, **extra) -> PoseEstimate:
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64).ravel()
    norm = np.linalg.norm(t)
    if not (norm > 0.0 and np.all(np.isfinite(R))):
        return _failed(len(inliers))
    alpha, beta = planar_motion_from_pose(R, t)
    return PoseEstimate(float(alpha), float(beta), R, t / norm, np.asarray(inliers, bool), **extra)


def _check_correspondences(q1, q2, min_items: int) -> tuple[np.ndarray, np.ndarray, int]:
    q1 = as_array('q1', q1, (None, 2), min_items=min_items)
    q2 = as_array('q2', q2, (None, 2), min_items=min_items)
    return q1, q2, same_length(q1=q1, q2=q2)


def _check_ransac(threshold: float, confidence: float, max_iters: int) -> None:
    if not threshold > 0.0:
        raise InputError(f'threshold: expected a positive inlier threshold, got {threshold}')
    if not 0.0 < confidence < 1.0:
        raise InputError(f'confidence: expected a probability in (0, 1), got {confidence}')
    if max_iters < 1:
        raise InputError(f'max_iters: expected at least 1 iteration, got {max_iters}')


def ransac_iterations(outlier_ratio: float | np.ndarray, sample_size: int,
                      confidence: float = 0.99) -> np.ndarray:
    """RANSAC iterations needed to draw one all-inlier sample with probability ``confidence``.

    ``k = ceil(log(1 - p) / log(1 - w^m))`` with inlier ratio ``w = 1 - outlier_ratio`` and
    sample size ``m`` (Fischler and Bolles 1981; Hajder and Barath, Table "computational
    complexity"). Zero outliers need one iteration; an outlier ratio of 1 needs infinitely many.

    Args:
        outlier_ratio: fraction of outliers in ``[0, 1]``, any shape.
        sample_size: correspondences per minimal sample (>= 1).
        confidence: required probability of success in ``(0, 1)``.

    Returns:
        Iterations (float array of the shape of ``outlier_ratio``; ``inf`` for ratio 1).
    """
    eps = np.asarray(outlier_ratio, dtype=np.float64)
    if sample_size < 1:
        raise InputError(f'sample_size: expected at least 1, got {sample_size}')
    if not 0.0 < confidence < 1.0:
        raise InputError(f'confidence: expected a probability in (0, 1), got {confidence}')
    if np.any((eps < 0.0) | (eps > 1.0)) or not np.all(np.isfinite(eps)):
        raise InputError(f'outlier_ratio: expected values in [0, 1], got {eps.tolist()}')
    good = (1.0 - eps) ** sample_size
    with np.errstate(divide='ignore'):
        k = np.log1p(-confidence) / np.log1p(-np.minimum(good, 1.0 - 1e-16))
    # The ratio is computed in floating point: 16.0000001 must not become 17.
    k = np.ceil(np.round(k, 9))
    return np.where(good >= 1.0, 1.0, np.where(good <= 0.0, np.inf, np.maximum(k, 1.0)))


# --------------------------------------------------------------------------------------------
# OpenCV
# --------------------------------------------------------------------------------------------

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

    q1, q2, n = _check_correspondences(q1, q2, 5)
    method = cv2.RANSAC if ransac else cv2.LMEDS
    E, mask = cv2.findEssentialMat(q1, q2, np.eye(3), method=method, prob=confidence,
                                   threshold=threshold, maxIters=max_iters)
    if E is None or E.shape[0] < 3:
        return _failed(n)
    # With few points OpenCV may stack several candidate matrices; recoverPose takes the first.
    E = E[:3]
    mask = np.ones((n, 1), np.uint8) if mask is None else mask
    _, R, t, pose_mask = cv2.recoverPose(E, q1, q2, np.eye(3), mask=mask.copy())
    inliers = (pose_mask.ravel() > 0) if pose_mask is not None else mask.ravel() > 0
    return _pose_estimate(R, t, inliers)


# --------------------------------------------------------------------------------------------
# PoseLib
# --------------------------------------------------------------------------------------------

def _poselib():
    try:
        import poselib
    except ImportError as err:
        raise ImportError("poselib is not installed: pip install 'planar_vo[bench]'") from err
    return poselib


def _bearings(q: np.ndarray) -> np.ndarray:
    """Unit bearing vectors of image points ``(..., 2)``: PoseLib's minimal solvers expect unit
    vectors (with ``[u, v, 1]`` its upright planar solver drops valid roots in its cheirality
    check; measured: the true root missing in 57% of exact samples)."""
    x = np.concatenate([q, np.ones(q.shape[:-1] + (1,))], axis=-1)
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


# PoseLib's identity camera: its thresholds are then in the units of the points (normalised).
_IDENTITY_CAMERA = {'model': 'PINHOLE', 'width': 2, 'height': 2, 'params': [1.0, 1.0, 0.0, 0.0]}


def _poselib_options(threshold: float, confidence: float, max_iters: int, min_iters: int
                     ) -> tuple[dict, dict]:
    """RANSAC and bundle options for PoseLib; the robust loss scale follows the threshold, as
    PoseLib's defaults do (both 1 px)."""
    ransac = {'max_epipolar_error': threshold, 'success_prob': confidence,
              'max_iterations': max_iters, 'min_iterations': min(min_iters, max_iters)}
    return ransac, {'loss_scale': threshold}


def estimate_5pc_poselib(q1: np.ndarray, q2: np.ndarray, *, threshold: float = 1e-3,
                         confidence: float = 0.999, max_iters: int = 1000,
                         min_iters: int = 0) -> PoseEstimate:
    """PoseLib's relative pose: five-point RANSAC, local optimisation, bundle refinement.

    ``poselib.estimate_relative_pose`` on identity (normalised) cameras; the robust (Cauchy)
    loss of the refinement uses the inlier threshold as its scale.

    Args:
        q1, q2: normalised image coordinates, shape ``(N, 2)``, ``N >= 5``.
        threshold: Sampson-error inlier threshold in normalised units (pixels / focal length).
        confidence: RANSAC success probability (PoseLib's default is 0.9999).
        max_iters: RANSAC iteration cap.
        min_iters: RANSAC minimum iterations (PoseLib's default is 1000; 0 lets it stop as soon
            as ``confidence`` is reached, like OpenCV).

    Returns:
        A `PoseEstimate` with PoseLib's inlier mask and iteration count.
    """
    poselib = _poselib()
    q1, q2, n = _check_correspondences(q1, q2, 5)
    _check_ransac(threshold, confidence, max_iters)
    ransac, bundle = _poselib_options(threshold, confidence, max_iters, min_iters)
    pose, info = poselib.estimate_relative_pose(q1, q2, _IDENTITY_CAMERA, _IDENTITY_CAMERA,
                                                ransac, bundle)
    if not info.get('num_inliers', 0):
        return _failed(n)
    return _pose_estimate(pose.R, pose.t, np.asarray(info['inliers'], bool),
                          iterations=int(info.get('iterations', -1)))


def estimate_6pc_focal_poselib(p1: np.ndarray, p2: np.ndarray, *, threshold: float = 1.0,
                               confidence: float = 0.999, max_iters: int = 1000,
                               min_iters: int = 0) -> PoseEstimate:
    """PoseLib's shared-focal relative pose: six-point RANSAC and refinement of pose and focal.

    ``poselib.estimate_shared_focal_relative_pose`` with the principal point at the origin.

    Args:
        p1, p2: pixel coordinates relative to the principal point, shape ``(N, 2)``, ``N >= 6``.
        threshold: inlier threshold in pixels (also the robust loss scale).
        confidence, max_iters, min_iters: RANSAC options, as in `estimate_5pc_poselib`.

    Returns:
        A `PoseEstimate` with ``focal`` in pixels.
    """
    poselib = _poselib()
    p1, p2, n = _check_correspondences(p1, p2, 6)
    _check_ransac(threshold, confidence, max_iters)
    ransac, bundle = _poselib_options(threshold, confidence, max_iters, min_iters)
    pair, info = poselib.estimate_shared_focal_relative_pose(p1, p2, np.zeros(2), ransac, bundle)
    focal = float(pair.camera1.focal())
    if not info.get('num_inliers', 0) or not (np.isfinite(focal) and focal > 0.0):
        return _failed(n)
    return _pose_estimate(pair.pose.R, pair.pose.t, np.asarray(info['inliers'], bool),
                          focal=focal, iterations=int(info.get('iterations', -1)))


def _per_sample(solver, x1: np.ndarray, x2: np.ndarray, width: int):
    """Call a PoseLib minimal solver once per sample; stack its roots NaN-padded to ``width``."""
    n = x1.shape[0]
    R = np.full((n, width, 3, 3), np.nan)
    t = np.full((n, width, 3), np.nan)
    focal = np.full((n, width), np.nan)
    # One C++ call per sample: PoseLib's Python binding solves a single sample per call.
    for i in range(n):
        for j, sol in enumerate(solver(x1[i], x2[i])[:width]):
            pose = getattr(sol, 'pose', sol)
            R[i, j], t[i, j] = pose.R, pose.t
            if hasattr(sol, 'camera1'):
                focal[i, j] = sol.camera1.focal()
    norm = np.linalg.norm(t, axis=-1, keepdims=True)
    return R, t / np.where(norm > 0.0, norm, np.nan), focal


def _check_samples(q1, q2, k: int) -> tuple[np.ndarray, np.ndarray]:
    q1 = as_array('q1', q1, (None, k, 2))
    q2 = as_array('q2', q2, (None, k, 2))
    same_length(q1=q1, q2=q2)
    return q1, q2


def solve_2pc_poselib(q1: np.ndarray, q2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """PoseLib's upright planar two-point solver (``relpose_upright_planar_2pt``) per sample.

    Args:
        q1, q2: normalised coordinates, shape ``(N, 2, 2)``: N samples of two points.

    Returns:
        ``alpha, beta`` (radians), each ``(N, 2)``: up to two roots per sample, NaN-padded
        (the same layout as `planar_vo.core.solve_2pc`).
    """
    poselib = _poselib()
    q1, q2 = _check_samples(q1, q2, 2)
    R, t, _ = _per_sample(poselib.relpose_upright_planar_2pt, _bearings(q1), _bearings(q2),
                          MAX_ROOTS['2pc'])
    return planar_motion_from_pose(R, t)


def solve_5pc_poselib(q1: np.ndarray, q2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """PoseLib's five-point solver (Nister; ``relpose_5pt``) per sample, all roots.

    Args:
        q1, q2: normalised coordinates, shape ``(N, 5, 2)``.

    Returns:
        ``R`` ``(N, 10, 3, 3)`` and unit ``t`` ``(N, 10, 3)``, NaN-padded.
    """
    poselib = _poselib()
    q1, q2 = _check_samples(q1, q2, 5)
    R, t, _ = _per_sample(poselib.relpose_5pt, _bearings(q1), _bearings(q2),
                          MAX_ROOTS['5pc'])
    return R, t


def solve_6pc_focal_poselib(p1: np.ndarray, p2: np.ndarray
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """PoseLib's six-point shared-focal solver (``shared_focal_relpose_6pt``) per sample.

    Args:
        p1, p2: pixel coordinates relative to the principal point, shape ``(N, 6, 2)``.

    Returns:
        ``R`` ``(N, 15, 3, 3)``, unit ``t`` ``(N, 15, 3)`` and ``focal`` ``(N, 15)`` (pixels),
        NaN-padded. Six points on one plane are a degenerate configuration for this solver: it
        then often returns no root or a wrong focal length.
    """
    poselib = _poselib()
    p1, p2 = _check_samples(p1, p2, 6)
    # Pixels are scaled to unit RMS first (as `solve_1acf` does) and the focal scaled back.
    scale = float(np.sqrt(np.mean(p1 ** 2) + np.mean(p2 ** 2))) or 1.0
    R, t, focal = _per_sample(poselib.shared_focal_relpose_6pt, _bearings(p1 / scale),
                              _bearings(p2 / scale), MAX_ROOTS['6pc'])
    return R, t, focal * scale


# --------------------------------------------------------------------------------------------
# Planar two-point RANSAC
# --------------------------------------------------------------------------------------------

def planar_sampson_errors(q1: np.ndarray, q2: np.ndarray, alpha: np.ndarray, beta: np.ndarray
                          ) -> np.ndarray:
    """Sampson distances of points ``(N, 2)`` to planar motions ``(H,)``; returns ``(H, N)``.

    With ``E = [t]x Ry(alpha)`` (`planar_vo.core.planar_essential`):
    ``E q1 = [-sb v1, sab u1 - cab, cb v1]``, ``E^T q2 = [sab v2, cb - sb u2, -cab v2]`` and the
    Sampson distance is ``|q2^T E q1| / sqrt((E q1)_1^2 + (E q1)_2^2 + (E^T q2)_1^2 +
    (E^T q2)_2^2)`` (Hartley and Zisserman, eq. 11.9), in normalised units.
    """
    sb, cb = np.sin(beta)[:, None], np.cos(beta)[:, None]
    sab, cab = np.sin(alpha + beta)[:, None], np.cos(alpha + beta)[:, None]
    u1, v1, u2, v2 = q1[:, 0], q1[:, 1], q2[:, 0], q2[:, 1]
    l0, l1 = -sb * v1, sab * u1 - cab                  # E q1, first two entries
    m0, m1 = sab * v2, cb - sb * u2                    # E^T q2, first two entries
    r = u2 * l0 + v2 * l1 + cb * v1
    with np.errstate(divide='ignore', invalid='ignore'):
        return np.abs(r) / np.sqrt(l0 * l0 + l1 * l1 + m0 * m0 + m1 * m1)


def estimate_2pc_ransac(q1: np.ndarray, q2: np.ndarray, *, solver: str = 'poselib',
                        threshold: float = 1e-3, confidence: float = 0.999,
                        max_iters: int = 1000, batch: int = 32,
                        rng: np.random.Generator | None = None) -> PoseEstimate:
    """Planar motion by RANSAC over two-point samples (no local optimisation).

    Samples are drawn in batches of ``batch``; every root of every sample is scored against all
    points at once (`planar_sampson_errors`, ``(hypotheses, N)``), the hypothesis with most
    inliers (ties: smaller truncated error sum) is kept, and the number of iterations adapts to
    the best inlier ratio (`ransac_iterations`). The result is the best minimal hypothesis: no
    refinement on its inliers (only the sign of ``t``, which the Sampson error cannot see, is
    decided by all inliers' cheirality), so differences between ``solver`` values are the
    solvers'.

    Args:
        q1, q2: normalised coordinates, shape ``(N, 2)``, ``N >= 2``.
        solver: ``'poselib'`` (PoseLib's ``relpose_upright_planar_2pt``, one Python call per
            sample) or ``'planar_vo'`` (`planar_vo.core.solve_2pc`, vectorised per batch).
        threshold: Sampson-distance inlier threshold in normalised units.
        confidence: required probability of drawing an all-inlier sample.
        max_iters: cap on the number of samples.
        batch: samples per batch (the iteration count is rounded up to whole batches).
        rng: random generator (default: seeded with 0, for repeatable runs).

    Returns:
        A `PoseEstimate` (``R = Ry(alpha)``) with the inlier mask and the samples drawn.
    """
    if solver not in TWO_PC_SOLVERS:
        raise InputError(f"solver: expected one of {TWO_PC_SOLVERS}, got '{solver}'")
    q1, q2, n = _check_correspondences(q1, q2, 2)
    _check_ransac(threshold, confidence, max_iters)
    solve = solve_2pc_poselib if solver == 'poselib' else solve_2pc
    rng = np.random.default_rng(0) if rng is None else rng
    best = (-1, np.inf, np.nan, np.nan)                      # inliers, score, alpha, beta
    needed, done = float(max_iters), 0
    while done < min(needed, max_iters):
        m = int(min(batch, max_iters - done))
        i = rng.integers(0, n, (m, 2))
        i[:, 1] = (i[:, 0] + rng.integers(1, n, m)) % n      # two distinct points per sample
        alpha, beta = (x.ravel() for x in solve(q1[i], q2[i]))
        ok = np.isfinite(alpha) & np.isfinite(beta)
        done += m
        if not ok.any():
            continue
        err = planar_sampson_errors(q1, q2, alpha[ok], beta[ok])
        inl = err < threshold
        count = inl.sum(axis=1)
        score = np.where(inl, err, threshold).sum(axis=1)     # MSAC-style tie break
        k = int(np.lexsort((score, -count))[0])
        if (count[k], -score[k]) > (best[0], -best[1]):
            best = (int(count[k]), float(score[k]), alpha[ok][k], beta[ok][k])
            needed = float(ransac_iterations(1.0 - best[0] / n, 2, confidence))
    if best[0] < 2:
        return _failed(n)
    a, b = best[2], best[3]
    inliers = planar_sampson_errors(q1, q2, np.array([a]), np.array([b]))[0] < threshold
    # The Sampson error cannot tell t from -t, and a sample's two points can vote the sign
    # wrong: all inliers decide it.
    if _cheirality_flip(q1[inliers][None], q2[inliers][None], np.array([a]), np.array([b]))[0]:
        b = float(np.arctan2(-np.sin(b), -np.cos(b)))
    return PoseEstimate(float(a), float(b), rotation_y(a), translation_direction(b), inliers,
                        iterations=done)
