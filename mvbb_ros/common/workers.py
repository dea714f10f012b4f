"""
Threads for the compiled kernels: the pipeline's workers, one shared pool per count.

Every numba kernel of the package releases the GIL (``nogil=True``), so threads that call
kernels run on as many cores as there are threads. :func:`workers` returns the shared
:class:`Workers` of a count, created on first use and kept for the process's life (never one
per cloud). A :class:`Workers` of ``count`` threads is the calling thread plus ``count - 1``
helper threads:

- :meth:`Workers.spread` runs a function over items, the caller taking its share, and returns the
  results in the items' order;
- :meth:`Workers.submit` starts one call in the background; :meth:`Task.result` waits for it,
  or runs it on the calling thread when no helper has started it yet.

A caller never waits for a task that nobody runs: what a busy pool has not started, the
caller runs itself. A call from a helper thread runs inline (nothing nests), so a kernel that
takes ``workers`` may be called from inside another task. With one worker nothing is threaded:
every call runs inline, in order. Results do not depend on the count as long as each task is a
pure function of its arguments and the results are gathered in order, which is how the
pipeline uses them (``docs/architecture.md``, "Workers").
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
import os
import threading
from typing import Generic, TypeVar

T = TypeVar('T')
R = TypeVar('R')

#: The most workers the default takes, however many cores the process may use.
MAX_DEFAULT_WORKERS = 8
#: The most workers anyone may ask for.
MAX_WORKERS = 64

_local = threading.local()
_pools: dict[int, Workers] = {}
_pools_lock = threading.Lock()


def available_cores() -> int:
    """Return how many cores this process may run on (its CPU affinity), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


def default_workers() -> int:
    """Return the default worker count: the cores this process may use, at most 8."""
    return min(available_cores(), MAX_DEFAULT_WORKERS)


def check_count(count: object) -> int:
    """
    Return `count` as a worker count, or raise.

    :raises ValueError: unless `count` is an integer in [1, :data:`MAX_WORKERS`].
    """
    if isinstance(count, bool) or not isinstance(count, int) or not 1 <= count <= MAX_WORKERS:
        raise ValueError(f'workers must be an integer in [1, {MAX_WORKERS}], got {count!r}')
    return count


def in_helper() -> bool:
    """Tell whether the calling thread is one of the pools' helper threads."""
    return bool(getattr(_local, 'helper', False))


def _mark_helper() -> None:
    _local.helper = True


class Task(Generic[R]):
    """One call started by :meth:`Workers.submit`: its result when asked for."""

    def __init__(self, function: Callable[[], R], future: Future[R] | None) -> None:
        self._function = function
        self._future = future
        self._value: R | None = None
        self._done = future is None
        if future is None:
            self._value = function()

    def result(self) -> R:
        """Return the call's result; run it here if no helper has started it (re-raises)."""
        if not self._done:
            assert self._future is not None
            if self._future.cancel():
                self._value = self._function()
            else:
                self._value = self._future.result()
            self._done = True
        return self._value  # type: ignore[return-value]

    def run_if_waiting(self) -> None:
        """Run the call on this thread now if no helper has started it."""
        if not self._done and self._future is not None and self._future.cancel():
            self._value = self._function()
            self._done = True

    def done(self) -> bool:
        """Tell whether the call has finished (run here or on a helper)."""
        return self._done or (self._future is not None and self._future.done())

    def cancel(self) -> None:
        """Drop the call if no helper has started it (its result is not wanted)."""
        if self._future is not None:
            self._future.cancel()


def gather(tasks: Sequence[Task[R]]) -> list[R]:
    """
    Return the tasks' results in order, running on this thread those no helper started.

    The caller takes the waiting tasks from the last, while the helpers take them from the
    first, so they meet in the middle.
    """
    for task in reversed(tasks):
        task.run_if_waiting()
    return [task.result() for task in tasks]


class Workers:
    """
    The calling thread and ``count - 1`` helper threads (see the module doc).

    Use :func:`workers` for the shared pool of a count; a pool made directly is closed with
    :meth:`close`.
    """

    def __init__(self, count: int) -> None:
        self.count = check_count(count)
        self._executor: ThreadPoolExecutor | None = None
        if self.count > 1:
            self._executor = ThreadPoolExecutor(
                self.count - 1, thread_name_prefix='mvbb-worker', initializer=_mark_helper
            )

    @property
    def parallel(self) -> bool:
        """Tell whether calls from this thread may run on other threads."""
        return self._executor is not None and not in_helper()

    def submit(self, function: Callable[[], R]) -> Task[R]:
        """Start ``function()`` on a helper thread (inline with one worker or on a helper)."""
        if not self.parallel:
            return Task(function, None)
        assert self._executor is not None
        return Task(function, self._executor.submit(function))

    def spread(self, function: Callable[[T], R], items: Iterable[T]) -> list[R]:
        """
        Return ``[function(item) for item in items]``, the calls spread over the threads.

        The caller runs the first item, then every item no helper has started yet; an error of
        a call is raised here (the first in item order).
        """
        listed = list(items)
        if not self.parallel or len(listed) < 2:
            return [function(item) for item in listed]
        tasks = [self.submit(_bind(function, item)) for item in listed[1:]]
        first = function(listed[0])
        return [first, *gather(tasks)]

    def close(self) -> None:
        """Stop the helper threads (after the calls started)."""
        if self._executor is not None:
            self._executor.shutdown(wait=True)
            self._executor = None


def _bind(function: Callable[[T], R], item: T) -> Callable[[], R]:
    return lambda: function(item)


def workers(count: int) -> Workers:
    """
    Return the shared :class:`Workers` of `count` threads (made on first use, then kept).

    :raises ValueError: for a count outside [1, :data:`MAX_WORKERS`].
    """
    check_count(count)
    with _pools_lock:
        pool = _pools.get(count)
        if pool is None:
            pool = _pools[count] = Workers(count)
        return pool


def _forget_pools() -> None:
    # A forked child has none of the parent's threads: it makes its own pools on first use.
    global _pools_lock
    _pools.clear()
    _pools_lock = threading.Lock()


if hasattr(os, 'register_at_fork'):
    os.register_at_fork(after_in_child=_forget_pools)


def chunks(count: int, parts: int) -> list[slice]:
    """
    Return at most `parts` consecutive slices that cover ``range(count)``, sizes within one.

    The kernels that split their rows over the workers take these.
    """
    parts = max(1, min(parts, count))
    bounds = [count * k // parts for k in range(parts + 1)]
    return [slice(bounds[k], bounds[k + 1]) for k in range(parts)]


def split_rows(pool: Workers | None, count: int, per_worker: int = 2) -> Sequence[slice]:
    """
    Return the row slices to spread `count` rows over `pool`: one slice without a pool.

    `per_worker` slices per thread let the caller take over slices a busy helper has not
    started.
    """
    if pool is None or not pool.parallel:
        return [slice(0, count)]
    return chunks(count, pool.count * per_worker)
