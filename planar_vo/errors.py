"""Typed errors of planar_vo, all under one root, `PlanarVoError`.

Library code raises these with a message that names the offending argument, what was received
and what was expected; the CLI turns them into a one-line message and exit code 1, the node into
a logged warning and a counted, skipped frame.
"""

from __future__ import annotations

__all__ = [
    'BagError',
    'CameraModelError',
    'ConcurrencyError',
    'ConfigError',
    'DependencyError',
    'ImageError',
    'InputError',
    'OutputError',
    'PlanarVoError',
    'plural',
    'one_line',
]


def plural(n: int, noun: str) -> str:
    """``1 frame``, ``2 frames`` (for messages)."""
    return f'{n} {noun}' if n == 1 else f'{n} {noun}s'


def one_line(err: BaseException | str) -> str:
    """An exception's (or any) text on one line (numpy reprs and third-party messages may span
    several)."""
    text = ' '.join(str(err).split())
    return text or type(err).__name__


class PlanarVoError(Exception):
    """Root of every error planar_vo raises on purpose."""


class InputError(PlanarVoError, ValueError):
    """An array argument has the wrong shape, type or non-finite values, or too few items."""


class ConfigError(PlanarVoError, ValueError):
    """A configuration value is unknown, of the wrong type or out of range."""


class CameraModelError(PlanarVoError, ValueError):
    """Camera intrinsics or distortion are missing, inconsistent or unsupported."""


class DependencyError(PlanarVoError, ImportError):
    """An optional dependency (an extra such as ``planar_vo[fleet]``) is not installed."""


class ConcurrencyError(PlanarVoError, RuntimeError):
    """An object that is not thread-safe was called from two threads at once (one
    `VisualOdometry` per camera and thread, or calls serialised by a lock)."""


class ImageError(PlanarVoError, ValueError):
    """An image cannot be used: unsupported encoding, wrong size, or no usable texture."""


class BagError(PlanarVoError):
    """A bag cannot be read or written: missing, corrupt, truncated, or would be overwritten."""


class OutputError(PlanarVoError):
    """An output file or folder cannot be written (no permission, read-only or full disk, or it
    exists and must not be overwritten); the message names it and says what was kept."""
