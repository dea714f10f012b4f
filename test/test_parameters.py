"""Hostile parameter values are refused with a reason and change nothing (issue 8)."""

from __future__ import annotations

import math

from mvbb_ros.pipeline.settings import (
    parse_assignments,
    PipelineSettings,
    settings_from_mapping,
    SPECS,
    validate_setting,
)
from mvbb_ros.ros.encode import create_cloud_xyz
import mvbb_ros.ros.node
import pytest
from rcl_interfaces.srv import SetParameters
from rclpy.parameter import Parameter
from ros_graph import Graph, l_shape_points


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

    def failing_once(cloud, settings):
        calls['count'] += 1
        if calls['count'] == 1:
            raise RuntimeError('injected fault')
        return real_process_cloud(cloud, settings)

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
