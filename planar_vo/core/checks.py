"""Input checks run once at each public entry point (kornia style): shapes, dtypes, finiteness.

The maths below an entry point trusts its inputs; numerically bad items are flagged there (NaN or
a weight), never raised.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from planar_vo.errors import InputError

__all__ = ['as_array', 'as_rotation', 'positive_number', 'same_length', 'shape_str']

# Array kinds accepted as real numbers: bool, integers, floats, and objects (Python ints,
# Decimals) converted one by one. Complex, strings, dates are refused, not silently cast.
_REAL_KINDS = frozenset('biufO')


def shape_str(shape: tuple[int | str | None, ...]) -> str:
    """Render a shape like ``(N, 2, 2)``; ``None`` and strings stand for free dimensions."""
    parts = ['N' if d is None else str(d) for d in shape]
    return '(' + ', '.join(parts) + (',)' if len(parts) == 1 else ')')


def positive_number(name: str, value: Any, what: str) -> float:
    """`value` as a finite positive float, or `InputError` naming `name` and `what`."""
    try:
        number = float(value)
    except (TypeError, ValueError, OverflowError):
        number = float('nan')
    if not (math.isfinite(number) and number > 0):
        raise InputError(f'{name}: expected {what}, got {value!r}')
    return number


def as_array(
    name: str,
    value: Any,
    shape: tuple[int | str | None, ...],
    *,
    min_items: int = 1,
    finite: bool = True,
) -> np.ndarray:
    """Return `value` as a float64 array of `shape`, or raise `InputError` naming `name`.

    Complex values (whose imaginary part a cast would drop), strings and numbers beyond float64
    (a Python ``10**400``) are refused; so are NaN and infinity (a ``Decimal('1e400')``
    becomes infinity) unless ``finite=False``.

    Args:
        name: argument name used in the error message.
        value: array-like input.
        shape: expected shape; ``None`` (or a string) marks a free dimension. A string names a
            dimension that must agree across the call, which the caller checks.
        min_items: minimum size of the first dimension when it is free.
        finite: reject NaN and infinity.
    """
    def expected() -> str:                         # built for an error only (hot path)
        return f'{name}: expected a numeric array of shape {shape_str(shape)}'

    try:
        arr = np.asarray(value)
    except (TypeError, ValueError) as err:        # ragged nesting
        raise InputError(f'{expected()}, got {type(value).__name__}') from err
    if arr.dtype.kind not in _REAL_KINDS:
        raise InputError(f'{expected()} of real numbers, got {arr.dtype} values')
    try:
        arr = arr.astype(np.float64, copy=False)
    except (TypeError, ValueError) as err:        # objects that are not real numbers
        raise InputError(f'{expected()}, got {type(value).__name__}') from err
    except OverflowError as err:                  # Python ints beyond float64 (10**400)
        raise InputError(f'{name}: expected finite values, got a number too large for float64 '
                         f'({err})') from err
    if arr.ndim != len(shape) or any(
        isinstance(d, int) and d != s for d, s in zip(shape, arr.shape)
    ):
        raise InputError(f'{name}: expected shape {shape_str(shape)}, got {arr.shape}')
    if not isinstance(shape[0], int) and arr.shape[0] < min_items:
        raise InputError(f'{name}: expected at least {min_items} item(s) along the first axis, '
                         f'got {arr.shape[0]}')
    if finite and not np.all(np.isfinite(arr)):
        bad = int(np.count_nonzero(~np.isfinite(arr)))
        raise InputError(f'{name}: expected finite values, got {bad} NaN or infinite value(s)')
    return arr


def same_length(**arrays: np.ndarray) -> int:
    """Check that all arrays have the same first dimension and return it."""
    lengths = {k: v.shape[0] for k, v in arrays.items()}
    if len(set(lengths.values())) > 1:
        desc = ', '.join(f'{k} has {n}' for k, n in lengths.items())
        raise InputError(f'arguments must have the same number of items: {desc}')
    return next(iter(lengths.values()))


def as_rotation(name: str, value: Any, tolerance: float = 1e-6) -> np.ndarray:
    """Return `value` as a 3x3 rotation matrix (orthonormal within ``tolerance``, determinant
    +1), or raise `InputError` naming `name`."""
    R = as_array(name, value, (3, 3))
    if not np.abs(R @ R.T - np.eye(3)).max() <= tolerance or np.linalg.det(R) <= 0:
        raise InputError(f'{name}: expected a rotation matrix, got {R.tolist()}')
    return R
