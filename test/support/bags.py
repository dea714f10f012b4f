"""Small rosbag2 bags of L-shaped clouds for the bag and fleet tests, whole or spoiled."""

from __future__ import annotations

from pathlib import Path

from mvbb_ros.ros.encode import create_cloud_xyz
import numpy as np
from rclpy.serialization import serialize_message
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import get_typestore, Stores
from support.shapes import l_shape_points

JAZZY = get_typestore(Stores.ROS2_JAZZY)
TOPIC = '/camera/segmented'
CLOUD = 'sensor_msgs/msg/PointCloud2'


def bag_stamp(position: int) -> int:
    """Return the bag time (ns) of the message at `position`."""
    return 1_000_000_000 * (10 + position)


def write_cloud_bag(
    path: Path,
    storage: str,
    count: int,
    *,
    points: int = 1000,
    spoiled: dict[int, str] | None = None,
) -> Path:
    """
    Write `count` L-shaped clouds (header stamp 100 + position s) on TOPIC; return `path`.

    `spoiled` maps positions to ``'cut short'`` (the message's first half) or
    ``'random bytes'`` (400 of them); other values, or none, leave the message whole.
    """
    plugin = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3
    spoiled = spoiled or {}
    with Writer(path, version=8, storage_plugin=plugin) as writer:
        connection = writer.add_connection(TOPIC, CLOUD, typestore=JAZZY)
        for position in range(count):
            cloud = create_cloud_xyz(l_shape_points(seed=position, count=points), frame_id='cam')
            cloud.header.stamp.sec = 100 + position
            raw = serialize_message(cloud)
            if spoiled.get(position) == 'cut short':
                raw = raw[: len(raw) // 2]
            elif spoiled.get(position) == 'random bytes':
                rng = np.random.default_rng(position)
                raw = rng.integers(0, 256, 400, dtype=np.uint8).tobytes()
            writer.write(connection, bag_stamp(position), raw)
    return path


def cut_in_the_middle(bag: Path) -> Path:
    """Cut the bag's storage file at its middle byte, its metadata.yaml kept as it was."""
    storage = next(path for path in bag.iterdir() if path.suffix in ('.db3', '.mcap'))
    with open(storage, 'r+b') as handle:
        handle.truncate(storage.stat().st_size // 2)
    return bag


def promise_more(bag: Path, count: int) -> Path:
    """Make the index (metadata.yaml) of a bag of `count` messages list two more."""
    metadata = bag / 'metadata.yaml'
    text = metadata.read_text()
    old = f'message_count: {count}'
    assert old in text
    metadata.write_text(text.replace(old, f'message_count: {count + 2}'))
    return bag
