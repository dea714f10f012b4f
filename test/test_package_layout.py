"""The package builds with colcon into the layout `ros2 run` and `ros2 launch` expect."""

import os
from pathlib import Path
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ElementTree

from conftest import REPO_ROOT
import pytest

VENV_BIN = Path(sys.executable).parent


def _tracked_files() -> list[str]:
    """List the files of the working tree that git would commit (tracked or not ignored)."""
    listing = subprocess.run(
        ['git', 'ls-files', '-co', '--exclude-standard'],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        check=True,
    )
    return [line for line in listing.stdout.splitlines() if (REPO_ROOT / line).is_file()]


@pytest.fixture(scope='module')
def colcon_install(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Copy the package into a fresh workspace, `colcon build` it, return the install space."""
    if shutil.which('git') is None:
        pytest.skip('git is needed to list the package files')
    workspace = tmp_path_factory.mktemp('ws')
    source = workspace / 'src' / 'mvbb_ros'
    for relative in _tracked_files():
        target = source / relative
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(REPO_ROOT / relative, target)
    result = subprocess.run(
        [
            str(VENV_BIN / 'colcon'),
            '--log-base',
            'log',
            'build',
            '--base-paths',
            'src',
            '--build-base',
            'build',
            '--install-base',
            'install',
        ],
        cwd=workspace,
        capture_output=True,
        text=True,
        check=False,
        timeout=300,
    )
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-4000:]
    return workspace / 'install'


def test_package_xml_is_format_3_ament_python():
    root = ElementTree.parse(REPO_ROOT / 'package.xml').getroot()
    assert root.get('format') == '3'
    assert root.findtext('name') == 'mvbb_ros'
    assert root.findtext('export/build_type') == 'ament_python'
    exec_depends = {element.text for element in root.findall('exec_depend')}
    assert {'rclpy', 'sensor_msgs', 'visualization_msgs', 'geometry_msgs'} <= exec_depends


@pytest.mark.slow
def test_colcon_install_layout(colcon_install: Path):
    prefix = colcon_install / 'mvbb_ros'
    for executable in ('decomposer', 'mvbb'):
        path = prefix / 'lib' / 'mvbb_ros' / executable
        assert path.is_file(), f'{path} missing: ros2 run would not find it'
        assert os.access(path, os.X_OK), f'{path} is not executable'
    assert (prefix / 'share' / 'mvbb_ros' / 'package.xml').is_file()
    assert (
        prefix / 'share' / 'ament_index' / 'resource_index' / 'packages' / 'mvbb_ros'
    ).is_file()
    assert (prefix / 'share' / 'mvbb_ros' / 'config' / 'decomposer.yaml').is_file()


@pytest.mark.slow
def test_installed_mvbb_help_runs(colcon_install: Path):
    """Source the install space as a user would, find the package like `ros2 run` does."""
    script = (
        '. install/setup.sh && '
        'prefix=$(python -c "from ament_index_python.packages import get_package_prefix; '
        "print(get_package_prefix('mvbb_ros'))\") && "
        '"$prefix/lib/mvbb_ros/mvbb" --help'
    )
    env = dict(os.environ, PATH=f'{VENV_BIN}{os.pathsep}{os.environ.get("PATH", "")}')
    result = subprocess.run(
        ['bash', '-c', script],
        cwd=colcon_install.parent,
        capture_output=True,
        text=True,
        check=False,
        env=env,
        timeout=120,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    assert 'decompose' in result.stdout
