"""VisualOdometry on rendered drives: accuracy bounds, scale sources, keyframes, and every drop
reason."""

from __future__ import annotations

import functools
import math
import pickle
import re

import cv2
import numpy as np
import pytest

from planar_vo.config import PlanarVoConfig
from planar_vo.core.camera import CameraModel
from planar_vo.core.conventions import invert, mount_transform, planar_pose, yaw_of
from planar_vo.core.trajectory import Trajectory
from planar_vo.errors import ConfigError, InputError
from planar_vo.frontend import leveling_rotation
from planar_vo.pipeline import DropReason, Stamp, TrackingState, VisualOdometry
from planar_vo.pipeline.calibration import focal_pitch
from planar_vo.sim import StreetWorld, hard_stop, reverse, stop_and_go, straight, turn
from planar_vo.sim.drive import body_twists, render_drive

CAMERA = CameraModel.pinhole(640, 480, 500.0)
HEIGHT = 1.5


@functools.lru_cache(maxsize=None)
def _drive(name: str, pitch: float = 0.0, roll: float = 0.0):
    """Rendered frames of a short drive (cached for the session): (trajectory, images, twists)."""
    trajectory = {
        'straight': lambda: straight(25.0, speed=8.0),
        'left': lambda: straight(8.0, speed=8.0).then(turn(np.pi / 3, radius=15.0, speed=6.0)),
        'right': lambda: turn(-np.pi / 4, radius=20.0, speed=6.0),
        'stop_and_go': lambda: stop_and_go(12.0, speed=6.0, stop_duration=1.5),
        'demo_stop': lambda: stop_and_go(30.0, speed=8.0, stop_duration=2.0),   # the demo's
        'reverse': lambda: reverse(6.0, speed=2.0),
        'long_turn': lambda: turn(np.pi / 2, radius=20.0, speed=8.0),
        # a simulator's brake at 30 Hz: 3 m/s^2 up to the stop
        'hard_stop': lambda: hard_stop(4.0, speed=8.0, deceleration=3.0, stop_duration=1.0),
    }[name]()
    world = StreetWorld.along(trajectory, seed=3)
    mount = mount_transform(height=HEIGHT, pitch=pitch, roll=roll)
    frames = list(render_drive(trajectory, world, CAMERA, mount))
    return trajectory, [f.image for f in frames], body_twists(trajectory)


def _run(name: str, config: PlanarVoConfig | None = None, *, pitch=0.0, roll=0.0, speed=False,
         camera=CAMERA):
    trajectory, images, twists = _drive(name, pitch, roll)
    config = config or PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}})
    vo = VisualOdometry(config, camera)
    results = []
    for stamp, image, twist in zip(trajectory.stamps, images, twists):
        if speed:
            vo.add_speed(float(stamp), float(np.hypot(twist[0], twist[1])))
        results.append(vo.process(image, float(stamp)))
    return trajectory, results, vo


def _errors(trajectory, results):
    """Final position error (m), final yaw error (deg) and distance driven (m)."""
    T0 = trajectory.poses[0]
    truth = invert(T0) @ trajectory.poses[-1]
    est = results[-1].pose
    distance = float(np.linalg.norm(np.diff(trajectory.xy, axis=0), axis=1).sum())
    pos = float(np.linalg.norm(est[:2, 3] - truth[:2, 3]))
    yaw = float(np.rad2deg(abs(yaw_of(est[:3, :3]) - yaw_of(truth[:3, :3]))))
    return pos, yaw, distance


# ---------------------------------------------------------------------------------------------
# Accuracy on rendered drives
# ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize('name', ['straight', 'left', 'right', 'stop_and_go', 'reverse'])
def test_drive_accuracy_with_ground_scale(name):
    trajectory, results, vo = _run(name)
    assert results[0].reason is DropReason.FIRST_FRAME
    assert all(r.ok for r in results[1:]), [(i, r.reason, r.message) for i, r in
                                            enumerate(results) if not r.ok][:5]
    pos, yaw, distance = _errors(trajectory, results)
    assert yaw < 0.1, yaw                              # degrees of drift at the end
    assert pos < 0.005 * distance + 0.02, (pos, distance)


def test_left_turn_is_positive_yaw_and_right_turn_negative():
    _, left, _ = _run('left')
    _, right, _ = _run('right')
    assert yaw_of(left[-1].pose[:3, :3]) > np.deg2rad(55)
    assert yaw_of(right[-1].pose[:3, :3]) < -np.deg2rad(40)
    assert left[-1].pose[1, 3] > 0 > right[-1].pose[1, 3]      # y left is positive (REP-103)


def test_reverse_moves_backwards_without_turning():
    trajectory, results, _ = _run('reverse')
    assert results[-1].pose[0, 3] < -5.0
    assert abs(results[-1].twist[0] + 2.0) < 0.1               # vx = -2 m/s in base_link


def test_stop_is_stationary_and_does_not_drift():
    trajectory, results, _ = _run('stop_and_go')
    still = np.flatnonzero(np.all(np.diff(trajectory.poses, axis=0) == 0, axis=(1, 2))) + 1
    assert len(still) >= 10
    # No drift while stopped: every still frame reports the same position.
    poses = np.array([results[i].pose for i in still])
    assert np.ptp(poses[:, :2, 3], axis=0).max() < 0.005
    # Once a keyframe sits at the stop, frames are recognised as stationary: zero motion, no
    # new keyframes, zero velocity.
    late = [results[i] for i in still[len(still) // 2:]]
    assert all(r.scale_source == 'stationary' and not r.keyframe for r in late)
    assert all(np.abs(r.twist).max() < 1e-6 for r in late[1:])


def test_twist_matches_ground_truth_speed():
    trajectory, results, _ = _run('left')
    _, _, twists = _drive('left')
    vx = np.array([r.twist[0] for r in results[2:]])
    wz = np.array([r.twist[5] for r in results[2:]])
    assert np.median(np.abs(vx - twists[2:, 0])) < 0.05
    assert np.median(np.abs(wz - twists[2:, 5])) < np.deg2rad(0.2)
    # In base_link at the stamp: a car turning at a steady rate moves straight ahead in its own
    # frame (the chord since the keyframe would have it slide sideways by v sin(yaw / 2)).
    turning = np.abs(twists[2:, 5]) > 0.1
    vy = np.array([r.twist[1] for r in results[2:]])
    assert np.median(np.abs(vy[turning] - twists[2:, 1][turning])) < 0.01


# ---------------------------------------------------------------------------------------------
# Scale sources
# ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize(('source', 'bound'), [('speed', 0.01), ('fixed', 0.02), ('unit', None)])
def test_scale_sources(source, bound):
    config = PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}, 'scale': {
        'source': source, 'fixed_speed': 8.0, 'fallback': 'unit'}})
    trajectory, results, _ = _run('straight', config, speed=source == 'speed')
    assert all(r.ok for r in results[1:])
    assert {r.scale_source for r in results[1:]} == {source}
    pos, yaw, distance = _errors(trajectory, results)
    if source == 'fixed':
        # One assumed speed for all steps: its error (3 m/s of 8) is shared, so the position's
        # standard deviation along the drive grows with the distance (a user test: as
        # independent step noise it grew with its square root, overconfident).
        along = math.sqrt(results[-1].pose_covariance[0, 0])
        assert along == pytest.approx(3.0 / 8.0 * distance, rel=0.05), (along, distance)
    if bound is not None:
        assert pos < bound * distance
    else:
        # Unit steps: the direction is right, the length is one unit per keyframe step.
        heading = np.arctan2(results[-1].pose[1, 3], results[-1].pose[0, 3])
        assert abs(heading) < np.deg2rad(0.5)


def _few_road_acs(top_up: bool, image: bool):
    """The straight drive with a front-end budget too small for the road ACs the ground scale
    needs (150 ACs, at least 40 on the road): final errors, step sources, the odometry."""
    config = PlanarVoConfig.from_dict({
        'mount': {'height': HEIGHT}, 'frontend': {'max_correspondences': 150},
        'scale': {'ground_min_correspondences': 40, 'ground_top_up': top_up,
                  'ground_image': image}})
    trajectory, results, vo = _run('straight', config)
    assert all(r.ok for r in results[1:])
    return _errors(trajectory, results), [r.scale_source for r in results[1:]], vo


def test_ground_scale_tops_up_road_acs_the_budget_left_out():
    """Without the top-up (nor the road's pixels) no step is metric (unit steps: the distance
    is wrong); with it the front-end adds road ACs from the same flows and the drive is
    measured at the camera height."""
    (pos, _, distance), sources, vo = _few_road_acs(top_up=False, image=False)
    assert 'ground' not in sources and vo.road_top_ups == 0 and pos > 0.1 * distance
    (pos, _, distance), sources, vo = _few_road_acs(top_up=True, image=False)
    assert vo.road_top_ups >= sources.count('ground') >= 5
    assert set(sources) <= {'ground', 'hold', 'unit'} and sources.count('unit') <= 1
    assert pos < 0.02 * distance


def test_ground_scale_from_the_road_pixels_where_road_acs_are_too_few():
    """Too few road ACs and no top-up (a fast car's flow keeps little of the near road): with
    the road's pixels (`scale.ground_image`, the default) every step is measured at the camera
    height, the blocks of road that matched counting as road ACs."""
    (pos, _, distance), sources, vo = _few_road_acs(top_up=False, image=True)
    assert vo.road_top_ups == 0
    assert sources.count('ground') == vo.image_road_steps >= len(sources) - 1
    assert pos < 0.02 * distance, (pos, distance)
    # Each step says what measured it.
    _, results, _ = _run('straight', vo.config)
    assert {r.scale_from for r in results if r.scale_source == 'ground'} == {'road pixels'}
    assert {r.scale_from for r in results if r.scale_source != 'ground'} <= {''}
    _, results, _ = _run('straight')
    assert {r.scale_from for r in results if r.scale_source == 'ground'} == {'road ACs'}


def test_road_pixel_steps_state_at_least_the_road_acs_deviation(monkeypatch, caplog):
    """A step from the road's pixels states at least the median relative standard deviation of
    the recent steps from road ACs (their errors are shared); a scan without a step is counted
    by its reason (numbers as '#') and logged the first time."""
    import logging
    import types

    from planar_vo.pipeline import odometry
    from planar_vo.pipeline.road_image import ImageRoadScale

    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}}), CAMERA)
    found = ImageRoadScale(2.0, 0.01, 20, np.zeros(3), np.zeros(2), 0.4, '',
                           np.zeros((20, 2)), np.zeros((20, 2)), np.zeros((20, 2, 2)),
                           np.ones(20))
    monkeypatch.setattr(odometry, 'image_road_scale', lambda *a, **k: found)
    monkeypatch.setattr(vo, '_road_step', lambda *a, **k: (2.0, 1e-6, 0.003))
    image = np.zeros((CAMERA.height, CAMERA.width), np.uint8)
    est = types.SimpleNamespace(R=np.eye(3), t=np.array([0.0, 0.0, -1.0]))
    step = vo._image_road_step(CAMERA, est, image, image, 0.1, 5.0)
    assert step == (2.0, 1e-6, 0.003) and vo.image_road_steps == 1     # no road-AC steps yet
    vo._road_relative_stds.extend([(-9.0, 0.5), (4.8, 0.04), (4.9, 0.05), (5.0, 0.06)])
    step = vo._image_road_step(CAMERA, est, image, image, 0.1, 5.1)
    # (the first is more than 10 s old: left out)
    assert step[0] == 2.0 and step[1] == pytest.approx((0.05 * 2.0) ** 2) and step[2] == 0.003
    missed = ImageRoadScale(math.nan, math.inf, 0, np.zeros(3), np.zeros(2), 0.01,
                            'no clear best step (contrast 0.012)')
    monkeypatch.setattr(odometry, 'image_road_scale', lambda *a, **k: missed)
    with caplog.at_level(logging.INFO, logger='planar_vo.pipeline.odometry'):
        assert vo._image_road_step(CAMERA, est, image, image, 0.1, 5.2) is None
        assert vo._image_road_step(CAMERA, est, image, image, 0.1, 5.3) is None
    assert vo.image_road_misses == {'no clear best step (contrast #)': 2}
    assert vo.image_road_steps == 2
    lines = [r.getMessage() for r in caplog.records if "road's pixels" in r.getMessage()]
    assert len(lines) == 1 and 'no clear best step (contrast 0.012)' in lines[0]
    assert 'steps searched up to 70 m/s x 0.100 s)' in lines[0]
    assert caplog.records[-1].levelno == logging.INFO
    # The longest step searched fitting best: a warning that the vehicle may be faster.
    missed = ImageRoadScale(math.nan, math.inf, 0, np.zeros(3), np.zeros(2), 0.3,
                            'the best step is the longest searched (6.97 m of 0-7 m)')
    monkeypatch.setattr(odometry, 'image_road_scale', lambda *a, **k: missed)
    with caplog.at_level(logging.INFO, logger='planar_vo.pipeline.odometry'):
        assert vo._image_road_step(CAMERA, est, image, image, 0.1, 5.4) is None
    assert caplog.records[-1].levelno == logging.WARNING
    assert caplog.records[-1].getMessage().endswith(
        '70 m/s x 0.100 s: is the vehicle faster than scale.ground_image_max_speed?)')
    # A measured speed beyond the setting: warned once, and the scan reaches twice that speed.
    ranges = []

    def scan(*a, steps, **k):
        ranges.append(steps)
        return found
    monkeypatch.setattr(odometry, 'image_road_scale', scan)
    vo._held = (90.0, 1.0, 5.5, 0.0)
    with caplog.at_level(logging.INFO, logger='planar_vo.pipeline.odometry'):
        for stamp in (5.6, 5.7):
            assert vo._image_road_step(CAMERA, est, image, image, 0.1, stamp)[0] == 2.0
    assert ranges == [(0.0, pytest.approx(18.0))] * 2
    # Nothing measured to widen by, and the longest step fitting best: once more over twice
    # the range, with a warning (a review: a start above the setting never widened).
    vo._held, ranges[:] = None, []
    longest = ImageRoadScale(math.nan, math.inf, 0, np.zeros(3), np.zeros(2), 0.3,
                             'the best step is the longest searched or beyond (8.6 m, the '
                             'range 0-7 m)')

    def scan2(*a, steps, **k):
        ranges.append(steps)
        return longest if steps[1] < 10.0 else found
    monkeypatch.setattr(odometry, 'image_road_scale', scan2)
    with caplog.at_level(logging.INFO, logger='planar_vo.pipeline.odometry'):
        assert vo._image_road_step(CAMERA, est, image, image, 0.1, 5.8)[0] == 2.0
    assert ranges == [(0.0, pytest.approx(7.0)), (0.0, pytest.approx(14.0))]
    assert caplog.records[-1].levelno == logging.WARNING
    assert "found the step beyond scale.ground_image_max_speed 70 m/s" in \
        caplog.records[-1].getMessage()
    # A reset (also a jump back in time) forgets the road-AC deviations of the old time base.
    assert vo._road_relative_stds
    vo.reset()
    assert not vo._road_relative_stds
    faster = [r.getMessage() for r in caplog.records if 'faster than' in r.getMessage()]
    assert faster[-1].startswith('the vehicle moved at 90.0 m/s (its last measured step), '
                                 'faster than scale.ground_image_max_speed 70 m/s')
    assert sum('its last measured step' in m for m in faster) == 1


def test_the_road_ac_steps_deviations_are_kept_for_the_pixels_floor():
    """Every step from road ACs leaves its stamp and relative standard deviation for the floor
    of the steps from the road's pixels (a review: nothing tested that they are kept)."""
    trajectory, results, vo = _run('straight')
    ground = [(r.stamp, r) for r in results if r.ok and r.scale_source == 'ground']
    assert len(ground) >= 20 and vo.image_road_steps == 0
    kept = list(vo._road_relative_stds)
    assert [when for when, _ in kept] == [stamp for stamp, _ in ground][-len(kept):]
    assert all(0.0 < rel < 0.2 for _, rel in kept)


def test_speed_source_falls_back_before_the_first_speed_message():
    config = PlanarVoConfig.from_dict({'mount': {'height': HEIGHT},
                                       'scale': {'source': 'speed', 'fallback': 'ground'}})
    _, results, _ = _run('straight', config)            # no speed samples at all
    assert {r.scale_source for r in results[1:]} == {'ground'}


def test_a_step_covariance_is_its_first_order_propagation(rng):
    """compose's analytic Jacobian of the step against central differences of the composed
    pose's log (at 1e-4: smaller steps lose digits in se3_log's small-angle terms)."""
    from planar_vo.core.conventions import se3, se3_log, so3_exp
    from planar_vo.core.robust.general import tangent_basis
    from planar_vo.pipeline.motion import compose, relative_pose

    for _ in range(20):
        R = so3_exp(rng.normal(0.0, 0.3, 3))
        t = rng.normal(size=3)
        t /= np.linalg.norm(t)
        B, s = tangent_basis(t), rng.uniform(0.05, 3.0)
        L = rng.normal(size=(6, 6))
        Sm = L @ L.T
        T1 = se3(so3_exp(rng.normal(size=3)), rng.normal(size=3))
        pose, cov, step = compose(T1, np.eye(6), R, t, B, Sm[:5, :5], s, Sm[5, 5])
        T21 = invert(relative_pose(R, t, s))
        J = np.empty((6, 6))
        for k in range(6):
            out = []
            for sign in (1.0, -1.0):
                d = np.zeros(6)
                d[k] = sign * 1e-4
                tk = t + B @ d[3:5]
                out.append(se3_log(T21 @ relative_pose(so3_exp(d[:3]) @ R,
                                                       tk / np.linalg.norm(tk), s + d[5])))
            J[:, k] = (out[0] - out[1]) / 2e-4
        Sm[:5, 5] = Sm[5, :5] = 0.0             # the step length is independent of (w, d)
        np.testing.assert_allclose(step, J @ Sm @ J.T, rtol=1e-6, atol=1e-7 * np.abs(step).max())
        np.testing.assert_allclose(pose, T1 @ relative_pose(R, t, s), atol=1e-12)


def test_covariance_is_derived_and_grows_along_the_drive():
    # (The levelling's share, which shrinks once the mount tilt is known, is tested below.)
    _, results, _ = _run('left', PlanarVoConfig.from_dict({'mount': {
        'height': HEIGHT, 'estimate_tilt': False}}))
    covs = np.array([r.pose_covariance for r in results[1:]])
    assert np.all(np.isfinite(covs))
    xx = covs[:, 0, 0]
    assert xx[-1] > xx[0] > 0.0                              # grows with distance
    assert np.all(np.linalg.eigvalsh(covs[-1]) > 0)           # positive definite
    # 3D: height, roll and pitch are estimated, their variances grow like the others. In a
    # turn the height's variance may dip a little: the new step's height error, from the tilt
    # error carried along, is anti-correlated with the height error the same tilt error made
    # while the car was heading elsewhere.
    zz = covs[:, 2, 2]
    assert np.all(np.diff(zz) >= -0.01 * zz[:-1]) and zz[-1] > 5 * zz[0] > 0.0
    assert covs[-1, 5, 5] > 0.0 and covs[-1, 3, 3] > 0.0 and covs[-1, 4, 4] > 0.0


def test_the_levelling_uncertainty_grows_roll_and_pitch_std_with_the_angle_turned(
        monkeypatch):
    # A levelling (mount tilt) error tilts the axis of every turn alike: a pitch error sigma
    # moves the vertical forwards (base x), a roll error sideways (base y), and turning by psi
    # rotates that into an orientation error of sigma (sin psi, 1 - cos psi) for the forward
    # displacement and sigma (-(1 - cos psi), sin psi) for the sideways one (odom x, y): the
    # sum of the turns' rotated axis errors. The heading's is unchanged; the poses are the
    # same whatever the covariance.
    sigma = 0.01
    runs = {}
    for name, stds in (('none', None), ('pitch', (sigma, 0.0)), ('roll', (0.0, sigma))):
        monkeypatch.setattr(VisualOdometry, '_tilt_stds', lambda self, stds=stds: stds)
        runs[name] = _run('left')[1]
    assert all(r.ok for r in runs['none'][1:])
    for r, a in zip(runs['pitch'][1:], runs['none'][1:]):
        np.testing.assert_array_equal(r.pose, a.pose)
    psi = float(yaw_of(runs['none'][-1].pose[:3, :3]))
    assert np.rad2deg(psi) == pytest.approx(60.0, abs=1.0)
    s, c = math.sin(psi), 1.0 - math.cos(psi)
    for name, expected in (('pitch', (s * s, c * c)), ('roll', (c * c, s * s))):
        added = runs[name][-1].pose_covariance - runs['none'][-1].pose_covariance
        np.testing.assert_allclose(np.diag(added)[3:5], sigma ** 2 * np.array(expected),
                                   rtol=0.05, err_msg=name)
        assert abs(added[5, 5]) < 1e-3 * sigma ** 2, name
        # Straight ahead, before the turn, the levelling's share is (almost) nothing.
        first = runs[name][5].pose_covariance - runs['none'][5].pose_covariance
        assert np.abs(first[3:5, 3:5]).max() < 1e-3 * sigma ** 2, name


def test_the_tilt_gain_is_the_first_order_effect_of_a_tilted_turn_axis():
    # Keyframe by keyframe, a camera turns (left, straight on, right) about the levelled
    # vertical and drives forward; turning instead about a vertical displaced by eps * d moves
    # the final orientation by eps G d and the position by eps H d (G, H: the tilt gain).
    from planar_vo.core.conventions import so3_exp, so3_log
    from planar_vo.pipeline.keyframes import Keyframe
    from planar_vo.pipeline.odometry import _tilt_gain

    R_lc = so3_exp(np.array([0.02, 0.0, -0.01]))          # camera -> level camera
    vertical = R_lc[1]
    forward = np.array([0.1, 0.0, 1.0])                     # camera frame, per step
    turns = [0.1] * 5 + [0.0] * 5 + [-0.15] * 4

    def drive(axis: np.ndarray) -> np.ndarray:
        pose = np.eye(4)
        for psi in turns:
            new = pose.copy()
            new[:3, :3] = pose[:3, :3] @ so3_exp(psi * axis)
            new[:3, 3] = pose[:3, 3] + pose[:3, :3] @ forward
            pose = new
        return pose

    keyframe, pose = Keyframe(None, 0.0, np.eye(4), np.zeros((6, 6)), 0), np.eye(4)
    for psi in turns:
        R = so3_exp(psi * vertical).T                       # X2 = R X1 + t
        pose = keyframe.pose.copy()
        pose[:3, :3] = keyframe.pose[:3, :3] @ R.T
        pose[:3, 3] = keyframe.pose[:3, 3] + keyframe.pose[:3, :3] @ forward
        gain = _tilt_gain(keyframe, pose, R, R_lc)
        keyframe = Keyframe(None, 0.0, pose, np.zeros((6, 6)), 0, tilt_gain=gain)
    np.testing.assert_allclose(drive(vertical), pose, atol=1e-12)
    eps = 1e-7
    for d in (R_lc.T @ np.array([1.0, 0.0, 0.0]), R_lc.T @ np.array([0.0, 0.0, 1.0])):
        tilted = drive(vertical + eps * d)
        orientation = so3_log(tilted[:3, :3] @ pose[:3, :3].T) / eps
        position = (tilted[:3, 3] - pose[:3, 3]) / eps
        np.testing.assert_allclose(gain[:3] @ d, orientation, rtol=1e-4, atol=1e-6)
        np.testing.assert_allclose(gain[3:] @ d, position, rtol=1e-4, atol=1e-5)
        assert np.linalg.norm(position) > 1.0                 # the position part matters


@pytest.mark.parametrize('case', ['known', 'gain'])
def test_the_focal_error_model_is_the_first_order_effect_of_the_focal_length(case):
    # Keyframe by keyframe, a camera turns (about axes with x, y and z parts) and moves (with
    # offsets across its optical axis, road-scaled or not); measured through focal lengths
    # f_i, a step turns by f / f_i of its angle about x and y, its direction's offset scales by
    # f / f_i and a road-scaled length by f_i / f. 'known': measured through f_i = f (1 +
    # eps k_i), the pose error is `_focal_error`'s known part at f; 'gain': measured through F
    # with the truth F (1 + eps), it is eps times its gain at F.
    from planar_vo.core.conventions import so3_exp, so3_log
    from planar_vo.pipeline.keyframes import Keyframe
    from planar_vo.pipeline.odometry import _focal_error, _focal_sums

    rng = np.random.default_rng(7)
    steps = [(rng.normal(0.0, [0.02, 0.1, 0.02]), rng.normal([0.0, 0.0, 1.0], [0.15, 0.05, 0.0]),
              rng.uniform(0.5, 1.5), k % 3 != 0) for k in range(12)]
    eps, F = 1e-7, 700.0
    focals = [F * (1.0 + eps * k) for k in rng.uniform(-3.0, 3.0, len(steps))] \
        if case == 'known' else [F] * len(steps)
    truth = F if case == 'known' else F * (1.0 + eps)

    def chain(measured: bool) -> tuple[np.ndarray, Keyframe]:
        keyframe = Keyframe(None, 0.0, np.eye(4), np.zeros((6, 6)), 0)
        for (omega, direction, length, ground), f in zip(steps, focals):
            c = truth / f if measured else 1.0
            omega = omega * np.array([c, c, 1.0])
            direction = direction * np.array([c, c, 1.0])
            direction /= np.linalg.norm(direction)
            if measured and ground:
                length = length * f / truth
            pose = keyframe.pose.copy()
            pose[:3, :3] = keyframe.pose[:3, :3] @ so3_exp(omega)
            pose[:3, 3] = keyframe.pose[:3, 3] + keyframe.pose[:3, :3] @ (length * direction)
            sums = _focal_sums(keyframe.focal_sums, keyframe.pose[:3, :3], omega,
                               pose[:3, 3] - keyframe.pose[:3, 3], f, ground)
            keyframe = Keyframe(None, 0.0, pose, np.zeros((6, 6)), 0, focal_sums=sums)
        return keyframe.pose, keyframe

    measured, keyframe = chain(True)
    true_pose, _ = chain(False)
    error = np.concatenate([so3_log(measured[:3, :3] @ true_pose[:3, :3].T),
                            measured[:3, 3] - true_pose[:3, 3]]) / eps
    known, gain = _focal_error(keyframe.focal_sums, F)
    predicted = known / eps if case == 'known' else gain
    np.testing.assert_allclose(predicted, error, rtol=1e-4, atol=1e-4 * np.abs(error).max())
    assert np.abs(error[3:]).max() > 1.0 and np.abs(error[:3]).max() > 0.01   # both matter
    if case == 'gain':
        assert np.abs(known).max() < 1e-12          # every step through the focal length F


def test_the_focal_step_covariance_is_the_first_order_effect_on_one_step():
    # One step measured through f, the truth f (1 + eps): the true step is the measured one
    # perturbed by xi (T_true = T exp(xi), as `compose`'s step covariance), and the focal
    # term of the step covariance is outer(xi, xi) / eps^2; likewise a principal point eps f
    # pixels off and its term. A user-facing twist rests on it (a review found the sign of
    # the across-axis term flipped).
    from planar_vo.core.conventions import se3_log, so3_exp
    from planar_vo.pipeline.motion import relative_pose
    from planar_vo.pipeline.odometry import _focal_step_covariance

    eps, s = 1e-7, 1.3
    omega = np.array([0.01, 0.08, -0.02])          # camera 1 -> 2 turn, camera frame
    direction = np.array([0.2, -0.05, 1.0])        # camera 2's centre in camera 1
    direction /= np.linalg.norm(direction)

    def step(omega, direction, length):
        R = so3_exp(omega).T                       # X2 = R X1 + t
        return R, -R @ direction, relative_pose(R, -R @ direction, length)

    R, t, T = step(omega, direction, s)
    for ground in (True, False):
        c = 1.0 + eps                              # through f (1 + eps): f / f_i
        d = direction * [c, c, 1.0]
        _, _, T_true = step(omega * [c, c, 1.0], d / np.linalg.norm(d), s * c if ground else s)
        xi = se3_log(invert(T) @ T_true) / eps
        np.testing.assert_allclose(_focal_step_covariance(R, t, s, ground, 1.0, 0.0),
                                   np.outer(xi, xi), rtol=1e-5, atol=1e-10)
    d = direction + [eps, 0.0, 0.0]                # the principal point eps f pixels off
    _, _, T_true = step(omega, d / np.linalg.norm(d), s)
    xi = se3_log(invert(T) @ T_true) / eps
    np.testing.assert_allclose(_focal_step_covariance(R, t, s, True, 0.0, 1.0),
                               np.outer(xi, xi), rtol=1e-5, atol=1e-10)


@pytest.mark.parametrize('drive', ['stop_and_go', 'demo_stop'])
def test_the_twist_covariance_covers_braking_stopping_and_starting_off(drive):
    # The twist is the mean over the keyframe interval: it lags the velocity while braking and
    # accelerating, and after the stop; standing is decided by a pixel threshold that a car
    # starting off passes below, and the first step after it holds what the standing frames
    # moved unseen. Its covariance says so: every frame's forward speed within 3 standard
    # deviations (before: 45 % of the frames of this drive outside, up to 300; the demo's stop,
    # found by a user test, 16 at the first step after it).
    trajectory, results, _ = _run(drive)
    _, _, twists = _drive(drive)
    z = np.array([(r.twist[0] - tw[0]) / math.sqrt(r.twist_covariance[0, 0])
                  for r, tw in zip(results[1:], twists[1:]) if r.ok])
    assert len(z) >= 0.9 * (len(results) - 1) and np.all(np.abs(z) < 3.0), np.abs(z).max()
    assert any(r.scale_source == 'stationary' for r in results)
    # Cruising, the covariance stays that of the mean's noise (the lag's share small) and of
    # the camera height's uncertainty (mount.height_std, a relative error of the speed).
    if drive == 'stop_and_go':
        cruise = [r for r, tw in zip(results, twists) if r.ok and abs(tw[0] - 6.0) < 1e-6]
        height = math.hypot(0.05, 6.0 * PlanarVoConfig().mount.height_std / HEIGHT)
        assert cruise and max(math.sqrt(r.twist_covariance[0, 0]) for r in cruise) < height


def _normal_share(monkeypatch, share: float) -> None:
    """Every ground step's shared relative error from the road normal set to ``share``."""
    road_step = VisualOdometry._road_step

    def shared(self, *args, **kwargs):
        step = road_step(self, *args, **kwargs)
        return None if step is None else (*step[:2], share)

    monkeypatch.setattr(VisualOdometry, '_road_step', shared)


def _assert_shared_growth(results, without, relative: float) -> None:
    """``results`` against the same straight drive ``without`` a shared relative error: the
    same poses, the position's covariance grown by ``relative`` of the camera's path (its outer
    product) and the twist's by ``relative`` of the velocity."""
    assert all(r.ok and r.scale_source == 'ground' for r in results[1:])
    mount = mount_transform(height=HEIGHT)
    for r, a in zip(results[1:], without[1:], strict=True):
        np.testing.assert_array_equal(r.pose, a.pose)               # the poses are the same
        path = (r.pose @ mount)[:3, 3] - mount[:3, 3]               # the camera's, in odom
        np.testing.assert_allclose(r.pose_covariance[:3, :3] - a.pose_covariance[:3, :3],
                                   relative ** 2 * np.outer(path, path), rtol=1e-9, atol=1e-15)
        v = r.twist[:2]
        np.testing.assert_allclose(r.twist_covariance[:2, :2] - a.twist_covariance[:2, :2],
                                   relative ** 2 * np.outer(v, v), rtol=1e-9, atol=1e-15)
    assert results[-1].pose[0, 3] > 20.0


def test_a_scale_error_shared_by_the_steps_grows_the_position_std_with_the_distance(
        monkeypatch):
    # The road normal's calibration error makes every step too long or short by the same
    # share: a relative error of 5 % shared by all steps is 5 % of the distance (not 5 % of a
    # step times the square root of the number of steps), along the camera's path, and 5 % of
    # the speed in the twist.
    config = PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}})

    def run(share: float):
        _normal_share(monkeypatch, share)
        return _run('straight', config)[1]

    alone = run(0.0)
    _assert_shared_growth(run(0.05), alone, 0.05)


def test_the_camera_heights_uncertainty_is_a_scale_error_shared_by_the_steps(monkeypatch):
    """``mount.height_std``: every ground step is relative to the camera height, so its
    uncertainty (here 5 %) is a relative error all steps share, independent of the road
    normal's (here held at 3 % per step): the position's variance along the path grows by
    (5 % of the distance)^2 exactly, the twist's by (5 % of the speed)^2, and the poses do not
    change (a review: the first version of this test could not tell a sum of the two errors
    from their quadrature)."""
    _normal_share(monkeypatch, 0.03)

    def run(height_std: float):
        config = PlanarVoConfig.from_dict({'mount': {'height': HEIGHT,
                                                     'height_std': height_std}})
        return _run('straight', config)[1]

    exact = run(0.0)
    _assert_shared_growth(run(0.05 * HEIGHT), exact, 0.05)


def _disturbed_straight_drive(monkeypatch, disturb):
    """The straight drive with every estimate passed through ``disturb(est, R_lc, rng)``:
    the ground truth relative to the first pose and the results."""
    trajectory, images, _ = _drive('straight')
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}}), CAMERA)
    rng = np.random.default_rng(7)
    real = vo._estimate
    monkeypatch.setattr(vo, '_estimate', lambda acs, camera: disturb(
        real(acs, camera), vo._estimator.R_lc, rng))
    results = [vo.process(image, float(stamp)) for stamp, image in
               zip(trajectory.stamps, images)]
    assert all(r.ok for r in results[1:])
    return [invert(trajectory.poses[0]) @ P for P in trajectory.poses], results


def _step_nees(error: np.ndarray, variance: np.ndarray) -> float:
    """Mean NEES of the per-step errors against the growth of their variance, from step 12 on
    (the excess is measured after 10 steps of history)."""
    nees = np.diff(error)[12:] ** 2 / np.diff(variance)[12:]
    assert len(nees) >= 15
    return float(np.mean(nees))


def test_yaw_covariance_covers_errors_the_estimator_does_not_predict(monkeypatch):
    """Every estimate's yaw disturbed by 0.15 deg of noise its covariance does not know about
    (errors shared by all ACs of a frame, as on real roads): after a few steps the published
    yaw variance includes it, measured from the steps' yaw-rate changes (no ground truth)."""
    import dataclasses

    from planar_vo.core.conventions import rotation_y

    def disturb(est, R_lc, rng):
        noise = R_lc.T @ rotation_y(np.deg2rad(0.15) * rng.standard_normal()) @ R_lc
        return dataclasses.replace(est, R=noise @ est.R)

    truth, results = _disturbed_straight_drive(monkeypatch, disturb)
    yaw_true = np.unwrap([yaw_of(P[:3, :3]) for P in truth])
    yaw_est = np.unwrap([yaw_of(r.pose[:3, :3]) for r in results])
    nees = _step_nees(yaw_est - yaw_true, [r.pose_covariance[5, 5] for r in results])
    assert 0.3 < nees < 3.0, nees


def test_roll_and_pitch_covariance_cover_the_rotation_errors_the_estimator_does_not_predict(
        monkeypatch):
    """Every estimate's rotation disturbed by 0.15 deg of noise about each axis that its
    covariance does not know about (errors shared by all ACs; on KITTI 05 the roll and pitch
    err by 0.022 and 0.024 deg per step against 0.0015 predicted): the excess measured on the
    yaw widens roll and pitch alike, so all three stay honest. With the excess on the yaw alone
    the roll's and pitch's NEES here are in the hundreds."""
    import dataclasses

    from planar_vo.core.conventions import so3_exp, so3_log

    def disturb(est, R_lc, rng):
        noise = R_lc.T @ so3_exp(np.deg2rad(0.15) * rng.standard_normal(3)) @ R_lc
        return dataclasses.replace(est, R=noise @ est.R)

    truth, results = _disturbed_straight_drive(monkeypatch, disturb)
    # Small-angle errors about the odom axes (x roll, y pitch, z yaw).
    error = np.array([so3_log(r.pose[:3, :3] @ P[:3, :3].T) for r, P in zip(results, truth)])
    for axis in (0, 1, 2):
        nees = _step_nees(error[:, axis], [r.pose_covariance[3 + axis, 3 + axis]
                                           for r in results])
        assert 0.3 < nees < 3.0, (axis, nees)


def test_position_covariance_covers_heading_errors_the_estimator_does_not_predict(monkeypatch):
    """Every estimate's direction of travel turned by 0.3 deg of noise about the vertical, which
    its covariance does not know about (on KITTI 05 the direction scatters 0.12-0.16 deg per
    step against a predicted 0.04): after a few steps the published position covariance
    includes it across the track, measured from the headings' spread (no ground truth)."""
    import dataclasses

    from planar_vo.core.conventions import rotation_y

    def disturb(est, R_lc, rng):
        turn = R_lc.T @ rotation_y(np.deg2rad(0.3) * rng.standard_normal()) @ R_lc
        return dataclasses.replace(est, t=turn @ est.t, basis=turn @ est.basis)

    truth, results = _disturbed_straight_drive(monkeypatch, disturb)
    # Across the track: base y (the drive is straight along x). The lateral variance also grows
    # with the yaw uncertainty of the first steps (the nominal AC accuracy, before the excess
    # is measured), which on this clean drive is conservative: hence the low lower bound.
    nees = _step_nees(np.array([r.pose[1, 3] - P[1, 3] for r, P in zip(results, truth)]),
                      [r.pose_covariance[1, 1] for r in results])
    assert 0.05 < nees < 3.0, nees


def test_first_steps_yaw_is_widened_by_the_nominal_accuracy_until_the_excess_is_measured():
    """Before 10 steps of history the yaw error the estimator misses cannot be measured: each
    step's yaw variance grows by at least ``voting.point_noise^2`` (a rotation of the nominal
    AC accuracy, shared by all ACs); afterwards by the measured excess, which on this clean
    drive is far smaller."""
    config = PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}})
    nominal = config.voting.point_noise ** 2
    _, results, _ = _run('straight', config)
    assert all(r.ok for r in results[1:])
    growth = np.diff([r.pose_covariance[5, 5] for r in results])
    assert np.all(growth[:10] >= nominal) and np.all(growth[:10] < 1.5 * nominal), growth[:10]
    assert np.all(growth[11:] < 0.2 * nominal), growth[11:]


def test_first_steps_heading_nominal_is_the_shared_error_read_as_a_turn_of_travel():
    """Before the heading's excess can be measured, the nominal AC accuracy ``d`` is carried to
    the direction of travel as ``d sum(b/Z) / sum((b/Z)^2)`` over the inliers (``b/Z``: the
    baseline over each point's distance from the second camera), exactly on noise-free
    geometry; points within 3 deg of the epipole carry no depth and are left out."""
    import dataclasses

    from planar_vo.core.correspondences import AffineCorrespondences
    from planar_vo.core.robust.general import tangent_basis
    from planar_vo.pipeline.estimator import FrameEstimate

    rng = np.random.default_rng(3)
    n, b = 200, 0.8
    X1 = np.column_stack([rng.uniform(-8, 8, n), rng.uniform(-2, 1.5, n), rng.uniform(4, 60, n)])
    X1[:5] = [[0.0, 0.0, 20.0], [0.1, 0.0, 30.0], [0.0, -0.2, 15.0], [0.3, 0.1, 50.0],
              [0.0, 0.0, 10.0]]                           # near the epipole: left out
    R = np.eye(3)
    t = np.array([0.0, 0.0, -b])                          # X2 = R X1 + t: straight ahead
    X2 = X1 @ R.T + t
    q1, q2 = X1[:, :2] / X1[:, 2:], X2[:, :2] / X2[:, 2:]
    inliers = np.ones(n, bool)
    inliers[-20:] = False                                 # outliers do not count
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}}))
    vo._norm = AffineCorrespondences(q1, q2, np.broadcast_to(np.eye(2), (n, 2, 2)).copy())
    est = FrameEstimate(R, t / b, np.eye(5), np.zeros((3, 2)), inliers, True, None,
                        (0.0, 0.0, True), {})
    distance = np.linalg.norm(X2, axis=1)
    # The angle at the first camera between the point and the second camera (straight ahead).
    off_axis = np.linalg.norm(np.cross(X1 / np.linalg.norm(X1, axis=1)[:, None],
                                       [0.0, 0.0, 1.0]), axis=1)
    keep = inliers & (off_axis > 0.05)
    assert np.count_nonzero(inliers & ~keep) >= 5
    p = b / distance[keep]
    expected = vo.config.voting.point_noise * p.sum() / (p @ p)
    assert np.sqrt(vo._heading_nominal(est)) == pytest.approx(expected, rel=1e-9)
    # The first steps' direction covariance carries it: the heading's variance grows by it.
    est.basis = tangent_basis(est.t)
    R_lc = vo._estimator.R_lc
    x, _, z = -(R_lc @ est.t)
    g = (R_lc.T @ np.array([z, 0.0, -x]) / (x * x + z * z)) @ -est.basis
    grown = vo._motion_covariance(est, 0.1)[3:5, 3:5] - est.cov[3:5, 3:5]
    assert g @ grown @ g == pytest.approx(expected ** 2, rel=1e-9)
    # Faster (a longer baseline at the same depths): the same shared error is a smaller turn.
    X2 = X1 + 2 * t
    vo._norm = dataclasses.replace(vo._norm, p2=X2[:, :2] / X2[:, 2:])
    assert vo._heading_nominal(est) < 0.6 * expected ** 2
    # No inlier away from the epipole: nothing to carry it by.
    est.inliers = np.zeros(n, bool)
    assert vo._heading_nominal(est) == 0.0


def test_flat_output_keeps_x_y_yaw_and_states_the_flat_world():
    config = PlanarVoConfig.from_dict({'mount': {'height': HEIGHT},
                                       'odometry': {'output': 'flat'}})
    trajectory, flat, _ = _run('left', config)
    _, full, _ = _run('left')
    for f, g in zip(flat[1:], full[1:]):
        assert f.pose[2, 3] == 0.0 and np.allclose(f.pose[2, :3], [0.0, 0.0, 1.0])
        np.testing.assert_allclose(f.pose[:2, 3], g.pose[:2, 3], atol=1e-12)
        assert yaw_of(f.pose[:3, :3]) == pytest.approx(yaw_of(g.pose[:3, :3]), abs=1e-12)
        # z, roll and pitch: the flat world's variances plus what was dropped (its variance and
        # its square: the zero is off by that much; a user test: 14 sigma on a climb).
        R = g.pose[:3, :3]
        dropped = [g.pose[2, 3], math.atan2(R[2, 1], R[2, 2]), -math.asin(R[2, 0])]
        np.testing.assert_allclose(np.diag(f.pose_covariance)[2:5],
                                   np.array([0.05, 0.02, 0.02]) ** 2 + np.square(dropped)
                                   + np.diag(g.pose_covariance)[2:5], rtol=1e-9)
        assert f.pose_covariance[5, 5] == pytest.approx(g.pose_covariance[5, 5])
        # The twist too: vz and the roll and pitch rates are zero, uncertain by what was
        # dropped; vx, vy and the yaw rate as in 3D.
        keep, drop = [0, 1, 5], [2, 3, 4]
        assert np.array_equal(f.twist[keep], g.twist[keep]) and not f.twist[drop].any()
        assert np.array_equal(f.twist_covariance[np.ix_(keep, keep)],
                              g.twist_covariance[np.ix_(keep, keep)])
        np.testing.assert_allclose(np.diag(f.twist_covariance)[drop],
                                   np.diag(g.twist_covariance)[drop] + g.twist[drop] ** 2,
                                   rtol=1e-12)


# ---------------------------------------------------------------------------------------------
# Mount, distortion and focal self-calibration
# ---------------------------------------------------------------------------------------------

def test_pitched_and_rolled_mount_is_levelled():
    pitch, roll = np.deg2rad(4.0), np.deg2rad(1.5)
    config = PlanarVoConfig.from_dict({'mount': {'height': HEIGHT, 'pitch': float(pitch),
                                                 'roll': float(roll)}})
    trajectory, results, _ = _run('left', config, pitch=pitch, roll=roll)
    assert all(r.ok for r in results[1:])
    pos, yaw, distance = _errors(trajectory, results)
    assert yaw < 0.15 and pos < 0.01 * distance
    # Without levelling the same frames give a clearly worse result.
    unlevelled = PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}})
    _, bad, _ = _run('left', unlevelled, pitch=pitch, roll=roll)
    assert _errors(trajectory, bad)[1] > 3 * max(yaw, 0.01)


def test_uncalibrated_camera_runs_on_a_provisional_focal_length():
    # No camera model and no intrinsics: the focal length is calibrated online from the keyframe
    # pairs the car turned between. One turn is not enough to adopt it (the profiles' honest
    # uncertainty stays above 2 %), so the odometry runs on a provisional focal length and
    # says so; whatever it estimates lies within 3 of its reported standard deviations.
    config = PlanarVoConfig.from_dict({'mount': {'height': HEIGHT},
                                       'camera': {'estimate_focal': True}})
    trajectory, images, _ = _drive('left')
    vo = VisualOdometry(config)
    results = [vo.process(image, float(t)) for t, image in zip(trajectory.stamps, images)]
    assert all(r.ok for r in results[1:])
    cal = vo.focal_calibrator
    assert cal.pairs + cal.pending >= 1                 # the turn was seen and queued
    assert all('focal' in r.timings for r in results[1:])
    cal.work(1000)                                      # finish the queue
    f, std, _ = cal.estimate()
    assert abs(f - 500.0) <= 3.0 * std
    if cal.adopted is not None:                         # adopted: precise and correct
        assert abs(cal.adopted - 500.0) <= 3.0 * cal.adopted_std
        assert vo.focal_status().endswith(f'(self-calibrated at frame {cal.adopted_at})')
    else:
        assert '(provisional' in vo.focal_status()
    # The provisional focal length keeps the turn's sign and rough size.
    yaw = float(np.rad2deg(yaw_of(results[-1].pose[:3, :3])))
    assert 40.0 < yaw < 80.0


def test_a_stated_field_of_view_is_where_the_focal_calibration_starts():
    # camera.nominal_fov (the camera's data sheet) centres the focal prior: until turning pairs
    # move it the odometry runs on width / (2 tan(fov / 2)) and the status names that field of
    # view. Stated right, the turn is measured through the right focal length from its start:
    # a smaller final yaw error than from the 53-degree default (640 px against 500).
    fov = 2.0 * math.atan(320.0 / 500.0)                # the rendered camera's: 640 px, f 500
    runs = {}
    for label, camera in (('stated', {'estimate_focal': True, 'nominal_fov': fov}),
                          ('default', {'estimate_focal': True})):
        config = PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}, 'camera': camera})
        trajectory, images, _ = _drive('left')
        vo = VisualOdometry(config)
        results = [vo.process(images[0], float(trajectory.stamps[0]))]
        if label == 'stated':
            assert vo.camera.fx == pytest.approx(500.0, rel=1e-12)
            assert vo.focal_status() == ('focal length 500.0 +- 284.2 px (provisional, no turn to '
                                         'calibrate from yet: the stated 65-degree field of '
                                         'view, 0 of 4 blocks)')
        else:
            assert vo.camera.fx == pytest.approx(640.0, rel=1e-12)
            assert '53-degree' in vo.focal_status()
        results += [vo.process(image, float(t))
                    for t, image in zip(trajectory.stamps[1:], images[1:])]
        assert all(r.ok for r in results[1:])
        runs[label] = _errors(trajectory, results)[1]
    assert runs['stated'] < 0.6 * runs['default'], runs


def test_a_second_pass_starts_from_the_first_passes_focal_calibration():
    # `replay --two-pass`: the first pass's calibration, finished (every queued pair
    # profiled), is the second pass's from its first frame: its focal length, no pair added
    # (the same frames' pairs would count twice), the status says where it comes from.
    config = PlanarVoConfig.from_dict({'mount': {'height': HEIGHT},
                                       'camera': {'estimate_focal': True}})
    trajectory, images, _ = _drive('left')
    first = VisualOdometry(config)
    for t, image in zip(trajectory.stamps, images):
        first.process(image, float(t))
    cal = first.focal_calibrator
    second = VisualOdometry(config)
    with pytest.raises(ConfigError, match='whose first pass is finished'):
        second.start_from_first_pass(cal)
    cal.finish_first_pass()
    assert cal.pending == 0 and cal.first_pass and cal.pairs >= 1
    f, pairs, status = cal.provisional, cal.pairs, cal.status()
    assert status.endswith('; from a first pass over the whole recording)')
    with pytest.raises(ConfigError, match='camera.estimate_focal: expected true'):
        VisualOdometry(PlanarVoConfig()).start_from_first_pass(cal)
    second.start_from_first_pass(cal)
    results = [second.process(images[0], float(trajectory.stamps[0]))]
    assert second.camera.fx == f
    with pytest.raises(InputError, match='expected no frame processed yet, got 1'):
        second.start_from_first_pass(cal)
    results += [second.process(image, float(t))
                for t, image in zip(trajectory.stamps[1:], images[1:])]
    assert all(r.ok for r in results[1:])
    assert second.camera.fx == f and cal.pairs == pairs and second.focal_status() == status
    assert cal.offer(0, np.zeros((99, 2)), np.zeros((99, 2)), np.zeros((99, 2, 2))) is False
    assert cal.work(10.0) == 0


def test_a_focal_calibration_carries_over_to_the_next_drive():
    """A self-calibrated focal length as the settings of the camera's next drive
    (``camera.nominal_fov`` and its standard deviation, `focal_carry`): the next drive starts
    at the same focal length with the same uncertainty (a straight drive cannot calibrate
    it). Nothing before any turning pair."""
    config = PlanarVoConfig.from_dict({'mount': {'height': HEIGHT},
                                       'camera': {'estimate_focal': True}})
    trajectory, images, _ = _drive('left')
    first = VisualOdometry(config)
    assert first.focal_carry() == {}
    first.process(images[0], float(trajectory.stamps[0]))
    assert first.focal_carry() == {}                       # no turning pair yet
    for t, image in zip(trajectory.stamps[1:], images[1:]):
        first.process(image, float(t))
    cal = first.focal_calibrator
    carry = first.focal_carry()
    assert set(carry) == {'camera.nominal_fov', 'camera.nominal_fov_std'}, carry
    f, rel = cal.provisional, cal.relative_std
    assert carry['camera.nominal_fov'] == pytest.approx(2 * math.atan(320.0 / f), abs=1e-4)
    assert carry['camera.nominal_fov_std'] == pytest.approx(
        math.log1p(rel) * math.sin(carry['camera.nominal_fov']), abs=1e-4)
    assert VisualOdometry(PlanarVoConfig()).focal_carry() == {}        # not self-calibrating
    # The next drive (straight: nothing to calibrate from) runs on it, as uncertain.
    nxt = VisualOdometry(PlanarVoConfig.from_dict({
        'mount': {'height': HEIGHT},
        'camera': {'estimate_focal': True, **{k.split('.')[1]: v for k, v in carry.items()}}}))
    straight, images2, _ = _drive('straight')
    for t, image in zip(straight.stamps[:5], images2[:5]):
        nxt.process(image, float(t))
    again = nxt.focal_calibrator
    assert again.provisional == pytest.approx(f, rel=2e-4)
    assert again.relative_std == pytest.approx(rel, rel=2e-3)


def test_a_new_focal_length_carries_the_tilt_and_road_normal_measured_through_the_old_one(
        monkeypatch):
    # Uncalibrated, a pitched and rolled mount: every change of the provisional focal length
    # carries the levelling, the mount tilt, the road normal and the estimator's history
    # (measured in the image through the old focal length) to the new one, with the ratio of
    # the old to the new focal length.
    pitch, roll = np.deg2rad(4.0), np.deg2rad(1.5)
    config = PlanarVoConfig.from_dict({'mount': {'height': HEIGHT},
                                       'camera': {'estimate_focal': True}})
    trajectory, images, _ = _drive('left', pitch, roll)
    vo = VisualOdometry(config)
    calls = []
    refocus = vo._refocus

    def spy(ratio):
        calls.append((ratio, vo._in_use.fx, vo.focal_calibrator.provisional))
        refocus(ratio)

    monkeypatch.setattr(vo, '_refocus', spy)
    for t, image in zip(trajectory.stamps, images):
        vo.process(image, float(t))
    assert calls and vo.camera.fx != 640.0
    for ratio, old, new in calls:
        assert ratio == pytest.approx(old / new, rel=1e-12) and ratio != 1.0
    level, tilt, road = vo._level, vo.tilt_estimate, vo._road.latest
    assert vo._level_estimated and level[0] == tilt.pitch
    motion = vo._estimator._motions[-1].copy()
    refocus(1.25)
    assert vo._level == (focal_pitch(level[0], 1.25), level[1])
    np.testing.assert_array_equal(vo._estimator.R_lc, leveling_rotation(*vo._level))
    assert vo.tilt_estimate.pitch == focal_pitch(tilt.pitch, 1.25)
    assert vo._road.latest.pitch == focal_pitch(road.pitch, 1.25)
    assert vo.road_normal[:2] == (vo._road.latest.pitch, road.roll)
    c = motion[3:] * [1.25, 1.25, 1.0]
    np.testing.assert_allclose(vo._estimator._motions[-1],
                               np.concatenate([motion[:3] * [1.25, 1.25, 1.0],
                                               c / np.linalg.norm(c)]), rtol=1e-12)
    # A configured mount pitch is an angle, not an image measurement: it stays.
    fixed = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT, 'pitch': 0.05},
                                                    'camera': {'estimate_focal': True}}))
    fixed._refocus(1.25)
    assert fixed._level == (0.05, 0.0) and not fixed._level_estimated


@pytest.mark.parametrize('name', ['left', 'stop_and_go'])
def test_a_self_calibrating_odometry_reports_an_honest_covariance(name):
    # No intrinsics: the odometry runs on the wide prior (640 px, truth 500) until the turn,
    # then on the calibration; the focal length's error is shared by every step and the
    # covariance says so: every pose's position (2D Mahalanobis) and yaw within 3.5 of it.
    # As independent step noise it was 94-366 (a review).
    config = PlanarVoConfig.from_dict({'mount': {'height': HEIGHT},
                                       'camera': {'estimate_focal': True}})
    trajectory, images, _ = _drive(name)
    vo = VisualOdometry(config)
    results = [vo.process(image, float(t)) for t, image in zip(trajectory.stamps, images)]
    origin = invert(trajectory.poses[0])
    position, yaw = [], []
    for k, r in enumerate(results):
        if not r.ok:
            continue
        truth = origin @ trajectory.poses[k]
        d = r.pose[:2, 3] - truth[:2, 3]
        position.append(math.sqrt(d @ np.linalg.solve(r.pose_covariance[:2, :2], d)))
        e = math.remainder(yaw_of(r.pose[:3, :3]) - yaw_of(truth[:3, :3]), 2 * math.pi)
        yaw.append(abs(e) / math.sqrt(r.pose_covariance[5, 5]))
    assert len(position) >= 0.9 * len(results)
    assert max(position) < 3.5 and max(yaw) < 3.5, (max(position), max(yaw))


def test_the_focal_sums_follow_stationary_frames_and_extrapolated_gaps():
    # Standing, the pose is the keyframe's, and so are the focal sums; across a gap in
    # tracking the extrapolated step was measured through the focal length too (its lever arm,
    # its road length and its offsets join the sums, `_focal_sums`).
    from planar_vo.core.conventions import so3_log
    from planar_vo.pipeline.odometry import _focal_sums

    config = PlanarVoConfig.from_dict({'mount': {'height': HEIGHT},
                                       'camera': {'estimate_focal': True}})
    trajectory, images, _ = _drive('stop_and_go')
    vo = VisualOdometry(config)
    standing = 0
    vo.process(images[0], float(trajectory.stamps[0]))          # the chain's first keyframe
    for t, image in zip(trajectory.stamps[1:], images[1:]):
        vo._focal_sums = vo._focal_sums + 1.0      # stale: every frame must set them anew
        r = vo.process(image, float(t))
        assert r.ok
        if r.scale_source == 'stationary':
            standing += 1
            assert np.array_equal(vo._focal_sums, vo._keyframes.current.focal_sums)
    assert standing >= 5
    before, pose = vo._focal_sums.copy(), vo.camera_pose.copy()
    vo._twist = np.array([6.0, 0.0, 0.0, 0.0, 0.0, 0.1])   # base frame: forward, turning left
    vo._extrapolate(vo._last_out[0] + 0.5)
    C = pose[:3, :3]
    expected = _focal_sums(before, C, so3_log(C.T @ vo.camera_pose[:3, :3]),
                           vo.camera_pose[:3, 3] - pose[:3, 3], vo.camera.fx, True)
    np.testing.assert_array_equal(vo._focal_sums, expected)
    assert np.abs(vo._focal_sums[4] - before[4]).max() > 1.0       # 3 m of road length


def test_after_camera_info_the_covariance_keeps_the_error_of_the_steps_before_it():
    # Self-calibrating on the 'left' drive, then a camera model arrives (CameraInfo mid-run):
    # the steps measured through the provisional focal lengths keep their error, now known
    # exactly (`_focal_error` at the camera's focal length), as the whole of the focal term,
    # and the published yaw variance covers it (with the known part dropped it fell to the
    # steps' noise, a surviving mutation of the last review).
    from planar_vo.pipeline.odometry import _focal_error

    config = PlanarVoConfig.from_dict({'mount': {'height': HEIGHT},
                                       'camera': {'estimate_focal': True}})
    trajectory, images, _ = _drive('left')
    vo = VisualOdometry(config)
    for k, (t, image) in enumerate(zip(trajectory.stamps, images)):
        r = vo.process(image, float(t), CAMERA if k >= 25 else None)
        assert r.ok or k == 0
    known, _ = _focal_error(vo._focal_sums, CAMERA.fx)
    # World frame = the first camera's: the yaw the prior got wrong is about its y axis.
    assert abs(known[1]) > np.deg2rad(3.0)
    C = vo.camera_pose[:3, :3]
    body = np.concatenate([C.T @ known[:3], C.T @ known[3:]])
    np.testing.assert_allclose(vo._focal_covariance(), np.outer(body, body), rtol=1e-12,
                               atol=1e-15)
    yaw_truth = yaw_of((invert(trajectory.poses[0]) @ trajectory.poses[-1])[:3, :3])
    yaw_error = abs(math.remainder(yaw_of(r.pose[:3, :3]) - yaw_truth, 2 * math.pi))
    assert r.pose_covariance[5, 5] >= 0.9 * known[1] ** 2      # up to the camera's tilt
    assert yaw_error < 3.0 * math.sqrt(r.pose_covariance[5, 5]), yaw_error


def test_a_self_calibrating_odometry_goes_on_after_an_image_of_another_size():
    # A single frame of another size is dropped, as with a camera model, and the next frames
    # of the first size track on (before, every later frame was a pipeline error: the keyframe
    # of the other size; then each size change restarted the calibration and the chain).
    config = PlanarVoConfig.from_dict({'mount': {'height': HEIGHT},
                                       'camera': {'estimate_focal': True}})
    trajectory, images, _ = _drive('left')
    vo = VisualOdometry(config)
    results = []
    for k, (t, image) in enumerate(zip(trajectory.stamps, images)):
        if k == 15:
            image = cv2.resize(image, (320, 240), interpolation=cv2.INTER_AREA)
        results.append(vo.process(image, float(t)))
    assert results[14].ok and results[15].reason is DropReason.SIZE_CHANGED
    assert all(r.ok for r in results[16:])
    assert np.isfinite(results[-1].pose_covariance).all()


def test_a_second_pass_hands_each_image_size_its_first_pass_calibration():
    # Two frames of another size in a row mid-drive: the first pass ends with a calibration
    # per size; the second pass uses each for its own images and adds no pair to either.
    config = PlanarVoConfig.from_dict({'mount': {'height': HEIGHT},
                                       'camera': {'estimate_focal': True}})
    trajectory, images, _ = _drive('left')
    frames = [cv2.resize(image, (320, 240), interpolation=cv2.INTER_AREA) if k in (20, 21)
              else image for k, image in enumerate(images)]
    first = VisualOdometry(config)
    for t, image in zip(trajectory.stamps, frames):
        first.process(image, float(t))
    calibrations = first.focal_calibrations
    assert [(c.width, c.height) for c in calibrations] == [(320, 240), (640, 480)]
    for cal in calibrations:
        cal.finish_first_pass()
    pairs = [c.pairs for c in calibrations]
    second = VisualOdometry(config)
    second.start_from_first_pass(*calibrations)
    used = []
    for t, image in zip(trajectory.stamps, frames):
        second.process(image, float(t))
        used.append(second.focal_calibrator)
    assert used[0] is calibrations[1] and used[21] is calibrations[0]
    assert used[-1] is calibrations[1]
    assert [c.pairs for c in calibrations] == pairs


def test_images_of_a_size_seen_before_resume_its_focal_calibration():
    # Two frames of another size in a row are a new resolution (its own calibration); when
    # the first size comes back, its calibration goes on where it was (a user test: it began
    # again, and the drive's turn was lost to it and to a --two-pass replay).
    config = PlanarVoConfig.from_dict({'mount': {'height': HEIGHT},
                                       'camera': {'estimate_focal': True}})
    trajectory, images, _ = _drive('left')
    vo = VisualOdometry(config)
    before = None
    for k, (t, image) in enumerate(zip(trajectory.stamps, images)):
        if k == 20:
            before = (vo.focal_calibrator, vo.focal_calibrator.pairs + vo.focal_calibrator.pending)
        if k in (20, 21):
            image = cv2.resize(image, (320, 240), interpolation=cv2.INTER_AREA)
        vo.process(image, float(t))
        if k == 21:
            assert (vo.focal_calibrator.width, vo.focal_calibrator.height) == (320, 240)
    cal, seen = before
    assert seen >= 1                                    # the turn had begun to calibrate it
    assert vo.focal_calibrator is cal and cal.pairs + cal.pending >= seen
    assert [(c.width, c.height) for c in vo.focal_calibrations] == [(320, 240), (640, 480)]


def test_focal_status_names_the_source():
    trajectory, images, _ = _drive('straight')
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}}))
    assert vo.focal_status() == 'focal length unknown (no frame with camera intrinsics yet)'
    vo.process(images[0], float(trajectory.stamps[0]), CAMERA)
    assert vo.focal_status() == f'focal length {CAMERA.fx:.1f} px (CameraInfo)'
    configured = VisualOdometry(PlanarVoConfig.from_dict({'camera': {'fx': 480.0}}))
    configured.process(images[0], float(trajectory.stamps[0]))
    assert configured.focal_status() == 'focal length 480.0 px (configured)'
    # A camera model given to the constructor is configured too (a user test: 'CameraInfo').
    given = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}}), CAMERA)
    given.process(images[0], float(trajectory.stamps[0]))
    assert given.focal_status() == f'focal length {CAMERA.fx:.1f} px (configured)'
    assert given.focal_length() == (CAMERA.fx, 0.0, 'configured')
    # A camera model of another size than the images is named, and why it is not used (a user
    # test: 'CameraInfo' was named while every frame was dropped for it).
    other = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}}))
    small = CameraModel(320, 240, np.diag([250.0, 250.0, 1.0]) + np.array(
        [[0, 0, 159.5], [0, 0, 119.5], [0, 0, 0]]))
    assert other.process(images[0], float(trajectory.stamps[0]), small).reason is \
        DropReason.NO_CAMERA_INFO
    assert other.focal_status() == ('focal length 250.0 px (CameraInfo, not used: it is 320x240, '
                                    'the images 640x480)')
    # ... and the status values' source is 'unknown' then (a user test: 'camera_info', 250 px)
    px, std, source = other.focal_length()
    assert math.isnan(px) and std == math.inf and source == 'unknown'
    assert other.process(images[1], float(trajectory.stamps[1]), CAMERA).reason is \
        DropReason.FIRST_FRAME
    assert other.focal_status() == f'focal length {CAMERA.fx:.1f} px (CameraInfo)'
    assert other.focal_length() == (CAMERA.fx, 0.0, 'camera_info')


# ---------------------------------------------------------------------------------------------
# Every frame yields an update or a counted reason
# ---------------------------------------------------------------------------------------------

def test_bad_frames_are_counted_and_do_not_stop_the_odometry():
    trajectory, images, _ = _drive('straight')
    stamps = trajectory.stamps
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}}), CAMERA)
    expect = []

    def feed(image, stamp, reason, camera=None):
        result = vo.process(image, stamp, camera)
        expect.append(reason)
        assert (result.reason is reason) if reason else result.ok, (result.reason,
                                                                    result.message)
        return result

    feed(images[0], stamps[0], DropReason.FIRST_FRAME)
    feed(images[1], stamps[1], None)
    feed(images[2], stamps[1], DropReason.DUPLICATE_STAMP)
    feed(images[2], stamps[0], DropReason.OUT_OF_ORDER)
    feed(np.zeros((480, 640), np.uint8), stamps[2], DropReason.BLANK_IMAGE)
    feed(np.full((480, 640), 255, np.uint8), stamps[3], DropReason.BLANK_IMAGE)
    feed(np.zeros((480, 640), np.float32), stamps[4], DropReason.BAD_IMAGE)
    # A bad image does not take its stamp: a good one sent with it is odometry, not a
    # duplicate_stamp.
    feed(images[4], stamps[4], None)
    feed('not an image', stamps[5], DropReason.BAD_IMAGE)
    feed(images[6][:240, :320], stamps[6], DropReason.SIZE_CHANGED)
    feed(images[7], float('nan'), DropReason.BAD_STAMP)
    # Stamps that are not numbers and a camera that is not a model: counted drops, no raise.
    for stamp in (None, 'abc', np.array([1.0, 2.0]), 1j):
        result = feed(images[7], stamp, DropReason.BAD_STAMP)
        assert 'is not a finite number' in result.message and '\n' not in result.message
    result = feed(images[7], stamps[7], DropReason.NO_CAMERA_INFO, camera='x')
    assert result.message == 'camera: expected a CameraModel or None, got str'
    good = feed(images[8], stamps[8], None)                   # a gap of several frames
    for i in range(9, 12):
        good = feed(images[i], stamps[i], None)
    truth = invert(trajectory.poses[0]) @ trajectory.poses[11]
    assert np.linalg.norm(good.pose[:2, 3] - truth[:2, 3]) < 0.1
    assert sum(vo.counters.values()) == len(expect)
    assert vo.counters['ok'] == expect.count(None)
    assert vo.counters['blank_image'] == 2 and vo.counters['bad_image'] == 2
    assert vo.counters['bad_stamp'] == 5
    assert vo.counters['no_camera_info'] == 1


def test_stamps_1_ns_apart_are_different_frames_as_integer_nanoseconds():
    """At 1.7e9 s a float holds about 0.24 us: stamps 1 ns apart are the same float seconds.
    Given as `Stamp` s (integer nanoseconds, as ROS headers and bags have them) they are
    compared exactly; plain float seconds keep their meaning."""
    _, images, _ = _drive('straight')
    t0 = 1_700_000_000 * 10**9
    assert Stamp(t0 + 1) == t0 / 1e9 and Stamp(t0 + 1).ns == t0 + 1
    copied = pickle.loads(pickle.dumps(Stamp(t0 + 1)))
    assert (copied, copied.ns) == (t0 / 1e9, t0 + 1)
    config = PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}})
    vo = VisualOdometry(config, CAMERA)
    # (the last image is the third with one grey level changed: the same image again would be
    # a frozen camera's at the speed of a step over 1 ns)
    nudged = images[2].copy()
    nudged[0, 0] ^= 1
    results = [vo.process(image, Stamp(t0 + ns)) for image, ns in (
        (images[0], 0), (images[1], 1), (images[2], 1), (images[2], 0), (images[2], 2),
        (nudged, 3))]
    reasons = [r.reason for r in results]
    assert reasons[0] is DropReason.FIRST_FRAME
    assert reasons[1] is None and reasons[4] is None                  # odometry
    # The image has not moved 1 ns later: standing still, with a finite speed bound (a user
    # test: the float seconds' difference of 0 divided, a pipeline error).
    assert reasons[5] is None and results[5].scale_source == 'stationary', results[5].message
    assert np.all(results[5].twist == 0.0) and np.all(np.isfinite(results[5].twist_covariance))
    assert reasons[2:4] == [DropReason.DUPLICATE_STAMP, DropReason.OUT_OF_ORDER]
    # The messages name the stamps as the headers had them (a user test: a float's 9 decimals
    # showed noise, 1700000000.415493965 for .415494000).
    assert results[2].message == 'timestamp 1700000000.000000001 repeats the previous frame'
    assert results[3].message == ('timestamp 1700000000.000000000 is older than the previous '
                                  '1700000000.000000001')
    floats = VisualOdometry(config, CAMERA)
    floats.process(images[0], t0 / 1e9)
    duplicate = floats.process(images[1], (t0 + 1) / 1e9)
    assert duplicate.reason is DropReason.DUPLICATE_STAMP
    assert duplicate.message == 'timestamp 1700000000.000000 repeats the previous frame'
    # A driver that leaves the stamps at 0 (a user test: every frame said to repeat the last).
    zeros = VisualOdometry(config, CAMERA)
    zeros.process(images[0], Stamp(0))
    assert zeros.process(images[1], Stamp(0)).message == (
        'timestamp 0.000000000 repeats the previous frame (a stamp of 0: does the driver set '
        'the header stamps?)')


def test_a_frame_stamped_far_sooner_than_the_usual_interval_is_refused():
    """A user test: frame 6 stamped 1 ns after frame 5 of a 10 Hz drive was odometry with a
    speed of 1e9 m/s. Once the usual interval is known (3 intervals), a frame under a quarter
    of it after the last is a counted duplicate_stamp; the next frame is odometry again at a
    sane speed."""
    _, images, _ = _drive('straight')                 # 8 m/s, 10 Hz
    t0 = 1_700_000_000 * 10**9
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}}), CAMERA)
    for i in range(5):
        assert vo.process(images[i], Stamp(t0 + i * 100_000_000)).reason in (
            None, DropReason.FIRST_FRAME)
    close = vo.process(images[5], Stamp(t0 + 4 * 100_000_000 + 1))
    assert close.reason is DropReason.DUPLICATE_STAMP
    assert close.message == ('timestamp 1700000000.400000001 is 1e-06 ms after the previous '
                             'frame, under 5 ms and a quarter of the usual 100 ms: a '
                             'duplicated or mis-stamped frame')
    after = vo.process(images[5], Stamp(t0 + 5 * 100_000_000))
    assert after.ok and np.linalg.norm(after.twist[:3]) < 16.0
    # A camera switching from 1 Hz to 30 Hz loses no frame (a review: a quarter of the usual
    # interval alone refused 44 of the first 90).
    from planar_vo.pipeline.clock import FrameClock, StampCheck

    clock = FrameClock(10.0, 1.0)
    stamps = [float(i) for i in range(6)] + [5.0 + k / 30.0 for k in range(1, 91)]
    assert {clock.check(t) for t in stamps} == {StampCheck.OK}
    assert clock.check(stamps[-1] + 0.001) is StampCheck.TOO_CLOSE


def test_gap_counter_counts_lost_frames_not_glitches_or_a_new_rate():
    from planar_vo.pipeline.clock import GapCounter

    ms = 1_000_000
    gaps = GapCounter(10.0, 1.0)
    t0 = 1_700_000_000 * 10 ** 9
    stamps = [t0 + 100 * ms * i for i in (0, 1, 2, 5, 6)]           # frames 3 and 4 lost
    found = [gaps.note(t) for t in stamps]
    assert found[:3] == [None] * 3 and found[4] is None
    assert (found[3].missing, found[3].interval_ns, found[3].period_ns) == (2, 300 * ms, 100 * ms)
    assert (gaps.gaps, gaps.missing) == (1, 2)
    # A frame stamped far ahead in place of frame 7, then frame 8: no gap (it came).
    assert gaps.note(t0 + 10**13) is None and gaps.note(t0 + 800 * ms) is None
    # ... nor one stamped far behind in place of frame 9, then frame 10.
    assert gaps.note(t0 - 10**10) is None and gaps.note(t0 + 1000 * ms) is None
    assert (gaps.gaps, gaps.missing) == (1, 2)
    # The camera halves its rate: three gaps of one length are the new rate, off the counts.
    last = [gaps.note(t0 + 1000 * ms + 200 * ms * k) for k in (1, 2, 3)]
    assert [g.rate_change for g in last[:2]] == [None, None]
    assert last[2].rate_change is not None and round(last[2].rate_change.after_hz, 3) == 5.0
    assert (gaps.gaps, gaps.missing) == (1, 2)
    assert gaps.note(t0 + 1000 * ms + 200 * ms * 4) is None        # the new rate: no gap


def test_stamps_print_their_nanoseconds_with_their_sign():
    from planar_vo.pipeline.clock import format_stamp

    assert format_stamp(Stamp(1_700_000_000_415_494_000)) == '1700000000.415494000'
    # (a user test: -4.61 s printed as -5.389627000)
    assert format_stamp(Stamp(-4_610_373_000)) == '-4.610373000'
    assert format_stamp(Stamp(-1)) == '-0.000000001' and format_stamp(1.5) == '1.500000'


def test_frame_clock_needs_a_second_frame_to_jump_in_time():
    from planar_vo.pipeline.clock import FrameClock, StampCheck

    clock = FrameClock(10.0, 1.0)
    verdicts = [clock.check(t) for t in (100.0, 100.1, 100.2, 0.0, 100.3, 50.0, 50.1, 50.2,
                                         50.25, 49.5, 1000.0, 50.3, 1000.0, 1000.1)]
    S = StampCheck
    assert verdicts == [S.OK, S.OK, S.OK, S.FAR_BEHIND, S.OK,        # one bad stamp: its own
                        S.FAR_BEHIND, S.JUMP_BACK, S.OK, S.OK,       # a loop: the next confirms
                        S.OUT_OF_ORDER, S.JUMP_AHEAD, S.OK, S.JUMP_AHEAD, S.NEW_TIME_BASE]
    assert clock.last == 1000.1
    # A far-back frame followed by one that does not follow it (earlier still) is refused too.
    verdicts = [clock.check(t) for t in (10.0, 5.0, 5.1)]
    assert verdicts == [S.FAR_BEHIND, S.FAR_BEHIND, S.JUMP_BACK]
    assert clock.jump == pytest.approx(5.0 - 1000.1)       # from the first refused frame
    # One pending stamp at a time (a review): a glitch far behind, one far ahead, then a frame
    # just after the first is no confirmation of either.
    verdicts = [clock.check(t) for t in (5.2, 1.0, 99.0, 1.1, 5.3)]
    assert verdicts == [S.OK, S.FAR_BEHIND, S.JUMP_AHEAD, S.FAR_BEHIND, S.OK]


def test_a_frame_stamped_early_among_the_first_is_not_said_to_follow_a_gap():
    """A user test: frame 10 of an evenly stamped 8 Hz stream, stamped before frame 9, was
    dropped with 'which came after a gap' (the first intervals are watched as gaps until the
    usual interval is known); after a real gap it still says so."""
    from planar_vo.pipeline.clock import FrameClock, StampCheck

    clock = FrameClock(10.0, 1.0)
    for i in range(10):
        assert clock.check(100.0 + 0.125 * i) is StampCheck.OK
    assert clock.check(100.0 + 0.125 * 10 - 0.16) is StampCheck.INSIDE_GAP
    assert clock.inside_start
    clock = FrameClock(10.0, 1.0)
    for t in [100.0 + 0.1 * i for i in range(15)] + [101.8]:      # a real gap before 101.8
        assert clock.check(t) is StampCheck.OK
    assert clock.check(101.6) is StampCheck.INSIDE_GAP and not clock.inside_start
    trajectory, images, _ = _drive('straight')
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}}))
    stamps = [Stamp(1_700_000_000_000_000_000 + 125_000_000 * i) for i in range(10)]
    for image, stamp in zip(images, stamps):
        vo.process(image, stamp, CAMERA)
    result = vo.process(images[10], Stamp(stamps[9].ns - 35_000_000), CAMERA)
    assert result.reason is DropReason.OUT_OF_ORDER
    assert result.message == ('timestamp 1700000001.090000000 is older than the previous '
                              '1700000001.125000000, one of the first frames, whose stamps are '
                              'not yet known to be even: if the next frame is older too, that '
                              'one was stamped ahead of its time')


def test_late_frames_of_a_gap_counted_as_the_receivers_take_it_off_both_counts():
    """A gap noted while the receiver was busy counts its frames as missing and 'behind'; the
    frames that come late into it take them off both (a review: 'behind' stayed)."""
    from planar_vo.pipeline.clock import GapCounter

    P = 100_000_000
    gaps = GapCounter(10.0, 1.0)
    for i in range(10):
        gaps.note(i * P)
    gaps.note(13 * P, busy=True)
    assert (gaps.gaps, gaps.missing, gaps.behind) == (1, 3, 3)
    gaps.note(11 * P)                                       # late, inside the gap
    assert (gaps.gaps, gaps.missing, gaps.behind) == (1, 2, 2)
    gaps.note(14 * P)
    gaps.note(17 * P)                                       # the camera's own gap
    assert (gaps.gaps, gaps.missing, gaps.behind) == (2, 4, 2)
    gaps.note(15 * P)
    assert (gaps.gaps, gaps.missing, gaps.behind) == (2, 3, 2)


def test_a_frame_stamped_ahead_within_the_max_gap_is_confirmed_mis_stamped():
    """A frame stamped 3 s ahead (under max_frame_gap) opens what looks like a gap; the first
    frame inside it is refused, the second confirms that the one before them was mis-stamped:
    the time goes on from them (not a looped bag), and the gap counter takes the gap back."""
    from planar_vo.pipeline.clock import FrameClock, GapCounter, StampCheck

    S = StampCheck
    clock = FrameClock(10.0, 1.0)
    verdicts = [clock.check(t) for t in (100.0, 100.1, 100.2, 100.3, 103.4, 100.5, 100.6)]
    assert verdicts == [S.OK] * 5 + [S.INSIDE_GAP, S.REWOUND]
    assert clock.mis_stamped == (103.4, pytest.approx(3.0))   # ahead of the slot it left
    assert clock.last == 103.4                      # a proposal: the caller accepts it ...
    clock.rewind()
    assert clock.check(100.7) is S.OK
    assert clock.last == 100.7 and clock.usual_interval == pytest.approx(0.1)
    # ... or not: frames delivered late into a real gap stay refused, and the stream goes on.
    verdicts = [clock.check(t) for t in (101.5, 101.0, 101.1, 101.2, 101.6)]
    assert verdicts == [S.OK, S.INSIDE_GAP, S.REWOUND, S.REWOUND, S.OK]
    with pytest.raises(RuntimeError, match='no StampCheck.REWOUND to accept'):
        clock.rewind()
    ms, t0 = 1_000_000, 1_700_000_000 * 10 ** 9
    gaps = GapCounter(10.0, 1.0)
    for i in (0, 1, 2, 3, 34, 5, 6, 7):             # frame 4 stamped 3 s ahead
        gaps.note(t0 + 100 * ms * i)
    assert (gaps.gaps, gaps.missing) == (1, 26)     # the frames inside its gap fill it ...
    for i in list(range(8, 34)) + [35]:
        gaps.note(t0 + 100 * ms * i)
    assert (gaps.gaps, gaps.missing) == (0, 0)      # ... as they come
    for i in (36, 37, 39, 38, 40):                  # frame 38 delivered after frame 39
        gaps.note(t0 + 100 * ms * i)
    assert (gaps.gaps, gaps.missing) == (0, 0)
    for i in (41, 47, 42, 43, 44, 45, 46, 48):      # frames 42-46 late: all came
        gaps.note(t0 + 100 * ms * i)
    assert (gaps.gaps, gaps.missing) == (0, 0)
    for i in [57, 58] + list(range(51, 60)) + [60]:  # frames 49, 50 stamped 0.8 s ahead
        gaps.note(t0 + 100 * ms * i)
    assert (gaps.gaps, gaps.missing) == (0, 0)
    assert gaps.note(t0 + 100 * ms * 62).missing == 1      # ... and a real gap still counts
    assert (gaps.gaps, gaps.missing) == (1, 1)
    for i in (63, 63, 65):                          # frame 64 came stamped as frame 63
        gaps.note(t0 + 100 * ms * i)
    assert (gaps.gaps, gaps.missing) == (1, 1)
    # A real gap (frames 71-73 lost) with frames 74-76 delivered late: the lost ones count
    # (a user test: the late frames took the whole gap off the counts; about: the first
    # frame after the gap may fill one of its slots).
    before = (gaps.gaps, gaps.missing)
    for i in (66, 67, 68, 69, 70, 77, 74, 75, 76, 78, 79):
        gaps.note(t0 + 100 * ms * i)
    assert gaps.gaps == before[0] + 1 and 2 <= gaps.missing - before[1] <= 3
    # A late frame inside the first gap of a frame-rate change (a review: the change then took
    # the gap's whole first count off, and missing went negative).
    gaps = GapCounter(10.0, 1.0)
    for t in [100 * i for i in range(11)] + [1300, 1150, 1600, 1900, 2200]:
        gaps.note(t0 + t * ms)
        assert gaps.missing >= 0 and gaps.gaps >= 0


@pytest.mark.parametrize('late', [1, 5])
def test_frames_delivered_late_into_a_real_gap_are_refused(late):
    """A review: frames 10-14 delivered after the correctly stamped frame 15 made it look
    mis-stamped; the rewind put its speed 12 times too high and the pose 17 m ahead for good.
    Its step over its own stamp fits the speed before it: the late frames are refused."""
    trajectory, images, _ = _drive('straight')
    stamps = [float(s) for s in trajectory.stamps]
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}}), CAMERA)
    order = list(range(10)) + [15] + list(range(10, 10 + late)) + list(range(16, 21))
    results = {i: vo.process(images[i], stamps[i]) for i in order}
    assert all(results[i].reason is DropReason.OUT_OF_ORDER for i in range(10, 10 + late))
    assert all(results[i].ok for i in order[1:] if not 10 <= i < 15), [
        (i, results[i].reason) for i in order]
    assert abs(results[20].pose[0, 3] - (trajectory.xy[20, 0] - trajectory.xy[0, 0])) < 0.1
    assert abs(results[20].twist[0] - 8.0) < 0.3


def test_a_mis_stamp_is_found_through_blank_frames_in_a_spin_and_mixed_glitches():
    """Reviews: blank frames after a mis-stamped one shrank the rewind by half a frame each
    (4.6 m off at 20 standard deviations); a turn on the spot moves the camera sideways, and
    the direction of travel did not tell; a proposing frame stamped ahead itself became the
    time base and the frames after it were refused."""
    trajectory, images, _ = _drive('straight')
    stamps = [float(s) for s in trajectory.stamps]
    blank = np.zeros_like(images[0])
    for ahead, frames in (({6: 0.8}, {8: blank, 9: blank, 10: blank}), ({6: 0.8, 8: 0.3}, {})):
        vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}}), CAMERA)
        results = [vo.process(frames.get(i, images[i]), stamps[i] + ahead.get(i, 0.0))
                   for i in range(24)]
        truth = trajectory.xy[23, 0] - trajectory.xy[0, 0]
        assert abs(results[23].pose[0, 3] - truth) < 0.1, (ahead, results[23].pose[0, 3])
        assert abs(results[23].twist[0] - 8.0) < 0.3
    # A turn on the spot, the camera 1.5 m ahead of base_link: frame 10 stamped 0.8 s ahead.
    spin = Trajectory.from_poses(np.arange(41) / 10.0, np.array(
        [planar_pose(0.0, 0.0, 0.05 * k) for k in range(41)]))
    world = StreetWorld.along(straight(10.0, speed=8.0), seed=3)
    images = [f.image for f in render_drive(spin, world, CAMERA,
                                            mount_transform(x=1.5, height=HEIGHT))]
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT, 'x': 1.5}}),
                        CAMERA)
    results = [vo.process(image, k / 10.0 + (0.8 if k == 10 else 0.0))
               for k, image in enumerate(images)]
    assert [k for k, r in enumerate(results[1:], 1) if not r.ok] == [11]
    assert abs(yaw_of(results[40].pose[:3, :3]) - 2.0) < math.radians(0.5)


def test_two_glitches_close_together_are_both_found():
    """A review: frames 6 and 8 each stamped 0.8 s ahead (7 refused between them): the second
    replaced the gap being watched, every frame up to the wrong stamps was lost and the pose
    ended 6.4 m off at 74 standard deviations."""
    trajectory, images, _ = _drive('straight')
    stamps = [float(s) for s in trajectory.stamps]
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}}), CAMERA)
    results = [vo.process(images[i], stamps[i] + (0.8 if i in (6, 8) else 0.0))
               for i in range(20)]
    dropped = [i for i, r in enumerate(results[1:], 1) if not r.ok]
    assert len(dropped) <= 3, [(i, results[i].reason) for i in dropped]
    truth = trajectory.xy[19, 0] - trajectory.xy[0, 0]
    assert abs(results[19].pose[0, 3] - truth) < 0.1
    assert abs(results[19].twist[0] - 8.0) < 0.3


def test_late_frames_of_a_car_stopping_in_the_gap_are_not_a_mis_stamp():
    """A review: frames delivered late into a real gap while the car braked to a stop in it
    were taken for a mis-stamp by the speeds' fit: the stamps went back and the pose became
    uncertain by metres. The late frames lie behind the last one, opposite to the travel."""
    trajectory, images, _ = _drive('stop_and_go')
    stamps = [float(s) for s in trajectory.stamps]
    speed = np.hypot(*np.diff(trajectory.xy, axis=0).T) / np.diff(trajectory.stamps)
    stop = int(np.flatnonzero(speed < 0.05)[0])               # the first standing interval
    gap = list(range(stop - 4, stop + 1))                      # braking: delivered late
    order = [i for i in range(stop + 12) if i not in gap]
    order = order[:order.index(stop + 1) + 1] + gap + order[order.index(stop + 1) + 1:]
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}}), CAMERA)
    results = {i: vo.process(images[i], stamps[i]) for i in order}
    assert all(results[i].reason is DropReason.OUT_OF_ORDER for i in gap), [
        (i, results[i].reason, results[i].message) for i in gap]
    last = order[-1]
    assert all(results[i].ok for i in order[1:] if i not in gap), [
        (i, results[i].reason) for i in order if not results[i].ok]
    truth = np.linalg.norm(trajectory.xy[last] - trajectory.xy[0])
    assert abs(results[last].pose[0, 3] - truth) < 0.2
    assert math.sqrt(results[last].pose_covariance[0, 0]) < 0.5


@pytest.mark.parametrize('source', ['speed', 'fixed'])
def test_a_mis_stamped_frame_with_a_time_based_scale_is_not_rewound(source):
    """A review: with the step length from a speed (a topic, a fixed speed), the mis-stamped
    frame's step is as long as its wrong interval, and rewinding to its pose left the odometry
    6.5 m ahead for good. Without the rewind the frames inside its gap are refused and the
    next step's interval makes up for it."""
    trajectory, images, twists = _drive('straight')
    stamps = [float(s) for s in trajectory.stamps]
    scale = {'source': 'fixed', 'fixed_speed': 8.0} if source == 'fixed' else {'source': 'speed'}
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}, 'scale': scale}),
                        CAMERA)
    results = []
    for i in range(20):
        stamp = stamps[i] + (0.8 if i == 6 else 0.0)
        if source == 'speed':
            vo.add_speed(stamps[i], float(np.hypot(*twists[i, :2])))
        results.append(vo.process(images[i], stamp))
    assert vo.counters.get('reinitialised', 0) == 0
    assert abs(results[19].pose[0, 3] - (trajectory.xy[19, 0] - trajectory.xy[0, 0])) < 0.3


@pytest.mark.parametrize('ahead, frames', [(0.8, (6,)), (3.0, (6,)), (0.8, (6, 7)),
                                           (0.8, (3,)), (0.8, (1,)), (0.8, (6, 7, 8, 9)),
                                           (0.3, (6, 7)), (0.3, (6, 7, 8))])
def test_frames_stamped_ahead_cost_one_frame_not_the_drive(ahead, frames):
    """A user test: a frame stamped 0.8 s ahead refused the 7 frames after it as older, one 3 s
    ahead (under odometry.max_frame_gap) made the next ones a looped bag and reset the pose to
    the origin; two in a row (a clock stepped forward and back) lost 10 frames and left the
    pose 9 m short at 7 standard deviations; early in the drive (frame 3) the clock did not
    know the usual interval yet. Now the first frame after them is refused, the second moves
    their stamps back and tracking goes on."""
    trajectory, images, _ = _drive('straight')
    stamps = [float(s) for s in trajectory.stamps]
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}}), CAMERA)
    results = [vo.process(images[i], stamps[i] + (ahead if i in frames else 0.0))
               for i in range(16)]
    inside = frames[-1] + 1
    # The same drive without the refused frame, stamped right:
    clean = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}}), CAMERA)
    clean = {i: clean.process(images[i], stamps[i]) for i in range(16) if i != inside}
    reasons = [r.reason for r in results]
    assert reasons[inside] is DropReason.OUT_OF_ORDER and 'stamped ahead' in \
        results[inside].message
    assert all(r.ok for i, r in enumerate(results[1:], 1) if i != inside), reasons
    assert vo.counters.get('time_jump_back', 0) == 0
    for i in (inside + 1, 15):
        true_x = trajectory.xy[i, 0] - trajectory.xy[0, 0]
        assert abs(results[i].pose[0, 3] - true_x) < 0.1, (i, results[i].pose[0, 3])
        # ... as the same frames give without the glitch (to the twist's share in the pose)
        assert abs(results[i].pose[0, 3] - clean[i].pose[0, 3]) < 0.01
        np.testing.assert_allclose(np.diag(results[i].pose_covariance),
                                   np.diag(clean[i].pose_covariance), rtol=0.1)
    assert abs(results[inside + 1].twist[0] - 8.0) < 0.5
    assert abs(results[15].twist[0] - 8.0) < 0.3


def test_undecodable_frames_count_towards_lost_tracking():
    """As blank ones do (a user test: after five undecodable frames the stale keyframe cost five
    good frames more): odometry.max_lost_frames of them in a row, and the next good frame
    starts a new keyframe chain; one with an old stamp does not count."""
    _, images, _ = _drive('straight')
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}}), CAMERA)
    for i in range(3):
        vo.process(images[i], 0.1 * i)
    bad = np.zeros((480, 640), np.float32)
    assert vo.process(bad, 0.05).reason is DropReason.BAD_IMAGE       # old stamp: not lost
    assert vo.tracking.value == 'tracking'
    for i in range(3, 8):
        result = vo.process(bad, 0.1 * i)
        assert result.reason is DropReason.BAD_IMAGE and vo.tracking.value == 'lost'
    assert 'tracking lost: the next usable frame starts a new keyframe chain' in result.message
    assert vo.process(images[8], 0.8).reason is DropReason.REINITIALISED
    assert vo.process(images[9], 0.9).ok


def test_a_dim_keyframe_that_nothing_matches_falls_back_to_the_one_before():
    """A user test: one dim frame (an exposure glitch) matched the keyframe before it and
    became the keyframe, offered no texture to the next frames, and cost six frames and a new
    chain. After two misses tracking goes back to the keyframe before it, and the pose stays
    on the drive."""
    trajectory, images, _ = _drive('straight')
    truth = invert(trajectory.poses[0]) @ trajectory.poses[13]
    # With the rotation window too (a review: it kept the dropped keyframe).
    for lags in (1, 3):
        config = PlanarVoConfig.from_dict({'mount': {'height': HEIGHT},
                                           'odometry': {'window_lags': lags}})
        vo = VisualOdometry(config, CAMERA)
        results = [vo.process(images[i] // 16 if i == 6 else images[i], 0.1 * i)
                   for i in range(14)]
        assert results[6].ok and results[6].keyframe             # the dim frame: a keyframe
        assert [r.reason for r in results[7:9]] == [DropReason.TOO_FEW_CORRESPONDENCES] * 2
        assert results[8].message.endswith('; the newest keyframe, far dimmer than the one '
                                           'before it, matched nothing: tracking goes on '
                                           'against the one before it')
        assert all(r.ok for r in results[9:]), lags
        assert np.linalg.norm(results[13].pose[:2, 3] - truth[:2, 3]) < 0.1, lags


def test_focal_calibration_blocks_stay_about_a_second_long_at_any_frame_rate():
    """A user test: the same frames as a 30 fps video made blocks of a third of a second, whose
    shared errors counted as independent: 2.5 % stated where 10 Hz stated 9.8 %. A block is
    camera.focal_block_frames frames at 10 Hz, as many more at a faster rate."""
    _, images, _ = _drive('straight')
    config = PlanarVoConfig.from_dict({'mount': {'height': HEIGHT},
                                       'camera': {'estimate_focal': True}})
    for rate, stride in ((10.0, 1), (9.65, 1), (20.0, 2), (28.0, 3), (30.0, 3)):
        vo = VisualOdometry(config)
        for i in range(31):
            vo.process(images[i], i / rate)
        block = vo._focal_block()
        assert (vo._focal_stride, block) == (stride, 31 // (10 * stride)), rate


def test_the_scale_status_names_the_source_and_the_camera_height():
    def status(**scale):
        return VisualOdometry(PlanarVoConfig.from_dict(scale)).scale_status()

    pixels = ("; too few road ACs: the road's pixels (steps up to "
              "scale.ground_image_max_speed 70 m/s)")
    assert status(mount={'height': 1.65, 'height_std': 0.02}) == \
        'ground at the camera height 1.65 +- 0.02 m (mount.height)' + pixels + '; fallback hold'
    assert status() == ("ground at the camera height 1.5 +- 0.01 m (mount.height, the default: "
                        "set the car's)" + pixels + "; fallback hold")
    assert status(scale={'ground_image': False}) == (
        "ground at the camera height 1.5 +- 0.01 m (mount.height, the default: set the car's); "
        "fallback hold")
    assert status(scale={'source': 'speed', 'fallback': 'ground'}) == \
        'speed topic (+- 0.1 m/s); fallback ground' + pixels
    assert status(scale={'source': 'fixed', 'fixed_speed': 8.0}) == \
        'fixed speed 8 +- 3 m/s; fallback hold'
    assert status(scale={'source': 'unit'}) == 'none (unit steps: no metric scale)'


def test_no_camera_is_a_reason_not_an_error():
    trajectory, images, _ = _drive('straight')
    vo = VisualOdometry(PlanarVoConfig())
    result = vo.process(images[0], 0.0)
    assert not result.ok and result.reason is DropReason.NO_CAMERA_INFO
    result = vo.process(images[1], 0.1, CAMERA)              # camera info arrives
    assert result.reason is DropReason.FIRST_FRAME


def test_camera_from_configured_intrinsics():
    config = PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}, 'camera': {
        'fx': 500.0, 'fy': 500.0, 'cx': 319.5, 'cy': 239.5}})
    trajectory, images, _ = _drive('straight')
    vo = VisualOdometry(config)
    results = [vo.process(image, float(t)) for t, image in zip(trajectory.stamps[:10], images)]
    assert all(r.ok for r in results[1:])


@pytest.mark.parametrize('fx, fov', [(1.0, 180), (100000.0, 0.367)])
def test_implausible_configured_intrinsics_are_refused_like_a_camera_info(fx, fov):
    # (a user test: fx 1 px lost every frame as 'unreliable', 100000 px published NaN
    # covariances) The CameraInfo's checks: every frame a counted no_camera_info that says why.
    trajectory, images, _ = _drive('straight')
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT},
                                                  'camera': {'fx': fx}}))
    results = [vo.process(image, float(t)) for t, image in zip(trajectory.stamps[:3], images)]
    assert all(r.reason is DropReason.NO_CAMERA_INFO for r in results)
    assert results[0].message == (
        f'configured intrinsics (camera.fx, fy, cx, cy, distortion): horizontal field of view '
        f'{fov:g} deg (fx {fx:g}, fy {fx:g} px on '
        f'640x480) is outside the 3-160 deg of real rectilinear lenses: is the focal length in '
        f'pixels of this resolution? (no camera model)')
    assert vo.counters == {'no_camera_info': 3}


def test_a_real_fisheye_calibration_is_accepted_as_configured_intrinsics():
    # (a review: one grid pixel whose undistortion Jacobian was singular refused the whole
    # check: the TUM-VI camera, 512x512 equidistant, 154 deg)
    K = np.array([[190.98, 0.0, 254.93], [0.0, 190.98, 256.9], [0.0, 0.0, 1.0]])
    D = [0.00348, 0.000715, -0.00205, 0.000203]
    camera = CameraModel(512, 512, K, 'equidistant', D)
    camera.check_plausible()
    grid = np.stack(np.meshgrid(np.linspace(0, 511, 9), np.linspace(0, 511, 9)), -1)
    q, J = camera.pixel_to_normalized(grid.reshape(-1, 2))
    ok = np.isfinite(q).all(axis=1)
    assert 61 <= ok.sum() < 81 and np.isfinite(J[ok]).all() and np.isnan(J[~ok]).all()
    config = PlanarVoConfig.from_dict({'camera': {
        'fx': 190.98, 'cx': 254.93, 'cy': 256.9, 'distortion_model': 'equidistant',
        'distortion': D}})
    vo = VisualOdometry(config)
    first = vo.process(np.random.default_rng(1).integers(0, 255, (512, 512), np.uint8), 0.0)
    assert first.reason is DropReason.FIRST_FRAME, first.message


def test_wrong_types_for_the_odometry_are_config_errors():
    # (a user test: a dict config was an AttributeError)
    with pytest.raises(ConfigError, match=r'config: expected a PlanarVoConfig \(PlanarVoConfig'
                                          r'.from_dict builds one from a dict\), got dict'):
        VisualOdometry({'mount': {'height': -1}})
    with pytest.raises(ConfigError, match=r'camera: expected a CameraModel or None, got str'):
        VisualOdometry(None, 'camera')


def test_self_calibration_takes_no_camera_model(caplog):
    # (a user test: a camera model given with estimate_focal was used without a word)
    config = PlanarVoConfig.from_dict({'mount': {'height': HEIGHT},
                                       'camera': {'estimate_focal': True}})
    with pytest.raises(ConfigError, match=r'camera: expected None with camera.estimate_focal'):
        VisualOdometry(config, CAMERA)
    trajectory, images, _ = _drive('straight')
    vo = VisualOdometry(config)
    assert vo.focal_status() == ('focal length unknown (the self-calibration starts at the '
                                 'first image)')
    # A camera model that arrives later (a CameraInfo) replaces the calibration, said once.
    with caplog.at_level('WARNING', logger='planar_vo.pipeline.odometry'):
        for k, (t, image) in enumerate(zip(trajectory.stamps[:4], images)):
            vo.process(image, float(t), CAMERA if k >= 2 else None)
            assert vo.focal_length()[2] == ('provisional' if k < 2 else 'camera_info')
    warnings = [r.getMessage() for r in caplog.records if 'camera model' in r.getMessage()]
    assert warnings == ['a camera model arrived: it replaces the focal self-calibration '
                        '(camera.estimate_focal) from frame 2 on']


def test_a_camera_model_that_takes_over_carries_what_was_measured_and_must_fit(caplog):
    """A review: a CameraInfo arriving while self-calibrating left the levelling, the tilt and
    the road normal as seen through the provisional focal length (now carried to the model's,
    as every change of the provisional one is), and one of another resolution replaced a
    working calibration and refused every later frame (now refused itself, said once)."""
    config = PlanarVoConfig.from_dict({'mount': {'height': HEIGHT},
                                       'camera': {'estimate_focal': True}})
    trajectory, images, _ = _drive('straight')
    stamps = [float(t) for t in trajectory.stamps]
    vo = VisualOdometry(config)
    other = CameraModel.pinhole(1280, 960, 1000.0)
    with caplog.at_level('WARNING', logger='planar_vo.pipeline.odometry'):
        results = [vo.process(images[k], stamps[k], other if k >= 3 else None)
                   for k in range(6)]
    assert all(r.ok for r in results[1:]), [r.reason for r in results]
    assert vo.focal_length()[2] == 'provisional' and vo.focal_calibrator is not None
    warnings = [r.getMessage() for r in caplog.records if 'camera model' in r.getMessage()]
    assert warnings == ['a camera model of 1280x960 arrived for 640x480 images: the focal '
                        'self-calibration goes on until one of their size comes']
    # One stray image of the model's size does not let it take over (a review: it did, and
    # every later frame was refused as size_changed).
    stray = vo.process(cv2.resize(images[6], (1280, 960)), stamps[6], other)
    assert stray.reason is DropReason.SIZE_CHANGED and vo.focal_length()[2] == 'provisional'
    ratios = []
    refocus = vo._refocus
    vo._refocus = lambda ratio: (ratios.append(ratio), refocus(ratio))
    provisional = vo.camera.fx
    assert vo.process(images[7], stamps[7], CAMERA).ok
    assert ratios == [provisional / CAMERA.fx] and vo.focal_length() == (500.0, 0.0,
                                                                         'camera_info')
    assert vo.focal_calibrator is None
    assert vo.process(images[8], stamps[8], CAMERA).ok and len(ratios) == 1


def test_one_image_of_another_size_keeps_the_focal_self_calibration():
    """A review: self-calibrating, one stray frame of another size threw the calibration away
    (and the old size's return the next one). It is dropped as size_changed, as with a camera
    model; a second image of the new size in a row is a new resolution."""
    config = PlanarVoConfig.from_dict({'mount': {'height': HEIGHT},
                                       'camera': {'estimate_focal': True}})
    trajectory, images, _ = _drive('left')
    stamps = [float(t) for t in trajectory.stamps]
    vo = VisualOdometry(config)
    for k in range(30):
        vo.process(images[k], stamps[k])
    cal = vo.focal_calibrator
    cal.work(1000)
    pairs = cal.pairs
    assert pairs >= 1
    small = [cv2.resize(image, (320, 240), interpolation=cv2.INTER_AREA) for image in images]
    stray = vo.process(small[30], stamps[30])
    assert stray.reason is DropReason.SIZE_CHANGED
    assert stray.message == ('image is 320x240 but the camera model is 640x480 (self-calibrating: '
                             'a second image of this size in a row starts a new focal '
                             'self-calibration)')
    after = [vo.process(images[k], stamps[k]) for k in (31, 32)]
    assert all(r.ok for r in after), [(r.reason, r.message) for r in after]
    assert vo.focal_calibrator is cal and cal.pairs >= pairs
    # Two in a row: a new resolution, a new calibration and keyframe chain.
    assert vo.process(small[33], stamps[33]).reason is DropReason.SIZE_CHANGED
    second = vo.process(small[34], stamps[34])
    assert second.reason is DropReason.REINITIALISED, (second.reason, second.message)
    assert (vo.focal_calibrator.width, vo.focal_calibrator.height) == (320, 240)


def test_a_fisheye_field_of_view_gives_the_equidistant_focal_length():
    # r = f theta: 2.0 rad over 640 px is f = 320 px (a rectilinear lens: 205.5 px).
    trajectory, images, _ = _drive('straight')
    camera = {'estimate_focal': True, 'nominal_fov': 2.0, 'distortion_model': 'equidistant',
              'distortion': [0.0] * 4}
    vo = VisualOdometry(PlanarVoConfig.from_dict({'camera': camera}))
    vo.process(images[0], float(trajectory.stamps[0]))
    assert vo.camera.fx == pytest.approx(320.0, rel=1e-12)
    assert vo.camera.field_of_view[0] == pytest.approx(2.0, rel=1e-3)   # through (cx, cy)
    assert 'the stated 115-degree field of view' in vo.focal_status()
    # Unstated, the focal length is the image's larger side: 1 rad through a fisheye lens.
    unstated = {**camera, 'nominal_fov': 0.0}
    vo = VisualOdometry(PlanarVoConfig.from_dict({'camera': unstated}))
    vo.process(images[0], float(trajectory.stamps[0]))
    assert vo.camera.fx == pytest.approx(640.0)
    assert 'an assumed 57-degree field of view' in vo.focal_status()
    camera.update(distortion_model='none', distortion=[])
    vo = VisualOdometry(PlanarVoConfig.from_dict({'camera': camera}))
    vo.process(images[0], float(trajectory.stamps[0]))
    assert vo.camera.fx == pytest.approx(320.0 / math.tan(1.0), rel=1e-12)


def test_internal_error_is_a_counted_pipeline_error(monkeypatch):
    trajectory, images, _ = _drive('straight')
    vo = VisualOdometry(PlanarVoConfig(), CAMERA)
    vo.process(images[0], 0.0)

    def broken(*args, **kwargs):
        raise RuntimeError('simulated failure')

    monkeypatch.setattr(vo._extractor, 'extract', broken)
    result = vo.process(images[1], 0.1)
    assert result.reason is DropReason.PIPELINE_ERROR and 'simulated failure' in result.message
    monkeypatch.undo()
    assert vo.process(images[2], 0.2).ok


def _window_only(image: np.ndarray, size: int = 80) -> np.ndarray:
    """``image`` with all but a central ``size`` x ``size`` window flat: a frame that sees
    only a little of the scene (some correspondences, too few)."""
    out = np.full_like(image, int(image.mean()))
    top, left = (image.shape[0] - size) // 2, (image.shape[1] - size) // 2
    out[top:top + size, left:left + size] = image[top:top + size, left:left + size]
    return out


def test_two_partial_misses_give_the_keyframe_one_more_try_then_restart():
    """Frames moving away from the keyframe find ever fewer correspondences (a user test:
    frames lost on the way, then 15, 10, 4, 4, 2 of them and six frames without odometry):
    after two misses in a row that still found some, the next frame that finds some but too
    few starts a new chain itself, before odometry.max_lost_frames (5); one that matches the
    keyframe keeps the chain (a review); garbled frames, which find none, wait for the five and
    never become keyframes."""
    trajectory, images, _ = _drive('straight')
    stamps = [float(s) for s in trajectory.stamps]
    noise = np.random.default_rng(0).integers(0, 255, (480, 640), dtype=np.uint8)
    for frames, expected in (
            ([_window_only(images[4]), _window_only(images[5]), images[6]], None),
            ([_window_only(images[4 + k]) for k in range(3)], DropReason.REINITIALISED),
            ([noise, noise[::-1].copy(), noise[:, ::-1].copy()],
             DropReason.TOO_FEW_CORRESPONDENCES)):
        vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}}), CAMERA)
        for i in range(4):
            vo.process(images[i], stamps[i])
        r1, r2, r3 = [vo.process(frame, stamps[4 + k]) for k, frame in enumerate(frames)]
        assert r1.reason is r2.reason is DropReason.TOO_FEW_CORRESPONDENCES
        partial = expected is not DropReason.TOO_FEW_CORRESPONDENCES
        assert (r1.num_correspondences > 0) is partial and 'new keyframe chain' not in r1.message
        assert r2.message.endswith('two frames in a row found too few correspondences with the '
                                   'keyframe: the next one that finds some but too few too starts '
                                   'a new keyframe chain (one that matches it keeps the chain; '
                                   'one that finds none, a garbled frame, waits for '
                                   'odometry.max_lost_frames)') is partial
        assert r3.reason is expected, r3.message
        if expected is None:                                # tracked against the keyframe
            step = np.linalg.norm(trajectory.xy[6] - trajectory.xy[0])
            assert abs(np.linalg.norm(r3.pose[:2, 3]) - step) < 0.05 * step


def test_lost_tracking_restarts_on_the_next_real_frame_with_inflated_covariance():
    trajectory, images, _ = _drive('straight')
    config = PlanarVoConfig.from_dict({'mount': {'height': HEIGHT},
                                       'odometry': {'max_lost_frames': 2}})
    vo = VisualOdometry(config, CAMERA)
    for i in range(4):
        last = vo.process(images[i], float(trajectory.stamps[i]))
    noise = np.random.default_rng(0).integers(0, 255, (480, 640), dtype=np.uint8)
    r1 = vo.process(noise, float(trajectory.stamps[4]))
    r2 = vo.process(noise[::-1].copy(), float(trajectory.stamps[5]))
    assert not r1.ok and not r2.ok
    assert 'tracking lost' in r2.message
    # The garbled frame is not the new keyframe: the next real frame is, with the pose carried
    # over (extrapolated) and its covariance inflated ...
    r7 = vo.process(images[7], float(trajectory.stamps[7]))
    assert r7.reason is DropReason.REINITIALISED
    # The covariance grows with the time of the gap (odometry.lost_speed_std = 1 m/s, and
    # braking at up to odometry.max_deceleration = 10 m/s^2 as three standard deviations) ...
    gap = float(trajectory.stamps[7] - trajectory.stamps[3])
    grown = gap ** 2 + (10.0 / 3.0) ** 2 * gap ** 4 / 4.0
    assert r7.pose_covariance[0, 0] == pytest.approx(last.pose_covariance[0, 0] + grown,
                                                     rel=0.05)
    # ... and the pose was carried on at the last velocity (8 m/s straight ahead).
    assert abs(r7.pose[0, 3] - (trajectory.xy[7, 0] - trajectory.xy[0, 0])) < 0.05
    # ... and the frame after it is tracked against it, with correspondences.
    r8 = vo.process(images[8], float(trajectory.stamps[8]))
    assert r8.ok and r8.num_correspondences >= config.odometry.min_correspondences
    true_step = np.linalg.norm(trajectory.xy[8] - trajectory.xy[7])
    step = np.linalg.norm(r8.pose[:2, 3] - r7.pose[:2, 3])
    assert abs(step - true_step) < 0.1 * true_step


def test_tracking_lost_before_any_motion_leaves_the_travel_unknown():
    """The node started while the car drove and lost the second frame (frames 1-19 never came):
    no velocity was measured, so the travel across the gap is unknown, and the covariance says
    so (a user test: the pose held 36 m behind at 12 standard deviations)."""
    trajectory, images, _ = _drive('straight')
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}}), CAMERA)
    results = [vo.process(images[i], float(trajectory.stamps[i]))
               for i in [0] + list(range(20, 26))]
    # Frame 20 is lost against the keyframe (frame 0); frame 21 is tracked from it, the new
    # chain's keyframe at the pose extrapolated to it (the bridge).
    assert results[1].reason is DropReason.TOO_FEW_CORRESPONDENCES
    assert results[2].ok and 'tracked from the frame before' in results[2].message
    for i, r in zip(range(20, 26), results[1:]):
        if r.ok:
            err = r.pose[:2, 3] - (trajectory.xy[i] - trajectory.xy[0])
            assert float(err @ np.linalg.solve(r.pose_covariance[:2, :2], err)) < 9.0
    assert results[-1].ok
    # With wheel speed the travel across the gap is measured: metres, not the kilometres an
    # unknown turn rate times the camera's lever arm gave (a review).
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT},
                                                  'scale': {'source': 'speed'}}), CAMERA)
    for t in np.arange(0.0, float(trajectory.stamps[26]), 0.05):
        vo.add_speed(float(t), 8.0)
    results = [vo.process(images[i], float(trajectory.stamps[i]))
               for i in [0] + list(range(20, 26))]
    last = results[-1]
    assert last.ok
    err = last.pose[:2, 3] - (trajectory.xy[25] - trajectory.xy[0])
    assert float(np.linalg.norm(err)) < 0.5
    assert np.sqrt(last.pose_covariance[0, 0]) < 10.0


@pytest.mark.parametrize('case', ['bridged', 'shared', 'sideways'])
def test_a_frame_lost_against_the_keyframe_bridges_the_next_one(case, monkeypatch):
    """Frames that moved away from the keyframe (two single frames lost in transport made the
    next steps two and three frames long: six frames and the chain lost, a user test): frame 6
    is lost against the keyframe (its estimate flagged here), so is frame 7, but frame 7
    against frame 6 is reliable: the chain restarts at frame 6, its pose extrapolated, and
    frame 7 is tracked from it, honestly. A disturbance the two share (``shared``: the bridge's
    estimate flagged too, and frame 8's against the keyframe) leaves frame 7 lost, and frame 8
    bridges from it; so does a bridge motion the car could not have made (``sideways``: a
    passing truck's, say, travelling at right angles to the last velocity)."""
    import dataclasses

    from planar_vo.core.conventions import rotation_y
    from planar_vo.pipeline.estimator import MotionEstimator

    trajectory, images, _ = _drive('straight')
    stamps = [float(t) for t in trajectory.stamps]
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}}), CAMERA)
    for i in range(6):
        assert vo.process(images[i], stamps[i]).ok or i == 0
    real, calls = MotionEstimator.estimate, []

    def altered(self, acs, level):
        est = real(self, acs, level)
        calls.append(est)
        if len(calls) <= (2 if case == 'bridged' else 4 if case == 'shared' else 0):
            return dataclasses.replace(est, reliable=False, flag='noisy')
        if case == 'sideways' and len(calls) <= 4:
            if len(calls) in (1, 2, 4):
                return dataclasses.replace(est, reliable=False, flag='noisy')
            return dataclasses.replace(est, t=rotation_y(np.pi / 2) @ est.t)   # the bridge
        return est

    monkeypatch.setattr(MotionEstimator, 'estimate', altered)
    assert vo.process(images[6], stamps[6]).reason is DropReason.UNRELIABLE
    r7 = vo.process(images[7], stamps[7])
    bridged = 7 if case == 'bridged' else 8
    if case == 'bridged':
        assert len(calls) == 3 and r7.ok        # against the keyframe, then against frame 6
    else:
        assert r7.reason is DropReason.UNRELIABLE and len(calls) == 3   # keyframe, bridge
        r8 = vo.process(images[8], stamps[8])
        assert len(calls) == 5 and r8.ok        # against the keyframe, then against frame 7
    monkeypatch.setattr(MotionEstimator, 'estimate', real)
    last = r7 if case == 'bridged' else r8
    assert 'tracked from the frame before' in last.message
    err = last.pose[:2, 3] - (trajectory.xy[bridged] - trajectory.xy[0])
    assert float(err @ np.linalg.solve(last.pose_covariance[:2, :2], err)) < 9.0
    assert float(np.linalg.norm(err)) < 0.3
    for i in range(bridged + 1, bridged + 5):
        r = vo.process(images[i], stamps[i])
        assert r.ok and r.message == ''
    err = r.pose[:2, 3] - (trajectory.xy[bridged + 4] - trajectory.xy[0])
    assert float(np.linalg.norm(err)) < 0.3


def test_frames_after_a_gap_that_find_nothing_of_a_new_keyframe_are_bridged():
    """Five frames lost in a turn just after a keyframe was set: the first frames after the
    gap find no correspondence with it at all (a review: from some to none at once, so no
    bridge, and the chain was lost for six frames). The second is tracked from the first, and
    the pose stays honest though extrapolated across the gap."""
    trajectory, images, _ = _drive('left')
    stamps = [float(t) for t in trajectory.stamps]
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}}), CAMERA)
    for i in range(10):
        assert vo.process(images[i], stamps[i]).ok or i == 0
    first = vo.process(images[15], stamps[15])
    assert first.reason is DropReason.TOO_FEW_CORRESPONDENCES and first.num_correspondences == 0
    results = [vo.process(images[i], stamps[i]) for i in range(16, 23)]
    assert results[0].ok and 'tracked from the frame before' in results[0].message
    assert all(r.ok for r in results)
    truth = invert(trajectory.poses[0]) @ trajectory.poses[22]
    err = results[-1].pose[:2, 3] - truth[:2, 3]
    assert float(err @ np.linalg.solve(results[-1].pose_covariance[:2, :2], err)) < 11.6


_FROZEN = (r"image identical to the previous frame's, pixel for pixel, (\S+) s after moving at "
           r"(\S+) \+- (\S+) m/s \(the last step's mean\), too fast to stop since at "
           r"odometry\.max_deceleration (\S+) m/s\^2: a frozen camera or a repeated frame")


def test_a_frozen_camera_is_lost_tracking_not_a_stop():
    """A driver republishing its last image while the car drives on at 8 m/s: the identical
    frames are counted as frozen_image (before, they read as a stop: the pose held with a
    confident speed of 0), tracking is lost after odometry.max_lost_frames of them (the first
    alone, a duplicated frame, leaves the state as it was), and the next real frame carries the
    pose on at the last velocity."""
    trajectory, images, _ = _drive('straight')
    stamps = trajectory.stamps
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}}), CAMERA)
    for i in range(4):
        last = vo.process(images[i], float(stamps[i]))
        assert i == 0 or last.ok
    frozen = [vo.process(images[3].copy(), float(stamps[i])) for i in range(4, 9)]
    assert [r.reason for r in frozen] == [DropReason.FROZEN_IMAGE] * 5
    assert [r.tracking for r in frozen[:2]] == [TrackingState.TRACKING, TrackingState.LOST]
    found = re.fullmatch(_FROZEN, frozen[0].message)
    assert found and abs(float(found[2]) - 8.0) < 0.2, frozen[0].message
    assert 'tracking lost' in frozen[-1].message
    resumed = vo.process(images[9], float(stamps[9]))
    assert resumed.reason is DropReason.REINITIALISED
    assert abs(resumed.pose[0, 3] - (trajectory.xy[9, 0] - trajectory.xy[0, 0])) < 0.05
    after = vo.process(images[10], float(stamps[10]))
    assert after.ok and abs(after.twist[0] - 8.0) < 0.2
    assert vo.counters['frozen_image'] == 5


def test_a_run_of_frozen_frames_stays_frozen_beyond_the_time_to_stop():
    """At 8 m/s and odometry.max_deceleration 40 m/s^2 the car could stop within 0.2 s: the
    frames of a camera frozen for 0.5 s stay frozen (a stop would hold the pose and zero the
    speed), and the first real frame after them is tracked against the last keyframe."""
    trajectory, images, _ = _drive('straight')
    stamps = trajectory.stamps
    config = PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}, 'odometry': {
        'max_lost_frames': 20, 'max_deceleration': 40.0}})
    vo = VisualOdometry(config, CAMERA)
    for i in range(4):
        vo.process(images[i], float(stamps[i]))
    frozen = [vo.process(images[3].copy(), float(stamps[i])) for i in range(4, 9)]
    assert [r.reason for r in frozen] == [DropReason.FROZEN_IMAGE] * 5
    found = re.fullmatch(_FROZEN, frozen[0].message)
    assert found and float(found[1]) < 0.2 and float(found[4]) == 40.0, frozen[0].message
    # The later frames name the run's first frame as where it was judged (a user test: each
    # named that frame's interval as its own).
    for r in frozen[1:]:
        assert r.message == frozen[0].message.replace(
            'pixel for pixel, ', 'pixel for pixel, in a run of identical frames that began ', 1)
    resumed = vo.process(images[9], float(stamps[9]))
    assert resumed.ok
    assert abs(resumed.pose[0, 3] - (trajectory.xy[9, 0] - trajectory.xy[0, 0])) < 0.05


def test_a_simulated_car_braking_hard_to_a_stop_stands():
    """A simulator's brake at 30 Hz (3 m/s^2 up to the stop): the last step's mean speed lags
    the car's, but the standing car's identical frames are a stop, not a frozen camera (a
    review: judged from the end of the last step, the whole stop was lost)."""
    trajectory, results, vo = _run('hard_stop')
    assert all(r.ok for r in results[1:]), vo.counters
    still = np.flatnonzero(np.all(np.diff(trajectory.poses, axis=0) == 0, axis=(1, 2))) + 1
    assert len(still) >= 20
    assert all(results[i].scale_source == 'stationary' for i in still[3:])
    pos, _, distance = _errors(trajectory, results)
    assert pos < 0.01 * distance


@pytest.mark.parametrize('case', ['fixed_speed', 'wheels_at_3_hz', 'wheels_late'])
def test_a_stop_stays_a_stop_without_evidence_of_motion(case):
    """The simulator's hard stop with an assumed fixed speed (an assumption is no evidence of
    motion) and with wheel speed samples at 3 Hz or arriving 0.2 s after their frames (not
    extrapolated past the last sample: a braking car's last sample is not the stop's speed):
    the standing frames are a stop (a review: the whole stop was lost as frozen)."""
    trajectory, images, twists = _drive('hard_stop')
    speeds = np.hypot(twists[:, 0], twists[:, 1])
    scale = {'source': 'fixed', 'fixed_speed': 12.0} if case == 'fixed_speed' else \
        {'source': 'speed'}
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}, 'scale': scale}),
                        CAMERA)
    stamps = [float(t) for t in trajectory.stamps]
    every = 10 if case == 'wheels_at_3_hz' else 1
    results = []
    for i, stamp in enumerate(stamps):
        if case == 'wheels_late' and i >= 6:
            vo.add_speed(stamps[i - 6], float(speeds[i - 6]))       # 0.2 s late at 30 Hz
        elif case != 'fixed_speed' and case != 'wheels_late' and i % every == 0:
            vo.add_speed(stamp, float(speeds[i]))
        results.append(vo.process(images[i], stamp))
    assert vo.counters.get('frozen_image', 0) == 0, [r.message for r in results
                                                     if r.reason is DropReason.FROZEN_IMAGE][:1]


def test_a_single_repeated_frame_is_only_counted():
    """One duplicated frame (a video converted to a constant frame rate) is counted, and
    neither changes the tracking state nor counts towards lost tracking, even with
    odometry.max_lost_frames 1 (a review: it restarted the chain)."""
    trajectory, images, _ = _drive('straight')
    stamps = trajectory.stamps
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT},
                                                  'odometry': {'max_lost_frames': 1}}), CAMERA)
    for i in range(4):
        vo.process(images[i], float(stamps[i]))
    repeated = vo.process(images[3].copy(), float(stamps[4]))
    assert repeated.reason is DropReason.FROZEN_IMAGE
    assert repeated.tracking is TrackingState.TRACKING and 'tracking lost' not in repeated.message
    after = vo.process(images[5], float(stamps[5]))
    assert after.ok and after.tracking is TrackingState.TRACKING
    assert abs(after.pose[0, 3] - (trajectory.xy[5, 0] - trajectory.xy[0, 0])) < 0.05
    # A blank frame between two repeats ends the run: each repeat alone is only counted (the
    # blank one counts towards lost tracking, by itself).
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT},
                                                  'odometry': {'max_lost_frames': 2}}), CAMERA)
    for i in range(4):
        vo.process(images[i], float(stamps[i]))
    results = [vo.process(image, float(stamps[i])) for i, image in
               ((4, images[3].copy()), (5, np.zeros_like(images[3])), (6, images[3].copy()))]
    assert [r.reason for r in results] == [DropReason.FROZEN_IMAGE, DropReason.BLANK_IMAGE,
                                           DropReason.FROZEN_IMAGE]
    assert [r.tracking for r in results] == [TrackingState.TRACKING, TrackingState.LOST,
                                             TrackingState.LOST]
    assert all('tracking lost' not in r.message for r in results), [r.message for r in results]
    after = vo.process(images[7], float(stamps[7]))
    assert after.ok and after.tracking is TrackingState.TRACKING, (after.reason, after.message)


def test_a_long_gap_widens_the_travel_by_braking_only_until_the_stop():
    """2.2 s without an update at 8 m/s: braking at odometry.max_deceleration (10 m/s^2) would
    stop the car after 0.8 s and fall short of the extrapolated travel by 8 x 2.2 - 8^2 / 20 =
    14.4 m (three standard deviations, along the travel), not by 10 x 2.2^2 / 2 = 24.2 m (a
    review: that grew as t^4 without bound)."""
    trajectory, images, _ = _drive('straight')
    stamps = trajectory.stamps
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}}), CAMERA)
    for i in range(4):
        last = vo.process(images[i], float(stamps[i]))
    for i in range(4, 25):
        assert vo.process(np.zeros_like(images[i]), float(stamps[i])).reason is \
            DropReason.BLANK_IMAGE
    resumed = vo.process(images[25], float(stamps[25]))
    assert resumed.reason is DropReason.REINITIALISED
    gap = float(stamps[25] - stamps[3])
    grown = resumed.pose_covariance - last.pose_covariance
    assert grown[0, 0] == pytest.approx(gap ** 2 + ((8.0 * gap - 3.2) / 3.0) ** 2, rel=0.02)
    assert grown[1, 1] == pytest.approx(gap ** 2, rel=0.02)                 # across: no braking


def test_an_older_image_republished_is_not_a_step_back():
    """A B A: frame 4's image again after frame 5's (a driver republishing an old buffer) is
    counted as frozen_image, not a step back at -8 m/s (a user test: a permanent 2 m error at
    10 standard deviations), and the next real frame is tracked."""
    trajectory, images, _ = _drive('straight')
    stamps = trajectory.stamps
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}}), CAMERA)
    for i in range(6):
        vo.process(images[i], float(stamps[i]))
    old = vo.process(images[4].copy(), float(stamps[6]))
    assert old.reason is DropReason.FROZEN_IMAGE, (old.reason, old.message)
    assert old.message == ('image identical, pixel for pixel, to the frame 2 frames before it, '
                           'with other images between: a camera republishing an old image')
    after = vo.process(images[7], float(stamps[7]))
    assert after.ok and abs(after.pose[0, 3] - (trajectory.xy[7, 0] - trajectory.xy[0, 0])) < 0.05
    assert abs(after.twist[0] - 8.0) < 0.3
    # Standing, a simulator's scene may repeat (a blinking light): A A' A is a stop.
    trajectory, images, _ = _drive('hard_stop')
    still = np.flatnonzero(np.all(np.diff(trajectory.poses, axis=0) == 0, axis=(1, 2))) + 1
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}}), CAMERA)
    for i in range(still[5] + 1):
        vo.process(images[i], float(trajectory.stamps[i]))
    blink = images[still[5]].copy()
    blink[200:210, 300:310] = 255 - blink[200:210, 300:310]
    for i, image in ((still[6], blink), (still[7], images[still[7]])):
        result = vo.process(image, float(trajectory.stamps[i]))
        assert result.ok and result.scale_source == 'stationary', (result.reason, result.message)


@pytest.mark.parametrize('mode', ['auto', 'frozen'])
def test_repeated_images_frozen_for_a_real_camera(mode):
    """With odometry.max_deceleration so high that any car could have stopped, 'auto' takes a
    frozen camera for a stop; 'frozen' (a real camera: its noise never repeats an image) does
    not."""
    trajectory, images, _ = _drive('straight')
    stamps = trajectory.stamps
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}, 'odometry': {
        'max_deceleration': 1000.0, 'repeated_images': mode}}), CAMERA)
    for i in range(4):
        vo.process(images[i], float(stamps[i]))
    repeated = vo.process(images[3].copy(), float(stamps[4]))
    if mode == 'auto':
        assert repeated.ok and repeated.scale_source == 'stationary'
    else:
        assert repeated.reason is DropReason.FROZEN_IMAGE
        assert 'odometry.repeated_images: frozen' in repeated.message


def test_a_gap_in_a_turn_widens_the_yaw_by_the_turn_that_may_go_on():
    """3 s without an update in a 90-deg turn at 0.4 rad/s: the extrapolated turn rate decays
    (2 s), the car turns on; the yaw's standard deviation covers the turn the decay leaves out
    (a user test: 35 deg off at a std of 8.9 deg, 4 standard deviations), and the position's
    the offset of that turn."""
    trajectory, images, _ = _drive('long_turn')
    stamps = trajectory.stamps
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}}), CAMERA)
    for i in range(6):
        vo.process(images[i], float(stamps[i]))
    for i in range(6, 36):
        vo.process(np.zeros_like(images[i]), float(stamps[i]))
    resumed = vo.process(images[36], float(stamps[36]))
    assert resumed.reason is DropReason.REINITIALISED
    truth = invert(trajectory.poses[0]) @ trajectory.poses[36]
    error = abs(yaw_of(resumed.pose[:3, :3]) - yaw_of(truth[:3, :3]))
    std = math.sqrt(resumed.pose_covariance[5, 5])
    assert error > math.radians(20)                    # the decay left much of the turn out
    assert error < 1.5 * std, (math.degrees(error), math.degrees(std))
    # The position follows the decaying turn (a review: straight ahead, 14.9 m off), and its
    # covariance covers the turn going on.
    e = resumed.pose[:2, 3] - truth[:2, 3]
    assert np.linalg.norm(e) < 7.0, e
    assert float(e @ np.linalg.solve(resumed.pose_covariance[:2, :2], e)) < 3.0 ** 2


def test_the_wheel_speed_tells_a_frozen_camera_from_a_stop():
    """With wheel speed: frames frozen from start-up while driving are frozen_image (nothing
    visual says the car moves yet), and a camera that stalls during a stop, the car driving
    off, turns frozen when the wheels move; across the lost frames the pose goes on over the
    wheels' distance (a user test: the stall held the pose at the stop, 10 m behind, at a
    speed of 0 +- 0.12 m/s)."""
    trajectory, images, twists = _drive('straight')
    speeds = np.hypot(twists[:, 0], twists[:, 1])
    vo = VisualOdometry(PlanarVoConfig.from_dict(
        {'mount': {'height': HEIGHT}, 'scale': {'source': 'speed'}}), CAMERA)
    results = []
    for i in range(5):
        vo.add_speed(float(trajectory.stamps[i]), float(speeds[i]))
        results.append(vo.process(images[0 if i < 4 else i].copy(), float(trajectory.stamps[i])))
    assert [r.reason for r in results[1:4]] == [DropReason.FROZEN_IMAGE] * 3
    assert re.search(r'while the wheel speed gives 0\.8\d* m travelled since it',
                     results[1].message)
    assert results[4].ok
    assert abs(results[4].pose[0, 3] - (trajectory.xy[4, 0] - trajectory.xy[0, 0])) < 0.05

    trajectory, images, twists = _drive('stop_and_go')
    speeds = np.hypot(twists[:, 0], twists[:, 1])
    still = np.flatnonzero(np.all(np.diff(trajectory.poses, axis=0) == 0, axis=(1, 2))) + 1
    stall, back = still[len(still) // 2], still[-1] + 19         # ... to 1.8 s after the stop
    vo = VisualOdometry(PlanarVoConfig.from_dict(
        {'mount': {'height': HEIGHT}, 'scale': {'source': 'speed'}}), CAMERA)
    results = []
    for i, stamp in enumerate(trajectory.stamps[:back + 3]):
        vo.add_speed(float(stamp), float(speeds[i]))
        image = images[stall] if stall <= i < back else images[i]
        results.append(vo.process(image.copy(), float(stamp)))
    reasons = [r.reason for r in results[stall:back]]
    moving = [i for i in range(stall, back) if speeds[i] > 0 or speeds[i - 1] > 0]
    assert reasons[:moving[0] - stall] == [None] * (moving[0] - stall)    # standing: a stop
    assert DropReason.FROZEN_IMAGE in reasons and reasons[-1] is DropReason.FROZEN_IMAGE
    assert results[back].reason is DropReason.REINITIALISED
    truth = (invert(trajectory.poses[0]) @ trajectory.poses[back])[0, 3]
    assert truth - results[stall].pose[0, 3] > 3.0                        # it drove off
    assert abs(results[back].pose[0, 3] - truth) < 0.3


def test_a_capture_loop_refilling_one_buffer_is_tracked():
    """The caller's array is not kept: a loop that refills one buffer per frame gives the
    same odometry as new arrays (kept, the keyframe and the previous frame changed with it)."""
    trajectory, images, _ = _drive('straight')
    config = PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}})
    fresh, reused = VisualOdometry(config, CAMERA), VisualOdometry(config, CAMERA)
    buffer = np.empty_like(images[0])
    for i in range(8):
        buffer[:] = images[i]
        a = fresh.process(images[i], float(trajectory.stamps[i]))
        b = reused.process(buffer, float(trajectory.stamps[i]))
        assert b.reason is a.reason
        assert np.array_equal(a.pose, b.pose)
    assert b.ok and b.pose[0, 3] > 4.0


@pytest.mark.parametrize('after_loss', [False, True])
@pytest.mark.parametrize('bridged', [True, False])
def test_a_chain_started_on_a_garbled_frame_restarts_after_two_misses(after_loss, bridged):
    """Noise is not blank, so a garbled frame can start a keyframe chain (the first frame, or
    the first after lost tracking). No real frame can match it. The second real frame is
    tracked from the first (`_bridge`: the chain restarts there). Where it cannot be (a frame
    far from the first: ``bridged`` False), when the first two frames after the noise find no
    correspondences with it, it is dropped and the next frame starts a new chain, instead of
    max_lost_frames (5) frames lost against the noise."""
    trajectory, images, _ = _drive('straight')
    stamps = [float(t) for t in trajectory.stamps]
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}}), CAMERA)
    rng = np.random.default_rng(0)
    k = 0
    if after_loss:
        for k in range(3):
            assert vo.process(images[k], stamps[k]).ok or k == 0
        for k in range(3, 8):                       # lost tracking: noise five times
            assert not vo.process(rng.integers(0, 255, (480, 640), np.uint8), stamps[k]).ok
        k = 8
    start = vo.process(rng.integers(0, 255, (480, 640), np.uint8), stamps[k])
    assert start.reason is (DropReason.REINITIALISED if after_loss else DropReason.FIRST_FRAME)
    first = vo.process(images[k + 1], stamps[k + 1])
    assert first.reason is DropReason.TOO_FEW_CORRESPONDENCES
    assert 'matched nothing' not in first.message
    j = k + 2 if bridged else k + 20              # (20 frames on: nothing in common with k + 1)
    second = vo.process(images[j], stamps[j])
    if bridged:
        assert second.ok and 'tracked from the frame before' in second.message
    else:
        assert second.reason is DropReason.TOO_FEW_CORRESPONDENCES
        assert 'first keyframe matched nothing' in second.message
        again = vo.process(images[j + 1], stamps[j + 1])
        assert again.reason is DropReason.REINITIALISED
        j += 1
    assert all(vo.process(images[i], stamps[i]).ok
               for i in range(j + 1, min(j + 4, len(images))))


def test_one_garbled_frame_after_a_chain_starts_leaves_its_keyframe():
    """The other order: a real first keyframe, then one garbled frame. The keyframe is kept
    (one frame without correspondences may be the garbled one itself), and the next real frame
    is tracked against it."""
    trajectory, images, _ = _drive('straight')
    stamps = [float(t) for t in trajectory.stamps]
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}}), CAMERA)
    assert vo.process(images[0], stamps[0]).reason is DropReason.FIRST_FRAME
    noise = np.random.default_rng(0).integers(0, 255, (480, 640), np.uint8)
    assert vo.process(noise, stamps[1]).reason is DropReason.TOO_FEW_CORRESPONDENCES
    assert all(vo.process(images[i], stamps[i]).ok for i in range(2, 5))


def test_a_camera_model_change_restarts_the_chain_only_when_the_image_moves():
    # A recalibration that moves the image by a hundredth of a pixel keeps the keyframe chain:
    # every frame is tracked. A model that moves it by pixels (fx 500 -> 520) starts a new
    # chain like lost tracking: the pose extrapolated over the interval, the covariance grown.
    trajectory, images, _ = _drive('straight')
    stamps = [float(t) for t in trajectory.stamps]
    K = CAMERA.K.copy()
    K[0, 0] += 0.01
    recalibrated = CameraModel(640, 480, K)
    K = CAMERA.K.copy()
    K[:2, :2] *= 1.04
    other = CameraModel(640, 480, K)
    config = PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}})
    vo = VisualOdometry(config)
    results = [vo.process(images[i], stamps[i], CAMERA if i < 5 else recalibrated)
               for i in range(10)]
    assert [r.ok for r in results] == [False] + [True] * 9
    before = results[-1]
    changed = vo.process(images[10], stamps[10], other)
    assert changed.reason is DropReason.REINITIALISED and 'camera model change' in changed.message
    assert changed.tracking is TrackingState.REINITIALISED
    truth = np.linalg.norm(trajectory.xy[10] - trajectory.xy[0])
    assert abs(changed.pose[0, 3] - truth) < 0.05                  # carried on at 8 m/s
    dt = stamps[10] - stamps[9]
    assert changed.pose_covariance[0, 0] == pytest.approx(
        before.pose_covariance[0, 0] + (config.odometry.lost_speed_std * dt) ** 2, rel=0.05)
    # The next frame is tracked against the new chain with the new model.
    assert vo.process(images[11], stamps[11], other).ok


def test_a_stray_camera_model_of_another_size_does_not_restart_the_chain():
    """User tests: a CameraInfo of another size for a few frames (a second camera's on the
    topic), then the right one again, restarted the keyframe chain as a camera model change;
    later, every frame was dropped (no_camera_info) while it lasted. The images keep the size of
    the model they were tracked with: that one stays in use, and tracking goes on."""
    trajectory, images, _ = _drive('straight')
    stamps = [float(t) for t in trajectory.stamps]
    half = CameraModel.pinhole(320, 240, 250.0)
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}}))
    results = [vo.process(images[i], stamps[i], half if 5 <= i < 8 else CAMERA)
               for i in range(12)]
    assert all(r.ok for r in results[1:]), [(r.reason, r.message) for r in results]
    assert vo.focal_status() == f'focal length {CAMERA.fx:.1f} px (CameraInfo)'
    # Before any image had a model's size, one of another size is no model for them.
    fresh = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}}))
    assert fresh.process(images[0], stamps[0], half).reason is DropReason.NO_CAMERA_INFO
    truth = trajectory.xy[11, 0] - trajectory.xy[0, 0]
    assert abs(results[11].pose[0, 3] - truth) < 0.1


def test_mount_tilt_is_estimated_and_used():
    # The camera is pitched 3 degrees and rolled 1 degree, the configuration says level: the
    # tilt estimate from the drive must find the pitch and level the camera with it.
    pitch, roll = np.deg2rad(3.0), np.deg2rad(1.0)
    config = PlanarVoConfig.from_dict({'mount': {'height': HEIGHT, 'estimate_tilt': True,
                                                 'tilt_tolerance': float(np.deg2rad(0.2))}})
    trajectory, results, vo = _run('left', config, pitch=pitch, roll=roll)
    estimate = vo.tilt_estimate
    assert estimate is not None
    assert abs(estimate.pitch - pitch) < np.deg2rad(0.2)
    assert abs(estimate.roll - roll) < np.deg2rad(0.5)
    assert all(r.ok for r in results[1:])


def test_first_road_steps_use_the_road_normal_fitted_with_their_own_pair():
    # The camera is pitched 3 degrees and the configuration says level: the very first road
    # steps must already be measured with the road normal refitted on their own road ACs, not
    # with the level guess (about 40 % long at 3 degrees).
    pitch = np.deg2rad(3.0)
    config = PlanarVoConfig.from_dict({'mount': {'height': HEIGHT, 'estimate_tilt': True}})
    trajectory, results, _ = _run('straight', config, pitch=pitch)
    truth = np.linalg.norm(np.diff(trajectory.xy, axis=0), axis=1)
    for k in (1, 2, 3):
        assert results[k].ok and results[k].scale_source == 'ground'
        step = np.linalg.norm(results[k].pose[:2, 3] - results[k - 1].pose[:2, 3])
        assert abs(step / truth[k - 1] - 1.0) < 0.03, (k, step, truth[k - 1])


# ---------------------------------------------------------------------------------------------
# Clock hiccups: nothing wedges
# ---------------------------------------------------------------------------------------------

def test_a_single_future_stamp_is_that_frames_problem_only():
    trajectory, images, _ = _drive('straight')
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}}), CAMERA)
    stamps = [float(s) for s in trajectory.stamps]
    for i in range(4):
        vo.process(images[i], stamps[i])
    glitch = vo.process(images[4], stamps[4] + 365 * 86400.0)
    assert glitch.reason is DropReason.TIME_JUMP_AHEAD
    results = [vo.process(images[i], stamps[i]) for i in range(5, 9)]
    assert all(r.ok for r in results)
    assert vo.tracking is TrackingState.TRACKING


def _tracked_straight(frames: int = 4):
    """The straight drive's first `frames` frames tracked: ``images, stamps, vo`` and the last
    result."""
    trajectory, images, _ = _drive('straight')
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}}), CAMERA)
    stamps = [float(s) for s in trajectory.stamps]
    for i in range(frames):
        last = vo.process(images[i], stamps[i])
    assert last.ok
    return images, stamps, vo, last


def test_a_confirmed_forward_gap_restarts_tracking():
    images, stamps, vo, last = _tracked_straight()
    later = 600.0                       # the driver restarted ten minutes later
    first = vo.process(images[4], stamps[4] + later)
    second = vo.process(images[5], stamps[5] + later)
    third = vo.process(images[6], stamps[6] + later)
    assert first.reason is DropReason.TIME_JUMP_AHEAD
    assert second.reason is DropReason.REINITIALISED
    assert second.tracking is TrackingState.REINITIALISED
    assert third.ok and third.tracking is TrackingState.TRACKING
    # The last velocity (8 m/s) says nothing about the ten minutes across a new time base: the
    # pose is held (carried on, it would be 4.8 km ahead), the covariance grown with the time.
    assert np.allclose(second.pose, last.pose)
    assert np.linalg.norm(third.pose[:3, 3] - last.pose[:3, 3]) < 2.0
    assert np.sqrt(second.pose_covariance[0, 0]) > 100.0
    # ... but no angle is less known than a uniform one (std pi / sqrt(3); a user test: 287 deg)
    angles = np.sqrt(np.diag(second.pose_covariance)[3:])
    assert np.all(angles > 1.0) and np.all(angles <= np.pi / np.sqrt(3.0) + 1e-9)


def test_a_first_frame_stamped_far_early_leaves_the_drive_its_own_origin():
    """A user test: one frame stamped 1000 s early (header and log time) came first and became
    the origin; the drive's frames were then a jump ahead and a new time base with the pose
    held and a std of 1000 m. Before any motion, a new time base starts the odometry afresh."""
    trajectory, images, _ = _drive('straight')
    stamps = [float(s) + 2000.0 for s in trajectory.stamps]
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}}), CAMERA)
    glitch = vo.process(images[0], stamps[0] - 1000.0)
    assert glitch.reason is DropReason.FIRST_FRAME
    results = [vo.process(images[i], stamps[i]) for i in range(0, 6)]
    assert [r.reason for r in results[:2]] == [DropReason.TIME_JUMP_AHEAD, DropReason.FIRST_FRAME]
    assert all(r.ok for r in results[2:])
    np.testing.assert_allclose(results[1].pose, np.eye(4))
    assert np.sqrt(results[-1].pose_covariance[0, 0]) < 1.0
    truth = np.linalg.norm(trajectory.xy[5] - trajectory.xy[1])
    assert abs(np.linalg.norm(results[-1].pose[:2, 3]) - truth) < 0.05 * truth


def test_two_new_time_bases_without_an_output_grow_the_covariance_once():
    """A review: the second restart added the whole time since the last output again (x std
    224 m after 100 s and 200 s instead of 200 m) and the angles grew past the cap."""
    images, stamps, vo, last = _tracked_straight()
    results = [vo.process(images[4], stamps[4] + 100.0), vo.process(images[5], stamps[5] + 100.0),
               vo.process(images[6], stamps[6] + 200.0), vo.process(images[7], stamps[7] + 200.0)]
    assert [r.reason for r in results] == [DropReason.TIME_JUMP_AHEAD, DropReason.REINITIALISED,
                                           DropReason.TIME_JUMP_AHEAD, DropReason.REINITIALISED]
    dt = stamps[7] + 200.0 - stamps[3]                       # since the last output
    x_std = np.sqrt(results[3].pose_covariance[0, 0] - last.pose_covariance[0, 0])
    assert x_std == pytest.approx(dt * 1.0, rel=0.01)        # odometry.lost_speed_std 1 m/s
    angles = np.sqrt(np.diag(results[3].pose_covariance)[3:])
    assert np.all(angles <= np.pi / np.sqrt(3.0) + 1e-9)


def test_time_jumping_back_resets_tracking_and_keeps_counters():
    trajectory, images, _ = _drive('straight')
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}}), CAMERA)
    stamps = [float(s) for s in trajectory.stamps]
    for i in range(6):
        vo.process(images[i], stamps[i] + 100.0)
    assert vo.counters['ok'] == 5
    assert np.linalg.norm(vo.pose[:3, 3]) > 1.0
    # The bag loops: stamps start again 100 s earlier. Small steps back stay out of order.
    assert vo.process(images[6], stamps[5] + 100.0 - 0.05).reason is DropReason.OUT_OF_ORDER
    # The first frame far back is refused (it could be one bad stamp); the next one, which
    # follows it, confirms the older time and resets tracking at the origin.
    refused = vo.process(images[0], stamps[0])
    assert refused.reason is DropReason.OUT_OF_ORDER and 'confirms' in refused.message
    reset = vo.process(images[1], stamps[1])
    assert reset.reason is DropReason.TIME_JUMP_BACK
    assert reset.tracking is TrackingState.REINITIALISED
    np.testing.assert_allclose(reset.pose, np.eye(4))
    again = vo.process(images[2], stamps[2])
    assert again.ok and vo.counters['ok'] == 6 and vo.counters['time_jump_back'] == 1
    step = np.linalg.norm(trajectory.xy[2] - trajectory.xy[1])
    assert abs(np.linalg.norm(again.pose[:2, 3]) - step) < 0.1 * step


def test_one_frame_stamped_far_back_is_its_own_problem():
    # A user test: one frame stamped 0 (or 10 s early) in the middle of a drive reset the rest
    # of it to the origin. It is refused like one stamped far ahead; tracking goes on.
    trajectory, images, _ = _drive('straight')
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}}), CAMERA)
    stamps = [float(s) + 100.0 for s in trajectory.stamps]
    results = [vo.process(images[i], stamps[i]) for i in range(5)]
    for glitch in (0.0, stamps[4] - 10.0):
        bad = vo.process(images[5], glitch)
        assert bad.reason is DropReason.OUT_OF_ORDER and bad.tracking is TrackingState.TRACKING
    results += [vo.process(images[i], stamps[i]) for i in range(5, 8)]
    assert all(r.ok for r in results[1:])
    assert 'time_jump_back' not in vo.counters and vo.counters['out_of_order'] == 2
    truth = trajectory.xy[7] - trajectory.xy[0]
    assert abs(np.linalg.norm(results[-1].pose[:2, 3]) - np.linalg.norm(truth)) \
        < 0.05 * np.linalg.norm(truth)


def test_a_reset_widens_its_first_steps_as_start_up_does():
    """A user test: after ~/reset the first step's lateral std was 0.0017 m against 0.017 m at
    start-up (the excess measured before the reset, kept, replaced the nominal widening) and
    the lateral error reached 5 standard deviations within 20 m."""
    trajectory, images, _ = _drive('straight')
    stamps = [float(s) for s in trajectory.stamps]
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}}), CAMERA)
    start = [vo.process(images[i], stamps[i]) for i in range(16)]
    assert all(r.ok for r in start[1:])
    vo.reset()
    again = [vo.process(images[i], stamps[i]) for i in range(16, 20)]
    assert again[0].reason is DropReason.FIRST_FRAME and all(r.ok for r in again[1:])
    for k in (1, 2, 3):                 # the k-th step after start-up and after the reset
        np.testing.assert_allclose(np.diag(again[k].pose_covariance),
                                   np.diag(start[k].pose_covariance), rtol=0.5)
    # After ten steps the measured excess takes over (smaller than the nominal here).
    late = [vo.process(images[i], stamps[i]) for i in range(20, 32)]
    step_var = [np.diag(b.pose_covariance - a.pose_covariance)[5] for a, b in zip(late, late[1:])]
    early_var = [np.diag(b.pose_covariance - a.pose_covariance)[5]
                 for a, b in zip(again[1:], again[2:])]
    assert step_var[-1] < 0.5 * min(early_var)


def test_one_instance_refuses_a_second_call_at_once():
    """An instance is one camera's state (a user test: two threads sharing one got internal
    errors, logged as pipeline errors): a call while one runs is a typed error; after it, the
    instance works on."""
    from planar_vo.errors import ConcurrencyError

    trajectory, images, _ = _drive('straight')
    stamps = [float(t) for t in trajectory.stamps]
    vo = VisualOdometry(PlanarVoConfig.from_dict({'mount': {'height': HEIGHT}}), CAMERA)
    assert vo.process(images[0], stamps[0]).reason is DropReason.FIRST_FRAME
    inner = []
    real = vo._extractor.extract

    def reentrant(*args):
        with pytest.raises(ConcurrencyError, match=r'^VisualOdometry\.process: called while '
                                                   r'another call on this instance runs'):
            vo.process(images[2], stamps[2])
        inner.append(True)
        return real(*args)

    vo._extractor.extract = reentrant
    assert vo.process(images[1], stamps[1]).ok and inner == [True]
    vo._extractor.extract = real
    assert vo.process(images[2], stamps[2]).ok
