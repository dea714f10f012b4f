"""benchmarks/peers.py: the machine a timing ran on, and Open3D's filter chain."""

from __future__ import annotations

import numpy as np
import pytest
from support.data import load_benchmark


@pytest.fixture(scope='module')
def peers():
    return load_benchmark('peers')


def write_cpuinfo(tmp_path, flags: str) -> str:
    path = tmp_path / 'cpuinfo'
    block = (
        f'processor\t: {{}}\nmodel name\t: AMD EPYC\ncpu MHz\t\t: 2445.428\nflags\t\t: {flags}\n'
    )
    path.write_text(block.format(0) + '\n' + block.format(1))
    return str(path)


def test_the_machine_names_its_vector_features_and_the_missing_ones(peers, tmp_path):
    zen2 = peers.machine(write_cpuinfo(tmp_path, 'fpu sse4_2 avx avx2 fma'))
    assert zen2 == 'AMD EPYC, avx2 fma, no avx512f, 2.45 GHz'
    zen4 = peers.machine(write_cpuinfo(tmp_path, 'fpu avx2 fma avx512f avx512bw'))
    assert zen4 == 'AMD EPYC, avx512f avx2 fma, 2.45 GHz'


def test_a_machine_without_cpuinfo_is_unknown(peers, tmp_path):
    assert peers.machine(str(tmp_path / 'missing')) == 'unknown CPU'


def test_the_chain_filters_and_takes_time(peers):
    pytest.importorskip('open3d', reason='the peer is Open3D (not in make compat)')
    from mvbb_ros.pipeline.settings import PipelineSettings

    rng = np.random.default_rng(0)
    points = np.ascontiguousarray(rng.uniform(-0.1, 0.1, (20_000, 3)))
    before = points.copy()
    elapsed = peers.open3d_filter_chain_ms(points, PipelineSettings().filtering)
    assert 0.0 < elapsed < 60_000.0
    np.testing.assert_array_equal(points, before)
