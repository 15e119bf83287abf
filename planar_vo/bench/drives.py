"""``planar_vo bench drives``: planar_vo and its peers on every real drive of a data folder.

Every sequence in ``--data`` (KITTI odometry layout: ``image_l/`` or ``image_0/``, ``calib.txt``,
``poses.txt``, ``times.txt``; `planar_vo.io.kitti.read_kitti_sequence`) is run as a user would
run it, and the peers run on the same frames:

- **planar_vo, calibrated**: the folder imported into a bag (`planar_vo.io.import_kitti`) and
  replayed (`planar_vo.tools.replay.replay_bag`) through `VisualOdometry` with the shipped
  defaults plus the one thing a user of that car knows, its camera height (``mount.height`` from
  ``--camera-height``). The metric scale is the pipeline's own (the shipped ``scale.source``).
- **planar_vo, self-calibrated focal**: the same frames without CameraInfo and with
  ``camera.estimate_focal: true``; the focal length in use at the end, whether and when it was
  adopted, its reported standard deviation. Again with the principal point given, and with
  ``--nominal-fov`` the field of view of the camera's specification (``camera.nominal_fov``).
- **Five-point peers, frame to frame**: OpenCV (``findEssentialMat`` + ``recoverPose``) and
  PoseLib LO-RANSAC with its nonlinear refinement (PoseLib's own defaults, at least 1,000
  iterations, and the early-stopping options of `planar_vo.bench.peers`), each on (a) the
  points of the ACs our front-end extracts between consecutive frames, (b) the same front-end's
  ACs without its per-frame budget (a 12-pixel grid, every textured cell: more points, which a
  five-point RANSAC can use) and (c) DIS 'fast' optical flow sampled at (b)'s grid; 1 px
  threshold. Their scale is the TRUE step length between consecutive frames (from
  ``poses.txt``), which planar_vo does not get.
- **Focal peer**: PoseLib's shared-focal six-point RANSAC and refinement on (b), per frame pair;
  the median of its per-pair focal lengths.
- **Harder conditions** (planar_vo calibrated only, `STRESS`): the same drive driven faster
  (every 2nd and every 3rd frame), with exposure flicker (each frame's brightness scaled by
  U(0.75, 1.25)), and with the principal point assumed at the image centre (what a user with an
  approximate calibration has); each as its own KITTI folder, imported and replayed as above.

Evaluation (`planar_vo.tools.evaluation`): camera trajectories (``T_world_camera``, world = the
first camera frame, as in ``poses.txt``) are put into one z-up frame the same way for every run
and the ground truth (`level_world`: ``T_bc0 T T_bc0^-1`` with a level mount at the camera
height, as ``import_kitti`` does for ``/ground_truth/odom``) and compared: ATE after Sim(3)
alignment and the alignment's scale; drift by the KITTI protocol (100-800 m segments that fit;
a drive shorter than 100 m gets the same protocol with 10-50 m segments, labelled as such), in
3D and on SE(2); the mean per-frame yaw-change error; the share of frames with odometry; the time
per frame on one thread. Frames without odometry are left out of the evaluation, as they are
from the replayed bag; the first frame is every run's origin.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from planar_vo.bench.odometry import (
    FIVE_POINT,
    PEER_GRID_STEP,
    POSELIB_DEFAULTS,
    SOURCES,
    THRESHOLD_PX,
    OdometryRun,
    PeerOdometry,
)
from planar_vo.config.sections import NOMINAL_FOV_RANGE
from planar_vo.errors import InputError

__all__ = [
    'HELP',
    'FrameRecorder',
    'add_arguments',
    'camera_pose',
    'evaluate_run',
    'find_drives',
    'level_world',
    'run',
]

HELP = 'planar_vo, OpenCV and PoseLib on every real drive of a data folder (KITTI layout)'
# The development data sits beside the repository (never inside it: its licence forbids that).
DEFAULT_DATA = Path('..') / 'shared' / 'data'
QUICK_FRAMES = 20

EXAMPLES = """examples:
  planar_vo bench drives --out planar_vo/bench/results/drives
  planar_vo bench drives --quick --out out/bench/drives        20 frames per drive
  planar_vo bench drives --data ~/kitti/sequences --drives 00 05 --skip-focal
  planar_vo bench drives --data ~/kitti/sequences/07 --frames 500 --camera-height 1.65
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``planar_vo bench drives`` (``--out`` is added by the bench command)."""
    parser.epilog = EXAMPLES
    parser.add_argument('--data', type=Path, default=DEFAULT_DATA, metavar='DIR',
                        help='folder of drives in the KITTI layout, or one such drive '
                             '(default: ../shared/data)')
    parser.add_argument('--drives', nargs='+', metavar='NAME',
                        help='drives (sub-folders of --data) to run (default: all)')
    parser.add_argument('--camera-height', type=float, default=1.65, metavar='M',
                        help='camera height above the road in metres, the one setting a user '
                             'of the car knows (default: 1.65, KITTI)')
    parser.add_argument('--nominal-fov', type=float, default=0.0, metavar='RAD',
                        help="the cameras' horizontal field of view as their specification "
                             'states it (rad; KITTI: about 90 deg, 1.5708): one more '
                             'self-calibrated run, with camera.nominal_fov (default: 0, none)')
    parser.add_argument('--frames', type=int, metavar='N',
                        help='only the first N frames of each drive')
    for flag, text in (('--skip-peers', 'no five-point peers'),
                       ('--skip-focal', 'no focal self-calibration run and no focal peer'),
                       ('--skip-stress', 'no runs in harder conditions (faster driving, '
                                         'exposure flicker, an assumed principal point)'),
                       ('--quick', f'smoke run: the first {QUICK_FRAMES} frames of each drive '
                                   f'(unless --frames)')):
        parser.add_argument(flag, action='store_true', help=text)


def run(args: argparse.Namespace) -> int:
    from planar_vo.bench.common import reexec_single_threaded, require

    if args.frames is not None and args.frames < 3:
        raise InputError(f'--frames: expected at least 3 frames, got {args.frames}')
    if not (math.isfinite(args.camera_height) and args.camera_height > 0.0):
        raise InputError(f'--camera-height: expected a positive height in metres, got '
                         f'{args.camera_height}')
    if args.nominal_fov:
        if args.skip_focal:
            raise InputError('--nominal-fov: it adds a self-calibrated run, which --skip-focal '
                             'leaves out; give one of them')
        lo, hi = NOMINAL_FOV_RANGE['rectilinear']      # the KITTI layout's lenses
        fov = args.nominal_fov
        if not lo <= fov <= hi:
            degrees = (f'; in degrees? {fov:g} deg is {math.radians(fov):.4f} rad'
                       if fov > 2.0 * math.pi else '')
            raise InputError(f'--nominal-fov: expected 0 (none) or a horizontal field of view of '
                             f'{lo:g}-{hi:g} rad (the range the focal calibration searches '
                             f'through a rectilinear lens{degrees}), got {fov}')
    drives = find_drives(args.data, args.drives)
    if not (args.skip_peers and args.skip_focal):
        require('poselib')
    code = reexec_single_threaded(args, pin_core=True)
    if code is not None:
        return code
    frames = args.frames if args.frames is not None else (QUICK_FRAMES if args.quick else None)
    results = {}
    for folder in drives:
        start = time.perf_counter()
        results[folder.name] = run_drive(folder, args.camera_height, frames=frames,
                                         peers=not args.skip_peers, focal=not args.skip_focal,
                                         nominal_fov=args.nominal_fov)
        if not args.skip_stress:
            results[folder.name]['stress'] = run_stress(folder, args.camera_height,
                                                        frames=frames)
        results[folder.name]['wall_s'] = time.perf_counter() - start
        print(drive_section(folder.name, results[folder.name]) + '\n', flush=True)
    write_results(Path(args.out), args.command, args.camera_height, results, args.nominal_fov)
    return 0


# ------------------------------------------------------------------------------------------------
# Drives
# ------------------------------------------------------------------------------------------------

def find_drives(data: Path, names: Sequence[str] | None = None) -> list[Path]:
    """The drive folders of ``data`` (sub-folders with ``calib.txt``), or ``data`` itself when it
    is one; with ``names``, those sub-folders in that order.

    Raises:
        InputError: ``data`` is not a folder, has no drive, a named drive is missing, or a drive
            has no ``poses.txt`` (nothing to evaluate against).
    """
    data = Path(data)
    if not data.is_dir():
        raise InputError(f"data: '{data}' is not a directory")
    if (data / 'calib.txt').is_file() and not names:
        drives = [data]
    else:
        found = sorted(p for p in data.iterdir() if (p / 'calib.txt').is_file())
        if names:
            known = {p.name: p for p in found}
            missing = [n for n in names if n not in known]
            if missing:
                raise InputError(f"drives: {', '.join(missing)} not found in '{data}' (drives "
                                 f"there: {', '.join(known) or 'none'})")
            drives = [known[n] for n in dict.fromkeys(names)]
        else:
            drives = found
    if not drives:
        raise InputError(f"data: '{data}' holds no drive in the KITTI layout (a folder with "
                         f'calib.txt, poses.txt, times.txt and image_l/ or image_0/)')
    for folder in drives:
        if not (folder / 'poses.txt').is_file():
            raise InputError(f"drives: '{folder}' has no poses.txt (no ground truth to compare "
                             f'with)')
        if not (folder / 'times.txt').is_file():
            # (a user test: the importer's advice to give a frame rate, an option the
            # benchmark does not have)
            raise InputError(f"drives: '{folder}' has no times.txt (the frames' times, which "
                             f'the evaluation needs)')
    return drives


def first_frames(folder: Path, count: int, into: Path) -> Path:
    """A drive folder holding the first ``count`` frames of ``folder`` (images linked, text
    files cut), created in ``into``; the folder itself when it has no more frames."""
    from planar_vo.io.kitti import read_kitti_sequence

    seq = read_kitti_sequence(folder)
    if len(seq.images) <= count:
        return folder
    view = into / folder.name
    (view / 'image_l').mkdir(parents=True)
    for path in seq.images[:count]:
        (view / 'image_l' / path.name).symlink_to(path.resolve())
    _write_texts(view, seq.P0, seq.times[:count], seq.poses[:count])
    return view


def _write_texts(view: Path, P0: np.ndarray, times: np.ndarray, poses: np.ndarray) -> None:
    """``calib.txt`` (P0 only), ``times.txt`` and ``poses.txt`` of a KITTI drive folder."""
    def numbers(values: np.ndarray) -> str:
        return ' '.join(repr(float(v)) for v in values.ravel())

    (view / 'calib.txt').write_text(numbers(P0) + '\n', encoding='utf-8')
    (view / 'times.txt').write_text(''.join(f'{t}\n' for t in times), encoding='utf-8')
    (view / 'poses.txt').write_text(''.join(numbers(p[:3]) + '\n' for p in poses),
                                    encoding='utf-8')


# The drive in harder conditions (module docstring): key, label, kind, parameter.
STRESS = (
    ('x2', 'every 2nd frame (2x speed)', 'stride', 2),
    ('x3', 'every 3rd frame (3x speed)', 'stride', 3),
    ('flicker', 'exposure flicker (brightness x U(0.75, 1.25) per frame)', 'flicker', 0.25),
    ('centre', 'principal point assumed at the image centre', 'centre', 0),
)


def stress_folder(folder: Path, kind: str, value: float, into: Path) -> Path:
    """A KITTI drive folder in ``into`` holding ``folder`` in a harder condition: ``'stride'``
    (every ``value``-th frame), ``'flicker'`` (frame ``i``'s brightness times a gain drawn from
    ``U(1 - value, 1 + value)`` with seed ``i``, saturating at 255) or ``'centre'`` (the
    principal point of ``calib.txt`` moved to the image centre)."""
    import cv2

    from planar_vo.io.kitti import read_kitti_sequence

    if kind not in ('stride', 'flicker', 'centre'):
        raise InputError(f"kind: expected 'stride', 'flicker' or 'centre', got {kind!r}")
    seq = read_kitti_sequence(folder)
    index = np.arange(0, len(seq.images), int(value) if kind == 'stride' else 1)
    (into / 'image_l').mkdir(parents=True)
    P0 = np.array(seq.P0, dtype=np.float64)
    for k, i in enumerate(index):
        target = into / 'image_l' / f'{k:06d}{seq.images[i].suffix}'
        if kind == 'flicker':
            image = cv2.imread(str(seq.images[i]), cv2.IMREAD_UNCHANGED)
            if image is None:
                raise InputError(f"'{seq.images[i]}' is not a readable image")
            gain = np.random.default_rng(int(i)).uniform(1.0 - value, 1.0 + value)
            cv2.imwrite(str(target), np.clip(np.rint(image * gain), 0, 255).astype(np.uint8))
        else:
            target.symlink_to(seq.images[i].resolve())
    if kind == 'centre':
        image = cv2.imread(str(seq.images[0]), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise InputError(f"'{seq.images[0]}' is not a readable image")
        P0[0, 2], P0[1, 2] = (image.shape[1] - 1) / 2.0, (image.shape[0] - 1) / 2.0
    _write_texts(into, P0, np.asarray(seq.times)[index], np.asarray(seq.poses)[index])
    return into


def run_stress(folder: Path, height: float, *, frames: int | None = None) -> dict:
    """planar_vo (shipped defaults + camera height, calibrated) on ``folder`` in every `STRESS`
    condition: per key its label, frame count and `evaluate_run` metrics."""
    from planar_vo.config import PlanarVoConfig
    from planar_vo.core.trajectory import Trajectory
    from planar_vo.io import import_kitti
    from planar_vo.io.kitti import read_kitti_sequence

    progress = sys.stderr.isatty()
    config = PlanarVoConfig.from_flat({'mount.height': float(height)})
    out = {}
    with tempfile.TemporaryDirectory(prefix='planar_vo_stress_') as tmp:
        tmp = Path(tmp)
        source = first_frames(folder, frames, tmp / 'source') if frames else folder
        for key, label, kind, value in STRESS:
            view = stress_folder(source, kind, value, tmp / key / 'drive')
            seq = read_kitti_sequence(view)
            import_kitti(view, tmp / key / 'bag', camera_height=height, progress=progress)
            run = replay_planar_vo(tmp / key / 'bag', tmp / key / 'replayed', config,
                                   progress=progress)
            if len(run.stamps_ns) != len(seq.images):
                raise InputError(f'{folder.name} ({label}): the replay saw '
                                 f'{len(run.stamps_ns)} frames of {len(seq.images)}')
            gt = Trajectory.from_poses(run.stamps_ns, level_world(seq.poses, height))
            metrics = evaluate_run(gt, run, height)
            metrics.pop('_yaw_abs_deg', None)            # (no paired comparison here)
            out[key] = {'label': label, 'frames': len(seq.images), **run.extra, **metrics}
    return out


def run_drive(folder: Path, height: float, *, frames: int | None = None, peers: bool = True,
              focal: bool = True, nominal_fov: float = 0.0) -> dict:
    """Every run on one drive and its evaluation (JSON-ready apart from NaN); with a
    ``nominal_fov`` (rad) and ``focal``, one more self-calibrated run that states it."""
    from planar_vo.config import PlanarVoConfig
    from planar_vo.core.trajectory import Trajectory
    from planar_vo.io import import_kitti, iter_camera_frames, open_bag
    from planar_vo.io.kitti import read_kitti_sequence

    progress = sys.stderr.isatty()
    # What a user of the car sets: the camera height; everything else is the shipped default.
    settings = {'mount.height': float(height)}
    config = PlanarVoConfig.from_flat(settings)
    focal_settings = {**settings, 'camera.estimate_focal': True}
    with tempfile.TemporaryDirectory(prefix='planar_vo_drives_') as tmp:
        tmp = Path(tmp)
        source = first_frames(folder, frames, tmp) if frames else folder
        seq = read_kitti_sequence(source)
        bag = tmp / 'drive'
        import_kitti(source, bag, camera_height=height, progress=progress)
        calibrated = replay_planar_vo(bag, tmp / 'replayed', config, progress=progress)
        # Offline, the focal length self-calibrated over the whole drive from its first frame.
        two_pass = (replay_planar_vo(bag, tmp / 'two_pass', PlanarVoConfig.from_flat(
            focal_settings), progress=progress, two_pass=True, label=FOCAL_2PASS_LABEL)
            if focal else None)

        # One pass over the bag's frames: the stamps, the focal run and the peers.
        true_steps = np.linalg.norm(np.diff(seq.poses[:, :3, 3], axis=0), axis=1)
        self_cal = FocalRun(PlanarVoConfig.from_flat(focal_settings)) if focal else None
        # The same with the principal point given (what a user who knows it sets): the
        # focal length's dependence on the assumed principal point, measured.
        pp_settings = {**focal_settings, 'camera.cx': float(seq.P0[0, 2]),
                       'camera.cy': float(seq.P0[1, 2])}
        self_cal_pp = FocalRun(PlanarVoConfig.from_flat(pp_settings),
                               label=FOCAL_PP_LABEL) if focal else None
        # The same with the field of view from the camera's specification (what a user who
        # has its data sheet sets): where the calibration starts.
        fov_settings = {**focal_settings, 'camera.nominal_fov': float(nominal_fov)}
        self_cal_fov = (FocalRun(PlanarVoConfig.from_flat(fov_settings), label=FOCAL_FOV_LABEL)
                        if focal and nominal_fov > 0 else None)
        peer = (PeerOdometry(FIVE_POINT if peers else (), SOURCES if peers else (), focal=focal)
                if peers or focal else None)
        stamps = []
        with open_bag(bag) as reader:
            for i, frame in enumerate(_bar(iter_camera_frames(reader), len(seq.images),
                                           'frames', progress)):
                stamps.append(frame.stamp_ns)
                if self_cal is not None:
                    self_cal.add(frame)
                    self_cal_pp.add(frame)
                if self_cal_fov is not None:
                    self_cal_fov.add(frame)
                if peer is not None:
                    peer.add(frame.image, frame.camera, true_steps[i - 1] if i else 0.0)
    stamps = np.array(stamps, dtype=np.int64)
    if len(stamps) != len(seq.images):
        raise InputError(f'{folder.name}: the bag holds {len(stamps)} frames, the folder '
                         f'{len(seq.images)}')
    gt = Trajectory.from_poses(stamps, level_world(seq.poses, height))
    runs = {'planar_vo': calibrated.aligned(stamps)}
    if self_cal is not None:
        runs['planar_vo_focal'] = self_cal.run.aligned(stamps)
        runs['planar_vo_focal_pp'] = self_cal_pp.run.aligned(stamps)
    if self_cal_fov is not None:
        runs['planar_vo_focal_fov'] = self_cal_fov.run.aligned(stamps)
    if two_pass is not None:
        runs['planar_vo_focal_2pass'] = two_pass.aligned(stamps)
    if peer is not None:
        runs.update(peer.runs(stamps))
    out = {
        'folder': str(folder), 'frames': len(stamps), 'path_length_m': gt.path_length,
        'duration_s': float((stamps[-1] - stamps[0]) / 1e9), 'true_focal_px': float(seq.P0[0, 0]),
        'settings': settings,
        'runs': {key: {'label': r.label, 'scale': r.scale, **r.extra, **evaluate_run(gt, r, height)}
                 for key, r in runs.items()},
    }
    ours = out['runs']['planar_vo'].pop('_yaw_abs_deg', {})
    per_frame = {}
    for key, run in out['runs'].items():
        theirs = per_frame[key] = run.pop('_yaw_abs_deg', {})
        if key != 'planar_vo':
            run['yaw_paired_vs_planar_vo'] = paired_yaw(ours, theirs)
    if focal:
        out['focal'] = {'self_calibrated': {'settings': focal_settings,
                                            **self_cal.summary(float(seq.P0[0, 0]))},
                        'principal_point_given': {'settings': pp_settings,
                                                  **self_cal_pp.summary(float(seq.P0[0, 0]))},
                        'six_point': peer.focal_summary(float(seq.P0[0, 0]))}
        if self_cal_fov is not None:
            out['focal']['field_of_view_given'] = {
                'settings': fov_settings, **self_cal_fov.summary(float(seq.P0[0, 0]))}
        bound = causal_bound(ours, per_frame['planar_vo_focal'], self_cal.first_pair_ns)
        bound['first_pair_frame'] = (None if self_cal.first_pair_ns is None else
                                     int(np.searchsorted(stamps, self_cal.first_pair_ns)))
        out['focal']['self_calibrated']['causal_bound'] = bound
    return out


def causal_bound(calibrated: dict, self_calibrated: dict, first_pair_ns: int | None) -> dict:
    """The least per-frame yaw-change error a causal self-calibration could have on this
    drive: the self-calibrated run's own errors over the frames before its first turning pair
    (no calibration can know the focal length before the car turns), the calibrated run's
    after it (a calibration perfect at once). Both ``{(stamp_ns, next stamp_ns): |e| deg}``;
    ``first_pair_ns`` the stamp of the frame that offered the first turning pair (None: the
    whole drive is before it)."""
    errors = []
    for key, e in calibrated.items():
        before = first_pair_ns is None or key[1] <= first_pair_ns
        value = self_calibrated.get(key) if before else e
        if value is not None and math.isfinite(value):
            errors.append(value)
    return {'first_pair_stamp_ns': first_pair_ns,
            'mean_deg': float(np.mean(errors)) if errors else math.nan}


def _bar(items, total: int, desc: str, progress: bool):
    from tqdm import tqdm

    return tqdm(items, total=total, desc=desc, unit='frame', file=sys.stderr,
                disable=not progress, leave=False)


# ------------------------------------------------------------------------------------------------
# Trajectories
# ------------------------------------------------------------------------------------------------

def level_world(poses: np.ndarray, height: float) -> np.ndarray:
    """Camera poses ``T_world_camera`` ``(N, 4, 4)`` (world = the first camera frame, optical
    axes) in a z-up frame: ``T_bc0 T T_bc0^-1`` with ``T_bc0`` a level mount at ``height``
    (`planar_vo.core.conventions.mount_transform`), as ``import_kitti`` writes the ground truth.
    The same map for the ground truth and every estimate: z is up, so SE(2) drops the right
    angles, and errors are measured for the point ``height`` below the camera (the vehicle)."""
    from planar_vo.core.conventions import invert, mount_transform

    T_bc0 = mount_transform(height=height)
    return T_bc0 @ np.asarray(poses, dtype=np.float64) @ invert(T_bc0)


def camera_pose(result) -> np.ndarray:
    """``T_world_camera`` after a pipeline frame (world = the first camera frame)."""
    return np.asarray(result.camera_pose, dtype=np.float64)


class FrameRecorder:
    """A replay `FrameProcessor` that keeps every `FrameResult` of the processor it wraps."""

    def __init__(self, processor) -> None:
        self.processor = processor
        self.stamps: list[float] = []
        self.results: list = []

    def process(self, image, stamp, camera):
        result = self.processor.process(image, stamp, camera)
        self.stamps.append(stamp)
        self.results.append(result)
        return result

    def add_speed(self, stamp: float, speed: float) -> None:
        self.processor.add_speed(stamp, speed)

    def __getattr__(self, name: str):
        # The rest is the processor's (its config, focal_status, start_from_first_pass); not
        # before it is set (copy and pickle look attributes up on a bare instance).
        if name == 'processor':
            raise AttributeError(name)
        return getattr(self.processor, name)


def _pipeline_run(label: str, scale: str, stamps_s: Sequence[float], results: list,
                  extra: dict) -> OdometryRun:
    stamps_ns = np.array([round(s * 1e9) for s in stamps_s], dtype=np.int64)
    poses = np.array([camera_pose(r) for r in results]).reshape(-1, 4, 4)
    timed = results[1:]
    return OdometryRun(
        label, scale, stamps_ns, poses, np.array([r.ok for r in results], dtype=bool),
        np.array([r.timings.get('total', np.nan) for r in timed]),
        np.array([r.timings.get('solve', np.nan) for r in timed]),
        {'dropped': dict(Counter(r.reason.value for r in results if not r.ok)), **extra})


def _scale_label(config) -> str:
    return f'own: {config.scale.source}, height {config.mount.height:g} m'


def replay_planar_vo(bag: Path, out: Path, config, *, progress: bool = False,
                     two_pass: bool = False, label: str = '') -> OdometryRun:
    """planar_vo as a user runs it: `replay_bag` of the bag through `VisualOdometry(config)`
    (``two_pass``: ``planar_vo replay --two-pass``, the focal length self-calibrated by a
    first pass)."""
    from planar_vo.pipeline import VisualOdometry
    from planar_vo.tools.replay import replay_bag

    vo = VisualOdometry(config)
    recorder = FrameRecorder(vo)
    summary = replay_bag(bag, out, recorder, progress=progress, two_pass=two_pass)
    extra = {'replay_wall_s': summary.wall_time, 'replay_frames': summary.frames_in,
             'replay_odometry': summary.odometry_out}
    cal = vo.focal_calibrator
    if cal is not None:
        extra.update(focal_status=vo.focal_status(), focal_in_use_px=float(vo.camera.fx),
                     focal_in_use_std_px=float(vo.camera.fx * cal.relative_std),
                     first_pass=summary.first_pass)
    return _pipeline_run(label or 'planar_vo, shipped defaults + camera height (replay)',
                         _scale_label(config), recorder.stamps, recorder.results, extra)


FOCAL_LABEL = 'planar_vo, self-calibrated focal (no CameraInfo)'
FOCAL_2PASS_LABEL = ('planar_vo, self-calibrated focal, two passes (offline: replay --two-pass, '
                     'no CameraInfo)')
FOCAL_PP_LABEL = 'planar_vo, self-calibrated focal, principal point given (camera.cx, cy)'
FOCAL_FOV_LABEL = 'planar_vo, self-calibrated focal, field of view given (camera.nominal_fov)'


class FocalRun:
    """planar_vo without CameraInfo, self-calibrating its focal length, frame by frame."""

    def __init__(self, config, label: str = FOCAL_LABEL) -> None:
        from planar_vo.pipeline import VisualOdometry

        self.config = config
        self.label = label
        self.vo = VisualOdometry(config)
        self.stamps: list[float] = []
        self.results: list = []
        self.first_pair_ns: int | None = None        # the frame that offered the first pair

    def add(self, frame) -> None:
        """One `planar_vo.io.CameraFrame`; its CameraInfo is withheld (``camera=None``)."""
        if frame.image is None:
            return                       # replay counts it too (bad_image, bad_stamp)
        self.results.append(self.vo.process(frame.image, frame.stamp, None))
        self.stamps.append(frame.stamp)
        cal = self.vo.focal_calibrator
        if self.first_pair_ns is None and cal is not None and \
                cal.pairs + cal.pending + cal.rejected > 0:
            self.first_pair_ns = int(frame.stamp_ns)

    @property
    def run(self) -> OdometryRun:
        return _pipeline_run(self.label, _scale_label(self.config), self.stamps, self.results,
                             {'focal_status': self.vo.focal_status()})

    def summary(self, true_focal: float) -> dict:
        """The focal length in use at the end (adopted or provisional) and the calibration's
        own estimate with its reported standard deviation (3-sigma honest), against the
        truth."""
        calibrator = self.vo.focal_calibrator
        in_use = float(calibrator.provisional) if calibrator is not None else math.nan
        estimate, std, info = calibrator.estimate() if calibrator is not None else \
            (math.nan, math.inf, {})
        adopted = calibrator is not None and calibrator.adopted is not None
        if adopted:
            estimate, std = calibrator.adopted, calibrator.adopted_std
        error = estimate - true_focal
        return {'focal_px': float(estimate), 'in_use_px': in_use, 'adopted': adopted,
                'adopted_at_frame': calibrator.adopted_at if adopted else None,
                'std_px': float(std), 'error_px': float(error),
                'error_pct': 100.0 * float(error) / true_focal,
                'error_over_std': abs(error) / std if std > 0 else math.nan,
                'pairs': calibrator.pairs if calibrator is not None else 0,
                'blocks': info.get('blocks', 0), 'pending': calibrator.pending if calibrator
                else 0, 'status': self.vo.focal_status()}


# ------------------------------------------------------------------------------------------------
# Evaluation
# ------------------------------------------------------------------------------------------------

# Contiguous batches of frame pairs for the standard error of a paired mean difference
# (`paired_yaw`): neighbouring frames share errors (the ground truth's own, the scenery).
_BATCHES = 10


def paired_yaw(ours: dict, theirs: dict) -> dict:
    """planar_vo's per-frame |yaw-change error| minus a peer's, over the frame pairs both have
    (``{(stamp_ns, next stamp_ns): |e| deg}`` each): the mean difference (negative: planar_vo
    closer to the ground truth) and its batch-means standard error (`_BATCHES` contiguous
    batches: the per-frame differences are not independent), NaN with fewer than 2 pairs per
    batch."""
    stamps = sorted(set(ours) & set(theirs))
    d = np.array([ours[s] - theirs[s] for s in stamps], dtype=np.float64)
    d = d[np.isfinite(d)]
    mean = float(np.mean(d)) if d.size else math.nan
    se = math.nan
    if d.size >= 2 * _BATCHES:
        means = np.array([b.mean() for b in np.array_split(d, _BATCHES)])
        se = float(np.std(means, ddof=1) / math.sqrt(_BATCHES))
    return {'frames': int(d.size), 'mean_diff_deg': mean, 'se_deg': se}


def _ms(seconds: np.ndarray) -> dict[str, float]:
    s = np.asarray(seconds, dtype=np.float64)
    s = s[np.isfinite(s)]
    if not s.size:
        return {'median': math.nan, 'mean': math.nan}
    return {'median': 1e3 * float(np.median(s)), 'mean': 1e3 * float(np.mean(s))}


def evaluate_run(gt, run: OdometryRun, height: float) -> dict:
    """A run against the ground truth (see the module docstring).

    Args:
        gt: the ground-truth camera trajectory in the z-up frame (`level_world`), a
            `planar_vo.core.Trajectory` with one pose per frame of the run.
        run: the run, aligned to the ground truth's frames (`OdometryRun.aligned`).
        height: the camera height of `level_world`.

    Returns:
        JSON-ready metrics: ``odometry_pct`` (frames after the first with odometry),
        ``yaw_change_error_deg`` and ``heading_error_deg`` (statistics of |e|), ``ate_m``
        (after Sim(3) alignment), ``sim3_scale``, ``kitti`` and ``kitti_se2``
        (`kitti_drift`, 100-800 m), and when no 100 m segment fits ``kitti_short`` and
        ``kitti_short_se2`` (10-50 m); ``ms_per_frame`` and ``estimator_ms_per_frame``;
        ``_yaw_abs_deg`` the per-frame |yaw-change error| by the frame pair's two stamps (for
        `paired_yaw`; the callers remove it: not JSON output).
    """
    from planar_vo.core.trajectory import Trajectory
    from planar_vo.tools.evaluation import evaluate

    use = run.ok.copy()
    use[0] = True                                   # the origin of every run
    out = {'frames_with_odometry': int(np.count_nonzero(run.ok[1:])),
           'odometry_pct': 100.0 * float(np.mean(run.ok[1:])) if len(run.ok) > 1 else math.nan,
           'ms_per_frame': _ms(run.seconds),
           'estimator_ms_per_frame': _ms(run.estimator_seconds)}
    est = Trajectory.from_poses(run.stamps_ns[use], level_world(run.poses[use], height))
    try:
        ev = evaluate(gt, est, align='sim3')
    except InputError as err:
        out['evaluation_error'] = str(err)
        return out
    m = ev.metrics()
    # Per frame pair, by the stamps of its two frames (a run that lost a frame has a longer
    # pair there, compared with nobody's): for the paired comparison of the runs
    # (`paired_yaw`); the callers take it out again before the JSON is written.
    stamps = ev.est.stamps_ns.tolist()
    out['_yaw_abs_deg'] = dict(zip(zip(stamps[:-1], stamps[1:]),
                                   np.abs(ev.yaw_change_error_deg).tolist()))
    out.update(yaw_change_error_deg=m['yaw_change_error_deg'],
               heading_error_deg=m['heading_error_deg'], ate_m=m['ate_m'],
               sim3_scale=ev.alignment.scale, kitti=m['kitti'], kitti_se2=m['kitti_se2'])
    if 'kitti_short' in m:          # no 100 m segment fits: `evaluate`'s 10-50 m figures
        out['kitti_short'], out['kitti_short_se2'] = m['kitti_short'], m['kitti_short_se2']
    return out


# ------------------------------------------------------------------------------------------------
# Report
# ------------------------------------------------------------------------------------------------

def _get(run: dict, *keys: str) -> float:
    value = run
    for key in keys:
        if not isinstance(value, dict) or key not in value:
            return math.nan
        value = value[key]
    return math.nan if value is None else float(value)


def _protocol(drive: dict) -> tuple[str, str]:
    """The drift keys of a drive and their label: the KITTI lengths, or 10-50 m segments when
    no 100 m segment fits."""
    if any('kitti_short' in r for r in drive['runs'].values()):
        return 'kitti_short', '10-50 m segments (drive < 100 m)'
    return 'kitti', '100-800 m segments'


def _fmt(value: float, digits: int = 3) -> str:
    from planar_vo.bench.common import format_cell

    return format_cell(value, digits)


def drive_section(name: str, drive: dict) -> str:
    """Markdown: a drive's table, its focal rows and the targets."""
    from planar_vo.bench.common import markdown_table

    key, segments = _protocol(drive)
    header = ['method', 'scale', 'frames with odometry (%)', 'yaw-change error, mean abs. (deg)',
              f'r_rel 3D (deg/100 m), {segments}', 'r_rel SE(2) (deg/100 m)', 't_rel 3D (%)',
              't_rel SE(2) (%)', 'ATE rmse after Sim(3) (m)', 'Sim(3) scale',
              'ms / frame (median)', 'estimator ms / frame (median)']
    rows = []
    for r in drive['runs'].values():
        rows.append([r['label'], r['scale'], _fmt(r['odometry_pct']),
                     _fmt(_get(r, 'yaw_change_error_deg', 'mean')),
                     _fmt(_get(r, key, 'r_rel_deg_per_100m')),
                     _fmt(_get(r, f'{key}_se2', 'r_rel_deg_per_100m')),
                     _fmt(_get(r, key, 't_rel_pct')), _fmt(_get(r, f'{key}_se2', 't_rel_pct')),
                     _fmt(_get(r, 'ate_m', 'rmse')), _fmt(_get(r, 'sim3_scale'), 4),
                     _fmt(_get(r, 'ms_per_frame', 'median')),
                     _fmt(_get(r, 'estimator_ms_per_frame', 'median'))])
    used = next((r[key]['lengths_m'] for r in drive['runs'].values() if key in r), [])
    lines = [f"## {name}: {drive['frames']} frames, {drive['path_length_m']:.1f} m, "
             f"{drive['duration_s']:.1f} s",
             '', f"Benchmark wall time on this drive (every run): {drive['wall_s']:.0f} s.",
             '', markdown_table(header, rows, 'll' + 'r' * (len(header) - 2)), '',
             f"Drift segments: {', '.join(f'{v:g}' for v in used) or 'none'} m, a start every "
             f"10 frames. The peers' scale is the TRUE step length between consecutive frames."]
    if 'focal' in drive:
        lines += ['', focal_table(drive)]
    if 'stress' in drive:
        lines += ['', stress_table(drive)]
    lines += ['', targets(drive)]
    return '\n'.join(lines)


def stress_table(drive: dict) -> str:
    """Markdown: planar_vo (calibrated) on the drive as recorded and in harder conditions."""
    from planar_vo.bench.common import markdown_table

    key, segments = _protocol(drive)
    header = ['condition', 'frames', 'frames with odometry (%)', 'frames lost (reasons)',
              'yaw-change error, mean abs. (deg)', f'r_rel 3D (deg/100 m), {segments}',
              'r_rel SE(2) (deg/100 m)', 't_rel 3D (%)', 'Sim(3) scale']
    rows = []
    for label, frames, r in [('as recorded', drive['frames'], drive['runs']['planar_vo'])] + [
            (r['label'], r['frames'], r) for r in drive['stress'].values()]:
        lost = {k: v for k, v in r.get('dropped', {}).items() if k != 'first_frame'}
        rows.append([label, str(frames), _fmt(r['odometry_pct']),
                     ', '.join(f'{k} {v}' for k, v in lost.items()) or '-',
                     _fmt(_get(r, 'yaw_change_error_deg', 'mean')),
                     _fmt(_get(r, key, 'r_rel_deg_per_100m')),
                     _fmt(_get(r, f'{key}_se2', 'r_rel_deg_per_100m')),
                     _fmt(_get(r, key, 't_rel_pct')), _fmt(_get(r, 'sim3_scale'), 4)])
    return '\n'.join(['### Harder conditions (planar_vo, calibrated; no peers)', '',
                      markdown_table(header, rows, 'lrrl' + 'r' * (len(header) - 4))])


def focal_table(drive: dict) -> str:
    """Markdown: the self-calibrated focal length beside the calibrated run and the focal peer."""
    from planar_vo.bench.common import markdown_table

    key, _ = _protocol(drive)
    true = drive['true_focal_px']
    cal = drive['runs']['planar_vo']
    six = drive['focal']['six_point']

    def status(f: dict) -> str:
        if f['adopted']:
            return f"self-calibrated at frame {f['adopted_at_frame']}"
        if not math.isfinite(f['focal_px']):
            return (f"no estimate (no turning pair); runs on the provisional "
                    f"{f['in_use_px']:.1f} px")
        return (f"not adopted ({f['pairs']} turning pairs in {f['blocks']} blocks); runs on "
                f"the provisional {f['in_use_px']:.1f} px")

    def self_calibrated(run: str, key: str) -> list[str]:
        f, r = drive['focal'][key], drive['runs'][run]
        return [r['label'], _fmt(f['focal_px'], 4), _fmt(f['error_pct']), status(f),
                _fmt(f['std_px']), _fmt(f['error_over_std']), *odometry(r)]

    def odometry(r: dict) -> list[str]:
        return [_fmt(r['odometry_pct']), _fmt(_get(r, 'yaw_change_error_deg', 'mean')),
                _fmt(_get(r, key, 'r_rel_deg_per_100m')),
                _fmt(_get(r, f'{key}_se2', 'r_rel_deg_per_100m')), _fmt(_get(r, key, 't_rel_pct'))]

    def two_passes(r: dict) -> list[str]:
        f, std = r['focal_in_use_px'], r['focal_in_use_std_px']
        return [r['label'], _fmt(f, 4), _fmt(100.0 * (f - true) / true),
                "the first pass's, used from the first frame", _fmt(std),
                _fmt(abs(f - true) / std), *odometry(r)]

    header = ['run', 'focal length (px)', 'error (%)', 'status', 'reported std (px)',
              'abs. error / std', 'frames with odometry (%)', 'yaw-change error (deg)',
              'r_rel 3D (deg/100 m)', 'r_rel SE(2) (deg/100 m)', 't_rel 3D (%)']
    q25, q75 = six['iqr_px']
    rows = [
        ['planar_vo, calibrated (CameraInfo)', _fmt(true, 4), '0', 'given', '-', '-',
         *odometry(cal)],
        self_calibrated('planar_vo_focal', 'self_calibrated'),
        self_calibrated('planar_vo_focal_pp', 'principal_point_given'),
        *([self_calibrated('planar_vo_focal_fov', 'field_of_view_given')]
          if 'field_of_view_given' in drive['focal'] else []),
        *([two_passes(drive['runs']['planar_vo_focal_2pass'])]
          if 'planar_vo_focal_2pass' in drive['runs'] else []),
        [six['label'], _fmt(six['focal_px'], 4), _fmt(six['error_pct']),
         f"median of {six['pairs_with_focal']} of {six['pairs']} pairs (IQR {_fmt(q25)}-"
         f"{_fmt(q75)} px), {_fmt(six['estimator_ms_median'])} ms / pair", '-', '-',
         '-', '-', '-', '-', '-'],
    ]
    align = 'lrrl' + 'r' * (len(header) - 4)
    return '\n'.join([f'### Focal length (true {true:.1f} px)', '',
                      markdown_table(header, rows, align)])


def _check(label: str, value: float, bound: float, text: str) -> str:
    if not (math.isfinite(value) and math.isfinite(bound)):
        return f'- {label}: {_fmt(value)} ({text} {_fmt(bound)}): not measured'
    verdict = 'met' if value <= bound else 'NOT met'
    return f'- {label}: {_fmt(value)} ({text} {_fmt(bound)}): {verdict}'


def _paired_note(peers: list[dict]) -> str:
    """The best PoseLib row's paired yaw difference, for the yaw target's line."""
    rows = [r for r in peers if math.isfinite(_get(r, 'yaw_change_error_deg', 'mean'))
            and 'yaw_paired_vs_planar_vo' in r]
    if not rows:
        return ''
    p = min(rows, key=lambda r: _get(r, 'yaw_change_error_deg', 'mean'))[
        'yaw_paired_vs_planar_vo']
    if not math.isfinite(p['se_deg']):
        return (f'; frame by frame, planar_vo minus that row {p["mean_diff_deg"]:+.2e} deg (mean '
                f'of the {p["frames"]} per-frame |e| differences; too few for a standard error '
                f'from {_BATCHES} batches)')
    return (f'; frame by frame, planar_vo minus that row {p["mean_diff_deg"]:+.2e} +- '
            f'{p["se_deg"]:.2e} deg (mean of the {p["frames"]} per-frame |e| differences +- its '
            f'standard error from {_BATCHES} contiguous batches)')


def targets(drive: dict) -> str:
    """Markdown: issue 10's and issue 14's targets on this drive."""
    key, segments = _protocol(drive)
    runs = drive['runs']
    ours = runs['planar_vo']
    peers = [r for k, r in runs.items() if k.startswith('poselib')]

    def best(*keys: str) -> float:
        values = [_get(r, *keys) for r in peers]
        values = [v for v in values if math.isfinite(v)]
        return min(values) if values else math.nan

    lines = ['Targets (issue 10; "PoseLib" = the best of the PoseLib five-point rows):',
             _check('planar_vo yaw-change error (deg)', _get(ours, 'yaw_change_error_deg', 'mean'),
                    best('yaw_change_error_deg', 'mean'), 'PoseLib') + _paired_note(peers),
             _check(f'r_rel 3D (deg/100 m, {segments})', _get(ours, key, 'r_rel_deg_per_100m'),
                    best(key, 'r_rel_deg_per_100m'), 'PoseLib'),
             _check('r_rel SE(2) (deg/100 m)', _get(ours, f'{key}_se2', 'r_rel_deg_per_100m'),
                    best(f'{key}_se2', 'r_rel_deg_per_100m'), 'PoseLib'),
             _check('t_rel 3D (%)', _get(ours, key, 't_rel_pct'), 3.0, 'target'),
             _check('Sim(3) scale, |s - 1| (%)', 100.0 * abs(_get(ours, 'sim3_scale') - 1.0),
                    3.0, 'target'),
             _check('frames without odometry (%)', 100.0 - ours['odometry_pct'], 3.0,
                    'target')]
    if 'focal' in drive:
        f = drive['focal']['self_calibrated']
        own = runs['planar_vo_focal']
        lines += ['', 'Targets (issue 14; the 2 % bound holds for drives with a real turn):',
                  _check('|focal error| (%)', abs(f['error_pct']), 2.0, 'target'),
                  _check('|error| / reported std, if adopted', f['error_over_std']
                         if f['adopted'] else math.nan, 3.0, 'target'),
                  _check('frames without odometry, self-calibrated (%)',
                         100.0 - own['odometry_pct'], 5.0, 'target'),
                  _check('yaw-change error, self-calibrated (deg)',
                         _get(own, 'yaw_change_error_deg', 'mean'),
                         1.5 * _get(ours, 'yaw_change_error_deg', 'mean'), '1.5x calibrated')]
        bound = f.get('causal_bound')
        if bound is not None:
            first = bound['first_pair_frame']
            how = (f"the self-calibrated run's per-frame errors until its first turning pair, "
                   f"at frame {first}, the calibrated run's after it" if first is not None else
                   "no turning pair: the self-calibrated run's own errors")
            lines.append(
                f"  - the least a causal self-calibration could reach here ({how}): "
                f"{_fmt(bound['mean_deg'])} deg, "
                f"{_fmt(bound['mean_deg'] / _get(ours, 'yaw_change_error_deg', 'mean'))}x "
                f'calibrated')
        two = runs.get('planar_vo_focal_2pass')
        if two is not None:
            yaw = _get(two, 'yaw_change_error_deg', 'mean')
            lines.append(
                f"  - offline, two passes (replay --two-pass: the focal length of a first pass "
                f"over the whole drive from the first frame on): {_fmt(yaw)} deg, "
                f"{_fmt(yaw / _get(ours, 'yaw_change_error_deg', 'mean'))}x calibrated; t_rel "
                f"3D {_fmt(_get(two, key, 't_rel_pct'))} %, frames without odometry "
                f"{_fmt(100.0 - two['odometry_pct'])} %")
    return '\n'.join(lines)


def summary_table(results: dict) -> str:
    """Markdown: the main numbers of every run on every drive."""
    from planar_vo.bench.common import markdown_table

    keys = list(dict.fromkeys(k for d in results.values() for k in d['runs']))
    header = ['method']
    for name, drive in results.items():
        key, _ = _protocol(drive)
        seg = ', 10-50 m segments' if key == 'kitti_short' else ''
        header += [f'{name}: yaw err. (deg)', f'{name}: r_rel 3D (deg/100 m{seg})',
                   f'{name}: r_rel SE(2) (deg/100 m{seg})', f'{name}: t_rel 3D (%{seg})']
    rows = []
    for k in keys:
        label = next(d['runs'][k]['label'] for d in results.values() if k in d['runs'])
        row = [label]
        for drive in results.values():
            key, _ = _protocol(drive)
            r = drive['runs'].get(k, {})
            row += [_fmt(_get(r, 'yaw_change_error_deg', 'mean')),
                    _fmt(_get(r, key, 'r_rel_deg_per_100m')),
                    _fmt(_get(r, f'{key}_se2', 'r_rel_deg_per_100m')),
                    _fmt(_get(r, key, 't_rel_pct'))]
        rows.append(row)
    lines = ['## Summary across drives', '',
             'Mean per-frame yaw-change error (deg), drift r_rel (deg/100 m) and t_rel (%) by '
             'the KITTI protocol; the five-point peers use the TRUE step length as scale.', '',
             markdown_table(header, rows)]
    focal = {n: d for n, d in results.items() if 'focal' in d}
    if focal:
        rows = []
        for name, drive in focal.items():
            f, six = drive['focal']['self_calibrated'], drive['focal']['six_point']
            pp = drive['focal']['principal_point_given']
            status = (f"adopted at frame {f['adopted_at_frame']}" if f['adopted']
                      else 'provisional')
            rows.append([name, _fmt(drive['true_focal_px'], 4), _fmt(f['focal_px'], 4),
                         _fmt(f['error_pct']), status, _fmt(f['std_px']),
                         _fmt(f['error_over_std']), _fmt(pp['focal_px'], 4),
                         _fmt(pp['error_pct']), _fmt(pp['std_px']), _fmt(six['focal_px'], 4),
                         _fmt(six['error_pct'])])
        lines += ['', markdown_table(
            ['drive', 'true focal (px)', 'planar_vo self-calibrated (px)', 'error (%)', 'status',
             'reported std (px)', 'abs. error / std', 'principal point given (px)',
             'error (%)', 'reported std (px)', 'PoseLib six-point, median (px)', 'error (%)'],
            rows, 'lrrrlrrrrrrr')]
    return '\n'.join(lines)


def method_notes(height: float, nominal_fov: float = 0.0) -> str:
    """Markdown: how each row was run, read from the shipped configuration."""
    from planar_vo.config import PlanarVoConfig

    c = PlanarVoConfig()
    shipped = ', '.join(f'{k} {v}' for k, v in (
        ('scale.source', c.scale.source), ('scale.fallback', c.scale.fallback),
        ('mount.estimate_tilt', c.mount.estimate_tilt), ('frontend.method', c.frontend.method),
        ('voting.method', c.voting.method), ('camera.focal_tolerance', c.camera.focal_tolerance)))
    return '\n'.join([
        '## How the rows were run',
        '',
        f'- **planar_vo** (every run): the shipped defaults ({shipped}) plus the one setting a '
        f'user of the car knows, mount.height {height:g} m. Calibrated: the drive imported '
        f'with import_kitti and replayed with replay_bag (CameraInfo from calib.txt). '
        f'Self-calibrated: the same frames without CameraInfo, camera.estimate_focal true; the '
        f'principal point is then assumed at the image centre; "principal point given": the '
        f'same with camera.cx and camera.cy from calib.txt (a user who knows them)'
        + (f'; "field of view given": the same with camera.nominal_fov {nominal_fov:g} rad '
           f'({math.degrees(nominal_fov):.0f} deg, the cameras\' specification)'
           if nominal_fov > 0 else '') + '.',
        f'- **Five-point peers**, frame to frame, {THRESHOLD_PX:g} px threshold, on (a) the '
        f'point parts of the ACs our front-end (default FrontendConfig) extracts between '
        f'consecutive frames, (b) the same front-end\'s ACs without its per-frame budget '
        f'(frontend.max_correspondences; a {PEER_GRID_STEP}-pixel grid, every textured cell) '
        f'and (c) DIS \'fast\' flow sampled at (b)\'s grid (p2 = p1 + flow(p1)). PoseLib '
        f'defaults: success probability '
        f"{POSELIB_DEFAULTS['confidence']}, {POSELIB_DEFAULTS['min_iters']} to "
        f"{POSELIB_DEFAULTS['max_iters']} iterations; early stop: planar_vo.bench.peers' "
        f'options (0.999, 0 to 1000). **Their scale is the TRUE step length** between '
        f'consecutive frames (poses.txt); planar_vo has no scale input but the camera height. '
        f'A failed pair loses its motion (the camera is held).',
        f'- **Focal peer**: PoseLib shared-focal six-point (PoseLib defaults, {THRESHOLD_PX:g} '
        f'px) on (b), pixels about the image centre; its per-pair focal lengths are voted by '
        f'their **median**.',
        '- **Harder conditions**: the calibrated planar_vo run again on the drive driven '
        'faster (every 2nd / 3rd frame), with exposure flicker (frame i\'s brightness times '
        'U(0.75, 1.25), seed i) and with the principal point assumed at the image centre; '
        'each imported and replayed like the drive itself, no peers.',
        '- **Evaluation**: camera trajectories (world = the first camera frame) and the ground '
        'truth in one z-up frame (a level mount at the camera height); ATE after Sim(3) '
        'alignment, the alignment\'s scale (> 1: the estimate is too short); KITTI-protocol '
        'drift on the estimate as it is (no scale fitted), in 3D and on SE(2); mean |e| of '
        'the per-frame yaw change; frames without odometry are left out (the first frame is '
        'the origin of every run).',
        '- **Time**: one thread (OMP/OpenBLAS 1, cv2.setNumThreads(1), one pinned core), '
        'median per frame after the first. planar_vo: VisualOdometry.process (checks, '
        'front-end, estimate, integration), estimator = its solve stage; peers: correspondences '
        '+ estimator, estimator alone beside it (OpenCV\'s includes recoverPose, which '
        'triangulates every point for four pose candidates).',
    ])


def write_results(out: Path, command: Sequence[str], height: float, results: dict,
                  nominal_fov: float = 0.0) -> None:
    """``drives.md`` and ``drives.json`` (every number) in ``out``."""
    from planar_vo.bench.common import environment_lines, write_markdown
    from planar_vo.io.outputs import write_file
    from planar_vo.tools.evaluation.report import json_ready

    sections = [method_notes(height, nominal_fov), summary_table(results)]
    sections += [drive_section(name, drive) for name, drive in results.items()]
    path = out / 'drives.md'
    write_markdown(path, 'planar_vo bench drives', command, sections)
    data = {'command': list(command), 'environment': environment_lines(),
            'camera_height_m': height, 'nominal_fov_rad': nominal_fov,
            'threshold_px': THRESHOLD_PX,
            'poselib_defaults': POSELIB_DEFAULTS, 'drives': results}
    write_file(out / 'drives.json', json.dumps(json_ready(data), indent=1) + '\n')
    print(f"wrote {path} and {out / 'drives.json'}")
