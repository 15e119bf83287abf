"""Stop signals noted before the node can act on them (`planar_vo.ros.startup` installs the
handlers first thing; the node's own handlers take over and read what came, `pending_stop`).

Light on purpose: only the standard library is imported here, and nothing of the node: the
entry point (`planar_vo.ros.startup`) and the node (`planar_vo.ros.node`) both point down to
this module.
"""

from __future__ import annotations

import signal

__all__ = ['catch_early_stops', 'pending_stop']

_PENDING: list[int] = []


def _note(signum: int, frame: object) -> None:
    _PENDING.append(signum)


def catch_early_stops() -> None:
    """Note SIGINT and SIGTERM (`pending_stop`) instead of acting on them, until the node
    installs its own handlers."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _note)


def pending_stop() -> int | None:
    """The first stop signal noted since `catch_early_stops`, or None; taken (a second call
    says None until another one comes)."""
    first = _PENDING[0] if _PENDING else None
    _PENDING.clear()
    return first
