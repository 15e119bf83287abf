"""``planar_vo replay``: run the visual odometry over a bag offline, odometry into a new bag.

Reads the images (raw or compressed) and camera info of IN, feeds them with the optional speed
topic through ``planar_vo.pipeline.VisualOdometry``, and writes ``nav_msgs/Odometry`` on /odom
(stamped with each image's header stamp) into OUT together with the ground-truth topics of IN
(Odometry, Path, TF, poses), ready for ``planar_vo eval OUT``; the first frame's odometry is
the origin. Exit code 1, after the summary, when no frame gave a motion (the summary's odometry
line says why; OUT is kept).
"""

from __future__ import annotations

import argparse
import logging
import sys

from planar_vo.cli import Once

STORAGES = ('mcap', 'sqlite3')       # planar_vo.io.writer.STORAGES (rosbags not imported here)
# The node's settings (ros.*) that replay uses: the frame ids of the odometry it writes.
REPLAY_ROS_KEYS = ('ros.odom_frame', 'ros.base_frame')

EXAMPLES = """examples:
  planar_vo replay drive.mcap --out drive_vo --set mount.height=1.65
  planar_vo replay drive_bag --out drive_vo --image-topic /cam/image_raw/compressed \\
      --speed-topic /vehicle/twist --tum drive_vo.tum --config config/planar_vo.yaml
  planar_vo replay dashcam --out dashcam_vo --set camera.estimate_focal=true --two-pass
  planar_vo eval drive_vo --out-dir drive_eval
"""


def register(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        'replay', help='run the visual odometry over a bag, odometry into a new bag',
        description=__doc__, epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    # dest 'bag': planar_vo.io.reader's name for it in errors ('bag: ...' becomes 'IN: ...').
    parser.add_argument('bag', metavar='IN', help='input bag (directory, .mcap or .db3)')
    parser.add_argument('--out', required=True, metavar='OUT',
                        help='output bag directory (must not exist)')
    parser.add_argument('--image-topic', metavar='TOPIC',
                        help='sensor_msgs/Image or CompressedImage topic (default: the only one)')
    parser.add_argument('--camera-info-topic', metavar='TOPIC',
                        help='sensor_msgs/CameraInfo topic (default: the only one, if any)')
    parser.add_argument('--speed-topic', metavar='TOPIC',
                        help='TwistStamped or Odometry topic giving the speed for metric scale '
                             '(sets scale.source: speed; required with scale.source: speed)')
    parser.add_argument('--odom-topic', default='/odom', metavar='TOPIC',
                        help='the output odometry topic (default: /odom; an input topic of that '
                             'name, wheel odometry say, is then not copied)')
    parser.add_argument('--tum', metavar='FILE', help='also write the odometry as a TUM file')
    parser.add_argument('--config', metavar='YAML', action=Once,
                        help='configuration file (default: built-in defaults, as in '
                             'config/planar_vo.yaml)')
    parser.add_argument('--set', action='append', default=[], metavar='KEY=VALUE',
                        help='a configuration value by dotted key, over the file '
                             '(mount.height=1.65); repeatable')
    parser.add_argument('--storage', choices=list(STORAGES), default='mcap',
                        help='output storage format (default: mcap)')
    parser.add_argument('--two-pass', action='store_true',
                        help='with camera.estimate_focal: a first pass over the whole bag '
                             'self-calibrates the focal length, and the odometry written is a '
                             'second pass using it (and its uncertainty) from the first frame '
                             'on (offline only: the node calibrates as it drives)')
    parser.add_argument('--no-progress', action='store_true', help='no progress bar')
    parser.set_defaults(run=run)
    return parser


def run(args: argparse.Namespace) -> int:
    from planar_vo.cli import print_final, show_progress
    from planar_vo.errors import BagError
    from planar_vo.pipeline import VisualOdometry
    from planar_vo.tools.replay import replay_bag

    config = speed_scale(with_sets(args.config, args.set), args.speed_topic, args.set)
    for item in args.set:
        key = item.partition('=')[0].strip()
        if key.startswith('ros.') and key not in REPLAY_ROS_KEYS:
            # The node's interface (a user's --set would otherwise be dropped without a word).
            logging.getLogger('planar_vo').warning(
                '--set %s: a setting of the ROS node; replay does not use it (of ros.* only %s)',
                key, ' and '.join(REPLAY_ROS_KEYS))
    try:
        summary = replay_bag(
            args.bag, args.out, VisualOdometry(config), image_topic=args.image_topic,
            camera_info_topic=args.camera_info_topic, speed_topic=args.speed_topic,
            tum_path=args.tum, storage=args.storage, odom_topic=args.odom_topic,
            odom_frame=config.ros.odom_frame,
            base_frame=config.ros.base_frame, progress=show_progress(args),
            two_pass=args.two_pass)
    except BagError as err:
        partial = getattr(err, 'replay_summary', None)
        if partial is not None and partial.frames_in:
            # The counts of the frames replayed before the bag failed (the error follows).
            print(partial.format().replace('\n', ' (until the error below)\n', 1))
        raise
    print_final(summary.format())
    if summary.no_motion:
        # The output bag is complete (the summary above says what it holds), but a script that
        # chains `replay && eval` must not go on as if there were motion in it.
        holds = ('the copied topics only' if not summary.origins else
                 f'the copied topics and {summary.origins} odometry message(s) at the origin')
        tum = '; no TUM file was written' if args.tum else ''
        print(f'{args.parser.prog}: error: {summary.no_motion}; {args.out} holds {holds}{tum}',
              file=sys.stderr)
        return 1
    return 0


def speed_scale(config, speed_topic: str | None, sets=()):
    """The configuration with the scale from ``--speed-topic``: given, it sets ``scale.source:
    speed`` (the command line over the file: a speed read but unused would leave the steps to
    the road without a word); ``scale.source: speed`` without it is an error (every step would
    be a fallback, unit lengths before the first metric one), and so is a ``--set
    scale.source=...`` other than speed beside it (two command-line wishes that contradict
    each other; the file's source is only a default the topic overrides).

    Raises:
        ConfigError: ``scale.source`` is ``speed`` and no speed topic is given, or ``sets``
            set it to another source while a speed topic is given.
    """
    import logging

    from planar_vo.config import PlanarVoConfig, flatten
    from planar_vo.errors import ConfigError

    if speed_topic is None:
        if config.scale.source == 'speed':
            raise ConfigError('scale.source: speed needs --speed-topic TOPIC (the bag\'s '
                              'TwistStamped or Odometry speed topic); without it no step '
                              'would be metric')
        return config
    if config.scale.source != 'speed':
        if any(item.partition('=')[0].strip() == 'scale.source' for item in sets):
            raise ConfigError(f'--speed-topic sets scale.source: speed, but --set gives '
                              f'scale.source={config.scale.source}; drop one of the two '
                              f'(scale.fallback may name a source for the steps without a '
                              f'speed)')
        logging.getLogger('planar_vo').info('scale.source: speed (from --speed-topic; the '
                                            'configuration said %s)', config.scale.source)
        config = PlanarVoConfig.from_flat({**flatten(config), 'scale.source': 'speed'})
    return config


def with_sets(path, sets):
    """The configuration of the file ``path`` (None: the defaults) with ``--set KEY=VALUE``
    items applied (one value each: a replay runs one configuration; ``planar_vo fleet run``
    takes several), validated as a whole: a file may need a ``--set`` to be valid (a user
    test: ``camera.nominal_fov`` in the file was refused before ``--set
    camera.estimate_focal=true`` could allow it).

    Raises:
        ConfigError: an unreadable file, a malformed item, an unknown key, several values, or a
            value the configuration refuses (named after the file, ``set:``, or both).
    """
    from planar_vo.config import PlanarVoConfig, build_config, flatten, parse_set, read_config
    from planar_vo.errors import ConfigError

    keys = flatten(PlanarVoConfig())
    changes = {}
    for item in sets:
        key, found = parse_set(item, keys, several=False)
        if key in changes:          # (a user test: the last one silently won)
            raise ConfigError(f"set: '{key}' given twice; give it once")
        if len(found) != 1:
            raise ConfigError(f"set: '{item}': expected one value (one --set per key: a replay "
                              f'runs one configuration; planar_vo fleet run takes several)')
        changes[key] = found[0]
    return build_config(read_config(path), changes, path)
