"""Minimal solvers: exact recovery, degenerate cases, noise behaviour and input checks."""

from __future__ import annotations

import warnings
from decimal import Decimal

import numpy as np
import pytest

from planar_vo.core import (
    ac_residuals,
    angle_difference,
    camera_displacement,
    planar_ac_matrix,
    planar_essential,
    rotation_y,
    solve_1ac,
    solve_1acf,
    solve_2pc,
    solve_3pc,
    translation_direction,
)
from planar_vo.errors import InputError, PlanarVoError
from planar_vo.sim.synthetic import paper_trial, random_exact_acs

EXACT = 1e-9          # rad, the exact-data bound
N_EXACT = 5000        # random cases for exact recovery
MAX_COND = 1e6        # 'non-degenerate': condition number of the AC's 3x4 system


def _cond(B: np.ndarray) -> np.ndarray:
    s = np.linalg.svd(B, compute_uv=False)
    return s[:, 0] / s[:, 2]


def _err(est, truth) -> np.ndarray:
    return np.abs(angle_difference(est, truth))


# ---------------------------------------------------------------------------------------------
# Conventions
# ---------------------------------------------------------------------------------------------

def test_essential_matches_t_cross_r(rng):
    a, b = rng.uniform(-np.pi, np.pi, (2, 50))
    t = translation_direction(b)
    tx = np.zeros((50, 3, 3))
    tx[:, 0, 1], tx[:, 0, 2], tx[:, 1, 2] = -t[:, 2], t[:, 1], -t[:, 0]
    tx -= np.swapaxes(tx, 1, 2)
    np.testing.assert_allclose(planar_essential(a, b), tx @ rotation_y(a), atol=1e-15)


def test_forward_driving_is_beta_minus_90_and_left_turn_is_positive_alpha():
    # Camera 2 one unit ahead along the optical axis: t = -[0, 0, 1] -> beta = -pi/2.
    np.testing.assert_allclose(camera_displacement(0.0, -np.pi / 2), [0.0, 0.0, 1.0], atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(camera_displacement(0.3, 1.0)), 1.0)
    # Positive alpha: the new optical axis (in frame 1) points to the camera's -x (left).
    axis = rotation_y(0.2).T @ np.array([0.0, 0.0, 1.0])
    assert axis[0] < 0.0


# ---------------------------------------------------------------------------------------------
# 1AC
# ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize('refine', [False, True])
def test_1ac_exact_recovery(rng, refine):
    s = random_exact_acs(rng, N_EXACT)
    alpha, beta = solve_1ac(s.normalized.p1, s.normalized.p2, s.normalized.A, refine=refine)
    err = np.maximum(_err(alpha, s.alpha), _err(beta, s.beta))
    cond = _cond(planar_ac_matrix(s.normalized.p1, s.normalized.p2, s.normalized.A))
    good = cond < MAX_COND
    assert good.mean() > 0.99
    assert err[good].max() < EXACT                      # includes the sign of t (beta mod 2 pi)
    assert np.median(err) < 1e-12
    # Near-degenerate samples degrade gracefully, in proportion to their conditioning.
    assert np.all(err[~good] < 1e-15 * cond[~good] * 100)


def test_1ac_sign_of_translation_from_cheirality(rng):
    s = random_exact_acs(rng, 2000)
    _, beta = solve_1ac(s.normalized.p1, s.normalized.p2, s.normalized.A)
    # Flipping t would be an error of pi; none may occur.
    assert np.all(_err(beta, s.beta) < 1e-6)


def test_1ac_forward_motion_gives_beta_minus_90(rng):
    t = paper_trial(rng, 0.0, motion='forward')
    alpha, beta = solve_1ac(t.normalized.p1, t.normalized.p2, t.normalized.A)
    np.testing.assert_allclose(alpha, 0.0, atol=EXACT)
    np.testing.assert_allclose(beta, -np.pi / 2, atol=EXACT)


def test_ac_residuals_refuse_angles_of_another_length(rng):
    s = random_exact_acs(rng, 20)
    n = s.normalized
    with pytest.raises(InputError, match=r'^alpha: expected one angle or one per AC, shape \(\) '
                                         r'or \(20,\), got \(21,\)$'):
        ac_residuals(n.p1, n.p2, n.A, np.zeros(21), 0.0)
    with pytest.raises(InputError, match=r'^alpha, beta: expected angles in radians'):
        ac_residuals(n.p1, n.p2, n.A, 0.0, 'left')
    # Non-finite angles, as the solvers refuse non-finite ACs (a user test: NaN residuals).
    with pytest.raises(InputError, match=r'^alpha: expected finite angles, got nan$'):
        ac_residuals(n.p1, n.p2, n.A, np.nan, -1.5)
    beta = np.full(20, -1.5)
    beta[7] = np.inf
    with pytest.raises(InputError, match=r'^beta: expected finite angles, got a non-finite one$'):
        ac_residuals(n.p1, n.p2, n.A, 0.0, beta)


def test_1ac_residuals_vanish_at_truth(rng):
    s = random_exact_acs(rng, 500)
    r = ac_residuals(s.normalized.p1, s.normalized.p2, s.normalized.A, s.alpha, s.beta)
    assert r.shape == (500, 3)
    assert np.abs(r).max() < 1e-12


def test_1ac_horizon_point_is_degenerate():
    # A point at the camera's height (v = 0 in both views) has a vanishing epipolar row and a
    # vanishing first affine row: B has rank 1 and the motion is not determined.
    q1 = np.array([[0.1, 0.0]])
    q2 = np.array([[0.2, 0.0]])
    A = np.array([[[1.1, 0.05], [0.0, 1.05]]])
    B = planar_ac_matrix(q1, q2, A)
    assert np.linalg.matrix_rank(B[0]) == 1
    alpha, beta = solve_1ac(q1, q2, A)
    assert np.isnan(alpha[0]) and np.isnan(beta[0])


def test_1ac_refinement_helps_under_noise(rng):
    plain, refined = [], []
    for _ in range(100):
        t = paper_trial(rng, 0.5)
        n = t.normalized
        plain.append(_err(solve_1ac(n.p1, n.p2, n.A)[1], t.beta))
        refined.append(_err(solve_1ac(n.p1, n.p2, n.A, refine=True)[1], t.beta))
    assert np.median(np.concatenate(refined)) < np.median(np.concatenate(plain))


def _median_errors_deg(rng, sigma, trials=150, refine=True):
    ea, eb = [], []
    for _ in range(trials):
        t = paper_trial(rng, sigma)
        a, b = solve_1ac(t.normalized.p1, t.normalized.p2, t.normalized.A, refine=refine)
        ea.append(_err(a, t.alpha))
        eb.append(_err(b, t.beta))
    return np.rad2deg(np.median(np.concatenate(ea))), np.rad2deg(np.median(np.concatenate(eb)))


def test_1ac_noise_errors_grow_smoothly_and_stay_bounded(rng):
    sigmas = [0.0, 0.1, 0.25, 0.5, 1.0]
    errors = np.array([_median_errors_deg(rng, s) for s in sigmas])
    assert errors[0].max() < 1e-9
    # Monotone growth with sigma, roughly linear: doubling the noise does not triple the error.
    assert np.all(np.diff(errors, axis=0) > 0)
    ratio = errors[4] / errors[3]
    assert np.all((ratio > 1.3) & (ratio < 3.0))
    # Per-AC (single minimal sample) median errors in degrees, paper protocol.
    alpha_05, beta_05 = errors[3]
    alpha_10, beta_10 = errors[4]
    assert alpha_05 < 0.6 and beta_05 < 3.0
    assert alpha_10 < 1.2 and beta_10 < 6.0


# ---------------------------------------------------------------------------------------------
# 1ACf
# ---------------------------------------------------------------------------------------------

def test_1acf_exact_focal_and_motion(rng):
    s = random_exact_acs(rng, N_EXACT)
    p1, p2 = s.centered
    alpha, beta, focal, weight = solve_1acf(p1, p2, s.acs.A, return_weight=True)
    cond = _cond(planar_ac_matrix(s.normalized.p1, s.normalized.p2, s.normalized.A))
    good = (weight > 0.01) & (cond < MAX_COND)
    assert good.mean() > 0.9
    assert np.max(np.abs(focal[good] / s.focal - 1.0)) < 1e-9
    assert np.max(_err(alpha[good], s.alpha[good])) < EXACT
    assert np.max(_err(beta[good], s.beta[good])) < EXACT
    assert np.nanmedian(np.abs(focal / s.focal - 1.0)) < 1e-12
    assert np.all((weight >= 0.0) & (weight <= 1.0))


@pytest.mark.parametrize('focal', [300.0, 1200.0])
def test_1acf_other_focal_lengths(rng, focal):
    s = random_exact_acs(rng, 500, K=np.array([[focal, 0, 320.0], [0, focal, 240.0], [0, 0, 1]]))
    p1, p2 = s.centered
    _, _, f, w = solve_1acf(p1, p2, s.acs.A, return_weight=True)
    good = w > 0.05
    assert np.nanmedian(np.abs(f[good] / focal - 1.0)) < 1e-12


def test_1acf_straight_driving_is_not_a_confident_focal(rng):
    # alpha = 0: n2^2 = n4^2 and n1^2 = n3^2, f^2 = 0/0. Must be NaN or carry ~zero weight.
    t = paper_trial(rng, 0.0, motion='forward')
    p1, p2 = t.centered
    _, _, focal, weight = solve_1acf(p1, p2, t.acs.A, return_weight=True)
    assert np.all(np.isnan(focal) | (weight < 1e-6))
    wrong = np.isfinite(focal) & (np.abs(focal / t.focal - 1.0) > 0.01)
    assert np.all(weight[wrong] < 1e-6)


def test_1acf_degenerate_acs_give_nan_without_warnings():
    # Identical points and identity affines carry no motion: NaN, no RuntimeWarning (a review:
    # 0 x inf warned from inside the solver).
    p = np.random.default_rng(0).normal(size=(5, 2))
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        alpha, beta, focal = solve_1acf(p, p, np.tile(np.eye(2), (5, 1, 1)))
    assert np.isnan(alpha).all() and np.isnan(beta).all() and np.isnan(focal).all()


def test_1acf_weight_tracks_yaw(rng):
    # The conditioning weight |sin^2(a+b) - sin^2 b| = |sin a sin(a + 2b)| grows with |alpha|.
    ws = []
    for yaw in (0.5, 2.0, 8.0):
        s = random_exact_acs(np.random.default_rng(1), 2000, max_yaw_deg=yaw)
        p1, p2 = s.centered
        ws.append(np.median(solve_1acf(p1, p2, s.acs.A, return_weight=True)[3]))
    assert ws[0] < ws[1] < ws[2]


def test_1acf_noise_bounds(rng):
    errors = {}
    for sigma in (0.5, 1.0):
        rel = []
        for _ in range(150):
            t = paper_trial(rng, sigma)
            p1, p2 = t.centered
            _, _, f, w = solve_1acf(p1, p2, t.acs.A, return_weight=True)
            rel.append(np.abs(f[w > 0.1] / t.focal - 1.0))
        errors[sigma] = np.nanmedian(np.concatenate(rel))
    assert errors[0.5] < errors[1.0] < 0.3
    assert errors[0.5] < 0.15


# ---------------------------------------------------------------------------------------------
# Point baselines
# ---------------------------------------------------------------------------------------------

def test_3pc_exact(rng):
    errs = []
    for _ in range(300):
        t = paper_trial(rng, 0.0)
        idx = rng.permutation(len(t))[:30].reshape(10, 3)
        a, b = solve_3pc(t.normalized.p1[idx], t.normalized.p2[idx])
        errs.append(np.maximum(_err(a, t.alpha), _err(b, t.beta)))
    assert np.max(errs) < EXACT


def test_2pc_exact_one_root_is_the_truth(rng):
    errs = []
    for _ in range(300):
        t = paper_trial(rng, 0.0)
        idx = rng.permutation(len(t))[:20].reshape(10, 2)
        a, b = solve_2pc(t.normalized.p1[idx], t.normalized.p2[idx])
        assert a.shape == b.shape == (10, 2)
        e = np.maximum(_err(a, t.alpha), _err(b, t.beta))
        errs.append(np.nanmin(e, axis=1))
    assert np.max(errs) < EXACT


def test_point_solvers_degrade_with_noise(rng):
    med = []
    for sigma in (0.0, 0.5, 1.0):
        e = []
        for _ in range(100):
            t = paper_trial(rng, sigma)
            idx = rng.permutation(len(t))[:30].reshape(10, 3)
            e.append(_err(solve_3pc(t.normalized.p1[idx], t.normalized.p2[idx])[0], t.alpha))
        med.append(np.median(np.concatenate(e)))
    assert med[0] < 1e-10 < med[1] < med[2]


# ---------------------------------------------------------------------------------------------
# Input checks
# ---------------------------------------------------------------------------------------------

GOOD_Q = np.zeros((3, 2)) + 0.1
GOOD_A = np.tile(np.eye(2), (3, 1, 1))


@pytest.mark.parametrize(('args', 'match'), [
    ((np.zeros((3, 3)), GOOD_Q, GOOD_A), r'q1: expected shape \(N, 2\), got \(3, 3\)'),
    ((GOOD_Q, np.zeros(3), GOOD_A), r'q2: expected shape \(N, 2\), got \(3,\)'),
    ((GOOD_Q, GOOD_Q, np.zeros((3, 4))), r'A: expected shape \(N, 2, 2\), got \(3, 4\)'),
    ((GOOD_Q, GOOD_Q, GOOD_A[:2]), r'same number of items: q1 has 3, q2 has 3, A has 2'),
    ((np.zeros((0, 2)), np.zeros((0, 2)), np.zeros((0, 2, 2))), r'q1: expected at least 1 item'),
    ((np.where(GOOD_Q == GOOD_Q, np.nan, 0), GOOD_Q, GOOD_A), r'q1: expected finite values, '
     r'got 6 NaN or infinite'),
    ((GOOD_Q, GOOD_Q, GOOD_A + np.inf), r'A: expected finite values'),
    (('abc', GOOD_Q, GOOD_A), r'q1: expected a numeric array'),
    # a cast would drop the imaginary part (numpy only warns): refused
    ((GOOD_Q + 1e-3j, GOOD_Q, GOOD_A), r'q1: expected a numeric array of shape \(N, 2\) of real '
     r'numbers, got complex128 values'),
    # Python ints and Decimals beyond float64: typed errors, not OverflowError
    ((np.array([[10**400, 0]] * 3, dtype=object), GOOD_Q, GOOD_A),
     r'q1: expected finite values, got a number too large for float64'),
    ((GOOD_Q, GOOD_Q, [[[1, Decimal('1e400')], [0, 1]]] * 3),
     r'A: expected finite values, got 3 NaN or infinite'),
    (([[0.1, 0.1], [0.1, 0.1], [0.1]], GOOD_Q, GOOD_A), r'q1: expected a numeric array of shape '
     r'\(N, 2\), got list'),
])
def test_1ac_input_errors(args, match):
    with pytest.raises(InputError, match=match):
        solve_1ac(*args)


def test_1acf_input_errors_name_pixel_arguments():
    with pytest.raises(InputError, match=r'p1: expected shape \(N, 2\)'):
        solve_1acf(np.zeros((3, 3)), GOOD_Q, GOOD_A)
    with pytest.raises(InputError, match=r'p2: expected finite'):
        solve_1acf(GOOD_Q, GOOD_Q * np.nan, GOOD_A)


@pytest.mark.parametrize(('solver', 'k'), [(solve_3pc, 3), (solve_2pc, 2)])
def test_point_solver_input_errors(solver, k):
    with pytest.raises(InputError, match=rf'q1: expected shape \(N, {k}, 2\), got \(4, 2\)'):
        solver(np.zeros((4, 2)), np.zeros((4, 2)))
    with pytest.raises(InputError, match=r'same number of items'):
        solver(np.zeros((4, k, 2)), np.zeros((5, k, 2)))


def test_errors_share_one_root():
    with pytest.raises(PlanarVoError):
        solve_1ac(np.zeros((3, 3)), GOOD_Q, GOOD_A)
    assert issubclass(InputError, ValueError)


def test_scalar_options_of_the_solvers_are_checked():
    """(a user test: iterations=1.5 raised a bare TypeError and -1 was taken; min_weight='x'
    raised numpy's UFuncTypeError and NaN made every output NaN)"""
    rng = np.random.default_rng(4)
    acs = random_exact_acs(rng, 5)
    q1, q2, A = acs.normalized.p1, acs.normalized.p2, acs.normalized.A
    for bad in (1.5, -1, True, '3'):
        with pytest.raises(InputError, match=r'^iterations: expected a non-negative integer'):
            solve_1ac(q1, q2, A, refine=True, iterations=bad)
    assert np.isfinite(solve_1ac(q1, q2, A, refine=True, iterations=np.int64(2))[0]).all()
    for bad in ('x', float('nan'), -0.1, float('inf'), None):
        with pytest.raises(InputError, match=r'^min_weight: expected a finite weight >= 0'):
            solve_1acf(*acs.centered, acs.acs.A, min_weight=bad)


def test_correspondences_refuse_negative_weights_and_cameras_stay_read_only_when_pickled():
    import pickle

    from planar_vo.core import AffineCorrespondences, CameraModel

    p = np.zeros((2, 2))
    A = np.broadcast_to(np.eye(2), (2, 2, 2))
    with pytest.raises(InputError, match=r'^weights: expected non-negative weights, got minimum '
                                         r'-1\.0$'):
        AffineCorrespondences(p, p, A, weights=[1.0, -1.0])
    assert len(AffineCorrespondences(p, p, A, weights=[0.0, 2.0])) == 2
    camera = pickle.loads(pickle.dumps(CameraModel.pinhole(64, 48, 50.0)))
    assert camera == CameraModel.pinhole(64, 48, 50.0) and not camera.K.flags.writeable


def test_affine_correspondences_compare_by_identity_and_keep_read_only_copies(rng):
    """A frozen dataclass of arrays compared and hashed its fields (a user test: ``a == b``
    raised 'truth value of an array is ambiguous', ``{a}`` unhashable); the caller's arrays
    were kept, writable, past the checks."""
    from planar_vo.core import AffineCorrespondences

    p1, p2 = rng.uniform(0, 100, (5, 2)), rng.uniform(0, 100, (5, 2))
    A = np.tile(np.eye(2), (5, 1, 1))
    a, b = AffineCorrespondences(p1, p2, A), AffineCorrespondences(p1, p2, A)
    assert a == a and a != b and a in [a] and b not in [a] and len({a, b}) == 2
    p1[0, 0] = np.nan                       # the caller's array, written afterwards
    assert np.isfinite(a.p1).all() and not np.shares_memory(a.p1, p1)
    for name in ('p1', 'p2', 'A', 'weights'):
        assert not getattr(a, name).flags.writeable, name
    sub = a.subset(np.array([0, 2]))        # derived containers are read-only too
    assert not sub.p1.flags.writeable and np.array_equal(sub.p1, a.p1[[0, 2]])
