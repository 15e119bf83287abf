"""Images in: the one place that turns pixels into the front-end's 8-bit grey.

- `as_gray`, `check_pair`: numpy arrays ``(H, W)`` or ``(H, W, 1)`` grey, ``(H, W, 3)`` BGR or
  ``(H, W, 4)`` BGRA, of dtype ``uint8``. Anything else raises `ImageError` naming the argument,
  what was received and what was expected.
- `decode_raw`, `decode_compressed`: the pixel buffers of ``sensor_msgs/Image`` and
  ``CompressedImage`` (`planar_vo.ros.messages` reads the message fields) and image files:

  - ``mono8``/``8UC1``: as stored.
  - ``mono16``/``16UC1``: the 16-bit value shifted right by ``mono16_shift`` bits (default 8, the
    top byte of the full 16-bit range) and clipped to 255. The map is the same for every frame, so
    brightness constancy between frames (which optical flow relies on) is kept; a per-frame
    min/max stretch would break it. For 12-bit sensors stored in 16 bits use ``mono16_shift=4``.
  - ``rgb8``, ``bgr8``, ``rgba8``, ``bgra8``: ITU-R BT.601 luma (OpenCV ``cvtColor``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np

from planar_vo.errors import ImageError, InputError

__all__ = [
    'IMAGE_ENCODINGS',
    'MAX_IMAGE_PIXELS',
    'MIN_IMAGE_SIZE',
    'as_gray',
    'buffer',
    'check_pair',
    'declared_size',
    'decode_compressed',
    'decode_raw',
    'read_image',
]

# DIS optical flow and the patch refinement need a few patches' worth of pixels.
MIN_IMAGE_SIZE = 32
# Compressed images declaring more pixels are refused before decoding: 2^25 = 33.5 million,
# room for 8K UHD (7680x4320), while a few hundred KB of PNG can declare 20000x20000 and cost
# 400 MB and seconds to inflate.
MAX_IMAGE_PIXELS = 1 << 25
_PNG_SIGNATURE = b'\x89PNG\r\n\x1a\n'
# JPEG start-of-frame markers (SOF0..SOF15 without DHT 0xC4, JPG 0xC8, DAC 0xCC): they carry
# the frame size. Markers without a length field: TEM, RST0..7, SOI, EOI.
_JPEG_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
_JPEG_NO_LENGTH = frozenset([0x01, *range(0xD0, 0xDA)])

# encoding -> (channels, bytes per channel, cv2 code to grey or None for single channel)
IMAGE_ENCODINGS: dict[str, tuple[int, int, int | None]] = {
    'mono8': (1, 1, None),
    '8UC1': (1, 1, None),
    'mono16': (1, 2, None),
    '16UC1': (1, 2, None),
    'rgb8': (3, 1, cv2.COLOR_RGB2GRAY),
    'bgr8': (3, 1, cv2.COLOR_BGR2GRAY),
    'rgba8': (4, 1, cv2.COLOR_RGBA2GRAY),
    'bgra8': (4, 1, cv2.COLOR_BGRA2GRAY),
}


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
        raise ImageError(f'{name}: expected a numpy uint8 image array (H, W), (H, W, 1), '
                         f'(H, W, 3) or (H, W, 4), got {type(image).__name__}')
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


def buffer(data: Any) -> np.ndarray:
    """A flat uint8 view of a byte buffer (bytes, array.array, numpy, list of ints)."""
    if isinstance(data, np.ndarray):
        return np.frombuffer(np.ascontiguousarray(data).data, dtype=np.uint8)
    try:
        return np.frombuffer(data, dtype=np.uint8)
    except TypeError:
        return np.asarray(data, dtype=np.uint8).reshape(-1)


def _mono16_to_8(img: np.ndarray, shift: int) -> np.ndarray:
    if not (isinstance(shift, (int, np.integer)) and 0 <= shift <= 8):
        raise InputError(f'mono16_shift: expected an integer in 0..8, got {shift!r}')
    return np.minimum(img >> np.uint16(shift), 255).astype(np.uint8)


def decode_raw(data: Any, encoding: str, height: int, width: int, step: int,
               is_bigendian: bool = False, *, gray: bool = True,
               mono16_shift: int = 8) -> np.ndarray:
    """Pixels of a raw image buffer (the fields of a ``sensor_msgs/Image``).

    Honours ``step`` (row padding) and ``is_bigendian`` (16-bit encodings).

    Args:
        data: the pixel bytes (``height * step`` at least).
        encoding, height, width, step, is_bigendian: as in ``sensor_msgs/Image``.
        gray: return ``(H, W)`` uint8 grey (see the module docstring for the conversions).
            ``False`` returns the pixels as stored: ``(H, W)`` for single-channel encodings,
            ``(H, W, C)`` in the encoding's channel order, native-endian uint8 or uint16.
        mono16_shift: right shift from 16-bit to 8-bit grey (0..8).

    Raises:
        ImageError: unsupported encoding, empty image, ``step`` too small for the width, or
            ``data`` shorter than ``height * step``.
    """
    encoding = str(encoding)
    if encoding not in IMAGE_ENCODINGS:
        raise ImageError(f"image.encoding: expected one of {list(IMAGE_ENCODINGS)}, "
                         f"got '{encoding}'")
    channels, depth, code = IMAGE_ENCODINGS[encoding]
    height, width, step = int(height), int(width), int(step)
    buf = buffer(data)
    if height <= 0 or width <= 0 or buf.size == 0:
        raise ImageError(f'image: expected a non-empty image, got {width}x{height} pixels and '
                         f'{buf.size} data bytes')
    row_bytes = width * channels * depth
    if step < row_bytes:
        raise ImageError(f'image.step: expected at least width * bytes per pixel = {width} * '
                         f'{channels * depth} = {row_bytes} for {encoding}, got {step}')
    if buf.size < height * step:
        raise ImageError(f'image.data: expected at least height * step = {height} * {step} = '
                         f'{height * step} bytes, got {buf.size}')
    rows = buf[:height * step].reshape(height, step)[:, :row_bytes]
    if depth == 2:
        dtype = np.dtype('>u2' if is_bigendian else '<u2')
        img = np.ascontiguousarray(rows).view(dtype).astype(np.uint16)
    else:
        img = np.array(rows)                         # owned: never alias the message buffer
    img = img.reshape((height, width, channels) if channels > 1 else (height, width))
    if not gray:
        return img
    if depth == 2:
        return _mono16_to_8(img, mono16_shift)
    return cv2.cvtColor(img, code) if code is not None else img


def declared_size(data: np.ndarray) -> tuple[str, int, int]:
    """``(format, width, height)`` that PNG or JPEG bytes declare in their header.

    PNG: the IHDR chunk, which must come first; JPEG: the first start-of-frame segment. Only
    the header is read (a few hundred bytes), nothing is decoded.

    Raises:
        ImageError: neither a PNG nor a JPEG signature, or a header too short to hold the size.
    """
    head = bytes(data[:24])
    if head.startswith(_PNG_SIGNATURE):
        if len(head) < 24 or head[12:16] != b'IHDR':
            raise ImageError(f'compressed_image.data: a PNG signature without an IHDR header '
                             f'({data.size} bytes)')
        return 'png', int.from_bytes(head[16:20], 'big'), int.from_bytes(head[20:24], 'big')
    if head.startswith(b'\xff\xd8'):
        raw = data.tobytes()
        for pos, marker in _jpeg_markers(raw):       # one step per header segment (a handful)
            if marker in _JPEG_SOF and pos + 9 <= len(raw):
                return ('jpeg', int.from_bytes(raw[pos + 7:pos + 9], 'big'),
                        int.from_bytes(raw[pos + 5:pos + 7], 'big'))
        raise ImageError(f'compressed_image.data: a JPEG without a readable frame header '
                         f'({data.size} bytes)')
    start = f' starting with {head[:8].hex(" ")}' if head else ''
    raise ImageError(f'compressed_image.data: expected PNG or JPEG data, got {data.size} '
                     f'bytes{start}')


def decode_compressed(data: Any, fmt: str = 'png', *, gray: bool = True,
                      mono16_shift: int = 8) -> np.ndarray:
    """Pixels of JPEG or PNG bytes (a ``sensor_msgs/CompressedImage`` or an image file).

    The size the header declares (`declared_size`) is checked before decoding: more than
    `MAX_IMAGE_PIXELS` pixels is refused without inflating anything.

    Args:
        data: the encoded bytes.
        fmt: the format; must name ``jpeg``/``jpg`` or ``png`` (e.g. ``'jpeg'``,
            ``'bgr8; jpeg compressed bgr8'``), or be empty (some drivers leave it so): the
            data's own signature then says which (anything else is refused).
        gray: return ``(H, W)`` uint8 grey; ``False`` returns what OpenCV decodes unchanged
            (``(H, W)`` grey, or ``(H, W, 3|4)`` in BGR(A) order; uint8 or uint16 for 16-bit PNG).
        mono16_shift: right shift from 16-bit to 8-bit grey for 16-bit PNGs.

    Raises:
        ImageError: unknown format, data that is not PNG or JPEG, a declared size above
            `MAX_IMAGE_PIXELS`, data cut short (no PNG IEND chunk, no JPEG end-of-image
            marker), or data OpenCV cannot decode.
    """
    lower = str(fmt).lower()
    if lower.strip() and (not any(name in lower for name in ('jpeg', 'jpg', 'png'))
                          or 'compresseddepth' in lower):
        raise ImageError(f"compressed_image.format: expected 'jpeg' or 'png' (or empty), got "
                         f"'{fmt}'")
    buf = buffer(data)
    kind, width, height = declared_size(buf)
    if width * height > MAX_IMAGE_PIXELS:
        raise ImageError(f'compressed_image.data: the {kind} header declares {width}x{height} '
                         f'pixels, more than the {MAX_IMAGE_PIXELS} accepted; not decoded')
    _check_complete(buf, kind)
    img = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    if img is None or img.size == 0:
        raise ImageError(f"compressed_image.data: expected decodable {kind} data, got "
                         f'{buf.size} bytes OpenCV cannot decode')
    if not gray:
        return img
    if img.dtype == np.uint16:
        img = _mono16_to_8(img, mono16_shift)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2GRAY if img.shape[2] == 4 else cv2.COLOR_BGR2GRAY)
    return img


_PNG_END = b'IEND\xaeB`\x82'            # the IEND chunk's type and its (fixed) CRC


def _check_complete(buf: np.ndarray, kind: str) -> None:
    """`ImageError` for PNG or JPEG data cut short (a partial write, a truncated file or
    message): a PNG holds its IEND chunk, a JPEG an end-of-image marker after the main image's
    first start-of-scan (entropy-coded data cannot hold one; an EXIF thumbnail's comes before).
    Bytes after the end (padding, trailers) are allowed. Checked before decoding because the
    decoders print to stderr and OpenCV fills a cut JPEG's missing rows with grey instead of
    failing."""
    raw = buf.tobytes()
    if kind == 'png':
        if raw.rfind(_PNG_END) < 0:
            raise ImageError(f'compressed_image.data: {buf.size} bytes of png data without '
                             f'its IEND chunk: the image is cut short')
        return
    scan = _jpeg_first_scan(raw)
    if scan < 0 or raw.find(b'\xff\xd9', scan) < 0:
        raise ImageError(f'compressed_image.data: {buf.size} bytes of jpeg data without '
                         f'its end-of-image marker: the image is cut short')


def _jpeg_markers(raw: bytes):
    """``(offset, marker)`` of each JPEG header segment in order, up to and including the first
    start-of-scan. Segments are skipped by their lengths, so a thumbnail inside APP1 is not
    entered; stray bytes before a marker and fill bytes are tolerated."""
    pos = 2
    while 0 <= pos and pos + 4 <= len(raw):
        if raw[pos] != 0xFF:                          # stray bytes before a marker
            pos = raw.find(b'\xff', pos)
            continue
        marker = raw[pos + 1]
        if marker == 0xFF:                            # fill byte
            pos += 1
            continue
        yield pos, marker
        if marker == 0xDA:
            return
        pos += 2 if marker in _JPEG_NO_LENGTH else 2 + int.from_bytes(raw[pos + 2:pos + 4], 'big')


def _jpeg_first_scan(raw: bytes) -> int:
    """Offset of the main image's first start-of-scan marker in JPEG bytes, or -1."""
    return next((pos for pos, marker in _jpeg_markers(raw) if marker == 0xDA), -1)


def read_image(path: str | Path) -> np.ndarray:
    """An image file (PNG or JPEG) as ``(H, W)`` uint8 grey.

    Raises:
        ImageError: the file cannot be read or decoded.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as err:
        raise ImageError(f"cannot read '{path}' ({err.strerror})") from err
    try:
        return decode_compressed(data, path.suffix.lstrip('.') or 'png')
    except ImageError as err:
        # (the message's field name is a CompressedImage's, not the file's: a user test)
        why = str(err).removeprefix('compressed_image.data: ')
        raise ImageError(f"cannot read '{path}' as an image ({why})") from err
