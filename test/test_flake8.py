"""The ROS 2 package template's flake8 check (ament_flake8 with its default configuration)."""

from ament_flake8.main import main_with_errors
import pytest
from support.data import REPO_ROOT

CHECKED = ['mvbb_ros', 'test', 'benchmarks', 'tools', 'launch', 'setup.py']


@pytest.mark.flake8
@pytest.mark.lint
def test_flake8(monkeypatch):
    monkeypatch.chdir(REPO_ROOT)
    rc, errors = main_with_errors(argv=CHECKED)
    assert rc == 0, f'Found {len(errors)} code style errors / warnings:\n' + '\n'.join(errors)
