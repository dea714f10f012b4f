"""
The layers stay apart: arrows only downwards, no circle, ROS only in mvbb_ros/ros/.

The folders of mvbb_ros are layers (docs/architecture.md): common, geometry (itself four
subsystems over box.py), pipeline, evaluation, ros and the command-line tools (cli). These tests
read every module's imports with ast (the module graph) and import the modules in fresh
interpreters, so that a stray import of rclpy or a message package fails here rather than on a
robot without ROS; a module past 800 lines is reported as a warning.
"""

from __future__ import annotations

import ast
import functools
import json
from pathlib import Path
import subprocess
import sys
import warnings

import pytest
from support.data import REPO_ROOT

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


@pytest.mark.slow
def test_no_module_outside_ros_loads_rclpy_or_messages():
    report = _import_in_fresh_interpreter(OUTSIDE_ROS)
    loaded = {module: seen['ros'] for module, seen in report.items() if seen['ros']}
    first = next(iter(loaded), None)
    assert not loaded, f'{first} loaded {loaded[first]} (only mvbb_ros.ros may import ROS)'


@pytest.mark.slow
def test_the_geometry_loads_numpy_and_scipy_only():
    geometry = ['mvbb_ros', *[name for name in MODULES if name.startswith('mvbb_ros.geometry')]]
    report = _import_in_fresh_interpreter(geometry)
    for module, seen in report.items():
        assert not seen['ros'] and not seen['heavy'], f'{module} loaded {seen}'


@pytest.mark.slow
def test_the_mvbb_command_and_the_settings_load_no_heavy_layer():
    """`mvbb --help` and reading the settings do not wait for Open3D, matplotlib or rclpy."""
    report = _import_in_fresh_interpreter(['mvbb_ros.pipeline.settings', 'mvbb_ros.cli.main'])
    for module, seen in report.items():
        assert not seen['ros'] and not seen['heavy'], f'{module} loaded {seen}'


@pytest.mark.slow
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
    assert 'mvbb_ros.ros.node' in MODULES and 'mvbb_ros.geometry.boxfit.fit' in MODULES


#: Which layers each layer may import at module level (arrays and common are shared by all;
#: kernels, the cache warm-up, by the programs that start: the node and the command line; the
#: packages with kernels load kernel_cache and compile_time before any of their modules).
ALLOWED = {
    'common': {'common'},
    'geometry': {'arrays', 'common', 'compile_time', 'kernel_cache', 'geometry'},
    'pipeline': {'arrays', 'common', 'compile_time', 'kernel_cache', 'geometry', 'pipeline'},
    'evaluation': {'arrays', 'common', 'geometry', 'evaluation'},
    'ros': {'arrays', 'common', 'kernels', 'geometry', 'pipeline', 'ros'},
    'cli': {'arrays', 'common', 'kernels', 'geometry', 'pipeline', 'evaluation', 'cli'},
    'fleet': {'arrays', 'common', 'kernels', 'geometry', 'pipeline', 'ros', 'fleet'},
}

#: What a layer may import inside a function besides: the command line loads the ROS layer only
#: in the commands that need it (``mvbb bag``, ``mvbb demo``, ``mvbb fleet``), so ``mvbb --help``
#: loads no ROS and no Ray.
ALLOWED_INSIDE_FUNCTIONS = {'cli': {'ros', 'fleet'}}

#: The top-level modules of the package and what each may import (the package's __init__ names
#: the public names' modules only for type checkers and imports them on first use).
TOP_LEVEL = {
    'arrays': set(),
    'compile_time': set(),
    'kernel_cache': set(),
    'kernels': {'compile_time', 'kernel_cache'},
}

#: The geometry's subsystems, and which of them each may import: box.py is the type all of
#: them share; the box fit stands alone, the decomposition and the single views build on it,
#: and the grasps on the decomposition's boxes and the views' cells.
GEOMETRY = {
    'box': set(),
    'boxfit': {'box'},
    'decomposition': {'box', 'boxfit'},
    'views': {'box', 'boxfit'},
    'grasping': {'box', 'boxfit', 'decomposition', 'views'},
}

#: The top-level packages that belong to ROS: only mvbb_ros.ros may import them.
ROS_PACKAGES = (
    'rclpy',
    'rosbags',
    'builtin_interfaces',
    'rcl_interfaces',
    'rosidl_runtime_py',
    'rpyutils',
    'launch',
    'launch_ros',
)


def _is_ros_package(name: str) -> bool:
    top = name.split('.')[0]
    return top in ROS_PACKAGES or top.endswith('_msgs') or top.startswith('rosidl_')


def _resolve(name: str) -> str:
    """Return the package module `name` names: itself, or the package it is an attribute of."""
    return name if name in MODULES else name.rpartition('.')[0]


def _imports(path: Path) -> list[tuple[str, bool]]:
    """
    Return what the module at `path` imports at run time, and whether at module level.

    Every ``import`` and ``from ... import`` of the file, inside functions too; ``from a import
    b`` counts as importing ``a.b`` when that is a module. Imports under ``if TYPE_CHECKING:``
    run only for type checkers and are left out.
    """
    tree = ast.parse(path.read_text())
    skipped = {
        id(node)
        for top in tree.body
        if isinstance(top, ast.If) and 'TYPE_CHECKING' in ast.unparse(top.test)
        for node in ast.walk(top)
    }
    top_level = {id(node) for node in tree.body}
    found = []
    for node in ast.walk(tree):
        if id(node) in skipped:
            continue
        at_module_level = id(node) in top_level
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            for alias in node.names:
                full = f'{node.module}.{alias.name}'
                found.append((full if full in MODULES else node.module, at_module_level))
        elif isinstance(node, ast.Import):
            found += [(alias.name, at_module_level) for alias in node.names]
    return found


@functools.cache
def _package_graph(*, module_level_only: bool) -> dict[str, set[str]]:
    """Return the package's import graph: each module and the package modules it imports."""
    graph: dict[str, set[str]] = {}
    for path in sorted(PACKAGE.rglob('*.py')):
        name = _module_name(path)
        graph[name] = {
            _resolve(imported)
            for imported, at_module_level in _imports(path)
            if imported.startswith('mvbb_ros.') and (at_module_level or not module_level_only)
        } - {name}
    return graph


def _layer(module: str) -> str:
    """Return the layer (first folder, or top-level module name) of a package module."""
    return module.split('.')[1] if module != 'mvbb_ros' else ''


def _subsystem(module: str) -> str:
    """Return the geometry subsystem of a ``mvbb_ros.geometry.*`` module (box for box.py)."""
    parts = module.split('.')
    return parts[2] if len(parts) > 2 else ''


def test_the_import_graph_is_read_from_every_module():
    graph = _package_graph(module_level_only=False)
    assert set(graph) == set(MODULES)
    assert 'mvbb_ros.geometry.boxfit.hull' in graph['mvbb_ros.geometry.boxfit.fit']
    assert 'mvbb_ros.geometry.decomposition.split' in graph['mvbb_ros.geometry.decomposition.tree']
    assert 'mvbb_ros.ros.offline' in graph['mvbb_ros.cli.commands']  # inside a function


@pytest.mark.parametrize('layer', sorted(ALLOWED))
def test_layers_import_only_the_layers_below(layer):
    graph = _package_graph(module_level_only=False)
    module_level = _package_graph(module_level_only=True)
    for module in sorted(name for name in graph if _layer(name) == layer):
        for target in sorted(graph[module]):
            allowed = ALLOWED[layer]
            if target not in module_level[module]:
                allowed = allowed | ALLOWED_INSIDE_FUNCTIONS.get(layer, set())
            assert target == 'mvbb_ros' or _layer(target) in allowed, f'{module} imports {target}'


def test_top_level_modules_import_only_what_they_build_on():
    graph = _package_graph(module_level_only=False)
    for module, allowed in TOP_LEVEL.items():
        imported = {_layer(target) for target in graph[f'mvbb_ros.{module}']}
        assert imported <= allowed, f'mvbb_ros.{module} imports {imported - allowed}'


def test_geometry_subsystems_import_only_the_ones_they_build_on():
    graph = _package_graph(module_level_only=False)
    assert {_subsystem(name) for name in graph if _layer(name) == 'geometry'} - {''} == {*GEOMETRY}
    for module in sorted(name for name in graph if _layer(name) == 'geometry'):
        own = _subsystem(module)
        for target in sorted(graph[module]):
            other = _subsystem(target)
            if _layer(target) != 'geometry' or other in ('', own):
                continue
            assert other in GEOMETRY.get(own, set()), f'{module} imports {target}'


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Return the strongly connected components of `graph` with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for target in graph.get(node, ()):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def test_the_cycle_check_finds_a_cycle():
    assert _cycles({'a': {'b'}, 'b': {'c'}, 'c': {'a'}, 'd': {'a'}}) == [['a', 'b', 'c']]
    assert _cycles({'a': {'b'}, 'b': set()}) == []


def test_no_modules_import_each_other():
    """No circle between modules, counting imports inside functions too."""
    assert _cycles(_package_graph(module_level_only=False)) == []


def test_only_the_ros_layer_imports_ros_packages():
    """No file outside mvbb_ros/ros/ names rclpy, rosbags or a message package, not even lazily."""
    for path in sorted(PACKAGE.rglob('*.py')):
        module = _module_name(path)
        if _layer(module) == 'ros':
            continue
        ros = sorted({name for name, _ in _imports(path) if _is_ros_package(name)})
        assert not ros, f'{module} imports {ros}'


def test_long_modules_are_reported():
    """Modules are cut by concept; past 800 lines a module is worth a look (a warning only)."""
    long = {
        str(path.relative_to(REPO_ROOT)): count
        for path in PACKAGE.rglob('*.py')
        if (count := len(path.read_text().splitlines())) > MAX_LINES
    }
    if long:
        warnings.warn(f'modules longer than {MAX_LINES} lines: {long}', stacklevel=1)


def test_nothing_imports_the_fleet_at_module_level():
    """Only `mvbb fleet` loads the fleet (and Ray), inside the command."""
    for path in sorted(PACKAGE.rglob('*.py')):
        if path.parent.name != 'fleet':
            imports = [name for name, top_level in _imports(path) if top_level]
            assert not [name for name in imports if name.startswith('mvbb_ros.fleet')], path
