"""
Bags: read the PointCloud2 messages of any bag, and run the node's pipeline over them offline.

Reading (:class:`CloudBag`) works on rosbag2 bags (a directory with ``metadata.yaml``, sqlite3 or
MCAP storage, or a bare ``.db3``/``.mcap`` file) and on ROS 1 bags (``.bag``), through the
``rosbags`` library. Every cloud comes out as :class:`BagCloud`: the ROS 2 (CDR) serialization of
a ``sensor_msgs/msg/PointCloud2`` and its bag timestamp. ROS 2 bags already hold CDR bytes,
which are passed on untouched; ROS 1 clouds are converted once (:func:`ros1_cloud_to_cdr`). The
player publishes those bytes as they are and :func:`process_bag` deserializes them with rclpy,
so the node, the player and the offline tool all see the same messages.

Processing (:func:`process_bag`) runs :func:`mvbb_ros.pipeline.process_cloud` on every cloud and
writes :func:`mvbb_ros.messages.output_messages` (what the node publishes) into a new rosbag2 at
the input's timestamps, optionally with the input clouds, so the result plays in RViz
(``ros2 bag play``) or Foxglove. The output is written into a temporary directory beside it and
renamed into place only when complete (:func:`mvbb_ros.atomic.atomic_path`): a failure leaves
nothing behind.

Problems with the input (a missing, truncated or unreadable bag, no PointCloud2, an unknown
topic) raise :class:`BagError` with a message meant for the user.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
import functools
import os
from pathlib import Path
import shutil
import time
from types import TracebackType
from typing import Any

#: The message type the tools read, as rosbags names it for ROS 1 and ROS 2 bags alike.
CLOUD_TYPE = 'sensor_msgs/msg/PointCloud2'
#: Namespace of the output topics: the node's default name, so RViz configs work for both.
DEFAULT_NAMESPACE = '/decomposer'
#: rosbag2 metadata version written (the one ROS 2 Jazzy writes and reads).
ROSBAG2_VERSION = 8
#: Output storage formats: MCAP is Jazzy's default and opens directly in Foxglove.
STORAGE_FORMATS = ('mcap', 'sqlite3')


class BagError(Exception):
    """A bag cannot be used: the message says which bag and why."""


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

    def message(self) -> Any:
        """Return the cloud as a new rclpy ``sensor_msgs.msg.PointCloud2``."""
        from rclpy.serialization import deserialize_message
        from sensor_msgs.msg import PointCloud2

        return deserialize_message(self.cdr, PointCloud2)


def ros1_cloud_to_cdr(cloud: Any) -> bytes:
    """
    Return the ROS 2 CDR bytes of a cloud deserialized from a ROS 1 bag.

    The header's ``seq`` (ROS 1 only) is dropped; everything else is copied.

    :param cloud: a rosbags (or any duck-typed) ``sensor_msgs/PointCloud2``.
    """
    from mvbb_ros.pointcloud2 import to_rclpy_cloud
    from rclpy.serialization import serialize_message

    return serialize_message(to_rclpy_cloud(cloud))


@functools.lru_cache(maxsize=1)
def jazzy_typestore() -> Any:
    """Return the rosbags typestore of ROS 2 Jazzy (message definitions and type hashes)."""
    from rosbags.typesys import get_typestore, Stores

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
        from rosbags.highlevel import AnyReader

        if not self.path.exists():
            raise BagError(f'bag not found: {self.path}')
        if self.path.is_dir() and not (self.path / 'metadata.yaml').exists():
            raise BagError(f'{self.path} is not a rosbag2 bag: the directory has no metadata.yaml')
        try:
            reader = AnyReader([self.path], default_typestore=jazzy_typestore())
            reader.open()
        except Exception as error:  # rosbags, sqlite3 and YAML each raise their own errors
            raise BagError(
                f'cannot read bag {self.path} (truncated, corrupt or not a bag?): '
                f'{_describe(error)}'
            ) from error
        self._reader = reader

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

    def clouds(self, topics: Sequence[str]) -> Iterator[BagCloud]:
        """
        Yield the clouds on `topics` in time order, as ROS 2 CDR bytes.

        :raises BagError: when a message cannot be read, or when fewer messages can be read
            than the bag's index lists (a truncated bag).
        """
        reader = self.reader
        wanted = set(topics)
        connections = [c for c in reader.connections if c.topic in wanted]
        expected = self.count(topics)
        seen = 0
        messages = reader.messages(connections=connections) if connections else iter(())
        while True:
            try:
                item = next(messages, None)
                if item is None:
                    break
                connection, timestamp, raw = item
                if connection.msgtype != CLOUD_TYPE:
                    continue
                if reader.is2:
                    cdr = bytes(raw)
                else:
                    cdr = ros1_cloud_to_cdr(reader.deserialize(raw, connection.msgtype))
            except Exception as error:  # storage and deserialization errors alike
                raise BagError(
                    f'cannot read message {seen + 1} of bag {self.path} '
                    f'(truncated or corrupt?): {_describe(error)}'
                ) from error
            seen += 1
            yield BagCloud(topic=connection.topic, timestamp_ns=int(timestamp), cdr=cdr)
        if seen < expected:
            raise BagError(
                f'bag {self.path} is truncated: its index lists {expected} messages on '
                f'{", ".join(topics)}, but only {seen} could be read'
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
        from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer

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
        """Write one serialized message on a declared topic."""
        self._writer.write(self._connections[topic], timestamp_ns, cdr)
        self.counts[topic] += 1


# Processing -------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ProcessedCloud:
    """
    What one cloud of a bag gave; one row of the `mvbb bag process` table.

    :ivar index: position among the processed clouds, from 0.
    :ivar topic: input topic.
    :ivar timestamp_ns: the bag timestamp, kept on every output message.
    :ivar stamp_ns: the cloud header's stamp, nanoseconds (kept in every output header).
    :ivar frame_id: the cloud header's frame.
    :ivar points: finite input points.
    :ivar filtered: points left after filtering.
    :ivar boxes: leaf boxes.
    :ivar grasps: grasp poses written.
    :ivar milliseconds: pipeline time (decode, filter, decompose, grasps).
    :ivar note: why the outputs are empty (the node's warning), or ''.
    """

    index: int
    topic: str
    timestamp_ns: int
    stamp_ns: int
    frame_id: str
    points: int
    filtered: int
    boxes: int
    grasps: int
    milliseconds: float
    note: str = ''


@dataclass
class ProcessSummary:
    """
    Totals of one `mvbb bag process` run.

    :ivar rows: one entry per cloud, in bag order.
    :ivar topics: output topic -> messages written.
    :ivar wall_seconds: wall-clock time of the whole run (reading, processing, writing).
    """

    input_path: Path
    output_path: Path
    input_topic: str
    rows: list[ProcessedCloud] = field(default_factory=list)
    topics: dict[str, int] = field(default_factory=dict)
    wall_seconds: float = 0.0

    @property
    def clouds(self) -> int:
        """Return the number of clouds processed."""
        return len(self.rows)

    @property
    def points(self) -> int:
        """Return the total of finite input points."""
        return sum(row.points for row in self.rows)

    @property
    def boxes(self) -> int:
        """Return the total number of boxes."""
        return sum(row.boxes for row in self.rows)

    @property
    def grasps(self) -> int:
        """Return the total number of grasps."""
        return sum(row.grasps for row in self.rows)

    @property
    def milliseconds(self) -> float:
        """Return the total pipeline time in milliseconds."""
        return sum(row.milliseconds for row in self.rows)

    @property
    def empty(self) -> int:
        """Return how many clouds gave cleared outputs (with a note)."""
        return sum(1 for row in self.rows if row.note)

    @property
    def clouds_per_second(self) -> float:
        """Return the throughput over the whole run (wall clock)."""
        return self.clouds / self.wall_seconds if self.wall_seconds > 0 else float('inf')


#: Called after each cloud with the row, the rclpy cloud and the pipeline result (or None).
CloudCallback = Callable[[ProcessedCloud, Any, Any], None]


def run_pipeline(cloud: Any, settings: Any) -> tuple[Any, str]:
    """
    Run the node's pipeline on one rclpy cloud, surviving any failure as the node does.

    :return: ``(result, note)``: the :class:`~mvbb_ros.pipeline.PipelineResult` (None when
        processing raised) and why the outputs are empty ('' when they are not).
    """
    from mvbb_ros.pipeline import process_cloud

    try:
        result = process_cloud(cloud, settings)
    except Exception as error:  # the node survives any cloud; so does the offline tool
        return None, f'processing failed: {type(error).__name__}: {error}'
    return result, result.warning or ''


def _check_output(input_path: Path, output_path: Path, force: bool) -> None:
    source, target = input_path.resolve(), output_path.resolve()
    if target == source or source in target.parents or target in source.parents:
        raise BagError(f'the output {output_path} must not be, contain or be inside the input')
    if output_path.exists() and not force:
        raise BagError(f'{output_path} exists already; pass --force to replace it')


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    elif path.exists() or path.is_symlink():
        path.unlink()


def _stamp_ns(header: Any) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def process_bag(
    input_path: str | os.PathLike[str],
    output_path: str | os.PathLike[str],
    *,
    settings: Any = None,
    topic: str | None = None,
    with_input: bool = False,
    namespace: str = DEFAULT_NAMESPACE,
    storage: str = 'mcap',
    compress: bool = False,
    force: bool = False,
    on_start: Callable[[int], None] | None = None,
    on_cloud: CloudCallback | None = None,
) -> ProcessSummary:
    """
    Run the node's pipeline on every cloud of a bag and write the outputs into a new rosbag2.

    Each cloud gives the node's output messages (:func:`mvbb_ros.messages.output_messages`) on
    ``<namespace>/boxes``, ``<namespace>/tree`` (when ``publish_tree``) and
    ``<namespace>/grasps``, written at the cloud's bag timestamp and stamped with its header;
    with `with_input` the cloud itself is written first, on its own topic. Every cloud gives
    one message per output topic, also when the outputs are cleared (bad cloud).

    :param input_path: any bag :class:`CloudBag` reads.
    :param output_path: the rosbag2 directory to write; written atomically.
    :param settings: :class:`~mvbb_ros.settings.PipelineSettings`; None for the defaults.
    :param topic: the cloud topic; None when the bag has exactly one PointCloud2 topic.
    :param with_input: also write the input clouds.
    :param namespace: prefix of the output topics.
    :param storage: ``'mcap'`` or ``'sqlite3'``.
    :param compress: zstd compression (see :class:`BagWriter`).
    :param force: replace an existing `output_path`.
    :param on_start: called with the number of clouds to process, before the first.
    :param on_cloud: called after each cloud (for tables, progress and pictures).
    :return: the per-cloud rows and totals.
    :raises BagError: for a bad input bag or topic, or an output that exists; nothing is
        written then.
    """
    from mvbb_ros.atomic import atomic_path
    from mvbb_ros.messages import output_messages, OUTPUT_TYPES
    from mvbb_ros.pipeline import process_cloud  # noqa: F401 (imports Open3D before the clock)
    from mvbb_ros.settings import PipelineSettings
    from rclpy.serialization import serialize_message

    settings = settings if settings is not None else PipelineSettings()
    source, target = Path(input_path), Path(output_path)
    if not namespace.startswith('/') or (namespace.endswith('/') and namespace != '/'):
        raise BagError(f'the output namespace must start and not end with /, got {namespace!r}')
    prefix = namespace.rstrip('/')
    start = time.perf_counter()
    with CloudBag(source) as bag:
        cloud_topic = bag.select_topics(topic, single=True)[0]
        _check_output(source, target, force)
        summary = ProcessSummary(input_path=source, output_path=target, input_topic=cloud_topic)
        with atomic_path(target) as tmp, BagWriter(tmp, storage=storage, compress=compress) as out:
            if with_input:
                out.add_topic(cloud_topic, CLOUD_TYPE)
            for suffix, message_class in OUTPUT_TYPES.items():
                if suffix != 'tree' or settings.publish_tree:
                    out.add_topic(f'{prefix}/{suffix}', ros_type_name(message_class))
            if on_start is not None:
                on_start(bag.count([cloud_topic]))
            for index, item in enumerate(bag.clouds([cloud_topic])):
                cloud = item.message()
                result, note = run_pipeline(cloud, settings)
                if with_input:
                    out.write(cloud_topic, item.timestamp_ns, item.cdr)
                outputs = output_messages(result, cloud.header, settings)
                for suffix, message in outputs.items():
                    out.write(f'{prefix}/{suffix}', item.timestamp_ns, serialize_message(message))
                row = ProcessedCloud(
                    index=index,
                    topic=item.topic,
                    timestamp_ns=item.timestamp_ns,
                    stamp_ns=_stamp_ns(cloud.header),
                    frame_id=str(cloud.header.frame_id),
                    points=0 if result is None else int(result.counts.finite),
                    filtered=0 if result is None else int(result.counts.inliers),
                    boxes=0 if result is None else len(result.leaves),
                    grasps=len(outputs['grasps'].poses),
                    milliseconds=0.0 if result is None else float(result.total_ms),
                    note=note,
                )
                summary.rows.append(row)
                if on_cloud is not None:
                    on_cloud(row, cloud, result)
            summary.topics = dict(out.counts)
            if force and target.exists():
                _remove(target)
    summary.wall_seconds = time.perf_counter() - start
    return summary


# Reporting --------------------------------------------------------------------------------------

TABLE_HEADER = (
    f'{"#":>4} {"time_s":>8} {"stamp":>21} {"points":>8} {"filtered":>8} {"boxes":>5} '
    f'{"grasps":>6} {"ms":>8}  note'
)


def format_row(row: ProcessedCloud, start_ns: int) -> str:
    """Return one line of the table; `start_ns` is the bag time of the first cloud."""
    stamp = f'{row.stamp_ns // 1_000_000_000}.{row.stamp_ns % 1_000_000_000:09d}'
    return (
        f'{row.index:4d} {(row.timestamp_ns - start_ns) / 1e9:8.3f} {stamp:>21} '
        f'{row.points:8d} {row.filtered:8d} {row.boxes:5d} {row.grasps:6d} '
        f'{row.milliseconds:8.1f}  {row.note}'
    ).rstrip()


def format_totals(summary: ProcessSummary) -> list[str]:
    """Return the totals lines printed under the table."""
    clouds = summary.clouds
    mean = summary.milliseconds / clouds if clouds else 0.0
    lines = [
        f'total: {clouds} clouds, {summary.points} points, {summary.boxes} boxes, '
        f'{summary.grasps} grasps, {summary.milliseconds:.1f} ms in the pipeline '
        f'({mean:.1f} ms per cloud)',
        f'{summary.clouds_per_second:.2f} clouds/s over {summary.wall_seconds:.2f} s wall '
        '(reading, processing and writing)',
    ]
    if summary.empty:
        lines.append(f'{summary.empty} of {clouds} clouds gave cleared outputs (see note)')
    written = ', '.join(f'{topic} ({count})' for topic, count in summary.topics.items())
    lines.append(f'wrote {summary.output_path}: {written}')
    return lines
