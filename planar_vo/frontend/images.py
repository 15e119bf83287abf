"""Image input checks for the front-end: one place that turns what callers pass into 8-bit grey.

Accepted: numpy arrays ``(H, W)`` or ``(H, W, 1)`` grey, ``(H, W, 3)`` BGR or ``(H, W, 4)`` BGRA, of
dtype ``uint8``. Anything else raises `ImageError` naming the argument, what was received and
what was expected.
"""

from __future__ import annotations

import cv2
import numpy as np

from planar_vo.errors import ImageError

__all__ = ['MIN_IMAGE_SIZE', 'as_gray', 'check_pair']

# DIS optical flow and the patch refinement need a few patches' worth of pixels.
MIN_IMAGE_SIZE = 32


def as_gray(name: str, image: object) -> np.ndarray:
    """Return `image` as a C-contiguous ``uint8`` grey image ``(H, W)``.

    Args:
        name: argument name for error messages (``'image1'``).
        image: ``(H, W)``, ``(H, W, 1)``, ``(H, W, 3)`` (BGR) or ``(H, W, 4)`` (BGRA) ``uint8``
            array.

    Raises:
        ImageError: not an array, wrong dtype or shape, empty, or smaller than
            `MIN_IMAGE_SIZE` pixels on a side.
    """
    if not isinstance(image, np.ndarray):
        raise ImageError(f'{name}: expected a numpy uint8 image array (H, W) or (H, W, 3), got '
                         f'{type(image).__name__}')
    if image.size == 0:
        raise ImageError(f'{name}: expected a non-empty image, got an array of shape '
                         f'{image.shape}')
    if image.dtype != np.uint8:
        raise ImageError(f'{name}: expected dtype uint8 (8-bit grey or BGR), got {image.dtype}')
    if image.ndim == 3 and image.shape[2] in (1, 3, 4):
        if image.shape[2] == 1:
            image = image[:, :, 0]
        else:
            code = cv2.COLOR_BGR2GRAY if image.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
            image = cv2.cvtColor(np.ascontiguousarray(image), code)
    elif image.ndim != 2:
        raise ImageError(f'{name}: expected shape (H, W), (H, W, 1), (H, W, 3) or (H, W, 4), got '
                         f'{image.shape}')
    h, w = image.shape
    if min(h, w) < MIN_IMAGE_SIZE:
        raise ImageError(f'{name}: expected at least {MIN_IMAGE_SIZE}x{MIN_IMAGE_SIZE} pixels, got '
                         f'{w}x{h}')
    return np.ascontiguousarray(image)


def check_pair(image1: object, image2: object) -> tuple[np.ndarray, np.ndarray]:
    """Both images as grey ``uint8`` of the same size (`as_gray`), or `ImageError`."""
    g1 = as_gray('image1', image1)
    g2 = as_gray('image2', image2)
    if g1.shape != g2.shape:
        raise ImageError(f'image2: expected the size of image1 ({g1.shape[1]}x{g1.shape[0]}), got '
                         f'{g2.shape[1]}x{g2.shape[0]}')
    return g1, g2
