"""The summary of a fleet run (`planar_vo.tools.fleet`): ``summary.json``, ``report.md`` and
its plots (drift per bag, trajectory thumbnails).

``summary.json``: ``rows`` (one per bag and configuration, in job order: ``bag``, ``config``,
``status``, ``reason``, ``frames_in``, ``odom_out``, ``drops`` by reason, ``wall_s``,
``frames_per_s``, with ground truth ``t_rel_pct``, ``r_rel_deg100m`` (on the segments
``drift_segments`` names: 100-800 m, or 10-50 m for a drive shorter than 100 m),
``yaw_err_mean_deg``, ``ate_sim3_m``, ``path_m``; and where the outputs are), ``totals``,
``configs`` (aggregates per configuration; their drift means only over the 100-800 m runs) and
``run`` (jobs, skipped, ran, not run, timings, where).
"""

from __future__ import annotations

import json
import math
import os
import shlex
import textwrap
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from planar_vo.errors import plural
from planar_vo.io.outputs import write_file
from planar_vo.tools.evaluation.report import json_ready
from planar_vo.tools.markdown import format_cell, markdown_table

__all__ = ['aggregate', 'bag_names', 'plot_drift', 'plot_thumbnails', 'write_json',
           'write_summary']

MAX_BARS = 80            # bags in the drift plot (the largest drifts beyond that)
MAX_THUMBNAILS = 48


def write_json(path: Path, value: Any) -> None:
    """Write JSON atomically (a reader sees the old file or the new one, never a part)."""
    write_file(path, json.dumps(json_ready(value), indent=1) + '\n')


def _mean(values: Sequence[float | None]) -> float | None:
    finite = [v for v in values if v is not None and math.isfinite(v)]
    return sum(finite) / len(finite) if finite else None


def _long(row: dict) -> bool:
    """Whether a row's drift is on the KITTI protocol's 100-800 m segments (rows written
    before ``drift_segments`` existed had only those)."""
    return row.get('drift_segments', '100-800 m') == '100-800 m'


def _drift_cell(row: dict, key: str) -> str:
    """A run's drift figure, with its segments when they are a short drive's."""
    cell = format_cell(row[key])
    return cell if row[key] is None or _long(row) else f'{cell} ({row["drift_segments"]})'


def _ate_pct(row: dict) -> float | None:
    ate, path = row.get('ate_sim3_m'), row.get('path_m')
    return 100.0 * ate / path if ate is not None and path else None


def aggregate(rows: Sequence[dict]) -> dict:
    """Counts, frames, kilometres (ground-truth path of the ``ok`` rows) and mean metrics."""
    ok = [r for r in rows if r['status'] == 'ok']
    task_s = sum(r['wall_s'] or 0.0 for r in ok)
    frames = sum(r['frames_in'] for r in ok)
    return {
        'runs': len(rows),
        'bags': len({r['bag'] for r in rows}),
        'ok': len(ok),
        'failed': len(rows) - len(ok),
        'frames_in': frames,
        'odom_out': sum(r['odom_out'] for r in ok),
        'km': sum(r['path_m'] or 0.0 for r in ok) / 1000.0,
        'task_s': task_s,
        'frames_per_s_per_task': frames / task_s if task_s > 0 else None,
        # Drift on 10-50 m segments is not that on 100-800 m: only the latter are averaged.
        't_rel_pct': _mean([r['t_rel_pct'] for r in ok if _long(r)]),
        'r_rel_deg100m': _mean([r['r_rel_deg100m'] for r in ok if _long(r)]),
        'yaw_err_mean_deg': _mean([r['yaw_err_mean_deg'] for r in ok]),
        'ate_sim3_m': _mean([r['ate_sim3_m'] for r in ok]),
        'ate_sim3_pct': _mean([_ate_pct(r) for r in ok]),
    }


def _figure(width: float, height: float):
    from matplotlib.figure import Figure

    return Figure(figsize=(width, height), dpi=80, layout='constrained')


def bag_names(bags: Sequence[str]) -> dict[str, str]:
    """Short names of bag paths: relative to their deepest common folder; the paths as they
    are when that is the root (a user test: 'data/k05' for '/data/k05' read as relative)."""
    bags = list(dict.fromkeys(bags))
    if not bags:
        return {}
    base = os.path.commonpath([str(Path(b).parent) for b in bags])
    if Path(base) == Path(base).parent:             # nothing in common but the root
        return {b: b for b in bags}
    return {b: os.path.relpath(b, base) for b in bags}


def _label(row: dict, names: dict[str, str], configs: int) -> str:
    name = names[row['bag']]
    return f'{name} [{row["config"]}]' if configs > 1 else name


# Characters of a thumbnail's title line at its font size (a panel is 2.2 in wide).
_TITLE_WIDTH = 34


def _panel_title(row: dict, names: dict[str, str], configs: int) -> str:
    """`_label` in lines that fit a thumbnail (a user test: long names ran into the next
    panel's): the name wrapped (a path anywhere), the configuration on a line of its own."""
    lines = textwrap.wrap(names[row['bag']], _TITLE_WIDTH, break_long_words=True) or ['']
    if configs > 1:
        lines += textwrap.wrap(f'[{row["config"]}]', _TITLE_WIDTH, break_long_words=True)
    return '\n'.join(lines)


def plot_drift(rows: Sequence[dict], path: Path, names: dict[str, str], configs: Sequence[str]
               ) -> Path | None:
    """Bars per bag (coloured by configuration): ATE after sim(3) alignment in % of the path,
    and the KITTI t_rel (%) when some drive is long enough for it."""
    rows = [r for r in rows if _ate_pct(r) is not None]
    if not rows:
        return None
    if len(rows) > MAX_BARS:
        rows = sorted(rows, key=_ate_pct, reverse=True)[:MAX_BARS]
    kitti = any(r['t_rel_pct'] is not None and _long(r) for r in rows)
    fig = _figure(9.0, 1.5 + 0.22 * len(rows))
    axes = fig.subplots(1, 2 if kitti else 1, sharey=True, squeeze=False)[0]
    y = list(range(len(rows)))
    labels = [_label(r, names, len(configs)) for r in rows]
    colours = [f'C{configs.index(r["config"]) % 10}' for r in rows]
    panels = [(axes[0], [_ate_pct(r) for r in rows], 'ATE sim(3) (% of path)')]
    if kitti:
        # No bar where there is no 100-800 m figure (a 0 would read as no drift).
        panels.append((axes[1], [r['t_rel_pct'] if r['t_rel_pct'] is not None and _long(r)
                                 else math.nan for r in rows], 'KITTI t_rel (%)'))
    for ax, values, title in panels:
        ax.barh(y, values, color=colours)
        ax.set_xlabel(title)
        ax.grid(True, axis='x', alpha=0.3)
    axes[0].set_yticks(y, labels, fontsize=7)
    axes[0].invert_yaxis()
    fig.suptitle('Drift per bag' + (f' (the {MAX_BARS} largest)' if len(rows) == MAX_BARS
                                    else ''))
    return write_file(path, fig.savefig, role='plot')


def plot_thumbnails(records: Sequence[dict], path: Path, names: dict[str, str], configs: int
                    ) -> Path | None:
    """Top views of ground truth (grey) and the sim(3)-aligned estimate (red), one per run."""
    records = [r for r in records if r.get('thumbnail')][:MAX_THUMBNAILS]
    if not records:
        return None
    cols = min(6, len(records))
    nrows = math.ceil(len(records) / cols)
    # At least 4.4 in wide, the title in two lines below three panels (a user test: one run's
    # title was cut to '...d truth (grey), estimate si...').
    fig = _figure(max(2.2 * cols, 4.4), 2.3 * nrows + 0.3)
    axes = fig.subplots(nrows, cols, squeeze=False)
    for k, (ax, record) in enumerate(zip(axes.ravel(), records)):
        ref, est = record['thumbnail']['ref_xy'], record['thumbnail']['est_xy']
        ax.plot([p[0] for p in ref], [p[1] for p in ref], '-', color='0.4', lw=1.5)
        ax.plot([p[0] for p in est], [p[1] for p in est], '-', color='tab:red', lw=0.9)
        ax.set_aspect('equal', adjustable='datalim')
        ax.set_title(_panel_title(record['row'], names, configs), fontsize=7)
        ax.tick_params(labelsize=6)
        if k % cols == 0:
            ax.set_ylabel('y (m)', fontsize=6)
        if k + cols >= len(records):
            ax.set_xlabel('x (m)', fontsize=6)
    for ax in axes.ravel()[len(records):]:
        ax.set_axis_off()
    sep = ', ' if cols >= 3 else ',\n'
    fig.suptitle(f'Trajectories: ground truth (grey){sep}estimate sim(3)-aligned (red)',
                 fontsize=10 if cols >= 3 else 9)
    return write_file(path, fig.savefig, role='plot')


def _report(summary: dict, plots: list[Path], names: dict[str, str],
            command: Sequence[str] | None) -> str:
    rows, totals, configs = summary['rows'], summary['totals'], summary['configs']
    info = summary['run']
    parts = ['# planar_vo fleet run']
    if command:
        parts.append('```sh\n' + shlex.join(command) + '\n```')
    state = (f"**Interrupted**: {info['not_run']} of {info['jobs']} not run; rerun the same "
             'command to finish them.' if info['interrupted'] else 'Complete.')
    if info.get('local'):
        where, start = 'this process (no Ray)', ''
    else:
        where = info['address'] or f"a local Ray instance with {plural(info['workers'], 'CPU')}"
        start = f" (Ray start {info['ray_start_s']:.1f} s)"
    ran = (f"{info['ran']} run now on {where} in {info['tasks_s']:.1f} s (wall time)"
           f"{start}, {info['skipped']} already there"
           if info['ran'] else f"all {info['skipped']} already there (nothing run)")
    parts.append(f"{state} {plural(totals['runs'], 'result')} ({plural(totals['bags'], 'bag')} "
                 f"x {plural(len(configs), 'configuration')}): {totals['ok']} ok, "
                 f"{totals['failed']} failed; {ran}.")
    throughput = info['frames_per_s']
    parts.append('## Totals\n\n' + markdown_table(
        ['frames', 'odometry', 'km (ground truth)', 'task time (s)', 'frames/s per task',
         'aggregate frames/s (this run)'],
        [[totals['frames_in'], totals['odom_out'], f"{totals['km']:.3f}",
          f"{totals['task_s']:.1f}", format_cell(totals['frames_per_s_per_task']),
          format_cell(throughput)]]))
    parts.append('## Per configuration\n\nMeans over the ok runs with ground truth; t_rel and '
                 'r_rel by the KITTI protocol (segments of 100-800 m; a drive shorter than 100 '
                 'm has them on 10-50 m in the runs table, left out of these means), ATE after '
                 'sim(3) alignment.\n\n' + markdown_table(
                     ['configuration', 'runs', 'ok', 'failed', 'frames', 'km', 't_rel (%)',
                      'r_rel (deg/100 m)', 'yaw err (deg)', 'ATE sim3 (m)', 'ATE (% path)',
                      'frames/s per task'],
                     [[c['config'], c['runs'], c['ok'], c['failed'], c['frames_in'],
                       f"{c['km']:.3f}",
                       *map(format_cell, (c['t_rel_pct'], c['r_rel_deg100m'],
                                          c['yaw_err_mean_deg'], c['ate_sim3_m'],
                                          c['ate_sim3_pct'], c['frames_per_s_per_task']))]
                      for c in configs], 'l' + 'r' * 11))
    table = []
    for r in rows:
        drops = ', '.join(f'{k} {v}' for k, v in r['drops'].items()) or '-'
        table.append([names[r['bag']], r['config'], r['status'], r['frames_in'],
                      r['odom_out'], drops,
                      *map(format_cell, (r['wall_s'], r['frames_per_s'])),
                      _drift_cell(r, 't_rel_pct'), _drift_cell(r, 'r_rel_deg100m'),
                      *map(format_cell, (r['yaw_err_mean_deg'], r['ate_sim3_m'], r['path_m'])),
                      (r['reason'] or '').replace('|', '/')])
    parts.append('## Runs\n\n' + markdown_table(
        ['bag', 'configuration', 'status', 'frames', 'odometry', 'drops', 'wall (s)',
         'frames/s', 't_rel (%)', 'r_rel (deg/100 m)', 'yaw err (deg)', 'ATE sim3 (m)',
         'path (m)', 'reason'], table, 'lllrrl' + 'r' * 7 + 'l'))
    if plots:
        parts.append('## Plots\n\n' + '\n\n'.join(f'![{p.stem}]({p.name})' for p in plots))
    else:
        parts.append('No plots: no run with ground truth.')
    return '\n\n'.join(parts) + '\n'


def write_summary(out_dir: Path, records: Sequence[dict], run: dict,
                  command: Sequence[str] | None = None) -> list[Path]:
    """Write ``summary.json``, the plots and ``report.md`` into `out_dir`; returns their paths.

    Args:
        records: result records (``row``, ``thumbnail``) in job order.
        run: what the run did (jobs, skipped, ran, not_run, interrupted, timings, where).
        command: the command line, shown in the report.

    Each file is replaced atomically, so an interrupted run leaves the summary of what is
    complete.
    """
    rows = [record['row'] for record in records]
    names = list(dict.fromkeys(r['config'] for r in rows))
    summary = {
        'rows': rows,
        'totals': aggregate(rows),
        'configs': [{'config': name, **aggregate([r for r in rows if r['config'] == name])}
                    for name in names],
        'run': dict(run),
    }
    path = out_dir / 'summary.json'
    write_json(path, summary)
    bags = bag_names([r['bag'] for r in rows])
    plots = [p for p in (plot_drift(rows, out_dir / 'drift.png', bags, names),
                         plot_thumbnails(records, out_dir / 'trajectories.png', bags, len(names)))
             if p is not None]
    report = write_file(out_dir / 'report.md', _report(summary, plots, bags, command))
    return [path, report, *plots]
