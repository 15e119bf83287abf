"""Installation: what ``ros2 run planar_vo planar_vo_node`` and the ament index need is installed.

The prefix is the one the ament index gives (colcon: ``install/planar_vo``), or the Python
environment's prefix for a pip install into a venv (where ``AMENT_PREFIX_PATH`` is not set).
"""

from __future__ import annotations

import ast
import os
import re
import signal
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

import planar_vo

ROOT = Path(__file__).resolve().parents[1]


def _prefix() -> Path:
    if os.environ.get('AMENT_PREFIX_PATH'):
        from ament_index_python.packages import get_package_prefix

        return Path(get_package_prefix('planar_vo'))
    return Path(sys.prefix)


@pytest.fixture(scope='module')
def prefix() -> Path:
    prefix = _prefix()
    if not (prefix / 'share' / 'planar_vo').is_dir():
        pytest.fail(f'planar_vo is not installed into {prefix}: run `make test` (pip) or '
                    f'`colcon build` first')
    return prefix


def test_ament_index_marker_and_share(prefix):
    assert (prefix / 'share/ament_index/resource_index/packages/planar_vo').is_file()
    assert (prefix / 'share/planar_vo/package.xml').is_file()
    assert (prefix / 'share/planar_vo/config/planar_vo.yaml').is_file()
    assert (prefix / 'share/planar_vo/launch/planar_vo.launch.py').is_file()


@pytest.mark.parametrize('exe', ['planar_vo_node', 'planar_vo'])
def test_executables_in_lib_package_dir(prefix, exe):
    path = prefix / 'lib' / 'planar_vo' / exe
    assert path.is_file()
    assert os.access(path, os.X_OK)
    assert path.read_text().startswith('#!/usr/bin/env python3\n')


def test_package_xml_version_and_dependencies():
    root = ET.parse(ROOT / 'package.xml').getroot()
    assert root.get('format') == '3'
    assert root.findtext('version') == planar_vo.__version__
    assert root.findtext('license') == 'Apache-2.0'
    deps = {e.text for e in root if e.tag.endswith('depend')}
    assert {'rclpy', 'sensor_msgs', 'nav_msgs', 'geometry_msgs', 'std_msgs', 'python3-numpy',
            'python3-opencv', 'python3-pytest', 'python3-threadpoolctl'} <= deps
    # Every ROS package the node imports is declared.
    source = (ROOT / 'planar_vo/ros/node.py').read_text()
    imported = set(re.findall(r'^from (\w+)\.(?:msg|srv) import', source, re.M))
    assert imported == {'builtin_interfaces', 'diagnostic_msgs', 'geometry_msgs', 'nav_msgs',
                        'rcl_interfaces', 'sensor_msgs', 'std_msgs', 'std_srvs'}
    assert imported | {'rclpy'} <= deps
    assert root.find('export/build_type').text == 'ament_python'


def test_launch_file_uses_the_node_and_default_parameters():
    source = (ROOT / 'resource/launch/planar_vo.launch.py').read_text()
    tree = ast.parse(source)
    assert any(isinstance(n, ast.FunctionDef) and n.name == 'generate_launch_description'
               for n in tree.body)
    assert "executable='planar_vo_node'" in source and "'planar_vo.yaml'" in source
    for argument in ('params_file', 'namespace', 'use_sim_time', 'log_level'):
        assert f"DeclareLaunchArgument('{argument}'" in source, argument
    try:
        import launch_ros  # noqa: F401
    except ImportError:
        return  # launch is not on PyPI; a ROS install runs the full check below
    namespace: dict = {}
    exec(compile(source, 'planar_vo.launch.py', 'exec'), namespace)
    assert namespace['generate_launch_description']().entities


def test_installed_cli_runs(prefix, ros_env):
    proc = subprocess.run([str(prefix / 'lib/planar_vo/planar_vo'), '--version'], env=ros_env,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert planar_vo.__version__ in proc.stdout


@pytest.mark.ros
@pytest.mark.timeout(60)
def test_ros2_run_starts_node_logs_parameters_and_stops_on_sigint(prefix, ros_env):
    pytest.importorskip('rclpy')
    # What `ros2 run planar_vo planar_vo_node` does: execute <prefix>/lib/planar_vo/<exe>.
    exe = prefix / 'lib' / 'planar_vo' / 'planar_vo_node'
    proc = subprocess.Popen([str(exe), '--ros-args', '-p', 'voting.bins:=360'], env=ros_env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        seen = []
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                break
            seen.append(line)
            if re.search(r'voting\.bins = 360', line):
                break
        assert any('voting.bins = 360' in s for s in seen), ''.join(seen)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=20) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
