"""
The node's diagnostics (issue 18, item 4), through a real rclpy graph.

On the wall clock, so that they go on under ``use_sim_time`` without ``/clock``; received and
re-processed clouds counted apart; input rate, age of the last cloud and a stale warning.
"""

from __future__ import annotations

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticStatus
from mvbb_ros.evaluation.synthetic import cut_table_top_frame
from mvbb_ros.pipeline.process import process_points
from mvbb_ros.pipeline.settings import PipelineSettings
from mvbb_ros.ros.diagnostics import ReceptionLog
from mvbb_ros.ros.encode import create_cloud_xyz
import pytest
from rclpy.parameter import Parameter
from support.ros_graph import Graph, set_parameter
from support.shapes import l_shape_points

pytestmark = pytest.mark.ros


def _values(status: DiagnosticStatus) -> dict[str, str]:
    return {kv.key: kv.value for kv in status.values}


def _statuses(graph: Graph) -> list[DiagnosticStatus]:
    return [
        status
        for array in graph.diagnostics
        for status in array.status
        if status.name.startswith('decomposer')
    ]


def _cloud(sec: int):
    cloud = create_cloud_xyz(l_shape_points(), frame_id='camera')
    cloud.header.stamp = Time(sec=sec, nanosec=0)
    return cloud


def test_reception_log_rate_and_age():
    now = [100.0]
    log = ReceptionLog(window_s=10.0, clock=lambda: now[0])
    assert log.age_s() is None and log.rate_hz() == 0.0
    now[0] = 103.0
    assert log.waiting_s() == 3.0, 'before the first cloud: since the start'
    for _ in range(5):
        log.record()
        now[0] += 0.5
    assert log.rate_hz() == pytest.approx(2.0)
    assert log.age_s() == pytest.approx(0.5)
    now[0] += 20.0
    assert log.rate_hz() == 0.0, 'the receptions left the window'
    assert log.age_s() == pytest.approx(20.5)


def test_diagnostics_arrive_under_sim_time_without_a_clock():
    graph = Graph(parameter_overrides=[Parameter('use_sim_time', value=True)])
    try:
        assert graph.node.get_clock().now().nanoseconds == 0, 'no /clock: ROS time stands still'
        assert graph.spin_until(lambda: len(_statuses(graph)) >= 3, timeout_s=15.0)
        status = _statuses(graph)[-1]
        assert status.hardware_id == '/cloud_in'
        assert status.level == DiagnosticStatus.OK and status.message == 'waiting for clouds'
        values = _values(status)
        assert values['last_cloud_age_s'] == 'never'
        assert values['input_qos'] == 'reliable, keep last 1, auto'
        assert values['clouds_lost'] == '0'
    finally:
        graph.close()


def test_received_and_reprocessed_clouds_are_counted_apart_with_rate_and_age():
    graph = Graph()
    try:
        publisher = graph.publisher()
        for sec in (1, 2, 3):
            graph.publish_until_answered(publisher, _cloud(sec))
        received = graph.node._stats['clouds_received']
        assert received >= 3
        ok, reason = set_parameter(graph, 'gain_threshold', 0.5)
        assert ok, reason
        assert graph.spin_until(lambda: graph.node._stats['clouds_reprocessed'] == 1)

        def counted() -> bool:
            statuses = _statuses(graph)
            return bool(statuses) and _values(statuses[-1])['clouds_reprocessed'] == '1'

        assert graph.spin_until(counted, timeout_s=10.0)
        status = _statuses(graph)[-1]
        values = _values(status)
        assert values['clouds_received'] == str(received), 'a parameter change is no new cloud'
        assert values['clouds_processed'] == str(received)
        assert float(values['input_rate_hz']) > 0.0
        assert 0.0 <= float(values['last_cloud_age_s']) < 10.0
        assert int(values['boxes']) >= 1 and int(values['grasps']) >= 1
        assert status.level == DiagnosticStatus.OK
    finally:
        graph.close()


def test_a_stale_input_warns():
    graph = Graph(parameter_overrides=[Parameter('stale_after', value=1.0)])
    try:
        graph.publish_until_answered(graph.publisher(), _cloud(1))

        def stale() -> bool:
            statuses = _statuses(graph)
            return bool(statuses) and 'stale input' in statuses[-1].message

        assert graph.spin_until(stale, timeout_s=15.0)
        status = _statuses(graph)[-1]
        assert status.level == DiagnosticStatus.WARN
        assert float(_values(status)['last_cloud_age_s']) > 1.0
        assert 'since the last one' in status.message
    finally:
        graph.close()


def test_a_cloud_in_millimetres_is_named_in_the_diagnostics():
    graph = Graph()
    try:
        cloud = create_cloud_xyz(l_shape_points() * 1000.0, frame_id='camera')
        cloud.header.stamp = Time(sec=7, nanosec=0)
        grasps = graph.publish_until_answered(graph.publisher(), cloud)
        assert len(grasps.poses) == 0, 'the region of interest (3 m) drops a cloud in mm'

        def hinted() -> bool:
            return any('units' in _values(status) for status in _statuses(graph))

        assert graph.spin_until(hinted, timeout_s=10.0)
        status = next(s for s in reversed(_statuses(graph)) if 'units' in _values(s))
        assert _values(status)['units'].startswith('looks like millimetres: ')
        assert status.level == DiagnosticStatus.WARN
    finally:
        graph.close()


def test_objects_cut_by_the_views_edge_are_named_in_the_diagnostics():
    points, _, _ = cut_table_top_frame(9, 5)
    expected = process_points(points, PipelineSettings())
    assert expected.cut_objects
    graph = Graph()
    try:
        cloud = create_cloud_xyz(points, frame_id='camera')
        cloud.header.stamp = Time(sec=3, nanosec=0)
        grasps = graph.publish_until_answered(graph.publisher(), cloud)
        assert len(grasps.poses) == len(expected.grasps)

        def named() -> bool:
            return any('cut_by_view_edge' in _values(status) for status in _statuses(graph))

        assert graph.spin_until(named, timeout_s=10.0)
        status = next(s for s in reversed(_statuses(graph)) if 'cut_by_view_edge' in _values(s))
        numbers = ', '.join(str(index) for index in expected.cut_objects)
        assert _values(status)['cut_by_view_edge'] == numbers
    finally:
        graph.close()


def test_the_frame_time_budget_degrades_and_says_so():
    graph = Graph(parameter_overrides=[Parameter('frame_time_budget', value=1e-6)])
    try:
        publisher = graph.publisher()
        graph.publish_until_answered(publisher, _cloud(1))
        graph.publish_until_answered(publisher, _cloud(2))

        def degraded() -> bool:
            return any(_values(s).get('frame_budget_level') == '2' for s in _statuses(graph))

        assert graph.spin_until(degraded, timeout_s=10.0)
        status = next(s for s in reversed(_statuses(graph)) if 'frame_budget' in _values(s))
        assert _values(status)['frame_budget'].startswith('frame_time_budget: level 1 of 6')
        assert 'voxel_size 0.005 -> 0.01 m' in status.message
        assert status.level == DiagnosticStatus.WARN
        assert graph.node.settings.filtering.voxel_size == 0.005, 'the parameter is unchanged'
    finally:
        graph.close()
