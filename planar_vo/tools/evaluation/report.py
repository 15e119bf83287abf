"""Writing an evaluation to a folder: ``metrics.json`` and the PNG plots."""

from __future__ import annotations

import json
import math
from pathlib import Path

from planar_vo.errors import InputError
from planar_vo.tools.evaluation.metrics import Evaluation
from planar_vo.tools.evaluation.plots import save_plots

__all__ = ['json_ready', 'write_report']


def json_ready(value):
    """NaN/inf -> None (JSON has no NaN), numpy scalars -> Python, recursively."""
    if isinstance(value, dict):
        return {k: json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_ready(v) for v in value]
    if hasattr(value, 'item') and not isinstance(value, (str, bytes)):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def write_report(evaluation: Evaluation, out_dir: str | Path, *, plots: bool = True,
                 **extra) -> list[Path]:
    """Write ``metrics.json`` (the metrics plus ``extra`` fields) and, with ``plots``, the plots
    into ``out_dir``.

    Returns the paths written, ``metrics.json`` first.
    """
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise InputError(f"out-dir: cannot create '{out}' ({err.strerror})") from err
    metrics = {**{k: str(v) for k, v in extra.items()}, **evaluation.metrics()}
    path = out / 'metrics.json'
    path.write_text(json.dumps(json_ready(metrics), indent=2) + '\n')
    return [path, *(save_plots(evaluation, out) if plots else [])]
