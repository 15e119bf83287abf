"""Synthetic affine correspondences with exact ground truth, including the paper's protocol.

Two generators, both seeded through a `numpy.random.Generator`:

- `random_exact_acs`: N independent exact ACs, each with its own random planar motion and its
  own random scene plane (for exact-recovery tests over thousands of cases).
- `paper_trial`: one trial of Hajder and Barath's synthetic experiment (section 4.2): ``f = 600``,
  principal point ``(300, 300)``, a random plane, 50 random points on it seen by both cameras,
  Gaussian noise ``sigma`` (pixels) on the point coordinates, and each AC's affine taken from the
  homography fitted to the noisy points. Optionally pure forward motion, or the planarity
  corrupted by tilting the second camera's vertical (``tilt_sigma_deg``).

Conventions: `planar_vo.core.conventions` (``X2 = Ry(alpha) X1 + t``).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from planar_vo.core.camera import CameraModel, intrinsic_matrix, normalize_points
from planar_vo.core.conventions import (
    R_BASE_OPTICAL,
    planar_motion_from_pose,
    rotation_rpy,
    rotation_y,
    so3_exp,
    translation_direction,
)
from planar_vo.core.correspondences import AffineCorrespondences
from planar_vo.core.homography import fit_homography, homography_jacobian
from planar_vo.errors import InputError

__all__ = [
    'PAPER_FOCAL',
    'PAPER_IMAGE_SIZE',
    'PAPER_PRINCIPAL_POINT',
    'SyntheticACs',
    'paper_trial',
    'random_exact_acs',
    'random_planar_motion',
    'shared_motion_acs',
    'street_pair',
]

PAPER_FOCAL = 600.0
PAPER_PRINCIPAL_POINT = (300.0, 300.0)
PAPER_IMAGE_SIZE = (600, 600)            # width, height: the principal point is the centre
MOTIONS = ('general', 'forward')


@dataclass(frozen=True)
class SyntheticACs:
    """Affine correspondences with their ground truth (what every generator here returns).

    Attributes:
        acs: the correspondences in pixels (noisy where noise was added, mismatches included).
        exact: the noise-free correspondences in pixels (mismatches keep their garbage).
        camera: the undistorted pinhole camera of both views.
        alpha, beta: true motion, shape ``()`` for one shared motion or ``(N,)`` per AC.
        R: true rotation of view 2 (``(3, 3)`` or ``(N, 3, 3)``); equals ``Ry(alpha)`` unless
            the planarity was corrupted.
        t: true unit translation (``(3,)`` or ``(N, 3)``).
        outliers: bool mask ``(N,)`` of the mismatches (`shared_motion_acs`; else all False).
        planes: the scene plane of each AC ``(N,)``: ACs of one plane share the error of its
            fitted homography (`shared_motion_acs`; else zeros).
        level: the rotation camera -> level camera of the scene's mount (`street_pair`; else
            the identity).
    """

    acs: AffineCorrespondences
    exact: AffineCorrespondences
    camera: CameraModel
    alpha: np.ndarray
    beta: np.ndarray
    R: np.ndarray
    t: np.ndarray
    outliers: np.ndarray | None = None
    planes: np.ndarray | None = None
    level: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = len(self.acs)
        if self.level is None:
            object.__setattr__(self, 'level', np.eye(3))
        if self.outliers is None:
            object.__setattr__(self, 'outliers', np.zeros(n, bool))
        if self.planes is None:
            object.__setattr__(self, 'planes', np.zeros(n, np.intp))

    def __len__(self) -> int:
        return len(self.acs)

    @cached_property
    def normalized(self) -> AffineCorrespondences:
        """The ACs in normalised coordinates (``q = K^-1 p``; affines likewise), the 1AC inputs."""
        return self.acs.normalized(self.camera)

    @property
    def centered(self) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates relative to the principal point (the 1ACf inputs), ``(N, 2)`` each."""
        c = self.camera.K[:2, 2]
        return self.acs.p1 - c, self.acs.p2 - c

    @property
    def K(self) -> np.ndarray:
        """The intrinsics of both views (3x3)."""
        return self.camera.K

    @property
    def focal(self) -> float:
        """The true focal length in pixels."""
        return self.camera.fx


def _make(K: np.ndarray, p1, p2, A, alpha, beta, R, t, p1_true, p2_true, A_true, **extra
          ) -> SyntheticACs:
    """A `SyntheticACs` from arrays; the image spans ``2 * (cx, cy)``."""
    width, height = (int(round(2.0 * v)) for v in K[:2, 2])
    return SyntheticACs(AffineCorrespondences(p1, p2, A), AffineCorrespondences(p1_true, p2_true,
                                                                                A_true),
                        CameraModel(max(width, 1), max(height, 1), K), np.asarray(alpha),
                        np.asarray(beta), R, t, **extra)


def paper_intrinsics(focal: float = PAPER_FOCAL) -> np.ndarray:
    """The paper's camera: ``fx = fy = focal``, principal point ``(300, 300)``."""
    return intrinsic_matrix(focal, focal, *PAPER_PRINCIPAL_POINT)


def random_planar_motion(rng: np.random.Generator, n: int | None = None, *,
                         max_yaw_deg: float = 30.0) -> tuple[np.ndarray, np.ndarray]:
    """Random planar motions: ``alpha`` uniform in ``+-max_yaw_deg``, ``beta`` uniform on the
    circle.

    Returns ``alpha, beta`` in radians, scalars (shape ``()``) when ``n`` is None.
    """
    size = () if n is None else (n,)
    alpha = rng.uniform(-1.0, 1.0, size) * np.deg2rad(max_yaw_deg)
    beta = rng.uniform(-np.pi, np.pi, size)
    return alpha, beta


def _random_unit_normals(rng: np.random.Generator, n: int, towards: np.ndarray,
                         max_angle_deg: float) -> np.ndarray:
    """Unit vectors within ``max_angle_deg`` of the unit vectors ``towards`` ``(n, 3)``."""
    v = rng.normal(size=(n, 3))
    v -= np.einsum('ni,ni->n', v, towards)[:, None] * towards
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    ang = np.deg2rad(max_angle_deg) * np.sqrt(rng.uniform(0.0, 1.0, n))
    return np.cos(ang)[:, None] * towards + np.sin(ang)[:, None] * v


def _project(K: np.ndarray, X: np.ndarray) -> np.ndarray:
    x = X @ K.T
    return x[..., :2] / x[..., 2:3]


def random_exact_acs(rng: np.random.Generator, n: int, *, K: np.ndarray | None = None,
                     max_yaw_deg: float = 45.0, depth_range: tuple[float, float] = (2.0, 20.0),
                     min_abs_v: float = 0.05) -> SyntheticACs:
    """N independent, noise-free ACs, each with its own planar motion and scene plane.

    Each item: a pixel uniform in the image, a depth uniform in ``depth_range`` (translation has
    unit length), a plane through that point whose normal is within 70 degrees of the viewing
    ray, and the exact affine ``J`` of the plane-induced homography at the pixel. Items whose
    point is not seen by camera 2 (depth below 0.5 or outside its image), or whose normalised
    ``v`` is within
    ``min_abs_v`` of the horizon row in either view, are redrawn: a point at the camera's height
    stays at it under planar motion, so at ``v = 0`` the epipolar row and the first affine row of
    the AC vanish and the AC is degenerate (the conditioning degrades like ``1 / v^2``).
    """
    if n < 1:
        raise InputError(f'n: expected at least 1 item, got {n}')
    K = paper_intrinsics() if K is None else np.asarray(K, dtype=np.float64)
    width, height = 2.0 * K[0, 2], 2.0 * K[1, 2]
    alpha = np.empty(n)
    beta = np.empty(n)
    X1 = np.empty((n, 3))
    normal = np.empty((n, 3))
    todo = np.arange(n)
    while todo.size:
        m = todo.size
        a, b = random_planar_motion(rng, m, max_yaw_deg=max_yaw_deg)
        pix = rng.uniform((0.0, 0.0), (width, height), (m, 2))
        ray = np.column_stack([normalize_points(K, pix), np.ones(m)])
        X = ray * rng.uniform(*depth_range, m)[:, None]
        unit_ray = ray / np.linalg.norm(ray, axis=1, keepdims=True)
        nrm = _random_unit_normals(rng, m, -unit_ray, 70.0)
        X2 = np.einsum('nij,nj->ni', rotation_y(a), X) + translation_direction(b)
        with np.errstate(divide='ignore', invalid='ignore'):
            pix2 = _project(K, X2)
        ok = ((X2[:, 2] > 0.5) & (np.abs(ray[:, 1]) >= min_abs_v)
              & (np.abs(X2[:, 1]) >= min_abs_v * np.abs(X2[:, 2]))
              & (pix2[:, 0] >= 0.0) & (pix2[:, 0] <= width)
              & (pix2[:, 1] >= 0.0) & (pix2[:, 1] <= height))
        alpha[todo[ok]], beta[todo[ok]] = a[ok], b[ok]
        X1[todo[ok]], normal[todo[ok]] = X[ok], nrm[ok]
        todo = todo[~ok]
    R = rotation_y(alpha)
    t = translation_direction(beta)
    distance = np.einsum('ni,ni->n', normal, X1)
    M = R + t[:, :, None] * normal[:, None, :] / distance[:, None, None]
    H = K @ M @ np.linalg.inv(K)                                   # (n, 3, 3) per-item homography
    p1 = _project(K, X1)
    h = np.einsum('nij,nj->ni', H, np.column_stack([p1, np.ones(n)]))
    p2 = h[:, :2] / h[:, 2:3]
    A = (H[:, :2, :2] - p2[:, :, None] * H[:, 2:3, :2]) / h[:, 2, None, None]
    return _make(K, p1, p2, A, alpha, beta, R, t, p1, p2, A)


def _small_rotation(rng: np.random.Generator, sigma_deg: float) -> np.ndarray:
    """Rotation about the camera's x and z axes by N(0, sigma) each: tilts the vertical (y) axis."""
    ax, az = np.deg2rad(rng.normal(0.0, sigma_deg, 2))
    cx, sx, cz, sz = np.cos(ax), np.sin(ax), np.cos(az), np.sin(az)
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]])
    Rz = np.array([[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]])
    return Rz @ Rx


def paper_trial(rng: np.random.Generator, sigma: float, *, n_points: int = 50,
                motion: str = 'general', tilt_sigma_deg: float = 0.0,
                focal: float = PAPER_FOCAL, max_yaw_deg: float = 30.0,
                plane_depth: tuple[float, float] = (4.0, 8.0), window: float | None = None,
                affine_sigma: float | None = None, _motion=None) -> SyntheticACs:
    """One trial of the paper's synthetic protocol (Hajder and Barath, section 4.2).

    A random plane (its normal within 60 degrees of the optical axis, through a point on the axis
    at a depth uniform in ``plane_depth``; the translation has unit length) carries ``n_points``
    points whose projections fall inside both 600x600 images. Zero-mean Gaussian noise of
    standard deviation ``sigma`` pixels is added to all point coordinates; the homography is then
    fitted to the noisy points (normalised DLT) and every AC's affine is its Jacobian at the
    noisy ``p1``.

    Args:
        rng: random generator (seed it for repeatable trials).
        sigma: point noise in pixels (>= 0).
        n_points: points on the plane (>= 4).
        motion: ``'general'`` (random planar motion) or ``'forward'`` (``alpha = 0``,
            ``beta = -pi/2``: straight ahead, no rotation).
        tilt_sigma_deg: if positive, the second camera's vertical is tilted by a random rotation
            with this standard deviation (corrupted planarity; the truth keeps the tilt in ``R``).
        focal: focal length in pixels (principal point stays at (300, 300)).
        max_yaw_deg: range of ``alpha`` for general motion.
        plane_depth: range of the plane's depth along the optical axis, in translation units.
        window: if given, the points are drawn in a random ``window x window`` pixel square of
            image 1 (a surface covers a region of the image) instead of the whole image.
        affine_sigma: if given, each affine is the exact one plus independent Gaussian noise of
            this standard deviation, instead of the Jacobian of the fitted homography.

    Returns:
        A `SyntheticACs` whose ``alpha``, ``beta``, ``R``, ``t`` are shared by all points.
    """
    if motion not in MOTIONS:
        raise InputError(f"motion: expected one of {MOTIONS}, got '{motion}'")
    if not (sigma >= 0.0) or n_points < 4:
        raise InputError(f'sigma >= 0 and n_points >= 4 expected, got sigma={sigma}, '
                         f'n_points={n_points}')
    K = paper_intrinsics(focal)
    width, height = PAPER_IMAGE_SIZE
    while True:
        if _motion is not None:
            alpha, beta = np.float64(_motion.alpha), np.float64(_motion.beta)
        elif motion == 'forward':
            alpha, beta = np.float64(0.0), np.float64(-np.pi / 2)
        else:
            alpha, beta = random_planar_motion(rng, max_yaw_deg=max_yaw_deg)
        R = rotation_y(alpha)
        if tilt_sigma_deg > 0.0:
            R = _small_rotation(rng, tilt_sigma_deg) @ R
        t = translation_direction(beta)
        normal = _random_unit_normals(rng, 1, np.array([[0.0, 0.0, -1.0]]), 60.0)[0]
        distance = float(normal @ np.array([0.0, 0.0, rng.uniform(*plane_depth)]))
        # Draw many pixels, keep those whose plane point is visible in both views.
        if window is None:
            lo, hi = np.zeros(2), np.array([width, height], float)
        else:
            lo = rng.uniform(0.0, 1.0, 2) * (np.array([width, height]) - window)
            hi = lo + window
        pix = rng.uniform(lo, hi, (20 * n_points, 2))
        ray = np.column_stack([normalize_points(K, pix), np.ones(len(pix))])
        depth = distance / (ray @ normal)
        X1 = ray * depth[:, None]
        X2 = X1 @ R.T + t
        with np.errstate(divide='ignore', invalid='ignore'):
            p2 = _project(K, X2)
        ok = ((depth > 0.5) & (X2[:, 2] > 0.5) & (p2[:, 0] >= 0) & (p2[:, 0] <= width)
              & (p2[:, 1] >= 0) & (p2[:, 1] <= height))
        if np.count_nonzero(ok) >= n_points:
            break
    p1_true = pix[ok][:n_points]
    p2_true = p2[ok][:n_points]
    H_true = K @ (R + np.outer(t, normal) / distance) @ np.linalg.inv(K)
    A_true = homography_jacobian(H_true, p1_true)
    p1 = p1_true + rng.normal(0.0, sigma, p1_true.shape) if sigma > 0 else p1_true.copy()
    p2 = p2_true + rng.normal(0.0, sigma, p2_true.shape) if sigma > 0 else p2_true.copy()
    if affine_sigma is not None:
        A = A_true + rng.normal(0.0, affine_sigma, A_true.shape)
    else:
        A = homography_jacobian(fit_homography(p1, p2), p1) if sigma > 0 else A_true.copy()
    return _make(K, p1, p2, A, alpha, beta, R, t, p1_true, p2_true, A_true)


def shared_motion_acs(rng: np.random.Generator, n: int, sigma: float, *,
                      outlier_ratio: float = 0.0, motion: str = 'general',
                      alpha: float | None = None, beta: float | None = None,
                      points_per_plane: int = 50, max_yaw_deg: float = 30.0,
                      window: float | None = None, affine_sigma: float | None = None,
                      plane_depth: tuple[float, float] = (4.0, 8.0)) -> SyntheticACs:
    """N ACs under ONE planar motion, from many random planes, with mismatches mixed in.

    The ACs come in groups of ``points_per_plane`` from independent `paper_trial` scenes that
    share the motion (so each group's affines come from the homography fitted to its own noisy
    points, as in the paper's protocol, unless ``affine_sigma`` is given). A fraction
    ``outlier_ratio`` of the ACs (chosen at random) is then replaced by mismatches: ``p2``
    uniform in image 2 and ``A`` an affine drawn around the identity (``I + N(0, 0.3^2)``), the
    kind of garbage a matcher produces.

    Args:
        rng: random generator.
        n: number of ACs (>= 1).
        sigma: point noise in pixels.
        outlier_ratio: fraction of mismatches, in ``[0, 1)``.
        motion: ``'general'`` or ``'forward'`` (ignored when ``alpha``/``beta`` are given).
        alpha, beta: the motion (radians); random when None.
        points_per_plane: ACs per plane (>= 4).
        max_yaw_deg: range of a random ``alpha``.
        window: side in pixels of the image square each plane's points are drawn in (None: the
            whole image). ACs of one plane share the error of its fitted homography, so their
            errors are correlated in a region of the image, as those of real neighbouring ACs are.
        affine_sigma, plane_depth: as for `paper_trial`.

    Returns:
        A `SyntheticACs` with shared ``alpha``/``beta``, its ``outliers`` mask and the
        ``planes`` index of every AC.
    """
    if n < 1 or not (0.0 <= outlier_ratio < 1.0):
        raise InputError(f'n >= 1 and 0 <= outlier_ratio < 1 expected, got n={n}, '
                         f'outlier_ratio={outlier_ratio}')
    if alpha is None or beta is None:
        if motion == 'forward':
            alpha, beta = 0.0, -np.pi / 2
        else:
            alpha, beta = (float(v) for v in random_planar_motion(rng, max_yaw_deg=max_yaw_deg))
    m = max(points_per_plane, 4)
    groups = [paper_trial(rng, sigma, n_points=m, window=window, affine_sigma=affine_sigma,
                          plane_depth=plane_depth, _motion=_FixedMotion(float(alpha), float(beta)))
              for _ in range(-(-n // m))]
    noisy = AffineCorrespondences.concatenate([g.acs for g in groups]).subset(slice(0, n))
    exact = AffineCorrespondences.concatenate([g.exact for g in groups]).subset(slice(0, n))
    p2, A = noisy.p2.copy(), noisy.A.copy()
    outliers = rng.permutation(n)[:int(round(outlier_ratio * n))]
    width, height = PAPER_IMAGE_SIZE
    p2[outliers] = rng.uniform((0.0, 0.0), (width, height), (outliers.size, 2))
    A[outliers] = np.eye(2) + rng.normal(0.0, 0.3, (outliers.size, 2, 2))
    mask = np.zeros(n, bool)
    mask[outliers] = True
    return SyntheticACs(AffineCorrespondences(noisy.p1, p2, A), exact, groups[0].camera,
                        np.asarray(alpha), np.asarray(beta), rotation_y(alpha),
                        translation_direction(beta), mask, np.repeat(np.arange(len(groups)), m)[:n])


@dataclass(frozen=True)
class _FixedMotion:
    alpha: float
    beta: float


# ------------------------------------------------------------------------------------------------
# A car's general (non-planar) motion in a street
# ------------------------------------------------------------------------------------------------

STREET_CAMERA = (1241, 376, 707.0912)       # width, height, focal: a KITTI-like camera


def street_pair(rng: np.random.Generator, n: int = 1000, *, outlier_ratio: float = 0.0,
                sigma_px: float = 0.3, sigma_affine: float = 0.01, max_yaw_deg: float = 5.0,
                tilt_deg: float = 0.1, heading_deg: float = 1.0, mount_pitch_deg: float = 1.0,
                step: float = 1.0, outlier_px: float = 60.0) -> SyntheticACs:
    """ACs of one frame pair of a car driving a street, in GENERAL (not planar) motion.

    Camera: KITTI-like (`STREET_CAMERA`, principal point at the centre), pitched down by
    ``mount_pitch_deg`` relative to the plane of motion (``level`` is its levelling rotation).
    Motion (level frame, y down): yaw uniform in ``+-max_yaw_deg``; the relative rotation's
    pitch and roll and the elevation of travel ``N(0, tilt_deg^2)`` (a car on its suspension
    and an uneven road); heading ``N(0, heading_deg^2)`` plus half the yaw; ``step`` metres.
    Scene: points on the road (1.65 m below the camera), on facades 4-8 m to each side and on
    random far planes (15-80 m); each AC is exact (its plane's homography Jacobian) plus
    Gaussian noise on the points (``sigma_px``) and the affine elements (``sigma_affine``).
    Outliers (``outlier_ratio``): ``p2 = p1 + U(-outlier_px, outlier_px)^2`` and
    ``A = I + N(0, 0.3^2)`` per element.

    Returns:
        A `SyntheticACs` with the true camera-frame ``R``, unit ``t`` and ``level``; ``alpha``
        and ``beta`` are the planar projection of the level-frame motion.
    """
    if n < 1 or not 0.0 <= outlier_ratio < 1.0:
        raise InputError(f'n >= 1 and 0 <= outlier_ratio < 1 expected, got n={n}, '
                         f'outlier_ratio={outlier_ratio}')
    width, height, f = STREET_CAMERA
    K = intrinsic_matrix(f, f, width / 2.0, height / 2.0)
    R_lc = rotation_rpy(0.0, np.deg2rad(mount_pitch_deg), 0.0)
    R_lc = R_BASE_OPTICAL.T @ R_lc @ R_BASE_OPTICAL           # camera -> level (pitched down)
    yaw = np.deg2rad(rng.uniform(-max_yaw_deg, max_yaw_deg))
    tilt = np.deg2rad(tilt_deg)
    wobble = so3_exp(np.array([rng.normal(0.0, tilt), 0.0, rng.normal(0.0, tilt)]))
    R_l = rotation_y(yaw) @ wobble
    heading = np.deg2rad(rng.normal(0.0, heading_deg)) + 0.5 * yaw
    elevation = rng.normal(0.0, tilt)
    c_l = step * np.array([np.sin(heading) * np.cos(elevation), np.sin(elevation),
                           np.cos(heading) * np.cos(elevation)])
    R = R_lc.T @ R_l @ R_lc
    t = -R @ (R_lc.T @ c_l)                                    # X2 = R X1 + t, metric
    # Surfaces n . X = d (camera-1 frame): road, left and right facades, far planes.
    kind = rng.choice(4, size=n, p=[0.35, 0.2, 0.2, 0.25])
    pix = np.column_stack([rng.uniform(20, width - 20, n), rng.uniform(20, height - 20, n)])
    rays = np.column_stack([normalize_points(K, pix), np.ones(n)])
    normal = np.empty((n, 3))
    dist = np.empty(n)
    normal[kind == 0] = R_lc.T @ np.array([0.0, 1.0, 0.0])
    dist[kind == 0] = 1.65
    for k, side in ((1, -1.0), (2, 1.0)):
        normal[kind == k] = R_lc.T @ np.array([side, 0.0, 0.0])
        dist[kind == k] = rng.uniform(4.0, 8.0, np.count_nonzero(kind == k))
    far = kind == 3
    nf = np.count_nonzero(far)
    nrm = rng.normal(size=(nf, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    nrm[nrm[:, 2] > 0] *= -1.0
    depth = rng.uniform(15.0, 80.0, nf)
    normal[far] = nrm
    dist[far] = -np.einsum('ni,ni->n', nrm, rays[far] / rays[far, 2:3] * depth[:, None])
    flip = far & (dist <= 0.5)
    normal[flip] *= -1.0
    dist[flip] *= -1.0
    with np.errstate(divide='ignore', invalid='ignore'):
        lam = dist / np.einsum('ni,ni->n', normal, rays)
    bad = ~((lam * rays[:, 2] > 0.5) & (lam * rays[:, 2] < 150.0))
    # Rays that miss their surface see a fronto-parallel plane 15-80 m away instead.
    normal[bad] = (0.0, 0.0, 1.0)
    dist[bad] = rng.uniform(15.0, 80.0, np.count_nonzero(bad))
    lam[bad] = dist[bad] / rays[bad, 2]
    X1 = lam[:, None] * rays
    X2 = X1 @ R.T + t
    with np.errstate(divide='ignore', invalid='ignore'):
        p2 = _project(K, X2)
        H = K @ (R[None] + t[None, :, None] * normal[:, None, :] / dist[:, None, None]) \
            @ np.linalg.inv(K)
        hp = np.einsum('nij,nj->ni', H, np.column_stack([pix, np.ones(n)]))
        A = (H[:, :2, :2] - (hp[:, :2] / hp[:, 2:3])[:, :, None] * H[:, 2:3, :2]) \
            / hp[:, 2, None, None]
    keep = ((X2[:, 2] > 0.5) & (p2[:, 0] > 0) & (p2[:, 0] < width) & (p2[:, 1] > 0)
            & (p2[:, 1] < height))
    p1_true, p2_true, A_true = pix[keep], p2[keep], A[keep]
    m = len(p1_true)
    p1 = p1_true + rng.normal(0.0, sigma_px, (m, 2))
    p2n = p2_true + rng.normal(0.0, sigma_px, (m, 2))
    An = A_true + rng.normal(0.0, sigma_affine, (m, 2, 2))
    outliers = np.zeros(m, bool)
    outliers[rng.permutation(m)[:int(round(outlier_ratio * m))]] = True
    k = int(outliers.sum())
    p2n[outliers] = p1[outliers] + rng.uniform(-outlier_px, outlier_px, (k, 2))
    An[outliers] = np.eye(2) + rng.normal(0.0, 0.3, (k, 2, 2))
    alpha, beta = planar_motion_from_pose(R_l, R_lc @ t)
    camera = CameraModel(width, height, K)
    return SyntheticACs(AffineCorrespondences(p1, p2n, An),
                        AffineCorrespondences(p1_true, p2_true, A_true), camera,
                        np.asarray(alpha), np.asarray(beta), R, t / np.linalg.norm(t),
                        outliers, kind[keep], R_lc)
