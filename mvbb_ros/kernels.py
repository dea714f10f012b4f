"""
The compiled (numba) kernels: which modules have them, warming their cache, keeping it fresh.

numba compiles a kernel on its first call and caches the machine code (``cache=True``) beside
its module, or in the user's cache directory when the package folder is read-only (a colcon
install space). :func:`warm_up` calls every kernel module's own ``warm_up()`` on tiny inputs,
so that the first cloud does not wait for the compiler: ``tools/bootstrap.sh`` runs it once at
set-up (``python -m mvbb_ros.kernels``), and the node and the command line run it at start
(:func:`warm_up_logged`) and say so in one line when something had to be compiled.

A kernel module registers itself by being listed in :data:`KERNEL_MODULES` and defining
``warm_up() -> None``, which calls each of its kernels once.

A kernel's cache is refreshed when any module it calls into changes, not only its own
(:mod:`mvbb_ros.kernel_cache`).

Kernels with explicit signatures compile (or load from the cache) when their module is
imported, not when warmed; :mod:`mvbb_ros.compile_time` clocks every numba compile of the
process from the package's first import on, and :class:`WarmUp` reports that time too.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
import importlib
import sys
import time
from types import ModuleType

from mvbb_ros.compile_time import compile_seconds
from mvbb_ros.kernel_cache import cache_folder, PACKAGE_ROOT
from numba.core import caching
from numba.core.registry import CPUDispatcher

#: Every module with numba kernels, each defining ``warm_up()``.
KERNEL_MODULES: tuple[str, ...] = (
    'mvbb_ros.geometry.box',
    'mvbb_ros.geometry.views.cells',
    'mvbb_ros.pipeline.decode',
    'mvbb_ros.pipeline.filtering',
    'mvbb_ros.pipeline.outliers',
    'mvbb_ros.pipeline.density',
    'mvbb_ros.pipeline.plane',
    'mvbb_ros.pipeline.outline',
    'mvbb_ros.pipeline.scene',
    'mvbb_ros.pipeline.view_edge',
    'mvbb_ros.geometry.boxfit.rectangle',
    'mvbb_ros.geometry.boxfit.hull',
    'mvbb_ros.geometry.boxfit.search',
    'mvbb_ros.geometry.boxfit.fit',
    'mvbb_ros.geometry.decomposition.split',
    'mvbb_ros.geometry.views.raster',
    'mvbb_ros.geometry.views.fill',
    'mvbb_ros.geometry.views.mirror',
    'mvbb_ros.geometry.views.objects',
    'mvbb_ros.geometry.grasping.surface',
    'mvbb_ros.geometry.grasping.contacts',
    'mvbb_ros.geometry.grasping.ranking',
)


@dataclass(frozen=True)
class WarmUp:
    """
    What warming the kernels took.

    :ivar seconds: wall-clock time of importing the modules and calling every kernel once.
    :ivar compiled: names of the kernels that had to be compiled (not found in the cache).
    :ivar compile_seconds: time numba spent compiling since the previous warm-up of this
        process, or since its start for the first (the imports compile the kernels with
        explicit signatures).
    """

    seconds: float
    compiled: tuple[str, ...]
    compile_seconds: float = 0.0


def _dispatchers(module: ModuleType) -> list[tuple[str, CPUDispatcher]]:
    """Return the cached kernels defined in `module` (not its helpers, nor imported kernels)."""
    return [
        (f'{module.__name__}.{name}', value)
        for name, value in vars(module).items()
        if isinstance(value, CPUDispatcher)
        and value.py_func.__module__ == module.__name__
        and not isinstance(getattr(value, '_cache', None), caching.NullCache)
    ]


#: What the previous :func:`warm_up` of this process counted: compiles per kernel, and numba's
#: compile time (the first call counts from the process's start, its imports included).
_COUNTED: dict[str, int] = {}
_COUNTED_SECONDS = [0.0]


def warm_up() -> WarmUp:
    """
    Import every kernel module and run its kernels once; report what had to be compiled.

    The first call of a process reports every compile since the package was imported (kernels
    with signatures compile at import); a later call only what it compiled itself (a long-lived
    process, such as a test session, compiles other argument types in between: not a start).
    """
    start = time.perf_counter()
    compiled = []
    for name in KERNEL_MODULES:
        module = importlib.import_module(name)
        module.warm_up()
        for kernel, dispatcher in _dispatchers(module):
            misses = sum(dispatcher.stats.cache_misses.values())
            if misses > _COUNTED.get(kernel, 0):
                compiled.append(kernel)
            _COUNTED[kernel] = misses
    seconds = compile_seconds() - _COUNTED_SECONDS[0]
    _COUNTED_SECONDS[0] = compile_seconds()
    return WarmUp(time.perf_counter() - start, tuple(compiled), seconds)


def warm_up_logged(log: Callable[[str], object]) -> WarmUp:
    """
    Warm the kernels; when some had to be compiled, say so in one line through `log`.

    The node and the command line call this before the first cloud, so that the first cloud
    does not wait for the compiler and a user knows why the first start took longer.

    :param log: where the line goes (a ROS logger's ``info``, or a print to stderr).
    :return: what warming took.
    """
    report = warm_up()
    if report.compiled:
        log(f'compiling geometry kernels, first run only ({report.compile_seconds:.1f} s)')
    return report


def cold_modules() -> list[str]:
    """
    Return the kernel modules that have no cached kernel yet (a first start after an install).

    Looks only at the cache folders, importing no kernel module, so that a program can say that
    it is about to compile before the imports that compile.
    """
    cold = []
    for name in KERNEL_MODULES:
        path = PACKAGE_ROOT.joinpath(*name.split('.')[1:]).with_suffix('.py')
        folder = cache_folder(path)
        if folder is None or not any(folder.glob(f'{path.stem}.*.nbi')):
            cold.append(name)
    return cold


def announce_cold_start(log: Callable[[str], object]) -> bool:
    """Say through `log`, before anything compiles, that the kernels are about to be compiled."""
    if not cold_modules():
        return False
    log(
        'compiling geometry kernels before the first cloud (first start after an install; '
        'about a minute on 2 quiet cores, several on a loaded machine)'
    )
    return True


def main() -> int:
    """Warm the cache (``python -m mvbb_ros.kernels``); print what it took."""
    announce_cold_start(lambda line: print(f'mvbb_ros kernels: {line}', flush=True))
    report = warm_up()
    if report.compiled:
        what = f'compiled {len(report.compiled)} kernels in {report.compile_seconds:.1f} s'
    else:
        what = f'cache was warm ({report.seconds:.1f} s)'
    print(f'mvbb_ros kernels: {what}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
