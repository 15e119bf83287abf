"""Online calibration: the road normal from the road's own consistency, the mount tilt without
the pitch-wobble lock, and the focal length from turning pairs (profiles, honest adoption,
bounded and amortised cost)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from planar_vo.config.sections import CameraConfig
from planar_vo.core.conventions import normal_from_tilt, rotation_y
from planar_vo.core.homography import apply_homography
from planar_vo.core.robust import combine_profiles, pair_profile, shifted_profile
from planar_vo.core.robust.stats import _student_t_mass, few_cluster_factor, student_t_quantile
from planar_vo.errors import ConfigError, InputError
from planar_vo.frontend import leveling_rotation
from planar_vo.pipeline.calibration import (
    MountTiltEstimator,
    OnlineFocalCalibrator,
    RoadNormalCalibrator,
    TurnPairSelector,
    focal_pitch,
    pair_road_normal,
)
from planar_vo.sim.synthetic import PAPER_PRINCIPAL_POINT, shared_motion_acs

HEIGHT = 1.65
PITCH, ROLL = np.deg2rad(1.2), np.deg2rad(-0.6)


def _rotation(w) -> np.ndarray:
    """``exp([w]x)`` (Rodrigues)."""
    return cv2.Rodrigues(np.asarray(w, dtype=np.float64))[0]


def _camera_motion(pitch, roll, yaw, wobble, step=1.0, heading=0.0):
    """Camera-frame ``(R, t)`` (``X2 = R X1 + t``) of a car mounted camera: in the level frame
    a yaw about the vertical, a wobble rotation ``(wx, wz)`` and a forward step (heading
    ``heading`` off the optical axis); mapped by the mount tilt."""
    R_lc = leveling_rotation(pitch, roll)                   # camera -> level
    R_level = _rotation([wobble[0], 0.0, wobble[1]]) @ rotation_y(yaw)
    c_level = step * np.array([math.sin(heading), 0.0, math.cos(heading)])   # centre 2 in 1
    R = R_lc.T @ R_level @ R_lc
    t = -R @ (R_lc.T @ c_level)
    return R, t


# --------------------------------------------------------------------------------------------
# Student t and the few-cluster factor
# --------------------------------------------------------------------------------------------

def test_student_t_quantiles_match_tables():
    assert student_t_quantile(0.975, 1) == pytest.approx(12.7062047, rel=1e-7)
    assert student_t_quantile(0.975, 10) == pytest.approx(2.2281389, rel=1e-7)
    assert student_t_quantile(0.995, 30) == pytest.approx(2.7499957, rel=1e-7)
    assert student_t_quantile(0.025, 4) == pytest.approx(-2.7764451, rel=1e-7)
    # Cauchy (nu = 1) in closed form; towards the normal for many degrees of freedom.
    q = 0.5 * (1.0 + math.erf(3.0 / math.sqrt(2.0)))
    assert few_cluster_factor(2, 3.0) == pytest.approx(math.tan(math.pi * (q - 0.5)) / 3.0)
    assert few_cluster_factor(1000, 3.0) == pytest.approx(1.0, abs=0.01)
    assert few_cluster_factor(1) == math.inf
    assert student_t_quantile(0.5, 7) == 0.0                      # the median, exactly
    with pytest.raises(ValueError, match=r'expected 0 < p < 1 and nu >= 1'):
        student_t_quantile(1.0, 3)


@pytest.mark.parametrize('p', [0.5000001, 0.6, 0.8413447460685429, 0.975, 0.9986501019683699,
                               0.999999])
def test_student_t_quantiles_match_closed_forms_over_the_tail(p):
    """The closed forms for 1 and 2 degrees of freedom, to near machine precision (p itself is
    rounded: the far tail's condition number), and the CDF at the quantile for many."""
    student_t_quantile.cache_clear()
    assert student_t_quantile(p, 1) == pytest.approx(math.tan(math.pi * (p - 0.5)), rel=1e-9)
    assert student_t_quantile(p, 2) == pytest.approx((2 * p - 1) / math.sqrt(2 * p * (1 - p)),
                                                     rel=1e-9)
    for nu in (3, 7, 30, 199, 5000):
        t = student_t_quantile(p, nu)
        theta = math.atan(t / math.sqrt(nu))
        assert 0.5 * (1.0 + _student_t_mass(theta, nu)) == pytest.approx(p, abs=1e-13)


# --------------------------------------------------------------------------------------------
# Road normal
# --------------------------------------------------------------------------------------------

def _road_frame(rng, normal, *, count=80, noise=0.0, yaw=None):
    """Exact (or noisy) road ACs of one frame pair for a general motion: normalised points."""
    R, t = _camera_motion(PITCH, ROLL, rng.uniform(-0.03, 0.03) if yaw is None else yaw,
                          rng.normal(0.0, 0.002, 2), step=rng.uniform(0.5, 1.5))
    q1 = np.column_stack([rng.uniform(-0.6, 0.6, count), rng.uniform(0.08, 0.3, count)])
    H = R + np.outer(t, normal) / HEIGHT
    q2 = apply_homography(H, q1) + rng.normal(0.0, noise, (count, 2))
    return q1, q2, R, t


def test_road_normal_is_recovered_exactly_from_exact_road_acs(rng):
    normal = normal_from_tilt(PITCH, ROLL)
    cal = RoadNormalCalibrator()
    for _ in range(15):
        q1, q2, R, t = _road_frame(rng, normal)
        assert cal.add(q1, q2, R, t, np.ones(len(q1), bool))
    est = cal.estimate(0.0, 0.0)                            # from the level guess
    assert abs(est.pitch - PITCH) < 1e-9 and abs(est.roll - ROLL) < 1e-9
    assert est.frames == 15 and est.pitch_std < 1e-6 and est.roll_std < 1e-6
    np.testing.assert_allclose(est.normal, normal, atol=1e-9)


def test_road_normal_std_is_honest_on_noisy_road_acs():
    rng = np.random.default_rng(11)
    normal = normal_from_tilt(PITCH, ROLL)
    z = []
    for _ in range(40):
        cal = RoadNormalCalibrator()
        for _ in range(30):
            cal.add(*_road_frame(rng, normal, noise=1e-3), np.ones(80, bool))
        est = cal.estimate(0.0, 0.0)
        assert abs(est.pitch - PITCH) < np.deg2rad(0.1) and abs(est.roll - ROLL) < np.deg2rad(0.5)
        z += [(est.pitch - PITCH) / est.pitch_std, (est.roll - ROLL) / est.roll_std]
    rms = float(np.sqrt(np.mean(np.square(z))))
    assert 0.6 < rms < 1.3, rms


def test_one_pair_road_normal_is_exact_on_exact_acs_and_honest_on_noisy_ones(rng):
    normal = normal_from_tilt(PITCH, ROLL)
    q1, q2, R, t = _road_frame(rng, normal, count=300)
    road = np.zeros(300, bool)
    road[:250] = True                                       # the mask selects what is used
    q2[250:] += 0.05                                        # ... the rest is not road
    est = pair_road_normal(q1, q2, R, t, road, None, 0.0, 0.0, iterations=8)
    assert abs(est.pitch - PITCH) < 1e-9 and abs(est.roll - ROLL) < 1e-9
    assert est.frames == 1
    z = []
    for _ in range(60):
        q1, q2, R, t = _road_frame(rng, normal, count=200, noise=1e-3)
        est = pair_road_normal(q1, q2, R, t, np.ones(200, bool), np.ones(200), PITCH, ROLL)
        assert math.isfinite(est.pitch_std) and est.pitch_std > 0
        z += [(est.pitch - PITCH) / est.pitch_std, (est.roll - ROLL) / est.roll_std]
    rms = float(np.sqrt(np.mean(np.square(z))))
    assert 0.3 < rms < 1.3, rms                             # never over-confident
    # Fewer than 10 road ACs: no estimate.
    assert pair_road_normal(q1, q2, R, t, np.arange(200) < 9, None, 0.0, 0.0) is None


def test_road_normal_memory_and_refits_are_bounded(rng):
    normal = normal_from_tilt(PITCH, ROLL)
    cal = RoadNormalCalibrator(per_frame=40, max_frames=50, refit_every=10)
    frames = [_road_frame(rng, normal, count=120) for _ in range(5)]
    fits = []
    for k in range(400):
        q1, q2, R, t = frames[k % 5]
        assert cal.add(q1, q2, R, t, np.ones(120, bool))
        est = cal.update()
        fits.append(cal.fits)
    assert len(cal) == 50 and cal._q.shape == (50, 40, 2)   # a ring of 50 x 40 road ACs
    # Once full, one refit per 10 new pairs; while filling, proportionally more often.
    assert fits[399] - fits[99] == 30
    assert fits[49] <= 50 and est is cal.latest
    assert abs(est.pitch - PITCH) < 1e-6 and abs(est.roll - ROLL) < 1e-6


def test_road_normal_input_errors(rng):
    cal = RoadNormalCalibrator()
    q1, q2, R, t = _road_frame(rng, normal_from_tilt(PITCH, ROLL), count=30)
    with pytest.raises(InputError, match=r'road: expected a bool mask of shape \(30,\)'):
        cal.add(q1, q2, R, t, np.ones(30))
    with pytest.raises(InputError, match=r'R: expected a rotation matrix'):
        cal.add(q1, q2, 3.0 * R, t, np.ones(30, bool))
    with pytest.raises(InputError, match=r't: expected a non-zero direction'):
        cal.add(q1, q2, R, np.zeros(3), np.ones(30, bool))
    with pytest.raises(ConfigError, match=r'expected per_frame >= 10'):
        RoadNormalCalibrator(per_frame=5)
    # Fewer than 10 road ACs: nothing stored, no estimate.
    assert not cal.add(q1, q2, R, t, np.arange(30) < 9)
    assert len(cal) == 0 and cal.update() is None and cal.estimate() is None


# --------------------------------------------------------------------------------------------
# Mount tilt: no lock onto the pitch wobble
# --------------------------------------------------------------------------------------------

def _drive(rng, pairs, *, turn_every=None, wobble=np.deg2rad(0.1), dir_noise=np.deg2rad(0.3),
           pitch=PITCH, roll=0.0):
    """Relative camera motions of a car with pitch wobble; straight, or with turns."""
    motions = []
    for k in range(pairs):
        yaw = np.deg2rad(4.0) if turn_every and k % turn_every < 5 else 0.0
        R, t = _camera_motion(pitch, roll, yaw, (rng.normal(0.0, wobble), 0.0),
                              heading=rng.normal(0.0, dir_noise))
        motions.append((R, t + rng.normal(0.0, dir_noise, 3)))
    return motions


def test_tilt_does_not_lock_onto_the_pitch_wobble_when_driving_straight():
    rng = np.random.default_rng(2)
    motions = _drive(rng, 100)
    locked = MountTiltEstimator(wobble_sigma=0.0)          # every rotation informs the axis
    fixed = MountTiltEstimator()                            # wobble 0.1 deg (the default)
    for R, t in motions:
        locked.add_motion(R, t)
        fixed.add_motion(R, t)
    # The model without the wobble turns the normal towards the camera's x axis (KITTI 05:
    # roll 85-88 deg); the wobble-aware one keeps it, and says the roll is not observed.
    assert abs(locked.estimate().roll) > np.deg2rad(45.0)
    tilt = fixed.estimate()
    assert abs(tilt.pitch - PITCH) < np.deg2rad(0.1)
    assert tilt.roll_std > np.deg2rad(1.0) and abs(tilt.roll) < 3.0 * tilt.roll_std
    # Without the level prior only the translation directions' noise speaks to the roll of
    # straight driving: a large standard deviation, honest about the error.
    blind = MountTiltEstimator(prior_sigma=None)
    for R, t in motions:
        blind.add_motion(R, t)
    tilt = blind.estimate()
    assert tilt.roll_std > np.deg2rad(2.0) and abs(tilt.roll) < 3.0 * tilt.roll_std


def test_tilt_with_turns_and_wobble_recovers_pitch_and_roll():
    rng = np.random.default_rng(4)
    roll = np.deg2rad(-1.5)
    est = MountTiltEstimator()
    for R, t in _drive(rng, 200, turn_every=20, roll=roll):
        est.add_motion(R, t)
    tilt = est.estimate()
    assert abs(tilt.pitch - PITCH) < np.deg2rad(0.1) and abs(tilt.roll - roll) < np.deg2rad(0.3)
    assert abs(tilt.pitch - PITCH) < 3 * tilt.pitch_std
    assert abs(tilt.roll - roll) < 3 * tilt.roll_std
    # Exact motions with turns: exact recovery whatever the wobble setting.
    exact = MountTiltEstimator(prior_sigma=None)
    for k in range(30):
        exact.add_motion(*_camera_motion(PITCH, roll, np.deg2rad(3.0 * (k % 3)), (0.0, 0.0)))
    tilt = exact.estimate()
    assert abs(tilt.pitch - PITCH) < 1e-9 and abs(tilt.roll - roll) < 1e-9


def test_tilt_wobble_is_settable_online_and_refits_are_bounded():
    rng = np.random.default_rng(5)
    est = MountTiltEstimator(max_pairs=50, refit_every=10)
    assert est.update() is None                             # fewer than two pairs
    for k, (R, t) in enumerate(_drive(rng, 500)):
        est.add_motion(R, t)
        est.update()
    assert len(est) == 50 and est._angles.shape == (50,)
    assert est.fits == 1 + (500 - 2) // 10                  # first at 2 pairs, then every 10
    good = est.update()
    assert est.fits == 50 and abs(good.roll) < np.deg2rad(10.0)
    est.wobble_sigma = 0.0                                  # the odometry measured no wobble
    locked = est.update()
    assert est.fits == 51 and abs(locked.roll) > np.deg2rad(45.0)
    est.wobble_sigma = np.deg2rad(0.1)
    assert abs(est.update().roll) < np.deg2rad(10.0)
    with pytest.raises(InputError, match=r'wobble_sigma: expected a non-negative angle'):
        est.wobble_sigma = -1.0
    with pytest.raises(InputError, match=r'weight: expected a non-negative number'):
        est.add_motion(np.eye(3), np.array([0.0, 0.0, -1.0]), -1.0)
    with pytest.raises(ConfigError, match=r'gate, max_pairs, refit_every'):
        MountTiltEstimator(max_pairs=1)


def _seen_through(R, t, k):
    """The relative pose ``(R, t)`` as the odometry finds it through a focal length ``1 / k``
    times the true one: the displacement direction (the epipole) mapped by ``M = diag(k, k,
    1)``, the rotation axis (pulled to the levelling, a normal) by ``M^-T``, the angle with its
    image-plane part's pixel shift kept: ``tan(angle') = |M a| tan(angle)``."""
    c = -R.T @ t
    w = cv2.Rodrigues(R)[0].ravel()
    angle = float(np.linalg.norm(w))
    R_seen = np.eye(3)
    if angle > 0.0:
        axis = w / angle
        seen = axis * np.array([1.0, 1.0, k])
        seen /= np.linalg.norm(seen)
        scale = float(np.linalg.norm(axis * np.array([k, k, 1.0])))
        R_seen = _rotation(seen * math.atan2(scale * math.sin(angle), math.cos(angle)))
    return R_seen, -R_seen @ (np.array([k, k, 1.0]) * c)


def test_focal_pitch_keeps_the_horizon_pixel_and_round_trips():
    for pitch in np.deg2rad([-8.0, -0.5, 0.0, 1.2, 7.0]):
        for f_old, f_new in ((1226.0, 707.1), (500.0, 640.0)):
            moved = focal_pitch(pitch, f_old / f_new)
            assert abs(f_new * math.tan(moved) - f_old * math.tan(pitch)) < 1e-9
            assert abs(focal_pitch(moved, f_new / f_old) - pitch) < 1e-12


def test_tilt_refocus_carries_pairs_seen_through_another_focal_length():
    # Exact motions with turns of a tilted mount, as a provisional focal length 1.7 times too
    # long saw them (KITTI 05 before its first turn): directions and axes disagree about the
    # normal and the fit lands off it; carried to the true focal length it is exact again.
    roll = np.deg2rad(-1.5)
    f_true, f_old = 707.0, 1226.0
    est = MountTiltEstimator(prior_sigma=None)
    for k in range(30):
        R, t = _camera_motion(PITCH, roll, np.deg2rad(3.0 * (k % 3)), (0.0, 0.0))
        est.add_motion(*_seen_through(R, t, f_true / f_old))
    seen = est.update()
    assert abs(seen.pitch - PITCH) > np.deg2rad(0.3)
    est.refocus(f_old / f_true)
    assert est.latest.pitch == focal_pitch(seen.pitch, f_old / f_true)     # carried at once
    tilt = est.update()                                                     # and refitted
    assert est.fits == 2
    assert abs(tilt.pitch - PITCH) < 1e-9 and abs(tilt.roll - roll) < 1e-9
    est.refocus(1.0)
    assert est.update() is tilt                                             # nothing to redo
    # A turn about the optical axis moves pixels alike through any focal length; about the
    # camera's y axis by f tan(angle).
    turns = MountTiltEstimator()
    turns.add_motion(_rotation([0.0, 0.0, np.deg2rad(4.0)]), np.array([0.0, 0.0, -1.0]))
    turns.add_motion(_rotation([0.0, np.deg2rad(4.0), 0.0]), np.array([0.0, 0.0, -1.0]))
    turns.refocus(1.7)
    np.testing.assert_allclose(turns._angles[:2], [np.deg2rad(4.0),
                                                   math.atan(1.7 * math.tan(np.deg2rad(4.0)))])
    with pytest.raises(InputError, match=r'ratio: expected a positive focal-length ratio'):
        est.refocus(0.0)


def test_road_normal_refocus_moves_the_fit_exactly_with_the_focal_length(rng):
    normal = normal_from_tilt(PITCH, ROLL)
    cal = RoadNormalCalibrator(refit_every=5, max_frames=10)
    for _ in range(15):
        q1, q2, R, t = _road_frame(rng, normal)
        assert cal.add(q1, q2, R, t, np.ones(len(q1), bool))
        cal.update()
    before = cal.latest
    assert abs(before.pitch - PITCH) < 1e-9
    ratio = 1226.0 / 707.0
    cal.refocus(ratio)
    assert cal.latest.pitch == focal_pitch(before.pitch, ratio)
    assert cal.latest.roll == before.roll
    fits = cal.fits
    assert cal.update() is cal.latest and cal.fits == fits      # carried, not refitted ...
    after = cal.estimate(0.0, 0.0)                              # ... as a refit would move it
    assert abs(after.pitch - focal_pitch(PITCH, ratio)) < 1e-9 and abs(after.roll - ROLL) < 1e-9
    with pytest.raises(InputError, match=r'ratio: expected a positive focal-length ratio'):
        cal.refocus(float('nan'))


# --------------------------------------------------------------------------------------------
# Focal length
# --------------------------------------------------------------------------------------------

FOCAL = 600.0
WIDTH = HEIGHT_PX = 600


def _pair(rng, yaw_deg, *, n=300, sigma=0.0):
    """ACs of one turning pair in pixels from the principal point (the paper's camera)."""
    syn = shared_motion_acs(rng, n, sigma, alpha=np.deg2rad(yaw_deg),
                            beta=-np.pi / 2 + np.deg2rad(3.0), window=200.0)
    pp = np.asarray(PAPER_PRINCIPAL_POINT)
    return syn.acs.p1 - pp, syn.acs.p2 - pp, syn.acs.A


def test_pair_profile_is_minimal_at_the_true_focal_on_exact_acs(rng):
    p1, p2, A = _pair(rng, 6.0)
    grid = np.log(FOCAL) + np.linspace(-0.5, 0.5, 21)       # the true focal is a grid point
    prof = pair_profile(p1, p2, A, None, grid, 900.0, noise=(0.5, 0.01))
    assert int(np.argmin(prof.cost)) == 10 and prof.cost[10] < 1e-12
    assert abs(prof.alpha[10] - np.deg2rad(6.0)) < 1e-9 and prof.yaw == prof.alpha[10]
    # The valley in between: the parabola of the combined profiles lands within 1 %.
    log_f, std, info = combine_profiles([prof.cost, prof.cost, prof.cost], grid + 0.01)
    assert abs(log_f - (np.log(FOCAL) + 0.01)) < 0.01 and not info['edge']
    with pytest.raises(ConfigError, match=r'log_f_grid: expected at least 3 increasing'):
        pair_profile(p1, p2, A, None, grid[::-1], 900.0)


def test_shifted_profile_predicts_the_focal_length_of_a_moved_principal_point():
    """The first-order profile with the principal point moved by a pixel lands where the
    profile re-minimised on the moved points lands (a tenth of the focal's shift), and is the
    profile itself for no shift."""
    rng = np.random.default_rng(3)
    grid = np.log(FOCAL) + np.linspace(-0.5, 0.5, 41)
    for yaw in (4.0, 6.0, 8.0):
        p1, p2, A = _pair(rng, yaw, sigma=0.3)
        w = np.ones(len(p1))
        prof = pair_profile(p1, p2, A, None, grid, 900.0, noise=(0.5, 0.01))
        assert np.array_equal(shifted_profile(p1, p2, A, w, grid, prof, 0.0), prof.cost)
        moved = np.array([1.0, 0.0])
        again = pair_profile(p1 - moved, p2 - moved, A, None, grid, 900.0, noise=(0.5, 0.01))
        f0, fr, fl = (np.exp(combine_profiles([c] * 3, grid)[0]) for c in (
            prof.cost, again.cost, shifted_profile(p1, p2, A, w, grid, prof, 1.0)))
        assert abs(fr - f0) > 2.0                           # the focal moves: 4-6 px per px
        assert abs((fl - f0) - (fr - f0)) < 0.1 * abs(fr - f0), (yaw, f0, fr, fl)
    with pytest.raises(ConfigError, match=r'shift, step: expected finite pixels and step > 0'):
        shifted_profile(p1, p2, A, w, grid, prof, 1.0, step=0.0)


def test_pair_profile_of_straight_driving_does_not_pin_the_focal(rng):
    syn = shared_motion_acs(rng, 300, 0.3, alpha=0.0, beta=-np.pi / 2)
    pp = np.asarray(PAPER_PRINCIPAL_POINT)
    grid = np.linspace(np.log(150.0), np.log(1500.0), 41)
    prof = pair_profile(syn.acs.p1 - pp, syn.acs.p2 - pp, syn.acs.A, None, grid, 900.0)
    # Flat within the noise: no grid focal is preferred by more than a few chi-square units.
    assert np.ptp(prof.cost) < 0.05 * prof.cost.mean()


def _calibrate(rng, sigma, *, pairs_per_block=2, blocks=4, pp_std=1.0, yaw=(5.0, 8.0),
               drain_at=None):
    """Turning pairs in ``blocks`` blocks, each worked off at once (or all at frame
    ``drain_at``)."""
    cal = OnlineFocalCalibrator(WIDTH, HEIGHT_PX, pp_std=pp_std)
    frame = 0
    for b in range(blocks):
        for k in range(pairs_per_block):
            frame = 10 * b + 3 * k + 1
            assert cal.offer(frame, *_pair(rng, rng.uniform(*yaw) * rng.choice([-1, 1]),
                                           sigma=sigma))
            if drain_at is None:
                cal.work(1000, frame)
    if drain_at is not None:
        cal.work(1000, drain_at)
    return cal


def test_focal_calibration_adopts_an_accurate_focal_from_exact_turning_pairs(rng):
    cal = _calibrate(rng, 0.0)
    f, std, info = cal.estimate()
    assert info['blocks'] == 4 and cal.pairs == 8 and cal.pending == 0
    assert abs(f / FOCAL - 1.0) < 0.01 and std < 0.02 * f
    assert cal.adopted == f and cal.adopted_at == 31 and cal.provisional == f
    assert cal.relative_std == pytest.approx(std / f)
    # Adopted with the first pair of the fourth block; its second pair moved the value.
    assert cal.updated_at == 34
    assert cal.status() == (f'focal length {f:.1f} +- {std:.1f} px (self-calibrated at frame 31, '
                            f'updated at frame 34)')
    # Adopted when the work that finishes the profiles runs: its frame is named.
    late = _calibrate(np.random.default_rng(20240607), 0.0, drain_at=99)
    assert late.adopted == pytest.approx(f) and late.adopted_at == 99
    # A later block moves it again: the status says since when.
    assert cal.offer(41, *_pair(rng, 6.0))
    cal.work(1000, 42)
    assert cal.adopted != f and cal.adopted_at == 31 and cal.updated_at == 42
    assert cal.status() == (f'focal length {cal.adopted:.1f} +- {cal.adopted_std:.1f} px '
                            f'(self-calibrated at frame 31, updated at frame 42)')


def test_an_adopted_focal_length_that_grew_uncertain_says_so(rng, monkeypatch):
    """Between the tolerance and twice it the adopted value stays, its standard deviation the
    calibration's: the status says it is uncertain again, not 'updated' (a user test: 'updated
    at frame 90' when only the +- had grown to 36 % against a 23 % tolerance)."""
    cal = _calibrate(rng, 0.0)
    adopted, tolerance = cal.adopted, cal.tolerance
    info = {'blocks': 4, 'edge': False}
    monkeypatch.setattr(cal, 'estimate',
                        lambda: (1.005 * adopted, 1.5 * tolerance * adopted, info))
    assert not cal.update_adoption(50)
    assert (cal.adopted, cal.adopted_std, cal.updated_at, cal.widened_at) == (
        adopted, 1.5 * tolerance * adopted, 34, 50)
    assert cal.status() == (f'focal length {adopted:.1f} +- {cal.adopted_std:.1f} px '
                            f'(self-calibrated at frame 31, updated at frame 34; uncertain again '
                            f'since frame 50: 3.0 % against the 2 % it was adopted at, revoked '
                            f'above 4 %)')
    # precise again: adopted anew, no longer said to be uncertain
    monkeypatch.setattr(cal, 'estimate', lambda: (1.002 * adopted, 0.01 * adopted, info))
    assert cal.update_adoption(60)
    assert cal.widened_at is None and cal.status().endswith('updated at frame 60)')


def test_an_adopted_focal_length_the_calibration_no_longer_supports_is_revoked(caplog):
    """A review: blocks whose pixels say another focal length (here 1.4 times the adopted one:
    a zoomed lens, or evidence that disagrees) moved the estimate far off, while the adopted
    value, its standard deviation and 'self-calibrated' stayed. Now it is revoked: provisional
    again, said in the status and the log."""
    rng = np.random.default_rng(0)
    cal = _calibrate(rng, 0.3)
    adopted, adopted_std = cal.adopted, cal.adopted_std
    assert adopted is not None and abs(adopted - FOCAL) <= 3.0 * adopted_std
    with caplog.at_level('WARNING', logger='planar_vo.pipeline.calibration.focal'):
        for b in range(4, 12):
            for k in range(2):
                frame = 10 * b + 3 * k + 1
                p1, p2, A = _pair(rng, rng.uniform(5.0, 8.0) * rng.choice([-1, 1]), sigma=0.3)
                assert cal.offer(frame, 1.4 * p1, 1.4 * p2, A)
                cal.work(1000, frame)
                if cal.adopted is not None:         # kept only while the estimate agrees
                    f, std, _ = cal.estimate()
                    assert abs(f - cal.adopted) <= std and cal.adopted_std >= std
    f, std, _ = cal.estimate()
    assert abs(f - adopted) > 3.0 * adopted_std
    assert cal.adopted is None and cal.adopted_at is None and cal.revoked_at is not None
    assert cal.provisional != adopted
    assert cal.status().endswith(f'; an adopted value revoked at frame {cal.revoked_at})')
    assert '(provisional, ' in cal.status()
    revoked = [r.getMessage() for r in caplog.records if 'revoked' in r.getMessage()]
    assert len(revoked) == 1 and revoked[0].startswith(
        f'focal length self-calibration revoked at frame {cal.revoked_at}: the calibration now '
        f'gives ')


def test_focal_calibration_uncertainty_is_honest_on_noisy_pairs():
    rng = np.random.default_rng(8)
    for _ in range(4):
        cal = _calibrate(rng, 0.7, pp_std=None)             # principal point assumed: 6 px
        f, std, info = cal.estimate()
        assert abs(f - FOCAL) <= 3.0 * std, (f, std)
        if cal.adopted is not None:
            assert abs(cal.adopted - FOCAL) <= 3.0 * cal.adopted_std
        else:                                               # enough blocks, not precise enough
            assert cal.status().endswith(f'(provisional, calibration {f:.1f} +- '
                                         f'{100 * std / f:.1f} %, adopted once below 2 %)')


def test_provisional_focal_uses_the_calibration_from_two_blocks_on():
    """Before adoption (4 blocks) the provisional focal length combines the prior with the
    calibration as soon as two blocks give a sandwich (its one degree of freedom widened by
    `few_cluster_factor`): during a first turn the odometry stops running on the prior."""
    rng = np.random.default_rng(5)
    cal = OnlineFocalCalibrator(WIDTH, HEIGHT_PX, nominal=1000.0, pp_std=1.0)
    for b in range(2):
        for k in range(2):
            assert cal.offer(10 * b + 3 * k + 1, *_pair(rng, rng.uniform(5.0, 8.0), sigma=0.7))
            cal.work(1000, 10 * b + 3 * k + 1)
        if b == 0:                                          # one block: the prior alone
            assert cal.provisional == pytest.approx(1000.0) and cal.blocks == 1
    assert cal.blocks == 2 and cal.adopted is None
    assert '(provisional, 2 of 4 blocks)' in cal.status()
    f = cal.provisional
    # The prior (1000 px) is left behind: most of the way to the truth, and the uncertainty
    # (1 sigma, log-normal) covers what is left.
    assert abs(math.log(f / FOCAL)) < 0.25 * math.log(1000.0 / FOCAL), f
    assert abs(math.log(f / FOCAL)) <= 3.0 * math.log1p(cal.relative_std)
    assert cal.relative_std < math.exp(0.45) - 1.0


def test_focal_calibration_stays_provisional_without_turns(rng):
    cal = OnlineFocalCalibrator(WIDTH, HEIGHT_PX)
    assert cal.provisional == 600.0 and cal.relative_std == pytest.approx(math.exp(0.45) - 1)
    assert cal.status() == ('focal length 600.0 +- 341.0 px (provisional, no turn to calibrate '
                            'from yet: an assumed 53-degree field of view, 0 of 4 blocks)')
    for b in range(5):
        syn = shared_motion_acs(rng, 300, 0.5, alpha=0.0, beta=-np.pi / 2)
        pp = np.asarray(PAPER_PRINCIPAL_POINT)
        cal.offer(10 * b, syn.acs.p1 - pp, syn.acs.p2 - pp, syn.acs.A)
        cal.work(1000, 10 * b)
    assert cal.adopted is None and '(provisional' in cal.status()
    assert cal.relative_std > 0.2                           # the odometry knows it is unsure


def test_focal_work_is_stepwise_bounded_and_deterministic(rng):
    cal = OnlineFocalCalibrator(WIDTH, HEIGHT_PX, max_queue=3)
    pairs = [_pair(rng, 6.0, n=60) for _ in range(4)]
    assert all(cal.offer(5, *p) for p in pairs[:3])
    assert not cal.offer(5, *pairs[3]) and cal.dropped == 1  # the queue is full: counted
    assert not cal.offer(5, *[x[:59] for x in pairs[3]])    # too few ACs (3 x min_inliers)
    assert cal.work(0.0) == 0 and cal.pending == 3
    # A step is about 10,000 AC evaluations: a pair of 60 ACs is 3 steps (a vote, all 41 grid
    # focal lengths, the first-order profile with the principal point shifted).
    assert cal.work(2, 7) == 2 and cal.pairs == 0
    assert cal.work(1, 8) == 1 and cal.pairs == 1 and cal.pending == 2
    # Fractional steps carry over: 0.25 steps a frame run one step every fourth frame, counted
    # in steps (not seconds), so the same frames give the same calibration at any load.
    steps = [cal.work(0.25) for _ in range(24)]
    assert steps == [0, 0, 0, 1] * 6 and cal.steps == 3 + 6 and cal.pairs == 3
    # Nothing is saved up while the queue is empty.
    cal.work(100)
    assert cal.pending == 0 and cal.work(5.0) == 0
    cal.offer(50, *pairs[3])
    assert cal.work(0.5) == 0 and cal.work(0.5) == 1
    # A pair of 1,250 ACs takes 8 grid focal lengths a step: a vote, 6 chunks, the shifted
    # profile.
    cal.work(100)
    cal.offer(60, *_pair(rng, 6.0, n=1250))
    assert cal.work(100) == 8 and cal.pairs == 5
    # The chunk follows the ACs kept (`max_acs`), not those offered.
    small = OnlineFocalCalibrator(WIDTH, HEIGHT_PX, max_acs=400)
    small.offer(70, *_pair(rng, 6.0, n=1250))
    assert small.work(100) == 4 and small.pairs == 1
    with pytest.raises(InputError, match=r'steps: expected a non-negative number of work steps'):
        cal.work(-1.0)


def test_focal_work_keeps_pace_with_a_turn(rng):
    """A turn offers a pair of about 400 ACs every other frame (`TurnPairSelector`'s stride);
    at the default 2 steps a frame each is profiled before the next arrives, so the provisional
    focal length follows the turn instead of a growing queue (with 8 grid focal lengths a step,
    such pairs took 8 steps and the queue grew by one pair every 4 frames)."""
    cal = OnlineFocalCalibrator(WIDTH, HEIGHT_PX)
    pending = []
    for frame in range(40):
        if frame % 2 == 0:
            assert cal.offer(frame, *_pair(rng, 6.0, n=400))
        cal.work(CameraConfig.focal_steps, frame)
        pending.append(cal.pending)
    assert max(pending) == 1 and cal.pending == 0 and cal.pairs == 20 and cal.dropped == 0
    assert abs(cal.provisional / FOCAL - 1.0) < 0.02


def test_focal_blocks_are_bounded(rng):
    cal = OnlineFocalCalibrator(WIDTH, HEIGHT_PX, pp_std=0.0, min_blocks=2, max_blocks=2)
    for b in range(4):
        cal.offer(10 * b, *_pair(rng, 6.0, n=120))
        assert cal.work(100) == 2                 # one profile of 120 ACs: the vote, the grid
    assert cal.blocks == 2 and cal.pairs == 4


def test_focal_calibrator_input_errors(rng):
    with pytest.raises(ConfigError, match=r'width, height: expected a positive image size'):
        OnlineFocalCalibrator(0, 10)
    with pytest.raises(ConfigError, match=r'focal_min_blocks: expected at least 2, got 1'):
        OnlineFocalCalibrator(WIDTH, HEIGHT_PX, min_blocks=1)
    cal = OnlineFocalCalibrator(WIDTH, HEIGHT_PX)
    p1, p2, A = _pair(rng, 6.0, n=60)
    with pytest.raises(InputError, match=r'same number of items'):
        cal.offer(1, p1, p2[:-1], A)


def test_turn_pair_selector_picks_turns_within_the_pixel_window():
    sel = TurnPairSelector(600)                             # 4-13 % of 600 px: 24-78 px
    f = 600.0
    step = math.atan(13.0 / f)                              # 13 px of rotation per keyframe
    picks = [sel.step(k, step, f) for k in range(10)]
    # Two steps (26 px) reach the lower bound; then at most every second keyframe.
    assert picks == [None, None, 0, None, 2, None, 4, None, 6, None]
    straight = TurnPairSelector(600)
    assert all(straight.step(k, 0.0, f) is None for k in range(20))
    fast = TurnPairSelector(600)                            # 90 px per step: beyond 13 %
    assert all(fast.step(k, math.atan(90.0 / f), f) is None for k in range(5))
    with pytest.raises(InputError, match=r'expected a finite yaw and a positive focal'):
        sel.step(11, float('nan'), f)
    with pytest.raises(ConfigError, match=r'0 < min_shift < max_shift'):
        TurnPairSelector(600, min_shift=0.2)


def test_a_pair_goes_into_the_block_its_caller_names():
    """`offer(block=...)`: the pipeline's blocks in time (about a second at any frame rate)
    rather than ``frame // block_frames``; without it, the frame's."""
    rng = np.random.default_rng(3)
    cal = OnlineFocalCalibrator(WIDTH, HEIGHT_PX, pp_std=1.0)
    assert cal.offer(5, *_pair(rng, 6.0), block=7)
    assert cal.offer(25, *_pair(rng, -7.0), block=7)          # another block by its frame
    assert cal.offer(31, *_pair(rng, 5.0))                     # 31 // 10
    cal.work(1000, 31)
    assert sorted(cal._blocks) == [3, 7] and cal.pairs == 3


def test_a_field_of_view_known_precisely_keeps_the_provisional_focal_near_it():
    """camera.nominal_fov_std (a user test: a correct data-sheet field of view barely counted
    against the wide prior): the prior's width in log focal length follows from the field of
    view's standard deviation, and a tight one holds the provisional focal length where a wide
    one lets the turns' profiles move it."""
    from planar_vo.pipeline.calibration import prior_sigma_for_fov

    fov, std = 1.43, 0.0175
    assert prior_sigma_for_fov(fov, std) == pytest.approx(std / math.sin(fov))
    assert prior_sigma_for_fov(3.0, std, fisheye=True) == pytest.approx(std / 3.0)
    assert prior_sigma_for_fov(fov, 0.0) == 1e-3
    nominal = 1.08 * FOCAL                                       # the stated value, 8 % long
    provisional = {}
    for sigma in (None, prior_sigma_for_fov(fov, std)):
        rng = np.random.default_rng(5)
        cal = OnlineFocalCalibrator(WIDTH, HEIGHT_PX, nominal, pp_std=1.0, prior_sigma=sigma,
                                    min_blocks=10)             # calibrates, never adopts
        for b in range(3):
            assert cal.offer(10 * b + 1, *_pair(rng, 7.0, sigma=0.5))
            cal.work(1000, 10 * b + 1)
        assert cal.adopted is None
        provisional[sigma is None] = cal.provisional
    # The wide prior follows the profiles to the truth; the tight one stays between, nearer
    # the stated value (both as a posterior should: the profiles here are sharp).
    assert abs(provisional[True] / FOCAL - 1) < 0.01
    assert provisional[True] < provisional[False] < nominal
    assert provisional[False] - FOCAL > 0.25 * (nominal - FOCAL)
    cal = OnlineFocalCalibrator(WIDTH, HEIGHT_PX, nominal, prior_fov=fov, stated=True,
                                prior_sigma=prior_sigma_for_fov(fov, std), prior_fov_std=std)
    assert 'the stated 82 +- 1-degree field of view' in cal.status()
