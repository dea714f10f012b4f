"""
When the node's input takes a cloud: once the frame worker is free, or as soon as it arrives.

Taking a 300k-point cloud costs about 4 ms on the core that processes the frames, so the node
normally takes a cloud only when its frame worker is free for it (:mod:`mvbb_ros.ros.input`):
clouds that arrive during a frame replace each other in the middleware's history and are never
taken. Whether that pays depends on the publisher's transport. With the project's profile
(``config/fastdds_large_clouds.xml``: a shared-memory segment that holds whole clouds) the next
cloud is waiting when a frame ends. With Fast DDS's default transport the node answered fewer
13 MB clouds that way than taking every cloud as it arrived (its frame thread waited for clouds
about a third of the time; why the transport delivers them later is not known):
``docs/performance.md``, the soak.

:class:`TakePolicy` finds out which pays on the running stream by trying both: after every
:data:`PROBE_EVERY_S` seconds of frames it takes clouds the other way, then the way in force
again, each for :data:`PROBE_SETTLE_S` seconds before and :data:`PROBE_S` seconds of counting
frames (right after a switch the stream still runs as before), and keeps taking every cloud
only when that answered at least :data:`PROBE_MARGIN` more clouds a second (taking when free has
the lower latency: a cloud starts as soon as it is taken). Only with ``input_depth`` 1: a
deeper input exists to process every cloud of a bag, from the middleware's history in order.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
import time

#: Seconds of frames between two probes (the first after this much streaming).
PROBE_EVERY_S = 30.0
#: Seconds after each switch of a probe before its frames count.
PROBE_SETTLE_S = 1.0
#: Seconds of frames counted for each way of taking in a probe.
PROBE_S = 2.0
#: Taking every cloud is kept only when it answered this share more clouds a second.
PROBE_MARGIN = 0.05
#: A probe window that lasted this many times :data:`PROBE_S` (the stream paused) is dropped.
STALE_WINDOW = 3.0


@dataclass(frozen=True)
class ProbeResult:
    """
    One probe's frame rates, clouds a second, and what it chose.

    :ivar when_free: the rate taking a cloud only when the frame worker is free.
    :ivar every_cloud: the rate taking every cloud as it arrives.
    :ivar chose_every_cloud: whether every cloud is taken until the next probe.
    """

    when_free: float
    every_cloud: float
    chose_every_cloud: bool


class TakePolicy:
    """
    Whether the input takes every cloud as it arrives, from probes of the frame rate.

    Driven by :meth:`frame_done`, called after each frame of a new cloud (any thread, one at a
    time); :attr:`every_cloud` is read by the input's gate.

    :param clock: monotonic seconds (injectable for tests).
    :param probe_every_s: :data:`PROBE_EVERY_S`.
    :param probe_s: :data:`PROBE_S`.
    :param settle_s: :data:`PROBE_SETTLE_S`.
    :param enabled: False keeps taking only when free (``input_depth`` above 1).
    """

    def __init__(
        self,
        clock: Callable[[], float] = time.monotonic,
        probe_every_s: float = PROBE_EVERY_S,
        probe_s: float = PROBE_S,
        enabled: bool = True,
        settle_s: float = PROBE_SETTLE_S,
    ) -> None:
        self._clock = clock
        self._probe_every_s = probe_every_s
        self._probe_s = probe_s
        self._settle_s = settle_s
        self.enabled = enabled
        #: Take every cloud as it arrives (else only when the frame worker is free).
        self.every_cloud = False
        #: The last probe that ran to its end, or None.
        self.last_probe: ProbeResult | None = None
        #: Probes run to their end.
        self.probes = 0
        self._kept = False  # the mode chosen by the last probe
        self._next_probe: float | None = None
        self._window: tuple[bool, float] | None = None  # probing: (every_cloud, start)
        self._frames = 0
        self._rates: dict[bool, float] = {}

    def frame_done(self) -> bool:
        """Count one frame of a new cloud; return whether :attr:`every_cloud` changed."""
        before = self.every_cloud
        if not self.enabled:
            self.every_cloud = False
            self._next_probe, self._window = None, None
            return before
        now = self._clock()
        if self._next_probe is None:
            self._next_probe = now + self._probe_every_s
        if self._window is None:
            if now >= self._next_probe:
                # The way not in force first, then the one in force, each for probe_s.
                self._start(not self._kept, now)
        else:
            mode, start = self._window
            if now < start:
                return self.every_cloud != before  # settling after the switch
            self._frames += 1
            elapsed = now - start
            if elapsed > STALE_WINDOW * self._probe_s:
                self._window = None  # the stream paused: try again later
                self.every_cloud = self._kept
                self._next_probe = now + self._probe_every_s
            elif elapsed >= self._probe_s:
                self._rates[mode] = self._frames / elapsed
                if len(self._rates) < 2:
                    self._start(not mode, now)
                else:
                    self._finish(now)
        return self.every_cloud != before

    def _start(self, every_cloud: bool, now: float) -> None:
        self._window = (every_cloud, now + self._settle_s)
        self._frames = 0
        self.every_cloud = every_cloud

    def _finish(self, now: float) -> None:
        free, every = self._rates[False], self._rates[True]
        self._kept = every > free * (1.0 + PROBE_MARGIN)
        self.last_probe = ProbeResult(free, every, self._kept)
        self.probes += 1
        self.every_cloud = self._kept
        self._window, self._rates = None, {}
        self._next_probe = now + self._probe_every_s

    def description(self) -> str:
        """Return how clouds are taken now and why, for the diagnostics."""
        if not self.enabled:
            return 'when the frame worker is free (input_depth above 1)'
        how = 'every cloud as it arrives' if self.every_cloud else 'when the frame worker is free'
        if self._window is not None:
            return f'{how} (probing)'
        probe = self.last_probe
        if probe is None:
            return f'{how} (no probe yet)'
        return (
            f'{how} (last probe: {probe.every_cloud:.1f} clouds/s taking every cloud, '
            f'{probe.when_free:.1f} when free)'
        )
