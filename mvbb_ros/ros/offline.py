"""
Run the node's pipeline over every cloud of a bag, offline, and write the results as a bag.

:func:`process_bag` runs :func:`mvbb_ros.pipeline.process.process_cloud` on every cloud and
writes :func:`mvbb_ros.ros.messages.output_messages` (what the node publishes) into a new
rosbag2 at the input's timestamps, optionally with the input clouds, so the result plays in RViz
(``ros2 bag play``) or Foxglove. The output is written into a temporary directory beside it and
renamed into place only when complete (:func:`mvbb_ros.common.atomic.atomic_path`): a failure
leaves nothing behind, but for one: when the bag's storage fails partway (a file cut short, an
index that lists more messages than it holds), the output holds the clouds processed before
that point and :attr:`ProcessSummary.storage_error` says where. A message that does not
deserialize as a PointCloud2 (corrupt bytes) is skipped, and listed in the summary
(:attr:`ProcessSummary.skipped`); the other clouds are processed and written as usual.
:func:`format_row` and :func:`format_totals` make the table that `mvbb bag process` prints.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
import contextlib
from dataclasses import dataclass, field
import math
import os
from pathlib import Path
import shutil
import time
from typing import Any

from mvbb_ros.common.atomic import atomic_path
from mvbb_ros.pipeline.budget import FrameBudget
from mvbb_ros.pipeline.explain import empty_grasps_note
from mvbb_ros.pipeline.process import GraspMemory, process_cloud
from mvbb_ros.pipeline.result import PipelineResult
from mvbb_ros.pipeline.settings import PipelineSettings
from mvbb_ros.ros.bag import (
    BagError,
    BagStorageError,
    BagWriter,
    CLOUD_TYPE,
    CloudBag,
    ros_type_name,
    SkippedMessage,
)
from mvbb_ros.ros.messages import output_messages, OUTPUT_TYPES
from rclpy.serialization import serialize_message
from sensor_msgs.msg import PointCloud2

#: Namespace of the output topics: the node's default name, so RViz configs work for both.
DEFAULT_NAMESPACE = '/decomposer'


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
    :ivar note: why the outputs are empty (the node's warning), or which grasp filter removed
        every grasp when there are boxes but no grasps, or which object's hidden side was not
        estimated (:attr:`~mvbb_ros.pipeline.result.PipelineResult.notes`), or ''.
    :ivar objects: objects found in the cloud.
    :ivar top_score: the top grasp's score, NaN when there is none.
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
    objects: int = 0
    top_score: float = math.nan


@dataclass
class ProcessSummary:
    """
    Totals of one `mvbb bag process` run.

    :ivar rows: one entry per cloud, in bag order.
    :ivar skipped: the messages skipped because they do not deserialize, in bag order.
    :ivar topics: output topic -> messages written.
    :ivar wall_seconds: wall-clock time of the whole run (reading, processing, writing).
    :ivar storage_error: where the bag's storage failed partway ('' when it did not); the
        output then holds the clouds before that point.
    """

    input_path: Path
    output_path: Path
    input_topic: str
    rows: list[ProcessedCloud] = field(default_factory=list)
    skipped: list[SkippedMessage] = field(default_factory=list)
    topics: dict[str, int] = field(default_factory=dict)
    wall_seconds: float = 0.0
    storage_error: str = ''

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
        return sum(1 for row in self.rows if row.note and not row.boxes)

    @property
    def without_grasps(self) -> int:
        """Return how many clouds gave boxes but no grasps (the note says which filter)."""
        return sum(1 for row in self.rows if row.boxes and not row.grasps)

    @property
    def clouds_per_second(self) -> float:
        """Return the throughput over the whole run (wall clock)."""
        return self.clouds / self.wall_seconds if self.wall_seconds > 0 else float('inf')


#: Called after each cloud with the row, the rclpy cloud and the pipeline result (or None).
CloudCallback = Callable[[ProcessedCloud, PointCloud2, PipelineResult | None], None]


def run_pipeline(
    cloud: PointCloud2,
    settings: PipelineSettings,
    memory: GraspMemory | None = None,
    budget: FrameBudget | None = None,
) -> tuple[PipelineResult | None, str]:
    """
    Run the node's pipeline on one rclpy cloud, surviving any failure as the node does.

    :param cloud: the cloud.
    :param settings: the settings.
    :param memory: the previous cloud's top grasp (the hysteresis, as in the node), updated
        with this cloud's; None: no memory.
    :param budget: the stream's frame time budget (``frame_time_budget``), as in the node;
        None: none.
    :return: ``(result, note)``: the pipeline result (None when processing raised) and why the
        outputs are empty, or why there are boxes but no grasps, or the result's notes ('' when
        none); the units hint (``looks like millimetres``) comes first when there is one.
    """
    frame = str(cloud.header.frame_id)
    previous = None if memory is None else memory.previous(frame)
    try:
        result = process_cloud(cloud, settings, previous=previous, budget=budget)
    except Exception as error:  # the node survives any cloud; so does the offline tool
        if memory is not None:
            memory.remember(frame, None)
        return None, f'processing failed: {type(error).__name__}: {error}'
    if memory is not None:
        memory.remember(frame, result)
    notes = [note for note in result.notes if note not in (result.units_note, result.budget_note)]
    note = result.warning or empty_grasps_note(result, settings) or '; '.join(notes)
    return result, '; '.join(filter(None, [result.units_note, result.budget_note, note]))


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


#: One message to write: ``(topic, bag timestamp ns, CDR bytes)``.
OutputMessage = tuple[str, int, bytes]


def output_prefix(namespace: str) -> str:
    """
    Return the prefix of the output topics for `namespace`.

    :raises BagError: when `namespace` does not start with ``/`` or ends with one.
    """
    if not namespace.startswith('/') or (namespace.endswith('/') and namespace != '/'):
        raise BagError(f'the output namespace must start and not end with /, got {namespace!r}')
    return namespace.rstrip('/')


@contextlib.contextmanager
def open_output(
    target: Path,
    cloud_topic: str,
    settings: PipelineSettings,
    *,
    with_input: bool = False,
    namespace: str = DEFAULT_NAMESPACE,
    storage: str = 'mcap',
    compress: bool = False,
    force: bool = False,
) -> Iterator[BagWriter]:
    """
    Open the output bag of :func:`process_bag` with its topics declared; write it atomically.

    The block writes the messages (:func:`process_clouds` gives them); the bag appears at
    `target` only when the block ends without an error, replacing an old one when `force`.

    :param target: the rosbag2 directory to write.
    :param cloud_topic: the input topic (declared first when `with_input`).
    :param settings: the settings (``publish_tree`` decides the tree topic).
    """
    prefix = output_prefix(namespace)
    with atomic_path(target) as tmp, BagWriter(tmp, storage=storage, compress=compress) as out:
        if with_input:
            out.add_topic(cloud_topic, CLOUD_TYPE)
        for suffix, message_class in OUTPUT_TYPES.items():
            if suffix != 'tree' or settings.node.publish_tree:
                out.add_topic(f'{prefix}/{suffix}', ros_type_name(message_class))
        yield out
        if force and target.exists():
            _remove(target)


def process_clouds(
    bag: CloudBag,
    cloud_topic: str,
    settings: PipelineSettings,
    memory: GraspMemory,
    *,
    with_input: bool = False,
    namespace: str = DEFAULT_NAMESPACE,
    start_ns: int | None = None,
    stop_ns: int | None = None,
    first_index: int = 0,
    on_skip: Callable[[SkippedMessage], None] | None = None,
) -> Iterator[tuple[ProcessedCloud, list[OutputMessage], Any, PipelineResult | None]]:
    """
    Run the node's pipeline on the clouds of an open bag; yield each one's row and messages.

    This is the one implementation of `mvbb bag process`: :func:`process_bag` writes what it
    yields, and the fleet (:mod:`mvbb_ros.fleet`) runs it on time ranges of long bags.

    :param bag: the open bag.
    :param cloud_topic: the cloud topic.
    :param settings: the settings.
    :param memory: the previous cloud's top grasp (the node's hysteresis), updated cloud after
        cloud. The frame time budget (``frame_time_budget``) starts afresh at the first cloud.
    :param start_ns: read clouds at or after this bag time (nanoseconds); None: from the start.
    :param stop_ns: read clouds before this bag time; None: to the end.
    :param first_index: the row index of the first cloud.
    :param on_skip: called with each message that does not deserialize, which is then skipped;
        None: such a message raises :class:`~mvbb_ros.ros.bag.BagError`.
    :return: ``(row, messages, cloud, result)`` per cloud: its table row, the messages to write
        in order (the input cloud first when `with_input`), the rclpy cloud and the pipeline
        result (None when processing raised).
    """
    prefix = output_prefix(namespace)
    budget = FrameBudget()  # the node's frame time budget, cloud after cloud
    clouds = bag.clouds([cloud_topic], start_ns=start_ns, stop_ns=stop_ns, on_skip=on_skip)
    for index, item in enumerate(clouds, start=first_index):
        cloud = item.message()
        result, note = run_pipeline(cloud, settings, memory, budget)
        messages: list[OutputMessage] = []
        if with_input:
            messages.append((cloud_topic, item.timestamp_ns, item.cdr))
        outputs = output_messages(result, cloud.header, settings)
        for suffix, message in outputs.items():
            messages.append((f'{prefix}/{suffix}', item.timestamp_ns, serialize_message(message)))
        grasps = [] if result is None else result.grasps
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
            objects=0 if result is None else len(result.objects),
            top_score=float(grasps[0].score) if grasps else math.nan,
        )
        yield row, messages, cloud, result


def process_bag(
    input_path: str | os.PathLike[str],
    output_path: str | os.PathLike[str],
    *,
    settings: PipelineSettings | None = None,
    topic: str | None = None,
    with_input: bool = False,
    namespace: str = DEFAULT_NAMESPACE,
    storage: str = 'mcap',
    compress: bool = False,
    force: bool = False,
    on_start: Callable[[int], None] | None = None,
    on_cloud: CloudCallback | None = None,
    on_skip: Callable[[SkippedMessage], None] | None = None,
    skip_corrupt: bool = True,
) -> ProcessSummary:
    """
    Run the node's pipeline on every cloud of a bag and write the outputs into a new rosbag2.

    Each cloud gives the node's output messages (:func:`mvbb_ros.ros.messages.output_messages`) on
    ``<namespace>/boxes``, ``<namespace>/tree`` (when ``publish_tree``) and
    ``<namespace>/grasps``, written at the cloud's bag timestamp and stamped with its header;
    with `with_input` the cloud itself is written first, on its own topic. Every cloud gives
    one message per output topic, also when the outputs are cleared (bad cloud). A message
    that does not deserialize as a PointCloud2 gives no outputs: it is skipped and listed in
    :attr:`ProcessSummary.skipped`, and the run goes on. When the storage fails partway
    (:class:`~mvbb_ros.ros.bag.BagStorageError`: a truncated file, an index that lists more
    messages than the bag holds), the clouds processed before are written as a complete bag
    and :attr:`ProcessSummary.storage_error` says where the storage failed.

    :param input_path: any bag :class:`CloudBag` reads.
    :param output_path: the rosbag2 directory to write; written atomically.
    :param settings: :class:`~mvbb_ros.pipeline.settings.PipelineSettings`; None for the defaults.
    :param topic: the cloud topic; None when the bag has exactly one PointCloud2 topic.
    :param with_input: also write the input clouds.
    :param namespace: prefix of the output topics.
    :param storage: ``'mcap'`` or ``'sqlite3'``.
    :param compress: zstd compression (see :class:`BagWriter`).
    :param force: replace an existing `output_path`.
    :param on_start: called with the number of clouds to process, before the first.
    :param on_cloud: called after each cloud (for tables, progress and pictures).
    :param on_skip: called with each skipped message, when it is skipped.
    :param skip_corrupt: skip messages that do not deserialize; False: such a message is a
        :class:`~mvbb_ros.ros.bag.BagError` and nothing is written.
    :return: the per-cloud rows and totals.
    :raises BagError: for a bad input bag or topic, an output that exists, or (without
        `skip_corrupt`) a message that does not deserialize; nothing is written then.
    """
    settings = settings if settings is not None else PipelineSettings()
    source, target = Path(input_path), Path(output_path)
    output_prefix(namespace)
    start = time.perf_counter()
    with CloudBag(source) as bag:
        cloud_topic = bag.select_topics(topic, single=True)[0]
        _check_output(source, target, force)
        summary = ProcessSummary(input_path=source, output_path=target, input_topic=cloud_topic)
        with open_output(
            target,
            cloud_topic,
            settings,
            with_input=with_input,
            namespace=namespace,
            storage=storage,
            compress=compress,
            force=force,
        ) as out:
            if on_start is not None:
                on_start(bag.count([cloud_topic]))
            memory = GraspMemory()  # the node's hysteresis, cloud after cloud

            def skip(message: SkippedMessage) -> None:
                summary.skipped.append(message)
                if on_skip is not None:
                    on_skip(message)

            processed = process_clouds(
                bag,
                cloud_topic,
                settings,
                memory,
                with_input=with_input,
                namespace=namespace,
                on_skip=skip if skip_corrupt else None,
            )
            try:
                for row, messages, cloud, result in processed:
                    for message in messages:
                        out.write(*message)
                    summary.rows.append(row)
                    if on_cloud is not None:
                        on_cloud(row, cloud, result)
            except BagStorageError as error:  # keep what came before: those clouds are whole
                summary.storage_error = str(error)
            summary.topics = dict(out.counts)
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


#: The totals list at most this many skipped messages one per line (then how many more).
MAX_SKIPPED_LINES = 20


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
    if summary.without_grasps:
        lines.append(
            f'{summary.without_grasps} of {clouds} clouds gave boxes but no grasps (the note '
            'names the filter that removed them)'
        )
    if summary.skipped:
        lines.append(
            f'skipped {len(summary.skipped)} messages of {summary.input_topic} that do not '
            f'deserialize (corrupt); every other cloud was processed:'
        )
        shown = summary.skipped[:MAX_SKIPPED_LINES]
        lines += [f'  {message.describe()}' for message in shown]
        if len(summary.skipped) > len(shown):
            lines.append(f'  ... and {len(summary.skipped) - len(shown)} more')
    written = ', '.join(f'{topic} ({count})' for topic, count in summary.topics.items())
    lines.append(f'wrote {summary.output_path}: {written}')
    return lines
