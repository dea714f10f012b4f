"""
Bags with corrupt messages: `mvbb bag process` and `mvbb bag play` skip them, name them and go on.

The bags are written here with rosbags (rosbag2 sqlite3 and MCAP, and ROS 1): good clouds and,
between them, messages whose bytes are cut short, random or empty, the way a recorder that
crashed or a bad disk leaves them. Every good cloud must come out processed, and each bad one
must be listed by topic, number and bag time.
"""

from __future__ import annotations

import io
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

from mvbb_ros.cli.main import main
from mvbb_ros.pipeline.settings import settings_from_mapping
from mvbb_ros.ros.bag import BagError, CloudBag, SkippedMessage
from mvbb_ros.ros.bag_play import play_bag, SkipWarnings
from mvbb_ros.ros.encode import create_cloud_xyz, to_rosbags_cloud
from mvbb_ros.ros.offline import process_bag
import numpy as np
import pytest
from rclpy.serialization import serialize_message
from rosbags.highlevel import AnyReader
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import get_typestore, Stores
from support.shapes import l_shape_points

JAZZY = get_typestore(Stores.ROS2_JAZZY)
NOETIC = get_typestore(Stores.ROS1_NOETIC)
TOPIC = '/camera/segmented'
CLOUD = 'sensor_msgs/msg/PointCloud2'
FAST = {'voxel_size': 0.0, 'outlier_neighbors': 0}
#: Positions (from 0, among the topic's messages) of the corrupt messages, and how each is bad.
CORRUPT = {1: 'cut short', 3: 'random bytes', 4: 'empty'}
MESSAGES = 7


def _stamp(position: int) -> int:
    return 1_000_000_000 * (10 + position)


def _good_cloud(position: int):
    cloud = create_cloud_xyz(l_shape_points(seed=position, count=300), frame_id='cam')
    cloud.header.stamp.sec = 100 + position
    return cloud


def _spoil(good: bytes, how: str, position: int) -> bytes:
    if how == 'cut short':
        return good[: len(good) // 2]
    if how == 'random bytes':
        return np.random.default_rng(position).integers(0, 256, 400, dtype=np.uint8).tobytes()
    return b''


def write_corrupt_bag(path: Path, storage: str) -> Path:
    """Write MESSAGES messages on TOPIC, those at CORRUPT spoiled; return the bag's path."""
    if storage == 'ros1':
        path = path.with_suffix('.bag')
        with Ros1Writer(path) as writer:
            connection = writer.add_connection(TOPIC, CLOUD, typestore=NOETIC)
            for position in range(MESSAGES):
                message = to_rosbags_cloud(_good_cloud(position), NOETIC)
                raw = bytes(NOETIC.serialize_ros1(message, CLOUD))
                if position in CORRUPT:
                    raw = _spoil(raw, CORRUPT[position], position)
                writer.write(connection, _stamp(position), raw)
        return path
    plugin = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3
    with Writer(path, version=8, storage_plugin=plugin) as writer:
        connection = writer.add_connection(TOPIC, CLOUD, typestore=JAZZY)
        for position in range(MESSAGES):
            raw = serialize_message(_good_cloud(position))
            if position in CORRUPT:
                raw = _spoil(raw, CORRUPT[position], position)
            writer.write(connection, _stamp(position), raw)
    return path


GOOD = [position for position in range(MESSAGES) if position not in CORRUPT]


@pytest.fixture(scope='module', params=['sqlite3', 'mcap', 'ros1'])
def corrupt_bag(request, tmp_path_factory) -> Path:
    return write_corrupt_bag(tmp_path_factory.mktemp('corrupt') / 'input', request.param)


def test_reader_skips_and_names_what_does_not_deserialize(corrupt_bag):
    skipped: list[SkippedMessage] = []
    with CloudBag(corrupt_bag) as bag:
        clouds = list(bag.clouds([TOPIC], on_skip=skipped.append))
    assert [cloud.timestamp_ns for cloud in clouds] == [_stamp(p) for p in GOOD]
    assert [c.message().header.stamp.sec for c in clouds] == [100 + p for p in GOOD]
    assert [(m.topic, m.number, m.timestamp_ns) for m in skipped] == [
        (TOPIC, p + 1, _stamp(p)) for p in CORRUPT
    ]
    assert all(m.reason for m in skipped)
    line = skipped[0].describe()
    assert line.startswith(f'message 2 of {TOPIC} (bag time 11.000000000) does not deserialize')


def test_reader_without_a_skip_callback_fails_naming_the_message(corrupt_bag):
    with CloudBag(corrupt_bag) as bag:
        clouds = bag.clouds([TOPIC])
        assert next(clouds).timestamp_ns == _stamp(0)
        with pytest.raises(BagError, match=f'message 2 of {TOPIC} .* does not deserialize'):
            next(clouds)


def test_process_processes_every_good_cloud_and_lists_the_bad(tmp_path, corrupt_bag):
    out = tmp_path / 'out'
    summary = process_bag(corrupt_bag, out, settings=settings_from_mapping(FAST))
    assert [row.timestamp_ns for row in summary.rows] == [_stamp(p) for p in GOOD]
    assert all(
        row.boxes > 0 and not row.note.startswith('processing failed') for row in summary.rows
    )
    assert [(m.number, m.timestamp_ns) for m in summary.skipped] == [
        (p + 1, _stamp(p)) for p in CORRUPT
    ]
    with AnyReader([out]) as reader:
        stamps: dict[str, list[int]] = {}
        for connection, stamp, _ in reader.messages():
            stamps.setdefault(connection.topic, []).append(stamp)
    assert stamps and all(found == [_stamp(p) for p in GOOD] for found in stamps.values())


def test_process_cli_lists_the_skipped_messages_and_exits_zero(tmp_path, corrupt_bag, capsys):
    out = tmp_path / 'out'
    code = main(['bag', 'process', str(corrupt_bag), str(out), '-p', 'voxel_size:=0'])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert 'Traceback' not in captured.err
    lines = captured.out.splitlines()
    skips = [line for line in lines if line.startswith('skip message')]
    assert len(skips) == len(CORRUPT), captured.out
    first_total = next(k for k, line in enumerate(lines) if line.startswith('total: '))
    totals = lines[first_total:]
    assert f'total: {len(GOOD)} clouds' in totals[0]
    assert f'skipped {len(CORRUPT)} messages of {TOPIC} that do not deserialize' in captured.out
    listed = [line.strip() for line in totals if line.startswith('  message ')]
    assert [line.split(' (bag time ')[0] for line in listed] == [
        f'message {p + 1} of {TOPIC}' for p in CORRUPT
    ]
    assert (out / 'metadata.yaml').exists()


def test_play_skips_counts_and_warns(corrupt_bag):
    log = io.StringIO()
    stats = play_bag(corrupt_bag, rate=1000.0, wait_for_subscribers=0, log=log, progress=False)
    assert stats.published == len(GOOD) and stats.skipped == len(CORRUPT)
    warnings = [line for line in log.getvalue().splitlines() if line.startswith('warning: ')]
    assert len(warnings) == 1, 'the later ones fall within the warning period'
    assert f'message 2 of {TOPIC}' in warnings[0] and '1 skipped so far' in warnings[0]


def test_skip_warnings_are_throttled():
    now = [0.0]
    log = io.StringIO()
    warn = SkipWarnings(log, period_s=5.0, clock=lambda: now[0])
    for step in range(12):  # one skipped message a second
        now[0] = float(step)
        warn(SkippedMessage(TOPIC, step + 1, step, 'bad'))
    lines = log.getvalue().splitlines()
    assert warn.count == 12
    assert [line.split(' of ')[0] for line in lines] == [
        'warning: not published: message 1',
        'warning: not published: message 6',
        'warning: not published: message 11',
    ]
    assert '(4 more since the last warning); 6 skipped so far' in lines[1]


# Stop signals: SIGTERM and SIGHUP clean up as SIGINT does ---------------------------------------


def _slow_bag(path: Path) -> Path:
    """Write a bag of clouds heavy enough (with the default filters off) to be stopped midway."""
    with Writer(path, version=8, storage_plugin=StoragePlugin.SQLITE3) as writer:
        connection = writer.add_connection(TOPIC, CLOUD, typestore=JAZZY)
        for position in range(40):
            points = np.random.default_rng(position).normal(size=(20_000, 3)) * 0.05
            cloud = create_cloud_xyz(points.astype(np.float32), frame_id='cam')
            writer.write(connection, _stamp(position), serialize_message(cloud))
    return path


@pytest.mark.parametrize('signum', [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_stop_signals_leave_nothing_behind(tmp_path, signum):
    source = _slow_bag(tmp_path / 'input')
    results = tmp_path / 'results'
    results.mkdir()
    process = subprocess.Popen(
        [sys.executable, '-m', 'mvbb_ros.cli.main', 'bag', 'process', str(source)]
        + [str(results / 'out'), '-p', 'voxel_size:=0'],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=dict(os.environ, PYTHONUNBUFFERED='1'),
    )
    try:
        assert process.stdout is not None
        rows = 0
        deadline = time.monotonic() + 240.0
        while rows < 2 and time.monotonic() < deadline:  # two clouds processed: writing
            line = process.stdout.readline()
            if not line:
                break
            rows += line.split()[0].isdigit() if line.strip() else 0
        assert rows == 2, 'the run started writing before the signal'
        assert any(results.iterdir()), 'the temporary output exists while writing'
        process.send_signal(signum)
        _out, err = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            process.kill()
    name = signal.Signals(signum).name
    assert process.returncode == 128 + signum, (err, _out)
    assert f'interrupted ({name}); nothing written' in err and 'Traceback' not in err, err
    assert list(results.iterdir()) == [], 'no hidden temporary folder is left'


def test_bag_process_runs_the_frame_time_budget_as_the_node_does(tmp_path):
    source = write_corrupt_bag(tmp_path / 'input', 'mcap')
    settings = settings_from_mapping({**FAST, 'frame_time_budget': 1e-6})
    summary = process_bag(source, tmp_path / 'out', settings=settings)
    notes = [row.note for row in summary.rows]
    assert 'frame_time_budget' not in notes[0], 'the first frame runs as set'
    assert all(f'frame_time_budget: level {k} of 6' in n for k, n in enumerate(notes[1:], 1))


def test_without_skipping_a_corrupt_message_fails_and_writes_nothing(tmp_path, corrupt_bag):
    results = tmp_path / 'results'
    with pytest.raises(BagError, match=f'message 2 of {TOPIC} .* does not deserialize'):
        process_bag(
            corrupt_bag,
            results / 'out',
            settings=settings_from_mapping(FAST),
            skip_corrupt=False,
        )
    assert list(results.iterdir()) == [], 'nothing half-written'
