"""
numba kernels: every kernel module is registered, and no cache outlives an edit of a callee.

numba checks only a kernel's own file when it loads the kernel's cache, although the kernel's
machine code holds its jitted callees from other files too; mvbb_ros.kernel_cache adds those
files to the stamp. The last test edits a callee in another file of a copy of the package and
checks that the caller's cache is not used any more.
"""

import importlib
import os
from pathlib import Path
import re
import shutil
import subprocess
import sys
import textwrap

from conftest import REPO_ROOT
from mvbb_ros import kernel_cache, kernels

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

    assert {'fit', 'search', 'hull', 'rectangle', 'box'} <= covered('fit')
    assert 'fit' not in covered('hull')
    assert {'completion', 'fit', 'hull'} <= covered('objects')
    fit_file = (PACKAGE / 'geometry' / 'fit.py').resolve()
    assert kernel_cache.dependency_digest(fit_file) != kernel_cache.dependency_digest(
        (PACKAGE / 'geometry' / 'hull.py').resolve()
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
