"""Dotted keys of the configuration (``voting.bins``): the names of ROS parameters, with their
descriptions read from the sections' ``Attributes:`` docstrings and their ranges from the
sections' fields (`planar_vo.core.options.bounded`)."""

from __future__ import annotations

import dataclasses
import typing
from typing import Any

from planar_vo.config.sections import PlanarVoConfig
from planar_vo.core.options import Options, Range

__all__ = ['describe', 'flatten', 'ranges']


def describe(section: type[Options] = None, prefix: str = '') -> dict[str, str]:
    """Dotted key -> one-line plain-text description (reStructuredText quotes removed), read
    from the sections' ``Attributes:`` docstrings."""
    section = PlanarVoConfig if section is None else section
    docs: dict[str, str] = {}
    current: list[str] = []
    lines = (section.__doc__ or '').splitlines()
    fields = {f.name for f in dataclasses.fields(section)}
    in_attrs, indent = False, None
    for line in lines:
        stripped = line.strip()
        if stripped == 'Attributes:':
            in_attrs = True
            continue
        if not in_attrs or not stripped:
            continue
        head, sep, text = stripped.partition(': ')
        # A new entry names fields at the entries' indentation (the first entry's); a
        # continuation line, indented further, is text even when it reads 'word: ...' (a
        # review: 'acceleration: ...' cut a description short) or names a field.
        depth = len(line) - len(line.lstrip())
        if (sep and (indent is None or depth <= indent)
                and all(part.strip() in fields for part in head.split(','))):
            indent = depth if indent is None else indent
            current = [part.strip() for part in head.split(',')]
            for name in current:
                docs[name] = text
        elif current:
            for name in current:
                docs[name] += ' ' + stripped
    out: dict[str, str] = {}
    hints = typing.get_type_hints(section)
    for f in dataclasses.fields(section):
        key = f'{prefix}.{f.name}' if prefix else f.name
        hint = hints[f.name]
        if isinstance(hint, type) and issubclass(hint, Options):
            out.update(describe(hint, key))
        else:
            out[key] = docs.get(f.name, '').replace('``', '').replace('`', '')
    return out


def ranges(section: type[Options] = None, prefix: str = '') -> dict[str, Range]:
    """Dotted key -> `Range` of every numeric parameter declared with a range."""
    section = PlanarVoConfig if section is None else section
    out: dict[str, Range] = {}
    hints = typing.get_type_hints(section)
    declared = section.ranges()
    for f in dataclasses.fields(section):
        key = f'{prefix}.{f.name}' if prefix else f.name
        hint = hints[f.name]
        if isinstance(hint, type) and issubclass(hint, Options):
            out.update(ranges(hint, key))
        elif f.name in declared:
            out[key] = declared[f.name]
    return out


def flatten(config: Options) -> dict[str, Any]:
    """Dotted-key view ``{'voting.bins': 720, ...}`` of a configuration (ROS parameter names)."""
    out: dict[str, Any] = {}

    def walk(prefix: str, value: Any) -> None:
        if isinstance(value, dict):
            for k, v in value.items():
                walk(f'{prefix}.{k}' if prefix else k, v)
        else:
            out[prefix] = value

    walk('', config.to_dict())
    return out
