"""`AffineCorrespondences`: the one type every AC source returns (front-end, renderer,
synthetic data)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planar_vo._checks import as_array, same_length

__all__ = ['AffineCorrespondences']


@dataclass(frozen=True)
class AffineCorrespondences:
    """N affine correspondences between two images.

    Attributes:
        p1, p2: points in images 1 and 2, shape ``(N, 2)``, pixels unless stated otherwise.
        A: local affines, shape ``(N, 2, 2)``: the Jacobian of the image-1 -> image-2 map at
            ``p1``, in the same units as the points.
        weights: per-AC quality in ``[0, inf)``, shape ``(N,)`` (1 when unknown); used by voting.
    """

    p1: np.ndarray
    p2: np.ndarray
    A: np.ndarray
    weights: np.ndarray | None = None

    def __post_init__(self) -> None:
        p1 = as_array('p1', self.p1, (None, 2), min_items=0)
        p2 = as_array('p2', self.p2, (None, 2), min_items=0)
        A = as_array('A', self.A, (None, 2, 2), min_items=0)
        w = np.ones(len(p1)) if self.weights is None else as_array(
            'weights', self.weights, (None,), min_items=0)
        same_length(p1=p1, p2=p2, A=A, weights=w)
        for name, value in (('p1', p1), ('p2', p2), ('A', A), ('weights', w)):
            object.__setattr__(self, name, value)

    def __len__(self) -> int:
        return int(self.p1.shape[0])

    def subset(self, index: np.ndarray | slice) -> AffineCorrespondences:
        """The correspondences selected by a boolean mask, an index array or a slice."""
        return AffineCorrespondences(self.p1[index], self.p2[index], self.A[index],
                                     self.weights[index])

    def transformed(self, map1, map2) -> AffineCorrespondences:
        """Apply point maps ``p -> (g(p), J_g(p))`` to each image: ``A' = J2 A J1^-1``.

        Items that a map sends to NaN (e.g. undistortion outside the calibrated field) are
        dropped.
        """
        g1, J1 = map1(self.p1)
        g2, J2 = map2(self.p2)
        ok = np.isfinite(g1).all(1) & np.isfinite(g2).all(1)
        ok &= np.isfinite(J1).all((1, 2)) & np.isfinite(J2).all((1, 2))
        J1i = np.linalg.inv(np.where(ok[:, None, None], J1, np.eye(2)))
        A = J2 @ self.A @ J1i
        return AffineCorrespondences(g1[ok], g2[ok], A[ok], self.weights[ok])

    def normalized(self, camera1, camera2=None) -> AffineCorrespondences:
        """Ideal normalised coordinates ``C^-1 undistort(p)`` (`planar_vo.camera.CameraModel`)."""
        camera2 = camera1 if camera2 is None else camera2
        return self.transformed(camera1.pixel_to_normalized, camera2.pixel_to_normalized)

    @staticmethod
    def concatenate(items: list[AffineCorrespondences]) -> AffineCorrespondences:
        """Join several sets into one."""
        if not items:
            return AffineCorrespondences(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros((0, 2, 2)))
        return AffineCorrespondences(np.concatenate([c.p1 for c in items]),
                                     np.concatenate([c.p2 for c in items]),
                                     np.concatenate([c.A for c in items]),
                                     np.concatenate([c.weights for c in items]))
