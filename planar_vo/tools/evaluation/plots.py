"""PNG plots of an `Evaluation` (matplotlib, imported lazily, drawn off-screen with Agg).

Figures are built with ``matplotlib.figure.Figure`` rather than pyplot, so no global backend or
figure state is touched (safe inside other programs and tests). Each PNG is written under a
temporary name and renamed when complete (`planar_vo.io.outputs.write_file`): an interrupted or
failed plot leaves no truncated file, and `OutputError` names the file and the reason.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from planar_vo.io.outputs import write_file
from planar_vo.tools.evaluation.metrics import Evaluation

__all__ = ['PLOTS', 'plot_ate', 'plot_trajectories', 'plot_yaw_heading', 'save_plots']


def _figure(rows: int = 1, height: float = 4.5):
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8.0, height * rows), dpi=100, layout='constrained')
    return fig, fig.subplots(rows, 1, squeeze=False)[:, 0]


def plot_trajectories(evaluation: Evaluation, path: str | Path) -> Path:
    """Top view (x-y) of the reference and the aligned estimate."""
    fig, (ax,) = _figure(height=6.0)
    ref, est = evaluation.ref.positions, evaluation.aligned.positions
    ax.plot(ref[:, 0], ref[:, 1], '-', color='0.3', lw=2.0, label='reference')
    ax.plot(est[:, 0], est[:, 1], '-', color='tab:red', lw=1.2,
            label=f'estimate ({evaluation.alignment.method}-aligned)')
    ax.plot(ref[:1, 0], ref[:1, 1], 'o', color='0.3', label='start')
    ax.set_xlabel('x (m)')
    ax.set_ylabel('y (m)')
    ax.set_aspect('equal', adjustable='datalim')
    ax.grid(True, alpha=0.3)
    ax.legend(loc='best')
    ax.set_title('Trajectory, top view')
    return write_file(path, fig.savefig, role='plot')


def plot_ate(evaluation: Evaluation, path: str | Path) -> Path:
    """Absolute trajectory error over time."""
    fig, (ax,) = _figure()
    t = evaluation.ref.stamps - evaluation.ref.stamps[0]
    ax.plot(t, evaluation.ate, '-', color='tab:blue')
    rmse = float(np.sqrt(np.mean(evaluation.ate ** 2)))
    ax.axhline(rmse, color='tab:orange', ls='--', label=f'RMSE {rmse:.3f} m')
    ax.set_xlabel('time (s)')
    ax.set_ylabel('ATE (m)')
    ax.grid(True, alpha=0.3)
    ax.legend(loc='best')
    ax.set_title(f'Absolute trajectory error ({evaluation.alignment.method} alignment)')
    return write_file(path, fig.savefig, role='plot')


def plot_yaw_heading(evaluation: Evaluation, path: str | Path) -> Path:
    """Per-frame yaw-change and heading errors (degrees)."""
    fig, axes = _figure(rows=2, height=3.2)
    t = evaluation.ref.stamps[1:] - evaluation.ref.stamps[0]
    for ax, values, label in ((axes[0], evaluation.yaw_change_error_deg, 'yaw-change error'),
                              (axes[1], evaluation.heading_error_deg, 'heading error')):
        ax.plot(t, values, '.-', ms=3, lw=0.8)
        ax.axhline(0.0, color='0.5', lw=0.8)
        ax.set_ylabel(f'{label} (deg)')
        ax.grid(True, alpha=0.3)
    axes[0].set_title('Per-frame errors (estimate - reference)')
    axes[1].set_xlabel('time (s)')
    return write_file(path, fig.savefig, role='plot')


# File name -> plot function, in the order they are written.
PLOTS = {
    'trajectory.png': plot_trajectories,
    'ate.png': plot_ate,
    'yaw_heading.png': plot_yaw_heading,
}


def save_plots(evaluation: Evaluation, out_dir: str | Path) -> list[Path]:
    """All plots (`PLOTS`: ``trajectory.png``, ``ate.png``, ``yaw_heading.png``) in `out_dir`."""
    return [plot(evaluation, Path(out_dir) / name) for name, plot in PLOTS.items()]
