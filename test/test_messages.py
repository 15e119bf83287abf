"""Duck-typed message conversion: every encoding, row padding, endianness, compressed images,
exact stamps and odometry fields, on rosbags and rclpy messages alike."""

from __future__ import annotations

import array
import math
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
from bagdata import (
    ENCODING_LAYOUT,
    T,
    compressed_msg,
    image_bytes,
    image_msg,
    odometry_msg,
    twist_msg,
    zero_png,
)

from planar_vo.core.conventions import planar_pose, rotation_rpy, se3
from planar_vo.errors import ImageError, InputError
from planar_vo.frontend.images import _check_complete, declared_size
from planar_vo.ros.messages import (
    compressed_to_array,
    covariance_to_list,
    image_to_array,
    ns_to_stamp_fields,
    pose_from_message,
    pose_to_position_quaternion,
    seconds_to_ns,
    seconds_to_stamp_fields,
    speed_from_message,
    stamp_to_ns,
    stamp_to_seconds,
    twist_to_fields,
)


def _pixels(rng, encoding: str, h: int = 7, w: int = 11) -> np.ndarray:
    channels, dtype = ENCODING_LAYOUT[encoding]
    shape = (h, w) if channels == 1 else (h, w, channels)
    return rng.integers(0, np.iinfo(dtype).max + 1, size=shape, dtype=np.int64).astype(dtype)


def _bt601(rgb: np.ndarray) -> np.ndarray:
    """Independent luma reference: Y = 0.299 R + 0.587 G + 0.114 B."""
    rgb = rgb.astype(np.float64)
    return 0.299 * rgb[..., 0] + 0.587 * rgb[..., 1] + 0.114 * rgb[..., 2]


def _rclpy_image(pixels: np.ndarray, encoding: str, *, pad: int = 0, bigendian: bool = False):
    from sensor_msgs.msg import Image

    data, step = image_bytes(pixels, pad=pad, bigendian=bigendian)
    msg = Image(height=pixels.shape[0], width=pixels.shape[1], encoding=encoding,
                is_bigendian=int(bigendian), step=step)
    msg.data = array.array('B', data.tobytes())
    return msg


MAKERS = {'rosbags': image_msg, 'rclpy': _rclpy_image}


@pytest.mark.parametrize('kind', sorted(MAKERS))
@pytest.mark.parametrize('encoding', sorted(ENCODING_LAYOUT))
@pytest.mark.parametrize('pad', [0, 5])
def test_every_encoding_round_trips_as_stored(rng, kind, encoding, pad):
    pixels = _pixels(rng, encoding)
    make = MAKERS[kind]
    msg = make(pixels, encoding, pad=pad) if kind == 'rclpy' else make(pixels, encoding, pad=pad)
    out = image_to_array(msg, gray=False)
    assert out.dtype == pixels.dtype and out.shape == pixels.shape
    np.testing.assert_array_equal(out, pixels)


@pytest.mark.parametrize('kind', sorted(MAKERS))
@pytest.mark.parametrize('pad', [0, 3])
def test_big_endian_mono16_round_trips_and_scales_to_top_byte(rng, kind, pad):
    pixels = _pixels(rng, 'mono16')
    msg = MAKERS[kind](pixels, 'mono16', pad=pad, bigendian=True)
    np.testing.assert_array_equal(image_to_array(msg, gray=False), pixels)
    gray = image_to_array(msg)
    assert gray.dtype == np.uint8
    np.testing.assert_array_equal(gray, (pixels >> 8).astype(np.uint8))
    # a 12-bit sensor: shift 4 keeps the whole range, values past 255 saturate
    twelve = (pixels >> 4).astype(np.uint16)
    msg12 = MAKERS[kind](twelve, '16UC1', pad=pad, bigendian=True)
    np.testing.assert_array_equal(image_to_array(msg12, mono16_shift=4),
                                  np.minimum(twelve >> 4, 255).astype(np.uint8))
    with pytest.raises(InputError, match=r'mono16_shift: expected an integer in 0\.\.8, got 9'):
        image_to_array(msg, mono16_shift=9)


@pytest.mark.parametrize('pad', [0, 2])
def test_colour_encodings_give_bt601_gray_regardless_of_channel_order(rng, pad):
    rgb = _pixels(rng, 'rgb8', 9, 13)
    expected = _bt601(rgb)
    outputs = {
        'rgb8': image_to_array(image_msg(rgb, 'rgb8', pad=pad)),
        'bgr8': image_to_array(image_msg(rgb[..., ::-1].copy(), 'bgr8', pad=pad)),
        'rgba8': image_to_array(image_msg(np.dstack([rgb, rgb[..., :1]]), 'rgba8', pad=pad)),
        'bgra8': image_to_array(image_msg(np.dstack([rgb[..., ::-1], rgb[..., :1]]), 'bgra8',
                                          pad=pad)),
    }
    for encoding, gray in outputs.items():
        assert gray.shape == rgb.shape[:2] and gray.dtype == np.uint8, encoding
        assert np.max(np.abs(gray - expected)) <= 0.51, encoding   # rounding only
    assert all(np.array_equal(outputs['rgb8'], g) for g in outputs.values())


def test_mono8_gray_is_an_owned_copy(rng):
    pixels = _pixels(rng, 'mono8')
    msg = image_msg(pixels, 'mono8')
    out = image_to_array(msg)
    out[:] = 0
    np.testing.assert_array_equal(image_to_array(msg), pixels)


def test_plain_bytes_buffer_is_accepted(rng):
    pixels = _pixels(rng, 'mono8')
    msg = SimpleNamespace(height=7, width=11, encoding='mono8', is_bigendian=0, step=11,
                          data=pixels.tobytes())
    np.testing.assert_array_equal(image_to_array(msg), pixels)


def _raw(**fields):
    base = dict(height=2, width=3, encoding='mono8', is_bigendian=0, step=3, data=bytes(6))
    base.update(fields)
    return SimpleNamespace(**base)


@pytest.mark.parametrize('fields, match', [
    (dict(encoding='yuv422'), r"image\.encoding: expected one of .*'mono8'.*, got 'yuv422'"),
    (dict(encoding='bayer_rggb8'), r"got 'bayer_rggb8'"),
    (dict(height=0, data=b''), r'image: expected a non-empty image, got 3x0 pixels'),
    (dict(data=b''), r'expected a non-empty image, got 3x2 pixels and 0 data bytes'),
    (dict(data=bytes(5)), r'image\.data: expected at least height \* step = 2 \* 3 = 6 bytes, '
                          r'got 5'),
    (dict(step=2), r'image\.step: expected at least width \* bytes per pixel = 3 \* 1 = 3 for '
                   r'mono8, got 2'),
    (dict(encoding='rgb8', step=8, data=bytes(16)), r'= 3 \* 3 = 9 for rgb8, got 8'),
    (dict(encoding='mono16', step=6, data=bytes(11)), r'at least height \* step = 2 \* 6 = 12'),
])
def test_image_errors(fields, match):
    with pytest.raises(ImageError, match=match):
        image_to_array(_raw(**fields))


def _smooth_rgb(h: int = 48, w: int = 64) -> np.ndarray:
    y, x = np.mgrid[0:h, 0:w]
    return np.dstack([x * 4, y * 5, (x + y) * 2]).clip(0, 255).astype(np.uint8)


def test_compressed_png_is_exact_and_jpeg_close():
    rgb = _smooth_rgb()
    bgr = rgb[..., ::-1].copy()
    expected = _bt601(rgb)
    ok, png = cv2.imencode('.png', bgr)
    assert ok
    gray = compressed_to_array(compressed_msg(png.tobytes(), 'bgr8; png compressed bgr8'))
    assert gray.shape == (48, 64) and np.max(np.abs(gray - expected)) <= 0.51
    np.testing.assert_array_equal(compressed_to_array(compressed_msg(png.tobytes(), 'png'),
                                                      gray=False), bgr)
    ok, jpg = cv2.imencode('.jpg', bgr, [cv2.IMWRITE_JPEG_QUALITY, 95])
    gray = compressed_to_array(compressed_msg(jpg.tobytes(), 'jpeg'))
    assert gray.shape == (48, 64) and np.mean(np.abs(gray - expected)) < 2.0


def test_compressed_mono_and_16bit_png():
    mono = _smooth_rgb()[..., 1]
    ok, png = cv2.imencode('.png', mono)
    np.testing.assert_array_equal(compressed_to_array(compressed_msg(png.tobytes(), 'png')),
                                  mono)
    deep = (mono.astype(np.uint16) * 257)
    ok, png16 = cv2.imencode('.png', deep)
    np.testing.assert_array_equal(compressed_to_array(compressed_msg(png16.tobytes(), 'png')),
                                  (deep >> 8).astype(np.uint8))


def test_compressed_rclpy_message():
    from sensor_msgs.msg import CompressedImage

    mono = _smooth_rgb()[..., 0]
    ok, png = cv2.imencode('.png', mono)
    msg = CompressedImage(format='png')
    msg.data = array.array('B', png.tobytes())
    np.testing.assert_array_equal(compressed_to_array(msg), mono)


def test_compressed_without_format_is_read_by_its_signature():
    """An empty ``format`` (some drivers leave it so; a user test saw such frames refused):
    the bytes' own PNG or JPEG signature says how to decode them."""
    mono = _smooth_rgb()[..., 0]
    for ext in ('.png', '.jpg'):
        ok, data = cv2.imencode(ext, mono)
        got = compressed_to_array(compressed_msg(data.tobytes(), ''))
        assert got.shape == mono.shape
        if ext == '.png':
            np.testing.assert_array_equal(got, mono)
        else:
            assert np.abs(got.astype(int) - mono).mean() < 2.0


@pytest.mark.parametrize('fmt, data, match', [
    ('bmp', b'BM...', r"compressed_image\.format: expected 'jpeg' or 'png' \(or empty\), "
     r"got 'bmp'"),
    ('', b'BM...', r'expected PNG or JPEG data, got 5 bytes starting with 42 4d 2e 2e 2e'),
    ('16UC1; compressedDepth png', b'x', r"got '16UC1; compressedDepth png'"),
    ('jpeg', b'\xff\xd8 not really a jpeg', r'compressed_image\.data: a JPEG without a readable '
     r'frame header \(20 bytes\)'),
    ('png', b'\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\x00\x00\x00\x28\x00\x00\x00\x1e broken',
     r'compressed_image\.data: 31 bytes of png data without its IEND chunk: the image is cut '
     r'short'),
    ('png', b'\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\x00\x00\x00\x28\x00\x00\x00\x1e broken'
     b'\x00\x00\x00\x00IEND\xaeB`\x82',
     r'compressed_image\.data: expected decodable png data, got 43 bytes OpenCV cannot decode'),
    ('png', b'GIF89a', r'expected PNG or JPEG data, got 6 bytes starting with 47 49 46 38 39 61'),
    ('png', b'', r'expected PNG or JPEG data, got 0 bytes$'),
])
def test_compressed_errors(fmt, data, match):
    with pytest.raises(ImageError, match=match):
        compressed_to_array(compressed_msg(data, fmt))


@pytest.mark.parametrize('ext', ['.png', '.jpg'])
def test_compressed_image_cut_short_is_refused_and_padding_is_not(ext, capfd):
    """A partial write or a truncated message: refused before the decoder (which prints to
    stderr, and fills a cut JPEG's missing rows with grey); zero padding after a JPEG's
    end-of-image marker is still an image."""
    mono = _smooth_rgb()[..., 0]
    data = cv2.imencode(ext, mono)[1].tobytes()
    fmt = ext.lstrip('.')
    with pytest.raises(ImageError, match=rf'{len(data) // 2} bytes of (png|jpeg) data without '
                                         r'its (IEND chunk|end-of-image marker): the image is cut '
                                         r'short'):
        compressed_to_array(compressed_msg(data[:len(data) // 2], fmt))
    assert capfd.readouterr().err == ''                 # nothing from the decoders
    # Bytes after the end are allowed (padded driver buffers, line ends, vendor trailers).
    whole = compressed_to_array(compressed_msg(data, fmt))
    for tail in (bytes(16), bytes(100), b'\r\n', b'\xff' * 8, b'SEFT\xff\xda\x00\x01trailer'):
        np.testing.assert_array_equal(compressed_to_array(compressed_msg(data + tail, fmt)),
                                      whole)


def test_a_cut_jpeg_is_refused_even_after_a_complete_thumbnail():
    """An EXIF thumbnail (inside APP1, before the main image) has its own end-of-image marker:
    the main image cut short is still refused."""
    mono = _smooth_rgb()[..., 0]
    main = cv2.imencode('.jpg', mono)[1].tobytes()
    thumb = cv2.imencode('.jpg', mono[::8, ::8])[1].tobytes()
    payload = b'Exif\x00\x00' + thumb
    app1 = b'\xff\xe1' + (len(payload) + 2).to_bytes(2, 'big') + payload
    data = main[:2] + app1 + main[2:]
    _check_complete(np.frombuffer(data, np.uint8), 'jpeg')          # complete: no error
    with pytest.raises(ImageError, match='without its end-of-image marker'):
        _check_complete(np.frombuffer(data[:len(data) - len(main) // 2], np.uint8), 'jpeg')


@pytest.mark.parametrize('ext, params', [
    ('.png', []), ('.jpg', []), ('.jpg', [cv2.IMWRITE_JPEG_PROGRESSIVE, 1])])
@pytest.mark.parametrize('size', [(40, 30), (1241, 376)])
def test_declared_size_is_the_decoded_size(ext, params, size):
    pixels = np.random.default_rng(1).integers(0, 256, size[::-1], dtype=np.uint8)
    ok, data = cv2.imencode(ext, pixels, params)
    assert declared_size(data.reshape(-1)) == ('png' if ext == '.png' else 'jpeg', *size)
    assert compressed_to_array(compressed_msg(data.tobytes(), ext[1:])).shape == size[::-1]


def test_decompression_bombs_are_refused_from_the_header(monkeypatch):
    """A 389 KB PNG (or a JPEG) declaring 20000x20000 pixels is refused before anything is
    inflated: decoding it would take 400 MB and seconds."""
    bomb = zero_png(20000, 20000)
    assert len(bomb) < 400_000
    assert cv2.imdecode(np.frombuffer(zero_png(64, 48), np.uint8), 0).shape == (48, 64)
    ok, jpeg = cv2.imencode('.jpg', np.zeros((30, 40), np.uint8))
    jpeg = bytearray(jpeg.tobytes())
    sof = jpeg.index(b'\xff\xc0')
    jpeg[sof + 5:sof + 9] = (20000).to_bytes(2, 'big') * 2          # height, width
    monkeypatch.setattr(cv2, 'imdecode', lambda *a: pytest.fail('decoded a refused image'))
    for data, kind in ((bomb, 'png'), (bytes(jpeg), 'jpeg')):
        with pytest.raises(ImageError, match=rf'compressed_image\.data: the {kind} header '
                                             r'declares 20000x20000 pixels, more than the '
                                             r'33554432 accepted; not decoded'):
            compressed_to_array(compressed_msg(data, kind))


# -- stamps -------------------------------------------------------------------------------------

def test_stamps_are_exact_integer_nanoseconds():
    stamp = T['builtin_interfaces/msg/Time'](sec=1_700_000_123, nanosec=987_654_321)
    assert stamp_to_ns(stamp) == 1_700_000_123_987_654_321
    assert ns_to_stamp_fields(1_700_000_123_987_654_321) == (1_700_000_123, 987_654_321)
    assert stamp_to_seconds(stamp) == 1_700_000_123_987_654_321 / 1_000_000_000  # correctly rounded
    assert ns_to_stamp_fields(-1) == (-1, 999_999_999)
    # decimal strings are exact; floats go through their shortest decimal form
    assert seconds_to_stamp_fields('1700000123.987654321') == (1_700_000_123, 987_654_321)
    assert seconds_to_stamp_fields(0.1) == (0, 100_000_000)
    assert seconds_to_ns(1.5) == 1_500_000_000
    assert seconds_to_ns(7) == 7_000_000_000
    # rclpy Time has the same fields
    from builtin_interfaces.msg import Time

    assert stamp_to_ns(Time(sec=3, nanosec=4)) == 3_000_000_004


@pytest.mark.parametrize('bad', [float('nan'), float('inf'), 'abc'])
def test_bad_seconds(bad):
    with pytest.raises(InputError, match=r'stamp: expected finite seconds, got'):
        seconds_to_ns(bad)


# -- odometry fields ----------------------------------------------------------------------------

def test_odometry_field_helpers():
    yaw = 0.7
    (p, q) = pose_to_position_quaternion(planar_pose(1.0, -2.0, yaw, z=0.5))
    assert p == (1.0, -2.0, 0.5)
    np.testing.assert_allclose(q, (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)), atol=1e-15)
    C = np.arange(36.0).reshape(6, 6)
    assert covariance_to_list(C) == list(np.arange(36.0))               # row-major
    assert twist_to_fields(np.arange(6.0)) == ((0.0, 1.0, 2.0), (3.0, 4.0, 5.0))


@pytest.mark.parametrize('call, match', [
    (lambda: pose_to_position_quaternion(np.eye(3)), r'pose: expected a finite 4x4 matrix, got '
                                                     r'shape \(3, 3\)'),
    (lambda: covariance_to_list(np.zeros(36)), r'covariance: expected shape \(6, 6\), got '
                                               r'\(36,\)'),
    (lambda: twist_to_fields(np.zeros(3)), r'twist: expected shape \(6,\), got \(3,\)'),
])
def test_odometry_field_errors(call, match):
    with pytest.raises(InputError, match=match):
        call()


def test_pose_and_speed_from_messages():
    odom = odometry_msg(5, 1.5, -0.5, 0.3)
    np.testing.assert_allclose(pose_from_message(odom), planar_pose(1.5, -0.5, 0.3), atol=1e-15)
    assert speed_from_message(odom) == 5.0                    # |(3, 4, 0)|
    assert speed_from_message(twist_msg(0, -2.5)) == 2.5      # a speed is a magnitude
    geo = 'geometry_msgs/msg/'
    R = rotation_rpy(0.1, -0.2, 0.3)
    from planar_vo.core.conventions import quaternion_from_rotation

    qx, qy, qz, qw = quaternion_from_rotation(R)
    stamped = T[geo + 'PoseStamped'](
        header=odom.header, pose=T[geo + 'Pose'](
            position=T[geo + 'Point'](x=1.0, y=2.0, z=3.0),
            orientation=T[geo + 'Quaternion'](x=qx, y=qy, z=qz, w=qw)))
    np.testing.assert_allclose(pose_from_message(stamped), se3(R, [1, 2, 3]), atol=1e-14)
    with pytest.raises(InputError, match=r'pose message: expected Odometry, PoseStamped or Pose '
                                         r'fields, got SimpleNamespace'):
        pose_from_message(SimpleNamespace(x=1))
    with pytest.raises(InputError, match=r'speed message: expected TwistStamped or Odometry'):
        speed_from_message(SimpleNamespace(x=1))
    # Huge components: refused (their squares overflowed a float before and crashed the node's
    # speed callback); a speed above MAX_SPEED is no vehicle's; non-numbers are refused.
    for value, match in ((1e300, 'at most 1000 m/s, got 1e[+]300'), (1e154, 'got 1e[+]154'),
                         (1001.0, 'got 1001'), (float('nan'), 'got nan')):
        with pytest.raises(InputError, match=match):
            speed_from_message(twist_msg(0, value))
    assert speed_from_message(twist_msg(0, 999.0)) == 999.0
    with pytest.raises(InputError, match='expected numbers'):
        speed_from_message(SimpleNamespace(linear=SimpleNamespace(x='fast', y=0.0, z=0.0)))
