"""The ``planar_vo`` command: one entry point, one module per subcommand.

Each subcommand module defines ``register(subparsers)`` (its parser, with examples) and
``run(args) -> int``. Known errors (`PlanarVoError`) become one line on stderr and exit code 1;
anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from collections.abc import Sequence

from planar_vo import __version__
from planar_vo.errors import PlanarVoError

__all__ = ['build_parser', 'main', 'show_progress']

# Subcommand modules, in --help order.
COMMANDS = ('demo', 'replay', 'eval', 'import-kitti', 'fleet', 'bench')

EPILOG = """examples:
  planar_vo demo                                  render, replay and evaluate the demo drive
  planar_vo import-kitti ~/kitti/06 --out kitti06 a KITTI sequence folder into a bag
  planar_vo replay kitti06 --out kitti06_vo       odometry over a bag into a new bag
  planar_vo eval kitti06_vo --out-dir kitti06_eval
  planar_vo fleet run --manifest bags.txt --out fleet_out   many bags on Ray, summary and report
  planar_vo bench pipeline                        speed per stage, KITTI accuracy vs five-point
"""


def show_progress(args: argparse.Namespace) -> bool:
    """Progress bars on stderr unless ``--no-progress`` or stderr is not a terminal (CI logs)."""
    return not getattr(args, 'no_progress', False) and sys.stderr.isatty()


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with every subcommand registered."""
    parser = argparse.ArgumentParser(
        prog='planar_vo',
        description='Planar visual odometry from single affine correspondences '
                    '(Hajder and Barath 1AC/1ACf).',
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--version', action='version', version=f'%(prog)s {__version__}')
    parser.add_argument('-v', '--verbose', action='count', default=0,
                        help='more log output (-vv for debug)')
    subparsers = parser.add_subparsers(dest='command', metavar='COMMAND', required=True)
    for name in COMMANDS:
        importlib.import_module(f'planar_vo.cli.{name.replace("-", "_")}').register(subparsers)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``planar_vo`` command; returns the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=(logging.WARNING, logging.INFO, logging.DEBUG)[min(args.verbose, 2)],
                        format='%(levelname)s %(name)s: %(message)s')
    try:
        return int(args.run(args) or 0)
    except PlanarVoError as err:
        print(f'planar_vo {args.command}: error: {err}', file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f'planar_vo {args.command}: interrupted', file=sys.stderr)
        return 130
