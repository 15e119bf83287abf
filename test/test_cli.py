"""The planar_vo command: help, version, demo, and one-line errors with exit code 1."""

from __future__ import annotations

import subprocess
import sys

import pytest

from planar_vo import __version__
from planar_vo.cli import main


def test_version(capsys):
    with pytest.raises(SystemExit) as exc:
        main(['--version'])
    assert exc.value.code == 0
    assert __version__ in capsys.readouterr().out


def test_help_lists_examples(capsys):
    with pytest.raises(SystemExit):
        main(['--help'])
    out = capsys.readouterr().out
    assert 'examples:' in out and 'demo' in out


def test_demo_solvers_prints_accuracy_table(capsys):
    assert main(['demo', '--solvers', '--trials', '5', '--sigmas', '0', '1']) == 0
    out = capsys.readouterr().out
    lines = [line for line in out.splitlines() if line.startswith('| 0.00 | 1AC |')]
    assert len(lines) == 1
    alpha_median = float(lines[0].split('|')[3])
    assert alpha_median < 1e-9                      # noise-free: exact


def test_known_error_is_one_line_and_exit_1(capsys):
    assert main(['demo', '--solvers', '--trials', '0']) == 1
    err = capsys.readouterr().err.strip()
    assert err == 'planar_vo demo: error: --trials: expected at least 1, got 0'


@pytest.mark.parametrize(('argv', 'message'), [
    (['fly'], "planar_vo: error: argument COMMAND: invalid choice: 'fly'"),
    ([], 'planar_vo: error: the following arguments are required: COMMAND'),
    (['replay', 'in_bag'], 'planar_vo replay: error: the following arguments are required: '
                           '--out (see planar_vo replay --help)'),
    (['demo', '--frames', 'x'], "planar_vo demo: error: argument --frames: invalid int value: "
                                "'x' (see planar_vo demo --help)"),
    # An unknown option after a subcommand points to that subcommand's help.
    (['replay', 'bag', '--out', 'x', '--bogus'],
     'planar_vo replay: error: unrecognized arguments: --bogus (see planar_vo replay --help)'),
    (['bench', 'speed', '--bogus'], 'planar_vo bench speed: error: unrecognized arguments: '
                                    '--bogus (see planar_vo bench speed --help)'),
    (['fleet', 'run', '--out', 'x', '--bogus'],
     'planar_vo fleet run: error: unrecognized arguments: --bogus (see planar_vo fleet run '
     '--help)'),
    (['--bogus', 'replay', 'bag', '--out', 'x'],
     'planar_vo: error: unrecognized arguments: --bogus (see planar_vo --help)'),
    # An option of planar_vo itself after the subcommand points to planar_vo --help, where it
    # is listed (the subcommand's help does not list it).
    (['replay', 'bag', '--out', 'x', '-v'],
     'planar_vo replay: error: unrecognized arguments: -v (an option of planar_vo itself goes '
     'before the command: see planar_vo --help)'),
    (['bench', 'speed', '-vv'],
     'planar_vo bench speed: error: unrecognized arguments: -vv (an option of planar_vo itself '
     'goes before the command: see planar_vo --help)'),
])
def test_usage_error_is_one_line_and_exit_1(capsys, argv, message):
    """Usage errors end like every other error: one line on stderr, exit code 1 (not
    argparse's usage block and exit code 2)."""
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 1
    captured = capsys.readouterr()
    assert captured.err.count('\n') == 1 and captured.err.startswith(message), captured.err
    assert captured.out == ''


def test_a_path_the_system_refuses_is_one_line_and_exit_1(capsys, tmp_path):
    """A file name too long for the file system raises OSError in the path checks themselves
    (Path.exists): one line and exit code 1, not a traceback."""
    long_name = str(tmp_path / ('x' * 300))
    for argv in (['replay', long_name, '--out', str(tmp_path / 'out')],
                 ['eval', long_name]):
        assert main(argv) == 1, argv
        err = capsys.readouterr().err
        assert err.count('\n') == 1 and 'File name too long' in err, err


@pytest.mark.parametrize('signum, code', [('SIGINT', 130), ('SIGTERM', 143)])
def test_a_stop_while_the_command_starts_is_one_line(capsys, monkeypatch, signum, code):
    """A user test: Ctrl-C while the commands are imported (a fraction of a second) printed a
    KeyboardInterrupt traceback. The handlers before the command are back afterwards."""
    import signal

    import planar_vo.cli as cli

    build = cli.build_parser
    went_on = []

    def stopped_while_importing():
        # Noted, not raised inside the imports (raised there, numpy's import turned it into
        # its own ImportError: exit 1), and the command stops once they are done.
        signal.raise_signal(signal.Signals[signum])
        went_on.append(True)
        return build()

    monkeypatch.setattr(cli, 'build_parser', stopped_while_importing)
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    assert main(['replay', 'in', '--out', 'out']) == code
    assert capsys.readouterr().err == f'planar_vo replay: interrupted by {signum}\n'
    assert went_on == [True]
    assert main(['-v', 'bench', 'paper']) == code
    assert capsys.readouterr().err == f'planar_vo: interrupted by {signum}\n'
    assert {s: signal.getsignal(s) for s in before} == before


def test_eval_into_a_closed_pipe_writes_its_files_and_exits_0(tmp_path):
    """A user test: `eval --out-dir D | head -1` said 'error: Broken pipe' (exit 1) and D was
    never written: the table came first."""
    lines = [f'{t:.1f} {0.5 * t} 0 0 0 0 0 1' for t in range(20)]
    for name in ('est.tum', 'gt.tum'):
        (tmp_path / name).write_text('\n'.join(lines) + '\n')
    proc = subprocess.Popen([sys.executable, '-m', 'planar_vo', 'eval', str(tmp_path / 'est.tum'),
                             '--gt', str(tmp_path / 'gt.tum'), '--out-dir', str(tmp_path / 'd')],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    proc.stdout.close()                       # the reader is gone before the first line
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 0 and 'Broken pipe' not in err, err
    assert (tmp_path / 'd' / 'metrics.json').stat().st_size > 0


def test_python_dash_m_entry_point():
    proc = subprocess.run([sys.executable, '-m', 'planar_vo', '--version'],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0 and __version__ in proc.stdout


def test_every_help_page_prints(capsys):
    """Help strings are %-formatted by argparse: a bare '%' in one broke `bench --help`."""
    from planar_vo.cli.bench import BENCHES

    for argv in (['bench', '--help'], *(['bench', name, '--help'] for name in BENCHES),
                 *([name, '--help'] for name in ('demo', 'replay', 'eval', 'import-kitti',
                                                 'import-video'))):
        with pytest.raises(SystemExit) as exc:
            main(argv)
        assert exc.value.code == 0, argv
    assert 'flat within 5 percent' in capsys.readouterr().out


@pytest.mark.parametrize(('argv', 'message'), [
    (['demo', '--seed', '-1', '--frames', '3'],
     'planar_vo demo: error: --seed: expected an integer in [0, 2^32), got -1'),
    (['bench', 'paper', '--quick', '--seed', '-1'],
     'planar_vo bench paper: error: --seed: expected an integer of at least 0, got -1'),
    (['bench', 'paper', '--quick', '--jobs', '0'],
     'planar_vo bench paper: error: --jobs: expected an integer of at least 1, got 0'),
    (['bench', 'paper', '--runs', '0'],
     'planar_vo bench paper: error: --runs: expected an integer of at least 1, got 0'),
    (['bench', 'paper', '--samples', '-2'],
     'planar_vo bench paper: error: --samples: expected an integer of at least 1, got -2'),
    (['bench', 'frontend', '--asift-pairs', '-1'],
     'planar_vo bench frontend: error: --asift-pairs: expected an integer of at least 0, got -1'),
    (['demo', '--frames', '100000'],
     'planar_vo demo: error: --frames: expected at most 392 (the demo drive), got 100000'),
    (['demo', '--solvers', '--sigmas', 'inf'],
     'planar_vo demo: error: --sigmas: expected finite non-negative noise levels, got [inf]'),
    (['demo', '--out', ''],
     'planar_vo demo: error: --out: an empty path; expected the folder to write the demo to'),
    (['demo', '--out', '.', '--force'],
     "planar_vo demo: error: --out: '.' is the current folder, one above it or the home folder; "
     'the demo replaces its folder, so choose another --out'),
    (['demo', '--out', '..', '--force'],
     "planar_vo demo: error: --out: '..' is the current folder, one above it or the home folder; "
     'the demo replaces its folder, so choose another --out'),
    (['replay', 'planar_vo_demo', '--out', ''],
     'planar_vo replay: error: --out: an empty path; expected the folder to write the bag to'),
    (['eval', 'planar_vo_demo/odometry.tum', '--gt', 'x.tum', '--out-dir', ' '],
     'planar_vo eval: error: --out-dir: an empty path; expected the folder for the report'),
    (['bench', 'pipeline', '--out', ''],
     'planar_vo bench pipeline: error: --out: an empty path; expected the folder for the report'),
    (['bench', 'pipeline', '--frames', '9'],
     'planar_vo bench pipeline: error: --frames: expected at least 10, got 9'),
    (['bench', 'pipeline', '--kitti', 'nowhere'],
     "planar_vo bench pipeline: error: --kitti: 'nowhere' is not a KITTI sequence folder "
     "(no calib.txt)"),
    (['bench', 'frontend', '--kitti', 'nowhere'],
     "planar_vo bench frontend: error: --kitti: 'nowhere' is not a KITTI excerpt folder "
     "(no poses.txt)"),
    (['bench', 'fleet', '--bags', '1'],
     'planar_vo bench fleet: error: --bags, --frames, --repeat: expected at least 2, 10 and 1, '
     'got 1, 100, 2'),
    (['bench', 'speed', '--repeats', '0', '--sizes', '9'],
     'planar_vo bench speed: error: --repeats, --sizes: expected at least 1 and sizes of at '
     'least 10, got 0, [9]'),
])
def test_bad_options_are_refused_before_any_work(tmp_path, monkeypatch, capsys, argv, message):
    """One line and exit code 1, and nothing touched: a previous demo folder survives a bad
    seed, a benchmark's output folder is checked before minutes of work."""
    monkeypatch.chdir(tmp_path)
    demo = tmp_path / 'planar_vo_demo'
    demo.mkdir()
    (demo / 'odometry.tum').write_text('kept\n')
    assert main(argv) == 1
    assert capsys.readouterr().err.strip() == message
    assert (demo / 'odometry.tum').read_text() == 'kept\n'


def test_bench_output_folder_is_checked_first(tmp_path, capsys):
    (tmp_path / 'file').write_text('')
    assert main(['bench', 'paper', '--quick', '--out', str(tmp_path / 'file')]) == 1
    assert capsys.readouterr().err.strip() == (f"planar_vo bench paper: error: --out: "
                                               f"'{tmp_path / 'file'}' exists and is not a folder")
    assert main(['bench', 'fleet', '--work', str(tmp_path / 'file'),
                 '--out', str(tmp_path / 'o')]) == 1
    assert "--work: '" in capsys.readouterr().err
