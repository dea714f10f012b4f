"""The ``decomposer`` executable's command line: ``--help`` answers without joining the graph."""

from __future__ import annotations

from pathlib import Path
import subprocess
import sys

from mvbb_ros.pipeline.settings import defaults, SPECS
from mvbb_ros.ros.decomposer import main, wants_help
import pytest
import rclpy


def test_help_lists_every_parameter_with_the_nodes_default_and_joins_no_graph(capsys):
    assert main(['--help']) == 0
    out = capsys.readouterr().out
    assert out.startswith('usage: decomposer')
    values = defaults()
    for spec in SPECS:
        assert f'  {spec.name}:=' in out, spec.name
    assert f'gain_threshold:={values["gain_threshold"]}' in out
    assert not rclpy.ok()  # rclpy was never initialized


def test_only_our_own_arguments_ask_for_help():
    assert wants_help(['-h']) and wants_help(['--help', '--ros-args', '-p', 'seed:=1'])
    assert not wants_help([])
    assert not wants_help(['--ros-args', '-r', '__node:=--help'])


@pytest.mark.slow  # a fresh process that loads the settings (and their kernels)
def test_installed_decomposer_help_exits_zero():
    script = Path(sys.executable).parent / 'decomposer'
    if not script.exists():
        pytest.skip(f'{script} is not installed (run make test, which installs the package)')
    result = subprocess.run(
        [str(script), '--help'], capture_output=True, text=True, timeout=120, check=False
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith('usage: decomposer')
