"""`AffineCorrespondences`: the one AC container, returned by every AC source (front-end,
renderer, synthetic data) and taken by every consumer.

Any smooth map applied to the images (normalisation by ``K^-1``, undistortion, a levelling
rotation) acts on ACs by the chain rule: ``p' = g(p)``, ``A' = J_g(p2) A J_g(p1)^-1``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planar_vo.core.checks import as_array, same_length
from planar_vo.core.homography import homography_jacobian
from planar_vo.errors import InputError

__all__ = ['AffineCorrespondences']


@dataclass(frozen=True, eq=False)
class AffineCorrespondences:
    """N affine correspondences between two images.

    The arrays are checked once, here, and kept read-only (copies of the caller's writable
    ones): the estimators that take them skip their own checks (a user test: a NaN written
    into the caller's array afterwards made a clean frame unreliable without a word).
    Compared and hashed by identity (the fields' ``np.array_equal`` compares contents).

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
        if w.size and not w.min() >= 0.0:
            # (a user test: accepted here, refused only by the estimator later)
            raise InputError(f'weights: expected non-negative weights, got minimum {w.min()}')
        for name, value in (('p1', p1), ('p2', p2), ('A', A), ('weights', w)):
            if value.flags.writeable or not value.flags.owndata:
                value = value.copy()
                value.flags.writeable = False
            object.__setattr__(self, name, value)

    def __len__(self) -> int:
        return int(self.p1.shape[0])

    def subset(self, index: np.ndarray | slice) -> AffineCorrespondences:
        """The correspondences selected by a boolean mask, an index array or a slice.

        Raises:
            InputError: an index out of range, not an integer, or a mask of another length.
        """
        try:
            if not isinstance(index, slice):
                index = np.asarray(index)
                if index.dtype == bool and index.shape != (len(self),):
                    # (numpy takes an empty one as no index at all)
                    raise IndexError(f'boolean index did not match: a mask of '
                                     f'{index.shape} for {len(self)} items')
                if index.size == 0 and index.dtype != bool:
                    index = index.astype(np.intp)                # (an empty list: nothing)
                elif index.dtype != bool and not np.issubdtype(index.dtype, np.integer):
                    raise IndexError(f'expected integer indices or a boolean mask, got '
                                     f'{index.dtype} values')
            return AffineCorrespondences(self.p1[index], self.p2[index], self.A[index],
                                         self.weights[index])
        except IndexError as err:
            # (a user test: numpy's IndexError, where every other entry point raises InputError)
            raise InputError(f'subset of {len(self)} correspondences: {err}') from None

    def transformed(self, map1, map2) -> AffineCorrespondences:
        """Apply point maps ``p -> (g(p), J_g(p))`` to each image: ``A' = J2 A J1^-1``.

        Items that a map sends to NaN (e.g. undistortion outside the calibrated field) or whose
        Jacobian is not finite or singular are dropped (`transformed_kept` also says which).
        """
        return self.transformed_kept(map1, map2)[0]

    def transformed_kept(self, map1, map2) -> tuple[AffineCorrespondences, np.ndarray]:
        """`transformed` and the ``(N,)`` bool mask of the items it kept, so that other arrays
        item by item with these ACs can be cut the same way. A map may return one ``(2, 2)``
        Jacobian for all items (a linear map) instead of ``(N, 2, 2)``."""
        g1, J1 = map1(self.p1)
        g2, J2 = map2(self.p2)
        ok = np.isfinite(g1).all(1) & np.isfinite(g2).all(1)
        # A map's Jacobian is (N, 2, 2), or (2, 2) for a linear map (the same for every item:
        # the arithmetic below broadcasts it, item by item the same numbers).
        ok &= np.isfinite(J1).all((-2, -1)) & np.isfinite(J2).all((-2, -1))
        # Dropped items may hold inf or NaN: their arithmetic is discarded.
        with np.errstate(invalid='ignore', over='ignore', divide='ignore'):
            j00, j01, j10, j11 = J1[..., 0, 0], J1[..., 0, 1], J1[..., 1, 0], J1[..., 1, 1]
            det = j00 * j11 - j01 * j10
            ok &= det != 0.0
            inv_det = 1.0 / np.where(ok, det, 1.0)
            # A J1^-1 (J1^-1 = [[j11, -j01], [-j10, j00]] / det), then J2 (A J1^-1), entry by
            # entry: batched 2x2 matrix products cost several times more at these sizes.
            a00, a01, a10, a11 = self.A[:, 0, 0], self.A[:, 0, 1], self.A[:, 1, 0], self.A[:, 1, 1]
            m00 = (a00 * j11 - a01 * j10) * inv_det
            m01 = (a01 * j00 - a00 * j01) * inv_det
            m10 = (a10 * j11 - a11 * j10) * inv_det
            m11 = (a11 * j00 - a10 * j01) * inv_det
            A = np.empty_like(self.A, dtype=np.float64)
            A[:, 0, 0] = J2[..., 0, 0] * m00 + J2[..., 0, 1] * m10
            A[:, 0, 1] = J2[..., 0, 0] * m01 + J2[..., 0, 1] * m11
            A[:, 1, 0] = J2[..., 1, 0] * m00 + J2[..., 1, 1] * m10
            A[:, 1, 1] = J2[..., 1, 0] * m01 + J2[..., 1, 1] * m11
        if ok.all():
            return AffineCorrespondences(g1, g2, A, self.weights), ok
        return AffineCorrespondences(g1[ok], g2[ok], A[ok], self.weights[ok]), ok

    def mapped(self, H: np.ndarray) -> AffineCorrespondences:
        """Both views mapped by the homography ``H`` (3x3), e.g. a rotation ``R`` of normalised
        rays (levelling) or ``K R K^-1`` of pixels. Items sent to infinity are dropped."""
        return self.mapped_kept(H)[0]

    def mapped_kept(self, H: np.ndarray) -> tuple[AffineCorrespondences, np.ndarray]:
        """`mapped` and the ``(N,)`` bool mask of the items it kept."""
        H = as_array('H', H, (3, 3))

        def g(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            with np.errstate(divide='ignore', invalid='ignore', over='ignore'):
                return homography_jacobian(H, p, with_points=True)

        return self.transformed_kept(g, g)

    def normalized(self, camera1, camera2=None) -> AffineCorrespondences:
        """Ideal normalised coordinates ``K^-1 undistort(p)`` of `CameraModel` s (``camera2``:
        image 2's, default ``camera1``); `InputError` for anything else."""
        camera2 = camera1 if camera2 is None else camera2
        for name, camera in (('camera1', camera1), ('camera2', camera2)):
            if not callable(getattr(camera, 'normalizing_map', None)):
                raise InputError(f'normalized: {name}: expected a CameraModel, got '
                                 f'{type(camera).__name__}')
        return self.transformed(camera1.normalizing_map(), camera2.normalizing_map())

    @staticmethod
    def concatenate(items: list[AffineCorrespondences]) -> AffineCorrespondences:
        """Join several sets into one (`InputError` for items that are not
        `AffineCorrespondences`)."""
        try:
            items = list(items)
        except TypeError:
            raise InputError(f'concatenate: expected a list of AffineCorrespondences, got '
                             f'{type(items).__name__}') from None
        for k, item in enumerate(items):
            if not isinstance(item, AffineCorrespondences):
                raise InputError(f'concatenate: item {k}: expected AffineCorrespondences, got '
                                 f'{type(item).__name__}')
        if not items:
            return AffineCorrespondences(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros((0, 2, 2)))
        return AffineCorrespondences(np.concatenate([c.p1 for c in items]),
                                     np.concatenate([c.p2 for c in items]),
                                     np.concatenate([c.A for c in items]),
                                     np.concatenate([c.weights for c in items]))
