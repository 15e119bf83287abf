"""``planar_vo bench frontend``: speed and accuracy of the affine-correspondence front-end.

Speed: wall time per frame pair of each method (`planar_vo.frontend.extract_acs`: ``flow``,
``klt``, ``asift``) as a RATIO to DIS optical flow alone (``cv2.DISOpticalFlow``, preset
``fast``, one forward flow: the peer) on the same frames, measured in the same process and
interleaved (per pair the minimum over ``--repeat`` runs, then the median over pairs, so other
load on the machine hits both alike). Frames: a rendered street drive (`planar_vo.sim`) at
640x480 and 1241x376, and the KITTI 06 excerpt (1226x370) when present. Run once with OpenCV's
default threads and once with one thread (``--threads``).

Accuracy (rendered drive, about 1 m forward and 1.5 deg yaw per frame): point and Frobenius
affine errors of the ACs against the exact plane-induced ACs (`planar_vo.sim.exact_acs`),
all planes, and the ground alone.

Motion (KITTI 06 excerpt, 51 frames): per-frame yaw and heading errors of front-end + planar
motion estimation against the ground-truth poses, beside OpenCV's five-point pipeline
(`planar_vo.bench.peers.estimate_5pc_opencv`) on the same points. Planar estimation is 1AC +
voting (`planar_vo.core.vote_planar_motion`). Rows with ``levelled`` first
remove the camera's tilt estimated from the five-point poses of the whole excerpt
(`MountTiltEstimator`; an angle with a standard deviation above 0.5 deg is left at 0,
`TiltEstimate.levelling_angles`); their ground truth is expressed in the same levelled frame.
"""

from __future__ import annotations

import argparse
import logging
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from planar_vo.bench.common import write_markdown
from planar_vo.config import FrontendConfig
from planar_vo.core import angle_difference, planar_motion_from_pose, vote_planar_motion
from planar_vo.core.camera import CameraModel, normalize_affines, normalize_points
from planar_vo.errors import InputError
from planar_vo.frontend import ACExtractor, level_acs, leveling_rotation
from planar_vo.pipeline.calibration import MountTiltEstimator

__all__ = ['HELP', 'VARIANTS', 'add_arguments', 'run', 'time_methods']

logger = logging.getLogger(__name__)

HELP = 'front-end speed (ratio to DIS flow) and accuracy (rendered, KITTI) of extract_acs'
DEFAULT_KITTI = Path('..') / 'shared' / 'data' / 'kitti06_excerpt'   # beside the repository
KITTI_K = np.array([[707.0912, 0.0, 601.8873], [0.0, 707.0912, 183.1104], [0.0, 0.0, 1.0]])
RENDER_SIZES = ((640, 480, 500.0), (1241, 376, 718.856))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The benchmark's options (``planar_vo bench frontend``)."""
    parser.add_argument('--methods', nargs='+', default=['flow', 'klt', 'asift'],
                        choices=['flow', 'klt', 'asift'],
                        help='methods to time (default: all); flow is also timed with the '
                             'forward-backward check and without re-seeding')
    parser.add_argument('--pairs', type=int, default=8,
                        help='frame pairs timed per image set (default: 8)')
    parser.add_argument('--repeat', type=int, default=3,
                        help='timed runs per pair; the minimum counts (default: 3)')
    parser.add_argument('--asift-pairs', type=int, default=1,
                        help='pairs for ASIFT, about 4 s each (default: 1)')
    parser.add_argument('--threads', type=int, nargs='+', default=[0, 1],
                        help='OpenCV thread counts to time with, 0 = default (default: 0 1)')
    parser.add_argument('--kitti', type=Path, default=None,
                        help=f'KITTI excerpt directory with image_l/ and poses.txt (default: '
                             f'{DEFAULT_KITTI}, skipped when missing; a folder given here '
                             f'must hold one)')
    parser.add_argument('--seed', type=int, default=3, help='rendered world seed (default: 3)')
    parser.add_argument('--per-frame', action='store_true',
                        help='also print the KITTI yaw and heading errors of every frame pair')


# --------------------------------------------------------------------------------------------
# Frames
# --------------------------------------------------------------------------------------------

@dataclass
class FrameSet:
    """Consecutive frames with what is known about them."""

    name: str
    images: list[np.ndarray]
    camera: CameraModel
    poses: np.ndarray | None = None          # T_odom_camera (N, 4, 4), rendered
    world: object = None                     # StreetWorld, rendered
    kinds: list[np.ndarray] | None = None    # per-pixel kind, rendered
    relative: np.ndarray | None = None       # (N-1, 4, 4) X2 = R X1 + t, KITTI ground truth


def rendered_frames(width: int, height: int, focal: float, count: int, seed: int) -> FrameSet:
    """A rendered street drive: 1 m per frame, straight then a 38 m-radius left turn (1.5 deg
    of yaw per frame), camera 1.5 m above the ground."""
    from planar_vo.core.conventions import mount_transform
    from planar_vo.sim import StreetWorld, concatenate, render, straight, turn

    traj = concatenate(straight(5.0, speed=10.0),
                       turn(np.deg2rad(1.5) * (count + 2), radius=38.0, speed=10.0))
    world = StreetWorld.along(traj, seed=seed)
    camera = CameraModel.pinhole(width, height, focal)
    poses = traj.camera_poses(mount_transform(height=1.5))[:count]
    frames = [render(world, camera, T) for T in poses]
    return FrameSet(f'rendered {width}x{height}', [f.image for f in frames], camera, poses,
                    world, [f.kind for f in frames])


def kitti_frames(directory: Path, count: int | None = None) -> FrameSet:
    """The KITTI excerpt: grey frames and ground-truth relative motions."""
    paths = sorted((directory / 'image_l').glob('*.png'))[:count]
    if len(paths) < 2:
        raise InputError(f'kitti: expected at least 2 PNG frames in {directory / "image_l"}, '
                         f'found {len(paths)}')
    images = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in paths]
    poses = np.loadtxt(directory / 'poses.txt').reshape(-1, 3, 4)[:len(images)]
    T = np.tile(np.eye(4), (len(poses), 1, 1))
    T[:, :3, :4] = poses
    relative = np.linalg.inv(T[1:]) @ T[:-1]                  # X_{k+1} = R X_k + t
    h, w = images[0].shape
    camera = CameraModel(w, h, KITTI_K)
    return FrameSet(f'KITTI 06 {w}x{h}', images, camera, relative=relative)


# --------------------------------------------------------------------------------------------
# Speed
# --------------------------------------------------------------------------------------------

# Timed variants: label -> (method, FrontendConfig overrides).
VARIANTS = {
    'flow': ('flow', {}),
    'flow + FB check': ('flow', {'fb_threshold': 2.0}),
    'flow, no re-seeding': ('flow', {'reseed': False}),
    'klt': ('klt', {}),
    'asift': ('asift', {}),
}


def time_methods(frames: FrameSet, variants: list[str], pairs: int, repeat: int,
                 asift_pairs: int) -> dict[str, dict[str, float]]:
    """Per variant: median ms per pair, median ratio to DIS fast (wall clock and, with one
    OpenCV thread, CPU time of the calling thread), median ACs per pair.

    DIS and the variants run interleaved on each pair; per pair the minimum over ``repeat``
    runs counts. With ``cv2.setNumThreads(1)`` everything runs on the calling thread, so its
    CPU time (``time.thread_time``) is the whole cost and is not inflated by other processes.
    """
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_FAST)
    n = min(pairs, len(frames.images) - 1)
    single = cv2.getNumThreads() <= 1
    out = {}
    for label in variants:
        method, overrides = VARIANTS[label]
        extractor = ACExtractor(FrontendConfig(**overrides))
        count = min(n, asift_pairs) if method == 'asift' else n
        reps = 1 if method == 'asift' else repeat
        ratios, cpu_ratios, times, sizes = [], [], [], []
        extractor.extract(frames.images[0], frames.images[1], method)       # warm-up
        dis.calc(frames.images[0], frames.images[1], None)
        for k in range(count):
            a, b = frames.images[k], frames.images[k + 1]
            wall = [np.inf, np.inf]
            cpu = [np.inf, np.inf]
            for _ in range(reps):
                for i, job in enumerate((lambda: dis.calc(a, b, None),
                                         lambda: extractor.extract(a, b, method))):
                    start, start_cpu = time.perf_counter(), time.thread_time()
                    result = job()
                    wall[i] = min(wall[i], time.perf_counter() - start)
                    cpu[i] = min(cpu[i], time.thread_time() - start_cpu)
            ratios.append(wall[1] / wall[0])
            cpu_ratios.append(cpu[1] / cpu[0] if single else np.nan)
            times.append((wall[0], wall[1]))
            sizes.append(len(result))
        times = np.array(times)
        out[label] = {'ms': 1e3 * float(np.median(times[:, 1])),
                      'dis_ms': 1e3 * float(np.median(times[:, 0])),
                      'ratio': float(np.median(ratios)),
                      'cpu_ratio': float(np.median(cpu_ratios)),
                      'acs': float(np.median(sizes))}
        logger.info('%s %s: %s', frames.name, label, out[label])
    return out


# --------------------------------------------------------------------------------------------
# Accuracy against exact ACs (rendered)
# --------------------------------------------------------------------------------------------

def rendered_accuracy(frames: FrameSet, method: str, pairs: int) -> dict[str, float]:
    """Median point and affine errors of ``method``'s ACs against the exact ones."""
    from planar_vo.sim import GROUND_KIND, exact_acs

    extractor = ACExtractor(FrontendConfig())
    point, affine, ground, counts = [], [], [], []
    for k in range(min(pairs, len(frames.images) - 1)):
        acs = extractor.extract(frames.images[k], frames.images[k + 1], method)
        exact, valid = exact_acs(frames.world, frames.poses[k], frames.poses[k + 1],
                                 frames.camera, acs.p1)
        counts.append(len(acs))
        acs, exact = acs.subset(valid), exact.subset(valid)
        point.append(np.linalg.norm(acs.p2 - exact.p2, axis=1))
        affine.append(np.linalg.norm(acs.A - exact.A, axis=(1, 2)))
        pix = np.rint(acs.p1).astype(int)
        ground.append(frames.kinds[k][pix[:, 1], pix[:, 0]] == GROUND_KIND)
    point, affine, ground = map(np.concatenate, (point, affine, ground))
    return {'acs': float(np.median(counts)), 'point': float(np.median(point)),
            'affine': float(np.median(affine)), 'ground_share': float(ground.mean()),
            'ground_point': float(np.median(point[ground])) if ground.any() else np.nan,
            'ground_affine': float(np.median(affine[ground])) if ground.any() else np.nan}


# --------------------------------------------------------------------------------------------
# Motion on KITTI
# --------------------------------------------------------------------------------------------

def _vote(q1: np.ndarray, q2: np.ndarray, A: np.ndarray, weights: np.ndarray
          ) -> tuple[float, float]:
    """``(alpha, beta)`` of 1AC + voting on normalised ACs."""
    motion, _ = vote_planar_motion(q1, q2, A, weights=weights)
    return float(motion.alpha), float(motion.beta)


def kitti_motion(frames: FrameSet) -> tuple[list[tuple[str, np.ndarray, np.ndarray]], dict]:
    """Per-frame |yaw| and |heading| errors (degrees) of planar estimation and five-point."""
    from planar_vo.bench.peers import estimate_5pc_opencv

    name, estimate = '1AC + vote_planar_motion', _vote
    K = frames.camera.K
    extractor = ACExtractor(FrontendConfig())
    tilt_estimator = MountTiltEstimator()
    per_frame = []
    for k in range(len(frames.images) - 1):
        acs = extractor.extract(frames.images[k], frames.images[k + 1])
        q1, q2 = normalize_points(K, acs.p1), normalize_points(K, acs.p2)
        pose = estimate_5pc_opencv(q1, q2)
        if pose.ok:
            tilt_estimator.add_motion(pose.R, pose.t)
        per_frame.append((acs, pose))
    tilt = tilt_estimator.estimate()
    pitch, roll = tilt.levelling_angles()
    rows = {f'{name}': [], f'{name}, levelled': [], 'OpenCV five-point (same points)': []}
    R_lc = leveling_rotation(pitch, roll)
    for (acs, pose), M in zip(per_frame, frames.relative):
        true_raw = planar_motion_from_pose(M[:3, :3], M[:3, 3])
        true_lev = planar_motion_from_pose(R_lc @ M[:3, :3] @ R_lc.T, R_lc @ M[:3, 3])
        for label, c, truth in ((name, acs, true_raw),
                                (f'{name}, levelled', level_acs(acs, K, pitch, roll),
                                 true_lev)):
            est = estimate(normalize_points(K, c.p1), normalize_points(K, c.p2),
                           normalize_affines(K, K, c.A), c.weights)
            rows[label].append((angle_difference(est[0], truth[0]),
                                angle_difference(est[1], truth[1])))
        rows['OpenCV five-point (same points)'].append(
            (angle_difference(pose.alpha, true_raw[0]), angle_difference(pose.beta, true_raw[1])))
    table = []
    for label, errs in rows.items():
        e = np.degrees(np.abs(np.array(errs, dtype=np.float64)))
        table.append((label, e[:, 0], e[:, 1]))
    info = {'tilt': tilt, 'level': (pitch, roll), 'frames': len(per_frame),
            'acs': float(np.median([len(a) for a, _ in per_frame]))}
    return table, info


# --------------------------------------------------------------------------------------------
# Report
# --------------------------------------------------------------------------------------------

def _markdown(header: list[str], rows: list[list[str]]) -> str:
    lines = ['| ' + ' | '.join(header) + ' |', '|' + '|'.join('---' for _ in header) + '|']
    lines += ['| ' + ' | '.join(r) + ' |' for r in rows]
    return '\n'.join(lines)


def run(args: argparse.Namespace) -> int:
    """Run the benchmark and print markdown tables; returns 0."""
    if args.pairs < 1 or args.repeat < 1:
        raise InputError(f'--pairs, --repeat: expected at least 1, got {args.pairs}, '
                         f'{args.repeat}')
    if args.kitti is None:
        folder = DEFAULT_KITTI if (DEFAULT_KITTI / 'poses.txt').is_file() else None
    elif (args.kitti / 'poses.txt').is_file():
        folder = args.kitti
    else:
        raise InputError(f"--kitti: '{args.kitti}' is not a KITTI excerpt folder (no "
                         f"poses.txt)")
    start = time.perf_counter()
    sections: list[str] = []
    out = sections.append
    count = max(args.pairs, 8) + 1
    sets = [rendered_frames(w, h, f, count, args.seed) for w, h, f in RENDER_SIZES]
    kitti = kitti_frames(folder) if folder is not None else None
    out('## Front-end speed: time per frame pair, as a ratio to DIS optical flow alone '
        '(preset fast)\n')
    out(f'Interleaved in one process; per pair the minimum of {args.repeat} runs, median '
        f'over {args.pairs} pairs (ASIFT: {args.asift_pairs} pair, 1 run).\n')
    rows = []
    variants = [v for v in VARIANTS if VARIANTS[v][0] in args.methods]
    default_threads = cv2.getNumThreads()
    try:
        for threads in args.threads:
            cv2.setNumThreads(threads if threads > 0 else default_threads)
            label = f'{cv2.getNumThreads()}'
            for frames in sets + ([kitti] if kitti is not None else []):
                timing = time_methods(frames, variants, args.pairs, args.repeat,
                                      args.asift_pairs)
                for name, t in timing.items():
                    cpu = '' if np.isnan(t['cpu_ratio']) else f'{t["cpu_ratio"]:.2f}'
                    rows.append([frames.name, label, name, f'{t["ms"]:.1f}',
                                 f'{t["dis_ms"]:.1f}', f'{t["ratio"]:.2f}', cpu,
                                 f'{t["acs"]:.0f}'])
    finally:
        cv2.setNumThreads(default_threads)
    out(_markdown(['frames', 'OpenCV threads', 'method', 'ms / pair', 'DIS fast ms / pair',
                   'ratio to DIS (wall)', 'ratio to DIS (CPU, 1 thread)', 'ACs / pair'],
                  rows))

    out('\n## Front-end accuracy against exact ACs (rendered street, all planes)\n')
    rows = []
    for frames in sets:
        for method in args.methods:
            pairs = min(args.pairs, args.asift_pairs) if method == 'asift' else args.pairs
            acc = rendered_accuracy(frames, method, pairs)
            rows.append([frames.name, method, f'{acc["acs"]:.0f}', f'{acc["point"]:.3f}',
                         f'{acc["affine"]:.4f}', f'{100 * acc["ground_share"]:.0f}%',
                         f'{acc["ground_point"]:.3f}', f'{acc["ground_affine"]:.4f}'])
    out(_markdown(['frames', 'method', 'ACs / pair', 'median point error (px)',
                   'median |A - A_true|_F', 'ground share', 'ground: point (px)',
                   'ground: |A - A_true|_F'], rows))

    if kitti is not None:
        table, info = kitti_motion(kitti)
        tilt = info['tilt']
        out(f'\n## Motion on {kitti.name} ({info["frames"]} frame pairs, flow front-end, '
            f'median {info["acs"]:.0f} ACs per pair)\n')
        out(f'Estimated camera tilt w.r.t. the motion plane (from the five-point poses): '
            f'pitch {np.degrees(tilt.pitch):.2f} +- {np.degrees(tilt.pitch_std):.2f} deg, '
            f'roll {np.degrees(tilt.roll):.2f} +- {np.degrees(tilt.roll_std):.2f} deg '
            f'({tilt.frames} pairs); levelled by pitch {np.degrees(info["level"][0]):.2f}, '
            f'roll {np.degrees(info["level"][1]):.2f} deg (an angle with a standard deviation '
            f'above 0.5 deg is left at 0).\n')
        rows = [[label, f'{yaw.mean():.3f}', f'{np.median(yaw):.3f}', f'{yaw.max():.3f}',
                 f'{head.mean():.3f}', f'{np.median(head):.3f}', f'{head.max():.3f}']
                for label, yaw, head in table]
        out(_markdown(['estimator', 'yaw err mean (deg)', 'median', 'max',
                       'heading err mean (deg)', 'median', 'max'], rows))
        if getattr(args, 'per_frame', False):
            header = ['pair'] + [f'{label}: {what}' for label, _, _ in table
                                 for what in ('yaw', 'heading')]
            frame_rows = [[f'{k}-{k + 1}'] + [f'{e[k]:.3f}' for _, yaw, head in table
                                              for e in (yaw, head)]
                          for k in range(len(table[0][1]))]
            out('\nPer frame pair, absolute errors in degrees:\n')
            out(_markdown(header, frame_rows))
    else:
        out(f'\n(KITTI excerpt not found at {DEFAULT_KITTI}: motion table skipped)')
    out(f'Wall time: {time.perf_counter() - start:.0f} s.')
    path = Path(args.out) / 'frontend.md'
    print(write_markdown(path, 'planar_vo bench frontend', args.command,
                         [text.strip('\n') for text in sections]))
    print(f'wrote {path}')
    return 0
