"""Stop signals noted before a process can act on them: while the node's entry point
(`planar_vo.ros.startup`) or the ``planar_vo`` command (`planar_vo.cli`) imports numpy, OpenCV,
rosbags or rclpy, SIGINT and SIGTERM are noted (`catch_early_stops`) and acted on once the
imports are done (`pending_stop`): a signal raised inside an extension's import became that
import's error, or a traceback.

Light on purpose: only the standard library is imported here; the entry points, the node and
the command all point down to this module.
"""

from __future__ import annotations

import signal

__all__ = ['catch_early_stops', 'pending_stop']

_PENDING: list[int] = []


def _note(signum: int, frame: object) -> None:
    _PENDING.append(signum)


def catch_early_stops() -> dict[int, object]:
    """Note SIGINT and SIGTERM (`pending_stop`) instead of acting on them, until the process
    installs its own handlers; returns the handlers they replaced."""
    return {sig: signal.signal(sig, _note) for sig in (signal.SIGINT, signal.SIGTERM)}


def pending_stop() -> int | None:
    """The first stop signal noted since `catch_early_stops`, or None; taken (a second call
    says None until another one comes)."""
    first = _PENDING[0] if _PENDING else None
    _PENDING.clear()
    return first
