"""``planar_vo bench fleet``: throughput of fleet runs on Ray, and Ray's cost per task.

Eight rendered drives (640x480, 100 frames each by default) run as fleet jobs
(`planar_vo.tools.fleet.run_job`: replay + sim(3) evaluation, one OpenCV and one BLAS thread):

- in one process, one after another: the baseline without Ray;
- on a local Ray instance with 1 worker (1 CPU), then with 2 workers (2 CPUs).

Every process is warmed up first by a 5-frame job (imports, OpenCV and bag-reading set-up: once
per Ray worker, once in-process), so the task time compares like with like; Ray's start and the
warm-up are reported apart. Throughput is frames per second of task time; the speed-up is 1
worker's task time over 2 workers'; the per-task overhead is 1 worker's task time over the
in-process time, minus one. Targets: a speed-up of at
least 1.7 with 2 workers on this 2-core machine, an overhead under 5 %. Each setup runs
``--repeat`` times, interleaved, and its fastest run is kept (the machine is shared). Every
result must be the same, to the last bit, in all setups.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

EXAMPLES = """examples:
  planar_vo bench fleet
  planar_vo bench fleet --bags 8 --frames 100 --repeat 2 --out planar_vo/bench/results/fleet
  planar_vo bench fleet --work /tmp/fleet_bench          keep the rendered drives for next time
"""

HELP = 'fleet runs on Ray: throughput with 1 and 2 workers, overhead per task'
SPEED_UP_TARGET = 1.7
OVERHEAD_TARGET = 0.05


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``planar_vo bench fleet`` (``--out`` is added by the bench command)."""
    parser.epilog = EXAMPLES
    parser.add_argument('--bags', type=int, default=8, help='rendered drives (default: 8)')
    parser.add_argument('--frames', type=int, default=100,
                        help='frames per drive, 10 Hz (default: 100)')
    parser.add_argument('--repeat', type=int, default=2,
                        help='runs of each setup, the fastest kept (default: 2)')
    parser.add_argument('--work', type=Path, default=None, metavar='DIR',
                        help='folder for the drives and the runs; the drives are reused from '
                             'it (default: a temporary folder, removed at the end)')


def _render(out: Path, bags: int, frames: int) -> list[Path]:
    """The drives (S-curves of growing amplitude in different street worlds) and a 5-frame
    warm-up drive (last), rendered once and reused while their parameters match."""
    import json
    from concurrent.futures import ProcessPoolExecutor

    import numpy as np

    from planar_vo.config import MountConfig
    from planar_vo.sim import s_curve
    from planar_vo.tools.demo import CAMERAS
    from planar_vo.tools.record import record_drive

    out.mkdir(parents=True, exist_ok=True)
    stamp = out / 'drives.json'
    params = {'bags': bags, 'frames': frames, 'camera': '640x480'}
    paths = [out / f'drive_{k:02d}' for k in range(bags)] + [out / 'warm_up']
    if stamp.exists() and json.loads(stamp.read_text()) == params and all(
            (p / 'metadata.yaml').exists() for p in paths):
        return paths
    for path in paths:
        shutil.rmtree(path, ignore_errors=True)
    speed = 8.0
    with ProcessPoolExecutor(max_workers=2) as pool:
        futures = [pool.submit(record_drive, path,
                               s_curve((frames if k < bags else 5) * speed / 10.0,
                                       np.radians(10.0 + 2.0 * k), speed),
                               camera=CAMERAS['640x480'](), mount=MountConfig(), seed=k)
                   for k, path in enumerate(paths)]
        for future in futures:
            future.result()
    stamp.write_text(json.dumps(params))
    return paths


def _warm(ray, workers: int, job, scratch: Path) -> float:
    """One short job per worker (imports, OpenCV and bag-reading set-up); seconds taken."""
    from planar_vo.tools.fleet import run_job

    @ray.remote(num_cpus=1)
    def warm_up(k: int) -> None:
        run_job(job, scratch / str(k))
        time.sleep(0.5)                       # hold the CPU so the next one lands elsewhere

    start = time.perf_counter()
    ray.get([warm_up.remote(k) for k in range(workers)])
    return time.perf_counter() - start


def _in_process(jobs, out: Path, warm_job) -> float:
    from planar_vo.tools.fleet import run_job

    run_job(warm_job, out.with_name(out.name + '_warm'))
    start = time.perf_counter()
    for job in jobs:
        run_job(job, out)
    return time.perf_counter() - start


def _on_ray(jobs, out: Path, workers: int, warm_job) -> dict:
    from planar_vo.tools.fleet import ray_session, run_fleet

    start = time.perf_counter()
    with ray_session(workers=workers) as ray:
        started = time.perf_counter() - start
        warm = _warm(ray, workers, warm_job, out.with_name(out.name + '_warm'))
        run = run_fleet(jobs, out, workers=workers)
    return {'start_s': started, 'warm_s': warm, 'tasks_s': run.tasks_s}


def _tums(jobs, out: Path) -> list[bytes]:
    from planar_vo.tools.fleet import load_result

    records = [load_result(out, job) for job in jobs]
    return [(out / r['row']['tum']).read_bytes() if r and r['row']['tum'] else b''
            for r in records]


def _measure(work: Path, args: argparse.Namespace):
    """Every setup ``args.repeat`` times; (fastest per setup, all results identical, frames,
    jobs)."""
    from planar_vo.config import PlanarVoConfig
    from planar_vo.tools.fleet import config_grid, plan_jobs

    print(f'rendering {args.bags} drives of {args.frames} frames into {work} (reused when '
          'present) ...', flush=True)
    *bags, warm_bag = _render(work / 'drives', args.bags, args.frames)
    jobs = plan_jobs(bags, config_grid(PlanarVoConfig()))
    (warm_job,) = plan_jobs([warm_bag], config_grid(PlanarVoConfig()))
    best: dict[str, dict] = {}
    outputs: dict[str, list[bytes]] = {}
    for attempt in range(args.repeat):
        for setup in ('in-process', '1 worker', '2 workers'):
            folder = work / 'runs' / setup.replace(' ', '_')
            shutil.rmtree(folder, ignore_errors=True)
            if setup == 'in-process':
                result = {'start_s': 0.0, 'warm_s': 0.0,
                          'tasks_s': _in_process(jobs, folder, warm_job)}
            else:
                result = _on_ray(jobs, folder, int(setup[0]), warm_job)
            outputs[setup] = _tums(jobs, folder)
            print(f'run {attempt + 1}: {setup}: {result["tasks_s"]:.2f} s of tasks', flush=True)
            if setup not in best or result['tasks_s'] < best[setup]['tasks_s']:
                best[setup] = result
    frames = sum(_frames(jobs, work / 'runs' / 'in-process'))
    identical = all(tums == outputs['in-process'] and all(tums) for tums in outputs.values())
    return best, identical, frames, jobs


def run(args: argparse.Namespace) -> int:
    from planar_vo.bench.common import markdown_table, new_figure, save_figure, write_markdown
    from planar_vo.errors import InputError
    from planar_vo.tools.fleet import import_ray

    if args.bags < 2 or args.frames < 10 or args.repeat < 1:
        raise InputError(f'bags, frames, repeat: expected at least 2, 10 and 1, got '
                         f'{args.bags}, {args.frames}, {args.repeat}')
    ray = import_ray()
    out = Path(args.out)
    work = Path(tempfile.mkdtemp(prefix='planar_vo_fleet_')) if args.work is None else args.work
    try:
        best, identical, frames, jobs = _measure(work, args)
    finally:
        if args.work is None:
            shutil.rmtree(work, ignore_errors=True)
    base, one, two = (best[s]['tasks_s'] for s in ('in-process', '1 worker', '2 workers'))
    speed_up, overhead = one / two, one / base - 1.0
    rows = []
    for setup, result in best.items():
        rows.append([setup, f'{result["tasks_s"]:.2f}', f'{frames / result["tasks_s"]:.1f}',
                     f'{base / result["tasks_s"]:.2f}',
                     f'{result["start_s"]:.1f}' if setup != 'in-process' else '-',
                     f'{result["warm_s"]:.1f}' if setup != 'in-process' else '-'])
    table = markdown_table(['setup', 'task time (s)', 'frames/s', 'vs in-process',
                            'Ray start (s)', 'worker warm-up (s)'], rows)
    per_task_ms = 1000.0 * (one - base) / len(jobs)
    targets = markdown_table(['target (issue)', 'measured', 'status'], [
        [f'2 workers at least {SPEED_UP_TARGET}x 1 worker', f'{speed_up:.2f}x',
         'met' if speed_up >= SPEED_UP_TARGET else 'NOT met'],
        [f'Ray overhead per task under {OVERHEAD_TARGET:.0%}',
         f'{overhead:+.1%} ({per_task_ms:+.0f} ms per task of {1000 * base / len(jobs):.0f} ms)',
         'met' if overhead < OVERHEAD_TARGET else 'NOT met'],
        ['every result identical in the three setups', 'yes' if identical else 'NO',
         'met' if identical else 'NOT met'],
    ], 'llr')
    setup_text = (f'{len(jobs)} rendered drives, {frames} frames in all (640x480, 10 Hz), '
                  f'Ray {ray.__version__}, default configuration; one fleet job per drive '
                  '(replay + sim(3) evaluation, one OpenCV and one BLAS thread per job). Task '
                  'time: from submitting the jobs to the last result (in-process: the jobs one '
                  'after another); Ray started and its workers warmed up before. Fastest of '
                  f'{args.repeat} interleaved runs per setup.')
    fig, axes = new_figure(1, 1, width=6.0, height=3.2)
    ax = axes[0, 0]
    ax.bar([r[0] for r in rows], [frames / best[r[0]]['tasks_s'] for r in rows],
           color=['0.5', 'tab:blue', 'tab:green'])
    ax.set_ylabel('frames/s (task time)')
    ax.set_title(f'Fleet throughput, {len(jobs)} bags of {args.frames} frames')
    plot = save_figure(fig, out / 'fleet.png')
    sections = [setup_text, table, targets, f'![throughput]({plot.name})']
    text = write_markdown(out / 'fleet.md', 'planar_vo bench fleet', args.command, sections)
    print(text)
    return 0


def _frames(jobs, out: Path) -> list[int]:
    from planar_vo.tools.fleet import load_result

    return [load_result(out, job)['row']['frames_in'] for job in jobs]
