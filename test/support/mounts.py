"""A folder made read-only for one command: a bind mount as root, file modes otherwise."""

from __future__ import annotations

import os
from pathlib import Path
import shutil
import stat
import subprocess

import pytest


def read_only_command(folder: Path) -> list[str]:
    """Return a command prefix under which `folder` is read-only (or make it so)."""
    if os.geteuid() != 0:
        for path in [folder, *folder.rglob('*')]:
            path.chmod(path.stat().st_mode & ~(stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH))
        return []
    if shutil.which('unshare') is None:
        pytest.skip('running as root without unshare: cannot make a read-only package')
    if subprocess.run(['unshare', '-m', 'true'], capture_output=True, check=False).returncode:
        pytest.skip('running as root without the right to make a mount namespace (unshare -m)')
    mount = f'mount --bind {folder} {folder} && mount -o remount,ro,bind {folder} {folder}'
    return ['unshare', '-m', 'sh', '-c', f'{mount} && exec "$0" "$@"']
