"""benchmarks/workers.py: issue 41's clouds, the fingerprint of a result, and one short run."""

from __future__ import annotations

from dataclasses import replace
import os
import subprocess
import sys

import numpy as np
import pytest
from support.data import load_benchmark, REPO_ROOT, require_shared_data


@pytest.fixture(scope='module')
def bench():
    return load_benchmark('workers')


def test_the_clouds_follow_the_recipe(bench):
    path = require_shared_data('scans', 'mosd_learn26_obj2.npy')
    scan = np.load(path).astype(np.float64)
    cloud = bench.resampled(path)
    assert cloud.shape == (300_000, 3) and cloud.dtype == np.float32
    assert np.array_equal(cloud, bench.resampled(path)), 'seed 3: the same cloud every time'
    rng = np.random.default_rng(3)
    drawn = scan[rng.integers(0, len(scan), 300_000)]
    noise = cloud.astype(np.float64) - drawn
    assert abs(float(noise.std()) - 0.0015) < 5e-5, 'isotropic noise of 1.5 mm'
    assert np.allclose(noise.std(axis=0), 0.0015, rtol=0.03)


def test_the_fingerprint_sees_a_changed_grasp_or_box(bench):
    from mvbb_ros.pipeline.process import process_points

    rng = np.random.default_rng(0)
    cloud = rng.uniform([0.0, 0.0, 0.5], [0.1, 0.05, 0.6], (4000, 3))
    result = process_points(cloud)
    assert result.grasps and result.leaves
    digest = bench.fingerprint(result)
    assert bench.fingerprint(process_points(cloud)) == digest
    result.grasps[0] = replace(result.grasps[0], width=result.grasps[0].width + 1e-12)
    assert bench.fingerprint(result) != digest
    moved = process_points(cloud + np.array([0.0, 0.0, 1e-9]))
    assert bench.fingerprint(moved) != digest


def test_one_short_run_compares_the_counts_and_finds_them_identical():
    require_shared_data('scans', 'mosd_learn33_obj4.npy')
    completed = subprocess.run(
        [sys.executable, 'benchmarks/workers.py', '--only', 'mosd_learn33_obj4', '--runs', '1',
         '--workers', '1,2'],
        cwd=REPO_ROOT,
        env={**os.environ, 'PYTHONPATH': str(REPO_ROOT)},
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )  # fmt: skip
    assert completed.returncode == 0, completed.stdout + completed.stderr
    assert '| mosd_learn33_obj4 |' in completed.stdout
    assert 'identical outputs for every worker count: yes' in completed.stdout
    assert 'workers 2 / workers 1: median ratio' in completed.stdout
    ratios = [line for line in completed.stdout.splitlines() if "/ Open3D's chain" in line]
    assert len(ratios) == 2, 'one ratio to the peer chain per worker count'
    assert all(float(line.rsplit(' ', 1)[1]) > 0.0 for line in ratios)
