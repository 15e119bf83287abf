"""Camera model (distortion maps and Jacobians), rigid frames, and the AC container."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from planar_vo.core.camera import CameraModel
from planar_vo.core.conventions import (
    R_BASE_OPTICAL,
    camera_motion_to_base,
    invert,
    mount_transform,
    planar_pose,
    quaternion_from_rotation,
    rotation_from_quaternion,
    rotation_rpy,
    yaw_of,
)
from planar_vo.core.correspondences import AffineCorrespondences
from planar_vo.core.homography import apply_homography
from planar_vo.errors import CameraModelError, InputError

K = np.array([[500.0, 0.0, 320.0], [0.0, 510.0, 240.0], [0.0, 0.0, 1.0]])
CAMERAS = {
    'none': CameraModel(640, 480, K),
    'plumb_bob': CameraModel(640, 480, K, 'plumb_bob', (-0.28, 0.07, 1e-3, -5e-4, -0.01)),
    # A wide lens calibrated with OpenCV's rational model (k4 near k1, as such fits come out).
    'rational_polynomial': CameraModel(640, 480, K, 'rational_polynomial',
                                       (0.45, -0.12, 1e-3, -5e-4, 0.01, 0.75, -0.05, 0.02)),
    'equidistant': CameraModel(640, 480, K, 'equidistant', (0.05, -0.01, 0.002, -0.0005)),
}


def _numeric_jacobian(f, x, h=1e-6):
    cols = []
    for k in range(2):
        d = np.zeros(2)
        d[k] = h
        cols.append((f(x + d) - f(x - d)) / (2 * h))
    return np.stack(cols, -1)


@pytest.mark.parametrize('name', list(CAMERAS))
def test_distortion_jacobian_matches_finite_differences(rng, name):
    cam = CAMERAS[name]
    x = rng.uniform(-0.6, 0.6, (200, 2))
    _, J = cam.distort(x)
    Jn = _numeric_jacobian(lambda y: cam.distort(y)[0], x)
    np.testing.assert_allclose(J, Jn, atol=1e-7)


@pytest.mark.parametrize('name', list(CAMERAS))
def test_pixel_round_trip_and_jacobians_are_inverse(rng, name):
    cam = CAMERAS[name]
    p = rng.uniform((0, 0), (640, 480), (300, 2))
    q, Jq = cam.pixel_to_normalized(p)
    p_back, Jp = cam.normalized_to_pixel(q)
    np.testing.assert_allclose(p_back, p, atol=1e-8)
    np.testing.assert_allclose(Jq @ Jp, np.broadcast_to(np.eye(2), Jq.shape), atol=1e-9)
    Jn = _numeric_jacobian(lambda y: cam.pixel_to_normalized(y)[0], p, h=1e-3)
    np.testing.assert_allclose(Jq, Jn, atol=1e-8)


def test_camera_info_duck_typed():
    msg = SimpleNamespace(width=640, height=480, k=K.ravel(), d=[0.0] * 5,
                          distortion_model='plumb_bob')
    cam = CameraModel.from_camera_info(msg)
    assert cam == CAMERAS['none'] and not cam.is_distorted
    msg.d = list(CAMERAS['plumb_bob'].D)
    assert CameraModel.from_camera_info(msg) == CAMERAS['plumb_bob']


def test_rectified_images_take_the_projection_without_distortion():
    """image_rect with its CameraInfo (a user test: the raw camera's D was applied to rectified
    KITTI frames and the distance came out 6 % long): camera.rectified reads P, as
    image_geometry does for rectified images; a P of zeros is refused, naming the switch."""
    P = np.array([[450.0, 0.0, 330.0, -45.0], [0.0, 452.0, 238.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
    msg = SimpleNamespace(width=640, height=480, k=K.ravel(), d=list(CAMERAS['plumb_bob'].D),
                          distortion_model='plumb_bob', p=P.ravel())
    assert CameraModel.from_camera_info(msg) == CAMERAS['plumb_bob']
    rect = CameraModel.from_camera_info(msg, rectified=True)
    assert rect == CameraModel(640, 480, P[:, :3]) and not rect.is_distorted
    msg.p = np.zeros(12)
    with pytest.raises(CameraModelError, match=r"camera_info: P is all zeros, and "
                                               r"camera.rectified uses it \(a raw camera's "
                                               r'CameraInfo: set camera.rectified false\)'):
        CameraModel.from_camera_info(msg, rectified=True)


def test_rational_polynomial_is_plumb_bob_with_a_radial_ratio_and_zero_padding_is_accepted(rng):
    """OpenCV's rational model (a user test: refused, so the node had no camera model): with
    k4 = k5 = k6 = 0 it is plumb_bob to the bit; drivers' zero-padded coefficient lists (8 for
    plumb_bob, 14 for the rational model) mean the shorter model, and all zeros no distortion."""
    x = rng.uniform(-0.6, 0.6, (100, 2))
    plumb = CAMERAS['plumb_bob']
    same = CameraModel(640, 480, K, 'rational_polynomial', plumb.D + (0.0, 0.0, 0.0))
    for a, b in zip(plumb.distort(x), same.distort(x)):
        np.testing.assert_array_equal(a, b)
    # The radial factor is the ratio of the two polynomials.
    rational = CAMERAS['rational_polynomial']
    k1, k2, p1, p2, k3, k4, k5, k6 = rational.D
    r2 = (x * x).sum(1)
    numerator = 1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
    radial = numerator / (1 + k4 * r2 + k5 * r2 ** 2 + k6 * r2 ** 3)
    u, v = x.T
    expected = np.stack([u * radial + 2 * p1 * u * v + p2 * (r2 + 2 * u * u),
                         v * radial + p1 * (r2 + 2 * v * v) + 2 * p2 * u * v], -1)
    np.testing.assert_allclose(rational.distort(x)[0], expected, rtol=1e-13, atol=1e-15)
    msg = SimpleNamespace(width=640, height=480, k=K.ravel(), d=list(plumb.D) + [0.0] * 3,
                          distortion_model='plumb_bob')
    assert CameraModel.from_camera_info(msg) == plumb
    msg.d, msg.distortion_model = list(rational.D) + [0.0] * 6, 'rational_polynomial'
    assert CameraModel.from_camera_info(msg) == rational
    msg.d = [0.0] * 8
    assert CameraModel.from_camera_info(msg) == CAMERAS['none']


def test_camera_info_binning_and_roi_give_the_images_model():
    """REP-104: K and the size are the full sensor's; the images are its ROI, binned."""
    full = np.array([[1414.2, 0.0, 1203.8], [0.0, 1414.2, 366.2], [0.0, 0.0, 1.0]])
    roi = SimpleNamespace(x_offset=0, y_offset=0, width=0, height=0, do_rectify=False)
    msg = SimpleNamespace(width=2452, height=740, k=full.ravel(), d=[], distortion_model='',
                          binning_x=2, binning_y=2, roi=roi)
    cam = CameraModel.from_camera_info(msg)
    assert cam.size == (1226, 370)
    assert np.allclose([cam.fx, cam.fy, cam.cx, cam.cy], [707.1, 707.1, 601.9, 183.1])
    # A 1000x400 window at (400, 100), not binned.
    msg.binning_x = msg.binning_y = 0
    msg.roi = SimpleNamespace(x_offset=400, y_offset=100, width=1000, height=400,
                              do_rectify=False)
    cam = CameraModel.from_camera_info(msg)
    assert cam.size == (1000, 400)
    assert np.allclose([cam.fx, cam.cx, cam.cy], [1414.2, 803.8, 266.2])
    msg.roi.x_offset = 1500
    with pytest.raises(CameraModelError, match=r'region of interest 1000x400 at \(1500, 100\) '
                                               r'does not fit the 2452x740 sensor'):
        CameraModel.from_camera_info(msg)


@pytest.mark.parametrize(('changes', 'match'), [
    ({'k': np.zeros(9)}, r'K is all zeros \(uncalibrated camera\)'),
    ({'distortion_model': 'kannala_brandt', 'd': [0.1] * 4},
     r"distortion_model: expected one of \['none', 'plumb_bob', 'rational_polynomial', "
     r"'equidistant'\], got 'kannala_brandt'"),
    ({'distortion_model': 'plumb_bob', 'd': [0.1, 0, 0, 0, 0, 0.2, 0, 0]},
     r"D: expected 5 coefficients for 'plumb_bob' \(more only if the extra ones are 0\), "
     r"got 8"),
    ({'distortion_model': 'rational_polynomial', 'd': [0.1] * 5},
     r"D: expected 8 coefficients for 'rational_polynomial', got 5"),
    ({'distortion_model': 'equidistant', 'd': [0.1, 0.2]}, r"D: expected 4 coefficients"),
    ({'distortion_model': '', 'd': [0.1, 0, 0, 0, 0]}, r'without a distortion model'),
    ({'width': 0}, r'image size: expected positive integers, got 0x480'),
    ({'k': [1.0, 2.0]}, r'camera_info: not a CameraInfo message'),
    ({'k': np.r_[K.ravel()[:8], np.nan]},
     r'K: expected a finite 3x3 matrix, got \[\[.*, nan\]\]$'),   # a list, on one line
])
def test_camera_info_errors(changes, match):
    fields = dict(width=640, height=480, k=K.ravel(), d=[], distortion_model='')
    fields.update(changes)
    with pytest.raises(CameraModelError, match=match):
        CameraModel.from_camera_info(SimpleNamespace(**fields))


def test_a_boolean_image_size_is_refused():
    # (a user test: a width of True was taken as 1)
    with pytest.raises(CameraModelError, match=r'^image size: expected positive integers, got '
                                               r'Truex100$'):
        CameraModel.pinhole(True, 100, 50.0)


@pytest.mark.parametrize(('changes', 'match'), [
    # A focal length 100 times too long: a 0.7-degree view, no lens on a vehicle has that.
    ({'k': np.diag([50000.0, 50000.0, 1.0]) + np.array([[0, 0, 319.5], [0, 0, 239.5], [0, 0, 0]])},
     r'horizontal field of view 0.733 deg \(fx 50000, fy 50000 px on 640x480\) is outside the '
     r'3-160 deg of real rectilinear lenses'),
    # Only the vertical focal length wrong.
    ({'k': np.array([[500.0, 0, 319.5], [0, 20000.0, 239.5], [0, 0, 1]])},
     r'vertical field of view 1.38 deg'),
    # A focal length 100 times too short: wider than a rectilinear lens can see.
    ({'k': np.array([[5.0, 0, 319.5], [0, 5.0, 239.5], [0, 0, 1]])},
     r'horizontal field of view 178 deg .* 3-160 deg of real rectilinear lenses'),
    ({'k': np.array([[50.0, 0, 319.5], [0, 50.0, 239.5], [0, 0, 1]]),
      'distortion_model': 'equidistant', 'd': [0.0] * 4},
     r'horizontal field of view 733 deg .* 3-280 deg of real fisheye lenses'),
    # Absurd distortion or skew: every frame would be lost.
    ({'distortion_model': 'plumb_bob', 'd': [1e308, 1e308, 0, 0, 0]},
     r"the plumb_bob distortion \[1e\+308, 1e\+308, 0.0, 0.0, 0.0\] cannot be inverted over "
     r"the image \(\d+ of 81 grid pixels"),
    ({'distortion_model': 'equidistant', 'd': [1e308] * 4}, r'equidistant distortion .* cannot'),
    # A distortion that folds over between the centre and the image's edge: Newton finds a
    # root beyond the fold, not the lens's own (a user test).
    ({'distortion_model': 'plumb_bob', 'd': [-2.0, 0, 0, 0, 0]},
     r"the plumb_bob distortion \[-2.0, 0.0, 0.0, 0.0, 0.0\] cannot be inverted over the image "
     r"\(\d+ of 81 grid pixels have no undistorted position on the lens's one-to-one part\)"),
    # One-to-one, but the image squeezed into a degree (a user test: D = [1e6, -1e6, 0, 0, 1e6]
    # was accepted; its frames ran on unit steps with a position std of 5 km).
    ({'distortion_model': 'plumb_bob', 'd': [1e6, -1e6, 0, 0, 1e6]},
     r'the plumb_bob distortion \[1000000.0, -1000000.0, 0.0, 0.0, 1000000.0\] leaves a '
     r'horizontal field of view of 0.983 deg, outside the 3-160 deg of real rectilinear lenses'),
    ({'k': np.array([[500.0, 1e308, 319.5], [0, 500.0, 239.5], [0, 0, 1]])},
     r'skew 1e\+308 is more than 0.1 fx \(fx 500\)'),
    # The principal point of a 1920x1440 calibration on 640x480 images.
    ({'k': np.array([[500.0, 0, 959.5], [0, 500.0, 719.5], [0, 0, 1]])},
     r'principal point \(959.5, 719.5\) lies outside the 640x480 image'),
])
def test_implausible_camera_info_is_refused(changes, match):
    fields = dict(width=640, height=480, k=K.ravel(), d=[], distortion_model='')
    fields.update({k: np.ravel(v) if k == 'k' else v for k, v in changes.items()})
    with pytest.raises(CameraModelError, match=match):
        CameraModel.from_camera_info(SimpleNamespace(**fields))


@pytest.mark.parametrize(('width', 'height', 'fx', 'model'), [
    (1241, 376, 718.856, 'none'),            # KITTI: 82 x 29 degrees
    (640, 480, 4000.0, 'none'),              # a 9-degree telephoto
    (1280, 800, 320.0, 'equidistant'),       # a 229-degree fisheye
    (320, 240, 60.0, 'plumb_bob'),           # 139 degrees, a wide-angle lens
])
def test_real_lenses_are_plausible(width, height, fx, model):
    d = {'none': (), 'plumb_bob': (-0.3, 0.1, 0.0, 0.0, 0.0), 'equidistant': (0.0,) * 4}[model]
    camera = CameraModel(width, height, np.array([[fx, 0, width / 2], [0, fx, height / 2],
                                                  [0, 0, 1.0]]), model, d)
    camera.check_plausible()
    horizontal, vertical = np.degrees(camera.field_of_view)
    expected = (2 * np.degrees(width / 2 / fx) if model == 'equidistant' else
                2 * np.degrees(np.arctan(width / 2 / fx)))
    assert horizontal == pytest.approx(expected, rel=1e-12) and 3.0 <= vertical <= horizontal


def test_an_equidistant_model_without_coefficients_is_the_ideal_fisheye():
    """All-zero coefficients of ``equidistant`` (a CameraInfo's, or the configuration's empty
    list) are the ideal fisheye ``theta_d = theta``, not a pinhole (a user test: a pixel 300 px
    from the centre at f = 300 px was the ray at 45 deg, not at 1 rad)."""
    K3 = np.array([[300.0, 0.0, 320.0], [0.0, 300.0, 240.0], [0.0, 0.0, 1.0]])
    info = SimpleNamespace(width=640, height=480, k=K3.ravel(), d=[0.0] * 4,
                           distortion_model='equidistant', p=np.zeros(12), binning_x=0,
                           binning_y=0, roi=None)
    for camera in (CameraModel(640, 480, K3, 'equidistant', (0.0,) * 4),
                   CameraModel.from_camera_info(info)):
        assert camera.is_distorted
        q, _ = camera.pixel_to_normalized(np.array([[620.0, 240.0], [320.0, 240.0]]))
        np.testing.assert_allclose(q, [[math.tan(1.0), 0.0], [0.0, 0.0]], rtol=1e-9, atol=1e-12)
        p, _ = camera.normalized_to_pixel(q)
        np.testing.assert_allclose(p, [[620.0, 240.0], [320.0, 240.0]], rtol=1e-12)


@pytest.mark.parametrize('name', list(CAMERAS))
def test_pixel_shift_is_how_far_another_model_moves_the_image(name):
    camera = CAMERAS[name]
    assert camera.pixel_shift(camera) < 1e-9
    # Pinhole: a focal length 1 % longer moves the pixel at (u, v) by 1 % of its distance from
    # the principal point: the most at the corner (0, 0) (K's centre is nearer the far corner).
    K2 = K.copy()
    K2[:2, :2] *= 1.01
    longer = CameraModel(640, 480, K2, camera.distortion_model, camera.D)
    if name == 'none':
        assert camera.pixel_shift(longer) == pytest.approx(0.01 * np.hypot(320.0, 240.0),
                                                           rel=1e-12)
    else:
        assert 1.0 < camera.pixel_shift(longer) < 10.0
    assert camera.pixel_shift(CameraModel(320, 240, K)) == np.inf       # another size


def test_mount_transform_conventions():
    T = mount_transform(height=1.65)
    np.testing.assert_allclose(T[:3, :3], R_BASE_OPTICAL)
    np.testing.assert_allclose(T[:3, 3], [0, 0, 1.65])
    # Optical axis along base x; positive pitch looks down (optical z gets a -z component).
    down = mount_transform(pitch=0.1)[:3, :3] @ [0, 0, 1]
    assert down[0] > 0 and down[2] < 0
    left = mount_transform(yaw=0.1)[:3, :3] @ [0, 0, 1]
    assert left[1] > 0


def test_camera_yaw_maps_to_positive_base_yaw_for_left_turn():
    # Camera turns by Ry(alpha) with alpha > 0 (a left turn, see geometry.planar): the camera-2
    # pose in camera 1 is [R^T | -R^T t]; the vehicle must yaw left (positive about z up).
    from planar_vo.core import rotation_y
    alpha = 0.1
    T_c1_c2 = np.eye(4)
    T_c1_c2[:3, :3] = rotation_y(alpha).T
    T_b1_b2 = camera_motion_to_base(T_c1_c2, mount_transform(height=1.5))
    assert yaw_of(T_b1_b2[:3, :3]) == pytest.approx(alpha)


def test_quaternions_round_trip(rng):
    R = rotation_rpy(*rng.uniform(-np.pi, np.pi, (3, 500)))
    q = quaternion_from_rotation(R)
    assert np.all(q[:, 3] >= 0)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0)
    np.testing.assert_allclose(rotation_from_quaternion(q), R, atol=1e-12)
    np.testing.assert_allclose(quaternion_from_rotation(np.eye(3)), [0, 0, 0, 1])


def test_planar_pose_and_inverse(rng):
    T = planar_pose(rng.normal(size=20), rng.normal(size=20), rng.uniform(-3, 3, 20))
    np.testing.assert_allclose(T @ invert(T), np.broadcast_to(np.eye(4), T.shape), atol=1e-12)


def test_correspondences_normalized_matches_chain_rule(rng):
    cam = CAMERAS['plumb_bob']
    p1 = rng.uniform((50, 50), (590, 430), (100, 2))
    A = np.tile([[1.02, 0.01], [-0.02, 0.98]], (100, 1, 1))
    p2 = p1 + 3.0
    acs = AffineCorrespondences(p1, p2, A).normalized(cam)
    q1, J1 = cam.pixel_to_normalized(p1)
    q2, J2 = cam.pixel_to_normalized(p2)
    np.testing.assert_allclose(acs.p1, q1)
    np.testing.assert_allclose(acs.A, J2 @ A @ np.linalg.inv(J1))
    assert len(acs.subset(acs.weights > 0)) == 100


def test_correspondences_check_shapes():
    with pytest.raises(InputError, match=r'same number of items: p1 has 3, p2 has 3, A has 2'):
        AffineCorrespondences(np.zeros((3, 2)), np.zeros((3, 2)), np.zeros((2, 2, 2)))


def test_correspondences_transformed_says_which_items_it_kept():
    """Items whose map gives a finite point but a non-finite Jacobian (or, in image 1, a
    singular one: ``A J1^-1``) are dropped as well as those mapped to NaN, and the mask says
    which: a finite-point check alone would keep them and pair other per-item arrays wrongly
    with the result."""
    p1 = np.array([[0.0, 0.0], [0.5, 0.1], [-0.5, 0.2], [0.3, -0.1], [0.2, 0.2]])
    acs = AffineCorrespondences(p1, p1 + 0.01, np.tile(np.eye(2), (5, 1, 1)),
                                np.array([0.1, 0.2, 0.3, 0.4, 0.5]))

    def identity(p):
        return p.copy(), np.tile(np.eye(2), (len(p), 1, 1))

    def faulty(p):
        g, J = identity(p)
        J[0] = np.inf                   # finite point, overflowing Jacobian
        J[2] = 0.0                      # singular Jacobian (image 1 only)
        g[3] = np.nan                   # no point
        return g, J

    out, kept = acs.transformed_kept(faulty, identity)
    assert kept.tolist() == [False, True, False, False, True]
    np.testing.assert_array_equal(out.p1, p1[kept])
    np.testing.assert_array_equal(out.weights, [0.2, 0.5])
    assert acs.transformed_kept(identity, faulty)[1].tolist() == [False, True, True, False, True]
    # A rotation keeps every ray in front of the camera, and mapped() is mapped_kept()'s ACs.
    R = rotation_rpy(0.1, -0.2, 0.05)
    level, kept = acs.mapped_kept(R)
    assert kept.all()
    np.testing.assert_allclose(level.p1, apply_homography(R, p1))
    np.testing.assert_array_equal(acs.mapped(R).A, level.A)
