"""
The node's frames on a thread of their own, so that the executor stays free for services.

A cloud is processed off the executor thread (:class:`FrameWorker`): parameter services,
diagnostics and the input's QoS checks answer while a frame is processed. The node's input
takes a cloud from the middleware only while fewer than `depth` clouds are in the worker, the
one being processed included (the node's ``input_depth``, 1 by default;
:meth:`FrameWorker.has_room`, :mod:`mvbb_ros.ros.input`). Meanwhile newer clouds replace older
ones in the subscription's keep-last history: with depth 1 the next frame is the newest cloud
when the worker becomes free, and a cloud that would be dropped costs no take (about 4 ms for a
300k-point frame, on the core that processes the frames). A deeper input processes every cloud
of a bag played faster than the node. At most `depth` clouds wait: one submitted beyond that
pushes out the oldest (counted as skipped). Settings changed during a frame are merged
into one re-processing of the last cloud, after the frame.
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
    :param depth: the most clouds that wait, >= 1; :meth:`has_room` counts the one being
        processed too.
    :param take: called on the worker's thread after each frame, before the next is chosen and
        while the frame still counts (no room): the node takes the newest waiting cloud here and
        submits it, so that it goes before a re-processing of the last cloud.
    :param on_room: called on the worker's thread after each frame, once room is open (the node
        wakes its executor, which then waits for the next cloud).
    """

    def __init__(
        self,
        process: Callable[[Any | None], None],
        name: str = 'frames',
        depth: int = 1,
        *,
        take: Callable[[], object] | None = None,
        on_room: Callable[[], None] | None = None,
    ) -> None:
        self._process = process
        self._take = take
        self._on_room = on_room
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

    def has_room(self) -> bool:
        """Tell whether a cloud submitted now would push out none: fewer than `depth` in here."""
        with self._condition:
            return int(self._busy) + len(self._clouds) < (self._clouds.maxlen or 1)

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
                if self._take is not None:
                    self._take()
                with self._condition:
                    self._busy = False
                    self._condition.notify_all()
                if self._on_room is not None:
                    self._on_room()


def _checked_depth(depth: int) -> int:
    """Return `depth`, or raise ValueError when it is below 1."""
    if depth < 1:
        raise ValueError(f'depth must be >= 1, got {depth}')
    return depth
