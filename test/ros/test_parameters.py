"""Hostile parameter values are refused with a reason and change nothing (issue 8)."""

from __future__ import annotations

import array
import math
from pathlib import Path
import subprocess
import sys

from mvbb_ros.pipeline.settings import PipelineSettings, settings_from_mapping, validate_setting
from mvbb_ros.pipeline.settings_text import parse_assignments, read_params_file
from mvbb_ros.pipeline.specs import SPECS
from mvbb_ros.ros.encode import create_cloud_xyz
import mvbb_ros.ros.node
from mvbb_ros.ros.node import DecomposerNode, UnknownParameterError
import numpy as np
import pytest
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType
from rcl_interfaces.srv import GetParameters, ListParameters, SetParameters
import rclpy
from rclpy.context import Context
from rclpy.parameter import Parameter
from support.ros_graph import Graph, set_parameter
from support.shapes import l_shape_points
from visualization_msgs.msg import Marker


def _hostile_values(spec) -> list:
    """Values of the wrong type, non-finite or out of range for `spec`."""
    values: list = ['text', [1.0, 2.0]] if spec.kind is not str else [3, 1.5, True]
    if spec.kind in (int, float):
        values += [math.nan, math.inf, -math.inf]
        low, high = spec.value_range
        values += [low - 1, high + 1] if spec.kind is int else [low - 0.5, high + 0.5]
        values += [True] if spec.kind is int else []
        values += [0.5] if spec.kind is int else []
    if spec.kind is list:
        values += [[1.0], [1.0, 2.0, math.nan], [math.inf, 0.0, 0.0], 5.0]
    if spec.kind is bool:
        values += [1, 0.0]
    if spec.kind is str:
        values += ['not-a-choice']
    return values


@pytest.mark.parametrize('spec', SPECS, ids=[spec.name for spec in SPECS])
def test_hostile_values_are_refused_with_the_setting_named(spec):
    for value in _hostile_values(spec):
        reason = validate_setting(spec.name, value)
        assert reason is not None, f'{spec.name}={value!r} was accepted'
        assert spec.name in reason


def test_defaults_are_valid_and_unknown_names_refused():
    for spec in SPECS:
        assert validate_setting(spec.name, PipelineSettings().value(spec.name)) is None
    assert 'unknown' in validate_setting('gain_thresold', 0.9)


def test_crop_corners_must_be_ordered():
    with pytest.raises(ValueError, match='crop_min'):
        settings_from_mapping({'crop_min': [0, 0, 1], 'crop_max': [1, 1, 0]})
    settings = settings_from_mapping({'crop_min': [0, 0, 0], 'crop_max': [1, 1, 1]})
    assert settings.filtering.crop_max == (1.0, 1.0, 1.0)


def test_one_crop_corner_leaves_the_box_open_on_the_other_side():
    from mvbb_ros.pipeline.filtering import crop_points

    points = np.array([[-5.0, 0.0, 0.0], [0.5, 0.5, 0.5], [5.0, 5.0, 5.0]])
    above = settings_from_mapping({'crop_min': [0, 0, 0]}).filtering
    below = settings_from_mapping({'crop_max': [1, 1, 1]}).filtering
    assert above.crop_max == () and below.crop_min == ()
    np.testing.assert_array_equal(crop_points(points, above.crop_min, above.crop_max), points[1:])
    np.testing.assert_array_equal(crop_points(points, below.crop_min, below.crop_max), points[:2])


def test_a_voxel_size_whose_grid_cannot_be_bounded_is_refused_with_the_range():
    assert validate_setting('voxel_size', 0.0) is None
    assert validate_setting('voxel_size', 1e-4) is None
    reason = validate_setting('voxel_size', 1e-9)
    assert reason is not None and '0 (off) or at least 0.0001' in reason


def test_assignments_parse_like_ros_and_reject_garbage():
    assert parse_assignments(
        ['gain_threshold:=0.9', 'min_points:=10', 'up_direction:=[0,0,1]']
    ) == {
        'gain_threshold': 0.9,
        'min_points': 10,
        'up_direction': [0, 0, 1],
    }
    assert parse_assignments(['voxel_size:=0']) == {'voxel_size': 0.0}
    with pytest.raises(ValueError, match='name:=value'):
        parse_assignments(['gain_threshold=0.9'])
    with pytest.raises(ValueError, match='unknown'):
        parse_assignments(['no_such:=1'])


def _snapshot(node) -> dict:
    return {spec.name: node.get_parameter_or(spec.name, None).value for spec in SPECS}


@pytest.mark.ros
def test_node_state_is_unchanged_after_every_refused_change():
    graph = Graph()
    try:
        client = graph.probe.create_client(SetParameters, '/decomposer/set_parameters')
        assert graph.spin_until(client.service_is_ready, timeout_s=10.0)
        settings_before = graph.node.settings
        parameters_before = _snapshot(graph.node)
        refused = 0
        for spec in SPECS:
            for value in _hostile_values(spec):
                try:
                    message = Parameter(spec.name, value=value).to_parameter_msg()
                except (TypeError, ValueError):
                    continue  # not representable as a ROS parameter at all
                future = client.call_async(SetParameters.Request(parameters=[message]))
                assert graph.spin_until(future.done, timeout_s=10.0)
                result = future.result().results[0]
                assert not result.successful, f'{spec.name}={value!r} was accepted'
                assert result.reason
                refused += 1
        assert refused > 3 * len(SPECS)
        assert graph.node.settings == settings_before
        assert _snapshot(graph.node) == parameters_before
    finally:
        graph.close()


@pytest.mark.ros
def test_a_fault_inside_processing_is_logged_and_the_next_cloud_processed(monkeypatch):
    calls = {'count': 0}
    real_process_cloud = mvbb_ros.ros.node.process_cloud

    def failing_once(cloud, settings, **options):
        calls['count'] += 1
        if calls['count'] == 1:
            raise RuntimeError('injected fault')
        return real_process_cloud(cloud, settings, **options)

    monkeypatch.setattr(mvbb_ros.ros.node, 'process_cloud', failing_once)
    graph = Graph()
    try:
        cloud = create_cloud_xyz(l_shape_points())
        cloud.header.stamp.sec = 1
        publisher = graph.publisher()
        cleared = graph.publish_until_answered(publisher, cloud)
        assert len(cleared.poses) == 0, 'the faulty cloud gives cleared outputs'
        assert graph.node._stats['clouds_failed'] == 1
        cloud.header.stamp.sec = 2
        grasps = graph.publish_until_answered(publisher, cloud)
        assert len(grasps.poses) > 0, 'the next cloud is processed normally'
    finally:
        graph.close()


# Every parameter has a typed value; unknown names are refused (issue 18, items 2 and 7) -------


def _call(graph: Graph, service_type, name: str, request):
    client = graph.probe.create_client(service_type, f'/decomposer/{name}')
    try:
        assert graph.spin_until(client.service_is_ready, timeout_s=10.0)
        future = client.call_async(request)
        assert graph.spin_until(future.done, timeout_s=10.0)
        return future.result()
    finally:
        graph.probe.destroy_client(client)


@pytest.mark.ros
def test_one_get_parameters_call_returns_every_value():
    graph = Graph()
    try:
        names = list(
            _call(graph, ListParameters, 'list_parameters', ListParameters.Request()).result.names
        )
        assert {spec.name for spec in SPECS} <= set(names)
        values = _call(graph, GetParameters, 'get_parameters', GetParameters.Request(names=names))
        assert len(values.values) == len(names), 'ros2 param dump needs every value'
        assert all(value.type != ParameterType.PARAMETER_NOT_SET for value in values.values)
        by_name = dict(zip(names, values.values, strict=True))
        for spec in SPECS:
            value = by_name[spec.name]
            assert value.type == mvbb_ros.ros.node.parameter_descriptor(spec).type, spec.name
            expected = PipelineSettings().value(spec.name)
            assert Parameter.from_parameter_msg(
                ParameterMsg(name=spec.name, value=value)
            ).value == (expected if spec.kind is not list else array.array('d', expected))
        assert list(by_name['crop_min'].double_array_value) == [], 'unset: an empty array'
    finally:
        graph.close()


@pytest.mark.ros
def test_vectors_take_integers_and_empty_arrays():
    graph = Graph(parameter_overrides=[Parameter('up_direction', value=[0, 0, 1])])
    try:
        assert graph.node.settings.view.up == (0.0, 0.0, 1.0)
        assert graph.node.get_parameter('up_direction').type_ == Parameter.Type.DOUBLE_ARRAY
        request = SetParameters.Request(
            parameters=[Parameter('up_direction', value=[]).to_parameter_msg()]
        )
        result = _call(graph, SetParameters, 'set_parameters', request).results[0]
        assert result.successful, result.reason
        assert graph.node.settings.view.up is None
        values = _call(
            graph, GetParameters, 'get_parameters', GetParameters.Request(names=['up_direction'])
        ).values
        assert values[0].type == ParameterType.PARAMETER_DOUBLE_ARRAY
    finally:
        graph.close()


def test_unknown_names_are_named_with_the_closest_and_the_known_ones():
    reason = validate_setting('gain_treshold', 0.9)
    assert "'gain_treshold'" in reason and 'did you mean gain_threshold' in reason
    assert all(spec.name in reason for spec in SPECS), 'the known names are listed'
    with pytest.raises(ValueError, match='did you mean min_points'):
        parse_assignments(['min_point:=3'])


def _start_with_params_file(params: Path) -> subprocess.CompletedProcess:
    """Start the installed ``decomposer`` with a parameter file; return how it ended."""
    script = Path(sys.executable).parent / 'decomposer'
    if not script.exists():
        pytest.skip(f'{script} is not installed (run make test, which installs the package)')
    return subprocess.run(
        [str(script), '--ros-args', '--params-file', str(params)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )


@pytest.mark.ros
def test_misspelt_key_in_a_parameter_file_stops_the_node(tmp_path):
    params = tmp_path / 'typo.yaml'
    params.write_text(
        '/**:\n  ros__parameters:\n    gain_treshold: 0.9\n    use_sim_time: false\n'
    )
    result = _start_with_params_file(params)
    output = result.stdout + result.stderr
    assert result.returncode == 1, output
    assert 'gain_treshold' in output and 'did you mean gain_threshold' in output
    assert 'known: gain_threshold, min_points' in output
    assert 'Traceback' not in output, 'one clear line, no traceback'


@pytest.mark.ros
def test_misspelt_override_raises_in_process():
    context = Context()
    rclpy.init(context=context)
    try:
        with pytest.raises(UnknownParameterError, match='voxel_sise'):
            DecomposerNode(
                context=context, parameter_overrides=[Parameter('voxel_sise', value=1.0)]
            )
    finally:
        rclpy.try_shutdown(context=context)


def test_cli_params_file_ignores_ros_parameters_and_refuses_typos(tmp_path):
    params = tmp_path / 'node.yaml'
    params.write_text(
        'decomposer:\n  ros__parameters:\n    use_sim_time: true\n    min_points: 5\n'
    )
    assert settings_from_mapping(read_params_file(params)).decomposition.min_points == 5
    params.write_text('decomposer:\n  ros__parameters:\n    min_pionts: 5\n')
    with pytest.raises(ValueError, match='did you mean min_points'):
        settings_from_mapping(read_params_file(params))


@pytest.mark.ros
def test_an_integer_for_a_number_is_taken_as_a_number_at_start_and_at_runtime():
    graph = Graph(parameter_overrides=[Parameter('cluster_tolerance', value=0)])
    try:
        assert graph.node.settings.view.cluster_tolerance == 0.0
        assert graph.node.get_parameter('cluster_tolerance').type_ == Parameter.Type.DOUBLE
        request = SetParameters.Request(
            parameters=[Parameter('gain_threshold', value=1).to_parameter_msg()]
        )
        result = _call(graph, SetParameters, 'set_parameters', request).results[0]
        assert result.successful, result.reason
        assert graph.node.settings.decomposition.gain_threshold == 1.0
        assert graph.node.get_parameter('gain_threshold').type_ == Parameter.Type.DOUBLE
    finally:
        graph.close()


def test_a_parameter_file_for_another_node_name_is_named(tmp_path):
    from mvbb_ros.pipeline.settings_text import unmatched_params_files

    files = {}
    for name, section in (
        ('typo', 'decomposr'),
        ('exact', 'decomposer'),
        ('slash', '/decomposer'),
        ('all', '/**'),
        ('star', '/robot/*'),
    ):
        files[name] = tmp_path / f'{name}.yaml'
        files[name].write_text(f'{section}:\n  ros__parameters:\n    gain_threshold: 0.9\n')
    arguments = ['decomposer', '--ros-args']
    for path in files.values():
        arguments += ['--params-file', str(path)]
    lines = unmatched_params_files(arguments, '/decomposer')
    assert len(lines) == 2
    assert str(files['typo']) in lines[0] and 'decomposr' in lines[0]
    assert str(files['star']) in lines[1]  # /robot/* is for nodes in the robot namespace
    in_namespace = unmatched_params_files(arguments, '/robot/decomposer')
    assert [line.split()[2] for line in in_namespace] == [
        str(files[name]) for name in ('typo', 'exact', 'slash')
    ]


def test_a_parameter_file_that_is_not_yaml_stops_the_node_with_one_line(tmp_path):
    params = tmp_path / 'broken.yaml'
    params.write_text('/**:\n  ros__parameters:\n    gain_threshold: [0.9\n')
    result = _start_with_params_file(params)
    assert result.returncode == 2, result.stderr
    assert 'decomposer: cannot start' in result.stderr and 'broken.yaml' in result.stderr
    assert 'Traceback' not in result.stdout + result.stderr


def _answers(graph: Graph, sec: int) -> tuple[list, list]:
    """Return the grasp poses and the box cubes of every answer stamped `sec`, in order."""
    grasps = [
        [(p.position.x, p.position.y, p.position.z, p.orientation.x, p.orientation.y,
          p.orientation.z, p.orientation.w) for p in message.poses]
        for message in graph.grasps
        if message.header.stamp.sec == sec
    ]  # fmt: skip
    boxes = [
        [(m.pose.position.x, m.pose.position.y, m.pose.position.z, m.pose.orientation.x,
          m.pose.orientation.y, m.pose.orientation.z, m.pose.orientation.w, m.scale.x,
          m.scale.y, m.scale.z) for m in message.markers if m.type == Marker.CUBE]
        for message in graph.boxes
        if message.markers and message.markers[0].header.stamp.sec == sec
    ]  # fmt: skip
    return grasps, boxes


@pytest.mark.ros
def test_workers_change_at_runtime_the_answer_does_not_and_fewer_than_one_is_refused():
    """The workers parameter through the node: set at start, changed live, bad values refused."""
    from mvbb_ros.evaluation.synthetic import table_top_frame

    graph = Graph(parameter_overrides=[Parameter('workers', value=1)])
    try:
        assert graph.node.settings.execution.workers == 1
        frame = table_top_frame(1, 3).points
        publisher = graph.publisher()

        def answer(sec: int) -> tuple[list, list]:
            # A frame id of its own: no previous grasp of the same frame (hysteresis) applies.
            cloud = create_cloud_xyz(
                frame.reshape(-1, 3), organized_shape=frame.shape[:2], frame_id=f'camera_{sec}'
            )
            cloud.header.stamp.sec = sec
            graph.publish_until_answered(publisher, cloud)
            assert graph.spin_until(lambda: all(_answers(graph, sec)), timeout_s=10.0), (
                'boxes and grasps'
            )
            grasps, boxes = _answers(graph, sec)
            return grasps[0], boxes[0]

        first = answer(41)
        assert first[0] and first[1], 'grasps and boxes'
        for count in (2, 3):
            successful, reason = set_parameter(graph, 'workers', count)
            assert successful, reason
            assert graph.node.settings.execution.workers == count
            assert answer(40 + count) == first, f'{count} workers'
        for bad in (0, -2):
            successful, reason = set_parameter(graph, 'workers', bad)
            assert not successful and 'workers' in reason and 'range' in reason, reason
        assert graph.node.settings.execution.workers == 3
        assert graph.node.get_parameter('workers').value == 3
    finally:
        graph.close()
