"""The causal keyframe window: the joint rotation solve, longer-baseline pairs refined from a
prediction, and the pipeline with ``odometry.window_lags``."""

from __future__ import annotations

import numpy as np
import pytest

from planar_vo.core.conventions import so3_exp, so3_log
from planar_vo.errors import ConfigError
from planar_vo.pipeline.estimator import MotionEstimator
from planar_vo.pipeline.window import RotationWindow, solve_window
from planar_vo.sim.synthetic import street_pair


def _angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> float:
    return float(np.rad2deg(np.linalg.norm(so3_log(Ra @ Rb.T))))


def _orientations(rng, n: int) -> list[np.ndarray]:
    """Camera-to-world orientations of a drive: yaw steps about the camera's y axis plus a
    small wobble."""
    C = [np.eye(3)]
    for _ in range(n - 1):
        step = so3_exp(np.array([rng.normal(0, 0.002), rng.uniform(-0.05, 0.05),
                                 rng.normal(0, 0.002)]))
        C.append(C[-1] @ step)
    return C


def _relative(C: list[np.ndarray], a: int, b: int) -> np.ndarray:
    """``R_ab`` with ``X_b = R_ab X_a + t``: ``C_b^T C_a``."""
    return C[b].T @ C[a]


def test_window_solve_recovers_consistent_pairs_exactly(rng):
    C = _orientations(rng, 6)
    pairs = [(a, b, _relative(C, a, b), np.eye(3) * 1e4)
             for a in range(6) for b in range(a + 1, min(a + 4, 6))]
    start = {k: (so3_exp(rng.normal(0, 0.01, 3)) @ C[k] if k else C[k]) for k in range(6)}
    solved = solve_window(start, pairs, anchor=0, iterations=4)
    assert np.array_equal(solved[0], C[0])                      # the anchor is held
    assert max(_angle_deg(solved[k], C[k]) for k in range(6)) < 1e-9


def _drift(rng, lags: int, frames: int = 120, sigma: float = 0.002) -> float:
    """Final orientation error (deg) of a causal run over pairs with independent noise
    (``sigma`` rad per axis), frame to frame (``lags = 1``) or with the window."""
    C = _orientations(rng, frames)
    info_cov = np.eye(3) * sigma ** 2
    window = RotationWindow(6)
    published = [C[0]]
    window.add_keyframe(0, C[0])
    for j in range(1, frames):
        noisy = {d: so3_exp(rng.normal(0, sigma, 3)) @ _relative(C, j - d, j)
                 for d in range(1, lags + 1) if j - d >= 0}
        prediction = published[-1] @ noisy[1].T
        if lags == 1:
            published.append(prediction)
            continue
        window.add_keyframe(j, prediction)
        for d, R in noisy.items():
            window.add_pair(j - d, j, R, info_cov)
        published.append(window.solve()[j])
    return _angle_deg(published[-1], C[-1])


def test_window_averages_independent_pair_noise():
    # Independent noise per measured pair (as from matching each pair directly): the window's
    # longer pairs cut the accumulated orientation error; the same seeds for both.
    single = [_drift(np.random.default_rng(s), 1) for s in range(12)]
    window = [_drift(np.random.default_rng(s), 3) for s in range(12)]
    rms = lambda e: float(np.sqrt(np.mean(np.square(e))))      # noqa: E731
    assert rms(window) < 0.6 * rms(single), (rms(window), rms(single))


def test_window_keeps_its_size_and_refuses_bad_input(rng):
    with pytest.raises(ConfigError, match='window size: expected at least 2 keyframes, got 1'):
        RotationWindow(1)
    window = RotationWindow(3)
    C = _orientations(rng, 5)
    for k in range(5):
        window.add_keyframe(k, C[k])
        if k:
            window.add_pair(k - 1, k, _relative(C, k - 1, k), np.eye(3))
    assert [k in window for k in range(5)] == [False, False, True, True, True]
    window.add_pair(0, 4, _relative(C, 0, 4), np.eye(3))        # 0 left: ignored
    window.add_pair(2, 4, _relative(C, 2, 4), np.zeros((3, 3)))  # singular: ignored
    solved = window.solve()
    assert sorted(solved) == [2, 3, 4]
    assert max(_angle_deg(solved[k], C[k]) for k in solved) < 1e-9


def test_refine_from_a_prediction_is_accurate_and_flags_a_wrong_one(rng):
    s = street_pair(rng, 800, outlier_ratio=0.2)
    acs = s.normalized
    estimator = MotionEstimator()
    near = so3_exp(np.deg2rad([0.05, 0.1, 0.05])) @ s.R
    est = estimator.refine_from(acs, near, s.t + 0.01 * rng.normal(size=3))
    assert est.reliable, est.flag
    assert _angle_deg(est.R, s.R) < 0.01
    assert np.rad2deg(np.arccos(np.clip(est.t @ s.t, -1, 1))) < 0.5
    # A prediction 2 degrees off: the data move it further than a consistent pair may.
    far = so3_exp(np.deg2rad([0.0, 2.0, 0.0])) @ s.R
    flagged = estimator.refine_from(acs, far, s.t)
    assert not flagged.reliable and flagged.flag in ('left_start', 'unconverged', 'flat')


def test_pipeline_with_the_window_tracks_a_rendered_turn():
    from test_pipeline import HEIGHT, _errors, _run

    from planar_vo.config import PlanarVoConfig

    config = PlanarVoConfig.from_dict({'mount': {'height': HEIGHT},
                                       'odometry': {'window_lags': 3}})
    trajectory, results, vo = _run('left', config)
    assert all(r.ok for r in results[1:])
    assert all('window' in r.timings for r in results[1:] if r.keyframe)
    pos, yaw, distance = _errors(trajectory, results)
    _, frame_to_frame, _ = _run('left')
    ref_pos, ref_yaw, _ = _errors(trajectory, frame_to_frame)
    assert yaw < 0.15 and pos < 0.02 * distance
    assert yaw <= ref_yaw + 0.05
