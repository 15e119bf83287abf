"""Fleet runs on Ray: rows and failure reasons, equality with a single replay + eval (with one
BLAS thread, as the fleet's tasks), resuming, Ctrl-C, a killed worker retried, an existing
cluster, and Ray staying out of replay and the node.

Each test that runs tasks starts its own local Ray (2 CPUs) through ``planar_vo fleet run`` and
shuts it down; the bags are short rendered drives (320x240, about 25 frames).
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from planar_vo.cli import main
from planar_vo.config import MountConfig, PlanarVoConfig, load_config, read_config, to_ros_yaml
from planar_vo.core.camera import CameraModel
from planar_vo.core.trajectory import Trajectory
from planar_vo.errors import ConfigError, InputError
from planar_vo.io import OdometryBagWriter, open_bag
from planar_vo.io.camera_bag import IMAGE_TOPIC
from planar_vo.sim import s_curve, straight, turn
from planar_vo.tools.evaluation import evaluate
from planar_vo.tools.fleet import (
    config_grid,
    kitti_fields,
    load_result,
    plan_jobs,
    read_manifest,
    run_fleet,
)
from planar_vo.tools.fleet_report import bag_names
from planar_vo.tools.record import record_drive

ray = pytest.importorskip('ray', reason='the fleet extra is pinned in the Makefile (make venv)')

CAMERA = CameraModel.pinhole(320, 240, 250.0)
GRID = ['--set', 'voting.bins=360,720']
CONFIGS = ('voting.bins=360', 'voting.bins=720')
TASK_TITLE = 'ray::planar_vo_fleet:'          # Ray's process title of a running fleet task


@pytest.fixture(scope='module')
def drives(tmp_path_factory):
    """Three rendered drives, a truncated copy of one, a bag without images, a missing path, a
    manifest (two of the drives and the missing path, relative paths, a comment) and a
    configuration file."""
    root = tmp_path_factory.mktemp('fleet_bags')
    trajectories = {
        'drive_a': straight(6.0, speed=8.0).then(turn(np.pi / 8, radius=15.0, speed=6.0)),
        'drive_b': s_curve(20.0, speed=8.0),
        'drive_c': straight(20.0, speed=8.0),
    }
    recorded = {name: record_drive(root / name, trajectory, camera=CAMERA,
                                   mount=MountConfig(height=1.5), seed=i)
                for i, (name, trajectory) in enumerate(trajectories.items())}
    bags = {name: r.path for name, r in recorded.items()}
    truncated = root / 'broken' / 'drive_a'
    shutil.copytree(bags['drive_a'], truncated)
    (mcap,) = truncated.glob('*.mcap')
    mcap.write_bytes(mcap.read_bytes()[:-1000])
    no_image = root / 'no_image'
    with OdometryBagWriter(no_image, topic='/ground_truth/odom') as writer:
        for k in range(3):
            writer.write(1_000_000_000 + k * 100_000_000, np.eye(4))
    manifest = root / 'bags.txt'
    manifest.write_text('# two drives and a bag that is gone\ndrive_b\n\ndrive_c\nmissing\n')
    config = root / 'fleet.yaml'
    config.write_text('frontend:\n  max_correspondences: 1500\n')
    return {**bags, 'distance': {name: r.distance for name, r in recorded.items()},
            'truncated': truncated, 'no_image': no_image, 'missing': root / 'missing',
            'manifest': manifest, 'config': config, 'root': root}


def _fleet_args(drives, out, *extra):
    return ['fleet', 'run', str(drives['drive_a']), str(drives['truncated']),
            str(drives['no_image']), '--manifest',
            str(drives['manifest']), '--out', str(out), '--config', str(drives['config']),
            *GRID, '--workers', '2', *extra]


@pytest.fixture(scope='module')
def fleet_run(drives, tmp_path_factory):
    """One fleet run over every bag under two configurations; (output folder, stdout)."""
    out = tmp_path_factory.mktemp('fleet') / 'out'
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        assert main(_fleet_args(drives, out)) == 0
    assert not ray.is_initialized()              # the run shut its Ray instance down
    return out, stdout.getvalue()


def _summary(out: Path) -> dict:
    return json.loads((out / 'summary.json').read_text())


def _rows(out: Path) -> dict[tuple[str, str], dict]:
    return {(Path(r['bag']).name if 'broken' not in r['bag'] else 'truncated', r['config']): r
            for r in _summary(out)['rows']}


# ---------------------------------------------------------------------------------------------
# One run: rows, failures, outputs, report
# ---------------------------------------------------------------------------------------------

def test_rows_failures_and_report(drives, fleet_run):
    out, text = fleet_run
    summary = _summary(out)
    rows = summary['rows']
    bags = ['drive_a', 'truncated', 'no_image', 'drive_b', 'drive_c', 'missing']
    assert [(r['bag'], r['config']) for r in rows] == [
        (str(drives[b]), c) for b in bags for c in CONFIGS]
    by_key = _rows(out)
    for bag in ('drive_a', 'drive_b', 'drive_c'):
        for config in CONFIGS:
            row = by_key[bag, config]
            assert row['status'] == 'ok' and row['reason'] is None
            with open_bag(drives[bag]) as reader:
                frames = reader.count(IMAGE_TOPIC)
            assert row['frames_in'] == frames and row['odom_out'] == frames   # the origin too
            assert row['drops'] == {}
            assert row['frames_per_s'] == pytest.approx(frames / row['wall_s'])
            # The ground truth's path over the frames with odometry: every frame (the first at
            # the origin).
            assert row['path_m'] == pytest.approx(drives['distance'][bag], rel=1e-9)
            assert row['ate_sim3_m'] < 0.01 * row['path_m']
            assert 0.0 <= row['yaw_err_mean_deg'] < 0.1
            # Drives under 100 m have no segment of 100-800 m: their drift is the one eval
            # reports on 10-50 m segments (a user test: the fleet showed none), or null.
            metrics = json.loads((out / row['run_dir'] / 'evaluation' / 'metrics.json')
                                 .read_text())
            assert not metrics['kitti']['segments']
            short = metrics.get('kitti_short') or {}
            if short.get('segments'):
                assert (row['t_rel_pct'], row['r_rel_deg100m'], row['drift_segments']) == (
                    short['t_rel_pct'], short['r_rel_deg_per_100m'], '10-50 m')
            else:
                assert (row['t_rel_pct'], row['r_rel_deg100m'], row['drift_segments']) == (
                    None, None, None)
            assert (out / row['odometry'] / 'metadata.yaml').exists()
            assert (out / row['tum']).stat().st_size > 0
            assert (out / row['run_dir'] / 'evaluation' / 'metrics.json').exists()
    reasons = {
        'truncated': r"bag: cannot open '.*broken/drive_a': corrupt, truncated or not a ROS 2 "
                     r'bag \(AnyReaderError: File end magic is invalid\.\)',
        'no_image': r"image_topic: no sensor_msgs/msg/Image or sensor_msgs/msg/CompressedImage "
                    r"topic in '.*no_image'",
        'missing': r"bag: '.*missing' does not exist",
    }
    for bag, pattern in reasons.items():
        for config in CONFIGS:
            row = by_key[bag, config]
            assert row['status'] == 'failed' and '\n' not in row['reason']
            assert re.fullmatch(pattern + '.*', row['reason']), row['reason']
            assert row['ate_sim3_m'] is None and row['frames_in'] == 0
    totals = summary['totals']
    ok = [r for r in rows if r['status'] == 'ok']
    assert (totals['runs'], totals['bags'], totals['ok'], totals['failed']) == (12, 6, 6, 6)
    assert totals['frames_in'] == sum(r['frames_in'] for r in ok)
    assert totals['km'] == pytest.approx(sum(r['path_m'] for r in ok) / 1000)
    assert [c['config'] for c in summary['configs']] == list(CONFIGS)
    assert all(c['ok'] == 3 and c['failed'] == 3 for c in summary['configs'])
    assert summary['run']['ran'] == 12 and summary['run']['skipped'] == 0
    assert summary['run']['frames_per_s'] > 0 and summary['run']['workers'] == 2
    # the ok runs' frames, as the totals count them (a user test: a failed row's too)
    assert summary['run']['frames_per_s'] == pytest.approx(
        totals['frames_in'] / summary['run']['tasks_s'])
    report = (out / 'report.md').read_text()
    assert '## Totals' in report and '## Per configuration' in report and '## Runs' in report
    assert len(re.findall(r'\| voting\.bins=\d+ \| failed \|', report)) == 6
    assert '| broken/drive_a | voting.bins=360 | failed |' in report
    assert '![drift](drift.png)' in report and '![trajectories](trajectories.png)' in report
    assert all((out / name).stat().st_size > 5_000 for name in ('drift.png', 'trajectories.png'))
    assert '12 of 12 results' in text and '6 failed' in text


def _single(*args: str) -> None:
    """``OMP_NUM_THREADS=1 planar_vo ARGS``: the fleet's reference (one BLAS thread)."""
    result = subprocess.run([sys.executable, '-m', 'planar_vo', *args], capture_output=True,
                            text=True, env={**os.environ, 'OMP_NUM_THREADS': '1'}, timeout=300)
    assert result.returncode == 0, result.stderr


def test_each_result_equals_a_single_replay_and_eval(drives, fleet_run, tmp_path):
    out, _ = fleet_run
    base = load_config(drives['config'])
    for fleet_config in config_grid(base, GRID[1:]):
        row = _rows(out)['drive_a', fleet_config.name]
        yaml = tmp_path / f'{fleet_config.name}.yaml'
        yaml.write_text(to_ros_yaml(fleet_config.build()))
        single, tum = tmp_path / f'{fleet_config.name}_vo', tmp_path / f'{fleet_config.name}.tum'
        _single('replay', str(drives['drive_a']), '--out', str(single), '--tum', str(tum),
                '--config', str(yaml))
        # The same odometry, to the last bit: TUM text and every serialised /odom message.
        assert tum.read_bytes() == (out / row['tum']).read_bytes()
        with open_bag(single) as a, open_bag(out / row['odometry']) as b:
            odom_a = [(m.log_time_ns, bytes(m.rawdata)) for m in a.messages(['/odom'])]
            odom_b = [(m.log_time_ns, bytes(m.rawdata)) for m in b.messages(['/odom'])]
        assert len(odom_a) == row['odom_out'] and odom_a == odom_b
        report = tmp_path / f'{fleet_config.name}_eval'
        _single('eval', str(single), '--align', 'sim3', '--out-dir', str(report))
        mine = json.loads((report / 'metrics.json').read_text())
        theirs = json.loads((out / row['run_dir'] / 'evaluation' / 'metrics.json').read_text())
        for metrics in (mine, theirs):
            del metrics['estimate'], metrics['reference']
        assert mine == theirs
        assert row['ate_sim3_m'] == mine['ate_m']['rmse']
        assert row['yaw_err_mean_deg'] == mine['yaw_change_error_deg']['mean']
        assert row['path_m'] == mine['path_length_m']
        assert (row['t_rel_pct'], row['r_rel_deg100m'], row['drift_segments']) == tuple(
            kitti_fields(mine).values())


# ---------------------------------------------------------------------------------------------
# Resuming and Ctrl-C
# ---------------------------------------------------------------------------------------------

def test_rerun_skips_complete_results_without_starting_ray(drives, fleet_run, tmp_path, capsys):
    out = tmp_path / 'out'
    shutil.copytree(fleet_run[0], out)
    before = _summary(out)['rows']
    started = time.perf_counter()
    assert main(_fleet_args(drives, out)) == 0
    assert time.perf_counter() - started < 3.0 and not ray.is_initialized()
    assert '12 already there, 0 run now' in capsys.readouterr().out
    summary = _summary(out)
    assert summary['rows'] == before
    assert (summary['run']['skipped'], summary['run']['ran']) == (12, 0)


def test_a_stop_while_the_summary_is_written_waits_for_its_files(
        drives, fleet_run, tmp_path, monkeypatch):
    """A (second) Ctrl-C in the summary's plotting: summary.json and report.md are written
    together, then the run returns as interrupted (a user test: a stale report.md beside a new
    summary.json)."""
    import planar_vo.tools.fleet_report as fleet_report
    from planar_vo.io.outputs import stop_signals_interrupt

    out = tmp_path / 'out'
    shutil.copytree(fleet_run[0], out)
    (out / 'report.md').write_text('stale\n')
    (out / 'summary.json').write_text('{}')
    configs = config_grid(load_config(drives['config']), GRID[1:])
    jobs = plan_jobs([drives['drive_a'], drives['drive_b']], configs)     # all complete
    plot_drift = fleet_report.plot_drift

    def interrupted_plot(*args, **kwargs):
        os.kill(os.getpid(), signal.SIGINT)
        return plot_drift(*args, **kwargs)

    monkeypatch.setattr(fleet_report, 'plot_drift', interrupted_plot)
    with stop_signals_interrupt():
        run = run_fleet(jobs, out, command=['planar_vo', 'fleet', 'run'])
    assert run.stop_signal == signal.SIGINT and run.interrupted      # said, with the table
    summary = _summary(out)
    assert len(summary['rows']) == 4 and summary['run']['skipped'] == 4
    report = (out / 'report.md').read_text()
    assert report.startswith('# planar_vo fleet run') and '## Runs' in report


def test_partial_stale_and_corrupt_results_are_not_trusted(drives, fleet_run, tmp_path):
    out = tmp_path / 'out'
    shutil.copytree(fleet_run[0], out)
    configs = config_grid(load_config(drives['config']), GRID[1:])
    job, other = plan_jobs([drives['drive_b']], configs)
    assert load_result(out, job)['row']['status'] == 'ok'
    # A run interrupted before its result was written: outputs but no result.json.
    (out / job.run_dir / 'result.json').unlink()
    assert load_result(out, job) is None
    # A result.json cut short, and one whose odometry is gone.
    text = (out / other.run_dir / 'result.json').read_text()
    (out / other.run_dir / 'result.json').write_text(text[:len(text) // 2])
    assert load_result(out, other) is None
    (_, broken) = plan_jobs([drives['drive_c']], configs)
    shutil.rmtree(out / broken.run_dir / 'odometry')
    assert load_result(out, broken) is None
    # An output removed from inside (a user test: the rerun kept these rows): the odometry
    # bag's storage file, or the evaluation's metrics.json.
    (no_mcap, no_metrics) = plan_jobs([drives['drive_a']], configs)
    assert load_result(out, no_mcap) is not None and load_result(out, no_metrics) is not None
    for path in (out / no_mcap.run_dir / 'odometry').glob('*.mcap'):
        path.unlink()
    (out / no_metrics.run_dir / 'evaluation' / 'metrics.json').unlink()
    assert load_result(out, no_mcap) is None and load_result(out, no_metrics) is None
    # The bag changed since: its files differ, so does the job's key.
    copy = tmp_path / 'drive_a'
    shutil.copytree(drives['drive_a'], copy)
    (changed,) = plan_jobs([copy], configs[1:])
    (mcap,) = copy.glob('*.mcap')
    os.utime(mcap, ns=(0, 0))
    assert plan_jobs([copy], configs[1:])[0].key != changed.key


def _session_processes(sid: int) -> list[int]:
    pids = []
    for entry in os.listdir('/proc'):
        if entry.isdigit():
            try:
                if os.getsid(int(entry)) == sid:
                    pids.append(int(entry))
            except OSError:
                pass
    return pids


def _wait_gone(sid: int, timeout: float = 20.0) -> list[int]:
    """Processes of session `sid` still there after `timeout` s (they are killed, by pid)."""
    deadline = time.monotonic() + timeout
    while (left := _session_processes(sid)) and time.monotonic() < deadline:
        time.sleep(0.2)
    for pid in left:
        try:
            os.kill(pid, signal.SIGKILL)
        except OSError:
            pass
    return left


@pytest.mark.parametrize('signum', [signal.SIGINT, signal.SIGTERM])
def test_ctrl_c_leaves_a_consistent_folder_and_the_rerun_finishes(drives, tmp_path, capsys,
                                                                  signum):
    """SIGTERM (a supervisor) stops like Ctrl-C (a user test: Ray's own handler dumped a crash
    report and exited 1 without the summary)."""
    out = tmp_path / 'out'
    bags = [str(drives[name]) for name in ('drive_a', 'drive_b', 'drive_c')]
    args = ['fleet', 'run', *bags, '--out', str(out), '--workers', '1', *GRID, '--set',
            'mount.height=1.5']
    cmd = [sys.executable, '-m', 'planar_vo', *args]
    # A new session, signalled as a whole: what Ctrl-C in a terminal does.
    proc = subprocess.Popen(cmd, start_new_session=True, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while not list(out.glob('runs/*/*/result.json')) and time.monotonic() < deadline:
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.05)
        os.killpg(proc.pid, signum)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
        left = _wait_gone(proc.pid)
    assert proc.returncode == 128 + signum, stderr
    assert left == []
    assert 'interrupted' in stdout and 'rerun the same command' in stdout
    # The command's last line says it (Ray's C++ core may log a line of its own before: a
    # task's error that could not reach the stopping driver), and no crash report.
    assert re.fullmatch(rf'planar_vo fleet run: interrupted by {signum.name}; kept \d of 6 '
                        rf'results in {re.escape(str(out))} \(rerun the same command to '
                        rf'finish\)', stderr.splitlines()[-1]), stderr
    assert 'SIGTERM received' not in stderr and 'Traceback' not in stderr, stderr
    summary = _summary(out)
    complete = sorted(p.parent for p in out.glob('runs/*/*/result.json'))
    # (SIGTERM to the process group reaches Ray's workers too; the tasks running may finish
    # before the driver ends its session.)
    assert summary['run']['interrupted'] and 1 <= len(summary['rows']) == len(complete)
    assert len(complete) < 6 or signum == signal.SIGTERM
    assert summary['run']['not_run'] == 6 - len(complete)
    assert sorted(out / r['run_dir'] for r in summary['rows']) == complete
    assert all(r['status'] == 'ok' for r in summary['rows'])
    # The rerun keeps the complete results and redoes the rest (partial folders included).
    assert main(args + ['--no-progress']) == 0
    capsys.readouterr()
    rerun = _summary(out)
    assert (rerun['run']['skipped'], rerun['run']['ran']) == (len(complete), 6 - len(complete))
    assert len(rerun['rows']) == 6 and all(r['status'] == 'ok' for r in rerun['rows'])
    again = {r['run_dir']: r for r in rerun['rows']}
    assert all(again[r['run_dir']] == r for r in summary['rows'])
    assert not rerun['run']['interrupted']


# ---------------------------------------------------------------------------------------------
# A worker killed mid-bag
# ---------------------------------------------------------------------------------------------

def _is_mine(pid: int) -> bool:
    """Whether `pid` descends from this process (Ray's workers do, through its raylet)."""
    while pid > 1:
        try:
            stat = Path(f'/proc/{pid}/stat').read_text()
        except OSError:
            return False
        pid = int(stat.rsplit(')', 1)[1].split()[1])
        if pid == os.getpid():
            return True
    return False


def _task_workers(bag_name: str) -> list[int]:
    pids = []
    for entry in os.listdir('/proc'):
        if not entry.isdigit():
            continue
        try:
            title = Path(f'/proc/{entry}/cmdline').read_text()
        except OSError:
            continue
        if title.startswith(f'{TASK_TITLE}{bag_name}:') and _is_mine(int(entry)):
            pids.append(int(entry))
    return pids


class Killer(threading.Thread):
    """SIGKILLs the worker running a bag's task once its odometry bag exists (mid-bag), up to
    `times` times."""

    def __init__(self, out: Path, bag: Path, times: int):
        super().__init__(daemon=True)
        self.out, self.bag, self.times = out, bag, times
        self.killed: list[int] = []
        self.stop = threading.Event()

    def run(self):
        while not self.stop.is_set() and len(self.killed) < self.times:
            started = [d for d in self.out.glob(f'runs/{self.bag.name}-*/*')
                       if (d / 'odometry').exists() and not (d / 'result.json').exists()]
            if started:
                for pid in _task_workers(self.bag.name):
                    if pid not in self.killed:
                        os.kill(pid, signal.SIGKILL)
                        self.killed.append(pid)
            time.sleep(0.01)


def test_killed_worker_is_retried_and_a_bag_that_keeps_failing_is_reported(
        drives, fleet_run, tmp_path, capsys):
    out = tmp_path / 'out'
    configs = config_grid(load_config(drives['config']), ['voting.bins=720'])
    jobs = plan_jobs([drives['drive_a'], drives['drive_b']], configs)
    once = Killer(out, drives['drive_a'], times=1)
    always = Killer(out, drives['drive_b'], times=99)
    for killer in (once, always):
        killer.start()
    try:
        run = run_fleet(jobs, out, workers=2, retries=1, progress=True)
    finally:
        for killer in (once, always):
            killer.stop.set()
            killer.join()
    assert len(once.killed) == 1 and len(always.killed) == 2       # first try and one retry
    retried, failed = run.rows
    assert retried['status'] == 'ok' and retried['pid'] not in once.killed
    # The retry's result is the one of the undisturbed run, to the last bit.
    reference = _rows(fleet_run[0])['drive_a', 'voting.bins=720']
    assert (out / retried['tum']).read_bytes() == (fleet_run[0] / reference['tum']).read_bytes()
    assert failed['status'] == 'failed'
    assert failed['reason'].startswith('worker died on each of 2 attempts (WorkerCrashedError')
    assert load_result(out, jobs[1]) is None             # not kept: a rerun tries again
    bar = capsys.readouterr().err
    assert 'fleet:' in bar and 'frames/s' in bar and '1 failed' in bar


# ---------------------------------------------------------------------------------------------
# An existing cluster
# ---------------------------------------------------------------------------------------------

def _free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def test_existing_cluster_by_ray_client_and_auto(drives, fleet_run, tmp_path):
    # The head and the clients are subprocesses with token authentication off (Ray 2.60's
    # default depends on whether ~/.ray/auth_token exists, and a process caches its mode).
    env = {**os.environ, 'RAY_AUTH_MODE': 'disabled'}
    gcs, client = _free_port(), _free_port()
    ray_cli = Path(sys.executable).with_name('ray')
    temp = Path(tempfile.mkdtemp(prefix='pvo-ray-'))     # short: Ray's socket paths
    head = subprocess.Popen(
        [str(ray_cli), 'start', '--head', '--block', '--num-cpus', '2', '--port', str(gcs),
         '--ray-client-server-port', str(client), '--include-dashboard', 'false',
         '--disable-usage-stats', '--temp-dir', str(temp)],
        env=env, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            assert head.poll() is None, 'ray start --head exited'
            try:
                socket.create_connection(('127.0.0.1', client), timeout=0.5).close()
                break
            except OSError:
                time.sleep(0.2)
        reference = _rows(fleet_run[0])['drive_c', 'voting.bins=720']
        for address in (f'ray://127.0.0.1:{client}', 'auto'):
            out = tmp_path / address.replace('/', '_').replace(':', '_')
            result = subprocess.run(
                [sys.executable, '-m', 'planar_vo', 'fleet', 'run', str(drives['drive_c']),
                 '--out', str(out), '--config', str(drives['config']), '--set',
                 'voting.bins=720', '--address', address],
                env={**env, 'RAY_ADDRESS': f'127.0.0.1:{gcs}'}, capture_output=True, text=True,
                timeout=180)
            logs = ''.join(f'\n== {p.name}\n' + p.read_text()[-1500:] for p in
                           sorted(temp.glob('session_latest/logs/*client_server*')))
            assert result.returncode == 0, result.stderr + logs
            (row,) = _summary(out)['rows']
            assert row['status'] == 'ok' and _summary(out)['run']['address'] == address
            assert (out / row['tum']).read_bytes() == \
                (fleet_run[0] / reference['tum']).read_bytes()
    finally:
        head.terminate()                 # `ray start --block` stops what it started
        try:
            head.wait(timeout=60)
        finally:
            left = _wait_gone(head.pid)
            shutil.rmtree(temp, ignore_errors=True)
    assert left == []


# ---------------------------------------------------------------------------------------------
# Without Ray; Ray kept out of replay and the node; arguments
# ---------------------------------------------------------------------------------------------

def test_without_ray_one_line_and_exit_1(drives, tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, 'ray', None)          # import ray -> ImportError
    assert main(['fleet', 'run', str(drives['drive_a']), '--out', str(tmp_path / 'o')]) == 1
    err = capsys.readouterr().err.strip()
    assert err == ("planar_vo fleet run: error: ray is not installed; fleet runs need the fleet "
                   "extra: pip install 'planar_vo[fleet]' (or run without Ray: --local)")
    assert not (tmp_path / 'o').exists()


def test_an_unreachable_head_address_is_one_line_and_exit_1(drives, tmp_path, capsys):
    """Ray would retry a host:port head that does not answer for ever; nothing listens on
    port 1 of this machine."""
    args = ['fleet', 'run', str(drives['drive_a']), '--out', str(tmp_path / 'o'), '--address',
            '127.0.0.1:1']
    assert main(args) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("planar_vo fleet run: error: --address: cannot reach Ray at "
                          "'127.0.0.1:1' within 5 s") and '\n' not in err
    assert main(args[:-1] + ['head-without-port']) == 1
    assert "expected 'auto', 'host:port' or 'ray://host:port'" in capsys.readouterr().err


@pytest.mark.timeout(180)
def test_a_fleet_whose_every_run_failed_exits_1(drives, tmp_path, capsys):
    manifest = tmp_path / 'bags.txt'
    manifest.write_text(f"{drives['missing']}\n")
    args = ['fleet', 'run', str(drives['truncated']), '--manifest', str(manifest), '--out',
            str(tmp_path / 'o'), '--workers', '1', '--retries', '0', '--no-progress']
    assert main(args) == 1
    captured = capsys.readouterr()
    assert '0 ok, 2 failed' in captured.out
    assert captured.err.strip() == 'planar_vo fleet run: error: all 2 runs failed'
    # The report's command is the one that ran, --retries too (a user test: it was left out).
    assert (f"--out {tmp_path / 'o'} --manifest {manifest} --workers 1 --retries 0\n"
            in (tmp_path / 'o' / 'report.md').read_text())


def test_replay_and_the_node_never_import_ray(drives, tmp_path):
    code = (
        'import sys\n'
        'from planar_vo.cli import build_parser, main\n'
        'import planar_vo.ros.node, planar_vo.tools.replay\n'
        'build_parser()\n'
        f'assert main(["replay", {str(drives["drive_c"])!r}, "--out", '
        f'{str(tmp_path / "vo")!r}, "--no-progress"]) == 0\n'
        'bad = sorted(m for m in sys.modules if m.split(".")[0] == "ray")\n'
        'assert not bad, bad\n'
    )
    result = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 0, result.stderr


@pytest.mark.parametrize(('extra', 'match'), [
    (['--address', 'auto', '--workers', '2'], r'--workers: --workers sizes the local Ray '
                                              r'instance; with --address'),
    (['--workers', '0'], r'--workers: expected at least 1, got 0'),
    (['--retries', '-1'], r'--retries: expected 0 or more, got -1'),
    (['--set', 'voting.binz=3'], r"--set: unknown configuration key 'voting.binz'; did you mean "
                                 r'voting.bins'),
    (['--set', 'voting.bins=3'], r'--set: voting.bins=3: .*bins: expected in \[36, 100000\], '
                                 r'got 3'),
    (['--manifest', 'nowhere.txt'], r"--manifest: cannot read 'nowhere.txt' \(No such file"),
])
def test_bad_arguments_are_one_line_and_exit_1(drives, tmp_path, capsys, extra, match):
    assert main(['fleet', 'run', str(drives['drive_a']), '--out', str(tmp_path / 'o'),
                 *extra]) == 1
    err = capsys.readouterr().err.strip()
    assert '\n' not in err and re.search(match, err), err
    assert not (tmp_path / 'o').exists()


@pytest.mark.parametrize('raised, signal_name', [
    (SystemExit(signal.SIGTERM), 'SIGTERM'), (KeyboardInterrupt('SIGINT'), 'SIGINT')])
def test_a_stop_while_ray_starts_shuts_it_down_and_is_a_stop(monkeypatch, raised, signal_name):
    """A stop signal while Ray starts (a user test: Ray's own SIGTERM handler, installed during
    its start, exited with code 15 and no word; Ctrl-C left Ray's agents running): what was
    started is shut down, and SIGTERM is a KeyboardInterrupt naming it, as everywhere else."""
    from planar_vo.tools.fleet import ray_session

    calls = []

    def init(**kwargs):
        raise raised

    monkeypatch.setattr(ray, 'init', init)
    monkeypatch.setattr(ray, 'is_initialized', lambda: False)
    monkeypatch.setattr(ray, 'shutdown', lambda: calls.append('shutdown'))
    with pytest.raises(KeyboardInterrupt, match=f'^{signal_name}$'):
        with ray_session(workers=1):
            pass
    assert calls == ['shutdown']


def test_no_bags_is_an_error(tmp_path, capsys):
    assert main(['fleet', 'run', '--out', str(tmp_path / 'o')]) == 1
    assert capsys.readouterr().err == ('planar_vo fleet run: error: BAG: expected BAG arguments or '
                                       '--manifest FILE, got none\n')


def test_only_missing_bags_fail_before_ray_starts(tmp_path, capsys):
    """A bag typed on the command line that does not exist is a typo: refused (a user test: it
    became a failed row of a run that exited 0); a manifest's missing bags are failed rows,
    unless none of them exists."""
    (tmp_path / 'there').mkdir()
    assert main(['fleet', 'run', str(tmp_path / 'there'), str(tmp_path / 'typo'), '--out',
                 str(tmp_path / 'o')]) == 1
    assert capsys.readouterr().err == (f"planar_vo fleet run: error: BAG: '{tmp_path / 'typo'}' "
                                       f'does not exist\n')
    (tmp_path / 'gone.txt').write_text('a\nb\n')
    assert main(['fleet', 'run', '--manifest', str(tmp_path / 'gone.txt'), '--out',
                 str(tmp_path / 'o')]) == 1
    assert capsys.readouterr().err == (f"planar_vo fleet run: error: BAG: none of the 2 bags "
                                       f"exists ('{tmp_path / 'a'}', ...)\n")
    nope = tmp_path / 'nope.mcap'
    assert main(['fleet', 'run', str(nope), '--out', str(tmp_path / 'o')]) == 1
    assert capsys.readouterr().err == (f"planar_vo fleet run: error: BAG: '{nope}' does not "
                                       f'exist\n')
    assert main(['fleet', 'run', str(tmp_path / 'a'), str(tmp_path / 'b'), '--out',
                 str(tmp_path / 'o')]) == 1
    assert capsys.readouterr().err == (f"planar_vo fleet run: error: BAG: '{tmp_path / 'a'}' "
                                       f'does not exist (and 1 more of the bags given)\n')
    assert not (tmp_path / 'o').exists()         # found before Ray and the output


def test_a_speed_scale_is_refused_without_a_speed_input(tmp_path, capsys):
    (tmp_path / 'bag').mkdir()
    assert main(['fleet', 'run', str(tmp_path / 'bag'), '--out', str(tmp_path / 'o'), '--set',
                 'scale.source=ground,speed']) == 1
    assert capsys.readouterr().err == (
        "planar_vo fleet run: error: scale.source: speed needs a speed topic, which fleet run "
        "does not feed (configuration 'scale.source=speed'); use planar_vo replay --speed-topic "
        'per bag, or another scale.source\n')
    assert not (tmp_path / 'o').exists()


# ---------------------------------------------------------------------------------------------
# Configurations, manifests, jobs (no Ray)
# ---------------------------------------------------------------------------------------------

def test_config_grid_is_every_combination_of_the_sets():
    base = PlanarVoConfig()
    (default,) = config_grid(base)
    assert default.name == 'default' and default.build() == base
    grid = config_grid(base, ['voting.bins=360,720,360', 'frontend.method=flow,klt',
                              'mount.height=1.2'])
    assert [c.name for c in grid] == [
        'voting.bins=360 frontend.method=flow mount.height=1.2',
        'voting.bins=360 frontend.method=klt mount.height=1.2',
        'voting.bins=720 frontend.method=flow mount.height=1.2',
        'voting.bins=720 frontend.method=klt mount.height=1.2']
    config = grid[1].build()
    assert (config.voting.bins, config.frontend.method, config.mount.height) == (360, 'klt', 1.2)
    assert config.replace(voting=base.voting, frontend=base.frontend, mount=base.mount) == base
    with pytest.raises(ConfigError, match=r"set: 'voting.bins' given twice"):
        config_grid(base, ['voting.bins=360', 'voting.bins=720'])
    with pytest.raises(ConfigError, match=r"set: expected KEY=VALUE\[,VALUE...\], got 'x'"):
        config_grid(base, ['x'])
    with pytest.raises(ConfigError, match=r'set: frontend.method=sift: .*expected one of'):
        config_grid(base, ['frontend.method=flow,sift'])


def test_config_grid_validates_a_file_with_its_sets(tmp_path):
    # (a user test: a --config file that needs a --set to be valid was refused on its own)
    path = tmp_path / 'fov.yaml'
    path.write_text('/**:\n  ros__parameters:\n    camera: {nominal_fov: 1.5708}\n')
    values = read_config(path)
    assert values == {'camera.nominal_fov': 1.5708}
    (config,) = config_grid(values, ['camera.estimate_focal=true'], source=str(path))
    assert config.build().camera.nominal_fov == 1.5708 and config.build().camera.estimate_focal
    with pytest.raises(ConfigError, match=rf'^{path}: camera.nominal_fov: expected 0 without '):
        config_grid(values, source=str(path))
    # The cause named: the file alone (the set changes nothing about it), the set alone (the
    # file is valid), or both (a review: every refusal named both).
    with pytest.raises(ConfigError, match=rf'^{path}: camera.nominal_fov: expected 0 without '):
        config_grid(values, ['voting.bins=360'], source=str(path))
    with pytest.raises(ConfigError, match=r'^set: camera.estimate_focal=true voting.bins=1: '
                                          r'voting.bins: expected'):
        config_grid(values, ['camera.estimate_focal=true', 'voting.bins=1'], source=str(path))
    path.write_text('camera: {nominal_fov: 1.5708, fy: 500.0}\n')
    with pytest.raises(ConfigError, match=rf'^{path}: camera.fy: expected 0 while fx is 0'):
        config_grid(read_config(path), ['camera.estimate_focal=true'], source=str(path))
    # A section whose settings are all commented out is empty, as load_config reads it.
    path.write_text('camera:\n  # fx: 500\nmount:\n  height: 1.6\n')
    assert read_config(path) == {'mount.height': 1.6}
    (config,) = config_grid(read_config(path), ['mount.pitch=0.01'], source=str(path))
    assert (config.build().mount.height, config.build().mount.pitch) == (1.6, 0.01)


def test_manifest_and_jobs(tmp_path):
    (tmp_path / 'sub').mkdir()
    manifest = tmp_path / 'sub' / 'list.txt'
    manifest.write_text(f'# drives\n a.mcap \n\n{tmp_path}/b\n')
    assert read_manifest(manifest) == [tmp_path / 'sub' / 'a.mcap', tmp_path / 'b']
    (tmp_path / 'empty.txt').write_text('# nothing\n\n')
    with pytest.raises(InputError, match=r"manifest: '.*empty.txt' lists no bags"):
        read_manifest(tmp_path / 'empty.txt')
    configs = config_grid(PlanarVoConfig(), ['voting.bins=360,720'])
    jobs = plan_jobs([tmp_path / 'x.mcap', tmp_path / 'y', tmp_path / 'sub' / '..' / 'x.mcap'],
                     configs)                     # the same bag twice, once through 'sub/..'
    assert jobs[0].bag == str(tmp_path / 'x.mcap')
    assert [(Path(j.bag).name, j.config.name) for j in jobs] == [
        ('x.mcap', 'voting.bins=360'), ('x.mcap', 'voting.bins=720'),
        ('y', 'voting.bins=360'), ('y', 'voting.bins=720')]
    assert len({j.run_dir for j in jobs}) == 4 and len({j.key for j in jobs}) == 4
    assert jobs[0].run_dir.startswith('runs/x-') and '/voting.bins=360-' in jobs[0].run_dir


def test_bag_names_are_relative_to_a_common_folder_or_else_the_paths():
    assert bag_names(['/d/x/k05', '/d/x/k06', '/d/y/k07']) == {
        '/d/x/k05': 'x/k05', '/d/x/k06': 'x/k06', '/d/y/k07': 'y/k07'}
    # Nothing in common but the root: the paths themselves (a user test: 'a/k05' for '/a/k05'
    # read as a relative path).
    assert bag_names(['/a/k05', '/b/k06']) == {'/a/k05': '/a/k05', '/b/k06': '/b/k06'}
    assert bag_names(['/data/k05']) == {'/data/k05': 'k05'}


def test_thumbnail_titles_fit_their_panels():
    """(a user test: a long bag name ran into the next panel's title)"""
    from planar_vo.tools.fleet_report import _TITLE_WIDTH, _panel_title

    bag = '/very/long/folder/of/the/drives/2026-11-28/drive_front_camera_left'
    row = {'bag': bag, 'config': 'voting.bins=360'}
    title = _panel_title(row, {bag: bag}, 2)
    lines = title.split('\n')
    assert max(len(line) for line in lines) <= _TITLE_WIDTH
    assert ''.join(lines[:-1]) == bag and lines[-1] == '[voting.bins=360]'
    assert _panel_title(row, {bag: 'k05'}, 1) == 'k05'


def test_kitti_fields_are_the_evaluations_kitti_drift():
    # A 300 m straight estimated 1 % too long: KITTI t_rel is 1 %, r_rel 0.
    n = 301
    stamps = np.arange(n, dtype=np.int64) * 100_000_000
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, 0, 3] = np.arange(n, dtype=float)
    ref = Trajectory.from_poses(stamps, poses)
    est_poses = poses.copy()
    est_poses[:, 0, 3] *= 1.01
    metrics = evaluate(ref, Trajectory.from_poses(stamps, est_poses)).metrics()
    fields = kitti_fields(metrics)
    assert fields['t_rel_pct'] == pytest.approx(1.0, abs=1e-9)
    assert fields['r_rel_deg100m'] == pytest.approx(0.0, abs=1e-9)
    assert fields['drift_segments'] == '100-800 m'
    # A 60 m drive: the 10-50 m segments eval reports for it; 5 m: none at all.
    for length, expected in ((61, {'t_rel_pct': pytest.approx(1.0, abs=1e-9),
                                   'r_rel_deg100m': pytest.approx(0.0, abs=1e-9),
                                   'drift_segments': '10-50 m'}),
                             (6, {'t_rel_pct': None, 'r_rel_deg100m': None,
                                  'drift_segments': None})):
        short = evaluate(Trajectory.from_poses(stamps[:length], poses[:length]),
                         Trajectory.from_poses(stamps[:length], est_poses[:length])).metrics()
        assert kitti_fields(short) == expected
    # The report's per-configuration means leave the short drive out, its row names its
    # segments.
    from planar_vo.tools.fleet_report import _drift_cell, aggregate
    from planar_vo.tools.markdown import format_cell
    rows = [{'status': 'ok', 'wall_s': 1.0, 'frames_in': 1, 'odom_out': 1, 'path_m': 300.0,
             'yaw_err_mean_deg': 0.0, 'ate_sim3_m': 0.1, 'bag': 'a', **fields},
            {'status': 'ok', 'wall_s': 1.0, 'frames_in': 1, 'odom_out': 1, 'path_m': 60.0,
             'yaw_err_mean_deg': 0.0, 'ate_sim3_m': 0.1, 'bag': 'b', 't_rel_pct': 5.0,
             'r_rel_deg100m': 2.0, 'drift_segments': '10-50 m'}]
    assert aggregate(rows)['t_rel_pct'] == pytest.approx(1.0, abs=1e-9)
    assert _drift_cell(rows[1], 't_rel_pct') == '5 (10-50 m)'
    assert _drift_cell(rows[0], 't_rel_pct') == format_cell(rows[0]['t_rel_pct'])


def test_bench_fleet_measures_the_three_setups(tmp_path, capsys):
    # Timings are not asserted (a shared machine); the machinery and the equality check are.
    out = tmp_path / 'bench'
    assert main(['bench', 'fleet', '--bags', '2', '--frames', '10', '--repeat', '1', '--out',
                 str(out), '--work', str(tmp_path / 'work')]) == 0
    report = (out / 'fleet.md').read_text()
    assert report.startswith('# planar_vo bench fleet')
    assert 'planar_vo bench fleet --out' in report and '--bags 2 --frames 10' in report
    for setup in ('| in-process |', '| 1 worker |', '| 2 workers |'):
        assert setup in report
    assert '| every result identical in the three setups | yes | met |' in report
    assert (out / 'fleet.png').stat().st_size > 5_000
    # The drives are kept in --work and reused by the next run.
    assert sorted(p.name for p in (tmp_path / 'work' / 'drives').iterdir()) == [
        'drive_00', 'drive_01', 'drives.json', 'warm_up']
    assert not ray.is_initialized()
    capsys.readouterr()


def test_task_errors_become_rows_and_interruptions_none(tmp_path):
    from planar_vo.tools.fleet import _failure

    (job,) = plan_jobs([tmp_path / 'x.mcap'], config_grid(PlanarVoConfig()))
    bug = ray.exceptions.RayTaskError('run_job', 'Traceback ...', ValueError('boom\nmore'))
    row = _failure(ray, bug, job, 2)['row']
    assert (row['status'], row['reason']) == ('failed', 'internal error: ValueError: boom more')
    died = ray.exceptions.WorkerCrashedError()
    assert _failure(ray, died, job, 2)['row']['reason'].startswith(
        'worker died on each of 3 attempts (WorkerCrashedError: ')
    assert _failure(ray, ray.exceptions.TaskCancelledError(), job, 2) is None
    interrupted = ray.exceptions.RayTaskError('run_job', 'Traceback ...', KeyboardInterrupt())
    assert _failure(ray, interrupted, job, 2) is None


# ---------------------------------------------------------------------------------------------
# From a user test: no motion, repeats, the output folder, local runs, output failures
# ---------------------------------------------------------------------------------------------

def _without_camera_info(bag: Path, out: Path) -> Path:
    """A copy of `bag`'s images without CameraInfo (a camera whose intrinsics nobody gave)."""
    from planar_vo.io import CameraBagWriter, iter_camera_frames

    with open_bag(bag) as reader, CameraBagWriter(out, camera_info=False) as writer:
        for frame in iter_camera_frames(reader):
            writer.write_frame(frame.stamp_ns, frame.image, None)
    return out


@pytest.mark.timeout(300)
def test_local_runs_equal_rays_and_a_bag_without_motion_is_a_failed_row(
        drives, fleet_run, tmp_path, capsys, caplog):
    """--local needs no Ray and gives the Ray run's rows; a bag that gives no motion is failed
    with replay's reason (was 'ok' with no odometry); the default camera height is said."""
    out, _ = fleet_run
    blind = _without_camera_info(drives['drive_c'], tmp_path / 'blind')
    args = ['fleet', 'run', str(drives['drive_a']), str(blind), '--out', str(tmp_path / 'o'),
            '--config', str(drives['config']), '--set', 'voting.bins=360', '--local',
            '--no-progress']
    with caplog.at_level('WARNING', logger='planar_vo'):
        assert main(args) == 0
    assert any(r.getMessage().startswith('mount.height: the default 1.5 m sets every metric '
                                         'scale') for r in caplog.records)
    printed = capsys.readouterr().out
    assert '1 ok, 1 failed' in printed and 'this process, no Ray' in printed
    rows = {Path(r['bag']).name: r for r in _summary(tmp_path / 'o')['rows']}
    assert rows['blind']['status'] == 'failed' and rows['blind']['reason'].startswith(
        f"no motion estimated from {rows['blind']['frames_in']} frame(s) "
        '(no_camera_info: no camera intrinsics yet')
    assert rows['blind']['odometry'] is not None       # the bag replay kept, named
    ray_row = _rows(out)[('drive_a', 'voting.bins=360')]
    local_row = rows['drive_a']
    for key in ('frames_in', 'odom_out', 't_rel_pct', 'r_rel_deg100m', 'ate_sim3_m',
                'yaw_err_mean_deg'):
        assert local_row[key] == ray_row[key], key
    assert not ray.is_initialized()
    # --local with Ray's options is a contradiction.
    for option in (['--workers', '2'], ['--retries', '1']):
        assert main(args + option) == 1
        assert capsys.readouterr().err == (f'planar_vo fleet run: error: {option[0]}: --local '
                                           f'runs in this process, without Ray\n')


def test_two_pass_fleet_runs_are_replays_with_two_passes(drives, tmp_path, capsys):
    """fleet run --two-pass: each bag replayed as `replay --two-pass`; refused for a
    configuration that does not self-calibrate the focal length."""
    from planar_vo.tools.provenance import bag_custom_data

    args = ['fleet', 'run', str(drives['drive_c']), '--out', str(tmp_path / 'o'), '--config',
            str(drives['config']), '--local', '--two-pass', '--no-progress']
    assert main(args) == 1
    assert capsys.readouterr().err == (
        "planar_vo fleet run: error: --two-pass: the first pass self-calibrates the focal "
        "length, which configuration 'fleet.yaml' does not: give --set "
        'camera.estimate_focal=true\n')
    assert main([*args, '--set', 'camera.estimate_focal=true']) == 0
    capsys.readouterr()
    (row,) = _summary(tmp_path / 'o')['rows']
    assert row['status'] == 'ok'
    focal = bag_custom_data(tmp_path / 'o' / row['run_dir'] / 'odometry')['planar_vo.focal']
    assert focal.endswith('; from a first pass over the whole recording)')
    assert '--local --two-pass --set camera.estimate_focal=true' in (
        tmp_path / 'o' / 'report.md').read_text()


def test_the_same_bag_twice_runs_once_and_the_repeat_is_said(drives, tmp_path, caplog):
    bag = Path(drives['drive_c'])
    (tmp_path / 'link').symlink_to(bag)
    (storage,) = bag.glob('*.mcap')
    configs = config_grid(PlanarVoConfig())
    with caplog.at_level('WARNING', logger='planar_vo'):
        jobs = plan_jobs([bag, tmp_path / 'link', storage, f'{bag}/'], configs)
    assert [j.bag for j in jobs] == [str(bag)]
    said = [r.getMessage() for r in caplog.records]
    # (the same path spelled another way too: 'k06/' after 'k06'; a user test)
    assert said == [f"BAG: '{tmp_path / 'link'}' is the bag '{bag}' again; it runs once",
                    f"BAG: '{storage}' is the bag '{bag}' again; it runs once",
                    f"BAG: '{bag}/' is the bag '{bag}' again; it runs once"]
    # The files of a split recording are different data (a review: only the first ran).
    split = tmp_path / 'split'
    split.mkdir()
    (split / 'metadata.yaml').write_text('')
    parts = [split / 'drive_0.mcap', split / 'drive_1.mcap']
    for part in parts:
        part.write_bytes(b'')
    assert [j.bag for j in plan_jobs(parts, configs)] == [str(p) for p in parts]


def test_the_output_folder_may_not_overlap_a_bag_nor_be_used_twice(drives, tmp_path, capsys):
    import fcntl

    bag = drives['drive_c']
    for out, why in ((bag, 'is a bag'), (bag / 'fleet', 'overlaps the input bag')):
        assert main(['fleet', 'run', str(bag), '--out', str(out), '--local']) == 1
        assert why in capsys.readouterr().err
    assert not (bag / 'fleet').exists() and not (bag / 'runs').exists()
    out = tmp_path / 'busy'
    out.mkdir()
    held = os.open(out, os.O_RDONLY)              # the lock is on the folder itself
    try:
        fcntl.flock(held, fcntl.LOCK_EX | fcntl.LOCK_NB)
        assert main(['fleet', 'run', str(bag), '--out', str(out), '--local']) == 1
    finally:
        os.close(held)
    assert capsys.readouterr().err == (f"planar_vo fleet run: error: --out: another fleet run "
                                       f"is using '{out}'; wait for it or give another folder\n")
    assert list(out.iterdir()) == []              # no lock file left in the results
    # A folder that holds the bags is fine (a review: refused).
    from planar_vo.tools.fleet import check_out_dir
    check_out_dir(bag.parent, [bag])


def test_a_failure_of_the_outputs_is_retried_by_the_rerun(drives, tmp_path, monkeypatch):
    """A full disk is not the bag's fault (a user test: the failure was kept for good)."""
    import planar_vo.tools.fleet as fleet
    from planar_vo.errors import BagError
    from planar_vo.tools.fleet import run_job

    (job,) = plan_jobs([drives['drive_c']], config_grid(PlanarVoConfig()))

    def full_disk(job, work, row):
        raise BagError(f"out: nothing was kept at '{work}/odometry' (cannot finish the bag: "
                       f"No space left on device)")

    monkeypatch.setattr(fleet, '_replay_and_evaluate', full_disk)
    record = run_job(job, tmp_path)
    assert (record['row']['status'], record['final']) == ('failed', False)
    assert load_result(tmp_path, job) is None
    monkeypatch.setattr(fleet, '_replay_and_evaluate',
                        lambda job, work, row: (_ for _ in ()).throw(InputError('bag: corrupt')))
    record = run_job(job, tmp_path)
    assert record['final'] and load_result(tmp_path, job)['row']['reason'] == 'bag: corrupt'
    # A bag that fails mid-way: the row counts what replay did before (a user test: 0 frames
    # and 0 odometry where 20 odometry messages were kept).
    from planar_vo.tools.replay import ReplaySummary

    def mid_way(job, work, row):
        err = BagError('bag: corrupt or truncated, reading failed after 41 messages')
        err.replay_summary = ReplaySummary('in', 'out', frames_in=20, odometry_out=19,
                                           dropped={'unreliable': 1})
        raise err

    monkeypatch.setattr(fleet, '_replay_and_evaluate', mid_way)
    row = run_job(job, tmp_path)['row']
    assert (row['status'], row['frames_in'], row['odom_out'], row['drops']) == \
        ('failed', 20, 19, {'unreliable': 1})


def test_config_given_twice_and_manifest_comments(drives, tmp_path, capsys):
    for prog, command in (('planar_vo fleet run', ['fleet', 'run']),
                          ('planar_vo replay', ['replay'])):
        with pytest.raises(SystemExit) as exc:          # a usage error, as argparse's
            main([*command, str(drives['drive_c']), '--out', str(tmp_path / 'o'), '--config',
                  'a.yaml', '--config', 'b.yaml'])
        assert exc.value.code == 1
        assert capsys.readouterr().err == (f'{prog}: error: --config: given twice; give it once '
                                           f'(see {prog} --help)\n')
    manifest = tmp_path / 'm.txt'
    manifest.write_text('a   # the main drive\nb#2\n  # c\n')
    assert read_manifest(manifest) == [tmp_path / 'a', tmp_path / 'b#2']


def test_a_job_that_raises_in_a_local_run_is_a_failed_row_and_the_rest_run(
        drives, tmp_path, monkeypatch):
    """As on Ray (a review: --local stopped the whole fleet, with a traceback and no summary)."""
    import planar_vo.tools.fleet as fleet

    real = fleet._replay_and_evaluate

    def buggy(job, work, row):
        if Path(job.bag).name == 'drive_b':
            raise RuntimeError('boom')
        return real(job, work, row)

    monkeypatch.setattr(fleet, '_replay_and_evaluate', buggy)
    jobs = plan_jobs([drives['drive_b'], drives['drive_c']], config_grid(PlanarVoConfig()))
    run = run_fleet(jobs, tmp_path / 'o', local=True)
    rows = {Path(r['bag']).name: r for r in run.rows}
    assert rows['drive_b']['status'] == 'failed'
    assert rows['drive_b']['reason'] == 'internal error: RuntimeError: boom'
    assert rows['drive_c']['status'] == 'ok' and (tmp_path / 'o' / 'summary.json').exists()
    assert load_result(tmp_path / 'o', jobs[0]) is None          # not kept: a rerun repeats it
