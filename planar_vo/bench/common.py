"""Plumbing shared by the benchmarks: optional dependencies, the reproducing command line, the
environment record, markdown tables and matplotlib figures (Agg backend, PNG files).

Every bench module (``planar_vo.bench.<name>``, listed in `planar_vo.cli.bench.BENCHES`) defines
``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``; ``args.out`` (output folder) and
``args.command`` (the full command that reproduces the run) are set by the CLI.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import importlib
import importlib.metadata
import os
import platform
import shlex
import signal
import subprocess
import sys
from collections.abc import Iterable, Sequence
from pathlib import Path

from planar_vo.errors import DependencyError
from planar_vo.io.outputs import interrupt_signal, write_file
from planar_vo.tools.markdown import format_cell, markdown_table

__all__ = [
    'BENCH_EXTRA',
    'BenchDependencyError',
    'command_argv',
    'environment_lines',
    'format_cell',
    'markdown_table',
    'new_figure',
    'reexec_single_threaded',
    'require',
    'save_figure',
    'write_markdown',
]

BENCH_EXTRA = "pip install 'planar_vo[bench]'"
SINGLE_THREAD_ENV = {'OMP_NUM_THREADS': '1', 'OPENBLAS_NUM_THREADS': '1',
                     'MKL_NUM_THREADS': '1', 'NUMEXPR_NUM_THREADS': '1'}


class BenchDependencyError(DependencyError):
    """An optional benchmark dependency (poselib, matplotlib, scipy) is not installed."""


def require(*modules: str) -> None:
    """Import-check optional dependencies; raise `BenchDependencyError` naming the install."""
    missing = []
    for name in modules:
        try:
            importlib.import_module(name)
        except ImportError:
            missing.append(name)
    if missing:
        raise BenchDependencyError(f'{", ".join(missing)} not installed: {BENCH_EXTRA}')


def command_argv(prefix: Sequence[str], parser: argparse.ArgumentParser,
                 args: argparse.Namespace) -> list[str]:
    """The argument vector that reproduces ``args``: ``prefix`` then every option of ``parser``
    spelled out with its value (defaults included, so the record does not depend on them)."""
    argv = list(prefix)
    for action in parser._actions:                       # argparse has no public iterator
        if not action.option_strings or action.dest in ('help', 'run'):
            continue
        value = getattr(args, action.dest, None)
        flag = action.option_strings[-1]
        if isinstance(action, argparse._StoreTrueAction):
            if value:
                argv.append(flag)
        elif value is not None:
            values = value if isinstance(value, (list, tuple)) else [value]
            argv += [flag] + [str(v) for v in values]
    return argv


def reexec_single_threaded(args: argparse.Namespace, *, pin_core: bool) -> int | None:
    """Re-run the benchmark in a process with one BLAS/OpenMP thread, unless this is that one.

    Thread counts are read when numpy (OpenBLAS) loads, so a process that has imported numpy
    cannot change them: the benchmark re-executes ``args.command`` with `SINGLE_THREAD_ENV` and
    returns its exit code (SIGINT and SIGTERM are passed on to it, so that it stops as it would
    alone). In the single-threaded process it returns None after
    ``cv2.setNumThreads(1)`` and, with ``pin_core``, pinning the process to one core. (Small
    solver calls are otherwise slowed down many times by idle BLAS threads competing for the
    cores.)
    """
    if all(os.environ.get(k) == v for k, v in SINGLE_THREAD_ENV.items()):
        if pin_core and hasattr(os, 'sched_setaffinity'):
            os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
        import cv2

        cv2.setNumThreads(1)
        return None
    env = dict(os.environ, **SINGLE_THREAD_ENV)
    cmd = [sys.executable, '-m', 'planar_vo'] + list(args.command[1:])
    with subprocess.Popen(cmd, env=env) as child:
        try:
            code = child.wait()
        except KeyboardInterrupt as err:
            # Ctrl-C reaches the whole process group, a supervisor's SIGTERM (or a kill) this
            # process only: pass it on unless the child is stopping already. The child finishes
            # its outputs and reports the interruption; its exit code is this one's.
            signum = interrupt_signal(err)
            try:
                code = child.wait(timeout=1.0 if signum == signal.SIGINT else 0.0)
            except subprocess.TimeoutExpired:
                child.send_signal(signum)
                code = child.wait()
    return 128 - code if code < 0 else code       # killed by signal N: the shell's 128 + N


def _version(dist: str) -> str:
    try:
        return importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:
        return 'not installed'


def environment_lines() -> list[str]:
    """Markdown bullet lines describing the machine and the library versions."""
    threads = ', '.join(f'{k}={os.environ.get(k, "unset")}'
                        for k in ('OMP_NUM_THREADS', 'OPENBLAS_NUM_THREADS', 'MKL_NUM_THREADS'))
    libs = ', '.join(f'{d} {_version(d)}' for d in (
        'planar_vo', 'numpy', 'opencv-python-headless', 'poselib', 'matplotlib'))
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, 'sched_getaffinity') else os.cpu_count()
    load = ', '.join(f'{x:.2f}' for x in os.getloadavg()) if hasattr(os, 'getloadavg') else '?'
    return [
        f'- date: {_dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")}',
        f'- machine: {platform.machine()}, {platform.processor() or "cpu"}, {cpus} usable '
        f'core(s) for this process, Python {platform.python_version()}, '
        f'{platform.system()}, load average {load} (other processes compete for the cores)',
        f'- libraries: {libs}',
        f'- threads: {threads}',
    ]


def write_markdown(path: Path, title: str, command: Sequence[str], sections: Iterable[str]
                   ) -> str:
    """Write a report that starts with the exact command that produced it; returns the text.

    The file is complete or absent (`planar_vo.io.outputs.write_file`); `OutputError` if it cannot
    be written."""
    text = '\n\n'.join([
        f'# {title}',
        'Produced by:\n\n```sh\n' + shlex.join(command) + '\n```',
        '\n'.join(environment_lines()),
        *sections,
    ]) + '\n'
    write_file(path, text)
    return text


def new_figure(nrows: int, ncols: int, *, width: float = 4.2, height: float = 3.3):
    """A matplotlib figure and its axes grid (always 2-D), on the non-interactive Agg backend."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(nrows, ncols, figsize=(width * ncols, height * nrows),
                             squeeze=False)
    return fig, axes


def save_figure(fig, path: Path, *, margins: dict | None = None) -> Path:
    """Save as PNG at 72 dpi (plots stay around 200 KB) and close the figure.

    ``margins``: ``Figure.subplots_adjust`` arguments for large grids, where matplotlib's
    automatic ``tight_layout`` costs seconds; without them ``tight_layout`` is used.
    """
    import matplotlib.pyplot as plt

    if margins:
        fig.subplots_adjust(**margins)
    else:
        fig.tight_layout()
    try:
        write_file(path, lambda tmp: fig.savefig(tmp, dpi=72))
    finally:
        plt.close(fig)
    return path
