"""Fleet runs: many bags, times a grid of configurations, replayed and evaluated as Ray tasks.

One Ray task per (bag, configuration) runs what ``planar_vo replay`` and ``planar_vo eval
--align sim3`` run (`planar_vo.tools.replay.replay_bag` with `planar_vo.pipeline.VisualOdometry`,
then `planar_vo.tools.evaluation.evaluate` when the bag has ground truth), with one thread, so
each result equals theirs with one BLAS thread (``OMP_NUM_THREADS=1 planar_vo replay ...``) to
the last bit. Ray (the ``fleet`` extra) is imported only here, inside the functions
that need it; nothing else in planar_vo imports it.

Output folder ``DIR``::

    summary.json              one row per (bag, configuration), totals, per-configuration
                              aggregates (`planar_vo.tools.fleet_report`)
    report.md, drift.png, trajectories.png
    runs/<bag>-<hash>/<configuration>-<hash>/
        odometry/             the odometry bag (MCAP), as ``planar_vo replay --out``
        odometry.tum          as ``planar_vo replay --tum``
        evaluation/metrics.json   as ``planar_vo eval --align sim3 --out-dir``
        result.json           the row; written last, atomically: it marks the result complete

Determinism: tasks share nothing (each builds its pipeline from its configuration, in a fresh
folder) and pin their threads (`single_threaded`): one OpenCV thread and one thread in every
BLAS, whatever the environment. One BLAS thread is also what makes a result independent of the
machine: OpenCV's ``cv2.gemm`` (the front-end's patch products) runs on the OpenBLAS inside
OpenCV's wheel, which rounds differently with another thread count, so a ``planar_vo replay``
with the default threads gives last bits that depend on the number of cores (and its busy-
waiting BLAS threads cost a second core). One BLAS thread set at load time
(``OMP_NUM_THREADS=1``, ``OPENBLAS_NUM_THREADS=1``) or at run time gives the same numbers.

Failures: a `PlanarVoError` of a bag (missing, corrupt, truncated, no image topic, no motion
estimated, too few poses to evaluate) makes a ``failed`` row with its one-line message, kept in
``result.json`` (a rerun does not repeat it unless the bag's files change); a failure of the
job's own outputs (a full disk) is a ``failed`` row too, but a rerun tries again. A worker that
dies (killed, out of memory) is retried by Ray up to ``retries`` times; then the row is
``failed`` and not kept, so a rerun tries again. Any other exception is a bug: a ``failed`` row
naming it, not kept.

Resuming: a job whose ``result.json`` matches it (same bag path, same bag files by size and
modification time, same configuration and topics, same planar_vo code) is skipped; anything
else in its folder is a partial result and is deleted before the job runs again. One run at a
time uses a folder. Ctrl-C stops the running tasks and writes
the summary of the complete results.
"""

from __future__ import annotations

import contextlib
import hashlib
import itertools
import json
import logging
import math
import os
import re
import shutil
import signal
import socket
import sys
import time
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from planar_vo.config import PlanarVoConfig, build_config, flatten, parse_set
from planar_vo.errors import (
    ConfigError,
    DependencyError,
    InputError,
    OutputError,
    PlanarVoError,
    one_line,
    plural,
)
from planar_vo.io.outputs import deferred_interrupts, interrupt_signal
from planar_vo.tools.fleet_report import bag_names, write_json, write_summary
from planar_vo.tools.provenance import bag_information, code_digest, evaluation_provenance

__all__ = [
    'FLEET_EXTRA',
    'FleetConfig',
    'FleetJob',
    'FleetRun',
    'bag_identity',
    'check_out_dir',
    'code_digest',
    'config_grid',
    'default_workers',
    'import_ray',
    'kitti_fields',
    'load_result',
    'plan_jobs',
    'ray_session',
    'read_manifest',
    'run_fleet',
    'run_job',
    'single_threaded',
]

log = logging.getLogger(__name__)

FLEET_EXTRA = "pip install 'planar_vo[fleet]'"
RESULT = 'result.json'
ODOMETRY, TUM, EVALUATION = 'odometry', 'odometry.tum', 'evaluation'
EST_TOPIC = '/odom'
ALIGN = 'sim3'
THUMBNAIL_POINTS = 150          # points per trajectory kept for the report's thumbnails
CLIENT_ATTEMPTS = 3             # connections to a ray:// address whose server fails to start
CONNECT_TIMEOUT_S = 5.0         # a host:port head must accept a TCP connection within this


# -- configurations and jobs ----------------------------------------------------------------------

def _digest(value: Any) -> str:
    return hashlib.sha1(json.dumps(value, sort_keys=True).encode()).hexdigest()


def _slug(text: str) -> str:
    return re.sub(r'[^A-Za-z0-9._=+-]+', '_', text).strip('_')[:60] or 'x'


@dataclass(frozen=True)
class FleetConfig:
    """One configuration of a run: its name in the rows (``default``, or the ``--set`` values
    that make it, ``voting.bins=360``) and every value by dotted key (`flatten` form)."""

    name: str
    values: dict[str, Any]

    def build(self) -> PlanarVoConfig:
        return PlanarVoConfig.from_flat(self.values)


def _format_value(value: Any) -> str:
    return value if isinstance(value, str) else json.dumps(value)


def config_grid(base: PlanarVoConfig | Mapping[str, Any], sets: Sequence[str] = (),
                source: str | None = None) -> list[FleetConfig]:
    """The configurations of ``--set KEY=V1,V2 ...`` on top of `base`: every combination.

    Args:
        base: the configuration the sets change: a `PlanarVoConfig`, or the settings of a
            ``--config`` file as dotted keys (`planar_vo.config.read_config`), validated only
            with each combination (a file may lean on the sets).
        source: the file ``base`` was read from, to name it in errors.
        sets: ``'KEY=V1[,V2...]'`` items with dotted keys (`planar_vo.config.flatten`); the
            values are YAML flow items (``360``, ``true``, ``flow``, ``[0.1, 0.2]``).

    Returns:
        One `FleetConfig` per combination, in ``itertools.product`` order of the items; just
        ``default`` (`base`) without sets.

    Raises:
        ConfigError: malformed item, unknown key (with the closest known ones), a key given
            twice, or a combination that does not validate (named by its values).
    """
    keys = flatten(PlanarVoConfig())
    base_values = flatten(base) if isinstance(base, PlanarVoConfig) else {**keys, **base}
    axes: list[tuple[str, list[Any]]] = []
    for item in sets:
        key, values = parse_set(item, keys)
        if any(key == k for k, _ in axes):
            raise ConfigError(f"set: '{key}' given twice; list its values once: {key}=V1,V2")
        axes.append((key, values))
    if not axes:
        # Named after its file: runs of several files into one folder stay apart in the rows.
        name = Path(source).name if source else 'default'
        return [FleetConfig(name, flatten(build_config(base_values, {}, source)))]
    grid = []
    for combo in itertools.product(*(values for _, values in axes)):
        changes = dict(zip((key for key, _ in axes), combo))
        name = ' '.join(f'{k}={_format_value(v)}' for k, v in changes.items())
        grid.append(FleetConfig(name, flatten(build_config(base_values, changes, source,
                                                           label=name))))
    return grid


def read_manifest(path: str | Path) -> list[Path]:
    """Bag paths of a manifest: one a line; blank lines and ``#`` comments (a whole line, or
    after a blank at the end of a line) are skipped; relative paths are relative to the
    manifest's folder.

    Raises:
        InputError: unreadable manifest, or no bags in it.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding='utf-8')
    except (OSError, UnicodeDecodeError) as err:
        detail = getattr(err, 'strerror', None) or err
        raise InputError(f"manifest: cannot read '{path}' ({detail})") from err
    bags = []
    for line in text.splitlines():
        # 'bag   # the main drive' (a user test: the comment became part of the path).
        entry = re.split(r'(?:^|\s)#', line, maxsplit=1)[0].strip()
        if entry:
            bag = Path(entry).expanduser()
            bags.append(bag if bag.is_absolute() else path.parent / bag)
    if not bags:
        raise InputError(f"manifest: '{path}' lists no bags")
    return bags


def bag_fingerprint(path: str | Path) -> list | None:
    """``[[file, size, mtime_ns], ...]`` of a bag (directory or file); None if unreadable."""
    path = Path(path)
    try:
        if path.is_dir():
            files = sorted(f for f in path.rglob('*') if f.is_file())
            names = [str(f.relative_to(path)) for f in files]
        else:
            files, names = [path], [path.name]
        return [[name, st.st_size, st.st_mtime_ns]
                for name, st in zip(names, (f.stat() for f in files))]
    except OSError:
        return None


@dataclass(frozen=True)
class FleetJob:
    """One task: a bag (absolute path) under one configuration.

    Attributes:
        bag: absolute path of the input bag.
        config: the configuration.
        run_dir: the job's folder, relative to the output folder.
        key: digest of the inputs (bag path, its files' sizes and times, configuration,
            topics, planar_vo's code): a ``result.json`` with another key is stale.
        image_topic, camera_info_topic: as ``planar_vo replay``'s (None: the only one).
        two_pass: as ``planar_vo replay --two-pass`` (the focal self-calibration's first pass).
    """

    bag: str
    config: FleetConfig
    run_dir: str
    key: str
    image_topic: str | None = None
    camera_info_topic: str | None = None
    two_pass: bool = False

    @property
    def label(self) -> str:
        """Short name for logs and Ray's task list: ``bag:configuration``."""
        return f'{Path(self.bag).name}:{_slug(self.config.name)}'


def bag_identity(path: str | Path) -> str:
    """The bag a path names, for finding the same bag under two spellings: symbolic links
    resolved, and a bag folder's only storage file (``bag/bag.mcap`` beside ``metadata.yaml``)
    taken as the folder. The files of a split recording (``drive_0.mcap``, ``drive_1.mcap``)
    are different data: each is itself."""
    real = Path(os.path.realpath(Path(path).expanduser()))
    if real.is_file() and (real.parent / 'metadata.yaml').is_file():
        storage = [p for p in real.parent.iterdir() if p.suffix in ('.mcap', '.db3')]
        if storage == [real]:
            return str(real.parent)
    return str(real)


def plan_jobs(bags: Iterable[str | Path], configs: Sequence[FleetConfig], *,
              image_topic: str | None = None, camera_info_topic: str | None = None,
              two_pass: bool = False) -> list[FleetJob]:
    """Every bag under every configuration, bag-major. The same bag given twice (another
    spelling, a symbolic link, its folder and its storage file) runs once, as first given, and
    a warning names the repeat. ``two_pass``: every replay as ``replay --two-pass`` (every
    configuration must self-calibrate the focal length).

    Raises:
        ConfigError: ``two_pass`` with a configuration without ``camera.estimate_focal``.
    """
    if two_pass:
        plain = [c.name for c in configs if not c.values['camera.estimate_focal']]
        if plain:
            raise ConfigError(f"two_pass: the first pass self-calibrates the focal length, "
                              f"which configuration '{plain[0]}' does not: give --set "
                              f'camera.estimate_focal=true')
    seen: dict[str, str] = {}                # identity -> the bag as first given
    for given in bags:
        bag = os.path.normpath(Path(given).expanduser().absolute())
        identity = bag_identity(bag)
        if identity not in seen:
            seen[identity] = bag
        else:           # (also the same spelling again, or 'k06/' after 'k06': a user test)
            log.warning("BAG: '%s' is the bag '%s' again; it runs once", given, seen[identity])
    paths = list(seen.values())
    jobs = []
    topics = {'image': image_topic, 'camera_info': camera_info_topic}
    for bag in paths:
        stem = Path(bag).name.removesuffix('.mcap').removesuffix('.db3')
        bag_dir = f'runs/{_slug(stem)}-{_digest(bag)[:8]}'
        files = bag_fingerprint(bag)
        for config in configs:
            # (two passes in a folder of their own: a review, toggling --two-pass overwrote)
            run_dir = (f'{bag_dir}/{_slug(config.name)}-{_digest(config.values)[:8]}'
                       + ('-two-pass' if two_pass else ''))
            key = _digest({'bag': bag, 'files': files, 'config': config.values,
                           'topics': topics, 'two_pass': two_pass, 'code': code_digest()})
            jobs.append(FleetJob(bag, config, run_dir, key, image_topic, camera_info_topic,
                                 two_pass))
    return jobs


# -- one job --------------------------------------------------------------------------------------

@contextlib.contextmanager
def single_threaded() -> Iterator[None]:
    """One OpenCV thread and one thread in every BLAS/OpenMP library (threadpoolctl), set at run
    time and restored after (see the module docstring)."""
    import cv2
    from threadpoolctl import threadpool_limits

    previous = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        with threadpool_limits(limits=1):
            yield
    finally:
        cv2.setNumThreads(previous)


def _new_row(job: FleetJob, **values: Any) -> dict[str, Any]:
    """A summary row of `job` with every field present (None where not measured)."""
    row = {'bag': job.bag, 'config': job.config.name, 'status': 'ok', 'reason': None,
           'frames_in': 0, 'odom_out': 0, 'drops': {}, 'wall_s': None, 'frames_per_s': None,
           't_rel_pct': None, 'r_rel_deg100m': None, 'drift_segments': None,
           'yaw_err_mean_deg': None,
           'ate_sim3_m': None, 'path_m': None, 'run_dir': job.run_dir, 'odometry': None,
           'tum': None, 'node': None, 'pid': None}
    row.update(values)
    return row


def kitti_fields(metrics: dict) -> dict[str, float | str | None]:
    """``t_rel_pct``, ``r_rel_deg100m`` and ``drift_segments`` of ``Evaluation.metrics()``:
    drift by the KITTI protocol in 3D on its 100-800 m segments (``metrics['kitti']``, from
    `planar_vo.tools.evaluation.metrics.kitti_drift`), or, for a drive shorter than 100 m, on
    the 10-50 m segments that `planar_vo eval` reports for it (``metrics['kitti_short']``; a
    user test: the fleet showed none where eval showed them). None without segments."""
    for key, segments in (('kitti', '100-800 m'), ('kitti_short', '10-50 m')):
        kitti = metrics.get(key) or {}
        t_rel, r_rel = kitti.get('t_rel_pct'), kitti.get('r_rel_deg_per_100m')
        if t_rel is not None and math.isfinite(t_rel) and kitti.get('segments'):
            return {'t_rel_pct': t_rel, 'r_rel_deg100m': r_rel, 'drift_segments': segments}
    return {'t_rel_pct': None, 'r_rel_deg100m': None, 'drift_segments': None}


def _thumbnail(evaluation) -> dict[str, list]:
    ref, est = evaluation.ref.positions[:, :2], evaluation.aligned.positions[:, :2]
    step = max(1, math.ceil(len(ref) / THUMBNAIL_POINTS))
    keep = list(range(0, len(ref), step))
    if keep[-1] != len(ref) - 1:
        keep.append(len(ref) - 1)
    return {'ref_xy': ref[keep].round(3).tolist(), 'est_xy': est[keep].round(3).tolist()}


def _replay_and_evaluate(job: FleetJob, work: Path, row: dict) -> dict | None:
    """``planar_vo replay`` and ``planar_vo eval --align sim3`` of one job; fills `row`."""
    from planar_vo.io.camera_bag import GROUND_TRUTH_TOPIC
    from planar_vo.pipeline import VisualOdometry
    from planar_vo.tools.evaluation import (evaluate, load_trajectory, read_bag_odometry,
                                            write_report)
    from planar_vo.tools.evaluation.report import read_as
    from planar_vo.tools.replay import replay_bag

    config = job.config.build()
    odometry = work / ODOMETRY
    summary = replay_bag(job.bag, odometry, VisualOdometry(config), tum_path=work / TUM,
                         image_topic=job.image_topic, camera_info_topic=job.camera_info_topic,
                         odom_frame=config.ros.odom_frame, base_frame=config.ros.base_frame,
                         progress=False, two_pass=job.two_pass)
    row.update(frames_in=summary.frames_in, odom_out=summary.odometry_out,
               drops=dict(sorted(summary.dropped.items())))
    if summary.unreadable:
        # A damaged bag that reading got through: the row says so (a user test: 'ok' alone).
        row['reason'] = ('damaged storage: unreadable ' + ', '.join(
            f'{t} {n}' for t, n in sorted(summary.unreadable.items())))
    elif summary.partial_input:
        # So does an import cut short (a review: its row looked like the whole drive's).
        row['reason'] = f'an import cut short: {summary.partial_input}'
    _kept_outputs(job, work, row)
    if not summary.frames_in:
        raise InputError(f'bag: no frames on {summary.image_topic}')
    if summary.no_motion:
        # As planar_vo replay's exit code 1 (a user test: the row was 'ok' with no odometry,
        # or failed for a missing /odom of the evaluation instead of the cause).
        raise InputError(summary.no_motion)
    if not summary.copied.get(GROUND_TRUTH_TOPIC):
        return None
    est, covariances = read_bag_odometry(odometry, EST_TOPIC, role='est-topic')
    ref = load_trajectory(odometry, GROUND_TRUTH_TOPIC, role='gt-topic')
    evaluation = evaluate(ref, est, align=ALIGN, covariances=covariances)
    write_report(evaluation, work / EVALUATION, plots=False, estimate=odometry.resolve(),
                 reference=odometry.resolve(),
                 read_as=read_as(est_topic=EST_TOPIC, gt_topic=GROUND_TRUTH_TOPIC),
                 **evaluation_provenance(odometry))
    metrics = evaluation.metrics()
    row.update(ate_sim3_m=metrics['ate_m']['rmse'],
               yaw_err_mean_deg=metrics['yaw_change_error_deg']['mean'],
               path_m=metrics['path_length_m'], **kitti_fields(metrics))
    return _thumbnail(evaluation)


def _kept_outputs(job: FleetJob, work: Path, row: dict) -> None:
    """Name in `row` the odometry bag and TUM file that replay left complete in `work`."""
    row.update(odometry=f'{job.run_dir}/{ODOMETRY}' if (work / ODOMETRY).is_dir() else None,
               tum=f'{job.run_dir}/{TUM}' if (work / TUM).is_file() else None)


def _output_failure(err: PlanarVoError) -> bool:
    """An error of the job's own outputs (a full disk, a file system that went away): not the
    bag's fault, so a rerun tries again."""
    return isinstance(err, OutputError) or str(err).startswith(('out:', 'tum:'))


def run_job(job: FleetJob, out_dir: str | Path) -> dict:
    """Replay and evaluate one job into ``out_dir/job.run_dir``; returns its result record.

    The body of a fleet task (also run in-process by ``planar_vo bench fleet``). Deletes what
    an earlier, unfinished attempt left in the job's folder, runs `single_threaded`, and writes
    ``result.json`` last: ``{'key': job.key, 'row': {...}, 'thumbnail': {...} or None}``.

    A `PlanarVoError` (bad bag, no motion, no poses to evaluate) makes a ``failed`` row, with
    the outputs that replay kept; one of the job's outputs (`_output_failure`) is marked
    ``final: False``, so that a rerun repeats it (`load_result`). Any other exception
    propagates (a bug; no ``result.json`` is written).
    """
    start = time.perf_counter()
    work = Path(out_dir) / job.run_dir
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)
    row = _new_row(job, node=socket.gethostname(), pid=os.getpid())
    thumbnail = None
    final = True
    with single_threaded():
        try:
            thumbnail = _replay_and_evaluate(job, work, row)
        except PlanarVoError as err:
            # After the damaged storage it found, if any (the failure may be its consequence).
            found = row['reason']
            row.update(status='failed', reason=one_line(err) + (f'; {found}' if found else ''))
            partial = getattr(err, 'replay_summary', None)
            if partial is not None:
                # What replay did before the bag failed (a user test: 0 frames, 0 odometry
                # where 20 odometry messages were kept).
                row.update(frames_in=partial.frames_in, odom_out=partial.odometry_out,
                           drops=dict(sorted(partial.dropped.items())))
            _kept_outputs(job, work, row)
            final = not _output_failure(err)
    wall = time.perf_counter() - start
    row.update(wall_s=wall, frames_per_s=row['frames_in'] / wall)
    record = {'key': job.key, 'row': row, 'thumbnail': thumbnail, 'final': final}
    write_json(work / RESULT, record)
    return record


def load_result(out_dir: str | Path, job: FleetJob) -> dict | None:
    """The complete result record of `job` in `out_dir`, or None (absent, partial, stale, or a
    failure of the outputs that a rerun repeats)."""
    out_dir = Path(out_dir)
    try:
        record = json.loads((out_dir / job.run_dir / RESULT).read_text(encoding='utf-8'))
        row = record['row']
        if record['key'] != job.key or record.get('final') is False:
            return None
        outputs = [row[name] for name in ('odometry', 'tum')] if row['status'] == 'ok' else []
        evaluated = row['status'] == 'ok' and row.get('ate_sim3_m') is not None
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if not all((out_dir / path).exists() for path in outputs):
        return None
    # Every output whole: the odometry bag's storage files, and the evaluation of a row that
    # has one (a user test: a rerun kept rows whose metrics.json or .mcap had been removed).
    if outputs and not _bag_files_present(out_dir / row['odometry']):
        return None
    if evaluated and not (out_dir / job.run_dir / EVALUATION / 'metrics.json').is_file():
        return None
    return record


def _bag_files_present(bag: Path) -> bool:
    """The storage files a bag's ``metadata.yaml`` names are there (and it is readable)."""
    files = bag_information(bag).get('relative_file_paths')
    return isinstance(files, list) and bool(files) and all((bag / str(name)).is_file()
                                                           for name in files)


# -- the run --------------------------------------------------------------------------------------

def import_ray():
    """The ``ray`` module, or `DependencyError` naming the install command in one line."""
    try:
        import ray
    except ImportError as err:
        raise DependencyError(f'{err.name or "ray"} is not installed; fleet runs need the fleet '
                              f'extra: {FLEET_EXTRA} (or run without Ray: --local)') from err
    return ray


@dataclass
class FleetRun:
    """What `run_fleet` did.

    Attributes:
        out_dir: the output folder.
        records: result records in job order (``row``, ``thumbnail``); jobs not run (an
            interrupted run) have none.
        jobs: number of jobs asked for.
        skipped: jobs whose complete result was already in ``out_dir``.
        ran: jobs finished by this run (ok or failed).
        stop_signal: the signal that stopped the run (SIGINT: Ctrl-C, or SIGTERM), or None;
            then ``jobs - skipped - ran`` jobs did not run.
        ray_start_s: seconds to start (or connect to) Ray; 0 when nothing had to run.
        tasks_s: seconds from submitting the tasks to the last result.
        wall_s: seconds of the whole call.
        address, workers: where it ran (``None``: a local instance with ``workers`` CPUs).
        local: run in this process, one job after the other, without Ray.
        files: summary.json, report.md and the plots.
    """

    out_dir: Path
    records: list[dict]
    jobs: int
    skipped: int = 0
    ran: int = 0
    stop_signal: signal.Signals | None = None
    ray_start_s: float = 0.0
    tasks_s: float = 0.0
    wall_s: float = 0.0
    address: str | None = None
    workers: int | None = None
    local: bool = False
    files: list[Path] = field(default_factory=list)

    def summary(self) -> dict[str, Any]:
        """The ``run`` part of ``summary.json``."""
        return {'jobs': self.jobs, 'skipped': self.skipped, 'ran': self.ran,
                'not_run': self.jobs - len(self.records), 'interrupted': self.interrupted,
                'wall_s': self.wall_s, 'ray_start_s': self.ray_start_s, 'tasks_s': self.tasks_s,
                'frames_per_s': self.frames_per_s, 'address': self.address,
                'workers': self.workers, 'local': self.local}

    @property
    def interrupted(self) -> bool:
        return self.stop_signal is not None

    @property
    def rows(self) -> list[dict]:
        return [record['row'] for record in self.records]

    @property
    def frames_per_s(self) -> float | None:
        """Aggregate throughput of this run: frames of the ok jobs it ran per second of tasks
        (the frames the totals count: a user test saw a failed row's frames in one figure and
        not in the other, an aggregate above what one task could do)."""
        frames = sum(r['row']['frames_in'] for r in self.records
                     if not r.get('skipped') and r['row']['status'] == 'ok')
        return frames / self.tasks_s if self.ran and self.tasks_s > 0 else None

    def format(self) -> str:
        """A few lines for the terminal."""
        rows = self.rows
        failed = [r for r in rows if r['status'] != 'ok']
        lines = [f'fleet: {len(rows)} of {plural(self.jobs, "result")} in {self.out_dir} '
                 f'({len(rows) - len(failed)} ok, {len(failed)} failed; {self.skipped} already '
                 f'there, {self.ran} run now)']
        if self.ran:
            where = ('this process, no Ray' if self.local else
                     (self.address or f'local Ray, {plural(self.workers, "CPU")}')
                     + f' (Ray start {self.ray_start_s:.1f} s)')
            lines.append(f'  {self.tasks_s:.1f} s (wall time) on {where}, '
                         f'{self.frames_per_s or 0:.1f} frames/s')
        names = bag_names([r['bag'] for r in rows])
        lines += [f'  failed: {names[r["bag"]]} [{r["config"]}]: {r["reason"]}' for r in failed]
        if self.interrupted:
            lines.append(f'  interrupted: {self.jobs - len(rows)} not run; rerun the same '
                         'command to finish them')
        lines += [f'  {path}' for path in self.files]
        return '\n'.join(lines)


@contextlib.contextmanager
def ray_session(address: str | None = None, workers: int | None = None, retries: int = 2
                ) -> Iterator[Any]:
    """Ray for a fleet run: connect to `address`, or start a local instance with `workers`
    CPUs (default: the CPUs this process may use); shut down on exit. Yields the ``ray``
    module.

    Ray kills of out-of-memory workers are retried `retries` times like other deaths (Ray's
    own default is forever). A ``ray://`` connection whose per-client server fails to start is tried
    `CLIENT_ATTEMPTS` times. A Ray already initialised by the caller is used as it is, and left
    running.

    Raises:
        DependencyError: Ray is missing.
        InputError: Ray cannot be started or reached.
    """
    ray = import_ray()
    if ray.is_initialized():
        yield ray
        return
    workers = default_workers() if workers is None else workers
    common = {'log_to_driver': False, 'logging_level': logging.ERROR}
    if address:
        _check_reachable(address)
    # Ray's core worker installs its own SIGTERM handler (a crash dump, exit code 1: a user
    # test); the command's handler (SIGTERM stops like Ctrl-C) is put back after the start.
    sigterm = signal.getsignal(signal.SIGTERM) if _main_thread() else None
    try:
        if address:
            for attempt in range(1, CLIENT_ATTEMPTS + 1):
                try:
                    ray.init(address=address, **common)
                    break
                except ConnectionAbortedError as err:
                    # A ray:// server took the connection, but the server process it starts
                    # for each client died at start (Ray 2.60 forks it from a process with
                    # gRPC threads; now and then the child dies): connect again.
                    if attempt == CLIENT_ATTEMPTS:
                        raise
                    log.warning('Ray at %s, attempt %d: %s', address, attempt, one_line(err))
        else:
            ray.init(num_cpus=workers, include_dashboard=False,
                     _system_config={'task_oom_retries': retries}, **common)
    except (KeyboardInterrupt, SystemExit) as err:
        # A stop while Ray starts (a user test: Ray's own SIGTERM handler, installed during
        # the start, exited with code 15 and no word; Ctrl-C left Ray's agents running): what
        # was started is shut down, and SIGTERM stops like Ctrl-C (exit 143, one line).
        if isinstance(err, SystemExit) and err.code != signal.SIGTERM:
            raise
        with contextlib.suppress(Exception):
            ray.shutdown()
        if isinstance(err, SystemExit):
            raise KeyboardInterrupt(signal.SIGTERM.name) from None
        raise
    except Exception as err:       # noqa: BLE001 - Ray raises bare Exception on a start timeout
        where = f"'{address}'" if address else f'a local instance ({plural(workers, "CPU")})'
        raise InputError(f'address: cannot start or reach Ray at {where} '
                         f'({one_line(err)})') from err
    finally:
        if callable(sigterm):
            signal.signal(signal.SIGTERM, sigterm)
    try:
        yield ray
    finally:
        ray.shutdown()


def _main_thread() -> bool:
    import threading

    return threading.current_thread() is threading.main_thread()


def _check_reachable(address: str) -> None:
    """A ``host:port`` head address must accept a TCP connection within
    `CONNECT_TIMEOUT_S`: Ray itself retries an unreachable head for ever (every 30 s a log
    line, no error). ``auto``, ``local`` and ``ray://`` addresses fail on their own."""
    import socket

    if address in ('auto', 'local') or '://' in address:
        return
    host, sep, port = address.rpartition(':')
    if not sep or not port.isdigit():
        raise InputError(f"address: expected 'auto', 'host:port' or 'ray://host:port', got "
                         f"'{address}'")
    try:
        socket.create_connection((host.strip('[]'), int(port)), timeout=CONNECT_TIMEOUT_S).close()
    except OSError as err:
        raise InputError(f"address: cannot reach Ray at '{address}' within "
                         f'{CONNECT_TIMEOUT_S:g} s ({err.strerror or err})') from err


def default_workers() -> int:
    """The CPUs this process may use."""
    if hasattr(os, 'sched_getaffinity'):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def _bug_record(job: FleetJob, cause: BaseException) -> dict:
    """The record of a job that raised (a bug, an OS error): a failed row, not kept (no
    ``result.json``: a rerun tries again)."""
    return {'key': job.key, 'row': _new_row(job, status='failed', reason=f'internal error: '
                                            f'{type(cause).__name__}: {one_line(cause)}'),
            'thumbnail': None}


def _failure(ray, err: Exception, job: FleetJob, retries: int) -> dict | None:
    """The row of a task that raised (a bug) or whose worker died; None if interrupted."""
    if isinstance(err, ray.exceptions.TaskCancelledError):
        return None
    if isinstance(err, ray.exceptions.RayTaskError):
        cause = err.cause if err.cause is not None else err
        if isinstance(cause, KeyboardInterrupt):
            return None
        log.error('fleet task %s raised:\n%s', job.label, err)
        return _bug_record(job, cause)
    reason = (f'worker died on each of {retries + 1} attempts ({type(err).__name__}: '
              f'{one_line(err)[:200]})')
    return {'key': job.key, 'row': _new_row(job, status='failed', reason=reason),
            'thumbnail': None}


def _execute(ray, jobs: Sequence[FleetJob], todo: list[int], out_dir: Path, retries: int,
             records: dict[int, dict], bar, cancel: bool) -> signal.Signals | None:
    """Submit the jobs `todo`, collect their records; the stop signal if interrupted (Ctrl-C,
    SIGTERM).

    On Ctrl-C the tasks still running are cancelled only with ``cancel`` (a Ray the caller
    started, which outlives the run). Otherwise ending the session stops them: Ray ends the
    tasks of a driver that shuts down, and ``ray.cancel`` racing a task's completion can abort
    the driver in Ray's core worker ("Tried to complete task that was not pending", seen once
    in a CI run of the Ctrl-C test; ray-project/ray PR 54527 names the race)."""
    task = ray.remote(num_cpus=1, max_retries=retries, retry_exceptions=False)(run_job)
    refs = {task.options(name=f'planar_vo_fleet:{jobs[i].label}').remote(jobs[i], str(out_dir)):
            i for i in todo}
    pending = list(refs)
    start, frames, failed = time.perf_counter(), 0, 0
    try:
        while pending:
            ready, pending = ray.wait(pending, num_returns=1, timeout=0.5)
            for ref in ready:
                job = jobs[refs[ref]]
                try:
                    record = ray.get(ref)
                except ray.exceptions.RayError as err:
                    record = _failure(ray, err, job, retries)
                    if record is None:
                        continue
                records[refs[ref]] = record
                frames += record['row']['frames_in']
                failed += record['row']['status'] != 'ok'
                bar.update(1)
                elapsed = time.perf_counter() - start
                bar.set_postfix_str(f'{frames / elapsed:.0f} frames/s, {failed} failed')
    except KeyboardInterrupt as err:
        if cancel:
            for ref in pending:
                ray.cancel(ref, force=True)
        return interrupt_signal(err)
    return None


def _run_local(jobs: Sequence[FleetJob], todo: list[int], out_dir: Path,
               records: dict[int, dict], bar) -> signal.Signals | None:
    """The jobs `todo` one after the other in this process; the stop signal if interrupted
    (Ctrl-C, SIGTERM: the job running then leaves no ``result.json``, a rerun repeats it)."""
    try:
        for i in todo:
            try:
                records[i] = run_job(jobs[i], out_dir)
            except Exception as err:      # noqa: BLE001 - a bug or an OS error: as on Ray
                log.error('fleet job %s raised', jobs[i].label, exc_info=True)
                records[i] = _bug_record(jobs[i], err)
            bar.update(1)
    except KeyboardInterrupt as err:
        return interrupt_signal(err)
    return None


def check_out_dir(out_dir: str | Path, bags: Iterable[str | Path]) -> None:
    """`out_dir` must not be a bag, nor sit inside one of the input bags (a user test: the
    results went into the input bag's folder, whose changed files then made every run stale).

    Raises:
        InputError: naming the bag.
    """
    out = Path(os.path.realpath(Path(out_dir).expanduser()))
    if (out / 'metadata.yaml').is_file():
        raise InputError(f"out: '{out_dir}' is a bag; give a folder for the fleet's results")
    for bag in bags:
        identity = Path(bag_identity(bag))
        if out == identity or identity in out.parents:
            raise InputError(f"out: '{out_dir}' overlaps the input bag '{bag}'; give a folder "
                             f'outside it')


@contextlib.contextmanager
def _locked(out_dir: Path) -> Iterator[None]:
    """One fleet run at a time in `out_dir` (a user test: two at once deleted each other's
    partial results and kept the failures): an exclusive ``flock`` on the folder itself (no
    lock file). A file system without ``flock`` (some network mounts) runs unlocked, with a
    warning."""
    import fcntl

    fd = os.open(out_dir, os.O_RDONLY)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise InputError(f"out: another fleet run is using '{out_dir}'; wait for it or "
                             f'give another folder') from None
        except OSError as err:
            log.warning("out: '%s' cannot be locked (%s); make sure no other fleet run uses it",
                        out_dir, err.strerror or err)
        yield
    finally:
        os.close(fd)


def run_fleet(jobs: Sequence[FleetJob], out_dir: str | Path, *, address: str | None = None,
              workers: int | None = None, retries: int = 2, progress: bool = False,
              command: Sequence[str] | None = None, local: bool = False) -> FleetRun:
    """Run the jobs not yet complete in `out_dir` as Ray tasks; write the summary and report.

    Args:
        jobs: from `plan_jobs`.
        out_dir: output folder (created; earlier results in it are reused, see the module).
        address: an existing Ray cluster (``'auto'``, ``'ray://host:10001'``, ``'host:6379'``);
            None starts a local instance for the run (shut down at the end). With a cluster,
            the bags and `out_dir` must be on a file system every node sees, and planar_vo with
            its ``fleet`` extra installed on every node.
        workers: CPUs of the local instance (default: the CPUs this process may use); one task
            per CPU.
        retries: how many times Ray reruns a task whose worker died (killed, out of memory).
        progress: progress bar on stderr (jobs done/total, aggregate frames/s, failures).
        command: the command line, recorded in the report.
        local: run the jobs in this process, one after the other, without Ray (the same
            results; ``address``, ``workers`` and ``retries`` do not apply).

    Returns:
        A `FleetRun`. Ctrl-C (KeyboardInterrupt) stops the tasks still running (ending the
        session, or cancelling them in a Ray the caller started) and returns with
        ``stop_signal`` set (SIGINT or SIGTERM, which stops alike), after writing the summary
        of the complete results.

    Raises:
        DependencyError: Ray is missing (only checked when a job must run).
        InputError: Ray cannot be started or reached, `out_dir` overlaps a bag
            (`check_out_dir`) or another run is using it.
    """
    workers = default_workers() if workers is None else workers
    if workers < 1 or retries < 0:
        raise InputError(f'workers, retries: expected at least 1 and 0, got {workers}, {retries}')
    check_out_dir(out_dir, dict.fromkeys(job.bag for job in jobs))   # each bag once
    out_dir = Path(out_dir)
    created = not out_dir.exists()
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise InputError(f"out: cannot create '{out_dir}' ({err.strerror})") from err
    try:
        with _locked(out_dir):
            return _run_fleet(jobs, out_dir, address, workers, retries, progress, command, local)
    except BaseException:
        if created:
            # Nothing run (Ray could not start, another error): no empty folder left behind
            # (a user test); one that holds results stays.
            with contextlib.suppress(OSError):
                out_dir.rmdir()
        raise


def _run_fleet(jobs: Sequence[FleetJob], out_dir: Path, address: str | None, workers: int,
               retries: int, progress: bool, command: Sequence[str] | None,
               local: bool) -> FleetRun:
    from tqdm import tqdm

    start = time.perf_counter()
    records: dict[int, dict] = {}
    for i, job in enumerate(jobs):
        record = load_result(out_dir, job)
        if record is not None:
            records[i] = {**record, 'skipped': True}
    run = FleetRun(out_dir, [], len(jobs), skipped=len(records), address=address,
                   workers=None if address or local else workers, local=local)
    todo = [i for i in range(len(jobs)) if i not in records]
    if todo and local:
        bar = tqdm(total=len(jobs), initial=len(records), desc='fleet', unit='bag',
                   file=sys.stderr, disable=not progress, leave=False)
        t0 = time.perf_counter()
        try:
            run.stop_signal = _run_local(jobs, todo, out_dir, records, bar)
        finally:
            run.tasks_s = time.perf_counter() - t0
            bar.close()
    elif todo:
        t0 = time.perf_counter()
        ray_module = sys.modules.get('ray')
        callers_ray = ray_module is not None and ray_module.is_initialized()
        with ray_session(address, workers, retries) as ray:
            run.ray_start_s = time.perf_counter() - t0
            bar = tqdm(total=len(jobs), initial=len(records), desc='fleet', unit='bag',
                       file=sys.stderr, disable=not progress, leave=False)
            t0 = time.perf_counter()
            try:
                run.stop_signal = _execute(ray, jobs, todo, out_dir, retries, records, bar,
                                           cancel=callers_ray)
            finally:
                run.tasks_s = time.perf_counter() - t0
                bar.close()
        if run.interrupted:       # results written by tasks whose end the driver did not see
            for i in todo:
                if i not in records and (record := load_result(out_dir, jobs[i])) is not None:
                    records[i] = record
    run.records = [records[i] for i in sorted(records)]
    run.ran = len(records) - run.skipped
    run.wall_s = time.perf_counter() - start
    try:
        with deferred_interrupts():
            # A (second) Ctrl-C while the summary is written waits for its files (a user test:
            # it left the last run's report.md beside a new summary.json), then the run
            # returns as interrupted (a review: it was raised, without the table).
            run.files = write_summary(out_dir, run.records, run.summary(), command)
    except KeyboardInterrupt as err:
        run.stop_signal = run.stop_signal or interrupt_signal(err)
    return run
