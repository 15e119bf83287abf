"""``planar_vo import-kitti``: a KITTI odometry sequence folder -> a ROS 2 bag.

Writes /camera/image_raw (mono8), /camera/camera_info (K from P0 of calib.txt, no distortion)
and, when poses.txt exists (in the folder, or as dataset/poses/<seq>.txt beside
dataset/sequences/<seq>/ in the KITTI download), /ground_truth/odom in REP-103 frames:
base_link is the camera projected to the ground (CAMERA_HEIGHT below it; x forward, y left, z
up), odom is base_link at the pose poses.txt counts from (the first frame of a whole KITTI
sequence; a cut-out keeps its sequence's frame, as planar_vo eval aligns the trajectories
anyway). Stamps are times.txt (or --rate-hz) plus --start seconds.
"""

from __future__ import annotations

import argparse
import os
import shlex

STORAGES = ('mcap', 'sqlite3')       # planar_vo.io.writer.STORAGES (rosbags not imported here)

EXAMPLES = """examples:
  planar_vo import-kitti dataset/sequences/06 --out kitti06
  planar_vo import-kitti seq06 --out kitti06_sqlite --storage sqlite3 --camera-height 1.65
  planar_vo replay kitti06 --out kitti06_vo --set mount.height=1.65 && planar_vo eval kitti06_vo

The replay needs the camera height too (--set mount.height=...; the default is 1.5 m): the
ground-plane scale is the height's.
"""


def register(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        'import-kitti', help='convert a KITTI odometry sequence folder into a bag',
        description=__doc__, epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    # dest 'sequence': planar_vo.io.kitti's name for it in errors ('sequence: ...' becomes
    # 'DIR: ...').
    parser.add_argument('sequence', metavar='DIR',
                        help='sequence folder with image_0/ (or image_l/), calib.txt, times.txt '
                             'and optionally poses.txt (or dataset/poses/<seq>.txt beside '
                             'dataset/sequences/<seq>/)')
    parser.add_argument('--out', required=True, metavar='BAG',
                        help='output bag directory (must not exist)')
    parser.add_argument('--storage', choices=list(STORAGES), default='mcap',
                        help='output storage format (default: mcap)')
    parser.add_argument('--camera-height', type=float, default=1.65, metavar='M',
                        help='camera height above the road in metres (default: 1.65, KITTI)')
    parser.add_argument('--rate-hz', type=float, metavar='HZ',
                        help='stamp frames at this rate instead of times.txt')
    parser.add_argument('--start', default='1700000000', metavar='SEC',
                        help='seconds added to every stamp (default: 1700000000)')
    parser.add_argument('--no-progress', action='store_true', help='no progress bar')
    parser.set_defaults(run=run)
    return parser


def run(args: argparse.Namespace) -> int:
    from planar_vo.cli import print_final, show_progress
    from planar_vo.io.kitti import import_kitti

    summary = import_kitti(args.sequence, args.out, storage=args.storage,
                           camera_height=args.camera_height, rate_hz=args.rate_hz,
                           start=args.start, progress=show_progress(args))
    # The height given here sets the ground truth's base_link; the replay's scale needs it too.
    # Quoted for the shell (a user test: a path with a space broke the suggested command).
    out = os.path.normpath(args.out)           # 'k06/' replays into 'k06_vo', not 'k06/_vo'
    print_final(f'{summary.format()}\nreplay it with: planar_vo replay {shlex.quote(out)} '
                f"--out {shlex.quote(out + '_vo')} --set mount.height={args.camera_height:g}")
    return 0
