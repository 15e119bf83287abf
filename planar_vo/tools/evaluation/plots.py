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

__all__ = ['PLOTS', 'SLOW_SPEED', 'plot_ate', 'plot_trajectories', 'plot_yaw_heading',
           'save_plots', 'slow_steps']


def _figure(rows: int = 1, height: float = 4.5):
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8.0, height * rows), dpi=100, layout='constrained')
    return fig, fig.subplots(rows, 1, squeeze=False)[:, 0]


def plot_trajectories(evaluation: Evaluation, path: str | Path) -> Path:
    """Top view (x-y) of the reference and the aligned estimate, with start and end markers.

    The reference is a wide light band under the thin estimate, so that both stay visible when
    they coincide (an accurate estimate would otherwise hide the reference completely)."""
    fig, (ax,) = _figure(height=6.0)
    ref, est = evaluation.ref.positions, evaluation.aligned.positions
    ax.plot(ref[:, 0], ref[:, 1], '-', color='tab:blue', lw=6.0, alpha=0.3,
            solid_capstyle='round', zorder=1, label='reference')
    ax.plot(est[:, 0], est[:, 1], '-', color='tab:red', lw=1.0, zorder=3,
            label=f'estimate ({evaluation.alignment.method}-aligned)')
    ax.plot(ref[0, 0], ref[0, 1], 'o', color='tab:green', ms=9, zorder=4, label='start')
    ax.plot(ref[-1, 0], ref[-1, 1], 's', mfc='none', mec='tab:blue', mew=2.0, ms=11, zorder=4,
            label='end (reference)')
    ax.plot(est[-1, 0], est[-1, 1], 'x', color='tab:red', mew=2.0, ms=9, zorder=5,
            label='end (estimate)')
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


# Below this reference speed the heading of a frame-to-frame step is ill-defined: a step of
# d metres with a centimetre of position noise has a heading error of about 0.01 / d rad, 6
# degrees at 1 m/s and 10 Hz, 60 at a crawl.
SLOW_SPEED = 0.5


def plot_yaw_heading(evaluation: Evaluation, path: str | Path) -> Path:
    """Per-frame yaw-change and heading errors (degrees).

    Heading errors of frames slower than `SLOW_SPEED` (standing still, stopping, starting),
    where the heading of the step is undefined or ill-defined, are left out of the line and the
    axis scale, marked as grey crosses (clipped to the axis) on a shaded background."""
    fig, axes = _figure(rows=2, height=3.2)
    t = evaluation.ref.stamps[1:] - evaluation.ref.stamps[0]
    slow = slow_steps(evaluation)
    axes[0].plot(t, evaluation.yaw_change_error_deg, '.-', ms=3, lw=0.8)
    heading = np.asarray(evaluation.heading_error_deg, dtype=float)
    axes[1].plot(t, np.where(slow, np.nan, heading), '.-', ms=3, lw=0.8,
                 label='heading error')
    if slow.any():
        valid = heading[~slow & np.isfinite(heading)]
        limit = max(1.0, 1.2 * float(np.max(np.abs(valid)))) if valid.size else 1.0
        axes[1].set_ylim(-limit, limit)
        axes[1].plot(t[slow], np.clip(heading[slow], -limit, limit), 'x', color='0.5', ms=4,
                     label=f'below {SLOW_SPEED:g} m/s: heading ill-defined (not in the line)')
        for start, end in _runs(slow):
            axes[1].axvspan(t[start], t[end], color='0.85', lw=0, zorder=0)
        axes[1].legend(loc='upper right', fontsize='small')
    for ax, label in ((axes[0], 'yaw-change error'), (axes[1], 'heading error')):
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


def slow_steps(evaluation: Evaluation) -> np.ndarray:
    """``(N-1,)`` bool: the reference moved slower than `SLOW_SPEED` between frames i and i+1
    (the steps of ``heading_error_deg``)."""
    ref = evaluation.ref
    steps = np.linalg.norm(np.diff(ref.positions[:, :2], axis=0), axis=1)
    return steps < SLOW_SPEED * np.maximum(np.diff(ref.stamps), 1e-9)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """``(first, last)`` indices of each run of True in ``mask``."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1))


def save_plots(evaluation: Evaluation, out_dir: str | Path) -> list[Path]:
    """All plots (`PLOTS`: ``trajectory.png``, ``ate.png``, ``yaw_heading.png``) in `out_dir`."""
    return [plot(evaluation, Path(out_dir) / name) for name, plot in PLOTS.items()]
