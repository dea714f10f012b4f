"""
The node's frames on a thread of their own, so that the executor stays free for services.

A cloud is processed off the executor thread (:class:`FrameWorker`): parameter services,
diagnostics and the input's QoS checks answer while a frame is processed. At most `depth`
clouds wait (the node's ``input_depth``, 1 by default): a cloud that arrives when that many
wait pushes out the oldest (counted as skipped, the node was busy), so with depth 1 the next
frame is always the newest cloud, and a deeper input processes every cloud of a bag played
faster than the node. Settings changed during a frame are merged into one re-processing of
the last cloud, after the frame.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
import threading
from typing import Any


class FrameWorker:
    """
    Process the waiting clouds (at most `depth`, oldest first) or the last one again, on a thread.

    :param process: called on the worker thread with a cloud (a new one) or None (process
        the last cloud again with the settings in force).
    :param depth: the most clouds that wait, >= 1 (1: only the newest).
    """

    def __init__(
        self, process: Callable[[Any | None], None], name: str = 'frames', depth: int = 1
    ) -> None:
        self._process = process
        self._condition = threading.Condition()
        self._clouds: deque[Any] = deque(maxlen=_checked_depth(depth))  # not started yet
        self._again = False  # process the last cloud again (settings changed)
        self._busy = False
        self._stopping = False
        #: Clouds pushed out by newer ones before they were started (the node was busy).
        self.skipped = 0
        #: Re-processing requests merged into one already waiting.
        self.merged = 0
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def submit(self, cloud: Any) -> None:
        """Queue `cloud`; when `depth` clouds wait, the oldest is dropped (counted as skipped)."""
        with self._condition:
            if len(self._clouds) == self._clouds.maxlen:
                self.skipped += 1
            self._clouds.append(cloud)
            self._condition.notify_all()

    @property
    def depth(self) -> int:
        """Return the most clouds that wait."""
        with self._condition:
            return self._clouds.maxlen or 1

    def set_depth(self, depth: int) -> None:
        """Let at most `depth` clouds wait from now on (the oldest beyond it are skipped)."""
        with self._condition:
            waiting = deque(self._clouds, maxlen=_checked_depth(depth))
            self.skipped += len(self._clouds) - len(waiting)
            self._clouds = waiting

    def again(self) -> None:
        """Process the last cloud again once the current frame is done (requests merge)."""
        with self._condition:
            if self._again or self._clouds:
                self.merged += 1
            self._again = True
            self._condition.notify_all()

    def idle(self) -> bool:
        """Tell whether nothing is being processed or waiting."""
        with self._condition:
            return not (self._busy or self._again or self._clouds)

    def wait_idle(self, timeout_s: float) -> bool:
        """Wait until nothing is processed or waiting; return whether that happened in time."""
        with self._condition:
            return self._condition.wait_for(
                lambda: not (self._busy or self._again or self._clouds), timeout_s
            )

    def stop(self, timeout_s: float = 10.0) -> None:
        """Finish the frame in progress, drop what waits, and end the thread."""
        with self._condition:
            self._stopping = True
            self._condition.notify_all()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout_s)

    def _run(self) -> None:
        while True:
            with self._condition:
                self._condition.wait_for(lambda: self._stopping or self._again or self._clouds)
                if self._stopping:
                    return
                cloud = self._clouds.popleft() if self._clouds else None
                self._again = False  # a new cloud is processed with the new settings anyway
                self._busy = True
            try:
                self._process(cloud)
            finally:
                with self._condition:
                    self._busy = False
                    self._condition.notify_all()


def _checked_depth(depth: int) -> int:
    """Return `depth`, or raise ValueError when it is below 1."""
    if depth < 1:
        raise ValueError(f'depth must be >= 1, got {depth}')
    return depth
