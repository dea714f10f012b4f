"""
numba kernels: every kernel module is registered, and no cache outlives an edit of a callee.

numba checks only a kernel's own file when it loads the kernel's cache, although the kernel's
machine code holds its jitted callees from other files too; mvbb_ros.kernel_cache adds those
files to the stamp. The last test edits a callee in another file of a copy of the package and
checks that the caller's cache is not used any more.
"""

import importlib
import json
import os
from pathlib import Path
import re
import shutil
import subprocess
import sys
import textwrap

from mvbb_ros import kernel_cache, kernels
import pytest
from support.data import REPO_ROOT
from support.mounts import read_only_command

PACKAGE = REPO_ROOT / 'mvbb_ros'


def _module_name(path: Path) -> str:
    return '.'.join(path.relative_to(REPO_ROOT).with_suffix('').parts)


def test_every_module_with_cached_kernels_is_registered_and_warms_up():
    with_kernels = {
        _module_name(path)
        for path in PACKAGE.rglob('*.py')
        if re.search(r'@nb\.njit\([^)]*cache=True', path.read_text(), re.S)
    }
    assert with_kernels <= set(kernels.KERNEL_MODULES), 'add them to kernels.KERNEL_MODULES'
    for name in kernels.KERNEL_MODULES:
        module = importlib.import_module(name)
        assert callable(module.warm_up), f'{name} defines no warm_up()'


def test_every_cached_kernel_of_the_package_uses_the_package_locator():
    count = 0
    for name in kernels.KERNEL_MODULES:
        for kernel, dispatcher in kernels._dispatchers(importlib.import_module(name)):
            locator = dispatcher._cache._impl.locator
            assert isinstance(locator, kernel_cache.PackageCacheLocator), kernel
            count += 1
    assert count >= 6


def test_every_cached_kernel_releases_the_gil():
    # The node runs its frames on a worker thread; a kernel holding the GIL would keep the
    # executor thread (parameter services, diagnostics) waiting for as long as the kernel runs.
    holding = [
        kernel
        for name in kernels.KERNEL_MODULES
        for kernel, dispatcher in kernels._dispatchers(importlib.import_module(name))
        if not dispatcher.targetoptions.get('nogil', False)
    ]
    assert holding == [], 'compile them with nogil=True'


def test_the_stamp_covers_the_kernel_modules_a_module_imports():
    def covered(name: str) -> set[str]:
        path = PACKAGE / 'geometry' / f'{name}.py'
        seen, waiting = {path}, [path]
        while waiting:
            for file in kernel_cache._imported_files(waiting.pop()):
                if file not in seen:
                    seen.add(file)
                    waiting.append(file)
        return {file.stem for file in seen}

    fit_parts = {'fit', 'search', 'turn', 'hull', 'rectangle', 'frames', 'enclose', 'box'}
    assert fit_parts <= covered('boxfit/fit')
    assert 'fit' not in covered('boxfit/hull')
    assert {'raster', 'cells'} <= covered('views/objects')
    assert {'raster', 'fill', 'rectangle'} <= covered('views/mirror')
    assert {'surface', 'cells', 'hypotheses', 'result', 'split'} <= covered('grasping/contacts')
    fit_file = (PACKAGE / 'geometry' / 'boxfit' / 'fit.py').resolve()
    assert kernel_cache.dependency_digest(fit_file) != kernel_cache.dependency_digest(
        (PACKAGE / 'geometry' / 'boxfit' / 'hull.py').resolve()
    )


CALLEE = """
import numba as nb


@nb.njit
def value():
    return {value}
"""

CALLER = """
from mvbb_ros.geometry._probe_callee import value
import numba as nb


@nb.njit(cache=True)
def kernel():
    return value()
"""

PROBE = """
from mvbb_ros.geometry import _probe_caller as probe
result = probe.kernel()
stats = probe.kernel.stats
print(probe.__file__, result, sum(stats.cache_hits.values()), sum(stats.cache_misses.values()))
"""


@pytest.mark.slow
def test_an_edited_callee_in_another_file_recompiles_the_kernel(tmp_path):
    copy = tmp_path / 'mvbb_ros'
    shutil.copytree(PACKAGE, copy, ignore=shutil.ignore_patterns('__pycache__'))
    callee = copy / 'geometry' / '_probe_callee.py'
    callee.write_text(textwrap.dedent(CALLEE.format(value=1)))
    (copy / 'geometry' / '_probe_caller.py').write_text(textwrap.dedent(CALLER))
    env = dict(os.environ, PYTHONPATH=str(tmp_path), NUMBA_CACHE_DIR=str(tmp_path / 'cache'))

    def run() -> tuple[int, int, int]:
        result = subprocess.run(
            [sys.executable, '-c', PROBE],
            cwd=tmp_path,
            env=env,
            capture_output=True,
            text=True,
            check=True,
            timeout=240,
        )
        where, value, hits, misses = result.stdout.split()
        assert Path(where).is_relative_to(copy)
        return int(value), int(hits), int(misses)

    assert run() == (1, 0, 1)  # compiled
    assert run() == (1, 1, 0)  # from the cache
    callee.write_text(textwrap.dedent(CALLEE.format(value=2)))
    assert run() == (2, 0, 1)  # the caller's file is unchanged, its cache is not used
    assert run() == (2, 1, 0)


_ROUND_TRIP = """
import json, sys
import numpy as np
sys.path.insert(0, sys.argv[1])
from support.shapes import l_shape_points
from mvbb_ros import kernels
from mvbb_ros.evaluation.synthetic import segmented_object_cloud
from mvbb_ros.pipeline.process import process_points
from mvbb_ros.pipeline.settings import PipelineSettings
import importlib
import mvbb_ros

assert mvbb_ros.__file__.startswith(sys.argv[2]), mvbb_ros.__file__
kernels.warm_up()
answers = []
for cloud in (l_shape_points(), segmented_object_cloud('mug', seed=3)):
    result = process_points(cloud, PipelineSettings())
    boxes = [np.concatenate([leaf.center, leaf.extents]) for leaf in result.leaves]
    grasps = [grasp.position for grasp in result.grasps]
    answers.append([np.round(boxes, 9).tolist(), np.round(grasps, 9).tolist()])
hits, misses = {}, {}
for name in kernels.KERNEL_MODULES:
    hits[name] = misses[name] = 0
    for _, dispatcher in kernels._dispatchers(importlib.import_module(name)):
        hits[name] += sum(dispatcher.stats.cache_hits.values())
        misses[name] += sum(dispatcher.stats.cache_misses.values())
print(json.dumps({'answers': answers, 'hits': hits, 'misses': misses}))
"""


@pytest.mark.slow  # compiles every kernel, then each module again, in fresh processes: minutes
def test_cached_kernels_answer_as_freshly_compiled_ones(tmp_path):
    """
    A kernel loaded from numba's cache gives the answers it gave when compiled.

    Not a given: with numba 0.68, a clustering kernel that called ``np.searchsorted``,
    recompiled in a process that had loaded the other kernels from the cache (as after an edit
    of its module), was saved so that every later load answered wrongly (2,792 clusters in one
    L-shaped cloud instead of 1). On a copy of the package with no cache: the first run compiles
    every kernel; then, one kernel module at a time, its cache goes (an edit) and one run
    recompiles it among cached ones, among them the module recompiled by the run before, which
    this run loads from the cache that run saved; a last run loads every module. Every run must
    answer alike, so every recompiled module answers alike both recompiled and loaded.
    """
    shutil.copytree(PACKAGE, tmp_path / 'mvbb_ros', ignore=shutil.ignore_patterns('__pycache__'))
    env = {key: value for key, value in os.environ.items() if key != 'NUMBA_CACHE_DIR'}
    env['PYTHONPATH'] = str(tmp_path)

    def run() -> dict:
        completed = subprocess.run(
            [sys.executable, '-c', _ROUND_TRIP, str(REPO_ROOT / 'test'), str(tmp_path)],
            cwd=tmp_path,
            env=env,
            capture_output=True,
            text=True,
            timeout=600,
            check=True,
        )
        return json.loads(completed.stdout.strip().splitlines()[-1])

    compiled = run()
    assert all(compiled['misses'].values()), 'the first run must compile every module'
    assert not any(compiled['hits'].values()), 'the first run must compile'
    assert len(compiled['answers'][0][0]) == 2, 'the L shape is two boxes'
    previous = None
    for name in kernels.KERNEL_MODULES:
        folder = tmp_path.joinpath(*name.split('.')[:-1], '__pycache__')
        stem = name.rsplit('.', 1)[-1]
        removed = list(folder.glob(f'{stem}.*.nb[ic]'))
        assert removed, f'no cache files of {name} in {folder}'
        for path in removed:
            path.unlink()
        recompiled = run()
        # This module compiled among cached ones, the one before loaded from its new cache.
        assert recompiled['misses'][name] > 0, name
        if previous is not None:
            assert recompiled['hits'][previous] > 0, f'{previous} not loaded from its new cache'
        assert recompiled['answers'] == compiled['answers'], (
            f'{name} recompiled or {previous} loaded from the cache'
        )
        previous = name
    loaded = run()
    assert not any(loaded['misses'].values()), loaded['misses']
    assert loaded['answers'] == compiled['answers'], f'{previous} loaded from the cache'


KERNEL = """
from mvbb_ros import kernel_cache  # noqa: F401 (the package's locator before the kernel)
import numba as nb


@nb.njit(cache=True)
def kernel(x):
    return x * 2
"""

KERNEL_PROBE = """
from mvbb_ros.geometry import _probe_kernel as probe
result = probe.kernel(21)
stats = probe.kernel.stats
print(probe.__file__, result, sum(stats.cache_hits.values()), sum(stats.cache_misses.values()))
"""


def _probe_package(tmp_path: Path) -> Path:
    """Copy the package (no caches) with one small cached kernel; return the copy's folder."""
    root = tmp_path / 'install'
    shutil.copytree(PACKAGE, root / 'mvbb_ros', ignore=shutil.ignore_patterns('__pycache__'))
    (root / 'mvbb_ros' / 'geometry' / '_probe_kernel.py').write_text(textwrap.dedent(KERNEL))
    for home in (tmp_path / 'home', root / 'home'):  # root/home is read-only with the install
        home.mkdir()
    return root


def _run_probe(
    root: Path, home: Path, read_only: bool = False
) -> tuple[tuple[int, int, int], str]:
    """Run the probe kernel from `root` with `home` as HOME; `read_only`: `root` read-only."""
    env = {key: value for key, value in os.environ.items() if key != 'NUMBA_CACHE_DIR'}
    env.update(PYTHONPATH=str(root), HOME=str(home), XDG_CACHE_HOME=str(home / '.cache'))
    prefix = read_only_command(root) if read_only else []
    completed = subprocess.run(
        [*prefix, sys.executable, '-c', KERNEL_PROBE],
        cwd=root,
        env=env,
        capture_output=True,
        text=True,
        timeout=240,
    )
    assert completed.returncode == 0, completed.stderr
    where, value, hits, misses = completed.stdout.split()
    assert Path(where).is_relative_to(root)
    return (int(value), int(hits), int(misses)), completed.stderr


@pytest.mark.slow
@pytest.mark.parametrize('suffix', ['nbi', 'nbc'])
def test_a_torn_cache_file_is_discarded_and_the_kernel_compiled_again(tmp_path, suffix):
    root = _probe_package(tmp_path)
    home = tmp_path / 'home'
    assert _run_probe(root, home) == ((42, 0, 1), '')
    assert _run_probe(root, home) == ((42, 1, 0), '')
    (torn,) = (root / 'mvbb_ros' / 'geometry' / '__pycache__').glob(f'_probe_kernel.*.{suffix}')
    torn.write_bytes(torn.read_bytes()[:10])  # what a power cut after the compile leaves
    counts, stderr = _run_probe(root, home)
    assert counts == (42, 0, 1)
    assert 'KernelCacheWarning' in stderr and 'could not be read' in stderr
    assert stderr.count('KernelCacheWarning') == 1
    assert _run_probe(root, home) == ((42, 1, 0), '')  # healed: the new entry loads


@pytest.mark.slow
def test_a_read_only_install_uses_its_shipped_cache_and_compiles_the_rest_in_memory(tmp_path):
    root = _probe_package(tmp_path)
    writable_home, read_only_home = tmp_path / 'home', root / 'home'
    assert _run_probe(root, writable_home) == ((42, 0, 1), '')  # the build ships a warm cache
    assert _run_probe(root, read_only_home, read_only=True) == ((42, 1, 0), '')
    assert _run_probe(root, writable_home, read_only=True) == ((42, 1, 0), '')  # not compiled
    assert not list(writable_home.rglob('*.nbi'))
    for path in (root / 'mvbb_ros' / 'geometry' / '__pycache__').glob('_probe_kernel.*'):
        path.unlink()  # shipped without a cache: nowhere to write one
    counts, stderr = _run_probe(root, read_only_home, read_only=True)
    assert counts == (42, 0, 1)
    assert 'KernelCacheWarning' in stderr and 'cannot be written' in stderr
    assert not list(read_only_home.rglob('*.nbi'))
