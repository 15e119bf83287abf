"""Outputs that survive a stop signal or a full disk: complete, or absent and said so.

Two things every command that writes files needs:

- **Stop signals.** A supervisor stops a process with SIGTERM, a user with Ctrl-C (SIGINT).
  Inside `stop_signals_interrupt` (the ``planar_vo`` command runs every subcommand in it) both
  raise ``KeyboardInterrupt('SIGTERM')`` (or ``'SIGINT'``), so the same cleanup runs for both:
  ``with`` blocks close their bags, ``finally`` clauses write what was computed. Inside
  `deferred_interrupts` (a bag writer's ``write`` and ``close``) the interrupt waits until the
  block has finished, so a file is never left half-updated.
- **Files under a temporary name.** `replacing_file` yields a temporary path next to the target
  and renames it onto the target only once it is complete; on any failure or interruption the
  temporary file is removed. A reader, or the next run, never finds a truncated file.

Process-wide by nature (signal handlers belong to the process): the state below is only touched
from the main thread, where Python runs signal handlers.
"""

from __future__ import annotations

import os
import secrets
import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Any

from planar_vo.errors import OutputError

__all__ = [
    'STOP_SIGNALS',
    'deferred_interrupts',
    'interrupt_signal',
    'replacing_file',
    'stop_signals_interrupt',
    'write_file',
]

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class _Deferral:
    """Depth of nested `deferred_interrupts` blocks and a stop signal that arrived inside."""

    depth = 0
    pending: signal.Signals | None = None
    # The last stop signal handled: a library that turns our KeyboardInterrupt into its own
    # (Ray's ray.wait raises a bare one) loses the name, which `interrupt_signal` then finds
    # here.
    last: signal.Signals | None = None


def _on_stop_signal(signum: int, frame: Any) -> None:
    name = signal.Signals(signum)
    _Deferral.last = name
    if _Deferral.depth:
        _Deferral.pending = name
        return
    raise KeyboardInterrupt(name.name)


def _in_main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


@contextmanager
def stop_signals_interrupt() -> Iterator[None]:
    """Within the block, SIGINT and SIGTERM raise ``KeyboardInterrupt(<signal name>)``.

    The previous handlers are restored on exit. Outside the main thread (where signal handlers
    cannot be set) this does nothing.
    """
    if not _in_main_thread():
        yield
        return
    previous = {s: signal.signal(s, _on_stop_signal) for s in STOP_SIGNALS}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        _Deferral.pending = _Deferral.last = None


@contextmanager
def deferred_interrupts() -> Iterator[None]:
    """A stop signal handled by `stop_signals_interrupt` arriving within the block is raised
    as ``KeyboardInterrupt`` when the (outermost) block ends, not inside it."""
    if not _in_main_thread():
        yield
        return
    _Deferral.depth += 1
    try:
        yield
    finally:
        _Deferral.depth -= 1
        if _Deferral.depth == 0 and _Deferral.pending is not None:
            name, _Deferral.pending = _Deferral.pending, None
            raise KeyboardInterrupt(name.name)


def interrupt_signal(err: KeyboardInterrupt) -> signal.Signals:
    """The signal behind a ``KeyboardInterrupt``: the one it names, else the last one handled
    by `stop_signals_interrupt` (a library re-raised it without the name), else SIGINT."""
    name = str(err)
    if name in signal.Signals.__members__:
        return signal.Signals[name]
    return _Deferral.last or signal.SIGINT


@contextmanager
def replacing_file(path: str | Path, role: str = 'out') -> Iterator[Path]:
    """Write `path` under a temporary name in its folder; rename it onto `path` when the block
    ends normally, remove it otherwise (an error, a full disk, an interruption).

    Args:
        path: the file to (re)place; its folder is created if needed. An existing file is
            replaced only once the new one is complete.
        role: names the output in error messages (``'tum'``, ``'out-dir'``).

    Yields:
        The temporary path to write to (same folder, so the rename is atomic).

    Raises:
        OutputError: the folder or file cannot be written (no permission, read-only or full
            disk), naming the file and the reason; the target is then unchanged.
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise OutputError(f"{role}: cannot create the folder of '{path}' "
                          f'({err.strerror or err})') from err
    # Hidden, unique, and with the target's suffix (matplotlib picks the format from it).
    tmp = path.with_name(f'.{path.stem}.{os.getpid()}-{secrets.token_hex(4)}.partial'
                         f'{path.suffix}')
    try:
        yield tmp
        os.replace(tmp, path)
    except OSError as err:
        raise OutputError(f"{role}: cannot write '{path}' ({err.strerror or err})") from err
    finally:
        with suppress(FileNotFoundError):
            tmp.unlink()


def write_file(path: str | Path, content: str | bytes | Callable[[Path], Any],
               role: str = 'out') -> Path:
    """Write `content` (text as UTF-8, bytes, or a function writing to the path it is given,
    e.g. a figure's ``savefig``) to `path` through `replacing_file`; returns `path`."""
    with replacing_file(path, role) as tmp:
        if isinstance(content, str):
            tmp.write_text(content, encoding='utf-8')
        elif isinstance(content, bytes):
            tmp.write_bytes(content)
        else:
            content(tmp)
    return Path(path)
