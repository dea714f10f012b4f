"""The package builds with colcon into the layout `ros2 run` and `ros2 launch` expect."""

import os
from pathlib import Path
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ElementTree

from mvbb_ros.ros.messages import OUTPUT_TYPES
import pytest
from support.data import REPO_ROOT
import yaml

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
    assert {'launch', 'launch_ros'} <= exec_depends, 'launch/decomposer.launch.py'


def test_rosdep_keys_cover_the_pip_only_dependencies():
    """Rosbags (the bag tools) is a rosdep pip key like open3d, not a manual pip install."""
    text = (REPO_ROOT / 'package.xml').read_text()
    exec_depends = {
        element.text
        for element in ElementTree.parse(REPO_ROOT / 'package.xml').findall('exec_depend')
    }
    assert {'python3-open3d-pip', 'python3-rosbags-pip', 'python3-numba'} <= exec_depends
    assert 'no rosdep' not in text and 'pip install rosbags' not in text


def test_readme_recipe_for_ubuntu_24_04():
    """The robot section works under PEP 668: a venv colcon builds with, or the pip override."""
    readme = (REPO_ROOT / 'README.md').read_text()
    robot = readme.partition('## On a robot with ROS 2 Jazzy')[2].partition('\n## ')[0]
    assert 'python3 -m venv --system-site-packages' in robot
    assert 'COLCON_IGNORE' in robot and 'python -m colcon build' in robot
    assert '--skip-keys' in robot and 'PIP_BREAK_SYSTEM_PACKAGES=1' in robot
    assert 'ros2 run mvbb_ros mvbb ' in robot
    assert 'ros2 launch mvbb_ros decomposer.launch.py' in robot
    assert '\npip install rosbags' not in robot, 'refused by pip on Ubuntu 24.04 (PEP 668)'


def test_rviz_config_matches_the_readme():
    """Fixed Frame the README names, the cloud on the topic it remaps, latched outputs."""
    config = yaml.safe_load((REPO_ROOT / 'config' / 'mvbb.rviz').read_text())
    manager = config['Visualization Manager']
    fixed_frame = manager['Global Options']['Fixed Frame']
    topics = {
        display['Topic']['Value']: display['Topic']
        for display in manager['Displays']
        if 'Topic' in display
    }
    readme = (REPO_ROOT / 'README.md').read_text()
    assert 'Fixed Frame' in readme and f'`{fixed_frame}`' in readme
    clouds = [topic for topic in topics if not topic.startswith('/decomposer/')]
    assert len(clouds) == 1 and f'cloud_in:={clouds[0]}' in readme
    assert topics[clouds[0]]['Reliability Policy'] == 'Reliable', 'best effort loses big clouds'
    outputs = {topic for topic in topics if topic.startswith('/decomposer/')}
    assert outputs == {f'/decomposer/{suffix}' for suffix in OUTPUT_TYPES} - {
        '/decomposer/box_list'
    }
    for topic in outputs:
        assert topics[topic]['Durability Policy'] == 'Transient Local', topic
        assert topics[topic]['Reliability Policy'] == 'Reliable', topic


@pytest.mark.slow
def test_colcon_install_layout(colcon_install: Path):
    prefix = colcon_install / 'mvbb_ros'
    for executable in ('decomposer', 'mvbb'):
        path = prefix / 'lib' / 'mvbb_ros' / executable
        assert path.is_file(), f'{path} missing: ros2 run would not find it'
        assert os.access(path, os.X_OK), f'{path} is not executable'
    assert (prefix / 'share' / 'mvbb_ros' / 'package.xml').is_file()
    assert (prefix / 'share' / 'mvbb_ros' / 'LICENSE').is_file()
    assert (
        prefix / 'share' / 'ament_index' / 'resource_index' / 'packages' / 'mvbb_ros'
    ).is_file()
    assert (prefix / 'share' / 'mvbb_ros' / 'config' / 'decomposer.yaml').is_file()
    assert (prefix / 'share' / 'mvbb_ros' / 'config' / 'mvbb.rviz').is_file()
    assert (prefix / 'share' / 'mvbb_ros' / 'config' / 'fastdds_large_clouds.xml').is_file()
    assert (prefix / 'share' / 'mvbb_ros' / 'launch' / 'decomposer.launch.py').is_file()
    # Built with a venv's colcon (the README's Ubuntu 24.04 recipe), the executables run with
    # that venv's Python, so `ros2 run` finds the pip-installed open3d and rosbags.
    for executable in ('decomposer', 'mvbb'):
        shebang = (prefix / 'lib' / 'mvbb_ros' / executable).read_text().splitlines()[0]
        assert shebang.startswith('#!') and Path(shebang[2:]).parent == VENV_BIN, shebang


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
