"""planar_vo.tools.evaluation: TUM I/O, association, Umeyama alignment, ATE/RPE/yaw/heading
metrics on exact synthetic trajectories, plots and the eval CLI; cross-checked against evo (run as
a tool)."""

from __future__ import annotations

import json
import math
import re
import shutil

import cv2
import numpy as np
import pytest
import yaml
from evo_tools import evo_ape_stats, run_evo

from planar_vo.cli import main
from planar_vo.core.conventions import planar_pose, rotation_rpy
from planar_vo.core.trajectory import Trajectory
from planar_vo.errors import BagError, InputError
from planar_vo.io import OdometryBagWriter
from planar_vo.tools.evaluation import (
    associate,
    covariance_consistency,
    evaluate,
    kitti_drift,
    read_bag_trajectory,
    read_tum,
    umeyama,
    write_tum,
)

T0 = 1_700_000_000_123_456_789


def _drive(rng, n=60) -> Trajectory:
    """A wiggly planar drive with small height changes, 10 Hz."""
    yaw = np.cumsum(rng.normal(0.0, 0.05, n))
    step = rng.uniform(0.8, 1.2, n)
    x = np.cumsum(step * np.cos(yaw))
    y = np.cumsum(step * np.sin(yaw))
    poses = planar_pose(x, y, yaw, z=rng.normal(0.0, 0.05, n))
    return Trajectory.from_poses(T0 + np.arange(n, dtype=np.int64) * 100_000_000, poses)


def _rotation(rng) -> np.ndarray:
    return rotation_rpy(*rng.uniform(-math.pi / 2, math.pi / 2, 3))


# -- trajectories and TUM -----------------------------------------------------------------------

def test_tum_round_trip_is_exact(tmp_path, rng):
    traj = _drive(rng, 7)
    write_tum(tmp_path / 't.tum', traj)
    text = (tmp_path / 't.tum').read_text()
    assert text.splitlines()[1].startswith('1700000000.123456789 ')
    back = read_tum(tmp_path / 't.tum')
    np.testing.assert_array_equal(back.stamps_ns, traj.stamps_ns)
    np.testing.assert_array_equal(back.positions, traj.positions)
    np.testing.assert_array_equal(back.quaternions, traj.quaternions)


GOOD = '1.0 0 0 0 0 0 0 1'


@pytest.mark.parametrize('lines, match', [
    ([GOOD, '2.0 1 2 3 0 0 0'], r't\.tum line 2: expected 8 values \'timestamp tx ty tz qx qy qz '
                                r"qw', got 7"),
    (['# header', '', GOOD, '2.0 1 2 x 0 0 0 1'], r"t\.tum line 4: tz: expected a number, got "
     r"'x'"),
    ([GOOD, 'two 1 2 3 0 0 0 1'], r"t\.tum line 2: the timestamp: expected a number, got 'two'"),
    ([GOOD, '2.0 1 2 nan 0 0 0 1'], r"t\.tum line 2: tz: expected a finite value, got 'nan'"),
    # (a user test: the line quoted to 80 characters hid the NaN at its end)
    ([GOOD, '1700000000.311634300 3.8123456789012345 0.0686188825109657 0.01 0.0 0.0 0.1 NaN'],
     r"t\.tum line 2: qw: expected a finite value, got 'NaN'"),
    ([GOOD, '2.0 1 2 3 0 0 0 0'], r't\.tum line 2: expected a non-zero quaternion'),
    ([GOOD, '1.0 1 2 3 0 0 0 1'], r't\.tum line 2: expected increasing timestamps, got 1\.0 '
                                  r'after 1\.000000000'),
    (['# nothing here'], r"tum: '.*t\.tum' contains no poses"),
    # nanoseconds written as seconds: beyond ROS time (int64 nanoseconds)
    ([GOOD, '10000000000 1 2 3 0 0 0 1'], r't\.tum line 2: expected a timestamp in seconds '
                                          r'within \+-9\.2e9 s'),
    # squaring such a coordinate overflows the alignment
    ([GOOD, '2.0 1e308 2 3 0 0 0 1'], r't\.tum line 2: expected positions within 1e\+09 m'),
])
def test_tum_errors_name_the_line(tmp_path, lines, match):
    (tmp_path / 't.tum').write_text('\n'.join(lines) + '\n')
    with pytest.raises(InputError, match=match):
        read_tum(tmp_path / 't.tum')


def test_trajectory_validation():
    with pytest.raises(InputError, match=r'quaternions: expected non-zero quaternions, got a '
                                         r'zero one at index 1'):
        Trajectory.from_quaternions(np.array([0, 1]), np.zeros((2, 3)),
                                    np.array([[0, 0, 0, 1], [0, 0, 0, 0]]))
    with pytest.raises(InputError, match=r'positions: expected shape \(2, 3\), got \(3, 3\)'):
        Trajectory.from_quaternions(np.array([0, 1]), np.zeros((3, 3)),
                                    np.tile([0, 0, 0, 1.0], (2, 1)))
    with pytest.raises(InputError, match=r'stamps_ns: expected a 1-D integer array, got float64'):
        Trajectory.from_quaternions(np.array([0.5, 1.0]), np.zeros((2, 3)),
                                    np.tile([0, 0, 0, 1.0], (2, 1)))


def test_associate_nearest_one_to_one():
    ms = 1_000_000
    a = np.array([0, 10, 20, 30, 40]) * ms
    b = np.array([3, 12, 14, 29, 100]) * ms
    ia, ib = associate(a, b, max_diff=0.005)
    assert ia.tolist() == [0, 1, 3] and ib.tolist() == [0, 1, 3]
    # two stamps of a compete for one stamp of b: the closer wins
    ia, ib = associate(np.array([0, 4]) * ms, np.array([3]) * ms, max_diff=0.01)
    assert ia.tolist() == [1] and ib.tolist() == [0]
    assert associate(a, b, max_diff=0.0)[0].size == 0


# -- alignment ----------------------------------------------------------------------------------

@pytest.mark.parametrize('with_scale', [False, True])
def test_umeyama_recovers_exact_transform(rng, with_scale):
    src = rng.normal(size=(20, 3))
    R, t, s = _rotation(rng), rng.normal(size=3), (1.7 if with_scale else 1.0)
    dst = s * src @ R.T + t
    R_, t_, s_ = umeyama(src, dst, with_scale=with_scale)
    np.testing.assert_allclose(R_, R, atol=1e-12)
    np.testing.assert_allclose(t_, t, atol=1e-12)
    assert abs(s_ - s) < 1e-12


def test_umeyama_never_returns_a_reflection(rng):
    src = rng.normal(size=(10, 3))
    R, _, _ = umeyama(src, src * np.array([1.0, 1.0, -1.0]))
    assert np.isclose(np.linalg.det(R), 1.0)
    with pytest.raises(InputError, match=r'src: expected points that are not all identical'):
        umeyama(np.zeros((5, 3)), rng.normal(size=(5, 3)))
    with pytest.raises(InputError, match=r'arguments must have the same number of items'):
        umeyama(src, src[:5])
    huge = src.copy()
    huge[3] = 1e300                # LAPACK's SVD may never return on the overflowed products
    with pytest.raises(InputError, match=r'src, dst: coordinates too large to align'):
        umeyama(huge, src)


# -- metrics on exact synthetic trajectories ----------------------------------------------------

def _assert_all_zero(ev, atol=1e-9):
    m = ev.metrics()
    assert m['ate_m']['max'] < atol
    assert m['rpe_frame']['translation_m']['max'] < atol
    assert m['rpe_frame']['rotation_deg']['max'] < atol
    assert m['yaw_change_error_deg']['max'] < atol and m['heading_error_deg']['max'] < atol
    for seg in m['rpe_distance'].values():
        assert seg['segments'] > 0 and seg['translation_percent'] < atol


def test_identical_trajectories_have_zero_error(rng):
    gt = _drive(rng)
    for align in ('se3', 'sim3', 'origin', 'none'):
        _assert_all_zero(evaluate(gt, gt, align=align))


def test_a_fitted_alignment_of_a_straight_path_says_its_ate_reads_low(rng):
    """A user test: on a nearly straight drive the SE(3) fit turned the estimate 2.5 deg
    about the path, and its ATE fell to a third of --align origin's. The table says so when the
    path's spread across its direction is below 2 % of that along it; not for a turning
    drive, nor for the origin alignment."""
    n = 60
    stamps = T0 + np.arange(n, dtype=np.int64) * 100_000_000
    gt = Trajectory.from_poses(stamps, planar_pose(np.arange(n, dtype=float),
                                                   rng.normal(0.0, 0.05, n), 0.0))
    # The estimate's height drifts and its y wanders: a roll about the path absorbs part.
    est = Trajectory.from_poses(stamps, planar_pose(np.arange(n, dtype=float),
                                                    rng.normal(0.0, 0.05, n), 0.0,
                                                    z=0.01 * np.arange(n)))
    line = evaluate(gt, est, align='se3')
    along, across = line.alignment.spread
    assert along == pytest.approx(np.std(np.arange(n)), rel=1e-3) and across < 0.1
    assert line.alignment.line_like and line.metrics()['alignment']['line_like'] is True
    row = next(r for r in line.format_table().splitlines() if r.startswith('| alignment'))
    assert f'; the path is almost a line (standard deviations {across:.2f} m across, ' \
           f'{along:.1f} m along it): the ' \
           f'fit turns the estimate about it to absorb errors, so the ATE reads low (--align ' \
           f'origin does not)' in row
    assert line.ate.max() < evaluate(gt, est, align='origin').ate.max()
    origin = evaluate(gt, est, align='origin')
    assert not origin.alignment.line_like and 'almost a line' not in origin.format_table()
    turning = _drive(rng)
    ev = evaluate(turning, turning, align='se3')
    assert ev.alignment.spread[1] > 0.02 * ev.alignment.spread[0]
    assert not ev.alignment.line_like and 'almost a line' not in ev.format_table()
    assert ev.metrics()['alignment']['line_like'] is False


def test_alignment_removes_a_known_rigid_offset_exactly(rng):
    gt = _drive(rng)
    R, t = _rotation(rng), np.array([5.0, -3.0, 2.0])
    est = gt.transformed(R, t)
    ev = evaluate(gt, est, align='se3')
    _assert_all_zero(ev)
    np.testing.assert_allclose(ev.alignment.R, R.T, atol=1e-12)     # the inverse transform
    _assert_all_zero(evaluate(gt, est, align='origin'))
    # without alignment a pure translation is the ATE of every pose
    ev = evaluate(gt, gt.transformed(np.eye(3), t), align='none')
    np.testing.assert_allclose(ev.ate, np.linalg.norm(t), rtol=1e-12)
    assert ev.metrics()['rpe_frame']['translation_m']['max'] < 1e-9


def test_sim3_recovers_a_known_scale(rng):
    gt = _drive(rng)
    est = gt.transformed(_rotation(rng), np.array([1.0, 2.0, 3.0]), scale=0.37)
    ev = evaluate(gt, est, align='sim3')
    _assert_all_zero(ev)
    assert abs(ev.alignment.scale - 1.0 / 0.37) < 1e-10
    assert evaluate(gt, est, align='se3').metrics()['ate_m']['rmse'] > 1.0


@pytest.mark.parametrize('align', ['none', 'se3'])
def test_known_yaw_drift_and_heading_offset_give_expected_errors(align):
    """Ground truth drives straight at 1 m/frame; the estimate turns an extra `w` per frame and
    steps at heading `h` in its own frame: yaw-change error w, heading error h, RPE as derived."""
    n, w, h = 41, math.radians(0.5), math.radians(2.0)
    stamps = T0 + np.arange(n, dtype=np.int64) * 100_000_000
    gt = Trajectory.from_poses(stamps, planar_pose(np.arange(n, dtype=float), 0.0, 0.0))
    yaw = w * np.arange(n)
    step = np.array([math.cos(h), math.sin(h)])
    xy = [np.zeros(2)]
    for k in range(1, n):
        c, s = math.cos(yaw[k - 1]), math.sin(yaw[k - 1])
        xy.append(xy[-1] + np.array([[c, -s], [s, c]]) @ step)
    xy = np.array(xy)
    est = Trajectory.from_poses(stamps, planar_pose(xy[:, 0], xy[:, 1], yaw))
    ev = evaluate(gt, est, align=align, segment_lengths=(5.0, 10.0))
    np.testing.assert_allclose(ev.yaw_change_error_deg, math.degrees(w), atol=1e-9)
    np.testing.assert_allclose(ev.heading_error_deg, math.degrees(h), atol=1e-9)
    np.testing.assert_allclose(ev.rpe_rotation_deg, math.degrees(w), atol=1e-9)
    np.testing.assert_allclose(ev.rpe_translation, 2 * math.sin(h / 2), atol=1e-9)
    m = ev.metrics()
    assert abs(m['yaw_change_error_deg']['bias'] - math.degrees(w)) < 1e-9
    for length in (5, 10):
        # independent derivation: the estimate's motion over `length` frames, in its own frame
        shift = sum(np.array([[math.cos(k * w), -math.sin(k * w)],
                              [math.sin(k * w), math.cos(k * w)]]) @ step for k in range(length))
        expected_t = 100.0 * np.linalg.norm(shift - [length, 0.0]) / length
        seg = m['rpe_distance'][f'{length}m']
        assert seg['segments'] == n - length
        assert abs(seg['translation_percent'] - expected_t) < 1e-9
        assert abs(seg['rotation_deg_per_m'] - math.degrees(w)) < 1e-9


def test_heading_undefined_when_standing_still(rng):
    stamps = T0 + np.arange(4, dtype=np.int64) * 100_000_000
    gt = Trajectory.from_poses(stamps, planar_pose(np.array([0.0, 1.0, 1.0, 2.0]), 0.0, 0.0))
    ev = evaluate(gt, gt, align='none')
    assert np.isnan(ev.heading_error_deg).tolist() == [False, True, False]
    assert ev.metrics()['heading_error_deg']['count'] == 2


def test_plots_mark_the_slow_frames_whose_heading_is_ill_defined(tmp_path, rng):
    from planar_vo.tools.evaluation.plots import SLOW_SPEED, save_plots, slow_steps

    # 1 m per frame, a crawl of 2 cm per frame (0.2 m/s), standing still, 1 m per frame again;
    # the estimate's heading is off by up to 30 degrees only where it crawls or stands.
    x = np.cumsum([0.0] + [1.0] * 10 + [0.02] * 5 + [0.0] * 5 + [1.0] * 10)
    stamps = T0 + np.arange(len(x), dtype=np.int64) * 100_000_000
    zero = np.zeros_like(x)
    gt = Trajectory.from_poses(stamps, planar_pose(x, zero, zero))
    y = np.zeros_like(x)
    y[11:21] = 0.01 * rng.standard_normal(10)
    est = Trajectory.from_poses(stamps, planar_pose(x, y, zero))
    ev = evaluate(gt, est, align='none')
    slow = slow_steps(ev)
    assert SLOW_SPEED == 0.5 and slow.tolist() == [False] * 10 + [True] * 10 + [False] * 10
    assert np.nanmax(np.abs(ev.heading_error_deg[slow])) > 5.0
    assert np.nanmax(np.abs(ev.heading_error_deg[~slow])) < 2.0
    paths = save_plots(ev, tmp_path)
    assert [p.name for p in paths] == ['trajectory.png', 'ate.png', 'yaw_heading.png']
    assert all(cv2.imread(str(p)) is not None for p in paths)


def test_evaluate_needs_matching_stamps(rng):
    gt = _drive(rng, 5)
    late = gt.shifted(10**9)
    with pytest.raises(InputError, match=r'association: expected at least 2 poses matched within '
                                         r'0\.02 s, got 0 \(estimate 5 poses 1700000001\.123\.\.'
                                         r'.*\); the ranges do not overlap: the estimate starts '
                                         r'1\.000 s after the reference \(stamps of another '
                                         r'clock, or relative to the start\?\)$'):
        evaluate(gt, late)
    with pytest.raises(InputError, match=r"align: expected one of \['se3', 'sim3', 'origin', "
                                         r"'none'\], got 'affine'"):
        evaluate(gt, gt, align='affine')


# -- evo cross-checks (evo is GPL: run as a tool, never imported) -------------------------------

def _noisy_estimate(rng, gt: Trajectory, scale: float) -> Trajectory:
    est = gt.transformed(_rotation(rng), np.array([3.0, -1.0, 0.5]), scale=scale)
    return Trajectory.from_quaternions(
        est.stamps_ns, est.positions + rng.normal(0, 0.2, est.positions.shape),
        est.quaternions)


@pytest.mark.parametrize('align, flags', [('se3', ['-a']), ('sim3', ['-as'])])
def test_ate_equals_evo_ape(tmp_path, rng, evo_env, align, flags):
    gt = _drive(rng)
    est = _noisy_estimate(rng, gt, scale=1.3)
    write_tum(tmp_path / 'gt.tum', gt)
    write_tum(tmp_path / 'est.tum', est)
    evo = evo_ape_stats(evo_env, tmp_path, 'tum', 'gt.tum', 'est.tum', *flags)
    ours = evaluate(read_tum(tmp_path / 'gt.tum'), read_tum(tmp_path / 'est.tum'),
                    align=align).metrics()['ate_m']
    assert ours['rmse'] > 0.1                                  # a real error, not a trivial 0
    for key in ('rmse', 'mean', 'median', 'std', 'min', 'max'):
        assert abs(ours[key] - evo[key]) < 1e-6, key


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_evo_reads_our_bags_and_agrees_on_ate(tmp_path, rng, evo_env, storage):
    gt = _drive(rng, 40)
    est = _noisy_estimate(rng, gt, scale=1.0)
    bag = tmp_path / 'vo'
    with OdometryBagWriter(bag, storage=storage) as writer:
        writer.add_topic('/ground_truth/odom', 'nav_msgs/msg/Odometry')
        for stamp, T_est, T_gt in zip(gt.stamps_ns, est.poses, gt.poses):
            writer.write(int(stamp), T_est)
            writer.write_odometry('/ground_truth/odom', int(stamp), T_gt)
    out = run_evo(evo_env, 'evo_traj', 'bag2', str(bag), '--all_topics', cwd=tmp_path)
    assert out.count('40 poses') == 2 and 'name:\t/odom' in out
    evo = evo_ape_stats(evo_env, tmp_path, 'bag2', str(bag), '/ground_truth/odom', '/odom',
                        '-a')
    ours = evaluate(read_bag_trajectory(bag, '/ground_truth/odom'),
                    read_bag_trajectory(bag, '/odom')).metrics()['ate_m']
    for key in ('rmse', 'mean', 'median', 'max'):
        assert abs(ours[key] - evo[key]) < 1e-6, key


# -- bags and the CLI ---------------------------------------------------------------------------

def _bag_with(tmp_path, rng, topics=('/odom', '/ground_truth/odom')):
    gt = _drive(rng, 30)
    est = gt.transformed(np.eye(3), np.array([0.5, 0.0, 0.0]))
    path = tmp_path / 'both'
    with OdometryBagWriter(path, topic=topics[0]) as writer:
        for name in topics[1:]:
            writer.add_topic(name, 'nav_msgs/msg/Odometry')
        for stamp, T_est, T_gt in zip(gt.stamps_ns, est.poses, gt.poses):
            writer.write(int(stamp), T_est)
            for name in topics[1:]:
                writer.write_odometry(name, int(stamp), T_gt)
    return path, gt, est


def test_read_bag_trajectory_exact_and_errors(tmp_path, rng):
    path, gt, est = _bag_with(tmp_path, rng)
    got = read_bag_trajectory(path, '/ground_truth/odom')
    np.testing.assert_array_equal(got.stamps_ns, gt.stamps_ns)
    np.testing.assert_allclose(got.poses, gt.poses, atol=1e-14)
    with pytest.raises(BagError, match=r"gt-topic: '/gt' is not a topic of '.*both'; available "
                                       r'topics: /ground_truth/odom \(nav_msgs/msg/Odometry\), '
                                       r'/odom \(nav_msgs/msg/Odometry\)'):
        read_bag_trajectory(path, '/gt', role='gt-topic')


def test_a_bad_pose_in_a_bag_names_the_bag_topic_and_stamp(tmp_path):
    from bagdata import odometry_msg, write_bag

    entries = [('/gt', 'nav_msgs/msg/Odometry', 1_000_000_000 + k * 100_000_000,
                odometry_msg(1_000_000_000 + k * 100_000_000, float('nan') if k == 2 else k))
               for k in range(4)]
    path = write_bag(tmp_path / 'gt_nan', 'mcap', entries)
    with pytest.raises(InputError, match=r"gt-topic: '/gt' in '.*gt_nan', the message stamped "
                                         r'1\.200000000 s: .*finite'):
        read_bag_trajectory(path, '/gt', role='gt-topic')


def test_cli_eval_warns_when_most_poses_find_no_partner(tmp_path, rng, caplog):
    """The same frames stamped two ways (import-video at a given rate, import-kitti from
    times.txt): a few poses match by chance and the figures describe them alone (a user test:
    19 of 120 matched, t_rel 126 %, and only a 'two drives?' note). Said, with both spans."""
    gt = _drive(rng)
    skewed = Trajectory(gt.stamps_ns[0] + ((gt.stamps_ns - gt.stamps_ns[0]) * 1.04).astype(
        np.int64), gt.poses)
    write_tum(tmp_path / 'gt.tum', gt)
    write_tum(tmp_path / 'est.tum', skewed)
    with caplog.at_level('WARNING', logger='planar_vo.eval'):
        assert main(['eval', str(tmp_path / 'est.tum'), '--gt', str(tmp_path / 'gt.tum')]) == 0
    warned = [r.getMessage() for r in caplog.records if 'are matched within' in r.getMessage()]
    assert len(warned) == 1 and warned[0].startswith('only ') and \
        'the two are stamped differently (EST ' in warned[0], warned
    caplog.clear()
    write_tum(tmp_path / 'est2.tum', gt)                    # every pose matched: nothing said
    with caplog.at_level('WARNING', logger='planar_vo.eval'):
        assert main(['eval', str(tmp_path / 'est2.tum'), '--gt', str(tmp_path / 'gt.tum')]) == 0
    assert not [r for r in caplog.records if 'are matched within' in r.getMessage()]


def test_cli_eval_tum_files_writes_metrics_and_plots(tmp_path, rng, capsys):
    gt = _drive(rng)
    est = _noisy_estimate(rng, gt, scale=1.0)
    write_tum(tmp_path / 'gt.tum', gt)
    write_tum(tmp_path / 'est.tum', est)
    out = tmp_path / 'eval'
    assert main(['eval', str(tmp_path / 'est.tum'), '--gt', str(tmp_path / 'gt.tum'),
                 '--out-dir', str(out), '--segments', '5', '10']) == 0
    printed = capsys.readouterr().out
    assert 'ATE (m) rmse' in printed and 'RPE 5m segments' in printed
    metrics = json.loads((out / 'metrics.json').read_text())
    expected = evaluate(gt, est, segment_lengths=(5.0, 10.0)).metrics()
    assert metrics['ate_m'] == pytest.approx(expected['ate_m'])
    assert set(metrics['rpe_distance']) == {'5m', '10m', 'all'}
    assert metrics['poses']['matched'] == 60
    for name in ('trajectory.png', 'ate.png', 'yaw_heading.png'):
        img = cv2.imread(str(out / name))
        assert img is not None and img.shape[0] > 300 and img.std() > 5, name
    # An earlier evaluation is replaced only with --force.
    again = ['eval', str(tmp_path / 'est.tum'), '--gt', str(tmp_path / 'gt.tum'), '--out-dir',
             str(out), '--align', 'none']
    before = (out / 'metrics.json').read_text()
    assert main(again) == 1
    assert capsys.readouterr().err == (
        f"planar_vo eval: error: --out-dir: '{out}' holds an earlier evaluation (metrics.json); "
        f'refusing to overwrite it (give --force, or choose another folder)\n')
    assert (out / 'metrics.json').read_text() == before
    assert main([*again, '--force']) == 0
    assert json.loads((out / 'metrics.json').read_text())['alignment']['method'] == 'none'


def test_cli_eval_bag_with_both_topics(tmp_path, rng, capsys):
    path, gt, est = _bag_with(tmp_path, rng)
    assert main(['eval', str(path), '--align', 'none']) == 0
    printed = capsys.readouterr().out
    assert f'reference: {path} (/ground_truth/odom)' in printed
    row = next(line for line in printed.splitlines() if line.startswith('| ATE (m)'))
    assert row.split('|')[2].split('/')[0].strip() == '0.500000'      # the known offset


def test_cli_eval_says_when_the_ground_truth_is_another_drives(tmp_path, rng, capsys, caplog):
    """A user test: one drive's odometry scored against another's ground truth (their stamps
    matched) without a word. A replayed bag names its input: a reference that is neither that
    bag nor replayed from it is warned about."""
    path, _, _ = _bag_with(tmp_path, rng)
    meta = path / 'metadata.yaml'
    text = meta.read_text()
    for name, source in (('a_vo', tmp_path / 'a'), ('b_vo', tmp_path / 'b')):
        shutil.copytree(path, tmp_path / name)
        info = yaml.safe_load(text)
        info['rosbag2_bagfile_information']['custom_data'] = {'planar_vo.input': str(source)}
        (tmp_path / name / 'metadata.yaml').write_text(yaml.safe_dump(info))
    shutil.copytree(path, tmp_path / 'a')                  # a's own bag (it holds no images)
    for gt, warned in (('b_vo', True), ('a_vo', False), ('a', False), (None, False)):
        caplog.clear()
        extra = ['--gt', str(tmp_path / gt)] if gt else []
        assert main(['eval', str(tmp_path / 'a_vo'), *extra, '--align', 'none']) == 0
        capsys.readouterr()
        found = [r.getMessage() for r in caplog.records if 'two drives' in r.getMessage()]
        assert found == ([f"EST was replayed from '{tmp_path / 'a'}' and GT is "
                          f"'{tmp_path / 'b_vo'}', replayed from '{tmp_path / 'b'}': two "
                          f'drives? Their stamps can match (import-kitti starts every drive at '
                          f'the same time)'] if warned else []), gt


def _with_known_errors(rng, ref: Trajectory):
    """The reference moved by an arbitrary rigid transform (the odometry's own origin), each
    pose after the first then off by a known error (position, and rotation in the world frame)
    and given a diagonal covariance; returns the estimate, the errors and the deviations."""
    from planar_vo.core.conventions import se3, so3_exp

    moved = se3(_rotation(rng), rng.normal(0.0, 10.0, 3))
    errors = rng.normal(0.0, 0.05, (len(ref), 6))
    errors[0] = 0.0
    std = rng.uniform(0.01, 0.1, (len(ref), 6))
    poses = []
    for P, e in zip(ref.poses, errors):
        T = moved @ P
        poses.append(se3(so3_exp(e[3:]) @ T[:3, :3], T[:3, 3] + e[:3]))
    covariances = np.array([np.diag(s * s) for s in std])
    return Trajectory(ref.stamps_ns, np.array(poses)), errors, std, covariances


def test_covariance_consistency_is_each_error_over_its_reported_deviation(rng):
    ref = _drive(rng, 40)
    est, errors, std, covariances = _with_known_errors(rng, ref)
    # Correlated x and y on every pose: the 2D distance must use the correlation.
    rho = rng.uniform(-0.9, 0.9, 40)
    covariances[:, 0, 1] = covariances[:, 1, 0] = rho * std[:, 0] * std[:, 1]
    c = covariance_consistency(ref, est, covariances)
    z = np.abs(errors[1:]) / std[1:]
    assert c['frames'] == 39
    for i, axis in enumerate(('x', 'y', 'z', 'roll', 'pitch', 'yaw')):
        assert c['abs_z'][axis]['median'] == pytest.approx(np.median(z[:, i]), rel=1e-9)
        assert c['abs_z'][axis]['max'] == pytest.approx(np.max(z[:, i]), rel=1e-9)
        assert c['abs_z'][axis]['within'] == pytest.approx(np.mean(z[:, i] <= 3.0))
    u, v, r = errors[1:, 0] / std[1:, 0], errors[1:, 1] / std[1:, 1], rho[1:]
    d = np.sqrt((u * u - 2 * r * u * v + v * v) / (1 - r * r))
    assert c['position_2d']['max'] == pytest.approx(np.max(d), rel=1e-9)
    assert c['position_2d']['p90'] == pytest.approx(np.percentile(d, 90), rel=1e-9)
    # A planar odometry (z, roll and pitch at zero) is judged on the axes it reports; a singular
    # x-y block leaves the 2D distance out instead of failing.
    planar = covariances.copy()
    planar[:, 2, 2] = planar[:, 3, 3] = planar[:, 4, 4] = 0.0
    planar[:, 0, 1] = planar[:, 1, 0] = std[:, 0] * std[:, 1]             # correlation 1
    c = covariance_consistency(ref, est, planar)
    assert set(c['abs_z']) == {'x', 'y', 'yaw'} and 'position_2d' not in c
    # No usable covariance (all zeros: a topic that does not fill it): said so.
    none = covariance_consistency(ref, est, np.zeros((40, 6, 6)))
    assert none['frames'] == 0 and 'no pose after the first' in none['reason']
    # One pose after the first (a two-frame drive): too few, not 'no variance' (a user test).
    two = covariance_consistency(Trajectory(ref.stamps_ns[:2], ref.poses[:2]),
                                 Trajectory(est.stamps_ns[:2], est.poses[:2]), covariances[:2])
    assert two == {'frames': 0, 'reason': 'needs at least 2 poses after the first with a '
                                          'positive variance on an axis, got 1'}
    with pytest.raises(InputError, match=r'covariances: expected shape \(40, 6, 6\)'):
        covariance_consistency(ref, est, covariances[1:])


def test_cli_eval_prints_the_covariance_consistency_of_an_odometry_bag(tmp_path, rng, capsys):
    ref = _drive(rng, 30)
    est, errors, std, covariances = _with_known_errors(rng, ref)
    path = tmp_path / 'odom'
    with OdometryBagWriter(path, topic='/odom') as writer:
        writer.add_topic('/ground_truth/odom', 'nav_msgs/msg/Odometry')
        # Written newest first, with an extra estimate before the reference starts and a
        # repeated stamp (dropped by the reader): the covariances must follow their poses.
        writer.write(int(ref.stamps_ns[0]) - 10 ** 9, est.poses[0], np.eye(6))
        for k in reversed(range(len(ref))):
            writer.write(int(ref.stamps_ns[k]), est.poses[k], covariances[k])
            writer.write_odometry('/ground_truth/odom', int(ref.stamps_ns[k]), ref.poses[k])
        writer.write(int(ref.stamps_ns[5]), est.poses[5], covariances[5] * 100.0)
    out = tmp_path / 'eval'
    assert main(['eval', str(path), '--out-dir', str(out)]) == 0
    printed = capsys.readouterr().out
    z = np.abs(errors[1:]) / std[1:]
    row = next(line for line in printed.splitlines() if line.startswith('|   roll '))
    assert row.split('|')[2].split('/')[0].strip() == f'{np.median(z[:, 3]):.2f}', row
    assert 'n=29)' in row
    assert 'honest: 0.67 / 1.65 (2D: 1.18 / 2.15)' in printed
    metrics = json.loads((out / 'metrics.json').read_text())
    assert metrics['covariance']['abs_z']['yaw']['max'] == pytest.approx(np.max(z[:, 5]))
    # The ground truth's topic has no covariance (zeros): evaluated as the estimate, said so.
    assert main(['eval', str(path), '--est-topic', '/ground_truth/odom', '--gt-topic',
                 '/odom']) == 0
    row = next(line for line in capsys.readouterr().out.splitlines()
               if line.startswith('| covariance'))
    assert 'not evaluated: no pose after the first' in row


def test_cli_eval_refuses_a_report_folder_that_is_a_file_or_a_bag(tmp_path, rng, capsys):
    # Before the work (a user test found the table computed first and then an error, and a bag
    # folder filled with metrics.json and plots).
    path, _, _ = _bag_with(tmp_path, rng)
    listing = sorted(p.name for p in path.iterdir())
    (tmp_path / 'a_file').write_text('x')
    as_file = 'is a file; expected the folder for the report (made if missing)'
    for out, why in ((tmp_path / 'a_file', as_file),
                     (path, 'is a bag; choose another folder for the report')):
        assert main(['eval', str(path), '--out-dir', str(out)]) == 1
        captured = capsys.readouterr()
        assert captured.out == ''
        assert captured.err == f"planar_vo eval: error: --out-dir: '{out}' {why}\n"
    assert sorted(p.name for p in path.iterdir()) == listing


def test_cli_eval_errors_are_one_line(tmp_path, rng, capsys):
    gt = _drive(rng, 5)
    write_tum(tmp_path / 'est.tum', gt)
    (tmp_path / 'bad.tum').write_text('1.0 0 0 0 0 0 0 1\n2.0 0 0\n')
    cases = [
        (['eval', str(tmp_path / 'est.tum')],
         'error: --gt: expected GT when EST is a file (TUM or KITTI poses), got none'),
        (['eval', str(tmp_path / 'est.tum'), '--gt', str(tmp_path / 'bad.tum')],
         "bad.tum line 2: expected 8 values 'timestamp tx ty tz qx qy qz qw', got 3"),
        (['eval', str(tmp_path / 'est.tum'), '--gt', str(tmp_path / 'missing.tum')],
         "error: --gt: '" + str(tmp_path / 'missing.tum') + "' does not exist"),
        (['eval', str(tmp_path / 'est.tum'), '--gt', str(tmp_path / 'est.tum'), '--segments',
          '0'], 'error: --segments: expected positive lengths in metres, got [0.0]'),
        # (a user test: twice the same length counted its segments twice; a topic for a TUM
        # file was ignored)
        (['eval', str(tmp_path / 'est.tum'), '--gt', str(tmp_path / 'est.tum'), '--segments',
          '5', '5'], 'error: --segments: expected different lengths, got [5.0, 5.0]'),
        (['eval', str(tmp_path / 'est.tum'), '--gt', str(tmp_path / 'est.tum'), '--est-topic',
          '/foo'], f"error: --est-topic: '{tmp_path / 'est.tum'}' is a file (TUM or KITTI "
                   f'poses), which has no topics; give --est-topic only for a bag'),
        (['eval', str(tmp_path / 'est.tum'), '--gt', str(tmp_path / 'est.tum'), '--gt-topic',
          '/foo'], f"error: --gt-topic: '{tmp_path / 'est.tum'}' is a file (TUM or KITTI "
                   f'poses), which has no topics; give --gt-topic only for a bag'),
    ]
    path, _, _ = _bag_with(tmp_path, rng, topics=('/odom',))
    cases.append((['eval', str(path)], "error: --gt-topic: '/ground_truth/odom' is not a topic of"))
    # Neither --gt nor --gt-topic given: the message says what to give (a user test).
    cases.append((['eval', str(path)], '; EST has no ground truth: give it with --gt (a TUM '
                                       'file or a bag), and its topic with --gt-topic'))
    # Errors of the evaluation itself name the arguments as typed: EST, --gt (--gt-topic when
    # the ground truth is in the EST bag), --max-diff.
    write_tum(tmp_path / 'parked.tum', Trajectory.from_poses(gt.stamps_ns, np.tile(np.eye(4),
                                                                                   (5, 1, 1))))
    cases.append((['eval', str(tmp_path / 'parked.tum'), '--gt', str(tmp_path / 'est.tum')],
                  'error: EST: expected points that are not all identical (a trajectory that '
                  'moves), got 5 identical points; a trajectory that does not move cannot be '
                  'aligned: give --align origin'))
    cases.append((['eval', str(tmp_path / 'est.tum'), '--gt', str(tmp_path / 'est.tum'),
                   '--max-diff', '-1'],
                  'error: --max-diff: expected a non-negative number of seconds, got -1.0'))
    huge = tmp_path / 'huge'
    with OdometryBagWriter(huge, topic='/odom') as writer:
        writer.add_topic('/ground_truth/odom', 'nav_msgs/msg/Odometry')
        for i, (stamp, T) in enumerate(zip(gt.stamps_ns, gt.poses)):
            writer.write(int(stamp), planar_pose(1e300, 0.0, 0.0) if i == 2 else T)
            writer.write_odometry('/ground_truth/odom', int(stamp), T)
    cases.append((['eval', str(huge)], 'error: EST, --gt-topic: coordinates too large to align'))
    for argv, expected in cases:
        assert main(argv) == 1
        err = capsys.readouterr().err.strip()
        assert err.startswith('planar_vo eval: error: ') and '\n' not in err, err
        assert expected in err, err


@pytest.mark.parametrize(('est', 'gt', 'message'), [
    ('missing.tum', 'est.tum', "EST: 'missing.tum' does not exist"),
    ('est.tum', 'missing.tum', "--gt: 'missing.tum' does not exist"),
    ('empty.tum', 'est.tum', "EST: 'empty.tum' contains no poses"),
    ('est.tum', 'empty.tum', "--gt: 'empty.tum' contains no poses"),
    ('est.tum', 'folder', "--gt: 'folder' is not a bag: expected a directory with metadata.yaml "
                          'or a .mcap/.db3 file'),
])
def test_cli_eval_names_the_paths_as_typed(tmp_path, rng, monkeypatch, capsys, est, gt, message):
    """A trajectory that cannot be read is EST or --gt, as on the command line (was the
    library's 'trajectory', 'tum' or 'bag', the same for both)."""
    monkeypatch.chdir(tmp_path)
    write_tum(tmp_path / 'est.tum', _drive(rng, 5))
    (tmp_path / 'empty.tum').write_text('')
    (tmp_path / 'folder').mkdir()
    assert main(['eval', est, '--gt', gt]) == 1
    assert capsys.readouterr().err == f'planar_vo eval: error: {message}\n'


# -- KITTI protocol ---------------------------------------------------------------------------

def _straight(n: int, step: float = 1.0, yaw_rate: float = 0.0) -> Trajectory:
    """A drive of ``n`` poses, ``step`` metres apart along the heading, turning ``yaw_rate`` rad
    per pose (a straight line for 0)."""
    yaw = yaw_rate * np.arange(n)
    xy = np.concatenate([[[0.0, 0.0]], np.cumsum(
        step * np.column_stack([np.cos(yaw[:-1]), np.sin(yaw[:-1])]), axis=0)])
    return Trajectory.from_poses(T0 + np.arange(n, dtype=np.int64) * 100_000_000,
                                 planar_pose(xy[:, 0], xy[:, 1], yaw))


def test_kitti_drift_is_zero_for_the_truth_and_ten_percent_for_a_scale_of_1_1():
    ref = _straight(351)                                   # 350 m: segments of 100..300 m
    zero = kitti_drift(ref, ref)
    assert zero['t_rel_pct'] == 0.0 and zero['r_rel_deg_per_100m'] == 0.0
    assert zero['lengths_m'] == [100.0, 200.0, 300.0]
    # Starts every 10 poses with a full segment: 26 + 16 + 6 of them.
    assert zero['segments'] == 26 + 16 + 6
    long = ref.transformed(np.eye(3), np.zeros(3), scale=1.1)
    assert kitti_drift(ref, long)['t_rel_pct'] == pytest.approx(10.0, abs=1e-9)
    assert kitti_drift(ref, long, planar=True)['t_rel_pct'] == pytest.approx(10.0, abs=1e-9)
    assert math.isnan(kitti_drift(ref.subset(slice(0, 50)), ref.subset(slice(0, 50)))['t_rel_pct'])
    # Unassociated trajectories are an error, not NaN (a user test); so is an array given to
    # evaluate.
    with pytest.raises(InputError, match=r'ref, est: expected associated trajectories of one '
                                         r'length, got 351 and 10 poses'):
        kitti_drift(ref, ref.subset(slice(0, 10)))
    with pytest.raises(InputError, match=r'^ref: expected a Trajectory .*, got ndarray$'):
        evaluate(ref.poses, ref)


def test_frame_pairs_across_dropped_frames_are_not_per_frame_errors():
    # The estimate lost frames 10-39 of a drive turning 1 deg per frame: the pair (9, 40) spans
    # 31 frames and is left out of the per-frame yaw and heading errors (it counted as one).
    ref = _straight(61, yaw_rate=math.radians(1.0))
    keep = np.r_[0:10, 40:61]
    est = ref.subset(keep)
    ev = evaluate(ref, est, align='none')
    yaw = ev.yaw_change_error_deg
    assert yaw.shape == (30,) and np.isnan(yaw[9]) and np.isnan(ev.heading_error_deg[9])
    assert np.all(np.abs(np.delete(yaw, 9)) < 1e-9)
    assert ev.metrics()['yaw_change_error_deg']['count'] == 29
    # The relative pose error per frame likewise (a user test: its maximum, 37.6 m, spanned a
    # gap of 100 frames).
    for rpe in (ev.rpe_translation, ev.rpe_rotation_deg):
        assert rpe.shape == (30,) and np.isnan(rpe[9])
        assert np.all(np.abs(np.delete(rpe, 9)) < 1e-9)
    assert ev.metrics()['rpe_frame']['translation_m']['count'] == 29


def test_kitti_rotation_drift_of_a_yaw_rate_bias():
    ref = _straight(301)
    bias = np.deg2rad(0.01)                               # per metre: 1 deg per 100 m
    est = _straight(301, yaw_rate=bias)
    drift = kitti_drift(ref, est)
    assert drift['r_rel_deg_per_100m'] == pytest.approx(1.0, rel=1e-6)
    assert kitti_drift(ref, est, planar=True)['r_rel_deg_per_100m'] == pytest.approx(1.0, rel=1e-6)


def test_a_drive_shorter_than_100_m_gets_the_protocol_on_10_to_50_m():
    ref = _straight(61)                                   # 60 m: no 100 m segment
    est = ref.transformed(np.eye(3), np.zeros(3), scale=1.1)
    metrics = evaluate(ref, est, align='none').metrics()
    assert metrics['kitti']['segments'] == 0 and math.isnan(metrics['kitti']['t_rel_pct'])
    short = metrics['kitti_short']
    assert short['lengths_m'] == [10.0, 20.0, 30.0, 40.0, 50.0]
    assert short['segments'] == 6 + 5 + 4 + 3 + 2          # a start every 10 frames (1 m)
    assert short['t_rel_pct'] == pytest.approx(10.0, abs=1e-9)
    assert metrics['kitti_short_se2']['t_rel_pct'] == pytest.approx(10.0, abs=1e-9)
    table = evaluate(ref, est, align='none').format_table().splitlines()
    rows = [ln for ln in table if ln.startswith('| KITTI protocol on 10-50 m (short drive)')]
    assert len(rows) == 2 and all('| 10.000 / ' in ln for ln in rows), rows
    assert not [ln for ln in table if 'nan / nan' in ln]      # no empty 100-800 m rows
    # A long drive has no short figures.
    assert 'kitti_short' not in evaluate(_straight(301), _straight(301)).metrics()


def test_se2_drift_ignores_height_roll_and_pitch():
    ref = _straight(301)
    rng = np.random.default_rng(3)
    bumpy = ref.poses.copy()
    bumpy[:, :3, :3] = rotation_rpy(rng.normal(0, 0.01, 301), rng.normal(0, 0.01, 301),
                                    ref.yaw)
    bumpy[:, 2, 3] = rng.normal(0, 0.2, 301)
    est = Trajectory(ref.stamps_ns, bumpy)
    assert kitti_drift(ref, est)['r_rel_deg_per_100m'] > 0.1
    flat = kitti_drift(ref, est, planar=True)
    assert flat['t_rel_pct'] < 1e-9 and flat['r_rel_deg_per_100m'] < 1e-9
    metrics = evaluate(ref, est).metrics()
    assert metrics['kitti_se2']['r_rel_deg_per_100m'] < 1e-9
    assert metrics['kitti']['segments'] == 21 + 11 + 1


def test_tum_with_a_byte_order_mark_reads_like_without(tmp_path):
    (tmp_path / 't.tum').write_text('\ufeff' + GOOD + '\n2.0 1 2 3 0 0 0 1\n', encoding='utf-8')
    assert len(read_tum(tmp_path / 't.tum')) == 2


def _camera_drive(rng, tmp_path, height=1.65):
    """A drive's ground truth as import-kitti writes it (a level vehicle, stamps from the
    default start plus times.txt) and the same drive as KITTI camera poses (T_w_cam)."""
    from planar_vo.core.conventions import mount_transform
    from planar_vo.core.trajectory import invert

    gt = _drive(rng)
    T_bc = mount_transform(height=height)
    cam = invert(T_bc) @ gt.poses @ T_bc              # the camera's poses, world = camera 0
    cam = invert(cam[0]) @ cam
    gt = Trajectory(gt.stamps_ns, T_bc @ cam @ invert(T_bc))
    times = (gt.stamps_ns - 1_700_000_000 * 10 ** 9) / 1e9
    (tmp_path / 'times.txt').write_text(''.join(f'{t:.9f}\n' for t in times))
    (tmp_path / 'other.txt').write_text(''.join(
        ' '.join(f'{v:.12g}' for v in p[:3].ravel()) + '\n' for p in cam))
    write_tum(tmp_path / 'gt.tum', gt)
    write_tum(tmp_path / 'cam.tum', Trajectory(gt.stamps_ns, cam))
    return gt, cam


def _metric_line(text: str, start: str) -> str:
    return next(line for line in text.splitlines() if line.startswith(start))


def test_cli_eval_of_another_methods_kitti_or_camera_poses(tmp_path, rng, capsys, caplog):
    """A user test: KITTI's own poses written as TUM (camera poses) scored t_rel 101 % against
    the ground truth import-kitti writes, without a word. A KITTI pose file with --est-times,
    or camera poses with --est-frame camera, now compare exactly; camera poses without the
    option are warned about."""
    _camera_drive(rng, tmp_path)
    gt = str(tmp_path / 'gt.tum')
    lines = (tmp_path / 'other.txt').read_text().splitlines()
    (tmp_path / 'commented.txt').write_text('# KITTI poses\n' + '\n'.join(lines) + '\n')
    for k, est in enumerate((['other.txt', '--est-times', str(tmp_path / 'times.txt')],
                             ['commented.txt', '--est-times', str(tmp_path / 'times.txt')],
                             ['cam.tum', '--est-frame', 'camera'])):
        out_dir = tmp_path / f'report{k}'
        assert main(['eval', str(tmp_path / est[0]), *est[1:], '--gt', gt,
                     '--segments', '5', '--out-dir', str(out_dir)]) == 0
        # How the files were read, to repeat it (a user test).
        read_as = json.loads((out_dir / 'metrics.json').read_text())['read_as']
        assert read_as['est_frame'] == 'camera' and read_as['camera_height_m'] == 1.65
        assert read_as['est_times'] == (str(tmp_path / 'times.txt') if k < 2 else None)
        out = capsys.readouterr().out
        assert '| matched poses | 60 (unmatched: 0 estimated, 0 reference) |' in \
            ' '.join(out.split()).replace('| |', '|')
        for start, value in (('| ATE (m) rmse', '0.000000 / 0.000000 / 0.000000 / 0.000000'),
                             ('| RPE/frame rot (deg)', '0.000000 / 0.000000'),
                             ('| KITTI protocol on 10-50 m (short drive), SE(2)', '0.000 / 0.000'),
                             ('| heading error (deg)', '0.0000 / 0.0000 / 0.0000')):
            assert value in _metric_line(out, start), (start, out)
    caplog.clear()
    assert main(['eval', str(tmp_path / 'cam.tum'), '--gt', gt, '--segments', '5']) == 0
    capsys.readouterr()
    assert "moves along its poses' z axis, an optical camera's forward" in caplog.text
    caplog.clear()
    assert main(['eval', gt, '--gt', gt, '--segments', '5']) == 0     # base poses: no word
    assert 'optical camera' not in caplog.text


@pytest.mark.parametrize('extra, message', [
    ([], "--est-times: '{est}' is a KITTI pose file, which has no stamps; give the sequence's "
         'times.txt'),
    (['--est-times', '{dir}/times.txt', '--est-frame', 'base'],
     '--est-frame: a KITTI pose file holds camera poses (T_w_cam); give --est-frame camera or '
     'leave it out'),
    (['--est-times', '{dir}/short.txt'],
     "--est-times: '{dir}/short.txt' holds 3 times for the 60 poses of other.txt; expected one "
     'per pose'),
    (['--est-times', '{dir}/times.txt', '--est-start', 'soon'],
     "--est-start: expected seconds, got 'soon'"),
    (['--est-times', '{dir}/missing.txt'],
     "--est-times: '{dir}/missing.txt' does not exist or is not a file"),
    (['--est-times', '{dir}/times.txt', '--est-start', '1e10'],
     '--est-start: 10000000000 s plus --est-times gives 10000000000.123456789 to '
     '10000000006.023456789 s, outside the range of a ROS time stamp (1970 to 2038)'),
])
def test_cli_eval_kitti_pose_file_errors_are_one_line(tmp_path, rng, capsys, extra, message):
    _camera_drive(rng, tmp_path)
    (tmp_path / 'short.txt').write_text('0\n0.1\n0.2\n')
    est = str(tmp_path / 'other.txt')
    args = [a.format(dir=tmp_path) for a in extra]
    assert main(['eval', est, *args, '--gt', str(tmp_path / 'gt.tum')]) == 1
    assert capsys.readouterr().err == \
        f'planar_vo eval: error: {message.format(est=est, dir=tmp_path)}\n'
    # A KITTI pose file given as ground truth says what it is.
    assert main(['eval', str(tmp_path / 'cam.tum'), '--gt', est]) == 1
    assert capsys.readouterr().err.endswith(
        "expected 8 values 'timestamp tx ty tz qx qy qz qw', got 12; a KITTI pose file? As the "
        'estimate it takes --est-times; as ground truth, import its sequence with planar_vo '
        'import-kitti\n')
    # --camera-height belongs to camera poses only (a user test: ignored without a word).
    assert main(['eval', str(tmp_path / 'gt.tum'), '--gt', str(tmp_path / 'gt.tum'),
                 '--camera-height', '1.5']) == 1
    assert capsys.readouterr().err == ('planar_vo eval: error: --camera-height: only for camera '
                                       'poses (--est-frame camera, or a KITTI pose file EST)\n')
    # ... and a height that import-kitti would take (a user test: 0 and 1e9 were).
    for height in ('0', '1e9'):
        assert main(['eval', str(tmp_path / 'cam.tum'), '--est-frame', 'camera', '--gt',
                     str(tmp_path / 'gt.tum'), '--camera-height', height]) == 1
        assert capsys.readouterr().err == (
            f'planar_vo eval: error: --camera-height: expected a height above the ground of '
            f'0.01-100 m (the range of mount.height), got {float(height):g}\n')
    # --est-times belongs to a KITTI pose file only.
    assert main(['eval', str(tmp_path / 'cam.tum'), '--est-times', str(tmp_path / 'times.txt'),
                 '--gt', str(tmp_path / 'gt.tum')]) == 1
    assert capsys.readouterr().err == (
        f"planar_vo eval: error: --est-times: only for a KITTI pose file EST (12 numbers per "
        f"line); '{tmp_path / 'cam.tum'}' is not one\n")


def test_a_topic_on_two_time_bases_is_read_by_its_longest_part(tmp_path, rng, caplog, capsys):
    """A replay across a restarted clock (stamps 2.3 s back from the 21st frame on, every topic;
    the odometry restarted at its origin): sorted by stamp the two time bases interleaved and
    eval scored garbage without a word (a user test: ATE 48 m). The longest part is read,
    with a warning; small steps back (out of order) stay one part."""
    gt = _drive(rng, 30)
    est = gt.transformed(np.eye(3), np.array([0.5, 0.0, 0.0]))
    jump = 2_300_000_000
    stamps = gt.stamps_ns.copy()
    stamps[20:] -= jump
    path = tmp_path / 'restarted'
    with OdometryBagWriter(path, topic='/odom') as writer:
        writer.add_topic('/ground_truth/odom', 'nav_msgs/msg/Odometry')
        for k in range(30):
            origin = est.poses[20] if k >= 20 else np.eye(4)
            # (recorded in order: the log times increase, as replay writes them)
            log = int(gt.stamps_ns[k])
            writer.write(int(stamps[k]), np.linalg.inv(origin) @ est.poses[k], log_time_ns=log)
            writer.write_odometry('/ground_truth/odom', int(stamps[k]), gt.poses[k],
                                  log_time_ns=log)
    with caplog.at_level('WARNING'):
        got = read_bag_trajectory(path, '/odom')
    np.testing.assert_array_equal(got.stamps_ns, stamps[:20])
    np.testing.assert_allclose(got.poses, est.poses[:20], atol=1e-12)
    warned = [r.getMessage() for r in caplog.records if 'go back' in r.getMessage()]
    assert warned == ["topic '/odom': its stamps go back 1 time(s) (first at message 20, "
                      f'{stamps[20] // 10 ** 9}.{stamps[20] % 10 ** 9:09d} s after '
                      f'{stamps[19] // 10 ** 9}.{stamps[19] % 10 ** 9:09d} '
                      's: a restarted clock or recording, where an odometry restarts from its '
                      'origin); evaluating the longest part, messages 0-19 (20 of 30)'], warned
    # The reference: the part of the estimate's stamps, whichever is longer.
    got = read_bag_trajectory(path, '/ground_truth/odom', span=('stamp', int(stamps[20]),
                                                                int(stamps[29])))
    np.testing.assert_array_equal(got.stamps_ns, stamps[20:])
    caplog.clear()
    assert main(['eval', str(path)]) == 0
    table = capsys.readouterr().out
    assert re.search(r'\| matched poses +\| 20 \(unmatched: 0 estimated, 0 reference\) \|',
                     table), table
    ate = next(line for line in table.splitlines() if line.startswith('| ATE'))
    assert float(ate.split('|')[2].split('/')[0]) < 1e-9, ate        # (the first part, exact)
    # Messages a little out of order (0.3 s back) are one time base, sorted.
    shuffled = gt.stamps_ns.copy()
    shuffled[[10, 11]] = shuffled[[11, 10]]
    path2 = tmp_path / 'shuffled'
    with OdometryBagWriter(path2, topic='/odom') as writer:
        for k in range(30):
            writer.write(int(shuffled[k]), gt.poses[int(np.flatnonzero(gt.stamps_ns
                                                                       == shuffled[k])[0])],
                         log_time_ns=int(gt.stamps_ns[k]))
    caplog.clear()
    with caplog.at_level('WARNING'):
        got = read_bag_trajectory(path2, '/odom')
    np.testing.assert_array_equal(got.stamps_ns, gt.stamps_ns)
    assert not [r for r in caplog.records if 'go back' in r.getMessage()]


def test_cli_eval_warns_when_the_estimate_origin_has_no_reference_pose(tmp_path, rng, caplog):
    """Ground truth stamped 5 s late (50 frames at 10 Hz): the later poses still match, to the
    wrong frames (a user test: 252 of 300 matched, ATE 17 m, no word). The origin's missing
    partner is said."""
    gt = _drive(rng, 120)
    late = Trajectory(gt.stamps_ns + 5_000_000_000, gt.poses)
    write_tum(tmp_path / 'est.tum', gt)
    write_tum(tmp_path / 'late.tum', late)
    with caplog.at_level('WARNING', logger='planar_vo.eval'):
        assert main(['eval', str(tmp_path / 'est.tum'), '--gt', str(tmp_path / 'late.tum')]) == 0
    warned = [r.getMessage() for r in caplog.records if 'first pose' in r.getMessage()]
    assert len(warned) == 1 and 'the nearest is 5.000 s away' in warned[0], warned
    caplog.clear()
    with caplog.at_level('WARNING', logger='planar_vo.eval'):
        assert main(['eval', str(tmp_path / 'est.tum'), '--gt', str(tmp_path / 'est.tum')]) == 0
    assert not [r for r in caplog.records if 'first pose' in r.getMessage()]


def test_cli_eval_a_mistyped_gt_topic_lists_the_topics_only(tmp_path, rng, capsys):
    path, _, _ = _bag_with(tmp_path, rng)
    assert main(['eval', str(path), '--gt-topic', '/nope']) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("planar_vo eval: error: --gt-topic: '/nope' is not a topic of") and \
        '/ground_truth/odom' in err and 'EST has no ground truth' not in err, err


def test_cli_eval_a_drive_too_short_for_any_segment_says_so(tmp_path, capsys):
    ref = _straight(8, step=1.0)                            # 7 m: not even a 10 m segment
    write_tum(tmp_path / 'ref.tum', ref)
    assert main(['eval', str(tmp_path / 'ref.tum'), '--gt', str(tmp_path / 'ref.tum')]) == 0
    rows = [line for line in capsys.readouterr().out.splitlines() if 'KITTI protocol' in line]
    assert rows and all('none: no segment of 10 m or more fits the 7.0 m path' in row
                        for row in rows), rows


def test_one_clock_with_frames_stamped_ahead_or_a_stale_message_is_one_part(tmp_path, caplog):
    """The odometry publishes frames stamped ahead after a gap, then rewinds (one clock, its
    stamps going back by the mis-stamp); another tool may write one stale message. Neither is
    a restarted clock (a review: either cut the topic in two, half of it left out)."""
    ref = _straight(100)
    stamps = ref.stamps_ns.copy()
    stamps[40:42] += 3_050_000_000                  # two frames stamped 3 s ahead
    stamps[70] -= 2_050_000_000                     # one stale message
    stamps[99] -= 2_050_000_000                     # ... and the last one
    path = tmp_path / 'one_clock'
    with OdometryBagWriter(path, topic='/odom') as writer:
        for k in range(100):
            writer.write(int(stamps[k]), ref.poses[k], log_time_ns=int(ref.stamps_ns[k]))
    with caplog.at_level('WARNING'):
        got = read_bag_trajectory(path, '/odom')
    assert len(got) == 100 and not [r for r in caplog.records if 'go back' in r.getMessage()]


def test_the_ground_truth_part_is_the_one_recorded_with_the_estimates(tmp_path, capsys):
    """A simulator's clock restarting at the same time each run: both runs' stamps cover the
    estimate's span alike, and the ground truth's longer run was taken (a review: another
    drive's, ATE 39.7 m). The part recorded with the estimate's (log times) is."""
    first, second = _straight(60), _straight(100, step=0.5, yaw_rate=0.01)
    path = tmp_path / 'two_runs'
    log = T0
    with OdometryBagWriter(path, topic='/odom') as writer:
        writer.add_topic('/ground_truth/odom', 'nav_msgs/msg/Odometry')
        for run, n_est in ((first, 60), (second, 40)):
            for k in range(len(run)):
                log += 100_000_000
                stamp = int(run.stamps_ns[k])         # both runs from the same start time
                if k < n_est:
                    writer.write(stamp, run.poses[k], log_time_ns=log)
                writer.write_odometry('/ground_truth/odom', stamp, run.poses[k],
                                      log_time_ns=log)
    assert main(['eval', str(path), '--align', 'origin']) == 0
    table = capsys.readouterr().out
    assert re.search(r'\| matched poses +\| 60 \(unmatched: 0 estimated, 0 reference\) \|',
                     table), table
    ate = next(line for line in table.splitlines() if line.startswith('| ATE'))
    assert float(ate.split('|')[2].split('/')[0]) < 1e-9, ate
