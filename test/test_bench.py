"""Benchmarks: CLI, reports, the paper's complexity numbers, metrics, PoseLib peers, the hook.

Timings are never asserted here (the benchmarks report them as ratios); these tests check that
the benchmark machinery measures the right thing.
"""

from __future__ import annotations

import csv

import numpy as np
import pytest

from planar_vo.bench import common, methods, peers
from planar_vo.bench.metrics import (
    focal_error,
    rotation_error_deg,
    translation_error_deg,
)
from planar_vo.cli import build_parser, main
from planar_vo.core import (
    angle_difference,
    planar_essential,
    rotation_y,
    solve_1ac,
    translation_direction,
)
from planar_vo.errors import InputError
from planar_vo.sim.synthetic import paper_trial, shared_motion_acs

EXACT_DEG = 1e-7


def _angle_err(a, b) -> np.ndarray:
    return np.abs(angle_difference(a, b))


def _exact_scene(rng, n=60, outlier_ratio=0.0):
    """Noise-free ACs of one planar motion on 40 planes (a non-planar scene), and the outlier
    mask."""
    acs = shared_motion_acs(rng, n, 0.0, outlier_ratio=outlier_ratio, alpha=0.05, beta=-1.4,
                            points_per_plane=-(-n // 40))
    return acs, acs.outliers


# ---------------------------------------------------------------------------------------------
# CLI and reports
# ---------------------------------------------------------------------------------------------

def test_bench_cli_parses_each_benchmark():
    parser = build_parser()
    args = parser.parse_args(['bench', 'paper', '--quick', '--runs', '7', '--out', 'x'])
    assert (args.command, args.bench, args.quick, args.runs, args.out) == \
        ('bench', 'paper', True, 7, 'x')
    assert args.sigmas[0] == 0.0 and args.sigmas[-1] == 2.0 and len(args.sigmas) == 11
    args = parser.parse_args(['bench', 'speed'])
    assert args.sizes == [500, 4000, 20000] and args.out == 'out/bench/speed'
    with pytest.raises(SystemExit) as exc:
        parser.parse_args(['bench'])
    assert exc.value.code == 1


def test_soak_trend_ignores_slow_blocks_and_reports_growth(capsys):
    from planar_vo.bench.soak import lap, report, run, trend_change

    x = np.arange(500.0, 10001.0, 500.0)
    flat = np.full(x.size, 20.0)
    flat[[2, 17]] = 35.0                        # two blocks slowed by other processes
    assert trend_change(x, flat) == 0.0
    assert trend_change(x, 20.0 + 0.001 * x) == pytest.approx(100 * 9.5 / 20.5)
    # The lap closes: its last pose is one 0.8 m step before the first.
    poses = lap().poses
    assert np.linalg.norm(poses[-1][:2, 3] - poses[0][:2, 3]) == pytest.approx(0.8, abs=0.01)
    blocks = [{'frames': int(f), 'rss_mb': 300.0 + 0.01 * f, 'cpu_ms': 20.0, 'node_ms': 25.0,
               'path_ms': 0.3, 'path_max_ms': 4.0, 'path_poses': 500, 'odometry_out': int(f)}
              for f in x]
    text = report(blocks, {'camera': '640x480', 'lap_frames': 219, 'render_s': 13.0,
                           'summary': 'summary: ...', 'path_subscribed': True, 'every': 500})
    assert 'RSS +29.0 %, node CPU time +0.0 %' in text and '**NOT flat**' in text
    args = build_parser().parse_args(['bench', 'soak', '--frames', '100', '--every', '60'])
    with pytest.raises(InputError, match=r'^--frames, --every: expected --every >= 10 and '
                                         r'--frames >= 2 \* --every, got 100, 60$'):
        run(args)


def test_command_line_spells_out_every_option():
    parser = build_parser()
    args = parser.parse_args(['bench', 'paper', '--quick', '--sigmas', '0', '1.5'])
    argv = common.command_argv(['planar_vo', 'bench', 'paper'], args.bench_parser, args)
    assert argv[:3] == ['planar_vo', 'bench', 'paper']
    assert '--quick' in argv and '--runs' in argv and argv[argv.index('--runs') + 1] == '1000'
    i = argv.index('--sigmas')
    assert argv[i + 1:i + 3] == ['0.0', '1.5']
    # The recorded command parses back to the same options.
    again = parser.parse_args(argv[1:])
    assert (again.sigmas, again.runs, again.quick) == (args.sigmas, args.runs, args.quick)


def test_bench_paper_quick_writes_plots_and_report(tmp_path, capfd):
    pytest.importorskip('poselib')
    pytest.importorskip('matplotlib')
    out = tmp_path / 'paper'
    assert main(['bench', 'paper', '--quick', '--out', str(out)]) == 0
    printed = capfd.readouterr().out
    text = (out / 'paper.md').read_text()
    assert f'planar_vo bench paper --out {out} --runs 1000' in text and '--quick' in text
    assert '## Findings' in text and '## Computational complexity' in text
    assert '## Findings' in printed
    for name in ('fig3a_calibrated.png', 'fig3b_focal.png', 'fig3c_corrupted_planarity.png'):
        data = (out / name).read_bytes()
        assert data[:8] == b'\x89PNG\r\n\x1a\n' and 10_000 < len(data) < 400_000
    with (out / 'paper.csv').open() as fh:
        rows = {(r['scenario'], float(r['sigma']), r['method']): r for r in csv.DictReader(fh)}
    # Noise-free: the closed-form planar solvers are exact; with noise they are not.
    for method in ('1AC', '1AC+LS', '3PC'):
        assert float(rows[('general', 0.0, method)]['rot_mean']) < 1e-9
        assert float(rows[('general', 0.0, method)]['trans_mean']) < 1e-9
        assert float(rows[('general', 2.0, method)]['rot_mean']) > 1e-3
    assert float(rows[('general', 0.0, '1ACf')]['focal_median']) < 1e-9


def test_paper_experiments_do_not_depend_on_the_number_of_workers():
    from planar_vo.bench.paper import run_experiments

    kwargs = dict(runs=3, samples=2, methods=['1AC', '2PC', '1ACf'], progress=False)
    rows1, free1 = run_experiments([0.0, 1.0], jobs=1, **kwargs)
    rows2, free2 = run_experiments([0.0, 1.0], jobs=2, **kwargs)
    np.testing.assert_equal(rows1, rows2)                  # NaN (no focal) equals NaN
    assert len(rows1) == 4 * 2 * 2 + 2 * 2                  # 1ACf: untilted+tilted general
    np.testing.assert_array_equal(free1['forward']['2PC']['rot'], free2['forward']['2PC']['rot'])
    assert max(free1['general']['1AC']['rot']) < 1e-9
    with pytest.raises(InputError, match='sigmas: expected finite non-negative noise levels'):
        run_experiments([-1.0], **kwargs)


def test_missing_optional_dependency_is_one_line_and_exit_1(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(__import__('sys').modules, 'poselib', None)   # import now fails
    assert main(['bench', 'speed', '--quick', '--out', str(tmp_path)]) == 1
    err = capsys.readouterr().err.strip()
    assert err == ("planar_vo bench speed: error: poselib not installed: "
                   "pip install 'planar_vo[bench]'")


def test_bench_speed_quick_times_voting_against_the_peers(tmp_path, capfd):
    pytest.importorskip('poselib')
    pytest.importorskip('matplotlib')
    out = tmp_path / 'speed'
    assert main(['bench', 'speed', '--quick', '--out', str(out)]) == 0
    text = (out / 'speed.md').read_text()
    assert text.count('planar_vo bench speed --out') == 1 and '--quick' in text
    assert (out / 'speed_vs_size.png').exists() and (out / 'speed_vs_outliers.png').exists()
    # Ratios are against the whole estimator (solve + vote), never solve alone; on a car's
    # general motion against the pipeline's estimator, with PoseLib's defaults and early stop.
    assert '(solve + vote)' in text and 'not run' not in text
    assert '| planar_vo estimator (1AC vote + general refinement) |' in text
    assert '5PC LO-RANSAC + refinement (PoseLib defaults) |' in text


def test_bench_pipeline_times_every_stage_against_dis(tmp_path, capfd):
    out = tmp_path / 'pipeline'
    assert main(['bench', 'pipeline', '--frames', '10', '--skip-kitti', '--out', str(out)]) == 0
    text = (out / 'pipeline.md').read_text()
    for stage in ('decode', 'correspondences', 'solve', 'scale', 'integrate', 'publish',
                  'whole frame (wall)', 'whole frame (CPU time)'):
        assert f'| {stage} |' in text
    assert '## rendered demo drive: 9 frame pairs, 1241x376, one core' in text
    assert 'target at most 20 ms at 1241x376' in text
    capfd.readouterr()
    # Both skipped: nothing to time, refused (a user test: an empty report, exit 0).
    assert main(['bench', 'pipeline', '--skip-kitti', '--skip-rendered', '--out',
                 str(tmp_path / 'none')]) == 1
    assert capfd.readouterr().err == ('planar_vo bench pipeline: error: --skip-kitti: with '
                                      '--skip-rendered too, nothing is left to time; drop one '
                                      'of the two\n')
    assert not (tmp_path / 'none' / 'pipeline.md').exists()


# ---------------------------------------------------------------------------------------------
# The paper's complexity table
# ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize('m, expected', [
    (1, [4, 7, 17, 44]),
    (2, [6, 17, 72, 459]),
    (3, [9, 35, 293, 4603]),
    (5, [17, 146, 4714, 460515]),
])
def test_ransac_iterations_equal_the_paper_table(m, expected):
    k = peers.ransac_iterations(np.array([0.25, 0.5, 0.75, 0.9]), m, 0.99)
    np.testing.assert_array_equal(k, expected)
    if m == 5:
        assert 4.5e5 < k[-1] < 5.5e5                    # the paper prints ~5e5


def test_ransac_iterations_edge_cases_and_bad_input():
    assert peers.ransac_iterations(0.0, 5) == 1.0
    assert np.isinf(peers.ransac_iterations(1.0, 2))
    with pytest.raises(InputError, match=r'outlier_ratio: expected values in \[0, 1\], got'):
        peers.ransac_iterations(1.5, 2)
    with pytest.raises(InputError, match='confidence: expected a probability'):
        peers.ransac_iterations(0.5, 2, confidence=1.0)


# ---------------------------------------------------------------------------------------------
# Metrics
# ---------------------------------------------------------------------------------------------

def _axis_angle(axis, angle) -> np.ndarray:
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def test_rotation_error_on_known_rotations():
    # Yaw a moves v = [1,1,1]/sqrt(3) by acos(1/3 + 2/3 cos a).
    a = np.array([0.0, 0.3, 1.0, np.pi])
    expected = np.rad2deg(np.arccos(1 / 3 + 2 / 3 * np.cos(a)))
    np.testing.assert_allclose(rotation_error_deg(rotation_y(a), np.eye(3)), expected,
                               atol=1e-12)
    # A rotation about v itself is invisible to the paper's metric; one about an axis
    # orthogonal to v shows its full angle.
    assert rotation_error_deg(_axis_angle([1, 1, 1], 0.7), np.eye(3)) < 1e-12
    np.testing.assert_allclose(rotation_error_deg(_axis_angle([1, -1, 0], 0.7), np.eye(3)),
                               np.rad2deg(0.7), rtol=1e-12)
    # Tiny errors keep their precision (acos would return 0 or ~1e-6 deg here).
    tiny = rotation_error_deg(_axis_angle([1, -1, 0], 1e-12), np.eye(3))
    np.testing.assert_allclose(tiny, np.rad2deg(1e-12), rtol=1e-3)
    assert np.isnan(rotation_error_deg(np.full((3, 3), np.nan), np.eye(3)))


def test_translation_and_focal_errors():
    assert translation_error_deg([1, 0, 0], [0, 0, 1]) == pytest.approx(90.0)
    assert translation_error_deg([1, 0, 0], [-2, 0, 0]) == pytest.approx(180.0)
    assert translation_error_deg([3, 0, 4], [0.6, 0, 0.8]) < 1e-12         # scale-free
    assert np.isnan(translation_error_deg([0, 0, 0], [1, 0, 0]))
    np.testing.assert_allclose(focal_error([600.0, 660.0, 540.0], 600.0), [0.0, 0.1, 0.1])


# ---------------------------------------------------------------------------------------------
# Peers (PoseLib is an optional extra)
# ---------------------------------------------------------------------------------------------

def test_planar_sampson_errors_match_the_essential_matrix(rng):
    t = paper_trial(rng, 1.0)
    alpha, beta = rng.uniform(-1, 1, 3), rng.uniform(-3, 3, 3)
    err = peers.planar_sampson_errors(t.normalized.p1, t.normalized.p2, alpha, beta)
    h1 = np.column_stack([t.normalized.p1, np.ones(len(t.normalized.p1))])
    h2 = np.column_stack([t.normalized.p2, np.ones(len(t.normalized.p2))])
    for k in range(3):
        E = planar_essential(alpha[k], beta[k])
        l2, l1 = h1 @ E.T, h2 @ E
        ref = np.abs(np.sum(h2 * l2, 1)) / np.sqrt(l2[:, 0] ** 2 + l2[:, 1] ** 2
                                                   + l1[:, 0] ** 2 + l1[:, 1] ** 2)
        np.testing.assert_allclose(err[k], ref, rtol=1e-12)


def test_shared_motion_scene_is_exact_and_has_the_outlier_ratio(rng):
    acs, outlier = _exact_scene(rng, 400, outlier_ratio=0.3)
    assert outlier.sum() == 120
    n = acs.normalized.subset(~outlier)
    a, b = solve_1ac(n.p1, n.p2, n.A)
    err = _angle_err(a, acs.alpha) + _angle_err(b, acs.beta)
    # Exact ACs: machine precision, except the rare AC near the horizon row (ill-conditioned).
    assert np.median(err) < 1e-12 and np.mean(err < 1e-8) > 0.97 and np.max(err) < 1e-6
    # The scene is not one plane: the points' depths spread over the 4..30 range.
    n = acs.normalized.subset(outlier)
    a, b = solve_1ac(n.p1, n.p2, n.A)
    assert np.median(_angle_err(a, acs.alpha)) > 1e-3


@pytest.mark.parametrize('solver', peers.TWO_PC_SOLVERS)
def test_2pc_ransac_recovers_exact_motion_among_outliers(rng, solver):
    if solver == 'poselib':
        pytest.importorskip('poselib')
    acs, outlier = _exact_scene(rng, 300, outlier_ratio=0.4)
    n = acs.normalized
    est = peers.estimate_2pc_ransac(n.p1, n.p2, solver=solver, threshold=1e-4,
                                    rng=np.random.default_rng(1))
    assert _angle_err(est.alpha, acs.alpha) < 1e-9 and _angle_err(est.beta, acs.beta) < 1e-9
    assert est.inliers[~outlier].all()
    assert np.count_nonzero(est.inliers & outlier) <= 2     # an outlier may hit the line by chance
    with pytest.raises(InputError, match="solver: expected one of"):
        peers.estimate_2pc_ransac(acs.normalized.p1, acs.normalized.p2, solver='opengv')


def test_poselib_2pc_minimal_solver_matches_ours_on_exact_samples(rng):
    pytest.importorskip('poselib')
    t = paper_trial(rng, 0.0)
    i = np.argsort(rng.random((40, 50)), axis=1)[:, :2]
    a, b = peers.solve_2pc_poselib(t.normalized.p1[i], t.normalized.p2[i])
    assert a.shape == (40, 2)
    err = np.nanmin(_angle_err(a, t.alpha) + _angle_err(b, t.beta), axis=1)
    assert np.max(err) < 1e-9
    with pytest.raises(InputError, match=r'q1: expected shape \(N, 2, 2\)'):
        peers.solve_2pc_poselib(t.normalized.p1[:4], t.normalized.p2[:4])


def test_poselib_5pc_recovers_exact_motion(rng):
    pytest.importorskip('poselib')
    acs, _ = _exact_scene(rng, 200)
    for estimate in (peers.estimate_5pc_poselib, peers.estimate_5pc_opencv):
        est = estimate(acs.normalized.p1, acs.normalized.p2, threshold=1e-5)
        assert est.ok and est.inliers.mean() > 0.95
        assert rotation_error_deg(est.R, acs.R) < EXACT_DEG
        assert translation_error_deg(est.t, acs.t) < EXACT_DEG
        assert _angle_err(est.alpha, acs.alpha) < 1e-9
    i = np.argsort(rng.random((20, 200)), axis=1)[:, :5]
    R, t = peers.solve_5pc_poselib(acs.normalized.p1[i], acs.normalized.p2[i])
    assert R.shape == (20, 10, 3, 3)
    best = np.nanmin(rotation_error_deg(R, acs.R) + translation_error_deg(t, acs.t), axis=1)
    # Some random 5-point samples are nearly degenerate (several points on one scene plane).
    assert np.median(best) < EXACT_DEG and np.mean(best < 1e-4) >= 0.8


def test_poselib_6pc_recovers_exact_focal_on_a_non_planar_scene(rng):
    pytest.importorskip('poselib')
    acs, _ = _exact_scene(rng, 120)
    c1, c2 = acs.centered
    i = np.argsort(rng.random((20, 120)), axis=1)[:, :6]
    R, t, f = peers.solve_6pc_focal_poselib(c1[i], c2[i])
    best = np.nanmin(np.abs(f / acs.focal - 1.0), axis=1)
    assert np.median(best) < 1e-8
    est = peers.estimate_6pc_focal_poselib(c1, c2, threshold=0.01)
    assert est.ok and abs(est.focal / acs.focal - 1.0) < 1e-6
    assert rotation_error_deg(est.R, acs.R) < 1e-4


# ---------------------------------------------------------------------------------------------
# '1AC + voting'
# ---------------------------------------------------------------------------------------------

def test_1ac_voting_method_is_exact_on_exact_data(rng):
    acs, _ = _exact_scene(rng, 200)
    n = acs.normalized
    alpha, beta = methods.estimate_1ac_voting(n.p1, n.p2, n.A)
    assert abs(alpha - float(acs.alpha)) < 1e-9 and abs(beta - float(acs.beta)) < 1e-9


def test_translation_direction_convention_is_poselibs(rng):
    # PoseLib's x2 = R x1 + t equals ours: its 2pt solver returns Ry(alpha), t(beta) exactly.
    pytest.importorskip('poselib')
    t = paper_trial(rng, 0.0)
    i = np.argsort(rng.random((5, 50)), axis=1)[:, :2]
    a, b = peers.solve_2pc_poselib(t.normalized.p1[i], t.normalized.p2[i])
    k = np.nanargmin(_angle_err(a, t.alpha), axis=1)
    np.testing.assert_allclose(rotation_y(a[np.arange(5), k]), np.broadcast_to(t.R, (5, 3, 3)),
                               atol=1e-12)
    np.testing.assert_allclose(translation_direction(b[np.arange(5), k]),
                               np.broadcast_to(t.t, (5, 3)), atol=1e-12)
