"""evo (GPL) as a command-line tool for cross-checks: never imported, run from the venv's bin."""

from __future__ import annotations

import json
import subprocess
import sys
import zipfile
from pathlib import Path

EVO_BIN = Path(sys.executable).parent


def run_evo(env: dict[str, str], tool: str, *args: str, cwd: Path) -> str:
    """Run an evo tool (``evo_ape``, ``evo_traj``...), assert success, return its stdout."""
    proc = subprocess.run([str(EVO_BIN / tool), *args], capture_output=True, text=True,
                          timeout=120, env=env, cwd=cwd)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return proc.stdout


def evo_ape_stats(env: dict[str, str], tmp_path: Path, *args: str) -> dict:
    """``evo_ape ARGS`` statistics (rmse, mean, median, std, min, max) via --save_results."""
    out = tmp_path / f'evo_{len(list(tmp_path.glob("evo_*.zip")))}.zip'
    run_evo(env, 'evo_ape', *args, '--save_results', str(out), '--no_warnings', cwd=tmp_path)
    with zipfile.ZipFile(out) as z:
        return json.loads(z.read('stats.json'))
