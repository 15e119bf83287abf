"""Metric scale: the road scale for a general motion and an explicit road normal, and the speed
integrator (bounded memory, long stops, slow speed sources)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from planar_vo.core.conventions import normal_from_tilt, rotation_rpy
from planar_vo.core.homography import apply_homography, homography_jacobian
from planar_vo.errors import ConfigError, InputError
from planar_vo.pipeline.scale import SpeedIntegrator, road_rays, road_scale

HEIGHT = 1.65
PITCH, ROLL = np.deg2rad(1.2), np.deg2rad(-0.7)     # the camera against the road


def _small_rotation(wx: float, wy: float, wz: float) -> np.ndarray:
    """``exp([w]x)`` (Rodrigues)."""
    return cv2.Rodrigues(np.array([wx, wy, wz], dtype=np.float64))[0]


def _motion(yaw: float = 0.02, wobble=(0.0015, -0.001)) -> tuple[np.ndarray, np.ndarray]:
    """A general camera motion: a yaw about the road normal plus pitch/roll wobble, forward."""
    n = normal_from_tilt(PITCH, ROLL)
    R = _small_rotation(wobble[0], 0.0, wobble[1]) @ _small_rotation(*(yaw * n))
    forward = np.array([0.0, 0.0, 1.0]) - n[2] * n           # along the road
    c = forward / np.linalg.norm(forward) + np.array([0.02, 0.0, 0.0])
    t = -R @ c
    return R, t / np.linalg.norm(t)


def _scene(rng, step: float, *, road: int = 400, wall: int = 150):
    """Exact ACs (normalised) of road points and of a facade, for a general motion."""
    n = normal_from_tilt(PITCH, ROLL)
    R, t = _motion()
    q_road = np.column_stack([rng.uniform(-0.6, 0.6, road), rng.uniform(0.06, 0.28, road)])
    H_road = R + (step / HEIGHT) * np.outer(t, n)
    wall_n, wall_d = np.array([1.0, 0.0, -0.2]) / math.hypot(1.0, 0.2), 4.0   # a facade right
    q_wall = np.column_stack([rng.uniform(0.25, 0.6, wall), rng.uniform(-0.3, 0.1, wall)])
    H_wall = R + step * np.outer(t, wall_n) / wall_d
    q1 = np.vstack([q_road, q_wall])
    q2 = np.vstack([apply_homography(H_road, q_road), apply_homography(H_wall, q_wall)])
    A = np.concatenate([homography_jacobian(H_road, q_road), homography_jacobian(H_wall, q_wall)])
    is_road = np.r_[np.ones(road, bool), np.zeros(wall, bool)]
    return q1, q2, A, R, t, n, is_road


def _per_ac(q1, q2, R, t, n):
    """The closed-form step of each AC, written independently (np.cross) for the checks."""
    Q1 = np.column_stack([q1, np.ones(len(q1))])
    Q2 = np.column_stack([q2, np.ones(len(q2))])
    X1 = Q1 * (HEIGHT / (Q1 @ n))[:, None]
    a = np.cross(Q2, X1 @ R.T)
    b = np.cross(Q2, t)
    return -np.einsum('ni,ni->n', a, b) / np.einsum('ni,ni->n', b, b)


# --------------------------------------------------------------------------------------------
# road_scale
# --------------------------------------------------------------------------------------------

def test_road_scale_is_exact_on_exact_road_acs_and_rejects_the_facade(rng):
    q1, q2, A, R, t, n, is_road = _scene(rng, 1.3)
    res = road_scale(q1, q2, A, R, t, n, HEIGHT, point_sigma=1.5e-3)
    assert abs(res.scale - 1.3) < 1e-9
    assert res.std_stat < 1e-9 and res.std_rot == 0.0 and res.std_normal == 0.0
    # Every road AC within the depth limit is used, no facade AC is.
    depth = HEIGHT / (q1 @ n[:2] + n[2]) * np.sqrt(1.0 + np.sum(q1 ** 2, 1))
    assert not np.any(res.mask & ~is_road)
    assert np.array_equal(res.mask, is_road & (depth <= 30.0))
    assert res.count == int(res.mask.sum()) > 300


def test_road_scale_needs_the_right_normal_and_a_level_guess_is_biased(rng):
    q1, q2, A, R, t, n, _ = _scene(rng, 1.0)
    level = road_scale(q1, q2, A, R, t, np.array([0.0, 1.0, 0.0]), HEIGHT, point_sigma=1.5e-3,
                       affine_sigma=0.5)
    # The 0-pitch guess for a camera pitched 1.2 deg down makes the steps long (KITTI: 22-29 %).
    assert level.scale > 1.1


def test_road_scale_sensitivities_are_the_derivatives_of_the_mean(rng):
    q1, q2, A, R, t, n, _ = _scene(rng, 1.2)
    q2 = q2 + rng.normal(0.0, 1e-3, q2.shape)
    w = rng.uniform(0.5, 1.0, len(q1))
    res = road_scale(q1, q2, A, R, t, n, HEIGHT, point_sigma=1.5e-3, weights=w,
                     affine_sigma=0.05, sigma_rot=1e-3, sigma_normal=2e-3)
    m = res.mask
    assert abs(np.average(_per_ac(q1[m], q2[m], R, t, n), weights=w[m]) - res.scale) < 1e-12
    eps = 1e-6

    def mean(Rm, nm):
        return np.average(_per_ac(q1[m], q2[m], Rm, t, nm), weights=w[m])

    for k in range(3):
        e = np.zeros(3)
        e[k] = eps
        fd = (mean(_small_rotation(*e) @ R, n) - mean(_small_rotation(*-e) @ R, n)) / (2 * eps)
        assert abs(fd - res.d_rotation[k]) < 1e-6 * (1.0 + abs(fd))
    for k in range(2):
        d = np.zeros(2)
        d[k] = eps
        fd = (mean(R, normal_from_tilt(PITCH + d[0], ROLL + d[1]))
              - mean(R, normal_from_tilt(PITCH - d[0], ROLL - d[1]))) / (2 * eps)
        assert abs(fd - res.d_normal[k]) < 1e-6 * (1.0 + abs(fd))
    assert res.std_rot == pytest.approx(1e-3 * math.hypot(res.d_rotation[0], res.d_rotation[2]))
    assert res.std_normal == pytest.approx(2e-3 * np.linalg.norm(res.d_normal))
    assert res.std == pytest.approx(math.sqrt(res.std_stat ** 2 + res.std_rot ** 2
                                              + res.std_normal ** 2))


@pytest.mark.parametrize(('point', 'sigma_rot', 'sigma_n'), [
    (1e-3, 0.0, 0.0),                                   # the ACs' own noise only
    (0.0, np.deg2rad(0.05), 0.0),                       # a rotation error only
    (0.0, 0.0, np.deg2rad(0.1)),                        # a road-normal error only
    (1e-3, np.deg2rad(0.05), np.deg2rad(0.1)),          # all three
])
def test_road_scale_std_is_honest_over_many_noisy_frames(point, sigma_rot, sigma_n):
    """Point and affine noise, a rotation error about the camera x and z axes, a road-normal
    error: the normalised errors (s - s_true) / std have an RMS near 1. Measured: 1.18-1.26
    with point noise alone (the far road ACs dominate the unweighted mean, and the sandwich
    variance of a mean with such leverage is somewhat low), 0.94-0.99 with one shared error
    alone, about 0.83 with all three (the shared errors also spread the ACs' steps, which the
    statistical part then counts once more; KITTI 05 / 06: 0.84 / 0.75)."""
    rng = np.random.default_rng(7)
    z = []
    for _ in range(200):
        step = rng.uniform(0.6, 1.6)
        q1, q2, A, R, t, n, is_road = _scene(rng, step, road=300, wall=60)
        q2 = q2 + rng.normal(0.0, point, q2.shape)
        A = A + rng.normal(0.0, 0.01, A.shape)
        R_used = _small_rotation(*rng.normal(0.0, sigma_rot, 3) * [1, 0, 1]) @ R
        dp, dr = rng.normal(0.0, sigma_n, 2)
        res = road_scale(q1, q2, A, R_used, t, normal_from_tilt(PITCH + dp, ROLL + dr), HEIGHT,
                         point_sigma=1.5e-3, sigma_rot=sigma_rot, sigma_normal=sigma_n)
        # A facade AC whose noisy point and affine happen to fit the road may slip in.
        assert res.count > 100 and np.count_nonzero(res.mask & ~is_road) <= 0.05 * res.count
        z.append((res.scale - step) / res.std)
    rms = float(np.sqrt(np.mean(np.square(z))))
    assert 0.75 < rms < 1.3, rms
    assert abs(float(np.mean(z))) < 0.25


def _cambered_road(rng, step: float, camber: float, count: int = 800):
    """Noisy ACs of a road whose surface rises by ``camber x^2`` (m) at the lateral distance
    ``x`` from the line of travel (a road in a shallow trough: kerbs, gutters, verges); each
    AC's affine is that of the surface's tangent plane. Returns the scene and ``x``."""
    n = normal_from_tilt(PITCH, ROLL)
    R, t = _motion()
    side = np.cross(n, t)
    side /= np.linalg.norm(side)
    q1 = np.column_stack([rng.uniform(-0.6, 0.6, count), rng.uniform(0.06, 0.28, count)])
    Q1 = np.column_stack([q1, np.ones(count)])
    a, b = Q1 @ side, Q1 @ n
    # The ray X = lam Q1 meets n.X + camber (side.X)^2 = HEIGHT.
    lam = 2.0 * HEIGHT / (b + np.sqrt(b * b + 4.0 * camber * a * a * HEIGHT))
    X1 = Q1 * lam[:, None]
    x = X1 @ side
    X2 = X1 @ R.T + step * t
    q2 = X2[:, :2] / X2[:, 2:]
    A = np.empty((count, 2, 2))
    for i in range(count):
        normal = n + 2.0 * camber * x[i] * side          # the tangent plane normal . X = d
        A[i] = homography_jacobian(R + step * np.outer(t, normal) / (normal @ X1[i]),
                                   q1[i:i + 1])[0]
    q2 = q2 + rng.normal(0.0, 1e-3, q2.shape)
    A = A + rng.normal(0.0, 0.01, A.shape)
    return q1, q2, A, R, t, n, x


def test_road_scale_lateral_weights_favour_the_surface_under_the_car(rng):
    """The camera height holds for the surface under the car. A road rising to the sides by
    0.1 m at 5 m makes the plain mean of the road ACs' steps long; the Gaussian lateral
    weights keep part of that bias out. On a plane they change nothing."""
    q1, q2, A, R, t, n, _ = _scene(rng, 1.3)
    flat = road_scale(q1, q2, A, R, t, n, HEIGHT, point_sigma=1.5e-3, lateral_std=3.5)
    assert abs(flat.scale - 1.3) < 1e-9
    step = 1.2
    for _ in range(3):
        q1, q2, A, R, t, n, _ = _cambered_road(rng, step, 0.004)
        plain = road_scale(q1, q2, A, R, t, n, HEIGHT, point_sigma=1.5e-3)
        weighted = road_scale(q1, q2, A, R, t, n, HEIGHT, point_sigma=1.5e-3, lateral_std=3.5)
        assert plain.count > 500 and weighted.count > 500
        assert plain.scale > 1.015 * step                        # measured: 1.019-1.021
        assert weighted.scale - step < 0.8 * (plain.scale - step)  # measured: 0.69-0.73
        # The weights: the Gaussian of each road AC's lateral distance on the plane n.X = h.
        m = weighted.mask
        side = np.cross(n, t) / np.linalg.norm(np.cross(n, t))
        lateral = HEIGHT * (q1[m] @ side[:2] + side[2]) / (q1[m] @ n[:2] + n[2])
        w = np.exp(-0.5 * (lateral / 3.5) ** 2)
        assert weighted.scale == pytest.approx(
            np.average(_per_ac(q1[m], q2[m], R, t, n), weights=w), abs=1e-12)


def test_road_scale_without_enough_road_gives_nan(rng):
    q1, q2, A, R, t, n, is_road = _scene(rng, 1.0, road=8, wall=100)
    res = road_scale(q1, q2, A, R, t, n, HEIGHT, point_sigma=1.5e-3)
    assert math.isnan(res.scale) and res.std == math.inf and res.count == 0
    assert res.mask.shape == (108,) and not res.mask.any()
    empty = road_scale(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros((0, 2, 2)), R, t, n, HEIGHT,
                       point_sigma=1.5e-3)
    assert math.isnan(empty.scale) and empty.count == 0


def test_road_scale_input_errors(rng):
    q1, q2, A, R, t, n, _ = _scene(rng, 1.0, road=20, wall=0)
    ok = dict(point_sigma=1.5e-3)
    with pytest.raises(InputError, match=r'R: expected a rotation matrix'):
        road_scale(q1, q2, A, 2.0 * R, t, n, HEIGHT, **ok)
    with pytest.raises(InputError, match=r't: expected a non-zero direction'):
        road_scale(q1, q2, A, R, np.zeros(3), n, HEIGHT, **ok)
    with pytest.raises(InputError, match=r'n: expected a non-zero direction'):
        road_scale(q1, q2, A, R, t, np.zeros(3), HEIGHT, **ok)
    with pytest.raises(InputError, match=r'same number of items: q1 has 20, q2 has 19'):
        road_scale(q1, q2[:-1], A, R, t, n, HEIGHT, **ok)
    with pytest.raises(InputError, match=r'q1: expected finite values'):
        road_scale(np.where(q1 > 0.5, np.nan, q1), q2, A, R, t, n, HEIGHT, **ok)
    with pytest.raises(InputError, match=r'weights: expected non-negative values'):
        road_scale(q1, q2, A, R, t, n, HEIGHT, weights=-np.ones(20), **ok)
    with pytest.raises(InputError, match=r'sigma_rot: expected a non-negative angle'):
        road_scale(q1, q2, A, R, t, n, HEIGHT, sigma_rot=-1.0, **ok)
    with pytest.raises(InputError, match=r'clusters: expected non-negative integers'):
        road_scale(q1, q2, A, R, t, n, HEIGHT, clusters=np.full(20, -1), **ok)
    with pytest.raises(ConfigError, match=r'height: expected a positive number, got 0.0'):
        road_scale(q1, q2, A, R, t, n, 0.0, **ok)
    with pytest.raises(ConfigError, match=r'point_sigma: expected a positive number'):
        road_scale(q1, q2, A, R, t, n, HEIGHT, point_sigma=0.0)
    with pytest.raises(ConfigError, match=r'lateral_std: expected a non-negative distance'):
        road_scale(q1, q2, A, R, t, n, HEIGHT, lateral_std=-1.0, **ok)


# --------------------------------------------------------------------------------------------
# SpeedIntegrator
# --------------------------------------------------------------------------------------------

def test_speed_integrator_is_exact_for_piecewise_linear_speed():
    speed = SpeedIntegrator()
    t = np.arange(0.0, 10.0, 0.01)
    v = 5.0 + 0.5 * t                                       # linear: trapezoids are exact
    for ti, vi in zip(t, v):
        speed.add(ti, vi)
    assert speed.distance(1.0, 3.0) == pytest.approx(5.0 * 2.0 + 0.25 * (9.0 - 1.0), abs=1e-9)
    # Inside an interval the distance follows the linear speed exactly too.
    assert speed.distance(1.005, 1.0125) == pytest.approx(
        5.0 * 0.0075 + 0.25 * (1.0125 ** 2 - 1.005 ** 2), abs=1e-12)
    assert speed.distance(2.0, 2.0) == 0.0
    assert speed.distance(3.0, 1.0) is None


def test_speed_integrator_bridges_gaps_up_to_max_gap_only():
    one_hz = [(float(k), 10.0) for k in range(20)]
    default = SpeedIntegrator()
    slow = SpeedIntegrator(max_gap=1.5)                     # scale.speed_max_gap for 1 Hz
    for stamp, v in one_hz:
        default.add(stamp, v)
        slow.add(stamp, v)
    assert default.distance(3.2, 5.7) is None               # a 1 Hz source never worked
    assert slow.distance(3.2, 5.7) == pytest.approx(25.0)
    # Extrapolation beyond the samples: at most max_gap, at the last speed.
    assert slow.distance(18.0, 20.4) == pytest.approx(24.0)
    assert slow.distance(18.0, 20.6) is None
    gap = SpeedIntegrator(max_gap=0.5)
    for stamp in (0.0, 0.2, 0.4, 3.0, 3.2):
        gap.add(stamp, 2.0)
    assert gap.distance(0.0, 0.4) == pytest.approx(0.8)
    assert gap.distance(0.3, 3.1) is None                   # 2.6 s without samples inside
    assert gap.distance(1.0, 1.2) is None


def test_speed_integrator_answers_across_a_long_stop_in_bounded_memory():
    """100 Hz wheel speed: 5 s at 8 m/s, a 40 s stop, 5 s at 8 m/s again, in 256 knots."""
    speed = SpeedIntegrator(max_samples=256)
    stamps = np.arange(0.0, 50.0, 0.01)
    v = np.where((stamps >= 5.0) & (stamps < 45.0), 0.0, 8.0)
    sizes = []
    for stamp, vi in zip(stamps, v):
        speed.add(stamp, vi)
        sizes.append(len(speed))
    assert max(sizes) <= 256
    # The keyframe before the stop is 46 s old: the distance is still exact (trapezoids across
    # the two speed steps at 5.00 and 45.00 s).
    expected = 8.0 * (5.0 - 4.0) - 0.5 * 8.0 * 0.01 + 8.0 * (49.5 - 45.0) + 0.5 * 8.0 * 0.01
    assert speed.distance(4.0, 49.5) == pytest.approx(expected, abs=1e-9)
    assert speed.distance(10.0, 40.0) == pytest.approx(0.0, abs=1e-12)


def test_speed_integrator_merges_least_harmful_knots_first():
    rng = np.random.default_rng(3)
    speed = SpeedIntegrator(max_samples=512)
    stamps = np.arange(0.0, 600.0, 0.01)                    # 10 minutes at 100 Hz
    v = 10.0 + 3.0 * np.sin(stamps / 7.0) + rng.normal(0.0, 0.02, stamps.size)
    for stamp, vi in zip(stamps, v):
        speed.add(stamp, vi)
    assert len(speed) <= 512
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(stamps))])
    for t0, t1 in ((10.0, 590.0), (300.0, 301.0), (598.0, 599.99)):
        i0, i1 = int(round(t0 * 100)), int(round(t1 * 100))
        exact = cum[i1] - cum[i0]
        # Distances over any span stay within a few centimetres (the merged knots' errors).
        assert abs(speed.distance(stamps[i0], stamps[i1]) - exact) < 0.05


def test_speed_integrator_out_of_order_and_repeated_samples():
    rng = np.random.default_rng(5)
    stamps = np.arange(0.0, 5.0, 0.05)
    v = 3.0 + rng.uniform(-1.0, 1.0, stamps.size)
    in_order, shuffled = SpeedIntegrator(), SpeedIntegrator()
    for stamp, vi in zip(stamps, v):
        in_order.add(stamp, vi)
    order = rng.permutation(stamps.size)
    for k in order:
        shuffled.add(stamps[k], 99.0)                       # wrong first, replaced below
    for k in order:
        shuffled.add(stamps[k], v[k])
    for t0, t1 in ((0.0, 4.95), (1.02, 3.33), (4.9, 5.2)):
        assert shuffled.distance(t0, t1) == pytest.approx(in_order.distance(t0, t1), abs=1e-9)
    assert len(shuffled) == len(in_order) == stamps.size


def test_speed_integrator_errors():
    with pytest.raises(InputError, match=r'expected finite stamp and speed, got 1.0, nan'):
        SpeedIntegrator().add(1.0, float('nan'))
    with pytest.raises(ConfigError, match=r'max_gap: expected a positive duration'):
        SpeedIntegrator(max_gap=0.0)
    with pytest.raises(ConfigError, match=r'max_samples: expected at least 16, got 2'):
        SpeedIntegrator(max_samples=2)
    assert SpeedIntegrator().distance(0.0, 1.0) is None      # no samples at all


def test_rotation_helper_matches_rpy():
    # _small_rotation about the x axis is the rpy roll: the helpers agree on the convention.
    assert np.allclose(_small_rotation(0.1, 0.0, 0.0), rotation_rpy(0.1, 0.0, 0.0))


def test_road_rays_are_those_meeting_the_road_below_the_horizon_within_the_depth():
    """Level camera 1.65 m above the road: a ray meets it at depth 1.65 / y along the optical
    axis, times the ray's length along the ray."""
    n = normal_from_tilt(0.0, 0.0)
    q = np.array([[0.0, 0.1], [0.0, 0.05], [0.0, -0.1], [0.0, 0.015], [0.5, 0.1], [0.9, 0.09]])
    # Depths along the rays: 16.6 m, 33 m, above the horizon, within 1 deg of it, 18.5 m, 24.7 m
    np.testing.assert_array_equal(road_rays(q, n, 1.65, max_depth=30.0),
                                  [True, False, False, False, True, True])
    assert not road_rays(q, n, 1.65, max_depth=15.0).any()
    # Pitched down 10 deg, the horizon rises: the ray along the optical axis meets the road.
    assert road_rays(np.zeros((1, 2)), normal_from_tilt(np.deg2rad(10.0), 0.0), 1.65)[0]
    with pytest.raises(InputError):
        road_rays(np.zeros((2, 3)), n, 1.65)
    for height, depth in ((-1.65, 30.0), (0.0, 30.0), (1.65, 0.0), (1.65, math.inf)):
        with pytest.raises(ConfigError):
            road_rays(q, n, height, max_depth=depth)
