"""
What a fleet worker does: one bag, or one time range of a long bag, through `mvbb bag process`.

A whole bag goes through :func:`mvbb_ros.ros.offline.process_bag` itself, so its output folder
holds the bytes a serial `mvbb bag process` writes. A long bag is cut into time ranges
(:func:`plan_ranges`) that run in parallel; each writes its messages to a part file, and
:meth:`BagWorker.assemble` writes them, in order, through the same writer
(:func:`~mvbb_ros.ros.offline.open_output`). The ranges are exact, not approximate: a cloud's
grasps depend on the previous cloud's top grasp (the node's hysteresis), so each range after
the first starts a few clouds early to rebuild that memory, and the run checks that the memory
it rebuilt equals the one the previous range ended with; when it does not, the range runs
again from the previous range's memory.

A message that does not deserialize as a PointCloud2 is skipped, as `bag process` skips it,
in whichever range holds it (a warm-up skips it too and does not report it), and every task
reports the messages it skipped (:func:`skipped_entry`). A bag whose storage fails partway
(truncated) keeps the clouds before the break, as `bag process` keeps them: a whole bag through
`process_bag` itself; for a bag cut into ranges, a range that meets the break (or ranges that
together read fewer clouds than the bag's index lists) make the driver run the bag again as one
task, so that its output stops where a serial run stops.

Every output appears under its final name only when complete (atomic renames), and
``<bag>.fleet.json`` beside the bag's folder records the settings hash, the per-cloud rows and
the skipped messages, so a re-run skips the bag (:func:`completed_rows`). Each attempt at a
task leaves a marker in the staging folder (``.fleet/``), which is how the summary counts Ray's
retries of a killed worker.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
import hashlib
import json
import math
import os
from pathlib import Path
import pickle
import shutil
import socket
import time
from typing import Any

from mvbb_ros.common.atomic import atomic_open
from mvbb_ros.pipeline.process import GraspMemory
from mvbb_ros.pipeline.settings import PipelineSettings
from mvbb_ros.ros.bag import BagError, BagStorageError, CLOUD_TYPE, CloudBag, SkippedMessage
from mvbb_ros.ros.offline import open_output, process_bag, process_clouds, ProcessedCloud

#: Name of the staging folder inside the output folder (part files, attempt markers).
STAGING = '.fleet'
#: Suffix of the manifest beside each bag's output folder.
MANIFEST_SUFFIX = '.fleet.json'
#: Clouds processed before a range's start to rebuild the grasp memory.
WARMUP_CLOUDS = 3


@dataclass(frozen=True)
class BagJob:
    """
    One bag under one setting.

    :ivar bag: the input bag.
    :ivar name: its output folder's name.
    :ivar label: the sweep setting's label ('' without a sweep).
    :ivar output: the bag's output folder (``DIR/<label>/<name>``).
    :ivar settings: the pipeline settings.
    :ivar options: `process_bag`'s other options (topic, namespace, storage, compress).
    :ivar digest: the settings hash (:func:`settings_digest`).
    """

    bag: Path
    name: str
    label: str
    output: Path
    settings: PipelineSettings
    options: dict[str, Any]
    digest: str

    @property
    def manifest(self) -> Path:
        """Return the manifest's path, beside the output folder."""
        return self.output.with_name(self.output.name + MANIFEST_SUFFIX)

    @property
    def staging(self) -> Path:
        """Return the folder of this job's part files and attempt markers."""
        root = self.output.parent if not self.label else self.output.parent.parent
        return root / STAGING / (self.label or '_') / self.name


@dataclass(frozen=True)
class TimeRange:
    """
    A time range of a bag: ``[start_ns, stop_ns)`` of bag time, and where its warm-up starts.

    :ivar number: position among the bag's ranges, from 0.
    :ivar warmup_ns: bag time the warm-up starts at (`start_ns` for the first range).
    :ivar memory: the grasp memory to start from, pickled; None: rebuild it in the warm-up.
    """

    number: int
    start_ns: int
    stop_ns: int
    warmup_ns: int
    memory: bytes | None = None


@dataclass
class Outcome:
    """
    What a task gave back to the driver.

    :ivar rows: the per-cloud rows (``ProcessedCloud`` fields as a dict, plus ``done_s``, the
        wall time the cloud was finished, seconds since the epoch).
    :ivar error: why the bag failed ('' when it did not).
    :ivar attempts: how many times the task was started (2 or more: Ray retried it).
    :ivar seconds: the task's wall time.
    :ivar cpu_seconds: the CPU time the worker process spent on it (less than `seconds` when
        the machine is shared or the task waits on storage).
    :ivar start_memory: for a range: the grasp memory at its start (rebuilt), pickled.
    :ivar end_memory: for a range: the grasp memory at its end, pickled.
    :ivar worker: host and process that ran it.
    :ivar skipped: the messages skipped because they do not deserialize
        (:func:`skipped_entry`), in bag order.
    :ivar storage_error: where the bag's storage failed partway ('' when it did not): for a
        whole bag, its output holds the clouds before it; for a range, nothing was written.
    """

    rows: list[dict[str, Any]] = field(default_factory=list)
    error: str = ''
    attempts: int = 1
    seconds: float = 0.0
    cpu_seconds: float = 0.0
    start_memory: bytes = b''
    end_memory: bytes = b''
    worker: str = ''
    skipped: list[dict[str, Any]] = field(default_factory=list)
    storage_error: str = ''


def skipped_entry(message: SkippedMessage) -> dict[str, Any]:
    """
    Return a skipped message as the fleet reports it: topic, bag time and why.

    Its number among the topic's messages is left out: a time range does not know how many
    messages come before it. The bag time names it.
    """
    return {
        'topic': message.topic,
        'timestamp_ns': message.timestamp_ns,
        'note': f'skipped: does not deserialize as {CLOUD_TYPE}: {message.reason}',
    }


def _input_identity(path: Path) -> list[Any]:
    """Size and modification time of every file of a bag (so a changed input runs again)."""
    files = sorted(path.rglob('*')) if path.is_dir() else [path]
    identity: list[Any] = []
    for item in files:
        if item.is_file():
            stat = item.stat()
            identity.append([item.name, stat.st_size, stat.st_mtime_ns])
    return identity


def settings_digest(bag: Path, settings: PipelineSettings, options: dict[str, Any]) -> str:
    """
    Return a hash of what a bag's output depends on: settings, options, the input's files.

    Not the worker threads (``execution``): the output is the same with any number, so a run
    on another machine (or with other ``workers``) resumes what is complete.

    :raises OSError: when the bag cannot be read (reported per bag).
    """
    stages = asdict(settings)
    stages.pop('execution', None)
    document = {
        'settings': stages,
        'options': options,
        'input': _input_identity(bag),
    }
    text = json.dumps(document, sort_keys=True, default=repr)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _completed(job: BagJob) -> dict[str, Any] | None:
    try:
        document = json.loads(job.manifest.read_text())
    except (OSError, ValueError):
        return None
    if document.get('digest') != job.digest or not (job.output / 'metadata.yaml').is_file():
        return None
    return document if isinstance(document, dict) else None


def completed_rows(job: BagJob) -> list[dict[str, Any]] | None:
    """Return the rows of a complete earlier output with the same settings hash, else None."""
    document = _completed(job)
    rows = None if document is None else document.get('rows')
    return rows if isinstance(rows, list) else None


def completed_skipped(job: BagJob) -> list[dict[str, Any]]:
    """Return the messages a complete earlier output skipped (:func:`skipped_entry`)."""
    document = _completed(job)
    skipped = None if document is None else document.get('skipped')
    return skipped if isinstance(skipped, list) else []


def completed_storage_error(job: BagJob) -> str:
    """Return where the bag's storage failed in a complete earlier output ('' if it did not)."""
    document = _completed(job)
    error = None if document is None else document.get('storage_error')
    return error if isinstance(error, str) else ''


def write_manifest(
    job: BagJob,
    rows: Sequence[dict[str, Any]],
    skipped: Sequence[dict[str, Any]] = (),
    storage_error: str = '',
) -> None:
    """
    Record that `job`'s output is complete (after it is in place), with its rows.

    :param storage_error: where the bag's storage failed partway (the output holds the clouds
        before it), '' when it did not.
    """
    document = {
        'bag': str(job.bag),
        'setting': job.label,
        'digest': job.digest,
        'rows': list(rows),
        'skipped': list(skipped),
        'storage_error': storage_error,
    }
    with atomic_open(job.manifest) as handle:
        json.dump(document, handle, default=_json_float)


def _json_float(value: Any) -> Any:
    return float(value)


def _row(row: ProcessedCloud) -> dict[str, Any]:
    values = asdict(row)
    if math.isnan(values['top_score']):
        values['top_score'] = None  # JSON has no NaN
    values['done_s'] = time.time()
    return values


def plan_ranges(bag: CloudBag, topic: str, clouds_per_range: int) -> list[TimeRange]:
    """
    Cut a bag into time ranges of about `clouds_per_range` clouds each (equal durations).

    A bag with fewer clouds gives one range (the whole bag). Each range after the first warms
    up on about :data:`WARMUP_CLOUDS` clouds before it (by the mean cloud period).
    """
    count = bag.count([topic])
    first, end = bag.time_range()
    parts = max(1, math.ceil(count / max(1, clouds_per_range)))
    if parts == 1 or end - first < parts:
        return [TimeRange(0, first, end, first)]
    period = (end - first) / count
    bounds = [first + (end - first) * k // parts for k in range(parts)] + [end]
    return [
        TimeRange(k, bounds[k], bounds[k + 1], max(first, int(bounds[k] - WARMUP_CLOUDS * period)))
        for k in range(parts)
    ]


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    elif path.exists() or path.is_symlink():
        path.unlink(missing_ok=True)


def remove_leftovers(job: BagJob) -> None:
    """Remove what killed attempts left: temporary folders beside the output, the staging."""
    for leftover in job.output.parent.glob(f'.{job.output.name}.*'):
        _remove(leftover)
    for leftover in job.manifest.parent.glob(f'.{job.manifest.name}.*'):
        _remove(leftover)
    _remove(job.staging)


def _claim_attempt(folder: Path, task: str) -> int:
    """Leave a marker for this attempt (with the worker's pid); return the attempt number."""
    folder.mkdir(parents=True, exist_ok=True)
    for attempt in range(1, 1000):
        marker = folder / f'{task}.attempt-{attempt}'
        try:
            with open(marker, 'x') as handle:
                handle.write(f'{socket.gethostname()} {os.getpid()}\n')
            return attempt
        except FileExistsError:
            continue
    return 1000


def cloud_topic(bag: CloudBag, topics: Sequence[str]) -> str:
    """
    Return the topic to process: the first of `topics` the bag has, or its one cloud topic.

    A fleet mixes bags recorded with different topics, so ``--topic`` may be given several
    times; without it, a bag must have exactly one PointCloud2 topic, as for `bag process`.

    :raises BagError: when the bag has none of `topics`, or several cloud topics and no
        `topics`.
    """
    if not topics:
        return bag.select_topics(None, single=True)[0]
    present = {summary.name for summary in bag.cloud_topics() if summary.count > 0}
    for topic in topics:
        if topic in present:
            return topic
    return bag.select_topics(topics[0], single=True)[0]  # raises, saying what the bag has


@contextmanager
def _reported(outcome: Outcome) -> Iterator[Outcome]:
    """Time a task into `outcome` and record, not raise, why it failed (the fleet goes on)."""
    start, cpu = time.time(), time.process_time()
    try:
        yield outcome
    except (BagError, OSError) as error:
        outcome.error = str(error)
    except Exception as error:  # a bag must not stop the fleet; the summary says why
        outcome.error = f'{type(error).__name__}: {error}'
    outcome.seconds = time.time() - start
    outcome.cpu_seconds = time.process_time() - cpu


class BagWorker:
    """
    A fleet worker (one Ray actor per worker): loads and warms the pipeline once, keeps it.

    Its methods never raise for a bad bag: the :class:`Outcome` says why the bag failed.
    """

    def __init__(self) -> None:
        from mvbb_ros.kernels import warm_up  # the compiled kernels, loaded once per worker

        self.warm_up_seconds = warm_up().seconds
        self.identity = f'{socket.gethostname()}:{os.getpid()}'

    def ready(self) -> str:
        """Return the worker's host and process id (the driver waits for every worker)."""
        return self.identity

    def process(self, job: BagJob) -> Outcome:
        """
        Run `mvbb bag process` on a whole bag into ``job.output``; write its manifest.

        A bag whose storage fails partway gives the output of the clouds before the break, as
        `bag process` writes it, and the outcome's ``storage_error`` says where.
        """
        with _reported(Outcome(worker=self.identity)) as outcome:
            outcome.attempts = _claim_attempt(job.staging, 'bag')
            rows: list[dict[str, Any]] = []
            options = dict(job.options)
            with CloudBag(job.bag) as bag:
                options['topic'] = cloud_topic(bag, options.pop('topics', ()))
            summary = process_bag(
                job.bag,
                job.output,
                settings=job.settings,
                force=True,  # an output without a manifest: a run stopped after the rename
                on_cloud=lambda row, cloud, result: rows.append(_row(row)),
                on_skip=lambda message: outcome.skipped.append(skipped_entry(message)),
                **options,
            )
            write_manifest(job, rows, outcome.skipped, summary.storage_error)
            outcome.rows, outcome.storage_error = rows, summary.storage_error
        return outcome

    def process_range(self, job: BagJob, span: TimeRange) -> Outcome:
        """
        Process one time range of a long bag; write its messages to a part file.

        The range starts from ``span.memory`` when given, else from the memory rebuilt by the
        warm-up clouds (whose outputs are dropped); both memories come back in the outcome.
        When the bag's storage fails in the range or its warm-up, the outcome says where
        (``storage_error``), without rows, and no part file is written.
        """
        with _reported(Outcome(worker=self.identity)) as outcome:
            task = f'range-{span.number:05d}' + ('-rerun' if span.memory is not None else '')
            outcome.attempts = _claim_attempt(job.staging, task)
            namespace = job.options.get('namespace', '/decomposer')
            try:
                with CloudBag(job.bag) as bag:
                    topic = cloud_topic(bag, job.options.get('topics', ()))
                    if span.memory is not None:
                        memory = pickle.loads(span.memory)
                    else:
                        memory = GraspMemory()
                        warmup = process_clouds(
                            bag,
                            topic,
                            job.settings,
                            memory,
                            namespace=namespace,
                            start_ns=span.warmup_ns,
                            stop_ns=span.start_ns,
                            on_skip=lambda message: None,  # the previous range reports it
                        )
                        for _ in warmup:
                            pass
                    outcome.start_memory = pickle.dumps(memory)
                    messages = []
                    for row, written, _, _ in process_clouds(
                        bag,
                        topic,
                        job.settings,
                        memory,
                        namespace=namespace,
                        start_ns=span.start_ns,
                        stop_ns=span.stop_ns,
                        on_skip=lambda message: outcome.skipped.append(skipped_entry(message)),
                    ):
                        messages += written
                        outcome.rows.append(_row(row))
                    outcome.end_memory = pickle.dumps(memory)
            except BagStorageError as error:  # the driver runs the bag again as one task
                outcome.storage_error, outcome.rows, outcome.skipped = str(error), [], []
                return outcome
            with atomic_open(self.part_path(job, span.number), 'wb') as handle:
                pickle.dump(messages, handle, protocol=pickle.HIGHEST_PROTOCOL)
        return outcome

    @staticmethod
    def part_path(job: BagJob, number: int) -> Path:
        """Return the part file of range `number` of `job`."""
        return job.staging / f'range-{number:05d}.part'

    def assemble(
        self,
        job: BagJob,
        ranges: int,
        rows: list[dict[str, Any]],
        skipped: Sequence[dict[str, Any]] = (),
    ) -> Outcome:
        """
        Write the bag from its ranges' part files, in order, with `process_bag`'s writer.

        :param rows: the ranges' rows, in order (renumbered here).
        :param skipped: the messages the ranges skipped, in order (kept in the manifest).
        """
        with _reported(Outcome(worker=self.identity)) as outcome:
            outcome.attempts = _claim_attempt(job.staging, 'assemble')
            settings, options = job.settings, job.options
            with CloudBag(job.bag) as bag:
                topic = cloud_topic(bag, options.get('topics', ()))
            with open_output(
                job.output,
                topic,
                settings,
                namespace=options.get('namespace', '/decomposer'),
                storage=options.get('storage', 'mcap'),
                compress=options.get('compress', False),
                force=True,
            ) as out:
                for number in range(ranges):
                    with open(self.part_path(job, number), 'rb') as handle:
                        for message in pickle.load(handle):
                            out.write(*message)
            rows = [dict(row, index=index) for index, row in enumerate(rows)]
            write_manifest(job, rows, skipped)
            outcome.rows, outcome.skipped = rows, list(skipped)
        return outcome
