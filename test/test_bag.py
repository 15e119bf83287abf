"""planar_vo.io: reading (both storages, every failure mode), writing, and replay plumbing
driven by a test double (the real pipeline is tested end to end elsewhere)."""

from __future__ import annotations

import logging
import re
import shutil

import cv2
import numpy as np
import pytest
import yaml
from bagdata import (
    TS,
    camera_info_msg,
    compressed_msg,
    corrupt_mid_way,
    image_msg,
    odometry_msg,
    storage_file,
    twist_msg,
    write_bag,
    zero_png,
)

from planar_vo.cli import main
from planar_vo.core.camera import CameraModel
from planar_vo.core.conventions import planar_pose
from planar_vo.errors import BagError
from planar_vo.io import OdometryBagWriter, iter_camera_frames, iter_messages, open_bag
from planar_vo.pipeline.types import DropReason, FrameResult
from planar_vo.ros.messages import pose_from_message, stamp_to_ns
from planar_vo.tools.evaluation import read_tum
from planar_vo.tools.replay import replay_bag

STORAGES = ['mcap', 'sqlite3']
IMAGE = 'sensor_msgs/msg/Image'
INFO = 'sensor_msgs/msg/CameraInfo'
ODOM = 'nav_msgs/msg/Odometry'
T0 = 1_700_000_000_123_456_789            # odd nanoseconds: any float round trip would show


def _one_line_error(excinfo) -> str:
    text = str(excinfo.value)
    assert '\n' not in text
    return text


# -- opening ------------------------------------------------------------------------------------

@pytest.fixture
def small_bag(tmp_path, rng):
    def make(storage='mcap', name='small'):
        frames = [rng.integers(0, 256, (24, 32), dtype=np.uint8) for _ in range(3)]
        entries = []
        for i, img in enumerate(frames):
            stamp = T0 + i * 100_000_007
            entries.append(('/cam/camera_info', INFO, stamp, camera_info_msg(stamp, 32, 24, 30.0)))
            entries.append(('/cam/image_raw', IMAGE, stamp, image_msg(img, 'mono8', stamp)))
        return write_bag(tmp_path / f'{name}_{storage}', storage, entries), frames
    return make


@pytest.mark.parametrize('storage', STORAGES)
def test_open_directory_and_single_file(small_bag, storage):
    bag_dir, frames = small_bag(storage)
    for path in (bag_dir, storage_file(bag_dir)):
        with open_bag(path) as bag:
            assert bag.topics == {'/cam/camera_info': INFO, '/cam/image_raw': IMAGE}
            got = list(iter_camera_frames(bag))
        assert [f.stamp_ns for f in got] == [T0 + i * 100_000_007 for i in range(3)]
        for frame, img in zip(got, frames):
            np.testing.assert_array_equal(frame.image, img)
            assert frame.error is None and frame.frame_id == 'camera'
            assert frame.camera == CameraModel.pinhole(32, 24, 30.0, cx=16.0, cy=12.0)


@pytest.mark.parametrize('storage', STORAGES)
def test_open_a_bag_directory_named_like_a_ros1_bag(small_bag, storage):
    # rosbags takes a path ending in '.bag' for a ROS 1 bag file; a rosbag2 directory of that
    # name (`import-kitti seq --out drive.bag`) was refused as corrupt.
    bag_dir, frames = small_bag(storage)
    named = bag_dir.rename(bag_dir.with_name('drive.bag'))
    with open_bag(named) as bag:
        got = list(iter_camera_frames(bag))
    assert len(got) == 3
    np.testing.assert_array_equal(got[-1].image, frames[-1])
    # A ROS 1 bag file stays refused by its suffix, in one line.
    ros1 = named.parent / 'old.bag'
    ros1.write_bytes(b'#ROSBAG V2.0\n')
    with pytest.raises(BagError, match=r"is not a bag: expected a rosbag2 directory or a "
                                       r"\.mcap/\.db3 file, got a '\.bag' file"):
        with open_bag(ros1):
            pass


def test_open_missing_path(tmp_path):
    with pytest.raises(BagError, match=r"bag: '.*nothing' does not exist") as exc:
        with open_bag(tmp_path / 'nothing'):
            pass
    _one_line_error(exc)


def test_open_not_a_bag(tmp_path):
    text = tmp_path / 'notes.txt'
    text.write_text('hello')
    with pytest.raises(BagError, match=r"is not a bag: expected a rosbag2 directory or a "
                                       r"\.mcap/\.db3 file, got a '\.txt' file"):
        with open_bag(text):
            pass
    with pytest.raises(BagError, match=r"is not a bag: expected a directory with metadata\.yaml"):
        with open_bag(tmp_path):
            pass
    junk = tmp_path / 'junk.mcap'
    junk.write_bytes(b'not an mcap file at all')
    with pytest.raises(BagError, match=r"bag: cannot open '.*junk\.mcap': corrupt, truncated or "
                                       r'not a ROS 2 bag \(.*magic') as exc:
        with open_bag(junk):
            pass
    _one_line_error(exc)


@pytest.mark.parametrize('storage, cut, detail', [
    ('mcap', 1000, r'AnyReaderError: File end magic is invalid\.'),
    ('sqlite3', 4096, r'AnyReaderError: .*database disk image is malformed'),
])
def test_open_truncated_bag(small_bag, storage, cut, detail):
    bag_dir, _ = small_bag(storage)
    file = storage_file(bag_dir)
    file.write_bytes(file.read_bytes()[:-cut])
    with pytest.raises(BagError, match=r"bag: cannot open '.*': corrupt, truncated or not a ROS 2 "
                                       rf'bag \({detail}\)') as exc:
        with open_bag(bag_dir):
            pass
    _one_line_error(exc)


def _big_image_bag(path, storage, rng, n=40, extra=()):
    """Over 1 MiB of images (MCAP: several chunks), for damage found part-way through."""
    images = [rng.integers(0, 256, (240, 320), dtype=np.uint8) for _ in range(n)]
    entries = []
    for i, img in enumerate(images):
        stamp = T0 + i * 100_000_000
        entries.append(('/cam/image_raw', IMAGE, stamp, image_msg(img, 'mono8', stamp)))
        entries += [e(i, stamp) for e in extra]
    return write_bag(path, storage, entries), images


@pytest.mark.parametrize('storage', STORAGES)
def test_corruption_found_mid_way_keeps_earlier_frames(tmp_path, rng, storage):
    bag_dir, images = _big_image_bag(tmp_path / 'big', storage, rng)
    corrupt_mid_way(bag_dir, images[25][120].tobytes())
    got = []
    with pytest.raises(BagError, match=r"bag '.*big': corrupt or truncated, reading failed after "
                                       r'\d+ messages \(\w+: .+\)') as exc:
        with open_bag(bag_dir) as bag:
            for frame in iter_camera_frames(bag):
                got.append(frame)
    _one_line_error(exc)
    assert 5 <= len(got) < 40
    for frame in got:
        np.testing.assert_array_equal(frame.image, images[frame.index])


def test_planar_vos_mcap_bags_carry_chunk_checksums(tmp_path, rng):
    """rosbags' writer leaves every chunk's CRC 0 ('none'), so damaged chunk data read back
    without an error (a user test: 64 KiB overwritten inside an imported bag replayed with the
    poses 9 cm off and 'dropped 0'). planar_vo's bags get them (`stamp_chunk_crcs`), and the
    same damage stops the replay with one line."""
    import zlib

    from planar_vo.io.writer import stamp_chunk_crcs

    def chunks(file):
        data, pos, found = file.read_bytes(), 8, []
        while pos + 9 <= len(data) and data[pos] != 0x0F:
            length = int.from_bytes(data[pos + 1:pos + 9], 'little')
            if data[pos] == 0x06:
                body = pos + 9
                name = int.from_bytes(data[body + 28:body + 32], 'little')
                start = body + 32 + name + 8
                size = int.from_bytes(data[start - 8:start], 'little')
                found.append((int.from_bytes(data[body + 24:body + 28], 'little'),
                              zlib.crc32(data[start:start + size]), start))
            pos += 9 + length
        return found

    bag_dir, _ = _big_image_bag(tmp_path / 'big', 'mcap', rng)
    file = storage_file(bag_dir)
    assert len(chunks(file)) >= 3 and all(crc == 0 for crc, _, _ in chunks(file))
    assert stamp_chunk_crcs(file) == len(chunks(file))
    assert all(crc == actual != 0 for crc, actual, _ in chunks(file))
    assert stamp_chunk_crcs(file) == 0                     # (stamped ones are left alone)
    # A replay's output bag has them from the start.
    replay_bag(bag_dir, tmp_path / 'out', ConstantVelocityDouble(), progress=False)
    out = chunks(storage_file(tmp_path / 'out'))
    assert out and all(crc == actual != 0 for crc, actual, _ in out)
    # Damage inside the second chunk's records: detected when it is read.
    data = bytearray(file.read_bytes())
    start = chunks(file)[1][2]
    data[start + 5000:start + 5064] = bytes(64)
    file.write_bytes(bytes(data))
    with pytest.raises(BagError, match=r'Chunk checksum mismatch') as exc:
        replay_bag(bag_dir, tmp_path / 'out2', ConstantVelocityDouble(), progress=False)
    _one_line_error(exc)


# -- topics -------------------------------------------------------------------------------------

def test_unknown_topic_lists_available(small_bag):
    bag_dir, _ = small_bag()
    with open_bag(bag_dir) as bag:
        with pytest.raises(BagError, match=r"topic: '/nope' is not a topic of '.*'; available "
                                           r'topics: /cam/camera_info \(sensor_msgs/msg/'
                                           r'CameraInfo\), /cam/image_raw \(sensor_msgs/msg/Image'
                                           r'\)'):
            list(iter_messages(bag, '/nope'))
        with pytest.raises(BagError, match=r"image_topic: '/cam/missing' is not a topic of"):
            list(iter_camera_frames(bag, image_topic='/cam/missing'))
        with pytest.raises(BagError, match=r"image_topic: '/cam/camera_info' in '.*' has type "
                                           r'sensor_msgs/msg/CameraInfo, expected sensor_msgs/'
                                           r'msg/Image or sensor_msgs/msg/CompressedImage'):
            list(iter_camera_frames(bag, image_topic='/cam/camera_info'))


def test_ambiguous_and_missing_image_topic(tmp_path, rng):
    img = rng.integers(0, 256, (4, 5), dtype=np.uint8)
    two = write_bag(tmp_path / 'two', 'mcap', [
        ('/left/image_raw', IMAGE, 1, image_msg(img, 'mono8', 1)),
        ('/right/image_raw', IMAGE, 2, image_msg(img, 'mono8', 2)),
        ('/left/camera_info', INFO, 1, camera_info_msg(1, 5, 4, 10.0)),
        ('/right/camera_info', INFO, 2, camera_info_msg(2, 5, 4, 20.0)),
    ])
    with open_bag(two) as bag:
        with pytest.raises(BagError, match=r"image_topic: '.*two' has several candidate topics "
                                           r'\(/left/image_raw, /right/image_raw\); choose one'):
            next(iter_camera_frames(bag))
        # with the image topic chosen, the camera info next to it is picked
        frames = list(iter_camera_frames(bag, image_topic='/right/image_raw'))
        assert len(frames) == 1 and frames[0].camera.fx == 20.0
    none = write_bag(tmp_path / 'none', 'mcap', [('/odom', ODOM, 1, odometry_msg(1, 0.0))])
    with open_bag(none) as bag:
        with pytest.raises(BagError, match=r'image_topic: no sensor_msgs/msg/Image or sensor_msgs/'
                                           r"msg/CompressedImage topic in '.*none'; topics: /odom "
                                           r'\(nav_msgs/msg/Odometry\)'):
            next(iter_camera_frames(bag))


@pytest.mark.parametrize('storage', STORAGES)
def test_frames_report_bad_images_and_bad_camera_info_without_stopping(tmp_path, rng, storage):
    gray = rng.integers(0, 256, (24, 32), dtype=np.uint8)
    ok, png = cv2.imencode('.png', gray)
    bad_info = camera_info_msg(T0 + 2, 32, 24, 30.0, k=np.zeros((3, 3)))
    entries = [
        ('/cam/image', IMAGE, T0, image_msg(gray, 'mono8', T0)),           # before the info
        ('/cam/camera_info', INFO, T0 + 1, camera_info_msg(T0 + 1, 32, 24, 30.0)),
        ('/cam/image', IMAGE, T0 + 10, image_msg(gray, 'yuv422', T0 + 10)),   # bad encoding
        ('/cam/camera_info', INFO, T0 + 11, bad_info),                      # K all zeros
        ('/cam/image', IMAGE, T0 + 20, image_msg(np.dstack([gray] * 3), 'rgb8', T0 + 20,
                                                 pad=3)),
        ('/cam/image_compressed_is_other_topic', 'sensor_msgs/msg/CompressedImage', T0 + 21,
         compressed_msg(png.tobytes(), 'png', T0 + 21)),
        ('/cam/image', IMAGE, T0 + 30, image_msg(gray, 'mono8', T0 + 30)),
    ]
    bag_dir = write_bag(tmp_path / 'mixed', storage, entries)
    with open_bag(bag_dir) as bag:
        frames = list(iter_camera_frames(bag, image_topic='/cam/image'))
        compressed = list(iter_camera_frames(bag, '/cam/image_compressed_is_other_topic'))
    assert [f.index for f in frames] == [0, 1, 2, 3]
    assert [f.stamp_ns for f in frames] == [T0, T0 + 10, T0 + 20, T0 + 30]
    assert frames[0].camera.fx == 30.0            # the first CameraInfo, logged just after
    assert frames[1].image is None and "got 'yuv422'" in frames[1].error
    assert frames[1].camera.fx == 30.0
    assert 'K is all zeros' in frames[2].camera_error                  # reported once...
    assert frames[3].camera_error is None
    assert frames[2].camera.fx == 30.0 and frames[3].camera.fx == 30.0  # ...last good one kept
    for f in (frames[0], frames[2], frames[3]):
        np.testing.assert_array_equal(f.image, gray)
    np.testing.assert_array_equal(compressed[0].image, gray)
    assert compressed[0].camera.fx == 30.0                             # the only CameraInfo


# -- writing ------------------------------------------------------------------------------------

def _read_odometry(path, topic='/odom'):
    with open_bag(path) as bag:
        return [item for item in iter_messages(bag, topic)]


@pytest.mark.parametrize('storage', STORAGES)
def test_odometry_writer_round_trip(tmp_path, rng, storage):
    out = tmp_path / 'odom'
    poses = [planar_pose(*rng.normal(size=3)) for _ in range(4)]
    covs = [np.diag(rng.uniform(0.1, 1.0, 6)) for _ in range(4)]
    twists = [rng.normal(size=6) for _ in range(4)]
    stamps = [T0 + i * 33_333_333 for i in range(4)]
    with OdometryBagWriter(out, storage=storage, odom_frame='world', base_frame='car') as w:
        for s, T, C, v in zip(stamps, poses, covs, twists):
            w.write(s, T, C, v, 2 * C, log_time_ns=s + 7)
        assert w.count == 4
    items = _read_odometry(out)
    assert [i.stamp_ns for i in items] == stamps
    assert [i.log_time_ns for i in items] == [s + 7 for s in stamps]
    for item, T, C, v in zip(items, poses, covs, twists):
        msg = item.msg
        assert msg.header.frame_id == 'world' and msg.child_frame_id == 'car'
        np.testing.assert_allclose(pose_from_message(msg), T, atol=1e-15)
        np.testing.assert_array_equal(msg.pose.covariance.reshape(6, 6), C)
        np.testing.assert_array_equal(msg.twist.covariance.reshape(6, 6), 2 * C)
        lin, ang = msg.twist.twist.linear, msg.twist.twist.angular
        np.testing.assert_array_equal([lin.x, lin.y, lin.z, ang.x, ang.y, ang.z], v)


def test_writer_refuses_to_overwrite(tmp_path):
    existing = tmp_path / 'existing'
    existing.mkdir()
    (existing / 'keep.txt').write_text('precious')
    with pytest.raises(BagError, match=r"out: '.*existing' already exists; refusing to overwrite "
                                       r'it'):
        OdometryBagWriter(existing)
    assert [p.name for p in existing.iterdir()] == ['keep.txt']
    assert (existing / 'keep.txt').read_text() == 'precious'
    afile = tmp_path / 'file.mcap'
    afile.write_bytes(b'x')
    with pytest.raises(BagError, match=r'already exists'):
        OdometryBagWriter(afile)
    assert afile.read_bytes() == b'x'
    with pytest.raises(BagError, match=r"storage: expected one of \['mcap', 'sqlite3'\], got "
                                       r"'zip'"):
        OdometryBagWriter(tmp_path / 'new', storage='zip')
    assert not (tmp_path / 'new').exists()


@pytest.mark.parametrize('storage', STORAGES)
def test_writer_closes_properly_on_exception(tmp_path, storage):
    out = tmp_path / 'partial'
    with pytest.raises(RuntimeError, match='boom'):
        with OdometryBagWriter(out, storage=storage) as w:
            for i in range(3):
                w.write(T0 + i, planar_pose(float(i), 0.0, 0.0))
            raise RuntimeError('boom')
    items = _read_odometry(out)
    assert [i.stamp_ns for i in items] == [T0, T0 + 1, T0 + 2]


def test_a_second_stop_while_the_writer_finishes_keeps_the_bag_and_says_so(tmp_path):
    """A stop signal inside the writer's exit (its on_stop mark, its close) waits until the
    bag is finished, then is raised with the note of what was kept (a review: the note stayed
    on the first exception, the line said nothing of the bag)."""
    import os
    import signal as signals

    from planar_vo.io.outputs import stop_signals_interrupt

    out = tmp_path / 'vo'
    writer = OdometryBagWriter(out)

    def second_stop(err):
        os.kill(os.getpid(), signals.SIGINT)
        writer.custom_data['marked'] = type(err).__name__

    writer.on_stop = second_stop
    with stop_signals_interrupt(), pytest.raises(KeyboardInterrupt) as exc:
        with writer:
            writer.write(T0, planar_pose(0.0, 0.0, 0.0))
            raise RuntimeError('first')
    assert str(exc.value) == 'SIGINT'
    assert exc.value.__notes__ == [f"kept '{out}', a complete bag with messages /odom: 1"]
    assert [i.stamp_ns for i in _read_odometry(out)] == [T0]


# -- replay -------------------------------------------------------------------------------------

class ConstantVelocityDouble:
    """TEST DOUBLE standing in for planar_vo.pipeline.VisualOdometry: not visual odometry.

    The first frame initialises (FIRST_FRAME, at the origin); every later frame moves the pose
    along x by the last fed speed times the elapsed time and turns it by 0.01 rad; it records
    what it saw.
    """

    def __init__(self):
        self.speed, self.x, self.yaw, self.last = 1.0, 0.0, 0.0, None
        self.speeds, self.calls, self.poses = [], [], []

    def add_speed(self, stamp, speed):
        self.speeds.append((stamp, speed))
        self.speed = speed

    def process(self, image, stamp, camera):
        self.calls.append((stamp, image.shape, camera, list(self.speeds)))
        if self.last is None:
            self.last = stamp
            return FrameResult(stamp, False, np.eye(4), np.zeros((6, 6)),
                               reason=DropReason.FIRST_FRAME)
        self.x += self.speed * (stamp - self.last)
        self.yaw += 0.01
        self.last = stamp
        pose = planar_pose(self.x, 0.0, self.yaw)
        self.poses.append(pose)
        return FrameResult(stamp, True, pose, np.eye(6) * 0.5, twist=np.arange(6.0),
                           twist_covariance=np.eye(6) * 0.25)


def _replay_input(path, storage, rng, n=10, bad=(4,), nan_speeds=()):
    images = [rng.integers(0, 256, (24, 32), dtype=np.uint8) for _ in range(n)]
    entries = [('/note', 'std_msgs/msg/String', T0 - 5, TS.types['std_msgs/msg/String'](
        data='not copied'))]
    stamps = []
    for i, img in enumerate(images):
        stamp = T0 + i * 100_000_007
        stamps.append(stamp)
        log = stamp + 5_000_000
        entries.append(('/cam/camera_info', INFO, log - 1, camera_info_msg(stamp, 32, 24, 30.0)))
        entries.append(('/cam/image_raw', IMAGE, log, image_msg(img, 'yuv422' if i in bad else
                                                                'mono8', stamp)))
        entries.append(('/ground_truth/odom', ODOM, log + 1, odometry_msg(stamp, 0.3 * i)))
        entries.append(('/vehicle/twist', 'geometry_msgs/msg/TwistStamped', log + 2,
                        twist_msg(stamp + 50_000_000,
                                  float('nan') if i in nan_speeds else 2.0 + i)))
    return write_bag(path, storage, entries), stamps


def test_replay_counts_a_header_stamp_that_is_no_ros_time(tmp_path, rng):
    """A user test: a first image stamped sec -1 aborted the replay when its odometry was
    written (the 9 frames after it never ran), and nanosec 4e9 read as 4 s later. Each is a
    bad_stamp now, seen neither by the pipeline nor by the gap counter."""
    entries = []
    for i in range(10):
        stamp = T0 + i * 100_000_000
        msg = image_msg(rng.integers(0, 256, (24, 32), dtype=np.uint8), 'mono8', stamp)
        if i == 0:
            msg.header.stamp.sec = -1
        if i == 5:
            msg.header.stamp.nanosec = 4_000_000_000
        entries.append(('/cam/camera_info', INFO, stamp, camera_info_msg(stamp, 32, 24, 30.0)))
        entries.append(('/cam/image_raw', IMAGE, stamp + 1, msg))
    double = ConstantVelocityDouble()
    summary = replay_bag(write_bag(tmp_path / 'in', 'mcap', entries), tmp_path / 'out', double,
                         progress=False)
    assert summary.frames_in == 10 and summary.dropped == {'bad_stamp': 2}
    assert summary.odometry_out == 8 and summary.origins == 1
    assert (summary.gaps, summary.missing_frames) == (0, 0)
    assert len(double.calls) == 8


def test_the_tum_file_leaves_out_poses_published_at_stamps_ahead(tmp_path):
    """A user test: after the odometry moved mis-stamped frames' stamps back, /odom's stamps
    went back once and the TUM file kept only the poses after it, as for a looped bag. Now it
    leaves out the few poses published at the wrong stamps; a loop still starts it afresh."""
    from planar_vo.tools.replay import _Poses

    poses = _Poses()
    for k in (0, 1, 2, 3, 9, 4, 5, 6, 10, 11):           # frame 9's stamp was 5 ahead
        poses.add(k, np.eye(4), k > 0)
    assert poses.stamps_ns == [0, 1, 2, 3, 4, 5, 6, 10, 11] and poses.earlier == 0
    assert poses.note == ' (without 1 pose published at stamps ahead of their time, which the ' \
        'bag holds)'
    for k in range(20, 40):
        poses.add(k, np.eye(4), True)
    poses.add(2, np.eye(4), True)                         # a looped bag: afresh
    assert poses.stamps_ns == [2] and poses.earlier == 29
    poses.write(tmp_path / 'x.tum')
    lines = (tmp_path / 'x.tum').read_text().splitlines()
    assert lines[1:] == ['0.000000002 0.0 0.0 0.0 0.0 0.0 0.0 1.0']


def test_replay_skips_and_counts_a_bad_speed_sample(tmp_path, rng, caplog):
    """A user test: one NaN wheel-speed sample aborted the whole replay; the node skips and
    counts such a message, and so does replay."""
    in_bag, stamps = _replay_input(tmp_path / 'in', 'mcap', rng, nan_speeds=(3, 6))
    double = ConstantVelocityDouble()
    with caplog.at_level(logging.WARNING, logger='planar_vo.tools.replay'):
        summary = replay_bag(in_bag, tmp_path / 'out', double, speed_topic='/vehicle/twist',
                             progress=False)
    assert summary.frames_in == 10 and summary.odometry_out == 9
    assert summary.speed_errors == 2 and summary.speed_messages == 7
    assert [s for _, s in double.speeds] == [2.0 + i for i in range(9) if i not in (3, 6)]
    assert summary.speed_error.startswith(f'at {stamps[3] + 50_000_000} ns: ')
    line = next(x for x in summary.format().splitlines() if 'speed messages' in x)
    assert line.startswith('  speed messages     7 (2 refused, the first at ')
    assert 'nan' in line
    assert sum('speed_topic' in r.getMessage() for r in caplog.records) == 1


@pytest.mark.parametrize('in_storage, out_storage', [('mcap', 'sqlite3'), ('sqlite3', 'mcap')])
def test_replay_writes_odometry_counts_drops_and_copies_ground_truth(
        tmp_path, rng, capsys, in_storage, out_storage):
    in_bag, stamps = _replay_input(tmp_path / 'in', in_storage, rng)
    double = ConstantVelocityDouble()
    tum = tmp_path / 'vo.tum'
    summary = replay_bag(in_bag, tmp_path / 'out', double, speed_topic='/vehicle/twist',
                         tum_path=tum, storage=out_storage, progress=True)
    assert summary.frames_in == 10 and summary.odometry_out == 9     # the origin's too
    assert summary.origins == 1 and summary.dropped == {'bad_image': 1}
    assert summary.copied == {'/ground_truth/odom': 10}
    assert summary.image_topic == '/cam/image_raw'
    assert summary.camera_info_topic == '/cam/camera_info'
    assert summary.throughput > 0 and 'frames/s' in summary.format()
    # The double's steps have the default source; it has no road top-ups to count.
    assert summary.scale_sources == {'unit': 8} and summary.road_top_ups is None
    assert summary.scale == '' and '  scale ' not in summary.format()    # the double has none
    assert ('  step lengths       unit 8 (8 of 8 without a metric length: their positions are '
            'in steps, not metres)\n') in summary.format()
    assert 'replay' in capsys.readouterr().err                     # the progress bar

    # the processor saw decoded images, the camera, and exactly the speeds stamped before
    ok_stamps = [s for i, s in enumerate(stamps) if i != 4]
    speed_stamps = [s + 50_000_000 for s in stamps]
    assert [c[0] for c in double.calls] == [s / 1_000_000_000 for s in ok_stamps]
    for stamp, shape, camera, speeds in double.calls:
        assert shape == (24, 32) and camera.fx == 30.0
        assert len(speeds) == sum(1 for s in speed_stamps if s / 1_000_000_000 <= stamp)
        assert all(t <= stamp for t, _ in speeds)
    assert summary.speed_messages == len(double.speeds) == 9

    with open_bag(tmp_path / 'out') as out:
        assert out.topics == {'/ground_truth/odom': ODOM, '/odom': ODOM}
        odom = list(iter_messages(out, '/odom'))
        gt_out = [m.rawdata for m in out.messages(['/ground_truth/odom'])]
        gt_conn = out.connection('/ground_truth/odom')
    with open_bag(in_bag) as bag:
        gt_in = [m.rawdata for m in bag.messages(['/ground_truth/odom'])]
        in_conn = bag.connection('/ground_truth/odom')
    assert [bytes(b) for b in gt_out] == [bytes(b) for b in gt_in]
    assert (gt_conn.msgdef, gt_conn.digest) == (in_conn.msgdef, in_conn.digest)
    # odometry stamped with the exact header stamps of the processed images, the first frame's
    # at the origin
    assert [m.stamp_ns for m in odom] == ok_stamps
    np.testing.assert_array_equal(pose_from_message(odom[0].msg), np.eye(4))
    assert not np.any(odom[0].msg.pose.covariance)
    for item, pose in zip(odom[1:], double.poses, strict=True):
        np.testing.assert_allclose(pose_from_message(item.msg), pose, atol=1e-15)
        np.testing.assert_array_equal(item.msg.pose.covariance, np.eye(6).ravel() * 0.5)
        assert item.msg.twist.twist.linear.y == 1.0 and item.msg.twist.covariance[0] == 0.25
    # the TUM file holds the same poses with full-precision stamps
    traj = read_tum(tum)
    assert traj.stamps_ns.tolist() == ok_stamps
    np.testing.assert_allclose(traj.poses, np.array([np.eye(4), *double.poses]), atol=1e-15)


def test_replay_refuses_existing_outputs(tmp_path, rng):
    in_bag, _ = _replay_input(tmp_path / 'in', 'mcap', rng, n=2)
    (tmp_path / 'out').mkdir()
    with pytest.raises(BagError, match=r"out: '.*out' already exists; refusing to overwrite"):
        replay_bag(in_bag, tmp_path / 'out', ConstantVelocityDouble(), progress=False)
    (tmp_path / 'vo.tum').write_text('keep')
    with pytest.raises(BagError, match=r"tum: '.*vo\.tum' already exists; refusing to overwrite"):
        replay_bag(in_bag, tmp_path / 'out2', ConstantVelocityDouble(), tum_path=tmp_path /
                   'vo.tum', progress=False)
    assert not (tmp_path / 'out2').exists() and (tmp_path / 'vo.tum').read_text() == 'keep'
    with pytest.raises(BagError, match=r"copy_topics: '/nope' is not a topic of"):
        replay_bag(in_bag, tmp_path / 'out3', ConstantVelocityDouble(), copy_topics=['/nope'],
                   progress=False)
    with pytest.raises(BagError, match=r"speed_topic: '/cam/image_raw' in .* has type "
                                       r'sensor_msgs/msg/Image, expected geometry_msgs/msg/'
                                       r'TwistStamped or'):
        replay_bag(in_bag, tmp_path / 'out4', ConstantVelocityDouble(),
                   speed_topic='/cam/image_raw', progress=False)


def test_replay_interrupted_before_any_motion_writes_no_tum_file(tmp_path, rng):
    """Stopped after the first frame (the origin's odometry) and before any motion: as after a
    complete replay without motion, the TUM file is not written (the origin alone says
    nothing; a review found it written with the one pose)."""
    in_bag, _ = _replay_input(tmp_path / 'in', 'mcap', rng)
    double = ConstantVelocityDouble()
    real = double.process

    def stopped(image, stamp, camera):
        if double.calls:
            raise KeyboardInterrupt
        return real(image, stamp, camera)

    double.process = stopped
    tum = tmp_path / 'vo.tum'
    with pytest.raises(KeyboardInterrupt) as exc:
        replay_bag(in_bag, tmp_path / 'out', double, tum_path=tum, progress=False)
    assert exc.value.__notes__[-1] == f"no motion was estimated; '{tum}' was not written"
    assert not tum.exists() and len(_read_odometry(tmp_path / 'out')) == 1


def test_a_replay_stopped_early_marks_its_bag_partial_and_eval_warns(tmp_path, rng, caplog):
    """A user test: an interrupted replay's bag could not be told from a complete one (no
    mark, no focal length), and eval scored it without a word."""
    from planar_vo.tools.provenance import bag_custom_data

    in_bag, _ = _replay_input(tmp_path / 'in', 'mcap', rng)
    double = ConstantVelocityDouble()
    double.focal_status = lambda: 'focal length 30.0 px (CameraInfo)'
    real = double.process

    def stopped(image, stamp, camera):
        if len(double.calls) == 6:              # the 8th frame (frame 4 is a bad image)
            raise KeyboardInterrupt('SIGINT')
        return real(image, stamp, camera)

    double.process = stopped
    with pytest.raises(KeyboardInterrupt):
        replay_bag(in_bag, tmp_path / 'out', double, progress=False)
    custom = bag_custom_data(tmp_path / 'out')
    # (the odometry messages, as the stop's line counts them: 7 frames processed, frame 4 a
    # bad image)
    assert custom['planar_vo.partial'] == ('odometry for 6 of 10 frames (the replay was '
                                           'interrupted)')
    assert custom['planar_vo.focal'] == 'focal length 30.0 px (CameraInfo)'
    with caplog.at_level('WARNING', logger='planar_vo'):
        main(['eval', str(tmp_path / 'out'), '--out-dir', str(tmp_path / 'ev')])
    assert ('EST covers part of its drive: odometry for 6 of 10 frames (the replay was '
            'interrupted); the evaluation covers those frames only') in caplog.text
    # A complete replay carries no mark.
    replay_bag(in_bag, tmp_path / 'whole', ConstantVelocityDouble(), progress=False)
    assert 'planar_vo.partial' not in bag_custom_data(tmp_path / 'whole')


@pytest.mark.parametrize('storage', STORAGES)
def test_replay_of_a_bag_corrupt_mid_way_keeps_what_was_written(tmp_path, rng, storage):
    gt = (lambda i, stamp: ('/ground_truth/odom', ODOM, stamp + 1, odometry_msg(stamp, 0.1 * i)))
    in_bag, images = _big_image_bag(tmp_path / 'in', storage, rng, extra=(gt,))
    corrupt_mid_way(in_bag, images[25][120].tobytes())
    double = ConstantVelocityDouble()
    with pytest.raises(BagError, match=r"bag '.*in': corrupt or truncated, reading failed after "
                                       r"\d+ messages .*\nkept '.*out', a complete bag with "
                                       r"messages /odom: \d+, /ground_truth/odom: \d+\nwrote "
                                       r"'.*vo\.tum' with the \d+ poses computed$") as exc:
        replay_bag(in_bag, tmp_path / 'out', double, tum_path=tmp_path / 'vo.tum',
                   progress=False)
    _one_line_error(exc)
    kept = int(re.search(r'/odom: (\d+),', exc.value.__notes__[0]).group(1))
    assert kept == len(double.poses) + 1 >= 5                # the origin and the steps
    # The counts of what was replayed travel with the error (the CLI prints them, the fleet's
    # row keeps them).
    partial = exc.value.replay_summary
    assert (partial.frames_in, partial.odometry_out, partial.dropped) == (kept, kept, {})
    odom = _read_odometry(tmp_path / 'out')                  # the output is a complete bag
    assert len(odom) == kept
    assert [m.stamp_ns for m in odom] == [T0 + i * 100_000_000 for i in range(kept)]
    assert len(read_tum(tmp_path / 'vo.tum')) == kept
    # Each frame's ground truth is logged just after its image: the last one may be lost.
    assert len(_read_odometry(tmp_path / 'out', '/ground_truth/odom')) >= kept - 1


@pytest.mark.parametrize('storage', STORAGES)
def test_replay_of_an_image_topic_without_messages_is_one_line_and_exit_1(tmp_path, capsys,
                                                                          storage):
    """The image topic was recorded but holds no message: not a replay of 0 frames that exits
    0, but one line naming the topic and what the bag has; no output is written."""
    in_bag = write_bag(tmp_path / 'in', storage, [
        ('/cam/image_raw', IMAGE, T0, None),
        ('/ground_truth/odom', ODOM, T0, odometry_msg(T0, 0.0))])
    assert main(['replay', str(in_bag), '--out', str(tmp_path / 'out'), '--no-progress']) == 1
    assert capsys.readouterr().err == (
        f"planar_vo replay: error: --image-topic: '/cam/image_raw' in '{in_bag}' has no messages; "
        f'messages per topic: /cam/image_raw (sensor_msgs/msg/Image): 0, /ground_truth/odom '
        f'(nav_msgs/msg/Odometry): 1\n')
    assert list(tmp_path.iterdir()) == [in_bag]


def test_replay_logs_the_first_bad_image_and_camera_info_and_counts_them_all(tmp_path, rng,
                                                                             caplog):
    """From frame 2 on, images in an encoding planar_vo cannot read and CameraInfo with K all
    zeros: one warning of each kind (not one per message), every one counted."""
    gray = rng.integers(0, 256, (24, 32), dtype=np.uint8)
    entries = []
    for i in range(20):
        stamp = T0 + i * 100_000_000
        entries.append(('/cam/camera_info', INFO, stamp, camera_info_msg(
            stamp, 32, 24, 30.0, k=None if i < 2 else np.zeros((3, 3)))))
        entries.append(('/cam/image_raw', IMAGE, stamp + 1,
                        image_msg(gray, 'mono8' if i < 2 else 'yuv422', stamp)))
    in_bag = write_bag(tmp_path / 'in', 'mcap', entries)
    with caplog.at_level('WARNING', logger='planar_vo'):
        summary = replay_bag(in_bag, tmp_path / 'out', ConstantVelocityDouble(), progress=False)
    assert (summary.frames_in, summary.odometry_out, summary.origins) == (20, 2, 1)
    assert summary.dropped == {'bad_image': 18}
    assert summary.camera_info_errors == 18
    stamp = T0 + 200_000_000
    assert [r.getMessage() for r in caplog.records] == [
        f'ignoring camera_info at {stamp} ns: camera_info: K is all zeros (uncalibrated camera); '
        f'set the camera.fx/fy/cx/cy parameters or enable camera.estimate_focal (further bad '
        f'camera_info messages are counted, not logged)',
        f"frame 2 ({stamp} ns) dropped, bad_image: image.encoding: expected one of ['mono8', "
        f"'8UC1', 'mono16', '16UC1', 'rgb8', 'bgr8', 'rgba8', 'bgra8'], got 'yuv422' (further "
        f'bad_image frames are counted in the summary)']


def test_replay_counts_a_decompression_bomb_as_a_bad_image(tmp_path, rng):
    """A 389 KB PNG declaring 20000x20000 pixels is refused from its header: a counted
    bad_image, and the frames around it go on."""
    ok, png = cv2.imencode('.png', rng.integers(0, 256, (24, 32), dtype=np.uint8))
    frames = [png.tobytes(), png.tobytes(), zero_png(20000, 20000), png.tobytes()]
    stamps = [T0 + i * 100_000_000 for i in range(len(frames))]
    in_bag = write_bag(tmp_path / 'in', 'mcap', [
        ('/cam/image_raw/compressed', 'sensor_msgs/msg/CompressedImage', stamp,
         compressed_msg(data, 'png', stamp)) for stamp, data in zip(stamps, frames)])
    double = ConstantVelocityDouble()
    summary = replay_bag(in_bag, tmp_path / 'out', double, progress=False)
    assert summary.frames_in == 4 and summary.odometry_out == 3 and summary.origins == 1
    assert summary.dropped == {'bad_image': 1}
    assert [c[0] for c in double.calls] == [stamps[i] / 1_000_000_000 for i in (0, 1, 3)]


def test_frames_without_camera_info_topic_have_no_camera(tmp_path, rng):
    img = rng.integers(0, 256, (4, 5), dtype=np.uint8)
    bag_dir = write_bag(tmp_path / 'nocam', 'sqlite3', [('/img', IMAGE, 1, image_msg(img, 'mono8',
                                                                                     1))])
    with open_bag(bag_dir) as bag:
        (frame,) = iter_camera_frames(bag)
    assert frame.camera is None and frame.camera_error is None
    np.testing.assert_array_equal(frame.image, img)


def test_storage_file_suffixes(small_bag):
    """A bag copied as a single file opens like its directory."""
    bag_dir, frames = small_bag('sqlite3')
    single = bag_dir.parent / 'copy.db3'
    shutil.copy(storage_file(bag_dir), single)
    with open_bag(single) as bag:
        assert stamp_to_ns(next(iter_messages(bag, '/cam/image_raw')).msg.header.stamp) == T0


@pytest.mark.parametrize('storage', STORAGES)
def test_messages_the_index_counts_but_reading_skips_are_counted(tmp_path, rng, storage, caplog):
    """A damaged MCAP chunk is skipped by the reader without an error (a user test: an image
    lost unsaid, 'dropped 0'). Here the bag's index (metadata.yaml) counts two images and one
    ground-truth message more than its storage holds: replay counts the images as
    'unreadable' frames, names every topic's loss, and eval warns about its topic's."""
    gt = (lambda i, stamp: ('/ground_truth/odom', ODOM, stamp + 1, odometry_msg(stamp, 0.1 * i)))
    in_bag, _ = _big_image_bag(tmp_path / 'in', storage, rng, n=8, extra=(gt,))
    meta = in_bag / 'metadata.yaml'
    info = yaml.safe_load(meta.read_text())
    for entry in info['rosbag2_bagfile_information']['topics_with_message_count']:
        assert entry['message_count'] == 8
        entry['message_count'] += 2 if entry['topic_metadata']['name'] == '/cam/image_raw' else 1
    meta.write_text(yaml.safe_dump(info))
    with open_bag(in_bag) as bag:
        counts = {t: bag.count(t) for t in bag.topics}
        assert {t: n - len(list(bag.messages([t]))) for t, n in counts.items()} == bag.unread
    assert sorted(bag.unread.values()) == [1, 2]
    summary = replay_bag(in_bag, tmp_path / 'out', ConstantVelocityDouble(), progress=False)
    lost = bag.unread['/cam/image_raw']
    assert summary.frames_in == counts['/cam/image_raw'] == 8 + lost
    assert summary.dropped == {'unreadable': lost} and summary.odometry_out == 8
    assert summary.unreadable == bag.unread
    text = summary.format()
    assert f'  dropped            {lost} (unreadable {lost})\n' in text
    other = next(t for t in bag.unread if t != '/cam/image_raw')
    assert (f'  unreadable         {" ".join(f"{t} {bag.unread[t]}," for t in sorted(bag.unread))}'
            .rstrip(',') + " (counted by the bag's metadata, not read: damaged storage, or a "
            'metadata.yaml that counts too many)'
            ) in text
    assert 'unreadable (damaged storage' in caplog.text and other in caplog.text
    caplog.clear()
    from planar_vo.tools.evaluation import load_trajectory
    load_trajectory(in_bag, other)
    assert (f"topic '{other}' in '{in_bag}': {bag.unread[other]} of its "
            f'{counts[other]} messages could not be read') in caplog.text


def test_an_input_topic_named_like_the_output_is_said_not_copied(tmp_path, rng, caplog):
    """A vehicle bag's wheel odometry on /odom (a user test: it vanished from the output
    without a word): said, and odom_topic (replay --odom-topic) names the output otherwise."""
    wheel = (lambda i, stamp: ('/odom', ODOM, stamp + 1, odometry_msg(stamp, 0.1 * i)))
    in_bag, _ = _big_image_bag(tmp_path / 'in', 'mcap', rng, n=5, extra=(wheel,))
    with caplog.at_level('WARNING', logger='planar_vo.tools.replay'):
        summary = replay_bag(in_bag, tmp_path / 'out', ConstantVelocityDouble(), progress=False)
    assert summary.not_copied == '/odom' and summary.copied == {}
    assert ("  copied             none; not /odom (the output odometry's topic: --odom-topic "
            'names another)\n') in summary.format()
    assert "input topic /odom not copied: it is the output odometry's topic" in caplog.text
    summary = replay_bag(in_bag, tmp_path / 'out2', ConstantVelocityDouble(), progress=False,
                         odom_topic='/vo/odom')
    assert summary.not_copied == '' and summary.copied == {'/odom': 5}
    assert len(_read_odometry(tmp_path / 'out2', '/vo/odom')) == 5
    assert len(_read_odometry(tmp_path / 'out2', '/odom')) == 5


def test_cli_replay_of_a_bag_corrupt_mid_way_prints_what_it_replayed(tmp_path, rng, capsys):
    in_bag, images = _big_image_bag(tmp_path / 'in', 'mcap', rng)
    corrupt_mid_way(in_bag, images[25][120].tobytes())
    assert main(['replay', str(in_bag), '--out', str(tmp_path / 'out'), '--no-progress',
                 '--set', 'camera.fx=300']) == 1
    captured = capsys.readouterr()
    assert captured.out.startswith(f'replay {in_bag} -> {tmp_path / "out"} (until the error '
                                   f'below)\n')
    frames = int(re.search(r'frames in +(\d+)', captured.out).group(1))
    assert 5 <= frames < 40
    # Every line of it describes the replay so far (a review: 'wall time 0.00 s', 'throughput
    # nan' and 'camera unknown' beside the counts).
    assert 'nan' not in captured.out and 'wall time          0.00 s' not in captured.out
    assert 'camera             focal length 300.0 px (configured)' in captured.out
    assert 'corrupt or truncated, reading failed after' in captured.err


def test_a_looped_bag_gives_a_tum_file_of_its_last_time_base(tmp_path, rng):
    """A user test: replay --tum of a drive followed by itself (the same stamps again) failed
    at the end on the repeated stamps, without a summary; a TUM file holds one time base."""
    in_bag, _ = _big_image_bag(tmp_path / 'in', 'mcap', rng, n=5)
    looped = tmp_path / 'looped'
    with open_bag(in_bag) as bag:
        messages = [(m.topic, m.log_time_ns, bag.deserialize(m)) for m in
                    bag.messages(['/cam/image_raw'])]
    write_bag(looped, 'mcap', [(t, IMAGE, log + k * 10**10, msg) for k in (0, 1)
                               for t, log, msg in messages])
    summary = replay_bag(looped, tmp_path / 'out', ConstantVelocityDouble(), progress=False,
                         tum_path=tmp_path / 'vo.tum')
    assert summary.odometry_out == 10
    assert summary.format().splitlines()[-1] == (
        f"  TUM trajectory     {tmp_path / 'vo.tum'} (the 5 poses after the stamps last jumped "
        f'back; the bag holds all 10)')
    assert read_tum(tmp_path / 'vo.tum').stamps_ns.tolist() == \
        [T0 + i * 100_000_000 for i in range(5)]
