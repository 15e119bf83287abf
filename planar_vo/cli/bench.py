"""``planar_vo bench``: benchmarks against the paper and the peers, one module per benchmark.

Each benchmark writes PNG plots and a markdown report (starting with the exact command that
produced it) into ``--out`` and prints the report. Optional dependencies: ``pip install
'planar_vo[bench]'``; without them a benchmark exits with one line and code 1.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from planar_vo.bench.common import BenchDependencyError, command_argv

__all__ = ['BENCHES', 'register', 'run']

# Benchmark modules planar_vo.bench.<name>, in --help order. To add one (e.g. 'frontend'):
# write planar_vo/bench/<name>.py with HELP, add_arguments(parser), run(args) -> int.
BENCHES = ('paper', 'speed', 'frontend', 'pipeline', 'drives', 'soak', 'fleet')

EXAMPLES = """examples:
  planar_vo bench paper --quick                 smoke run of the paper's experiments
  planar_vo bench paper --runs 1000 --out out/bench/paper
  planar_vo bench speed --out out/bench/speed   one-core throughput vs OpenCV and PoseLib
  planar_vo bench frontend                      AC extraction time vs DIS, accuracy, KITTI
  planar_vo bench pipeline                      whole frame per stage vs DIS, rendered and KITTI
  planar_vo bench drives                        every real drive: planar_vo vs OpenCV, PoseLib
  planar_vo bench soak --frames 10000           memory and time per frame over a long drive
  planar_vo bench fleet                         fleet throughput on Ray, 1 and 2 workers
"""


def register(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        'bench', help='benchmarks: the paper\'s experiments, speed against the peers',
        description=__doc__, epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    benches = parser.add_subparsers(dest='bench', metavar='BENCH', required=True)
    for name in BENCHES:
        module = importlib.import_module(f'planar_vo.bench.{name}')
        sub = benches.add_parser(name, help=module.HELP, description=module.__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
        sub.add_argument('--out', default=f'out/bench/{name}', metavar='DIR',
                         help=f'output folder (default: out/bench/{name})')
        module.add_arguments(sub)
        sub.set_defaults(run=run, bench_module=module, bench_parser=sub)
    return parser


def _check_common(args: argparse.Namespace) -> None:
    """The options several benchmarks share, checked before any work (a benchmark runs for
    minutes and writes its report at the end): the output folder can be written, seeds are
    non-negative, counts are positive."""
    import os
    from pathlib import Path

    from planar_vo.errors import InputError, OutputError

    for name, low in (('seed', 0), ('jobs', 1), ('asift_pairs', 0), ('runs', 1), ('samples', 1)):
        value = getattr(args, name, None)
        if value is not None and value < low:
            raise InputError(f'--{name.replace("_", "-")}: expected an integer of at least '
                             f'{low}, got {value}')
    work = getattr(args, 'work', None)
    if work is not None and Path(work).exists() and not Path(work).is_dir():
        raise InputError(f"--work: '{work}' exists and is not a folder")
    if not str(args.out).strip():
        raise InputError('--out: an empty path; expected the folder for the report')
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise InputError(f"--out: '{out}' exists and is not a folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise OutputError(f"--out: cannot create '{out}' ({err.strerror or err})") from err
    if not os.access(out, os.W_OK | os.X_OK):
        raise OutputError(f"--out: '{out}' is not writable")


def run(args: argparse.Namespace) -> int:
    args.command = command_argv(['planar_vo', 'bench', args.bench], args.bench_parser, args)
    _check_common(args)
    try:
        return int(args.bench_module.run(args) or 0)
    except BenchDependencyError as err:
        print(f'planar_vo bench {args.bench}: error: {err}', file=sys.stderr)
        return 1
