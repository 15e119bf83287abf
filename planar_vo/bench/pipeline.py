"""``planar_vo bench pipeline``: end-to-end speed per stage, and accuracy on real KITTI frames.

Speed (one core): rendered 1241x376 frames of the demo drive, each stage timed per frame:
``decode`` (sensor_msgs/Image -> pixels), ``correspondences`` (front-end), ``solve`` (voting,
refinement and scale), ``integrate`` (pose, covariance, twist) and ``publish`` (building and
serialising the nav_msgs/Odometry). Reported as medians and as ratios to DIS optical flow alone
on the same frames, the peer measured in the same process. Target: the whole frame under 15 ms,
at most 2.5x DIS alone (fast preset).

Accuracy: the KITTI odometry excerpt (``--kitti DIR``, default the shared development data when
present) imported with ``import-kitti``; per-frame yaw-change and heading errors and ATE of
planar_vo beside OpenCV's five-point pipeline (``findEssentialMat`` + ``recoverPose``) on the
same frames, the same correspondences' points and the same scale (ground-truth speed), so the
difference is the estimator.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

# The development data sits beside the repository (never inside it: its licence forbids that).
KITTI_EXCERPT = Path('..') / 'shared' / 'data' / 'kitti06_excerpt'
EXAMPLES = """examples:
  planar_vo bench pipeline
  planar_vo bench pipeline --frames 100 --out out/bench/pipeline
  planar_vo bench pipeline --kitti /data/kitti/sequences/06 --kitti-pitch 0.0188
"""


HELP = 'end-to-end speed per stage and KITTI accuracy vs the five-point peer'


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``planar_vo bench pipeline`` (``--out`` is added by the bench command)."""
    parser.epilog = EXAMPLES
    parser.add_argument('--frames', type=int, default=60,
                        help='rendered frames for the speed part (default: 60)')
    parser.add_argument('--kitti', type=Path, default=None, metavar='DIR',
                        help='KITTI sequence folder for the accuracy part (default: the shared '
                             'excerpt ../shared/data/kitti06_excerpt when present)')
    parser.add_argument('--kitti-height', type=float, default=1.65,
                        help='KITTI camera height in metres (default: 1.65)')
    parser.add_argument('--kitti-pitch', type=float, default=None, metavar='RAD',
                        help='known camera pitch; default: estimated online (mount.estimate_tilt)')
    parser.add_argument('--skip-speed', action='store_true', help='accuracy part only')
    parser.add_argument('--skip-kitti', action='store_true', help='speed part only')


def run(args: argparse.Namespace) -> int:
    from planar_vo.bench.common import reexec_single_threaded, write_markdown
    from planar_vo.errors import InputError

    if args.frames < 10:
        raise InputError(f'frames: expected at least 10, got {args.frames}')
    kitti = args.kitti if args.kitti is not None else KITTI_EXCERPT
    if args.kitti is not None and not (kitti / 'calib.txt').exists():
        raise InputError(f"kitti: '{kitti}' is not a KITTI sequence folder (no calib.txt)")
    code = reexec_single_threaded(args, pin_core=True)
    if code is not None:
        return code
    sections = []
    if not args.skip_speed:
        sections.append(speed_table(args.frames))
        print(sections[-1] + '\n', flush=True)
    if not args.skip_kitti:
        if (kitti / 'calib.txt').exists():
            sections.append(kitti_table(kitti, args.kitti_height, args.kitti_pitch))
        else:
            sections.append(f'(KITTI accuracy skipped: no excerpt at {kitti}; pass --kitti DIR)')
        print(sections[-1] + '\n', flush=True)
    path = Path(args.out) / 'pipeline.md'
    write_markdown(path, 'planar_vo bench pipeline', args.command, sections)
    print(f'wrote {path}')
    return 0


# ------------------------------------------------------------------------------------------------
# Speed
# ------------------------------------------------------------------------------------------------

def speed_table(frames: int) -> str:
    """Per-stage medians (ms) on rendered 1241x376 frames, and ratios to DIS alone."""
    import cv2

    from planar_vo.config import PlanarVoConfig
    from planar_vo.core.conventions import mount_transform
    from planar_vo.io.reader import TYPESTORE
    from planar_vo.io.writer import ODOMETRY_TYPE, odometry_message
    from planar_vo.pipeline import VisualOdometry
    from planar_vo.ros.messages import image_to_array
    from planar_vo.sim import StreetWorld
    from planar_vo.sim.drive import demo_drive, render_drive
    from planar_vo.tools.demo import CAMERAS

    camera = CAMERAS['1241x376']()
    config = PlanarVoConfig()
    drive = demo_drive()
    drive = drive.subset(slice(0, frames))
    world = StreetWorld.along(drive, seed=0)
    mount = mount_transform(height=config.mount.height)
    t = TYPESTORE.types
    messages, images = [], []
    for frame in render_drive(drive, world, camera, mount):
        header = t['std_msgs/msg/Header'](stamp=t['builtin_interfaces/msg/Time'](sec=0, nanosec=0),
                                          frame_id='camera')
        messages.append(t['sensor_msgs/msg/Image'](
            header=header, height=camera.height, width=camera.width, encoding='mono8',
            is_bigendian=0, step=camera.width, data=frame.image.reshape(-1)))
        images.append(frame.image)

    stages = {k: [] for k in ('decode', 'correspondences', 'solve', 'integrate', 'publish',
                              'total')}
    dis = {'ultrafast': [], 'fast': []}
    flows = {p: cv2.DISOpticalFlow_create(getattr(cv2, f'DISOPTICAL_FLOW_PRESET_{p.upper()}'))
             for p in dis}
    for _ in range(2):                                     # warm-up pass, then the timed pass
        vo = VisualOdometry(config, camera)
        for k in stages:
            stages[k].clear()
        for k in dis:
            dis[k].clear()
        for i, (msg, stamp) in enumerate(zip(messages, drive.stamps)):
            t0 = time.perf_counter()
            image = image_to_array(msg)
            t1 = time.perf_counter()
            result = vo.process(image, float(stamp))
            t2 = time.perf_counter()
            odom = odometry_message(int(stamp * 1e9), result.pose, odom_frame='odom',
                                    base_frame='base_link', pose_covariance=result.pose_covariance,
                                    twist=result.twist, twist_covariance=result.twist_covariance)
            TYPESTORE.serialize_cdr(odom, ODOMETRY_TYPE)
            t3 = time.perf_counter()
            if i == 0:
                continue                                   # the first frame only initialises
            stages['decode'].append(t1 - t0)
            for key in ('correspondences', 'solve', 'integrate'):
                stages[key].append(result.timings.get(key, 0.0))
            stages['publish'].append(t3 - t2)
            stages['total'].append(t3 - t0)
            for preset, flow in flows.items():
                s = time.perf_counter()
                flow.calc(images[i - 1], images[i], None)
                dis[preset].append(time.perf_counter() - s)
    med = {k: 1e3 * float(np.median(v)) for k, v in stages.items()}
    dis_ms = {k: 1e3 * float(np.median(v)) for k, v in dis.items()}
    total = med['total']
    lines = [f'## Speed: {frames - 1} frame pairs, {camera.width}x{camera.height}, one core',
             '', '| stage | median (ms) | / DIS fast | / DIS ultrafast |', '|---|---|---|---|']
    for key in ('decode', 'correspondences', 'solve', 'integrate', 'publish', 'total'):
        lines.append(f'| {key} | {med[key]:.2f} | {med[key] / dis_ms["fast"]:.2f} | '
                     f'{med[key] / dis_ms["ultrafast"]:.2f} |')
    lines.append(f'| DIS optical flow alone (fast / ultrafast) | {dis_ms["fast"]:.2f} / '
                 f'{dis_ms["ultrafast"]:.2f} | 1 | 1 |')
    ok_time = total < 15.0
    ok_ratio = total / dis_ms['fast'] <= 2.5
    lines += ['', f'Whole frame {total:.1f} ms ({1e3 / total:.0f} frames/s): target < 15 ms '
                  f'{"met" if ok_time else "NOT met"}; {total / dis_ms["fast"]:.2f}x DIS fast: '
                  f'target <= 2.5x {"met" if ok_ratio else "NOT met"}.']
    return '\n'.join(lines)


# ------------------------------------------------------------------------------------------------
# Accuracy on KITTI
# ------------------------------------------------------------------------------------------------

def kitti_table(folder: Path, height: float, pitch: float | None) -> str:
    """planar_vo and the OpenCV five-point pipeline on the same KITTI frames."""
    from planar_vo.config import PlanarVoConfig
    from planar_vo.core.trajectory import Trajectory
    from planar_vo.io import import_kitti, iter_camera_frames, iter_messages, open_bag
    from planar_vo.pipeline import VisualOdometry
    from planar_vo.ros.messages import pose_from_message
    from planar_vo.tools.evaluation import evaluate

    with tempfile.TemporaryDirectory() as tmp:
        bag_path = Path(tmp) / 'kitti'
        import_kitti(folder, bag_path, camera_height=height)
        with open_bag(bag_path) as bag:
            frames = list(iter_camera_frames(bag))
            gt_msgs = list(iter_messages(bag, '/ground_truth/odom'))
    stamps_ns = np.array([f.stamp_ns for f in frames])
    gt_poses = np.array([pose_from_message(m.msg) for m in gt_msgs])
    gt = Trajectory.from_poses(stamps_ns, gt_poses)
    steps = np.linalg.norm(np.diff(gt_poses[:, :3, 3], axis=0), axis=1)

    runs: dict[str, tuple[np.ndarray, float]] = {}
    mount = {'height': height}
    if pitch is None:
        mount.update(estimate_tilt=True)
    else:
        mount['pitch'] = float(pitch)
    for label, scale in (('planar_vo (1AC + voting), ground-plane scale', 'ground'),
                         ('planar_vo (1AC + voting), ground-truth speed', 'speed')):
        config = PlanarVoConfig.from_dict({'mount': mount, 'scale': {'source': scale}})
        vo = VisualOdometry(config)
        poses, times = [], []
        for frame, msg in zip(frames, gt_msgs):
            stamp = frame.stamp_ns * 1e-9
            if scale == 'speed':
                vo.add_speed(stamp, float(np.hypot(msg.msg.twist.twist.linear.x,
                                                   msg.msg.twist.twist.linear.y)))
            result = vo.process(frame.image, stamp, frame.camera)
            poses.append(result.pose)
            times.append(result.timings.get('total', 0.0))
        tilt = vo.tilt_estimate
        runs[label] = (np.array(poses), float(np.median(times[1:])))
    levelled_pitch = tilt.pitch if pitch is None and tilt is not None else (pitch or 0.0)
    runs['OpenCV five-point, ground-truth speed'] = _five_point_run(frames, steps, height,
                                                                    levelled_pitch)
    lines = [f'## Accuracy on KITTI ({folder.name}: {len(frames)} frames, {gt.path_length:.1f} m); '
             f'camera pitch {"estimated online" if pitch is None else "given"}: '
             f'{np.rad2deg(levelled_pitch):.2f} deg',
             '', '| method | ATE rmse (m) | yaw-change err. mean / rmse / max (deg) | '
                 'heading err. mean / rmse / max (deg) | time per frame (ms) |',
             '|---|---|---|---|---|']
    for label, (poses, ms) in runs.items():
        est = Trajectory.from_poses(stamps_ns, poses)
        m = evaluate(gt, est, align='se3').metrics()
        y, h = m['yaw_change_error_deg'], m['heading_error_deg']
        lines.append(f"| {label} | {m['ate_m']['rmse']:.3f} | {y['mean']:.3f} / {y['rmse']:.3f} "
                     f"/ {y['max']:.3f} | {h['mean']:.3f} / {h['rmse']:.3f} / {h['max']:.3f} | "
                     f'{1e3 * ms:.1f} |')
    lines += ['', 'Both use the same front-end correspondences; the five-point peer gets only '
                  'their '
                  'points (it cannot use the affinities), with a 1 px RANSAC threshold.']
    return '\n'.join(lines)


def _five_point_run(frames, steps: np.ndarray, height: float, pitch: float
                    ) -> tuple[np.ndarray, float]:
    """Frame-to-frame OpenCV five-point odometry on our front-end's points, GT step lengths
    (`planar_vo.bench.odometry.PeerOdometry`), as vehicle poses ``T_odom_base`` for the mount."""
    from planar_vo.bench.odometry import PeerOdometry
    from planar_vo.core.conventions import invert, mount_transform

    peer = PeerOdometry(('opencv',), ('frontend',))
    for i, frame in enumerate(frames):
        peer.add(frame.image, frame.camera, steps[i - 1] if i else 0.0)
    run = peer.runs(np.array([f.stamp_ns for f in frames]))['opencv_frontend']
    T_bc = mount_transform(height=height, pitch=pitch)
    return T_bc @ run.poses @ invert(T_bc), float(np.median(run.seconds))
