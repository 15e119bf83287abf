"""Make ACs those of an ideal, level pinhole camera: undistortion and mount levelling.

Both corrections are smooth per-image point maps ``g`` and act on an AC by the chain rule
(`AffineCorrespondences.transformed`):

    p1' = g(p1),  p2' = g(p2),  A' = J_g(p2) A J_g(p1)^-1

- Undistortion: distorted pixels -> pixels of the ideal pinhole camera with the same ``K``,
  ``p' = K undistort(K^-1 p)`` (`planar_vo.core.camera.CameraModel`, ``plumb_bob``,
  ``rational_polynomial`` or ``equidistant``).
- Levelling (`leveling_rotation`, applied by `AffineCorrespondences.mapped`: to normalised ACs
  as the pipeline does, or to pixels by `level_acs`): the camera is mounted with pitch and roll
  (`planar_vo.config.MountConfig`: the optical frame rotated by ``Rz(yaw) Ry(pitch) Rx(roll)``
  about the base_link axes; positive pitch looks down). The level camera has the same centre
  and yaw but zero pitch and roll, so its y axis is vertical and vehicle motion on a plane is
  exactly planar for it. A point seen
  by the real camera at ``X_c`` is ``X_l = R_lc X_c`` in the level camera, with
  ``R_lc = R_BO^T Ry(pitch) Rx(roll) R_BO`` (``R_BO`` = `R_BASE_OPTICAL`; the yaw cancels), and
  pixels map by the rotation homography ``H = K R_lc K^-1``.
"""

from __future__ import annotations

import numpy as np

from planar_vo.core.camera import CameraModel
from planar_vo.core.checks import as_array
from planar_vo.core.conventions import R_BASE_OPTICAL, rotation_rpy
from planar_vo.core.correspondences import AffineCorrespondences

__all__ = [
    'correct_acs',
    'level_acs',
    'leveling_homography',
    'leveling_rotation',
    'undistort_acs',
    'undistortion_map',
]


def undistortion_map(camera: CameraModel):
    """The point map distorted pixels -> ideal pinhole pixels (same ``K``) with its Jacobian.

    Returns:
        A callable ``p (N, 2) -> (p' (N, 2), J (N, 2, 2))``; points outside the calibrated
        field (where undistortion does not converge) map to NaN.
    """
    L = camera.K[:2, :2]
    c = camera.K[:2, 2]

    def g(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        q, J = camera.pixel_to_normalized(p)
        return q @ L.T + c, L @ J

    return g


def undistort_acs(acs: AffineCorrespondences, camera: CameraModel) -> AffineCorrespondences:
    """ACs in pixels of the ideal (undistorted) pinhole camera with the same intrinsics.

    Args:
        acs: ACs in the camera's raw (distorted) pixels.
        camera: the calibrated camera (both images).

    Returns:
        The corrected ACs; those the undistortion sends outside its domain are dropped. An
        undistorted camera returns ``acs`` itself.
    """
    if not camera.is_distorted:
        return acs
    g = undistortion_map(camera)
    return acs.transformed(g, g)


def leveling_rotation(pitch: float, roll: float) -> np.ndarray:
    """``R_lc`` (3x3): camera-optical coordinates -> level-camera optical coordinates.

    ``R_lc = R_BO^T Ry(pitch) Rx(roll) R_BO`` with the base-axis rotations of `MountConfig`
    (radians; positive pitch looks down). The yaw of the mount does not enter.
    """
    return R_BASE_OPTICAL.T @ rotation_rpy(roll, pitch, 0.0) @ R_BASE_OPTICAL


def leveling_homography(K: np.ndarray, pitch: float, roll: float) -> np.ndarray:
    """``H = K R_lc K^-1``: pixels of the tilted camera -> pixels of the level camera."""
    K = as_array('K', K, (3, 3))
    return K @ leveling_rotation(pitch, roll) @ np.linalg.inv(K)


def level_acs(acs: AffineCorrespondences, K: np.ndarray, pitch: float, roll: float
              ) -> AffineCorrespondences:
    """ACs of the level camera from those of a camera mounted with ``pitch`` and ``roll``.

    Args:
        acs: ACs in ideal (undistorted) pixels of the tilted camera.
        K: intrinsics (3x3), kept for the level camera.
        pitch, roll: mount angles in radians (`MountConfig`; positive pitch looks down).

    Returns:
        ACs in pixels of the level camera: points by ``H = K R_lc K^-1``, affines by
        ``A' = J_H(p2) A J_H(p1)^-1`` (`homography_jacobian`). Points the homography sends to
        infinity (90 degrees of tilt) are dropped.
    """
    return acs.mapped(leveling_homography(K, pitch, roll))


def correct_acs(acs: AffineCorrespondences, camera: CameraModel, pitch: float = 0.0,
                roll: float = 0.0) -> AffineCorrespondences:
    """Undistort (`undistort_acs`) then level (`level_acs`): the ACs an ideal, level pinhole
    camera with intrinsics ``camera.K`` would have measured, in pixels."""
    acs = undistort_acs(acs, camera)
    if pitch == 0.0 and roll == 0.0:
        return acs
    return level_acs(acs, camera.K, pitch, roll)
