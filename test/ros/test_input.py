"""
The input's reliability matches its publishers (issue 18, item 1), through a real rclpy graph.

Clouds come from another process (:class:`ros_graph.CloudSource`): only the middleware's real
transport loses a multi-megabyte cloud on a best-effort subscription.
"""

from __future__ import annotations

from mvbb_ros.pipeline.settings import validate_setting
from mvbb_ros.ros.input import choose_reliability, InputPublisher
from mvbb_ros.ros.node import DecomposerNode, UnknownParameterError
import pytest
import rclpy
from rclpy.context import Context
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2
from support.ros_graph import CloudSource, Graph, set_parameter

pytestmark = pytest.mark.ros

#: A 300k-point cloud: 3.6 MB, as a depth camera's frame.
BIG = 300_000


@pytest.fixture
def graph():
    graph = Graph()
    yield graph
    graph.close()


def _wait_until_heard(graph: Graph, source: CloudSource, reliability: str) -> None:
    """Spin until the input has `reliability` and is matched with the source, both ways."""
    cloud_input = graph.node.cloud_input
    assert graph.spin_until(
        lambda: (
            cloud_input.reliability == reliability
            and cloud_input.matched >= 1
            and source.subscription_count() >= 1
        ),
        timeout_s=60.0,
    ), f'input {cloud_input.description()}, matched {cloud_input.matched}'


def _endpoint_qos(graph: Graph) -> QoSProfile:
    """Return the input's QoS as the graph reports it, once a replaced one has left it."""

    def single() -> bool:
        return len(graph.node.get_subscriptions_info_by_topic('/cloud_in')) == 1

    assert graph.spin_until(single, timeout_s=10.0), 'one input subscription at a time'
    return graph.node.get_subscriptions_info_by_topic('/cloud_in')[0].qos_profile


def test_auto_rule_reliable_only_when_every_publisher_offers_it():
    reliable, best_effort = InputPublisher('/a', True), InputPublisher('/b', False)
    assert choose_reliability('auto', []) == 'reliable'
    assert choose_reliability('auto', [reliable, reliable]) == 'reliable'
    assert choose_reliability('auto', [reliable, best_effort]) == 'best_effort'
    assert choose_reliability('best_effort', [reliable]) == 'best_effort'
    assert choose_reliability('reliable', [best_effort]) == 'reliable'


def test_big_clouds_from_a_reliable_publisher_are_all_answered_by_default(graph):
    with CloudSource('reliable') as source:
        _wait_until_heard(graph, source, 'reliable')
        assert graph.node.cloud_input.qos.depth == 1, 'keep last 1 stays the default'
        answered = 0
        for sec in (1, 2, 3):
            source.publish(sec, BIG)  # once each: no second chance
            answered += graph.wait_for_answer(sec, 60.0)
        assert answered == 3, f'{answered} of 3 clouds of {BIG} points answered'
        assert graph.node._stats['clouds_received'] == 3


def test_best_effort_publishers_are_still_answered(graph):
    with CloudSource('best_effort') as source:
        _wait_until_heard(graph, source, 'best_effort')
        assert _endpoint_qos(graph).reliability == ReliabilityPolicy.BEST_EFFORT
        for sec in (1, 2):  # best effort may drop one; a camera sends the next
            for _ in range(20):
                source.publish(sec)
                if graph.wait_for_answer(sec, 2.0):
                    break
            assert graph.answer(sec) is not None, f'cloud {sec} of a best-effort publisher'


def test_auto_is_checked_again_as_publishers_come_and_go(graph):
    with CloudSource('reliable') as reliable:
        _wait_until_heard(graph, reliable, 'reliable')
        with CloudSource('best_effort') as best_effort:
            _wait_until_heard(graph, best_effort, 'best_effort')
        # The best-effort publisher is gone: every publisher left offers reliable delivery.
        _wait_until_heard(graph, reliable, 'reliable')
        assert _endpoint_qos(graph).reliability == ReliabilityPolicy.RELIABLE
        assert graph.node.cloud_input.created >= 3
        reliable.publish(7, BIG)
        assert graph.wait_for_answer(7, 60.0)


def test_input_reliability_and_depth_are_settable_at_runtime(graph):
    created = graph.node.cloud_input.created
    ok, reason = set_parameter(graph, 'input_reliability', 'best_effort')
    assert ok, reason
    assert graph.spin_until(
        lambda: _endpoint_qos(graph).reliability == ReliabilityPolicy.BEST_EFFORT
    ), 'the subscription is re-created best effort'
    ok, reason = set_parameter(graph, 'input_depth', 5)
    assert ok, reason
    assert graph.spin_until(lambda: graph.node.cloud_input.qos.depth == 5)
    assert graph.node.cloud_input.qos.history == HistoryPolicy.KEEP_LAST
    assert graph.node.cloud_input.created == created + 2
    ok, reason = set_parameter(graph, 'input_reliability', 'sometimes')
    assert not ok and 'auto' in reason
    ok, reason = set_parameter(graph, 'input_depth', 0)
    assert not ok and 'input_depth' in reason
    assert _endpoint_qos(graph).reliability == ReliabilityPolicy.BEST_EFFORT, 'old value kept'


def test_forced_reliable_input_reports_a_best_effort_publisher(graph):
    ok, reason = set_parameter(graph, 'input_reliability', 'reliable')
    assert ok, reason
    qos = QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.BEST_EFFORT
    )
    graph.probe.create_publisher(PointCloud2, 'cloud_in', qos)
    assert graph.spin_until(lambda: graph.node.cloud_input.incompatible > 0, 30.0)
    assert graph.node.cloud_input.reliability == 'reliable', 'forced: it stays reliable'

    def warned() -> bool:
        status = graph.diagnostics[-1].status[0] if graph.diagnostics else None
        return status is not None and 'best-effort publisher' in status.message

    assert graph.spin_until(warned, 10.0)


def test_lost_clouds_show_in_the_diagnostics(graph):
    ok, reason = set_parameter(graph, 'input_reliability', 'best_effort')
    assert ok, reason
    with CloudSource('reliable') as source:
        _wait_until_heard(graph, source, 'best_effort')
        sent = answered = 0
        cloud_input = graph.node.cloud_input
        while sent < 10 and not cloud_input.lost:
            sent += 1
            source.publish(sent, BIG)
            answered += graph.wait_for_answer(sent, 5.0)
            source.publish(100 + sent, 100)  # a small one after it: a gap shows a loss
            graph.wait_for_answer(100 + sent, 5.0)
        # The middleware reports the clouds it loses (Fast DDS does), or it lost none.
        assert cloud_input.lost is not None
        assert cloud_input.lost >= 1 or answered == sent

        def reported() -> bool:
            if not graph.diagnostics:
                return False
            values = {kv.key: kv.value for kv in graph.diagnostics[-1].status[0].values}
            return values.get('clouds_lost') == str(cloud_input.lost)

        assert graph.spin_until(reported, 10.0)


def test_the_old_reliable_input_parameter_fails_naming_its_replacement():
    assert 'input_reliability' in validate_setting('reliable_input', True)
    context = Context()
    rclpy.init(context=context)
    try:
        with pytest.raises(UnknownParameterError, match='input_reliability: reliable'):
            DecomposerNode(
                context=context, parameter_overrides=[Parameter('reliable_input', value=True)]
            )
    finally:
        rclpy.try_shutdown(context=context)
