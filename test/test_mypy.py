"""The package type-checks with mypy (mypy.ini): all layers, geometry and pipeline included."""

import subprocess
import sys

from conftest import REPO_ROOT
import pytest

#: The layers mypy checks: all of the package (the issue asked for geometry and pipeline at least).
CHECKED = ['mvbb_ros']


@pytest.mark.linter
def test_mypy_is_clean():
    result = subprocess.run(
        [sys.executable, '-m', 'mypy', *CHECKED],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        check=False,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    assert 'Success: no issues found' in result.stdout
