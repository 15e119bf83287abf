"""Running ``planar_vo`` on a small (full) or read-only disk, and watching a running command.

A real full disk: a tmpfs of a few KiB mounted on an empty folder inside a private mount
namespace (``unshare -m`` as root, ``unshare -rm`` as a user where user namespaces are allowed),
so nothing outside the command sees it; writes beyond its size fail with ENOSPC exactly as on a
full disk. The namespace (and the tmpfs) ends with the command, so what the command left on the
disk is copied out first. Where no namespace can be made, the size limit is a per-file limit
(RLIMIT_FSIZE with SIGXFSZ ignored: writes fail with EFBIG), and `DiskRun.method` says so.
"""

from __future__ import annotations

import functools
import os
import resource
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import pytest


@dataclass(frozen=True)
class DiskRun:
    """A finished command: exit code, output, and how the disk was limited."""

    returncode: int
    stdout: str
    stderr: str
    method: str        # 'tmpfs' (a real full disk) or 'RLIMIT_FSIZE'


@functools.cache
def namespace_prefix() -> tuple[str, ...] | None:
    """The ``unshare`` arguments under which a shell may mount a tmpfs here, or None."""
    if shutil.which('unshare') is None:
        return None
    with tempfile.TemporaryDirectory() as probe:
        for prefix in (('unshare', '-m'), ('unshare', '-rm')):
            proc = subprocess.run([*prefix, 'sh', '-c',
                                   f'mount -t tmpfs -o size=64k tmpfs {shlex.quote(probe)}'],
                                  capture_output=True, timeout=30, check=False)
            if proc.returncode == 0:
                return prefix
    return None


def run_planar_vo(args: Sequence[str], *, disk: Path, keep: Path, size_kib: int = 0,
                  read_only: bool = False, timeout: float = 300.0) -> DiskRun:
    """Run ``python -m planar_vo ARGS`` with the empty folder `disk` as a tmpfs of `size_kib`
    KiB (read-only if asked); what the command left on it is copied into `keep` afterwards."""
    disk.mkdir(parents=True, exist_ok=True)
    keep.mkdir(parents=True, exist_ok=True)
    command = [sys.executable, '-m', 'planar_vo', *map(str, args)]
    prefix = namespace_prefix()
    if prefix is not None:
        options = ','.join(['size=' + str(max(size_kib, 4)) + 'k'] + (['ro'] if read_only else []))
        script = (f'mount -t tmpfs -o {options} tmpfs {shlex.quote(str(disk))} || exit 99\n'
                  f'{shlex.join(command)}\nrc=$?\n'
                  f'cp -a {shlex.quote(str(disk))}/. {shlex.quote(str(keep))}/\nexit $rc\n')
        proc = subprocess.run([*prefix, 'sh', '-c', script], capture_output=True, text=True,
                              timeout=timeout, check=False)
        assert proc.returncode != 99, proc.stderr
        return DiskRun(proc.returncode, proc.stdout, proc.stderr, 'tmpfs')
    if read_only:
        if os.geteuid() == 0:
            pytest.skip('a read-only folder needs a mount namespace when running as root')
        disk.chmod(0o555)

    def limit() -> None:
        if size_kib:
            resource.setrlimit(resource.RLIMIT_FSIZE, (size_kib * 1024, size_kib * 1024))
            signal.signal(signal.SIGXFSZ, signal.SIG_IGN)

    try:
        proc = subprocess.run(command, capture_output=True, text=True, timeout=timeout,
                              check=False, preexec_fn=limit)
    finally:
        disk.chmod(0o755)
    shutil.copytree(disk, keep, dirs_exist_ok=True, symlinks=True)
    return DiskRun(proc.returncode, proc.stdout, proc.stderr, 'RLIMIT_FSIZE')


def partial_leftovers(folder: Path) -> list[Path]:
    """Temporary files or bag folders (``.NAME.*.partial*``) anywhere under `folder`."""
    return [p for p in folder.rglob('.*') if '.partial' in p.name]


def wait_for(condition: Callable[[], bool], timeout: float, what: str,
             proc: subprocess.Popen | None = None) -> None:
    """Poll `condition` every 20 ms until it holds; fail naming `what` after `timeout` seconds
    or when `proc` exits first."""
    deadline = time.monotonic() + timeout
    while not condition():
        if proc is not None and proc.poll() is not None:
            pytest.fail(f'the process exited ({proc.returncode}) before {what}')
        if time.monotonic() > deadline:
            pytest.fail(f'timed out after {timeout} s waiting for {what}')
        time.sleep(0.02)


def stop_after_odometry(args: Sequence[str], log: Path, frames: int, signum: int,
                        timeout: float = 180.0) -> int:
    """Run ``python -m planar_vo -vv ARGS`` (stderr into `log`), send `signum` once `frames`
    frames have odometry (replay logs each frame at debug level), return its exit code."""
    command = [sys.executable, '-m', 'planar_vo', '-vv', *map(str, args)]
    with open(log, 'w') as stderr, subprocess.Popen(command, stdout=subprocess.DEVNULL,
                                                    stderr=stderr) as proc:
        try:
            wait_for(lambda: log.read_text().count('): odometry') >= frames, timeout,
                     f'{frames} odometry frames', proc)
            proc.send_signal(signum)
            return proc.wait(timeout=timeout)
        finally:
            if proc.poll() is None:
                proc.kill()


def catches_signal(pid: int, signum: int) -> bool:
    """Whether process `pid` has a handler installed for `signum` (Linux: SigCgt)."""
    try:
        status = Path(f'/proc/{pid}/status').read_text()
    except OSError:
        return False
    caught = next((line.split()[1] for line in status.splitlines()
                   if line.startswith('SigCgt:')), '0')
    return bool(int(caught, 16) >> (signum - 1) & 1)


def child_pids(pid: int) -> list[int]:
    """Direct children of `pid` (Linux ``/proc/PID/task/*/children``)."""
    pids: list[int] = []
    for task in Path(f'/proc/{pid}/task').glob('*'):
        try:
            pids += [int(p) for p in (task / 'children').read_text().split()]
        except OSError:
            continue
    return pids
