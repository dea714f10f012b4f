"""
What the node's diagnostics need beyond counters: the input rate and the age of the last cloud.

Both run on the wall clock (``time.monotonic``), never on ROS time: under ``use_sim_time`` with a
paused bag (no ``/clock``) the diagnostics still say how long ago the last cloud came.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
import time

#: Seconds of receptions the input rate is measured over.
RATE_WINDOW_S = 10.0


class ReceptionLog:
    """
    The wall-clock times of the clouds received in the last `window_s` seconds.

    :param window_s: how far back the rate looks.
    :param clock: the time source, seconds (``time.monotonic``; tests pass their own).
    """

    def __init__(
        self, window_s: float = RATE_WINDOW_S, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self._window_s = window_s
        self._clock = clock
        self._times: deque[float] = deque()
        self._last: float | None = None
        self._start = clock()

    def record(self, count: int = 1) -> None:
        """Note that `count` clouds arrived now."""
        now = self._clock()
        self._times.extend([now] * count)
        self._last = now
        self._expire(now)

    def _expire(self, now: float) -> None:
        while self._times and self._times[0] < now - self._window_s:
            self._times.popleft()

    def rate_hz(self) -> float:
        """Return the input rate over the window, Hz (0 with fewer than two clouds in it)."""
        self._expire(self._clock())
        if len(self._times) < 2 or self._times[-1] <= self._times[0]:
            return 0.0
        return (len(self._times) - 1) / (self._times[-1] - self._times[0])

    def age_s(self) -> float | None:
        """Return the seconds since the last cloud arrived; None before the first."""
        return None if self._last is None else self._clock() - self._last

    def waiting_s(self) -> float:
        """Return the seconds since the last cloud, or since the start before the first."""
        return self._clock() - (self._start if self._last is None else self._last)


#: Seconds over which skipped clouds count as a sustained overload.
OVERLOAD_WINDOW_S = 5.0


class OverloadWatch:
    """
    Tell when the node skips clouds for a sustained while: it cannot keep up with the input.

    :param window_s: how far back the counts are compared.
    :param clock: the time source, seconds (``time.monotonic``; tests pass their own).
    """

    def __init__(
        self, window_s: float = OVERLOAD_WINDOW_S, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self._window_s = window_s
        self._clock = clock
        self._samples: deque[tuple[float, int, int]] = deque()

    def update(self, received: int, skipped: int) -> str | None:
        """Record the counters now; return a warning when half the recent clouds were skipped."""
        now = self._clock()
        self._samples.append((now, received, skipped))
        while now - self._samples[0][0] > self._window_s:
            self._samples.popleft()
        start, received_then, skipped_then = self._samples[0]
        came, lost = received - received_then, skipped - skipped_then
        if came >= 5 and 2 * lost >= came:
            return (
                f'overloaded: {lost} of the last {came} clouds were skipped because the node was '
                f'busy ({now - start:.0f} s); lower the input rate or the work per cloud'
            )
        return None
