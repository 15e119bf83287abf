"""Outputs under stop signals and full or read-only disks: SIGTERM handled like SIGINT, files
and bags complete or absent, one line saying what was kept."""

from __future__ import annotations

import errno
import json
import signal
import subprocess
import sys

import numpy as np
import pytest
from disk_tools import (
    catches_signal,
    child_pids,
    partial_leftovers,
    run_planar_vo,
    wait_for,
)
from rosbags.rosbag2 import Writer

from planar_vo.cli import main
from planar_vo.core.conventions import planar_pose
from planar_vo.errors import BagError, OutputError
from planar_vo.io import OdometryBagWriter, iter_messages, open_bag
from planar_vo.io.outputs import (
    deferred_interrupts,
    interrupt_signal,
    replacing_file,
    stop_signals_interrupt,
    write_file,
)
from planar_vo.tools.evaluation.plots import PLOTS

T0 = 1_700_000_000 * 10**9


# -- stop signals -------------------------------------------------------------------------------

@pytest.mark.parametrize('signum', [signal.SIGINT, signal.SIGTERM])
def test_stop_signals_raise_keyboard_interrupt_naming_the_signal(signum):
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    with pytest.raises(KeyboardInterrupt) as exc:
        with stop_signals_interrupt():
            signal.raise_signal(signum)
            for _ in range(1000):          # the handler runs between bytecodes
                pass
    assert interrupt_signal(exc.value) == signum
    assert {s: signal.getsignal(s) for s in before} == before         # handlers restored


def test_a_stop_signal_inside_a_deferred_block_is_raised_when_the_block_ends():
    steps = []
    with pytest.raises(KeyboardInterrupt, match='SIGTERM'):
        with stop_signals_interrupt():
            with deferred_interrupts():
                signal.raise_signal(signal.SIGTERM)
                with deferred_interrupts():      # nested: only the outermost end raises
                    steps.append('inner')
                steps.append('after inner')
            steps.append('after the block')      # never reached
    assert steps == ['inner', 'after inner']


def test_a_bag_finished_while_a_stop_signal_arrives_is_kept(tmp_path, monkeypatch):
    """SIGTERM in the middle of finishing a bag (sqlite commit, MCAP summary) does not cut it:
    the bag is finished and moved into place, then the interrupt is raised."""
    close = Writer.close

    def close_with_signal(self):
        signal.raise_signal(signal.SIGTERM)
        for _ in range(1000):
            pass
        close(self)

    monkeypatch.setattr(Writer, 'close', close_with_signal)
    out = tmp_path / 'odom'
    with pytest.raises(KeyboardInterrupt, match='SIGTERM'):
        with stop_signals_interrupt():
            with OdometryBagWriter(out, storage='sqlite3') as writer:
                for i in range(3):
                    writer.write(T0 + i, planar_pose(float(i), 0.0, 0.0))
    assert writer.kept
    with open_bag(out) as bag:
        assert [m.stamp_ns for m in iter_messages(bag, '/odom')] == [T0, T0 + 1, T0 + 2]
    assert partial_leftovers(tmp_path) == []


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_a_message_written_while_a_stop_signal_arrives_is_counted(tmp_path, monkeypatch, storage):
    """SIGTERM during a message's write: the message is written and counted before the interrupt
    is raised, so the note's counts are the bag's (a CI run once reported 6 of 7 messages)."""
    write = Writer.write
    calls = []

    def write_with_signal(self, connection, timestamp, data):
        calls.append(timestamp)
        if len(calls) == 3:
            signal.raise_signal(signal.SIGTERM)
            for _ in range(1000):
                pass
        write(self, connection, timestamp, data)

    monkeypatch.setattr(Writer, 'write', write_with_signal)
    out = tmp_path / 'odom'
    with pytest.raises(KeyboardInterrupt, match='SIGTERM') as exc:
        with stop_signals_interrupt():
            with OdometryBagWriter(out, storage=storage) as writer:
                for i in range(5):
                    writer.write(T0 + i, planar_pose(float(i), 0.0, 0.0))
    assert writer.kept and writer.count == 3
    assert exc.value.__notes__ == [f"kept '{out}', a complete bag with messages /odom: 3"]
    with open_bag(out) as bag:
        assert [m.stamp_ns for m in iter_messages(bag, '/odom')] == [T0, T0 + 1, T0 + 2]


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_a_bag_that_cannot_be_finished_is_removed_not_reported_as_kept(tmp_path, monkeypatch,
                                                                       storage):
    def full(self):
        raise OSError(errno.ENOSPC, 'No space left on device')

    monkeypatch.setattr(Writer, 'close', full)
    out = tmp_path / 'odom'
    with pytest.raises(BagError, match=r"^out: nothing was kept at '.*odom' \(cannot finish the "
                                       r'bag: No space left on device\)$'):
        with OdometryBagWriter(out, storage=storage) as writer:
            writer.write(T0, planar_pose(0.0, 0.0, 0.0))
    assert not writer.kept and not out.exists() and partial_leftovers(tmp_path) == []
    # An error inside the block keeps its type and gets the same note.
    with pytest.raises(ValueError, match=r"boom\nnothing was kept at '.*odom2'"):
        with OdometryBagWriter(tmp_path / 'odom2', storage=storage) as writer:
            writer.write(T0, planar_pose(0.0, 0.0, 0.0))
            raise ValueError('boom')
    assert not (tmp_path / 'odom2').exists()


def test_bag_stamps_outside_the_ros_time_range_are_refused(tmp_path):
    with OdometryBagWriter(tmp_path / 'odom') as writer:
        for stamp in (-1, 2**31 * 10**9, 10**400):
            with pytest.raises(BagError, match=rf"stamp on '/odom': {stamp} ns is outside the "
                                               r'range of a ROS time stamp \(0 to '
                                               r'2147483647999999999 ns, i\.e\. 1970 to 2038\)'):
                writer.write(stamp, np.eye(4))
        writer.write(2**31 * 10**9 - 1, np.eye(4))
    assert writer.counts == {'/odom': 1}


# -- files --------------------------------------------------------------------------------------

def _fail_after_half(exc: BaseException):
    def write(tmp):
        tmp.write_text('half a fi')
        raise exc
    return write


@pytest.mark.parametrize('exc, raised', [
    (OSError(errno.ENOSPC, 'No space left on device'), OutputError),
    (KeyboardInterrupt('SIGTERM'), KeyboardInterrupt),
])
def test_a_file_interrupted_or_failing_mid_write_leaves_the_target_as_it_was(tmp_path, exc,
                                                                             raised):
    fresh, old = tmp_path / 'new.tum', tmp_path / 'old.tum'
    old.write_text('complete\n')
    for target in (fresh, old):
        with pytest.raises(raised):
            write_file(target, _fail_after_half(exc), role='tum')
    assert not fresh.exists() and old.read_text() == 'complete\n'
    assert sorted(p.name for p in tmp_path.iterdir()) == ['old.tum']
    # ... so the next run is not blocked by a truncated file
    write_file(fresh, 'complete too\n')
    assert fresh.read_text() == 'complete too\n'


def test_output_error_names_the_file_and_the_reason(tmp_path):
    with pytest.raises(OutputError, match=r"tum: cannot write '.*x\.tum' \(No space left on "
                                          r'device\)'):
        full = OSError(errno.ENOSPC, 'No space left on device')
        write_file(tmp_path / 'x.tum', _fail_after_half(full), role='tum')
    (tmp_path / 'file').write_text('')
    with pytest.raises(OutputError, match=r"out-dir: cannot create the folder of "
                                          r"'.*file/metrics\.json'"):
        with replacing_file(tmp_path / 'file' / 'metrics.json', role='out-dir'):
            pass


# -- the command --------------------------------------------------------------------------------

def test_binary_config_is_one_line(tmp_path, capsys):
    config = tmp_path / 'config.yaml'
    config.write_bytes(b'\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR' + bytes(range(256)))
    assert main(['replay', str(tmp_path / 'in'), '--out', str(tmp_path / 'out'), '--config',
                 str(config)]) == 1
    err = capsys.readouterr().err
    assert err == (f"planar_vo replay: error: {config}: not a YAML text file (byte 0 is not "
                   f"UTF-8: b'\\x89')\n")
    config.write_bytes(bytes(300))
    assert main(['replay', str(tmp_path / 'in'), '--out', str(tmp_path / 'out'), '--config',
                 str(config)]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f'planar_vo replay: error: {config}: not valid YAML (unacceptable '
                          f'character #x0000') and err.count('\n') == 1
    assert not (tmp_path / 'out').exists()


def test_demo_on_a_read_only_disk_is_one_line(tmp_path):
    run = run_planar_vo(['demo', '--out', tmp_path / 'ro' / 'demo', '--frames', '5'],
                        disk=tmp_path / 'ro', keep=tmp_path / 'kept', read_only=True)
    reason = 'Read-only file system' if run.method == 'tmpfs' else 'Permission denied'
    assert run.returncode == 1
    assert run.stderr == (f"planar_vo demo: error: --out: cannot write the demo folder "
                          f"'{tmp_path / 'ro' / 'demo'}' ({reason})\n")
    assert list((tmp_path / 'kept').iterdir()) == []


def test_demo_on_a_full_disk_says_nothing_was_kept(tmp_path):
    """640x480 frames of about 300 KB on a 1 MiB disk: the drive bag fills it while rendering."""
    run = run_planar_vo(['demo', '--out', tmp_path / 'disk' / 'demo', '--frames', '20',
                         '--no-progress'], disk=tmp_path / 'disk', keep=tmp_path / 'kept',
                        size_kib=1024)
    demo = tmp_path / 'disk' / 'demo'
    reason = 'No space left on device' if run.method == 'tmpfs' else 'File too large'
    assert run.returncode == 1, run.stderr
    assert run.stderr == (f"planar_vo demo: error: --out: cannot write to bag '{demo}/drive' "
                          f"({reason}); nothing was kept at '{demo}/drive' (removed after a "
                          f"failed write); '{demo}' holds: nothing\n")
    assert partial_leftovers(tmp_path / 'kept') == []
    assert [p.name for p in (tmp_path / 'kept' / 'demo').iterdir()] == ['.planar_vo_demo']


def _tum_pair(folder):
    """An estimate and a reference TUM file of a 60-pose drive."""
    rng = np.random.default_rng(3)
    stamps = T0 + np.arange(60) * 100_000_000
    xy = np.cumsum(rng.uniform(0.5, 1.0, (60, 2)), axis=0)
    for name, noise in (('gt', 0.0), ('est', 0.05)):
        lines = [f'{s / 1e9:.9f} {x + noise * rng.normal()} {y} 0 0 0 0 1'
                 for s, (x, y) in zip(stamps, xy)]
        (folder / f'{name}.tum').write_text('\n'.join(lines) + '\n')


def test_eval_stopped_by_sigterm_names_the_complete_files(tmp_path, capsys, monkeypatch):
    _tum_pair(tmp_path)
    plot_ate = PLOTS['ate.png']

    def stop_then_plot(evaluation, path):
        signal.raise_signal(signal.SIGTERM)
        return plot_ate(evaluation, path)

    monkeypatch.setitem(PLOTS, 'ate.png', stop_then_plot)
    out = tmp_path / 'eval'
    assert main(['eval', str(tmp_path / 'est.tum'), '--gt', str(tmp_path / 'gt.tum'),
                 '--out-dir', str(out)]) == 143
    assert capsys.readouterr().err == (f"planar_vo eval: interrupted by SIGTERM; written to "
                                       f"'{out}': metrics.json, trajectory.png\n")
    assert sorted(p.name for p in out.iterdir()) == ['metrics.json', 'trajectory.png']


def test_eval_on_a_full_disk_keeps_complete_files_and_names_them(tmp_path):
    _tum_pair(tmp_path)
    out = tmp_path / 'disk' / 'eval'
    run = run_planar_vo(['eval', tmp_path / 'est.tum', '--gt', tmp_path / 'gt.tum', '--out-dir',
                         out], disk=tmp_path / 'disk', keep=tmp_path / 'kept', size_kib=48)
    assert run.returncode == 1, run.stderr
    line = run.stderr.rstrip('\n')
    assert '\n' not in line and line.startswith('planar_vo eval: error: ')
    assert "cannot write '" in line
    written = line.split(f"written to '{out}': ")[1].split(', ')
    kept = tmp_path / 'kept' / 'eval'
    assert sorted(written) == sorted(p.name for p in kept.iterdir())
    assert written[0] == 'metrics.json' and json.loads((kept / 'metrics.json').read_text())
    for name in written[1:]:                                   # complete PNGs
        assert (kept / name).read_bytes()[-8:] == b'IEND\xaeB`\x82'
    assert partial_leftovers(tmp_path / 'kept') == []


def test_bench_stopped_by_sigterm_stops_its_child_and_reports_once(tmp_path):
    """``bench paper`` re-runs itself single-threaded in a child; a supervisor's SIGTERM reaches
    the parent only, which passes it on and exits with the child's code."""
    with subprocess.Popen([sys.executable, '-m', 'planar_vo', 'bench', 'paper', '--quick',
                           '--out', str(tmp_path / 'bench')], stdout=subprocess.DEVNULL,
                          stderr=subprocess.PIPE, text=True) as proc:
        try:
            wait_for(lambda: any(catches_signal(c, signal.SIGTERM)
                                 for c in child_pids(proc.pid)), 120,
                     'the single-threaded child to handle SIGTERM', proc)
            (child,) = child_pids(proc.pid)
            proc.send_signal(signal.SIGTERM)
            _, err = proc.communicate(timeout=120)
        finally:
            if proc.poll() is None:
                proc.kill()
    assert proc.returncode == 143
    assert err.splitlines()[-1] == 'planar_vo bench paper: interrupted by SIGTERM'
    assert err.count('interrupted') == 1
    wait_for(lambda: not _alive(child), 10, 'the child to be gone')
    assert partial_leftovers(tmp_path) == []


def _alive(pid: int) -> bool:
    try:
        status = open(f'/proc/{pid}/status').read()
    except OSError:
        return False
    return '\nState:\tZ' not in status
