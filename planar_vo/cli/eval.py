"""``planar_vo eval``: compare an estimated trajectory with ground truth.

EST and GT are TUM files or bags (directory, .mcap or .db3). A bag written by ``planar_vo
replay`` holds both: the estimate on /odom and the copied ground truth, which is used when --gt
is not given. Poses are associated by stamp, the estimate is aligned (Umeyama SE(3) by default),
and ATE, RPE per frame and per distance, and per-frame yaw-change and heading errors are printed
(the yaw-change error: each step's change of yaw, estimate minus reference; the heading error:
the direction of each step's travel in the frame before it, ``atan2(dy, dx)`` of base_link's
forward and left motion, estimate minus reference, so a positive bias is travel turned left of
the reference's; degrees);
with --out-dir, metrics.json and PNG plots are written there. When EST is a bag whose topic
carries a pose covariance (Odometry), its consistency with the errors is printed too: each
axis's |error| / std and the 2D position's Mahalanobis distance, against the reference anchored
at the first pose.

Another method's output: a TUM file of camera poses (x right, y down, z forward, the world its
first camera's frame; most visual odometry and SLAM outputs) with --est-frame camera, or a
KITTI pose file (12 numbers per line: the 3x4 T_w_cam of KITTI's poses.txt, no stamps) with
--est-times (the sequence's times.txt): their poses become a level vehicle's, the camera
--camera-height above it, and their stamps start at --est-start, as planar_vo import-kitti
writes the ground truth, so they compare with it.
"""

from __future__ import annotations

import argparse
import math
from decimal import Decimal, InvalidOperation
from pathlib import Path

from planar_vo.io.camera_bag import DEFAULT_START
from planar_vo.tools.evaluation.align import ALIGNMENTS

EXAMPLES = """examples:
  planar_vo eval drive_vo                         estimate and ground truth from one bag
  planar_vo eval est.tum --gt gt.tum --align sim3 --out-dir eval_out
  planar_vo eval drive_vo --gt kitti06 --gt-topic /ground_truth/odom --segments 5 10 20
  planar_vo eval orbslam_05.txt --est-times kitti/05/times.txt --gt k05_vo   another method
"""

DEFAULT_EST_TOPIC = '/odom'
DEFAULT_GT_TOPIC = '/ground_truth/odom'


def register(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        'eval', help='trajectory errors (ATE, RPE, yaw and heading) against ground truth',
        description=__doc__, epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('est', metavar='EST', help='estimate: TUM file or bag')
    parser.add_argument('--gt', metavar='GT',
                        help='ground truth: TUM file or bag (default: GT topic of the EST bag)')
    parser.add_argument('--est-topic', default=DEFAULT_EST_TOPIC, metavar='TOPIC',
                        help=f'estimate topic in a bag (default: {DEFAULT_EST_TOPIC})')
    parser.add_argument('--gt-topic', default=DEFAULT_GT_TOPIC, metavar='TOPIC',
                        help=f'ground-truth topic in a bag (default: {DEFAULT_GT_TOPIC})')
    parser.add_argument('--est-frame', choices=('base', 'camera'), default=None,
                        help="the frame EST's poses are of: 'base' (REP-103 x forward, z up: "
                             "planar_vo's and a robot's odometry) or 'camera' (x right, y down, "
                             'z forward, the world the first camera frame: most VO and SLAM '
                             'outputs; re-expressed as a level vehicle\'s); default: base, '
                             'camera for a KITTI pose file')
    parser.add_argument('--est-times', metavar='FILE',
                        help='times of a KITTI pose file EST (one per pose: the sequence\'s '
                             'times.txt)')
    parser.add_argument('--est-start', default=None, metavar='SEC',
                        help='seconds added to --est-times (default: import-kitti\'s start, '
                             f'{DEFAULT_START:g})')
    parser.add_argument('--camera-height', type=float, default=None, metavar='M',
                        help='camera height above the vehicle origin for camera poses (default: '
                             '1.65, KITTI\'s; as given to import-kitti)')
    parser.add_argument('--align', choices=ALIGNMENTS, default='se3',
                        help='alignment of the estimate (default: se3)')
    parser.add_argument('--max-diff', type=float, default=0.02, metavar='SEC',
                        help='maximum stamp difference for association (default: 0.02)')
    parser.add_argument('--segments', type=float, nargs='+', default=[5.0, 10.0, 20.0],
                        metavar='M', help='RPE segment lengths in metres (default: 5 10 20); a '
                                          'segment spans at least its length, and its errors are '
                                          "divided by the length, as KITTI's devkit does")
    parser.add_argument('--out-dir', metavar='DIR',
                        help='write metrics.json and trajectory/ate/yaw_heading PNGs here (a '
                             'folder holding an earlier evaluation only with --force)')
    parser.add_argument('--force', action='store_true',
                        help='replace an earlier evaluation in --out-dir')
    parser.set_defaults(run=run)
    return parser


def _load(path: str, topic: str, name: str, topic_option: str, covariances: bool = False,
          span: tuple[str, int, int] | None = None, part: dict | None = None):
    """The trajectory of `path` (`topic` of a bag), with its pose covariances (None without
    them: a TUM file, a PoseStamped topic) when asked for; errors call the path `name` (EST,
    --gt), not the library's 'trajectory', 'tum' or 'bag', and the topic `topic_option`."""
    from planar_vo.cli import relabel
    from planar_vo.errors import PlanarVoError
    from planar_vo.tools.evaluation import load_trajectory, read_bag_odometry
    from planar_vo.tools.evaluation.files import is_bag_path

    try:
        if covariances and is_bag_path(path):
            return read_bag_odometry(path, topic, role=topic_option, part=part)
        trajectory = load_trajectory(path, topic, role=topic_option, span=span)
        return (trajectory, None) if covariances else trajectory
    except PlanarVoError as err:
        relabel(err, dict.fromkeys(('trajectory', 'tum', 'bag'), name))
        raise


def _load_estimate(args: argparse.Namespace, part: dict):
    """EST and its pose covariances (None without them): a bag topic or a TUM file, in the
    vehicle's frame or the camera's (--est-frame), or a KITTI pose file with --est-times (a
    user test: KITTI's own poses as a TUM file scored 101 % t_rel, without a word). ``part``
    receives the part of a bag topic read (`read_bag_odometry`)."""
    from planar_vo.errors import InputError
    from planar_vo.core.trajectory import Trajectory
    from planar_vo.io.kitti import camera_to_vehicle
    from planar_vo.tools.evaluation.files import (
        is_bag_path,
        is_kitti_pose_file,
        read_kitti_trajectory,
    )

    kitti = is_kitti_pose_file(args.est)
    given = {'--est-times': args.est_times, '--est-start': args.est_start}
    if not kitti:
        for option, value in given.items():
            if value is not None:
                raise InputError(f"{option}: only for a KITTI pose file EST (12 numbers per "
                                 f"line); '{args.est}' is not one")
    height = args.camera_height
    if height is not None and not (kitti or args.est_frame == 'camera'):
        # (a user test: it was ignored without a word)
        raise InputError('--camera-height: only for camera poses (--est-frame camera, or a '
                         'KITTI pose file EST)')
    if height is None:
        height = args.camera_height = 1.65
    if not (math.isfinite(height) and 0.01 <= height <= 100.0):
        # (a user test: 0 and 1e9 were taken, which import-kitti refuses)
        raise InputError(f'--camera-height: expected a height above the ground of 0.01-100 m '
                         f'(the range of mount.height), got {height:g}')
    if kitti:
        if args.est_frame == 'base':
            raise InputError('--est-frame: a KITTI pose file holds camera poses (T_w_cam); '
                             'give --est-frame camera or leave it out')
        if args.est_times is None:
            raise InputError(f"--est-times: '{args.est}' is a KITTI pose file, which has no "
                             f"stamps; give the sequence's times.txt")
        start = DEFAULT_START
        if args.est_start is not None:
            try:
                start = Decimal(args.est_start)
                if not start.is_finite():
                    raise InvalidOperation
            except InvalidOperation:
                raise InputError(f'--est-start: expected seconds, got '
                                 f'{args.est_start!r}') from None
        return read_kitti_trajectory(args.est, args.est_times, start, args.camera_height), None
    est, covariances = _load(args.est, args.est_topic, 'EST', '--est-topic', covariances=True,
                             part=part)
    if args.est_frame == 'camera':
        if covariances is not None:
            raise InputError(f"--est-frame camera: '{args.est}' carries a pose covariance in "
                             f'its own frame; give camera poses as a TUM file')
        est = Trajectory(est.stamps_ns, camera_to_vehicle(est.poses, args.camera_height))
    elif args.est_frame is None and not is_bag_path(args.est):
        _warn_if_camera_frame(est, args.est)
    return est, covariances


def _warn_if_camera_frame(est, path: str) -> None:
    """A TUM estimate that moves along its own z axis (an optical camera's forward) rather
    than x (REP-103's) is most likely camera poses: said, with the option."""
    import logging

    import numpy as np

    p = est.poses[:, :3, 3]
    if len(p) < 2:
        return
    # Displacements in each pose's own frame, over the drive.
    d = np.einsum('nji,nj->ni', est.poses[:-1, :3, :3], np.diff(p, axis=0))
    along = np.abs(d).sum(axis=0)
    if along.sum() > 0 and along[2] > 0.8 * along.sum():
        logging.getLogger('planar_vo.eval').warning(
            "EST '%s' moves along its poses' z axis, an optical camera's forward: if these are "
            'camera poses (x right, y down, z forward), give --est-frame camera', path)


def _is_camera_bag(path: str) -> bool:
    """``path`` is a readable bag with an image topic (a camera recording, not odometry)."""
    from planar_vo.errors import PlanarVoError
    from planar_vo.io import open_bag
    from planar_vo.tools.evaluation.files import is_bag_path

    if not is_bag_path(path):
        return False
    try:
        with open_bag(path) as bag:
            return bool(bag.topics_of_type('sensor_msgs/msg/Image',
                                           'sensor_msgs/msg/CompressedImage'))
    except PlanarVoError:
        return False


def _another_drive(est: str, gt: str) -> str | None:
    """Why EST and GT look like two drives' bags, or None: a replayed estimate names the bag it
    was replayed from (`planar_vo replay` records ``planar_vo.input``), and a reference that is
    neither that bag nor replayed from it is another's, whose stamps may still match (a user
    test: KITTI 06's odometry scored against KITTI 05's ground truth without a word; every
    `import-kitti` starts its drive at the same time)."""
    from planar_vo.tools.evaluation.files import is_bag_path
    from planar_vo.tools.provenance import bag_custom_data

    if not (is_bag_path(est) and is_bag_path(gt)):
        return None
    source = bag_custom_data(est).get('planar_vo.input')
    if not source:
        return None
    gt_source = bag_custom_data(gt).get('planar_vo.input')
    same = Path(source).resolve()
    if same == Path(gt).resolve() or (gt_source and Path(gt_source).resolve() == same):
        return None
    of = f", replayed from '{gt_source}'" if gt_source else ''
    return (f"EST was replayed from '{source}' and GT is '{gt}'{of}: two drives? Their stamps "
            f'can match (import-kitti starts every drive at the same time)')


def _warn_few_matched(evaluation, est, ref, max_diff: float) -> None:
    """A warning when fewer than half of the shorter trajectory's poses found a partner
    within ``max_diff``: the two are stamped differently, and the figures compare the few
    poses that happened to match (a user test: KITTI frames imported by import-video at 10 Hz
    scored against import-kitti's times.txt, 19 of 120 matched, t_rel 126 %, with only the
    'two drives?' note)."""
    matched = len(evaluation.ref)
    if matched >= 0.5 * min(len(est), len(ref)):
        return
    import logging

    import numpy as np

    def span(traj) -> str:
        t = traj.stamps_ns.astype(np.float64) * 1e-9
        rate = (len(t) - 1) / (t[-1] - t[0]) if len(t) > 1 and t[-1] > t[0] else float('nan')
        return f'{t[0]:.3f}-{t[-1]:.3f} s, {rate:.3g} Hz'

    logging.getLogger('planar_vo.eval').warning(
        'only %d of %d estimated and %d reference poses are matched within --max-diff %g s: the '
        'two are stamped differently (EST %s, the reference %s); the figures compare those %d '
        'poses only. The same frames imported two ways (import-video --rate-hz, import-kitti '
        'from times.txt) are: import both alike (import-kitti --rate-hz)', matched, len(est),
        len(ref), max_diff, span(est), span(ref), matched)


def _warn_origin_unmatched(est, ref, max_diff: float) -> None:
    """A warning when EST's first pose (an odometry's origin) has no reference pose within
    ``max_diff``: with the reference stamped some whole frames apart from the estimate, the
    later poses still match, pairing the wrong frames (a user test: ground truth stamped 5 s
    late, 252 of 300 matched; ATE 17 m with no word)."""
    import logging

    import numpy as np

    stamps = ref.stamps_ns
    t0 = int(est.stamps_ns[0])
    k = int(np.searchsorted(stamps, t0))
    nearest = min(abs(int(stamps[j]) - t0) for j in (k - 1, k) if 0 <= j < len(stamps))
    if nearest <= max_diff * 1e9:
        return
    logging.getLogger('planar_vo.eval').warning(
        "EST's first pose (%.3f s, an odometry's origin) has no reference pose within "
        '--max-diff %g s (the nearest is %.3f s away; the reference spans %.3f-%.3f s): if the '
        'two are stamped with an offset, the figures pair the wrong poses', t0 * 1e-9,
        max_diff, nearest * 1e-9, stamps[0] * 1e-9, stamps[-1] * 1e-9)


def run(args: argparse.Namespace) -> int:
    from planar_vo.errors import InputError, PlanarVoError
    from planar_vo.tools.evaluation import evaluate, write_report
    from planar_vo.tools.evaluation.files import is_bag_path

    if any(not (math.isfinite(s) and s > 0) for s in args.segments):
        raise InputError(f'--segments: expected positive lengths in metres, got {args.segments}')
    if len(set(args.segments)) != len(args.segments):     # (a user test: counted twice)
        raise InputError(f'--segments: expected different lengths, got {args.segments}')
    # A topic option for a TUM file would be ignored (a user test): refused instead.
    gt_file = args.gt if args.gt is not None else args.est
    for option, value, default, path in (('--est-topic', args.est_topic, DEFAULT_EST_TOPIC,
                                          args.est),
                                         ('--gt-topic', args.gt_topic, DEFAULT_GT_TOPIC,
                                          gt_file)):
        if value != default and Path(path).is_file() and not is_bag_path(path):
            raise InputError(f"{option}: '{path}' is a file (TUM or KITTI poses), which has "
                             f'no topics; give {option} only for a bag')
    if args.out_dir is not None and not args.out_dir.strip():
        raise InputError('--out-dir: an empty path; expected the folder for the report')
    out = Path(args.out_dir) if args.out_dir else None
    if out is not None and out.exists() and not out.is_dir():
        raise InputError(f"--out-dir: '{args.out_dir}' is a file; expected the folder for the "
                         f'report (made if missing)')
    if out is not None and (out / 'metadata.yaml').exists():
        raise InputError(f"--out-dir: '{args.out_dir}' is a bag; choose another folder for the "
                         f'report')
    if args.out_dir and not args.force and (Path(args.out_dir) / 'metrics.json').exists():
        # Checked before the work, like every output of the command line.
        raise InputError(f"--out-dir: '{args.out_dir}' holds an earlier evaluation "
                         f'(metrics.json); refusing to overwrite it (give --force, or choose '
                         f'another folder)')
    if args.est_topic == DEFAULT_EST_TOPIC and is_bag_path(args.est):
        # The odometry's topic as replay recorded it (a user test: with --odom-topic
        # /vo/odom, eval scored the copied wheel odometry on /odom, perfectly).
        from planar_vo.tools.provenance import bag_custom_data

        made = bag_custom_data(args.est).get('planar_vo.odom_topic')
        if made and made != DEFAULT_EST_TOPIC:
            args.est_topic = made
    # With the pose covariance the odometry published (Odometry, PoseWithCovarianceStamped):
    # its consistency with the errors is evaluated too.
    est_part: dict = {}                 # the part of EST's topic read (time bases)
    try:
        est, covariances = _load_estimate(args, est_part)
    except PlanarVoError as err:
        if args.est_topic == DEFAULT_EST_TOPIC and _is_camera_bag(args.est):
            # A user test: the bag of images itself, given for EST, named only the topic.
            err.args = (f'{err}; EST holds images, not odometry: replay it first (planar_vo '
                        f'replay {args.est} --out ODOMETRY), then evaluate ODOMETRY',)
        raise
    gt_path = args.gt
    if gt_path is None:
        if not is_bag_path(args.est):
            raise InputError('--gt: expected GT when EST is a file (TUM or KITTI poses), got '
                             'none')
        gt_path = args.est
    try:
        # A topic on two time bases: the part recorded with the estimate's in the same bag
        # (by log time: a simulator's clock restarting at the same time each run gives equal
        # stamps, a review), else the part of its stamps.
        span = (('log', *est_part['log_span'])
                if args.gt is None and est_part.get('split') else
                ('stamp', int(est.stamps_ns[0]), int(est.stamps_ns[-1])))
        ref = _load(gt_path, args.gt_topic, '--gt', '--gt-topic', span=span)
    except PlanarVoError as err:
        if args.gt is None and args.gt_topic == DEFAULT_GT_TOPIC \
                and 'is not a topic of' in str(err):
            # A user test: neither option was given, yet the message named --gt-topic only.
            # (Not when --gt-topic was given: a mistyped topic of a bag that has ground truth,
            # another user test; the error lists its topics.)
            err.args = (f'{err}; EST has no ground truth: give it with --gt (a TUM file or a '
                        f'bag), and its topic with --gt-topic',)
        raise
    other = _another_drive(args.est, gt_path)
    if other:
        import logging

        logging.getLogger('planar_vo.eval').warning('%s', other)
    if is_bag_path(args.est):
        from planar_vo.io.camera_bag import PARTIAL_KEY
        from planar_vo.tools.provenance import bag_custom_data

        cut = bag_custom_data(args.est).get(PARTIAL_KEY)
        if cut:
            # (a review: an import cut short was evaluated like the whole drive)
            import logging

            logging.getLogger('planar_vo.eval').warning(
                'EST covers part of its drive: %s; the evaluation covers those frames only',
                cut)
    try:
        evaluation = evaluate(ref, est, align=args.align, max_diff=args.max_diff,
                              segment_lengths=tuple(args.segments),
                              names={'ref': '--gt-topic' if args.gt is None else '--gt',
                                     'est': 'EST', 'max_diff': '--max-diff'},
                              covariances=covariances)
    except InputError as err:
        if 'identical points' in str(err) and args.align != 'origin':
            # (a user test: a drive standing still, with the default alignment)
            err.args = (f'{err}; a trajectory that does not move cannot be aligned: give '
                        f'--align origin',)
        raise
    _warn_few_matched(evaluation, est, ref, args.max_diff)
    _warn_origin_unmatched(est, ref, args.max_diff)
    written = []
    if args.out_dir:
        # The files first, the table after (a user test: `eval --out-dir D | head -1` closed
        # the pipe on the table and D was never written).
        from planar_vo.tools.evaluation.report import read_as
        from planar_vo.tools.provenance import evaluation_provenance

        # Absolute paths (a user test: relative to wherever eval ran), the planar_vo that
        # evaluated, and what produced the estimate when its bag says (replay records it).
        # How the files were read (a user test: a KITTI pose file's times, the camera height
        # and the topics were not recorded, so the evaluation could not be repeated).
        options = read_as(
            est_topic=args.est_topic if is_bag_path(args.est) else None,
            gt_topic=args.gt_topic if is_bag_path(gt_path) else None,
            est_frame=args.est_frame or ('camera' if args.est_times else 'base'),
            est_times=args.est_times,
            est_start=(args.est_start or DEFAULT_START) if args.est_times else None,
            camera_height=(args.camera_height if args.est_times or args.est_frame == 'camera'
                           else None),
            max_diff=args.max_diff, segments=args.segments)
        written = write_report(evaluation, args.out_dir, estimate=Path(args.est).resolve(),
                               reference=Path(gt_path).resolve(), read_as=options,
                               **evaluation_provenance(args.est))
    from planar_vo.cli import print_final

    print_final('\n'.join([
        f'estimate: {args.est}' + (f' ({args.est_topic})' if is_bag_path(args.est) else ''),
        f'reference: {gt_path}' + (f' ({args.gt_topic})' if is_bag_path(gt_path) else ''),
        evaluation.format_table(),
        *([f'wrote {written[0]}, ' + ', '.join(p.name for p in written[1:])] if written
          else [])]))
    return 0
