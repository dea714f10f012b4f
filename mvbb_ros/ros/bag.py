"""
Bags: read the PointCloud2 messages of any bag, and write messages into a new rosbag2.

Reading (:class:`CloudBag`) works on rosbag2 bags (a directory with ``metadata.yaml``, sqlite3 or
MCAP storage, or a bare ``.db3``/``.mcap`` file) and on ROS 1 bags (``.bag``), through the
``rosbags`` library. Every cloud comes out as :class:`BagCloud`: the ROS 2 (CDR) serialization of
a ``sensor_msgs/msg/PointCloud2`` and its bag timestamp. ROS 2 bags already hold CDR bytes,
which are passed on untouched; ROS 1 clouds are converted once (:func:`ros1_cloud_to_cdr`). The
player (:mod:`mvbb_ros.ros.bag_play`) publishes those bytes as they are and the offline tool
(:mod:`mvbb_ros.ros.offline`) deserializes them with rclpy, so the node, the player and the
offline tool all see the same messages. :class:`BagWriter` writes CDR messages into a new
rosbag2 (MCAP or sqlite3).

Problems with the input (a missing or unreadable bag, no PointCloud2, an unknown topic) raise
:class:`BagError` with a message meant for the user. A rosbag2 whose storage file is cut short
(so that ``rosbags`` cannot open it) is read without its index
(:class:`mvbb_ros.ros.salvage.SalvageReader`): its messages come in recording order up to the
first one that is not wholly in the file, and there, as anywhere the storage fails partway,
:class:`BagStorageError` (a :class:`BagError`) says where; the clouds read before it are good.
A message the storage gives but that does not deserialize as a PointCloud2 (corrupt bytes) is
either skipped and described by a :class:`SkippedMessage` (when the reader asks for that) or a
:class:`BagError`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
import functools
import os
from pathlib import Path
import shutil
from types import TracebackType
from typing import Any, Final

from builtin_interfaces.msg import Time
from mvbb_ros.common.atomic import atomic_path
from mvbb_ros.ros.encode import create_cloud_xyz, to_rclpy_cloud
from mvbb_ros.ros.salvage import SalvageReader, storage_kind
from numpy.typing import ArrayLike
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
from rosbags.typesys import get_typestore, Stores
from sensor_msgs.msg import PointCloud2

#: The message type the tools read, as rosbags names it for ROS 1 and ROS 2 bags alike.
CLOUD_TYPE = 'sensor_msgs/msg/PointCloud2'
#: rosbag2 metadata version written (the one ROS 2 Jazzy writes and reads).
ROSBAG2_VERSION: Final = 8
#: Output storage formats: MCAP is Jazzy's default and opens directly in Foxglove.
STORAGE_FORMATS = ('mcap', 'sqlite3')


class BagError(Exception):
    """A bag cannot be used: the message says which bag and why."""


class BagStorageError(BagError):
    """
    The bag's storage stopped giving messages partway (truncated or corrupt storage).

    The clouds read before it are whole: a reader may keep what it made of them.

    :ivar read: the messages read on the requested topics before the storage failed.
    """

    def __init__(self, message: str, read: int) -> None:
        super().__init__(message)
        self.read = read


# Reading ----------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TopicSummary:
    """One topic of a bag: name, message type and message count."""

    name: str
    msgtype: str
    count: int


@dataclass(frozen=True)
class BagCloud:
    """
    One PointCloud2 of a bag.

    :ivar topic: the topic it was recorded on.
    :ivar timestamp_ns: the bag's timestamp (receive time), nanoseconds.
    :ivar cdr: the ROS 2 CDR serialization of the ``sensor_msgs/msg/PointCloud2``.
    """

    topic: str
    timestamp_ns: int
    cdr: bytes
    cloud: Any = field(default=None, compare=False, repr=False)

    def message(self) -> Any:
        """Return the cloud as an rclpy ``sensor_msgs.msg.PointCloud2`` (deserialized once)."""
        return self.cloud if self.cloud is not None else deserialize_message(self.cdr, PointCloud2)


@dataclass(frozen=True)
class SkippedMessage:
    """
    A message of a bag that was read but does not deserialize as a PointCloud2 (corrupt bytes).

    :ivar topic: its topic.
    :ivar number: its position among the messages of `topic` that were read, from 1.
    :ivar timestamp_ns: its bag timestamp, nanoseconds.
    :ivar reason: what the deserializer said.
    """

    topic: str
    number: int
    timestamp_ns: int
    reason: str

    def describe(self) -> str:
        """Return one line naming the message and why it was skipped."""
        seconds, nanoseconds = divmod(self.timestamp_ns, 1_000_000_000)
        return (
            f'message {self.number} of {self.topic} (bag time {seconds}.{nanoseconds:09d}) '
            f'does not deserialize as {CLOUD_TYPE}: {self.reason}'
        )


def ros1_cloud_to_cdr(cloud: Any) -> bytes:
    """
    Return the ROS 2 CDR bytes of a cloud deserialized from a ROS 1 bag.

    The header's ``seq`` (ROS 1 only) is dropped; everything else is copied.

    :param cloud: a rosbags (or any duck-typed) ``sensor_msgs/PointCloud2``.
    """
    return serialize_message(to_rclpy_cloud(cloud))


@functools.lru_cache(maxsize=1)
def jazzy_typestore() -> Any:
    """Return the rosbags typestore of ROS 2 Jazzy (message definitions and type hashes)."""
    return get_typestore(Stores.ROS2_JAZZY)


def _describe(error: BaseException) -> str:
    text = str(error).strip() or type(error).__name__
    return text if text.endswith('.') else f'{text}.'


class CloudBag:
    """
    A bag opened for reading its PointCloud2 messages; use it as a context manager.

    :param path: a rosbag2 directory, a ``.db3`` or ``.mcap`` file, or a ROS 1 ``.bag`` file.
    :raises BagError: when the path does not exist or is not a readable bag.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self._reader: Any = None

    def __enter__(self) -> CloudBag:
        """
        Open the bag and read its index.

        :raises BagError: when the path does not exist or is not a readable bag.
        """
        self._open()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc_value: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        """Close the bag."""
        self.close()

    def _open(self) -> None:
        if not self.path.exists():
            raise BagError(f'bag not found: {self.path}')
        if self.path.is_dir() and not (self.path / 'metadata.yaml').exists():
            raise BagError(f'{self.path} is not a rosbag2 bag: the directory has no metadata.yaml')
        reader: Any
        try:
            reader = AnyReader([self.path], default_typestore=jazzy_typestore())
            reader.open()
        except Exception as error:  # rosbags, sqlite3 and YAML each raise their own errors
            reader = self._salvage()
            if reader is None:
                raise BagError(
                    f'cannot read bag {self.path} (truncated, corrupt or not a bag?): '
                    f'{_describe(error)}'
                ) from error
        self._reader = reader

    def _salvage(self) -> SalvageReader | None:
        """Return a reader of a rosbag2 whose storage is cut short, or None for other failures."""
        if not self.path.is_dir() and not storage_kind(self.path):
            return None
        try:
            reader = SalvageReader(self.path)
        except Exception:  # not a rosbag2 this reader knows: the first error is the one to tell
            return None
        return reader if reader.cut else None

    @property
    def salvaged(self) -> bool:
        """Whether the bag is read without its index (its storage file is cut short)."""
        return isinstance(self.reader, SalvageReader)

    def close(self) -> None:
        """Close the bag (no-op when it is not open)."""
        if self._reader is not None:
            reader, self._reader = self._reader, None
            reader.close()

    @property
    def reader(self) -> Any:
        """Return the open ``rosbags.highlevel.AnyReader``."""
        if self._reader is None:
            raise BagError(f'bag {self.path} is not open')
        return self._reader

    @property
    def is_ros1(self) -> bool:
        """Return whether this is a ROS 1 bag."""
        return not self.reader.is2

    def topics(self) -> list[TopicSummary]:
        """Return every topic of the bag, sorted by name."""
        return [
            TopicSummary(name, info.msgtype or '?', int(info.msgcount))
            for name, info in sorted(self.reader.topics.items())
        ]

    def cloud_topics(self) -> list[TopicSummary]:
        """Return the topics that hold PointCloud2 messages, sorted by name."""
        return [topic for topic in self.topics() if topic.msgtype == CLOUD_TYPE]

    def _topics_text(self) -> str:
        topics = self.topics()
        if not topics:
            return 'the bag has no topics'
        return 'its topics: ' + ', '.join(
            f'{topic.name} ({topic.msgtype}, {topic.count})' for topic in topics
        )

    def select_topics(self, topic: str | None = None, *, single: bool = False) -> list[str]:
        """
        Return the cloud topics to read: `topic`, or every PointCloud2 topic when it is None.

        :param topic: a topic name; None for all PointCloud2 topics.
        :param single: require exactly one topic (ask for ``--topic`` when there are more).
        :raises BagError: when `topic` is not in the bag or is not PointCloud2, when the bag
            has no PointCloud2 messages, or when `single` and there are several topics.
        """
        clouds = self.cloud_topics()
        if topic is not None:
            known = {summary.name: summary for summary in self.topics()}
            if topic not in known:
                raise BagError(f'topic {topic} is not in bag {self.path}; {self._topics_text()}')
            if known[topic].msgtype != CLOUD_TYPE:
                raise BagError(
                    f'topic {topic} in bag {self.path} holds {known[topic].msgtype}, '
                    f'not {CLOUD_TYPE}'
                )
            if known[topic].count == 0:
                raise BagError(f'topic {topic} in bag {self.path} has no messages')
            return [topic]
        clouds = [summary for summary in clouds if summary.count > 0]
        if not clouds:
            raise BagError(f'bag {self.path} has no {CLOUD_TYPE} messages; {self._topics_text()}')
        if single and len(clouds) > 1:
            names = ', '.join(f'{summary.name} ({summary.count})' for summary in clouds)
            raise BagError(
                f'bag {self.path} has {len(clouds)} PointCloud2 topics: {names}; '
                'choose one with --topic'
            )
        return [summary.name for summary in clouds]

    def count(self, topics: Sequence[str]) -> int:
        """Return how many messages the bag's index lists on `topics`."""
        counts = {summary.name: summary.count for summary in self.topics()}
        return sum(counts.get(topic, 0) for topic in topics)

    def time_range(self) -> tuple[int, int]:
        """Return the bag times of its first message and just after its last, nanoseconds."""
        return int(self.reader.start_time), int(self.reader.end_time)

    def clouds(
        self,
        topics: Sequence[str],
        *,
        start_ns: int | None = None,
        stop_ns: int | None = None,
        on_skip: Callable[[SkippedMessage], None] | None = None,
    ) -> Iterator[BagCloud]:
        """
        Yield the clouds on `topics` in time order, as ROS 2 CDR bytes and rclpy messages.

        With `start_ns` or `stop_ns`, only the clouds of bag times in ``[start_ns, stop_ns)``:
        rosbags seeks there through the bag's index (MCAP chunk index, the sqlite3 timestamp
        column, ROS 1 chunk records) rather than reading what comes before.

        Every message is deserialized here, once (the node would fail on the same bytes): one
        that does not deserialize is passed to `on_skip` and skipped, or raises when `on_skip`
        is None.

        :raises BagStorageError: when the storage cannot give a message (cut short or corrupt),
            or when fewer messages can be read than the bag's index lists (checked when
            reading all of it); the clouds yielded before are good.
        :raises BagError: when a message does not deserialize and `on_skip` is None.
        """
        reader = self.reader
        wanted = set(topics)
        connections = [c for c in reader.connections if c.topic in wanted]
        whole = start_ns is None and stop_ns is None
        expected = self.count(topics) if whole else 0
        seen = 0
        numbers: dict[str, int] = {}
        messages = (
            reader.messages(connections=connections, start=start_ns, stop=stop_ns)
            if connections
            else iter(())
        )
        while True:
            try:
                item = next(messages, None)
            except Exception as error:  # storage errors: nothing after this can be read
                raise BagStorageError(
                    f'cannot read bag {self.path} past message {seen} on {", ".join(topics)} '
                    f'(truncated or corrupt?): {_describe(error)}',
                    seen,
                ) from error
            if item is None:
                break
            connection, timestamp, raw = item
            if connection.msgtype != CLOUD_TYPE:
                continue
            seen += 1
            topic = connection.topic
            numbers[topic] = numbers.get(topic, 0) + 1
            try:
                if reader.is2:
                    cdr = bytes(raw)
                    cloud = deserialize_message(cdr, PointCloud2)
                else:
                    cloud = to_rclpy_cloud(reader.deserialize(raw, connection.msgtype))
                    cdr = serialize_message(cloud)
            except Exception as error:  # rclpy's RMWError, rosbags' errors, bad field values
                skipped = SkippedMessage(topic, numbers[topic], int(timestamp), _describe(error))
                if on_skip is None:
                    raise BagError(f'bag {self.path}: {skipped.describe()}') from error
                on_skip(skipped)
                continue
            yield BagCloud(topic=topic, timestamp_ns=int(timestamp), cdr=cdr, cloud=cloud)
        if seen < expected:
            raise BagStorageError(
                f'bag {self.path} is truncated: its index lists {expected} messages on '
                f'{", ".join(topics)}, but only {seen} could be read',
                seen,
            )


# Writing ----------------------------------------------------------------------------------------


def ros_type_name(message_class: type) -> str:
    """Return ``package/msg/Name`` of an rclpy message class (the name bags store)."""
    package = message_class.__module__.split('.', 1)[0]
    return f'{package}/msg/{message_class.__name__}'


class BagWriter:
    """
    Write CDR messages into a new rosbag2 (metadata version 8); use it as a context manager.

    :param path: the bag directory to create; it must not exist.
    :param storage: ``'mcap'`` or ``'sqlite3'``.
    :param compress: zstd compression: MCAP chunks, or each sqlite3 message.
    """

    def __init__(
        self, path: str | os.PathLike[str], *, storage: str = 'mcap', compress: bool = False
    ) -> None:
        if storage not in STORAGE_FORMATS:
            raise BagError(f'storage must be one of {", ".join(STORAGE_FORMATS)}, got {storage!r}')
        plugin = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3
        self._writer = Writer(Path(path), version=ROSBAG2_VERSION, storage_plugin=plugin)
        if compress:
            mode = CompressionMode.STORAGE if storage == 'mcap' else CompressionMode.MESSAGE
            self._writer.set_compression(mode, CompressionFormat.ZSTD)
        self._connections: dict[str, Any] = {}
        self.counts: dict[str, int] = {}

    def __enter__(self) -> BagWriter:
        """Create the bag."""
        self._writer.open()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc_value: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        """Finish the bag (its index and metadata.yaml), or abandon it after an error."""
        if exc_type is None:
            self._writer.close()
        else:
            self._writer.abort()

    def add_topic(self, topic: str, msgtype: str) -> None:
        """Declare `topic` with its message type (``package/msg/Name``), once."""
        if topic not in self._connections:
            self._connections[topic] = self._writer.add_connection(
                topic, msgtype, typestore=jazzy_typestore()
            )
            self.counts[topic] = 0

    def write(self, topic: str, timestamp_ns: int, cdr: bytes) -> None:
        """Write one serialized message on a declared topic, its padding bytes zeroed."""
        connection = self._connections[topic]
        self._writer.write(connection, timestamp_ns, canonical_cdr(cdr, connection.msgtype))
        self.counts[topic] += 1


def canonical_cdr(cdr: bytes, msgtype: str) -> bytes:
    """
    Return `cdr` with its alignment padding zeroed: the same message, always the same bytes.

    rclpy's serializer leaves CDR padding bytes as it found them in memory, so one message
    serialized twice may differ in those bytes; rosbags' serializer writes zeros. Writing
    every message through it makes a bag tool's output reproducible byte for byte (the fleet
    compares its outputs with a serial run's that way).

    :param cdr: a CDR serialization (little- or big-endian) of a `msgtype` message.
    :param msgtype: ``package/msg/Name``.
    """
    store = jazzy_typestore()
    message = store.deserialize_cdr(cdr, msgtype)
    return bytes(store.serialize_cdr(message, msgtype, little_endian=bool(cdr[1])))


def write_cloud_bag(
    path: str | os.PathLike[str],
    topic: str,
    frame_id: str,
    clouds: Iterable[tuple[int, ArrayLike]],
    *,
    storage: str = 'mcap',
) -> None:
    """
    Write (N, 3) point clouds as PointCloud2 messages on `topic` into a new rosbag2.

    Each cloud is given with its time in nanoseconds, used both as the bag timestamp and as the
    header stamp. The bag is written atomically and replaces an old one at `path`.

    :param path: the rosbag2 directory to write.
    :param topic: the cloud topic.
    :param frame_id: the clouds' frame.
    :param clouds: ``(stamp_ns, points)`` pairs in time order.
    :param storage: ``'mcap'`` or ``'sqlite3'``.
    """
    target = Path(path)
    with atomic_path(target) as tmp, BagWriter(tmp, storage=storage) as writer:
        writer.add_topic(topic, CLOUD_TYPE)
        for stamp_ns, points in clouds:
            sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
            stamp = Time(sec=sec, nanosec=nanosec)
            cloud = create_cloud_xyz(points, frame_id=frame_id, stamp=stamp)
            writer.write(topic, int(stamp_ns), serialize_message(cloud))
        if target.exists():
            shutil.rmtree(target)
