"""`extract_acs`: affine correspondences between two images by one of three methods.

- ``'flow'`` (default, `planar_vo.frontend.flow`): DIS optical flow, textured grid,
  flow-Jacobian affines refined per patch by affine Lucas-Kanade, failures re-seeded from their
  neighbours; optional forward-backward check. A thousand and more ACs per frame in about twice
  the time of one DIS flow.
- ``'klt'`` (`planar_vo.frontend.klt`): Shi-Tomasi corners tracked by pyramidal Lucas-Kanade,
  affines from the same patch refinement started at the identity on a two-level pyramid.
- ``'asift'`` (`planar_vo.frontend.asift`): ASIFT features (``cv2.AffineFeature`` with SIFT),
  the paper's source of ACs; about 1.6 s per image on a CPU, so for offline comparison only.
"""

from __future__ import annotations

import threading

import cv2
import numpy as np

from planar_vo.config import FrontendConfig
from planar_vo.core.correspondences import AffineCorrespondences
from planar_vo.core.homography import homography_jacobian
from planar_vo.errors import InputError
from planar_vo.frontend.images import check_pair

__all__ = ['METHODS', 'ACExtractor', 'extract_acs']

METHODS = ('flow', 'klt', 'asift')


class ACExtractor:
    """Extracts ACs frame pair after frame pair, keeping OpenCV state (DIS, SIFT) alive.

    Args:
        config: front-end configuration; ``config.method`` is the default method.

    Attributes:
        stats: counts of the last call per stage (e.g. ``candidates``, ``accepted``).
    """

    def __init__(self, config: FrontendConfig | None = None) -> None:
        self.config = FrontendConfig() if config is None else config
        self._extractors: dict[str, object] = {}
        self._last = None                   # the extractor of the last pair
        self.stats: dict[str, float] = {}

    def _extractor(self, method: str):
        if method not in self._extractors:
            if method == 'flow':
                from planar_vo.frontend.flow import FlowExtractor as cls
            elif method == 'klt':
                from planar_vo.frontend.klt import KLTExtractor as cls
            else:
                from planar_vo.frontend.asift import ASIFTExtractor as cls
            self._extractors[method] = cls(self.config)
        return self._extractors[method]

    def extract(self, image1: np.ndarray, image2: np.ndarray, method: str | None = None
                ) -> AffineCorrespondences:
        """ACs from ``image1`` to ``image2`` in pixels (see `extract_acs`)."""
        self._last = None
        method = self.config.method if method is None else method
        if method not in METHODS:
            raise InputError(f"method: expected one of {list(METHODS)}, got {method!r}")
        gray1, gray2 = check_pair(image1, image2)
        extractor = self._extractor(method)
        acs = extractor.extract(gray1, gray2)
        self._last = extractor
        self.stats = dict(extractor.stats)
        return acs

    def extract_warped(self, image1: np.ndarray, image2: np.ndarray, H: np.ndarray,
                       method: str | None = None) -> AffineCorrespondences:
        """ACs from ``image1`` to ``image2`` found after warping ``image1`` by ``H``.

        ``H`` (3x3, pixels of image 1 -> image 2) predicts image 2, e.g. ``K R K^-1`` of the
        rotation between the views: image 1 is resampled by it (bilinear), the ACs are extracted
        between the warped image and image 2, and mapped back exactly (``p1 = H^-1(p1')``,
        ``A = A' J_H(p1)``), so they are ACs between the given images whatever the prediction's
        error; ACs whose patch would reach outside image 1 are dropped. Why: ACs extracted with
        a turn's rotation left in the flow carry an affine bias that the focal self-calibration
        turns into a focal length 5-7 % shorter (KITTI 05, `planar_vo.pipeline.calibration.focal`);
        the odometry itself is not affected (measured, README Findings). ``extract_more`` is not
        available after this call (its candidates would be in the warped image).

        Raises:
            InputError: ``H`` is not a finite, invertible 3x3 matrix; as `extract` otherwise.
        """
        H = np.asarray(H, dtype=np.float64)
        if H.shape != (3, 3) or not np.all(np.isfinite(H)):
            raise InputError(f'H: expected a finite 3x3 homography, got shape {H.shape}')
        cond = np.linalg.cond(H)
        if not (np.isfinite(cond) and cond < 1e12):
            raise InputError(f'H: expected an invertible homography, got condition number '
                             f'{cond:.3g}')
        gray1, gray2 = check_pair(image1, image2)
        height, width = gray1.shape
        warped = cv2.warpPerspective(gray1, H, (width, height), flags=cv2.INTER_LINEAR,
                                     borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        acs = self.extract(warped, gray2, method)
        self._last = None
        H_inv = np.linalg.inv(H)

        def back(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            with np.errstate(divide='ignore', invalid='ignore', over='ignore'):
                return homography_jacobian(H_inv, p, with_points=True)

        def same(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            return p, np.broadcast_to(np.eye(2), (len(p), 2, 2))

        acs = acs.transformed(back, same)
        margin = self.config.patch_radius + 1
        inside = ((acs.p1[:, 0] >= margin) & (acs.p1[:, 0] <= width - 1 - margin)
                  & (acs.p1[:, 1] >= margin) & (acs.p1[:, 1] <= height - 1 - margin))
        return acs if inside.all() else acs.subset(inside)

    def extract_more(self, select) -> AffineCorrespondences | None:
        """More ACs on the last pair where ``select(points) -> bool mask`` keeps candidates:
        without the per-frame budget's larger cells (`FlowExtractor.extract_more`) or from the
        region's own corners (`KLTExtractor.extract_more`); None when the last pair's method
        cannot (``'asift'``) or there was no pair."""
        more = getattr(self._last, 'extract_more', None)
        return None if more is None else more(select)


_local = threading.local()


def extract_acs(image1: np.ndarray, image2: np.ndarray, method: str | None = None,
                config: FrontendConfig | None = None) -> AffineCorrespondences:
    """Affine correspondences from ``image1`` to ``image2``.

    Args:
        image1, image2: 8-bit images of the same size, grey ``(H, W)`` or BGR ``(H, W, 3)``.
        method: ``'flow'``, ``'klt'`` or ``'asift'``; default ``config.method``.
        config: `FrontendConfig` (defaults if None).

    Returns:
        `AffineCorrespondences` in pixel coordinates of the input images: ``p1`` in image 1,
        ``p2`` in image 2, ``A`` the Jacobian of the image-1 -> image-2 map at ``p1``, and
        ``weights`` in ``[0, 1]`` (the per-AC quality; see each method). A textureless, black or
        saturated frame gives few or no ACs, not an exception.

    Raises:
        ImageError: an image is not an 8-bit array, is empty or tiny, or the sizes differ.
        InputError: unknown method.

    The OpenCV objects are cached per thread and configuration, so calling this per frame costs
    no set-up; `ACExtractor` does the same explicitly.
    """
    config = FrontendConfig() if config is None else config
    cache = getattr(_local, 'extractors', None)
    if cache is None:
        cache = _local.extractors = {}
    extractor = cache.get(config)
    if extractor is None:
        if len(cache) > 8:          # bounded: configurations rarely change at run time
            cache.clear()
        extractor = cache[config] = ACExtractor(config)
    return extractor.extract(image1, image2, method)
