"""The project's ruff configuration (ruff.toml) holds for the whole tree."""

import subprocess
import sys

from conftest import REPO_ROOT


def _ruff(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, '-m', 'ruff', *args],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        check=False,
    )


def test_ruff_check_is_clean():
    result = _ruff('check', '--no-cache', '.')
    assert result.returncode == 0, result.stdout + result.stderr


def test_ruff_format_is_clean():
    result = _ruff('format', '--check', '--no-cache', '.')
    assert result.returncode == 0, result.stdout + result.stderr
