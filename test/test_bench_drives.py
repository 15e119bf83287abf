"""``planar_vo bench drives`` on a tiny rendered drive in the KITTI layout (never real data): the
benchmark runs, its report has every row, and the peers' trajectories on rendered frames with
exact poses are near the truth; the trajectory helpers are exact on exact motions."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest

from planar_vo.bench.drives import (
    STRESS,
    camera_pose,
    causal_bound,
    find_drives,
    first_frames,
    level_world,
    paired_yaw,
    stress_folder,
)
from planar_vo.bench.odometry import FIVE_POINT, SOURCES, OdometryRun, chain_camera_motions
from planar_vo.cli import main
from planar_vo.core.camera import CameraModel
from planar_vo.core.conventions import invert, mount_transform, rotation_rpy, se3
from planar_vo.errors import InputError
from planar_vo.io.kitti import read_kitti_sequence
from planar_vo.pipeline import FrameResult
from planar_vo.sim import StreetWorld, straight, turn
from planar_vo.sim.drive import render_drive

CAMERA = CameraModel.pinhole(640, 480, 500.0)
HEIGHT = 1.65
DRIVE = 'straight_turn'
PIPELINE_RUNS = ('planar_vo', 'planar_vo_focal', 'planar_vo_focal_pp', 'planar_vo_focal_fov',
                 'planar_vo_focal_2pass')
FOV = 2.0 * math.atan(320.0 / 500.0)        # CAMERA's horizontal field of view (rad)
PEER_RUNS = tuple(f'{e}_{s}' for s in SOURCES for e in FIVE_POINT)


def _write_kitti_folder(folder, trajectory, world) -> None:
    """A KITTI odometry folder: image_l/ PNGs, calib.txt (P0), poses.txt (T_w_cam in the frame
    of camera 0: x right, y down, z forward) and times.txt, rendered along ``trajectory``."""
    mount = mount_transform(height=HEIGHT)
    (folder / 'image_l').mkdir(parents=True)
    for i, frame in enumerate(render_drive(trajectory, world, CAMERA, mount)):
        assert cv2.imwrite(str(folder / 'image_l' / f'{i:06d}.png'), frame.image)
    cameras = trajectory.camera_poses(mount)                      # T_odom_camera
    poses = invert(cameras[0]) @ cameras                          # T_cam0_cam
    P0 = np.hstack([CAMERA.K, np.zeros((3, 1))])
    (folder / 'calib.txt').write_text('P0: ' + ' '.join(f'{v:.12e}' for v in P0.ravel()) + '\n')
    (folder / 'poses.txt').write_text(''.join(
        ' '.join(f'{v:.12e}' for v in T[:3].ravel()) + '\n' for T in poses))
    (folder / 'times.txt').write_text(''.join(f'{t:.6f}\n' for t in trajectory.stamps))


@pytest.fixture(scope='module')
def data(tmp_path_factory):
    """A data folder holding one rendered drive: 4 m straight, then a 30-degree left turn."""
    root = tmp_path_factory.mktemp('drives_data')
    trajectory = straight(4.0, speed=10.0).then(turn(np.deg2rad(30.0), radius=15.0, speed=8.0))
    _write_kitti_folder(root / DRIVE, trajectory, StreetWorld.along(trajectory, seed=3))
    (root / 'notes').mkdir()                                      # not a drive: ignored
    return root


@pytest.fixture(scope='module')
def report(data, tmp_path_factory):
    """The benchmark's outputs on the rendered drive (run once for the module)."""
    pytest.importorskip('poselib')
    out = tmp_path_factory.mktemp('drives_out')
    assert main(['bench', 'drives', '--data', str(data), '--out', str(out),
                 '--nominal-fov', repr(FOV)]) == 0
    return (out / 'drives.md').read_text(), json.loads((out / 'drives.json').read_text())


def test_report_has_every_row_and_the_command(report, data):
    text, results = report
    assert 'planar_vo bench drives --out ' in text and f'--data {data}' in text
    assert '--camera-height 1.65' in text and '## Summary across drives' in text
    assert f'## {DRIVE}: 15 frames' in text and '### Focal length (true 500.0 px)' in text
    drive = results['drives'][DRIVE]
    assert set(drive['runs']) == set(PIPELINE_RUNS + PEER_RUNS)
    for run in drive['runs'].values():
        assert run['label'] in text                       # a row per run in the tables
        assert text.count(f"| {run['label']} |") >= 2     # drive table and summary
    assert 'PoseLib shared-focal six-point' in text and 'median of 14 of 14 pairs' in text
    assert "  - the least a causal self-calibration could reach here (the self-calibrated run's " \
           'per-frame errors until its first turning pair, at frame ' in text
    # The drive is 12 m long: no 100 m segment, so the 10-50 m protocol, labelled.
    assert drive['path_length_m'] == pytest.approx(11.85, abs=0.05)
    assert '10-50 m segments (drive < 100 m)' in text
    assert drive['settings'] == {'mount.height': HEIGHT}
    assert results['command'][:3] == ['planar_vo', 'bench', 'drives']


def test_peers_on_rendered_frames_are_near_the_truth(report):
    _, results = report
    runs = results['drives'][DRIVE]['runs']
    for key in PEER_RUNS:
        run = runs[key]
        assert run['scale'] == 'TRUE step length' and run['failed_pairs'] == 0, key
        assert run['odometry_pct'] == 100.0, key
        assert run['yaw_change_error_deg']['mean'] < 0.05, key
        assert run['ate_m']['rmse'] < 0.05, key
        assert run['sim3_scale'] == pytest.approx(1.0, abs=0.01), key
        assert run['kitti_short']['segments'] == 1 and run['kitti_short']['t_rel_pct'] < 1.0, key
        assert run['estimator_ms_per_frame']['median'] > 0.0, key


def test_every_peer_is_compared_with_planar_vo_frame_by_frame(report):
    """The paired yaw comparison: over frames both runs have, the mean of the per-frame
    differences is the difference of the means; 14 frame pairs are too few for the
    batch-means standard error; the yaw target's line quotes the best PoseLib row's."""
    text, results = report
    runs = results['drives'][DRIVE]['runs']
    ours = runs['planar_vo']
    assert '_yaw_abs_deg' not in ours
    for key in PEER_RUNS:
        paired = runs[key]['yaw_paired_vs_planar_vo']
        assert '_yaw_abs_deg' not in runs[key]
        if ours['odometry_pct'] == 100.0 and runs[key]['odometry_pct'] == 100.0:
            assert paired['frames'] == 14
            assert paired['mean_diff_deg'] == pytest.approx(
                ours['yaw_change_error_deg']['mean'] - runs[key]['yaw_change_error_deg']['mean'],
                abs=1e-12)
        assert paired['se_deg'] is None                    # NaN is null in the JSON
    assert 'frame by frame, planar_vo minus that row' in text
    assert 'too few for a standard error from 10 batches' in text and '+- nan' not in text
    assert '_yaw_abs_deg' not in json.dumps(results)           # nor in the stress runs


def test_paired_yaw_mean_and_batch_means_standard_error():
    """Frame pairs by their two stamps: a run that lost frame 20 has the pair (19, 21), which
    the other run does not; the mean difference and its batch-means standard error."""
    ours = {(s, s + 1): 1.0 + 0.01 * s for s in range(40)}
    theirs = {(s, s + 1): 0.5 + 0.01 * s for s in range(5, 45) if s not in (19, 20)}
    theirs[(19, 21)] = 9.0                                        # lost frame 20: not paired
    theirs[(10, 11)] = float('nan')                               # dropped
    p = paired_yaw(ours, theirs)
    assert p['frames'] == 32 and p['mean_diff_deg'] == pytest.approx(0.5)
    assert p['se_deg'] == pytest.approx(0.0, abs=1e-15)           # every difference is 0.5
    d = np.random.default_rng(0).normal(size=100)
    p = paired_yaw({(s, s + 1): float(x) for s, x in enumerate(d)},
                   {(s, s + 1): 0.0 for s in range(100)})
    means = [b.mean() for b in np.array_split(d, 10)]
    assert p['mean_diff_deg'] == pytest.approx(d.mean())
    assert p['se_deg'] == pytest.approx(np.std(means, ddof=1) / np.sqrt(10))
    p = paired_yaw({(1, 2): 1.0}, {(2, 3): 1.0})
    assert p['frames'] == 0 and np.isnan(p['mean_diff_deg']) and np.isnan(p['se_deg'])


def test_the_causal_bound_takes_the_self_calibrated_errors_until_the_first_turning_pair():
    calibrated = {(0, 1): 0.1, (1, 2): 0.1, (2, 3): 0.1, (3, 4): 0.1}
    self_cal = {(0, 1): 0.5, (1, 2): 0.5, (2, 3): 0.9, (3, 4): 0.9}
    assert causal_bound(calibrated, self_cal, 2)['mean_deg'] == pytest.approx(0.3)
    assert causal_bound(calibrated, self_cal, None)['mean_deg'] == pytest.approx(0.7)
    # A frame the self-calibrated run lost counts as nothing, not as the calibrated error.
    del self_cal[(0, 1)]
    assert causal_bound(calibrated, self_cal, 2)['mean_deg'] == pytest.approx(0.7 / 3)


def test_planar_vo_runs_are_reported_with_their_focal_length(report):
    _, results = report
    drive = results['drives'][DRIVE]
    ours = drive['runs']['planar_vo']
    assert ours['scale'] == 'own: ground, height 1.65 m'
    assert ours['odometry_pct'] > 90.0 and ours['yaw_change_error_deg']['mean'] < 0.1
    assert ours['dropped'].get('first_frame') == 1
    focal = drive['focal']['self_calibrated']
    assert focal['settings'] == {'mount.height': HEIGHT, 'camera.estimate_focal': True}
    assert isinstance(focal['adopted'], bool) and focal['status'].startswith('focal length ')
    assert focal['in_use_px'] > 0 and focal['pairs'] >= 0
    given = drive['focal']['principal_point_given']
    assert given['settings'] == {'mount.height': HEIGHT, 'camera.estimate_focal': True,
                                 'camera.cx': CAMERA.cx, 'camera.cy': CAMERA.cy}
    assert given['in_use_px'] > 0 and given['status'].startswith('focal length ')
    assert drive['runs']['planar_vo_focal_pp']['odometry_pct'] > 90.0
    # The field of view of the camera's specification: the calibration starts at the truth
    # (500 px), so the odometry runs within the calibration's reach of it.
    stated = drive['focal']['field_of_view_given']
    assert stated['settings'] == {'mount.height': HEIGHT, 'camera.estimate_focal': True,
                                  'camera.nominal_fov': FOV}
    assert abs(math.log(stated['in_use_px'] / 500.0)) < abs(math.log(focal['in_use_px'] / 500.0))
    assert results['nominal_fov_rad'] == FOV
    assert drive['runs']['planar_vo_focal_fov']['odometry_pct'] > 90.0
    bound = focal['causal_bound']
    # The drive turns from its 4th metre: the first turning pair comes after a few frames.
    assert 3 <= bound['first_pair_frame'] < 15, bound
    assert 0 < bound['mean_deg'] < drive['runs']['planar_vo_focal']['yaw_change_error_deg']['mean']
    # Two passes (replay --two-pass): the first pass's focal length from the first frame on,
    # said in the report's table and beside the targets.
    two = drive['runs']['planar_vo_focal_2pass']
    assert two['focal_status'].endswith('; from a first pass over the whole recording)')
    assert two['first_pass'].startswith(f"{drive['frames']} frames in ")
    assert two['focal_in_use_px'] > 0 and two['odometry_pct'] > 90.0
    text, _ = report
    assert "| the first pass's, used from the first frame |" in text
    assert '  - offline, two passes (replay --two-pass: the focal length of a first pass' in text
    six = drive['focal']['six_point']
    assert six['pairs'] == 14 and six['vote'] == 'median of the per-pair focal lengths'
    assert len(six['per_pair_px']) == 14


def test_harder_conditions_are_run_and_reported(report):
    text, results = report
    stress = results['drives'][DRIVE]['stress']
    assert list(stress) == [key for key, *_ in STRESS]
    assert '### Harder conditions (planar_vo, calibrated; no peers)' in text
    assert [stress[k]['frames'] for k in ('x2', 'x3', 'flicker', 'centre')] == [8, 5, 15, 15]
    for run in stress.values():
        assert f"| {run['label']} |" in text
        # Rendered frames: harder, but still tracked (the true principal point is the centre).
        assert run['odometry_pct'] > 70.0 and run['yaw_change_error_deg']['mean'] < 0.2, run


# ---------------------------------------------------------------------------------------------
# Helpers, on exact data
# ---------------------------------------------------------------------------------------------

def _random_poses(rng, n: int) -> np.ndarray:
    steps = se3(rotation_rpy(*rng.normal(0.0, 0.05, (3, n))),
                rng.normal(0.0, 1.0, (n, 3)) + [0.0, 0.0, 1.0])
    poses = [np.eye(4)]
    for T in steps:
        poses.append(poses[-1] @ T)
    return np.array(poses)


def test_chained_camera_motions_reproduce_the_trajectory_exactly(rng):
    poses = _random_poses(rng, 20)                            # T_world_camera, poses[0] = I
    rel = invert(poses[1:]) @ poses[:-1]                      # X2 = R X1 + t
    R, t = rel[:, :3, :3], rel[:, :3, 3]
    steps = np.linalg.norm(t, axis=1)
    chained = chain_camera_motions(R, t / steps[:, None], steps, np.ones(20, bool))
    np.testing.assert_allclose(chained, poses, atol=1e-12)
    # A missing motion holds the camera where it was; the later motions still chain.
    ok = np.ones(20, bool)
    ok[5] = False
    held = chain_camera_motions(R, t / steps[:, None], steps, ok)
    np.testing.assert_allclose(held[:6], poses[:6], atol=1e-12)
    np.testing.assert_allclose(held[6], held[5])
    np.testing.assert_allclose(held[7], held[6] @ invert(rel[6]), atol=1e-12)


def test_pipeline_pose_maps_back_to_the_vehicle_pose_in_the_z_up_frame(rng):
    # A level mount at the camera height: the pipeline's camera pose (T_bc^-1 T_odom_base T_bc,
    # world = the first camera frame) in the z-up frame is T_odom_base.
    pose = se3(rotation_rpy(0.0, 0.0, 0.3), [4.0, -1.0, 0.0])
    T_bc = mount_transform(height=HEIGHT)
    result = FrameResult(stamp=1.0, ok=True, pose=pose, pose_covariance=np.eye(6),
                         camera_pose=invert(T_bc) @ pose @ T_bc)
    T_wc = camera_pose(result)
    np.testing.assert_allclose(level_world(T_wc[None], HEIGHT)[0], pose, atol=1e-12)
    # Driving forward (+x in odom) moves the camera along its optical axis (+z).
    np.testing.assert_allclose(T_wc[:3, 3], [1.0, 0.0, 4.0], atol=1e-12)


def test_runs_are_aligned_to_the_frames_by_nearest_stamp():
    stamps = np.array([0, 100_000_000, 200_000_000, 300_000_000])
    poses = np.tile(np.eye(4), (3, 1, 1))
    poses[:, 0, 3] = [0.0, 1.0, 3.0]
    # The run saw frames 0, 1 and 3 (stamps off by rounding); frame 2 gave no result.
    run = OdometryRun('x', 'unit', np.array([0, 100_000_123, 299_999_900]), poses,
                      np.array([False, True, True]), np.zeros(2), np.zeros(2))
    on = run.aligned(stamps)
    np.testing.assert_array_equal(on.ok, [False, True, False, True])
    np.testing.assert_allclose(on.poses[:, 0, 3], [0.0, 1.0, 1.0, 3.0])
    nothing = OdometryRun('x', 'unit', np.zeros(0, np.int64), np.zeros((0, 4, 4)),
                          np.zeros(0, bool), np.zeros(0), np.zeros(0)).aligned(stamps)
    assert not nothing.ok.any()


def test_first_frames_is_the_same_drive_cut_short(data, tmp_path):
    full = read_kitti_sequence(data / DRIVE)
    view = first_frames(data / DRIVE, 5, tmp_path)
    cut = read_kitti_sequence(view)
    assert [p.name for p in cut.images] == [p.name for p in full.images[:5]]
    np.testing.assert_array_equal(cut.poses, full.poses[:5])
    np.testing.assert_array_equal(cut.P0, full.P0)
    assert cut.times == full.times[:5]
    assert first_frames(data / DRIVE, 100, tmp_path) == data / DRIVE


def test_stress_folders_hold_the_drive_in_harder_conditions(data, tmp_path):
    full = read_kitti_sequence(data / DRIVE)
    fast = read_kitti_sequence(stress_folder(data / DRIVE, 'stride', 3, tmp_path / 'x3'))
    assert len(fast.images) == 5
    np.testing.assert_array_equal(fast.poses, full.poses[::3])
    assert fast.times == full.times[::3]
    for k, path in enumerate(fast.images):
        assert path.resolve() == full.images[3 * k].resolve()
    flicker = read_kitti_sequence(stress_folder(data / DRIVE, 'flicker', 0.25, tmp_path / 'f'))
    for i in (0, 7):
        a = cv2.imread(str(full.images[i]), cv2.IMREAD_UNCHANGED).astype(np.float64)
        b = cv2.imread(str(flicker.images[i]), cv2.IMREAD_UNCHANGED).astype(np.float64)
        gain = np.random.default_rng(i).uniform(0.75, 1.25)
        unsaturated = a * gain < 254.5
        assert np.abs(b - a * gain)[unsaturated].max() <= 0.5 + 1e-9
    np.testing.assert_array_equal(flicker.poses, full.poses)
    centre = read_kitti_sequence(stress_folder(data / DRIVE, 'centre', 0, tmp_path / 'c'))
    expected = full.P0.copy()
    expected[0, 2], expected[1, 2] = (CAMERA.width - 1) / 2.0, (CAMERA.height - 1) / 2.0
    np.testing.assert_array_equal(centre.P0, expected)
    with pytest.raises(InputError, match="kind: expected 'stride', 'flicker' or 'centre'"):
        stress_folder(data / DRIVE, 'rain', 1, tmp_path / 'r')


# ---------------------------------------------------------------------------------------------
# Bad input
# ---------------------------------------------------------------------------------------------

def test_drive_folders_are_found_or_refused(data, tmp_path):
    assert find_drives(data) == [data / DRIVE]
    assert find_drives(data / DRIVE) == [data / DRIVE]          # one drive given directly
    assert find_drives(data, [DRIVE, DRIVE]) == [data / DRIVE]
    with pytest.raises(InputError, match="data: '.*nowhere' is not a directory"):
        find_drives(tmp_path / 'nowhere')
    with pytest.raises(InputError, match='holds no drive in the KITTI layout'):
        find_drives(tmp_path)
    with pytest.raises(InputError, match=f'drives: 05 not found .*drives there: {DRIVE}'):
        find_drives(data, ['05'])
    (tmp_path / 'no_truth').mkdir()
    (tmp_path / 'no_truth' / 'calib.txt').write_text('0 ' * 12)
    with pytest.raises(InputError, match="no_truth' has no poses.txt"):
        find_drives(tmp_path)
    (tmp_path / 'no_truth' / 'poses.txt').write_text('1 0 0 0 0 1 0 0 0 0 1 0\n')
    # (a user test: the importer's advice, a frame rate, is no option of the benchmark)
    with pytest.raises(InputError, match=r"no_truth' has no times.txt \(the frames' times, "
                                         r'which the evaluation needs\)'):
        find_drives(tmp_path)


@pytest.mark.parametrize('options, message', [
    (['--frames', '2'], '--frames: expected at least 3 frames, got 2'),
    (['--camera-height', '-1'], '--camera-height: expected a positive height in metres, got -1'),
    (['--nominal-fov', '90'], '--nominal-fov: expected 0 (none) or a horizontal field of view of '
                              '0.4-2.2 rad (the range the focal calibration searches through a '
                              'rectilinear lens; in degrees? 90 deg is 1.5708 rad), got 90.0'),
    (['--nominal-fov', '1.5', '--skip-focal'],
     '--nominal-fov: it adds a self-calibrated run, which --skip-focal leaves out; give one of '
     'them'),
    (['--drives', 'kitti99'], '--drives: kitti99 not found'),
])
def test_bad_options_are_one_line_and_exit_1(data, tmp_path, capsys, options, message):
    assert main(['bench', 'drives', '--data', str(data), '--out', str(tmp_path), *options]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f'planar_vo bench drives: error: {message}') and err.count('\n') == 1
    assert not (tmp_path / 'drives.md').exists()


def test_planar_vo_alone_on_the_first_frames(data, tmp_path, capfd):
    out = tmp_path / 'out'
    assert main(['bench', 'drives', '--data', str(data), '--out', str(out), '--frames', '4',
                 '--skip-peers', '--skip-focal', '--skip-stress']) == 0
    text = (out / 'drives.md').read_text()
    results = json.loads((out / 'drives.json').read_text())
    assert '--frames 4 --skip-peers --skip-focal --skip-stress' in text
    assert 'Focal length' not in text and '### Harder conditions' not in text
    drive = results['drives'][DRIVE]
    assert drive['frames'] == 4 and set(drive['runs']) == {'planar_vo'} and 'stress' not in drive
    assert drive['runs']['planar_vo']['frames_with_odometry'] == 3
    assert f'## {DRIVE}: 4 frames' in capfd.readouterr().out        # printed as it goes


def test_cli_defaults():
    from pathlib import Path

    from planar_vo.cli import build_parser

    args = build_parser().parse_args(['bench', 'drives'])
    assert (args.data, args.drives, args.camera_height, args.frames) == \
        (Path('../shared/data'), None, 1.65, None)
    assert not (args.skip_peers or args.skip_focal or args.skip_stress or args.quick)
    assert args.out == 'out/bench/drives'
