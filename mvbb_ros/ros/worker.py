"""
The node's frames on a thread of their own, so that the executor stays free for services.

A cloud is processed off the executor thread (:class:`FrameWorker`): parameter services,
diagnostics and the input's QoS checks answer while a frame is processed. Work never queues
up: a cloud that arrives while another waits replaces it (the older one is counted as skipped,
the node was busy), and settings changed during a frame are merged into one re-processing of
the last cloud, after the frame.
"""

from __future__ import annotations

from collections.abc import Callable
import threading
from typing import Any


class FrameWorker:
    """
    Process the newest cloud, or the last one again, on one thread; never queue.

    :param process: called on the worker thread with a cloud (a new one) or None (process
        the last cloud again with the settings in force).
    """

    def __init__(self, process: Callable[[Any | None], None], name: str = 'frames') -> None:
        self._process = process
        self._condition = threading.Condition()
        self._cloud: Any | None = None  # the newest cloud, not started yet
        self._again = False  # process the last cloud again (settings changed)
        self._busy = False
        self._stopping = False
        #: Clouds replaced by a newer one before they were started (the node was busy).
        self.skipped = 0
        #: Re-processing requests merged into one already waiting.
        self.merged = 0
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def submit(self, cloud: Any) -> None:
        """Process `cloud` next; a cloud still waiting is dropped and counted as skipped."""
        with self._condition:
            if self._cloud is not None:
                self.skipped += 1
            self._cloud = cloud
            self._condition.notify_all()

    def again(self) -> None:
        """Process the last cloud again once the current frame is done (requests merge)."""
        with self._condition:
            if self._again or self._cloud is not None:
                self.merged += 1
            self._again = True
            self._condition.notify_all()

    def idle(self) -> bool:
        """Tell whether nothing is being processed or waiting."""
        with self._condition:
            return not (self._busy or self._again or self._cloud is not None)

    def wait_idle(self, timeout_s: float) -> bool:
        """Wait until nothing is processed or waiting; return whether that happened in time."""
        with self._condition:
            return self._condition.wait_for(
                lambda: not (self._busy or self._again or self._cloud is not None), timeout_s
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
                self._condition.wait_for(
                    lambda: self._stopping or self._again or self._cloud is not None
                )
                if self._stopping:
                    return
                cloud, self._cloud = self._cloud, None
                self._again = False  # a new cloud is processed with the new settings anyway
                self._busy = True
            try:
                self._process(cloud)
            finally:
                with self._condition:
                    self._busy = False
                    self._condition.notify_all()
