"""The shared pools of worker threads: results in order, nothing nested, errors raised."""

from __future__ import annotations

import os
import threading

from mvbb_ros.common.workers import (
    check_count,
    chunks,
    default_workers,
    gather,
    in_helper,
    MAX_WORKERS,
    split_rows,
    Workers,
    workers,
)
import pytest


def test_the_default_is_the_cores_this_process_may_use_at_most_eight():
    assert default_workers() == min(len(os.sched_getaffinity(0)), 8)


@pytest.mark.parametrize('bad', [0, -1, MAX_WORKERS + 1, 1.0, True, '2', None])
def test_a_count_below_one_or_not_an_integer_is_refused(bad):
    with pytest.raises(ValueError, match='workers must be an integer'):
        check_count(bad)
    with pytest.raises(ValueError, match='workers must be an integer'):
        workers(bad)


def test_one_worker_runs_everything_on_the_calling_thread():
    pool = workers(1)
    caller = threading.get_ident()
    assert not pool.parallel
    assert pool.spread(lambda _: threading.get_ident(), range(5)) == [caller] * 5
    assert pool.submit(threading.get_ident).result() == caller


def test_spread_keeps_the_order_and_uses_the_helpers():
    pool = workers(3)
    release = threading.Barrier(3, timeout=10.0)

    def meet(item: int) -> tuple[int, int]:
        release.wait()  # three items run at once, or this times out
        return item * item, threading.get_ident()

    results = pool.spread(meet, range(3))
    assert [square for square, _ in results] == [0, 1, 4]
    assert len({thread for _, thread in results}) == 3
    assert pool.spread(lambda item: -item, range(100)) == [-item for item in range(100)]


def test_calls_from_a_helper_run_inline_so_nothing_waits_on_itself():
    pool = workers(2)

    def outer(item: int) -> tuple[bool, list[int]]:
        inner = pool.spread(lambda value: value + item, range(4))  # would deadlock if queued
        return in_helper(), inner

    results = pool.spread(outer, range(4))
    assert [inner for _, inner in results] == [[v + i for v in range(4)] for i in range(4)]
    assert not in_helper()


def test_the_caller_runs_what_no_helper_started():
    pool = Workers(2)
    try:
        started = threading.Event()
        hold = threading.Event()
        blocker = pool.submit(lambda: (started.set(), hold.wait(10.0))[1])
        assert started.wait(10.0)
        caller = threading.get_ident()
        tasks = [pool.submit(threading.get_ident) for _ in range(3)]
        assert gather(tasks) == [caller] * 3, 'the only helper is busy: the caller ran them'
        hold.set()
        assert blocker.result() is True
    finally:
        pool.close()


def test_an_error_in_a_task_is_raised_to_the_caller():
    def fail(item: int) -> int:
        if item == 2:
            raise RuntimeError('item 2')
        return item

    with pytest.raises(RuntimeError, match='item 2'):
        workers(2).spread(fail, range(4))


def test_row_slices_cover_every_row_once():
    for count in (0, 1, 5, 17, 1000):
        for parts in (1, 2, 3, 8):
            slices = chunks(count, parts)
            covered = [row for part in slices for row in range(count)[part]]
            assert covered == list(range(count))
            sizes = [len(range(count)[part]) for part in slices]
            assert max(sizes, default=0) - min(sizes, default=0) <= 1
    assert split_rows(None, 10) == [slice(0, 10)]
    assert split_rows(workers(1), 10) == [slice(0, 10)]
    assert len(split_rows(workers(2), 10)) == 4


def test_a_forked_child_makes_its_own_pool():
    parent = workers(2)
    read, write = os.pipe()
    child = os.fork()
    if child == 0:  # the child: the parent's helper threads do not exist here
        try:
            pool = workers(2)
            ok = pool is not parent and pool.spread(lambda item: item * 2, range(6)) == [
                0, 2, 4, 6, 8, 10,
            ]  # fmt: skip
            os.write(write, b'1' if ok else b'0')
        finally:
            os._exit(0)
    os.close(write)
    answer = os.read(read, 1)
    os.close(read)
    os.waitpid(child, 0)
    assert answer == b'1'
    assert workers(2) is parent
