"""The ``planar_vo`` command: one entry point, one module per subcommand.

Each subcommand module defines ``register(subparsers)`` (its parser, with examples) and
``run(args) -> int``. Known errors (`PlanarVoError`), paths the system refuses (`OSError`) and
usage errors (a missing or unknown argument, a value of the wrong type) become one line on
stderr and exit code 1; anything else is a bug and keeps its traceback. A known error that
starts with the library's name for an argument (``speed_topic: ...``) names it as typed on the
command line instead (``--speed-topic: ...``; a positional argument by its metavar, ``IN: ...``).
SIGTERM is handled like SIGINT (Ctrl-C): the command stops, its outputs are finished or removed,
and one line says what was kept.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import logging
import os
import re
import signal
import sys
import threading
from collections.abc import Iterator, Sequence

from planar_vo import __version__
from planar_vo.early_stops import catch_early_stops, pending_stop
from planar_vo.errors import PlanarVoError, one_line

__all__ = ['CommandParser', 'Once', 'build_parser', 'main', 'print_final', 'relabel',
           'show_progress']

# Subcommand modules, in --help order.
COMMANDS = ('demo', 'replay', 'eval', 'import-kitti', 'import-video', 'fleet', 'bench')

EPILOG = """examples:
  planar_vo demo                                  render, replay and evaluate the demo drive
  planar_vo import-kitti ~/kitti/06 --out kitti06 a KITTI sequence folder into a bag
  planar_vo import-video dashcam.mp4 --out dash   a video (or a folder of images) into a bag
  planar_vo replay kitti06 --out kitti06_vo       odometry over a bag into a new bag
  planar_vo eval kitti06_vo --out-dir kitti06_eval
  planar_vo fleet run --manifest bags.txt --out fleet_out   many bags on Ray, summary and report
  planar_vo bench pipeline                        speed per stage, KITTI accuracy vs five-point
"""

# The options of planar_vo itself, which go before the command (-v, -vv, --verbose, --version).
TOP_LEVEL_OPTION = re.compile(r'-v+|--verbose|--version')


# A negative number as argparse's matcher should see it: -5, -0.5, -.5, -1e12, -2.5E-3.
_NEGATIVE_NUMBER = re.compile(r'^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$')


class CommandParser(argparse.ArgumentParser):
    """An `argparse.ArgumentParser` whose usage errors are one line on stderr and exit code 1,
    like every other error of the command (argparse's own: the usage block and exit code 2).
    Subcommand parsers inherit it (`add_subparsers` uses the parent's class). Negative numbers
    in exponent form (``--start -1e12``) are values, as ``-5`` and ``-0.5`` are (argparse
    took ``-1e12`` for an option and said the option expected an argument)."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        if hasattr(self, '_negative_number_matcher'):   # argparse's own; no public switch
            self._negative_number_matcher = _NEGATIVE_NUMBER

    def error(self, message: str):
        self.exit(1, f'{self.prog}: error: {one_line(message)} '
                     f'(see {self.prog} --help)\n')

    def parse_known_args(self, args=None, namespace=None):
        """An argument left over is a usage error of the parser it was left to: a subcommand's
        (argparse hands a subcommand's leftovers up to the top-level parser, whose message
        then pointed to ``planar_vo --help``)."""
        namespace, extras = super().parse_known_args(args, namespace)
        top = self.prog.split()[0]
        if extras and self.prog != top and all(TOP_LEVEL_OPTION.fullmatch(e) for e in extras):
            # Their help is planar_vo --help, not this command's.
            self.exit(1, f"{self.prog}: error: unrecognized arguments: {' '.join(extras)} "
                         f'(an option of {top} itself goes before the command: see {top} '
                         f'--help)\n')
        if extras:
            self.error(f"unrecognized arguments: {' '.join(extras)}")
        # The innermost parser, the command's own, parses first: its arguments name the errors.
        if not hasattr(namespace, 'parser'):
            namespace.parser = self
        return namespace, extras


class Once(argparse.Action):
    """An option that takes one value and refuses a second (argparse keeps the last without a
    word: a user test ran on the second of two --config files)."""

    def __call__(self, parser, namespace, values, option_string=None):
        if getattr(namespace, self.dest, None) is not None:
            parser.error(f'{option_string}: given twice; give it once')
        setattr(namespace, self.dest, values)


def print_final(text: str) -> None:
    """Print a command's last lines, once its outputs are written: a reader of stdout that
    went away (``planar_vo eval ... | head -1``) is no error then (a user test: 'error: Broken
    pipe', exit 1, for outputs that were complete). Stdout goes to the null device after, where
    Python flushes it at exit. Lines printed while a command still works raise as before."""
    try:
        print(text, flush=True)
    except BrokenPipeError:
        with contextlib.suppress(OSError, ValueError):
            null = os.open(os.devnull, os.O_WRONLY)
            try:
                os.dup2(null, sys.stdout.fileno())
            finally:
                os.close(null)


def show_progress(args: argparse.Namespace) -> bool:
    """Progress bars on stderr unless ``--no-progress`` or stderr is not a terminal (CI logs)."""
    return not getattr(args, 'no_progress', False) and sys.stderr.isatty()


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with every subcommand registered."""
    parser = CommandParser(
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


def _stop_if_noted() -> None:
    """Raise the first stop signal noted while the command started (`_early_stops`) as a
    ``KeyboardInterrupt`` naming it, once the imports are done."""
    signum = pending_stop()
    if signum is not None:
        raise KeyboardInterrupt(signal.Signals(signum).name)


def _typed_command(argv: Sequence[str] | None) -> str:
    """The command as typed before its parser exists: ``planar_vo``, ``planar_vo replay``,
    ``planar_vo bench paper`` (the commands with subcommands: bench, fleet)."""
    words = list(sys.argv[1:] if argv is None else argv)
    parts = ['planar_vo']
    if words and words[0] in COMMANDS:
        parts.append(words[0])
        if words[0] in ('bench', 'fleet') and len(words) > 1 and not words[1].startswith('-'):
            parts.append(words[1])
    return ' '.join(parts)


def _signal_of(err: KeyboardInterrupt) -> signal.Signals:
    name = str(err)
    return signal.Signals[name] if name in signal.Signals.__members__ else signal.SIGINT


@contextlib.contextmanager
def _early_stops() -> Iterator[None]:
    """SIGINT and SIGTERM are noted while the command starts (`planar_vo.early_stops`: raised
    inside numpy's import, one became that import's error, 'exit 1, PyCapsule_Import could not
    import module "datetime"', or lost its signal, exit 130 for a SIGTERM) and stop it once its
    imports are done (`_stop_if_noted`); the previous handlers come back after, and a noted
    signal not acted on is forgotten."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = catch_early_stops()
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        pending_stop()


def relabel(err: PlanarVoError, names: dict[str, str]) -> None:
    """If `err` starts with one of the keys of `names` (``'speed_topic: ...'``), name it
    ``names[key]`` instead (``'--speed-topic: ...'``)."""
    label, sep, rest = str(err).partition(': ')
    if sep and label in names:
        err.args = (f'{names[label]}: {rest}',)


def _typed_names(parser: argparse.ArgumentParser) -> dict[str, str]:
    """The arguments of `parser` as typed, by their Python names: an option by its long form
    (``rate_hz`` -> ``--rate-hz``), a positional argument by its metavar (``est`` -> ``EST``)."""
    return {action.dest: action.option_strings[-1] if action.option_strings else
            action.metavar or action.dest
            for action in parser._actions}                 # argparse has no public iterator


def _with_notes(text: str, err: BaseException) -> str:
    """`text` and the error's notes (what was kept, added on the way out) on one line."""
    parts = [text, *getattr(err, '__notes__', ())]
    return '; '.join(one_line(p) for p in parts if p.strip())


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``planar_vo`` command; returns the process exit code.

    Exit codes: 0 done, 1 a known or usage error (one line on stderr, saying what was kept),
    128 + the signal number when stopped by SIGINT (130) or SIGTERM (143): both are
    handled alike, outputs are finished or removed and one line says what was kept.
    """
    with _early_stops():
        try:
            # Importing every command takes a fraction of a second (numpy, OpenCV, rosbags): a
            # stop signal then is one line too (a user test: a KeyboardInterrupt traceback).
            from planar_vo.io.outputs import interrupt_signal, stop_signals_interrupt

            parser = build_parser()
            _stop_if_noted()
            args = parser.parse_args(argv)
            logging.basicConfig(
                level=(logging.WARNING, logging.INFO, logging.DEBUG)[min(args.verbose, 2)],
                format='%(levelname)s %(name)s: %(message)s')
            from planar_vo.pipeline.threads import limit_blas_threads

            limit_blas_threads()    # idle OpenBLAS workers busy-wait: one thread is faster here
            command = args.parser.prog   # the command as typed: 'planar_vo bench drives'
            with stop_signals_interrupt():
                try:
                    _stop_if_noted()
                    return int(args.run(args) or 0)
                except (PlanarVoError, OSError) as err:
                    if isinstance(err, PlanarVoError):
                        relabel(err, _typed_names(args.parser))
                    # OSError: a path the system refuses (no permission, a name too long, a
                    # full disk) that no check of ours named first.
                    print(_with_notes(f'{command}: error: {err}', err), file=sys.stderr)
                    return 1
                except KeyboardInterrupt as err:
                    signum = interrupt_signal(err)
                    print(_with_notes(f'{command}: interrupted by {signum.name}', err),
                          file=sys.stderr)
                    return 128 + signum.value
        except KeyboardInterrupt as err:
            # While the command starts, or between its handlers and these (a review: a
            # traceback in those windows).
            signum = _signal_of(err)
            print(f'{_typed_command(argv)}: interrupted by {signum.name}', file=sys.stderr)
            return 128 + signum.value
