"""Robust estimation: histogram voting, RANSAC, flags, covariance, focal variant, calibrator."""

from __future__ import annotations

import numpy as np
import pytest

from planar_vo.config import VotingConfig
from planar_vo.core import (
    AffineCorrespondences,
    angle_difference,
    vote_planar_motion,
    vote_planar_motion_focal,
)
from planar_vo.errors import ConfigError, InputError
from planar_vo.sim.synthetic import shared_motion_acs

DEG = np.pi / 180.0


def _vote(acs, **kwargs):
    """`vote_planar_motion` on a synthetic set's normalised ACs."""
    n = acs.normalized
    return vote_planar_motion(n.p1, n.p2, n.A, **kwargs)


def _errors_deg(motion, acs) -> tuple[float, float]:
    return (abs(float(angle_difference(motion.alpha, acs.alpha))) / DEG,
            abs(float(angle_difference(motion.beta, acs.beta))) / DEG)


# ---------------------------------------------------------------------------------------------
# Exact data
# ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize('outliers', [0.0, 0.5, 0.8])
@pytest.mark.parametrize('method', ['histogram', 'ransac'])
def test_noise_free_exact_through_the_whole_estimator(rng, outliers, method):
    for _ in range(3):
        acs = shared_motion_acs(rng, 2000, 0.0, outlier_ratio=outliers)
        motion, stats = _vote(acs,
                              config=VotingConfig(method=method))
        assert stats.reliable, stats.flag
        assert abs(angle_difference(motion.alpha, acs.alpha)) < 1e-9
        assert abs(angle_difference(motion.beta, acs.beta)) < 1e-9
        # Every true AC is an inlier; mismatches are not.
        truth = ~acs.outliers
        assert np.all(stats.inliers[truth])
        assert np.count_nonzero(stats.inliers & ~truth) <= 0.01 * np.count_nonzero(~truth) + 1


def test_forward_motion_exact(rng):
    acs = shared_motion_acs(rng, 1000, 0.0, motion='forward')
    motion, stats = _vote(acs)
    assert abs(motion.alpha) < 1e-9 and abs(motion.beta + np.pi / 2) < 1e-9


# ---------------------------------------------------------------------------------------------
# The accuracy requirements: 4,000 ACs, 0.5 px, 0-90 % outliers
# ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize('outliers', [0.0, 0.5, 0.7])
def test_accuracy_4000_acs_half_pixel(outliers):
    for seed in range(6):
        acs = shared_motion_acs(np.random.default_rng(seed), 4000, 0.5, outlier_ratio=outliers)
        motion, stats = _vote(acs)
        ea, eb = _errors_deg(motion, acs)
        assert stats.reliable, stats.flag
        assert ea < 0.05, (seed, ea)
        assert eb < 0.5, (seed, eb)


def test_accuracy_at_90_percent_outliers_is_correct_or_flagged():
    correct = 0
    for seed in range(8):
        acs = shared_motion_acs(np.random.default_rng(100 + seed), 4000, 0.5, outlier_ratio=0.9)
        motion, stats = _vote(acs)
        ea, eb = _errors_deg(motion, acs)
        if stats.reliable:
            assert ea < 0.05 and eb < 0.5, (seed, ea, eb)
            correct += 1
        else:
            assert stats.flag in ('too_few_inliers', 'unstable', 'ambiguous', 'weak_peak')
    assert correct >= 6                     # and flags are the exception, not the rule


@pytest.mark.parametrize('outliers', [0.0, 0.5, 0.7])
def test_ransac_comparison_is_accurate_too(outliers):
    for seed in range(3):
        acs = shared_motion_acs(np.random.default_rng(seed), 4000, 0.5, outlier_ratio=outliers)
        motion, stats = _vote(acs,
                              config=VotingConfig(method='ransac'))
        ea, eb = _errors_deg(motion, acs)
        assert stats.reliable and stats.iterations >= 1
        assert ea < 0.1 and eb < 0.5


def test_first_round_on_a_sample_is_as_accurate_as_on_all(monkeypatch):
    # Above STAT_SAMPLE ACs the vote's first selection and refinement round (only a start for
    # the second, which selects and refines on all of them) runs on an even sample: each answer
    # stays within a fraction of its standard deviation of the whole first round's, and the
    # errors are as small.
    from planar_vo.core.robust import vote as vote_module

    errors = {True: [], False: []}
    for seed in range(24):
        acs = shared_motion_acs(np.random.default_rng(seed), 4000, 0.5,
                                outlier_ratio=(0.0, 0.5, 0.7)[seed % 3])
        answers = {}
        for sampled in (True, False):
            if not sampled:
                monkeypatch.setattr(vote_module, '_FIRST_ROUND_SAMPLE', 10 ** 9)
            motion, stats = _vote(acs, clusters=acs.planes)
            monkeypatch.undo()
            assert stats.reliable, (seed, sampled, stats.flag)
            answers[sampled] = motion, stats
            errors[sampled].append(_errors_deg(motion, acs))
        (m1, _), (m2, s2) = answers[True], answers[False]
        sigma = np.sqrt(np.diag(s2.covariance))
        assert abs(float(angle_difference(m1.alpha, m2.alpha))) < 0.5 * sigma[0], seed
        assert abs(float(angle_difference(m1.beta, m2.beta))) < 0.5 * sigma[1], seed
    rms = {k: np.sqrt(np.mean(np.square(v), axis=0)) for k, v in errors.items()}
    assert np.all(rms[True] <= 1.05 * rms[False]), rms


def test_errors_shrink_with_more_correspondences():
    spread = []
    for n in (250, 4000):
        errs = []
        for seed in range(8):
            acs = shared_motion_acs(np.random.default_rng(seed), n, 0.5)
            motion, _ = _vote(acs)
            errs.append(_errors_deg(motion, acs)[0])
        spread.append(np.sqrt(np.mean(np.square(errs))))
    assert spread[1] < 0.5 * spread[0]


# ---------------------------------------------------------------------------------------------
# Honest uncertainty
# ---------------------------------------------------------------------------------------------

def test_covariance_is_calibrated():
    # z = error / reported sigma must be of order one: neither over- nor under-confident. ACs
    # of one plane share the error of its fitted homography, so the planes are the clusters.
    z = []
    for seed in range(24):
        acs = shared_motion_acs(np.random.default_rng(seed), 4000, 0.5, outlier_ratio=0.5)
        motion, stats = _vote(acs,
                              clusters=acs.planes)
        sigma = np.sqrt(np.diag(stats.covariance))
        z.append([float(angle_difference(motion.alpha, acs.alpha)) / sigma[0],
                  float(angle_difference(motion.beta, acs.beta)) / sigma[1]])
    rms = np.sqrt(np.mean(np.square(z), axis=0))
    assert np.all((rms > 0.5) & (rms < 2.0)), rms


def test_the_answer_is_the_sampson_minimum_not_the_biased_fixed_point():
    """A library user test: with many ACs and little noise the refinement (its whitening held
    per round) stopped at a fixed point biased by 3 standard deviations at 5 deg of yaw and
    beta -60 deg, the covariance far too confident; the last step on the Sampson cost itself
    removes it (what remains, about half a standard deviation, is the Sampson minimum's own:
    six steps leave the same)."""
    errors = {True: [], False: []}
    for seed in range(20):
        acs = shared_motion_acs(np.random.default_rng(seed), 1600, 0.5, alpha=5.0 * DEG,
                                beta=-60.0 * DEG, affine_sigma=0.005, plane_depth=(4.0, 30.0))
        for sampson in (True, False):
            motion, stats = _vote(acs, clusters=acs.planes, sampson=sampson)
            assert stats.reliable, (seed, sampson, stats.flag)
            sigma = np.sqrt(np.diag(stats.covariance))
            errors[sampson].append([float(angle_difference(motion.alpha, acs.alpha)),
                                    float(angle_difference(motion.beta, acs.beta))] / sigma)
        if seed < 6:
            # The step does not depend on the weights' scale (a review: weights of 10 let the
            # biased answer through, up to 4 standard deviations).
            scaled, _ = _vote(acs, clusters=acs.planes, weights=np.full(1600, 10.0))
            plain, _ = _vote(acs, clusters=acs.planes)
            assert scaled.alpha == pytest.approx(plain.alpha, abs=1e-9)
            assert scaled.beta == pytest.approx(plain.beta, abs=1e-9)
    z = {k: np.array(v) for k, v in errors.items()}
    assert np.all(np.abs(z[False].mean(axis=0)) > 2.0), z[False].mean(axis=0)   # (2.9, 2.7)
    assert np.all(np.abs(z[True].mean(axis=0)) < 1.0), z[True].mean(axis=0)     # (0.6, 0.4)
    assert np.all(np.sqrt(np.mean(z[True] ** 2, axis=0)) < 1.5)                  # (1.0, 0.9)


def test_covariance_grows_when_the_frame_is_weak(rng):
    strong = shared_motion_acs(np.random.default_rng(1), 4000, 0.3)
    weak = shared_motion_acs(np.random.default_rng(1), 300, 1.5, outlier_ratio=0.6)
    _, s_strong = _vote(strong)
    _, s_weak = _vote(weak)
    assert np.trace(s_weak.covariance) > 10 * np.trace(s_strong.covariance)
    assert np.all(np.linalg.eigvalsh(s_strong.covariance) > 0)


def test_weights_scale_does_not_change_the_result(rng):
    acs = shared_motion_acs(rng, 2000, 0.5, outlier_ratio=0.3)
    w = rng.uniform(0.5, 2.0, 2000)
    m1, s1 = _vote(acs, weights=w)
    m2, s2 = _vote(acs, weights=10.0 * w)
    assert m1.alpha == pytest.approx(m2.alpha, abs=1e-12)
    np.testing.assert_allclose(s1.covariance, s2.covariance, rtol=1e-9)


@pytest.mark.parametrize('outliers', [0.0, 0.5])
@pytest.mark.parametrize('method', ['histogram', 'ransac'])
def test_skipping_the_covariance_changes_nothing_else(rng, outliers, method):
    acs = shared_motion_acs(rng, 1500, 0.5, outlier_ratio=outliers)
    config = VotingConfig(method=method)
    m1, s1 = _vote(acs, config=config)
    m2, s2 = _vote(acs, config=config, covariance=False)
    assert (m1.alpha, m1.beta) == (m2.alpha, m2.beta)
    np.testing.assert_array_equal(s1.inliers, s2.inliers)
    assert (s1.reliable, s1.flag, s1.point_scale, s1.affine_scale) == \
        (s2.reliable, s2.flag, s2.point_scale, s2.affine_scale)
    assert np.all(np.isfinite(s1.covariance))
    if method == 'histogram':
        assert np.all(np.isinf(s2.covariance)) and np.isnan(s2.residual_rms)


def test_zero_weights_exclude_correspondences(rng):
    acs = shared_motion_acs(rng, 2000, 0.5, outlier_ratio=0.5)
    good = ~acs.outliers
    m_w, s_w = _vote(acs, weights=good.astype(float))
    assert not np.any(s_w.inliers[~good])
    assert s_w.num_candidates == np.count_nonzero(good)
    assert _errors_deg(m_w, acs)[0] < 0.05


# ---------------------------------------------------------------------------------------------
# Degenerate and ambiguous input: flagged, never raised, never confidently wrong
# ---------------------------------------------------------------------------------------------

def test_too_few_correspondences_is_flagged(rng):
    acs = shared_motion_acs(rng, 10, 0.5)
    motion, stats = _vote(acs)
    assert not stats.reliable and stats.flag == 'too_few_candidates'
    assert np.isnan(motion.alpha) and np.all(np.isinf(stats.covariance))


def test_stationary_vehicle_is_flagged(rng):
    # No motion: p2 = p1 and A = I. E = 0, every (alpha, beta) fits: nothing to estimate.
    q = rng.uniform(-0.4, 0.4, (500, 2))
    _, stats = vote_planar_motion(q, q.copy(), np.tile(np.eye(2), (500, 1, 1)))
    assert not stats.reliable


def test_pure_outliers_are_flagged(rng):
    acs = shared_motion_acs(rng, 3000, 0.5, outlier_ratio=0.999)
    _, stats = _vote(acs)
    assert not stats.reliable


def test_two_equal_motions_are_ambiguous(rng):
    a = shared_motion_acs(rng, 1500, 0.2, alpha=0.05, beta=-1.4)
    b = shared_motion_acs(rng, 1500, 0.2, alpha=-0.15, beta=-1.9)
    n = AffineCorrespondences.concatenate([a.normalized, b.normalized])
    motion, stats = vote_planar_motion(n.p1, n.p2, n.A)
    assert not stats.reliable and stats.flag == 'ambiguous'
    assert stats.ambiguity >= 0.8


def test_a_dominant_motion_wins_over_a_minor_one(rng):
    a = shared_motion_acs(rng, 3000, 0.3, alpha=0.05, beta=-1.4)
    b = shared_motion_acs(rng, 600, 0.3, alpha=-0.15, beta=-1.9)
    n = AffineCorrespondences.concatenate([a.normalized, b.normalized])
    motion, stats = vote_planar_motion(n.p1, n.p2, n.A)
    assert stats.reliable
    assert _errors_deg(motion, a)[0] < 0.05
    assert stats.ambiguity < 0.5


# ---------------------------------------------------------------------------------------------
# Input checks
# ---------------------------------------------------------------------------------------------

def test_input_errors(rng):
    acs = shared_motion_acs(rng, 100, 0.5)
    q1, q2, A = acs.normalized.p1, acs.normalized.p2, acs.normalized.A
    with pytest.raises(InputError, match=r'weights: expected shape \(N,\), got \(100, 1\)'):
        vote_planar_motion(q1, q2, A, weights=np.ones((100, 1)))
    with pytest.raises(InputError, match=r'same number of items: q1 has 100, weights has 99'):
        vote_planar_motion(q1, q2, A, weights=np.ones(99))
    # An array input: InputError like the NaN weights (a user test: it was a ConfigError).
    with pytest.raises(InputError, match=r'weights: expected non-negative values'):
        vote_planar_motion(q1, q2, A, weights=-np.ones(100))
    with pytest.raises(ConfigError, match=r'config: expected VotingConfig, got dict'):
        vote_planar_motion(q1, q2, A, config={'bins': 360})
    with pytest.raises(InputError, match=r'clusters: expected non-negative integers'):
        vote_planar_motion(q1, q2, A, clusters=np.zeros(100))
    with pytest.raises(InputError, match=r'q1: expected shape \(N, 2\)'):
        vote_planar_motion(q1[:, :1], q2, A)
    with pytest.raises(InputError, match=r'q2: expected a numeric array of shape \(N, 2\) of '
                                         r'real numbers, got complex128 values'):
        vote_planar_motion(q1, q2 + 1e-3j, A)
    huge = np.ones(100, dtype=object)
    huge[7] = 10**400
    with pytest.raises(InputError, match=r'weights: expected finite values, got a number too '
                                         r'large for float64'):
        vote_planar_motion(q1, q2, A, weights=huge)
    # The focal variant's own arguments (a user test: ValueError, IndexError, TypeError, and
    # starts=0 or 2.5 accepted).
    p1, p2 = acs.centered
    for bad in (('a', 'b'), (600,), None, (800, 600), (0, 10)):
        with pytest.raises(ConfigError, match=r'^focal_range: expected \(min, max\) pixels'):
            vote_planar_motion_focal(p1, p2, acs.acs.A, focal_range=bad)
    for bad in (0, -1, 2.5, True):
        with pytest.raises(ConfigError, match=r'^starts: expected a positive integer'):
            vote_planar_motion_focal(p1, p2, acs.acs.A, starts=bad)


@pytest.mark.parametrize('clusters, match', [
    (-np.ones(100, dtype=int), r'clusters: expected non-negative integers of shape \(100,\), '
                               r'got int64 \(100,\)'),
    (np.array([10**400] * 100), r'got object \(100,\)'),
    (np.zeros(100, dtype=bool), r'got bool \(100,\)'),
    (np.zeros(99, dtype=int), r'got int64 \(99,\)'),
    ([[0]] * 99 + [[0, 1]], r'got object \(\)'),
], ids=['negative', 'beyond_int64', 'bool', 'short', 'ragged'])
def test_bad_cluster_labels_are_input_errors(rng, clusters, match):
    acs = shared_motion_acs(rng, 100, 0.5)
    with pytest.raises(InputError, match=match):
        _vote(acs, clusters=clusters)


@pytest.mark.parametrize('dtype, scale', [(np.int64, 2**58), (np.uint64, 2**60)])
def test_huge_cluster_labels_group_like_small_ones(rng, dtype, scale):
    """Labels only group ACs: ids near 2**63 (or 2**64 unsigned) give the same estimate and
    covariance as 0..K-1, instead of a bincount of 2**63 bins (MemoryError)."""
    acs = shared_motion_acs(rng, 600, 0.5, outlier_ratio=0.3)
    planes = np.asarray(acs.planes)
    assert 8 <= planes.max() < 15
    reference = _vote(acs, clusters=planes)
    singletons = _vote(acs, clusters=np.arange(600))           # the labels do matter
    assert not np.allclose(singletons[1].covariance, reference[1].covariance, rtol=1e-3)
    huge = (planes.astype(dtype) + dtype(1)) * dtype(scale) + dtype(scale - 1)
    assert huge.max() > 2**61
    for variant, args in (('calibrated', {}), ('focal', None)):
        if args is None:
            ref = vote_planar_motion_focal(*acs.centered, acs.acs.A, clusters=planes)
            got = vote_planar_motion_focal(*acs.centered, acs.acs.A, clusters=huge)
        else:
            ref, got = reference, _vote(acs, clusters=huge)
        assert got[0] == ref[0], variant
        np.testing.assert_allclose(got[1].covariance, ref[1].covariance, rtol=1e-12)


# ---------------------------------------------------------------------------------------------
# Unknown focal length
# ---------------------------------------------------------------------------------------------

def test_focal_variant_exact(rng):
    acs = shared_motion_acs(rng, 2000, 0.0, alpha=0.12, beta=-1.3, outlier_ratio=0.3)
    p1, p2 = acs.centered
    motion, stats = vote_planar_motion_focal(p1, p2, acs.acs.A)
    assert stats.reliable, stats.flag
    assert motion.focal == pytest.approx(acs.focal, rel=1e-9)
    assert abs(angle_difference(motion.alpha, acs.alpha)) < 1e-9
    assert abs(angle_difference(motion.beta, acs.beta)) < 1e-9


def test_focal_variant_noisy_turn(rng):
    errors = []
    for seed in range(4):
        acs = shared_motion_acs(np.random.default_rng(seed), 3000, 0.5, alpha=0.15,
                                beta=-1.4, outlier_ratio=0.3)
        motion, stats = vote_planar_motion_focal(*acs.centered, acs.acs.A, clusters=acs.planes)
        assert stats.reliable, stats.flag
        errors.append(abs(motion.focal / acs.focal - 1.0))
        assert abs(float(angle_difference(motion.alpha, acs.alpha))) < 0.2 * DEG
        assert stats.focal_std < 0.05 * acs.focal
    assert max(errors) < 0.02


def test_straight_driving_does_not_reveal_the_focal_length(rng):
    acs = shared_motion_acs(rng, 3000, 0.5, alpha=0.0, beta=-np.pi / 2)
    motion, stats = vote_planar_motion_focal(*acs.centered, acs.acs.A)
    assert not stats.reliable and stats.flag == 'focal_unobservable'


@pytest.mark.parametrize('alpha', [0.0, 0.05])
def test_a_camera_that_did_not_move_is_flagged_no_parallax(alpha):
    """A standing (alpha 0) or only turning camera: every heading fits, the vote's beta is
    noise however sharp its peak; flagged (a user test: reliable, with a confident arbitrary
    heading), its covariance infinite. A moving camera's vote stays reliable, its covariance
    symmetric."""
    from planar_vo.core.conventions import rotation_y
    from planar_vo.sim.synthetic import street_pair

    rng = np.random.default_rng(3)
    n = 400
    q1 = np.column_stack([rng.uniform(-0.8, 0.8, n), rng.uniform(-0.2, 0.25, n)])
    R = rotation_y(alpha)
    h = np.column_stack([q1, np.ones(n)]) @ R.T
    q2 = h[:, :2] / h[:, 2:] + rng.normal(0.0, 1e-4, (n, 2))
    # The rotation's exact local affine at each point (the Jacobian of the map above).
    u = q1[:, 0]
    z = -np.sin(alpha) * u + np.cos(alpha)
    A = np.zeros((n, 2, 2))
    A[:, 0, 0] = 1.0 / z ** 2
    A[:, 1, 0] = q1[:, 1] * np.sin(alpha) / z ** 2
    A[:, 1, 1] = 1.0 / z
    A += rng.normal(0.0, 1e-4, (n, 2, 2))
    motion, stats = vote_planar_motion(q1, q2, A)
    assert motion.alpha == pytest.approx(alpha, abs=1e-3)
    assert (stats.reliable, stats.flag) == (False, 'no_parallax')
    assert np.isinf(stats.covariance).all()
    pair = street_pair(rng, 800, sigma_px=0.3, sigma_affine=0.01, tilt_deg=0.0)
    level = pair.normalized.mapped(pair.level)
    _, moving = vote_planar_motion(level.p1, level.p2, level.A)
    assert moving.reliable and np.array_equal(moving.covariance, moving.covariance.T)


# ---------------------------------------------------------------------------------------------
# Another basin of the cost: a refinement that settled in the wrong one is left or flagged
# ---------------------------------------------------------------------------------------------

def test_sampson_costs_are_the_refinement_chi_squares(rng):
    from planar_vo.core.robust import basins, refine

    acs = shared_motion_acs(rng, 300, 1.0, outlier_ratio=0.3).normalized
    q1, q2, A = acs.p1, acs.p2, acs.A
    rows = refine.design_rows(q1, q2, A)
    theta, beta = rng.uniform(-np.pi, np.pi, 5), rng.uniform(-np.pi, np.pi, 5)
    sp, sa, gate = 2e-3, 0.03, 11.34
    w = rng.uniform(0.5, 2.0, len(acs))
    per = basins.sampson_costs(q1, q2, A, rows, theta, beta, sp, sa, None, gate)
    total = basins.sampson_costs(q1, q2, A, rows, theta, beta, sp, sa, w, gate)
    for k in range(5):
        r, g, h = refine.residual_terms(q1, q2, A, rows, theta[k], beta[k])
        chi2 = np.sum(refine.whitened(r, g, h, sp, sa) ** 2, axis=1)
        np.testing.assert_allclose(per[k], chi2, rtol=1e-10)
        assert total[k] == pytest.approx(float(np.minimum(chi2, gate) @ w), rel=1e-10)


def test_polish_finds_the_exact_motion_from_a_few_degrees_off():
    from planar_vo.core.robust import basins
    from planar_vo.sim.synthetic import paper_trial

    for seed in range(5):
        acs = paper_trial(np.random.default_rng(seed), 0.0)
        n = acs.normalized
        alpha, beta = float(acs.alpha), float(acs.beta)
        start = (alpha + 3.0 * DEG + beta - 2.0 * DEG, beta - 2.0 * DEG)
        theta, b = basins.polish(n.p1, n.p2, n.A, np.ones(len(n)), np.ones(len(n), bool),
                                 *start, 1e-3, 0.01, 1e12)
        assert abs(angle_difference(theta - b, alpha)) < 1e-7
        assert abs(angle_difference(b, beta)) < 1e-7


def test_exact_data_has_no_competing_basin():
    from planar_vo.core.robust import basins
    from planar_vo.sim.synthetic import paper_trial

    for seed in range(5):
        acs = paper_trial(np.random.default_rng(seed), 0.0)
        n = acs.normalized
        alpha, beta = float(acs.alpha), float(acs.beta)
        alt = basins.other_basin(n.p1, n.p2, n.A, np.ones(len(n)), np.ones(len(n), bool),
                                 alpha + beta, beta, 1e-4, 1e-3, 11.34)
        assert alt is None or (alt.cost_change > 100.0 and alt.rival_change > 100.0)


def test_a_refinement_in_the_wrong_basin_is_left_or_flagged():
    """The paper's general protocol (50 ACs on one plane, sideways travel, 1 px and 0.02 affine
    noise): the vote's biased 1AC candidates start the refinement in the wrong basin of the cost
    in about one trial in five, where it settled confidently (a library user test); the scan
    leaves that basin or flags the estimate."""
    from planar_vo.sim.synthetic import paper_trial

    counts = {}
    for scan in (False, True):
        reliable = wrong = 0
        for seed in range(100):
            acs = paper_trial(np.random.default_rng(1000 + seed), 1.0, affine_sigma=0.02)
            motion, stats = _vote(acs, scan=scan)
            if stats.reliable:
                reliable += 1
                wrong += abs(float(angle_difference(motion.alpha, acs.alpha))) > 1.0 * DEG
        counts[scan] = (reliable, wrong)
    (_, wrong_before), (reliable, wrong) = counts[False], counts[True]
    assert wrong_before >= 9                        # (11 of 48 measured)
    assert wrong <= 5 and reliable >= 38, counts   # (3 of 42 measured)


def test_the_scan_leaves_straight_ahead_answers_as_they_were():
    """Straight ahead on one plane (the paper's forward protocol, affines from the fitted
    homography): the plane's two decompositions explain its points alike and the fitted
    affines can favour the wrong one; the scan's first version left two correct answers of
    600 for ones 8 and 17 deg off, reliable. The points decide, or the answer is flagged: no
    answer gets worse."""
    from planar_vo.sim.synthetic import paper_trial

    rng = np.random.default_rng(7)
    for trial in range(300):
        acs = paper_trial(rng, 1.0, motion='forward')
        scanned, stats = _vote(acs)
        plain, _ = _vote(acs, scan=False)
        if stats.reliable:
            assert _errors_deg(scanned, acs)[0] <= _errors_deg(plain, acs)[0] + 0.2, trial
