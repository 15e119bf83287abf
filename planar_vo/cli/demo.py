"""``planar_vo demo``: the embedded default job.

Renders the demo drive (a textured street world: straights, left and right turns, a full stop,
an S-curve; about 40 s and 290 m at 10 Hz) into a bag with exact ground truth, replays it through
the visual odometry, evaluates the result against the ground truth and writes the plots. With
``--solvers`` it prints the minimal solvers' accuracy on the paper's synthetic protocol instead.
"""

from __future__ import annotations

import argparse
import time

from planar_vo.errors import InputError

EXAMPLES = """examples:
  planar_vo demo                               everything into ./planar_vo_demo
  planar_vo demo --out /tmp/demo --camera 1241x376
  planar_vo demo --solvers --trials 1000       synthetic solver accuracy only
"""


def register(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        'demo', help='render, replay and evaluate the demo drive',
        description=__doc__, epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--out', default='planar_vo_demo', metavar='DIR',
                        help='output folder (default: planar_vo_demo; a previous demo there is '
                             'replaced)')
    parser.add_argument('--camera', default='640x480', choices=['640x480', '1241x376'],
                        help='rendered camera (default: 640x480)')
    parser.add_argument('--frames', type=int, metavar='N',
                        help='use only the first N frames of the drive')
    parser.add_argument('--seed', type=int, default=0, help='random seed (default: 0)')
    parser.add_argument('--storage', choices=['mcap', 'sqlite3'], default='mcap',
                        help='bag storage (default: mcap)')
    parser.add_argument('--force', action='store_true',
                        help='replace --out even if it is not a previous demo folder')
    parser.add_argument('--no-progress', action='store_true', help='no progress bars')
    solvers = parser.add_argument_group('synthetic solver accuracy (--solvers)')
    solvers.add_argument('--solvers', action='store_true',
                         help='print the minimal solvers\' accuracy on the paper protocol')
    solvers.add_argument('--trials', type=int, default=200,
                         help='synthetic trials per noise level (default: 200)')
    solvers.add_argument('--sigmas', type=float, nargs='+', default=[0.0, 0.5, 1.0],
                         metavar='PX', help='point noise levels in pixels (default: 0 0.5 1)')
    parser.set_defaults(run=run)
    return parser


def run(args: argparse.Namespace) -> int:
    from planar_vo.cli import show_progress

    start = time.perf_counter()
    if not 0 <= args.seed < 2 ** 32:
        raise InputError(f'--seed: expected an integer in [0, 2^32), got {args.seed}')
    if args.solvers:
        from planar_vo.bench.solvers import format_accuracy_table, solver_accuracy

        rows = solver_accuracy(args.sigmas, trials=args.trials, seed=args.seed)
        print(f'Minimal-solver accuracy on the paper protocol ({args.trials} trials x 50 ACs per '
              f'noise level, seed {args.seed}); errors in degrees, focal error relative.')
        print(format_accuracy_table(rows))
        print(f'done in {time.perf_counter() - start:.1f} s')
        return 0

    from planar_vo.tools.demo import run_demo

    result = run_demo(args.out, camera=args.camera, seed=args.seed, frames=args.frames,
                      storage=args.storage, force=args.force, progress=show_progress(args))
    m = result.metrics
    print()
    print(f'demo drive: {result.frames} frames, {result.distance:.1f} m; odometry at '
          f'{result.replay_fps:.1f} frames/s')
    print(f"  ATE rmse {m['ate_m']['rmse']:.3f} m "
          f"({100 * m['ate_m']['rmse'] / max(result.distance, 1e-9):.3f} % of the distance); "
          f"yaw-change error rmse {m['yaw_change_error_deg']['rmse']:.4f} deg; "
          f"heading error rmse {m['heading_error_deg']['rmse']:.3f} deg")
    print(f'files in {result.out_dir}/:')
    for name, path in result.files.items():
        print(f'  {name:<12} {path}')
    print(f'done in {time.perf_counter() - start:.1f} s')
    return 0
