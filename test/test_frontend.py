"""Front-end: ACs from images (flow, klt, asift), the batched affine Lucas-Kanade, undistortion
and levelling of ACs, and the mount-tilt estimator.

Image pairs with exact ground truth are made by sampling one procedural texture through a known
homography (image 2 at ``p`` shows the texture at ``H^-1 p``), so the true AC at ``p1`` is
``(H p1, J_H(p1))`` (`homography_jacobian`).
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from planar_vo.config import FrontendConfig
from planar_vo.core import angle_difference, solve_1ac, vote_planar_motion
from planar_vo.core.camera import CameraModel, normalize_affines, normalize_points
from planar_vo.core.conventions import (
    invert,
    mount_transform,
    planar_motion_from_pose,
    planar_pose,
    rotation_y,
)
from planar_vo.core.correspondences import AffineCorrespondences
from planar_vo.core.homography import apply_homography, homography_jacobian, plane_homography
from planar_vo.core.robust.options import EstimatorConfig
from planar_vo.errors import ConfigError, ImageError, InputError
from planar_vo.frontend import (
    ACExtractor,
    correct_acs,
    extract_acs,
    level_acs,
    leveling_homography,
    leveling_rotation,
    undistort_acs,
)
from planar_vo.frontend.affine_lk import (
    _cholesky_inverse,
    patch_offsets,
    prepare_template,
    refine_affines,
    singular_values_2x2,
    smooth_for_refinement,
)
from planar_vo.frontend.asift import asift_views, keypoint_frames
from planar_vo.frontend.flow import (
    _PARALLEL_MIN_PATCHES,
    flow_downscale,
    flow_jacobian,
    neighbour_predictions,
    shrink,
    texture_grid,
)
from planar_vo.pipeline.calibration import MountTiltEstimator
from planar_vo.pipeline.estimator import MotionEstimator
from planar_vo.sim import (
    GROUND_KIND,
    StreetWorld,
    concatenate,
    exact_acs,
    relative_planar_motion,
    render,
    turn,
)

W, H = 320, 240
K = np.array([[250.0, 0.0, 159.5], [0.0, 250.0, 119.5], [0.0, 0.0, 1.0]])
PAD = 80                 # texture margin around the image (pixels)
SUPERSAMPLE = 2


# --------------------------------------------------------------------------------------------
# Procedural texture pairs with exact ground truth
# --------------------------------------------------------------------------------------------

def _texture(seed: int) -> np.ndarray:
    """Multi-octave noise (1/f-like), supersampled, covering the image plus ``PAD``."""
    rng = np.random.default_rng(seed)
    h, w = (H + 2 * PAD) * SUPERSAMPLE, (W + 2 * PAD) * SUPERSAMPLE
    out = np.zeros((h, w), np.float32)
    for octave in (1, 2, 4, 8, 16, 32):
        s = octave * SUPERSAMPLE
        noise = rng.standard_normal((h // s + 3, w // s + 3)).astype(np.float32)
        up = cv2.resize(noise, (noise.shape[1] * s, noise.shape[0] * s),
                        interpolation=cv2.INTER_CUBIC)
        out += up[:h, :w] * np.sqrt(octave)
    out = cv2.GaussianBlur(out, (0, 0), 0.7 * SUPERSAMPLE)
    return 128.0 + 45.0 * (out - out.mean()) / out.std()


def _sample(texture: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """The texture seen at image coordinates ``xy`` ``(H, W, 2)``, as uint8."""
    m = ((xy + PAD + 0.5) * SUPERSAMPLE - 0.5).astype(np.float32)
    img = cv2.remap(texture, m[..., 0], m[..., 1], cv2.INTER_CUBIC,
                    borderMode=cv2.BORDER_REFLECT)
    return np.clip(img + 0.5, 0, 255).astype(np.uint8)


def _grid() -> np.ndarray:
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float64)
    return np.stack([xs, ys], -1)


def _homography_pair(Hmat: np.ndarray, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    tex = _texture(seed)
    p = _grid()
    p_src = apply_homography(np.linalg.inv(Hmat), p.reshape(-1, 2)).reshape(H, W, 2)
    return _sample(tex, p), _sample(tex, np.nan_to_num(p_src, nan=-1e4))


MILD = np.array([[1.03, 0.02, 4.3], [-0.01, 0.98, -2.7], [4e-5, -2e-5, 1.0]])


def _ground_homography(forward: float = 0.4, yaw_deg: float = 1.0) -> np.ndarray:
    """Ground plane 1.5 m below a level camera that moves ``forward`` metres and turns."""
    R = rotation_y(np.deg2rad(yaw_deg))
    t = -R @ np.array([0.0, 0.0, forward])
    return plane_homography(K, K, R, t, np.array([0.0, 1.0, 0.0]), 1.5)


def _errors(acs: AffineCorrespondences, Hmat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    point = np.linalg.norm(acs.p2 - apply_homography(Hmat, acs.p1), axis=1)
    affine = np.linalg.norm(acs.A - homography_jacobian(Hmat, acs.p1), axis=(1, 2))
    return point, affine


@pytest.fixture(scope='module')
def mild_pair():
    return _homography_pair(MILD, seed=1)


@pytest.fixture(scope='module')
def ground_pair():
    return _homography_pair(_ground_homography(), seed=2)


# --------------------------------------------------------------------------------------------
# extract_acs on exact pairs
# --------------------------------------------------------------------------------------------

def test_flow_acs_match_the_exact_homography(mild_pair):
    acs = extract_acs(*mild_pair)
    point, affine = _errors(acs, MILD)
    assert len(acs) > 300
    assert np.median(point) < 0.05 and np.percentile(point, 95) < 0.15
    assert np.median(affine) < 0.015 and np.percentile(affine, 95) < 0.04
    assert np.all((acs.weights > 0) & (acs.weights <= 1))


def test_flow_refinement_fixes_the_foreshortened_ground(ground_pair):
    Hg = _ground_homography()
    below = 119.5 + 40.0          # rows well below the horizon, where the ground is seen
    refined = extract_acs(*ground_pair)
    raw = extract_acs(*ground_pair, config=FrontendConfig(refine_affine=False))
    refined = refined.subset(refined.p1[:, 1] > below)
    raw = raw.subset(raw.p1[:, 1] > below)
    point, affine = _errors(refined, Hg)
    _, affine_raw = _errors(raw, Hg)
    assert len(refined) > 100
    assert np.median(point) < 0.1
    assert np.median(affine) < 0.03
    # The flow Jacobian alone is several times worse on the ground (the 0.2 vs 0.04).
    assert np.median(affine_raw) > 3.0 * np.median(affine)


@pytest.mark.parametrize(('width', 'max_width', 'factor'), [
    (640, 800, 1), (1241, 800, 2), (1600, 800, 2), (1601, 800, 3), (1920, 0, 1), (320, 160, 2)])
def test_flow_downscale_is_the_smallest_factor_that_fits(width, max_width, factor):
    assert flow_downscale(width, max_width) == factor


@pytest.mark.parametrize('scale', [1, 2, 3])
def test_flow_jacobian_of_a_shrunk_affine_field_is_exact(scale):
    # A flow field that is an affine map of the full-resolution pixels, stored as the flow of
    # the shrunk images (shrunk displacements at shrunk pixel centres): the Jacobian at
    # full-resolution points is the map's, whatever the shrink factor.
    A = np.array([[1.04, -0.03], [0.02, 0.97]])
    t = np.array([3.2, -1.7])
    hs, ws = 120 // scale, 160 // scale
    qy, qx = np.mgrid[0:hs, 0:ws].astype(np.float64)
    q = np.stack([qx, qy], -1)
    p = (q + 0.5) * scale - 0.5
    flow = ((p @ (A - np.eye(2)).T + t) / scale).astype(np.float32)
    points = np.array([[40, 30], [81, 57], [100, 77], [63, 44]])
    J = flow_jacobian(flow, points, 4, scale)
    np.testing.assert_allclose(J, np.broadcast_to(A, J.shape), atol=1e-5)


def test_shrink_averages_blocks():
    image = np.arange(48, dtype=np.uint8).reshape(6, 8) * 5
    small = shrink(image, 2)
    assert small.shape == (3, 4)
    expected = image.reshape(3, 2, 4, 2).astype(float).mean(axis=(1, 3))
    assert np.all(np.abs(small - expected) <= 0.5)
    assert shrink(image, 1) is image


@pytest.mark.parametrize('max_width', [0, 160, 107])
def test_flow_acs_from_a_shrunk_flow_match_the_exact_homography(
        mild_pair, ground_pair, max_width):
    # Flow on images shrunk 1x, 2x and 3x: the full-resolution refinement gives the same ACs.
    config = FrontendConfig(flow_max_width=max_width)
    acs = extract_acs(*mild_pair, config=config)
    point, affine = _errors(acs, MILD)
    assert len(acs) > 300
    assert np.median(point) < 0.05 and np.percentile(point, 95) < 0.15
    assert np.median(affine) < 0.015 and np.percentile(affine, 95) < 0.04
    ground = extract_acs(*ground_pair, config=config)
    ground = ground.subset(ground.p1[:, 1] > 159.5)
    point, affine = _errors(ground, _ground_homography())
    assert len(ground) > 100
    assert np.median(point) < 0.1 and np.median(affine) < 0.03


def test_flow_points_are_spread_over_the_image(mild_pair):
    acs = extract_acs(*mild_pair)
    cells, _, _ = np.histogram2d(acs.p1[:, 0], acs.p1[:, 1], bins=(4, 3),
                                 range=((0, W), (0, H)))
    assert cells.min() >= 0.5 * cells.mean()


def test_klt_acs_match_the_exact_homography(mild_pair):
    acs = extract_acs(*mild_pair, method='klt')
    point, affine = _errors(acs, MILD)
    assert len(acs) > 200
    assert np.median(point) < 0.05 and np.median(affine) < 0.015


def test_klt_converges_on_the_ground_from_the_identity(ground_pair):
    Hg = _ground_homography()
    acs = extract_acs(*ground_pair, method='klt')
    acs = acs.subset(acs.p1[:, 1] > 119.5 + 40.0)
    point, affine = _errors(acs, Hg)
    assert len(acs) > 50
    assert np.median(point) < 0.1 and np.median(affine) < 0.03


def test_asift_affines_follow_rotation_and_anisotropic_scaling():
    c = np.array([[1.0, 0.0, 159.5], [0.0, 1.0, 119.5], [0.0, 0.0, 1.0]])
    th = np.deg2rad(30.0)
    rot = np.array([[np.cos(th), -np.sin(th), 0.0], [np.sin(th), np.cos(th), 0.0], [0, 0, 1.0]])
    Hmat = c @ rot @ np.diag([1.4, 0.9, 1.0]) @ np.linalg.inv(c)
    acs = extract_acs(*_homography_pair(Hmat, seed=3), method='asift')
    point, affine = _errors(acs, Hmat)
    inliers = point < 2.0
    assert inliers.sum() > 100 and inliers.mean() > 0.7
    # ASIFT frames are coarse (the paper's ACs are noisy), but a wrong rotation sense or a
    # similarity-only frame gives errors around 1; the true A has norm about 1.7.
    assert np.median(affine[inliers]) < 0.3
    assert np.all(acs.weights > 0)


def test_asift_view_sampling_and_keypoint_frames():
    tilts, rolls = asift_views()
    assert len(tilts) == 43 and tilts[0] == 1.0 and np.isclose(tilts.max(), 4 * np.sqrt(2))
    assert np.all(rolls < 180.0)
    # A keypoint of the view with tilt t and roll phi: F = R(-phi) diag(t, 1) s R(theta).
    view = 20
    kp = cv2.KeyPoint(10.0, 20.0, 3.0, 40.0, 0, 0, view)
    points, frames = keypoint_frames([kp], tilts, rolls)
    phi, th, t = np.deg2rad(rolls[view]), np.deg2rad(40.0), tilts[view]
    P = np.diag([1.0 / t, 1.0]) @ np.array([[np.cos(phi), -np.sin(phi)],
                                            [np.sin(phi), np.cos(phi)]])
    S = 3.0 * np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    np.testing.assert_allclose(points, [[10.0, 20.0]])
    np.testing.assert_allclose(frames[0], np.linalg.inv(P) @ S, atol=1e-12)


def test_bgr_input_gives_the_same_acs_as_grey(mild_pair):
    g1, g2 = mild_pair
    bgr1, bgr2 = (cv2.cvtColor(g, cv2.COLOR_GRAY2BGR) for g in (g1, g2))
    a, b = extract_acs(g1, g2), extract_acs(bgr1, bgr2)
    np.testing.assert_array_equal(a.p1, b.p1)
    np.testing.assert_allclose(a.A, b.A)


def test_flow_acs_do_not_depend_on_the_opencv_thread_count():
    # The refinement batches its patches alike with one OpenCV thread or several (cv2.gemm
    # rounds differently for other row counts), so the ACs agree to the last bit: fleet tasks
    # run with one thread and must equal a replay. A rendered VGA street has enough patches.
    camera = CameraModel.pinhole(640, 480, 500.0)
    drive = turn(np.pi / 8, radius=15.0, speed=6.0)
    poses = drive.camera_poses(mount_transform(height=1.5))
    world = StreetWorld.along(drive, seed=4)
    images = [render(world, camera, poses[k]).image for k in (0, 1)]
    previous = cv2.getNumThreads()
    try:
        runs = []
        for threads in (1, 2):
            cv2.setNumThreads(threads)
            runs.append(extract_acs(*images))
    finally:
        cv2.setNumThreads(previous)
    one, two = runs
    assert len(one) >= _PARALLEL_MIN_PATCHES            # enough patches to run in two halves
    for name in ('p1', 'p2', 'A', 'weights'):
        np.testing.assert_array_equal(getattr(one, name), getattr(two, name), err_msg=name)


@pytest.mark.parametrize('value', [0, 128, 255])
@pytest.mark.parametrize('method', ['flow', 'klt'])
def test_textureless_frames_give_no_acs(value, method):
    flat = np.full((H, W), value, np.uint8)
    acs = extract_acs(flat, flat, method=method)
    assert len(acs) == 0


def test_weights_drop_where_the_image_is_noisy(mild_pair):
    g1, g2 = mild_pair
    rng = np.random.default_rng(5)
    noisy = g2.astype(np.float64)
    noisy[:, W // 2:] += rng.normal(0.0, 12.0, (H, W - W // 2))
    noisy = np.clip(noisy, 0, 255).astype(np.uint8)
    acs = extract_acs(g1, noisy)
    right = acs.p1[:, 0] > W // 2 + 10
    left = acs.p1[:, 0] < W // 2 - 10
    assert np.median(acs.weights[right]) < 0.5 * np.median(acs.weights[left])


def test_extractor_reports_stage_counts(mild_pair):
    ex = ACExtractor(FrontendConfig(max_correspondences=200))
    acs = ex.extract(*mild_pair)
    assert ex.stats['candidates'] <= 200
    assert ex.stats['accepted'] == len(acs) <= ex.stats['fb_consistent'] <= ex.stats['candidates']


def _turn_homography(yaw_deg: float) -> np.ndarray:
    """Image 1 -> image 2 of a camera turning by ``yaw_deg`` (the infinite homography)."""
    return K @ rotation_y(np.deg2rad(yaw_deg)) @ np.linalg.inv(K)


@pytest.fixture(scope='module')
def turn_pair():
    return _homography_pair(_turn_homography(8.0), seed=4)


@pytest.mark.parametrize('predicted_yaw', [8.0, 6.5, 0.0])
def test_warped_extraction_gives_the_acs_of_the_given_images(turn_pair, predicted_yaw):
    """A turn of 8 deg (35 px at the centre); the prediction exact, 1.5 deg off, or none: the
    ACs are those of the original images, mapped back exactly, patches inside image 1."""
    ex = ACExtractor()
    acs = ex.extract_warped(*turn_pair, _turn_homography(predicted_yaw))
    point, affine = _errors(acs, _turn_homography(8.0))
    assert len(acs) > 250
    assert np.median(point) < 0.05 and np.percentile(point, 95) < 0.15
    assert np.median(affine) < 0.015 and np.percentile(affine, 95) < 0.04
    margin = ex.config.patch_radius + 1
    assert np.all((acs.p1 >= margin) & (acs.p1 <= np.array([W, H]) - 1 - margin))
    assert ex.extract_more(lambda p: np.ones(len(p), bool)) is None


def test_warped_extraction_by_the_identity_is_plain_extraction(mild_pair):
    ex = ACExtractor()
    plain = ex.extract(*mild_pair)
    warped = ex.extract_warped(*mild_pair, np.eye(3))
    margin = ex.config.patch_radius + 1
    inside = np.all((plain.p1 >= margin) & (plain.p1 <= np.array([W, H]) - 1 - margin), axis=1)
    assert 0 < len(warped) == inside.sum()
    for name in ('p1', 'p2', 'A', 'weights'):
        np.testing.assert_array_equal(getattr(warped, name), getattr(plain, name)[inside])


@pytest.mark.parametrize(('Hmat', 'match'), [
    (np.eye(2), r'H: expected a finite 3x3 homography, got shape \(2, 2\)'),
    (np.full((3, 3), np.nan), r'H: expected a finite 3x3 homography'),
    (np.diag([1.0, 1.0, 0.0]), r'H: expected an invertible homography, got condition number'),
])
def test_warped_extraction_rejects_a_bad_homography(mild_pair, Hmat, match):
    with pytest.raises(InputError, match=match):
        ACExtractor().extract_warped(*mild_pair, Hmat)


@pytest.mark.parametrize(('image1', 'image2', 'match'), [
    ([[1, 2]], np.zeros((64, 64), np.uint8), r'image1: expected a numpy uint8 image array .* '
                                             r'got list'),
    (np.zeros((0, 64), np.uint8), np.zeros((64, 64), np.uint8), r'image1: expected a non-empty '
                                                                r'image, got .*\(0, 64\)'),
    (np.zeros((64, 64), np.float32), np.zeros((64, 64), np.uint8), r'image1: expected dtype '
                                                                   r'uint8 .* got float32'),
    (np.zeros((64, 64, 2), np.uint8), np.zeros((64, 64), np.uint8), r'image1: expected shape '
                                                                    r'.* got \(64, 64, 2\)'),
    (np.zeros((16, 64), np.uint8), np.zeros((16, 64), np.uint8), r'image1: expected at least '
                                                                 r'32x32 pixels, got 64x16'),
    (np.zeros((64, 64), np.uint8), np.zeros((64, 80), np.uint8), r'image2: expected the size of '
                                                                 r'image1 \(64x64\), got 80x64'),
    (np.zeros((64, 64), np.uint8), None, r'image2: expected a numpy uint8 image array .* got '
                                         r'NoneType'),
])
def test_bad_images_are_rejected_with_a_clear_message(image1, image2, match):
    with pytest.raises(ImageError, match=match):
        extract_acs(image1, image2)


def test_unknown_method_is_rejected(mild_pair):
    with pytest.raises(InputError, match=r"method: expected one of \['flow', 'klt', 'asift'\], "
                                         r"got 'sift'"):
        extract_acs(*mild_pair, method='sift')


@pytest.mark.parametrize(('field', 'value', 'match'), [
    ('patch_stride', 10, r'patch_stride: expected between 1 and patch_radius'),
    ('fb_threshold', -1.0, r'fb_threshold: expected a non-negative number'),
    ('match_ratio', 1.5, r'match_ratio: expected in \(0, 1\]'),
    ('lk_iterations', 0, r'lk_iterations: expected at least 1'),
])
def test_frontend_config_validation(field, value, match):
    with pytest.raises(ConfigError, match=match):
        FrontendConfig(**{field: value})


# --------------------------------------------------------------------------------------------
# The batched affine Lucas-Kanade and its helpers
# --------------------------------------------------------------------------------------------

def test_affine_lk_converges_to_an_exact_affine_warp(rng):
    # Image 2 is image 1 under one exact affine map, so every patch's warp is that map.
    M = np.array([[1.08, 0.06, 3.3], [-0.04, 0.93, -1.7]])
    tex = _texture(7)
    p = _grid()
    g1 = _sample(tex, p)
    Minv = cv2.invertAffineTransform(M)
    g2 = _sample(tex, p @ Minv[:, :2].T + Minv[:, 2])
    p1 = rng.integers(20, (W - 20, H - 20), (300, 2))
    true_p2 = p1 @ M[:, :2].T + M[:, 2]
    f1, f2 = smooth_for_refinement(g1), smooth_for_refinement(g2)
    template = prepare_template(f1, p1, patch_offsets(7, 2))
    start_A = np.broadcast_to(np.eye(2), (300, 2, 2)) + rng.normal(0, 0.05, (300, 2, 2))
    start_p2 = true_p2 + rng.normal(0, 0.7, (300, 2))
    result = refine_affines(template, f2, start_p2, start_A, iterations=6)
    ok = result.ok
    assert ok.mean() > 0.9
    assert np.median(np.linalg.norm(result.p2[ok] - true_p2[ok], axis=1)) < 0.03
    assert np.median(np.linalg.norm(result.A[ok] - M[:, :2], axis=(1, 2))) < 0.01
    # The predicted standard error is of the order of the actual error.
    actual = np.median(np.linalg.norm(result.A[ok] - M[:, :2], axis=(1, 2)))
    assert 0.2 < np.median(result.sigma_A[ok]) / actual < 5.0


def test_a_patch_refines_to_the_same_bits_in_any_batch(rng):
    # One batch on one thread, two halves on two: a patch's result must not depend on which
    # other patches share its batch (BLAS and cv2.gemm round differently for other row counts).
    M = np.array([[1.05, 0.03, 2.6], [-0.02, 0.96, -1.1]])
    tex = _texture(5)
    p = _grid()
    Minv = cv2.invertAffineTransform(M)
    f1 = smooth_for_refinement(_sample(tex, p))
    f2 = smooth_for_refinement(_sample(tex, p @ Minv[:, :2].T + Minv[:, 2]))
    n = 301
    p1 = rng.integers(20, (W - 20, H - 20), (n, 2))
    template = prepare_template(f1, p1, patch_offsets(9, 3))
    p2 = p1 @ M[:, :2].T + M[:, 2] + rng.normal(0, 1.0, (n, 2))
    A = np.broadcast_to(np.eye(2), (n, 2, 2)) + rng.normal(0, 0.05, (n, 2, 2))
    whole = refine_affines(template, f2, p2, A, iterations=2, max_iterations=4)
    assert whole.ok.mean() > 0.8
    for index in (np.arange(1), np.arange(n // 2), np.arange(n // 2, n), rng.permutation(n)[:37]):
        part = refine_affines(template.subset(index), f2, p2[index], A[index], iterations=2,
                              max_iterations=4)
        for name in ('p2', 'A', 'residual', 'sigma_A', 'ok'):
            np.testing.assert_array_equal(getattr(part, name), getattr(whole, name)[index],
                                          err_msg=f'{name}, batch of {index.size}')


def test_cholesky_inverse_matches_numpy(rng):
    B = rng.normal(size=(50, 6, 6))
    Hs = B @ B.transpose(0, 2, 1) + 0.1 * np.eye(6)
    inv, ok = _cholesky_inverse(np.ascontiguousarray(Hs.transpose(1, 2, 0)))
    assert ok.all()
    np.testing.assert_allclose(inv.transpose(2, 0, 1), np.linalg.inv(Hs), rtol=1e-9, atol=1e-9)
    singular = np.zeros((6, 6, 1))
    assert not _cholesky_inverse(singular)[1][0]


def test_singular_values_2x2_match_svd(rng):
    A = rng.normal(size=(100, 2, 2))
    smax, smin, det = singular_values_2x2(A)
    s = np.linalg.svd(A, compute_uv=False)
    np.testing.assert_allclose(smax, s[:, 0], rtol=1e-12)
    np.testing.assert_allclose(smin, s[:, 1], atol=1e-12)
    np.testing.assert_allclose(det, np.linalg.det(A), atol=1e-12)


@pytest.mark.parametrize(('radius', 'stride', 'count'), [(7, 2, 64), (7, 1, 225), (5, 3, 9)])
def test_patch_offsets_are_symmetric(radius, stride, count):
    off = patch_offsets(radius, stride)
    assert len(off) == count
    np.testing.assert_array_equal(off.sum(axis=0), [0, 0])
    assert np.abs(off).max() <= radius


def test_texture_grid_one_point_per_cell_inside_the_margin(mild_pair):
    g1, _ = mild_pair
    grid = texture_grid(g1, 16, 12, 1.0, 10000)
    points = grid.points
    assert np.all(points >= 12) and np.all(points[:, 0] <= W - 13) and np.all(
        points[:, 1] <= H - 13)
    cells = {(x // 16, y // 16) for x, y in points - 12}
    assert len(cells) == len(points) > 150
    # The reported cell of each point is the one it lies in.
    np.testing.assert_array_equal(grid.cells, (points - 12)[:, ::-1] // 16)
    assert np.all(grid.texture > 1.0)
    flat = np.full_like(g1, 90)
    assert len(texture_grid(flat, 16, 12, 1.0, 10000)) == 0
    # The cap enlarges the cells instead of dropping well-spread points.
    capped = texture_grid(g1, 16, 12, 1.0, 50)
    assert 25 <= len(capped) <= 50
    # It counts the textured cells only: with half the image blank, the same budget buys a
    # grid twice as fine in area (about as many points, all on the textured half).
    half_blank = g1.copy()
    half_blank[:, W // 2:] = 90
    both = texture_grid(half_blank, 16, 12, 1.0, 50)
    assert 25 <= len(both) <= 50 and np.all(both.points[:, 0] < W // 2 + 16)
    assert both.shape[0] * both.shape[1] > 1.5 * capped.shape[0] * capped.shape[1]
    # A cap below what the largest cells that fit the image hold: the most textured cells of
    # those, never none (a textured strip across a wide, low image).
    strip = np.full((79, 1293), 90, np.uint8)
    strip[30:50] = g1[100:120, :1].repeat(1293, axis=1) ^ np.arange(1293, dtype=np.uint8) * 37
    for cap in (24, 5, 1):
        assert len(texture_grid(strip, 8, 10, 1.0, cap)) == cap


def test_flow_extractor_reuses_image_2_only_while_its_pixels_are_the_same(mild_pair):
    """Image 2's shrunk and smoothed images serve as image 1's in the next call: the ACs equal a
    fresh extractor's, also when the caller refills one buffer with a new frame in place."""
    from planar_vo.config import FrontendConfig
    from planar_vo.frontend.flow import FlowExtractor

    g1, g2 = mild_pair
    g3 = _homography_pair(MILD @ MILD, seed=1)[1]
    config = FrontendConfig(flow_max_width=320)              # a shrunk flow: both caches used

    def same(a, b):
        fields = ('p1', 'p2', 'A', 'weights')
        return all(np.array_equal(getattr(a, f), getattr(b, f)) for f in fields)

    tracker = FlowExtractor(config)
    tracker.extract(g1, g2)
    assert same(tracker.extract(g2, g3), FlowExtractor(config).extract(g2, g3))
    buffer = g2.copy()
    tracker.extract(g1, buffer)
    buffer[:] = g3                                           # the next frame, same array
    assert same(tracker.extract(buffer, g1), FlowExtractor(config).extract(g3, g1))


def test_neighbour_predictions_extrapolate_the_neighbours_affine(mild_pair):
    g1, _ = mild_pair
    grid = texture_grid(g1, 16, 12, 1.0, 10000)
    p1 = grid.points.astype(np.float64)
    p2 = apply_homography(MILD, p1)
    A = homography_jacobian(MILD, p1)
    accepted = np.arange(len(p1)) % 2 == 0
    index, q, J = neighbour_predictions(grid, accepted, ~accepted, p2, A)
    assert len(index) > 0.9 * np.count_nonzero(~accepted)
    assert not accepted[index].any()
    # One cell (16 px) of first-order extrapolation of a mild homography: sub-pixel.
    assert np.median(np.linalg.norm(q - p2[index], axis=1)) < 0.1
    assert np.median(np.linalg.norm(J - A[index], axis=(1, 2))) < 0.01


# --------------------------------------------------------------------------------------------
# Undistortion and levelling
# --------------------------------------------------------------------------------------------

CAMERAS = {
    'plumb_bob': CameraModel(W, H, K, 'plumb_bob', (-0.25, 0.06, 1e-3, -5e-4, -0.01)),
    'equidistant': CameraModel(W, H, K, 'equidistant', (0.05, -0.01, 0.002, -0.0005)),
}


def _distort_pixels(camera: CameraModel, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ideal pixels -> distorted pixels and the Jacobian."""
    q = normalize_points(camera.K, p)
    pd, J = camera.normalized_to_pixel(q)
    return pd, J @ np.linalg.inv(camera.K[:2, :2])


@pytest.mark.parametrize('name', list(CAMERAS))
def test_undistort_acs_inverts_the_distortion_exactly(rng, name):
    camera = CAMERAS[name]
    p1 = rng.uniform((20, 20), (W - 20, H - 20), (200, 2))
    p2 = apply_homography(MILD, p1)
    A = homography_jacobian(MILD, p1)
    d1, J1 = _distort_pixels(camera, p1)
    d2, J2 = _distort_pixels(camera, p2)
    distorted = AffineCorrespondences(d1, d2, J2 @ A @ np.linalg.inv(J1))
    ideal = undistort_acs(distorted, camera)
    np.testing.assert_allclose(ideal.p1, p1, atol=1e-8)
    np.testing.assert_allclose(ideal.p2, p2, atol=1e-8)
    np.testing.assert_allclose(ideal.A, A, atol=1e-8)


@pytest.mark.parametrize('name', list(CAMERAS))
def test_acs_from_distorted_images_undistort_to_the_ideal_homography(name):
    camera = CAMERAS[name]
    tex = _texture(4)
    # Each distorted pixel shows what the ideal camera sees at its undistorted position.
    pd = _grid().reshape(-1, 2)
    q, _ = camera.pixel_to_normalized(pd)
    ideal = (q @ K[:2, :2].T + K[:2, 2]).reshape(H, W, 2)
    src = apply_homography(np.linalg.inv(MILD), ideal.reshape(-1, 2)).reshape(H, W, 2)
    acs = undistort_acs(extract_acs(_sample(tex, ideal), _sample(tex, src)), camera)
    point, affine = _errors(acs, MILD)
    assert len(acs) > 300
    assert np.median(point) < 0.05 and np.median(affine) < 0.015


def test_undistort_acs_passes_an_ideal_camera_through():
    acs = AffineCorrespondences(np.ones((3, 2)), np.ones((3, 2)), np.tile(np.eye(2), (3, 1, 1)))
    assert undistort_acs(acs, CameraModel(W, H, K)) is acs


def test_leveling_rotation_is_the_mount_rotation():
    pitch, roll, yaw = 0.05, -0.03, 0.2
    T_tilted = mount_transform(pitch=pitch, roll=roll, yaw=yaw)
    T_level = mount_transform(yaw=yaw)
    # X_level = R_lc X_cam, whatever the yaw.
    np.testing.assert_allclose(leveling_rotation(pitch, roll),
                               T_level[:3, :3].T @ T_tilted[:3, :3], atol=1e-12)
    # Positive pitch looks down: the level camera sees the optical axis below its centre.
    p = apply_homography(leveling_homography(K, 0.05, 0.0), K[:2, 2][None])[0]
    assert p[1] > K[1, 2] + 10


def _plane_acs(T_c1, T_c2, normal_odom, offset_odom, p1):
    """Exact ACs of the plane ``normal . X = offset`` (odom) between two camera poses."""
    M = invert(T_c2) @ T_c1                     # X2 = R X1 + t
    n1 = T_c1[:3, :3].T @ normal_odom
    d1 = offset_odom - normal_odom @ T_c1[:3, 3]
    Hmat = plane_homography(K, K, M[:3, :3], M[:3, 3], n1, d1)
    return AffineCorrespondences(p1, apply_homography(Hmat, p1), homography_jacobian(Hmat, p1))


@pytest.fixture(scope='module')
def tilted_drive():
    """A turning drive seen by a camera mounted 2 deg pitched down and rolled -1.5 deg."""
    rng = np.random.default_rng(11)
    yaw = np.cumsum(rng.normal(0.0, np.deg2rad(2.0), 201))
    xy = np.cumsum(np.stack([np.cos(yaw), np.sin(yaw)], -1), axis=0)
    base = planar_pose(xy[:, 0], xy[:, 1], yaw)
    pitch, roll = np.deg2rad(2.0), np.deg2rad(-1.5)
    return base, pitch, roll


def test_level_acs_give_the_acs_of_the_level_camera(rng, tilted_drive):
    base, pitch, roll = tilted_drive
    tilted = base @ mount_transform(height=1.5, pitch=pitch, roll=roll, yaw=0.02)
    level = base @ mount_transform(height=1.5, yaw=0.02)
    p1 = rng.uniform((10, 150), (W - 10, H - 10), (100, 2))
    ground = (np.array([0.0, 0.0, 1.0]), 0.0)
    acs = _plane_acs(tilted[0], tilted[1], *ground, p1)
    leveled = level_acs(acs, K, pitch, roll)
    expected = _plane_acs(level[0], level[1], *ground, leveled.p1)
    np.testing.assert_allclose(leveled.p2, expected.p2, atol=1e-8)
    np.testing.assert_allclose(leveled.A, expected.A, atol=1e-10)
    # correct_acs of an undistorted camera is levelling alone.
    again = correct_acs(acs, CameraModel(W, H, K), pitch, roll)
    np.testing.assert_allclose(again.A, leveled.A)


def _noisy_motion(rng, T_c1, T_c2, rot_sigma, dir_sigma):
    M = invert(T_c2) @ T_c1
    w = rng.normal(0.0, rot_sigma, 3)
    R = cv2.Rodrigues(w)[0] @ M[:3, :3]
    t = M[:3, 3] + np.linalg.norm(M[:3, 3]) * rng.normal(0.0, dir_sigma, 3)
    return R, t


def test_tilt_estimator_recovers_the_mount_exactly(tilted_drive):
    base, pitch, roll = tilted_drive
    cams = base @ mount_transform(height=1.5, pitch=pitch, roll=roll, yaw=0.05)
    est = MountTiltEstimator(prior_sigma=None)
    for k in range(len(cams) - 1):
        M = invert(cams[k + 1]) @ cams[k]
        est.add_motion(M[:3, :3], M[:3, 3])
    tilt = est.estimate()
    assert tilt.frames == len(cams) - 1
    assert abs(tilt.pitch - pitch) < 1e-9 and abs(tilt.roll - roll) < 1e-9
    np.testing.assert_allclose(tilt.normal, leveling_rotation(pitch, roll).T @ [0, 1, 0],
                               atol=1e-9)


def test_tilt_estimator_with_noisy_poses_and_outliers(tilted_drive):
    base, pitch, roll = tilted_drive
    cams = base @ mount_transform(height=1.5, pitch=pitch, roll=roll)
    rng = np.random.default_rng(3)
    est = MountTiltEstimator()
    for k in range(len(cams) - 1):
        R, t = _noisy_motion(rng, cams[k], cams[k + 1], np.deg2rad(0.05), np.deg2rad(1.0))
        if k % 10 == 3:                        # a bad pose now and then: a bump or a failure
            R, t = _noisy_motion(rng, cams[k], cams[k + 1], np.deg2rad(3.0), np.deg2rad(20.0))
        est.add_motion(R, t)
    tilt = est.estimate()
    err_pitch, err_roll = abs(tilt.pitch - pitch), abs(tilt.roll - roll)
    assert err_pitch < np.deg2rad(0.2) and err_roll < np.deg2rad(0.2)
    # The reported uncertainty is honest: errors within 3 sigma, sigma not absurdly large.
    assert err_pitch < 3 * tilt.pitch_std + 1e-4 and err_roll < 3 * tilt.roll_std + 1e-4
    assert tilt.pitch_std < np.deg2rad(0.3) and tilt.roll_std < np.deg2rad(0.3)


def test_tilt_estimator_reports_an_unobservable_roll_when_driving_straight():
    cams = planar_pose(np.arange(11.0), 0.0, 0.0) @ mount_transform(pitch=0.03, roll=0.02)
    est = MountTiltEstimator(prior_sigma=None)
    est_prior = MountTiltEstimator()
    for k in range(10):
        M = invert(cams[k + 1]) @ cams[k]
        est.add_motion(M[:3, :3], M[:3, 3])
        est_prior.add_motion(M[:3, :3], M[:3, 3])
    tilt = est.estimate()
    # Only n . forward = 0 is known: n may turn about the forward axis, which to first order
    # is a roll.
    assert tilt.roll_std == np.inf
    assert abs(tilt.normal @ (-cams[0][:3, :3].T @ (cams[1][:3, 3] - cams[0][:3, 3]))) < 1e-9
    # With the default level prior the roll stays near 0, with about the prior's uncertainty.
    tilt = est_prior.estimate()
    assert abs(tilt.pitch - 0.03) < 1e-3 and abs(tilt.roll) < 1e-3
    assert np.deg2rad(1.0) < tilt.roll_std < np.deg2rad(10.0)
    # Levelling uses only the angles that are known: here the pitch.
    pitch, roll = tilt.levelling_angles(np.deg2rad(0.5))
    assert pitch == tilt.pitch and roll == 0.0


def test_tilt_estimator_input_errors():
    est = MountTiltEstimator()
    with pytest.raises(InputError, match=r'expected at least 2 frame pairs, got 0'):
        est.estimate()
    with pytest.raises(InputError, match=r'R: expected a rotation matrix'):
        est.add_motion(2 * np.eye(3), np.zeros(3))
    with pytest.raises(InputError, match=r't: expected shape \(3,\), got \(2,\)'):
        est.add_motion(np.eye(3), np.zeros(2))
    with pytest.raises(InputError, match=r'prior_sigma: expected a positive angle or None'):
        MountTiltEstimator(prior_sigma=0.0)


def test_leveling_with_the_estimated_tilt_makes_1ac_exact_again(rng, tilted_drive):
    base, pitch, roll = tilted_drive
    cams = base @ mount_transform(height=1.5, pitch=pitch, roll=roll)
    level = base @ mount_transform(height=1.5)
    est = MountTiltEstimator()
    for k in range(len(cams) - 1):
        est.add_motion(*_noisy_motion(rng, cams[k], cams[k + 1], np.deg2rad(0.05),
                                      np.deg2rad(1.0)))
    tilt = est.estimate()

    def errors(c, M):
        alpha, beta = solve_1ac(normalize_points(K, c.p1), normalize_points(K, c.p2),
                                normalize_affines(K, K, c.A))
        true_alpha, true_beta = planar_motion_from_pose(M[:3, :3], M[:3, 3])
        return np.abs(alpha - true_alpha), np.abs(np.angle(np.exp(1j * (beta - true_beta))))

    raw, leveled = [], []
    for k in range(10):
        p1 = rng.uniform((10, 150), (W - 10, H - 10), (100, 2))
        acs = _plane_acs(cams[k], cams[k + 1], np.array([0.0, 0.0, 1.0]), 0.0, p1)
        M = invert(level[k + 1]) @ level[k]           # the motion of the level camera
        raw.append(errors(acs, M))
        leveled.append(errors(level_acs(acs, K, tilt.pitch, tilt.roll), M))
    raw_alpha, raw_beta = np.concatenate(raw, axis=1)
    lev_alpha, lev_beta = np.concatenate(leveled, axis=1)
    # 2 deg of pitch and 1.5 deg of roll break the planar model for single ACs ...
    assert np.percentile(raw_alpha, 90) > np.deg2rad(0.1)
    assert np.percentile(raw_beta, 90) > np.deg2rad(1.0)
    # ... and levelling by the estimated tilt restores it to a fraction of that.
    assert np.percentile(lev_alpha, 90) < 0.2 * np.percentile(raw_alpha, 90)
    assert np.percentile(lev_beta, 90) < 0.2 * np.percentile(raw_beta, 90)


# --------------------------------------------------------------------------------------------
# The rendered street world (planar_vo.sim): exact ACs of every visible plane
# --------------------------------------------------------------------------------------------

RENDER_CAMERA = CameraModel.pinhole(640, 480, 500.0)


def _street(traj, mount, camera=RENDER_CAMERA, seed=5):
    world = StreetWorld.along(traj, seed=seed)
    poses = traj.camera_poses(mount)
    return world, poses, [render(world, camera, T).image for T in poses]


@pytest.fixture(scope='module')
def street():
    """About 1 m forward and 1.5 deg of yaw per frame, level camera 1.5 m above the ground."""
    traj = turn(np.deg2rad(1.5 * 6), radius=38.0, speed=10.0)
    world, poses, images = _street(traj, mount_transform(height=1.5))
    frames = [render(world, RENDER_CAMERA, T) for T in poses]
    return world, poses, images, [f.kind for f in frames]


def test_flow_acs_on_the_rendered_street_match_the_exact_acs(street):
    world, poses, images, kinds = street
    extractor = ACExtractor()
    points, affines, near_ground = [], [], []
    for k in range(len(images) - 1):
        acs = extractor.extract(images[k], images[k + 1])
        # Over half the per-frame budget, spread over the image: most of a 4 x 3 grid of image
        # regions hold at least a third of their even share (the sky and the ground leaving
        # the view hold fewer).
        budget = extractor.config.max_correspondences
        assert 0.5 * budget <= len(acs) <= budget
        cells, _, _ = np.histogram2d(acs.p1[:, 0], acs.p1[:, 1], bins=(4, 3),
                                     range=((0, 640), (0, 480)))
        assert np.count_nonzero(cells >= len(acs) / 36) >= 9
        exact, valid = exact_acs(world, poses[k], poses[k + 1], RENDER_CAMERA, acs.p1)
        assert valid.mean() > 0.95            # hardly any AC on an occluded or exiting point
        acs, exact = acs.subset(valid), exact.subset(valid)
        points.append(np.linalg.norm(acs.p2 - exact.p2, axis=1))
        affines.append(np.linalg.norm(acs.A - exact.A, axis=(1, 2)))
        pix = np.rint(acs.p1).astype(int)
        near_ground.append((kinds[k][pix[:, 1], pix[:, 0]] == GROUND_KIND) & (pix[:, 1] > 360))
    points, affines, near_ground = map(np.concatenate, (points, affines, near_ground))
    # All planes, the ground close to the car included.
    assert np.median(points) < 0.15
    assert np.median(affines) < 0.03
    # The ground within ~4 m is covered; its rendering is less consistent between frames
    # (texture level of detail, lens blur under strong foreshortening), so the bound is looser.
    # (At least 2 % of the ACs: about the share of the image it covers at an even spread.)
    assert near_ground.sum() >= 0.02 * len(points)
    assert np.median(affines[near_ground]) < 0.06


def test_acs_give_the_rendered_motion_by_voting(street):
    world, poses, images, _ = street
    K = RENDER_CAMERA.K
    extractor = ACExtractor()
    for k in range(len(images) - 1):
        acs = extractor.extract(images[k], images[k + 1])
        motion, stats = vote_planar_motion(normalize_points(K, acs.p1),
                                           normalize_points(K, acs.p2),
                                           normalize_affines(K, K, acs.A), acs.weights)
        alpha, beta, _ = relative_planar_motion(poses[k], poses[k + 1])
        # Inliers pass a 99 % chi-square test at noise scales estimated from the inliers' median;
        # front-end errors have heavier tails than a Gaussian, so about 70 % pass.
        assert stats.reliable and stats.num_inliers > 0.6 * len(acs)
        assert abs(angle_difference(motion.alpha, alpha)) < np.deg2rad(0.05)
        assert abs(angle_difference(motion.beta, beta)) < np.deg2rad(1.0)


def test_distorted_pitched_camera_corrects_to_the_ideal_level_camera():
    camera = CameraModel(640, 480, RENDER_CAMERA.K, 'plumb_bob', (-0.25, 0.06, 1e-3, -5e-4, 0.0))
    ideal = RENDER_CAMERA
    pitch, roll = np.deg2rad(2.0), np.deg2rad(-1.0)
    traj = turn(np.deg2rad(1.5 * 3), radius=38.0, speed=10.0)
    world, poses, images = _street(traj, mount_transform(height=1.5, pitch=pitch, roll=roll),
                                   camera)
    level = traj.camera_poses(mount_transform(height=1.5))
    K = ideal.K
    extractor = ACExtractor()
    for k in range(len(images) - 1):
        acs = correct_acs(extractor.extract(images[k], images[k + 1]), camera, pitch, roll)
        exact, valid = exact_acs(world, level[k], level[k + 1], ideal, acs.p1)
        # Distortion widens the view: some corrected points fall outside the ideal image.
        assert valid.mean() > 0.85 and valid.sum() >= 0.4 * extractor.config.max_correspondences
        good, truth = acs.subset(valid), exact.subset(valid)
        assert np.median(np.linalg.norm(good.p2 - truth.p2, axis=1)) < 0.15
        assert np.median(np.linalg.norm(good.A - truth.A, axis=(1, 2))) < 0.03
        motion, _ = vote_planar_motion(normalize_points(K, acs.p1), normalize_points(K, acs.p2),
                                       normalize_affines(K, K, acs.A), acs.weights)
        alpha, _, _ = relative_planar_motion(level[k], level[k + 1])
        assert abs(angle_difference(motion.alpha, alpha)) < np.deg2rad(0.05)


def test_mount_tilt_from_a_rendered_drive_makes_voting_work_on_a_tilted_camera():
    pitch, roll = np.deg2rad(2.0), np.deg2rad(-1.5)
    traj = concatenate(turn(np.deg2rad(25.0), radius=38.0, speed=10.0),
                       turn(np.deg2rad(-25.0), radius=38.0, speed=10.0))
    _, _, images = _street(traj, mount_transform(height=1.5, pitch=pitch, roll=roll))
    level = traj.camera_poses(mount_transform(height=1.5))
    K = RENDER_CAMERA.K
    extractor = ACExtractor()
    estimator = MountTiltEstimator()
    # General motions without the planar prior (which would hold them to the unknown plane).
    motions = MotionEstimator(EstimatorConfig(use_prior=False))
    pairs = []
    for k in range(len(images) - 1):
        acs = extractor.extract(images[k], images[k + 1])
        norm = acs.normalized(RENDER_CAMERA)
        est = motions.estimate(norm, norm)
        assert est.reliable
        estimator.add_motion(est.R, est.t)
        pairs.append(acs)
    tilt = estimator.estimate()
    assert tilt.frames == len(pairs)
    assert abs(tilt.pitch - pitch) < np.deg2rad(0.2) and abs(tilt.roll - roll) < np.deg2rad(0.2)
    assert abs(tilt.pitch - pitch) < 3 * tilt.pitch_std
    assert abs(tilt.roll - roll) < 3 * tilt.roll_std

    def yaw_errors(pitch_used, roll_used):
        errors = []
        for k, acs in enumerate(pairs):
            c = level_acs(acs, K, pitch_used, roll_used)
            motion, _ = vote_planar_motion(normalize_points(K, c.p1), normalize_points(K, c.p2),
                                           normalize_affines(K, K, c.A), c.weights)
            alpha, _, _ = relative_planar_motion(level[k], level[k + 1])
            errors.append(abs(angle_difference(motion.alpha, alpha)))
        return np.array(errors)

    raw = yaw_errors(0.0, 0.0)
    leveled = yaw_errors(tilt.pitch, tilt.roll)
    assert np.max(leveled) < np.deg2rad(0.05)
    assert np.mean(raw) > 5 * np.mean(leveled)


@pytest.mark.parametrize('darker', [1, 2])
def test_flow_acs_survive_an_exposure_change(mild_pair, darker):
    """One image 30 % darker and offset (auto-exposure, a shadow): the refinement compares
    patches up to gain and offset, so the ACs are as many and as accurate as without the change
    (KITTI 05 with the frames' brightness scaled by U(0.75, 1.25): 9 % of frames were lost)."""
    g1, g2 = mild_pair
    images = [g1, g2]
    images[darker - 1] = (images[darker - 1].astype(np.float64) * 0.7 + 8.0).astype(np.uint8)
    same, acs = extract_acs(g1, g2), extract_acs(*images)
    point, affine = _errors(acs, MILD)
    assert len(acs) >= 0.9 * len(same)
    assert np.median(point) < 0.05 and np.percentile(point, 95) < 0.15
    assert np.median(affine) < 0.015 and np.percentile(affine, 95) < 0.04


def test_extract_more_adds_the_selected_cells_from_the_same_flows(ground_pair):
    """A budget-capped pair asked for more ACs in a region: its candidates on the grid without
    the budget's larger cells, tracked on the same flows exactly as an extraction without the
    budget tracks them; nothing before the first pair; a bad mask is refused."""
    from planar_vo.frontend.flow import FlowExtractor

    g1, g2 = ground_pair
    capped = FrontendConfig(max_correspondences=60, reseed=False)
    tracker = FlowExtractor(capped)
    assert tracker.extract_more(lambda p: np.ones(len(p), bool)) is None
    main = tracker.extract(g1, g2)

    def lower(p):
        return p[:, 1] > 0.6 * H

    more = tracker.extract_more(lower)
    assert np.all(lower(more.p1)) and len(more) <= 60
    assert len(more) > 2 * np.count_nonzero(lower(main.p1))
    free = FlowExtractor(FrontendConfig(max_correspondences=30000, reseed=False)).extract(g1, g2)
    index = {tuple(p): i for i, p in enumerate(free.p1)}
    same = np.array([index[tuple(p)] for p in more.p1])
    # The same up to the order of floating-point sums over the batch of patches.
    np.testing.assert_allclose(more.p2, free.p2[same], rtol=0, atol=1e-6)
    np.testing.assert_allclose(more.A, free.A[same], rtol=0, atol=1e-8)
    with pytest.raises(InputError, match='select'):
        tracker.extract_more(lambda p: np.ones(3, bool))
    asift = ACExtractor(FrontendConfig(method='asift'))
    assert asift.extract_more(lower) is None
    flow = ACExtractor(capped)
    flow.extract(g1, g2)
    assert len(flow.extract_more(lower)) == len(more)


def test_klt_extract_more_finds_corners_on_a_faint_road():
    """KLT corners are ranked against the frame's strongest: a faint road (a tenth of the
    contrast, below 60 % of the height) gets none of a small budget. Asked for more ACs there,
    the KLT front-end detects corners in the region alone, tracks and refines them: all in the
    region, many, and as accurate as the exact ground homography allows; nothing before the
    first pair; a bad mask is refused."""
    from planar_vo.frontend.klt import KLTExtractor

    Hg = _ground_homography()
    tex = _texture(2)
    faint_from = int((0.6 * H + PAD) * SUPERSAMPLE)          # texture rows of image rows > 0.6 H
    tex[faint_from:] = 128.0 + 0.1 * (tex[faint_from:] - 128.0)
    p = _grid()
    p_src = apply_homography(np.linalg.inv(Hg), p.reshape(-1, 2)).reshape(H, W, 2)
    g1, g2 = _sample(tex, p), _sample(tex, np.nan_to_num(p_src, nan=-1e4))

    def road(q):
        return q[:, 1] > 0.65 * H

    klt = KLTExtractor(FrontendConfig(method='klt', max_correspondences=60))
    assert klt.extract_more(road) is None
    main = klt.extract(g1, g2)
    assert np.count_nonzero(road(main.p1)) <= 2
    more = klt.extract_more(road)
    assert np.all(road(more.p1)) and 20 <= len(more) <= 60
    point, affine = _errors(more, Hg)
    assert np.median(point) < 0.1 and np.median(affine) < 0.03
    with pytest.raises(InputError, match='select'):
        klt.extract_more(lambda q: np.ones(3, bool))
    through = ACExtractor(FrontendConfig(method='klt', max_correspondences=60))
    through.extract(g1, g2)
    np.testing.assert_array_equal(through.extract_more(road).p1, more.p1)


def test_structure_texture_is_the_smaller_eigenvalue_in_full_resolution_units(mild_pair):
    from planar_vo.frontend.flow import structure_texture

    small = cv2.pyrDown(mild_pair[0]).astype(np.float64)
    # Derivatives per full-resolution pixel: Sobel is 8x the derivative, a pixel here is two.
    gx = cv2.Sobel(small, cv2.CV_64F, 1, 0, ksize=3) / 16.0
    gy = cv2.Sobel(small, cv2.CV_64F, 0, 1, ksize=3) / 16.0
    a, b, c = (cv2.blur(x, (3, 3)) for x in (gx * gx, gx * gy, gy * gy))
    expected = 0.5 * (a + c) - np.sqrt(0.25 * (a - c) ** 2 + b * b)
    got = structure_texture(mild_pair[0])
    assert got.shape == small.shape and expected.max() > 10.0
    np.testing.assert_allclose(got, expected, rtol=1e-4, atol=1e-3 * expected.max())


def test_extract_more_refuses_masks_and_texture_maps_that_do_not_fit(mild_pair):
    """A score or index array is not a mask; a texture map of another image is refused; a
    failed extraction leaves no pair to add to."""
    from planar_vo.frontend.flow import FlowExtractor, structure_texture

    g1, g2 = mild_pair
    tracker = FlowExtractor(FrontendConfig(max_correspondences=60))
    tracker.extract(g1, g2)
    with pytest.raises(InputError, match='bool mask'):
        tracker.extract_more(lambda p: p[:, 1].astype(np.float64))
    with pytest.raises(InputError, match='bool mask'):
        tracker.extract_more(lambda p: np.arange(len(p)))
    for bad in (structure_texture(cv2.resize(g1, (2 * W, 2 * H))), structure_texture(g1).T,
                g1[::2, ::2]):
        with pytest.raises(InputError, match='texture'):
            texture_grid(g1, 12, 10, 1.0, 100, bad)
    assert len(texture_grid(g1, 12, 10, 1.0, 100, structure_texture(g1)).points) == \
        len(texture_grid(g1, 12, 10, 1.0, 100).points)
    extractor = ACExtractor(FrontendConfig(max_correspondences=60))
    extractor.extract(g1, g2)
    assert extractor.extract_more(lambda p: np.ones(len(p), bool)) is not None
    with pytest.raises(ImageError):
        extractor.extract(g1, g2[:-5])
    assert extractor.extract_more(lambda p: np.ones(len(p), bool)) is None
