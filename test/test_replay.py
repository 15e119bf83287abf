"""End to end: a rendered drive recorded as a bag (both storages), replayed, evaluated, and read
by evo."""

from __future__ import annotations

import json
import re
import signal

import numpy as np
import pytest
from disk_tools import partial_leftovers, run_planar_vo, stop_after_odometry
from evo_tools import evo_ape_stats, run_evo

from planar_vo.cli import main
from planar_vo.config import MountConfig
from planar_vo.core.camera import CameraModel
from planar_vo.io import iter_messages, open_bag
from planar_vo.sim import straight, turn
from planar_vo.tools.demo import run_demo
from planar_vo.tools.evaluation import load_trajectory, read_tum
from planar_vo.tools.record import record_drive

CAMERA = CameraModel.pinhole(640, 480, 500.0)


@pytest.fixture(scope='module')
def drive_bags(tmp_path_factory):
    """The same short drive (straight, then a left turn) as an MCAP and a sqlite3 bag."""
    trajectory = straight(10.0, speed=8.0).then(turn(np.pi / 4, radius=15.0, speed=6.0))
    root = tmp_path_factory.mktemp('drives')
    bags = {storage: record_drive(root / storage, trajectory, camera=CAMERA,
                                  mount=MountConfig(height=1.5), seed=4, storage=storage).path
            for storage in ('mcap', 'sqlite3')}
    return trajectory, bags


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_replay_evaluate_and_evo(tmp_path, capsys, drive_bags, evo_env, storage):
    trajectory, bags = drive_bags
    out, tum, report = tmp_path / 'vo', tmp_path / 'vo.tum', tmp_path / 'eval'
    assert main(['replay', str(bags[storage]), '--out', str(out), '--tum', str(tum),
                 '--storage', storage, '--no-progress']) == 0
    text = capsys.readouterr().out
    frames = len(trajectory)
    assert f'frames in          {frames}' in text
    # The first frame's odometry is the origin (it sets odom); it is no drop.
    assert f'odometry out       {frames} (the first frame\'s among them, at the origin)' in text
    assert 'dropped            0 (none)' in text
    # The scale's source and the camera height it rests on (here the default: said so).
    assert "  scale              ground at the camera height 1.5 +- 0.01 m (mount.height, the " \
           "default: set the car's); too few road ACs: the road's pixels (steps up to " \
           "scale.ground_image_max_speed 70 m/s); fallback hold\n" in text
    # Every odometry message's step length has a named source; the drive's are mostly metric.
    line = next(x for x in text.splitlines() if x.startswith('  step lengths'))
    counts = dict(item.rsplit(' ', 1) for item in
                  line.split('step lengths', 1)[1].split('(')[0].strip().split(', '))
    assert sum(map(int, counts.values())) == frames - 1 and int(counts['ground']) > frames / 2
    assert '(road top-ups ' in line
    # Every odometry message carries its image's header stamp, exactly.
    with open_bag(out) as bag:
        topics = set(bag.topics)
    assert {'/odom', '/ground_truth/odom'} <= topics
    est = load_trajectory(out, '/odom')
    gt = load_trajectory(out, '/ground_truth/odom')
    np.testing.assert_array_equal(est.stamps_ns, gt.stamps_ns)
    np.testing.assert_array_equal(read_tum(tum).stamps_ns, est.stamps_ns)
    assert np.all(est.positions[0] == 0.0) and np.all(est.quaternions[0] == [0, 0, 0, 1])
    # Evaluation: accurate, and a left turn is positive yaw.
    assert main(['eval', str(out), '--out-dir', str(report)]) == 0
    metrics = json.loads((report / 'metrics.json').read_text())
    distance = metrics['path_length_m']
    assert metrics['ate_m']['rmse'] < 0.005 * distance
    assert metrics['yaw_change_error_deg']['rmse'] < 0.05
    assert all((report / f'{name}.png').stat().st_size > 10_000
               for name in ('trajectory', 'ate', 'yaw_heading'))
    yaw = 2 * np.arctan2(est.quaternions[-1, 2], est.quaternions[-1, 3])
    assert np.rad2deg(yaw) == pytest.approx(45.0, abs=0.5)
    # evo reads the odometry bag we wrote and agrees on the ATE.
    listing = run_evo(evo_env, 'evo_traj', 'bag2', str(out), '--all_topics', cwd=tmp_path)
    assert '/odom' in listing and '/ground_truth/odom' in listing
    evo = evo_ape_stats(evo_env, tmp_path, 'bag2', str(out), '/ground_truth/odom', '/odom', '-a')
    assert evo['rmse'] == pytest.approx(metrics['ate_m']['rmse'], abs=1e-6)


def test_replay_refuses_to_overwrite_and_reports_bad_input(tmp_path, capsys, drive_bags):
    _, bags = drive_bags
    (tmp_path / 'exists').mkdir()
    assert main(['replay', str(bags['mcap']), '--out', str(tmp_path / 'exists')]) == 1
    assert 'exists' in capsys.readouterr().err
    assert main(['replay', str(tmp_path / 'missing'), '--out', str(tmp_path / 'o')]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith('planar_vo replay: error:') and '\n' not in err
    # Not into the input bag's folder (eval and fleet refuse that too), however spelt.
    inner = bags['mcap'] / '..' / bags['mcap'].name / 'inner'
    storage = next(bags['mcap'].glob('*.mcap'))             # the bag by its storage file
    for given in (bags['mcap'], storage):
        assert main(['replay', str(given), '--out', str(inner)]) == 1
        assert capsys.readouterr().err == (f"planar_vo replay: error: --out: '{inner}' lies "
                                           f"inside the input bag '{given}'; choose a folder "
                                           f'outside it\n')
        assert not inner.exists()


@pytest.mark.parametrize(('options', 'message'), [
    (['--image-topic', '/nope'], "--image-topic: '/nope' is not a topic of '{bag}'"),
    (['--camera-info-topic', '/nope'], "--camera-info-topic: '/nope' is not a topic of '{bag}'"),
    (['--speed-topic', '/nope'], "--speed-topic: '/nope' is not a topic of '{bag}'"),
    (['--speed-topic', '/camera/image_raw'],
     "--speed-topic: '/camera/image_raw' in '{bag}' has type sensor_msgs/msg/Image, expected "
     'geometry_msgs/msg/TwistStamped or geometry_msgs/msg/TwistWithCovarianceStamped or '
     'nav_msgs/msg/Odometry'),
    (['--odom-topic', 'odom'], "--odom-topic: expected an absolute topic name ('/odom'), got "
                               "'odom'"),
    (['--odom-topic', ''], "--odom-topic: expected an absolute topic name ('/odom'), got ''"),
    (['--odom-topic', '/ground_truth/odom'],
     "--odom-topic: '/ground_truth/odom' is the ground truth's topic; name the odometry "
     'otherwise'),
])
def test_replay_errors_name_the_options_as_typed(tmp_path, capsys, drive_bags, options, message):
    """--image-topic, not the library's image_topic (and so on): one line, exit code 1."""
    _, bags = drive_bags
    assert main(['replay', str(bags['mcap']), '--out', str(tmp_path / 'o'), *options]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"planar_vo replay: error: {message.format(bag=bags['mcap'])}"), err
    assert err.count('\n') == 1 and not (tmp_path / 'o').exists()


def _step_sources(text: str) -> dict[str, int]:
    line = next(x for x in text.splitlines() if x.startswith('  step lengths'))
    return {k: int(v) for k, v in (item.rsplit(' ', 1) for item in
                                   line.split('step lengths', 1)[1].split('(')[0].strip()
                                   .split(', '))}


def test_replay_speed_topic_gives_the_scale(tmp_path, capsys, drive_bags):
    """--speed-topic sets scale.source: speed (the ground truth's odometry as the speed)."""
    trajectory, bags = drive_bags
    assert main(['replay', str(bags['mcap']), '--out', str(tmp_path / 'o'), '--speed-topic',
                 '/ground_truth/odom', '--no-progress']) == 0
    text = capsys.readouterr().out
    sources = _step_sources(text)
    assert sources.get('speed', 0) > len(trajectory) / 2 and 'ground' not in sources, text
    assert f'speed messages     {len(trajectory)}' in text


def test_replay_with_speed_scale_needs_a_speed_topic(tmp_path, capsys, drive_bags):
    _, bags = drive_bags
    config = tmp_path / 'speed.yaml'
    config.write_text('scale: {source: speed}\n')
    assert main(['replay', str(bags['mcap']), '--out', str(tmp_path / 'o'), '--config',
                 str(config)]) == 1
    err = capsys.readouterr().err
    assert err == ("planar_vo replay: error: scale.source: speed needs --speed-topic TOPIC (the "
                   "bag's TwistStamped or Odometry speed topic); without it no step would be "
                   'metric\n') and not (tmp_path / 'o').exists()


def test_replay_speed_topic_against_an_explicit_source_is_an_error(tmp_path, capsys,
                                                                   drive_bags):
    """--speed-topic with --set scale.source=ground: two contradicting command-line wishes;
    one line, exit 1, nothing written (the file's source is only a default it overrides)."""
    _, bags = drive_bags
    assert main(['replay', str(bags['mcap']), '--out', str(tmp_path / 'o'), '--speed-topic',
                 '/ground_truth/odom', '--set', 'scale.source=ground']) == 1
    err = capsys.readouterr().err
    assert err == ('planar_vo replay: error: --speed-topic sets scale.source: speed, but --set '
                   'gives scale.source=ground; drop one of the two (scale.fallback may name a '
                   'source for the steps without a speed)\n') and not (tmp_path / 'o').exists()


def test_replay_camera_info_topic_beside_own_intrinsics_is_an_error(
        tmp_path, capsys, drive_bags):
    """An explicit --camera-info-topic that the configuration would leave unused (the focal
    self-calibration, or camera.fx): one line, exit 1, nothing written."""
    _, bags = drive_bags
    for setting, why in (('camera.estimate_focal=true', 'camera.estimate_focal is on'),
                         ('camera.fx=480', 'camera.fx is configured (480 px)')):
        assert main(['replay', str(bags['mcap']), '--out', str(tmp_path / 'o'), '--set',
                     setting, '--camera-info-topic', '/camera/camera_info']) == 1
        assert capsys.readouterr().err == (
            f"planar_vo replay: error: --camera-info-topic: '/camera/camera_info' would not be "
            f"used: {why} (the bag's CameraInfo is then ignored, as in the node); drop one of "
            f"the two\n")
        assert not (tmp_path / 'o').exists()


def test_two_passes_use_the_whole_drives_focal_calibration_from_the_first_frame(
        tmp_path, capsys, drive_bags):
    """--two-pass (offline): the focal length self-calibrated over the whole bag is used from
    the first frame on, its uncertainty in the covariance, no pair counted twice; the one-pass
    replay runs on the wide prior (640 px for 500) until the turn."""
    trajectory, bags = drive_bags
    args = ['replay', str(bags['mcap']), '--set', 'mount.height=1.5', '--set',
            'camera.estimate_focal=true', '--no-progress']
    assert main([*args, '--out', str(tmp_path / 'one')]) == 0
    one = capsys.readouterr().out
    assert main([*args, '--out', str(tmp_path / 'two'), '--two-pass']) == 0
    two = capsys.readouterr().out
    assert 'first pass' not in one
    assert re.search(rf'\n  first pass         {len(trajectory)} frames in [\d.]+ s: \d+ turning '
                     r'pairs profiled; the focal length they give \(the camera line\) used from '
                     r'the first frame on\n', two)
    camera = next(x for x in two.splitlines() if x.startswith('  camera      '))
    assert camera.endswith('; from a first pass over the whole recording)')
    from planar_vo.tools.provenance import bag_custom_data

    made = bag_custom_data(tmp_path / 'two')
    assert made['planar_vo.focal'] == camera.split(None, 1)[1]
    assert two.split('\n  first pass         ')[1].startswith(made['planar_vo.first_pass'])
    assert 'planar_vo.first_pass' not in bag_custom_data(tmp_path / 'one')
    errors = {}
    for name in ('one', 'two'):
        assert main(['eval', str(tmp_path / name), '--out-dir', str(tmp_path / f'{name}_ev')]) == 0
        capsys.readouterr()
        metrics = json.loads((tmp_path / f'{name}_ev' / 'metrics.json').read_text())
        errors[name] = (metrics['yaw_change_error_deg']['mean'],
                        metrics['ate_m']['rmse'] / metrics['path_length_m'])
    # (measured: mean yaw-change error 0.032 against 0.29 deg, ATE 0.7 % against 8.2 %)
    assert errors['two'][0] < 0.3 * errors['one'][0] and errors['two'][1] < 0.3 * errors['one'][1]
    # Without the focal self-calibration there is nothing for a first pass to do.
    assert main(['replay', str(bags['mcap']), '--out', str(tmp_path / 'x'), '--two-pass']) == 1
    assert capsys.readouterr().err == (
        "planar_vo replay: error: --two-pass: the first pass self-calibrates the focal length: "
        "give --set camera.estimate_focal=true (with the bag's CameraInfo, or camera.fx, there "
        'is nothing to calibrate)\n')
    assert not (tmp_path / 'x').exists()


def test_a_stop_in_the_first_pass_writes_nothing_and_says_so(tmp_path, drive_bags, monkeypatch):
    from planar_vo.config import PlanarVoConfig
    from planar_vo.pipeline import VisualOdometry
    from planar_vo.tools.replay import replay_bag

    _, bags = drive_bags
    process = VisualOdometry.process
    calls = []

    def stopped(self, *args, **kwargs):
        calls.append(1)
        if len(calls) == 5:
            raise KeyboardInterrupt('SIGINT')
        return process(self, *args, **kwargs)

    monkeypatch.setattr(VisualOdometry, 'process', stopped)
    config = PlanarVoConfig.from_flat({'camera.estimate_focal': True})
    with pytest.raises(KeyboardInterrupt) as exc:
        replay_bag(bags['mcap'], tmp_path / 'out', VisualOdometry(config), progress=False,
                   two_pass=True)
    assert exc.value.__notes__ == [
        f"in the first pass (--two-pass): nothing was written to '{tmp_path / 'out'}'"]
    assert list(tmp_path.iterdir()) == []


def test_replay_without_odometry_says_why_and_exits_1(tmp_path, capsys, drive_bags):
    """A principal point outside the image: no camera model, every frame counted, the
    summary's odometry line says why (a user test found only the counts), and the command
    fails with one line on stderr, so that `replay && eval` stops there; the bag is kept."""
    _, bags = drive_bags
    out = tmp_path / 'o'
    assert main(['replay', str(bags['mcap']), '--out', str(out), '--set',
                 'camera.fx=480', '--set', 'camera.cx=5000', '--no-progress', '--tum',
                 str(tmp_path / 'o.tum')]) == 1
    captured = capsys.readouterr()
    why = ('no_camera_info: camera.cx, camera.cy (5000; 239.5, the image centre) lie outside '
           'the 640x480 image: no camera model')
    assert f'  odometry out       0 ({why})' in captured.out, captured.out
    frames = int(captured.out.split('frames in')[1].split()[0])
    assert frames > 1
    assert captured.err == (f'planar_vo replay: error: no motion estimated from {frames} '
                            f'frame(s) ({why}); {out} holds the copied topics only; no TUM '
                            f'file was written\n')
    assert out.exists() and not (tmp_path / 'o.tum').exists()
    assert 'TUM trajectory' not in captured.out


def test_eval_of_the_camera_bag_itself_says_to_replay_it_first(capsys, drive_bags):
    """A user test: `planar_vo eval` given the camera bag (not replay's output) named only
    the missing /odom topic."""
    _, bags = drive_bags
    assert main(['eval', str(bags['mcap'])]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"planar_vo eval: error: --est-topic: '/odom' is not a topic of "
                          f"'{bags['mcap']}'; available topics: ")
    assert err.endswith(f"; EST holds images, not odometry: replay it first (planar_vo replay "
                        f"{bags['mcap']} --out ODOMETRY), then evaluate ODOMETRY\n")


def test_replay_with_the_origin_only_exits_1(tmp_path, capsys, drive_bags):
    """The first frame's odometry is the origin; when every later frame fails (here blank),
    nothing was estimated: the summary says why beside the origin, the command exits 1 and
    writes no TUM file, and the bag holds the origin's message."""
    from planar_vo.io import iter_camera_frames
    from planar_vo.io.camera_bag import CameraBagWriter

    _, bags = drive_bags
    with open_bag(bags['mcap']) as bag:
        frame = next(iter(iter_camera_frames(bag)))
    with CameraBagWriter(tmp_path / 'blank') as writer:
        writer.write_frame(frame.stamp_ns, frame.image, frame.camera)
        for i in range(1, 4):
            writer.write_frame(frame.stamp_ns + i * 100_000_000, np.zeros_like(frame.image),
                               frame.camera)
    out = tmp_path / 'o'
    assert main(['replay', str(tmp_path / 'blank'), '--out', str(out), '--no-progress',
                 '--tum', str(tmp_path / 'o.tum')]) == 1
    captured = capsys.readouterr()
    line = next(x for x in captured.out.splitlines() if x.startswith('  odometry out'))
    assert line.startswith("  odometry out       1 (the first frame's among them, at the origin; "
                           'no motion: '
                           'blank_image: '), line
    assert 'dropped            3 (blank_image 3)' in captured.out
    assert captured.err.startswith('planar_vo replay: error: no motion estimated from 4 '
                                   'frame(s) (blank_image: ')
    assert captured.err.endswith(f'; {out} holds the copied topics and 1 odometry message(s) '
                                 f'at the origin; no TUM file was written\n')
    assert not (tmp_path / 'o.tum').exists()
    est = load_trajectory(out, '/odom')
    assert est.stamps_ns.tolist() == [frame.stamp_ns] and np.all(est.positions == 0.0)


def test_replay_uses_configured_intrinsics_over_the_bags_camera_info(tmp_path, capsys,
                                                                     drive_bags):
    """As the node: camera.fx > 0 means no CameraInfo (the bag's is 500 px)."""
    _, bags = drive_bags
    config = tmp_path / 'fx.yaml'
    config.write_text('camera: {fx: 450}\n')
    assert main(['replay', str(bags['mcap']), '--out', str(tmp_path / 'o'), '--config',
                 str(config), '--no-progress']) == 0
    text = capsys.readouterr().out
    assert '(camera info: /camera/camera_info not used: camera.fx is configured (450 px), ' \
           'speed: none)' in text
    assert 'camera             focal length 450.0 px (configured)' in text
    assert main(['replay', str(bags['mcap']), '--out', str(tmp_path / 'o2'),
                 '--no-progress']) == 0
    text = capsys.readouterr().out
    assert '(camera info: /camera/camera_info, speed: none)' in text
    assert 'focal length 500.0 px (CameraInfo)' in text


def test_replay_set_overrides_the_configuration(tmp_path, capsys, drive_bags):
    """--set KEY=VALUE over the file (the camera height without writing a YAML file); one value
    each; unknown keys and refused values are one line."""
    _, bags = drive_bags
    config = tmp_path / 'fx.yaml'
    config.write_text('camera: {fx: 450}\n')
    assert main(['replay', str(bags['mcap']), '--out', str(tmp_path / 'o'), '--config',
                 str(config), '--set', 'camera.fx=500', '--no-progress']) == 0
    assert 'focal length 500.0 px (configured)' in capsys.readouterr().out
    for item, message in (
            ('mount.height=1.5,1.6', "set: 'mount.height=1.5,1.6': expected one value (one --set "
                                     'per key: a replay runs one configuration; planar_vo fleet '
                                     'run takes several)'),
            ('mount.height', "set: expected KEY=VALUE, got 'mount.height'"),
            ('mount.hieght=1.6', "set: unknown configuration key 'mount.hieght'; did you mean "
                                 'mount.height, mount.height_std, mount.pitch?'),
            ('mount.height=-1', 'set: mount.height: expected a height above the ground of '
                                '0.01-100 m, got -1'),
            ('mount.height=1.6 --set mount.height=1.7',
             "set: 'mount.height' given twice; give it once")):
        sets = [arg for part in item.split(' --set ') for arg in ('--set', part)]
        assert main(['replay', str(bags['mcap']), '--out', str(tmp_path / 'x'), *sets]) == 1
        err = capsys.readouterr().err
        assert err.startswith(f'planar_vo replay: error: --{message}') and err.count('\n') == 1, err
    assert not (tmp_path / 'x').exists()
    # The file and the sets are validated together (a user test: a file's camera.fy, valid
    # with the --set camera.fx, was refused on its own); what neither fixes names both.
    config.write_text('camera: {fy: 455}\n')
    assert main(['replay', str(bags['mcap']), '--out', str(tmp_path / 'o2'), '--config',
                 str(config), '--set', 'camera.fx=450', '--no-progress']) == 0
    assert 'focal length 450.0 px (configured)' in capsys.readouterr().out
    # A refusal names its cause: the file (whatever the sets), or the set (a valid file).
    assert main(['replay', str(bags['mcap']), '--out', str(tmp_path / 'x'), '--config',
                 str(config), '--set', 'mount.height=1.6']) == 1
    assert capsys.readouterr().err == (
        f'planar_vo replay: error: {config}: camera.fy: expected 0 while fx is 0 (fy is used '
        f'with fx only; fx = 0 means the focal length comes from CameraInfo or estimate_focal), '
        f'got 455.0\n')
    config.write_text('camera: {fx: 450}\n')
    assert main(['replay', str(bags['mcap']), '--out', str(tmp_path / 'x'), '--config',
                 str(config), '--set', 'mount.height=-1']) == 1
    assert capsys.readouterr().err.startswith('planar_vo replay: error: --set: mount.height: '
                                              'expected a height above the ground')
    # The file named as typed (a review: './x.yaml' was reported as 'x.yaml')
    missing = f'./{tmp_path.name}_missing.yaml'
    assert main(['replay', str(bags['mcap']), '--out', str(tmp_path / 'x'), '--config', missing,
                 '--set', 'mount.height=1.6']) == 1
    assert capsys.readouterr().err == (f'planar_vo replay: error: {missing}: cannot read '
                                       f'configuration (No such file or directory)\n')


def test_replay_says_which_node_settings_it_does_not_use(tmp_path, caplog, drive_bags):
    """--set ros.publish_tf (the node's) was dropped without a word; the frame ids are used."""
    _, bags = drive_bags
    with caplog.at_level('WARNING', logger='planar_vo'):
        assert main(['replay', str(bags['mcap']), '--out', str(tmp_path / 'o'), '--no-progress',
                     '--set', 'ros.publish_tf=false', '--set', 'ros.odom_frame=map']) == 0
    assert [r.getMessage() for r in caplog.records if '--set' in r.getMessage()] == [
        '--set ros.publish_tf: a setting of the ROS node; replay does not use it (of ros.* only '
        'ros.odom_frame and ros.base_frame)']
    with open_bag(tmp_path / 'o') as bag:
        assert next(iter_messages(bag, '/odom')).msg.header.frame_id == 'map'


def test_replay_names_its_input_as_typed(tmp_path, capsys):
    """IN, as in the usage line (was the library's 'bag')."""
    assert main(['replay', str(tmp_path / 'missing'), '--out', str(tmp_path / 'o')]) == 1
    assert capsys.readouterr().err == (f"planar_vo replay: error: IN: '{tmp_path / 'missing'}' "
                                       f'does not exist\n')


def test_replay_says_once_why_frames_are_dropped(tmp_path, caplog, drive_bags):
    """A camera model whose size is not the images' (configured for another resolution): every
    frame is dropped, as without usable intrinsics (a user test: counted as size changes of
    every frame); the first drop of the kind says why, the summary counts them all."""
    from planar_vo.config import PlanarVoConfig
    from planar_vo.pipeline import VisualOdometry
    from planar_vo.tools.replay import replay_bag

    _, bags = drive_bags
    config = PlanarVoConfig.from_flat({'camera.fx': 700.0, 'camera.cx': 612.0,
                                       'camera.cy': 185.0, 'mount.height': 1.5})
    wrong = CameraModel.pinhole(1226, 370, 700.0)

    class OtherCamera(VisualOdometry):
        def process(self, image, stamp, camera=None):
            return super().process(image, stamp, wrong)

    with caplog.at_level('WARNING', logger='planar_vo.tools.replay'):
        summary = replay_bag(bags['mcap'], tmp_path / 'o', OtherCamera(config), progress=False)
    text = summary.format()
    n = summary.frames_in
    why = ('no_camera_info: the camera model (CameraInfo) is 1226x370 but the image is '
           '640x480: intrinsics of another camera or resolution')
    assert n > 1 and f'  dropped            {n} (no_camera_info {n})' in text      # all counted
    assert f'odometry out       0 ({why})' in text
    lines = [r.getMessage() for r in caplog.records if 'dropped' in r.getMessage()]
    assert len(lines) == 1 and why in lines[0]


def test_replay_tells_apart_frames_stamped_1_ns_apart(tmp_path, drive_bags):
    """The drive's first frames stamped 1 ns apart (the same float seconds at 1.7e9 s): the
    stamps are the bag's integer nanoseconds, so none is a duplicate_stamp; each frame gets its
    odometry, stamped exactly."""
    from planar_vo.config import PlanarVoConfig
    from planar_vo.io import iter_camera_frames
    from planar_vo.io.camera_bag import CameraBagWriter
    from planar_vo.pipeline import VisualOdometry
    from planar_vo.tools.replay import replay_bag

    _, bags = drive_bags
    with open_bag(bags['mcap']) as bag:
        frames = list(iter_camera_frames(bag))[:6]
    t0 = 1_700_000_000 * 10**9
    with CameraBagWriter(tmp_path / 'ns') as writer:
        for i, frame in enumerate(frames):
            writer.write_frame(t0 + i, frame.image, frame.camera)
    config = PlanarVoConfig.from_flat({'mount.height': 1.5})
    summary = replay_bag(tmp_path / 'ns', tmp_path / 'vo', VisualOdometry(config),
                         progress=False)
    assert summary.dropped == {} and summary.odometry_out == 6
    assert summary.origins == 1 and summary.motion_out == 5
    assert load_trajectory(tmp_path / 'vo', '/odom').stamps_ns.tolist() == \
        [t0 + i for i in range(6)]


def test_replay_counts_the_frames_missing_from_the_stamps(tmp_path, caplog, drive_bags):
    """Frames lost before the recording show as gaps in the stamps, counted as the node counts
    them (a user test: the summary said nothing of them)."""
    from planar_vo.config import PlanarVoConfig
    from planar_vo.io import iter_camera_frames
    from planar_vo.io.camera_bag import CameraBagWriter
    from planar_vo.pipeline import VisualOdometry
    from planar_vo.tools.replay import replay_bag

    _, bags = drive_bags
    with open_bag(bags['mcap']) as bag:
        frames = list(iter_camera_frames(bag))[:14]
    with CameraBagWriter(tmp_path / 'gaps') as writer:
        for i, frame in enumerate(frames):
            if i not in (4, 9, 10):
                writer.write_frame(frame.stamp_ns, frame.image, frame.camera)
    config = PlanarVoConfig.from_flat({'mount.height': 1.5})
    with caplog.at_level('WARNING', logger='planar_vo.tools.replay'):
        summary = replay_bag(tmp_path / 'gaps', tmp_path / 'vo', VisualOdometry(config),
                             progress=False)
    assert (summary.frames_in, summary.gaps, summary.missing_frames) == (11, 2, 3)
    assert '  frames in          11 (3 frames missing in 2 gaps of the stamps)\n' in \
        summary.format()
    lines = [r.getMessage() for r in caplog.records if 'gap of' in r.getMessage()]
    assert len(lines) == 1 and lines[0].startswith('frame 4 (') and \
        'a gap of 200 ms in the image stamps (about 1 frame missing at 10.0 Hz' in lines[0]


def test_replay_of_rectified_images_uses_the_projection(tmp_path, capsys, drive_bags):
    """camera.rectified: CameraInfo's P is the model (the drive's frames, rendered through K,
    written with a P of another focal length: only the switch makes the replay use it)."""
    from planar_vo.io import iter_camera_frames
    from planar_vo.io.camera_bag import CameraBagWriter

    _, bags = drive_bags
    with open_bag(bags['mcap']) as bag:
        frames = list(iter_camera_frames(bag))[:4]
    camera = frames[0].camera
    P = np.hstack([camera.K, np.zeros((3, 1))])
    P[0, 0] = P[1, 1] = 1.25 * camera.fx
    with CameraBagWriter(tmp_path / 'rect') as writer:
        for frame in frames:
            writer.write_frame(frame.stamp_ns, frame.image, camera, projection=P)
    for rectified, fx in (('false', camera.fx), ('true', 1.25 * camera.fx)):
        assert main(['replay', str(tmp_path / 'rect'), '--out', str(tmp_path / rectified),
                     '--set', f'camera.rectified={rectified}', '--no-progress']) == 0
        assert f'focal length {fx:.1f} px (CameraInfo)' in capsys.readouterr().out


def test_replay_checks_the_tum_path_before_replaying(tmp_path, capsys, drive_bags):
    _, bags = drive_bags
    out = tmp_path / 'o'
    assert main(['replay', str(bags['mcap']), '--out', str(out), '--tum',
                 str(tmp_path / 'missing' / 'x.tum')]) == 1
    err = capsys.readouterr().err.strip()
    assert err == (f"planar_vo replay: error: --tum: cannot write "
                   f"'{tmp_path / 'missing' / 'x.tum'}'"
                   f" (its folder '{tmp_path / 'missing'}' does not exist or is not writable)")
    assert not out.exists()
    assert main(['replay', str(bags['mcap']), '--out', str(out), '--tum', str(out)]) == 1
    assert "is also the output bag's path" in capsys.readouterr().err
    assert not out.exists()


def test_demo_writes_everything(tmp_path):
    result = run_demo(tmp_path / 'demo', frames=25, progress=False, log=lambda *_: None)
    for name in ('drive', 'odometry', 'tum', 'metrics', 'trajectory', 'ate', 'yaw_heading'):
        assert result.files[name].exists(), name
    assert result.frames == 25
    assert result.metrics['ate_m']['rmse'] < 0.01 * result.distance
    # A second run replaces its own folder, but never a folder it did not write.
    run_demo(tmp_path / 'demo', frames=5, progress=False, log=lambda *_: None)
    other = tmp_path / 'mine'
    other.mkdir()
    with pytest.raises(Exception, match=r"'.*mine' exists and is not a demo folder"):
        run_demo(other, frames=5, progress=False, log=lambda *_: None)


@pytest.mark.parametrize('signum', [signal.SIGTERM, signal.SIGINT])
def test_replay_stopped_by_a_signal_keeps_a_complete_bag_and_tum(tmp_path, drive_bags, signum):
    """A supervisor's SIGTERM is handled like Ctrl-C: the odometry written so far is a complete
    bag, the TUM file holds the same poses, and one line says so."""
    trajectory, bags = drive_bags
    out, tum, log = tmp_path / 'vo', tmp_path / 'vo.tum', tmp_path / 'stderr.txt'
    assert stop_after_odometry(['replay', bags['mcap'], '--out', out, '--tum', tum], log, 5,
                               signum) == 128 + signum
    last = log.read_text().splitlines()[-1]
    match = re.fullmatch(rf"planar_vo replay: interrupted by {signum.name}; kept '{out}', a "
                         rf"complete bag with messages /odom: (\d+), /ground_truth/odom: (\d+); "
                         rf"wrote '{tum}' with the (\d+) poses computed", last)
    assert match, last
    kept, gt, poses = map(int, match.groups())
    assert 5 <= kept == poses < len(trajectory) - 1 and gt >= kept
    assert 'Traceback' not in log.read_text()
    est = load_trajectory(out, '/odom')
    assert len(est) == kept and len(load_trajectory(out, '/ground_truth/odom')) == gt
    np.testing.assert_array_equal(read_tum(tum).stamps_ns, est.stamps_ns)
    assert partial_leftovers(tmp_path) == []


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_replay_on_a_full_disk_removes_the_bag_and_says_what_was_kept(
        tmp_path, drive_bags, storage):
    """A disk of a few KiB: the odometry bag cannot be finished (MCAP, written at close) or
    written (sqlite3, which needs 28 KiB for its schema). It is removed rather than left broken
    or reported as kept; the TUM file, written after the bag freed its space, holds the poses
    computed."""
    _, bags = drive_bags
    disk = tmp_path / 'disk'
    run = run_planar_vo(['replay', bags['mcap'], '--out', disk / 'vo', '--tum', disk / 'vo.tum',
                         '--storage', storage, '--no-progress'], disk=disk,
                        keep=tmp_path / 'kept', size_kib={'mcap': 16, 'sqlite3': 48}[storage])
    assert run.returncode == 1 and run.stdout == ''
    line = run.stderr.rstrip('\n')
    assert '\n' not in line and line.startswith('planar_vo replay: error: --out: '), run.stderr
    assert f"nothing was kept at '{disk / 'vo'}'" in line
    assert not (tmp_path / 'kept' / 'vo').exists()
    assert partial_leftovers(tmp_path / 'kept') == []
    # The line says what became of the TUM file, and it is so.
    poses = re.search(rf"; wrote '{disk / 'vo.tum'}' with the (\d+) poses computed$", line)
    if poses:
        assert len(read_tum(tmp_path / 'kept' / 'vo.tum')) == int(poses.group(1)) > 0
    else:
        assert line.endswith(f"no motion was estimated; '{disk / 'vo.tum'}' was not written") \
            or f"tum: cannot write '{disk / 'vo.tum'}'" in line
        assert not (tmp_path / 'kept' / 'vo.tum').exists()


def test_demo_stopped_by_sigterm_lists_what_its_folder_holds(tmp_path):
    out, log = tmp_path / 'demo', tmp_path / 'stderr.txt'
    assert stop_after_odometry(['demo', '--out', out, '--frames', 30, '--no-progress'], log, 3,
                               signal.SIGTERM) == 143
    last = log.read_text().splitlines()[-1]
    match = re.fullmatch(rf"planar_vo demo: interrupted by SIGTERM; kept '{out}/odometry', a "
                         rf"complete bag with messages /odom: (\d+), /ground_truth/odom: \d+; "
                         rf"wrote '{out}/odometry\.tum' with the (\d+) poses computed; '{out}' "
                         rf"holds: drive, odometry, odometry\.tum", last)
    assert match and match.group(1) == match.group(2), last
    assert len(load_trajectory(out / 'drive', '/ground_truth/odom')) == 30     # complete
    assert len(read_tum(out / 'odometry.tum')) == int(match.group(1))
    assert partial_leftovers(tmp_path) == []


def test_the_odometry_bag_and_the_evaluation_say_what_made_them(tmp_path, capsys, drive_bags,
                                                                monkeypatch):
    """A user test: an odometry bag evaluated later could not be traced to the camera height it
    ran with, and metrics.json's paths were relative to wherever eval ran."""
    import planar_vo
    from planar_vo.tools.provenance import bag_custom_data, code_digest

    _, bags = drive_bags
    monkeypatch.chdir(tmp_path)
    assert main(['replay', str(bags['mcap']), '--out', 'vo', '--no-progress',
                 '--set', 'mount.height=1.5', '--set', 'voting.bins=360']) == 0
    made = bag_custom_data(tmp_path / 'vo')
    assert made == {'planar_vo.version': planar_vo.__version__,
                    'planar_vo.source_digest': code_digest(),
                    'planar_vo.settings': '{"voting.bins": 360}',   # 1.5 m is the default
                    'planar_vo.input': str(bags['mcap'].resolve()),
                    'planar_vo.odom_topic': '/odom',
                    # the focal length the odometry ended on (a user test: in the summary only)
                    'planar_vo.focal': f'focal length {CAMERA.fx:.1f} px (CameraInfo)'}
    assert main(['eval', 'vo', '--out-dir', 'report']) == 0
    capsys.readouterr()
    metrics = json.loads((tmp_path / 'report' / 'metrics.json').read_text())
    assert metrics['estimate'] == metrics['reference'] == str(tmp_path / 'vo')
    assert metrics['estimate_made_by'] == made
    assert metrics['evaluated_by'] == {k: made[k] for k in ('planar_vo.version',
                                                            'planar_vo.source_digest')}
    # The odometry under another name is the one eval scores (a user test: it scored the copied
    # /odom of the input, perfectly).
    assert main(['replay', str(bags['mcap']), '--out', 'vo2', '--no-progress',
                 '--odom-topic', '/vo/odom']) == 0
    assert main(['eval', 'vo2']) == 0
    assert 'estimate: vo2 (/vo/odom)\n' in capsys.readouterr().out


def test_summary_counts_the_steps_measured_on_the_road_pixels():
    """The step-lengths line names the steps the road's pixels measured (none: not said)."""
    from planar_vo.tools.replay import ReplaySummary

    summary = ReplaySummary('in', 'out', frames_in=20, odometry_out=19,
                            scale_sources={'ground': 18}, road_top_ups=7, image_road_steps=5)
    line = next(x for x in summary.format().splitlines() if x.startswith('  step lengths'))
    assert line.endswith("ground 18 (road top-ups 7; 5 ground steps from the road's pixels)"), \
        line
    summary.image_road_misses = {'the best step is the longest searched (# m of #-# m)': 2,
                                 'no clear best step (contrast #)': 1}
    line = next(x for x in summary.format().splitlines() if x.startswith('  step lengths'))
    assert line.endswith("; 3 scans of the road's pixels found no step, most often (2): the "
                         "best step is the longest searched (# m of #-# m))"), line
    # A reason is shown as first said when the processor kept it.
    summary.image_road_examples = {
        'the best step is the longest searched (# m of #-# m)':
            'the best step is the longest searched (6.98 m of 0-7 m)'}
    line = next(x for x in summary.format().splitlines() if x.startswith('  step lengths'))
    assert line.endswith('most often (2): the best step is the longest searched (6.98 m of '
                         '0-7 m))'), line
    summary.image_road_steps, summary.image_road_misses = 1, {}
    line = next(x for x in summary.format().splitlines() if x.startswith('  step lengths'))
    assert line.endswith("(road top-ups 7; 1 ground step from the road's pixels)"), line
    summary.image_road_steps = 0
    line = next(x for x in summary.format().splitlines() if x.startswith('  step lengths'))
    assert line.endswith('ground 18 (road top-ups 7)'), line
