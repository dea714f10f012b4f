"""
The node's input subscription, its reliability matched to the publishers of the topic.

A best-effort subscription loses multi-megabyte clouds from reliable publishers (a lost
fragment drops the whole cloud), and a reliable subscription hears nothing from a best-effort
publisher. :class:`CloudInput` owns the ``cloud_in`` subscription of a node and chooses its
reliability from ``input_reliability``:

* ``auto``: reliable while every publisher of the topic offers reliable delivery (also while
  there is none), best effort as soon as one offers only best effort, as rosbag2's adaptive QoS
  does. The choice is checked again when a publisher is matched or offers an incompatible QoS,
  and every :data:`POLL_S` seconds of wall-clock time (publishers coming and going);
* ``reliable`` or ``best_effort``: forced.

The history is keep last ``input_depth``. A change of the wanted QoS (a parameter change or a
new publisher) destroys the subscription and creates it again. What the middleware reports is
counted: clouds lost on the way (the ``message_lost`` event, where the RMW supports it) and
publishers whose QoS is incompatible.

With a `ready` test (the node's: its frame worker has room), the executor takes a cloud only
while it passes: the subscription sits in a callback group that the executor skips until then
(the owner wakes the executor when it may pass again). The clouds that arrive meanwhile replace
each other in the keep-last history and are never taken, which spares the executor the cost of
taking clouds that would be dropped. Their number is read from the publisher's sequence numbers
(:attr:`CloudInput.skipped`, while one publisher is matched: the message info does not say
which publisher sent a cloud).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, cast

from mvbb_ros.pipeline.stage_settings import InputReliability
from rclpy.callback_groups import CallbackGroup
from rclpy.clock import Clock, ClockType
from rclpy.event_handler import (
    QoSMessageLostInfo,
    QoSRequestedIncompatibleQoSInfo,
    QoSSubscriptionMatchedInfo,
    SubscriptionEventCallbacks,
    UnsupportedEventTypeError,
)
from rclpy.exceptions import InvalidHandle
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.subscription import Subscription
from sensor_msgs.msg import PointCloud2

#: Seconds (wall clock) between checks of the publishers in ``auto`` mode.
POLL_S = 0.5
#: The subscription's topic, before remapping.
INPUT_TOPIC = 'cloud_in'
_POLICIES = {
    'reliable': ReliabilityPolicy.RELIABLE,
    'best_effort': ReliabilityPolicy.BEST_EFFORT,
}


@dataclass(frozen=True)
class InputPublisher:
    """
    One publisher of the input topic, as the ROS graph reports it.

    :ivar node: the publishing node's fully qualified name.
    :ivar reliable: True when it offers reliable delivery.
    """

    node: str
    reliable: bool


def choose_reliability(
    mode: InputReliability, publishers: list[InputPublisher]
) -> InputReliability:
    """
    Return the reliability the subscription needs: `mode`, or for ``auto`` the publishers'.

    ``auto`` is ``reliable`` when every publisher offers reliable delivery (also when there is
    none yet), ``best_effort`` as soon as one does not.
    """
    if mode != 'auto':
        return mode
    return 'reliable' if all(publisher.reliable for publisher in publishers) else 'best_effort'


class CloudInput:
    """
    The ``cloud_in`` subscription of a node, re-created whenever its wanted QoS changes.

    :ivar reliability: the subscription's reliability now (``reliable`` or ``best_effort``).
    :ivar depth: its queue depth now.
    :ivar lost: clouds the middleware reported lost, over every subscription so far; None when
        the RMW does not report lost messages.
    :ivar incompatible: incompatible-QoS events (a publisher the subscription cannot hear).
    :ivar matched: publishers matched with the current subscription.
    :ivar created: how many subscriptions were created (1 + re-creations).
    :ivar skipped: clouds a publisher sent that were never taken, replaced in the history by
        newer ones (the node was busy) or, best effort, lost on the way: the gaps in the
        publisher's sequence numbers while one publisher is matched.

    :param callback: called with each cloud taken and how many of the publisher's clouds were
        skipped just before it.
    :param ready: clouds are taken only while this returns True (None: always); the owner
        wakes the executor when it may have turned True.
    """

    def __init__(
        self,
        node: Node,
        callback: Callable[[PointCloud2, int], None],
        mode: InputReliability,
        depth: int,
        ready: Callable[[], bool] | None = None,
    ) -> None:
        self._node = node
        self._gate = None if ready is None else _Gate(ready)
        self.skipped = 0
        self._last_sequence: int | None = None
        self._callback = callback
        self._mode: InputReliability = mode
        self._wanted_depth = depth
        self.topic_name = node.resolve_topic_name(INPUT_TOPIC)
        self.reliability: InputReliability = 'reliable'
        self.depth = depth
        self.lost: int | None = 0
        self.incompatible = 0
        self.matched = 0
        self.created = 0
        self._subscription: Subscription | None = None
        # Event callbacks and parameter changes only ask for an update; it runs on its own.
        self._update_trigger = node.create_guard_condition(self.update)
        self._poll = node.create_timer(
            POLL_S, self.update, clock=Clock(clock_type=ClockType.STEADY_TIME)
        )
        self.update()

    @property
    def mode(self) -> InputReliability:
        """Return the ``input_reliability`` setting in force."""
        return self._mode

    @property
    def qos(self) -> QoSProfile:
        """Return the QoS the subscription was created with."""
        assert self._subscription is not None
        return self._subscription.qos_profile

    def configure(self, mode: InputReliability, depth: int) -> None:
        """Take new settings; the subscription is re-created (soon) when its QoS changes."""
        self._mode, self._wanted_depth = mode, depth
        self._update_trigger.trigger()

    def publishers(self) -> list[InputPublisher]:
        """Return the publishers of the input topic that the graph knows now."""
        return [
            InputPublisher(
                node=_node_name(info.node_namespace, info.node_name),
                reliable=info.qos_profile.reliability == ReliabilityPolicy.RELIABLE,
            )
            for info in self._node.get_publishers_info_by_topic(self.topic_name)
        ]

    def description(self) -> str:
        """Return the subscription's QoS in words, e.g. ``reliable, keep last 1, auto``."""
        return f'{self.reliability.replace("_", " ")}, keep last {self.depth}, {self._mode}'

    def update(self) -> None:
        """Create the subscription, or create it again when the wanted QoS has changed."""
        publishers = self.publishers()
        wanted = choose_reliability(self._mode, publishers)
        if self._subscription is not None and (wanted, self._wanted_depth) == (
            self.reliability,
            self.depth,
        ):
            return
        if self._subscription is not None:
            self._node.destroy_subscription(self._subscription)
        self.reliability, self.depth, self.matched = wanted, self._wanted_depth, 0
        self._subscription = self._subscribe()
        self.created += 1
        offered = ', '.join(
            f'{p.node} ({"reliable" if p.reliable else "best effort"})' for p in publishers
        )
        self._node.get_logger().info(
            f'listening on {self.topic_name} ({self.description()}); '
            f'publishers: {offered or "none yet"}'
        )

    def _subscribe(self) -> Subscription:
        qos = QoSProfile(
            history=HistoryPolicy.KEEP_LAST,
            depth=self.depth,
            reliability=_POLICIES[self.reliability],
        )

        def create(report_lost: bool) -> Subscription:
            events = SubscriptionEventCallbacks(
                matched=self._on_matched,
                incompatible_qos=self._on_incompatible,
                message_lost=self._on_lost if report_lost else None,
            )
            return self._node.create_subscription(
                PointCloud2,
                INPUT_TOPIC,
                # rclpy passes the message info to a callback of two parameters; its annotation
                # names the one-parameter form only.
                cast(Callable[[PointCloud2], None], self._take),
                qos,
                event_callbacks=events,
                callback_group=self._gate,
            )

        if self.lost is not None:
            try:
                return create(report_lost=True)
            except UnsupportedEventTypeError:  # this RMW does not report lost messages
                self.lost = None
        return create(report_lost=False)

    def take_waiting(self) -> bool:
        """
        Take the oldest cloud the subscription holds now, if any, and pass it on (any thread).

        :return: whether a cloud was taken.
        """
        subscription = self._subscription
        if subscription is None:
            return False
        try:
            with subscription.handle:
                taken = subscription.handle.take_message(subscription.msg_type, subscription.raw)
        except InvalidHandle:  # destroyed meanwhile (a re-creation, the node's end)
            return False
        if taken is None:
            return False
        self._take(*taken)
        return True

    def _take(self, cloud: PointCloud2, info: dict[str, Any]) -> None:
        sequence = info.get('publication_sequence_number')
        gap = 0
        if not isinstance(sequence, int):
            sequence = None
        elif (
            self.matched == 1
            and self._last_sequence is not None
            and sequence > self._last_sequence
        ):
            gap = sequence - self._last_sequence - 1
        self._last_sequence = sequence
        self.skipped += gap
        self._callback(cloud, gap)

    def _on_matched(self, info: QoSSubscriptionMatchedInfo) -> None:
        self.matched = int(info.current_count)
        # Another publisher (or none): its sequence numbers are not comparable with the last.
        self._last_sequence = None
        self._update_trigger.trigger()

    def _on_incompatible(self, info: QoSRequestedIncompatibleQoSInfo) -> None:
        self.incompatible += int(info.total_count_change)
        self._node.get_logger().warning(
            f'a publisher of {self.topic_name} offers a QoS that the subscription '
            f'({self.description()}) cannot hear',
            throttle_duration_sec=5.0,
        )
        self._update_trigger.trigger()

    def _on_lost(self, info: QoSMessageLostInfo) -> None:
        self.lost = (self.lost or 0) + int(info.total_count_change)

    def destroy(self) -> None:
        """Destroy the subscription, its timer and its trigger."""
        if self._subscription is not None:
            self._node.destroy_subscription(self._subscription)
            self._subscription = None
        self._node.destroy_timer(self._poll)
        self._node.destroy_guard_condition(self._update_trigger)


def _node_name(namespace: str, name: str) -> str:
    return f'{namespace.rstrip("/")}/{name}'


class _Gate(CallbackGroup):
    """
    The input's callback group: the executor waits for and takes clouds only while `ready`.

    rclpy's executor leaves an entity out of its wait set while the entity's group cannot
    execute, so a closed gate costs nothing; callbacks may run concurrently (reentrant).
    """

    def __init__(self, ready: Callable[[], bool]) -> None:
        super().__init__()
        self._ready = ready

    def can_execute(self, entity: Any) -> bool:
        """Tell whether the executor may take a cloud now."""
        return self._ready()

    def beginning_execution(self, entity: Any) -> bool:
        """Start a callback (always allowed: the gate was tested when the cloud was taken)."""
        return True

    def ending_execution(self, entity: Any) -> None:
        """End a callback (nothing to release)."""
