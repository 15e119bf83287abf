"""Rendered street world: determinism, texture, exact ground-truth ACs, trajectories, mounts."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from planar_vo.config import MountConfig
from planar_vo.core import ac_residuals, camera_displacement, solve_1ac, wrap_angle
from planar_vo.core.camera import CameraModel
from planar_vo.core.conventions import invert, mount_transform, yaw_of
from planar_vo.core.trajectory import Trajectory
from planar_vo.errors import InputError
from planar_vo.sim import (
    FACADE_KIND,
    GROUND_KIND,
    OBSTACLE_KIND,
    StreetWorld,
    backproject,
    concatenate,
    exact_acs,
    relative_planar_motion,
    render,
    reverse,
    s_curve,
    stop_and_go,
    straight,
    turn,
)

K = np.array([[500.0, 0.0, 320.0], [0.0, 510.0, 240.0], [0.0, 0.0, 1.0]])
CAMERAS = {
    'pinhole': CameraModel(640, 480, K),
    'plumb_bob': CameraModel(640, 480, K, 'plumb_bob', (-0.28, 0.07, 1e-3, -5e-4, -0.01)),
    'equidistant': CameraModel(640, 480, K, 'equidistant', (0.05, -0.01, 0.002, -0.0005)),
}
KITTI = CameraModel.pinhole(1241, 376, 718.856, cx=607.19, cy=185.22)
MOUNT = mount_transform(height=1.5)


@pytest.fixture(scope='module')
def drive() -> Trajectory:
    """Straight, a left turn and straight again: forward motion with and without rotation."""
    return concatenate(straight(20.0, speed=8.0), turn(np.pi / 2, radius=25.0), straight(30.0))


@pytest.fixture(scope='module')
def world(drive) -> StreetWorld:
    return StreetWorld.along(drive, seed=11)


@pytest.fixture(scope='module')
def poses(drive) -> np.ndarray:
    return drive.camera_poses(MOUNT)


def _grid(camera: CameraModel, step: int = 8, border: int = 2) -> np.ndarray:
    xs = np.arange(border, camera.width - border, step)
    ys = np.arange(border, camera.height - border, step)
    return np.stack(np.meshgrid(xs, ys), -1).reshape(-1, 2).astype(np.float64)


def _in_turn(drive: Trajectory) -> int:
    """A frame in the middle of the turn."""
    return int(np.argmin(np.abs(drive.yaw - np.pi / 4)))


# -- determinism and appearance --------------------------------------------------------------

def test_same_seed_same_images_other_seed_differs(drive, poses):
    cam = CAMERAS['pinhole']
    a = render(StreetWorld.along(drive, seed=5), cam, poses[3])
    b = render(StreetWorld.along(drive, seed=5), cam, poses[3])
    c = render(StreetWorld.along(drive, seed=6), cam, poses[3])
    np.testing.assert_array_equal(a.image, b.image)
    np.testing.assert_array_equal(a.plane, b.plane)
    assert np.mean(a.image != c.image) > 0.5


def _local_energy(image: np.ndarray, size: int = 15) -> np.ndarray:
    img = image.astype(np.float32)
    gx = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    return cv2.blur(gx * gx + gy * gy, (size, size))


@pytest.mark.parametrize('camera', [CAMERAS['pinhole'], KITTI], ids=['vga', 'kitti'])
def test_surfaces_are_textured_and_sky_is_plain(world, poses, camera):
    frame = render(world, camera, poses[2])
    assert frame.image.shape == (camera.height, camera.width) and frame.image.dtype == np.uint8
    energy = _local_energy(frame.image)
    # Windows (plus Sobel and PSF reach) entirely on one surface (or entirely sky).
    plane = frame.plane.astype(np.float32)
    uniform = cv2.dilate(plane, np.ones((21, 21))) == cv2.erode(plane, np.ones((21, 21)))
    for kind in (GROUND_KIND, FACADE_KIND, OBSTACLE_KIND):
        sel = uniform & (frame.kind == kind) & (frame.depth < 50.0)
        assert sel.sum() > 2000, kind
        # Every window has texture: mean squared gradient of several grey levels per pixel.
        assert np.percentile(energy[sel], 1) > 5.0, kind
    sky = uniform & (frame.kind == -1)
    assert sky.sum() > 2000
    assert np.percentile(energy[sky], 99) < 0.5
    assert np.all(np.isinf(frame.depth[frame.kind == -1]))


def test_rendering_is_anti_aliased_at_every_distance(world, poses):
    # The image must equal a 2x supersampled render averaged down (a band-limited reference),
    # near and far: an aliased far ground or facade would differ by about the texture's
    # standard deviation there.
    low = CameraModel.pinhole(640, 480, 500.0, cx=319.5, cy=239.5)
    high = CameraModel.pinhole(1280, 960, 1000.0, cx=639.5, cy=479.5)   # same pixel centres
    frame = render(world, low, poses[0], psf_sigma=0.0)
    reference = cv2.resize(render(world, high, poses[0], psf_sigma=0.0).image.astype(np.float32),
                           (640, 480), interpolation=cv2.INTER_AREA)
    diff = np.abs(reference - frame.image)
    plane = frame.plane.astype(np.float32)
    interior = cv2.dilate(plane, np.ones((5, 5))) == cv2.erode(plane, np.ones((5, 5)))
    checked = 0
    for near, far in ((0, 10), (10, 20), (20, 40), (40, 80)):
        for kind in (GROUND_KIND, FACADE_KIND):
            sel = interior & (frame.kind == kind) & (frame.depth >= near) & (frame.depth < far)
            if sel.sum() < 500:
                continue
            checked += 1
            assert np.std(frame.image[sel]) > 10.0, (near, kind)
            assert np.median(diff[sel]) < 3.0, (near, kind)
    assert checked >= 5


def test_ground_texture_does_not_repeat_with_the_detail_tile(world, poses):
    # Shift the camera by one period of the ground's detail tile (a lattice vector of its
    # texel coordinates): that layer looks identical, but the coarse and macro layers, rotated
    # and incommensurate, must make the image differ. A small shift is the control.
    from planar_vo.sim.textures import TILE
    cam = CAMERAS['pinhole']
    M = world.texture_map[0, :, :2]                          # ground: (a, b) = odom (x, y) + c
    rows, cols = slice(300, 470), slice(100, 540)            # near ground ahead
    base = render(world, cam, poses[0], psf_sigma=0.0).image[rows, cols].astype(float)

    def shifted(dxy):
        T = poses[0].copy()
        T[:2, 3] += dxy
        return render(world, cam, T, psf_sigma=0.0).image[rows, cols].astype(float)

    period = np.linalg.solve(M, [TILE, 0.0])
    assert 8.0 < np.linalg.norm(period) < 13.0
    assert np.mean(np.abs(shifted(period) - base)) > 8.0
    assert np.mean(np.abs(shifted(period * 1e-5) - base)) < 1.0


# -- exact ground truth ----------------------------------------------------------------------

@pytest.mark.parametrize('name', list(CAMERAS))
def test_p2_is_the_projection_of_the_rendered_surface_point(world, drive, poses, name):
    cam = CAMERAS[name]
    i, j = _in_turn(drive), _in_turn(drive) + 2
    frame = render(world, cam, poses[i])
    px = _grid(cam, step=7)
    acs, valid = exact_acs(world, poses[i], poses[j], cam, px)
    assert valid.mean() > 0.4
    # Back-project with the RENDERED depth, move to camera 2 and project.
    depth = frame.depth[px[:, 1].astype(int), px[:, 0].astype(int)]
    q, _ = cam.pixel_to_normalized(px)
    X1 = np.column_stack([q, np.ones(len(q))])[valid] * depth[valid, None]
    T21 = invert(poses[j]) @ poses[i]
    X2 = X1 @ T21[:3, :3].T + T21[:3, 3]
    p2, _ = cam.normalized_to_pixel(X2[:, :2] / X2[:, 2:])
    np.testing.assert_allclose(acs.p2[valid], p2, atol=1e-6)
    # The rendered plane ids are the exact ray casts.
    _, plane = backproject(world, cam, poses[i], px)
    np.testing.assert_array_equal(frame.plane[px[:, 1].astype(int), px[:, 0].astype(int)], plane)
    np.testing.assert_array_equal(valid & (plane < 0), False)


@pytest.mark.parametrize('name', list(CAMERAS))
def test_exact_acs_recover_the_true_planar_motion_with_1ac(world, drive, poses, name):
    cam = CAMERAS[name]
    i = _in_turn(drive)
    for j in (i + 1, i + 3):
        px = _grid(cam, step=11)
        acs, valid = exact_acs(world, poses[i], poses[j], cam, px)
        n = acs.subset(valid).normalized(cam)
        alpha, beta, scale = relative_planar_motion(poses[i], poses[j])
        assert alpha > 0.01 and scale > 0.5                       # a left turn, moving
        # All exact ACs satisfy the three planar AC constraints of the true motion...
        np.testing.assert_allclose(ac_residuals(n.p1, n.p2, n.A, alpha, beta), 0.0, atol=1e-9)
        # ...and each ground AC alone determines it (facade ACs are degenerate for 1AC under
        # planar motion: a vertical plane gives B rank 2).
        _, plane = backproject(world, cam, poses[i], acs.p1[valid])
        ground = world.kind[plane] == GROUND_KIND
        assert ground.sum() > 100
        a, b = solve_1ac(n.p1[ground], n.p2[ground], n.A[ground])
        np.testing.assert_allclose(a, alpha, atol=1e-9)
        np.testing.assert_allclose(wrap_angle(b - beta), 0.0, atol=1e-9)


def test_affine_is_the_derivative_of_the_p2_map(world, drive, poses):
    cam = CAMERAS['plumb_bob']
    i = _in_turn(drive)
    px = _grid(cam, step=13, border=5) + 0.37
    acs, valid = exact_acs(world, poses[i], poses[i + 2], cam, px)
    h = 1e-4
    cols = []
    for e in np.eye(2):
        plus, vp = exact_acs(world, poses[i], poses[i + 2], cam, px + h * e)
        minus, vm = exact_acs(world, poses[i], poses[i + 2], cam, px - h * e)
        cols.append((plus.p2 - minus.p2) / (2 * h))
        valid &= vp & vm
    numeric = np.stack(cols, -1)
    assert valid.sum() > 500
    np.testing.assert_allclose(acs.A[valid], numeric[valid], atol=1e-6)


def test_exact_affine_warp_matches_the_second_image(world, drive, poses):
    cam = CAMERAS['pinhole']
    i = _in_turn(drive)
    j = i + 4                                         # 3.2 m and 7 degrees apart
    frame1 = render(world, cam, poses[i])
    img1 = frame1.image.astype(np.float32)
    img2 = render(world, cam, poses[j]).image.astype(np.float32)
    acs, valid = exact_acs(world, poses[i], poses[j], cam, _grid(cam, step=9, border=12))
    r = np.arange(-5, 6, dtype=np.float32)
    off = np.stack(np.meshgrid(r, r), -1).reshape(-1, 2)
    keep = []
    for k in np.flatnonzero(valid):
        x1 = (acs.p1[k] + off).astype(int)
        if np.ptp(frame1.plane[x1[:, 1], x1[:, 0]]) == 0:          # patch on one surface
            keep.append(k)
    keep = np.array(keep)
    p1, p2, A = acs.p1[keep], acs.p2[keep], acs.A[keep]
    x2a = p2[:, None] + off @ A.transpose(0, 2, 1)                # (N, 121, 2)
    x2i = p2[:, None] + off[None]
    inside = np.all((x2a >= 0) & (x2a <= [639, 479]) & (x2i >= 0) & (x2i <= [639, 479]),
                    axis=(1, 2))
    p1, x2a, x2i = p1[inside], x2a[inside], x2i[inside]
    assert len(p1) > 500
    x1 = (p1[:, None] + off[None]).astype(int)
    patch1 = img1[x1[..., 1], x1[..., 0]]

    def sample(x):
        x = x.astype(np.float32)
        return cv2.remap(img2, x[..., 0], x[..., 1], cv2.INTER_CUBIC)

    err_affine = np.abs(sample(x2a) - patch1).mean(axis=1)
    err_shift = np.abs(sample(x2i) - patch1).mean(axis=1)
    # The exact affine explains the second image to about a grey level (the rest: the surface
    # seen at another resolution, interpolation, rounding); a plain shift does far worse.
    assert np.median(err_affine) < 2.0
    assert np.median(err_affine) < 0.4 * np.median(err_shift)
    assert np.mean(err_affine < err_shift) > 0.95


def test_validity_sky_behind_and_occlusion(world, drive, poses):
    cam = CAMERAS['pinhole']
    i = _in_turn(drive)
    px = _grid(cam, step=6)
    frame1 = render(world, cam, poses[i])
    acs, valid = exact_acs(world, poses[i], poses[i], cam, px)
    # Same view: every surface pixel maps to itself with A = I; the sky is invalid.
    sky = frame1.plane[px[:, 1].astype(int), px[:, 0].astype(int)] < 0
    assert sky.any()
    np.testing.assert_array_equal(valid, ~sky)
    np.testing.assert_allclose(acs.p2[valid], px[valid], atol=1e-9)
    np.testing.assert_allclose(acs.A[valid], np.broadcast_to(np.eye(2), (valid.sum(), 2, 2)),
                               atol=1e-9)
    np.testing.assert_array_equal(acs.weights, valid.astype(float))
    # Camera 2 six metres ahead: the near ground is behind it (invalid); valid points are the
    # nearest surface along their ray in view 2, invalid ones projecting inside image 2 in front
    # of camera 2 are occluded there.
    T2 = poses[i].copy()
    T2[:3, 3] += T2[:3, :3] @ [0.0, 0.0, 6.0]
    acs, valid = exact_acs(world, poses[i], T2, cam, px)
    X, plane = backproject(world, cam, poses[i], px)
    Xc2 = (X - T2[:3, 3]) @ T2[:3, :3]
    behind = Xc2[:, 2] <= 0
    assert behind.sum() > 100 and not np.any(valid & behind)
    frame2 = render(world, cam, T2)
    p2 = np.round(acs.p2).astype(int)
    plane2 = frame2.plane.astype(np.float32)
    interior = cv2.dilate(plane2, np.ones((3, 3))) == cv2.erode(plane2, np.ones((3, 3)))
    ok = valid & interior[p2[:, 1], p2[:, 0]]                     # away from edges in view 2
    assert ok.sum() > 0.9 * valid.sum()
    np.testing.assert_array_equal(frame2.plane[p2[ok, 1], p2[ok, 0]], plane[ok])
    q2 = np.nan_to_num(Xc2[:, :2]) / np.where(behind | (plane < 0), 1.0, Xc2[:, 2])[:, None]
    p2_all, _ = cam.normalized_to_pixel(q2)
    inside = (~behind & (plane >= 0) & np.all((p2_all >= 0) & (p2_all <= [639, 479]), axis=1))
    occluded = inside & ~valid
    assert occluded.sum() > 20
    pi = np.round(p2_all).astype(int).clip(0)
    occluded &= interior[pi[:, 1].clip(max=479), pi[:, 0].clip(max=639)]
    assert occluded.sum() > 20
    assert np.all(frame2.depth[pi[occluded, 1], pi[occluded, 0]] < Xc2[occluded, 2])


def test_exact_acs_rejects_bad_input(world, poses):
    cam = CAMERAS['pinhole']
    with pytest.raises(InputError, match=r'pixels: expected shape \(N, 2\), got \(4,\)'):
        exact_acs(world, poses[0], poses[1], cam, np.zeros(4))
    with pytest.raises(InputError, match=r'T_odom_camera2: expected shape \(4, 4\)'):
        exact_acs(world, poses[0], np.eye(3), cam, np.zeros((1, 2)))
    with pytest.raises(InputError, match=r'camera: expected a CameraModel, got ndarray'):
        exact_acs(world, poses[0], poses[1], K, np.zeros((1, 2)))
    with pytest.raises(InputError, match=r'psf_sigma: expected a blur in \[0, 10\] pixels'):
        render(world, cam, poses[0], psf_sigma=-1.0)


def test_relative_planar_motion_conventions():
    # A left turn gives alpha > 0 equal to the yaw change; forward driving beta = -pi/2.
    radius, angle = 30.0, np.radians(30)
    traj = turn(angle, radius=radius, rate=10.0)
    cams = traj.camera_poses(MOUNT)
    alpha, beta, scale = relative_planar_motion(cams[0], cams[-1])
    assert alpha == pytest.approx(angle, abs=1e-12)
    # Camera 2's centre in camera 1 (x right, z forward): ahead and to the left on the arc.
    centre = np.array([-radius * (1 - np.cos(angle)), 0.0, radius * np.sin(angle)])
    np.testing.assert_allclose(camera_displacement(alpha, beta) * scale, centre, atol=1e-9)
    a, b, s = relative_planar_motion(cams[0], cams[0])
    assert a == 0 and s == 0 and np.isnan(b)
    fwd = straight(10.0).camera_poses(MOUNT)
    _, beta, scale = relative_planar_motion(fwd[0], fwd[-1])
    assert beta == pytest.approx(-np.pi / 2) and scale == pytest.approx(10.0)


# -- trajectories ----------------------------------------------------------------------------

@pytest.mark.parametrize('sign', [1.0, -1.0])
def test_turns_change_yaw_in_the_right_direction(sign):
    angle, radius = sign * np.pi / 2, 20.0
    traj = turn(angle, radius=radius, speed=8.0, rate=10.0)
    yaw = np.unwrap(traj.yaw)
    assert np.all(sign * np.diff(yaw) > 0)
    assert yaw[-1] == pytest.approx(angle, abs=1e-12)
    # On the circle of the given radius whose centre is on the left (right) of the start.
    centre = np.array([0.0, sign * radius])
    np.testing.assert_allclose(np.linalg.norm(traj.xy - centre, axis=1), radius, atol=1e-9)
    assert np.all(np.diff(traj.stamps) == pytest.approx(0.1))


def test_straight_reverse_and_s_curve():
    fwd = straight(30.0, speed=10.0, rate=10.0)
    assert len(fwd) == 31
    np.testing.assert_allclose(fwd.xy[-1], [30.0, 0.0], atol=1e-12)
    back = reverse(5.0, speed=2.0, rate=10.0)
    steps = np.einsum('nij,nj->ni', np.linalg.inv(back.poses[:-1]),
                      np.column_stack([np.diff(back.xy, axis=0), np.zeros((len(back) - 1, 2))])
                      )[:, :3]
    assert np.all(steps[:, 0] < 0) and np.allclose(steps[:, 1:], 0.0)   # along -x of base_link
    np.testing.assert_allclose(back.yaw, 0.0)
    s = s_curve(60.0, max_heading=np.radians(20))
    assert abs(s.yaw[-1]) < 1e-12 and s.xy[-1, 1] > 5.0 and s.yaw.max() > np.radians(19.9)


def test_stop_and_go_has_stationary_frames():
    traj = stop_and_go(distance=10.0, speed=5.0, stop_duration=1.0, ramp_duration=1.0,
                       rate=10.0)
    step = np.linalg.norm(np.diff(traj.xy, axis=0), axis=1)
    still = step == 0.0
    assert 9 <= still.sum() <= 11                        # one second at 10 Hz
    assert np.all(np.diff(traj.stamps) > 0)
    # Identical poses while stopped, continuous speed (no jumps) around the stop.
    np.testing.assert_array_equal(traj.poses[1:][still], traj.poses[:-1][still])
    assert np.max(np.abs(np.diff(step))) < 0.1
    assert traj.xy[-1, 0] == pytest.approx(2 * 10.0 + 5.0, rel=1e-9)


def test_concatenate_chains_segments_without_duplicates():
    a = straight(10.0, rate=10.0)
    b = turn(np.pi / 2, radius=10.0, rate=10.0)
    c = reverse(2.0, rate=10.0)
    traj = concatenate(a, b, c)
    assert len(traj) == len(a) + len(b) + len(c) - 2
    assert np.all(np.diff(traj.stamps) > 0)
    np.testing.assert_allclose(traj.poses[len(a) - 1], a.poses[-1])
    np.testing.assert_allclose(traj.xy[len(a) + len(b) - 2], [20.0, 10.0], atol=1e-9)
    assert traj.yaw[-1] == pytest.approx(np.pi / 2)
    assert traj.then(a).stamps[-1] > traj.stamps[-1]


@pytest.mark.parametrize(('call', 'match'), [
    (lambda: straight(-1.0), r'distance: expected a positive finite number, got -1.0'),
    (lambda: turn(0.0), r'angle: expected a non-zero finite angle \(rad\), got 0.0'),
    (lambda: s_curve(max_heading=2.0), r'max_heading: expected 0 < \|max_heading\| < pi/2'),
    (lambda: concatenate(), r'segments: expected at least one Trajectory'),
    (lambda: Trajectory.from_poses(np.zeros(2), np.broadcast_to(np.eye(4), (2, 4, 4))),
     r'stamps: expected strictly increasing times'),
    # Not rigid transforms (a user test: evaluated as some other trajectory without a word).
    (lambda: Trajectory.from_poses(np.arange(2.0), np.stack([np.diag([3.0, 3.0, 3.0, 1.0])] * 2)),
     r'poses: expected rigid transforms .* got pose 0 with R\^T R off the identity by 8, '
     r'determinant 27'),
    (lambda: Trajectory.from_poses(np.arange(2.0), np.stack([np.eye(4), 2.0 * np.eye(4)])),
     r'got pose 1 .* bottom row \[0.0, 0.0, 0.0, 2.0\]'),
    (lambda: Trajectory.from_poses(np.arange(1.0), np.diag([1.0, 1.0, -1.0, 1.0])[None]),
     r'got pose 0 with R\^T R off the identity by 0, determinant -1'),
    (lambda: StreetWorld.along(np.zeros((3, 3))), r'path: expected shape \(N, 2\), got \(3, 3\)'),
    (lambda: StreetWorld.along(straight(), setback=(9.0, 7.0)),
     r'setback: expected a range 0 <= low <= high \(m\), got \(9.0, 7.0\)'),
    (lambda: StreetWorld.along(straight(), parked_car_probability=2),
     r'parked_car_probability: expected a probability in \[0, 1\], got 2'),
    (lambda: render(None, CAMERAS['pinhole'], np.eye(4)),
     r'world: expected a StreetWorld, got NoneType'),
])
def test_bad_input_raises_typed_errors(call, match):
    with pytest.raises(InputError, match=match):
        call()


def test_open_ground_world_has_only_ground_and_cars(drive, poses):
    world = StreetWorld.along(drive, seed=2, buildings=False, parked_car_probability=0.0)
    assert len(world) == 1 and world.kind[0] == GROUND_KIND
    frame = render(world, CAMERAS['pinhole'], poses[0])
    assert set(np.unique(frame.kind)) == {-1, GROUND_KIND}


# -- mounts ----------------------------------------------------------------------------------

def test_pitched_rolled_mount_renders_and_poses_reflect_it(world, drive):
    pitch, roll = np.radians(2.0), np.radians(1.0)
    T_bc = mount_transform(x=1.2, y=-0.3, height=1.6, roll=roll, pitch=pitch)
    cams = drive.camera_poses(T_bc)
    np.testing.assert_allclose(cams, drive.poses @ T_bc)
    config = MountConfig(x=1.2, y=-0.3, height=1.6, roll=roll, pitch=pitch)
    np.testing.assert_allclose(drive.camera_poses(config), cams)
    optical = cams[:, :3, 2]                                 # optical axis in odom
    np.testing.assert_allclose(optical[:, 2], -np.sin(pitch), atol=1e-12)
    np.testing.assert_allclose(cams[:, 2, 3], 1.6)
    cam = CAMERAS['pinhole']
    frame = render(world, cam, cams[2])
    level = render(world, cam, drive.camera_poses(mount_transform(x=1.2, y=-0.3,
                                                                  height=1.6))[2])
    # Looking down shows more ground; the ground seen through the pitched, rolled camera lies
    # on z = 0 when back-projected with that camera's pose.
    assert (frame.kind == GROUND_KIND).mean() > (level.kind == GROUND_KIND).mean() + 0.02
    px = _grid(cam, step=10)
    rows, cols = px[:, 1].astype(int), px[:, 0].astype(int)
    ground = frame.kind[rows, cols] == GROUND_KIND
    q, _ = cam.pixel_to_normalized(px[ground])
    X = (np.column_stack([q, np.ones(len(q))]) * frame.depth[rows, cols][ground, None])
    np.testing.assert_allclose((X @ cams[2][:3, :3].T + cams[2][:3, 3])[:, 2], 0.0, atol=1e-9)
    # Roll tilts the optical x axis (image right) out of the horizontal plane.
    np.testing.assert_allclose(cams[:, 2, 0], -np.cos(pitch) * np.sin(roll), atol=1e-12)
    np.testing.assert_allclose(yaw_of(cams[:, :3, :3] @ mount_transform()[:3, :3].T),
                               yaw_of(drive.poses[:, :3, :3]), atol=1e-12)
