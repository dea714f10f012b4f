"""
How long a frame keeps other Python threads waiting for the GIL, and where.

Run from the repository root::

    PYTHONPATH=. .venv/bin/python benchmarks/gil_stalls.py               # 4 frames, 10 ms
    PYTHONPATH=. .venv/bin/python benchmarks/gil_stalls.py --frames 8 --threshold-ms 5

The node processes its frames on a worker thread (``mvbb_ros/ros/worker.py``) while its executor
thread answers services; whatever holds the GIL on the worker delays those answers. Here the
pipeline runs on the 300-blob cloud of ``benchmarks/abuse.py`` (node defaults) on a worker
thread, after one frame that pays the first frame's one-off costs, while the main thread sleeps
1 ms in a loop and records how much later than asked each sleep ends (it needs the GIL to wake).
A wake-up later than the threshold is a stall; it is attributed to the worker's stack at that
moment (three innermost frames): a stall ends when the worker gives the GIL up, which for a
compiled kernel holding it is right after its call. The table lists the places by longest stall.
The delays also count the machine's other load: compare runs in the same state.
"""

from __future__ import annotations

import argparse
from collections import defaultdict
from pathlib import Path
import sys
import threading
import time
import traceback

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))  # the abuse suite's cloud

#: The main thread's sleep per wake-up, seconds.
SLEEP_S = 0.001


def _place(frame: object) -> str:
    """Return the three innermost Python frames of a stack, innermost first, package-relative."""
    stack = traceback.extract_stack(frame)[-3:]  # type: ignore[arg-type]
    return ' <- '.join(
        f'{item.filename.split("/mvbb_ros/")[-1].split("/site-packages/")[-1]}:{item.lineno} '
        f'{item.name}'
        for item in reversed(stack)
    )


def main() -> int:
    """Run the frames on a worker thread, time the main thread's wake-ups, print the table."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--frames', type=int, default=4, help='frames measured (default 4)')
    parser.add_argument(
        '--threshold-ms', type=float, default=10.0, help='a later wake-up is a stall (10 ms)'
    )
    args = parser.parse_args()

    from abuse import blobs_cloud
    from mvbb_ros.kernels import warm_up
    from mvbb_ros.pipeline.process import process_points

    warm_up()
    cloud = blobs_cloud()
    process_points(cloud)  # the first frame's one-off costs
    frame_seconds: list[float] = []
    done = threading.Event()

    def work() -> None:
        for _ in range(args.frames):
            start = time.perf_counter()
            process_points(cloud)
            frame_seconds.append(time.perf_counter() - start)
        done.set()

    worker = threading.Thread(target=work, name='frames')
    worker.start()
    delays: list[float] = []
    places: dict[str, list[float]] = defaultdict(list)
    while not done.is_set():
        start = time.perf_counter()
        time.sleep(SLEEP_S)
        delay_ms = (time.perf_counter() - start - SLEEP_S) * 1e3
        delays.append(delay_ms)
        frame = sys._current_frames().get(worker.ident or -1)
        if delay_ms > args.threshold_ms and frame is not None:
            places[_place(frame)].append(delay_ms)
    worker.join()
    late = np.array(delays)
    print(
        f'{args.frames} frames of the 300-blob cloud on a worker thread: median '
        f'{np.median(frame_seconds):.2f} s'
    )
    print(
        f'main-thread wake-ups: {len(late)}, delay median {np.median(late):.2f} ms, p99 '
        f'{np.percentile(late, 99):.1f} ms, max {late.max():.1f} ms; '
        f'over {args.threshold_ms:g} ms: {int((late > args.threshold_ms).sum())}'
    )
    if places:
        print('| stalls | longest ms | total ms | where the worker was (innermost first) |')
        print('| --- | --- | --- | --- |')
        for place, stalls in sorted(places.items(), key=lambda item: -max(item[1])):
            print(f'| {len(stalls)} | {max(stalls):.1f} | {sum(stalls):.1f} | {place} |')
    return 0


if __name__ == '__main__':
    sys.exit(main())
