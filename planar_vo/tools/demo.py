"""The demo: a rendered drive recorded as a bag, replayed through the odometry, evaluated.

``planar_vo demo`` (the README's first command) calls `run_demo`. Everything it writes goes to
one folder, marked as a demo folder so that the next run may replace it (and nothing else).
"""

from __future__ import annotations

import shutil
import time
from dataclasses import dataclass
from pathlib import Path

from planar_vo.config import PlanarVoConfig
from planar_vo.core.camera import CameraModel
from planar_vo.errors import InputError, OutputError, PlanarVoError

__all__ = ['CAMERAS', 'DemoResult', 'run_demo']

MARKER = '.planar_vo_demo'
# Demo cameras: VGA, and a KITTI-like wide strip.
CAMERAS = {
    '640x480': lambda: CameraModel.pinhole(640, 480, 500.0),
    '1241x376': lambda: CameraModel.pinhole(1241, 376, 718.856, cx=607.19, cy=185.22),
}


@dataclass(frozen=True)
class DemoResult:
    """What the demo produced: its folder, the files in it, and the headline numbers."""

    out_dir: Path
    files: dict[str, Path]
    frames: int
    distance: float
    metrics: dict
    replay_fps: float


def _prepare(out_dir: Path, force: bool) -> None:
    if out_dir.exists():
        if not (out_dir / MARKER).exists() and not force:
            raise InputError(f"out: '{out_dir}' exists and is not a demo folder; choose another "
                             f"--out or pass --force")
        where = out_dir.resolve()
        cwd = Path.cwd().resolve()
        if where == cwd or where in cwd.parents or where == Path.home().resolve():
            # --force replaces the folder: never the one the user works in, one above it or
            # the home folder (``--out . --force`` would otherwise delete the working folder).
            raise InputError(f"out: '{out_dir}' is the current folder, one above it or the home "
                             f'folder; the demo replaces its folder, so choose another --out')
    try:
        if out_dir.exists():
            shutil.rmtree(out_dir)
        out_dir.mkdir(parents=True)
        (out_dir / MARKER).write_text('written by planar_vo demo; replaced by the next run\n')
    except OSError as err:
        raise OutputError(f"out: cannot write the demo folder '{out_dir}' "
                          f'({err.strerror or err})') from err


def _contents(out_dir: Path) -> str:
    """What a stopped demo left in its folder, for the note on the exception."""
    names = sorted(p.name for p in out_dir.iterdir() if not p.name.startswith('.')
                   ) if out_dir.is_dir() else []
    return f"'{out_dir}' holds: {', '.join(names) or 'nothing'}"


def run_demo(out_dir: str | Path = 'planar_vo_demo', *, camera: str = '640x480',
             seed: int = 0, frames: int | None = None, storage: str = 'mcap',
             force: bool = False, progress: bool = True, log=print) -> DemoResult:
    """Render the demo drive, replay it through `VisualOdometry`, evaluate against ground truth.

    Args:
        out_dir: folder for everything (a previous demo folder there is replaced).
        camera: ``'640x480'`` or ``'1241x376'``.
        seed: seed of the rendered street world.
        frames: use only the first ``frames`` frames of the drive (None: all, about 390).
        storage: bag storage, ``'mcap'`` or ``'sqlite3'``.
        force: replace ``out_dir`` even if it is not a demo folder.
        progress: progress bars on stderr.
        log: where progress lines go.

    Raises:
        InputError: bad arguments, or `out_dir` exists and is not a demo folder.
        OutputError, BagError: the folder or a file in it cannot be written (read-only or full
            disk). On any error or interruption the exception carries a note listing what the
            folder holds; every file in it is complete (bags, TUM, plots), or absent.
    """
    if camera not in CAMERAS:
        raise InputError(f"camera: expected one of {list(CAMERAS)}, got '{camera}'")
    if frames is not None and frames < 3:
        raise InputError(f'frames: expected at least 3, got {frames}')
    if not 0 <= seed < 2 ** 32:
        raise InputError(f'seed: expected an integer in [0, 2^32), got {seed}')
    if frames is not None:
        from planar_vo.sim.drive import demo_drive

        total = len(demo_drive())
        if frames > total:
            raise InputError(f'frames: expected at most {total} (the demo drive), got {frames}')
    if not str(out_dir).strip():
        raise InputError('out: an empty path; expected the folder to write the demo to')
    out_dir = Path(out_dir)
    _prepare(out_dir, force)
    try:
        return _run(out_dir, camera, seed, frames, storage, progress, log)
    except (PlanarVoError, KeyboardInterrupt) as err:
        err.add_note(_contents(out_dir))
        raise


def _run(out_dir: Path, camera: str, seed: int, frames: int | None, storage: str,
         progress: bool, log) -> DemoResult:
    """`run_demo` after the folder is prepared."""
    from planar_vo.pipeline import VisualOdometry
    from planar_vo.sim.drive import demo_drive
    from planar_vo.tools.evaluation import (evaluate, load_trajectory, read_bag_odometry,
                                            write_report)
    from planar_vo.tools.record import record_drive
    from planar_vo.tools.replay import replay_bag

    drive = demo_drive()
    if frames is not None:
        drive = drive.subset(slice(0, frames))
    config = PlanarVoConfig()                  # the camera is mounted at config.mount (defaults)
    files = {'drive': out_dir / 'drive', 'odometry': out_dir / 'odometry',
             'tum': out_dir / 'odometry.tum', 'evaluation': out_dir / 'evaluation'}
    t = time.perf_counter()
    recorded = record_drive(files['drive'], drive, camera=CAMERAS[camera](), mount=config.mount,
                            seed=seed, storage=storage, progress=progress)
    log(f'rendered {recorded.frames} frames ({recorded.distance:.0f} m, {recorded.duration:.0f} s '
        f'of driving, {camera}) in {time.perf_counter() - t:.1f} s -> {files["drive"]}')
    summary = replay_bag(files['drive'], files['odometry'], VisualOdometry(config),
                         tum_path=files['tum'], storage=storage, progress=progress)
    log(summary.format())
    est, covariances = read_bag_odometry(files['odometry'], '/odom', role='est-topic')
    ref = load_trajectory(files['odometry'], '/ground_truth/odom', role='gt-topic')
    evaluation = evaluate(ref, est, align='se3', covariances=covariances)
    log(evaluation.format_table())
    for path in write_report(evaluation, files['evaluation'], estimate=files['odometry'],
                             reference=files['drive']):
        files[path.stem] = path
    return DemoResult(out_dir, files, recorded.frames, recorded.distance, evaluation.metrics(),
                      summary.throughput)
