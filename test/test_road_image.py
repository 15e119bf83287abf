"""The step length from the road's pixels (`planar_vo.pipeline.road_image`)."""

from __future__ import annotations

import functools
import math

import cv2
import numpy as np
import pytest

from planar_vo.core.camera import CameraModel
from planar_vo.core.conventions import normal_from_tilt, so3_exp
from planar_vo.errors import ConfigError, InputError
from planar_vo.pipeline.road_image import image_road_scale
from planar_vo.pipeline.scale import road_scale

HEIGHT = 1.6
CAMERA = CameraModel.pinhole(960, 300, 700.0, cx=470.0, cy=120.0)
TEXTURE_CELL = 0.01              # metres per texture pixel


@pytest.fixture(scope='module')
def texture():
    rng = np.random.default_rng(3)
    noise = rng.uniform(0.0, 255.0, (3000, 1200)).astype(np.float32)      # 30 m x 12 m
    return cv2.GaussianBlur(noise, (0, 0), 2.0)


def _render(texture, camera, T_wc, n_w):
    """The road ``n_w . X = HEIGHT`` (world = camera 1, ``n_w`` down) seen by a camera at
    ``T_wc`` (camera -> world), textured by ``texture`` (rows: forward from 2 m, columns: lateral
    from -6 m); grey 40 above the horizon and beyond the texture."""
    v, u = np.mgrid[0:camera.size[1], 0:camera.size[0]].astype(np.float64)
    q, _ = camera.pixel_to_normalized(np.column_stack([u.ravel(), v.ravel()]))
    d = np.column_stack([q, np.ones(len(q))]) @ T_wc[:3, :3].T                # ray, world
    o = T_wc[:3, 3]
    with np.errstate(divide='ignore', invalid='ignore'):
        lam = (HEIGHT - n_w @ o) / (d @ n_w)
    X = o + lam[:, None] * d
    col = ((X[:, 0] + 6.0) / TEXTURE_CELL).astype(np.float32)
    row = ((X[:, 2] - 2.0) / TEXTURE_CELL).astype(np.float32)
    bad = ~(lam > 0) | ~np.isfinite(lam)
    col[bad] = row[bad] = -1e6
    image = cv2.remap(texture, col.reshape(v.shape), row.reshape(v.shape), cv2.INTER_LINEAR,
                      borderMode=cv2.BORDER_CONSTANT, borderValue=40.0)
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


def _pair(texture, step, yaw_deg=1.0, pitch_deg=0.5, camera=CAMERA):
    """Images 1 and 2 of a camera pitched down by ``pitch_deg`` above the road, moving
    ``step`` forward along the road and turning by ``yaw_deg``; ``R, t, n`` as
    `image_road_scale` takes them (``X2 = R X1 + s t``, ``n`` in camera 1)."""
    n = normal_from_tilt(math.radians(pitch_deg), 0.0)
    forward = np.cross(np.array([1.0, 0.0, 0.0]), n)          # in the road, camera 1 frame
    forward /= np.linalg.norm(forward)
    R_21 = so3_exp(n * math.radians(yaw_deg))                 # a turn about the road normal
    T_w2 = np.eye(4)
    T_w2[:3, :3] = R_21.T
    T_w2[:3, 3] = step * forward
    T_w1 = np.eye(4)
    image1 = _render(texture, camera, T_w1, n)
    image2 = _render(texture, camera, T_w2, n)
    t = -R_21 @ forward                                        # X2 = R (X1 - c), c = s forward
    return image1, image2, R_21, t, n


KITTI = CameraModel.pinhole(1241, 376, 718.9, cx=607.2, cy=185.2)


@pytest.mark.parametrize('step, camera', [(0.7, CAMERA), (2.5, CAMERA), (4.0, CAMERA),
                                          (0.7, KITTI), (3.6, KITTI)])
def test_recovers_the_step_of_a_rendered_road(texture, step, camera):
    image1, image2, R, t, n = _pair(texture, step, camera=camera)
    found = image_road_scale(image1, image2, camera, R, t, n, HEIGHT, steps=(0.0, 7.0))
    assert found.reason == '' and found.blocks >= 30
    assert found.scale == pytest.approx(step, rel=0.01)
    assert found.std < 0.01 * step
    # The blocks are road correspondences of that step: they lie on its homography, and the
    # road ACs' closed form measures the same step from them.
    H = R + (step / HEIGHT) * np.outer(t, n)
    Q2 = np.column_stack([found.q1, np.ones(found.blocks)]) @ H.T
    err = np.linalg.norm(Q2[:, :2] / Q2[:, 2:] - found.q2, axis=1) * camera.fx
    assert np.median(err) < 1.0 and err.max() < 3.0                              # pixels
    rs = road_scale(found.q1, found.q2, found.A, R, t, n, HEIGHT,
                    point_sigma=1.0 / camera.fx, weights=found.weights)
    assert rs.count >= 0.75 * found.blocks and rs.scale == pytest.approx(step, rel=0.01)


def test_sensitivities_predict_the_answer_under_another_rotation_or_normal(texture):
    """d_rotation and d_normal (those of the blocks as road ACs, their matches held) predict
    how the answer moves when the rotation or the road normal given is off by a little."""
    image1, image2, R, t, n = _pair(texture, 2.0)
    found = image_road_scale(image1, image2, CAMERA, R, t, n, HEIGHT, steps=(0.0, 7.0))
    delta = 2e-3
    R_off = so3_exp(np.array([delta, 0.0, 0.0])) @ R                     # pitch of view 2
    moved = image_road_scale(image1, image2, CAMERA, R_off, t, n, HEIGHT, steps=(0.0, 7.0))
    assert abs(found.d_rotation[0] * delta) > 10 * found.std
    # (the blocks' matches held: a rescan under the other rotation also moves them along
    # another line, 1.4 times as far here)
    assert moved.scale - found.scale == pytest.approx(found.d_rotation[0] * delta, rel=0.5)
    n_off = normal_from_tilt(math.radians(0.5) + delta, 0.0)
    moved = image_road_scale(image1, image2, CAMERA, R, t, n_off, HEIGHT, steps=(0.0, 7.0))
    assert moved.scale - found.scale == pytest.approx(found.d_normal[0] * delta, rel=0.2)


def test_a_step_beyond_the_range_is_no_answer(texture):
    image1, image2, R, t, n = _pair(texture, 3.0)
    # Far outside the range: nothing correlates, or the scan's end beyond it fits best.
    found = image_road_scale(image1, image2, CAMERA, R, t, n, HEIGHT, steps=(4.0, 9.0))
    assert math.isnan(found.scale) and found.reason.startswith('no clear best step')
    found = image_road_scale(image1, image2, CAMERA, R, t, n, HEIGHT, steps=(0.0, 2.0))
    assert math.isnan(found.scale) and found.blocks == 0
    assert found.reason.startswith('the best step is the longest searched'), found.reason
    # Just outside it: the end of the range fits best, and the reason says which.
    found = image_road_scale(image1, image2, CAMERA, R, t, n, HEIGHT, steps=(0.0, 2.8))
    assert found.reason.startswith('the best step is the longest searched'), found.reason
    found = image_road_scale(image1, image2, CAMERA, R, t, n, HEIGHT, steps=(3.3, 9.0))
    assert found.reason.startswith('the best step is the shortest searched'), found.reason
    found = image_road_scale(image1, image2, CAMERA, R, t, n, HEIGHT, steps=(2.0, 6.0))
    assert found.scale == pytest.approx(3.0, rel=0.01)


@pytest.mark.parametrize('step', [0.35, 0.6, 3.0])
def test_the_answer_does_not_depend_on_the_range(texture, step):
    """The coarse scan moves the fastest block by a shrunk pixel per step whatever the range
    (a review: evenly spaced steps over 0-35 m skipped 0.35 and 0.6 m, and a user test saw one
    pair's answer move by 20 % with the range): short steps in long ranges are found, alike."""
    image1, image2, R, t, n = _pair(texture, step, camera=KITTI)
    answers = [image_road_scale(image1, image2, KITTI, R, t, n, HEIGHT, steps=(0.0, high)).scale
               for high in (7.0, 14.0, 35.0, 100.0)]
    np.testing.assert_allclose(answers, step, rtol=0.01)


@pytest.mark.parametrize('step, high', [(0.5, 7.0), (2.0, 3.0), (2.0, 7.0), (2.0, 35.0)])
def test_a_camera_moving_away_from_the_road_ahead(texture, step, high):
    """Reversing (or a rear camera driving forward): the road leaves image 1's view as the
    step grows; the scan still spaces its steps by the blocks still in view (a review: the
    first version left the short steps unscanned and called long ranges motionless)."""
    image1, image2, R, t, n = _pair(texture, -step, camera=KITTI)
    found = image_road_scale(image1, image2, KITTI, R, -t, n, HEIGHT, steps=(0.0, high))
    assert found.scale == pytest.approx(step, rel=0.01), found.reason


def test_many_road_blocks_are_thinned(texture):
    """A tall image from a camera pitched down sees the road in many more blocks than a wide
    one: at most 128 are scanned (a review: 741 blocks, 2.2 million samples a scan)."""
    tall = CameraModel.pinhole(640, 480, 500.0)
    image1, image2, R, t, n = _pair(texture, 1.5, pitch_deg=12.0, camera=tall)
    found = image_road_scale(image1, image2, tall, R, t, n, HEIGHT, steps=(0.0, 7.0))
    assert 64 <= found.blocks <= 128
    assert found.scale == pytest.approx(1.5, rel=0.01)


def test_no_texture_no_road_no_range_say_why(texture):
    image1, image2, R, t, n = _pair(texture, 2.0)
    flat = np.full_like(image1, 90)
    found = image_road_scale(flat, flat, CAMERA, R, t, n, HEIGHT, steps=(0.0, 7.0))
    assert math.isnan(found.scale) and found.blocks == 0 and found.reason
    # A camera looking up (the road out of view).
    up = normal_from_tilt(math.radians(-40.0), 0.0)
    found = image_road_scale(image1, image2, CAMERA, R, t, up, HEIGHT, steps=(0.0, 7.0))
    assert 'road blocks in view' in found.reason
    for steps in ((1.0, 0.5), (0.0, math.inf), (-1.0, 2.0), (0.0, math.nan)):
        found = image_road_scale(image1, image2, CAMERA, R, t, n, HEIGHT, steps=steps)
        assert 'no range of steps' in found.reason and math.isnan(found.scale)


def test_different_images_are_no_answer(texture):
    """Image 2 of another road (unrelated texture): no step correlates."""
    image1, _, R, t, n = _pair(texture, 2.0)
    other = np.random.default_rng(9).uniform(0, 255, texture.shape).astype(np.float32)
    _, image2, _, _, _ = _pair(cv2.GaussianBlur(other, (0, 0), 2.0), 2.0)
    found = image_road_scale(image1, image2, CAMERA, R, t, n, HEIGHT, steps=(0.0, 7.0))
    assert math.isnan(found.scale) and found.reason


def test_a_distorted_camera(texture):
    """A lens with distortion: the images are undistorted first (rendered by the distorted
    camera here); taken as undistorted, the same images give another step."""
    camera = CameraModel(CAMERA.size[0], CAMERA.size[1], CAMERA.K, 'plumb_bob',
                         (-0.25, 0.05, 0.0, 0.0, 0.0))
    n = normal_from_tilt(math.radians(0.5), 0.0)
    _, _, R, t, _ = _pair(texture, 2.5)
    forward = np.cross(np.array([1.0, 0.0, 0.0]), n)
    forward /= np.linalg.norm(forward)
    T_w2 = np.eye(4)
    T_w2[:3, :3] = R.T
    T_w2[:3, 3] = 2.5 * forward
    image1, image2 = _render(texture, camera, np.eye(4), n), _render(texture, camera, T_w2, n)
    found = image_road_scale(image1, image2, camera, R, t, n, HEIGHT, steps=(0.0, 7.0))
    assert found.scale == pytest.approx(2.5, rel=0.01)
    wrong = image_road_scale(image1, image2, CAMERA, R, t, n, HEIGHT, steps=(0.0, 7.0))
    assert math.isfinite(wrong.scale) and abs(wrong.scale - 2.5) > 0.02 * 2.5, wrong.scale


def test_bad_arguments_raise(texture):
    image1, image2, R, t, n = _pair(texture, 2.0)
    call = functools.partial(image_road_scale, steps=(0.0, 7.0))
    with pytest.raises(InputError, match='gray1: expected an 8-bit grey image of the camera'):
        call(cv2.cvtColor(image1, cv2.COLOR_GRAY2BGR), image2, CAMERA, R, t, n, HEIGHT)
    with pytest.raises(InputError, match='gray2: .* 960x300'):
        call(image1, image2[:280, :900], CAMERA, R, t, n, HEIGHT)
    with pytest.raises(InputError, match='camera: expected a CameraModel'):
        call(image1, image2, 'kitti', R, t, n, HEIGHT)
    with pytest.raises(InputError, match='R: expected a rotation'):
        call(image1, image2, CAMERA, 2 * R, t, n, HEIGHT)
    with pytest.raises(InputError, match='t: expected a non-zero direction'):
        call(image1, image2, CAMERA, R, np.zeros(3), n, HEIGHT)
    with pytest.raises(InputError, match='n: '):
        call(image1, image2, CAMERA, R, t, [0.0, np.nan, 1.0], HEIGHT)
    for name, value in (('height', 0.0), ('height', -1.6), ('max_depth', math.inf),
                        ('lateral_std', 0.0)):
        args = {'height': HEIGHT, name: value}
        with pytest.raises(ConfigError, match=f'{name}: expected a positive number'):
            call(image1, image2, CAMERA, R, t, n, **args)
    with pytest.raises(ConfigError, match='min_blocks: expected an integer of at least 1'):
        call(image1, image2, CAMERA, R, t, n, HEIGHT, min_blocks=0)
