"""
The layers stay apart: only mvbb_ros/ros/ loads ROS, the geometry only numpy and scipy.

The folders of mvbb_ros are layers (docs/architecture.md): geometry, pipeline, evaluation, ros
and the command-line tools (cli). These tests import the modules in fresh interpreters and read
their imports, so that a stray import of rclpy or a message package fails here rather than on a
robot without ROS, and no module grows past 800 lines.
"""

from __future__ import annotations

import ast
import json
from pathlib import Path
import subprocess
import sys

from conftest import REPO_ROOT
import pytest

PACKAGE = REPO_ROOT / 'mvbb_ros'
MAX_LINES = 800


def _module_name(path: Path) -> str:
    parts = path.relative_to(REPO_ROOT).with_suffix('').parts
    return '.'.join(parts[:-1] if parts[-1] == '__init__' else parts)


MODULES = sorted(_module_name(path) for path in PACKAGE.rglob('*.py'))
#: The fleet (mvbb_ros/fleet) sits above ros/ and may load it; every other layer must not.
ABOVE_ROS = ('mvbb_ros.ros', 'mvbb_ros.fleet')
OUTSIDE_ROS = [name for name in MODULES if not name.startswith(ABOVE_ROS)]

#: Loaded after importing each module in turn; the ROS packages must not appear outside ros/.
_PROBE = """
import importlib, json, sys

def ros_side(name):
    top = name.split('.')[0]
    return top.endswith('_msgs') or top in ('rclpy', 'rosbags', 'builtin_interfaces',
        'rcl_interfaces', 'rosidl_runtime_py', 'rpyutils') or top.startswith('rosidl_')

def heavy(name):
    return name.split('.')[0] in ('open3d', 'matplotlib')

def compiled(name):
    return name.split('.')[0] == 'numba' or name.startswith('mvbb_ros.geometry')

report = {}
for module in sys.argv[1:]:
    importlib.import_module(module)
    report[module] = {
        'ros': sorted({m.split('.')[0] for m in sys.modules if ros_side(m)}),
        'heavy': sorted({m.split('.')[0] for m in sys.modules if heavy(m)}),
        'compiled': sorted({m for m in sys.modules if compiled(m)}),
    }
print(json.dumps(report))
"""


def _import_in_fresh_interpreter(modules: list[str]) -> dict[str, dict[str, list[str]]]:
    """Import `modules` in order in a new Python; return what was loaded after each one."""
    result = subprocess.run(
        [sys.executable, '-c', _PROBE, *modules],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        check=False,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout.strip().splitlines()[-1])


def test_no_module_outside_ros_loads_rclpy_or_messages():
    report = _import_in_fresh_interpreter(OUTSIDE_ROS)
    loaded = {module: seen['ros'] for module, seen in report.items() if seen['ros']}
    first = next(iter(loaded), None)
    assert not loaded, f'{first} loaded {loaded[first]} (only mvbb_ros.ros may import ROS)'


def test_the_geometry_loads_numpy_and_scipy_only():
    geometry = ['mvbb_ros', *[name for name in MODULES if name.startswith('mvbb_ros.geometry')]]
    report = _import_in_fresh_interpreter(geometry)
    for module, seen in report.items():
        assert not seen['ros'] and not seen['heavy'], f'{module} loaded {seen}'


def test_the_mvbb_command_and_the_settings_load_no_heavy_layer():
    """`mvbb --help` and reading the settings do not wait for Open3D, matplotlib or rclpy."""
    report = _import_in_fresh_interpreter(['mvbb_ros.pipeline.settings', 'mvbb_ros.cli.main'])
    for module, seen in report.items():
        assert not seen['ros'] and not seen['heavy'], f'{module} loaded {seen}'


def test_the_node_and_the_pipeline_load_no_heavy_layer():
    """Importing Open3D alone takes about 2 s: the node's start (3 s at most) must not pay it."""
    report = _import_in_fresh_interpreter(['mvbb_ros.pipeline.process', 'mvbb_ros.ros.node'])
    for module, seen in report.items():
        assert not seen['heavy'], f'{module} loaded {seen["heavy"]}'


def test_the_package_and_the_node_executable_load_no_kernels():
    """
    ``import mvbb_ros`` and the ``decomposer`` executable's module load no numba, no geometry.

    The package loads its names on first use, and the executable joins the ROS graph before the
    geometry loads (``mvbb_ros/ros/decomposer.py``).
    """
    report = _import_in_fresh_interpreter(['mvbb_ros', 'mvbb_ros.ros.decomposer'])
    for module, seen in report.items():
        assert not seen['compiled'] and not seen['heavy'], f'{module} loaded {seen}'


def test_every_module_is_imported_by_the_layer_test():
    assert set(MODULES) - set(OUTSIDE_ROS) == {
        name
        for name in MODULES
        if name.split('.')[:2] in (['mvbb_ros', 'ros'], ['mvbb_ros', 'fleet'])
    }
    assert 'mvbb_ros.ros.node' in MODULES and 'mvbb_ros.geometry.fit' in MODULES


#: Which layers each layer may import at module level (arrays and common are shared by all;
#: kernels, the cache warm-up, by the programs that start: the node and the command line).
ALLOWED = {
    'common': {'common'},
    'geometry': {'arrays', 'common', 'geometry'},
    'pipeline': {'arrays', 'common', 'geometry', 'pipeline'},
    'evaluation': {'arrays', 'common', 'geometry', 'evaluation'},
    'ros': {'arrays', 'common', 'kernels', 'geometry', 'pipeline', 'ros'},
    'cli': {'arrays', 'common', 'kernels', 'geometry', 'pipeline', 'evaluation', 'cli'},
    'fleet': {'arrays', 'common', 'geometry', 'pipeline', 'ros', 'fleet'},
}


def test_nothing_imports_the_fleet_at_module_level():
    """Only `mvbb fleet` loads the fleet (and Ray), inside the command."""
    for path in sorted(PACKAGE.rglob('*.py')):
        if path.parent.name != 'fleet':
            imports = _module_level_imports(path)
            assert not [name for name in imports if name.startswith('mvbb_ros.fleet')], path


def _module_level_imports(path: Path) -> list[str]:
    """Return the mvbb_ros modules imported at module level (not inside functions)."""
    tree = ast.parse(path.read_text())
    names = []
    for node in tree.body:
        if isinstance(node, ast.If):  # `if TYPE_CHECKING:` blocks import nothing at run time
            continue
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith('mvbb_ros'):
            names.append(node.module)
        elif isinstance(node, ast.Import):
            names += [alias.name for alias in node.names if alias.name.startswith('mvbb_ros')]
    return names


@pytest.mark.parametrize('layer', sorted(ALLOWED))
def test_layers_import_only_the_layers_below(layer):
    for path in sorted((PACKAGE / layer).glob('*.py')):
        for module in _module_level_imports(path):
            target = module.removeprefix('mvbb_ros').lstrip('.')
            allowed = ALLOWED[layer]
            assert (
                target == ''
                or target.split('.')[0] in allowed
                or any(target == name or target.startswith(name + '.') for name in allowed)
            ), f'{path.relative_to(REPO_ROOT)} imports {module}'


def test_no_module_is_longer_than_800_lines():
    long = {
        str(path.relative_to(REPO_ROOT)): count
        for path in PACKAGE.rglob('*.py')
        if (count := len(path.read_text().splitlines())) > MAX_LINES
    }
    assert not long, f'split these by idea: {long}'
