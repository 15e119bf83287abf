"""Exact ground truth for rendered views: surface points, affine correspondences, planar motion.

For a pixel ``p1`` of view 1 that sees plane ``n . X1 = d`` (camera-1 frame), the image-1 ->
image-2 map is

    p1 -> q1 = undistort(K^-1 p1) -> q2 = pi(H [q1; 1]),  H = R + t n^T / d -> p2 = K distort(q2)

with ``X2 = R X1 + t`` (``T_cam2_cam1 = inv(T_odom_cam2) @ T_odom_cam1``). Its Jacobian, the
exact local affine, is by the chain rule ``A = J_p2(q2) J_H(q1) J_q1(p1)`` with
``J_H = (H[:2, :2] - q2 H[2, :2]) / (H [q1; 1])_z`` (`planar_vo.core.homography`).
Visibility uses the same culling as `planar_vo.sim.render`, so an AC is valid exactly when the
surface point is drawn in both views.
"""

from __future__ import annotations

import numpy as np

from planar_vo.core.camera import CameraModel
from planar_vo.core.checks import as_array
from planar_vo.core.conventions import invert, planar_motion_from_pose
from planar_vo.core.correspondences import AffineCorrespondences
from planar_vo.errors import InputError
from planar_vo.sim.renderer import NEAR, _visible
from planar_vo.sim.world import StreetWorld

__all__ = ['backproject', 'cast_rays', 'exact_acs', 'relative_planar_motion']

# A point is visible in view 2 when the first surface along its ray there is at its depth.
_OCCLUSION_RTOL = 1e-6


def cast_rays(world: StreetWorld, T_odom_camera: np.ndarray, q: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    """First surface along the rays ``[q, 1]`` (ideal normalised coordinates, camera frame).

    Args:
        world: the scene.
        T_odom_camera: camera pose (4x4).
        q: normalised coordinates, shape ``(N, 2)``; NaN rows hit nothing.

    Returns:
        ``plane`` (N,) int: world plane index or -1 (sky), and ``depth`` (N,) ``z`` in the camera
        frame (m; inf where nothing is hit). Float64; same culling as `render`.
    """
    T = as_array('T_odom_camera', T_odom_camera, (4, 4))
    q = as_array('q', q, (None, 2), min_items=0, finite=False)
    vis = _visible(world, T)
    n = len(q)
    best = np.zeros(n)                                   # inverse depth of the nearest hit
    plane = np.full(n, -1)
    good = np.flatnonzero(np.isfinite(q).all(1))
    if good.size:
        # Bin the points on a grid over q so that each plane tests only the points in the bins
        # its projection's bounding box overlaps (sorted by bin: one slice per grid row).
        bins = int(np.clip(np.sqrt(good.size / 32.0), 1, 64))
        lo, hi = q[good].min(axis=0), q[good].max(axis=0)
        width = np.maximum(hi - lo, 1e-12) / bins
        cell = np.clip(((q[good] - lo) / width).astype(np.int64), 0, bins - 1)
        key = cell[:, 1] * bins + cell[:, 0]
        order = np.argsort(key, kind='stable')
        points = good[order]
        edges = np.searchsorted(key[order], np.arange(bins * bins + 1))
        first = np.clip(np.floor((vis.qlo - lo) / width), 0, bins - 1).astype(np.int64)
        last = np.clip(np.floor((vis.qhi - lo) / width), 0, bins - 1).astype(np.int64)
        overlap = np.all((vis.qhi >= lo) & (vis.qlo <= hi), axis=1)
        r = np.column_stack([q, np.ones(n)])
        for k in np.flatnonzero(overlap):
            (x0, y0), (x1, y1) = first[k], last[k]
            sel = np.concatenate([points[edges[y * bins + x0]:edges[y * bins + x1 + 1]]
                                  for y in range(y0, y1 + 1)])
            aw, bw, iw = vis.g[k] @ r[sel].T
            m = ((iw > best[sel]) & (iw <= 1.0 / NEAR) & (aw >= 0) & (bw >= 0)
                 & (aw <= iw * vis.size[k, 0]) & (bw <= iw * vis.size[k, 1]))
            best[sel[m]] = iw[m]
            plane[sel[m]] = vis.index[k]
    with np.errstate(divide='ignore'):
        depth = np.where(plane >= 0, 1.0 / best, np.inf)
    return plane, depth


def backproject(world: StreetWorld, camera: CameraModel, T_odom_camera: np.ndarray,
                pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The surface points seen at ``pixels`` ``(N, 2)``: odom points ``(N, 3)`` (NaN for sky)
    and plane indices ``(N,)`` (-1 for sky)."""
    T = as_array('T_odom_camera', T_odom_camera, (4, 4))
    p = as_array('pixels', pixels, (None, 2), min_items=0)
    q, _ = camera.pixel_to_normalized(p)
    plane, depth = cast_rays(world, T, q)
    hit = plane >= 0
    X = np.column_stack([q, np.ones(len(q))]) * np.where(hit, depth, np.nan)[:, None]
    X[hit] = X[hit] @ T[:3, :3].T + T[:3, 3]
    return X, plane


def exact_acs(world: StreetWorld, T_odom_camera1: np.ndarray, T_odom_camera2: np.ndarray,
              camera: CameraModel, pixels: np.ndarray, camera2: CameraModel | None = None
              ) -> tuple[AffineCorrespondences, np.ndarray]:
    """Exact affine correspondences of image-1 pixels between two rendered views.

    Args:
        world: the scene.
        T_odom_camera1, T_odom_camera2: camera poses (4x4).
        camera: camera model of view 1 (and of view 2 unless ``camera2`` is given).
        pixels: points ``p1`` in image 1, shape ``(N, 2)`` (pixel centres are integers).

    Returns:
        ``(acs, valid)``: `AffineCorrespondences` with ``p1 = pixels``, ``p2`` the projection
        of the surface point seen at ``p1`` into view 2 and ``A = dp2/dp1`` (pixels, distortion
        included by the chain rule), and ``valid`` (N,) bool: False for sky, points behind
        camera 2, outside image 2 or occluded there. Invalid items hold ``p2 = p1``, ``A = I``
        and weight 0 (``acs.subset(valid)`` drops them).
    """
    T1 = as_array('T_odom_camera1', T_odom_camera1, (4, 4))
    T2 = as_array('T_odom_camera2', T_odom_camera2, (4, 4))
    p1 = as_array('pixels', pixels, (None, 2), min_items=0)
    camera2 = camera if camera2 is None else camera2
    for name, cam in (('camera', camera), ('camera2', camera2)):
        if not isinstance(cam, CameraModel):
            raise InputError(f'{name}: expected a CameraModel, got {type(cam).__name__}')
    n = len(p1)
    q1, Jq1 = camera.pixel_to_normalized(p1)
    plane, z1 = cast_rays(world, T1, q1)
    valid = plane >= 0
    T21 = invert(T2) @ T1
    R, t = T21[:3, :3], T21[:3, 3]
    r1 = np.column_stack([np.where(valid[:, None], q1, 0.0), np.ones(n)])
    X1 = r1 * np.where(valid, z1, 1.0)[:, None]
    X2 = X1 @ R.T + t
    valid &= X2[:, 2] > NEAR
    z2 = np.where(valid, X2[:, 2], 1.0)
    q2 = X2[:, :2] / z2[:, None]
    p2, Jp2 = camera2.normalized_to_pixel(q2)
    valid &= ((p2[:, 0] >= 0) & (p2[:, 0] <= camera2.width - 1)
              & (p2[:, 1] >= 0) & (p2[:, 1] <= camera2.height - 1))
    if camera2.is_distorted:
        # Beyond the calibrated field a distortion polynomial folds back; such p2 are not images
        # of q2 under the renderer's per-pixel undistortion.
        back, _ = camera2.pixel_to_normalized(np.where(valid[:, None], p2, 0.0))
        valid &= np.linalg.norm(np.nan_to_num(back - q2, nan=np.inf), axis=1) < 1e-9
    plane2, depth2 = cast_rays(world, T2, np.where(valid[:, None], q2, np.nan))
    valid &= np.abs(depth2 - z2) <= _OCCLUSION_RTOL * z2
    # Plane-induced homography in normalised coordinates, per point: H = R + t m^T with
    # m = n / d for the plane n . X1 = d of each point in camera-1 coordinates; its Jacobian
    # at q1 is (H[:2, :2] - q2 H[2, :2]) / (H [q1; 1])_z. Written out per element: stacks of
    # tiny matrices are slow in numpy.
    idx = np.maximum(plane, 0)
    normal = world.normal[idx]
    d = np.einsum('ij,ij->i', normal, world.origin[idx] - T1[:3, 3])
    m = (normal @ T1[:3, :3]) / np.where(valid, d, 1.0)[:, None]        # odom -> camera 1
    hz = r1 @ R[2] + t[2] * np.einsum('ij,ij->i', m, r1)
    JH = np.empty((n, 2, 2))
    for i in range(2):
        for j in range(2):
            JH[:, i, j] = (R[i, j] + t[i] * m[:, j] - q2[:, i] * (R[2, j] + t[2] * m[:, j])) / hz
    A = _matmul2(_matmul2(Jp2, JH), Jq1)
    eye = np.broadcast_to(np.eye(2), (n, 2, 2))
    ok = valid[:, None]
    acs = AffineCorrespondences(p1, np.where(ok, p2, p1), np.where(ok[..., None], A, eye),
                                valid.astype(np.float64))
    return acs, valid


def _matmul2(X: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """Products of stacks of 2x2 matrices ``(N, 2, 2)``, element-wise (fast for large N)."""
    Z = np.empty(np.broadcast_shapes(X.shape, Y.shape))
    for i in range(2):
        for j in range(2):
            Z[..., i, j] = X[..., i, 0] * Y[..., 0, j] + X[..., i, 1] * Y[..., 1, j]
    return Z


def relative_planar_motion(T_odom_camera1: np.ndarray, T_odom_camera2: np.ndarray
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """True camera motion between two views in planar_vo's convention ``X2 = Ry(alpha) X1 + t``.

    ``T_cam2_cam1 = inv(T_odom_camera2) @ T_odom_camera1`` gives ``(R, t)``;
    `planar_vo.core.planar_motion_from_pose` projects it onto ``(alpha, beta)``.

    Args:
        T_odom_camera1, T_odom_camera2: poses ``(..., 4, 4)``.

    Returns:
        ``alpha, beta`` (rad) and ``scale = |t|`` (m), each of shape ``(...)``; ``beta`` is NaN
        where the camera did not move (``scale == 0``).
    """
    T1 = np.asarray(T_odom_camera1, dtype=np.float64)
    T2 = np.asarray(T_odom_camera2, dtype=np.float64)
    if T1.shape[-2:] != (4, 4) or T2.shape[-2:] != (4, 4):
        raise InputError(f'T_odom_camera1, T_odom_camera2: expected (..., 4, 4) poses, got '
                         f'{T1.shape} and {T2.shape}')
    T21 = invert(T2) @ T1
    alpha, beta = planar_motion_from_pose(T21[..., :3, :3], T21[..., :3, 3])
    scale = np.linalg.norm(T21[..., :3, 3], axis=-1)
    return alpha, np.where(scale > 0.0, beta, np.nan), scale
