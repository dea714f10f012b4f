"""OpenBLAS on one thread while a cloud is processed, its own counts given back after."""

from __future__ import annotations

import threading

from mvbb_ros.common import blas
from mvbb_ros.common.blas import _loaded_libraries, one_blas_thread, openblas_libraries
import mvbb_ros.pipeline.process as process
from mvbb_ros.pipeline.settings import PipelineSettings
import numpy as np
import pytest


@pytest.fixture
def libraries():
    """Yield the process's OpenBLAS libraries, each set to two threads (restored after)."""
    import scipy.linalg  # noqa: F401  (scipy's own OpenBLAS, where its wheel bundles one)

    found = openblas_libraries()
    if not found:
        pytest.skip('no OpenBLAS is loaded in this process (numpy built on another BLAS)')
    before = [library.threads for library in found]
    for library in found:
        library.threads = 2
    if any(library.threads != 2 for library in found):
        pytest.skip('this OpenBLAS was built for one thread only: nothing to hold')
    yield found
    for library, count in zip(found, before, strict=True):
        library.threads = count


def test_a_block_runs_on_one_thread_and_gives_the_count_back(libraries):
    with one_blas_thread():
        assert [library.threads for library in libraries] == [1] * len(libraries)
    assert [library.threads for library in libraries] == [2] * len(libraries)


def test_the_count_comes_back_when_a_block_raises(libraries):
    with pytest.raises(RuntimeError), one_blas_thread():
        raise RuntimeError('a failing cloud')
    assert [library.threads for library in libraries] == [2] * len(libraries)


def test_overlapping_blocks_on_two_threads_give_the_count_back_when_the_last_ends(libraries):
    first_in, second_in, first_out = threading.Event(), threading.Event(), threading.Event()
    seen = {}

    def first() -> None:
        with one_blas_thread():
            first_in.set()
            second_in.wait(5)
        first_out.set()

    thread = threading.Thread(target=first)
    thread.start()
    first_in.wait(5)
    with one_blas_thread():
        second_in.set()
        first_out.wait(5)
        # The other block has ended: this one still holds one thread.
        seen['inside'] = [library.threads for library in libraries]
    thread.join(5)
    assert seen['inside'] == [1] * len(libraries)
    assert [library.threads for library in libraries] == [2] * len(libraries)


def test_process_points_runs_on_one_blas_thread_and_gives_the_count_back(libraries, monkeypatch):
    seen = []
    separate = process.separate_objects

    def watched(*args, **kwargs):
        seen.append([library.threads for library in libraries])
        return separate(*args, **kwargs)

    monkeypatch.setattr(process, 'separate_objects', watched)
    rng = np.random.default_rng(0)
    cube = rng.uniform(-0.05, 0.05, (4000, 3)) + (0.0, 0.0, 0.6)
    result = process.process_points(cube, PipelineSettings())
    assert result.leaves
    assert seen == [[1] * len(libraries)]
    assert [library.threads for library in libraries] == [2] * len(libraries)


def test_only_mapped_openblas_files_are_taken(tmp_path):
    maps = tmp_path / 'maps'
    maps.write_text(
        '7f00-7f01 r-xp 00000000 08:01 42   /usr/lib/x86_64-linux-gnu/libm.so.6\n'
        '7f01-7f02 r-xp 00000000 08:01 43   /opt/numpy.libs/libscipy_openblas64_-ab.so\n'
        '7f02-7f03 rw-p 00001000 08:01 43   /opt/numpy.libs/libscipy_openblas64_-ab.so\n'
        '7f03-7f04 r-xp 00000000 08:01 44   /usr/lib/openblas-pthread/libblas.so.3\n'
        '7f04-7f05 rw-p 00000000 00:00 0 \n'
        '7f05-7f06 rw-p 00000000 00:00 0    [heap]\n'
        '7f06-7f07 r-xp 00000000 08:01 45   /home/a user/OpenBLAS build/libopenblas.so\n'
    )
    assert _loaded_libraries(maps) == [
        '/home/a user/OpenBLAS build/libopenblas.so',
        '/opt/numpy.libs/libscipy_openblas64_-ab.so',
        '/usr/lib/openblas-pthread/libblas.so.3',
    ]
    assert _loaded_libraries(tmp_path / 'missing') == []


def test_without_openblas_a_block_does_nothing(monkeypatch):
    monkeypatch.setattr(blas, '_libraries', [])
    with one_blas_thread():
        assert openblas_libraries() == []
