"""
Play the PointCloud2 messages of a bag onto the live ROS graph (`mvbb bag play`).

Clouds are read with :class:`mvbb_ros.ros.bag.CloudBag` (rosbag2 sqlite3 or MCAP, or ROS 1) and
published, on their recorded topics, as the ROS 2 serialized bytes the bag holds (no decoding),
with the recorded timing divided by the rate. The first cloud goes out at once; a cloud recorded
``d`` seconds after it goes out ``d / rate`` seconds after it.

With ``clock`` the player also publishes ``/clock`` (rosgraph_msgs/Clock) with the bag time, at
``clock_hz`` and at each cloud just before it, so nodes started with ``use_sim_time:=true`` run
on bag time. On a loop, bag time jumps back to the start, as with ``ros2 bag play --loop``.

Publishers are reliable (keep last 10), which reliable and best-effort subscribers both hear.
Before playing, the player waits until a subscriber is matched on every cloud topic (up to
``wait_for_subscribers`` seconds, by default :data:`DEFAULT_WAIT_S`, long enough for DDS
discovery and a node that is still starting), so the first clouds are not lost to discovery;
when none comes it plays nothing and says so (:attr:`PlayStats.subscribers_found` is False).
``wait_for_subscribers=0`` plays at once, subscribed or not. At the end it waits (up to a few
seconds) until reliable subscribers have acknowledged everything.

A message that does not deserialize as a PointCloud2 (corrupt bytes) is not published: it is
counted (:attr:`PlayStats.skipped`) and named in a warning, the first at once and then at most
one warning every :data:`SKIP_WARNING_PERIOD_S` with how many more were skipped.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
import os
from pathlib import Path
import sys
import threading
import time
from typing import TextIO

from builtin_interfaces.msg import Time
from mvbb_ros.common.progress import ProgressBar
from mvbb_ros.ros.bag import BagCloud, CloudBag, SkippedMessage
import rclpy
from rclpy.context import Context
from rclpy.duration import Duration
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import PointCloud2

#: Default rate of /clock messages, Hz (as ``ros2 bag play --clock``).
DEFAULT_CLOCK_HZ = 40.0
#: Default wait for subscribers before playing, seconds: DDS discovery takes up to a few
#: seconds, and a node started at the same time needs several more to import its libraries.
DEFAULT_WAIT_S = 30.0
#: How long to wait at the end for reliable subscribers to acknowledge the last clouds, seconds.
ACK_TIMEOUT_S = 5.0
#: Depth of the publishers' queues.
QUEUE_DEPTH = 10
#: At most one warning about skipped (corrupt) messages in this many seconds.
SKIP_WARNING_PERIOD_S = 5.0


@dataclass
class PlayStats:
    """
    What a playback did.

    :ivar topics: the cloud topics played.
    :ivar published: clouds published (over all loops).
    :ivar clock_messages: /clock messages published.
    :ivar loops: complete passes through the bag.
    :ivar seconds: wall-clock time of the playback (after waiting for subscribers).
    :ivar interrupted: True when stopped (SIGINT) before the end.
    :ivar subscribers_found: False when the wait for subscribers timed out (nothing was
        played then).
    :ivar skipped: messages not published because they do not deserialize (over all loops).
    """

    topics: list[str]
    published: int = 0
    clock_messages: int = 0
    loops: int = 0
    seconds: float = 0.0
    interrupted: bool = False
    subscribers_found: bool = True
    skipped: int = 0


class SkipWarnings:
    """
    Count skipped messages; warn about the first at once, then at most once per period.

    :param log: where the warnings go.
    :param period_s: the least time between two warnings, seconds.
    :param clock: the time source (seconds); the tests pass their own.
    """

    def __init__(
        self,
        log: TextIO,
        period_s: float = SKIP_WARNING_PERIOD_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.log = log
        self.period_s = period_s
        self.clock = clock
        self.count = 0
        self._unreported = 0
        self._last: float | None = None

    def __call__(self, message: SkippedMessage) -> None:
        """Count `message`; print a warning when none was printed within the period."""
        self.count += 1
        self._unreported += 1
        now = self.clock()
        if self._last is not None and now - self._last < self.period_s:
            return
        more = (
            f' ({self._unreported - 1} more since the last warning)'
            if self._last is not None
            else ''
        )
        print(
            f'warning: not published: {message.describe()}{more}; {self.count} skipped so far',
            file=self.log,
        )
        self._last, self._unreported = now, 0


def wall_offset_s(timestamp_ns: int, first_ns: int, rate: float) -> float:
    """Return when (seconds after the first cloud) a cloud recorded at `timestamp_ns` is due."""
    return max(0, timestamp_ns - first_ns) / 1e9 / rate


def _clock_message(bag_time_ns: int) -> Clock:
    sec, nanosec = divmod(int(bag_time_ns), 1_000_000_000)
    return Clock(clock=Time(sec=sec, nanosec=nanosec))


class _Player:
    """The ROS side of a playback: one node with a publisher per cloud topic and /clock."""

    def __init__(self, topics: list[str], clock: bool) -> None:
        self.context = Context()
        # Signals stay ours: SIGINT ends the playback cleanly instead of raising in rclpy.
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        try:
            self.node = rclpy.create_node(f'mvbb_bag_play_{os.getpid()}', context=self.context)
        except BaseException:
            rclpy.try_shutdown(context=self.context)
            raise
        qos = QoSProfile(
            history=HistoryPolicy.KEEP_LAST,
            depth=QUEUE_DEPTH,
            reliability=ReliabilityPolicy.RELIABLE,
        )
        self.clouds = {
            topic: self.node.create_publisher(PointCloud2, topic, qos) for topic in topics
        }
        self.clock = self.node.create_publisher(Clock, '/clock', qos) if clock else None

    def all_subscribed(self) -> bool:
        return all(publisher.get_subscription_count() > 0 for publisher in self.clouds.values())

    def publish_clock(self, bag_time_ns: int) -> None:
        if self.clock is not None:
            self.clock.publish(_clock_message(bag_time_ns))

    def wait_for_acks(self, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        for publisher in (*self.clouds.values(), self.clock):
            if publisher is not None:
                remaining = max(0.0, deadline - time.monotonic())
                publisher.wait_for_all_acked(Duration(seconds=remaining))

    def close(self) -> None:
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def play_bag(
    path: str | os.PathLike[str],
    *,
    topic: str | None = None,
    rate: float = 1.0,
    loop: bool = False,
    clock: bool = False,
    clock_hz: float = DEFAULT_CLOCK_HZ,
    wait_for_subscribers: float = DEFAULT_WAIT_S,
    stop: threading.Event | None = None,
    progress: bool | None = None,
    log: TextIO | None = None,
    on_publish: Callable[[BagCloud], None] | None = None,
) -> PlayStats:
    """
    Publish the clouds of a bag with their recorded timing; return when done or stopped.

    :param path: any bag :class:`~mvbb_ros.ros.bag.CloudBag` reads.
    :param topic: the cloud topic to play; None plays every PointCloud2 topic.
    :param rate: playback speed factor (2 plays twice as fast); > 0.
    :param loop: start again at the end, until `stop` is set.
    :param clock: also publish /clock with the bag time.
    :param clock_hz: /clock rate, Hz; > 0.
    :param wait_for_subscribers: seconds to wait for a subscriber on every cloud topic before
        playing; when none comes in that time nothing is played. 0 plays at once, subscribed
        or not.
    :param stop: set it (from a signal handler or another thread) to end the playback.
    :param progress: draw a progress bar on `log`; None draws it only on a terminal.
    :param log: where messages and the bar go; None means stderr.
    :param on_publish: called after each cloud is published.
    :return: what was played.
    :raises mvbb_ros.ros.bag.BagError: for a missing or unreadable bag, or a bad topic.
    :raises ValueError: for a rate or clock rate that is not positive.
    """
    if not rate > 0.0:
        raise ValueError(f'rate must be > 0, got {rate}')
    if clock and not clock_hz > 0.0:
        raise ValueError(f'clock rate must be > 0 Hz, got {clock_hz}')
    stop = stop if stop is not None else threading.Event()
    log = log if log is not None else sys.stderr
    with CloudBag(Path(path)) as bag:
        topics = bag.select_topics(topic)
        total = bag.count(topics)
        stats = PlayStats(topics=topics)
        player = _Player(topics, clock)
        try:
            stats.subscribers_found = _wait_for_subscribers(
                player, wait_for_subscribers, stop, log
            )
            if stop.is_set():
                stats.interrupted = True
                return stats
            if not stats.subscribers_found:
                print(
                    f'no subscriber on {", ".join(topics)} after {wait_for_subscribers:g} s '
                    f'(ROS_DOMAIN_ID={os.environ.get("ROS_DOMAIN_ID", "0")}); nothing played '
                    '(--wait-for-subscribers 0 plays without waiting)',
                    file=log,
                )
                return stats
            bar = ProgressBar(total, label='playing', stream=log, enabled=progress)
            skip_warnings = SkipWarnings(log)

            def skip(message: SkippedMessage) -> None:
                bar.close()
                skip_warnings(message)
                stats.skipped = skip_warnings.count

            start = time.monotonic()
            try:
                while not stop.is_set():
                    finished = _play_once(
                        bag, topics, player, rate, clock_hz, stop, bar, stats, on_publish, skip
                    )
                    if not finished:
                        break
                    stats.loops += 1
                    if not loop:
                        break
            finally:
                bar.close()
                stats.seconds = time.monotonic() - start
            stats.interrupted = stop.is_set()
            player.wait_for_acks(0.5 if stats.interrupted else ACK_TIMEOUT_S)
        finally:
            player.close()
    return stats


def _wait_for_subscribers(
    player: _Player, timeout_s: float, stop: threading.Event, log: TextIO
) -> bool:
    if timeout_s <= 0.0:
        return True
    if not player.all_subscribed():
        print(
            f'waiting up to {timeout_s:g} s for a subscriber on {", ".join(player.clouds)}',
            file=log,
        )
    deadline = time.monotonic() + timeout_s
    while not player.all_subscribed():
        if time.monotonic() >= deadline or stop.is_set():
            return player.all_subscribed()
        stop.wait(0.02)
    return True


def _play_once(
    bag: CloudBag,
    topics: list[str],
    player: _Player,
    rate: float,
    clock_hz: float,
    stop: threading.Event,
    bar: ProgressBar,
    stats: PlayStats,
    on_publish: Callable[[BagCloud], None] | None,
    on_skip: Callable[[SkippedMessage], None],
) -> bool:
    """Play the bag once; return False when stopped before the end."""
    clock_period_s = 1.0 / clock_hz
    total = bar.total or 0
    first_ns: int | None = None
    start = time.monotonic()
    next_clock = start
    for index, cloud in enumerate(bag.clouds(topics, on_skip=on_skip)):
        if first_ns is None:
            first_ns = cloud.timestamp_ns
        due = start + wall_offset_s(cloud.timestamp_ns, first_ns, rate)
        while True:
            now = time.monotonic()
            if player.clock is not None and now >= next_clock:
                # Bag time, but never past the cloud not yet published: /clock never goes back.
                bag_now = first_ns + round((now - start) * rate * 1e9)
                player.publish_clock(min(bag_now, cloud.timestamp_ns))
                stats.clock_messages += 1
                next_clock = now + clock_period_s
            if now >= due:
                break
            wake = min(due, next_clock) if player.clock is not None else due
            if stop.wait(max(0.0, min(wake - now, 0.1))):
                return False
            bar.update(index, _bar_text(now - start, rate, first_ns, cloud))
        if player.clock is not None:
            player.publish_clock(cloud.timestamp_ns)
            stats.clock_messages += 1
        player.clouds[cloud.topic].publish(cloud.cdr)
        stats.published += 1
        if on_publish is not None:
            on_publish(cloud)
        bar.update(index + 1, f'{cloud.topic}', force=index + 1 == total)
    return True


def _bar_text(elapsed_s: float, rate: float, first_ns: int, cloud: BagCloud) -> str:
    bag_elapsed = elapsed_s * rate
    next_in = (cloud.timestamp_ns - first_ns) / 1e9
    return f'bag time {bag_elapsed:.1f} s, next cloud at {next_in:.1f} s (x{rate:g})'
