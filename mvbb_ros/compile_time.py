"""
A clock of numba's compiles in this process, started before the first kernel module loads.

Kernels with explicit signatures compile (or load from numba's cache) when their module is
imported, so the time a first run spends compiling is not the time of any one call: this clock
adds up every compile (numba's ``numba:compile`` events, the outermost ones only, so a kernel
compiled inside another is not counted twice). Loading from the cache is no compile: on a warm
start it stays at zero. The packages that hold kernels (``geometry`` and ``pipeline``)
import this module before anything that compiles; :func:`mvbb_ros.kernels.warm_up` reports it.
"""

from __future__ import annotations

import time

from numba.core import event


class _CompileClock(event.Listener):
    """Add up the wall-clock time of numba's outermost compiles."""

    def __init__(self) -> None:
        self.depth = 0
        self.seconds = 0.0
        self._start = 0.0

    def on_start(self, _: object) -> None:
        if self.depth == 0:
            self._start = time.perf_counter()
        self.depth += 1

    def on_end(self, _: object) -> None:
        self.depth -= 1
        if self.depth == 0:
            self.seconds += time.perf_counter() - self._start


_CLOCK = _CompileClock()
event.register('numba:compile', _CLOCK)


def compile_seconds() -> float:
    """Return the seconds numba has spent compiling in this process since the clock started."""
    return _CLOCK.seconds
