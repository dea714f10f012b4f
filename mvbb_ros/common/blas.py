"""
OpenBLAS held to one thread while a cloud is processed: the pipeline's workers are its threads.

numpy's and scipy's matrix products go to OpenBLAS (in their wheels, and usually on Ubuntu),
which runs a large product on a thread per core and keeps those threads spinning for a while
after it. The pipeline's products are of (N, 3) by (3, 3) matrices: the extra threads do not make
them faster, but their spinning takes the cores that the pipeline's own helper threads
(:mod:`mvbb_ros.common.workers`) need (``docs/performance.md``, "Workers"). The products give
the same numbers on any number of BLAS threads.

:func:`one_blas_thread` sets every OpenBLAS loaded in the process to one thread for the length
of a block and gives each its count back when the last such block ends (blocks may overlap on
several threads). Without OpenBLAS (another BLAS, or a system without ``/proc/self/maps``) it
does nothing.
"""

from __future__ import annotations

from collections.abc import Iterator
import contextlib
import ctypes
from pathlib import Path
import threading
from typing import Any

#: The (set, get) symbol pairs an OpenBLAS build may export: the plain names, the 64-bit
#: integer builds' suffix, and the prefixed builds that numpy's and scipy's wheels bundle.
_SYMBOLS: tuple[tuple[str, str], ...] = tuple(
    (f'{prefix}openblas_set_num_threads{suffix}', f'{prefix}openblas_get_num_threads{suffix}')
    for prefix in ('', 'scipy_')
    for suffix in ('', '64_')
)


class _OpenBlas:
    """One loaded OpenBLAS library's thread count."""

    def __init__(self, setter: Any, getter: Any) -> None:
        setter.argtypes = [ctypes.c_int]
        setter.restype = None
        getter.argtypes = []
        getter.restype = ctypes.c_int
        self._set = setter
        self._get = getter

    @property
    def threads(self) -> int:
        """Return the library's current thread count."""
        return int(self._get())

    @threads.setter
    def threads(self, count: int) -> None:
        self._set(count)


def _loaded_libraries(maps: Path = Path('/proc/self/maps')) -> list[str]:
    """Return the paths of the shared libraries mapped in this process whose name says OpenBLAS."""
    try:
        text = maps.read_text()
    except OSError:
        return []
    paths = {line.split(maxsplit=5)[-1] for line in text.splitlines() if line.count(' ') >= 5}
    return sorted(path for path in paths if path.startswith('/') and 'openblas' in path.lower())


def _open(path: str) -> _OpenBlas | None:
    """Return the thread count of the OpenBLAS at `path`, or None when it exports none."""
    try:
        library = ctypes.CDLL(path)
    except OSError:
        return None
    for setter, getter in _SYMBOLS:
        if hasattr(library, setter) and hasattr(library, getter):
            return _OpenBlas(getattr(library, setter), getattr(library, getter))
    return None


_lock = threading.Lock()
_libraries: list[_OpenBlas] | None = None
_inside = 0
_saved: list[int] = []


def openblas_libraries() -> list[_OpenBlas]:
    """Return the OpenBLAS libraries loaded in this process (looked up once, on first use)."""
    global _libraries
    with _lock:
        if _libraries is None:
            found = (_open(path) for path in _loaded_libraries())
            _libraries = [library for library in found if library is not None]
        return _libraries


@contextlib.contextmanager
def one_blas_thread() -> Iterator[None]:
    """Run the block with every loaded OpenBLAS on one thread; restore the counts after."""
    global _inside, _saved
    libraries = openblas_libraries()
    with _lock:
        if _inside == 0:
            _saved = [library.threads for library in libraries]
            for library in libraries:
                library.threads = 1
        _inside += 1
    try:
        yield
    finally:
        with _lock:
            _inside -= 1
            if _inside == 0:
                for library, count in zip(libraries, _saved, strict=True):
                    library.threads = count
