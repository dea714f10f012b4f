"""
Tests of the bag tools: `mvbb bag process` (offline) and `mvbb bag play` (live).

The bags are written here with rosbags directly (rosbag2 sqlite3 and MCAP, and ROS 1), not with
the code under test; the shared real bags are used too when present.
"""

from __future__ import annotations

import io
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PolygonStamped, PoseArray
from mvbb_ros.cli.main import main
from mvbb_ros.common.progress import ProgressBar
from mvbb_ros.evaluation.synthetic import cut_table_top_frame
from mvbb_ros.geometry.grasping.hypotheses import GraspStats
from mvbb_ros.pipeline import explain
from mvbb_ros.pipeline.decode import read_xyz
from mvbb_ros.pipeline.explain import empty_grasps_note
from mvbb_ros.pipeline.process import process_cloud
from mvbb_ros.pipeline.settings import PipelineSettings, settings_from_mapping
from mvbb_ros.ros.bag import BagError, BagWriter, CloudBag, ros_type_name
from mvbb_ros.ros.bag_play import wall_offset_s
from mvbb_ros.ros.encode import create_cloud_xyz, to_rosbags_cloud
from mvbb_ros.ros.messages import output_messages
from mvbb_ros.ros.offline import process_bag
import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.highlevel import AnyReader
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import get_typestore, Stores
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import String
from support.data import require_shared_data
from support.ros_graph import Graph
from support.shapes import l_shape_points
from visualization_msgs.msg import MarkerArray

JAZZY = get_typestore(Stores.ROS2_JAZZY)
NOETIC = get_typestore(Stores.ROS1_NOETIC)
TOPIC = '/camera/segmented'
#: Bag times of the test clouds (ns), deliberately unlike the header stamps.
BAG_TIMES = (5_000_000_000, 5_500_000_000, 7_000_000_000)
#: Fast settings for the small test clouds.
FAST = {'voxel_size': 0.0, 'outlier_neighbors': 0}
OUTPUT_GRASPS = '/decomposer/grasps'
OUTPUT_TYPES_BY_TOPIC = {
    '/decomposer/boxes': MarkerArray,
    '/decomposer/tree': MarkerArray,
    '/decomposer/box_list': PointCloud2,
    OUTPUT_GRASPS: PoseArray,
    '/decomposer/grasp_candidates': PointCloud2,
    '/decomposer/support': PolygonStamped,
}
OUTPUT_TOPICS = tuple(OUTPUT_TYPES_BY_TOPIC)


def _header(message):
    """Return an output's header: a MarkerArray's is its first marker's (the DELETEALL)."""
    return message.markers[0].header if isinstance(message, MarkerArray) else message.header


def _cloud(points: np.ndarray, sec: int, nanosec: int = 0, frame: str = 'cam') -> PointCloud2:
    cloud = create_cloud_xyz(points, frame_id=frame)
    cloud.header.stamp = Time(sec=sec, nanosec=nanosec)
    return cloud


def _test_clouds() -> list[PointCloud2]:
    return [_cloud(l_shape_points(seed=k, count=400), sec=100 + k, nanosec=k) for k in range(3)]


def write_bag(
    path: Path,
    clouds: list[tuple[str, int, PointCloud2]],
    *,
    storage: str = 'sqlite3',
    strings: list[tuple[str, int, str]] = (),
) -> Path:
    """Write a bag with rosbags: sqlite3 or mcap (rosbag2 directory), or ros1 (`path`.bag)."""
    if storage == 'ros1':
        path = path.with_suffix('.bag')
        with Ros1Writer(path) as writer:
            connections = {}
            for topic, stamp, cloud in clouds:
                if topic not in connections:
                    connections[topic] = writer.add_connection(
                        topic, 'sensor_msgs/msg/PointCloud2', typestore=NOETIC
                    )
                message = to_rosbags_cloud(cloud, NOETIC)
                writer.write(
                    connections[topic], stamp, NOETIC.serialize_ros1(message, message.__msgtype__)
                )
            for topic, stamp, text in strings:
                if topic not in connections:
                    connections[topic] = writer.add_connection(
                        topic, 'std_msgs/msg/String', typestore=NOETIC
                    )
                message = NOETIC.types['std_msgs/msg/String'](data=text)
                writer.write(
                    connections[topic], stamp, NOETIC.serialize_ros1(message, message.__msgtype__)
                )
        return path
    plugin = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3
    with Writer(path, version=8, storage_plugin=plugin) as writer:
        connections = {}
        items = [(t, s, c) for t, s, c in clouds] + [(t, s, String(data=x)) for t, s, x in strings]
        for topic, stamp, message in sorted(items, key=lambda item: item[1]):
            if topic not in connections:
                connections[topic] = writer.add_connection(
                    topic, ros_type_name(type(message)), typestore=JAZZY
                )
            writer.write(connections[topic], stamp, serialize_message(message))
    return path


def _read(path: Path) -> dict[str, list[tuple[int, bytes, str]]]:
    """Return topic -> [(bag time, raw CDR, msgtype)] of a rosbag2, read with rosbags."""
    found: dict[str, list[tuple[int, bytes, str]]] = {}
    with AnyReader([path]) as reader:
        for connection, stamp, raw in reader.messages():
            found.setdefault(connection.topic, []).append((stamp, raw, connection.msgtype))
    return found


def _listing(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


@pytest.fixture(scope='module')
def sqlite_bag(tmp_path_factory) -> Path:
    clouds = _test_clouds()
    return write_bag(
        tmp_path_factory.mktemp('bags') / 'input',
        [(TOPIC, t, c) for t, c in zip(BAG_TIMES, clouds, strict=True)],
        strings=[('/chatter', 6_000_000_000, 'hello')],
    )


# Processing ------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ('input_storage', 'output_storage'),
    [('sqlite3', 'mcap'), ('mcap', 'sqlite3'), ('ros1', 'mcap')],
)
def test_process_keeps_counts_and_timestamps(tmp_path, input_storage, output_storage):
    clouds = _test_clouds()
    source = write_bag(
        tmp_path / 'input',
        [(TOPIC, t, c) for t, c in zip(BAG_TIMES, clouds, strict=True)],
        storage=input_storage,
        strings=[('/chatter', 6_000_000_000, 'not a cloud')],
    )
    out = tmp_path / 'out'
    summary = process_bag(
        source,
        out,
        settings=settings_from_mapping(FAST),
        with_input=True,
        storage=output_storage,
    )
    assert summary.clouds == 3 and summary.input_topic == TOPIC
    assert summary.boxes > 0 and summary.grasps > 0
    found = _read(out)
    assert set(found) == {TOPIC, *OUTPUT_TYPES_BY_TOPIC}
    with AnyReader([out]) as reader:
        assert {c.ext.serialization_format for c in reader.connections} == {'cdr'}
    assert (out / 'metadata.yaml').read_text().count(f'storage_identifier: {output_storage}') == 1
    for topic, messages in found.items():
        assert [stamp for stamp, _, _ in messages] == list(BAG_TIMES), f'bag times of {topic}'
        for (_, raw, msgtype), cloud in zip(messages, clouds, strict=True):
            # Foxglove and ros2 bag read the schema from the bag: rosbags must decode it.
            JAZZY.deserialize_cdr(raw, msgtype)
            if topic == TOPIC:
                message = deserialize_message(raw, PointCloud2)
                assert bytes(message.data) == bytes(cloud.data)
                header = message.header
            else:
                header = _header(deserialize_message(raw, OUTPUT_TYPES_BY_TOPIC[topic]))
            assert header.stamp == cloud.header.stamp, 'output headers keep the input stamp'
            assert header.frame_id == 'cam'


def test_process_options_namespace_no_tree_and_compression(tmp_path, sqlite_bag):
    out = tmp_path / 'out'
    settings = settings_from_mapping({**FAST, 'publish_tree': False})
    summary = process_bag(
        sqlite_bag, out, settings=settings, namespace='/tuning', storage='sqlite3', compress=True
    )
    assert summary.topics == {
        '/tuning/boxes': 3,
        '/tuning/box_list': 3,
        '/tuning/grasps': 3,
        '/tuning/grasp_candidates': 3,
        '/tuning/support': 3,
    }
    assert 'compression_mode: message' in (out / 'metadata.yaml').read_text()
    assert {topic: len(messages) for topic, messages in _read(out).items()} == summary.topics


def test_process_cli_prints_table_and_totals(tmp_path, sqlite_bag, capsys):
    out = tmp_path / 'out'
    code = main(
        ['bag', 'process', str(sqlite_bag), str(out), '-p', 'voxel_size:=0.0', '--no-progress']
    )
    captured = capsys.readouterr()
    assert code == 0, captured.err
    lines = captured.out.splitlines()
    header = next(i for i, line in enumerate(lines) if line.split()[:2] == ['#', 'time_s'])
    first, last = header + 1, header + 4
    rows = lines[first:last]
    assert [row.split()[0] for row in rows] == ['0', '1', '2']
    assert rows[1].split()[1] == '0.500', 'bag time relative to the first cloud'
    assert rows[0].split()[2] == '100.000000000'
    assert rows[0].split()[3] == '400', 'finite input points'
    assert 'total: 3 clouds, 1200 points' in captured.out
    assert 'clouds/s' in captured.out
    assert captured.err == '', 'no progress bar when stderr is not a terminal'


def test_process_says_which_filter_removed_the_grasps(tmp_path, sqlite_bag, capsys):
    out = tmp_path / 'out'
    arguments = ['bag', 'process', str(sqlite_bag), str(out), '-p', 'voxel_size:=0.0']
    code = main([*arguments, '-p', 'gripper_max_width:=0.001', '--no-progress'])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    rows = [line for line in captured.out.splitlines() if line.split()[:1] in (['0'], ['1'])]
    assert len(rows) == 2
    for row in rows:
        assert int(row.split()[5]) >= 1 and int(row.split()[6]) == 0, 'boxes, no grasps'
        assert '0 grasps: gripper_max_width: every free face needs more than 0.001 m' in row
        assert '-> width 0' in row
    assert '3 of 3 clouds gave boxes but no grasps' in captured.out
    assert 'gave cleared outputs' not in captured.out, 'the boxes are published'


def test_empty_grasps_note_names_the_first_filter_that_leaves_none(monkeypatch):
    settings = settings_from_mapping({**FAST, 'up_direction': [0.0, 0.0, 1.0]})
    result = process_cloud(_test_clouds()[0], settings)
    assert result.grasps and empty_grasps_note(result, settings) == '', 'grasps: no note'
    rejected = process_cloud(_cloud(np.zeros((0, 3)), sec=1), settings)
    assert empty_grasps_note(rejected, settings) == '', 'no boxes: the warning says why'
    # The filters the L shape never empties, with their counts as the grasp stage gives them.
    result.grasps = []
    for counts, named in (
        ((2, 12, 0, 0, 48, 0, 0, 0), 'occlusion: every face is covered'),
        ((2, 12, 10, 0, 48, 40, 26, 0), 'support: every remaining approach comes from below'),
    ):
        monkeypatch.setattr(
            explain, 'grasp_filter_counts', lambda *_, c=counts, **__: GraspStats(*c)
        )
        note = empty_grasps_note(result, settings)
        assert note.startswith('2 boxes, 0 grasps: ' + named), note
        assert 'up_direction [0.0, 0.0, 1.0]' in note or 'occlusion' in named


def test_params_file_and_p_override(tmp_path, sqlite_bag, capsys):
    params = tmp_path / 'params.yaml'
    params.write_text('/**:\n  ros__parameters:\n    gain_threshold: 0.2\n    voxel_size: 0.0\n')
    out = tmp_path / 'out'
    code = main(
        ['bag', 'process', str(sqlite_bag), str(out), '--params-file', str(params), '--quiet']
    )
    assert code == 0, capsys.readouterr().err
    assert 'total: 3 clouds, 1200 points, 3 boxes' in capsys.readouterr().out, 't = 0.2: one box'
    code = main(
        ['bag', 'process', str(sqlite_bag), str(out), '--params-file', str(params)]
        + ['-p', 'gain_threshold:=0.94', '--force', '--quiet']
    )
    assert code == 0
    assert 'total: 3 clouds, 1200 points, 6 boxes' in capsys.readouterr().out


def test_bad_clouds_give_cleared_outputs_like_the_node(tmp_path):
    good = _cloud(l_shape_points(count=400), sec=1)
    no_z = _cloud(l_shape_points(count=400), sec=2)
    no_z.fields = [f for f in no_z.fields if f.name != 'z']
    empty = _cloud(np.zeros((0, 3)), sec=3)
    source = write_bag(
        tmp_path / 'in', [(TOPIC, k + 1, c) for k, c in enumerate((good, no_z, empty))]
    )
    summary = process_bag(source, tmp_path / 'out', settings=settings_from_mapping(FAST))
    assert [row.boxes > 0 for row in summary.rows] == [True, False, False]
    assert 'malformed cloud' in summary.rows[1].note
    assert 'no finite points' in summary.rows[2].note
    grasps = [
        deserialize_message(raw, PoseArray) for _, raw, _ in _read(tmp_path / 'out')[OUTPUT_GRASPS]
    ]
    assert [len(g.poses) > 0 for g in grasps] == [True, False, False]


def test_ros1_and_ros2_bags_give_the_same_clouds(tmp_path):
    clouds = [(TOPIC, t, c) for t, c in zip(BAG_TIMES, _test_clouds(), strict=True)]
    ros1 = write_bag(tmp_path / 'one', clouds, storage='ros1')
    ros2 = write_bag(tmp_path / 'two', clouds, storage='mcap')
    with CloudBag(ros1) as first, CloudBag(ros2) as second:
        assert first.is_ros1 and not second.is_ros1
        a = [(c.timestamp_ns, c.message()) for c in first.clouds([TOPIC])]
        b = [(c.timestamp_ns, c.message()) for c in second.clouds([TOPIC])]
    assert a == b
    assert [t for t, _ in a] == list(BAG_TIMES)


def test_bare_storage_files_are_read(tmp_path):
    bag = write_bag(tmp_path / 'in', [(TOPIC, 1, _test_clouds()[0])], storage='mcap')
    with CloudBag(bag / 'in.mcap') as reader:
        assert reader.select_topics() == [TOPIC]
        assert len(list(reader.clouds([TOPIC]))) == 1


# The node and `mvbb bag process` give the same messages --------------------------------------


@pytest.mark.ros
def test_node_and_bag_process_outputs_are_identical(tmp_path):
    values = {'gain_threshold': 0.9, 'voxel_size': 0.002, 'max_grasps': 7, 'seed': 3}
    cloud = _cloud(l_shape_points(seed=5, count=1500), sec=77, nanosec=5, frame='optical')
    graph = Graph(parameter_overrides=[Parameter(k, value=v) for k, v in values.items()])
    try:
        grasps = graph.publish_until_answered(graph.publisher(), cloud)
        assert graph.spin_until(lambda: graph.boxes and graph.trees)
        live = {'boxes': graph.boxes[-1], 'tree': graph.trees[-1], 'grasps': grasps}
    finally:
        graph.close()

    source = write_bag(tmp_path / 'in', [(TOPIC, 1_000, cloud)])
    process_bag(source, tmp_path / 'out', settings=settings_from_mapping(values))
    found = _read(tmp_path / 'out')
    offline = {
        suffix: deserialize_message(found[f'/decomposer/{suffix}'][0][1], type(message))
        for suffix, message in live.items()
    }
    assert len(live['grasps'].poses) == 7
    assert len([m for m in live['boxes'].markers if m.ns == 'object0/boxes']) >= 2
    for suffix in live:
        assert offline[suffix] == live[suffix], f'{suffix} differs between node and bag process'


def test_output_messages_follow_publish_tree_and_clear_on_failure():
    cloud = _cloud(l_shape_points(count=400), sec=1)
    settings = settings_from_mapping(FAST)
    result = process_cloud(cloud, settings)
    every = ['boxes', 'tree', 'box_list', 'grasps', 'grasp_candidates', 'support']
    assert list(output_messages(result, cloud.header, settings)) == every
    no_tree = settings_from_mapping({**FAST, 'publish_tree': False})
    assert list(output_messages(result, cloud.header, no_tree)) == [
        suffix for suffix in every if suffix != 'tree'
    ]
    cleared = output_messages(None, cloud.header, settings)
    assert [m.action for m in cleared['boxes'].markers] == [3]  # DELETEALL
    assert cleared['grasps'].poses == [] and cleared['grasps'].header == cloud.header
    for suffix in ('box_list', 'grasp_candidates'):
        assert cleared[suffix].width == 0 and cleared[suffix].header == cloud.header
        assert len(cleared[suffix].fields) > 3, 'an empty cloud still names its fields'
    assert cleared['support'].polygon.points == [] and cleared['support'].header == cloud.header


def test_the_labels_of_boxes_of_objects_cut_by_the_view_say_so():
    points, _, _ = cut_table_top_frame(9, 5)
    cloud = _cloud(points, sec=1)
    settings = settings_from_mapping({})
    result = process_cloud(cloud, settings)
    assert result.cut_objects
    boxes = output_messages(result, cloud.header, settings)['boxes'].markers
    labels = {m.id: m.text for m in boxes if m.ns.endswith('/labels')}
    objects = result.leaf_object_indices
    assert len(labels) == len(objects)
    for index, obj in enumerate(objects):
        assert labels[index].endswith(', cut by the view') == (obj in result.cut_objects)


# Shared real bags ------------------------------------------------------------------------------


SHARED_BAGS = [
    ('embag_luminar_lidar_ros1.bag', None, 5),
    ('embag_luminar_lidar_ros2', None, 5),
    ('constructed_real_objects_ros2', '/segmented_object', 8),
    ('constructed_real_objects_ros2', '/camera/depth_registered/points', 1),
]


@pytest.mark.slow
@pytest.mark.parametrize(('name', 'topic', 'count'), SHARED_BAGS)
def test_shared_bags_process_with_counts_and_timestamps_kept(tmp_path, name, topic, count):
    bag = require_shared_data('bags', name)
    with CloudBag(bag) as reader:
        topics = reader.select_topics(topic, single=True)
        inputs = [(c.timestamp_ns, c.message().header) for c in reader.clouds(topics)]
    assert len(inputs) == count
    out = tmp_path / 'out'
    # A coarse voxel keeps the test quick on the 2e5-point scene and the 250 m LiDAR clouds.
    summary = process_bag(
        bag, out, topic=topic, settings=settings_from_mapping({'voxel_size': 0.05})
    )
    assert summary.clouds == count
    found = _read(out)
    assert set(found) == set(OUTPUT_TOPICS)
    for topic_name, messages in found.items():
        assert [stamp for stamp, _, _ in messages] == [stamp for stamp, _ in inputs]
        for (_, raw, _), (_, header) in zip(messages, inputs, strict=True):
            assert _header(deserialize_message(raw, OUTPUT_TYPES_BY_TOPIC[topic_name])) == header


def test_shared_ros1_and_ros2_embag_decode_identically():
    ros1 = require_shared_data('bags', 'embag_luminar_lidar_ros1.bag')
    ros2 = require_shared_data('bags', 'embag_luminar_lidar_ros2')
    with CloudBag(ros1) as first, CloudBag(ros2) as second:
        a = [(c.timestamp_ns, c.message()) for c in first.clouds(['/luminar_pointcloud'])]
        b = [(c.timestamp_ns, c.message()) for c in second.clouds(['/luminar_pointcloud'])]
    assert len(a) == 5 and a == b
    assert len(read_xyz(a[0][1])) == 35707


# Bad input: a clear error, exit code 1, nothing left behind ------------------------------------


def _truncate(bag: Path) -> Path:
    storage = bag if bag.is_file() else next(p for p in bag.iterdir() if p.suffix != '.yaml')
    with open(storage, 'r+b') as handle:
        handle.truncate(storage.stat().st_size * 2 // 3)
    return bag


def _bad_inputs(folder: Path) -> dict[str, tuple[list[str], str]]:
    clouds = [(TOPIC, t, c) for t, c in zip(BAG_TIMES, _test_clouds(), strict=True)]
    two_topics = clouds + [('/other', 9_000_000_000, _test_clouds()[0])]
    strings = [('/chatter', 1, 'a'), ('/chatter', 2, 'b')]
    miscounted = write_bag(folder / 'miscounted', clouds)
    metadata = miscounted / 'metadata.yaml'
    metadata.write_text(metadata.read_text().replace('message_count: 3', 'message_count: 5'))
    not_a_bag = folder / 'garbage.bag'
    not_a_bag.write_bytes(b'this is not a bag' * 10)
    (folder / 'empty_dir').mkdir()
    return {
        'missing': ([str(folder / 'nope')], 'bag not found'),
        'truncated sqlite3': ([str(_truncate(write_bag(folder / 'ts', clouds)))], 'cannot read'),
        'truncated mcap': (
            [str(_truncate(write_bag(folder / 'tm', clouds, storage='mcap')))],
            'cannot read',
        ),
        'truncated ros1': (
            [str(_truncate(write_bag(folder / 'tr', clouds, storage='ros1')))],
            'cannot read',
        ),
        'fewer messages than its index': ([str(miscounted)], 'truncated'),
        'not a bag': ([str(not_a_bag)], 'cannot read'),
        'directory without metadata': ([str(folder / 'empty_dir')], 'no metadata.yaml'),
        'no PointCloud2': (
            [str(write_bag(folder / 'strings', [], strings=strings))],
            'has no sensor_msgs/msg/PointCloud2 messages; its topics: /chatter',
        ),
        'unknown topic': (
            [str(write_bag(folder / 'unknown', clouds)), '--topic', '/nope'],
            'topic /nope is not in bag',
        ),
        'topic of another type': (
            [str(write_bag(folder / 'typed', clouds, strings=strings)), '--topic', '/chatter'],
            'holds std_msgs/msg/String',
        ),
        'two cloud topics (process only)': (
            [str(write_bag(folder / 'two', two_topics))],
            'choose one with --topic',
        ),
    }


@pytest.fixture(scope='module')
def bad_inputs(tmp_path_factory) -> dict[str, tuple[list[str], str]]:
    return _bad_inputs(tmp_path_factory.mktemp('bad'))


BAD_CASES = [
    'missing',
    'truncated sqlite3',
    'truncated mcap',
    'truncated ros1',
    'fewer messages than its index',
    'not a bag',
    'directory without metadata',
    'no PointCloud2',
    'unknown topic',
    'topic of another type',
    'two cloud topics (process only)',
]


#: Storage that breaks partway: `bag process` keeps the clouds before the break (exit code 1).
STORAGE_CASES = ('truncated sqlite3', 'truncated mcap', 'fewer messages than its index')


@pytest.mark.parametrize('case', [c for c in BAD_CASES if c not in STORAGE_CASES])
def test_bad_input_to_process_fails_cleanly(tmp_path, bad_inputs, case, capsys):
    arguments, message = bad_inputs[case]
    out_dir = tmp_path / 'results'
    out_dir.mkdir()
    out = out_dir / 'processed'
    code = main(['bag', 'process', arguments[0], str(out), *arguments[1:], '-p', 'voxel_size:=0'])
    error = capsys.readouterr().err
    assert code == 1
    assert error.startswith('mvbb bag process: error: ') and message in error, error
    assert _listing(out_dir) == [], 'nothing (not even a temporary directory) is left behind'


@pytest.mark.parametrize('case', [c for c in BAD_CASES if 'process only' not in c])
def test_bad_input_to_play_fails_cleanly(bad_inputs, case, capsys):
    arguments, message = bad_inputs[case]
    code = main(['bag', 'play', *arguments, '--wait-for-subscribers', '0', '--rate', '100'])
    error = capsys.readouterr().err
    assert code == 1
    assert error.startswith('mvbb bag play: error: ') and message in error, error


def test_existing_output_needs_force_and_input_is_never_the_output(tmp_path, sqlite_bag, capsys):
    out = tmp_path / 'out'
    out.mkdir()
    (out / 'keep.txt').write_text('precious')
    code = main(['bag', 'process', str(sqlite_bag), str(out), '-p', 'voxel_size:=0'])
    assert code == 1 and 'exists already; pass --force' in capsys.readouterr().err
    assert _listing(out) == ['keep.txt']
    assert main(['bag', 'process', str(sqlite_bag), str(sqlite_bag), '--force']) == 1
    assert 'must not be' in capsys.readouterr().err
    assert (sqlite_bag / 'metadata.yaml').exists()
    code = main(['bag', 'process', str(sqlite_bag), str(out), '--force', '--quiet'])
    assert code == 0
    assert 'keep.txt' not in _listing(out) and 'metadata.yaml' in _listing(out)
    assert _listing(tmp_path) == ['out']


@pytest.mark.parametrize('case', STORAGE_CASES)
def test_storage_failing_midway_keeps_the_clouds_before_it(tmp_path, bad_inputs, case, capsys):
    source = bad_inputs[case][0][0]
    out = tmp_path / 'out'
    out.mkdir()
    (out / 'old.txt').write_text('old result')
    code = main(['bag', 'process', source, str(out), '--force', '-p', 'voxel_size:=0'])
    captured = capsys.readouterr()
    assert code == 1 and 'Traceback' not in captured.err
    error = [line for line in captured.err.splitlines() if line.startswith('mvbb bag process')]
    assert len(error) == 1 and 'truncated' in error[0], captured.err
    kept = int(error[0].split('; kept the ')[1].split()[0])
    assert 0 <= kept <= 3 and f'total: {kept} clouds' in captured.out
    assert _listing(tmp_path) == ['out'], 'no temporary folder left'
    assert 'old.txt' not in _listing(out) and 'metadata.yaml' in _listing(out)
    assert all(len(stamps) == kept for stamps in _read(out).values())


def test_bad_parameters_are_refused(tmp_path, sqlite_bag, capsys):
    out = tmp_path / 'out'
    assert main(['bag', 'process', str(sqlite_bag), str(out), '-p', 'gain_threshold:=7']) == 1
    assert 'gain_threshold' in capsys.readouterr().err
    assert main(['bag', 'process', str(sqlite_bag), str(out), '-p', 'bogus:=1']) == 1
    assert "unknown setting 'bogus'" in capsys.readouterr().err
    assert not out.exists()
    with pytest.raises(SystemExit) as exit_info:
        main(['bag', 'play', str(sqlite_bag), '--rate', '0'])
    assert exit_info.value.code == 2


def test_cloud_bag_errors_are_bag_errors(tmp_path):
    with pytest.raises(BagError, match='bag not found'), CloudBag(tmp_path / 'nothing'):
        pass


# Playing on the live graph -------------------------------------------------------------------


def test_wall_offsets_scale_with_the_rate():
    assert wall_offset_s(5_000_000_000, 5_000_000_000, 1.0) == 0.0
    assert wall_offset_s(7_000_000_000, 5_000_000_000, 1.0) == pytest.approx(2.0)
    assert wall_offset_s(7_000_000_000, 5_000_000_000, 4.0) == pytest.approx(0.5)
    assert wall_offset_s(4_000_000_000, 5_000_000_000, 2.0) == 0.0, 'never in the past'


class _Listener:
    """The test's own node, in its own context: counts clouds on TOPIC and /clock."""

    def __init__(self, topic: str = TOPIC, message_class: type = PointCloud2) -> None:
        self.context = Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node('bag_play_test_listener', context=self.context)
        self.clouds: list = []
        self.clock: list[int] = []
        qos = QoSProfile(
            history=HistoryPolicy.KEEP_LAST, depth=50, reliability=ReliabilityPolicy.RELIABLE
        )
        self.subscription = self.node.create_subscription(
            message_class, topic, self.clouds.append, qos
        )
        self.node.create_subscription(
            Clock,
            '/clock',
            lambda m: self.clock.append(m.clock.sec * 1_000_000_000 + m.clock.nanosec),
            QoSProfile(depth=50, reliability=ReliabilityPolicy.BEST_EFFORT),
        )
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def spin_until(self, condition, timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and not condition():
            self.executor.spin_once(timeout_sec=0.05)
        return condition()

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def _play(*arguments: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, '-m', 'mvbb_ros.cli.main', 'bag', 'play', *arguments],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=dict(os.environ, PYTHONUNBUFFERED='1'),
    )


@pytest.fixture
def listener():
    node = _Listener()
    yield node
    node.close()


@pytest.mark.ros
@pytest.mark.parametrize('storage', ['sqlite3', 'ros1'])
def test_play_publishes_every_cloud_with_clock_and_ends(tmp_path, listener, storage):
    clouds = _test_clouds()
    bag = write_bag(
        tmp_path / 'in',
        [(TOPIC, t, c) for t, c in zip(BAG_TIMES, clouds, strict=True)],
        storage=storage,
        strings=[('/chatter', 6_000_000_000, 'not played')],
    )
    rate = 4.0
    player = _play(str(bag), '--rate', str(rate), '--clock', '--wait-for-subscribers', '30')
    try:
        assert listener.spin_until(lambda: player.poll() is not None, timeout_s=60.0)
        listener.spin_until(lambda: len(listener.clouds) >= 3, timeout_s=5.0)
        out, err = player.communicate(timeout=10)
    finally:
        if player.poll() is None:
            player.kill()
    assert player.returncode == 0, err
    assert 'done: published 3 clouds on /camera/segmented' in err
    assert [c.header for c in listener.clouds] == [c.header for c in clouds]
    assert [bytes(c.data) for c in listener.clouds] == [bytes(c.data) for c in clouds]
    # /clock: bag time, never backwards, within the played span; about 40 Hz for 0.5 s.
    assert len(listener.clock) >= 5, listener.clock
    assert listener.clock == sorted(listener.clock)
    assert BAG_TIMES[0] <= listener.clock[0] and listener.clock[-1] <= BAG_TIMES[-1]
    assert BAG_TIMES[-1] in listener.clock, 'the clock reaches each cloud time before it'
    played = float(err.split(' in ')[-1].split(' s')[0])
    assert played >= (BAG_TIMES[-1] - BAG_TIMES[0]) / 1e9 / rate - 0.01, 'timing kept'


@pytest.mark.ros
def test_play_loops_until_sigint_and_exits_zero(tmp_path, listener):
    bag = write_bag(
        tmp_path / 'in', [(TOPIC, t, c) for t, c in zip(BAG_TIMES, _test_clouds(), strict=True)]
    )
    player = _play(str(bag), '--rate', '10', '--loop', '--wait-for-subscribers', '30')
    try:
        assert listener.spin_until(lambda: len(listener.clouds) >= 7, timeout_s=60.0)
        player.send_signal(signal.SIGINT)
        out, err = player.communicate(timeout=20)
    finally:
        if player.poll() is None:
            player.kill()
    assert player.returncode == 0, err
    assert 'stopped: published' in err and 'complete loops' in err
    assert 'Traceback' not in err


def _play_to_the_end(bag: Path, *arguments: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, '-m', 'mvbb_ros.cli.main', 'bag', 'play', str(bag), *arguments],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )


@pytest.mark.ros
def test_play_without_subscribers_plays_nothing_and_fails(tmp_path):
    bag = write_bag(tmp_path / 'in', [(TOPIC, t, _test_clouds()[0]) for t in BAG_TIMES[:2]])
    result = _play_to_the_end(bag, '--rate', '20', '--wait-for-subscribers', '0.5')
    assert result.returncode == 1, result.stderr
    assert f'no subscriber on {TOPIC} after 0.5 s' in result.stderr
    assert 'nothing played' in result.stderr and 'published' not in result.stderr


@pytest.mark.ros
def test_play_without_waiting_plays_to_nobody_and_exits_zero(tmp_path):
    bag = write_bag(tmp_path / 'in', [(TOPIC, t, _test_clouds()[0]) for t in BAG_TIMES[:2]])
    result = _play_to_the_end(bag, '--rate', '20', '--wait-for-subscribers', '0')
    assert result.returncode == 0, result.stderr
    assert 'done: published 2 clouds' in result.stderr and 'waiting' not in result.stderr


def test_play_default_wait_is_long_enough_for_discovery_and_a_starting_node():
    from mvbb_ros.cli.main import build_parser, PLAY_WAIT_S
    from mvbb_ros.ros.bag_play import DEFAULT_WAIT_S

    assert PLAY_WAIT_S == DEFAULT_WAIT_S >= 10.0
    assert build_parser().parse_args(['bag', 'play', 'x']).wait_for_subscribers == DEFAULT_WAIT_S


@pytest.mark.ros
def test_play_waits_by_default_for_a_subscriber_that_comes_late(tmp_path):
    clouds = _test_clouds()
    bag = write_bag(tmp_path / 'in', list(zip([TOPIC] * 3, BAG_TIMES, clouds, strict=True)))
    player = _play(str(bag), '--rate', '10')  # the default wait
    try:
        assert player.stderr is not None
        assert 'waiting up to' in player.stderr.readline(), 'it says that it waits'
        time.sleep(2.0)  # nobody there yet: the player must hold the clouds back
        late = _Listener()
        try:
            assert late.spin_until(lambda: len(late.clouds) == 3, timeout_s=60.0)
            assert late.spin_until(lambda: player.poll() is not None, timeout_s=60.0)
        finally:
            late.close()
        _, err = player.communicate(timeout=10)
    finally:
        if player.poll() is None:
            player.kill()
    assert player.returncode == 0, err
    assert [c.header for c in late.clouds] == [c.header for c in clouds], 'none lost'


@pytest.mark.ros
@pytest.mark.slow
def test_play_through_a_node_started_at_the_same_time_answers_every_cloud(tmp_path):
    """The case of issue 18: 11 clouds at --rate 4 to a node that is still starting."""
    count = 11
    clouds = [_cloud(l_shape_points(seed=k, count=400), sec=200 + k) for k in range(count)]
    times = [1_000_000_000 * (k + 1) for k in range(count)]
    bag = write_bag(tmp_path / 'in', list(zip([TOPIC] * count, times, clouds, strict=True)))
    node = subprocess.Popen(
        [sys.executable, '-m', 'mvbb_ros.ros.decomposer', '--ros-args', '-r', f'cloud_in:={TOPIC}']
        + ['-p', 'input_depth:=50'],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    answers = _Listener(topic=OUTPUT_GRASPS, message_class=PoseArray)
    diagnostics: list = []
    answers.node.create_subscription(DiagnosticArray, '/diagnostics', diagnostics.append, 10)

    def skipped_busy() -> int:
        # The node's own count of clouds replaced by a newer one while it was busy.
        values = [
            int(value.value)
            for array in diagnostics
            for status in array.status
            for value in status.values
            if value.key == 'clouds_skipped_busy'
        ]
        return values[-1] if values else 0

    try:
        # The node makes its outputs before it warms up and subscribes: once this listener is
        # matched to them the node may still be starting, and no answer is lost on the way
        # back (a volatile subscription misses what was published before it matched).
        assert answers.spin_until(
            lambda: answers.subscription.get_publisher_count() > 0, timeout_s=60.0
        ), 'the node never offered its grasps'
        result = _play_to_the_end(bag, '--rate', '4')
        assert result.returncode == 0, result.stderr

        def stamps() -> set[int]:
            return {m.header.stamp.sec for m in answers.clouds}

        # Every cloud is answered, or counted as replaced by a newer one while a frame ran
        # (the node keeps only the newest waiting cloud); none is lost unaccounted for, and the
        # last one is always answered.
        assert answers.spin_until(
            lambda: 200 + count - 1 in stamps() and len(stamps()) + skipped_busy() >= count,
            timeout_s=60.0,
        ), f'{len(stamps())} of {count} answered, {skipped_busy()} skipped as busy'
        assert len(stamps()) + skipped_busy() == count
    finally:
        answers.close()
        node.send_signal(signal.SIGINT)
        try:
            node.wait(timeout=30)
        except subprocess.TimeoutExpired:
            node.kill()


def test_default_settings_are_the_node_defaults():
    assert settings_from_mapping({}) == PipelineSettings()


def test_output_is_removed_when_the_writer_fails(tmp_path, sqlite_bag, monkeypatch):
    def explode(*args, **kwargs):
        raise RuntimeError('disk full')

    monkeypatch.setattr(BagWriter, 'write', explode)
    with pytest.raises(RuntimeError, match='disk full'):
        process_bag(sqlite_bag, tmp_path / 'out', settings=settings_from_mapping(FAST))
    assert _listing(tmp_path) == []


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_progress_bar_draws_on_a_terminal_only():
    terminal = _Terminal()
    bar = ProgressBar(4, label='processing', stream=terminal, width=8)
    bar.update(2, 'half', force=True)
    assert terminal.getvalue() == '\rprocessing [####....] 2/4 half'
    bar.close()
    assert terminal.getvalue().endswith('\r')
    log = io.StringIO()
    quiet = ProgressBar(4, stream=log)
    quiet.update(1, force=True)
    quiet.close()
    assert log.getvalue() == ''
