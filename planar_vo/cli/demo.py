"""``planar_vo demo``: the embedded default job.

Runs the minimal solvers on the paper's synthetic protocol (f = 600, 50 points on a random plane,
ACs from the homography fitted to noisy points) and prints their accuracy.
"""

from __future__ import annotations

import argparse
import time

from planar_vo.experiments import format_accuracy_table, solver_accuracy

EXAMPLES = """examples:
  planar_vo demo
  planar_vo demo --trials 1000 --sigmas 0 0.5 1 2
"""


def register(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        'demo', help='run the demo: solver accuracy on synthetic data',
        description=__doc__, epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--trials', type=int, default=200,
                        help='synthetic trials per noise level (default: 200)')
    parser.add_argument('--sigmas', type=float, nargs='+', default=[0.0, 0.5, 1.0],
                        metavar='PX', help='point noise levels in pixels (default: 0 0.5 1)')
    parser.add_argument('--seed', type=int, default=0, help='random seed (default: 0)')
    parser.set_defaults(run=run)
    return parser


def run(args: argparse.Namespace) -> int:
    start = time.perf_counter()
    rows = solver_accuracy(args.sigmas, trials=args.trials, seed=args.seed)
    print(f'Minimal-solver accuracy on the paper protocol ({args.trials} trials x 50 ACs per '
          f'noise level, seed {args.seed}); errors in degrees, focal error relative.')
    print(format_accuracy_table(rows))
    print(f'done in {time.perf_counter() - start:.1f} s')
    return 0
