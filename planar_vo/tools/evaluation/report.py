"""Writing an evaluation to a folder: ``metrics.json`` and the PNG plots."""

from __future__ import annotations

import json
import math
from pathlib import Path

from planar_vo.errors import PlanarVoError
from planar_vo.io.outputs import write_file
from planar_vo.tools.evaluation.metrics import DEFAULT_SEGMENTS, Evaluation
from planar_vo.tools.evaluation.plots import PLOTS

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


def read_as(*, est_topic: str | None = None, gt_topic: str | None = None,
            est_frame: str = 'base', est_times: str | Path | None = None,
            est_start: object = None, camera_height: float | None = None,
            max_diff: float = 0.02, segments: tuple[float, ...] | list[float] = DEFAULT_SEGMENTS
            ) -> dict:
    """``metrics.json``'s record of how the estimate and reference were read (the topics of
    bags, the estimate's frame, a KITTI pose file's times and start, the camera height of camera
    poses, the association's and segments' parameters): enough to repeat the evaluation."""
    return {'est_topic': est_topic, 'gt_topic': gt_topic, 'est_frame': est_frame,
            'est_times': None if est_times is None else str(Path(est_times).resolve()),
            'est_start': None if est_start is None else str(est_start),
            'camera_height_m': camera_height, 'max_diff_s': max_diff,
            'segments_m': [float(x) for x in segments]}


def write_report(evaluation: Evaluation, out_dir: str | Path, *, plots: bool = True,
                 **extra) -> list[Path]:
    """Write ``metrics.json`` (the metrics plus ``extra`` fields: dicts as they are, other
    values as text) and, with ``plots``, the plots into ``out_dir``.

    Each file is complete or absent (`planar_vo.io.outputs.write_file`). When one cannot be
    written (a full or read-only disk) or the run is interrupted, the exception carries a note
    naming the files that were written.

    Returns:
        The paths written, ``metrics.json`` first.

    Raises:
        OutputError: a file or the folder cannot be written.
    """
    out = Path(out_dir)
    metrics = {**{k: v if isinstance(v, dict) else str(v) for k, v in extra.items()},
               **evaluation.metrics()}
    written: list[Path] = []
    try:
        written.append(write_file(out / 'metrics.json',
                                  json.dumps(json_ready(metrics), indent=2) + '\n',
                                  role='out_dir'))
        for name, plot in (PLOTS.items() if plots else ()):
            written.append(plot(evaluation, out / name))
    except (PlanarVoError, KeyboardInterrupt) as err:
        kept = ', '.join(p.name for p in written) or 'nothing'
        err.add_note(f"written to '{out}': {kept}")
        raise
    return written
