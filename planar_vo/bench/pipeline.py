"""``planar_vo bench pipeline``: end-to-end speed per stage on rendered and real frames.

One core (the process pinned, one BLAS and one OpenCV thread). Frames: rendered 1241x376 frames
of the demo drive, and real KITTI frames (``--kitti DIR``, default the shared development drive
when present: real texture gives more ACs than the rendered world). Each stage is timed per
frame: ``decode`` (sensor_msgs/Image -> pixels), ``correspondences`` (front-end), ``solve`` (the
motion estimator), ``scale`` (the step length, the road normal), ``integrate`` (pose,
covariance, twist), ``publish`` (building and serialising the nav_msgs/Odometry), and the whole
frame in wall and CPU time. Reported as medians and as ratios to DIS optical flow alone on the
same frames, the peer measured in the same process. Target (issue 10): the whole frame at most
20 ms at 1241x376 on one core.

Accuracy on real drives against the five-point peers is `planar_vo bench drives`.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

# The development data sits beside the repository (never inside it: its licence forbids that).
KITTI_DRIVE = Path('..') / 'shared' / 'data' / 'kitti05_0000_0299'
EXAMPLES = """examples:
  planar_vo bench pipeline
  planar_vo bench pipeline --frames 100 --out out/bench/pipeline
  planar_vo bench pipeline --kitti /data/kitti/sequences/06
"""
TARGET_MS = 20.0


HELP = 'end-to-end speed per stage on rendered and KITTI frames vs DIS flow'


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``planar_vo bench pipeline`` (``--out`` is added by the bench command)."""
    parser.epilog = EXAMPLES
    parser.add_argument('--frames', type=int, default=60,
                        help='rendered frames for the speed part (default: 60)')
    parser.add_argument('--kitti', type=Path, default=None, metavar='DIR',
                        help='KITTI sequence folder for the real frames (default: the shared '
                             'drive ../shared/data/kitti05_0000_0299 when present)')
    parser.add_argument('--kitti-height', type=float, default=1.65,
                        help='KITTI camera height in metres (default: 1.65)')
    parser.add_argument('--skip-rendered', action='store_true', help='real frames only')
    parser.add_argument('--skip-kitti', action='store_true', help='rendered frames only')


def run(args: argparse.Namespace) -> int:
    from planar_vo.bench.common import reexec_single_threaded, write_markdown
    from planar_vo.errors import InputError

    if args.frames < 10:
        raise InputError(f'--frames: expected at least 10, got {args.frames}')
    if args.skip_rendered and args.skip_kitti:
        # (a user test: an empty report, exit 0)
        raise InputError('--skip-kitti: with --skip-rendered too, nothing is left to time; '
                         'drop one of the two')
    kitti = args.kitti if args.kitti is not None else KITTI_DRIVE
    if args.kitti is not None and not (kitti / 'calib.txt').exists():
        raise InputError(f"kitti: '{kitti}' is not a KITTI sequence folder (no calib.txt)")
    code = reexec_single_threaded(args, pin_core=True)
    if code is not None:
        return code
    sections = []
    if not args.skip_rendered:
        sections.append(speed_table('rendered demo drive', *_rendered_frames(args.frames)))
        print(sections[-1] + '\n', flush=True)
    if not args.skip_kitti:
        if (kitti / 'calib.txt').exists():
            sections.append(speed_table(f'KITTI {kitti.name}',
                                        *_kitti_frames(kitti, args.frames, args.kitti_height)))
        else:
            sections.append(f'(KITTI frames skipped: no drive at {kitti}; pass --kitti DIR)')
        print(sections[-1] + '\n', flush=True)
    path = Path(args.out) / 'pipeline.md'
    write_markdown(path, 'planar_vo bench pipeline', args.command, sections)
    print(f'wrote {path}')
    return 0


# ------------------------------------------------------------------------------------------------
# Speed
# ------------------------------------------------------------------------------------------------

def _rendered_frames(frames: int):
    """``(camera, images, stamps, config)`` of the first rendered demo frames at 1241x376."""
    from planar_vo.config import PlanarVoConfig
    from planar_vo.core.conventions import mount_transform
    from planar_vo.sim import StreetWorld
    from planar_vo.sim.drive import demo_drive, render_drive
    from planar_vo.tools.demo import CAMERAS

    camera = CAMERAS['1241x376']()
    config = PlanarVoConfig()
    drive = demo_drive().subset(slice(0, frames))
    world = StreetWorld.along(drive, seed=0)
    mount = mount_transform(height=config.mount.height)
    images = [f.image for f in render_drive(drive, world, camera, mount)]
    return camera, images, [float(t) for t in drive.stamps], config


def _kitti_frames(folder: Path, frames: int, height: float):
    """``(camera, images, stamps, config)`` of the first frames of a KITTI-layout drive: the
    shipped defaults and the camera height."""
    from planar_vo.config import PlanarVoConfig
    from planar_vo.core.camera import CameraModel
    from planar_vo.frontend.images import read_image
    from planar_vo.io.kitti import read_kitti_sequence

    seq = read_kitti_sequence(folder)
    images = [read_image(p) for p in seq.images[:frames]]
    stamps = seq.times[:len(images)]
    height_px, width = images[0].shape[:2]
    camera = CameraModel(width, height_px, seq.P0[:, :3])
    config = PlanarVoConfig.from_flat({'mount.height': height})
    return camera, images, [float(t) for t in stamps], config


def speed_table(label: str, camera, images, stamps, config) -> str:
    """Per-stage medians (ms) of the pipeline on ``images``, and ratios to DIS alone."""
    import cv2

    from planar_vo.io.reader import TYPESTORE
    from planar_vo.io.writer import ODOMETRY_TYPE, odometry_message
    from planar_vo.pipeline import VisualOdometry
    from planar_vo.ros.messages import image_to_array

    t = TYPESTORE.types
    messages = []
    for image in images:
        header = t['std_msgs/msg/Header'](stamp=t['builtin_interfaces/msg/Time'](sec=0, nanosec=0),
                                          frame_id='camera')
        messages.append(t['sensor_msgs/msg/Image'](
            header=header, height=camera.height, width=camera.width, encoding='mono8',
            is_bigendian=0, step=camera.width, data=np.ascontiguousarray(image).reshape(-1)))
    keys = ('decode', 'correspondences', 'solve', 'scale', 'integrate', 'publish', 'total', 'cpu')
    stages = {k: [] for k in keys}
    counts = []
    dis = {'ultrafast': [], 'fast': []}
    flows = {p: cv2.DISOpticalFlow_create(getattr(cv2, f'DISOPTICAL_FLOW_PRESET_{p.upper()}'))
             for p in dis}
    for _ in range(2):                                     # warm-up pass, then the timed pass
        vo = VisualOdometry(config, camera)
        for v in (*stages.values(), *dis.values(), counts):
            v.clear()
        for i, (msg, stamp) in enumerate(zip(messages, stamps)):
            c0 = time.process_time()
            t0 = time.perf_counter()
            image = image_to_array(msg)
            t1 = time.perf_counter()
            result = vo.process(image, stamp)
            t2 = time.perf_counter()
            odom = odometry_message(TYPESTORE.types, int(stamp * 1e9), result.pose,
                                    odom_frame='odom',
                                    base_frame='base_link', pose_covariance=result.pose_covariance,
                                    twist=result.twist, twist_covariance=result.twist_covariance)
            TYPESTORE.serialize_cdr(odom, ODOMETRY_TYPE)
            t3 = time.perf_counter()
            c1 = time.process_time()
            if i == 0:
                continue                                   # the first frame only initialises
            stages['decode'].append(t1 - t0)
            for key in ('correspondences', 'solve', 'scale', 'integrate'):
                stages[key].append(result.timings.get(key, 0.0))
            stages['publish'].append(t3 - t2)
            stages['total'].append(t3 - t0)
            stages['cpu'].append(c1 - c0)
            counts.append(result.num_correspondences)
            for preset, flow in flows.items():
                s = time.perf_counter()
                flow.calc(images[i - 1], images[i], None)
                dis[preset].append(time.perf_counter() - s)
    med = {k: 1e3 * float(np.median(v)) for k, v in stages.items()}
    dis_ms = {k: 1e3 * float(np.median(v)) for k, v in dis.items()}
    total = med['total']
    names = {'total': 'whole frame (wall)', 'cpu': 'whole frame (CPU time)'}
    lines = [f'## {label}: {len(images) - 1} frame pairs, {camera.width}x{camera.height}, one '
             f'core; median {int(np.median(counts))} ACs per frame',
             '', '| stage | median (ms) | / DIS fast | / DIS ultrafast |', '|---|---|---|---|']
    for key in keys:
        lines.append(f'| {names.get(key, key)} | {med[key]:.2f} | '
                     f'{med[key] / dis_ms["fast"]:.2f} | {med[key] / dis_ms["ultrafast"]:.2f} |')
    lines.append(f'| DIS optical flow alone (fast / ultrafast) | {dis_ms["fast"]:.2f} / '
                 f'{dis_ms["ultrafast"]:.2f} | 1 | 1 |')
    met = total <= TARGET_MS
    lines += ['', f'Whole frame {total:.1f} ms ({1e3 / total:.0f} frames/s), '
                  f'{total / dis_ms["fast"]:.2f}x DIS fast alone: target at most '
                  f'{TARGET_MS:g} ms at 1241x376 {"met" if met else "NOT met"}.']
    return '\n'.join(lines)
