"""The ``decomposer`` executable's command line: ``--help`` answers without joining the graph."""

from __future__ import annotations

import gc
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

from mvbb_ros.pipeline.settings import defaults
from mvbb_ros.pipeline.specs import SPECS
from mvbb_ros.ros import decomposer
from mvbb_ros.ros.decomposer import main, ros_log_fallback, wants_help
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


def test_ros_log_fallback_only_when_ros_cannot_write_its_own_folder(tmp_path):
    blocked = tmp_path / 'a_file'
    blocked.write_text('HOME below a file: nothing can be made there, even as root')
    found = ros_log_fallback({'HOME': str(blocked / 'home')})
    assert found is not None and found[0] == blocked / 'home' / '.ros' / 'log'
    assert ros_log_fallback({'HOME': str(tmp_path / 'home')}) is None
    assert (tmp_path / 'home' / '.ros' / 'log').is_dir()
    assert ros_log_fallback({'HOME': str(blocked), 'ROS_LOG_DIR': str(tmp_path)}) is None
    assert ros_log_fallback({'HOME': str(blocked), 'ROS_HOME': str(tmp_path / 'ros')}) is None


def test_the_node_starts_with_a_home_it_cannot_write(tmp_path):
    """A read-only HOME (a read-only container) stopped rcl at init; the node logs elsewhere."""
    blocked = tmp_path / 'a_file'
    blocked.write_text('')
    env = {k: v for k, v in os.environ.items() if k not in ('ROS_LOG_DIR', 'ROS_HOME')}
    env.update(HOME=str(blocked / 'home'), PYTHONUNBUFFERED='1')
    process = subprocess.Popen(
        [sys.executable, '-m', 'mvbb_ros.ros.decomposer'],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env,
    )
    try:
        lines = []
        deadline = time.monotonic() + 120.0
        while time.monotonic() < deadline:
            line = process.stdout.readline()
            lines.append(line)
            if 'publishing on' in line or (not line and process.poll() is not None):
                break
        assert 'publishing on' in lines[-1], ''.join(lines)
        process.send_signal(signal.SIGINT)
        rest, _ = process.communicate(timeout=30)
    finally:
        if process.poll() is None:
            process.kill()
    output = ''.join(lines) + rest
    assert process.returncode == 0, output
    assert output.count('cannot write ROS log files in') == 1 and 'Traceback' not in output


@pytest.fixture()
def unraisable(monkeypatch):
    """Collect what Python reports as raised and ignored (an exception in ``__del__``)."""
    caught = []
    monkeypatch.setattr(sys, 'unraisablehook', caught.append)
    yield caught
    gc.collect()


def test_a_sigint_before_the_node_spins_is_a_clean_exit(monkeypatch, unraisable):
    # SIGINT's handler shuts rclpy down; landing after the node's constructor (which says
    # "publishing on") but before the executor existed, it made the executor's creation fail:
    # the node exited 2 ("cannot start"), then printed a traceback from the executor's __del__.
    real_add_node = decomposer._Executor.add_node

    def shut_down_then_add(executor, node):
        rclpy.shutdown()  # what SIGINT's handler does, on its own thread
        return real_add_node(executor, node)

    monkeypatch.setattr(decomposer._Executor, 'add_node', shut_down_then_add)
    assert main(['decomposer']) == 0
    assert not rclpy.ok()
    gc.collect()
    assert not unraisable


def test_a_sigint_before_the_executor_is_made_is_a_clean_exit(monkeypatch, unraisable):
    # Earlier still, the executor's own construction fails halfway: a stop, and nothing printed.
    real_init = decomposer._Executor.__init__

    def shut_down_then_init(executor, *args, **kwargs):
        rclpy.shutdown()
        real_init(executor, *args, **kwargs)

    monkeypatch.setattr(decomposer._Executor, '__init__', shut_down_then_init)
    assert main(['decomposer']) == 0
    assert not rclpy.ok()
    gc.collect()
    assert not unraisable
