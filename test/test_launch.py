"""
The launch file (issue 18, item 10): it parses, and builds where the launch packages exist.

ROS 2 from PyPI has no ``launch`` or ``launch_ros``: there the file is checked as source (its
function, arguments, remapping and parameter file); on a ROS install it is also built.
"""

from __future__ import annotations

import ast
import importlib.util

import pytest
from support.data import REPO_ROOT

LAUNCH_FILE = REPO_ROOT / 'launch' / 'decomposer.launch.py'
ARGUMENTS = {'cloud_in', 'params_file', 'use_sim_time', 'rviz', 'fixed_frame'}


def _calls(tree: ast.AST, name: str) -> list[ast.Call]:
    return [
        node
        for node in ast.walk(tree)
        if isinstance(node, ast.Call)
        and (getattr(node.func, 'id', None) == name or getattr(node.func, 'attr', None) == name)
    ]


def _keyword(call: ast.Call, name: str) -> ast.expr:
    return next(keyword.value for keyword in call.keywords if keyword.arg == name)


def test_launch_file_parses_and_defines_generate_launch_description():
    tree = ast.parse(LAUNCH_FILE.read_text(), filename=str(LAUNCH_FILE))
    functions = {node.name: node for node in tree.body if isinstance(node, ast.FunctionDef)}
    assert 'generate_launch_description' in functions
    assert not functions['generate_launch_description'].args.args, 'launch calls it bare'
    declared = {
        call.args[0].value
        for call in _calls(tree, 'DeclareLaunchArgument')
        if isinstance(call.args[0], ast.Constant)
    }
    assert declared == ARGUMENTS
    nodes = {ast.literal_eval(_keyword(call, 'package')): call for call in _calls(tree, 'Node')}
    assert set(nodes) == {'mvbb_ros', 'rviz2'}
    decomposer = nodes['mvbb_ros']
    assert ast.literal_eval(_keyword(decomposer, 'executable')) == 'decomposer'
    assert 'cloud_in' in ast.unparse(_keyword(decomposer, 'remappings'))
    assert "LaunchConfiguration('params_file')" in ast.unparse(_keyword(decomposer, 'parameters'))
    assert "IfCondition(LaunchConfiguration('rviz'))" in ast.unparse(
        _keyword(nodes['rviz2'], 'condition')
    )
    source = LAUNCH_FILE.read_text()
    assert "'decomposer.yaml'" in source and "'mvbb.rviz'" in source


def test_setup_py_installs_the_launch_file():
    assert "glob('launch/*.launch.py')" in (REPO_ROOT / 'setup.py').read_text()


def test_launch_description_builds_where_launch_is_installed():
    pytest.importorskip(
        'launch_ros',
        reason='launch_ros is not installed (ROS 2 from PyPI has rclpy and messages only); '
        'the launch file was checked as source',
    )
    from launch import LaunchDescription
    from launch.actions import DeclareLaunchArgument

    spec = importlib.util.spec_from_file_location('decomposer_launch', LAUNCH_FILE)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    description = module.generate_launch_description()
    assert isinstance(description, LaunchDescription)
    declared = {
        entity.name for entity in description.entities if isinstance(entity, DeclareLaunchArgument)
    }
    assert declared == ARGUMENTS
