"""The ROS 2 package template's docstring check (ament_pep257, 'ament' convention)."""

from ament_pep257.main import main
import pytest
from support.data import REPO_ROOT


@pytest.mark.lint
@pytest.mark.pep257
def test_pep257(monkeypatch):
    monkeypatch.chdir(REPO_ROOT)
    rc = main(argv=['mvbb_ros', 'test', 'benchmarks', 'tools', 'launch', 'setup.py'])
    assert rc == 0, 'Found code style errors / warnings'
