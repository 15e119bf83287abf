"""End to end: a rendered drive recorded as a bag (both storages), replayed, evaluated, and read
by evo."""

from __future__ import annotations

import json

import numpy as np
import pytest
from evo_tools import evo_ape_stats, run_evo

from planar_vo.cli import main
from planar_vo.config import MountConfig
from planar_vo.core.camera import CameraModel
from planar_vo.io import open_bag
from planar_vo.sim import straight, turn
from planar_vo.tools.demo import run_demo
from planar_vo.tools.evaluation import load_trajectory, read_tum
from planar_vo.tools.record import record_drive

CAMERA = CameraModel.pinhole(640, 480, 500.0)


@pytest.fixture(scope='module')
def drive_bags(tmp_path_factory):
    """The same short drive (straight, then a left turn) as an MCAP and a sqlite3 bag."""
    trajectory = straight(10.0, speed=8.0).then(turn(np.pi / 4, radius=15.0, speed=6.0))
    root = tmp_path_factory.mktemp('drives')
    bags = {storage: record_drive(root / storage, trajectory, camera=CAMERA,
                                  mount=MountConfig(height=1.5), seed=4, storage=storage).path
            for storage in ('mcap', 'sqlite3')}
    return trajectory, bags


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_replay_evaluate_and_evo(tmp_path, capsys, drive_bags, evo_env, storage):
    trajectory, bags = drive_bags
    out, tum, report = tmp_path / 'vo', tmp_path / 'vo.tum', tmp_path / 'eval'
    assert main(['replay', str(bags[storage]), '--out', str(out), '--tum', str(tum),
                 '--storage', storage, '--no-progress']) == 0
    text = capsys.readouterr().out
    frames = len(trajectory)
    assert f'frames in          {frames}' in text
    assert f'odometry out       {frames - 1}' in text and 'first_frame 1' in text
    # Every odometry message carries its image's header stamp, exactly.
    with open_bag(out) as bag:
        topics = set(bag.topics)
    assert {'/odom', '/ground_truth/odom'} <= topics
    est = load_trajectory(out, '/odom')
    gt = load_trajectory(out, '/ground_truth/odom')
    np.testing.assert_array_equal(est.stamps_ns, gt.stamps_ns[1:])
    np.testing.assert_array_equal(read_tum(tum).stamps_ns, est.stamps_ns)
    # Evaluation: accurate, and a left turn is positive yaw.
    assert main(['eval', str(out), '--out-dir', str(report)]) == 0
    metrics = json.loads((report / 'metrics.json').read_text())
    distance = metrics['path_length_m']
    assert metrics['ate_m']['rmse'] < 0.005 * distance
    assert metrics['yaw_change_error_deg']['rmse'] < 0.05
    assert all((report / f'{name}.png').stat().st_size > 10_000
               for name in ('trajectory', 'ate', 'yaw_heading'))
    yaw = 2 * np.arctan2(est.quaternions[-1, 2], est.quaternions[-1, 3])
    assert np.rad2deg(yaw) == pytest.approx(45.0, abs=0.5)
    # evo reads the odometry bag we wrote and agrees on the ATE.
    listing = run_evo(evo_env, 'evo_traj', 'bag2', str(out), '--all_topics', cwd=tmp_path)
    assert '/odom' in listing and '/ground_truth/odom' in listing
    evo = evo_ape_stats(evo_env, tmp_path, 'bag2', str(out), '/ground_truth/odom', '/odom', '-a')
    assert evo['rmse'] == pytest.approx(metrics['ate_m']['rmse'], abs=1e-6)


def test_replay_refuses_to_overwrite_and_reports_bad_input(tmp_path, capsys, drive_bags):
    _, bags = drive_bags
    (tmp_path / 'exists').mkdir()
    assert main(['replay', str(bags['mcap']), '--out', str(tmp_path / 'exists')]) == 1
    assert 'exists' in capsys.readouterr().err
    assert main(['replay', str(tmp_path / 'missing'), '--out', str(tmp_path / 'o')]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith('planar_vo replay: error:') and '\n' not in err


def test_demo_writes_everything(tmp_path):
    result = run_demo(tmp_path / 'demo', frames=25, progress=False, log=lambda *_: None)
    for name in ('drive', 'odometry', 'tum', 'metrics', 'trajectory', 'ate', 'yaw_heading'):
        assert result.files[name].exists(), name
    assert result.frames == 25
    assert result.metrics['ate_m']['rmse'] < 0.01 * result.distance
    # A second run replaces its own folder, but never a folder it did not write.
    run_demo(tmp_path / 'demo', frames=5, progress=False, log=lambda *_: None)
    other = tmp_path / 'mine'
    other.mkdir()
    with pytest.raises(Exception, match=r"'.*mine' exists and is not a demo folder"):
        run_demo(other, frames=5, progress=False, log=lambda *_: None)
