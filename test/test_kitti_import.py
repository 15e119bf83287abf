"""KITTI odometry folder -> bag: images, intrinsics, exact stamps and REP-103 ground truth
(forward driving is +x, a left turn is +yaw), on a tiny synthetic sequence folder."""

from __future__ import annotations

import math
import signal

import cv2
import numpy as np
import pytest
from disk_tools import partial_leftovers, run_planar_vo

from planar_vo.cli import main
from planar_vo.core.camera import CameraModel
from planar_vo.core.conventions import yaw_of
from planar_vo.errors import BagError, InputError
from planar_vo.io import import_kitti, iter_camera_frames, iter_messages, open_bag
from planar_vo.io.kitti import read_kitti_sequence
from planar_vo.io.outputs import stop_signals_interrupt
from planar_vo.ros.messages import pose_from_message

P0 = np.array([[50.0, 0.0, 19.5, 0.0], [0.0, 50.0, 14.5, 0.0], [0.0, 0.0, 1.0, 0.0]])
TURN = math.radians(10.0)
START_NS = 1_700_000_000 * 10**9


def _ry(a: float) -> np.ndarray:
    """The paper's Ry (camera frame, y down)."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _camera_poses() -> np.ndarray:
    """T_w_cam in KITTI's camera-0 frame: two metres straight ahead along z, then a left turn
    (the camera yaws towards -x, i.e. Ry(-TURN)) while moving 0.9 m forward and 0.1 m left."""
    poses = np.tile(np.eye(4), (4, 1, 1))
    poses[1, :3, 3] = [0.0, 0.0, 1.0]
    poses[2, :3, 3] = [0.0, 0.0, 2.0]
    poses[3, :3, :3] = _ry(-TURN)
    poses[3, :3, 3] = [-0.1, 0.0, 2.9]
    return poses


def _write_sequence(folder, rng, *, label=True, times=('0.0', '0.1', '0.2', '3.000000e-01'),
                    poses=True, image_dir='image_0', n=4):
    (folder / image_dir).mkdir(parents=True)
    images = []
    for i in range(n):
        img = rng.integers(0, 256, (30, 40), dtype=np.uint8)
        cv2.imwrite(str(folder / image_dir / f'{i:06d}.png'), img)
        images.append(img)
    p0 = ' '.join(f'{v:e}' for v in P0.ravel())
    (folder / 'calib.txt').write_text(f"{'P0: ' if label else ''}{p0}\n"
                                      f"{'P1: ' if label else ''}{p0}\n")
    if times is not None:
        (folder / 'times.txt').write_text('\n'.join(times) + '\n')
    if poses:
        rows = [' '.join(f'{v:.9e}' for v in T[:3].ravel()) for T in _camera_poses()[:n]]
        (folder / 'poses.txt').write_text('\n'.join(rows) + '\n')
    return images


@pytest.mark.parametrize('storage, label, image_dir', [
    ('mcap', True, 'image_0'), ('sqlite3', False, 'image_l')])
def test_import_writes_images_intrinsics_stamps_and_rep103_ground_truth(
        tmp_path, rng, storage, label, image_dir):
    images = _write_sequence(tmp_path / 'seq', rng, label=label, image_dir=image_dir)
    summary = import_kitti(tmp_path / 'seq', tmp_path / 'bag', storage=storage,
                           camera_height=1.65)
    assert summary.frames == 4 and summary.ground_truth
    stamps = [START_NS + k * 100_000_000 for k in range(4)]
    with open_bag(tmp_path / 'bag') as bag:
        assert bag.topics == {'/camera/camera_info': 'sensor_msgs/msg/CameraInfo',
                              '/camera/image_raw': 'sensor_msgs/msg/Image',
                              '/ground_truth/odom': 'nav_msgs/msg/Odometry'}
        frames = list(iter_camera_frames(bag))
        infos = list(iter_messages(bag, '/camera/camera_info'))
        gt = list(iter_messages(bag, '/ground_truth/odom'))
    assert [f.stamp_ns for f in frames] == stamps == [g.stamp_ns for g in gt]
    for frame, img in zip(frames, images):
        np.testing.assert_array_equal(frame.image, img)
        assert frame.camera == CameraModel(40, 30, P0[:, :3])
    info = infos[0].msg
    np.testing.assert_array_equal(info.p, P0.ravel())
    assert (info.width, info.height) == (40, 30) and not np.any(info.d)

    poses = np.array([pose_from_message(g.msg) for g in gt])
    np.testing.assert_allclose(poses[0], np.eye(4), atol=1e-12)
    # forward driving is +x in odom, height stays 0
    np.testing.assert_allclose(poses[1][:3, 3], [1.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(poses[2][:3, 3], [2.0, 0.0, 0.0], atol=1e-12)
    # the left turn is positive yaw, the leftward step positive y
    np.testing.assert_allclose(poses[3][:3, 3], [2.9, 0.1, 0.0], atol=1e-9)
    np.testing.assert_allclose(yaw_of(poses[:, :3, :3]), [0, 0, 0, TURN], atol=1e-9)
    assert gt[3].msg.header.frame_id == 'odom' and gt[3].msg.child_frame_id == 'base_link'
    # twist: finite differences over 0.1 s in base_link
    assert math.isclose(gt[1].msg.twist.twist.linear.x, 10.0, rel_tol=1e-9)
    assert math.isclose(gt[0].msg.twist.twist.linear.x, 10.0, rel_tol=1e-9)
    assert math.isclose(gt[3].msg.twist.twist.angular.z, TURN / 0.1, rel_tol=1e-9)
    v3 = gt[3].msg.twist.twist.linear
    assert math.isclose(math.hypot(v3.x, v3.y), math.hypot(0.9, 0.1) / 0.1, rel_tol=1e-9)


def test_the_download_layout_keeps_the_poses_apart_and_a_missing_ground_truth_is_said(
        tmp_path, rng):
    """The KITTI odometry download has dataset/sequences/06/ and dataset/poses/06.txt (a user
    test: README's own example imported without ground truth, without a word)."""
    seq = tmp_path / 'dataset' / 'sequences' / '06'
    _write_sequence(seq, rng)
    (tmp_path / 'dataset' / 'poses').mkdir()
    (seq / 'poses.txt').rename(tmp_path / 'dataset' / 'poses' / '06.txt')
    summary = import_kitti(seq, tmp_path / 'bag', camera_height=1.65)
    assert summary.ground_truth
    assert summary.format().endswith(
        f"/ground_truth/odom (from {tmp_path / 'dataset' / 'poses' / '06.txt'})")
    with open_bag(tmp_path / 'bag') as bag:
        gt = list(iter_messages(bag, '/ground_truth/odom'))
    poses = np.array([pose_from_message(g.msg) for g in gt])
    np.testing.assert_allclose(poses[3][:3, 3], [2.9, 0.1, 0.0], atol=1e-9)
    # Another sequence of the tree has no poses file: the summary says which were looked for.
    other = tmp_path / 'dataset' / 'sequences' / '11'
    _write_sequence(other, rng, poses=False)
    summary = import_kitti(other, tmp_path / 'bag11')
    assert not summary.ground_truth
    assert summary.format().endswith(
        f"; no ground truth (no {other / 'poses.txt'} nor "
        f"{tmp_path / 'dataset' / 'poses' / '11.txt'})")
    # A sequence folder linked into the tree from elsewhere is in the tree (a review).
    _write_sequence(tmp_path / 'elsewhere' / '07', rng)
    (tmp_path / 'elsewhere' / '07' / 'poses.txt').rename(tmp_path / 'dataset' / 'poses' / '07.txt')
    (tmp_path / 'dataset' / 'sequences' / '07').symlink_to(tmp_path / 'elsewhere' / '07')
    assert import_kitti(tmp_path / 'dataset' / 'sequences' / '07', tmp_path / 'bag07').ground_truth
    # A folder outside such a tree only has its own poses.txt to look for.
    _write_sequence(tmp_path / 'loose', rng, poses=False)
    summary = import_kitti(tmp_path / 'loose', tmp_path / 'bag_loose')
    assert summary.format().endswith(f"; no ground truth (no {tmp_path / 'loose' / 'poses.txt'})")


def test_stamps_are_exact_decimal_times_and_rate_option(tmp_path, rng):
    _write_sequence(tmp_path / 'seq', rng, times=('0', '1.036624e-01', '0.207793512', '0.31'),
                    poses=False)
    summary = import_kitti(tmp_path / 'seq', tmp_path / 'bag', start='12.000000001')
    assert not summary.ground_truth
    with open_bag(tmp_path / 'bag') as bag:
        assert '/ground_truth/odom' not in bag.topics
        stamps = [f.stamp_ns for f in iter_camera_frames(bag)]
    assert stamps == [12_000_000_001, 12_103_662_401, 12_207_793_513, 12_310_000_001]
    _write_sequence(tmp_path / 'seq2', rng, times=None, poses=False)
    import_kitti(tmp_path / 'seq2', tmp_path / 'bag2', rate_hz=4.0, start=0)
    with open_bag(tmp_path / 'bag2') as bag:
        assert [f.stamp_ns for f in iter_camera_frames(bag)] == [0, 250_000_000, 500_000_000,
                                                                 750_000_000]


@pytest.mark.parametrize('damage, match', [
    (lambda d: (d / 'calib.txt').unlink(), r"sequence: '.*seq' has no calib\.txt"),
    (lambda d: (d / 'calib.txt').write_text('P0: 1 2 3\n'),
     r"calib\.txt line 1: expected P0 as 12 numbers, got '1 2 3'"),
    (lambda d: (d / 'calib.txt').write_text('P1: ' + ' 1' * 12 + '\n'),
     r"calib\.txt line 1: expected P0 first, got 'P1:'"),
    (lambda d: (d / 'calib.txt').write_text(' 0' * 12 + '\n'),
     r'calib\.txt: P0 does not hold valid intrinsics'),
    # (a user test: fx 1 px was imported, and the node then refused every frame's CameraInfo)
    (lambda d: (d / 'calib.txt').write_text('P0: 1 0 19.5 0 0 1 14.5 0 0 0 1 0\n'),
     r'calib\.txt: P0 does not hold valid intrinsics \(horizontal field of view 174 deg \(fx 1, '
     r'fy 1 px on 40x30\) is outside the 3-160 deg of real rectilinear lenses'),
    (lambda d: (d / 'times.txt').write_text('0\n0.1\nabc\n0.3\n'),
     r"times\.txt line 3: expected seconds, got 'abc'"),
    (lambda d: (d / 'times.txt').write_text('0\n0.1\n0.1\n0.3\n'),
     r'times\.txt line 3: expected increasing times, got 0\.1 after 0\.1'),
    (lambda d: (d / 'times.txt').write_text('0\n0.1\n'),
     r'times\.txt: expected one time per image \(4\), got 2'),
    (lambda d: (d / 'times.txt').unlink(),
     r"has no times\.txt; give the frame rate instead \(import-kitti --rate-hz; "
     r"import_kitti\(rate_hz=\.\.\.\) in Python\)"),
    # (a user test: a missing image was blamed on times.txt's count)
    (lambda d: (d / 'image_0' / '000002.png').unlink(),
     r"images: '000002\.png' is missing from '.*image_0' \(frames are numbered without gaps; "
     r"the next there is '000003\.png'\)"),
    (lambda d: (d / 'poses.txt').write_text('1 0 0 0 0 1 0 0 0 0 1 0\n1 2 3\n'),
     r"poses\.txt line 2: expected a 3x4 pose as 12 numbers, got '1 2 3'"),
    (lambda d: (d / 'poses.txt').write_text('1 0 0 0 0 1 0 0 0 0 1 0\n' + 'nan ' * 12 + '\n'),
     r"poses\.txt line 2: expected a 3x4 pose as 12 finite numbers, got 'nan'"),
    (lambda d: (d / 'poses.txt').write_text('1 0 0 0 0 1 0 0 0 0 1 0\n'),
     r'poses\.txt: expected one pose per image \(4\), got 1'),
    # a scaled, a zero and a mirrored rotation block
    (lambda d: (d / 'poses.txt').write_text('1 0 0 0 0 1 0 0 0 0 1 0\n' * 3
                                            + '2 0 0 0 0 2 0 0 0 0 2 0\n'),
     r'poses\.txt line 4: expected a rotation matrix in the first 3x3 block \(orthonormal, '
     r'determinant \+1\), got R\^T R off the identity by 3 and determinant 8'),
    (lambda d: (d / 'poses.txt').write_text('0 0 0 0 0 0 0 0 0 0 0 0\n'
                                            + '1 0 0 0 0 1 0 0 0 0 1 0\n' * 3),
     r'poses\.txt line 1: expected a rotation matrix'),
    (lambda d: (d / 'poses.txt').write_text('1 0 0 0 0 1 0 0 0 0 -1 0\n' * 4),
     r'poses\.txt line 1: expected a rotation matrix .* determinant -1'),
    (lambda d: cv2.imwrite(str(d / 'image_0' / '000002.png'), np.zeros((31, 40), np.uint8)),
     r"images: expected every image 40x30, got 40x31 for '000002\.png'"),
    (lambda d: (d / 'image_0' / '000001.png').write_bytes(b'not a png'),
     r"images: cannot read '.*000001\.png' as an image \(expected PNG or JPEG"),
    # (a user test: the message of a cut-short PNG named a CompressedImage's field)
    (lambda d: (d / 'image_0' / '000001.png').write_bytes(
        (d / 'image_0' / '000001.png').read_bytes()[:60]),
     r"images: cannot read '.*000001\.png' as an image \(\d+ bytes of png data"),
    (lambda d: [p.unlink() for p in (d / 'image_0').iterdir()],
     r"sequence: '.*image_0' contains no \.png images"),
    (lambda d: (d / 'image_0').rename(d / 'pictures'),
     r"sequence: '.*seq' has no image_0/ or image_l/ folder"),
])
def test_malformed_sequence_errors(tmp_path, rng, damage, match):
    """Each leaves no bag, not even when the bad image comes after frames were written."""
    _write_sequence(tmp_path / 'seq', rng)
    damage(tmp_path / 'seq')
    with pytest.raises(InputError, match=match):
        import_kitti(tmp_path / 'seq', tmp_path / 'bag')
    assert not (tmp_path / 'bag').exists() and partial_leftovers(tmp_path) == []


def test_cli_a_corrupt_image_mid_way_is_one_line_and_leaves_no_bag(tmp_path, rng, capsys):
    _write_sequence(tmp_path / 'seq', rng)
    png = tmp_path / 'seq' / 'image_0' / '000002.png'
    png.write_bytes(png.read_bytes()[:60])                  # truncated
    assert main(['import-kitti', str(tmp_path / 'seq'), '--out', str(tmp_path / 'bag')]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"planar_vo import-kitti: error: images: cannot read '{png}' as an "
                          f'image (') and err.count('\n') == 1
    assert err.endswith(f"; nothing was kept at '{tmp_path / 'bag'}' (removed: 2 of 4 frames "
                        f'were written before the bad image)\n')
    assert not (tmp_path / 'bag').exists() and partial_leftovers(tmp_path) == []


def test_argument_errors_and_existing_output(tmp_path, rng):
    _write_sequence(tmp_path / 'seq', rng)
    with pytest.raises(InputError, match=r'camera_height: expected a positive height in metres, '
                                         r'got -1'):
        import_kitti(tmp_path / 'seq', tmp_path / 'bag', camera_height=-1.0)
    # (a user test: 1e9 m was imported, and the replay command it suggests refused it)
    with pytest.raises(InputError, match=r'camera_height: expected a height above the ground of '
                                         r'0.01-100 m \(the range of mount.height\), got 1e\+09'):
        import_kitti(tmp_path / 'seq', tmp_path / 'bag', camera_height=1e9)
    with pytest.raises(InputError, match=r'rate_hz: expected a camera frame rate of '
                                         r'0.01-1000 Hz, got 0'):
        import_kitti(tmp_path / 'seq', tmp_path / 'bag', rate_hz=0.0)
    with pytest.raises(InputError, match=r"start: expected a number of seconds, got 'soon'"):
        import_kitti(tmp_path / 'seq', tmp_path / 'bag', start='soon')
    with pytest.raises(InputError, match=r"sequence: '.*nowhere' is not a directory"):
        import_kitti(tmp_path / 'nowhere', tmp_path / 'bag')
    (tmp_path / 'bag').mkdir()
    with pytest.raises(BagError, match=r'already exists; refusing to overwrite'):
        import_kitti(tmp_path / 'seq', tmp_path / 'bag')
    assert list((tmp_path / 'bag').iterdir()) == []


@pytest.mark.parametrize(('options', 'message'), [
    (['--camera-height', '-1'], '--camera-height: expected a positive height in metres, got -1.0'),
    (['--rate-hz', '0'], '--rate-hz: expected a camera frame rate of 0.01-1000 Hz, got 0.0'),
    (['--start', 'soon'], "--start: expected a number of seconds, got 'soon'"),
    (['--storage', 'mcap'], "DIR: '{seq}' is not a directory"),
])
def test_cli_errors_name_the_arguments_as_typed(tmp_path, capsys, options, message):
    """--camera-height, not the library's camera_height (and so on); the folder is DIR, as in
    the usage line: one line, exit code 1."""
    seq = tmp_path / 'nowhere'
    assert main(['import-kitti', str(seq), '--out', str(tmp_path / 'bag'), *options]) == 1
    assert capsys.readouterr().err == (f'planar_vo import-kitti: error: '
                                       f'{message.format(seq=seq)}\n')
    assert not (tmp_path / 'bag').exists()


def test_cli_import_kitti(tmp_path, rng, capsys):
    _write_sequence(tmp_path / 'seq', rng)
    out = tmp_path / 'out'
    assert main(['import-kitti', str(tmp_path / 'seq'), '--out', str(out), '--storage',
                 'sqlite3', '--no-progress']) == 0
    printed = capsys.readouterr().out
    assert 'wrote 4 frames (40x30, fx 50.00, 0.30 s)' in printed and '/ground_truth/odom' in printed
    assert main(['import-kitti', str(tmp_path / 'seq'), '--out', str(out)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith('planar_vo import-kitti: error: --out: ') and '\n' not in err
    assert err.endswith('already exists; refusing to overwrite it (remove it or choose another '
                        'path)')
    # A bag is a folder: 'x.mcap' would have become the folder x.mcap holding x.mcap.mcap.
    assert main(['import-kitti', str(tmp_path / 'seq'), '--out', str(tmp_path / 'x.mcap')]) == 1
    assert capsys.readouterr().err == (
        f"planar_vo import-kitti: error: --out: '{tmp_path / 'x.mcap'}' names a storage file; a "
        f"bag is written as a folder (metadata.yaml and the mcap file): give the folder's name, "
        f"e.g. '{tmp_path / 'x'}'\n")
    assert not (tmp_path / 'x.mcap').exists()
    # A negative start in exponent form is a value (argparse took '-1e12' for an option).
    assert main(['import-kitti', str(tmp_path / 'seq'), '--out', str(tmp_path / 'neg'),
                 '--start', '-1e12']) == 1
    err = capsys.readouterr().err
    assert err.startswith('planar_vo import-kitti: error: stamps: times.txt plus start gives '
                          '-1000000000000') and 'outside the range of a ROS time stamp' in err


RANGE = r'outside the range of a ROS time stamp \(0 to 2147483647\.999999999 s: 1970 to 2038\)'


@pytest.mark.parametrize('times, kwargs, match', [
    (('1e12', '1000000000000.1', '1000000000000.2', '1000000000000.3'), {},
     rf'stamps: times\.txt plus start gives 1001700000000 to 1001700000000\.3 s, {RANGE}'),
    (None, {'start': '1e30'}, rf'stamps: times\.txt plus start gives 1e\+30 to 1e\+30 s, {RANGE}'),
    (None, {'start': 10**400}, r'stamps: times\.txt plus start gives 1e\+400 to 1e\+400 s'),
    (('-0.3', '-0.2', '-0.1', '0'), {'start': 0},
     rf'stamps: times\.txt plus start gives -0\.3 to 0 s, {RANGE}'),
    (None, {'rate_hz': 1e-300}, r'rate_hz: expected a camera frame rate of 0\.01-1000 Hz, got '
                                r'1e-300'),
    (None, {'rate_hz': 1e12}, r'rate_hz: expected a camera frame rate of 0\.01-1000 Hz, got '
                              r'1000000000000\.0'),
    (None, {'rate_hz': 10**400}, r'rate_hz: expected a camera frame rate of 0\.01-1000 Hz, got '
                                 r'1000'),
    (None, {'camera_height': 10**400}, r'camera_height: expected a positive height in metres'),
], ids=['times_1e12', 'start_1e30', 'start_10**400', 'negative_times', 'rate_1e-300',
        'rate_1e12', 'rate_10**400', 'height_10**400'])
def test_absurd_times_are_refused_before_anything_is_written(tmp_path, rng, times, kwargs,
                                                             match):
    _write_sequence(tmp_path / 'seq', rng, **({} if times is None else {'times': times}))
    with pytest.raises(InputError, match=match):
        import_kitti(tmp_path / 'seq', tmp_path / 'bag', **kwargs)
    assert not (tmp_path / 'bag').exists() and partial_leftovers(tmp_path) == []


def test_frames_1_ns_apart_import_without_numpy_warnings(tmp_path, rng):
    """--rate-hz 1e9: the ground truth's velocities came from float64 absolute nanoseconds
    (256 ns apart near 1.7e18), divided by zero and were refused as 'poses too far apart'
    (a user test)."""
    import warnings

    from planar_vo.io.kitti import kitti_ground_truth

    _write_sequence(tmp_path / 'seq', rng)
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        import_kitti(tmp_path / 'seq', tmp_path / 'bag', rate_hz=1000.0)   # the fastest taken
    # (1e9 Hz itself is refused now: no camera's; a user test replayed it at 1e9 m/s)
    with pytest.raises(InputError, match=r'rate_hz: expected a camera frame rate'):
        import_kitti(tmp_path / 'seq', tmp_path / 'bag_ns', rate_hz=1e9)
    stamps = 1_700_000_000_000_000_000 + np.arange(3)
    poses = np.tile(np.eye(4), (3, 1, 1))
    poses[:, 2, 3] = [0.0, 1e-9, 2e-9]                      # 1 m/s forward
    _, twists = kitti_ground_truth(poses, stamps, 1.65)
    np.testing.assert_allclose(twists[:, :3], [[1.0, 0.0, 0.0]] * 3, atol=1e-6)


def test_cli_absurd_times_are_one_line(tmp_path, rng, capsys):
    _write_sequence(tmp_path / 'seq', rng)
    for flags in (['--start', '1e30'], ['--rate-hz', '1e12'], ['--rate-hz', '1e-300'],
                  ['--start', '-5']):
        assert main(['import-kitti', str(tmp_path / 'seq'), '--out', str(tmp_path / 'bag'),
                     *flags]) == 1
        err = capsys.readouterr().err
        assert err.startswith(('planar_vo import-kitti: error: stamps: ',
                               'planar_vo import-kitti: error: --rate-hz: expected a camera '
                               'frame rate of 0.01-1000 Hz')) and err.count('\n') == 1
    assert not (tmp_path / 'bag').exists()


def test_import_stopped_by_sigterm_keeps_the_frames_written(tmp_path, rng, monkeypatch):
    """SIGTERM while reading the third image: the two frames written are a complete bag and the
    interruption says so."""
    import planar_vo.io.kitti as kitti

    _write_sequence(tmp_path / 'seq', rng)
    read_png = kitti._read_png

    def read_and_stop(path):
        if path.name == '000002.png':
            signal.raise_signal(signal.SIGTERM)
        return read_png(path)

    monkeypatch.setattr(kitti, '_read_png', read_and_stop)
    with pytest.raises(KeyboardInterrupt, match=r"SIGTERM\nkept '.*bag', a complete bag with "
                                                r'messages /camera/camera_info: 2, '
                                                r'/camera/image_raw: 2, /ground_truth/odom: 2 '
                                                r'\(2 of 4 frames: the rest were not '
                                                r'imported\)$'):
        with stop_signals_interrupt():
            import_kitti(tmp_path / 'seq', tmp_path / 'bag')
    with open_bag(tmp_path / 'bag') as bag:
        assert [f.stamp_ns for f in iter_camera_frames(bag)] == [START_NS, START_NS + 10**8]
    from planar_vo.tools.provenance import bag_custom_data
    from planar_vo.tools.replay import replay_bag

    assert bag_custom_data(tmp_path / 'bag') == {
        'planar_vo.partial': '2 of 4 frames (the import was interrupted)'}
    # replay says so in its summary (the odometry of 2 frames is not the sequence's)
    from planar_vo.pipeline import VisualOdometry

    summary = replay_bag(tmp_path / 'bag', tmp_path / 'vo', VisualOdometry())
    assert summary.partial_input == '2 of 4 frames (the import was interrupted)'
    assert ('\n  input              an import cut short: 2 of 4 frames (the import was '
            'interrupted)\n') in summary.format()
    # ... and passes it on to the odometry bag (eval and fleet rows say it from there)
    assert bag_custom_data(tmp_path / 'vo')['planar_vo.partial'] == summary.partial_input


def test_an_interrupt_inside_a_frame_waits_for_its_last_message(tmp_path, rng, monkeypatch):
    """SIGINT between a frame's image and its ground truth (a user test: 99 images and 98
    ground-truth poses kept): the frame is finished first, every topic keeps the same count."""
    from planar_vo.io.camera_bag import CameraBagWriter

    _write_sequence(tmp_path / 'seq', rng)
    write_odometry = CameraBagWriter.write_odometry
    calls = []

    def interrupt_then_write(self, *args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            signal.raise_signal(signal.SIGINT)
        return write_odometry(self, *args, **kwargs)

    monkeypatch.setattr(CameraBagWriter, 'write_odometry', interrupt_then_write)
    with pytest.raises(KeyboardInterrupt, match=r'/camera/camera_info: 2, /camera/image_raw: 2, '
                                                r'/ground_truth/odom: 2 \(2 of 4 frames'):
        with stop_signals_interrupt():
            import_kitti(tmp_path / 'seq', tmp_path / 'bag')


def test_import_on_a_full_disk_keeps_nothing_and_says_so(tmp_path, rng):
    _write_sequence(tmp_path / 'seq', rng)
    disk = tmp_path / 'disk'
    run = run_planar_vo(['import-kitti', tmp_path / 'seq', '--out', disk / 'bag', '--storage',
                         'mcap'], disk=disk, keep=tmp_path / 'kept', size_kib=4)
    reason = 'No space left on device' if run.method == 'tmpfs' else 'File too large'
    assert run.returncode == 1
    assert run.stderr.startswith('planar_vo import-kitti: error: --out: ')
    assert run.stderr.endswith(f"nothing was kept at '{disk / 'bag'}' (cannot finish the bag: "
                               f'{reason})\n') and run.stderr.count('\n') == 1
    assert list((tmp_path / 'kept').iterdir()) == []


def test_an_excerpt_may_keep_its_first_frame_number(tmp_path, rng):
    """Frames are numbered without gaps; an excerpt that keeps the original numbers (000100...)
    is a sequence like any other."""
    _write_sequence(tmp_path / 'seq', rng)
    images = sorted((tmp_path / 'seq' / 'image_0').glob('*.png'))
    for i, path in reversed(list(enumerate(images))):
        path.rename(path.with_name(f'{100 + i:06d}.png'))
    summary = import_kitti(tmp_path / 'seq', tmp_path / 'bag')
    assert summary.frames == len(images)
    (tmp_path / 'seq' / 'image_0' / '000101.png').unlink()
    with pytest.raises(InputError, match=r"images: '000101\.png' is missing"):
        read_kitti_sequence(tmp_path / 'seq')


def test_text_files_saved_with_a_byte_order_mark_are_read(tmp_path, rng):
    """A user test: a calib.txt saved by an editor with a UTF-8 byte-order mark was refused
    ('got \\ufeff7.07...'); the same numbers without one are read alike."""
    _write_sequence(tmp_path / 'plain', rng)
    _write_sequence(tmp_path / 'bom', np.random.default_rng(0))
    for name in ('calib.txt', 'times.txt', 'poses.txt'):
        text = (tmp_path / 'plain' / name).read_text()
        (tmp_path / 'bom' / name).write_text(text, encoding='utf-8-sig')
    plain, bom = (read_kitti_sequence(tmp_path / k) for k in ('plain', 'bom'))
    assert (tmp_path / 'bom' / 'calib.txt').read_bytes().startswith(b'\xef\xbb\xbf')
    np.testing.assert_array_equal(bom.P0, plain.P0)
    np.testing.assert_array_equal(bom.poses, plain.poses)
    assert list(bom.times) == list(plain.times)


def test_frames_numbered_without_zero_padding_are_taken_in_number_order(tmp_path, rng):
    """'0.png' ... '10.png' (a user test: sorted as text, '02.png' was reported missing)."""
    times = [f'{0.1 * i:.1f}' for i in range(11)]
    images = _write_sequence(tmp_path / 'seq', rng, n=11, times=times, poses=False)
    for i, path in enumerate(sorted((tmp_path / 'seq' / 'image_0').glob('*.png'))):
        path.rename(path.with_name(f'{i}.png'))
    seq = read_kitti_sequence(tmp_path / 'seq')
    assert [p.name for p in seq.images] == [f'{i}.png' for i in range(11)]
    import_kitti(tmp_path / 'seq', tmp_path / 'bag')
    with open_bag(tmp_path / 'bag') as bag:
        got = [f.image for f in iter_camera_frames(bag)]
    assert all(np.array_equal(a, b) for a, b in zip(got, images, strict=True))
    (tmp_path / 'seq' / 'image_0' / '5.png').rename(tmp_path / 'seq' / 'image_0' / '05.png')
    cv2.imwrite(str(tmp_path / 'seq' / 'image_0' / '5.png'), images[5])
    with pytest.raises(InputError, match=r"images: '05\.png' and '5\.png' in '.*' both number "
                                         r'frame 5'):
        read_kitti_sequence(tmp_path / 'seq')
    (tmp_path / 'seq' / 'image_0' / '05.png').unlink()
    (tmp_path / 'seq' / 'image_0' / '4.png').unlink()
    with pytest.raises(InputError, match=r"images: '4\.png' is missing .* the next there is "
                                         r"'5\.png'"):
        read_kitti_sequence(tmp_path / 'seq')
    # Padded like the name before the gap ('099999.png' between '099998.png' and '100000.png')
    for path in sorted((tmp_path / 'seq' / 'image_0').glob('*.png')):
        path.unlink()
    for number in (99998, 100000):
        cv2.imwrite(str(tmp_path / 'seq' / 'image_0' / f'{number:06d}.png'), images[0])
    with pytest.raises(InputError, match=r"images: '099999\.png' is missing .* the next there "
                                         r"is '100000\.png'"):
        read_kitti_sequence(tmp_path / 'seq')


@pytest.mark.parametrize('times', [('0.0', '0.1'), ('0.0', 'x', '0.2', '0.3'), None])
def test_a_rate_replaces_times_txt_whatever_it_holds(tmp_path, rng, times):
    """--rate-hz stamps the frames instead of times.txt: a short, malformed or missing one is
    no reason to refuse (a user test: a read-only dataset with a short times.txt could not be
    imported at any rate)."""
    _write_sequence(tmp_path / 'seq', rng, times=times)
    with pytest.raises(InputError, match='times.txt'):
        import_kitti(tmp_path / 'seq', tmp_path / 'bag0')
    import_kitti(tmp_path / 'seq', tmp_path / 'bag', rate_hz=10.0, start=0)
    with open_bag(tmp_path / 'bag') as bag:
        assert [f.stamp_ns for f in iter_camera_frames(bag)] == [0, 10**8, 2 * 10**8, 3 * 10**8]
