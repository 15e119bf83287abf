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
    assert err == 'planar_vo demo: error: trials: expected at least 1, got 0'


def test_unknown_command_is_a_usage_error():
    with pytest.raises(SystemExit) as exc:
        main(['fly'])
    assert exc.value.code == 2


def test_python_dash_m_entry_point():
    proc = subprocess.run([sys.executable, '-m', 'planar_vo', '--version'],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0 and __version__ in proc.stdout
