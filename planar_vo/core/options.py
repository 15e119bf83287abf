"""`Options`: the base of every frozen options dataclass (typed construction from plain data,
validation once, plain-data output).

The estimators' options (`planar_vo.core.robust.VotingConfig`) and every section of the
configuration (`planar_vo.config`) derive from it, so one mechanism checks names, types and
ranges everywhere and reports the dotted path of a bad value as a `ConfigError`.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import numbers
import re
import types
import typing
from typing import Any, ClassVar

from planar_vo.errors import ConfigError

__all__ = ['Options', 'Range', 'bounded', 'finite', 'nest_dotted']

# A number with an exponent (2e-2, 1.5e3, -1E3): YAML 1.1 (PyYAML) reads it as text unless it has
# a dot and a signed exponent; YAML 1.2 and ROS 2's parameter files read it as a number.
_YAML12_FLOAT = re.compile(r'[-+]?([0-9]+(\.[0-9]*)?|\.[0-9]+)[eE][-+]?[0-9]+')


def _bound(value: float) -> str:
    """A bound as a message shows it: an integer in full (a user test: a seed's 2**32 - 1 read
    4.29497e+09), else ``%g``."""
    return str(value) if isinstance(value, int) else f'{value:g}'


@dataclasses.dataclass(frozen=True)
class Range:
    """The interval a numeric option must lie in, declared once beside its field (`bounded`):
    `Options` checks it, and the ROS node publishes it in the parameter descriptors.

    Attributes:
        low, high: bounds (None: unbounded on that side); the value must be finite.
        low_open, high_open: the bound itself is excluded.
        expected: how an error message describes the range (default: from the bounds).
    """

    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    expected: str = ''

    def __contains__(self, value: float) -> bool:
        if not math.isfinite(value):
            return False
        if self.low is not None and (value < self.low or (self.low_open and value == self.low)):
            return False
        return self.high is None or not (value > self.high or
                                         (self.high_open and value == self.high))

    def __str__(self) -> str:
        if self.expected:
            return self.expected
        if self.low is not None and self.high is not None:
            return (f'in {"(" if self.low_open else "["}{_bound(self.low)}, '
                    f'{_bound(self.high)}{")" if self.high_open else "]"}')
        if self.low is not None:
            return f'{"more than" if self.low_open else "at least"} {_bound(self.low)}'
        if self.high is not None:
            return f'{"less than" if self.high_open else "at most"} {_bound(self.high)}'
        return 'a finite number'


def bounded(default: float, low: float | None = None, high: float | None = None, *,
            low_open: bool = False, high_open: bool = False, expected: str = ''):
    """A dataclass field with a default and its `Range` (checked by `Options`)."""
    return dataclasses.field(default=default, metadata={
        'range': Range(low, high, low_open, high_open, expected)})


class Options:
    """Base of frozen options dataclasses: typed construction from dicts and validation.

    Subclasses are ``@dataclass(frozen=True)`` with defaults for every field; a numeric field
    declares its range with `bounded` (checked here, shown by ``ros2 param describe``), and
    `validate` checks relations between fields; `from_dict` checks names and types and reports
    the dotted path of any bad value.
    """

    _section: ClassVar[str] = ''

    def __post_init__(self) -> None:
        # Types first (built directly, not only through `from_dict`): an int field given
        # '720', 720.5 or True, a choice outside its Literal, a float given a string.
        hints = _type_hints(type(self))
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            typed = _typed(f.name, value, hints[f.name])
            if typed is not value:
                object.__setattr__(self, f.name, typed)
        for name, allowed in self.ranges().items():
            value = getattr(self, name)
            if isinstance(value, (int, float)) and not isinstance(value, bool) \
                    and value not in allowed:
                raise ConfigError(f'{name}: expected {allowed}, got {value!r}')
        self.validate()

    @classmethod
    def ranges(cls) -> dict[str, Range]:
        """Field name -> its `Range`, for the fields declared with `bounded`."""
        return {f.name: f.metadata['range'] for f in dataclasses.fields(cls)
                if 'range' in f.metadata}

    def validate(self) -> None:
        """Check what the fields' `Range` s cannot say (relations between fields); raise
        `ConfigError` naming the field."""

    # -- construction ------------------------------------------------------------------------

    @classmethod
    def from_dict(cls, data: typing.Mapping[str, Any] | None, *, path: str = ''):
        """Build from a (nested) mapping; unknown keys and wrong types raise `ConfigError`."""
        data = {} if data is None else data
        if not isinstance(data, typing.Mapping):
            raise ConfigError(f'{path or "config"}: expected a mapping, got {type(data).__name__}')
        hints = typing.get_type_hints(cls)
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - names)
        if unknown:
            where = f'{path}.' if path else ''
            keys = ', '.join(where + k for k in unknown)
            raise ConfigError(f'unknown configuration key(s) {keys}'
                              f'; known keys: {", ".join(sorted(names))}')
        values = {}
        for name, raw in data.items():
            key = f'{path}.{name}' if path else name
            values[name] = _coerce(key, raw, hints[name])
        try:
            return cls(**values)
        except ConfigError as err:
            raise ConfigError(f'{path + "." if path else ""}{err}') from None

    def to_dict(self) -> dict[str, Any]:
        """Nested plain dict (tuples as lists), the shape of ``config/planar_vo.yaml``."""
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, Options):
                value = value.to_dict()
            elif isinstance(value, tuple):
                value = list(value)
            out[f.name] = value
        return out

    def replace(self, **changes: Any):
        """A copy with some fields changed (validated)."""
        return dataclasses.replace(self, **changes)

    # -- validation helpers ------------------------------------------------------------------

    def _require(self, ok: bool, name: str, expected: str) -> None:
        if not ok:
            raise ConfigError(f'{name}: expected {expected}, got {getattr(self, name)!r}')


@functools.cache
def _type_hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _typed(key: str, value: Any, hint: Any) -> Any:
    """A field's value as its annotated type, or `ConfigError` (direct construction: numpy
    numbers are taken as numbers, strings are not parsed)."""
    if isinstance(hint, type) and issubclass(hint, Options):
        if isinstance(value, hint):
            return value
        raise ConfigError(f'{key}: expected {hint.__name__}, got {type(value).__name__}')
    if hint in (int, float) and not isinstance(value, bool):
        if hint is int and isinstance(value, numbers.Integral):
            return value if type(value) is int else int(value)
        if hint is float and isinstance(value, numbers.Real):
            return value if type(value) is float else float(value)
        if hint is float and isinstance(value, str):
            raise ConfigError(f'{key}: expected float, got str {value!r}')
    return _coerce(key, value, hint)


def nest_dotted(data: dict, path: str = '') -> dict:
    """Dotted keys (``voting.bins: 360``, as ROS parameter files may write them) as nested
    sections, merged with the nested ones; a parameter given twice is a `ConfigError`."""
    out: dict = {}
    for key, value in data.items():
        *parents, leaf = str(key).split('.')
        node, where = out, path
        for part in parents:
            where = f'{where}.{part}' if where else part
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise ConfigError(f'{where}: a value and a section at once')
        where = f'{where}.{leaf}' if where else leaf
        if isinstance(value, dict):
            value = nest_dotted(value, where)
            if isinstance(node.get(leaf), dict):
                for k, v in value.items():
                    if k in node[leaf]:
                        raise ConfigError(f'{where}.{k}: given twice')
                    node[leaf][k] = v
                continue
        if leaf in node:
            raise ConfigError(f'{where}: given twice')
        node[leaf] = value
    return out


def _coerce(key: str, raw: Any, hint: Any) -> Any:
    """Check and convert one value to the annotated type."""
    if isinstance(hint, type) and issubclass(hint, Options):
        return hint.from_dict(raw, path=key)
    origin = typing.get_origin(hint)
    if hint is bool:
        if isinstance(raw, bool):
            return raw
    elif hint is int:
        if isinstance(raw, int) and not isinstance(raw, bool):
            if not -2**63 <= raw < 2**63:
                raise ConfigError(f'{key}: expected int, got one of {raw.bit_length()} bits '
                                  f'(at most 64)')
            return raw
    elif hint is float:
        if isinstance(raw, str) and _YAML12_FLOAT.fullmatch(raw.strip()):
            # YAML 1.1 (PyYAML) reads 2e-2 as a string, YAML 1.2 and ROS 2's parameter files
            # as a number: a file ROS accepts must not be refused here.
            raw = float(raw)
        if isinstance(raw, (int, float)) and not isinstance(raw, bool):
            try:
                return float(raw)
            except OverflowError:
                raise ConfigError(f'{key}: expected float, got an int of {raw.bit_length()} '
                                  f'bits (beyond float64)') from None
    elif hint is str:
        if isinstance(raw, str):
            return raw
    elif origin is tuple:
        (item,) = {a for a in typing.get_args(hint) if a is not Ellipsis}
        if isinstance(raw, (list, tuple)):
            return tuple(_coerce(f'{key}[{i}]', v, item) for i, v in enumerate(raw))
    elif origin is typing.Literal:
        if raw in typing.get_args(hint):
            return raw
        raise ConfigError(f'{key}: expected one of {list(typing.get_args(hint))}, got {raw!r}')
    elif origin in (typing.Union, types.UnionType):
        raise ConfigError(f'{key}: optional values are not supported')  # pragma: no cover
    else:  # pragma: no cover - a programming error in a section definition
        raise TypeError(f'{key}: unsupported configuration type {hint!r}')
    name = getattr(hint, '__name__', str(hint))
    raise ConfigError(f'{key}: expected {name}, got {type(raw).__name__} {raw!r}')


def finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)
