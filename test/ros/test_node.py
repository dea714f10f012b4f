"""End-to-end tests of the decomposer node through a real rclpy graph (localhost, own domain)."""

from __future__ import annotations

import os
from pathlib import Path
import signal
import subprocess
import sys
import time

from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseArray
from mvbb_ros.ros.encode import create_cloud_xyz
import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import PointCloud2
from support.ros_graph import Graph, set_parameter
from support.shapes import l_shape_points
from visualization_msgs.msg import Marker, MarkerArray

pytestmark = pytest.mark.ros


@pytest.fixture
def graph():
    graph = Graph()
    yield graph
    graph.close()


def _cloud(points: np.ndarray, frame_id: str = 'camera_optical_frame', sec: int = 42):
    cloud = create_cloud_xyz(points, frame_id=frame_id)
    cloud.header.stamp = Time(sec=sec, nanosec=7)
    return cloud


def _leaf_markers(array, marker_type: int) -> list[Marker]:
    return [m for m in array.markers if m.type == marker_type and m.action == Marker.ADD]


def test_cloud_comes_back_as_markers_and_poses(graph):
    cloud = _cloud(l_shape_points())
    data_before = bytes(cloud.data)
    grasps = graph.publish_until_answered(graph.publisher(), cloud)
    assert graph.spin_until(lambda: graph.boxes)
    boxes = graph.boxes[-1]

    assert boxes.markers[0].action == Marker.DELETEALL
    cubes = _leaf_markers(boxes, Marker.CUBE)
    edges = _leaf_markers(boxes, Marker.LINE_LIST)
    labels = _leaf_markers(boxes, Marker.TEXT_VIEW_FACING)
    assert len(cubes) == len(edges) == len(labels) == 2, 'the L shape is two boxes'
    assert [m.id for m in cubes] == [0, 1]
    assert {m.ns for m in cubes} == {'object0/boxes'}
    assert {m.ns for m in edges} == {'object0/edges'}
    assert all(len(m.points) == 24 for m in edges)
    for message in (*boxes.markers, grasps):
        assert message.header.frame_id == 'camera_optical_frame'
        assert (message.header.stamp.sec, message.header.stamp.nanosec) == (42, 7)
    # The two boxes hold the points: every point lies in one of the CUBEs (within 1 mm).
    points = l_shape_points()
    inside = np.zeros(len(points), dtype=bool)
    for cube in cubes:
        q = cube.pose.orientation
        rotation = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
        center = np.array([cube.pose.position.x, cube.pose.position.y, cube.pose.position.z])
        half = np.array([cube.scale.x, cube.scale.y, cube.scale.z]) / 2
        inside |= np.all(np.abs((points - center) @ rotation) <= half + 1e-3, axis=1)
    assert inside.mean() > 0.99
    assert len(grasps.poses) > 0
    for pose in grasps.poses:
        q = pose.orientation
        assert abs(np.linalg.norm([q.x, q.y, q.z, q.w]) - 1.0) < 1e-6
    assert bytes(cloud.data) == data_before, 'the input message must never be modified'


def test_best_effort_and_reliable_publishers_are_both_heard(graph):
    for reliability in (ReliabilityPolicy.BEST_EFFORT, ReliabilityPolicy.RELIABLE):
        grasps = graph.publish_until_answered(
            graph.publisher(reliability), _cloud(l_shape_points())
        )
        assert grasps.header.frame_id == 'camera_optical_frame'


def test_runtime_parameter_change_is_validated_and_reprocesses(graph):
    graph.publish_until_answered(graph.publisher(), _cloud(l_shape_points()))
    assert graph.spin_until(lambda: graph.boxes)
    assert len(_leaf_markers(graph.boxes[-1], Marker.CUBE)) == 2

    ok, reason = set_parameter(graph, 'gain_threshold', 1.5)
    assert not ok and 'gain_threshold' in reason
    ok, reason = set_parameter(graph, 'gain_threshold', float('nan'))
    assert not ok and 'gain_threshold' in reason
    ok, reason = set_parameter(graph, 'split_measure', 'diagonal')
    assert not ok and 'area' in reason
    ok, reason = set_parameter(graph, 'min_points', 'many')
    assert not ok
    assert graph.node.settings.decomposition.gain_threshold == pytest.approx(0.94), (
        'refused: old value kept'
    )

    seen = len(graph.boxes)
    ok, reason = set_parameter(graph, 'gain_threshold', 0.2)
    assert ok, reason
    # No new cloud is published: the node processes the last one again at once.
    assert graph.spin_until(lambda: len(graph.boxes) > seen, timeout_s=10.0)
    assert len(_leaf_markers(graph.boxes[-1], Marker.CUBE)) == 1, 'lower t, fewer boxes'


def test_bad_clouds_give_cleared_outputs_and_the_node_keeps_running(graph):
    publisher = graph.publisher()
    empty = _cloud(np.zeros((0, 3)))
    grasps = graph.publish_until_answered(publisher, empty)
    assert graph.spin_until(lambda: graph.boxes)
    assert len(grasps.poses) == 0
    assert [m.action for m in graph.boxes[-1].markers] == [Marker.DELETEALL]

    no_xyz = _cloud(l_shape_points())
    no_xyz.fields = [field for field in no_xyz.fields if field.name != 'z']
    grasps = graph.publish_until_answered(publisher, no_xyz)
    assert len(grasps.poses) == 0
    assert graph.node.settings is not None

    grasps = graph.publish_until_answered(publisher, _cloud(l_shape_points()))
    assert len(grasps.poses) > 0, 'a good cloud after bad ones is processed normally'


def test_input_reliability_override_makes_the_subscription_reliable_with_a_deep_queue():
    graph = Graph(
        parameter_overrides=[
            Parameter('input_reliability', value='reliable'),
            Parameter('input_depth', value=50),
        ]
    )
    try:
        grasps = graph.publish_until_answered(graph.publisher(), _cloud(l_shape_points()))
        assert len(grasps.poses) > 0
        endpoint = graph.node.get_subscriptions_info_by_topic('/cloud_in')[0]
        assert endpoint.qos_profile.reliability == ReliabilityPolicy.RELIABLE
        assert graph.node.cloud_input.qos.depth == 50
    finally:
        graph.close()


def _console_script(name: str) -> Path:
    path = Path(sys.executable).parent / name
    if not path.exists():
        pytest.skip(f'{path} is not installed (run make test, which installs the package)')
    return path


@pytest.mark.parametrize(
    ('arguments', 'says_up_is_unknown'),
    [([], True), (['--ros-args', '-p', 'up_direction:=[0.0, -0.8, -0.6]'], False)],
)
def test_installed_decomposer_exits_zero_on_sigint(arguments, says_up_is_unknown):
    """It starts, says once what an unknown up direction costs (only then), and stops cleanly."""
    from mvbb_ros.ros.node import UP_UNKNOWN_HINT

    process = subprocess.Popen(
        [str(_console_script('decomposer')), *arguments],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=dict(os.environ, PYTHONUNBUFFERED='1'),
    )
    try:
        deadline = time.monotonic() + 60.0
        started = False
        lines = []
        while time.monotonic() < deadline and not started:
            line = process.stdout.readline()
            lines.append(line)
            started = 'publishing on' in line  # the constructor's last line
            if not line and process.poll() is not None:
                break
        assert started, 'the node did not start:\n' + ''.join(lines)
        process.send_signal(signal.SIGINT)
        rest, _ = process.communicate(timeout=30)
        output = ''.join(lines) + rest
        assert process.returncode == 0, output
        assert (output.count(UP_UNKNOWN_HINT) == 1) == says_up_is_unknown, output
    finally:
        if process.poll() is None:
            process.kill()


def test_installed_decomposer_takes_a_remapped_name_and_leaves_no_startup_node():
    """
    The start-up node takes none of the command line's remappings and is gone once up.

    The executable creates it (and so the DDS participant) before loading the geometry.
    """
    from mvbb_ros.ros.decomposer import STARTUP_NODE

    context = Context()
    rclpy.init(context=context)
    observer = rclpy.create_node('observer', context=context)
    process = subprocess.Popen(
        [
            str(_console_script('decomposer')),
            '--ros-args',
            '-r',
            '__node:=renamed_decomposer',
            '-r',
            '__ns:=/arm',
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=dict(os.environ, PYTHONUNBUFFERED='1'),
    )
    try:
        subscribed = False
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline and not subscribed:
            subscribed = bool(observer.get_subscriptions_info_by_topic('/arm/cloud_in'))
            time.sleep(0.05)
        assert subscribed, 'the node never subscribed to /arm/cloud_in'
        names: list[tuple[str, str]] = []
        for _ in range(20):  # the start-up node's departure reaches the graph shortly after
            names = observer.get_node_names_and_namespaces()
            if all(name != STARTUP_NODE for name, _ in names):
                break
            time.sleep(0.1)
        assert ('renamed_decomposer', '/arm') in names
        assert [name for name, _ in names].count('renamed_decomposer') == 1
        assert all(name != STARTUP_NODE for name, _ in names), names
        process.send_signal(signal.SIGINT)
        assert process.wait(timeout=30) == 0
    finally:
        if process.poll() is None:
            process.kill()
        observer.destroy_node()
        rclpy.try_shutdown(context=context)


def test_bad_parameter_file_fails_loudly(tmp_path):
    params = tmp_path / 'bad.yaml'
    params.write_text('/**:\n  ros__parameters:\n    gain_threshold: 7.5\n')
    result = subprocess.run(
        [str(_console_script('decomposer')), '--ros-args', '--params-file', str(params)],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert result.returncode != 0
    assert 'gain_threshold' in result.stderr + result.stdout


def test_turning_publish_tree_off_clears_the_drawn_tree(graph):
    graph.publish_until_answered(graph.publisher(), _cloud(l_shape_points()))
    assert graph.spin_until(lambda: graph.trees and len(graph.trees[-1].markers) > 1)
    seen = len(graph.trees)
    ok, reason = set_parameter(graph, 'publish_tree', False)
    assert ok, reason
    assert graph.spin_until(lambda: len(graph.trees) > seen)
    final = graph.trees[-1]
    assert [m.action for m in final.markers] == [Marker.DELETEALL], 'a final DELETEALL'
    assert final.markers[0].header.frame_id == 'camera_optical_frame'
    # Re-processing the last cloud publishes no tree any more.
    assert graph.spin_until(lambda: graph.node._stats['clouds_reprocessed'] == 1)
    graph.spin_until(lambda: False, timeout_s=1.0)
    assert len(graph.trees) == seen + 1


def test_late_subscribers_get_the_last_result():
    """Outputs are transient local: RViz started after the node still sees the last result."""
    graph = Graph()
    try:
        graph.publish_until_answered(graph.publisher(), _cloud(l_shape_points(), sec=77))
        late: list = []
        qos = QoSProfile(
            history=HistoryPolicy.KEEP_LAST,
            depth=1,
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL,
        )
        for topic, message_class in (
            ('/decomposer/boxes', MarkerArray),
            ('/decomposer/grasps', PoseArray),
            ('/decomposer/grasp_candidates', PointCloud2),
        ):
            graph.probe.create_subscription(message_class, topic, late.append, qos)
        assert graph.spin_until(lambda: len(late) >= 3, timeout_s=15.0)
        stamps = {_stamp(message) for message in late}
        assert stamps == {77}
    finally:
        graph.close()


def _stamp(message) -> int:
    header = message.markers[0].header if isinstance(message, MarkerArray) else message.header
    return header.stamp.sec


def test_a_table_top_frame_publishes_its_table_on_support(graph):
    from mvbb_ros.evaluation.synthetic import table_top_frame

    frame = table_top_frame(seed=1, count=2)
    points = frame.points.reshape(-1, 3)
    graph.publish_until_answered(
        graph.publisher(), _cloud(points[np.isfinite(points).all(axis=1)])
    )
    assert graph.spin_until(lambda: any(s.header.stamp.sec == 42 for s in graph.supports))
    support = [s for s in graph.supports if s.header.stamp.sec == 42][-1]
    assert support.header.frame_id == 'camera_optical_frame'
    assert support.header.stamp.nanosec == 7
    corners = np.array([[p.x, p.y, p.z] for p in support.polygon.points])
    assert len(corners) >= 3
    a, b, c, d = frame.table_plane
    assert np.all(np.abs(corners @ [a, b, c] + d) < 0.01), 'the outline lies on the table top'
    boxes = [m for m in graph.boxes if m.markers[0].header.stamp.sec == 42][-1]
    table = [m for m in boxes.markers if m.ns == 'support']
    assert sorted(m.type for m in table) == [Marker.LINE_STRIP, Marker.TRIANGLE_LIST]
    cubes = {m.ns for m in _leaf_markers(boxes, Marker.CUBE)}
    assert cubes == {'object0/boxes', 'object1/boxes'}, 'two objects, no box on table or wall'

    # A segmented object has no table: the outline is cleared.
    graph.publish_until_answered(graph.publisher(), _cloud(l_shape_points(), sec=43))
    assert graph.spin_until(lambda: any(s.header.stamp.sec == 43 for s in graph.supports))
    assert not [s for s in graph.supports if s.header.stamp.sec == 43][-1].polygon.points
