"""Markdown tables for reports (the benchmarks' and the fleet runs')."""

from __future__ import annotations

from collections.abc import Iterable, Sequence

__all__ = ['format_cell', 'markdown_table']


def format_cell(value: float, digits: int = 2) -> str:
    """Compact scientific/fixed formatting for a table cell; NaN -> '-'."""
    if value is None or value != value:
        return '-'
    if value == 0.0:
        return '0'
    if 1e-2 <= abs(value) < 1e4:
        return f'{value:.{digits + 1}g}'
    return f'{value:.{digits}e}'


def markdown_table(header: Sequence[str], rows: Iterable[Sequence[object]],
                   align: str | None = None) -> str:
    """A GitHub markdown table; ``align`` is one character per column (``l``/``r``)."""
    header = list(header)
    align = align or 'l' + 'r' * (len(header) - 1)
    rule = ['---:' if a == 'r' else ':---' for a in align]
    lines = ['| ' + ' | '.join(header) + ' |', '|' + '|'.join(rule) + '|']
    lines += ['| ' + ' | '.join(str(c) for c in row) + ' |' for row in rows]
    return '\n'.join(lines)
