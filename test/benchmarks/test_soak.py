"""benchmarks/soak.py: how it measures the node's memory growth (the soak is a benchmark)."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st
import numpy as np
import pytest
from support.data import load_benchmark

MIB = 2**20


@pytest.fixture(scope='module')
def soak():
    return load_benchmark('soak')


def _figures(soak, memory):
    return soak.Figures(memory[-1][0], 1, np.array([1.0]), memory, 0)


@settings(max_examples=30, deadline=None)
@given(
    st.floats(300.0, 400.0),
    st.lists(st.floats(0.0, 0.1), min_size=19, max_size=19),
    st.floats(0.06, 0.5),
)
def test_a_leak_shows_as_growth_and_the_allocators_dips_do_not(soak, steady, dips, leak):
    """Ten minutes sampled every 30 s: warming up, then steady with dips, or leaking."""
    times = [30.0 * k for k in range(21)]
    warming = [(0.0, 0.7 * steady * MIB), (30.0, 0.9 * steady * MIB)]
    flat = [(t, steady * (1.0 - dip) * MIB) for t, dip in zip(times[2:], dips, strict=True)]
    # The peaks are what the node holds; glibc's trims show as samples below them.
    flat[1] = (flat[1][0], steady * MIB)
    flat[-2] = (flat[-2][0], steady * MIB)
    assert abs(_figures(soak, warming + flat).growth) < 0.01
    leaking = [(t, steady * (1.0 + leak * (t - 60.0) / 540.0) * MIB) for t in times[2:]]
    # Three quarters of a steady leak show (the first and the last quarter's peaks).
    assert _figures(soak, warming + leaking).growth == pytest.approx(0.75 * leak, rel=0.2)


def test_a_short_run_warms_up_for_its_first_third(soak):
    assert soak.warm_up_s(600.0) == soak.WARM_UP_S
    assert soak.warm_up_s(60.0) == pytest.approx(20.0)
    growing = [(0.0, 100.0 * MIB), (30.0, 100.0 * MIB), (60.0, 110.0 * MIB)]
    assert _figures(soak, growing).growth == pytest.approx(0.10)


def test_the_decomposers_parameters_reach_its_command_line_as_ros_arguments(soak, tmp_path):
    executable = tmp_path / 'decomposer'
    assert soak.decomposer_command(executable, []) == [str(executable)]
    command = soak.decomposer_command(executable, ['frame_time_budget:=0.03', 'workers:=1'])
    assert command == [
        str(executable),
        '--ros-args',
        '-p',
        'frame_time_budget:=0.03',
        '-p',
        'workers:=1',
    ]
    for bad in ('workers=1', ':=1', 'workers:='):
        with pytest.raises(ValueError, match='NAME:=VALUE'):
            soak.decomposer_command(executable, [bad])


def test_the_report_says_how_long_the_node_ran_at_each_budget_level(soak, capsys):
    memory = [(0.0, 100.0 * MIB), (60.0, 100.0 * MIB)]
    lighter = soak.Figures(60.0, 1800, np.array([20.0, 30.0]), memory, 0, (0, 1, 2, 2, 2))
    soak.report('decomposer', lighter)
    assert 'budget level, seconds at each (from /diagnostics): 0: 1, 1: 1, 2: 3' in (
        capsys.readouterr().out
    )
    soak.report('decomposer', _figures(soak, memory))
    assert 'budget level' not in capsys.readouterr().out


CHILD = r"""
import ctypes, threading, time

spun = []

def spin(seconds, name=None):
    if name is not None:  # as Fast DDS names its threads (prctl PR_SET_NAME)
        ctypes.CDLL(None).prctl(15, name.encode(), 0, 0, 0)
    end = time.thread_time() + seconds
    while time.thread_time() < end:
        pass
    spun.append(name)
    time.sleep(60)  # alive while measured: an ended thread leaves /proc

for arguments in ((0.6, 'dds.shm.7'), (0.3,)):
    threading.Thread(target=spin, args=arguments, daemon=True).start()
spin_main = time.thread_time() + 0.2
while time.thread_time() < spin_main:
    pass
while len(spun) < 2:
    time.sleep(0.01)
print('done', flush=True)
time.sleep(60)
"""


def test_the_node_cpu_is_split_by_thread_role(soak):
    import subprocess
    import sys

    import psutil

    child = subprocess.Popen([sys.executable, '-c', CHILD], stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout is not None and child.stdout.readline().strip() == 'done'
        seconds = soak.thread_cpu_s(psutil.Process(child.pid))
    finally:
        child.kill()
        child.wait()
    assert set(seconds) == set(soak.THREAD_ROLES)
    # Each thread's spin is its own CPU time (thread_time), plus the interpreter's start; Linux
    # counts it in clock ticks (10 ms).
    assert 0.55 <= seconds['middleware'] < 0.8
    assert 0.25 <= seconds['frames'] < 0.5
    assert 0.15 <= seconds['executor'] < 1.0
