"""``planar_vo import-video``: a video file or a folder of images -> a ROS 2 bag.

For a camera you recorded yourself (a dashcam, a phone): writes /camera/image_raw (mono8)
stamped at the video's frame rate (or --rate-hz, which a folder of images needs), and
/camera/camera_info only when --fx is given. Without intrinsics, replay it with the focal
self-calibration (camera.estimate_focal=true): it starts from the field of view the camera's
specification states (camera.nominal_fov, radians) when you give one, and needs turns to
calibrate (replay's --two-pass uses the whole recording's calibration from its first frame on).
Stamps are --start seconds plus each frame's time in the video (or its index over
--rate-hz, which a folder of images needs). A video whose container counts its frames (MP4,
MOV, AVI) and that decodes to more than 2 frames fewer (damaged or truncated: where a frame
was lost cannot be told, and the frames after it would be stamped early) is refused: nothing is
kept.
"""

from __future__ import annotations

import argparse
import os
import shlex

from planar_vo.cli.import_kitti import STORAGES

EXAMPLES = """examples:
  planar_vo import-video dashcam.mp4 --out dash --every 3 --max-width 1280
  planar_vo replay dash --out dash_vo --set mount.height=1.3 --set camera.estimate_focal=true \\
      --set camera.nominal_fov=2.0
  planar_vo import-video frames/ --rate-hz 10 --out drive --fx 718.9 --cx 607.2 --cy 185.2

Without --fx the bag has no CameraInfo; the replay then needs camera.estimate_focal=true (or
camera.fx and friends). The camera height above the road (mount.height, metres) sets the
metric scale.
"""


def register(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        'import-video', help='convert a video file or a folder of images into a bag',
        description=__doc__, epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('source', metavar='SOURCE',
                        help='a video file (MP4, MOV, AVI, MKV: what OpenCV decodes) or a folder '
                             'of PNG/JPEG images (natural name order: 2.png before 10.png)')
    parser.add_argument('--out', required=True, metavar='BAG',
                        help='output bag directory (must not exist)')
    parser.add_argument('--storage', choices=list(STORAGES), default='mcap',
                        help='output storage format (default: mcap)')
    parser.add_argument('--rate-hz', type=float, metavar='HZ',
                        help="the frames' rate (needed for a folder; overrides a video's own)")
    parser.add_argument('--every', type=int, default=1, metavar='N',
                        help='keep one frame in N (default: 1, every frame)')
    parser.add_argument('--max-width', type=int, metavar='PX',
                        help='shrink wider frames to this width (the intrinsics follow)')
    parser.add_argument('--fx', type=float, metavar='PX',
                        help='focal length in pixels of the source frames: writes CameraInfo')
    parser.add_argument('--fy', type=float, metavar='PX', help='(default: --fx)')
    parser.add_argument('--cx', type=float, metavar='PX',
                        help='principal point (default: the image centre)')
    parser.add_argument('--cy', type=float, metavar='PX', help='(default: the image centre)')
    parser.add_argument('--start', default='1700000000', metavar='SEC',
                        help="the first frame's stamp in seconds (default: 1700000000)")
    parser.add_argument('--no-progress', action='store_true', help='no progress bar')
    parser.set_defaults(run=run)
    return parser


def run(args: argparse.Namespace) -> int:
    from planar_vo.cli import print_final, show_progress
    from planar_vo.core.camera import CameraModel
    from planar_vo.core.checks import positive_number
    from planar_vo.errors import CameraModelError, InputError
    from planar_vo.io.video import frame_size, import_video

    given = [name for name in ('fy', 'cx', 'cy') if getattr(args, name) is not None]
    if given and args.fx is None:
        raise InputError(f"--{given[0]}: given without --fx (the intrinsics are written only "
                         f"with a focal length)")
    camera = None
    if args.fx is not None:
        for name in ('fx', 'fy'):
            if getattr(args, name) is not None:
                positive_number(f'--{name}', getattr(args, name),
                                'a positive focal length in pixels')
        width, height = frame_size(args.source)
        try:
            camera = CameraModel.pinhole(width, height, args.fx, args.fy, args.cx, args.cy)
            camera.check_plausible()
        except CameraModelError as err:
            # Named by what was given (a review: --cx's error said --fx).
            given = ', '.join(f'--{n}' for n in ('fx', 'fy', 'cx', 'cy')
                              if getattr(args, n) is not None)
            raise InputError(f'{given}: {err}') from err
    summary = import_video(args.source, args.out, storage=args.storage, rate_hz=args.rate_hz,
                           every=args.every, max_width=args.max_width, camera=camera,
                           start=args.start, progress=show_progress(args))
    out = os.path.normpath(args.out)           # 'dash/' replays into 'dash_vo', not 'dash/_vo'
    command = (f'planar_vo replay {shlex.quote(out)} --out {shlex.quote(out + "_vo")} '
               f'--set mount.height=H')
    if camera is None:
        command += ' --set camera.estimate_focal=true --two-pass'
    assumed = ''
    if camera is not None and (args.cx is None or args.cy is None):
        # (a user test: the centre 6 px off the true principal point biased the heading by 1
        # deg and the replay's covariance was optimistic, 29 % of 2D errors within 3.4 sigma)
        assumed = (f'\nthe principal point is assumed at the image centre '
                   f'({camera.cx:g}, {camera.cy:g} px of the source frames'
                   + (')' if args.max_width is None else ', before --max-width)')
                   + ': give --cx and --cy from your calibration (a few pixels off bias the '
                     'heading, and the covariance does not allow for it)')
    print_final(f'{summary.format()}{assumed}\nreplay it with: {command}\n'
                "  (H: the camera's height above the road in metres"
                + ('; --two-pass: the focal length self-calibrated over the whole recording, '
                   'used from its first frame on; add --set camera.nominal_fov=RAD if its '
                   'specification states a horizontal field of view)' if camera is None
                   else ')'))
    return 0
